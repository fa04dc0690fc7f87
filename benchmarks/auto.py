"""The ``auto`` fit against ABC and the spectral NLB, each fitted to the same measurement
(docs/models.md#auto, docs/design.md "Never worse than ABC").

    python benchmarks/auto.py [--groups virtual_validation,rgl_validation,rgl_real,merl_held_out]
        [--plan DS1] [--render-groups virtual_validation,rgl_validation] [--work runs/auto_bench]
        [--out benchmarks/auto.json]

For every material: ``nb.fit`` of ``abc``, ``nlb_spectral`` and ``auto`` (their shipped configs)
on the material's measurement on ``--plan``, each exported (no fast paths) and scored by
``neuralbrdf evaluate`` against the material's truth: the hemisphere log-cos RMSE (102 400 pairs)
and, for the ``--render-groups``, the image ΔE2000 mean of the material-preview scene (128 px,
64 spp, matched seeds; the truth-against-truth noise stated).  Groups:

* ``virtual_validation`` — the six virtual validation materials (spectral, the virtual instrument
  with 1 % noise, seed 0);
* ``rgl_validation`` — the nine RGL validation proxies (RGB NBRDF networks, never pretrained on);
* ``rgl_real`` — the ten real RGL ``.bsdf`` measurements in ``../shared/data/rgl-bsdf`` (truth:
  Mitsuba's ``measured`` plugin; the materials are among the pretraining proxies: validation on
  real data, not evidence on unseen materials);
* ``merl_held_out`` — the ten MERL materials held out of pretraining: a test set, never used to
  choose the rule (reported, not tuned on).

The rule was chosen on the first three groups (docs/design.md).  Fit times are ``fit/wall_time_s``
(the fit proper).  Cells are kept in ``--work`` and reused while the three configs are unchanged.  Writes JSON and prints a table: per
group, the medians, the share of materials where auto is within 1.02x ABC, strictly closer than ABC,
and auto's median over the spectral NLB's.
"""

from __future__ import annotations

import argparse
import hashlib
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
from neuralbrdf.data.proxy_corpus import HELD_OUT, RGL_VALIDATION  # noqa: E402
from neuralbrdf.data.table import write_table  # noqa: E402
from neuralbrdf.sources import virtual_measurement  # noqa: E402
from neuralbrdf.virtual.materials import VALIDATION_MATERIALS  # noqa: E402

SHARED = REPO.parent / "shared" / "data"
METHODS = ("abc", "nlb_spectral", "auto")
GROUPS = ("virtual_validation", "rgl_validation", "rgl_real", "merl_held_out")
QUIET = {"trainer.enable_progress_bar": False, "data.eval_plan": None}


def plan_label(plan: str) -> str:
    """A plan's name in file names: a report plan's name, a plan file's stem (``configs/plans/pca_6.csv``: ``pca_6``)."""
    return Path(plan).stem if plan.endswith(".csv") else plan


def materials(group: str, plan: str, work: Path) -> list[tuple[str, str, str]]:
    """``(name, measurement, truth)`` of each material of ``group``; ``plan`` (a name or a plan file)
    is the plan the virtual materials are measured on (the others are sampled on it when read)."""
    if group == "rgl_validation":
        return [(m,) + (str(SHARED / "rgl-nbrdf" / f"{m}.h5"),) * 2 for m in RGL_VALIDATION]
    if group == "merl_held_out":
        return [(m,) + (str(SHARED / "merl-nbrdf" / f"{m}.h5"),) * 2 for m in HELD_OUT]
    if group == "rgl_real":
        return [(p.stem, str(p), str(p)) for p in sorted((SHARED / "rgl-bsdf").glob("*.bsdf"))]
    found = []
    for m in VALIDATION_MATERIALS:
        path = work / "tables" / f"{m}_{plan_label(plan)}.csv"
        if not path.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            write_table(virtual_measurement(m, plan, 0.01, seed=0, reference_seed=1), path)
        found.append((m, str(path), f"virtual:{m}"))
    return found


def cell(name: str, measurement: str, truth: str, plan: str, render: bool, work: Path) -> dict:
    """Every method's scores and fit time on one material (kept in ``work`` and reused)."""
    configs = hashlib.sha256("".join((REPO / "configs" / f"{m}.yaml").read_text() for m in METHODS).encode())
    done = work / "cells" / f"{name}_{plan}{'_render' if render else ''}_{configs.hexdigest()[:12]}.json"
    if done.is_file():
        return json.loads(done.read_text())
    folder = work / "runs" / f"{name}_{plan}"
    source = nb.read(measurement, name=name) if measurement.endswith(".csv") else nb.read(measurement, plan=plan,
                                                                                          name=name)
    if truth.endswith(".bsdf"):
        truth_file = truth
    else:
        truth_file = work / "truths" / f"{name}.onnx"
        if not truth_file.is_file():
            truth_file.parent.mkdir(parents=True, exist_ok=True)
            nb.truth(truth, truth_file)
    row = {}
    for method in METHODS:
        try:
            result = nb.fit(method, source, run_dir=folder / method, overwrite=True, overrides=QUIET)
        except nb.FitFailed as error:
            row[method] = {"failed": str(error)}
            continue
        model = result.export(folder / f"{method}.onnx", fast=False, rgb_head=False)
        scores = nb.evaluate(model, truth_file, folder / f"{method}_eval", spp=64, resolution=128, images=render)
        row[method] = {"hemisphere_logcos_rmse": scores["hemisphere_logcos_rmse"],
                       "image_delta_e2000_mean": scores.get("image_delta_e2000_mean"),
                       "image_noise_delta_e2000_mean": (scores.get("noise") or {}).get("image_delta_e2000_mean"),
                       "fit_s": result.metrics.get("fit/wall_time_s")}
        if method == "auto":
            row[method] |= {"choice": result.metrics["fit/auto/choice"],
                            "inplane_logcos_rmse": result.metrics["fit/auto/inplane_logcos_rmse"],
                            "candidate_fit_s": result.metrics["fit/auto/fit_s"]}
    done.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(done) as handle:
        handle.write(json.dumps(row, indent=2) + "\n")
    return row


def summary(rows: dict[str, dict]) -> dict:
    """Medians, auto against ABC (within 1.02x, strictly closer) and against the spectral NLB."""
    fitted = {name: row for name, row in rows.items() if not any("failed" in row[m] for m in METHODS)}
    out = {"materials": len(rows), "fitted_by_all": len(fitted),
           "failed": {m: sorted(n for n, r in rows.items() if "failed" in r[m]) for m in METHODS}}
    for metric in ("hemisphere_logcos_rmse", "image_delta_e2000_mean"):
        if not fitted or any(r[m].get(metric) is None for r in fitted.values() for m in METHODS):
            continue
        value = {m: np.array([r[m][metric] for r in fitted.values()]) for m in METHODS}
        ratio = value["auto"] / value["abc"]
        out[metric] = {
            "median": {m: float(np.median(v)) for m, v in value.items()},
            "auto_within_1.02_abc": float(np.mean(ratio <= 1.02)),
            "auto_closer_than_abc": float(np.mean(ratio < 1.0)),
            "auto_over_abc_max": float(ratio.max()),
            "auto_median_over_nlb_spectral_median": float(np.median(value["auto"]) / np.median(value["nlb_spectral"])),
        }
    times = {m: [r[m]["fit_s"] for r in fitted.values() if r[m].get("fit_s")] for m in METHODS}
    if all(times.values()):
        out["fit_s_median"] = {m: float(statistics.median(t)) for m, t in times.items()}
        out["auto_fit_over_nlb_spectral"] = out["fit_s_median"]["auto"] / out["fit_s_median"]["nlb_spectral"]
    out["choices"] = {c: sum(r["auto"].get("choice") == c for r in fitted.values()) for c in ("abc", "nlb_spectral")}
    return out


def print_table(results: dict) -> None:
    for group, block in results["groups"].items():
        print(f"\n{group} ({results['plan']}): hemisphere log-cos RMSE (image ΔE2000 mean)")
        print(f"{'material':<28}" + "".join(f"{m:>22}" for m in METHODS) + "  choice")
        for name, row in block["materials"].items():
            cells = []
            for m in METHODS:
                r = row[m]
                if "failed" in r:
                    cells.append(f"{'failed':>22}")
                    continue
                image = r.get("image_delta_e2000_mean")
                cells.append(f"{r['hemisphere_logcos_rmse']:>13.4f}" + (f" ({image:5.2f})" if image is not None else " " * 8))
            print(f"{name[:27]:<28}" + "".join(cells) + f"  {row['auto'].get('choice', '-')}")
        s = block["summary"]
        for metric in ("hemisphere_logcos_rmse", "image_delta_e2000_mean"):
            if metric in s:
                m = s[metric]
                print(f"  {metric}: medians " + ", ".join(f"{k} {v:.4g}" for k, v in m["median"].items())
                      + f"; auto within 1.02x ABC on {m['auto_within_1.02_abc']:.0%}, closer on "
                      f"{m['auto_closer_than_abc']:.0%}, worst {m['auto_over_abc_max']:.2f}x ABC; auto median / "
                      f"NLB median {m['auto_median_over_nlb_spectral_median']:.3f}")
        if "fit_s_median" in s:
            print("  fit s (median): " + ", ".join(f"{k} {v:.2f}" for k, v in s["fit_s_median"].items())
                  + f"; auto / nlb_spectral {s['auto_fit_over_nlb_spectral']:.2f}")
        print(f"  choices: {s['choices']}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--groups", default=",".join(GROUPS))
    parser.add_argument("--plan", default="DS1")
    parser.add_argument("--render-groups", default="virtual_validation,rgl_validation")
    parser.add_argument("--work", default=str(REPO / "runs" / "auto_bench"))
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "auto.json"))
    args = parser.parse_args(argv)
    groups = [g for g in args.groups.split(",") if g]
    unknown = [g for g in groups if g not in GROUPS]
    if unknown:
        parser.error(f"unknown group {unknown[0]!r}; expected some of {', '.join(GROUPS)}")
    work = Path(args.work)
    began = time.time()
    results = {"command": "python benchmarks/" + Path(__file__).name + " " + " ".join(argv or sys.argv[1:]),
               "plan": args.plan, "machine": {"cores": 2, "python": platform.python_version()}, "groups": {}}
    for group in groups:
        render = group in args.render_groups.split(",")
        rows = {}
        for name, measurement, truth in materials(group, args.plan, work):
            print(f"[{group}] {name} ...", flush=True)
            rows[name] = cell(name, measurement, truth, args.plan, render, work)
        results["groups"][group] = {"rendered": render, "materials": rows, "summary": summary(rows)}
    results["wall_s"] = time.time() - began
    with atomic_write(Path(args.out)) as handle:
        handle.write(json.dumps(results, indent=1) + "\n")
    print_table(results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
