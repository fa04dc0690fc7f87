"""``neuralbrdf study``: run a profile's cells (cached, resumable, in parallel) and write the report.

Layout of ``DIR``: ``cells/KEY/`` (one finished cell: ``cell.json``, ``result.json``, its data,
run, model and evaluation; :mod:`neuralbrdf.study.cells`), ``truths/`` (each material's truth,
exported once), ``figures/*.png``, ``study.json``, ``index.html`` and ``runs.jsonl``.  A cell
whose ``result.json`` is a finished result of that cell is reused (checked:
:mod:`neuralbrdf.study.cache`); any other cell folder is left over from a killed run or damaged,
and is cleared and rerun.  Each cell runs in a cell worker process
(:mod:`neuralbrdf.study.workers`), in an attempt folder of its own that becomes ``cells/KEY/``
when the cell has ended; a cell whose process dies without a result is reported as
``cell_crashed`` (its log in ``cells/KEY/log.txt``) and rerun next time.  The worker processes
are the study's own, ``jobs`` at a time, one thread each (:class:`LocalCells`), or those of the
workers of a Dask cluster (``--cluster``: :mod:`neuralbrdf.study.cluster`); a progress bar counts
the finished cells.

One study at a time runs in ``DIR``: it holds the folder's lock
(:func:`~neuralbrdf.folder_lock.folder_lock`) from start to end, and so do its own cell workers.
A worker ends with its study (:func:`~neuralbrdf.study.cell.die_with_study`: within a tenth of a
second of a study killed by any signal), so a rerun never races a cell still being written; until
the worker is gone, the lock it holds keeps a new run out.
``study.json``'s ``health`` (:mod:`neuralbrdf.study.health`) says whether every cell gave a
model; it sets the command's exit status.
"""

from __future__ import annotations

import contextlib
import json
import queue
import shutil
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path
from typing import Protocol

from neuralbrdf.atomic import atomic_write
from neuralbrdf.console import progress as progress_bar
from neuralbrdf.folder_lock import folder_lock
from neuralbrdf.study import aggregate
from neuralbrdf.study.cache import Repairs, cached_result, read_runs, truth_file, write_runs
from neuralbrdf.study.cell import WORKER_THREADS
from neuralbrdf.study.cells import Cell, cell_key, is_rendered, plan_cells, renders_images, seeding_description
from neuralbrdf.study.figures import write_figures
from neuralbrdf.study.health import health
from neuralbrdf.study.profile import Profile, load_profile
from neuralbrdf.study.workers import CellWorker, remove_attempts, run_in_worker

STUDY_FORMAT = 1


def cell_spec(cell: Cell, key: str, profile: Profile, truth: tuple[Path, str]) -> dict:
    """What ``cells/KEY/cell.json`` holds: everything the cell's worker needs to run it
    (:mod:`neuralbrdf.study.cell`)."""
    material = next(m for m in profile.materials if m.name == cell.material)
    return {"cell": asdict(cell), "key": key, "is_main": is_rendered(cell, profile),
            "images": renders_images(cell, profile), "plan": profile.stability.plan(cell.plan), "material": asdict(material),
            "variant": asdict(profile.variant(cell.variant)), "truth": str(truth[0].resolve()),
            "truth_sha256": truth[1],
            "render": asdict(profile.render), "cost": asdict(profile.cost)}


class Cells(Protocol):
    """Where a study's cells run: ``jobs`` at a time, on the Dask cluster at ``cluster`` or (``None``)
    on this machine; ``run`` runs the cells of ``specs``, calling ``finished(index, result)`` as each
    ends (``say``: a line for the user, beside the progress bar)."""

    jobs: int
    cluster: str | None

    def run(self, specs: list[dict], cells_dir: Path, finished: Callable[[int, dict], None],
            say: Callable[[str], None]) -> None: ...


class LocalCells:
    """``--jobs N``: the cells run in N :class:`~neuralbrdf.study.workers.CellWorker` processes
    of the study's own, which inherit ``keep_fds`` (the study folder's lock)."""

    cluster = None

    def __init__(self, jobs: int, keep_fds: tuple[int, ...] = ()) -> None:
        self.jobs = jobs
        self.keep_fds = keep_fds

    def run(self, specs: list[dict], cells_dir: Path, finished: Callable[[int, dict], None],
            say: Callable[[str], None]) -> None:
        """:meth:`Cells.run`."""
        workers: queue.SimpleQueue[CellWorker] = queue.SimpleQueue()
        for _ in range(self.jobs):
            workers.put(CellWorker(keep_fds=self.keep_fds))

        def run_in_a_worker(spec: dict) -> dict:
            worker = workers.get()
            try:
                return run_in_worker(spec, cells_dir, worker)
            finally:
                workers.put(worker)

        try:
            with ThreadPoolExecutor(max_workers=self.jobs) as pool:
                futures = {pool.submit(run_in_a_worker, spec): i for i, spec in enumerate(specs)}
                for future in as_completed(futures):
                    finished(futures[future], future.result())
        finally:
            while not workers.empty():
                workers.get().close()


def run_cells(profile: Profile, out_dir: Path, cells: Cells, repairs: Repairs,
              progress: bool = True) -> tuple[list[dict], int]:
    """Every cell's result in :func:`plan_cells` order, and how many ran now: each cell whose
    folder holds a finished result of it is reused (:func:`~neuralbrdf.study.cache.cached_result`),
    every other runs in ``cells`` (:class:`LocalCells`, or
    :class:`~neuralbrdf.study.cluster.ClusterCells`), material by material."""
    planned = plan_cells(profile)
    truths = {m.name: truth_file(m, out_dir, repairs) for m in profile.materials}
    materials = [m.name for m in profile.materials]
    keys = [cell_key(c, profile) for c in planned]
    specs = [cell_spec(c, k, profile, truths[c.material]) for c, k in zip(planned, keys)]
    cells_dir = out_dir / "cells"
    remove_attempts(cells_dir)
    results: list[dict | None] = [None] * len(planned)
    with progress_bar(total=len(planned), unit="cell", desc="study", disable=not progress, file=sys.stderr) as bar:
        if progress:
            repairs.say = lambda line: bar.write(line, file=sys.stderr)
        for i, (cell, key) in enumerate(zip(planned, keys)):
            results[i] = cached_result(cells_dir / key, cell, key, specs[i]["truth_sha256"], repairs)
            if results[i] is None and (cells_dir / key).exists():  # left by a crash or a killed run, or damaged
                shutil.rmtree(cells_dir / key)
        # material by material: a worker's truth evaluator serves the cells that follow (cell.truth_evaluator)
        to_run = sorted((i for i, result in enumerate(results) if result is None),
                        key=lambda i: (materials.index(planned[i].material), not planned[i].is_main))
        if len(to_run) < len(planned):
            bar.update(len(planned) - len(to_run))

        def finished(j: int, result: dict) -> None:
            cell = planned[to_run[j]]
            results[to_run[j]] = result
            bar.set_postfix_str(f"{cell.material}/{cell.variant} {cell.condition}", refresh=False)
            bar.update()

        cells.run([specs[i] for i in to_run], cells_dir, finished, repairs.say)
    remove_attempts(cells_dir)  # those of cluster workers lost while they ran a cell
    return [{**result, "key": key} for result, key in zip(results, keys)], len(to_run)

def group_members(profile: Profile) -> dict[str, list[tuple[str, str]]]:
    """The profile's variant groups in order of appearance: group → ``(label, variant)`` pairs."""
    members: dict[str, list[tuple[str, str]]] = {}
    for v in profile.variants:
        if v.group:
            members.setdefault(v.group, []).append((v.label, v.name))
    return members


def _shown_path(path: Path) -> str:
    """``path`` relative to the repository when it lies inside (no machine-specific prefix)."""
    from neuralbrdf.study.profile import REPO_ROOT

    try:
        return str(path.resolve().relative_to(REPO_ROOT))
    except ValueError:
        return str(path)


_RUN_FIELDS = ("started", "command", "jobs", "cells_run", "cells_cached", "wall_time_s", "cells_cpu_time_s")


def run_study(profile_name: str, out_dir: str | Path, jobs: int = 1, command: str | None = None,
              progress: bool = True, allow_failures: bool = False, cluster: str | None = None) -> dict:
    """Run (or resume) the study of ``profile_name`` into ``out_dir``; the content of ``study.json``
    (its ``health`` says whether every cell gave a model; ``allow_failures``: failed fits do not
    fail the run, :mod:`neuralbrdf.study.health`).  The cells run ``jobs`` at a time in processes
    of this one, or with ``cluster`` (``tcp://HOST:PORT``) as tasks on that Dask scheduler's
    workers (:mod:`neuralbrdf.study.cluster`)."""
    profile = load_profile(profile_name)  # a bad profile is refused before the folder exists
    with contextlib.ExitStack() as stack:
        if cluster is not None:  # an unreachable scheduler is refused before the folder exists too
            from neuralbrdf.study.cluster import ClusterCells

            cells = stack.enter_context(ClusterCells.connect(cluster))
        lock = stack.enter_context(folder_lock(out_dir, "study"))
        if cluster is None:
            cells = LocalCells(jobs, keep_fds=(lock.fd,))
        return _run_locked(profile, profile_name, Path(out_dir), cells, command, progress, allow_failures)


def _run_locked(profile: Profile, profile_name: str, out_dir: Path, cells: Cells, command: str | None,
                progress: bool, allow_failures: bool) -> dict:
    from neuralbrdf.study.cost import machine

    started_at = datetime.now(timezone.utc).isoformat(timespec="seconds")
    started = time.perf_counter()
    repairs = Repairs(out_dir)
    history = read_runs(out_dir, repairs)  # one line per earlier run (a report made from cached cells
    # still shows the run that computed them, its wall time above all)
    results, ran = run_cells(profile, out_dir, cells, repairs, progress)
    methods = {v.name: v.method for v in profile.variants}
    pairs = {plan: profile.stability.pairs(plan) for plan in dict.fromkeys(r["plan"] for r in results)}
    points = aggregate.points_from_results(results, methods, pairs)
    failure_rows = aggregate.failures(points)
    study = {
        "format": STUDY_FORMAT,
        "health": health(points, repairs.entries, allow_failures),
        "points": points,
        "pareto": aggregate.pareto(points),
        "failures": failure_rows,
        "failure_causes": list(aggregate.CAUSES),
        "summary": aggregate.budgets(points),
        "groups": aggregate.groups(points, group_members(profile), [m.name for m in profile.materials]),
        "sentences": aggregate.method_sentences(points, failure_rows),
        "machine": machine(),
        "seeding": {method: seeding_description(method) for method in dict.fromkeys(methods.values())},
        "run": {"profile": _shown_path(profile.path), "command": command or f"neuralbrdf study --profile {profile_name}",
                "jobs": cells.jobs, "cluster": cells.cluster, "threads_per_job": WORKER_THREADS,
                "seeds": sorted({p["seed"] for p in points}), "started": started_at,
                "cells_run": ran, "cells_cached": len(results) - ran,
                "cells_time_s": sum(r.get("cell_wall_time_s") or 0.0 for r in results),
                "cells_cpu_time_s": sum(r.get("cell_cpu_time_s") or 0.0 for r in results),
                "hemisphere_pairs": (profile.render.hemisphere_strata[0] * profile.render.hemisphere_strata[1]) ** 2},
    }
    study["figures"] = write_figures(study, out_dir)
    study["run"]["wall_time_s"] = time.perf_counter() - started
    study["run"]["history"] = [*history, {key: study["run"][key] for key in _RUN_FIELDS}]
    write_runs(out_dir, study["run"]["history"])
    with atomic_write(out_dir / "study.json", encoding="utf-8") as handle:
        json.dump(study, handle, indent=1, allow_nan=False)
    from neuralbrdf.study.report import write_report

    write_report(study, study["figures"], out_dir)
    return study
