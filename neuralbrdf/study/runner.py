"""``neuralbrdf study``: run a profile's cells (cached, resumable, in parallel) and write the report.

Layout of ``DIR``: ``cells/KEY/`` (one finished cell: ``cell.json``, ``result.json``, its data,
run, model and evaluation; :mod:`neuralbrdf.study.cells`), ``truths/`` (each material's truth,
exported once), ``figures/*.png``, ``study.json``, ``index.html`` and ``runs.jsonl``.  A cell
whose ``result.json`` is a finished result of that cell is reused (checked:
:mod:`neuralbrdf.study.cache`); any other cell folder is left over from a killed run or damaged,
and is cleared and rerun.  Cells run as child processes (``python -m neuralbrdf.study.cell``),
``jobs`` at a time, one thread each, with a progress bar; a cell whose process dies without a
result is reported as ``cell_crashed`` (its log in ``cells/KEY/log.txt``) and rerun next time.

One study at a time runs in ``DIR``: it holds the folder's lock
(:func:`~neuralbrdf.folder_lock.folder_lock`) from start to end, and so do its cell workers.  A
worker ends with its study (:func:`~neuralbrdf.study.cell.die_with_study`: within a tenth of a
second of a study killed by any signal), so a rerun never races a cell still being written; until
the worker is gone, the lock it holds keeps a new run out.
``study.json``'s ``health`` (:mod:`neuralbrdf.study.health`) says whether every cell gave a
model; it sets the command's exit status.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path

from neuralbrdf.atomic import atomic_write
from neuralbrdf.console import progress as progress_bar
from neuralbrdf.folder_lock import folder_lock
from neuralbrdf.study import aggregate
from neuralbrdf.study.cache import Repairs, cached_result, read_runs, truth_file, write_runs
from neuralbrdf.study.cell import STUDY_PID_VARIABLE, WORKER_THREADS
from neuralbrdf.study.cells import Cell, cell_key, is_rendered, plan_cells, seeding_description
from neuralbrdf.study.figures import write_figures
from neuralbrdf.study.health import health
from neuralbrdf.study.profile import Profile, load_profile

STUDY_FORMAT = 1
#: Cells a worker process runs before it is replaced by a fresh one.
CELLS_PER_WORKER = 50
WORKER_COMMAND = (sys.executable, "-m", "neuralbrdf.study.cell", "--serve")


class CellWorker:
    """One worker process (:func:`neuralbrdf.study.cell.serve`), started on first use and again
    after it died or ran :data:`CELLS_PER_WORKER` cells; ``keep_fds``: descriptors it inherits
    (the study folder's lock)."""

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

    def run(self, folder: Path) -> bool:
        """Run the cell in ``folder``; ``False`` when the worker died doing it (it is restarted next time)."""
        if self.process is None or self.process.poll() is not None or self.cells >= CELLS_PER_WORKER:
            self._start()
        self.cells += 1
        try:
            self.process.stdin.write(f"{folder.resolve()}\n")
            self.process.stdin.flush()
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


def _cell_spec(cell: Cell, key: str, profile: Profile, truth: tuple[Path, str]) -> dict:
    material = next(m for m in profile.materials if m.name == cell.material)
    return {"cell": asdict(cell), "key": key, "is_main": is_rendered(cell, profile), "material": asdict(material),
            "variant": asdict(profile.variant(cell.variant)), "truth": str(truth[0].resolve()),
            "truth_sha256": truth[1],
            "render": asdict(profile.render), "cost": asdict(profile.cost)}


def run_one(cell: Cell, spec: dict, cells_dir: Path, repairs: Repairs,
            worker: CellWorker | None = None) -> tuple[dict, bool]:
    """``(result, ran)``: the cached result of the cell ``spec`` describes (checked:
    :func:`~neuralbrdf.study.cache.cached_result`), or the result of running it now in ``worker``
    (a worker of its own when none is given)."""
    key = spec["key"]
    folder = cells_dir / key
    result_path = folder / "result.json"
    cached = cached_result(folder, cell, key, spec["truth_sha256"], repairs)
    if cached is not None:
        return cached, False
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    with atomic_write(folder / "cell.json", encoding="utf-8") as handle:
        json.dump(spec, handle, indent=1)
    own = worker is None
    worker = CellWorker() if own else worker
    try:
        survived = worker.run(folder)
    finally:
        if own:
            worker.close()
    if result_path.is_file():
        return json.loads(result_path.read_text()), True
    log = folder / "log.txt"
    tail = (log.read_text(errors="replace").strip().splitlines() if log.is_file() else [])[-1:] or ["(empty log)"]
    what = "the cell ended without a result" if survived else "the cell's worker process died"
    return {**asdict(cell), "is_main": spec["is_main"], "failure": "cell_crashed",
            "message": f"{what}: {tail[0][:300]} (log: cells/{key}/log.txt)", "cost": {}, "error": {}}, True


def run_cells(profile: Profile, out_dir: Path, jobs: int, repairs: Repairs, progress: bool = True,
              keep_fds: tuple[int, ...] = ()) -> tuple[list[dict], int]:
    """Every cell's result in :func:`plan_cells` order, and how many ran now; ``keep_fds``: what the
    workers inherit (the study folder's lock)."""
    cells = plan_cells(profile)
    truths = {m.name: truth_file(m, out_dir, repairs) for m in profile.materials}
    materials = [m.name for m in profile.materials]
    keys = [cell_key(c, profile) for c in cells]
    results: list[dict | None] = [None] * len(cells)
    ran = 0
    workers: queue.SimpleQueue[CellWorker] = queue.SimpleQueue()
    for _ in range(jobs):
        workers.put(CellWorker(keep_fds=keep_fds))

    def run_in_a_worker(cell: Cell, key: str) -> tuple[dict, bool]:
        worker = workers.get()
        try:
            return run_one(cell, _cell_spec(cell, key, profile, truths[cell.material]), out_dir / "cells", repairs,
                           worker)
        finally:
            workers.put(worker)

    # material by material: a worker's truth evaluator serves the cells that follow (cell.truth_evaluator)
    order = sorted(range(len(cells)), key=lambda i: (materials.index(cells[i].material), not cells[i].is_main))
    with ThreadPoolExecutor(max_workers=jobs) as pool, progress_bar(total=len(cells), unit="cell", desc="study",
                                                            disable=not progress, file=sys.stderr) as bar:
        if progress:
            repairs.say = lambda line: bar.write(line, file=sys.stderr)
        futures = {pool.submit(run_in_a_worker, cells[i], keys[i]): i for i in order}
        for future in as_completed(futures):
            i = futures[future]
            result, did_run = future.result()
            results[i] = {**result, "key": keys[i]}
            ran += did_run
            bar.set_postfix_str(f"{cells[i].material}/{cells[i].variant} {cells[i].condition}", refresh=False)
            bar.update()
    while not workers.empty():
        workers.get().close()
    return results, ran


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
              progress: bool = True, allow_failures: bool = False) -> dict:
    """Run (or resume) the study of ``profile_name`` into ``out_dir``; the content of ``study.json``
    (its ``health`` says whether every cell gave a model; ``allow_failures``: failed fits do not
    fail the run, :mod:`neuralbrdf.study.health`)."""
    profile = load_profile(profile_name)  # a bad profile is refused before the folder exists
    with folder_lock(out_dir, "study") as lock:
        return _run_locked(profile, profile_name, Path(out_dir), jobs, command, progress, allow_failures, lock.fd)


def _run_locked(profile: Profile, profile_name: str, out_dir: Path, jobs: int, command: str | None,
                progress: bool, allow_failures: bool, lock_fd: int) -> dict:
    from neuralbrdf.study.cost import machine

    started_at = datetime.now(timezone.utc).isoformat(timespec="seconds")
    started = time.perf_counter()
    repairs = Repairs(out_dir)
    history = read_runs(out_dir, repairs)  # one line per earlier run (a report made from cached cells
    # still shows the run that computed them, its wall time above all)
    results, ran = run_cells(profile, out_dir, jobs, repairs, progress, keep_fds=(lock_fd,))
    methods = {v.name: v.method for v in profile.variants}
    points = aggregate.points_from_results(results, methods)
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
                "jobs": jobs, "threads_per_job": WORKER_THREADS,
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
