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
from neuralbrdf.cli.main import main as cli
from neuralbrdf.lightning.metrics_json import MetricsJson
from neuralbrdf.lightning.run import main
from neuralbrdf.lightning.spectral_mlp_module import SpectralMlpModule
from neuralbrdf.virtual import instrument

# main(args) runs in-process while pytest's own arguments are in sys.argv.
pytestmark = pytest.mark.filterwarnings("ignore:LightningCLI's args parameter is intended")

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "configs" / "spectral_mlp.yaml"



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
    # the shared names of docs/evaluate.md#metrics on the data it was given; a user's file has no truth
    assert 0 < metrics["fit/inplane_glossy_rel_rmse"] < float("inf")
    assert 0 < metrics["fit/inplane_diffuse_rel_rmse"] < float("inf")
    assert "fit/hemisphere_logcos_rmse" not in metrics
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


def test_virtual_measurement_run_reports_the_hemisphere_against_its_truth(tmp_path):
    """The shipped virtual measurements have a truth: metrics.json carries fit/hemisphere_logcos_rmse
    for the best checkpoint, the same quantity ``neuralbrdf evaluate`` computes on more pairs."""
    from neuralbrdf.evaluation.scores import TorchEvaluator, hemisphere_scores
    from neuralbrdf.evaluation.truth import load_truth
    from neuralbrdf.models.directional import SpectralMlpOnDirections

    run_dir = tmp_path / "run"
    assert main(["fit", "--config", str(CONFIG), "--data.virtual", "cyan", *quick("--run_dir", str(run_dir))]) == 0
    metrics = read_metrics(run_dir)
    module = SpectralMlpModule.load_from_checkpoint(run_dir / "checkpoints" / "best.ckpt")
    truth = load_truth("virtual:cyan")
    expected = hemisphere_scores(TorchEvaluator(SpectralMlpOnDirections(module.network), True),
                                 TorchEvaluator(truth.module, True), strata=(8, 10))["hemisphere_logcos_rmse"]
    assert metrics["fit/hemisphere_logcos_rmse"] == pytest.approx(expected, rel=1e-9)
    assert metrics["fit/inplane_diffuse_rel_rmse"] > 0


def test_bad_data_path_is_one_line_error_and_nonzero_exit(tmp_path):
    run_dir = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, str(REPO / "train.py"), "fit", "--config", str(CONFIG),
         "--data.path", str(tmp_path / "missing.csv"), "--run_dir", str(run_dir)],
        capture_output=True, text=True, cwd=tmp_path,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("neuralbrdf train: error:")]
    assert errors == [f"neuralbrdf train: error: {tmp_path / 'missing.csv'}: file not found"]
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
    the Table 5.1 test angles: glossy relative RMSE <= 0.05, diffuse <= 0.10 (the spectral MLP's accuracy targets)."""
    shipped = instrument.default_data_path(material)
    if not shipped.is_file():
        pytest.skip(f"shipped measurement {shipped} not generated")
    args = ["fit", "--config", str(CONFIG), "--data.virtual", material, "--run_dir", str(tmp_path)]
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


# --------------------------------------------------------------------------- runs and failures


def _fit(run_dir, gcms_session, *extra):
    return main(["fit", "--config", str(CONFIG), *data_args(gcms_session), *quick("--run_dir", str(run_dir)), *extra])


def _snapshot(run_dir):
    return {p.relative_to(run_dir): p.read_bytes() for p in sorted(run_dir.rglob("*")) if p.is_file()}


@pytest.fixture
def short_run(tmp_path, gcms_session):
    run_dir = tmp_path / "run"
    assert _fit(run_dir, gcms_session) == 0
    return run_dir


def test_a_run_is_never_overwritten_without_resume_or_overwrite(short_run, gcms_session, capsys):
    """An existing run is refused, unchanged, unless --resume or --overwrite is given."""
    before = _snapshot(short_run)
    assert _fit(short_run, gcms_session) == 2
    err = capsys.readouterr().err
    assert "already holds a run" in err and "--resume" in err and "--overwrite" in err
    assert _snapshot(short_run) == before


def test_overwrite_replaces_a_run_but_a_failed_start_puts_it_back(short_run, gcms_session, tmp_path):
    before = _snapshot(short_run)
    missing = ["--data.path", str(tmp_path / "missing.csv"), "--data.reference", gcms_session[1]]
    assert main(["fit", "--config", str(CONFIG), *quick("--run_dir", str(short_run)), *missing, "--overwrite"]) == 2
    assert _snapshot(short_run) == before  # the old run is back, nothing of the failed start
    assert _fit(short_run, gcms_session, "--overwrite", "--seed_everything", "1") == 0
    assert read_metrics(short_run)["status"] == "ok"
    assert _snapshot(short_run) != before
    assert not [p for p in short_run.iterdir() if "neuralbrdf-tmp" in p.name]


@pytest.mark.parametrize("config", ["spectral_mlp", "abc"])
def test_a_single_wavelength_table_is_refused_before_a_fit(tmp_path, capsys, config):
    """One wavelength is no range: the spectral MLP exported a model claiming 400-700 nm, ABC a
    best.ckpt that export refused."""
    import csv

    full = tmp_path / "full.csv"
    assert cli(["simulate", "--material", "gold", "--truth", "--out", str(full)]) == 0
    with open(full, newline="") as handle:
        rows = list(csv.reader(handle))
    keep = [0, 1, 2, 3, rows[0].index("550")]
    table = tmp_path / "550.csv"
    with open(table, "w", newline="") as handle:
        csv.writer(handle).writerows([[row[i] for i in keep] for row in rows])
    capsys.readouterr()
    run_dir = tmp_path / "run"
    assert main(["fit", "--config", config, "--data.path", str(table), "--run_dir", str(run_dir)]) == 2
    assert capsys.readouterr().err == (f"neuralbrdf train: error: {table}: holds one wavelength (550 nm); a spectral fit "
                                       "needs samples at two or more wavelengths, whose range the fitted model covers\n")
    assert not run_dir.exists()


def test_a_run_directory_is_locked_while_a_command_runs_in_it(short_run, gcms_session, monkeypatch, capsys):
    """Two fits into one run directory at once (with or without --overwrite/--resume): the second is
    refused in one line, before it touches anything, and the first ends as if alone."""
    attempts = []
    finish = MetricsJson.on_fit_end

    def second_command_meanwhile(self, trainer, module):
        for extra in ([], ["--overwrite"], ["--resume"]):
            attempts.append(_fit(short_run, gcms_session, *extra))
        finish(self, trainer, module)

    monkeypatch.setattr(MetricsJson, "on_fit_end", second_command_meanwhile)
    assert _fit(short_run, gcms_session, "--overwrite", "--seed_everything", "1") == 0
    assert attempts == [2, 2, 2]
    err = capsys.readouterr().err
    assert err.count(f"neuralbrdf train: error: {short_run}: in use by another training run (process ") == 3, err
    assert read_metrics(short_run)["status"] == "ok"
    assert [row.split(",")[0] for row in (short_run / "metrics.csv").read_text().splitlines()][:1] == ["epoch"]
    monkeypatch.undo()
    assert _fit(short_run, gcms_session, "--overwrite") == 0  # the lock ends with the command


def test_a_refused_start_leaves_no_folder_it_created(tmp_path, gcms_session):
    run_dir = tmp_path / "new" / "deeper" / "run"
    assert main(["fit", "--config", str(CONFIG), *quick("--run_dir", str(run_dir)),
                 "--data.path", str(tmp_path / "missing.csv")]) == 2
    assert not (tmp_path / "new").exists()


def test_resume_continues_from_last_appending_the_log_and_summing_wall_time(short_run, gcms_session):
    first = read_metrics(short_run)
    rows_before = (short_run / "metrics.csv").read_text().splitlines()
    args = ["fit", "--config", str(CONFIG), *data_args(gcms_session), "--run_dir", str(short_run),
            "--trainer.max_epochs", "2", "--trainer.limit_train_batches", "2", "--resume"]
    assert main(args) == 0
    metrics = read_metrics(short_run)
    assert metrics["status"] == "ok" and metrics["fit/epochs"] == 2
    assert metrics["fit/wall_time_s"] > first["fit/wall_time_s"]
    rows = (short_run / "metrics.csv").read_text().splitlines()
    assert rows[: len(rows_before)][1:] == rows_before[1:] and len(rows) > len(rows_before)
    epochs = {row.split(",")[rows[0].split(",").index("epoch")] for row in rows[1:]}
    assert epochs == {"0", "1"}


@pytest.mark.parametrize("damage", ["missing", "truncated"])
def test_resume_from_a_missing_or_truncated_checkpoint_is_one_line(short_run, gcms_session, damage):
    """No traceback."""
    last = short_run / "checkpoints" / "last.ckpt"
    if damage == "missing":
        last.unlink()
    else:
        last.write_bytes(last.read_bytes()[:1000])
    proc = subprocess.run(
        [sys.executable, str(REPO / "train.py"), "fit", "--config", str(CONFIG), *data_args(gcms_session),
         "--run_dir", str(short_run), "--resume"],
        capture_output=True, text=True,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("neuralbrdf train: error:")]
    assert len(errors) == 1 and ("last.ckpt not found" in errors[0] or "not a readable PyTorch checkpoint" in errors[0])


def test_binary_config_and_missing_evaluation_checkpoint_are_one_line(tmp_path):
    binary = tmp_path / "config.yaml"
    binary.write_bytes(b"\x00\x01binary\xff\xfe")
    for args in (["fit", "--config", str(binary)],
                 ["validate", "--config", str(CONFIG), "--ckpt_path", str(tmp_path / "none.ckpt")]):
        proc = subprocess.run([sys.executable, str(REPO / "train.py"), *args], capture_output=True, text=True, cwd=tmp_path)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert len([line for line in proc.stderr.splitlines() if line.startswith("neuralbrdf train: error:")]) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["config.yaml"]


def _assert_failed_run(run_dir, cause_fragment, capsys):
    err = capsys.readouterr().err
    assert "neuralbrdf train: error: fit failed: " in err and cause_fragment in err, err
    assert f"(run: {run_dir}; its metrics.json holds the cause)" in err
    text = (run_dir / "metrics.json").read_text()
    metrics = json.loads(text, parse_constant=lambda c: pytest.fail(f"not strict JSON: {c}"))
    assert metrics["status"] == "failed" and cause_fragment in metrics["cause"]
    assert "fit/best_model_path" not in metrics
    assert not list(run_dir.rglob("best*.ckpt"))


@pytest.mark.parametrize(
    "extra, cause",
    [
        (["--model.init_args.optimizer.init_args.lr", "10", "--trainer.limit_train_batches", "20"],
         "no better than predicting 0"),
        (["--model.init_args.optimizer.init_args.lr", "1e30", "--model.init_args.residual", "linear"],
         "non-finite training loss"),
    ],
    ids=["dead network after a huge learning rate", "non-finite loss"],
)
def test_a_failed_fit_exits_1_with_its_cause_and_no_best_checkpoint(tmp_path, gcms_session, capsys, extra, cause):
    """A failed fit is the command's failure too."""
    run_dir = tmp_path / "run"
    assert _fit(run_dir, gcms_session, *extra) == 1
    _assert_failed_run(run_dir, cause, capsys)


@pytest.mark.parametrize("scores, fails", [
    ({"val/rel_rmse_glossy": [1.0]}, True),                    # a dead network: predicting 0 exactly
    ({"val/rel_rmse_glossy": [0.98, 0.95]}, True),             # a non-fit: too few steps
    ({"val/rel_rmse_glossy": [1.6, 1.3]}, True),               # overshoots, worse than predicting 0
    ({"val/rel_rmse_glossy": [1.3, 0.89]}, False),             # came below the line once: kept
    ({"val/rel_rmse_glossy": [0.95], "val/rel_rmse_glossy_median": [0.5]}, True),   # each must come below
    ({"val/rel_rmse_glossy": [0.6], "val/rel_rmse_glossy_median": [0.95, 0.4]}, False),
    ({"val/rel_rmse_glossy": [0.9]}, True),                    # the line itself fails
    ({"val/rel_rmse_glossy": [0.5], "val/rel_rmse_excluded": [12.0]}, False),  # a count of left-out entries
])
def test_fit_health_fails_a_fit_no_better_than_predicting_zero(scores, fails):
    """A fit fails when a validation relative error stayed at or above NO_BETTER_THAN_ZERO (0.9;
    predicting 0 scores 1) at its best over the validations."""
    from types import SimpleNamespace

    from neuralbrdf.errors import FitFailed
    from neuralbrdf.lightning.fit_health import NO_BETTER_THAN_ZERO, FitHealth

    assert NO_BETTER_THAN_ZERO == 0.9
    health = FitHealth()
    for epoch in range(max(len(values) for values in scores.values())):
        metrics = {name: torch.tensor(values[min(epoch, len(values) - 1)], dtype=torch.float64)
                   for name, values in scores.items()}
        trainer = SimpleNamespace(sanity_checking=False, state=SimpleNamespace(fn="fit"), callback_metrics=metrics,
                                  checkpoint_callbacks=[], current_epoch=epoch)
        health.on_validation_end(trainer, None)
    if fails:
        with pytest.raises(FitFailed, match="no better than predicting 0"):
            health.on_train_end(trainer, object())
    else:
        health.on_train_end(trainer, object())


@pytest.mark.parametrize("name, value", [("gamma", "-1"), ("gamma", "-1e-12"), ("rel_rmse_floor", "-1e-4")])
def test_parameters_outside_their_domain_fail_before_a_run_exists(tmp_path, gcms_session, capsys, name, value):
    run_dir = tmp_path / "run"
    assert _fit(run_dir, gcms_session, f"--model.init_args.{name}={value}") == 2
    assert f"model.{name} must be a finite number >= 0" in capsys.readouterr().err
    assert not run_dir.exists()


def test_a_successful_fit_is_marked_ok_in_strict_json(fitted_run):
    text = (fitted_run / "metrics.json").read_text()
    assert json.loads(text, parse_constant=lambda c: pytest.fail(c))["status"] == "ok"


def test_metrics_json_writes_non_finite_numbers_as_null(tmp_path):
    class Trainer:
        default_root_dir = str(tmp_path)
        is_global_zero = True
        callback_metrics = {"test/loss": torch.tensor(float("nan")), "test/x": torch.tensor(float("inf"))}

    MetricsJson().on_test_end(Trainer(), None)
    assert json.loads((tmp_path / "metrics.json").read_text()) == {"test/loss": None, "test/x": None}


def test_checkpoints_are_written_whole_or_not_at_all(tmp_path, monkeypatch):
    """A save that dies half-way leaves the previous checkpoint, never a truncated one."""
    from neuralbrdf import checkpoints
    from neuralbrdf.lightning import checkpoint_io

    path = tmp_path / "checkpoints" / "last.ckpt"
    checkpoint_io.AtomicCheckpointIO().save_checkpoint({"epoch": 1}, path)

    def dying_save(obj, handle):
        handle.write(b"PK\x03\x04 half")
        raise KeyboardInterrupt

    monkeypatch.setattr(checkpoints.torch, "save", dying_save)
    with pytest.raises(KeyboardInterrupt):
        checkpoint_io.AtomicCheckpointIO().save_checkpoint({"epoch": 2}, path)
    assert torch.load(path, weights_only=True) == {"epoch": 1}
    assert [p.name for p in path.parent.iterdir()] == ["last.ckpt"]


# --------------------------------------------------------------------------- the command's habits


def test_a_fit_ends_with_a_summary_that_says_how_to_export(tmp_path, gcms_session, capsys):
    run_dir = tmp_path / "run"
    assert main(["fit", "--config", "spectral_mlp", *data_args(gcms_session), *quick("--run_dir", str(run_dir))]) == 0
    err = capsys.readouterr().err
    best = run_dir / "checkpoints" / "best.ckpt"
    assert f"run: {run_dir}" in err and "metrics: fit/" in err and f"checkpoint: {best}" in err
    score = json.loads((run_dir / "metrics.json").read_text())["fit/best_model_score"]
    assert f"(chosen on val/loss: {score:.4g}; the fit/val metrics above are the last epoch's)" in err
    assert f"export: neuralbrdf export --ckpt {best} --out MODEL.onnx" in err
    assert "GPU available" not in err and "Tip" not in err  # quiet without --verbose


def test_an_epoch_line_says_when_the_fit_stops_before_its_last_epoch():
    from neuralbrdf.lightning.progress import epoch_line

    assert epoch_line(0, 6, {"train/loss": 0.5}, 2.2) == "epoch 1/6 train/loss=0.5 time_s=2.2"
    assert epoch_line(0, 6, {}, 2.2, stopping=True).startswith("epoch 1/6 time_s=2.2; the fit is done: it stopped before")
    assert epoch_line(5, 6, {}, 2.2, stopping=True) == "epoch 6/6 time_s=2.2"  # the last epoch: nothing to say


def test_off_a_terminal_a_fit_logs_one_line_per_epoch(tmp_path, gcms_session, capfd):
    """pytest's output is no terminal: Lightning's bar gives way to ``epoch E/N key=value`` lines."""
    args = ["fit", "--config", "spectral_mlp", *data_args(gcms_session), "--trainer.max_epochs", "2",
            "--trainer.limit_train_batches", "2"]
    assert main([*args, "--run_dir", str(tmp_path / "run")]) == 0
    out, err = capfd.readouterr()
    epochs = [line for line in err.splitlines() if line.startswith("epoch ")]
    assert [line.split()[1] for line in epochs] == ["1/2", "2/2"]
    assert all(" val/loss=" in line and line.split()[-1].startswith("time_s=") for line in epochs)
    assert "\r" not in out + err and "Epoch 0" not in out + err and "Sanity Checking" not in out + err
    assert main([*args, "--run_dir", str(tmp_path / "quiet"), "--trainer.enable_progress_bar", "false"]) == 0
    assert "epoch " not in capfd.readouterr().err


def test_verbose_keeps_lightnings_lines_and_quiet_mode_restores_logging(tmp_path, gcms_session, caplog):
    import logging

    caplog.set_level(logging.INFO)
    loggers = [logging.getLogger(name) for name in ("pytorch_lightning", "lightning.pytorch")]
    levels = [logger.level for logger in loggers]
    assert main(["fit", "--config", "spectral_mlp", *data_args(gcms_session),
                 *quick("--run_dir", str(tmp_path / "quiet"))]) == 0
    assert not [r for r in caplog.records if "GPU available" in r.getMessage()]
    assert [logger.level for logger in loggers] == levels
    assert main(["fit", "--config", "spectral_mlp", "--verbose", *data_args(gcms_session),
                 *quick("--run_dir", str(tmp_path / "verbose"))]) == 0
    assert [r for r in caplog.records if "GPU available" in r.getMessage()]


def test_help_names_every_shipped_config_and_the_data_options():
    from neuralbrdf.configs_dir import shipped_configs
    from neuralbrdf.lightning.train_help import help_text

    text = help_text()
    for path in shipped_configs():
        assert f"  {path.stem} " in text, path.stem
    for option in ("--data.path", "--data.reference", "--data.virtual", "--data.nbrdf", "--data.plan",
                   "--data.sources", "--data.test_split", "--run_dir", "--verbose"):
        assert option in text, option
    assert "sr⁻¹" in text and "``" not in text and ":mod:" not in text  # units kept, markup gone
    assert len(text.splitlines()) < 200


def test_help_and_no_arguments(capsys):
    assert main(["--help"]) == 0 and "shipped configs (--config NAME)" in capsys.readouterr().out
    assert main([]) == 2 and "usage: neuralbrdf train" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["abc", "abc.yaml", "configs/abc.yaml"])
def test_a_shipped_config_by_name(tmp_path, monkeypatch, name):
    from neuralbrdf.configs_dir import CONFIGS_DIR, resolve_config

    monkeypatch.chdir(tmp_path)  # no configs/ folder here
    assert resolve_config(name) == CONFIGS_DIR / "abc.yaml"
    assert resolve_config("no_such_config") == Path("no_such_config")
    (tmp_path / "abc.yaml").write_text("seed_everything: 1\n")
    assert resolve_config("abc.yaml") == Path("abc.yaml")  # a file that exists wins


def test_an_overlay_alone_loads_its_base_first(tmp_path, monkeypatch):
    from neuralbrdf.configs_dir import CONFIGS_DIR, overlay_base
    from neuralbrdf.lightning.run import _resolve_config_files

    monkeypatch.chdir(tmp_path)
    assert overlay_base(CONFIGS_DIR / "nlb_latent_report.yaml") == CONFIGS_DIR / "nlb_latent.yaml"
    assert overlay_base(CONFIGS_DIR / "nlb_latent.yaml") is None
    base, overlay = str(CONFIGS_DIR / "nlb_latent.yaml"), str(CONFIGS_DIR / "nlb_latent_report.yaml")
    expected = ["fit", "--config", base, "--config", overlay, "--data.plan", "DS2"]
    assert _resolve_config_files(["fit", "--data.plan", "DS2", "-c", "nlb_latent_report"]) == expected
    assert _resolve_config_files(["fit", "--config", "nlb_latent", "--config=nlb_latent_report", "--data.plan", "DS2"]) == expected


def test_the_neuralbrdf_command_hands_train_and_export_their_arguments(capsys):
    from neuralbrdf.cli.main import main as neuralbrdf

    assert neuralbrdf(["train", "--help"]) == 0 and "data options of" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exit_info:
        neuralbrdf(["export", "--help"])
    assert exit_info.value.code == 0 and "usage: neuralbrdf export" in capsys.readouterr().out
    assert neuralbrdf(["export", "--ckpt", "missing.ckpt", "--out", "m.onnx"]) == 2
    assert "missing.ckpt" in capsys.readouterr().err
