"""Write docs/results.md from the committed result files, so that the page cannot drift from them.

    python docs/make_results.py            # rewrite docs/results.md and the README's main-job caption
    python docs/make_results.py --check    # exit 1 if either is not what this script writes

Every table on the page is computed here from a JSON or TSV file committed in ``benchmarks/`` or
``docs/study/``, and each section names its file and the command that reproduces it.  Only the
Python standard library is used, so the page can be checked anywhere (``tests/test_docs.py``).
The caption of the README's picture (the paragraph that starts with :data:`CAPTION_START`) is
written the same way, from the main job's scores (:data:`MAIN_JOB`, remade by
``bash benchmarks/main_job.sh``).
To change a number on the page, rerun the command that makes its file, then this script.
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
import textwrap
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "results.md"
README = ROOT / "README.md"
#: The README main job's ``evaluation.json``, committed by ``benchmarks/main_job.sh`` with its picture.
MAIN_JOB = "benchmarks/main_job/evaluation.json"
#: How the README's caption of the main job's picture begins; the paragraph ends at a blank line.
CAPTION_START = "*The main job's result*"

#: Legend of the fits of ``benchmarks/nlb_render_check.sh``, by the label its summary uses.
RENDER_CHECK_LABELS = {
    "nlb_compact": "network `nlb_compact`, no latent prior",
    "nlb_latent32_scratch": "network `nlb_latent32_scratch`, no latent prior",
    "nlb_latent32_blends": "network `nlb_latent32_blends`, no latent prior",
    "nlb_latent32_blends_prior0.01_measured": "network `nlb_latent32_blends`, latent prior 0.01 fitted to the "
                                              "measured materials' codes",
    "nlb_latent32_blends_prior0.01": "network `nlb_latent32_blends`, latent prior 0.01 fitted to all codes: the "
                                     "default fit",
}
#: The latent-fit recipes of ``benchmarks/models.py`` (columns of its per-material results).
NLB_COLUMNS = (
    ("nlb_DS1", "NLB DS1"), ("nlb_DS3", "NLB DS3"), ("nlb_DS4", "NLB DS4"),
    ("nlb_DS1_report_recipe", "DS1 report recipe"), ("nlb_DS1_centroid_start", "DS1 centroid start"),
    ("nlb_DS1_one_start", "DS1 one start"), ("abc_DS1", "ABC DS1"), ("abc_low2012", "Löw ABC"),
)
#: The pretrained networks compared without a prior, and the default fit, with their result files.
NETWORK_FILES = (
    ("`nlb_compact`", "no prior", "benchmarks/models_nlb_compact.json",
     "python benchmarks/models.py --checkpoint nlb_compact --latent-prior-weight 0 --out benchmarks/models_nlb_compact.json"),
    ("`nlb_latent32_scratch`", "no prior", "benchmarks/models_latent32_scratch.json",
     "python benchmarks/models.py --only-nlb --plans DS1,DS3,DS4 --skip-timing --latent-prior-weight 0 "
     "--checkpoint nlb_latent32_scratch --out benchmarks/models_latent32_scratch.json"),
    ("`nlb_latent32_blends`", "no prior", "benchmarks/models_latent32_blends.json",
     "python benchmarks/models.py --only-nlb --plans DS1,DS3,DS4 --skip-timing --latent-prior-weight 0 "
     "--checkpoint nlb_latent32_blends --out benchmarks/models_latent32_blends.json"),
    ("`nlb_latent32_blends`", "prior 0.01, all codes (default)", "benchmarks/models.json", "python benchmarks/models.py"),
)
#: The latent prior's sweeps and the commands that made them.
SWEEP_FILES = (
    ("benchmarks/latent_prior_sweep.json", "python benchmarks/latent_prior_sweep.py --codes measured"),
    ("benchmarks/latent_prior_sweep_all_codes.json",
     "python benchmarks/latent_prior_sweep.py --checkpoints nlb_latent32_blends --weights 0.003,0.01,0.03 "
     "--out benchmarks/latent_prior_sweep_all_codes.json"),
    ("benchmarks/latent_prior_sweep_ds34.json",
     "python benchmarks/latent_prior_sweep.py --checkpoints nlb_latent32_blends --plans DS3,DS4 "
     "--weights 0,0.003,0.01,0.03 --codes measured --out benchmarks/latent_prior_sweep_ds34.json"),
)
STUDIES = (
    ("docs/study/full/study.json", "docs/study/full/index.html"),
    ("docs/study/spectral/study.json", "docs/study/spectral/index.html"),
    ("docs/study/study.json", "docs/study/index.html"),
)
SPECTRAL_NLB = (("benchmarks/spectral_nlb.json", "python benchmarks/spectral_nlb.py"),
                ("benchmarks/spectral_nlb_virtual.json", "python benchmarks/spectral_nlb.py --groups virtual "
                 "--plans DS1,DS3,DS4 --out benchmarks/spectral_nlb_virtual.json"))
STUDY_CLUSTER = "benchmarks/study_cluster.json"
#: The budget profile's study (error against the number of measured pairs) and its report.
BUDGET_STUDY = ("docs/study/budget/study.json", "docs/study/budget/index.html")
#: Designed plans against the report's plans of as many pairs or more: (designed plan, named plan).
BUDGET_PAIRS = (("nlb_spectral_6", "DS4"), ("nlb_spectral_12", "DS3"), ("nlb_spectral_24", "DS3"),
                ("nlb_spectral_48", "DS3"))
#: The report's plans (a study point's plan is one of these or a plan file's stem).
REPORT_PLANS = ("DS1", "DS2", "DS3", "DS4")
#: The image and hemisphere metrics of the budget tables.
BUDGET_METRICS = (("hemisphere_logcos_rmse", "hemisphere log-cos", 4), ("image_delta_e2000_mean", "image ΔE2000", 2))
SPECTRAL_NLB_VALIDATION = "benchmarks/spectral_nlb_validation.json"
SPECTRAL_NLB_TIMING = "benchmarks/spectral_nlb_timing.json"
SPECTRAL_PRETRAIN = "benchmarks/nlb_spectral_pretrain.json"
RGL_REAL = ("benchmarks/rgl_real.json", "python benchmarks/rgl_real.py")
AUTO = ("benchmarks/auto.json", "python benchmarks/auto.py")
AUTO_RULES = ("benchmarks/auto_rules.json", "python benchmarks/auto_rules.py")
AUTO_TIMING = ("benchmarks/auto_timing.json", "python benchmarks/auto_timing.py")
#: The groups of benchmarks/auto.json and what each is for the choice of the rule.
AUTO_GROUPS = {
    "virtual_validation": "six virtual validation materials, spectral, 1 % noise (validation)",
    "rgl_validation": "nine RGL validation proxies, RGB (validation)",
    "rgl_real": "the ten real RGL measurements, truth Mitsuba's `measured` plugin (validation on real data; the "
                "materials are among the pretraining proxies)",
    "merl_held_out": "the ten held-out MERL proxies (a test set: the rule was not chosen on it)",
}
#: Methods of ``benchmarks/rgl_real.py`` as the page names them.
RGL_METHODS = {"abc": "ABC", "spectral_mlp": "spectral MLP", "nlb": "RGB NLB", "nlb_spectral": "spectral NLB"}


# -- formatting ------------------------------------------------------------------------------


def num(value, digits: int = 4) -> str:
    """A number with ``digits`` decimals; ``—`` for a missing value."""
    if value is None:
        return "—"
    return f"{value:.{digits}f}"


def table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return lines + [""]


def load(relative: str):
    return json.loads((ROOT / relative).read_text(encoding="utf-8"))


def link(relative: str) -> str:
    """A link from docs/results.md to a file of the repository."""
    return f"[`{relative}`](../{relative})"


def machine_line(machine: dict | None) -> str:
    if not machine:
        return "Machine: not recorded."
    parts = [machine.get("cpu"), f"{machine['cores']} cores" if machine.get("cores") else None,
             f"{machine['cpus']} cores" if machine.get("cpus") else None, machine.get("platform")]
    versions = machine.get("versions") or {}
    if machine.get("torch"):
        versions = {"torch": machine["torch"], **versions}
    text = ", ".join(p for p in parts if p)
    if versions:
        text += "; " + ", ".join(f"{k} {v}" for k, v in versions.items())
    return f"Machine: {text}."


def source_lines(relative: str, command: str, machine: dict | None = None) -> list[str]:
    lines = [f"Source: {link(relative)}. Reproduce: `{command}`."]
    if machine is not None:
        lines.append(machine_line(machine))
    return lines + [""]


def median(values):
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def mean(values):
    values = [v for v in values if v is not None]
    return statistics.fmean(values) if values else None


# -- NLB latent fits against ABC (benchmarks/models*.json) ----------------------------------


def _material_table(materials: dict, held_out: bool) -> list[str]:
    names = sorted(n for n, m in materials.items() if bool(m.get("held_out")) == held_out)
    rows = [[n] + [num(materials[n].get(key)) for key, _ in NLB_COLUMNS] for n in names]
    for label, reduce in (("**median**", median), ("mean", mean)):
        rows.append([label] + [num(reduce([materials[n].get(key) for n in names])) for key, _ in NLB_COLUMNS])
    return table(["material"] + [title for _, title in NLB_COLUMNS], rows)


def _wins(materials: dict, names: list[str], key: str, against: str) -> str:
    pairs = [(materials[n].get(key), materials[n].get(against)) for n in names]
    pairs = [(a, b) for a, b in pairs if a is not None and b is not None]
    return f"{sum(a < b for a, b in pairs)}/{len(pairs)}"


TARGETS = (
    ("nlb_DS1_beats_abc_DS1_share", "held-out share where NLB from DS1 beats the in-plane ABC fit", ">=",
     lambda d: d["nlb_vs_abc"]["summary"]["held_out"]["nlb_DS1_beats_abc_DS1"], "{:.0%}"),
    ("median_nlb_DS1_over_abc_DS1", "held-out median of NLB DS1 over ABC DS1's", "<=",
     lambda d: d["nlb_vs_abc"]["summary"]["held_out"]["median_nlb_DS1_over_abc_DS1"], "{:.2f}×"),
    ("nlb_DS1_beats_low2012_share", "held-out share where NLB from DS1 beats Löw's full-data ABC fit", ">=",
     lambda d: d["nlb_vs_abc"]["summary"]["held_out"]["nlb_DS1_beats_low2012"], "{:.0%}"),
    ("median_nlb_DS3_over_nlb_DS1", "held-out median of NLB DS3 over NLB DS1's", "<=",
     lambda d: d["nlb_vs_abc"]["summary"]["held_out"]["median_nlb_DS3_over_nlb_DS1"], "{:.2f}×"),
    ("latent_fit_s", "one material's latent fit on DS1, s", "<=",
     lambda d: d["nlb_vs_abc"]["latent_fit_s"]["single_DS1"], "{:.2f}"),
    ("latent_fit_batched_100_per_material_s", "100 materials in one batch, s per material", "<=",
     lambda d: d["nlb_vs_abc"]["latent_fit_s"]["batched_100_per_material"], "{:.3f}"),
    ("abc_known_logcos_rmse", "ABC fit of known ABC parameters, hemisphere log-cos RMSE", "<=",
     lambda d: d["abc_known"]["hemisphere_logcos_rmse"], "{:.5f}"),
    ("abc_fit_s", "that ABC fit, s", "<=", lambda d: d["abc_known"]["fit_wall_time_s"], "{:.2f}"),
    ("spectral_mlp_fit_s", "spectral MLP 30-epoch fit, slowest material, s", "<=",
     lambda d: max(m["fit_wall_time_s"] for m in d["spectral_mlp"].values()), "{:.1f}"),
    ("spectral_mlp_rel_rmse", "spectral MLP test glossy relative RMSE (median), worst material", "<=",
     lambda d: max(m["test_rel_rmse_glossy_median"] for m in d["spectral_mlp"].values()), "{:.3f}"),
)


def _target_rows(models: dict) -> list[list[str]]:
    rows = []
    for key, what, relation, measured, fmt in TARGETS:
        target = models.get("targets", {}).get(key)
        try:
            value = measured(models)
        except (KeyError, TypeError, ValueError):
            continue
        if target is None or value is None:
            continue
        met = value >= target if relation == ">=" else value <= target
        shown_target = fmt.format(target) if "%" in fmt or "×" in fmt else f"{target:g}"
        rows.append([what, f"{relation.replace('>=', '≥').replace('<=', '≤')} {shown_target}", fmt.format(value),
                     "met" if met else "**missed**"])
    return rows


def _prior_text(weight) -> str:
    if isinstance(weight, (int, float)):
        return f"latent prior weight {weight:g}"
    return "the config's latent prior"


def nlb_section() -> list[str]:
    models = load("benchmarks/models.json")
    nlb = models["nlb_vs_abc"]
    materials = nlb["materials"]
    lines = ["## NLB latent fits against ABC on MERL proxies", ""]
    lines += ["Hemisphere log-cosine RMSE of each fit against the material's NBRDF proxy on the Löw et al. "
              "direction set ([metrics](evaluate.md#metrics)). NLB is the default latent fit (`configs/nlb_latent.yaml`: network "
              f"`{Path(nlb['checkpoint']).stem}`, {_prior_text(nlb.get('latent_prior_weight'))}), all "
              "fifteen materials in one batch; ABC DS1 is `fit_abc` on the same DS1 samples; Löw is the published "
              "full-data ABC fit. The recipes (report recipe, centroid start, one start) are described in "
              "[models.md](models.md#latent-fit-rgb-nlb). No network was pretrained on the held-out ten or on "
              "the report's five.", ""]
    lines += source_lines("benchmarks/models.json", "python benchmarks/models.py", models.get("machine"))
    lines += ["### The ten held-out materials", ""] + _material_table(materials, True)
    lines += ["### The report's five materials", ""] + _material_table(materials, False)
    lines += ["### Against the targets", ""]
    lines += table(["quantity", "target", "measured", ""], _target_rows(models))
    fits = nlb.get("latent_fit_s", {})
    rows = [[key.replace("_per_material", "").replace("_", " "), num(value, 3)]
            for key, value in fits.items() if isinstance(value, (int, float))]
    lines += ["### Fit times", "", "Latent fits, seconds per material (the 15-material batches include the "
              "evaluation on the Löw set, 15 × 230 400 pairs; `single DS1` and `batched 100` do not):", ""]
    lines += table(["fit", "s per material"], rows)
    if models.get("spectral_mlp"):
        rows = [[name, num(m["fit_wall_time_s"], 1), num(m["test_rel_rmse_glossy_median"], 4)]
                for name, m in models["spectral_mlp"].items()]
        lines += ["Spectral MLP, 30 epochs on the shipped DS1 measurement:", ""]
        lines += table(["material", "fit s", "test glossy relative RMSE (median)"], rows)
    return lines


def networks_section() -> list[str]:
    reference = load("benchmarks/models.json")["nlb_vs_abc"]["materials"]
    held = sorted(n for n, m in reference.items() if m.get("held_out"))
    report = sorted(n for n, m in reference.items() if not m.get("held_out"))
    abc_median = median([reference[n]["abc_DS1"] for n in held])
    lines = ["## Pretrained networks compared", "",
             "The same benchmark for each shipped RGB network (latent fit from DS1, DS3 and DS4 of the held-out "
             "ten; the report's five from DS1). The networks are described in "
             "[models.md](models.md#shipped-rgb-networks).", ""]
    rows, per_material = [], {}
    for name, prior, relative, command in NETWORK_FILES:
        materials = load(relative)["nlb_vs_abc"]["materials"]
        ds1 = median([materials[n]["nlb_DS1"] for n in held])
        per_material[(name, prior)] = materials
        rows.append([
            name, prior, f"{num(ds1)} ({ds1 / abc_median:.2f}×)", num(mean([materials[n]["nlb_DS1"] for n in held])),
            _wins(materials, held, "nlb_DS1", "abc_DS1"), _wins(materials, held, "nlb_DS1", "abc_low2012"),
            num(median([materials[n].get("nlb_DS3") for n in held])),
            num(median([materials[n].get("nlb_DS4") for n in held])),
            num(median([materials[n]["nlb_DS1"] for n in report])),
            f"[json](../{relative})",
        ])
    lines += table(["network", "fit", "held-out DS1 median (× ABC DS1)", "mean", "wins vs ABC DS1", "wins vs Löw",
                    "held-out DS3 median", "DS4 median", "report's five DS1 median", "file"], rows)
    lines += ["Commands:", ""]
    lines += [f"- {name}, {prior}: `{command}`" for name, prior, _, command in NETWORK_FILES] + [""]
    keys = list(per_material)
    for plan in ("DS1", "DS3", "DS4"):
        lines += [f"Held-out ten, NLB from {plan}, per material:", ""]
        rows = [[n] + [num(per_material[k][n].get(f"nlb_{plan}")) for k in keys]
                + [num(reference[n]["abc_DS1"]), num(reference[n]["abc_low2012"])] for n in held]
        lines += table(["material"] + [f"{name} ({prior})" for name, prior in keys] + ["ABC DS1", "Löw"], rows)
    lines += ["Latent-fit recipes on each network (DS1; the recipes are described in "
              "[models.md](models.md#latent-fit-rgb-nlb)):", ""]
    rows = []
    for (name, prior), materials in per_material.items():
        for key, title in NLB_COLUMNS:
            if not key.startswith("nlb_DS1") or any(materials[n].get(key) is None for n in held):
                continue
            recipe = "default" if key == "nlb_DS1" else title.replace("DS1 ", "")
            rows.append([name, prior, recipe, num(median([materials[n][key] for n in held])),
                         num(mean([materials[n][key] for n in held])), _wins(materials, held, key, "abc_DS1"),
                         num(mean([m[key] for m in materials.values() if m.get(key) is not None]))])
    lines += table(["network", "fit", "recipe", "held-out median", "held-out mean", "wins vs ABC DS1", "all 15 mean"],
                   rows)
    compact = load("benchmarks/models_nlb_compact.json").get("pretraining")
    if compact and compact.get("curve"):
        points = curve_points(compact["curve"])
        lines += ["Validation log-cos RMSE of the last pretraining stage of `nlb_compact` "
                  f"(`{compact['run_dir']}`, {compact['wall_time_s'] / 60:.0f} min), by optimiser step of that "
                  f"stage: {points}. Drawn in [nlb_pretrain_curve.png](nlb_pretrain_curve.png) by "
                  "`python benchmarks/models.py --pretrain-run DIR --curve-png PNG`.", ""]
    return lines


# -- the latent prior's weight (benchmarks/latent_prior_sweep*.json) ------------------------------


def prior_section() -> list[str]:
    abc = load("benchmarks/models.json")["nlb_vs_abc"]["materials"]
    abc_median = median([m["abc_DS1"] for m in abc.values() if m.get("held_out")])
    lines = ["## The latent prior's weight", "",
             "Latent fits of the held-out ten and the report's five in one batch, hemisphere log-cos RMSE against "
             "the proxy; wins counted on the held-out ten; `× ABC` against the held-out median of ABC DS1 "
             f"({num(abc_median)}). The prior is described in [models.md](models.md#nlb-latent-prior). "
             "Leave-one-out: the weight chosen for each material on the other fourteen (by their mean or median "
             "error), and the held-out result of those choices.", ""]
    for relative, command in SWEEP_FILES:
        sweep = load(relative)
        rows = []
        for row in sweep["rows"]:
            held, rep = row["held_out"], row["report"]
            everything = mean(list(row["materials"].values()))
            rows.append([f"`{row['checkpoint']}`", row["codes"], row["plan"], f"{row['weight']:g}",
                         f"{num(held['median'])} ({held['median'] / abc_median:.2f}×)", num(held["mean"]),
                         f"{held['wins_vs_abc_DS1']}/10, {held['wins_vs_low2012']}/10",
                         f"{num(rep['median'])} / {num(rep['mean'])}", num(everything),
                         num(row.get("fit_s_per_material"), 2)])
        lines += [f"### {Path(relative).name}", ""] + source_lines(relative, command)
        lines += table(["network", "codes", "plan", "weight", "held-out median (× ABC)", "held-out mean",
                        "wins vs ABC DS1 / Löw", "report's five median / mean", "all 15 mean", "fit s per material"],
                       rows)
        rows = []
        for key, choice in sweep.get("leave_one_out", {}).items():
            for by, result in choice.items():
                chosen = Counter(result["weights"].values())
                weights = ", ".join(f"{w:g} ×{n}" for w, n in sorted(chosen.items()))
                rows.append([key, by.replace("_", " "), weights, num(result["held_out_median"]),
                             num(result["held_out_mean"])])
        if rows:
            lines += table(["network, plan", "choice", "weights chosen (materials)", "held-out median",
                            "held-out mean"], rows)
    return lines


# -- where users look (nlb_render_check, accuracy_merl) ----------------------------------------


def render_check_section() -> list[str]:
    relative = "benchmarks/nlb_render_check/summary.tsv"
    with open(ROOT / relative, encoding="utf-8", newline="") as handle:
        records = list(csv.DictReader(handle, delimiter="\t"))
    labels = list(dict.fromkeys(r["model"] for r in records))
    materials = list(dict.fromkeys(r["material"] for r in records))
    cell = {(r["model"], r["material"]): r for r in records}
    lines = ["## Where users look: the held-out ten rendered", "",
             "The held-out ten fitted from DS1 in one batch per fit, exported, and scored by `neuralbrdf evaluate` "
             "against the proxy's own export in the material-preview scene (`llvm_ad_rgb`, 128 px, 256 spp, model "
             "and truth at the same seeds). The truth rendered against itself with other seeds gives the render "
             "noise, stated in each `evaluation.json`. Fits:", ""]
    lines += [f"- `{label}`: {RENDER_CHECK_LABELS.get(label, label)}" for label in labels]
    lines += [""] + source_lines(relative, "bash benchmarks/nlb_render_check.sh OUT [CHECKPOINT[:WEIGHT[:CODES]] ...]")
    lines += ["Image CIEDE2000, mean / p95:", ""]
    rows = [[m] + [f"{float(cell[(l, m)]['image_delta_e2000_mean']):.2f} / {float(cell[(l, m)]['image_delta_e2000_p95']):.2f}"
                   if (l, m) in cell else "—" for l in labels] for m in materials]
    means = {l: [float(cell[(l, m)]["image_delta_e2000_mean"]) for m in materials if (l, m) in cell] for l in labels}
    rows.append(["median (mean)"] + [f"{median(means[l]):.2f} ({mean(means[l]):.2f})" for l in labels])
    lines += table(["material"] + [f"`{l}`" for l in labels], rows)
    noise = [_render_noise(ROOT / "benchmarks" / "nlb_render_check" / f"{l}_{m}.json") for l in labels for m in materials]
    noise = [n for n in noise if n is not None]
    if noise:
        lines += [f"Render noise (the truth against itself at other seeds), ΔE2000 mean: {min(noise):.2f}–"
                  f"{max(noise):.2f} over these cells.", ""]
    lines += ["Hemisphere log-cos RMSE of the same fits (102 400 stratified pairs):", ""]
    rows = [[m] + [num(float(cell[(l, m)]["hemisphere_logcos_rmse"])) if (l, m) in cell else "—" for l in labels]
            for m in materials]
    lines += table(["material"] + [f"`{l}`" for l in labels], rows)
    return lines


def _render_noise(path: Path):
    if not path.is_file():
        return None
    return (json.loads(path.read_text(encoding="utf-8")).get("noise") or {}).get("image_delta_e2000_mean")


def accuracy_section() -> list[str]:
    relative = "benchmarks/accuracy_merl.json"
    data = load(relative)
    settings = data.get("settings", {})
    lines = ["## ABC against NLB in the image: the report's five", "",
             "DS1 samples of each NBRDF proxy, fitted by `configs/abc.yaml` and by the default latent fit "
             "(`configs/nlb_latent.yaml`), scored by `neuralbrdf evaluate` against `neuralbrdf export-truth NAME.h5` "
             f"(`llvm_ad_rgb`, {settings.get('resolution')}², {settings.get('spp')} spp). The render noise is the "
             "truth against itself at other seeds.", ""]
    lines += source_lines(relative, data.get("command", "python benchmarks/accuracy.py --part merl"), data.get("machine"))
    rows = [[r["material"], r["model"], num(r["image_delta_e2000_mean"], 2), num(r["image_delta_e2000_p95"], 2),
             num(r["noise_delta_e2000_mean"], 2), num(r["hemisphere_logcos_rmse"]), num(r["inplane_glossy_rel_rmse"], 3),
             num(r["inplane_diffuse_rel_rmse"], 3)] for r in data["rows"]]
    lines += table(["material", "model", "ΔE mean", "ΔE p95", "render noise ΔE", "hemisphere log-cos",
                    "in-plane glossy", "in-plane diffuse"], rows)
    return lines


# -- rendering speed (benchmarks/results.json) and level of detail (benchmarks/lod_demo) ---------


def speed_section() -> list[str]:
    relative = "benchmarks/results.json"
    data = load(relative)
    settings = data.get("settings", {})
    lines = ["## Rendering speed and throughput", "",
             f"Material-preview scene, {settings.get('resolution')}² at {settings.get('spp')} spp, path depth 5, "
             f"{settings.get('repeats')} renders per configuration taken round-robin; the spectral MLP trained on the "
             f"virtual gold ({settings.get('epochs')} epochs, seed {data.get('seed')}), the default NLB network with "
             "one pretraining material's latent, an ABC model, the spectral NLB fitted to the virtual gold's "
             "measurement (`nlb_spectral`: its `f` in spectral variants, its RGB head in RGB ones; "
             "`nlb_spectral_integrated`: its `f` through the plugin's sRGB rule; `nlb_spectral_fast`: its fast path). "
             "Render time over Mitsuba's `roughconductor` (GGX gold, "
             "α = 0.2) in the same variant and mode, same process (median of the renders, and shortest over "
             "shortest). Where the time goes: [design.md](design.md#rendering-speed).", ""]
    lines += source_lines(relative, data.get("command", "python benchmarks/run.py"), data.get("machine"))
    load_average = data.get("load_average")
    if load_average:
        lines += [f"Load average (1, 5, 15 min) before the run {', '.join(f'{v:.1f}' for v in load_average['before'])}, "
                  f"after {', '.join(f'{v:.1f}' for v in load_average['after'])}.", ""]
    rows = []
    for variant, block in data["render"].items():
        for name, ratio in block["ratios"].items():
            config = block["configs"][name]
            rows.append([f"`{variant}`", f"`{name}`", f"`{config.get('output', 'f')}`", f"{config['median_s']:.3f}",
                         f"{ratio['median']:.2f}×", f"{ratio['shortest']:.2f}×", f"`{ratio['baseline']}`"])
    lines += table(["variant", "model / backend", "output", "median s", "÷ baseline (median)", "÷ baseline (shortest)",
                    "baseline"], rows)
    rows = [[f"`{variant}`", f"`{pair}`", num(m.get("image_delta_e2000_mean"), 3), num(m.get("image_delta_e2000_p95"), 3)]
            for variant, block in data["render"].items() for pair, m in block.get("image_errors", {}).items()]
    if rows:
        lines += ["Image error of each fast path against its parent (first render, seed 0, the same paths):", ""]
        lines += table(["variant", "fast path vs parent", "ΔE2000 mean", "ΔE2000 p95"], rows)
    backends = []
    for model in data["throughput"].values():
        backends += [b for b in model["backends"] if b not in backends]
    rows = [[f"{name}" + (f" ({model['note']})" if model.get("note") else "")]
            + [f"{model['backends'][b]['queries_per_s'] / 1e6:.1f}" if b in model["backends"] else "—" for b in backends]
            for name, model in data["throughput"].items()]
    batch = f"{settings.get('batch'):,}".replace(",", " ")
    lines += [f"Evaluation throughput at a batch of {batch} queries, M queries/s (`drjit_kernel`: the fused kernel's "
              "own run time, tracing and compilation excluded):", ""]
    lines += table(["model"] + backends, rows)
    rows = [[f"`{key}`", str(value)] + _speed_measured(data, key, str(value))
            for key, value in data.get("targets", {}).items()]
    lines += ["Targets quoted by the benchmark (not asserted):", ""]
    lines += table(["quantity", "target", "measured", ""], rows)
    return lines + [""] + fast_paths_section()


def _speed_measured(data: dict, key: str, target: str) -> list[str]:
    """The measured value of a target of ``benchmarks/results.json`` and whether it is met: a
    render ratio (``VARIANT/CONFIG``, median) or the worst image error of a fast path against its
    parent (``... image dE2000 mean``)."""
    try:
        relation, bound = target.split()[0], float(target.split()[1])
        if key.endswith("image dE2000 mean"):
            pair = ("nlb_spectral" if key.startswith("nlb_spectral") else "spectral_mlp/drjit vs" if "rgb head" in key
                    else "nlb_fast/drjit vs")
            values = [m["image_delta_e2000_mean"] for block in data["render"].values()
                      for name, m in block.get("image_errors", {}).items() if name.startswith(pair)]
            value = max(values)
            shown = f"{value:.2f}"
        else:
            variant, _, name = key.partition("/")
            value = data["render"][variant]["ratios"][name]["median"]
            shown = f"{value:.2f}×"
    except (KeyError, IndexError, ValueError):
        return ["—", ""]
    met = value <= bound if relation == "<=" else value >= bound
    return [shown, "met" if met else "**missed**"]


def fast_paths_section() -> list[str]:
    relative = "benchmarks/fast_paths.json"
    if not (ROOT / relative).is_file():
        return []
    data = load(relative)
    lines = ["### Fast paths against their parents", "",
             f"Each fast path rendered against its parent in the preview scene ({data['resolution']} px, "
             f"{data['spp']} spp, seed 0, matched paths: the difference is the fast path's own error): the spectral "
             "MLPs' RGB heads against the sRGB integration, the NLB fits' compact copies against the full NLB, and "
             "the spectral NLB's fits rendered as `--fast` renders them (its `f_fast`; for a spectral fit in "
             "`llvm_ad_rgb` its RGB head) against their full network (the four virtual materials and the report's "
             "five MERL materials, DS1). Mosaics: `benchmarks/fast_paths_*.png`.", ""]
    lines += source_lines(relative, data["command"], data.get("machine"))
    rows = [[r["fast_path"], r["material"], f"`{r['variant']}`", num(r["image_delta_e2000_mean"], 3),
             num(r["image_delta_e2000_p95"], 3), num(r["recorded_hemisphere_logcos_rmse"])] for r in data["results"]]
    lines += table(["fast path", "material", "variant", "ΔE2000 mean", "ΔE2000 p95", "recorded log-cos RMSE vs f"], rows)
    targets = data["targets_mean_delta_e2000"]
    lines += [f"- largest mean ΔE2000, {key}: {value:.3f} (target ≤ {targets[key.rsplit(' ', 1)[0]]}; "
              f"{'met' if value <= targets[key.rsplit(' ', 1)[0]] else '**missed**'})"
              for key, value in data["largest_mean_delta_e2000"].items()]
    return lines + [""]


def lod_section() -> list[str]:
    folder = ROOT / "benchmarks" / "lod_demo"
    runs = sorted(p for p in folder.glob("*.json") if not p.name.endswith("_SELECTED.json"))
    lines = ["## Level of detail: selection on the demo scenes", "",
             "`neuralbrdf select` on `export/scenes/lod_demo.xml` (the four spectral MLPs of `export/lod_models.sh`) "
             "and on the preview scene with the gold alone; both tolerances 1.0. ΔE: the selected scene at matched "
             "paths against the all-full one (the stand-ins' bias), over the whole image and over each object's "
             "pixels. Speed: shortest of the interleaved renders after a compiling one (Dr.Jit symbolic mode).", ""]
    lines += ["Source: [`benchmarks/lod_demo/`](../benchmarks/lod_demo/). Reproduce: "
              "`bash export/lod_models.sh && python benchmarks/lod_demo.py --variant V [--preview-gold]`.",
              machine_line(load(str(runs[0].relative_to(ROOT))).get("machine")) if runs else "", ""]
    rows = []
    for path in runs:
        run = json.loads(path.read_text(encoding="utf-8"))
        scene = "preview, gold alone" if path.name.startswith("preview") else Path(run["scene"]).name
        chosen = " / ".join(f"{m}: `{r}`" for m, r in run["chosen"].items())
        objects = " / ".join(f"{num(o['delta_e2000_mean'], 2)}" for o in run["on_object"].values())
        selection = run["selection"]
        rows.append([scene, f"`{run['variant']}`", chosen,
                     f"{run['selection_time_s']:.0f} s ({run['selection_cpu_s']:.0f} s CPU; {selection['noise']['spp']} spp)",
                     f"{num(run['image_delta_e2000_mean'], 2)} ({num(run.get('image_delta_e2000_p95'), 2)})", objects,
                     f"{run['full_time_s']:.2f} s → {run['selected_time_s']:.2f} s",
                     f"{run['speedup']:.2f}× (medians {run['speedup_of_medians']:.2f}×)",
                     ", ".join(("" if met else "**missed** ") + name.replace("_", " ")
                               for name, met in run.get("targets", {}).items()) or "—"])
    lines += table(["scene", "variant", "chosen", "selection wall", "ΔE whole image (p95)", "ΔE on each object",
                    "all-full → selected", "speed-up", "targets (met unless marked)"], rows)
    rows = []
    for path in runs:
        run = json.loads(path.read_text(encoding="utf-8"))
        scene = "preview, gold alone" if path.name.startswith("preview") else Path(run["scene"]).name
        rows.append([scene, f"`{run['variant']}`", num(run.get("image_delta_e2000_mean_own_proposals"), 2),
                     num(run.get("reference_noise_delta_e2000_mean"), 2)])
    lines += ["The selected scene as written (each stand-in with its own sampler) against the all-full one, and the "
              "all-full scene against itself at another seed — the Monte Carlo noise both carry at the reference "
              "sample count:", ""]
    lines += table(["scene", "variant", "ΔE selected as written", "ΔE all-full seed to seed"], rows)
    lines += ["Each rung's hemisphere log-cos RMSE against its parent / relative Dr.Jit cost, as measured by "
              "`neuralbrdf ladder` (the ladders of `export/lod_models.sh`):", ""]
    ladders: dict[str, dict[str, dict]] = defaultdict(dict)
    for path in sorted(folder.glob("demo_*_SELECTED.json")):
        for material, candidates in json.loads(path.read_text(encoding="utf-8"))["candidates"].items():
            for c in candidates:
                ladders[c["rung"]].setdefault(material, c)
    materials = list(dict.fromkeys(m for rungs in ladders.values() for m in rungs))
    rows = [[f"`{rung}`"] + [f"{num(by[m]['hemisphere_logcos_rmse'])} / {by[m]['relative_cost']:.2f}" if m in by else "—"
                             for m in materials] for rung, by in ladders.items() if rung != "full"]
    lines += table(["rung"] + materials, rows)
    return lines


# -- the study (docs/study/**/study.json) ---------------------------------------------------------


def _by_model(points, key):
    out: dict[str, dict[str, float]] = defaultdict(dict)
    for p in points:
        value = key(p)
        if value is not None:
            out[p["model"]][p["material"]] = value
    return out


def study_section(relative: str, report: str) -> list[str]:
    study = load(relative)
    run = study.get("run", {})
    materials = list(dict.fromkeys(p["material"] for p in study["points"]))
    main = [p for p in study["points"] if p.get("is_main") and p.get("cost") and p["cost"].get("render_ratio")]
    lines = [f"### `{run.get('profile', relative)}`", "",
             f"Report: [`{report}`](../{report}). Reproduce: `{run.get('command')}`. {len(study['points'])} cells "
             f"({run.get('cells_run')} run, {run.get('cells_cached')} from the cache in the last run: "
             f"{run.get('wall_time_s', 0):.0f} s wall, {run.get('cells_cpu_time_s', 0):.0f} s of the cells' CPU); "
             f"{run.get('jobs')} jobs; hemisphere metrics on {run.get('hemisphere_pairs')} pairs; seeds "
             f"{', '.join(str(s) for s in run.get('seeds', []))}.", machine_line(study.get("machine")), ""]
    delta_e = _by_model(main, lambda p: p["error"].get("image_delta_e2000_mean"))
    logcos = _by_model(main, lambda p: p["error"].get("hemisphere_logcos_rmse"))
    models = list(dict.fromkeys(p["model"] for p in main))
    lines += ["Main cells (DS1, no noise, seed 0): image ΔE2000 mean against the truth on matched paths / "
              "hemisphere log-cos RMSE; — where the model does not fit that material:", ""]
    rows = [[f"`{m}`"] + [f"{num(delta_e[m].get(mat), 2)} / {num(logcos[m].get(mat))}" if mat in logcos[m] else "—"
                          for mat in materials] for m in models]
    lines += table(["model"] + materials, rows)
    common = [mat for mat in materials if all(mat in delta_e[m] for m in models)]
    costs = {m: [p["cost"] for p in main if p["model"] == m and p["material"] in common] for m in models}
    rows = [[f"`{m}`", num(median([delta_e[m][mat] for mat in common]), 2), num(median([logcos[m][mat] for mat in common])),
             num(median([c["render_ratio"] for c in costs[m]]), 2),
             num(median([c.get("mqueries_per_s") for c in costs[m]]), 1), num(median([c.get("fit_time_s") for c in costs[m]]), 1),
             str(costs[m][0].get("parameters", "—")) if costs[m] else "—"] for m in models]
    lines += [f"Pooled over {', '.join(common)} (the materials every model fits; medians): the numbers of the "
              "report's pooled chart.", ""]
    lines += table(["model", "ΔE mean", "log-cos RMSE", "render time ÷ roughconductor", "M queries/s", "fit s",
                    "parameters"], rows)
    rows = [[f"`{f['model']}`", f["condition"], f"{f['failed']}/{f['cells']}", num(f.get("median_error")),
             ", ".join(f"{k} {v}" for k, v in f.get("causes", {}).items()) or "—"]
            for f in study.get("failures", [])]
    lines += ["Failure map: a cell fails on a non-finite loss, an optimiser failure, a refused fit or export, or an "
              "error above twice the same model's noise-free DS1 median.", ""]
    lines += table(["model", "condition", "failed / cells", "median log-cos RMSE", "causes"], rows)
    for group in study.get("groups", []):
        names = group["materials"]
        rows = [[member["label"], f"`{member['model']}`", num(member["median"])]
                + [num(next((x["median"] for x in member["per_material"] if x["material"] == n), None)) for n in names]
                for member in group["members"]]
        lines += [f"Group *{group['group']}*: median log-cos RMSE over seeds per material, and the median of those:", ""]
        lines += table(["member", "model", "median"] + names, rows)
    lines += _seed_lines(study["points"])
    return lines


def _seed_lines(points) -> list[str]:
    """How many noise-free cell groups (model, material, plan) have the same error for every seed."""
    groups: dict[tuple, list] = defaultdict(list)
    for p in points:
        error = (p.get("error") or {}).get("hemisphere_logcos_rmse")
        if error is not None:
            groups[(p["model"], p["material"], p["plan"], p["noise"])].append(error)
    same, total = Counter(), Counter()
    for (model, _, _, noise), errors in groups.items():
        if len(errors) > 1 and noise == 0:
            total[model] += 1
            same[model] += len({round(e, 12) for e in errors}) == 1
    if not total:
        return []
    rows = [[f"`{m}`", f"{same[m]}/{total[m]}"] for m in total]
    return ["Seeds: noise-free groups (model, material, plan) with more than one seed in which every seed gave the "
            "same error. A fit that is deterministic without noise spreads over materials only; its spread over "
            "seeds is no evidence of stability.", ""] + table(["model", "groups with one error for all seeds"], rows)


def studies_section() -> list[str]:
    lines = ["## The study", "",
             "`neuralbrdf study` (see [study.md](study.md)): every variant fitted to every material, scored against "
             "the truth, timed against `roughconductor` in the same process, and swept over plans, noise and seeds.",
             ""]
    for relative, report in STUDIES:
        if (ROOT / relative).is_file():
            lines += study_section(relative, report)
    if (ROOT / STUDY_CLUSTER).is_file():
        lines += study_cluster_section()
    return lines + budget_section()


def _budget_values(points: list[dict], metric: str) -> dict:
    """``{model: {plan: {material: value}}}`` of the noise-free points (failed fits have none)."""
    values: dict = defaultdict(lambda: defaultdict(dict))
    for p in points:
        if p["noise"] == 0.0 and p["error"].get(metric) is not None:
            values[p["model"]][p["plan"]][p["material"]] = p["error"][metric]
    return values


def _plan_label(plan: str) -> str:
    return plan if plan in REPORT_PLANS else f"designed {plan.rpartition('_')[2]}"


def budget_section() -> list[str]:
    """Error against the number of measured pairs: the ``budget`` study profile (docs/study/budget)."""
    relative, report = BUDGET_STUDY
    if not (ROOT / relative).is_file():
        return []
    study = load(relative)
    points = study["points"]
    pairs = {p["plan"]: p.get("pairs") for p in points}
    plans = sorted(pairs, key=lambda plan: (pairs[plan] or 0, plan in REPORT_PLANS))
    models = list(dict.fromkeys(p["model"] for p in points))
    materials = list(dict.fromkeys(p["material"] for p in points))
    failures = Counter((p["model"], p["plan"]) for p in points if p.get("failure") and not p["error"])
    run = study.get("run", {})
    lines = ["## Error against the number of measured pairs", "",
             f"The `budget` study profile: {', '.join(f'`{m}`' for m in models)} fitted to {len(materials)} validation "
             "materials (six virtual, spectral; nine RGL proxies, RGB) from each plan, without noise, one seed, every "
             "fit scored over the hemisphere and rendered; designed plans are `neuralbrdf plan design`'s for the "
             "spectral NLB (made on training materials). Per plan the median over materials, "
             f"fits that failed left out (their count in brackets). Report: [`{report}`](../{report}). "
             f"Reproduce: `{run.get('command', 'neuralbrdf study --profile budget --out docs/study/budget --jobs 2 --allow-failures')}`.",
             machine_line(study.get("machine")), "",
             "![Error against the number of measured pairs](study/budget/figures/stability_pairs.png)", ""]
    values_of = {metric: _budget_values(points, metric) for metric, _, _ in BUDGET_METRICS}
    for metric, label, digits in BUDGET_METRICS:
        values = values_of[metric]
        rows = []
        for plan in plans:
            row = [_plan_label(plan), str(pairs[plan])]
            for model in models:
                got = values[model].get(plan, {})
                failed = failures[(model, plan)]
                row.append(num(median(got.values()), digits) + (f" ({failed})" if failed else ""))
            rows.append(row)
        lines += [f"Median {label}:", ""] + table(["plan", "pairs"] + [f"`{m}`" for m in models], rows)
    rows = []
    for designed, named in BUDGET_PAIRS:
        if designed not in pairs or named not in pairs:
            continue
        for metric, label, _ in BUDGET_METRICS:
            values = values_of[metric]
            row = [f"{_plan_label(designed)} ÷ {named}", label]
            for model in models:
                a, b = values[model].get(designed, {}), values[model].get(named, {})
                both = [m for m in a if m in b and b[m] > 0]
                ratios = [a[m] / b[m] for m in both]
                row.append(f"{num(median(ratios), 2)} ({sum(r < 1 for r in ratios)}/{len(ratios)})" if ratios else "—")
            rows.append(row)
    lines += ["Designed plans against the report's: per material the ratio of errors, the median over materials "
              "and (in brackets) on how many materials the designed plan is better:", ""]
    lines += table(["plans", "metric"] + [f"`{m}`" for m in models], rows)
    return lines


def study_cluster_section() -> list[str]:
    """The quick profile on a two-worker local Dask cluster against ``--jobs 2`` (benchmarks/study_cluster.py)."""
    data = load(STUDY_CLUSTER)
    load_average = data["load_average"]
    lines = ["### The study on a cluster", "",
             f"The `{data['profile']}` profile ({data['cells']} cells) from an empty cache, run by `neuralbrdf study "
             "--cluster` on a local Dask cluster of two one-thread workers (started before the command, as a cluster "
             "is there before a study is submitted) and by `--jobs 2`, on the same machine, in turn. Wall time of "
             "each command, from start to exit; the target: the cluster within "
             f"{data['target']:.2f}× of `--jobs 2` ([study.md](study.md#on-a-cluster)).", ""]
    rows = [[str(number + 1), f"`{'--jobs 2' if r['first'] == 'jobs' else '--cluster'}`", f"{r['jobs_2']['wall_s']:.1f}",
             f"{r['cluster']['wall_s']:.1f}", f"{r['ratio']:.3f}", f"{r['cluster']['cluster_start_s']:.1f}"]
            for number, r in enumerate(data["repeats"])]
    lines += table(["repeat", "first", "`--jobs 2` s", "`--cluster` s", "cluster ÷ jobs 2", "cluster start s"], rows)
    verdict = "within" if data["ratio_median"] <= data["target"] else "above"
    lines += [f"Median ratio {data['ratio_median']:.3f}, {verdict} the target. Every cell's metrics (all but the "
              f"timings) {'are the same' if data['same_metrics'] else 'differ'} on the cluster and with `--jobs 2`. "
              f"Load average (1 min) {load_average['before'][0]:.2f} before, {load_average['after'][0]:.2f} after.", ""]
    return lines + source_lines(STUDY_CLUSTER, data["command"], data.get("machine"))


# -- the spectral NLB (benchmarks/nlb_spectral_pretrain.json, benchmarks/spectral_nlb.json) ----------


def curve_points(curve: list[dict]) -> str:
    """``step: value`` of a pretraining's validation curve, in one line."""
    return " · ".join(f"{p['step']}: {p['val_logcos_rmse']:.4f}" for p in curve)


def spectral_nlb_section() -> list[str]:
    lines = ["## The spectral NLB", ""]
    if (ROOT / SPECTRAL_PRETRAIN).is_file():
        run = load(SPECTRAL_PRETRAIN)
        best = min(run["curve"], key=lambda p: p["val_logcos_rmse"])
        lines += ["### Pretraining", ""]
        lines += source_lines(SPECTRAL_PRETRAIN, run.get("command", "neuralbrdf train fit --config nlb_spectral_pretrain"))
        lines += [f"{run['curve'][-1]['step']} steps of 8192 samples in {run['wall_time_s'] / 60:.0f} min; the best "
                  f"validation log-cos RMSE {best['val_logcos_rmse']:.4f} at step {best['step']} (epoch "
                  f"{best['epoch']}) is the shipped `neuralbrdf/pretrained/nlb_spectral.ckpt`. By step: "
                  f"{curve_points(run['curve'])}. Drawn in [nlb_spectral_pretrain_curve.png](nlb_spectral_pretrain_curve.png).",
                  ""]
    lines += ["### Against the RGB NLB, ABC and the spectral MLP", "",
              "Each group's materials fitted from one plan by the spectral NLB (`configs/nlb_spectral.yaml`: "
              "spectral measurements band by band, RGB proxies per channel), the RGB NLB's default fit, the in-plane "
              "ABC fit and, for the virtual groups, the spectral MLP; each scored by `neuralbrdf evaluate` against the "
              "material's truth (hemisphere log-cos RMSE; image ΔE2000 at 128 px, 64 spp, `llvm_ad_rgb` for proxies "
              "and `llvm_ad_spectral` for virtual materials, matched seeds). Settings are chosen on the validation "
              "groups (`rgl_validation`, `virtual_validation`), never on the others.", ""]
    if (ROOT / SPECTRAL_NLB_VALIDATION).is_file():
        lines += validation_sweep_lines(load(SPECTRAL_NLB_VALIDATION))
    if (ROOT / SPECTRAL_NLB_TIMING).is_file():
        lines += spectral_timing_lines(load(SPECTRAL_NLB_TIMING))
    for relative, command in SPECTRAL_NLB:
        if not (ROOT / relative).is_file():
            lines += [f"No result file is committed: `{command}` writes `{relative}`, and `python "
                      "docs/make_results.py` then shows it here.", ""]
            continue
        data = load(relative)
        lines += source_lines(relative, command, data.get("machine"))
        lines += spectral_nlb_tables(data)
    return lines


def _fit_time_cell(row: dict, method: str) -> str:
    """A method's median fit time per material and, with several runs, their range."""
    runs = [seconds / row["materials"] for seconds in row[method].get("runs_s", [])]
    spread = f" ({min(runs):.3f}–{max(runs):.3f})" if len(runs) > 1 else ""
    return f"{row[method]['fit_s_per_material']:.3f}{spread}"


def spectral_timing_lines(data: dict) -> list[str]:
    """The fit times of ``benchmarks/spectral_nlb_timing.json`` against their targets."""
    repeats = data.get("repeats", 1)
    lines = ["### Fit time", "", "`fit/wall_time_s` of `neuralbrdf train fit` (the fit proper, its screening of starts included; "
             "not the Python start-up or the loading of the tables), "
             "per material, the spectral NLB beside the RGB NLB on the same tables in the same run (virtual "
             "materials measured on DS1 with 1 % noise, as spectra or converted to sRGB)"
             + (f"; the median of {repeats} runs of each fit, taken in turn with the RGB NLB's, and the range of the runs "
                "(one fit's time varies by ±25 % from minute to minute on this virtual machine)." if repeats > 1 else "."), ""]
    lines += source_lines(SPECTRAL_NLB_TIMING, data["command"])
    load_average = data["machine"]
    lines += [f"Load average (1, 5, 15 min) before {', '.join(f'{v:.1f}' for v in load_average['load_average_before'])}, "
              f"after {', '.join(f'{v:.1f}' for v in load_average['load_average_after'])}.", ""]
    targets = data["targets"]
    rows = []
    for label, row in data["fits"].items():
        target = targets["single_s_per_material" if row["materials"] == 1 else "batched_s_per_material"]
        value = row["nlb_spectral"]["fit_s_per_material"]
        rows.append([label, str(row["materials"]), _fit_time_cell(row, "nlb_spectral"), _fit_time_cell(row, "nlb"),
                     f"{row['nlb_spectral_over_nlb']:.2f}", f"≤ {target:g}", "met" if value <= target else "**missed**"])
    lines += table(["fit", "materials", "spectral NLB s/material", "RGB NLB s/material", "ratio", "target", ""], rows)
    return lines + [""]


def validation_sweep_lines(data: dict) -> list[str]:
    """The settings sweep of ``benchmarks/spectral_nlb_validation.json``: each setting's mean errors
    of the spectral NLB per validation group."""
    lines = ["### Settings chosen on validation materials", "", data["what"], "",
             f"Chosen: {', '.join(f'`{k}` {v}' for k, v in data['chosen'].items())}. Each sweep is `{data['command']}`.", ""]
    groups = list(dict.fromkeys(g for sweep in data["sweeps"].values() for g in sweep["groups"]))
    rows = []
    for name, sweep in data["sweeps"].items():
        settings = f"`{' '.join(sweep['spectral_args'])}`" if sweep["spectral_args"] else "defaults"
        row = [f"`{name}`", f"{settings} ({sweep['note']})" if sweep.get("note") else settings]
        for group in groups:
            block = sweep["groups"].get(group)
            if block is None:
                row.append("")
                continue
            logcos = block["hemisphere_logcos_rmse"]["mean"]["nlb_spectral"]
            delta_e = (block.get("image_delta_e2000_mean") or {}).get("mean", {}).get("nlb_spectral")
            row.append(num(logcos) + ("" if delta_e is None else f" / {delta_e:.2f}"))
        rows.append(row)
    lines += ["Spectral NLB mean hemisphere log-cos RMSE (/ mean image ΔE2000 where rendered):", ""]
    return lines + table(["sweep", "settings"] + groups, rows)


def spectral_nlb_tables(data: dict) -> list[str]:
    """The tables of a ``benchmarks/spectral_nlb.json``: per group, every material and method."""
    lines = []
    if data.get("spectral_args"):
        lines += [f"Spectral NLB settings: `{' '.join(data['spectral_args'])}`.", ""]
    for label, block in data["groups"].items():
        methods = list(dict.fromkeys(m for row in block["materials"].values() for m in row))

        def cell(scores):
            if scores is None:
                return "—"
            if "failed" in scores:
                return "failed"
            return f"{num(scores.get('hemisphere_logcos_rmse'))} / {num(scores.get('image_delta_e2000_mean'), 2)}"

        rows = [[name] + [cell(row.get(m)) for m in methods] for name, row in block["materials"].items()]
        lines += [f"#### {label}", "", "Hemisphere log-cos RMSE / image ΔE2000 mean:", ""]
        lines += table(["material"] + [f"`{m}`" for m in methods], rows)
        summary = block.get("summary", {})
        for metric in ("hemisphere_logcos_rmse", "image_delta_e2000_mean"):
            if metric not in summary:
                continue
            result = summary[metric]
            medians = ", ".join(f"`{m}` {num(v, 4 if 'logcos' in metric else 2)}" for m, v in result["median"].items())
            beats = result.get("nlb_spectral_beats", {})
            wins = ", ".join(f"`{m}` on {v:.0%}" for m, v in beats.items())
            lines += [f"- {metric}, medians over {result.get('materials', len(rows))} materials: {medians}"
                      + (f"; the spectral NLB beats {wins} of them." if wins else ".")]
        failed = {m: n for m, n in summary.get("failed", {}).items() if n}
        if failed:
            lines += [f"- failed fits: {', '.join(f'`{m}` {n}' for m, n in failed.items())}."]
        lines += [""]
    return lines


# -- the page -----------------------------------------------------------------------------------


def _auto_rows(materials: dict) -> list[list[str]]:
    rows = []
    for name, row in materials.items():
        cells = []
        for method in ("abc", "nlb_spectral", "auto"):
            r = row[method]
            if "failed" in r:
                cells.append("failed")
                continue
            image = r.get("image_delta_e2000_mean")
            cells.append(num(r["hemisphere_logcos_rmse"]) + (f" ({image:.2f})" if image is not None else ""))
        auto = row["auto"]
        ratio = (auto["hemisphere_logcos_rmse"] / row["abc"]["hemisphere_logcos_rmse"]
                 if "failed" not in auto and "failed" not in row["abc"] else None)
        inplane = auto.get("inplane_logcos_rmse") or {}
        rows.append([name, *cells, auto.get("choice", "—"), num(ratio, 3),
                     f"{num(inplane.get('abc'))} / {num(inplane.get('nlb_spectral'))}"])
    return rows


def auto_section() -> list[str]:
    relative, command = AUTO
    lines = ["## Auto against ABC and the spectral NLB", ""]
    if not (ROOT / relative).is_file():
        return lines + [f"No result file is committed: `{command}` writes `{relative}`.", ""]
    data = load(relative)
    lines += source_lines(relative, command, data.get("machine"))
    lines += ["Each material's measurement on DS1 fitted three times: `configs/abc.yaml`, `configs/nlb_spectral.yaml` "
              "and `configs/auto.yaml` (the better of the two on the measured samples, [models.md](models.md#auto)); "
              "each exported and scored by `neuralbrdf evaluate` against the truth: hemisphere log-cos RMSE "
              "(102 400 pairs) and, for the virtual materials, the image ΔE2000 mean in brackets (`llvm_ad_spectral`, "
              "128 px, 64 spp, matched seeds). The last columns: the choice, auto's error over ABC's, and the two "
              "candidates' log-cos RMSE on the measured samples that the choice was made on. This run's fit times "
              "were taken on a loaded machine; the fit times below are from an idle one.", ""]
    pooled = {}
    for group, block in data["groups"].items():
        summary = block["summary"]
        lines += [f"### {group}", "", AUTO_GROUPS.get(group, group) + ".", ""]
        lines += table(["material", "ABC", "spectral NLB", "auto", "choice", "auto / ABC", "in-plane ABC / NLB"],
                       _auto_rows(block["materials"]))
        for metric, label in (("hemisphere_logcos_rmse", "Hemisphere log-cos RMSE"),
                              ("image_delta_e2000_mean", "Image ΔE2000 mean")):
            m = summary.get(metric)
            if m:
                lines += [f"{label}: medians ABC {num(m['median']['abc'])}, spectral NLB "
                          f"{num(m['median']['nlb_spectral'])}, auto {num(m['median']['auto'])}; auto within 1.02× "
                          f"ABC on {m['auto_within_1.02_abc']:.0%} of the materials, closer than ABC on "
                          f"{m['auto_closer_than_abc']:.0%}, at worst {m['auto_over_abc_max']:.2f}× ABC; auto's median "
                          f"over the spectral NLB's {m['auto_median_over_nlb_spectral_median']:.3f}.", ""]
        lines += [f"Choices: ABC {summary['choices']['abc']}, spectral NLB {summary['choices']['nlb_spectral']}.", ""]
        if group in ("virtual_validation", "rgl_validation"):
            pooled.update(block["materials"])
    if pooled:
        value = {m: [r[m]["hemisphere_logcos_rmse"] for r in pooled.values()] for m in ("abc", "nlb_spectral", "auto")}
        within = sum(u <= 1.02 * a for u, a in zip(value["auto"], value["abc"]))
        lines += ["### Against the targets", "",
                  f"On the {len(pooled)} validation materials (virtual and RGL proxies together): auto within 1.02× "
                  f"ABC's hemisphere error on {within} of {len(pooled)} ({within / len(pooled):.0%}; target ≥ 90 %), "
                  f"median {num(median(value['auto']))} against the spectral NLB's {num(median(value['nlb_spectral']))} "
                  f"and ABC's {num(median(value['abc']))} (target: no worse than the spectral NLB's).", ""]
    timing_relative, timing_command = AUTO_TIMING
    lines += ["### Auto's fit time", ""]
    if not (ROOT / timing_relative).is_file():
        lines += [f"No result file is committed: `{timing_command}` writes `{timing_relative}`.", ""]
    else:
        timing = load(timing_relative)
        lines += source_lines(timing_relative, timing_command)
        load_before = timing["machine"]["load_average_before"][0]
        load_after = timing["machine"]["load_average_after"][0]
        for table_kind, r in timing["fits"].items():
            candidates = r["runs_s"]["auto_candidates"]
            abc = median([c.get("abc") for c in candidates])
            nlb = median([c.get("nlb_spectral") for c in candidates])
            lines += [f"- {table_kind} table: auto {num(r['median_s']['auto'], 2)} s against the spectral NLB's "
                      f"{num(r['median_s']['nlb_spectral'], 2)} s (`fit/wall_time_s`, median of {timing['repeats']}), "
                      f"**{r['auto_over_nlb_spectral']:.2f}×** (target ≤ 1.5×); inside the auto fit, side by side, ABC "
                      f"{num(abc, 2)} s and the spectral NLB {num(nlb, 2)} s."]
        lines += ["", f"Load average {load_before:.2f} before and {load_after:.2f} after the run.", ""]
    rules_relative, rules_command = AUTO_RULES
    if (ROOT / rules_relative).is_file():
        rules = load(rules_relative)
        lines += ["### The rule and its alternatives", ""]
        lines += source_lines(rules_relative, rules_command)
        lines += ["Both candidates' predictions at the measured pairs and on 36 864 hemisphere pairs; each rule sees "
                  "the measured pairs only ([design.md](design.md#never-worse-than-abc)). Per rule: the median of its "
                  "hemisphere error over ABC's, the share of materials within 1.02× ABC and below ABC, the worst "
                  "ratio, and its median over the spectral NLB's median. `oracle` is the best blend for the "
                  "hemisphere (it needs the truth: a bound, not a rule).", ""]
        blocks = [("validation: virtual and RGL proxies", rules.get("validation_pooled"))]
        blocks += [(group, block["summary"]) for group, block in rules["groups"].items() if group == "rgl_real"]
        for label, summary in blocks:
            if not summary:
                continue
            lines += [f"{label}:", ""]
            lines += table(["rule", "median / ABC", "≤ 1.02× ABC", "< ABC", "worst / ABC", "median / NLB median"],
                           [[rule, num(s["median_over_abc"], 3), f"{s['within_1.02_abc']:.0%}", f"{s['below_abc']:.0%}",
                             num(s["worst_over_abc"], 2), num(s["median_over_nlb_spectral_median"], 3)]
                            for rule, s in summary.items()])
    return lines


def rgl_real_section() -> list[str]:
    relative, command = RGL_REAL
    lines = ["## A real measurement: RGL green acrylic felt", ""]
    if not (ROOT / relative).is_file():
        return lines + [f"No result file is committed: `{command}` writes `{relative}`.", ""]
    data = load(relative)
    render = data["render"]
    lines += [f"The RGL material database's `{data['file']}` ({data['description']}; Dupuy & Jakob 2018, EPFL, CC0), "
              "a real measurement, sampled on each plan by Mitsuba's `measured` plugin and fitted by each method "
              "(ABC: `configs/abc.yaml`; spectral MLP: `configs/spectral_mlp.yaml` on the samples upsampled to "
              "spectra as the renderer upsamples RGB; RGB NLB: `configs/nlb_latent.yaml`; spectral NLB: "
              "`configs/nlb_spectral.yaml`, per channel). Every score is against the measurement itself through "
              "the plugin ([evaluate.md](evaluate.md#neuralbrdf-evaluate)): hemisphere log-cos RMSE over 102 400 "
              f"pairs, and image ΔE2000 against the plugin's own render of the preview scene ({render['variant']}, "
              f"{render['resolution']} px, {render['spp']} spp, matched seeds; `noise`: the truth against itself at "
              "other seeds).", ""]
    lines += source_lines(relative, command, data.get("machine"))
    rows = []
    for plan, methods in data["plans"].items():
        for method in sorted(methods, key=lambda m: list(RGL_METHODS).index(m) if m in RGL_METHODS else len(RGL_METHODS)):
            scores, name = methods[method], RGL_METHODS.get(method, method)
            if "failed" in scores:
                rows.append([plan, name] + ["fit failed"] + ["—"] * 6)
                continue
            rows.append([plan, name, num(scores["hemisphere_logcos_rmse"]), num(scores["image_delta_e2000_mean"], 2),
                         num(scores["image_delta_e2000_p95"], 2), num(scores["image_noise_delta_e2000_mean"], 2),
                         num(scores["inplane_glossy_rel_rmse"], 3), num(scores["inplane_diffuse_rel_rmse"], 3),
                         num(scores["fit_time_s"], 1)])
    lines += table(["plan", "method", "hemisphere log-cos RMSE", "ΔE2000 mean", "ΔE2000 p95", "noise ΔE mean",
                    "in-plane glossy rel. RMSE", "in-plane diffuse rel. RMSE", "fit s"], rows)
    for plan, methods in data["plans"].items():
        spectral, abc = methods.get("nlb_spectral", {}), methods.get("abc", {})
        if "hemisphere_logcos_rmse" in spectral and "hemisphere_logcos_rmse" in abc:
            ratio = spectral["hemisphere_logcos_rmse"] / abc["hemisphere_logcos_rmse"]
            closer = spectral["image_delta_e2000_mean"] < abc["image_delta_e2000_mean"]
            gap = abs(spectral["image_delta_e2000_mean"] - abc["image_delta_e2000_mean"])
            noise = spectral["image_noise_delta_e2000_mean"]
            lines += [f"From {plan}, the spectral NLB's hemisphere log-cos RMSE is {ratio:.2f}× ABC's, and its image "
                      f"ΔE2000 mean is {'below' if closer else 'not below'} ABC's "
                      f"({spectral['image_delta_e2000_mean']:.2f} against {abc['image_delta_e2000_mean']:.2f}: "
                      f"a gap of {gap:.2f}, against {noise:.2f} between two renders of the truth at other seeds"
                      f"{' — the images barely tell them apart, the hemisphere does' if gap < 0.1 * noise else ''}).",
                      ""]
    first = next(iter(data["plans"]))
    pictures = [f"[{RGL_METHODS.get(m, m)}](../benchmarks/rgl_real_{first}_{m}.png)" for m in RGL_METHODS
                if (ROOT / "benchmarks" / f"rgl_real_{first}_{m}.png").is_file()]
    if pictures:
        lines += [f"The {first} comparisons (truth render, model render, ΔE2000 map) are committed beside the file: "
                  + ", ".join(pictures) + ".", ""]
    return lines


# -- the caption of the README's picture (benchmarks/main_job/evaluation.json) -------------


def main_job_caption(scores: dict) -> str:
    """The README's caption of ``docs/gold_truth_vs_model.png``, its numbers from ``scores``."""
    text = (
        f"{CAPTION_START} (`out/demo/gold_eval/comparison.png`, committed as "
        f"`docs/gold_truth_vs_model.png` with its scores, [`{MAIN_JOB}`]({MAIN_JOB})): left, the ground truth "
        "of the virtual gold, a glossy gold sphere on a grey checkerboard floor under a key and a rim light; "
        "middle, the 3×10 spectral MLP trained on 677 of the 1001 shipped DS1 samples (the other 324, at the report's Table 5.1 incident angles, choose its checkpoint), indistinguishable at this size; "
        "right, their per-pixel CIEDE2000 on a 0–10 scale, black over the floor and most of the sphere "
        f"(ΔE mean {scores['image_delta_e2000_mean']:.2f}, p95 {scores['image_delta_e2000_p95']:.2f}, against a "
        f"render noise of {scores['noise']['image_delta_e2000_mean']:.2f} between two seeds of the truth; "
        f"`{scores['variant']}`, {scores['resolution']}², {scores['spp']} spp, seed {scores['seed']}), with the "
        "remaining error in a thin bright ring on the sphere's rim — grazing angles beyond the measured ±60°, "
        "where the model extrapolates — and a spot in the rim light's highlight at the upper right."
    )
    return textwrap.fill(text, width=99, break_long_words=False, break_on_hyphens=False) + "\n"


def readme_with_caption(readme: str) -> str:
    """``readme`` with the paragraph that starts with :data:`CAPTION_START` written from :data:`MAIN_JOB`."""
    start = readme.index("\n" + CAPTION_START) + 1
    end = readme.index("\n\n", start) + 1
    return readme[:start] + main_job_caption(load(MAIN_JOB)) + readme[end:]


def build() -> str:
    lines = ["# Results", "",
             "<!-- Generated by docs/make_results.py from the committed result files: edit the script, not this "
             "page. -->", "",
             "Every table below is computed by `python docs/make_results.py` from a result file committed in "
             "`benchmarks/` or `docs/study/`; each section names its file, the command that rewrites it and the "
             "machine it ran on. Absolute times are of that machine; compare ratios measured in one run. "
             "Metrics are defined in [evaluate.md](evaluate.md#metrics); the decisions they justify are in "
             "[design.md](design.md).", "",
             "Contents: [NLB against ABC](#nlb-latent-fits-against-abc-on-merl-proxies) · "
             "[networks](#pretrained-networks-compared) · [latent prior](#the-latent-priors-weight) · "
             "[rendered held-out ten](#where-users-look-the-held-out-ten-rendered) · "
             "[ABC against NLB in the image](#abc-against-nlb-in-the-image-the-reports-five) · "
             "[speed](#rendering-speed-and-throughput) · [level of detail](#level-of-detail-selection-on-the-demo-scenes) · "
             "[study](#the-study) · [spectral NLB](#the-spectral-nlb) · "
             "[auto](#auto-against-abc-and-the-spectral-nlb) · "
             "[a real measurement](#a-real-measurement-rgl-green-acrylic-felt)", ""]
    for section in (nlb_section, networks_section, prior_section, render_check_section, accuracy_section,
                    speed_section, lod_section, studies_section, spectral_nlb_section, auto_section,
                    rgl_real_section):
        lines += section()
    while lines and lines[-1] == "":
        lines.pop()
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--check", action="store_true", help="exit 1 if docs/results.md differs from what is built")
    args = parser.parse_args(argv)
    readme = README.read_text(encoding="utf-8")
    pages = ((OUT, OUT.read_text(encoding="utf-8") if OUT.is_file() else "", build()),
             (README, readme, readme_with_caption(readme)))
    if args.check:
        stale = [path for path, current, text in pages if current != text]
        for path in stale:
            print(f"{path.relative_to(ROOT)} is stale: run python docs/make_results.py", file=sys.stderr)
        return 1 if stale else 0
    for path, current, text in pages:
        if current != text:
            path.write_text(text, encoding="utf-8")
            print(f"wrote {path.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
