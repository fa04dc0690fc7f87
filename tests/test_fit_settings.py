"""Fits that would be endless or meaningless are refused in one line before a run directory exists:
settings (:mod:`neuralbrdf.lightning.fit_settings`) from the command line, a config file and
``nb.fit(overrides=…)``, and data without signal (:func:`neuralbrdf.sources.check_signal`, the
ABC fit's :func:`~neuralbrdf.sources.require_lobe`, the spectral MLP's wavelength range)."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import yaml

import neuralbrdf as nb
from neuralbrdf.cli.main import main as cli
from neuralbrdf.configs_dir import CONFIGS_DIR
from neuralbrdf.data.table import read_table, write_table
from neuralbrdf.lightning.run import main as train
from process_hooks import GUARD

#: ``train fit`` arguments that end a fit which should have been refused (not hang the test).
GUARDED = [argument for key, value in GUARD.items() for argument in (f"--{key}", value)]

pytestmark = pytest.mark.filterwarnings("ignore:LightningCLI's args parameter is intended")



def refused(args: list[str], tmp_path: Path, capsys) -> str:
    run = tmp_path / "run"
    assert train([*args, "--run_dir", str(run)]) == 2
    assert not run.exists()
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("neuralbrdf train: error: "), lines
    return lines[0].removeprefix("neuralbrdf train: error: ")


@pytest.mark.parametrize("flags, message", [
    (["--trainer.max_epochs", "-1"], "--trainer.max_epochs -1: -1 is Lightning's 'no limit', and neither "
                                     "trainer.max_steps nor trainer.max_time is set: the fit would never end"),
    (["--trainer.max_epochs", "0"], "--trainer.max_epochs 0: trains no epoch"),
    (["--trainer.max_epochs", "null"], "--trainer.max_epochs None: null leaves the limit to Lightning's default of "
                                       "1000 epochs"),
    (["--trainer.max_steps", "0"], "--trainer.max_steps 0: trains no step"),
    (["--trainer.limit_train_batches", "0"], "--trainer.limit_train_batches 0.0: no training step in an epoch"),
    (["--trainer.limit_val_batches", "0"], "--trainer.limit_val_batches 0.0: no validation, so the checkpoint "
                                           "chosen on val/loss would never be chosen"),
    (["--model.optimizer.lr", "0"], "--model.optimizer.lr 0.0: expected a finite number > 0 (the learning rate)"),
    (["--model.init_args.optimizer.init_args.lr=-0.01"], "--model.optimizer.lr -0.01: expected a finite number > 0"),
    (["--model.optimizer.lr", ".inf"], "--model.optimizer.lr inf: expected a finite number > 0"),
    (["--model.optimizer.lr", ".nan"], "--model.optimizer.lr nan: expected a finite number > 0"),
    (["--model.lr_scheduler.gamma", "0"], "--model.lr_scheduler.gamma 0.0: expected a finite number > 0 (the "
                                          "learning rate's decay factor)"),
])
def test_an_endless_or_empty_fit_is_refused_naming_the_key(tmp_path, capsys, flags, message):
    """``trainer.max_epochs -1`` ran until a timeout killed it; 0 epochs saved the untrained model as
    best; a learning rate of 0 left it as it started."""
    assert refused(["fit", "--config", "spectral_mlp", *flags, *GUARDED], tmp_path, capsys).startswith(message)


def test_a_limit_set_elsewhere_makes_no_epoch_limit_fine(tmp_path):
    run = tmp_path / "run"
    assert train(["fit", "--config", "spectral_mlp", "--trainer.max_epochs", "-1", "--trainer.max_steps", "2",
                  "--trainer.limit_train_batches", "1", "--trainer.enable_progress_bar", "false",
                  "--run_dir", str(run)]) == 0


def test_a_setting_from_a_config_file_names_the_file(tmp_path, capsys):
    overlay = tmp_path / "mine.yaml"
    overlay.write_text("trainer:\n  max_epochs: -1\n")
    line = refused(["fit", "--config", "abc", "--config", str(overlay), *GUARDED], tmp_path, capsys)
    assert line.startswith(f"{overlay}: trainer.max_epochs -1: -1 is Lightning's 'no limit'"), line


@pytest.mark.parametrize("overrides, key", [({"trainer.max_epochs": -1}, "trainer.max_epochs"),
                                            ({"trainer.max_epochs": None}, "trainer.max_epochs"),
                                            ({"model.optimizer.lr": float("nan")}, "model.optimizer.lr")])
def test_python_overrides_are_refused_alike(tmp_path, overrides, key):
    with pytest.raises(nb.InputError, match=rf"^--{key} (-1|nan|None): "):
        nb.fit("spectral_mlp", "virtual:gold", run_dir=tmp_path / "run", overrides={**overrides, **GUARD})
    assert not (tmp_path / "run").exists()


def _config(name: str) -> dict:
    """A shipped config as YAML data, an overlay over its base."""
    from neuralbrdf.configs_dir import overlay_base

    path = CONFIGS_DIR / f"{name}.yaml"
    base = overlay_base(path)
    merged = yaml.safe_load(base.read_text()) if base is not None else {}

    def merge(into: dict, update: dict) -> dict:
        for key, value in update.items():
            into[key] = merge(dict(into.get(key) or {}), value) if isinstance(value, dict) else value
        return into

    return merge(merged, yaml.safe_load(path.read_text()))


SHIPPED = sorted(path.stem for path in CONFIGS_DIR.glob("*.yaml"))


@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_config_passes_and_refuses_what_it_has(name):
    """The survey: each shipped config's own settings pass; each endless or empty setting it could
    be given is refused, for every learning rate and decay factor it has."""
    from neuralbrdf.lightning.fit_settings import fit_setting_problems

    config = _config(name)
    assert fit_setting_problems(config) == []
    nonsense = [("trainer", "max_epochs", -1), ("trainer", "max_epochs", 0), ("trainer", "limit_train_batches", 0)]
    model = config["model"].get("init_args", {})
    for part, key in (("optimizer", "lr"), ("lr_scheduler", "gamma")):
        if key in (model.get(part) or {}).get("init_args", {}):
            nonsense += [(part, key, value) for value in (0.0, -1.0, float("inf"), float("nan"))]
    for part, key, value in nonsense:
        changed = _config(name)
        where = changed["trainer"] if part == "trainer" else changed["model"]["init_args"][part]["init_args"]
        where[key] = value
        assert fit_setting_problems(changed), (name, part, key, value)


# --------------------------------------------------------------------------- data without signal


@pytest.fixture(scope="module")
def gold(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("tables") / "gold.csv"
    assert cli(["simulate", "--material", "gold", "--plan", "DS2", "--truth", "--out", str(path)]) == 0
    return path


def _changed(table: Path, name: str, **changes) -> Path:
    data = read_table(table)
    out = table.parent / f"{name}.csv"
    write_table(dataclasses.replace(data, **changes), out)
    return out


KINDS = {
    "spectral_mlp": ["--trainer.max_epochs", "1"],
    "abc": ["--model.n_starts", "1", "--data.eval_plan", "null"],
    "nlb_spectral": ["--trainer.max_epochs", "1", "--data.steps_per_epoch", "2", "--data.eval_plan", "null",
                     "--model.init_starts", "1", "--model.init_candidates", "0"],
    "nlb_latent": ["--trainer.max_epochs", "1", "--data.steps_per_epoch", "2", "--data.eval_plan", "null"],
}
#: The RGB NLB reads linear sRGB tables only.
RGB_ONLY = {"nlb_latent"}


@pytest.mark.parametrize("kind", KINDS)
def test_an_all_zero_table_is_refused_for_every_model(gold, tmp_path, capsys, kind):
    """The spectral NLB fitted it with status "ok": a model of nothing."""
    table = read_table(gold).to_rgb() if kind in RGB_ONLY else read_table(gold)
    zeros = gold.parent / f"zeros_{kind}.csv"
    write_table(dataclasses.replace(table, values=np.zeros_like(table.values)), zeros)
    line = refused(["fit", "--config", kind, "--data.path", str(zeros), *KINDS[kind]], tmp_path, capsys)
    assert line == (f"{zeros}: every BRDF value is 0 (185 rows): there is nothing to fit; check that the values are "
                    "the sample's (not an empty export, a dark frame or the wrong columns)")


def test_a_lambertian_table_is_refused_by_abc_and_fitted_by_the_others(gold, tmp_path, capsys):
    """ABC fits a lobe: on a constant table it ran its lobe to a bound and failed with 31 lines of
    causes; the other models fit a Lambertian surface as it is."""
    values = read_table(gold).values
    spectrum = np.linspace(0.1, 0.3, values.shape[1])  # the same at every geometry
    flat = _changed(gold, "lambertian", values=np.broadcast_to(spectrum, values.shape).copy())
    line = refused(["fit", "--config", "abc", "--data.path", str(flat), *KINDS["abc"]], tmp_path, capsys)
    assert line.startswith(f"{flat}: every channel holds the same value at all 185 geometries (a Lambertian surface): "
                           "there is no specular lobe for the ABC model to fit"), line
    assert train(["fit", "--config", "spectral_mlp", "--data.path", str(flat), "--run_dir", str(tmp_path / "mlp"),
                  "--trainer.limit_train_batches", "2", "--trainer.enable_progress_bar", "false",
                  *KINDS["spectral_mlp"]]) == 0


def test_a_spectral_mlp_on_data_outside_its_range_is_refused(gold, tmp_path, capsys):
    """Fitted on 800-900 nm, it was exported as a model of 400-700 nm."""
    infrared = _changed(gold, "infrared", wavelengths=np.linspace(800.0, 900.0, len(read_table(gold).wavelengths)))
    line = refused(["fit", "--config", "spectral_mlp", "--data.path", str(infrared), *KINDS["spectral_mlp"]],
                   tmp_path, capsys)
    assert line == (f"{infrared}: holds 800-900 nm but model.wavelength_range_nm is 400-700 nm, the range the fitted "
                    "model declares; give --model.wavelength_range_nm '[800, 900]'")


def test_a_fit_from_a_fresh_clone_says_nothing_of_reference_data_it_never_had(gold, tmp_path):
    """Run where no ../shared lies beside it (a fresh clone): the nlb_latent config's comparison with
    Löw et al.'s ABC fits (../shared/data/abc-low2012) warned every user fitting their own table."""
    import subprocess
    import sys

    table = read_table(gold).to_rgb()
    zeros = tmp_path / "zeros.csv"
    write_table(dataclasses.replace(table, values=np.zeros_like(table.values)), zeros)
    clone = tmp_path / "clone"
    clone.mkdir()
    assert not (clone.parent / "shared").exists()
    run = subprocess.run([sys.executable, "-m", "neuralbrdf", "train", "fit", "--config", "nlb_latent", "--data.path",
                          str(zeros), *KINDS["nlb_latent"], "--run_dir", str(clone / "run")], cwd=clone,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 2 and run.stderr.splitlines() == [
        f"neuralbrdf train: error: {zeros}: every BRDF value is 0 (185 rows): there is nothing to fit; check that the "
        "values are the sample's (not an empty export, a dark frame or the wrong columns)"], run.stderr


def test_train_fit_refuses_a_bad_table_before_importing_lightning(tmp_path):
    """``train fit`` took 9-10 s to refuse a table other commands refuse in 2 s: the table is read
    before Lightning is imported, with the fit's own words (its option past a unit slip included)."""
    import subprocess
    import sys

    bad = tmp_path / "bad.csv"
    bad.write_text("theta_i,phi_i,theta_o,phi_o,R,G,B\n30,0,30,180,0.1,0.2,nan\n")
    radians = tmp_path / "radians.csv"
    radians.write_text("theta_i,phi_i,theta_o,phi_o,R,G,B\n" + "".join(
        f"{t:.3f},0,{t:.3f},3.1416,0.1,0.2,0.3\n" for t in (0.2, 0.4, 0.6, 0.8, 1.0, 1.2)))
    probe = ("import sys; from neuralbrdf.cli.main import main; status = main(sys.argv[1:]); "
             "print('lightning imported' if 'pytorch_lightning' in sys.modules else 'no lightning'); sys.exit(status)")
    for table, reason in ((bad, "line 2, column 'B': non-finite value 'nan'"), (radians, "--data.trust_units true")):
        run = subprocess.run([sys.executable, "-c", probe, "train", "fit", "--config", "spectral_mlp", "--data.path",
                              str(table), "--run_dir", str(tmp_path / "run")], capture_output=True, text=True,
                             timeout=300)
        assert run.returncode == 2 and run.stdout.strip() == "no lightning", (run.stdout, run.stderr)
        err = run.stderr.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"neuralbrdf train: error: {table}") and reason in err[0], err
        assert not (tmp_path / "run").exists()
