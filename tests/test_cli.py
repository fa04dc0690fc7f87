"""The ``neuralbrdf`` command line end to end: outputs, help, exit codes, atomic writes."""

import re
import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from neuralbrdf.cli.main import main
from neuralbrdf.data.gcms import read_gcms
from neuralbrdf.data.table import read_table

ROOT = Path(__file__).resolve().parents[1]

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
NBRDF_DIR = SHARED_DATA / "merl-nbrdf"


def run(*args):
    return main([str(a) for a in args])


def test_console_script_help_explains_conventions():
    out = subprocess.run(
        [sys.executable, "-m", "neuralbrdf", "calibrate", "--help"], capture_output=True, text=True, check=True
    ).stdout
    assert "0.79" in out and "degrees" in out and "1/sr" in out


@pytest.mark.parametrize("name, count", [("DS1", 1001), ("DS4", 6), ("low", 230_400)])
def test_plan_writes_the_pairs(tmp_path, name, count):
    out = tmp_path / "plan.csv"
    assert run("plan", name, "--out", out) == 0
    with open(out) as handle:
        rows = list(csv.reader(handle))
    assert len(rows) == count + 1


def test_noiseless_simulation_calibrates_back_to_the_truth(tmp_path):
    """Instrument response and the Munsell factor cancel exactly (docs/measure.md#the-virtual-goniospectrophotometer)."""
    for material in ("gold", "munsell_n9"):
        assert run("simulate", "--material", material, "--plan", "DS2", "--out", tmp_path / f"{material}.csv") == 0
    assert run("simulate", "--material", "gold", "--plan", "DS2", "--truth", "--out", tmp_path / "truth.csv") == 0
    cal = tmp_path / "cal.csv"
    assert run("calibrate", tmp_path / "gold.csv", "--reference", tmp_path / "munsell_n9.csv", "--out", cal) == 0
    got, truth = read_table(cal), read_table(tmp_path / "truth.csv")
    np.testing.assert_allclose(got.wavelengths, truth.wavelengths)
    order_got = np.lexsort((got.theta_o, got.phi_o, got.theta_i))
    order_truth = np.lexsort((truth.theta_o, truth.phi_o, truth.theta_i))
    np.testing.assert_allclose(got.values[order_got], truth.values[order_truth], rtol=1e-6, atol=1e-12)


def test_noisy_simulation_is_seeded(tmp_path):
    for name, seed in (("a", 1), ("b", 1), ("c", 2)):
        run("simulate", "--material", "cyan", "--plan", "DS3", "--noise", "0.02", "--seed", seed, "--out", tmp_path / f"{name}.csv")
    a, b, c = (read_gcms(tmp_path / f"{n}.csv").beta for n in "abc")
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_to_rgb_and_plot(tmp_path):
    run("simulate", "--material", "gonio", "--plan", "DS2", "--truth", "--out", tmp_path / "truth.csv")
    assert run("to-rgb", tmp_path / "truth.csv", "--out", tmp_path / "rgb.csv") == 0
    rgb = read_table(tmp_path / "rgb.csv")
    assert not rgb.is_spectral and rgb.n_rows == 185
    assert run("plot", tmp_path / "rgb.csv", "--out", tmp_path / "p.png") == 0
    assert (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_plot_formats_legend_and_non_positive_values(tmp_path, capsys):
    """The legend names the channels and every incident angle (signed), values <= 0 are left out and
    counted rather than drawn as a floor, and the format follows the suffix or is refused."""
    table = "theta_i,phi_i,theta_o,phi_o,R,G,B\n" + "\n".join(
        f"30,0,{t},{180 if t > 0 else 0},{0.0 if t == 50 else 0.5},0.3,0.1" for t in (10, 20, 30, 40, 50)
    ) + "\n" + "\n".join(f"30,180,{t},0,0.4,0.3,0.2" for t in (10, 20, 30)) + "\n"
    path = _write(tmp_path / "t.csv", table)
    assert run("plot", path, "--theta-i", "30", "-30", "--out", tmp_path / "p.svg") == 0
    svg = (tmp_path / "p.svg").read_text()
    assert svg.startswith("<?xml")
    for text in ("R channel", "G channel", "B channel", "θi = +30°", "θi = -30°", "1 value(s) ≤ 0 not drawn"):
        assert text in svg, text
    assert run("plot", path, "--out", tmp_path / "p.pdf") == 0
    assert (tmp_path / "p.pdf").read_bytes()[:4] == b"%PDF"
    assert run("plot", path, "--out", tmp_path / "p.jpg") == 2
    assert "unsupported figure format '.jpg'" in capsys.readouterr().err and not (tmp_path / "p.jpg").exists()


def test_demo_runs_on_the_shipped_data(tmp_path):
    assert run("demo", "--out-dir", tmp_path, "--material", "gold") == 0
    for suffix in ("_spectral.csv", "_rgb.csv", ".png"):
        assert (tmp_path / f"gold_DS1{suffix}").stat().st_size > 0


@pytest.mark.skipif(not NBRDF_DIR.is_dir(), reason="../shared/data/merl-nbrdf is absent")
def test_sample_nbrdf(tmp_path):
    out = tmp_path / "brass.csv"
    assert run("sample-nbrdf", NBRDF_DIR / "brass.h5", "--plan", "DS3", "--out", out) == 0
    table = read_table(out)
    assert table.n_rows == 57 and np.all(table.values >= 0)


def _write(path, text):
    path.write_text(text)
    return path


GCMS_HEADER = "theta_i,theta_r," + ",".join(str(w) for w in range(390, 731, 10))


def _gcms(path, rows):
    """A GCMS raw file with the given rows (each: theta_i, theta_r, then one value repeated)."""
    lines = [GCMS_HEADER] + [f"{ti},{tr}," + ",".join([str(v)] * 35) for ti, tr, v in rows]
    return _write(path, "\n".join(lines) + "\n")


def _good_reference(d):
    return _gcms(d / "ref.csv", [(30, 30, 0.79), (30, 0, 0.79)])


def _wrong_h5_layout(d):
    import h5py

    with h5py.File(d / "net.h5", "w") as handle:
        handle["dense_1/kernel"] = np.zeros((6, 21))
    _write(d / "net.json", "{}")
    return d / "net.h5"


@pytest.mark.parametrize(
    "argv_builder, expected",
    [
        (lambda d: ["calibrate", d / "missing.csv", "--reference", d / "missing.csv"], "missing.csv"),
        (lambda d: ["to-rgb", _write(d / "empty.csv", "")], "empty.csv"),
        (lambda d: ["simulate", "--material", "unobtainium", "--plan", "DS1"], "unobtainium"),
        (lambda d: ["sample-nbrdf", _write(d / "x.h5", "not hdf5"), "--plan", "DS1"], "x.json"),
        (lambda d: ["to-rgb", _write(d / "t.csv", "theta_i,phi_i,theta_o,phi_o,R,G,B\n10,0,95,0,1,1,1\n")], "line 2"),
        (lambda d: ["to-rgb", _write(d / "t.csv", "theta_i,phi_i,theta_o,400,410\n10,0,5,1,1\n")], "phi_o"),
        (lambda d: ["to-rgb", _write(d / "t.csv", "theta_i,phi_i,theta_o,phi_o,400,410\n10,0,5,0,1,1\n10,0,5\n")], "line 3"),
        (lambda d: ["to-rgb", _write(d / "t.csv", "theta_i,phi_i,theta_o,phi_o,400,420,430\n10,0,5,0,1,1,1\n")], "regular"),
        (lambda d: ["calibrate", _gcms(d / "s.csv", [(30, 30, "nan")]), "--reference", _good_reference(d)], "line 2"),
        (lambda d: ["calibrate", _gcms(d / "s.csv", [(30, 30, 1)]), "--reference", _gcms(d / "r.csv", [(30, 30, -0.2)])], "r.csv"),
        (lambda d: ["calibrate", _gcms(d / "s.csv", [(95, 30, 1)]), "--reference", _good_reference(d)], "theta_i"),
        (lambda d: ["calibrate", _gcms(d / "s.csv", [(30, 10, 1)]), "--reference", _good_reference(d)], "s.csv"),
        (lambda d: ["calibrate", _write(d / "s.csv", "theta_i,theta_r,400,410\n30,30,1,1\n"), "--reference", _good_reference(d)], "390"),
        (lambda d: ["sample-nbrdf", _wrong_h5_layout(d), "--plan", "DS1"], "net."),
    ],
)
def test_bad_input_exits_2_with_one_line_and_no_output(tmp_path, capsys, argv_builder, expected):
    out = tmp_path / "out.csv"
    assert run(*argv_builder(tmp_path), "--out", out) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expected in err
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]


# --------------------------------------------------------------------------- one error form, no abbreviations


@pytest.mark.parametrize("argv, command", [
    (["to-rgb", "missing.csv", "--out", "x.csv"], "to-rgb"),
    (["train", "fit", "--config", "abc", "--data.path", "missing.csv"], "train"),
    (["train", "fitt", "--config", "abc"], "train"),
    (["export", "--ckpt", "missing.ckpt", "--out", "x.onnx"], "export"),
    (["render", "--model", "missing.onnx", "--out", "x.png"], "render"),
    (["study", "--out", "study"], "study"),
    (["to-rgb", "--no-such-option"], "to-rgb"),
])
def test_every_command_says_an_error_in_one_form(tmp_path, capsys, monkeypatch, argv, command):
    """Errors began 'error:' (train, export, render), 'Error:' (jsonargparse) or 'neuralbrdf to-rgb:
    error:' (the other commands); argparse's own usage errors use the last form, so all do."""
    monkeypatch.chdir(tmp_path)
    try:
        status = main(argv)
    except SystemExit as exit_:  # argparse's usage error
        status = exit_.code
    assert status == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if "rror" in line]
    assert len(lines) == 1 and lines[0].startswith(f"neuralbrdf {command}: error: "), lines
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, option", [
    (["plan", "DS1", "--ou", "{out}"], "--ou"),
    (["to-rgb", "{table}", "--ou", "{out}"], "--ou"),
    (["export", "--ck", "x.ckpt", "--out", "{out}"], "--ck"),
    (["render", "--mod", "x.onnx", "--out", "{out}"], "--mod"),
    (["train", "fit", "--config", "abc", "--trainer.max_epoch", "1", "--run_dir", "{out}"], "--trainer.max_epoch"),
])
def test_an_abbreviated_option_is_refused(tmp_path, capsys, argv, option):
    """``--trainer.max_epoch`` was taken for ``--trainer.max_epochs``: an abbreviation that changes
    meaning when an option is added; only whole option names are accepted."""
    table = tmp_path / "t.csv"
    assert main(["simulate", "--material", "gold", "--plan", "DS4", "--truth", "--out", str(table)]) == 0
    capsys.readouterr()
    out = tmp_path / "out"
    try:
        status = main([a.format(out=out, table=table) for a in argv])
    except SystemExit as exit_:
        status = exit_.code
    assert status == 2 and not out.exists()
    err = capsys.readouterr().err
    assert "error: " in err and (option in err or "required" in err), err


def test_the_exit_statuses_are_documented_as_the_code_gives_them():
    from neuralbrdf import errors

    text = (Path(__file__).resolve().parents[1] / "docs" / "robustness.md").read_text()
    section = text.split("## Exit status", 1)[1].split("\n## ", 1)[0]
    for status in (errors.EXIT_OK, errors.EXIT_FAILED, errors.EXIT_BAD_INPUT, errors.EXIT_ENVIRONMENT):
        assert f"| {status} |" in section, status
    assert errors.exit_status(errors.InputError("x")) == 2
    assert errors.exit_status(errors.EnvironmentFailure("x")) == 3
    assert errors.exit_status(errors.FitFailed("x")) == 1


SCRIPTS_WITH_OPTIONS = sorted((ROOT / "benchmarks").glob("*.py")) + [ROOT / "docs" / "make_results.py",
                                                                     *sorted((ROOT / "examples").glob("*.py"))]


@pytest.mark.parametrize("script", SCRIPTS_WITH_OPTIONS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_script_parser_refuses_abbreviations(script):
    """The benchmark, docs and example scripts took ``--ou`` for ``--out`` like the commands once did:
    every argument parser they build is made with ``allow_abbrev=False``."""
    source = script.read_text(encoding="utf-8")
    calls = re.findall(r"argparse\.ArgumentParser\((.*?)\)\n", source)
    assert all("allow_abbrev=False" in call for call in calls), (script, calls)


def test_a_script_refuses_an_abbreviated_option():
    """docs/make_results.py --chec: refused by argparse (exit 2), not taken for --check."""
    result = subprocess.run([sys.executable, str(ROOT / "docs" / "make_results.py"), "--chec"],
                            capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert result.returncode == 2 and "unrecognized arguments: --chec" in result.stderr, result.stderr
