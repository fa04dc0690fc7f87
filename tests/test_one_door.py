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
