"""A study on a Dask cluster against the same study on this machine: the wall time of a profile's
cells on a two-worker local cluster (docs/study.md, "On a cluster") beside ``--jobs 2``.

    python benchmarks/study_cluster.py [--profile quick] [--repeats 2] [--work out/study_cluster]
        [--out benchmarks/study_cluster.json]

Each repeat runs ``neuralbrdf study --profile P`` twice from an empty cache, each as a command of
its own: with ``--jobs 2``, and with ``--cluster ADDRESS`` on a scheduler and two one-thread
workers started for it on this machine (``distributed.LocalCluster``; started, and ready, before
the command, as a cluster is there before a user submits to it, and closed after it, so that
every cluster run starts its cell workers cold, as ``--jobs 2`` does).  The two runs of a repeat
take turns at going first, so that a change of load from elsewhere hits both alike.  Reported:
each run's wall time (the command's, from start to exit) and its study's (``study.json``'s
``run.wall_time_s``), the cluster's start-up apart, the ratio cluster ÷ ``--jobs 2`` of the
commands' wall times per repeat and its median against the target (:data:`TARGET`), whether every
cell's metrics agree (timings aside), and the load average before and after.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from neuralbrdf.atomic import atomic_write  # noqa: E402
from neuralbrdf.study.cost import machine  # noqa: E402

#: Cluster ÷ ``--jobs 2`` wall time the cluster should stay within: scheduling costs little beside a cell.
TARGET = 1.15


def study(profile: str, out: Path, *where: str) -> dict:
    """Run ``neuralbrdf study`` as a command; its wall time and ``study.json``."""
    shutil.rmtree(out, ignore_errors=True)
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "neuralbrdf", "study", "--profile", profile, "--out", str(out),
                    "--no-progress", *where], check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - started
    return {"wall_s": wall, "study": json.loads((out / "study.json").read_text(encoding="utf-8"))}


def on_cluster(profile: str, out: Path) -> dict:
    """:func:`study` on a two-worker local cluster started for it (module docstring)."""
    from distributed import Client, LocalCluster

    started = time.perf_counter()
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        client.wait_for_workers(2)
        start_s = time.perf_counter() - started
        run = study(profile, out, "--cluster", cluster.scheduler_address)
    return {**run, "cluster_start_s": start_s}


def untimed(points: list[dict]) -> list[dict]:
    """The points without what a run's timing changes (render ratio, throughput, fit time)."""
    return [{**p, "cost": p["cost"]["parameters"]} for p in points]


def summary(run: dict) -> dict:
    study_run = run["study"]["run"]
    return {"wall_s": run["wall_s"], "study_wall_s": study_run["wall_time_s"], "cells_run": study_run["cells_run"],
            "cells_cpu_s": study_run["cells_cpu_time_s"],
            **({"cluster_start_s": run["cluster_start_s"]} if "cluster_start_s" in run else {})}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--profile", default="quick", help="study profile (default quick)")
    parser.add_argument("--repeats", type=int, default=2, help="pairs of runs (default 2)")
    parser.add_argument("--work", default=str(REPO / "out" / "study_cluster"), help="the studies' folders")
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "study_cluster.json"))
    args = parser.parse_args(argv)
    work = Path(args.work)
    load_before = os.getloadavg()
    started = time.perf_counter()
    repeats, same = [], True
    for repeat in range(args.repeats):
        order = ("jobs", "cluster") if repeat % 2 == 0 else ("cluster", "jobs")
        runs = {}
        for where in order:
            out = work / f"{where}{repeat}"
            runs[where] = on_cluster(args.profile, out) if where == "cluster" else study(args.profile, out, "--jobs", "2")
        same = same and untimed(runs["cluster"]["study"]["points"]) == untimed(runs["jobs"]["study"]["points"])
        repeats.append({"first": order[0], "jobs_2": summary(runs["jobs"]), "cluster": summary(runs["cluster"]),
                        "ratio": runs["cluster"]["wall_s"] / runs["jobs"]["wall_s"]})
    ratio = statistics.median(r["ratio"] for r in repeats)
    output = {
        "command": "python benchmarks/study_cluster.py" + (f" --profile {args.profile}" if args.profile != "quick" else "")
                   + (f" --repeats {args.repeats}" if args.repeats != 2 else ""),
        "profile": args.profile,
        "cells": len(runs["jobs"]["study"]["points"]),
        "machine": machine(),
        "load_average": {"before": load_before, "after": os.getloadavg()},
        "repeats": repeats,
        "ratio_median": ratio,
        "target": TARGET,
        "same_metrics": same,
        "wall_time_s": time.perf_counter() - started,
    }
    with atomic_write(Path(args.out)) as handle:
        handle.write(json.dumps(output, indent=2) + "\n")
    print(f"{'repeat':<8}{'first':<9}{'--jobs 2 s':>12}{'cluster s':>11}{'ratio':>8}{'cluster start s':>17}")
    for number, r in enumerate(repeats):
        print(f"{number:<8}{r['first']:<9}{r['jobs_2']['wall_s']:>12.1f}{r['cluster']['wall_s']:>11.1f}"
              f"{r['ratio']:>8.3f}{r['cluster']['cluster_start_s']:>17.1f}")
    print(f"median ratio {ratio:.3f} (target <= {TARGET}); every cell's metrics the same: {same}; "
          f"load average before {load_before[0]:.2f}, after {output['load_average']['after'][0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
