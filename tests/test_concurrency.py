"""Concurrency with real processes (docs/robustness.md, *Runs*): two ``neuralbrdf`` processes on one
run folder or one study folder — one runs, the other is refused at once in one line, and the run
left is whole; a study killed with SIGKILL in the middle of a cell and run again loses no finished
cell and counts none twice.  The race of two fits runs by default; the others are ``slow`` (each
waits for a whole fit or study in several processes).

Each contender is a Python process that has already imported the package and waits for a ``go``
file, so that the contenders meet inside the commands, not in their start-up."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from neuralbrdf.folder_lock import LOCK_FILE

#: A contender: imports the command's entry point, waits for GO, runs it with ARGS, exits with its status.
CONTENDER = """
import os, sys, time
from neuralbrdf.{module} import main
go = sys.argv[1]
while not os.path.exists(go):
    time.sleep(0.02)
sys.exit(main(sys.argv[2:]))
"""
TRAIN = "lightning.run"
CLI = "cli.main"
ABC_FIT = ["fit", "--config", "abc", "--model.n_starts", "8", "--data.eval_plan", "null",
           "--trainer.enable_progress_bar", "false"]
STUDY_PROFILE = """render: {spp: 1, resolution: 16}
hemisphere_strata: [4, 5]
cost: {spp: 1, resolution: 16, repeats: 1, batch: 1024}
materials:
  - {name: gold, truth: "virtual:gold"}
variants:
  - {name: abc, method: abc, config: configs/abc.yaml, args: [--model.n_starts, "1"], speed_accuracy: false}
stability:
  variants: [abc]
  plans: [DS1, DS2, DS3]
  noise: [0.0, 0.01]
  seeds: [0]
"""
N_STUDY_CELLS = 4  # DS1, DS2, DS3 without noise and DS1 with 1 % noise


def contender(module: str, go: Path, args: list[str], cwd: Path, **popen) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", CONTENDER.format(module=module), str(go), *args], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **popen)


def wait_for(condition, timeout: float = 120.0, what: str = "") -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def holder(folder: Path) -> int | None:
    """The process id the folder's lock file names (its last holder), if any."""
    try:
        return int((folder / LOCK_FILE).read_text().strip())
    except (OSError, ValueError):
        return None


def test_two_fits_started_together_on_one_run_folder_give_one_whole_run(tmp_path):
    """Both start at the same instant: exactly one runs, the other exits 2 naming the folder and the
    holder; the run folder holds one run, logged once."""
    go = tmp_path / "go"
    fits = [contender(TRAIN, go, [*ABC_FIT, "--run_dir", "run"], tmp_path) for _ in range(2)]
    time.sleep(0.5)  # both imported or importing; neither can start before go
    go.touch()
    outcomes = [(fit.wait(timeout=300), *fit.communicate()) for fit in fits]
    statuses = sorted(status for status, _, _ in outcomes)
    assert statuses == [0, 2], outcomes
    winner, loser = (outcomes.index(next(o for o in outcomes if o[0] == s)) for s in (0, 2))
    refusal = outcomes[loser][2].strip().splitlines()
    assert len(refusal) == 1 and f"run: in use by another training run (process {fits[winner].pid})" in refusal[0], \
        refusal
    run = tmp_path / "run"
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["status"] == "ok" and metrics["fit/epochs"] == 1
    log = (run / "metrics.csv").read_text().splitlines()
    assert sum(line.startswith("epoch") for line in log) == 1  # one header: one run's log
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["best.ckpt", "last.ckpt"]
    assert not [p for p in tmp_path.rglob("*neuralbrdf-tmp*")]


@pytest.mark.slow
def test_a_fit_into_a_run_folder_in_use_is_refused_and_the_running_fit_finishes(tmp_path):
    go = tmp_path / "go"
    second = contender(TRAIN, go, [*ABC_FIT, "--run_dir", "run", "--overwrite"], tmp_path)
    first = subprocess.Popen([sys.executable, "-m", "neuralbrdf", "train", *ABC_FIT, "--run_dir", "run"], cwd=tmp_path,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for(lambda: holder(tmp_path / "run") == first.pid or first.poll() is not None, what="the first fit's lock")
    assert first.poll() is None, "the first fit ended before the second could meet it"
    go.touch()
    assert second.wait(timeout=300) == 2
    refusal = second.communicate()[1].strip().splitlines()
    assert len(refusal) == 1 and f"run: in use by another training run (process {first.pid})" in refusal[0], refusal
    assert first.wait(timeout=300) == 0, first.communicate()
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["status"] == "ok"  # --overwrite of the second touched nothing


def _study(tmp_path: Path, out: Path, **popen) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "neuralbrdf", "study", "--profile", str(tmp_path / "p.yaml"),
                             "--out", str(out), "--no-progress"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **popen)


def _finished_cells(out: Path) -> set[str]:
    return {p.parent.name for p in (out / "cells").glob("*/result.json")} if (out / "cells").is_dir() else set()


@pytest.mark.slow
def test_a_study_killed_mid_cell_and_run_again_loses_nothing_and_counts_nothing_twice(tmp_path):
    """A second study on the folder while the first runs is refused; the first, SIGKILLed (with its
    cell worker: the process group) while a cell runs after others finished, leaves those cells'
    results, which the rerun reuses; the rerun runs the rest, and study.json and runs.jsonl count
    every cell once."""
    (tmp_path / "p.yaml").write_text(STUDY_PROFILE)
    out = tmp_path / "study"
    first = _study(tmp_path, out, start_new_session=True)  # its own process group: the worker dies with it
    try:
        wait_for(lambda: holder(out) == first.pid or first.poll() is not None, what="the study's lock")
        go = tmp_path / "go"
        second = contender(CLI, go, ["study", "--profile", str(tmp_path / "p.yaml"), "--out", str(out),
                                     "--no-progress"], tmp_path)
        go.touch()
        assert second.wait(timeout=300) == 2
        assert "in use by another study" in second.communicate()[1]
        # mid-cell: some cells finished, and a cell folder without its result (the worker is in it)
        wait_for(lambda: len(_finished_cells(out)) >= 2 or first.poll() is not None, timeout=600, what="two cells")
        wait_for(lambda: len({p.name for p in (out / "cells").iterdir()} - _finished_cells(out)) >= 1
                 or first.poll() is not None, what="a cell in progress")
        assert first.poll() is None, "the study ended before it could be killed"
        os.killpg(first.pid, signal.SIGKILL)
        first.wait(timeout=60)
    finally:
        if first.poll() is None:
            os.killpg(first.pid, signal.SIGKILL)
    done_before = _finished_cells(out)
    results_before = {key: (out / "cells" / key / "result.json").read_bytes() for key in done_before}
    assert 2 <= len(done_before) < N_STUDY_CELLS and not (out / "study.json").exists()
    wait_for(lambda: holder(out) is None or not _alive(holder(out)), what="the killed study's processes to end")
    rerun = _study(tmp_path, out)
    assert rerun.wait(timeout=900) == 0, rerun.communicate()
    study = json.loads((out / "study.json").read_text())
    cells = [(p["material"], p["model"], p["plan"], p["noise"], p["seed"]) for p in study["points"]]
    assert len(cells) == len(set(cells)) == N_STUDY_CELLS and all(p["failure"] is None for p in study["points"])
    assert study["run"]["cells_cached"] == len(done_before)  # nothing lost ...
    assert study["run"]["cells_run"] == N_STUDY_CELLS - len(done_before)  # ... nothing counted twice
    assert {key: (out / "cells" / key / "result.json").read_bytes() for key in done_before} == results_before
    assert len(_finished_cells(out)) == N_STUDY_CELLS
    runs = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    assert [(r["cells_run"], r["cells_cached"]) for r in runs] == [(N_STUDY_CELLS - len(done_before), len(done_before))]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True
