"""``DIR/index.html``: the study as one static page (SPEC §8, §10).

Self-contained: inline CSS, no script, no network; figures are relative links to ``figures/*.png``
and the data to ``study.json``.  Every number shown that comes from ``study.json`` carries
``data-json="PATH"`` (a dotted path into it, list indices as numbers), so a test can check that
the page and the file agree; numbers are printed with :data:`NUMBER_FORMAT`.
"""

from __future__ import annotations

import html
from pathlib import Path

from neuralbrdf.atomic import atomic_write

NUMBER_FORMAT = "{:.4g}"
ERROR_COLUMNS = ("image_delta_e2000_mean", "hemisphere_logcos_rmse", "inplane_glossy_rel_rmse",
                 "inplane_diffuse_rel_rmse")
COST_COLUMNS = ("render_ratio", "mqueries_per_s", "fit_time_s", "parameters")
STYLE = """
body{font-family:system-ui,sans-serif;max-width:1200px;margin:1em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;font-size:12px;margin:.5em 0}
td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}
td:first-child,th:first-child,td.t{text-align:left}
img{max-width:100%;border:1px solid #eee;margin:.3em 0}
.fail{color:#a00}
code{background:#f4f4f4;padding:0 3px}
"""


def number(value, path: str) -> str:
    """A table cell holding a number from ``study.json`` at ``path``."""
    if value is None:
        return f'<td data-json="{path}" data-null="1">–</td>'
    return f'<td data-json="{path}">{NUMBER_FORMAT.format(value)}</td>'


def text(value) -> str:
    return f'<td class="t">{html.escape("–" if value is None else str(value))}</td>'


def figure(name: str, alt: str) -> str:
    return f'<p><a href="figures/{html.escape(name)}"><img src="figures/{html.escape(name)}" alt="{html.escape(alt)}"></a></p>'


def _points_table(study: dict) -> str:
    head = "".join(f"<th>{h}</th>" for h in ("material", "model", "plan", "noise", "seed", *COST_COLUMNS,
                                             *ERROR_COLUMNS, "failure"))
    rows = []
    for i, p in enumerate(study["points"]):
        cells = [text(p["material"]), text(p["model"]), text(p["plan"]), number(p["noise"], f"points.{i}.noise"),
                 number(p["seed"], f"points.{i}.seed")]
        cells += [number(p["cost"][k], f"points.{i}.cost.{k}") if k in p["cost"] else text(None) for k in COST_COLUMNS]
        cells += [number(p["error"][k], f"points.{i}.error.{k}") if k in p["error"] else text(None)
                  for k in ERROR_COLUMNS]
        failure = p["failure"]
        cells.append(f'<td class="t fail" title="{html.escape(p.get("message") or "")}">{html.escape(failure)}</td>'
                     if failure else text(None))
        rows.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table><tr>{head}</tr>{''.join(rows)}</table>"


def _budget_table(study: dict) -> str:
    rows = ["<tr><th>material</th><th>ΔE budget</th><th>cheapest model within it</th><th>render ratio</th>"
            "<th>mean ΔE2000</th></tr>"]
    for i, b in enumerate(study["summary"]):
        rows.append("<tr>" + text(b["material"]) + number(b["budget_delta_e"], f"summary.{i}.budget_delta_e")
                    + text(b["model"] or "none within budget") + number(b["render_ratio"], f"summary.{i}.render_ratio")
                    + number(b["image_delta_e2000_mean"], f"summary.{i}.image_delta_e2000_mean") + "</tr>")
    return "<table>" + "".join(rows) + "</table>"


def _failure_table(study: dict) -> str:
    rows = ["<tr><th>model</th><th>condition</th><th>cells</th><th>failed</th><th>causes</th>"
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
        rows = [f"<tr><th>{html.escape(table['group'])}</th><th>variant</th>{head}<th>median</th><th>cells</th></tr>"]
        for r, row in enumerate(table["members"]):
            path = f"groups.{g}.members.{r}"
            rows.append("<tr>" + text(row["label"]) + text(row["model"])
                        + "".join(number(v["median"], f"{path}.per_material.{i}.median")
                                  for i, v in enumerate(row["per_material"]))
                        + number(row["median"], f"{path}.median") + number(row["cells"], f"{path}.cells") + "</tr>")
        parts.append("<table>" + "".join(rows) + "</table>")
    return "".join(parts)


def _pareto_text(study: dict) -> str:
    items = []
    for cost_key, label in (("render_ratio", "render cost"), ("fit_time_s", "fit time")):
        front = study["pareto"][cost_key]
        per = "; ".join(f"{m}: {', '.join(v) or 'none'}" for m, v in front["per_material"].items())
        items.append(f"<li>ΔE against {label} — pooled: <b>{html.escape(', '.join(front['pooled']) or 'none')}</b>; "
                     f"per material: {html.escape(per)}</li>")
    return "<ul>" + "".join(items) + "</ul>"


def _history(run: dict) -> str:
    """The runs that made this folder's cells (``runs.jsonl``), when there was more than this one."""
    history = run.get("history") or []
    if len(history) < 2:
        return ""
    rows = "".join(f"<tr><td>{html.escape(h['started'])}</td><td>{h['cells_run']}</td><td>{h['cells_cached']}</td>"
                   f"<td>{NUMBER_FORMAT.format(h['wall_time_s'])}</td><td><code>{html.escape(h['command'])}</code></td></tr>"
                   for h in history)
    return ("<p>Runs into this folder (<code>runs.jsonl</code>): a run that found its cells cached only "
            "redrew the report.</p><table><tr><th>started</th><th>cells run</th><th>cached</th><th>wall time (s)</th>"
            f"<th>command</th></tr>{rows}</table>")


def write_report(study: dict, out_dir: Path) -> Path:
    """Write ``out_dir/index.html`` from ``study`` (the content of ``study.json``)."""
    figs = study["figures"]
    run = study["run"]
    parts = [f"<!doctype html><html lang=en><head><meta charset=utf-8><title>neuralbrdf study</title>"
             f"<style>{STYLE}</style></head><body>",
             "<h1>neuralbrdf study: speed against accuracy, and where methods fail</h1>",
             f"<p>Profile <code>{html.escape(run['profile'])}</code>; command <code>{html.escape(run['command'])}</code>; "
             f"{len(study['points'])} cells ({run['cells_run']} run now, {run['cells_cached']} from the cache), "
             f"wall time {run['wall_time_s']:.0f} s (the cells took {run['cells_time_s']:.0f} s together when they ran, "
             f"{run.get('cells_cpu_time_s', 0.0):.0f} s of CPU); hemisphere metrics over {run['hemisphere_pairs']} direction pairs. "
             "Data: <a href=\"study.json\">study.json</a>.</p>",
             _history(run),
             "<h2>Best model per material under an error budget</h2>",
             "<p>Cheapest model (render time ÷ Mitsuba roughconductor in the same run) whose mean CIEDE2000 against "
             "the truth render is within the budget (main cells: DS1, no noise, seed 0).</p>",
             _budget_table(study),
             "<h2>Speed against accuracy</h2>", _pareto_text(study),
             figure(figs["speed_accuracy_pooled"], "pooled speed-accuracy")]
    parts += [figure(name, f"speed-accuracy {m}") for m, name in figs["speed_accuracy"].items()]
    parts += ["<h2>Stability</h2>",
              "<p>Hemisphere log-cosine RMSE against the truth over seeds (and materials) per sampling plan "
              "(report Figs. 6.5/6.6/6.11/6.12) and per relative measurement noise.</p>"]
    parts += [figure(name, key) for key, name in figs["stability"].items()]
    if study.get("groups"):
        parts += ["<p>Variant groups: median hemisphere log-cos RMSE over seeds per material (DS1, no noise; "
                  "the materials every member fits).</p>", _group_tables(study)]
    parts += ["<h2>Failure map</h2>", "<ul>" + "".join(f"<li>{html.escape(s)}</li>" for s in study["sentences"].values())
              + "</ul>"]
    if figs.get("failure_map"):
        parts.append(figure(figs["failure_map"], "failure map"))
    parts.append(_failure_table(study))
    parts.append("<h2>The report's figures from our data</h2>")
    for kind in ("rel_rmse_vs_angle", "per_channel", "renders"):
        parts += [figure(name, f"{kind} {m}") for m, name in figs[kind].items()]
    parts += ["<h2>Every point</h2>", "<div style=\"overflow-x:auto\">" + _points_table(study) + "</div>"]
    machine = study["machine"]
    versions = ", ".join(f"{k} {v}" for k, v in machine["versions"].items())
    parts.append(f"<h2>Machine</h2><p>{html.escape(machine['cpu'])}, {machine['cores']} cores, "
                 f"{html.escape(machine['platform'])}, Python {machine['python']}; {html.escape(versions)}; "
                 f"jobs {run['jobs']}; seeds {html.escape(str(run['seeds']))}; started {html.escape(run['started'])}.</p>")
    parts.append("</body></html>\n")
    path = out_dir / "index.html"
    with atomic_write(path, encoding="utf-8") as handle:
        handle.write("\n".join(parts))
    return path
