"""The study's figures, drawn from ``study.json`` alone (docs/study.md).

:func:`write_figures` needs only the study's content, so a report can be drawn again without the
cell folders (``neuralbrdf study --report-only``).  The renders are images, not data: each
rendered main cell's ``model.png`` and its material's ``truth.png`` are copied from the cell
folder (``cells/KEY/evaluation``) into ``figures/renders/MATERIAL/`` when it is there and
reused from there when it is not.  A PNG directly in ``figures/`` that this drawing does not
write is left over from an earlier report into the same folder and is removed.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from neuralbrdf.atomic import atomic_path
from neuralbrdf.study import aggregate, charts

RENDERS = "renders"


def materials(points: list[dict]) -> list[str]:
    """The study's materials in the order of its cells (the profile's order)."""
    return list(dict.fromkeys(p["material"] for p in points))


def rendered(points: list[dict], material: str) -> list[dict]:
    """The material's main cells that were rendered and timed, in the profile's order of variants."""
    return [p for p in points if p["material"] == material and p["is_main"] and p["cost"].get("render_ratio") is not None]


def sweep_models(points: list[dict]) -> list[str]:
    """The models of the stability sweeps: those with a cell at another plan than DS1 or with noise."""
    return list(dict.fromkeys(p["model"] for p in points if p["plan"] != "DS1" or p["noise"]))


def _pooled_entries(pareto: dict) -> list[dict]:
    entries: dict[str, dict] = {}
    for cost_key in charts.COST_AXES:
        for q in pareto[cost_key]["pooled_points"]:
            entry = entries.setdefault(q["model"], {"model": q["model"], "method": q["method"]})
            entry[cost_key] = q[cost_key]
            entry[aggregate.ACCURACY_METRIC] = q[aggregate.ACCURACY_METRIC]
    return list(entries.values())


def pooled_materials(study: dict) -> list[str]:
    """The materials the pooled chart takes each model's median over."""
    used = {m for q in study["pareto"]["render_ratio"]["pooled_points"] for m in q["materials"]}
    return [m for m in materials(study["points"]) if m in used]


def _speed_accuracy(study: dict, figures_dir: Path) -> dict:
    pareto = study["pareto"]
    shared = pooled_materials(study)
    figs = {"speed_accuracy_pooled": charts.speed_accuracy(
        _pooled_entries(pareto), {k: pareto[k]["pooled"] for k in charts.COST_AXES},
        f"Each model's median over {', '.join(shared) or 'no material every model fits'}",
        figures_dir / "speed_accuracy_pooled.png"), "speed_accuracy": {}}
    for material in materials(study["points"]):
        entries = [{"model": p["model"], "method": p["method"], **p["cost"],
                    aggregate.ACCURACY_METRIC: p["error"].get(aggregate.ACCURACY_METRIC)}
                   for p in rendered(study["points"], material) if p["failure"] is None]
        if entries:
            figs["speed_accuracy"][material] = charts.speed_accuracy(
                entries, {k: pareto[k]["per_material"].get(material, []) for k in charts.COST_AXES}, material,
                figures_dir / f"speed_accuracy_{material}.png")
    return figs


def _stability(study: dict, figures_dir: Path) -> dict:
    """Box plots over seeds: each distinct fit once (:func:`~neuralbrdf.study.aggregate.distinct_fits`),
    plans from most pairs to fewest (a plan file named by its stem and number of pairs); the error
    against the number of pairs."""
    points, figs = aggregate.distinct_fits(study["points"]), {}
    models = sweep_models(points)
    sweep = [p for p in points if p["model"] in models]
    pairs = {p["plan"]: aggregate.pairs_of(p) for p in sweep}
    plans = sorted(pairs, key=lambda plan: (-pairs[plan], plan not in aggregate.NAMED_PAIRS, plan))
    if len(plans) > 1:
        figs["plans"] = charts.box_by_condition(
            [p for p in sweep if p["noise"] == 0.0], models, plans, lambda p: p["plan"],
            lambda plan: plan if plan in aggregate.NAMED_PAIRS else f"{plan} ({pairs[plan]} pairs)",
            "Error per sampling plan (no noise)", figures_dir / "stability_plans.png")
    noise = sorted({p["noise"] for p in sweep if p["plan"] == "DS1"})
    if len(noise) > 1:
        figs["noise"] = charts.box_by_condition(
            [p for p in sweep if p["plan"] == "DS1"], models, noise, lambda p: p["noise"], lambda n: f"{n * 100:g}%",
            "Error per relative measurement noise (DS1)", figures_dir / "stability_noise.png")
    curves = {metric: lines for metric in aggregate.CURVE_METRICS
              if (lines := aggregate.pair_curves(points, metric))}
    if curves:
        figs["pairs"] = charts.pair_curves(curves, "Error against the number of measured pairs (no noise)",
                                          figures_dir / "stability_pairs.png")
    for g, table in enumerate(study.get("groups", [])):
        # over the materials every member fits (a member may fit more materials than the others)
        values = {row["label"]: [p["error"][aggregate.THRESHOLD_METRIC] for p in points
                                 if p["model"] == row["model"] and p["plan"] == "DS1" and p["noise"] == 0.0
                                 and p["material"] in table["materials"]
                                 and p["error"].get(aggregate.THRESHOLD_METRIC) is not None]
                  for row in table["members"]}
        figs[f"group {table['group']}"] = charts.group_boxes(values, table["group"], figures_dir / f"stability_group{g}.png")
    return figs


def _per_angle(study: dict, figures_dir: Path) -> dict:
    figs = {"rel_rmse_vs_angle": {}, "per_channel": {}}
    for material in materials(study["points"]):
        rows = [p for p in rendered(study["points"], material) if p.get("per_angle")]
        if rows:
            figs["rel_rmse_vs_angle"][material] = charts.rel_rmse_vs_angle(
                rows, material, figures_dir / f"rel_rmse_angle_{material}.png")
            figs["per_channel"][material] = charts.per_channel_boxes(rows, material, figures_dir / f"per_channel_{material}.png")
    return figs


def _copy(source: Path, target: Path) -> bool:
    """Copy ``source`` onto ``target`` when it exists; whether ``target`` exists after."""
    if source.is_file():
        with atomic_path(target) as tmp:
            shutil.copyfile(source, tmp)
    return target.is_file()


def _renders(study: dict, out_dir: Path, figures_dir: Path) -> dict:
    """Per material: ``truth`` and per model the render's path relative to ``figures/`` (only those there)."""
    renders = {}
    for material in materials(study["points"]):
        folder, shown = figures_dir / RENDERS / material, {}
        truth = None
        for p in rendered(study["points"], material):
            evaluation = out_dir / "cells" / str(p.get("key")) / "evaluation"
            if _copy(evaluation / "model.png", folder / f"{p['model']}.png"):
                shown[p["model"]] = f"{RENDERS}/{material}/{p['model']}.png"
            if _copy(evaluation / "truth.png", folder / "truth.png"):
                truth = f"{RENDERS}/{material}/truth.png"
        if shown and truth:
            renders[material] = {"truth": truth, "models": shown}
    return renders


def write_figures(study: dict, out_dir: str | Path) -> dict:
    """Draw every figure of ``study`` (the content of ``study.json``) into ``out_dir/figures``;
    their names relative to that folder, by section (module docstring)."""
    out_dir = Path(out_dir)
    figures_dir = out_dir / "figures"
    figs = _speed_accuracy(study, figures_dir)
    figs["stability"] = _stability(study, figures_dir)
    if study["failures"]:
        figs["failure_map"] = charts.failure_map(study["failures"], figures_dir / "failure_map.png")
    figs.update(_per_angle(study, figures_dir))
    figs["renders"] = _renders(study, out_dir, figures_dir)
    written = {figs["speed_accuracy_pooled"], figs.get("failure_map"), *figs["speed_accuracy"].values(),
               *figs["stability"].values(), *figs["rel_rmse_vs_angle"].values(), *figs["per_channel"].values()}
    for left_over in figures_dir.glob("*.png"):
        if left_over.name not in written:
            left_over.unlink()
    return figs
