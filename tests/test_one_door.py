"""The API is the one door: ``nb.fit`` hands its run the configuration as data (config files and a
mapping of typed overrides, no command-line text) and gets its result back as an object; the
``neuralbrdf`` commands parse, call :mod:`neuralbrdf.api` and print."""

import ast
import json
from pathlib import Path

import pytest

import neuralbrdf as nb
from neuralbrdf.lightning import fit_call

pytestmark = pytest.mark.filterwarnings("ignore:LightningCLI's args parameter is intended")
API = Path(nb.__file__).parent / "api"
QUICK_ABC = {"model.n_starts": 1, "data.eval_plan": None}


def test_the_fit_builds_no_command_line():
    source = (API / "fitting.py").read_text(encoding="utf-8")
    strings = [node.value for node in ast.walk(ast.parse(source)) if isinstance(node, ast.Constant)
               and isinstance(node.value, str)]
    assert not [s for s in strings if s.startswith("--")], "nb.fit builds command-line arguments"
    assert "json.dumps" not in source and "lightning.run import" not in source


def test_the_run_gets_the_configuration_as_data_and_hands_back_its_result(tmp_path, monkeypatch):
    handed = []
    parse = fit_call._DataFitCLI.parse_arguments

    def spy(self, parser, args):
        handed.append((list(self._files), args))
        return parse(self, parser, args)

    monkeypatch.setattr(fit_call._DataFitCLI, "parse_arguments", spy)
    result = nb.fit("abc", "virtual:gold", run_dir=tmp_path / "run", overrides=QUICK_ABC)
    [(files, args)] = handed
    assert [f.name for f in files] == ["abc.yaml"]
    assert args == {"data.virtual": "gold", **QUICK_ABC, "run_dir": str(tmp_path / "run")}  # typed: 1, None
    on_disk = json.loads((tmp_path / "run" / "metrics.json").read_text(encoding="utf-8"))
    assert result.metrics == on_disk and result.metrics["status"] == "ok"  # what the run wrote, kept as written
    assert result.checkpoint == tmp_path / "run" / "checkpoints" / "best.ckpt"


def test_a_non_finite_value_inside_an_override_stays_a_number(tmp_path):
    bounds = {"A": [1e-8, 1e6], "sharpness": [1e-3, 1e9], "C": [1e-3, float("inf")], "eta": [1.001, 100.0]}
    nb.fit("abc", "virtual:gold", run_dir=tmp_path / "run", overrides={**QUICK_ABC, "model.bounds": bounds})
    config = (tmp_path / "run" / "config.yaml").read_text(encoding="utf-8")
    assert "- .inf" in config and "Infinity" not in config  # through text it became the string 'Infinity'


def test_an_override_of_the_wrong_type_is_named_like_its_flag(tmp_path):
    with pytest.raises(nb.InputError, match=r"^--trainer.max_epochs: expected int, got 'many'$"):
        nb.fit("abc", "virtual:gold", run_dir=tmp_path / "run", overrides={"trainer.max_epochs": "many"})
    assert not (tmp_path / "run").exists()


# --------------------------------------------------------------------------- the commands


#: What a command may take from a module other than :mod:`neuralbrdf.api`: its options' defaults
#: and help, how it prints, and ``train``, the config-driven entry that stays a command line.
PRINTING_AND_HELP = {
    "neuralbrdf.data.plans": {"plan_label", "PLAN_HELP", "PLAN_NAMES"},
    "neuralbrdf.data.units": {"overridden_by"},  # names --trust-units as the way past a unit slip
    "neuralbrdf.evaluation.evaluate": {"format_table"},
    "neuralbrdf.render": {"DEFAULT_VARIANT"},
    "neuralbrdf.render.preview": {"BACKENDS", "DEFAULT_MAX_DEPTH", "MEMORY_FRACTION", "PASS_LANES_SYMBOLIC",
                                  "PASS_LANES_WAVEFRONT", "REFERENCE_BSDFS"},
    "neuralbrdf.render.spectral_quadrature": {"DEFAULT_RMS_TOLERANCE"},
    "neuralbrdf.lightning.run": {"main"},
    "neuralbrdf.lightning.train_precheck": {"refused_table"},  # train's table, refused before Lightning loads
    "neuralbrdf": {"api", "kinds"},  # kinds: the export command's help lists them
}
#: Modules every command uses as they are: errors, warnings, the inputs-are-not-outputs guard.
SHARED = ("neuralbrdf.api", "neuralbrdf.errors", "neuralbrdf.console", "neuralbrdf.atomic", "neuralbrdf.cli")


def test_the_commands_reach_the_library_only_through_the_api():
    taken = []
    for path in sorted((API.parent / "cli").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                taken += [(path.name, alias.name, "") for alias in node.names if alias.name.startswith("neuralbrdf")]
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("neuralbrdf") and \
                    not node.module.startswith(SHARED):
                taken += [(path.name, node.module, alias.name) for alias in node.names
                          if alias.name not in PRINTING_AND_HELP.get(node.module, ())]
    assert not taken, f"commands that work past neuralbrdf.api: {taken}"


@pytest.fixture(scope="module")
def cli():
    from neuralbrdf.cli.main import main

    return main


def _same_files(cli_file: Path, api_file: Path) -> None:
    assert cli_file.read_bytes() == api_file.read_bytes()


def test_simulate_calibrate_to_rgb_and_sample_are_their_api_calls(cli, tmp_path, capsys):
    c, a = tmp_path / "cli", tmp_path / "api"
    c.mkdir(), a.mkdir()
    assert cli(["simulate", "--material", "cyan", "--plan", "DS3", "--noise", "0.01", "--seed", "3",
                "--out", str(c / "cyan.csv")]) == 0
    nb.simulate("cyan", a / "cyan.csv", plan="DS3", noise=0.01, seed=3)
    assert cli(["simulate", "--material", "munsell_n9", "--plan", "DS3", "--out", str(c / "white.csv")]) == 0
    nb.simulate("munsell_n9", a / "white.csv", plan="DS3")
    assert cli(["simulate", "--material", "gold", "--plan", "DS4", "--truth", "--out", str(c / "gold.csv")]) == 0
    nb.simulate("gold", a / "gold.csv", plan="DS4", truth=True)
    assert cli(["calibrate", str(c / "cyan.csv"), "--reference", str(c / "white.csv"),
                "--out", str(c / "calibrated.csv")]) == 0
    nb.calibrate(a / "cyan.csv", a / "white.csv", a / "calibrated.csv")
    assert cli(["to-rgb", str(c / "calibrated.csv"), "--out", str(c / "rgb.csv")]) == 0
    nb.to_rgb(a / "calibrated.csv", a / "rgb.csv")
    assert cli(["sample", "virtual:gold", "--plan", "DS2", "--out", str(c / "sampled.csv")]) == 0
    nb.sample("virtual:gold", "DS2", a / "sampled.csv")
    assert cli(["plan", "DS4", "--out", str(c / "ds4.csv")]) == 0
    nb.write_plan("DS4", a / "ds4.csv")
    for name in ("cyan.csv", "white.csv", "gold.csv", "calibrated.csv", "rgb.csv", "sampled.csv", "ds4.csv"):
        _same_files(c / name, a / name)
    out = capsys.readouterr().out
    assert "GCMS raw measurement of cyan on DS3 (57 pairs)" in out and "ground truth of gold on DS4: 6 rows" in out


def test_an_api_argument_in_error_is_named_as_the_commands_option(cli, tmp_path, capsys):
    assert cli(["sample", "virtual:gold", "--plan", "DS9", "--out", str(tmp_path / "x.csv")]) == 2
    assert "option '--plan'" in capsys.readouterr().err
    with pytest.raises(nb.InputError, match="key 'plan'"):
        nb.sample("virtual:gold", "DS9")
    assert cli(["demo", "--material", "silver", "--out-dir", str(tmp_path)]) == 2
    assert "option '--material': unknown stand-in 'silver'" in capsys.readouterr().err


def test_export_truth_is_the_api_call_and_prints_its_log(cli, tmp_path, capsys):
    assert cli(["export-truth", "virtual:gonio", "--out", str(tmp_path / "cli.onnx")]) == 0
    printed = capsys.readouterr().out
    lines = []
    nb.truth("virtual:gonio", tmp_path / "api.onnx", log=lines.append)
    _same_files(tmp_path / "cli.onnx", tmp_path / "api.onnx")
    assert printed == "".join(f"{line}\n" for line in lines).replace(str(tmp_path / "api.onnx"),
                                                                    str(tmp_path / "cli.onnx"))
