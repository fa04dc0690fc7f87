"""Training commands killed part-way (SIGKILL, with real processes, at a point the test chooses):
the run directory holds the old run or the new one whole, and the next command in it repairs
what the killed one left (:mod:`neuralbrdf.lightning.run_dir`, docs/robustness.md, "Runs")."""

import json
import os
import shutil
import signal
from pathlib import Path

import pytest

from neuralbrdf.cli.main import main as cli
from neuralbrdf.lightning.run import main as train
from process_hooks import pause_arguments, start, wait_for_marker

pytestmark = [pytest.mark.filterwarnings("ignore:LightningCLI's args parameter is intended"),
              pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX signals")]

SHORT = ["--trainer.limit_train_batches", "2", "--trainer.enable_progress_bar", "false"]



@pytest.fixture(scope="module")
def table(tmp_path_factory):
    path = tmp_path_factory.mktemp("data") / "gold.csv"
    assert cli(["simulate", "--material", "gold", "--truth", "--out", str(path)]) == 0
    return path


def fit_args(table: Path, run: Path, epochs: int, *extra: str) -> list[str]:
    return ["fit", "--config", "spectral_mlp", "--data.path", str(table), "--run_dir", str(run),
            "--trainer.max_epochs", str(epochs), *SHORT, *extra]


#: Part of the name of everything a killed command leaves (neuralbrdf.atomic.TEMP_MARKER).
LEFTOVER = "neuralbrdf-tmp-"


def run_files(run: Path) -> dict:
    """The run's files and their bytes, leftovers of killed commands and the lock file aside."""
    return {p.relative_to(run): p.read_bytes() for p in sorted(run.rglob("*"))
            if p.is_file() and p.name != ".neuralbrdf.lock" and not any(LEFTOVER in part for part in p.parts)}


def leftovers(run: Path) -> list[str]:
    return sorted(str(p.relative_to(run)) for p in run.rglob("*") if LEFTOVER in p.name)


def held(run: Path) -> str:
    """What a run holds, as the refusal lists it."""
    entries = ("metrics.json", "metrics.csv", "config.yaml", "hparams.yaml", "checkpoints", "validate", "test")
    return ", ".join(f"{e}/" if (run / e).is_dir() else e for e in entries if (run / e).exists())


def kill_paused(args: list[str], tmp_path: Path, epoch: int, signal_number: int = signal.SIGKILL) -> tuple[int, int]:
    """Run ``neuralbrdf train ARGS`` in a child process and send it ``signal_number`` at the end of
    ``epoch``; its process id and exit status."""
    marker, log = tmp_path / f"paused-{epoch}", tmp_path / f"log-{epoch}.txt"
    process = start(["train", *args, *pause_arguments(marker, epoch)], log)
    try:
        pid = wait_for_marker(marker, process, log)
        process.send_signal(signal_number)
        status = process.wait(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    return pid, status


def test_a_killed_overwrite_leaves_the_old_run_and_the_next_command_clears_up(table, tmp_path, capsys):
    """Killed mid-fit, ``--overwrite`` left half a new run in the directory and the old one parked
    in a folder no later command removed."""
    run = tmp_path / "run"
    assert train(fit_args(table, run, 1)) == 0
    before = run_files(run)
    pid, _ = kill_paused(fit_args(table, run, 50, "--overwrite", "--seed_everything", "1"), tmp_path, epoch=1)
    assert run_files(run) == before  # the old run, untouched; the new one was written beside it
    capsys.readouterr()
    assert train(fit_args(table, run, 1)) == 2  # a plain fit: refused, and the leftover is gone
    err = capsys.readouterr().err
    assert f"removed the unfinished run of process {pid}" in err and "already holds a run (" in err, err
    assert leftovers(run) == [] and run_files(run) == before


@pytest.mark.slow
def test_a_terminated_overwrite_exits_143_and_leaves_the_old_run(table, tmp_path, capsys):
    """SIGTERM (``timeout``, a job scheduler): Lightning turned it into SystemExit, the command
    exited 0, and the old run, set aside, was deleted."""
    run = tmp_path / "run"
    assert train(fit_args(table, run, 1)) == 0
    before = run_files(run)
    _, status = kill_paused(fit_args(table, run, 50, "--overwrite"), tmp_path, epoch=1, signal_number=signal.SIGTERM)
    assert status == 128 + signal.SIGTERM
    log = (tmp_path / "log-1.txt").read_text()
    assert f"neuralbrdf train: error: interrupted by SIGTERM; {run} keeps what the run saved" in log, log
    assert run_files(run) == before and leftovers(run) == []


@pytest.mark.slow
def test_a_killed_plain_fit_says_it_did_not_finish_and_resumes(table, tmp_path, capsys):
    """A plain fit killed after its first checkpoints: the refusal said the folder held
    metrics.json, which it did not; ``--resume`` continues it."""
    run = tmp_path / "run"
    kill_paused(fit_args(table, run, 50), tmp_path, epoch=1)
    assert (run / "checkpoints" / "last.ckpt").is_file()
    assert train(fit_args(table, run, 1)) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line == (f"neuralbrdf train: error: {run}: already holds a run that did not finish ({held(run)}; its "
                    "metrics.json says it is still running, but no command runs in it: it was killed); pass --resume "
                    "to continue it from checkpoints/last.ckpt or --overwrite to replace it")
    assert train([*fit_args(table, run, 3), "--resume"]) == 0
    assert json.loads((run / "metrics.json").read_text())["status"] == "ok"


@pytest.mark.slow
def test_a_killed_resume_keeps_the_log_of_the_sessions_before_it(table, tmp_path):
    """``--resume`` held the earlier sessions' log in memory while Lightning started a new file:
    killed, it lost them."""
    run = tmp_path / "run"
    assert train(fit_args(table, run, 2)) == 0
    kill_paused([*fit_args(table, run, 50), "--resume"], tmp_path, epoch=3)
    assert train([*fit_args(table, run, 5), "--resume"]) == 0
    rows = (run / "metrics.csv").read_text().splitlines()
    epochs = sorted({int(row.split(",")[rows[0].split(",").index("epoch")]) for row in rows[1:]})
    assert epochs == [0, 1, 2, 3, 4] and leftovers(run) == []


def _entries(folder: Path, text: str) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for entry in ("config.yaml", "metrics.json", "checkpoints/best.ckpt"):
        (folder / entry).parent.mkdir(exist_ok=True)
        (folder / entry).write_text(f"{text} {entry}")


def _holds(run: Path, text: str) -> bool:
    return {str(k): v.decode() for k, v in run_files(run).items()} == {
        e: f"{text} {e}" for e in ("config.yaml", "metrics.json", "checkpoints/best.ckpt")}


@pytest.mark.parametrize("reached", ["new run whole", "old run half out", "old run out", "new run half in"])
def test_a_replacement_killed_while_swapping_is_completed(tmp_path, reached):
    """Every state :func:`~neuralbrdf.lightning.run_dir.swap_in` passes through ends with the new
    run whole and nothing else left."""
    from neuralbrdf.lightning import run_dir as runs

    run, dead = tmp_path / "run", 99999999
    _entries(run, "old")
    finished = runs.leftover(run, runs.FINISHED_RUN, dead)
    _entries(finished, "new")
    if reached == "old run half out":
        old = runs.leftover(run, runs.OLD_RUN, dead)
        old.mkdir()
        os.replace(run / "config.yaml", old / "config.yaml")
    elif reached in ("old run out", "new run half in"):
        discard = runs.leftover(run, runs.DISCARD, dead)
        _entries(discard, "old")
        for entry in ("config.yaml", "metrics.json", "checkpoints"):
            os.remove(run / entry) if (run / entry).is_file() else shutil.rmtree(run / entry)
        if reached == "new run half in":
            os.replace(finished / "checkpoints", run / "checkpoints")
    notes = runs.recover(run)
    assert _holds(run, "new") and leftovers(run) == []
    assert notes == [f"put in place the finished run of process {dead}, which ended while replacing the run"]


def test_a_run_left_half_replaced_by_an_older_version_is_put_back(tmp_path):
    """Older versions set the old run aside in ``neuralbrdf-tmp-PID-replaced-run`` and wrote the new one
    in its place; killed, they left both."""
    from neuralbrdf.lightning import run_dir as runs

    run = tmp_path / "run"
    _entries(run, "half new")
    (run / "metrics.csv").write_text("epoch\n0\n")
    _entries(runs.leftover(run, runs.REPLACED_RUN, 99999999), "old")
    assert runs.recover(run) == ["put back the run that process 99999999 was replacing when it ended (the "
                                 "half-written new run is removed)"]
    assert _holds(run, "old") and leftovers(run) == []


def test_the_temporaries_of_dead_processes_are_removed_and_live_ones_kept(tmp_path):
    from neuralbrdf.lightning import run_dir as runs

    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    dead = run / "checkpoints" / ".best.ckpt.neuralbrdf-tmp-99999999-x1.ckpt"
    live = run / "checkpoints" / f".last.ckpt.neuralbrdf-tmp-{os.getppid()}-x2.ckpt"
    for path in (dead, live):
        path.write_text("partial")
    runs.recover(run)
    assert not dead.exists() and live.exists()
