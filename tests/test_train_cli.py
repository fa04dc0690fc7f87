"""``train.py`` (LightningCLI) end to end: run directory, checkpoints, metrics.json, errors."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from neuralbrdf.data.gcms import write_gcms
from neuralbrdf.data.plans import in_plane_plan, spectral_mlp_split
from neuralbrdf.data.table import write_table
from neuralbrdf.evaluation.scores import inplane_scores
from neuralbrdf.lightning.measurement_data import MeasurementDataModule
from neuralbrdf.lightning.run import MetricsJson, main
from neuralbrdf.lightning.spectral_mlp_module import SpectralMlpModule
from neuralbrdf.virtual import instrument

# main(args) runs in-process while pytest's own arguments are in sys.argv.
pytestmark = pytest.mark.filterwarnings("ignore:LightningCLI's args parameter is intended")

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "configs" / "spectral_mlp.yaml"


@pytest.fixture(autouse=True)
def keep_torch_threads():
    """The config sets torch's thread count for the process; give other tests theirs back."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def gcms_session(tmp_path_factory):
    folder = tmp_path_factory.mktemp("gcms")
    device = instrument.VirtualGoniospectrophotometer(noise_rel=0.01, noise_abs=1e-4, seed=3)
    paths = []
    for name in ("gold", "munsell_n9"):
        write_gcms(device.measure_plan(name, "DS1"), folder / f"{name}.csv")
        paths.append(str(folder / f"{name}.csv"))
    return paths


def data_args(gcms_session):
    return ["--data.path", gcms_session[0], "--data.reference", gcms_session[1]]


def quick(*extra):
    return ["--trainer.max_epochs", "1", "--trainer.limit_train_batches", "2", *extra]


@pytest.fixture(scope="module")
def fitted_run(tmp_path_factory, gcms_session):
    """One short fit of a 12-wide network (later stages must take the width from the checkpoint)."""
    run_dir = tmp_path_factory.mktemp("run")
    threads = torch.get_num_threads()
    args = ["fit", "--config", str(CONFIG), *data_args(gcms_session), "--model.init_args.hidden", "12"]
    assert main([*args, *quick("--run_dir", str(run_dir))]) == 0
    torch.set_num_threads(threads)
    return run_dir


def read_metrics(run_dir):
    return json.loads((run_dir / "metrics.json").read_text())


def test_fit_writes_config_checkpoints_csv_log_and_metrics(fitted_run, gcms_session):
    assert (fitted_run / "config.yaml").is_file()
    assert gcms_session[0] in (fitted_run / "config.yaml").read_text()
    assert (fitted_run / "checkpoints" / "best.ckpt").is_file()
    assert (fitted_run / "checkpoints" / "last.ckpt").is_file()
    header = (fitted_run / "metrics.csv").read_text().splitlines()[0].split(",")
    assert {"train/loss", "val/loss", "val/rel_rmse_glossy_median"} <= set(header)
    metrics = read_metrics(fitted_run)
    for key in ("fit/train/loss", "fit/val/loss", "fit/val/rel_rmse_glossy", "fit/val/rel_rmse_glossy_median"):
        assert 0 < metrics[key] < float("inf")
    assert metrics["fit/epochs"] == 1
    assert metrics["fit/best_model_path"] == "checkpoints/best.ckpt"
    assert metrics["fit/best_model_score"] == pytest.approx(metrics["fit/val/loss"])
    assert not list(fitted_run.glob(".*tmp*"))  # atomic writes leave no temporaries


def test_test_and_validate_with_a_checkpoint_merge_into_the_run(fitted_run, gcms_session):
    best = fitted_run / "checkpoints" / "best.ckpt"
    for stage in ("test", "validate"):
        assert main([stage, "--config", str(CONFIG), *data_args(gcms_session), "--ckpt_path", str(best)]) == 0
        assert (fitted_run / stage / "config.yaml").is_file() and (fitted_run / stage / "metrics.csv").is_file()
    metrics = read_metrics(fitted_run)
    # The best checkpoint was chosen on this very split: evaluating it again gives the same number.
    assert metrics["test/loss"] == pytest.approx(metrics["fit/best_model_score"], rel=1e-6)
    assert metrics["validate/rel_rmse_glossy_median"] == pytest.approx(metrics["test/rel_rmse_glossy_median"])
    assert "fit/train/loss" in metrics and "test/loss" in metrics


def test_a_checkpoint_loads_without_the_cli(fitted_run):
    module = SpectralMlpModule.load_from_checkpoint(fitted_run / "checkpoints" / "best.ckpt")
    assert module.hparams.hidden == 12 and module.hparams.activation == "tanh"
    assert module.network.layers[0].out_features == 12
    f = module(torch.tensor([30.0]), torch.tensor([30.0]), torch.tensor([550.0]))
    assert f.shape == (1,) and bool(torch.isfinite(f).all())


def test_default_run_dir_is_under_runs_by_config_stem(tmp_path, monkeypatch, gcms_session):
    monkeypatch.chdir(tmp_path)
    assert main(["fit", "--config", str(CONFIG), *data_args(gcms_session), *quick("--data.eval_batch_size", "4000")]) == 0
    (run_dir,) = (tmp_path / "runs" / "spectral_mlp").iterdir()
    assert (run_dir / "checkpoints" / "last.ckpt").is_file()
    # The evaluation split came in several batches; the metrics see all of it.
    assert 0 < read_metrics(run_dir)["fit/val/rel_rmse_glossy_median"] < float("inf")


@pytest.mark.parametrize("plan, split", [("DS2", "every_third_theta_i"), ("DS3", "every_third_theta_i"), ("DS4", "none")])
def test_sparse_plans_train(tmp_path, plan, split):
    """DS2–DS4 tables train with the default config: the test split follows the plan (``auto``)."""
    table = tmp_path / f"gold_{plan}.csv"
    write_table(instrument.VirtualGoniospectrophotometer.ground_truth("gold", *in_plane_plan(plan)), table)
    run_dir = tmp_path / "run"
    assert main(["fit", "--config", str(CONFIG), "--data.path", str(table), *quick("--run_dir", str(run_dir))]) == 0
    metrics = read_metrics(run_dir)
    assert metrics["fit/epochs"] == 1 and (run_dir / "checkpoints" / "best.ckpt").is_file()
    assert 0 < metrics["fit/val/loss"] < float("inf")
    module = SpectralMlpModule.load_from_checkpoint(run_dir / "checkpoints" / "best.ckpt")
    f = module(torch.tensor([30.0]), torch.tensor([30.0]), torch.tensor([550.0]))
    assert bool(torch.isfinite(f).all())
    data = MeasurementDataModule(str(table))
    data.setup("fit")
    assert data.resolved_test_split == split


def test_bad_data_path_is_one_line_error_and_nonzero_exit(tmp_path):
    run_dir = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, str(REPO / "train.py"), "fit", "--config", str(CONFIG),
         "--data.path", str(tmp_path / "missing.csv"), "--run_dir", str(run_dir)],
        capture_output=True, text=True, cwd=tmp_path,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert errors == [f"error: {tmp_path / 'missing.csv'}: file not found"]
    assert not run_dir.exists()  # nothing written for a run that never started


def test_gcms_raw_without_reference_is_an_input_error(gcms_session, capsys):
    assert main(["fit", "--config", str(CONFIG), "--data.path", gcms_session[0], *quick()]) == 2
    assert "pass the Munsell N9 reference" in capsys.readouterr().err


def test_metrics_json_refuses_to_merge_into_a_corrupt_file(tmp_path):
    from neuralbrdf.errors import InputError

    class Trainer:
        default_root_dir = str(tmp_path)
        is_global_zero = True
        callback_metrics = {"test/loss": torch.tensor(0.5)}

    (tmp_path / "metrics.json").write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        MetricsJson().on_test_end(Trainer(), None)
    (tmp_path / "metrics.json").write_text('{"fit/epochs": 3}')
    MetricsJson().on_test_end(Trainer(), None)
    assert read_metrics(tmp_path) == {"fit/epochs": 3, "test/loss": 0.5}


@pytest.mark.slow
@pytest.mark.parametrize("material", ["gold", "gonio", "cyan", "magenta"])
def test_full_training_fits_glossy_and_diffuse_against_the_truth(tmp_path, material):
    """30 epochs of the default config on the shipped DS1 data, scored against the noiseless truth on
    the Table 5.1 test angles: glossy relative RMSE <= 0.05, diffuse <= 0.10 (issue 8 targets)."""
    shipped = instrument.default_data_path(material)
    if not shipped.is_file():
        pytest.skip(f"shipped measurement {shipped} not generated")
    args = ["fit", "--config", str(CONFIG), "--data.virtual_material", material, "--run_dir", str(tmp_path)]
    assert main(args) == 0
    metrics = read_metrics(tmp_path)
    assert metrics["fit/epochs"] == 30
    assert metrics["fit/wall_time_s"] <= 600.0  # 78-433 s measured at load average 8-15 on 2 cores
    theta_i, theta_r = in_plane_plan("DS1")
    held_out = spectral_mlp_split(theta_i)
    theta_i, theta_r = theta_i[held_out], theta_r[held_out]
    truth = instrument.VirtualGoniospectrophotometer.ground_truth(material, theta_i, theta_r)
    module = SpectralMlpModule.load_from_checkpoint(tmp_path / "checkpoints" / "best.ckpt")
    n, wavelengths = len(theta_i), truth.wavelengths
    with torch.no_grad():
        pred = module(
            *(torch.tensor(np.repeat(a, len(wavelengths)), dtype=torch.float32) for a in (theta_i, theta_r)),
            torch.tensor(np.tile(wavelengths, n), dtype=torch.float32),
        )
    scores, _ = inplane_scores(pred.double().numpy().reshape(n, -1), truth.values, theta_i, theta_r)
    assert scores["inplane_glossy_rel_rmse"] <= 0.05
    assert scores["inplane_diffuse_rel_rmse"] <= 0.10
