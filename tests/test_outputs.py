"""Outputs never destroy anything (docs/robustness.md): :mod:`neuralbrdf.atomic`.

An output that is an input of the same command (same path, hard link, symbolic link), or an
existing directory, device or FIFO, is refused with one line and exit status 2; a symbolic link
that is not an input is written through; temporaries are recognisable and cleaned up; errors
name the target; several outputs are committed all-or-nothing.
"""

import os
import subprocess
import sys

import pytest

from neuralbrdf import atomic
from neuralbrdf.atomic import TEMP_MARKER, atomic_paths, atomic_write, command_inputs, note_input
from neuralbrdf.cli.main import main
from neuralbrdf.errors import EnvironmentFailure, OutputError


@pytest.fixture
def spectral_table(tmp_path):
    path = tmp_path / "x.csv"
    assert main(["simulate", "--material", "gold", "--plan", "DS4", "--truth", "--out", str(path)]) == 0
    return path


def _one_line_error(capsys, fragment):
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("neuralbrdf") and fragment in err, err
    return err


def test_out_equal_to_the_input_is_refused_and_the_input_kept(spectral_table, capsys):
    before = spectral_table.read_bytes()
    assert main(["to-rgb", str(spectral_table), "--out", str(spectral_table)]) == 2
    err = _one_line_error(capsys, "is also an input of this command")
    assert str(spectral_table) in err and TEMP_MARKER not in err
    assert spectral_table.read_bytes() == before
    assert sorted(p.name for p in spectral_table.parent.iterdir()) == ["x.csv"]


@pytest.mark.parametrize("link", ["hard", "symbolic", "relative spelling"])
def test_out_reaching_the_input_another_way_is_refused(spectral_table, capsys, link, monkeypatch):
    before = spectral_table.read_bytes()
    out = spectral_table.parent / "alias.csv"
    if link == "hard":
        os.link(spectral_table, out)
    elif link == "symbolic":
        out.symlink_to(spectral_table)
    else:
        monkeypatch.chdir(spectral_table.parent)
        out = "./sub/../x.csv"
        (spectral_table.parent / "sub").mkdir()
    assert main(["to-rgb", str(spectral_table), "--out", str(out)]) == 2
    _one_line_error(capsys, "is also an input of this command")
    assert spectral_table.read_bytes() == before


def test_calibrate_refuses_to_write_over_its_reference(tmp_path, capsys):
    for material in ("gold", "munsell_n9"):
        assert main(["simulate", "--material", material, "--plan", "DS4", "--out", str(tmp_path / f"{material}.csv")]) == 0
    reference = tmp_path / "munsell_n9.csv"
    before = reference.read_bytes()
    assert main(["calibrate", str(tmp_path / "gold.csv"), "--reference", str(reference), "--out", str(reference)]) == 2
    _one_line_error(capsys, "is also an input")
    assert reference.read_bytes() == before


@pytest.mark.parametrize("kind", ["fifo", "directory", "device"])
def test_non_regular_outputs_are_refused_and_left_as_they_are(tmp_path, capsys, kind):
    if kind == "fifo":
        out = tmp_path / "pipe.csv"
        os.mkfifo(out)
        expected = "a FIFO"
    elif kind == "directory":
        out = tmp_path / "folder.csv"
        out.mkdir()
        expected = "a directory"
    else:
        out, expected = "/dev/null", "a character device"
    assert main(["plan", "DS4", "--out", str(out)]) == 2
    _one_line_error(capsys, expected)
    if kind == "fifo":
        assert os.path.exists(out) and not os.path.isfile(out)
    if kind == "directory":
        assert out.is_dir()


def test_a_symbolic_link_output_is_written_through(tmp_path):
    real = tmp_path / "data" / "plan.csv"
    real.parent.mkdir()
    real.write_text("old\n")
    link = tmp_path / "plan.csv"
    link.symlink_to(real)
    assert main(["plan", "DS4", "--out", str(link)]) == 0
    assert link.is_symlink() and real.read_text().startswith("theta_i,theta_r")
    assert "symbolic link is written through" in subprocess.run(
        [sys.executable, "-m", "neuralbrdf", "plan", "--help"], capture_output=True, text=True, check=True
    ).stdout.replace("\n", " ").replace("  ", " ")


def test_write_errors_name_the_target_never_the_temporary(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    out = blocker / "plan.csv"  # its folder is a regular file
    assert main(["plan", "DS4", "--out", str(out)]) == 2
    err = _one_line_error(capsys, str(out))
    assert TEMP_MARKER not in err and ".tmp" not in err


def test_failing_writer_leaves_neither_output_nor_temporary_nor_new_folders(tmp_path):
    out = tmp_path / "new" / "deeper" / "x.csv"
    with pytest.raises(RuntimeError, match="writer broke"):
        with atomic_write(out) as handle:
            handle.write("partial")
            raise RuntimeError("writer broke")
    assert list(tmp_path.iterdir()) == []


def test_temporaries_of_dead_processes_are_removed_and_of_live_ones_kept(tmp_path):
    target = tmp_path / "x.csv"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(dead.stdout)
    stale = tmp_path / f".x.csv{TEMP_MARKER}{dead_pid}-abc.csv"
    live = tmp_path / f".x.csv{TEMP_MARKER}1-def.csv"  # pid 1 always runs
    other = tmp_path / f".y.csv{TEMP_MARKER}{dead_pid}-abc.csv"  # another target's
    for path in (stale, live, other):
        path.write_text("half")
    with atomic_write(target) as handle:
        handle.write("whole\n")
    assert target.read_text() == "whole\n"
    assert not stale.exists() and live.exists() and other.exists()


def test_several_outputs_appear_together_or_not_at_all(tmp_path, monkeypatch):
    png, exr = tmp_path / "a.png", tmp_path / "a.exr"
    png.write_text("old png")
    with pytest.raises(RuntimeError):
        with atomic_paths(png, exr) as (tmp_png, tmp_exr):
            tmp_png.write_text("new png")
            raise RuntimeError("the EXR writer failed")
    assert png.read_text() == "old png" and not exr.exists()

    # The second rename fails: the first target is rolled back to what it held.
    real_replace = os.replace
    calls = []

    def flaky_replace(src, dst):
        calls.append(dst)
        if str(dst) == str(exr) and len([c for c in calls if str(c) == str(exr)]) == 1:
            raise OSError(28, "No space left on device")
        return real_replace(src, dst)

    monkeypatch.setattr(atomic.os, "replace", flaky_replace)
    with pytest.raises(EnvironmentFailure, match="cannot write: no space left on device"):
        with atomic_paths(png, exr) as (tmp_png, tmp_exr):
            tmp_png.write_text("new png")
            tmp_exr.write_text("new exr")
    assert png.read_text() == "old png" and not exr.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]


def test_the_same_file_twice_as_output_is_refused(tmp_path):
    with pytest.raises(OutputError, match="given twice"):
        with atomic_paths(tmp_path / "a.png", tmp_path / "." / "a.png"):
            pass


def test_library_use_outside_a_command_may_rewrite_what_it_read(tmp_path):
    """Only commands (a :func:`command_inputs` scope) guard their inputs; a script may edit in place."""
    path = tmp_path / "x.csv"
    path.write_text("a\n")
    note_input(path)
    with atomic_write(path) as handle:
        handle.write("b\n")
    with command_inputs():
        note_input(path)
        with pytest.raises(OutputError, match="is also an input"):
            with atomic_write(path) as handle:
                handle.write("c\n")
    assert path.read_text() == "b\n"
