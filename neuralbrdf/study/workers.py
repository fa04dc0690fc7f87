"""The processes that run study cells, and the one function that runs a cell in one of them.

A :class:`CellWorker` is a persistent worker process (``python -m neuralbrdf.study.cell --serve``,
:func:`neuralbrdf.study.cell.serve`): it imports torch, Lightning, onnxruntime and Mitsuba once
and runs one cell folder per request.  :func:`run_in_worker` runs one cell in a worker, wherever
the worker is: in the study's own process for ``--jobs N`` (:mod:`neuralbrdf.study.runner`), in
a Dask worker for ``--cluster`` (:mod:`neuralbrdf.study.cluster`).

**A cell folder appears whole.**  A cell runs in an *attempt* folder of its own beside the cell
folders, ``cells/.KEY.neuralbrdf-tmp-PID-RANDOM`` (named as :mod:`neuralbrdf.atomic` names its
temporary files), which is renamed to ``cells/KEY`` when the cell has ended: with its
``result.json``, or, for a cell that ended without one, with its ``cell.json`` and ``log.txt`` as
the record of the crash (no ``result.json``: the next run runs it again).  Two attempts of one
cell — a cluster task run again after its worker was lost while the lost worker's cell process
still wrote — never write into one folder; the first to finish with a result is kept.  A stopped
attempt (:class:`CellStopped`) is removed, and the attempt folders a killed study or a lost worker
left are removed by the study at its start and end (:func:`remove_attempts`).
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import select
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from neuralbrdf.atomic import TEMP_MARKER, atomic_write
from neuralbrdf.study.cell import STUDY_PID_VARIABLE

#: Cells a worker process runs before it is replaced by a fresh one.
CELLS_PER_WORKER = 50
WORKER_COMMAND = (sys.executable, "-m", "neuralbrdf.study.cell", "--serve")
#: Seconds between two checks of ``should_stop`` while a cell runs (:meth:`CellWorker.run`).
STOP_POLL_S = 0.5


class CellStopped(Exception):
    """The cell was stopped before it ended (its study's task was cancelled); nothing was kept."""


class CellWorker:
    """One worker process (:func:`neuralbrdf.study.cell.serve`), started on first use and again
    after it died or ran :data:`CELLS_PER_WORKER` cells; ``keep_fds``: descriptors it inherits
    (the study folder's lock).  The process ends with the process that started it
    (:func:`~neuralbrdf.study.cell.die_with_study`)."""

    def __init__(self, command: tuple[str, ...] | None = None, keep_fds: tuple[int, ...] = ()) -> None:
        self.command = WORKER_COMMAND if command is None else command
        self.keep_fds = keep_fds
        self.process: subprocess.Popen | None = None
        self.cells = 0

    def _start(self) -> None:
        self.close()
        env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONWARNINGS": "ignore", STUDY_PID_VARIABLE: str(os.getpid())}
        self.process = subprocess.Popen(self.command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        stderr=subprocess.DEVNULL, env=env, text=True, bufsize=1,
                                        pass_fds=self.keep_fds)
        self.cells = 0

    def run(self, folder: Path, should_stop: Callable[[], bool] | None = None) -> bool:
        """Run the cell in ``folder``; ``False`` when the worker died doing it (it is restarted next
        time).  ``should_stop`` is asked every :data:`STOP_POLL_S` seconds while the cell runs: when
        it says yes, the worker is killed and :class:`CellStopped` raised."""
        if self.process is None or self.process.poll() is not None or self.cells >= CELLS_PER_WORKER:
            self._start()
        self.cells += 1
        try:
            self.process.stdin.write(f"{folder.resolve()}\n")
            self.process.stdin.flush()
            if should_stop is not None:
                while not select.select([self.process.stdout], [], [], STOP_POLL_S)[0]:
                    if should_stop():
                        self.process.kill()
                        self.close()
                        raise CellStopped(f"stopped: {folder.name}")
            answered = bool(self.process.stdout.readline())
        except (BrokenPipeError, OSError):
            answered = False
        if not answered:
            self.close()
        return answered

    def close(self) -> None:
        if self.process is not None:
            with contextlib.suppress(OSError):
                self.process.stdin.close()
            try:
                self.process.wait(timeout=60)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
            self.process.stdout.close()
            self.process = None


def crashed(spec: dict, message: str) -> dict:
    """The result of the cell ``spec`` describes when it ended without one (``cell_crashed``)."""
    return {**spec["cell"], "is_main": spec["is_main"], "failure": "cell_crashed", "message": message,
            "cost": {}, "error": {}}


def attempt_folder(cells_dir: Path, key: str) -> Path:
    """A new, empty attempt folder for the cell ``key`` (module docstring)."""
    folder = cells_dir / f".{key}{TEMP_MARKER}{os.getpid()}-{secrets.token_hex(4)}"
    folder.mkdir(parents=True)
    return folder


def remove_attempts(cells_dir: Path) -> None:
    """Remove the attempt folders in ``cells_dir``: those left by a killed study or a lost cluster worker."""
    for folder in cells_dir.glob(f".*{TEMP_MARKER}*"):
        shutil.rmtree(folder, ignore_errors=True)


def _publish(attempt: Path, folder: Path) -> dict | None:
    """Move ``attempt`` to ``folder``; the result already there when another attempt of the cell
    finished first with one (``attempt`` is then removed), else ``None``."""
    published = folder / "result.json"
    if published.is_file():
        shutil.rmtree(attempt, ignore_errors=True)
        with contextlib.suppress(OSError, ValueError):
            return json.loads(published.read_text(encoding="utf-8"))
        return None
    if folder.exists():  # a crashed attempt's record, or a folder left by a killed run
        shutil.rmtree(folder)
    try:
        os.rename(attempt, folder)
    except OSError:  # another attempt published between the check and the rename
        shutil.rmtree(attempt, ignore_errors=True)
    return None


def run_in_worker(spec: dict, cells_dir: Path, worker: CellWorker,
                  should_stop: Callable[[], bool] | None = None) -> dict:
    """Run the cell ``spec`` describes (``cell.json``: :func:`neuralbrdf.study.runner.cell_spec`) in
    ``worker`` and publish it as ``cells_dir/KEY`` (module docstring); its result, or a
    ``cell_crashed`` result naming its log when it ended without one.  ``should_stop``: as for
    :meth:`CellWorker.run` (the attempt is removed and :class:`CellStopped` raised)."""
    key = spec["key"]
    attempt = attempt_folder(cells_dir, key)
    with atomic_write(attempt / "cell.json", encoding="utf-8") as handle:
        json.dump(spec, handle, indent=1)
    try:
        survived = worker.run(attempt, should_stop)
    except CellStopped:
        shutil.rmtree(attempt, ignore_errors=True)
        raise
    result_path, log = attempt / "result.json", attempt / "log.txt"
    if result_path.is_file():
        result = json.loads(result_path.read_text(encoding="utf-8"))
    else:
        tail = (log.read_text(errors="replace").strip().splitlines() if log.is_file() else [])[-1:] or ["(empty log)"]
        what = "the cell ended without a result" if survived else "the cell's worker process died"
        result = crashed(spec, f"{what}: {tail[0][:300]} (log: cells/{key}/log.txt)")
    return _publish(attempt, cells_dir / key) or result
