"""Stop a command at a point a test chooses, so that the test can kill it there (no sleep races).

:class:`PauseAtEpochEnd` is a Lightning callback a test adds to ``neuralbrdf train fit`` with
:func:`pause_arguments`; the training process writes a marker file holding its process id at the
end of the chosen epoch (after that epoch's checkpoints) and then sleeps until it is killed.
:func:`wait_for_marker` waits for that file.  The test's Python path must hold this folder
(:func:`hook_environment`).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytorch_lightning as pl

#: Longest wait for a paused process on a loaded machine, seconds.
MARKER_DEADLINE_S = 300.0


class PauseAtEpochEnd(pl.Callback):
    """At the end of training epoch ``epoch``: write ``marker`` (this process's id), then sleep
    until killed, or until a SIGTERM reaches Lightning (which then stops the fit its own way)."""

    def __init__(self, marker: str, epoch: int = 0) -> None:
        self.marker, self.epoch = marker, epoch

    def on_train_epoch_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        if trainer.current_epoch == self.epoch:
            Path(self.marker).write_text(str(os.getpid()))
            while not trainer.received_sigterm:
                time.sleep(0.05)


def pause_arguments(marker: Path, epoch: int) -> list[str]:
    """``train fit`` arguments that add :class:`PauseAtEpochEnd` to the config's callbacks."""
    hook = {"class_path": f"{__name__}.PauseAtEpochEnd", "init_args": {"marker": str(marker), "epoch": epoch}}
    return [f"--trainer.callbacks+={json.dumps(hook)}"]


def hook_environment() -> dict[str, str]:
    """The environment of a child process that can import this module."""
    here = str(Path(__file__).resolve().parent)
    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (here, os.environ.get("PYTHONPATH")) if p)}


def start(args: list[str], log: Path) -> subprocess.Popen:
    """``python -m neuralbrdf ARGS`` in a child process that can import this module, output in ``log``."""
    with open(log, "w") as handle:
        return subprocess.Popen([sys.executable, "-m", "neuralbrdf", *args], stdout=handle, stderr=subprocess.STDOUT,
                                env=hook_environment())


def wait_for_marker(marker: Path, process: subprocess.Popen, log: Path) -> int:
    """The process id in ``marker`` once it is written; fails if ``process`` ends first."""
    deadline = time.monotonic() + MARKER_DEADLINE_S
    while not (marker.is_file() and marker.read_text().strip()):
        if process.poll() is not None:
            raise AssertionError(f"the process ended (status {process.returncode}) before its pause:\n"
                                 f"{log.read_text()}")
        if time.monotonic() > deadline:
            process.kill()
            raise AssertionError(f"no pause within {MARKER_DEADLINE_S:.0f} s:\n{log.read_text()}")
        time.sleep(0.05)
    return int(marker.read_text())


def is_alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, ended but not reaped, does not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False
    return state not in ("Z", "X")


class FailAtEpoch(pl.Callback):
    """Ends the fit with an error at the start of epoch ``epoch``: a guard that turns a fit that
    should have been refused and would never end into a failing test, not a hanging one."""

    def __init__(self, epoch: int = 2) -> None:
        self.epoch = epoch

    def on_train_epoch_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        if trainer.current_epoch >= self.epoch:
            raise RuntimeError(f"the fit reached epoch {trainer.current_epoch}: it should have been refused")


#: ``overrides`` of ``nb.fit`` (and, as ``--KEY VALUE``, arguments of ``train fit``) adding :class:`FailAtEpoch`.
GUARD = {"trainer.callbacks+": json.dumps({"class_path": f"{__name__}.FailAtEpoch"})}
