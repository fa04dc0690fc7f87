"""The study's figures as PNG files (matplotlib, SPEC §8, §10).

Every function writes one figure atomically and returns its file name.  Errors are the
evaluation's fixed metric names; costs are ratios or times measured in the same run.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from neuralbrdf.atomic import atomic_path  # noqa: E402
from neuralbrdf.study.aggregate import ACCURACY_METRIC, THRESHOLD_METRIC  # noqa: E402

DPI = 80
METHOD_COLOURS = {"spectral_mlp": "tab:blue", "abc": "tab:orange", "nlb": "tab:green", "nlb_spectral": "tab:purple"}
COST_AXES = {"render_ratio": "render time ÷ roughconductor (same run)", "fit_time_s": "fit wall time (s)"}


def _save(fig, path: Path) -> str:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=DPI, bbox_inches="tight", format="png")
    plt.close(fig)
    return path.name


def _front_line(ax, named: dict[str, tuple[float, float]], front: list[str]) -> None:
    if front:
        xs, ys = zip(*(named[n] for n in front))
        ax.step(xs, ys, where="post", color="k", lw=1, ls="--", label="Pareto front")


def speed_accuracy(entries: list[dict], fronts: dict[str, list[str]], title: str, path: Path) -> str:
    """ΔE against render ratio and against fit time; ``entries`` hold ``model, method`` and
    ``render_ratio``/``fit_time_s`` and ``image_delta_e2000_mean``; ``fronts`` per cost key."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, cost_key in zip(axes, COST_AXES):
        named, labels = {}, []
        for e in entries:
            if e.get(cost_key) is None or e.get(ACCURACY_METRIC) is None:
                continue
            x, y = e[cost_key], e[ACCURACY_METRIC]
            named[e["model"]] = (x, y)
            ax.scatter(x, y, color=METHOD_COLOURS.get(e["method"], "grey"), s=30, zorder=3)
            labels.append(ax.annotate(e["model"], (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points",
                                      arrowprops={"arrowstyle": "-", "lw": 0.4, "color": "grey", "shrinkA": 0}))
        _front_line(ax, named, fronts.get(cost_key, []))
        _cost_scale(ax, [x for x, _ in named.values()])
        spread_labels(ax, labels)
        ax.set_xlabel(COST_AXES[cost_key])
        ax.set_ylabel("mean ΔE2000 vs truth render")
        ax.set_title("Pareto: " + (", ".join(fronts.get(cost_key, [])) or "none"), fontsize=8)
        ax.grid(alpha=0.3, which="both")
    handles = [plt.Line2D([], [], marker="o", ls="", color=c, label=m) for m, c in METHOD_COLOURS.items()]
    axes[1].legend(handles=handles, fontsize=7, loc="best")
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def spread_labels(ax, labels: list) -> None:
    """Move point labels (``ax.annotate`` in offset points) up, lowest point first, in steps of a
    label's height until none overlaps a label placed before it: models of similar cost and error
    keep legible names, each joined to its point by a thin line."""
    renderer = ax.figure.canvas.get_renderer()
    placed = []
    for label in sorted(labels, key=lambda a: ax.transData.transform(a.xy)[1]):
        box = label.get_window_extent(renderer)
        shift = 0.0  # pixels
        while any(box.translated(0, shift).overlaps(other) for other in placed):
            shift += 1.1 * box.height
        if shift:
            dx, dy = label.xyann
            label.xyann = (dx, dy + shift * 72.0 / ax.figure.dpi)
        placed.append(box.translated(0, shift))


def _cost_scale(ax, values: list[float]) -> None:
    """Logarithmic when the costs span more than a decade; plain numbers on the ticks either way."""
    from matplotlib.ticker import FormatStrFormatter, NullFormatter

    if values and min(values) > 0 and max(values) / min(values) > 10:
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
    ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))


def box_by_condition(points: list[dict], models: list[str], conditions: list, condition_of, label_of,
                     title: str, path: Path) -> str:
    """Box plots of :data:`THRESHOLD_METRIC` per condition (x) and model (boxes side by side),
    over seeds and materials; cells without an error value are left out and counted in the title."""
    fig, ax = plt.subplots(figsize=(max(6, 1.6 * len(conditions) * max(1, len(models)) / 2), 4))
    width = 0.8 / max(1, len(models))
    missing = 0
    for k, model in enumerate(models):
        data, positions = [], []
        for j, condition in enumerate(conditions):
            values = [p["error"].get(THRESHOLD_METRIC) for p in points
                      if p["model"] == model and condition_of(p) == condition]
            missing += sum(v is None for v in values)
            values = [v for v in values if v is not None]
            if values:
                data.append(values)
                positions.append(j + (k - (len(models) - 1) / 2) * width)
        if data:
            parts = ax.boxplot(data, positions=positions, widths=width * 0.9, patch_artist=True, manage_ticks=False)
            colour = plt.cm.tab10(k % 10)
            for box in parts["boxes"]:
                box.set_facecolor(colour)
                box.set_alpha(0.6)
            ax.plot([], [], color=colour, lw=6, alpha=0.6, label=model)
    ax.set_xticks(range(len(conditions)), [label_of(c) for c in conditions])
    ax.set_yscale("log")
    ax.set_ylabel("hemisphere log-cos RMSE vs truth")
    ax.set_title(title + (f" ({missing} cells without an error: failed before evaluation)" if missing else ""),
                 fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3, axis="y")
    rotate_crowded_ticks(ax)
    return _save(fig, path)


def rotate_crowded_ticks(ax) -> bool:
    """Slant the x tick labels (25°, right-aligned) when two neighbours, drawn level, would stand
    closer than one font size (about a wide character: closer, two labels read as one); measured
    on the drawn figure.  Returns whether it did."""
    renderer = ax.figure.canvas.get_renderer()
    labels = [label for label in ax.get_xticklabels() if label.get_text()]
    if not labels:
        return False
    min_gap_px = labels[0].get_fontsize() * ax.figure.dpi / 72.0
    boxes = sorted((label.get_window_extent(renderer) for label in labels), key=lambda b: b.x0)
    if not any(right.x0 - left.x1 < min_gap_px for left, right in zip(boxes, boxes[1:])):
        return False
    for label in labels:
        label.set_rotation(25)
        label.set_horizontalalignment("right")
    return True


def failure_map(rows: list[dict], path: Path) -> str:
    """Model × condition grid: failed/cells per square, coloured by the failed fraction, with causes."""
    models = list(dict.fromkeys(r["model"] for r in rows))
    conditions = sorted(dict.fromkeys(r["condition"] for r in rows), key=_condition_order)
    grid = np.full((len(models), len(conditions)), np.nan)
    fig, ax = plt.subplots(figsize=(1.3 + 1.25 * len(conditions), 0.9 + 0.45 * len(models)))
    for r in rows:
        i, j = models.index(r["model"]), conditions.index(r["condition"])
        grid[i, j] = r["failed"] / r["cells"]
        short = ",".join(_short(c) + str(n) for c, n in sorted(r["causes"].items()))
        ax.text(j, i, f"{r['failed']}/{r['cells']}\n{short}", ha="center", va="center", fontsize=7,
                color="white" if grid[i, j] > 0.5 else "black")
    ax.imshow(grid, cmap="Reds", vmin=0, vmax=1, aspect="auto")
    ax.set_xticks(range(len(conditions)), conditions, rotation=30, ha="right", fontsize=7)
    ax.set_yticks(range(len(models)), models, fontsize=7)
    ax.set_title("failed cells / cells (N non-finite loss, O optimiser, R fit refused data, E error > 2× DS1, X export, V evaluation)",
                 fontsize=8)
    return _save(fig, path)


def _short(cause: str) -> str:
    return {"non_finite_loss": "N", "optimizer_failure": "O", "fit_refused": "R", "error_above_2x_ds1": "E",
            "export_refused": "X", "evaluation_error": "V"}.get(cause, "C")


def _condition_order(condition: str):
    plan, _, rest = condition.partition(" ")
    return plan, float(rest.split("%")[0]) if rest else 0.0


def rel_rmse_vs_angle(results: list[dict], material: str, path: Path) -> str:
    """Glossy relative RMSE per incident angle (report Figs. 4.6/4.7, 4.13/4.14), one line per model."""
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    for r in results:
        angles = r["per_angle"]
        values = [np.nan if v is None else v for v in angles["glossy_rel_rmse"]]
        ax.plot(angles["theta_i_deg"], values, marker="o", ms=3, label=r["variant"])
    ax.set_yscale("log")
    ax.set_xlabel("incident angle θi (degrees, signed)")
    ax.set_ylabel("glossy relative RMSE (Eq. 4.3)")
    ax.set_title(f"{material}: relative RMSE against incident angle (DS1 fits vs truth)", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3, which="both")
    return _save(fig, path)


def per_channel_boxes(results: list[dict], material: str, path: Path) -> str:
    """Box plots over incident angles of the glossy relative RMSE per wavelength (report Fig. 5.3)."""
    fig, axes = plt.subplots(len(results), 1, figsize=(9, 2.6 * len(results)), squeeze=False, constrained_layout=True)
    for ax, r in zip(axes[:, 0], results):
        matrix = np.array([[np.nan if v is None else v for v in row] for row in r["per_angle"]["per_channel"]])
        channels = r["per_angle"]["channels"]
        data = [col[np.isfinite(col)] for col in matrix.T]
        ax.boxplot(data, widths=0.6)
        ax.set_xticks(range(1, len(channels) + 1), [f"{c:g}" if not isinstance(c, str) else c for c in channels],
                      fontsize=6, rotation=90)
        ax.set_ylabel("rel. RMSE", fontsize=7)
        ax.set_title(f"{material} / {r['variant']}: per channel over θi", fontsize=8)
        ax.grid(alpha=0.3, axis="y")
    axes[-1, 0].set_xlabel("wavelength (nm) or channel")
    return _save(fig, path)


def renders_grid(rows: list[tuple[str, Path]], material: str, path: Path) -> str:
    """Truth | model | ΔE map per model: each main cell's ``comparison.png`` (``neuralbrdf evaluate``)."""
    # 7 in at DPI: each 128-pixel render of a comparison shows at about its own size
    fig, axes = plt.subplots(len(rows), 1, figsize=(7, 2.3 * len(rows)), squeeze=False)
    for (model, folder), ax in zip(rows, axes[:, 0]):
        ax.imshow(plt.imread(folder / "comparison.png"))
        ax.set_title(f"{material} / {model}", fontsize=9)
        ax.set_axis_off()
    return _save(fig, path)
