"""One export path (neuralbrdf.exporting): ``neuralbrdf export``, ``nb.export`` and
``FitResult.export`` write the same bytes and print the same checks with the same defaults (a
spectral model gets its RGB head), and one checkpoint exported twice gives the same file (the
slow test: adding the head to an exported file gives the file exported with it)."""

from pathlib import Path

import pytest
import yaml

import neuralbrdf as nb
from neuralbrdf.cli.export_command import main as export_cli
from neuralbrdf.kinds import load_model
from neuralbrdf.lod.config import load_lod_config
from neuralbrdf.onnx_contract import OUTPUT_FAST, OUTPUT_RGB


@pytest.fixture(scope="module")
def fit(tmp_path_factory):
    """A spectral ABC fit of the virtual gold (one start: about a second)."""
    folder = tmp_path_factory.mktemp("fit")
    return nb.fit("abc", "virtual:gold", run_dir=folder / "run", overrides={"model.n_starts": 1, "data.eval_plan": None})


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> str:
    """The shipped fast-path settings with a short distillation (seconds, not half a minute)."""
    raw = yaml.safe_load(load_lod_config().path.read_text())
    raw["fast_paths"]["distill"].update(n_pairs=4096, steps=100, batch=1024)
    raw["fast_paths"].update(error_strata=[6, 8], max_hemisphere_logcos_rmse=1.0)
    raw["fast_paths"]["image_check"].update(resolution=16, spp=2, max_delta_e2000_mean=100.0)
    path = tmp_path_factory.mktemp("lod") / "tiny.yaml"
    path.write_text(yaml.safe_dump(raw))
    return str(path)


def test_the_three_doors_write_the_same_bytes_and_print_the_same_checks(fit, tiny, tmp_path, capsys):
    doors = {
        "command": lambda out: export_cli(["--ckpt", str(fit.checkpoint), "--out", str(out), "--config", tiny]),
        "nb.export": lambda out: nb.export(fit.checkpoint, out, config=tiny),
        "FitResult.export": lambda out: fit.export(out, config=tiny),
    }
    files, printed = {}, {}
    for name, door in doors.items():
        out = tmp_path / name / "gold.onnx"  # one file name: the file records no path of its own
        door(out)
        files[name] = out.read_bytes()
        printed[name] = capsys.readouterr().out.replace(str(out), "OUT")
    # three exports of one checkpoint, the same bytes: seeded distillation, costs counted (not timed),
    # and nothing in the file names a temporary file
    assert files["nb.export"] == files["command"] and files["FitResult.export"] == files["command"]
    assert printed["nb.export"] == printed["command"] == printed["FitResult.export"]
    assert OUTPUT_RGB in load_model(tmp_path / "command" / "gold.onnx").fast_paths  # the default: an RGB head
    assert "onnxruntime vs PyTorch on 17408 probes" in printed["command"]
    assert "f_rgb (log-cos RMSE" in printed["command"] and "in Dr.Jit operations" in printed["command"]
    head = load_model(tmp_path / "command" / "gold.onnx").fast_paths[OUTPUT_RGB]
    assert 0 < head.relative_cost < 1 and "distilled from 4096 samples of the linear sRGB of f" in head.approximates


def test_the_doors_share_their_options(fit, tiny, tmp_path, capsys):
    assert export_cli(["--ckpt", str(fit.checkpoint), "--out", str(tmp_path / "a.onnx"), "--no-rgb-head", "--fast",
                       "--config", tiny]) == 0
    nb.export(fit.checkpoint, tmp_path / "b.onnx", rgb_head=False, fast=True, config=tiny)
    assert set(load_model(tmp_path / "b.onnx").fast_paths) == {OUTPUT_FAST}
    assert (tmp_path / "a.onnx").read_bytes() == (tmp_path / "b.onnx").read_bytes()
    nb.export(fit.checkpoint, tmp_path / "c.onnx", rgb_head=False)
    assert "fast paths" not in capsys.readouterr().out.splitlines()[-1]
    assert load_model(tmp_path / "c.onnx").fast_paths == {}


@pytest.mark.slow
def test_adding_fast_paths_to_a_model_file_goes_the_same_way(fit, tiny, tmp_path):
    nb.export(fit.checkpoint, tmp_path / "plain.onnx", rgb_head=False)
    assert export_cli(["--model", str(tmp_path / "plain.onnx"), "--out", str(tmp_path / "head.onnx"),
                       "--config", tiny]) == 0
    nb.export(fit.checkpoint, tmp_path / "direct.onnx", config=tiny)
    assert Path(tmp_path / "head.onnx").read_bytes() == Path(tmp_path / "direct.onnx").read_bytes()


def test_a_student_that_misses_its_bound_costs_its_fast_path_not_the_model(fit, tiny, tmp_path, capsys, monkeypatch):
    """A real measurement's spectral NLB was refused by a plain export because the f_fast it gets
    unasked missed its bound: an unasked fast path is left out with one line; one asked for still
    fails the export."""
    import dataclasses

    from neuralbrdf import kinds

    strict = tmp_path / "strict.yaml"
    raw = yaml.safe_load(Path(tiny).read_text())
    raw["fast_paths"]["max_hemisphere_logcos_rmse"] = 1e-12
    strict.write_text(yaml.safe_dump(raw))
    # the ABC kind as one that gets f_fast by default, as the spectral NLB does
    monkeypatch.setitem(kinds._discover(), "abc", dataclasses.replace(kinds.get("abc"), fast_by_default=True))
    from neuralbrdf.cli.main import main as cli

    out = tmp_path / "gold.onnx"
    assert cli(["export", "--ckpt", str(fit.checkpoint), "--out", str(out), "--config", str(strict)]) == 0
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith(f"warning: {out}: written without the optional fast path f_")
                                 and "above the bound 1e-12" in line for line in err), err
    assert load_model(out).fast_paths == {} and f"wrote {out} without fast paths" in captured.out
    plain = tmp_path / "plain.onnx"
    nb.export(fit.checkpoint, plain, fast=False, rgb_head=False)
    assert out.read_bytes() == plain.read_bytes()
    asked = tmp_path / "asked.onnx"
    assert export_cli(["--ckpt", str(fit.checkpoint), "--out", str(asked), "--fast", "--no-rgb-head",
                       "--config", str(strict)]) == 1
    assert "not written: the f_fast student" in capsys.readouterr().err and not asked.exists()
