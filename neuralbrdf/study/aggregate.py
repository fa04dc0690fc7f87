"""From cell results to the study's evidence: points, Pareto fronts, failures, budgets (docs/study.md).

* **Points** — one per cell: ``material, model, method, plan, pairs`` (the number of direction
  pairs its plan measures), ``noise, seed``, ``cost`` (the render
  ratio against ``roughconductor``, M queries/s of the fastest backend and the parameter count
  of the variant's main cell — speed does not depend on the weights — and the cell's own fit
  wall time) and ``error`` (the metrics of :mod:`neuralbrdf.evaluation`), ``failure``; a rendered
  main cell also ``per_angle`` (the glossy relative RMSE per incident angle and per angle ×
  channel, :func:`neuralbrdf.study.cell.per_angle`), so that every figure can be drawn again from
  ``study.json`` alone; a cell of method ``auto`` also ``auto`` (which candidate its fit kept, each
  candidate's in-plane error, why ABC was none: :data:`neuralbrdf.study.cell.AUTO_RESULT_KEYS`).
* **Error threshold** — a cell that ran but whose ``hemisphere_logcos_rmse`` exceeds
  :data:`THRESHOLD_FACTOR` × the median of the same (material, model) at DS1 without noise gets
  the cause ``error_above_2x_ds1``.
* **Pareto fronts** — among main cells without failure, the models no other beats on both
  render ratio and ``image_delta_e2000_mean`` (and on both fit time and ΔE), per material; pooled
  on each model's median render ratio and median ΔE over the materials *every* model has a point
  on (a model fitted to fewer materials, e.g. the spectral MLP without the RGB MERL proxies, would
  otherwise be compared on easier or harder ones).
* **Budgets** — per material and ΔE budget, the model of lowest render ratio within it.
* **Pair curves** — per sweep model, its error against the number of measured pairs: per plan
  without noise the median over materials of each material's median over seeds, and the
  quartiles over materials; DS1..DS4 and plan files (designed plans) as two curves, as two plans
  with one number of pairs (DS4 and a designed 6-pair plan) are what the curve compares.
* **Groups** — per group of variants (γ and angle unit, latent size), each member's median
  :data:`THRESHOLD_METRIC` over seeds per material (DS1, no noise), on the materials every member
  fits.
"""

from __future__ import annotations

import statistics
from collections import Counter, defaultdict

import numpy as np

from neuralbrdf.data.plans import PLAN_NAMES, in_plane_plan

THRESHOLD_FACTOR = 2.0
THRESHOLD_METRIC = "hemisphere_logcos_rmse"
#: The failure cause of a cell above the threshold: a fit that gave a model, measured as broken.
THRESHOLD_CAUSE = "error_above_2x_ds1"
ACCURACY_METRIC = "image_delta_e2000_mean"
BUDGETS_DELTA_E = (1.0, 2.0, 5.0, 10.0)
#: Every failure cause a point can carry (:mod:`neuralbrdf.study.cell`, :func:`points_from_results`).
CAUSES = ("non_finite_loss", "optimizer_failure", "fit_refused", "error_above_2x_ds1", "export_refused",
          "evaluation_error", "cell_crashed")
COST_FROM_MAIN = ("render_ratio", "mqueries_per_s", "parameters", "fastest_backend")
#: The number of direction pairs of each named in-plane plan.
NAMED_PAIRS = {name: len(in_plane_plan(name)[0]) for name in ("DS1", "DS2", "DS3", "DS4")}
#: The number of direction pairs of DS1, the plan of the reference condition.
DS1_PAIRS = NAMED_PAIRS["DS1"]


def pairs_of(point: dict) -> int:
    """The number of direction pairs of a point's plan (a study.json written before points recorded
    it has only DS1..DS4, whose numbers are :data:`NAMED_PAIRS`)."""
    return point["pairs"] if "pairs" in point else NAMED_PAIRS[point["plan"]]


def distinct_fits(points: list[dict]) -> list[dict]:
    """``points`` without those that repeat another seed's result exactly (same material, model,
    plan, noise, errors and failure): a deterministic fit run at several seeds is one fit, and a
    spread over its copies would claim a stability nobody measured."""
    seen, kept = set(), []
    for p in points:
        identity = (p["material"], p["model"], p["plan"], p["noise"], p.get("failure"),
                    tuple(sorted((k, v) for k, v in p["error"].items() if not isinstance(v, (list, dict)))))
        if identity not in seen:
            seen.add(identity)
            kept.append(p)
    return kept


def points_from_results(results: list[dict], methods: dict[str, str], pairs: dict[str, int]) -> list[dict]:
    """The points of module docstring (threshold failures included), in cell order; ``pairs``: the
    number of direction pairs of each plan."""
    main_cost = {(r["material"], r["variant"]): r.get("cost", {}) for r in results if r.get("is_main")}
    points = []
    for r in results:
        own = r.get("cost", {})
        shared = main_cost.get((r["material"], r["variant"]), {})
        cost = {key: shared.get(key) for key in COST_FROM_MAIN}
        cost["fit_time_s"] = own.get("fit_time_s")
        points.append({
            "material": r["material"], "model": r["variant"], "method": methods[r["variant"]], "plan": r["plan"],
            "pairs": pairs[r["plan"]], "noise": r["noise"], "seed": r["seed"], "is_main": bool(r.get("is_main")), "cost": cost,
            "error": r.get("error") or {}, "failure": r.get("failure"), "message": r.get("message"),
            "key": r.get("key"), **({"per_angle": r["per_angle"]} if r.get("per_angle") else {}),
            **({"auto": r["auto"]} if r.get("auto") else {}),
        })
    reference: dict[tuple[str, str], list[float]] = defaultdict(list)
    for p in points:
        value = p["error"].get(THRESHOLD_METRIC)
        if p["plan"] == "DS1" and p["noise"] == 0.0 and p["failure"] is None and value is not None:
            reference[(p["material"], p["model"])].append(value)
    for p in points:
        values = reference.get((p["material"], p["model"]))
        value = p["error"].get(THRESHOLD_METRIC)
        if p["failure"] is None and values and value is not None and value > THRESHOLD_FACTOR * statistics.median(values):
            p["failure"] = THRESHOLD_CAUSE
            p["message"] = (f"{THRESHOLD_METRIC} {value:.4g} > {THRESHOLD_FACTOR:g} x DS1 noise-free "
                            f"{statistics.median(values):.4g}")
    return points


def pareto_front(items: list[tuple[str, float, float]]) -> list[str]:
    """Names of the items ``(name, cost, error)`` no other item beats on both (ties kept), by cost."""
    front = []
    for name, cost, error in items:
        dominated = any(c <= cost and e <= error and (c < cost or e < error) for _, c, e in items)
        if not dominated:
            front.append((cost, name))
    return [name for _, name in sorted(front)]


def _usable(p: dict, cost_key: str) -> bool:
    return (p["is_main"] and p["failure"] is None and p["cost"].get(cost_key) is not None
            and p["error"].get(ACCURACY_METRIC) is not None)


def shared_materials(points: list[dict], models) -> set[str]:
    """The materials on which every one of ``models`` has a point (none for no models)."""
    return set.intersection(*({p["material"] for p in points if p["model"] == m} for m in models)) if models else set()


def pooled_points(points: list[dict], cost_key: str) -> list[dict]:
    """Per model: median cost and median ΔE over the materials on which every model's main cell
    succeeded (module docstring); none when no material is shared by all."""
    usable = [p for p in points if _usable(p, cost_key)]
    shared = shared_materials(usable, dict.fromkeys(p["model"] for p in usable))
    by_model: dict[str, list[dict]] = defaultdict(list)
    for p in usable:
        if p["material"] in shared:
            by_model[p["model"]].append(p)
    return [{"model": model, "method": ps[0]["method"], "materials": [p["material"] for p in ps],
             cost_key: statistics.median(p["cost"][cost_key] for p in ps),
             ACCURACY_METRIC: statistics.median(p["error"][ACCURACY_METRIC] for p in ps)}
            for model, ps in by_model.items()]


def pareto(points: list[dict]) -> dict:
    """Pareto fronts per material and pooled, for render ratio and for fit time (module docstring)."""
    result = {}
    for cost_key in ("render_ratio", "fit_time_s"):
        per_material = {}
        for material in dict.fromkeys(p["material"] for p in points):
            items = [(p["model"], p["cost"][cost_key], p["error"][ACCURACY_METRIC]) for p in points
                     if p["material"] == material and _usable(p, cost_key)]
            per_material[material] = pareto_front(items)
        pooled = pooled_points(points, cost_key)
        result[cost_key] = {
            "per_material": per_material,
            "pooled": pareto_front([(q["model"], q[cost_key], q[ACCURACY_METRIC]) for q in pooled]),
            "pooled_points": pooled,
        }
    return result


def failures(points: list[dict]) -> list[dict]:
    """Per (model, condition): its plan's number of pairs, cells, failures and counts by cause, and the seed-to-seed spread of
    :data:`THRESHOLD_METRIC` (median and sample standard deviation over the cells with a value)."""
    cells: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for p in points:
        condition = p["plan"] + (f" {p['noise'] * 100:g}% noise" if p["noise"] else "")
        cells[(p["model"], condition)].append(p)
    rows = []
    for (model, condition), ps in cells.items():
        counts = Counter(p["failure"] for p in ps if p["failure"])
        values = [p["error"][THRESHOLD_METRIC] for p in ps if p["error"].get(THRESHOLD_METRIC) is not None]
        rows.append({"model": model, "method": ps[0]["method"], "condition": condition, "pairs": ps[0]["pairs"],
                     "cells": len(ps),
                     "failed": sum(counts.values()), "causes": dict(counts),
                     "materials": sorted({p["material"] for p in ps}),
                     "median_error": statistics.median(values) if values else None,
                     "seed_std_error": statistics.stdev(values) if len(values) > 1 else None})
    return rows


#: The metrics of the pair curves: the hemisphere error and the image error.
CURVE_METRICS = (THRESHOLD_METRIC, ACCURACY_METRIC)
#: The two curves of a model: the report's plans, and plan files.
CURVE_FAMILIES = {"named": "DS1–DS4", "files": "plan files"}


def pair_curves(points: list[dict], metric: str) -> list[dict]:
    """The pair curves of ``metric`` (module docstring): per model and family (:data:`CURVE_FAMILIES`)
    with values at two numbers of pairs at least in all, ``{model, method, family, rows}``, each row
    ``{pairs, plans, materials, median, q1, q3}`` in order of pairs; models in order of the points."""
    runs = [p for p in distinct_fits(points) if p["noise"] == 0.0 and p["error"].get(metric) is not None]
    counts = {model: {pairs_of(p) for p in runs if p["model"] == model} for model in dict.fromkeys(p["model"] for p in runs)}
    curves = []
    for model in (m for m, n in counts.items() if len(n) > 1):
        for family in CURVE_FAMILIES:
            mine = [p for p in runs if p["model"] == model and (p["plan"] in PLAN_NAMES) == (family == "named")]
            rows = []
            for pairs in sorted({pairs_of(p) for p in mine}):
                at = [p for p in mine if pairs_of(p) == pairs]
                per_material = [statistics.median(p["error"][metric] for p in at if p["material"] == m)
                                for m in dict.fromkeys(p["material"] for p in at)]
                q1, median, q3 = (np.quantile(per_material, (0.25, 0.5, 0.75)).tolist())
                rows.append({"pairs": pairs, "plans": list(dict.fromkeys(p["plan"] for p in at)),
                             "materials": len(per_material), "median": median, "q1": q1, "q3": q3})
            if rows:
                curves.append({"model": model, "method": mine[0]["method"], "family": family, "rows": rows})
    return curves


def groups(points: list[dict], members: dict[str, list[tuple[str, str]]], material_order: list[str]) -> list[dict]:
    """Per group (``members``: group name → ``(label, model)`` pairs): the materials every member has
    a DS1 noise-free point on (in ``material_order``), and per member the median :data:`THRESHOLD_METRIC` over seeds per
    material (``per_material``, in the order of ``materials``), the median of those medians
    (``median``) and the number of distinct fits with a value (:func:`distinct_fits`)."""
    tables = []
    runs = [p for p in distinct_fits(points)
            if p["plan"] == "DS1" and p["noise"] == 0.0 and p["error"].get(THRESHOLD_METRIC) is not None]
    for group, pairs in members.items():
        shared = shared_materials(runs, [model for _, model in pairs])
        materials = [m for m in material_order if m in shared]
        rows = []
        for label, model in pairs:
            per_material = [{"material": m, "median": statistics.median(
                p["error"][THRESHOLD_METRIC] for p in runs if p["model"] == model and p["material"] == m)}
                for m in materials]
            rows.append({"label": label, "model": model, "per_material": per_material,
                         "median": statistics.median(v["median"] for v in per_material) if materials else None,
                         "cells": sum(p["model"] == model and p["material"] in materials for p in runs)})
        tables.append({"group": group, "materials": materials, "members": rows})
    return tables


def budgets(points: list[dict]) -> list[dict]:
    """Per material and ΔE budget, the main-cell model of least render ratio within it."""
    rows = []
    for material in dict.fromkeys(p["material"] for p in points):
        usable = [p for p in points if p["material"] == material and _usable(p, "render_ratio")]
        for budget in BUDGETS_DELTA_E:
            within = [p for p in usable if p["error"][ACCURACY_METRIC] <= budget]
            best = min(within, key=lambda p: p["cost"]["render_ratio"]) if within else None
            rows.append({"material": material, "budget_delta_e": budget, "model": best and best["model"],
                         "render_ratio": best and best["cost"]["render_ratio"],
                         ACCURACY_METRIC: best and best["error"][ACCURACY_METRIC]})
    return rows


#: What each failure cause means for the fit.
CAUSE_MEANING = {"non_finite_loss": "training diverged", "optimizer_failure": "the optimiser gave up",
                 "fit_refused": "the fit refused its data", "error_above_2x_ds1": "this seed's fit is far from the others'",
                 "export_refused": "the exported graph failed its check", "evaluation_error": "evaluation failed",
                 "cell_crashed": "the cell crashed"}


def _meaning(cause: str, condition: str) -> str:
    """:data:`CAUSE_MEANING`, for an error above the threshold said by what the condition changed
    (fewer samples, noise); at DS1 without noise (a seed far from the others) the general meaning."""
    plan, _, noise = condition.partition(" ")
    reasons = [] if cause != "error_above_2x_ds1" else (
        ([] if plan == "DS1" else ["too few samples pin down too little of the lobe"])
        + (["the fit follows the noise"] if noise else []))
    return " and ".join(reasons) or CAUSE_MEANING[cause]


def condition_change(condition: str, pairs: int) -> str:
    """What a condition (``DS4``, ``DS1 10% noise``) whose plan measures ``pairs`` direction pairs
    takes from a fit, against DS1 without noise."""
    plan, _, noise = condition.partition(" ")
    changes = []
    if plan != "DS1":
        changes.append(f"{pairs} in-plane pairs instead of DS1's {DS1_PAIRS}")
    if noise:
        changes.append(f"{noise.removesuffix(' noise')} relative noise on every sample")
    return " and ".join(changes) or "the reference condition"


def auto_choices(points: list[dict], model: str) -> str:
    """For a model of method ``auto``: which candidate its fits kept, e.g. ``" Its fit kept abc in 3
    and nlb_spectral in 5 of 8 fitted cells."``; empty for other models."""
    kept = Counter(p["auto"]["choice"] for p in points if p["model"] == model and (p.get("auto") or {}).get("choice"))
    if not kept:
        return ""
    listed = " and ".join(f"{choice} in {n}" for choice, n in sorted(kept.items()))
    return f" Its fit kept {listed} of {sum(kept.values())} fitted cells."


def method_sentences(points: list[dict], failure_rows: list[dict]) -> dict[str, str]:
    """One sentence per model on where it breaks and why (from the failure map); for an ``auto``
    model also which candidate its fits kept (:func:`auto_choices`)."""
    sentences = {}
    for model in dict.fromkeys(p["model"] for p in points):
        rows = [r for r in failure_rows if r["model"] == model]
        total, failed = sum(r["cells"] for r in rows), sum(r["failed"] for r in rows)
        conditions = ", ".join(sorted({r["condition"] for r in rows}))
        if failed == 0:
            sentences[model] = f"{model}: no failure in {total} cells ({conditions})." + auto_choices(points, model)
            continue
        broken = sorted((r for r in rows if r["failed"]), key=lambda r: -r["failed"] / r["cells"])
        parts = []
        for r in broken:
            causes = ", ".join(f"{cause.replace('_', ' ')} ×{n}" for cause, n in sorted(r["causes"].items()))
            meaning = "; ".join(dict.fromkeys(_meaning(c, r["condition"]) for c in r["causes"]))
            parts.append(f"{r['condition']} ({r['failed']}/{r['cells']}: {causes}) — {condition_change(r['condition'], r['pairs'])}: "
                         f"{meaning}")
        example = next((p["message"] for p in points if p["model"] == model and p["failure"] and p["message"]), "")
        sentences[model] = (f"{model}: breaks in {failed} of {total} cells — " + "; ".join(parts)
                            + (f". Example: {example}" if example else ".") + auto_choices(points, model))
    return sentences
