"""``DIR/index.html``: the study as one static page a person reads top down (docs/results.md, docs/study.md).

The page leads with what to use: whether every cell gave a result, then per material the model
to use under each ΔE2000 budget (budgets that choose the same model share one row), then the
pooled speed-accuracy chart; everything else (per-material charts, stability, the failure map,
per-angle errors, renders, every cell, the machine and how to reproduce) sits below in collapsed
sections.  Text is at least 13 px and figures are shown at their own size (drawn for a page
1400 px wide, :mod:`neuralbrdf.study.charts`).

Self-contained: inline CSS, no script, no network; figures are relative links to ``figures/*.png``
and the data to ``study.json``.  Every number shown that comes from ``study.json`` carries
``data-json="PATH"`` (a dotted path into it, list indices as numbers), so a test can check that
the page and the file agree; numbers are printed with :data:`NUMBER_FORMAT`.
:func:`rebuild` draws figures and page again from ``study.json`` alone.
"""

from __future__ import annotations

import html
import json
import struct
from collections import Counter
from pathlib import Path

from neuralbrdf.atomic import atomic_write
from neuralbrdf.errors import InputError
from neuralbrdf.study import aggregate
from neuralbrdf.study.aggregate import ACCURACY_METRIC, BUDGETS_DELTA_E, THRESHOLD_CAUSE, THRESHOLD_FACTOR
from neuralbrdf.study.charts import CAUSE_LETTERS
from neuralbrdf.study.figures import pooled_materials, rendered, write_figures

NUMBER_FORMAT = "{:.4g}"
ERROR_COLUMNS = ("image_delta_e2000_mean", "hemisphere_logcos_rmse", "inplane_glossy_rel_rmse",
                 "inplane_diffuse_rel_rmse")
COST_COLUMNS = ("render_ratio", "mqueries_per_s", "fit_time_s", "parameters")
#: Column headings of the table of every cell.
HEADINGS = {"render_ratio": "render time ÷ roughconductor", "mqueries_per_s": "M queries/s", "fit_time_s": "fit time (s)",
            "parameters": "parameters", "image_delta_e2000_mean": "mean ΔE2000", "hemisphere_logcos_rmse": "hemisphere log-cos RMSE",
            "inplane_glossy_rel_rmse": "in-plane glossy rel. RMSE", "inplane_diffuse_rel_rmse": "in-plane diffuse rel. RMSE"}
#: The failure cause of a cell whose process ended without a result (no finding about a method).
CRASHED = "cell_crashed"
#: Cells without a result or model listed by name at the top of the page; the rest are counted.
LISTED = 20
#: Pixels a render is shown at (its pixels enlarged, not smoothed).
RENDER_PX = 256
STYLE = """
body{font:15px/1.45 system-ui,sans-serif;color:#222;margin:0}
main{max-width:1320px;margin:0 auto;padding:4px 20px 40px}
h1{font-size:26px;margin:.6em 0 .2em}
h2{font-size:21px;margin:1.3em 0 .4em}
h3{font-size:17px;margin:1em 0 .3em}
p,li{max-width:1100px}
table{border-collapse:collapse;font-size:14px;margin:.5em 0}
td,th{border:1px solid #ccc;padding:3px 8px;text-align:right;vertical-align:top}
th{background:#f3f3f3}
td.t,th.t{text-align:left}
table.rec td,table.rec th{font-size:15px;padding:4px 10px}
table.rec td.m{font-weight:600;background:#fafafa}
.status{padding:10px 16px;border-left:6px solid;border-radius:4px;margin:.8em 0}
.status.ok{background:#eef7ee;border-color:#3a3}
.status.warn{background:#fff5e0;border-color:#e90}
.status.bad{background:#fdeaea;border-color:#c00}
.status ul{margin:.3em 0}
.fail{color:#a00}
code{background:#f4f4f4;padding:0 3px;font-size:14px}
details{border:1px solid #ddd;border-radius:5px;margin:10px 0;padding:2px 10px}
summary{font-size:18px;font-weight:600;cursor:pointer;padding:6px 0}
figure{margin:10px 0}
figcaption{font-size:14px;color:#444;max-width:1100px}
img{max-width:100%;height:auto}
.pair{display:grid;grid-template-columns:repeat(auto-fill,minmax(630px,1fr));gap:12px}
.renders{display:flex;flex-wrap:wrap;gap:12px}
.renders figure{margin:0;width:256px}
.renders img{image-rendering:pixelated}
.wide{overflow-x:auto}
"""


def number(value, path: str, tag: str = "td") -> str:
    """An element (a table cell by default) holding a number from ``study.json`` at ``path``."""
    if value is None:
        return f'<{tag} data-json="{path}" data-null="1">–</{tag}>'
    return f'<{tag} data-json="{path}">{NUMBER_FORMAT.format(value)}</{tag}>'


def text(value, css: str = "t") -> str:
    return f'<td class="{css}">{html.escape("–" if value is None else str(value))}</td>'


def png_size(path: Path) -> tuple[int, int]:
    """``(width, height)`` in pixels from a PNG file's header."""
    with open(path, "rb") as handle:
        header = handle.read(24)
    if header[:8] != b"\x89PNG\r\n\x1a\n":
        raise InputError("not a PNG file", path=path)
    return struct.unpack(">II", header[16:24])


def figure(figures_dir: Path, name: str, alt: str, caption: str = "") -> str:
    """A figure shown at its own size (width and height from the file), linked to itself."""
    src = "figures/" + html.escape(name)
    width, height = png_size(figures_dir / name)
    return (f'<figure><a href="{src}"><img src="{src}" width="{width}" height="{height}" alt="{html.escape(alt)}"></a>'
            + (f"<figcaption>{caption}</figcaption>" if caption else "") + "</figure>")


def distinct_budget_rows(summary: list[dict]) -> list[dict]:
    """The budget table (``study.json``'s ``summary``: per material and budget, in budget order)
    with neighbouring budgets of one material that choose the same model merged: per row the
    material, the model (``None``: none within the budget) and ``first``/``last``, the indices in
    ``summary`` of its smallest and largest budget."""
    rows: list[dict] = []
    for i, b in enumerate(summary):
        last = rows[-1] if rows else None
        if last and last["material"] == b["material"] and last["model"] == b["model"]:
            last["last"] = i
        else:
            rows.append({"material": b["material"], "model": b["model"], "first": i, "last": i})
    return rows


def _recommendation(study: dict) -> str:
    summary = study["summary"]
    rows = distinct_budget_rows(summary)
    spans = Counter(r["material"] for r in rows)
    out = ['<table class="rec"><tr><th class="t">material</th><th>mean ΔE2000 budget</th><th class="t">model to use</th>'
           "<th>its mean ΔE2000</th><th>its render time ÷ roughconductor</th></tr>"]
    seen = set()
    for r in rows:
        first, last = r["first"], r["last"]
        cells = "" if r["material"] in seen else f'<td class="t m" rowspan="{spans[r["material"]]}">{html.escape(r["material"])}</td>'
        seen.add(r["material"])
        budget = number(summary[first]["budget_delta_e"], f"summary.{first}.budget_delta_e", "span")
        if last != first:
            budget += " – " + number(summary[last]["budget_delta_e"], f"summary.{last}.budget_delta_e", "span")
        cells += f"<td>{budget}</td>"
        if r["model"] is None:
            cells += '<td class="t fail" colspan="3">no model within this budget</td>'
        else:
            cells += (f'<td class="t"><b>{html.escape(r["model"])}</b></td>'
                      + number(summary[first][ACCURACY_METRIC], f"summary.{first}.{ACCURACY_METRIC}")
                      + number(summary[first]["render_ratio"], f"summary.{first}.render_ratio"))
        out.append(f"<tr>{cells}</tr>")
    return "".join(out) + "</table>"


def _listed(points: list[dict]) -> str:
    """The first :data:`LISTED` cells by name, condition and message; the rest counted."""
    items = "".join(f"<li>{html.escape(p['material'])} / {html.escape(p['model'])} / {html.escape(_condition(p))}: "
                    f"{html.escape(p.get('message') or 'no message')}</li>" for p in points[:LISTED])
    more = f"<li>and {len(points) - LISTED} more (see <i>Every cell</i>)</li>" if len(points) > LISTED else ""
    return f"<ul>{items}{more}</ul>"


def _status(study: dict) -> str:
    """Whether every cell gave a model, from the points' failure causes: crashed cells (the study
    is incomplete) and cells without a model (a fit, export or evaluation that failed) in red and
    named; cells whose error is above the threshold, a measurement of the study, counted; cached
    files the run had to redo (``health.repaired``), when ``study.json`` records them."""
    points = study["points"]
    crashed = [p for p in points if p["failure"] == CRASHED]
    no_model = [p for p in points if p["failure"] not in (None, CRASHED, THRESHOLD_CAUSE)]
    above = sum(p["failure"] == THRESHOLD_CAUSE for p in points)
    repaired = (study.get("health") or {}).get("repaired") or []
    parts = []
    if crashed:
        parts.append(f'<div class="status bad"><b>{len(crashed)} of {len(points)} cells crashed and have no result</b>: '
                     "this study is incomplete, and the recommendation and charts leave those cells out. Running the "
                     f"same command again retries them (finished cells are reused).{_listed(crashed)}</div>")
    if no_model:
        causes = ", ".join(f"{CAUSE_LETTERS.get(c, (c, c))[1]}: {n}"
                           for c, n in sorted(Counter(p["failure"] for p in no_model).items()))
        parts.append(f'<div class="status bad"><b>{len(no_model)} of {len(points)} cells failed and have no model</b> '
                     f"({causes}): their models are missing from the recommendation and the charts.{_listed(no_model)}</div>")
    if not parts:
        parts.append(f'<div class="status ok">Every one of the {len(points)} cells gave a model.</div>')
    if above:
        parts.append(f'<div class="status warn"><b>{above} of {len(points)} cells</b> have an error above '
                     f"{THRESHOLD_FACTOR:g}× the same model's DS1 noise-free error: fits that broke under fewer samples "
                     "or noise, a finding of the study — where and why under <i>Where methods fail</i> below.</div>")
    if repaired:
        files = f"{len(repaired)} cached file" + ("s were" if len(repaired) != 1 else " was")
        parts.append(f'<div class="status warn">{files} damaged or stale and redone.</div>')
    return "".join(parts)


def _when(started: str) -> str:
    """An ISO 8601 time with its offset (``2026-12-02T14:11:20+00:00``) as ``2026-12-02 14:11 UTC``."""
    from datetime import datetime, timezone

    try:
        moment = datetime.fromisoformat(started)
    except ValueError:
        return started
    if moment.tzinfo is not None:
        moment = moment.astimezone(timezone.utc)
    return moment.strftime("%Y-%m-%d %H:%M") + (" UTC" if moment.tzinfo is not None else "")


def _condition(p: dict) -> str:
    return p["plan"] + (f" {p['noise'] * 100:g}% noise" if p["noise"] else "") + f", seed {p['seed']}"


def _points_table(study: dict) -> str:
    head = "".join(f"<th>{html.escape(HEADINGS.get(h, h))}</th>" for h in (
        "material", "model", "plan", "noise", "seed", *COST_COLUMNS, *ERROR_COLUMNS, "failure"))
    rows = []
    for i, p in enumerate(study["points"]):
        chose = (p.get("auto") or {}).get("choice")  # an auto fit: the candidate it kept
        cells = [text(p["material"]), text(p["model"] + (f" ({chose})" if chose else "")), text(p["plan"]),
                 number(p["noise"], f"points.{i}.noise"),
                 number(p["seed"], f"points.{i}.seed")]
        cells += [number(p["cost"][k], f"points.{i}.cost.{k}") if k in p["cost"] else text(None) for k in COST_COLUMNS]
        cells += [number(p["error"][k], f"points.{i}.error.{k}") if k in p["error"] else text(None)
                  for k in ERROR_COLUMNS]
        failure = p["failure"]
        cells.append(f'<td class="t fail" title="{html.escape(p.get("message") or "")}">{html.escape(failure)}</td>'
                     if failure else text(None))
        rows.append("<tr>" + "".join(cells) + "</tr>")
    return f'<div class="wide"><table><tr>{head}</tr>{"".join(rows)}</table></div>'


def _failure_table(study: dict) -> str:
    rows = ['<tr><th class="t">model</th><th class="t">condition</th><th>cells</th><th>failed</th><th class="t">causes</th>'
            "<th>median log-cos RMSE</th><th>std over cells</th></tr>"]
    for i, f in enumerate(study["failures"]):
        causes = ", ".join(f"{c}: {n}" for c, n in sorted(f["causes"].items())) or "–"
        rows.append("<tr>" + text(f["model"]) + text(f["condition"]) + number(f["cells"], f"failures.{i}.cells")
                    + number(f["failed"], f"failures.{i}.failed") + text(causes)
                    + number(f.get("median_error"), f"failures.{i}.median_error")
                    + number(f.get("seed_std_error"), f"failures.{i}.seed_std_error") + "</tr>")
    return "<table>" + "".join(rows) + "</table>"


def _group_tables(study: dict) -> str:
    """Per variant group: each member's median hemisphere log-cos RMSE over seeds, per material."""
    parts = []
    for g, table in enumerate(study.get("groups", [])):
        head = "".join(f"<th>{html.escape(m)}</th>" for m in table["materials"])
        rows = [f'<tr><th class="t">{html.escape(table["group"])}</th><th class="t">variant</th>{head}'
                "<th>median</th><th>cells</th></tr>"]
        for r, row in enumerate(table["members"]):
            path = f"groups.{g}.members.{r}"
            rows.append("<tr>" + text(row["label"]) + text(row["model"])
                        + "".join(number(v["median"], f"{path}.per_material.{i}.median")
                                  for i, v in enumerate(row["per_material"]))
                        + number(row["median"], f"{path}.median") + number(row["cells"], f"{path}.cells") + "</tr>")
        parts.append('<div class="wide"><table>' + "".join(rows) + "</table></div>")
    return "".join(parts)


def _names(models: list[str]) -> str:
    return html.escape(", ".join(models) or "none")


def _section(title: str, body: str) -> str:
    return f"<details><summary>{html.escape(title)}</summary>{body}</details>"


def _per_material_section(study: dict, figs: dict, figures_dir: Path) -> str:
    fronts = study["pareto"]
    parts = ["<p>Each model's main cell (DS1, no noise, seed 0) per material; the dashed line joins the "
             "models no other beats on both cost and error (the Pareto front).</p>"]
    for material, name in figs["speed_accuracy"].items():
        caption = (f"Pareto front against render cost: {_names(fronts['render_ratio']['per_material'].get(material, []))}; "
                   f"against fit time: {_names(fronts['fit_time_s']['per_material'].get(material, []))}.")
        parts.append(figure(figures_dir, name, f"{material}: mean ΔE2000 against render cost and against fit time, "
                                               "one point per model", caption))
    return _section("Speed against accuracy per material", "".join(parts))


def _pairs_part(figs: dict, figures_dir: Path) -> str:
    """The chart of error against the number of measured pairs, with its heading; none without a plan sweep."""
    if "pairs" not in figs["stability"]:
        return ""
    return "<h2>Error against the number of measured pairs</h2>" + figure(
        figures_dir, figs["stability"]["pairs"], "error against the number of measured direction pairs, one line per "
        "model and kind of plan, hemisphere log-cos and, where the sweep was rendered, image ΔE2000",
        "Without noise: per model the median over materials of each material's median over seeds, the band from "
        "first to third quartile over materials; solid: the report's plans DS1–DS4, dashed: plan files (such as "
        "designed plans, <code>neuralbrdf plan design</code>). Image ΔE2000 is shown where the sweep's cells were "
        "rendered (<code>stability.render</code>).")


def _stability_section(study: dict, figs: dict, figures_dir: Path) -> str:
    stability = figs["stability"]
    sweep = [figure(figures_dir, stability[key], alt) for key, alt in (
        ("plans", "box plots of the hemisphere log-cos error per sampling plan, per model"),
        ("noise", "box plots of the hemisphere log-cos error per relative noise level, per model")) if key in stability]
    seeding = "".join(f"<li>{html.escape(method)}: {html.escape(what)}</li>" for method, what in study.get("seeding", {}).items())
    parts = ["<p>Hemisphere log-cosine RMSE against the truth over seeds and materials per sampling plan "
             "(report Figs. 6.5/6.6/6.11/6.12) and per relative measurement noise. A seed whose fit repeats "
             "another seed's exactly (a deterministic fit) is counted once.</p>",
             f"<p>What a seed changes:</p><ul>{seeding}</ul>" if seeding else "",
             f'<div class="pair">{"".join(sweep)}</div>']
    groups = [figure(figures_dir, stability[f"group {t['group']}"],
                     f"{t['group']}: box plot of the error over seeds per member",
                     f"{_seeds(study['points'], t)} on {html.escape(', '.join(t['materials']))} (DS1, no noise).")
              for t in study.get("groups", []) if f"group {t['group']}" in stability]
    if groups:
        parts += ["<h3>Variant groups</h3>", f'<div class="pair">{"".join(groups)}</div>',
                  "<p>Median hemisphere log-cos RMSE over seeds per material (DS1, no noise; the materials every "
                  "member fits).</p>", _group_tables(study)]
    return _section("Stability over sampling plans, noise and seeds", "".join(parts))


def _seeds(points: list[dict], table: dict) -> str:
    """``Over seeds 0, 1, 2`` (or ``One seed (0)``): the seeds of distinct fits a variant group's box
    plot is over."""
    models = {row["model"] for row in table["members"]}
    seeds = sorted({p["seed"] for p in aggregate.distinct_fits(points) if p["model"] in models and p["plan"] == "DS1"
                    and not p["noise"] and p["material"] in table["materials"]})
    return f"Over seeds {', '.join(map(str, seeds))}" if len(seeds) > 1 else f"One seed ({', '.join(map(str, seeds))})"


def _failure_section(study: dict, figs: dict, figures_dir: Path) -> str:
    parts = ["<ul>" + "".join(f"<li>{html.escape(s)}</li>" for s in study["sentences"].values()) + "</ul>"]
    if figs.get("failure_map"):
        parts.append(figure(figures_dir, figs["failure_map"], "failure map: failed cells per model and condition"))
    parts.append(_failure_table(study))
    return _section("Where methods fail", "".join(parts))


def _per_angle_section(figs: dict, figures_dir: Path, rerun: str) -> str:
    if not figs["rel_rmse_vs_angle"]:
        return _section("Error per incident angle and per channel",
                        "<p>This <code>study.json</code> holds no per-angle errors, so these charts cannot be drawn "
                        f"from it; a study run writes them: <code>{html.escape(rerun)}</code>.</p>")
    angle = [figure(figures_dir, name, f"{material}: glossy relative RMSE per incident angle, one line per model")
             for material, name in figs["rel_rmse_vs_angle"].items()]
    channel = [figure(figures_dir, name, f"{material}: box plots of the glossy relative RMSE per channel, one panel per model")
               for material, name in figs["per_channel"].items()]
    return _section("Error per incident angle and per channel",
                    "<p>Glossy relative RMSE of the main fits against the truth per incident angle "
                    "(report Figs. 4.6/4.7, 4.13/4.14), and per wavelength or channel over incident angles "
                    f'(report Fig. 5.3).</p><div class="pair">{"".join(angle)}</div>{"".join(channel)}')


def _render_card(src: str, alt: str, caption: str) -> str:
    return (f'<figure><img src="figures/{html.escape(src)}" width="{RENDER_PX}" height="{RENDER_PX}" '
            f'alt="{html.escape(alt)}"><figcaption>{caption}</figcaption></figure>')


def _renders_section(study: dict, figs: dict, rerun: str) -> str:
    renders = figs["renders"]
    if not renders:
        return _section("Renders", "<p>The renders are copied from the study's cell folders when it runs; this folder "
                                   f"has neither, so none are shown. A study run renders them: <code>{html.escape(rerun)}</code>.</p>")
    index = {id(p): i for i, p in enumerate(study["points"])}
    parts = ["<p>Each model's render of the material-preview scene beside the truth's (same seeds and paths); "
             "the numbers are the mean and 95th percentile of the per-pixel CIEDE2000 difference.</p>"]
    for material, shown in renders.items():
        cards = [_render_card(shown["truth"], f"{material}: truth render", f"<b>truth</b> ({html.escape(material)})")]
        for p in rendered(study["points"], material):
            if p["model"] in shown["models"]:
                i = index[id(p)]
                cards.append(_render_card(
                    shown["models"][p["model"]], f"{material}: render of {p['model']}",
                    f"<b>{html.escape(p['model'])}</b>: ΔE "
                    + number(p["error"].get(ACCURACY_METRIC), f"points.{i}.error.{ACCURACY_METRIC}", "span")
                    + ", p95 " + number(p["error"].get("image_delta_e2000_p95"), f"points.{i}.error.image_delta_e2000_p95", "span")))
        parts.append(f'<h3>{html.escape(material)}</h3><div class="renders">{"".join(cards)}</div>')
    return _section("Renders", "".join(parts))


def _on_cluster(run: dict) -> str:
    """`` on the Dask cluster at ADDRESS`` for a study whose cells ran there, else ``""``."""
    return f" on the Dask cluster at {html.escape(run['cluster'])}" if run.get("cluster") else ""


def _machine_section(study: dict, rerun: str) -> str:
    machine, run = study["machine"], study["run"]
    versions = ", ".join(f"{k} {v}" for k, v in machine["versions"].items())
    return _section("Machine and how to reproduce", (
        f"<p>{html.escape(machine['cpu'])}, {machine['cores']} cores, {html.escape(machine['platform'])}, "
        f"Python {machine['python']}; {html.escape(versions)}. {run['jobs']} cell{'s' if run['jobs'] != 1 else ''} at a time"
        f"{_on_cluster(run)}; seeds "
        f"{html.escape(', '.join(str(s) for s in run['seeds']))}; hemisphere metrics over {run['hemisphere_pairs']} "
        "direction pairs.</p>"
        f"<p>Run the study again (finished cells in the output folder's <code>cells/</code> are reused, new or "
        f"changed ones computed): <code>{html.escape(rerun)}</code>. Draw this page and its figures again from "
        "<code>study.json</code> alone, with no cell run: <code>neuralbrdf study --report-only --out DIR</code> "
        "(DIR: the folder holding this page).</p>"))


#: What a report of a profile that times no cell says instead of a recommendation.
_UNTIMED = ("<h2>Which model to use</h2><p>This profile times no model (each variant has "
            "<code>speed_accuracy: false</code>): without render costs there is no recommendation and no chart of "
            "speed against accuracy. What it measures — each model's error over its sweep — is below.</p>")


def _timed(study: dict) -> bool:
    """Whether the profile times any cell: a point's ``is_main`` marks a rendered and timed cell
    (:func:`neuralbrdf.study.cells.is_rendered`), failed or not."""
    return any(p["is_main"] for p in study["points"])


def _choice_parts(study: dict, figs: dict, figures_dir: Path) -> list[str]:
    """The recommendation per material and ΔE budget, and the pooled chart of speed against accuracy."""
    shared = pooled_materials(study)
    fronts = study["pareto"]
    budgets = ", ".join(f"{b:g}" for b in BUDGETS_DELTA_E)
    return [
        "<h2>Which model to use</h2>",
        "<p>Per material, the cheapest model to render (render time ÷ Mitsuba's roughconductor in the same run) "
        "whose mean CIEDE2000 difference from the truth's render stays within the budget; ΔE 1 is about a just "
        f"noticeable difference. Budgets tried: {budgets}; a row stands for every budget in its range. From each "
        "model's main cell (DS1 sampling, no noise, seed 0).</p>",
        _recommendation(study),
        "<h2>Speed against accuracy</h2>",
        figure(figures_dir, figs["speed_accuracy_pooled"],
               "mean ΔE2000 against render cost (left) and fit time (right), one point per model, pooled over materials",
               f"Each model's median over the materials every model fits ({html.escape(', '.join(shared) or 'none')}). "
               f"Pareto front (dashed: no other model is both cheaper and more accurate) against render cost: "
               f"<b>{_names(fronts['render_ratio']['pooled'])}</b>; against fit time: "
               f"<b>{_names(fronts['fit_time_s']['pooled'])}</b>."),
    ]


def write_report(study: dict, figs: dict, out_dir: str | Path) -> Path:
    """Write ``out_dir/index.html`` from ``study`` (the content of ``study.json``) and ``figs``
    (:func:`neuralbrdf.study.figures.write_figures` of it)."""
    out_dir = Path(out_dir)
    figures_dir = out_dir / "figures"
    run = study["run"]
    rerun = run["command"]
    parts = [
        "<!doctype html><html lang=en><head><meta charset=utf-8><meta name=viewport content=\"width=device-width\">"
        f"<title>neuralbrdf study: which model to use</title><style>{STYLE}</style></head><body><main>",
        "<h1>neuralbrdf study: which model to use</h1>",
        f"<p>Profile <code>{html.escape(run['profile'])}</code>, run {html.escape(_when(run['started']))}: {len(study['points'])} "
        f"cells{_on_cluster(run) + ', submitted from' if run.get('cluster') else ' on'} "
        f"{html.escape(study['machine']['cpu'])} ({study['machine']['cores']} cores). "
        'Data: <a href="study.json">study.json</a>.</p>',
        _status(study),
        *(_choice_parts(study, figs, figures_dir) if _timed(study) else [_UNTIMED]),
        _pairs_part(figs, figures_dir),
        "<h2>Details</h2>",
        _per_material_section(study, figs, figures_dir),
        _stability_section(study, figs, figures_dir),
        _failure_section(study, figs, figures_dir),
        _per_angle_section(figs, figures_dir, rerun),
        _renders_section(study, figs, rerun),
        _section(f"Every cell ({len(study['points'])})", _points_table(study)),
        _machine_section(study, rerun),
        "</main></body></html>\n",
    ]
    path = out_dir / "index.html"
    with atomic_write(path, encoding="utf-8") as handle:
        handle.write("\n".join(parts))
    return path


def read_study(out_dir: str | Path) -> dict:
    """``out_dir/study.json``, or an :class:`InputError` naming the file and what is wrong."""
    path = Path(out_dir) / "study.json"
    try:
        study = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("no study.json here: run `neuralbrdf study --profile PROFILE --out DIR` first", path=path) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise InputError(f"cannot read the study: {error}", path=path) from None
    missing = [k for k in ("points", "pareto", "failures", "summary", "sentences", "machine", "run")
               if not isinstance(study, dict) or k not in study]
    if missing:
        raise InputError(f"not a study.json: missing key(s) {', '.join(missing)}", path=path)
    return study


def rebuild(out_dir: str | Path) -> Path:
    """Draw the figures and ``index.html`` of ``out_dir`` again from its ``study.json`` (no cell is
    run); ``study.json``'s list of figures is brought up to date, nothing else in it changes."""
    study = read_study(out_dir)
    figs = write_figures(study, out_dir)
    if study.get("figures") != figs:
        study["figures"] = figs
        with atomic_write(Path(out_dir) / "study.json", encoding="utf-8") as handle:
            json.dump(study, handle, indent=1, allow_nan=False)
    return write_report(study, figs, out_dir)
