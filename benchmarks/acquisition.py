"""Measuring a fraction of the pairs: designed plans against the report's, on materials the design never saw (docs/how-many-measurements.md).

    python benchmarks/acquisition.py [--groups rgl_validation,virtual_validation,rgl_real]
        [--plans DS4,design:6,design:12,DS3,design:24,DS2,DS1] [--design-noise X] [--design-normalise true|false]
        [--noise 0.01] [--work DIR] [--out benchmarks/acquisition_plans.json]

For every material of the chosen groups and every plan, the material is measured at the plan's
pairs (:class:`neuralbrdf.acquisition.truths.TruthMaterial`: the virtual instrument, or the
file's own reader, with relative noise ``--noise``), fitted by the spectral NLB (the fit of
``configs/nlb_spectral.yaml``, run in process: the codes ``neuralbrdf train fit`` reaches), and the
fit scored over the hemisphere against the material's truth (``hemisphere_logcos_rmse``, 102 400
pairs; an RGL measurement through Mitsuba's ``measured`` plugin), averaged over the noise
``--seeds`` (with few pairs, which start the fit ends in varies with the noise drawn).  ``design:N`` is the plan
``neuralbrdf plan design --budget N`` writes with the settings of
``configs/acquisition/default.yaml`` (or ``--design-*``).  Groups, all never seen by the design:

* ``rgl_validation`` — the RGL validation split (:data:`neuralbrdf.data.proxy_corpus.RGL_VALIDATION`),
  NBRDF proxies, RGB;
* ``virtual_validation`` — the virtual validation materials
  (:data:`neuralbrdf.virtual.materials.VALIDATION_MATERIALS`), spectral;
* ``rgl_real`` — the real RGL measurements of ``../shared/data/rgl-bsdf`` (their materials are
  among the pretraining proxies: a check on real data, not evidence about unseen materials).

Every cell (material × plan × settings) is kept in ``--work`` and reused.  Writes JSON and prints
per group and plan the median error, and per designed plan the median and geometric mean over
materials of its error over the report plan it is compared with (``design:6`` with DS4,
``design:12`` and ``design:24`` with DS3, ``design:48`` with DS2), and the same for ``random:N``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from neuralbrdf.acquisition.design import design_nlb_spectral  # noqa: E402
from neuralbrdf.acquisition.instrument import Instrument  # noqa: E402
from neuralbrdf.acquisition.latent_fit import fit_module, fit_table  # noqa: E402
from neuralbrdf.acquisition.settings import load_acquisition_config  # noqa: E402
from neuralbrdf.acquisition.truths import TruthMaterial  # noqa: E402
from neuralbrdf.atomic import atomic_write  # noqa: E402
from neuralbrdf.data.plans import Plan, in_plane_plan  # noqa: E402
from neuralbrdf.data.proxy_corpus import RGL_VALIDATION  # noqa: E402
from neuralbrdf.virtual.materials import VALIDATION_MATERIALS  # noqa: E402

SHARED = REPO.parent / "shared" / "data"
REAL_RGL = ("acrylic_felt_green", "aurora_white", "cc_green_malachite", "cc_iris_purple_gem", "chm_mint",
            "cm_military_green", "ilm_l3_37_matte", "ilm_solo_m_68", "irid_flake_paint1_fine", "vch_golden_yellow")
GROUPS = {
    "rgl_validation": lambda: [str(SHARED / "rgl-nbrdf" / f"{m}.h5") for m in RGL_VALIDATION],
    "virtual_validation": lambda: [f"virtual:{m}" for m in VALIDATION_MATERIALS],
    "rgl_real": lambda: [str(SHARED / "rgl-bsdf" / f"{m}_rgb.bsdf") for m in REAL_RGL],
}
#: The report plan a designed plan of each budget is compared with.
COMPARED = {6: "DS4", 12: "DS3", 24: "DS3", 48: "DS2"}


def digest(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def design_path(budget: int, design, cache: Path) -> Path:
    return cache / f"design_{budget}_{digest(vars(design))}.json"


def plan_pairs(name: str, design, cache: Path) -> tuple[np.ndarray, np.ndarray]:
    """The signed pairs of a report plan, of ``random:N`` (N of the instrument's pairs drawn
    uniformly, seed 0: the design's naive alternative) or of ``design:N`` (designed once per
    settings, kept)."""
    if name.startswith("random:"):
        theta_i, theta_r = Instrument().candidates()
        drawn = np.random.default_rng(0).choice(len(theta_i), int(name.split(":")[1]), replace=False)
        return theta_i[drawn], theta_r[drawn]
    if not name.startswith("design:"):
        return in_plane_plan(name)
    budget = int(name.split(":")[1])
    path = design_path(budget, design, cache)
    if not path.is_file():
        started = time.perf_counter()
        plan = design_nlb_spectral(budget, Instrument(), design)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"theta_i": plan.theta_i.tolist(), "theta_r": plan.theta_r.tolist(),
                                    "predicted_error": plan.predicted_error,
                                    "design_s": time.perf_counter() - started}))
    data = json.loads(path.read_text())
    return np.asarray(data["theta_i"]), np.asarray(data["theta_r"])


def score(source: str, plan: Plan, noise: float, seed: int, module) -> float:
    material = TruthMaterial(source)
    table = material.measure(plan, noise, seed=2 * seed)
    fitted = fit_table(table, material.name, module=module)
    return material.hemisphere_error(fitted.model(), fitted.node_wavelengths_nm is not None)


def run(groups: list[str], plans: list[str], design, noise: float, seeds: list[int], work: Path) -> dict:
    """Per group, material and plan the hemisphere error of the fit, the mean over the noise ``seeds``."""
    module = fit_module()
    fit_settings = (REPO / "configs" / "nlb_spectral.yaml").read_text()
    rows: dict = {}
    for group in groups:
        for source in GROUPS[group]():
            name = Path(source).stem if not source.startswith("virtual:") else source.split(":")[1]
            for plan in plans:
                ti, tr = plan_pairs(plan, design, work)
                values = []
                for seed in seeds:
                    cell = work / "cells" / f"{digest(source, ti.tolist(), tr.tolist(), noise, seed, fit_settings)}.json"
                    if not cell.is_file():
                        cell.parent.mkdir(parents=True, exist_ok=True)
                        value = score(source, Plan.of_pairs(ti, tr, plan), noise, seed, module)
                        cell.write_text(json.dumps({"hemisphere_logcos_rmse": value}))
                    values.append(json.loads(cell.read_text())["hemisphere_logcos_rmse"])
                rows.setdefault(group, {}).setdefault(name, {})[plan] = float(np.mean(values))
                print(f"{group} {name} {plan}: {rows[group][name][plan]:.4f}", flush=True)
    return rows


def summarise(rows: dict, plans: list[str]) -> dict:
    summary = {}
    pooled = {plan: [] for plan in plans}
    ratios: dict[str, list[float]] = {}
    for group, materials in [*rows.items(), ("all", None)]:
        values = {p: [m[p] for m in materials.values()] for p in plans} if materials else pooled
        if materials:
            for p in plans:
                pooled[p] += values[p]
        block = {"materials": len(next(iter(values.values()))), "median": {p: float(np.median(v)) for p, v in values.items()}}
        for p in plans:
            if p.startswith(("design:", "random:")) and COMPARED.get(int(p.split(":")[1])) in plans:
                ref = COMPARED[int(p.split(":")[1])]
                ratio = np.asarray(values[p]) / np.asarray(values[ref])
                block.setdefault("over_report_plan", {})[p] = {
                    "plan": ref, "median_ratio": float(np.median(ratio)),
                    "geometric_mean_ratio": float(np.exp(np.mean(np.log(ratio)))),
                    "better_on": float(np.mean(ratio < 1.0)),
                    "medians_ratio": float(np.median(values[p]) / np.median(values[ref]))}
        summary[group] = block
    return summary


def print_summary(summary: dict, plans: list[str]) -> None:
    print(f"\n{'group':<20}{'n':>4}" + "".join(f"{p:>11}" for p in plans))
    for group, block in summary.items():
        print(f"{group:<20}{block['materials']:>4}" + "".join(f"{block['median'][p]:>11.4f}" for p in plans))
    for group, block in summary.items():
        for p, r in block.get("over_report_plan", {}).items():
            print(f"  {group} {p} / {r['plan']}: medians {r['medians_ratio']:.3f}, per-material median "
                  f"{r['median_ratio']:.3f}, geometric mean {r['geometric_mean_ratio']:.3f}, better on "
                  f"{r['better_on']:.0%}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--groups", default="rgl_validation,virtual_validation")
    parser.add_argument("--plans", default="DS4,design:6,design:12,DS3,design:24")
    parser.add_argument("--noise", type=float, default=0.01, help="relative measurement noise")
    parser.add_argument("--seeds", default="0,1,2", help="noise seeds; a material's error is the mean over them")
    parser.add_argument("--design-noise", type=float, default=None)
    parser.add_argument("--design-normalise", choices=("true", "false"), default=None)
    parser.add_argument("--work", default=str(REPO / "runs" / "acquisition"))
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "acquisition_plans.json"))
    args = parser.parse_args(argv)
    design = load_acquisition_config().design
    from dataclasses import replace

    if args.design_noise is not None:
        design = replace(design, noise=args.design_noise)
    if args.design_normalise is not None:
        design = replace(design, normalise=args.design_normalise == "true")
    groups, plans = args.groups.split(","), args.plans.split(",")
    if not SHARED.is_dir():
        groups = [g for g in groups if g == "virtual_validation"]
    started, load_before = time.perf_counter(), os.getloadavg()
    seeds = [int(s) for s in args.seeds.split(",")]
    rows = run(groups, plans, design, args.noise, seeds, Path(args.work))
    summary = summarise(rows, plans)
    designs = {p: json.loads(design_path(int(p.split(":")[1]), design, Path(args.work)).read_text())
               for p in plans if p.startswith("design:")}
    result = {"machine": platform.platform(), "noise": args.noise, "seeds": seeds, "design": vars(design), "plans": plans,
              "designs": {p: {"pairs": [list(v) for v in zip(d["theta_i"], d["theta_r"])], "design_s": d["design_s"]}
                          for p, d in designs.items()},
              "load_average": {"before": load_before, "after": os.getloadavg()},
              "materials": rows, "summary": summary, "wall_time_s": time.perf_counter() - started}
    with atomic_write(args.out) as handle:
        handle.write(json.dumps(result, indent=2, sort_keys=True) + "\n")
    print_summary(summary, plans)
    print(f"\n-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
