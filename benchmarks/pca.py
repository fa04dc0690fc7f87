"""The PCA prior (docs/models.md#pca) against ABC and the spectral NLB, each fitted to the same
measurement of a validation material.

    python benchmarks/pca.py [--groups rgl_validation,virtual_validation] [--plans DS1,DS3,DS4]  # or plan files
        [--methods pca,abc,nlb_spectral] [--work runs/pca_bench] [--out benchmarks/pca.json]

For every material and plan: ``nb.fit`` of each method through its shipped config on the
material's measurement, exported (no fast paths, no RGB head) and scored by ``nb.evaluate(model,
truth, out, images=False)``: the hemisphere log-cos RMSE over 102 400 stratified pairs (spectral
models against a spectral truth at 31 wavelengths, else in linear sRGB).  Groups (validation
materials only; none is in the PCA basis or the spectral NLB's pretraining):

* ``rgl_validation`` — the nine RGL validation proxies (``RGL_VALIDATION``; RGB NBRDF networks),
  measured by ``nb.read(proxy, plan=PLAN)``;
* ``virtual_validation`` — the six virtual validation materials (``VALIDATION_MATERIALS``,
  spectral), measured by ``virtual_measurement(m, PLAN, 0.01, seed=0, reference_seed=1)``.

Cells (one material, plan and method) are kept in ``--work`` and reused.  Writes JSON and prints a
table: per group and plan, each method's median, PCA's median over each other method's, and the
share of materials where PCA is closer than each.  A fit that fails is listed, not scored.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import neuralbrdf as nb  # noqa: E402
from neuralbrdf.atomic import atomic_write  # noqa: E402
from auto import QUIET, materials, plan_label  # noqa: E402  (benchmarks/auto.py: the same groups)

METHODS = ("pca", "abc", "nlb_spectral")
GROUPS = ("rgl_validation", "virtual_validation")
PLANS = ("DS1", "DS3", "DS4")


def truth_file(name: str, truth: str, work: Path) -> Path:
    path = work / "truths" / f"{name}.onnx"
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        nb.truth(truth, path)
    return path


def cell(name: str, measurement: Path, truth: str, plan: str, method: str, work: Path) -> dict:
    """One method's score and fit time on one material and plan (kept in ``work`` and reused)."""
    done = work / "cells" / f"{name}_{plan_label(plan)}_{method}.json"
    if done.is_file():
        return json.loads(done.read_text())
    folder = work / "runs" / f"{name}_{plan_label(plan)}"
    source = nb.read(measurement, name=name) if measurement.suffix == ".csv" else nb.read(measurement, plan=plan,
                                                                                          name=name)
    truth_path = truth_file(name, truth, work)
    began = time.perf_counter()
    try:
        result = nb.fit(method, source, run_dir=folder / method, overwrite=True, overrides=QUIET)
    except nb.FitFailed as error:
        row = {"failed": str(error)}
    else:
        model = result.export(folder / f"{method}.onnx", fast=False, rgb_head=False)
        scores = nb.evaluate(model, truth_path, folder / f"{method}_eval", images=False)
        row = {"hemisphere_logcos_rmse": scores["hemisphere_logcos_rmse"],
               "fit_s": result.metrics.get("fit/wall_time_s"), "cell_s": time.perf_counter() - began,
               "spectral": model.is_spectral}
        if method == "pca":
            row["inplane_logcos_rmse"] = result.metrics["fit/pca/inplane_logcos_rmse"]
    done.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(done) as handle:
        handle.write(json.dumps(row, indent=2) + "\n")
    return row


def summary(rows: dict[str, dict], methods: tuple[str, ...]) -> dict:
    """Medians over the materials every method fitted; PCA against each other method."""
    fitted = {name: row for name, row in rows.items() if not any("failed" in row[m] for m in methods)}
    out = {"materials": len(rows), "fitted_by_all": len(fitted),
           "failed": {m: sorted(n for n, r in rows.items() if "failed" in r[m]) for m in methods}}
    if not fitted:
        return out
    value = {m: np.array([r[m]["hemisphere_logcos_rmse"] for r in fitted.values()]) for m in methods}
    out["median"] = {m: float(np.median(v)) for m, v in value.items()}
    out["mean"] = {m: float(np.mean(v)) for m, v in value.items()}
    if "pca" in methods:
        for other in (m for m in methods if m != "pca"):
            out[f"pca_median_over_{other}_median"] = out["median"]["pca"] / out["median"][other]
            out[f"pca_closer_than_{other}"] = float(np.mean(value["pca"] < value[other]))
    out["fit_s_median"] = {m: float(statistics.median(r[m]["fit_s"] for r in fitted.values())) for m in methods}
    return out


def print_table(results: dict) -> None:
    methods = tuple(results["methods"])
    for group, plans in results["groups"].items():
        for plan, block in plans.items():
            print(f"\n{group} ({plan}): hemisphere log-cos RMSE")
            print(f"{'material':<28}" + "".join(f"{m:>14}" for m in methods))
            for name, row in block["materials"].items():
                print(f"{name[:27]:<28}" + "".join(
                    f"{'failed':>14}" if "failed" in row[m] else f"{row[m]['hemisphere_logcos_rmse']:>14.4f}"
                    for m in methods))
            s = block["summary"]
            if "median" in s:
                print(f"{'median':<28}" + "".join(f"{s['median'][m]:>14.4f}" for m in methods)
                      + f"   (over {s['fitted_by_all']} of {s['materials']})")
                print("  " + "; ".join(f"PCA closer than {m} on {s[f'pca_closer_than_{m}']:.0%}, median ratio "
                                       f"{s[f'pca_median_over_{m}_median']:.2f}" for m in methods if m != "pca"
                                       and f"pca_closer_than_{m}" in s)
                      + "; fit s (median): " + ", ".join(f"{m} {v:.2f}" for m, v in s["fit_s_median"].items()))
            failed = {m: v for m, v in s["failed"].items() if v}
            if failed:
                print(f"  failed: {failed}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--groups", default=",".join(GROUPS))
    parser.add_argument("--plans", default=",".join(PLANS))
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--work", default=str(REPO / "runs" / "pca_bench"))
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "pca.json"))
    args = parser.parse_args(argv)
    groups = [g for g in args.groups.split(",") if g]
    plans = [p for p in args.plans.split(",") if p]
    methods = tuple(m for m in args.methods.split(",") if m)
    for given, valid, what in ((groups, GROUPS, "group"), (methods, METHODS, "method")):
        unknown = [g for g in given if g not in valid]
        if unknown:
            parser.error(f"unknown {what} {unknown[0]!r}; expected some of {', '.join(valid)}")
    work = Path(args.work)
    began = time.time()
    results = {"command": "python benchmarks/" + Path(__file__).name + " " + " ".join(argv or sys.argv[1:]),
               "methods": list(methods), "machine": {"cores": 2, "python": platform.python_version()}, "groups": {}}
    for group in groups:
        results["groups"][group] = {}
        for plan in plans:
            rows = {}
            for name, measurement, truth in materials(group, plan, work):
                print(f"[{group} {plan}] {name} ...", flush=True)
                rows[name] = {m: cell(name, Path(measurement), truth, plan, m, work) for m in methods}
            results["groups"][group][plan_label(plan)] = {"materials": rows, "summary": summary(rows, methods)}
    results["wall_s"] = time.time() - began
    with atomic_write(Path(args.out)) as handle:
        handle.write(json.dumps(results, indent=1) + "\n")
    print_table(results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
