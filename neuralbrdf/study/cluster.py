"""``neuralbrdf study --cluster tcp://HOST:PORT``: the study's cells as tasks on a Dask cluster
(docs/study.md, "On a cluster").  Needs the ``cluster`` extra (``pip install 'neuralbrdf[cluster]'``).

The submitting process does all that a study on one machine does — it loads the profile, holds
the study folder's lock from start to end, exports the truths, reuses finished cells, and writes
``study.json`` and the report — and hands each cell that must run to the scheduler as one task
(:func:`run_task`), in the order a local study runs them.  A task runs its cell with
:func:`neuralbrdf.study.workers.run_in_worker`, as a local study does, in a cell worker process
that its Dask worker keeps between tasks (one per thread: ``dask worker --nthreads N`` runs N
cells at once), so the same cell gives the same result and the same folder wherever it ran.

**What every worker must see.**  The same neuralbrdf installation, and the study folder and the
profile's files (its truths, tables and configs) at the paths the submitting machine sees them:
a shared filesystem, as on a cluster.  Before its cell, each task checks that its worker sees
this run's mark (:data:`MARK`, written by the submitting process into the study folder with an
id of the run) and the cell's input files; a worker that does not ends the study in one line
(:class:`~neuralbrdf.errors.EnvironmentFailure`, exit status 3).

**Failures.**  An address Dask cannot read is bad input (exit status 2), a scheduler that does
not answer within :data:`CONNECT_TIMEOUT_S` the machine's (3); both before the study folder is
made.  A worker lost while it ran a cell (killed, its machine gone) is replaced by Dask, which
runs the task again elsewhere; the lost attempt's folder never becomes the cell's folder
(:mod:`neuralbrdf.study.workers`).  A cell whose workers were lost more often than the
scheduler allows (``distributed.scheduler.allowed-failures``) is recorded as crashed.  Ctrl-C
cancels the study's tasks: a running task asks its Dask worker every
:data:`~neuralbrdf.study.workers.STOP_POLL_S` seconds whether it was cancelled, and then kills
its cell and removes the cell's attempt folder; the same happens when the submitting process is
killed, since the scheduler then releases its tasks.
"""

from __future__ import annotations

import contextlib
import secrets
import signal
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import distributed
from distributed.comm import get_address_host_port

from neuralbrdf.atomic import atomic_write
from neuralbrdf.errors import EnvironmentFailure, InputError, Interrupted, one_line
from neuralbrdf.study.workers import CellStopped, CellWorker, crashed, run_in_worker

#: Seconds the submitting process waits for the scheduler to answer.
CONNECT_TIMEOUT_S = 10
#: The mark of a run in the study folder: the run's id, which every task checks its worker sees.
MARK = ".neuralbrdf.cluster"
#: Where the study's documentation explains what a cluster's workers need.
HOW_TO = "docs/study.md, \"On a cluster\""

#: The cell worker process of each thread of this Dask worker (:func:`run_task`).
_threads = threading.local()


# --------------------------------------------------------------------------- on a worker


def cell_inputs(spec: dict) -> list[str]:
    """The files the cell of ``spec`` reads: its truth, the variant's config, the material's table
    or measured source and its plan file."""
    material = spec["material"]
    sources = [material["table"], None if material["truth"].startswith("virtual:") else material["truth"],
               spec["plan"] if spec["plan"] != spec["cell"]["plan"] else None]
    return [spec["truth"], spec["variant"]["config"], *(path for path in sources if path)]


def unseen(out_dir: Path, run_id: str, spec: dict) -> str | None:
    """What of the study this worker cannot see (the study folder, or a file the cell reads), or ``None``."""
    try:
        seen = (out_dir / MARK).read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        seen = None
    if seen != run_id:
        return f"the study folder {out_dir}"
    return next((path for path in cell_inputs(spec) if not Path(path).exists()), None)


def run_task(spec: dict, out_dir: str, run_id: str, key: str) -> dict | None:
    """The cell of ``spec`` as the task ``key`` of the run ``run_id``, on a Dask worker (module
    docstring); its result, ``None`` when the task was cancelled while its cell ran."""
    worker = distributed.get_worker()
    missing = unseen(Path(out_dir), run_id, spec)
    if missing is not None:
        raise EnvironmentFailure(f"the Dask worker {worker.address} does not see {missing} at the path the "
                                 f"submitting machine does; every worker must see the study folder and the "
                                 f"profile's files at the same paths ({HOW_TO})")
    if not hasattr(_threads, "cell_worker"):
        _threads.cell_worker = CellWorker()
    task = worker.state.tasks

    def cancelled() -> bool:
        return key not in task or task[key].state == "cancelled"

    try:
        return run_in_worker(spec, Path(out_dir) / "cells", _threads.cell_worker, should_stop=cancelled)
    except CellStopped:
        return None


# --------------------------------------------------------------------------- the submitting process


class ClusterCells:
    """The cells of a study as tasks of the Dask scheduler at ``address`` (module docstring);
    ``jobs``: the threads of its workers when the study started (cells at a time)."""

    def __init__(self, client: distributed.Client, address: str) -> None:
        self.client = client
        self.cluster = address
        self.jobs = sum(client.nthreads().values())

    @classmethod
    @contextlib.contextmanager
    def connect(cls, address: str) -> Iterator[ClusterCells]:
        """Connected to the scheduler at ``address`` for the block."""
        try:
            get_address_host_port(address)
        except ValueError as error:
            raise InputError(f"{address!r} is not a Dask scheduler's address ({error}); expected tcp://HOST:PORT",
                             key="--cluster") from None
        try:
            client = distributed.Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
        except OSError:
            raise EnvironmentFailure(f"no Dask scheduler answered at {address} within {CONNECT_TIMEOUT_S} s: is one "
                                     f"running there, and reachable from this machine? ({HOW_TO})") from None
        try:
            yield cls(client, address)
        finally:
            client.close()

    def run(self, specs: list[dict], cells_dir: Path, finished: Callable[[int, dict], None],
            say: Callable[[str], None]) -> None:
        """:meth:`~neuralbrdf.study.runner.Cells.run`: each cell as a task (module docstring)."""
        out_dir = cells_dir.parent
        run_id = secrets.token_hex(8)
        with atomic_write(out_dir / MARK, encoding="ascii") as handle:
            handle.write(run_id + "\n")
        if not self.jobs:
            say(f"study: the Dask cluster at {self.cluster} has no workers yet; the cells wait for the first")
        futures: dict[distributed.Future, int] = {}
        try:
            for i, spec in enumerate(specs):
                key = f"neuralbrdf-cell-{spec['key']}-{run_id}"
                futures[self.client.submit(run_task, spec, str(out_dir), run_id, key, key=key)] = i
            for future in distributed.as_completed(futures, loop=self.client.loop):
                finished(futures[future], self._result(future, specs[futures[future]]))
        except KeyboardInterrupt:
            self.client.cancel(list(futures))
            raise Interrupted(signal.SIGINT, "interrupted by Ctrl-C (SIGINT): the study's tasks on the cluster were "
                                             "cancelled; finished cells are kept and a rerun goes on") from None
        except BaseException:
            self.client.cancel(list(futures))
            raise
        finally:
            (out_dir / MARK).unlink(missing_ok=True)

    def _result(self, future: distributed.Future, spec: dict) -> dict:
        try:
            return future.result()
        except distributed.KilledWorker as error:
            return crashed(spec, f"the Dask workers that ran the cell were lost each time: {one_line(error)}")
        except ImportError as error:  # the task cannot be loaded on the worker
            raise EnvironmentFailure(f"a Dask worker of {self.cluster} cannot run a cell: {one_line(error)}; every "
                                     f"worker needs neuralbrdf installed ({HOW_TO})") from None
