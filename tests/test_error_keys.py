"""Errors name what the user wrote: a column of a table, a key of a configuration or metadata
entry, an option of a command (``InputError(key=...)``); and a refused hyper-parameter is bad
input (exit 2, no run folder), as docs/fit.md and docs/robustness.md say."""

import pytest

from neuralbrdf.cli.export_command import main as export_cli
from neuralbrdf.errors import InputError
from neuralbrdf.lightning.run import main as train


def test_keys_options_and_columns_are_named_as_what_they_are():
    assert str(InputError("bad", path="c.yaml", key="model.n_starts")) == "c.yaml, key 'model.n_starts': bad"
    assert str(InputError("bad", key="--material")) == "option '--material': bad"
    assert str(InputError("bad", path="t.csv", line=3, column="theta_i")) == "t.csv, line 3, column 'theta_i': bad"


def test_a_bad_config_value_names_its_key_and_is_refused_with_exit_2(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert train(["fit", "--config", "abc", "--model.n_starts", "0", "--run_dir", "run"]) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert "key 'model.n_starts'" in error and "column" not in error, error
    assert not (tmp_path / "run").exists()


def test_metadata_keys_and_options_say_key_and_option(tmp_path, capsys):
    from neuralbrdf.onnx_contract import metadata_float

    with pytest.raises(InputError, match=r"^m.onnx, key 'neuralbrdf.x': metadata value 'y' is not a number"):
        metadata_float({"neuralbrdf.x": "y"}, "neuralbrdf.x", "m.onnx")
    model = tmp_path / "m.onnx"
    model.write_bytes(b"")
    assert export_cli(["--model", str(model), "--material", "x", "--out", str(tmp_path / "o.onnx")]) == 2
    assert "option '--material'" in capsys.readouterr().err
