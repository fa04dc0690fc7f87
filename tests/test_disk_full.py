"""A disk that fills up: every command ends with one line naming the file it could not write and
"no space left on device", exit status 3 (the machine's failure, not the user's: docs/robustness.md,
"Exit status"), and leaves no partial output.

The disk is a small tmpfs mounted for the test where this machine allows it (root with mount
rights; skipped otherwise), else ENOSPC is injected at the write call.
"""

import errno
import os
import shutil
import subprocess
from pathlib import Path

import pytest
import torch

from neuralbrdf import atomic, checkpoints
from neuralbrdf.cli.main import main as cli
from neuralbrdf.errors import EXIT_ENVIRONMENT
from neuralbrdf.lightning.run import main as train

pytestmark = pytest.mark.filterwarnings("ignore:LightningCLI's args parameter is intended")

NO_SPACE = "cannot write: no space left on device"
QUICK_FIT = ["--trainer.max_epochs", "2", "--trainer.limit_train_batches", "2",
             "--trainer.enable_progress_bar", "false"]



def mount_disk(folder: Path, size_kib: int) -> None:
    """A tmpfs of ``size_kib`` KiB at ``folder``; the test is skipped where none can be mounted."""
    folder.mkdir(parents=True)
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a small tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kib}k", "tmpfs", str(folder)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"this machine does not allow mounting a tmpfs: {done.stderr.strip()}")


def fill(folder: Path, leave_bytes: int = 0) -> None:
    """Fill the file system of ``folder`` until at most ``leave_bytes`` are free."""
    def free() -> int:
        info = os.statvfs(folder)
        return info.f_bfree * info.f_frsize

    with open(folder / "filler", "ab", buffering=0) as handle:
        try:
            while free() > leave_bytes:
                handle.write(b"\0" * min(free() - leave_bytes, 64 * 1024))
        except OSError as error:
            assert error.errno == errno.ENOSPC and leave_bytes == 0


@pytest.fixture
def disk(tmp_path):
    folder = tmp_path / "disk"
    mount_disk(folder, 1024)
    yield folder
    if subprocess.run(["umount", str(folder)], capture_output=True).returncode != 0:
        subprocess.run(["umount", "-l", str(folder)], capture_output=True)  # a file still open: detach it


def one_error_line(capsys, prog: str) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith(f"{prog}: error: ")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# --------------------------------------------------------------------------- the checkpoint


def test_a_disk_that_fills_while_a_checkpoint_is_written_is_one_line(disk, tmp_path, capsys):
    """torch.save reported it as ``RuntimeError: basic_ios::clear: iostream error``, with a traceback,
    and metrics.json recorded the same."""
    run = disk / "run"
    fill(disk, leave_bytes=24 * 1024)  # config, hparams, logs fit; a checkpoint (~19 KB) does not
    assert train(["fit", "--config", "spectral_mlp", "--run_dir", str(run), *QUICK_FIT]) == EXIT_ENVIRONMENT
    line = one_error_line(capsys, "neuralbrdf train")
    assert line.startswith(f"neuralbrdf train: error: {run}") and line.endswith(NO_SPACE), line
    assert not list(run.rglob("*.ckpt")) and not list(run.rglob("*neuralbrdf-tmp*"))


@pytest.mark.parametrize("writer_says", ["OSError", "native"])
def test_a_checkpoint_write_refused_for_space_is_one_line_naming_it(tmp_path, capsys, monkeypatch, writer_says):
    """Without a small disk: ENOSPC at the checkpoint's write call, as Python reports it or as a
    native writer does (torch.save to a path) while the disk is full."""
    def full(checkpoint, handle):
        handle.write(b"PK\x03\x04 partial")
        if writer_says == "OSError":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        raise RuntimeError("basic_ios::clear: iostream error")

    monkeypatch.setattr(checkpoints.torch, "save", full)
    monkeypatch.setattr(atomic, "_free_bytes", lambda folder: 0 if writer_says == "native" else 10 ** 12)
    run = tmp_path / "run"
    assert train(["fit", "--config", "spectral_mlp", "--run_dir", str(run), *QUICK_FIT]) == EXIT_ENVIRONMENT
    line = one_error_line(capsys, "neuralbrdf train")
    assert line == f"neuralbrdf train: error: {run / 'checkpoints' / 'best.ckpt'}: {NO_SPACE}", line
    metrics = (run / "metrics.json").read_text()
    assert '"status": "environment"' in metrics and NO_SPACE in metrics  # the machine's doing, not the fit's
    assert not list(run.rglob("*.ckpt")) and not list(run.rglob("*neuralbrdf-tmp*"))


def test_metrics_json_refused_for_space_is_one_line_naming_it(tmp_path, capsys, monkeypatch):
    """The last write of a fit: ENOSPC when metrics.json is put in place."""
    commit = atomic._commit

    def no_space_for_metrics(moves):
        if any(real.name == "metrics.json" for _, real in moves) and '"ok"' in moves[0][0].read_text():
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        commit(moves)

    monkeypatch.setattr(atomic, "_commit", no_space_for_metrics)
    run = tmp_path / "run"
    assert train(["fit", "--config", "spectral_mlp", "--run_dir", str(run), *QUICK_FIT]) == EXIT_ENVIRONMENT
    assert one_error_line(capsys, "neuralbrdf train") == f"neuralbrdf train: error: {run / 'metrics.json'}: {NO_SPACE}"


# --------------------------------------------------------------------------- every other output


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A spectral table, the gold truth, a small RGB model and an ABC checkpoint, on an ordinary disk."""
    from onnx_fixtures import write_lambert

    folder = tmp_path_factory.mktemp("inputs")
    write_lambert(folder / "lambert.onnx")
    assert cli(["simulate", "--material", "gold", "--plan", "DS2", "--truth", "--out", str(folder / "t.csv")]) == 0
    assert cli(["export-truth", "virtual:gold", "--out", str(folder / "gold.onnx")]) == 0
    for material in ("gold", "munsell_n9"):  # a raw measurement and its white reference, to calibrate
        assert cli(["simulate", "--material", material, "--plan", "DS2", "--out", str(folder / f"{material}.csv")]) == 0
    threads = torch.get_num_threads()
    assert train(["fit", "--config", "abc", "--data.path", str(folder / "t.csv"), "--run_dir", str(folder / "abc"),
                  "--model.n_starts", "1", "--data.eval_plan", "null", "--trainer.enable_progress_bar", "false"]) == 0
    torch.set_num_threads(threads)
    return folder


COMMANDS = {
    "plan": (["plan", "DS1", "--out", "{disk}/plan.csv"], "plan.csv"),
    "simulate": (["simulate", "--material", "gold", "--out", "{disk}/raw.csv"], "raw.csv"),
    "to-rgb": (["to-rgb", "{inputs}/t.csv", "--out", "{disk}/rgb.csv"], "rgb.csv"),
    "plot": (["plot", "{inputs}/t.csv", "--out", "{disk}/plot.png"], "plot.png"),
    "export-truth": (["export-truth", "virtual:gold", "--out", "{disk}/truth.onnx"], "truth.onnx"),
    "sample": (["sample", "virtual:gold", "--plan", "DS2", "--out", "{disk}/sampled.csv"], "sampled.csv"),
    "calibrate": (["calibrate", "{inputs}/gold.csv", "--reference", "{inputs}/munsell_n9.csv", "--out",
                   "{disk}/calibrated.csv"], "calibrated.csv"),
    "evaluate": (["evaluate", "{inputs}/lambert.onnx", "--truth", "{inputs}/lambert.onnx", "--out-dir", "{disk}/eval",
                  "--no-render"], "eval/evaluation.json"),
    "export": (["export", "--ckpt", "{inputs}/abc/checkpoints/best.ckpt", "--out", "{disk}/abc.onnx", "--no-rgb-head"],
               "abc.onnx"),
    "render": (["render", "--model", "{inputs}/gold.onnx", "--out", "{disk}/gold.png", "--spp", "1", "--resolution",
                "16", "--backend", "onnxruntime", "--quiet"], "gold.png"),
}


@pytest.mark.parametrize("command", COMMANDS)
def test_every_output_on_a_full_disk_is_one_line_naming_it(inputs, disk, capsys, command):
    fill(disk)
    args, written = COMMANDS[command]
    before = sorted(p.name for p in disk.iterdir())
    assert cli([arg.format(disk=disk, inputs=inputs) for arg in args]) == EXIT_ENVIRONMENT
    line = one_error_line(capsys, f"neuralbrdf {command}")
    assert line == f"neuralbrdf {command}: error: {disk / written}: {NO_SPACE}", line
    assert sorted(p.name for p in disk.iterdir()) == before  # nothing half-written, no folder left


def test_a_study_on_a_full_disk_is_one_line_naming_the_file(tmp_path, disk, capsys, monkeypatch):
    """The study's own writes (a new cell's cell.json here; its truths, results and report go the
    same way) on a disk that filled since its last run."""
    import sys

    from test_study_robustness import ABC, FAKE_WORKER, profile

    from neuralbrdf.study import workers

    monkeypatch.setattr(workers, "WORKER_COMMAND", (sys.executable, "-c", FAKE_WORKER))
    path = profile(tmp_path, variants=ABC)
    out = disk / "study"
    assert cli(["study", "--profile", str(path), "--out", str(out), "--no-progress"]) == 0
    path.write_text(path.read_text().replace("seeds: [0, 1]", "seeds: [0, 1, 2]"))
    fill(disk)
    capsys.readouterr()
    assert cli(["study", "--profile", str(path), "--out", str(out), "--no-progress"]) == EXIT_ENVIRONMENT
    line = one_error_line(capsys, "neuralbrdf study")
    assert line.startswith(f"neuralbrdf study: error: {out}/") and line.endswith(NO_SPACE), line
