"""What the command line shows a log: warnings as one clean line, progress as plain lines, one
default render variant, and a demo that refuses to replace its earlier outputs silently."""

import warnings

import pytest

from neuralbrdf import console
from neuralbrdf.cli.main import build_parser
from neuralbrdf.cli.main import main as neuralbrdf
from neuralbrdf.console import LineProgress, clean_warnings, progress


def test_a_warning_is_one_line_without_source_or_install_path(capsys):
    shipped = console._INSTALL_ROOT + "neuralbrdf/data/default/cyan_DS1.csv"
    with clean_warnings():
        for _ in range(2):
            warnings.warn(f"{shipped}: clipped 3 negative values\n  to 0", stacklevel=1)
        warnings.warn("another", DeprecationWarning)
    err = capsys.readouterr().err
    assert err.splitlines() == ["warning: neuralbrdf/data/default/cyan_DS1.csv: clipped 3 negative values to 0",
                                "warning: another"]


def test_a_recorder_around_still_gets_every_warning(capsys):
    with pytest.warns(UserWarning, match="twice") as record, clean_warnings():
        warnings.warn("twice")
        warnings.warn("twice")
    assert len(record) == 2 and capsys.readouterr().err == "warning: twice\n"


def test_the_demo_warns_about_gamut_clipping_in_one_clean_line(tmp_path, capsys):
    assert neuralbrdf(["demo", "--out-dir", str(tmp_path), "--material", "cyan"]) == 0
    err = capsys.readouterr().err
    warned = [line for line in err.splitlines() if line.startswith("warning:")]
    assert warned == [line for line in err.splitlines() if "clipped" in line]  # each once, nothing else quoted
    assert len(warned) == 1 and warned[0].startswith("warning: neuralbrdf/data/default/cyan_DS1.csv: clipped")
    assert "UserWarning" not in err and ".py:" not in err and "\r" not in err


def test_a_rerun_of_the_demo_stops_before_any_work_unless_told_to_overwrite(tmp_path, capsys):
    assert neuralbrdf(["demo", "--out-dir", str(tmp_path), "--material", "gold"]) == 0
    written = {path: path.stat().st_mtime_ns for path in tmp_path.iterdir()}
    capsys.readouterr()
    assert neuralbrdf(["demo", "--out-dir", str(tmp_path), "--material", "gold"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "already holds the demo's outputs (gold_DS1_spectral.csv" in err
    assert "--overwrite" in err
    assert {path: path.stat().st_mtime_ns for path in tmp_path.iterdir()} == written
    assert neuralbrdf(["demo", "--out-dir", str(tmp_path), "--material", "gold", "--overwrite"]) == 0
    assert neuralbrdf(["demo", "--out-dir", str(tmp_path), "--material", "silver"]) == 2
    assert "unknown stand-in 'silver'" in capsys.readouterr().err


def test_off_a_terminal_progress_is_a_few_plain_lines(capsys, monkeypatch):
    monkeypatch.setattr(console, "on_terminal", lambda: False)
    monkeypatch.setattr(console, "LINE_INTERVAL_S", 0.0)
    bar = progress(range(3), desc="demo", unit="material")
    assert isinstance(bar, LineProgress) and list(bar) == [0, 1, 2]
    with progress(total=8, desc="render", unit="spp") as manual:
        manual.set_postfix_str("gold")
        manual.update(8)
    lines = capsys.readouterr().err.splitlines()
    assert [line.split(" (")[0] for line in lines] == ["demo: 1/3 material", "demo: 2/3 material", "demo: 3/3 material",
                                                       "render: 8/8 spp"]
    assert lines[-1].endswith("s) gold")
    monkeypatch.setattr(console, "LINE_INTERVAL_S", 3600.0)
    assert list(progress(range(3), desc="quiet")) == [0, 1, 2] and capsys.readouterr().err == ""


def test_render_and_evaluate_share_the_spectral_default_variant():
    from neuralbrdf.cli import render_command
    from neuralbrdf.evaluation.evaluate import RenderSettings, measurement_variant
    from neuralbrdf.render import DEFAULT_VARIANT

    render = render_command.build_parser().parse_args(["--model", "m.onnx", "--out", "x.png"])
    evaluate = build_parser().parse_args(["evaluate", "m.onnx", "--truth", "t.onnx", "--out-dir", "d"])
    assert evaluate.variant is None  # the truth's kind decides: a measurement renders in the variant of its kind
    assert render.variant == measurement_variant("t.onnx", evaluate.variant) == RenderSettings().variant \
        == DEFAULT_VARIANT == "llvm_ad_spectral"
