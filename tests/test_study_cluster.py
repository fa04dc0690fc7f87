"""``neuralbrdf study --cluster`` (docs/study.md, "On a cluster"): the cells as tasks on a Dask cluster
that each test starts itself on this machine — a scheduler and two one-thread workers, as a user
starts them by hand.

Most tests run fake cells (:data:`CLUSTER_CELL`: the real cell worker loop, whose cells write a
result at once, or stay running for the variants ``lost`` and ``endless``) and a fake truth
exporter, so that they take seconds; the slow test runs the quick profile's real cells on the
cluster and with ``--jobs 2`` and compares every cell's metrics.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from test_study_robustness import STUDY_DRIVER, fake, profile, study  # noqa: F401  (fake: a fixture)

from neuralbrdf.cli.main import main as cli
from neuralbrdf.errors import InputError
from neuralbrdf.folder_lock import folder_lock

ROOT = Path(__file__).resolve().parents[1]
HAS_DASK = importlib.util.find_spec("distributed") is not None
needs_dask = pytest.mark.skipif(not HAS_DASK, reason="needs Dask's distributed (the cluster extra)")

#: A cell worker for the cluster's workers: the real loop (:func:`neuralbrdf.study.cell.serve`, which
#: ends with its Dask worker), with cells that write their result at once — except ``lost``, whose
#: first attempt marks itself (``markers/KEY`` beside the study folder, holding its pid) and runs
#: until it is killed, and ``endless…``, whose every attempt does.
CLUSTER_CELL = r"""
import json, os, time
from pathlib import Path
from neuralbrdf.study import cell

def run_cell(folder):
    spec = json.loads((folder / "cell.json").read_text())
    variant, markers = spec["variant"]["name"], folder.parents[2] / "markers"
    if variant.startswith("endless") or (variant == "lost" and not (markers / spec["key"]).exists()):
        markers.mkdir(exist_ok=True)
        (markers / (spec["key"] + ".tmp")).write_text(str(os.getpid()))
        os.replace(markers / (spec["key"] + ".tmp"), markers / spec["key"])
        while True:
            time.sleep(1)
    result = {**spec["cell"], "is_main": spec["is_main"], "key": spec["key"], "truth_sha256": spec["truth_sha256"],
              "failure": None, "message": None, "cost": {"fit_time_s": 1.0},
              "error": {"hemisphere_logcos_rmse": 0.01 + 0.001 * spec["cell"]["seed"]}, "pid": os.getpid()}
    (folder / "result.json").write_text(json.dumps(result))

cell._import_fitting = lambda: None
cell.run_cell = run_cell
cell.serve()
"""

#: A worker's preload: its cells run :data:`CLUSTER_CELL`.
PRELOAD = f"""import sys
from neuralbrdf.study import workers
workers.WORKER_COMMAND = (sys.executable, "-c", {CLUSTER_CELL!r})
"""


def variants(*names: str) -> str:
    return "".join(f"  - {{name: {n}, method: abc, config: configs/abc.yaml, speed_accuracy: false}}\n" for n in names)


def without_stability(path: Path) -> Path:
    """The profile ``path`` with main cells only."""
    text = path.read_text()
    path.write_text(text[:text.index("stability:")])
    return path


@contextlib.contextmanager
def dask_cluster(folder: Path, preload: Path | None = None, wrap: tuple[str, ...] = ()):
    """A scheduler and two one-thread workers (``wrap``: a command each worker runs under), as
    processes of their own sessions, all ended afterwards; yields the scheduler's address."""
    from distributed import Client

    folder.mkdir(parents=True, exist_ok=True)
    scheduler_file = folder / "scheduler.json"
    processes = []

    def start(*command: str, log: str) -> None:
        with open(folder / log, "w") as out:
            processes.append(subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT, start_new_session=True))

    try:
        start(sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0",
              "--no-dashboard", "--scheduler-file", str(scheduler_file), log="scheduler.log")
        deadline = time.monotonic() + 60
        while not scheduler_file.is_file():
            assert time.monotonic() < deadline and processes[0].poll() is None, (folder / "scheduler.log").read_text()
            time.sleep(0.1)
        address = json.loads(scheduler_file.read_text())["address"]
        for n in range(2):
            start(*wrap, sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1",
                  "--no-dashboard", "--name", f"worker{n}", *(("--preload", str(preload)) if preload else ()),
                  log=f"worker{n}.log")
        with Client(address, timeout=30) as client:
            client.wait_for_workers(2, timeout=120)
        yield address
    finally:
        for process in processes:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            process.wait()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A cluster whose cells are :data:`CLUSTER_CELL`, for the tests of this module that share it."""
    if not HAS_DASK:
        pytest.skip("needs Dask's distributed (the cluster extra)")
    folder = tmp_path_factory.mktemp("cluster")
    (folder / "preload.py").write_text(PRELOAD)
    with dask_cluster(folder, preload=folder / "preload.py") as address:
        yield address


def worker_pids(address: str) -> set[int]:
    from distributed import Client

    with Client(address, timeout=30) as client:
        return set(client.run(os.getpid).values())


def parent(pid: int) -> int:
    status = Path(f"/proc/{pid}/status").read_text()
    return int(next(line.split()[1] for line in status.splitlines() if line.startswith("PPid:")))


def alive(pid: int) -> bool:
    from process_hooks import is_alive

    return is_alive(pid)


def wait_for(condition, seconds: float = 60, what: str = "") -> None:
    deadline = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def cell_folders(out: Path) -> list[str]:
    return sorted(p.name for p in (out / "cells").iterdir()) if (out / "cells").is_dir() else []


# --------------------------------------------------------------------------- the same study, its cache shared


@needs_dask
def test_a_study_on_a_cluster_is_the_study_of_this_machine_and_shares_its_cache(tmp_path, fake, cluster, capsys,
                                                                                monkeypatch):
    """The same points, cell keys and folders as ``--jobs 2`` (the same fake cells), the cells run in
    processes of the Dask workers, the progress counts every finished task, and each run reuses the
    other's cells."""
    from neuralbrdf import console
    from neuralbrdf.study import workers

    monkeypatch.setattr(workers, "WORKER_COMMAND", (sys.executable, "-c", CLUSTER_CELL))
    monkeypatch.setattr(console, "LINE_INTERVAL_S", 0.0)
    path = profile(tmp_path)
    here, there = tmp_path / "here", tmp_path / "there"
    assert study(path, here, "--jobs", "2") == 0
    assert cli(["study", "--profile", str(path), "--out", str(there), "--cluster", cluster]) == 0
    progress = [line for line in capsys.readouterr().err.splitlines() if line.startswith("study: ")]
    assert [line.split()[1] for line in progress] == [f"{n}/6" for n in range(1, 7)]  # one line per finished task
    local, remote = (json.loads((out / "study.json").read_text()) for out in (here, there))
    assert remote["points"] == local["points"] and remote["summary"] == local["summary"]
    assert remote["run"]["cluster"] == cluster and remote["run"]["jobs"] == 2 and local["run"]["cluster"] is None
    assert remote["run"]["command"].endswith(f"--cluster {cluster}") and (there / "index.html").is_file()
    assert cell_folders(there) == cell_folders(here) == sorted(p["key"] for p in local["points"])
    dask_workers = worker_pids(cluster)
    for key in cell_folders(there):
        assert parent(json.loads((there / "cells" / key / "result.json").read_text())["pid"]) in dask_workers
    assert not (there / ".neuralbrdf.cluster").exists()
    assert study(path, there) == 0  # cells finished on the cluster, reused here
    assert cli(["study", "--profile", str(path), "--out", str(here), "--cluster", cluster, "--no-progress"]) == 0
    for out in (here, there):
        assert json.loads((out / "study.json").read_text())["run"]["cells_run"] == 0


# --------------------------------------------------------------------------- a worker lost, Ctrl-C


@needs_dask
def test_a_worker_killed_mid_cell_means_the_cell_runs_again(tmp_path, fake, cluster):
    """The Dask worker running a cell is killed (SIGKILL): its cell process ends with it, the task
    runs again on a worker, and the study ends complete with the cell's folder whole; nothing of
    the lost attempt stays."""
    out, markers = tmp_path / "study", tmp_path / "markers"
    path = profile(tmp_path, variants=variants("abc", "lost"))
    status = []
    submitter = threading.Thread(target=lambda: status.append(study(path, out, "--cluster", cluster)))
    submitter.start()
    try:
        wait_for(lambda: markers.is_dir() and any(markers.iterdir()), what="the cell to start")
        (marker,) = markers.iterdir()
        lost_cell = int(marker.read_text())
        os.kill(parent(lost_cell), signal.SIGKILL)  # its Dask worker
    finally:
        submitter.join(timeout=120)
    assert status == [0] and not alive(lost_cell)
    points = json.loads((out / "study.json").read_text())["points"]
    assert all(p["failure"] is None for p in points) and len(points) == 7
    folder = out / "cells" / marker.name
    assert sorted(p.name for p in folder.iterdir()) == ["cell.json", "log.txt", "result.json"]
    assert json.loads((folder / "result.json").read_text())["pid"] != lost_cell
    assert cell_folders(out) == sorted(p["key"] for p in points)  # no attempt folder beside them
    wait_for(lambda: len(worker_pids(cluster)) == 2, what="the nanny to restart the worker")


@needs_dask
def test_ctrl_c_cancels_the_studys_tasks_and_leaves_no_cell_half_written(tmp_path, cluster):
    """SIGINT to the submitting process while both workers run a cell: it exits 130 with one line,
    the scheduler forgets the study's tasks, the cell processes end, no cell folder appears, and
    the study folder's lock, held until then, is free."""
    from distributed import Client

    out, markers = tmp_path / "study", tmp_path / "markers"
    path = without_stability(profile(tmp_path, variants=variants("endless", "endless2")))
    # SIGINT as a terminal delivers it, also when pytest itself runs in the background (a shell starts
    # background jobs with SIGINT ignored, and a child would inherit that)
    submitter = subprocess.Popen([sys.executable, "-c", STUDY_DRIVER, "", "study", "--profile", str(path), "--out",
                                  str(out), "--cluster", cluster, "--no-progress"],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                 preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        wait_for(lambda: markers.is_dir() and len(list(markers.iterdir())) == 2, what="both workers' cells")
        running = [int(m.read_text()) for m in markers.iterdir()]
        with pytest.raises(InputError, match="in use by another study"):  # the submitter holds the folder
            with folder_lock(out, "study"):
                pass
        submitter.send_signal(signal.SIGINT)
        _, err = submitter.communicate(timeout=60)
    finally:
        if submitter.poll() is None:
            submitter.kill()
    assert submitter.returncode == 130, err
    assert err.strip().splitlines() == ["neuralbrdf study: error: interrupted by Ctrl-C (SIGINT): the study's tasks "
                                        "on the cluster were cancelled; finished cells are kept and a rerun goes on"]
    wait_for(lambda: not any(alive(pid) for pid in running), seconds=30, what="the cells to end")
    with Client(cluster, timeout=30) as client:
        wait_for(lambda: not client.run_on_scheduler(lambda dask_scheduler: list(dask_scheduler.tasks)),
                 seconds=30, what="the scheduler to forget the tasks")
    assert cell_folders(out) == [] and not (out / ".neuralbrdf.cluster").exists()
    with folder_lock(out, "study"):
        pass


# --------------------------------------------------------------------------- a cluster that cannot run the study


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err
    return err


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@needs_dask
def test_an_unreachable_or_unreadable_address_is_one_line_and_leaves_no_folder(tmp_path, fake, capsys, monkeypatch):
    from neuralbrdf.study import cluster as cluster_module

    monkeypatch.setattr(cluster_module, "CONNECT_TIMEOUT_S", 1)
    path, out = profile(tmp_path), tmp_path / "study"
    address = f"tcp://127.0.0.1:{free_port()}"
    assert cli(["study", "--profile", str(path), "--out", str(out), "--cluster", address]) == 3
    assert one_line(capsys) == (f"neuralbrdf study: error: no Dask scheduler answered at {address} within 1 s: is one "
                                "running there, and reachable from this machine? (docs/study.md, \"On a cluster\")")
    assert cli(["study", "--profile", str(path), "--out", str(out), "--cluster", "127.0.0.1"]) == 2
    assert one_line(capsys).startswith("neuralbrdf study: error: option '--cluster': '127.0.0.1' is not a Dask "
                                       "scheduler's address (missing port number")
    assert not out.exists() and not fake


def test_cluster_without_the_extra_or_with_jobs_is_one_line_before_any_work(tmp_path, fake, capsys, monkeypatch):
    path, out = profile(tmp_path), tmp_path / "study"
    assert cli(["study", "--profile", str(path), "--out", str(out), "--cluster", "tcp://h:1", "--jobs", "2"]) == 2
    assert "option '--jobs': is for a study on this machine" in one_line(capsys)
    monkeypatch.setitem(sys.modules, "distributed", None)  # as where the extra is not installed
    assert cli(["study", "--profile", str(path), "--out", str(out), "--cluster", "tcp://h:1"]) == 3
    assert one_line(capsys) == ("neuralbrdf study: error: --cluster needs Dask's distributed package, which is not "
                                "installed: pip install 'neuralbrdf[cluster]'")
    assert not out.exists() and not fake


def _can_unshare() -> bool:
    try:
        return subprocess.run(["unshare", "--mount", "--propagation", "private", "true"],
                              capture_output=True).returncode == 0
    except OSError:
        return False


@needs_dask
@pytest.mark.skipif(not _can_unshare(), reason="needs a mount namespace (unshare --mount) to hide the study folder")
def test_workers_that_see_another_folder_at_the_studys_path_end_it_in_one_line(tmp_path, fake, capsys):
    """The workers run where a folder of their own hides the test's (a mount namespace with an empty
    folder at the study's path, as on a machine whose local disk has a folder of that name): the
    study ends with exit status 3 and one line, with no cell, study.json or report written."""
    path, out = profile(tmp_path), tmp_path / "study"
    hide = ("unshare", "--mount", "--propagation", "private", "sh", "-c",
            'mount -t tmpfs none "$1" && mkdir -p "$2" && shift 2 && exec "$@"', "sh", str(tmp_path), str(out))
    with dask_cluster(tmp_path / "cluster-elsewhere", wrap=hide) as address:
        assert cli(["study", "--profile", str(path), "--out", str(out), "--cluster", address, "--no-progress"]) == 3
    line = one_line(capsys)
    assert line.startswith("neuralbrdf study: error: the Dask worker tcp://127.0.0.1:") and line.endswith(
        f" does not see the study folder {out} at the path the submitting machine does; every worker must see "
        "the study folder and the profile's files at the same paths (docs/study.md, \"On a cluster\")"), line
    assert sorted(p.name for p in out.iterdir()) == [".neuralbrdf.lock", "truths"]
    with folder_lock(out, "study"):
        pass


# --------------------------------------------------------------------------- the quick profile, real cells


@pytest.mark.slow
@needs_dask
@pytest.mark.skipif(not (ROOT.parent / "shared" / "data" / "merl-nbrdf").is_dir(),
                    reason="../shared/data/merl-nbrdf is absent (the quick profile fits its nylon proxy)")
def test_the_quick_profile_on_a_two_worker_cluster_gives_the_results_of_jobs_2(tmp_path):
    """Every cell's metrics (its error, failure, per-angle errors and parameter count: all but the
    timings) are those of ``--jobs 2``; each run then reuses every cell of the other."""
    here, there = tmp_path / "here", tmp_path / "there"
    assert cli(["study", "--profile", "quick", "--out", str(here), "--jobs", "2", "--no-progress"]) == 0
    with dask_cluster(tmp_path / "cluster") as address:
        assert cli(["study", "--profile", "quick", "--out", str(there), "--cluster", address, "--no-progress"]) == 0
        assert cli(["study", "--profile", "quick", "--out", str(here), "--cluster", address, "--no-progress"]) == 0
    assert cli(["study", "--profile", "quick", "--out", str(there), "--no-progress"]) == 0

    def untimed(point: dict) -> dict:
        return {**point, "cost": point["cost"]["parameters"]}

    local, remote = (json.loads((out / "study.json").read_text()) for out in (here, there))
    assert len(local["points"]) == 22
    assert [untimed(p) for p in remote["points"]] == [untimed(p) for p in local["points"]]
    assert remote["run"]["history"][0]["cells_run"] == 22
    assert local["run"]["cells_run"] == remote["run"]["cells_run"] == 0
