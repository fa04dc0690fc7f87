"""``neuralbrdf study``: run a profile's cells (cached, resumable, in parallel) and write the report.

Layout of ``DIR``: ``cells/KEY/`` (one finished cell: ``cell.json``, ``result.json``, its data,
run, model and evaluation; :mod:`neuralbrdf.study.cells`), ``truths/NAME.onnx`` (each material's
truth, exported once), ``figures/*.png``, ``study.json`` and ``index.html``.  A cell with a
``result.json`` is reused; any other cell folder is left over from a killed run and is cleared
and rerun.  Cells run as child processes (``python -m neuralbrdf.study.cell``), ``jobs`` at a
time, one thread each, with a progress bar; a cell whose process dies without a result is
reported as ``cell_crashed`` (its log in ``cells/KEY/log.txt``) and rerun next time.
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

from tqdm import tqdm

from neuralbrdf.atomic import atomic_write
from neuralbrdf.study import aggregate
from neuralbrdf.study.cell import WORKER_THREADS
from neuralbrdf.study.cells import Cell, cell_key, is_rendered, plan_cells
from neuralbrdf.study.figures import write_figures
from neuralbrdf.study.profile import Profile, load_profile

STUDY_FORMAT = 1
#: Cells a worker process runs before it is replaced by a fresh one.
CELLS_PER_WORKER = 50
WORKER_COMMAND = (sys.executable, "-m", "neuralbrdf.study.cell", "--serve")


class CellWorker:
    """One worker process (:func:`neuralbrdf.study.cell.serve`), started on first use and again
    after it died or ran :data:`CELLS_PER_WORKER` cells."""

    def __init__(self, command: tuple[str, ...] = WORKER_COMMAND) -> None:
        self.command = command
        self.process: subprocess.Popen | None = None
        self.cells = 0

    def _start(self) -> None:
        self.close()
        env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONWARNINGS": "ignore"}
        self.process = subprocess.Popen(self.command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        stderr=subprocess.DEVNULL, env=env, text=True, bufsize=1)
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


def truth_path(profile: Profile, material: str, out_dir: Path) -> Path:
    """The material's truth as an ``.onnx`` file, exported under ``out_dir/truths`` once."""
    from neuralbrdf.evaluation.truth import export_truth

    spec = next(m for m in profile.materials if m.name == material)
    if spec.truth.endswith(".onnx"):
        return Path(spec.truth)
    path = out_dir / "truths" / f"{material}.onnx"
    if not path.is_file():
        export_truth(spec.truth, path)
    return path


def _cell_spec(cell: Cell, profile: Profile, truth: Path) -> dict:
    material = next(m for m in profile.materials if m.name == cell.material)
    return {"cell": asdict(cell), "is_main": is_rendered(cell, profile), "material": asdict(material),
            "variant": asdict(profile.variant(cell.variant)), "truth": str(truth),
            "render": asdict(profile.render), "cost": asdict(profile.cost)}


def run_one(cell: Cell, key: str, spec: dict, cells_dir: Path, worker: CellWorker | None = None) -> tuple[dict, bool]:
    """``(result, ran)``: the cached result, or the result of running the cell now in ``worker``
    (a worker of its own when none is given)."""
    folder = cells_dir / key
    result_path = folder / "result.json"
    if result_path.is_file():
        return json.loads(result_path.read_text()), False
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    (folder / "cell.json").write_text(json.dumps(spec, indent=1))
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


def run_cells(profile: Profile, out_dir: Path, jobs: int, progress: bool = True) -> tuple[list[dict], int]:
    """Every cell's result in :func:`plan_cells` order, and how many ran now."""
    cells = plan_cells(profile)
    truths = {m.name: truth_path(profile, m.name, out_dir) for m in profile.materials}
    materials = [m.name for m in profile.materials]
    keys = [cell_key(c, profile) for c in cells]
    results: list[dict | None] = [None] * len(cells)
    ran = 0
    workers: queue.SimpleQueue[CellWorker] = queue.SimpleQueue()
    for _ in range(jobs):
        workers.put(CellWorker())

    def run_in_a_worker(cell: Cell, key: str) -> tuple[dict, bool]:
        worker = workers.get()
        try:
            return run_one(cell, key, _cell_spec(cell, profile, truths[cell.material]), out_dir / "cells", worker)
        finally:
            workers.put(worker)

    # material by material: a worker's truth evaluator serves the cells that follow (cell.truth_evaluator)
    order = sorted(range(len(cells)), key=lambda i: (materials.index(cells[i].material), not cells[i].is_main))
    with ThreadPoolExecutor(max_workers=jobs) as pool, tqdm(total=len(cells), unit="cell", desc="study",
                                                            disable=not progress, file=sys.stderr) as bar:
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


#: One line per ``neuralbrdf study`` run into a folder (JSON Lines): how its cells came about.
RUNS_LOG = "runs.jsonl"
_RUN_FIELDS = ("started", "command", "jobs", "cells_run", "cells_cached", "wall_time_s", "cells_cpu_time_s")


def _record_run(out_dir: Path, run: dict) -> list[dict]:
    """Append this run to ``out_dir/runs.jsonl`` and return every run recorded there: a report made
    from cached cells still shows the run that computed them (its wall time, above all)."""
    log = out_dir / RUNS_LOG
    entry = {key: run[key] for key in _RUN_FIELDS}
    with log.open("a", encoding="utf-8") as handle:
        handle.write(json.dumps(entry) + "\n")
    return [json.loads(line) for line in log.read_text(encoding="utf-8").splitlines() if line.strip()]


def run_study(profile_name: str, out_dir: str | Path, jobs: int = 1, command: str | None = None,
              progress: bool = True) -> dict:
    """Run (or resume) the study of ``profile_name`` into ``out_dir``; the content of ``study.json``."""
    from neuralbrdf.study.cost import machine

    started_at = datetime.now(timezone.utc).isoformat(timespec="seconds")
    started = time.perf_counter()
    profile = load_profile(profile_name)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    results, ran = run_cells(profile, out_dir, jobs, progress)
    methods = {v.name: v.method for v in profile.variants}
    points = aggregate.points_from_results(results, methods)
    failure_rows = aggregate.failures(points)
    study = {
        "format": STUDY_FORMAT,
        "points": points,
        "pareto": aggregate.pareto(points),
        "failures": failure_rows,
        "failure_causes": list(aggregate.CAUSES),
        "summary": aggregate.budgets(points),
        "groups": aggregate.groups(points, group_members(profile), [m.name for m in profile.materials]),
        "sentences": aggregate.method_sentences(points, failure_rows),
        "machine": machine(),
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
    study["run"]["history"] = _record_run(out_dir, study["run"])
    with atomic_write(out_dir / "study.json", encoding="utf-8") as handle:
        json.dump(study, handle, indent=1, allow_nan=False)
    from neuralbrdf.study.report import write_report

    write_report(study, study["figures"], out_dir)
    return study
