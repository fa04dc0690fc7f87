"""Simulated measuring sessions on validation materials: does ``neuralbrdf acquire`` reach the DS3 fit's error within its budget, and does its interval hold the true error (docs/how-many-measurements.md)?

    python benchmarks/acquisition_sessions.py [--groups virtual_validation,rgl_validation]
        [--count 6] [--max 24] [--ds3 benchmarks/acquisition_calibration_validation.json] [--out ...]

For every material of the groups, a session (:func:`neuralbrdf.acquisition.session.run_session`)
starts from the config's start plan (the shipped six-pair design), asks ``plan next`` for
``--count`` pairs at each step and stops at ``--max`` pairs; each step's fit is scored over the
hemisphere against the truth (no renders).  Compared with the error of the same material's DS3 fit
(57 pairs, the same noise and seed) from ``acquisition_calibration_validation.json``
(``benchmarks/acquisition_calibration.py --split validation``, or ``--ds3`` the plans benchmark's file).  Writes
per material the steps (pairs, estimate, interval, true error), and in ``summary``: the share of
materials whose session reaches its DS3 error within the budget, the median over materials of the
last step's error over DS3's, and the share of steps whose 80 % interval holds the true error.
Every session is kept in ``--work`` and reused.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from acquisition import GROUPS, REPO, SHARED, digest  # noqa: E402

from neuralbrdf.acquisition.instrument import Instrument  # noqa: E402
from neuralbrdf.acquisition.session import run_session  # noqa: E402
from neuralbrdf.acquisition.settings import load_acquisition_config  # noqa: E402
from neuralbrdf.atomic import atomic_write  # noqa: E402


def session(source: str, config, count: int, max_pairs: int, work: Path) -> list[dict]:
    """The steps of one session: pairs, estimated log-cos (estimate, low, high), true log-cos."""
    settings = replace(config.session, count=count, max_pairs=max_pairs)
    path = work / "sessions" / f"{digest(source, vars(settings), vars(config.design), vars(config.estimate))}.json"
    if not path.is_file():
        result = run_session(source, settings, Instrument(), config.design, config.estimate, render=False)
        steps = [{"pairs": s.pairs, "estimated_logcos": s.estimated_logcos, "true_logcos": s.true_logcos}
                 for s in result.steps]
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(steps))
    return json.loads(path.read_text())


def ds3_of(path: Path) -> dict[str, float]:
    """Each material's DS3 hemisphere log-cos (same noise and seed as a session's measurements) from
    ``acquisition_calibration_validation.json`` or ``acquisition_plans.json``; empty without the file."""
    if not path.is_file():
        return {}
    data = json.loads(path.read_text())
    if "cells" in data:
        return {c["source"].removeprefix("virtual:"): c["logcos"] for c in data["cells"] if c["plan"] == "DS3"}
    return {name: plans["DS3"] for group in data["materials"].values() for name, plans in group.items()
            if "DS3" in plans}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--groups", default="virtual_validation,rgl_validation")
    parser.add_argument("--count", type=int, default=6, help="pairs asked for at each step")
    parser.add_argument("--max", type=int, default=24, dest="max_pairs", help="the budget of pairs")
    parser.add_argument("--ds3", default=str(REPO / "benchmarks" / "acquisition_calibration_validation.json"),
                        help="each material's DS3 error: the calibration check's result on the validation split "
                             "(or the plans benchmark's)")
    parser.add_argument("--work", default=str(REPO / "runs" / "acquisition"))
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "acquisition_sessions.json"))
    args = parser.parse_args(argv)
    config = load_acquisition_config()
    groups = args.groups.split(",") if SHARED.is_dir() else ["virtual_validation"]
    ds3_errors = ds3_of(Path(args.ds3))
    started, load_before = time.perf_counter(), os.getloadavg()
    rows: dict = {}
    for group in groups:
        for source in GROUPS[group]():
            name = Path(source).stem if not source.startswith("virtual:") else source.split(":")[1]
            steps = session(source, config, args.count, args.max_pairs, Path(args.work))
            ds3 = ds3_errors.get(name)
            rows.setdefault(group, {})[name] = {"steps": steps, "ds3": ds3}
            print(f"{group} {name}: " + ", ".join(f"{s['pairs']}: {s['true_logcos']:.4f}" for s in steps)
                  + (f"; DS3 {ds3:.4f}" if ds3 else ""), flush=True)
    materials = [m for g in rows.values() for m in g.values()]
    steps = [s for m in materials for s in m["steps"]]
    held = [s["estimated_logcos"]["low"] <= s["true_logcos"] <= s["estimated_logcos"]["high"] for s in steps]
    compared = [m for m in materials if m["ds3"]]
    summary = {
        "materials": len(materials), "steps": len(steps),
        "interval_holds_true": float(np.mean(held)),
        "interval_below_true": float(np.mean([s["true_logcos"] > s["estimated_logcos"]["high"] for s in steps])),
        "interval_above_true": float(np.mean([s["true_logcos"] < s["estimated_logcos"]["low"] for s in steps])),
    }
    if compared:
        summary.update({
            "compared_with_ds3": len(compared),
            "reach_ds3_within_budget": float(np.mean([min(s["true_logcos"] for s in m["steps"]) <= m["ds3"]
                                                      for m in compared])),
            "last_over_ds3_median": float(np.median([m["steps"][-1]["true_logcos"] / m["ds3"] for m in compared])),
            "start_over_ds3_median": float(np.median([m["steps"][0]["true_logcos"] / m["ds3"] for m in compared])),
        })
    result = {"machine": platform.platform(), "count": args.count, "max_pairs": args.max_pairs,
              "session": vars(config.session), "materials": rows, "summary": summary,
              "load_average": {"before": load_before, "after": os.getloadavg()},
              "wall_time_s": time.perf_counter() - started}
    with atomic_write(args.out) as handle:
        handle.write(json.dumps(result, indent=2, sort_keys=True) + "\n")
    print(json.dumps(summary, indent=2))
    print(f"-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
