"""The study's figures as PNG files (matplotlib, docs/results.md, docs/study.md), drawn to be read at their own size.

Every figure is drawn at :data:`DPI` to an exact size in pixels that the report shows unscaled:
:data:`FULL_WIDTH_PX` wide across the page, :data:`HALF_WIDTH_PX` for one of two side by side.
No text is smaller than :data:`MIN_TEXT_PX` pixels, every label lies inside the figure, point
labels lie inside their axes and clear of each other, and every panel whose colours or line
styles mean something has a legend; :func:`layout_problems` lists what breaks those rules in a
drawn figure.  Every function writes one figure atomically and returns its file name.  Errors
are the evaluation's fixed metric names; costs are ratios or times measured in the same run.
"""

from __future__ import annotations

import functools
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.text import Annotation, Text  # noqa: E402
from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter  # noqa: E402

from neuralbrdf.atomic import atomic_path  # noqa: E402
from neuralbrdf.study.aggregate import ACCURACY_METRIC, CURVE_FAMILIES, NAMED_PAIRS, THRESHOLD_METRIC  # noqa: E402

DPI = 100
#: The smallest text, in pixels of the PNG shown at its own size (the report never scales a figure down).
MIN_TEXT_PX = 11.0
FULL_WIDTH_PX = 1280
HALF_WIDTH_PX = 630
#: Font sizes in points: at :data:`DPI` 9 pt is 12.5 px, the smallest used.
STYLE = {"font.size": 10, "axes.titlesize": 10.5, "axes.labelsize": 10, "xtick.labelsize": 9.5,
         "ytick.labelsize": 9.5, "legend.fontsize": 9.5, "figure.titlesize": 11.5, "figure.dpi": DPI,
         "savefig.dpi": DPI}
LABEL_PT = 9
METHOD_COLOURS = {"spectral_mlp": "tab:blue", "abc": "tab:orange", "nlb": "tab:green", "nlb_spectral": "tab:purple",
                  "auto": "tab:red", "pca": "tab:brown"}
COST_AXES = {"render_ratio": "render time ÷ roughconductor (same run)", "fit_time_s": "fit wall time (s)"}
MARKERS = ("o", "s", "^", "D", "v")
#: One letter per failure cause in the failure map (``C``: the cell crashed).
CAUSE_LETTERS = {"non_finite_loss": ("N", "non-finite loss"), "optimizer_failure": ("O", "optimiser gave up"),
                 "fit_refused": ("R", "fit refused its data"), "error_above_2x_ds1": ("E", "error > 2× DS1"),
                 "export_refused": ("X", "export refused"), "evaluation_error": ("V", "evaluation error"),
                 "cell_crashed": ("C", "cell crashed")}


def _styled(draw):
    """Run a drawing function under :data:`STYLE`."""
    @functools.wraps(draw)
    def styled(*args, **kwargs):
        with plt.rc_context(STYLE):
            return draw(*args, **kwargs)
    return styled


def _figure(width_px: float, height_px: float, rows: int = 1, columns: int = 1):
    """A figure of exactly ``width_px`` × ``height_px`` with a grid of axes, laid out so that every
    axis label, title and legend lies inside it."""
    return plt.subplots(rows, columns, figsize=(width_px / DPI, height_px / DPI), dpi=DPI, layout="constrained",
                        squeeze=False)


def _save(fig, path: Path) -> str:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=DPI, format="png")
    plt.close(fig)
    return path.name


def _drawn_texts(fig) -> list[Text]:
    """The visible, non-empty texts of a drawn figure: tick labels only of the ticks drawn (an axis
    keeps label objects for ticks outside its view)."""
    tick_labels, drawn = set(), []
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                tick_labels.update((tick.label1, tick.label2))
            if ax.axison and axis.get_visible():
                drawn += [label for tick in axis._update_ticks() for label in (tick.label1, tick.label2)]
    texts = [t for t in fig.findobj(Text) if t not in tick_labels] + drawn
    return [t for t in texts if t.get_visible() and t.get_text().strip()]


def layout_problems(fig) -> list[str]:
    """What keeps ``fig`` from being read at its own size, one line each: a text under
    :data:`MIN_TEXT_PX`, a text not wholly inside the figure, two texts over each other, a point
    label outside its axes."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    width, height = fig.bbox.width, fig.bbox.height
    problems = []
    texts = _drawn_texts(fig)
    boxes = [_text_box(t, renderer) if isinstance(t, Annotation) else t.get_window_extent(renderer) for t in texts]
    for i, (text, box) in enumerate(zip(texts, boxes)):
        size_px = text.get_fontsize() * fig.dpi / 72.0
        if size_px < MIN_TEXT_PX:
            problems.append(f"{text.get_text()!r} is {size_px:.1f} px")
        if box.x0 < -0.5 or box.y0 < -0.5 or box.x1 > width + 0.5 or box.y1 > height + 0.5:
            problems.append(f"{text.get_text()!r} is cut off by the figure's edge")
        if isinstance(text, Annotation) and not _inside(box, text.axes.get_window_extent(renderer)):
            problems.append(f"label {text.get_text()!r} leaves its axes")
        problems += [f"{text.get_text()!r} and {texts[j].get_text()!r} overlap"
                     for j in range(i) if box.overlaps(boxes[j])]
    return problems


def _text_box(label: Annotation, renderer):
    """The box of a label's text alone (an annotation's own box also holds its line to the point)."""
    label.update_positions(renderer)
    return Text.get_window_extent(label, renderer)


def _inside(box, frame) -> bool:
    return box.x0 >= frame.x0 and box.x1 <= frame.x1 and box.y0 >= frame.y0 and box.y1 <= frame.y1


#: Where :func:`place_labels` tries a label, in label heights above (+) or below (-) its point.
LABEL_STEPS = (0, 1, -1, 2, -2, 3, -3, 4, -4, 5, 6, 7, 8, 9, 10)


def place_labels(ax, labels: list[Annotation], marker_px: float = 8.0) -> None:
    """Put each point label (``ax.annotate`` in offset points) beside its point, on the right or
    else the left, where it lies inside the axes and clear of the labels placed before it and of
    every labelled point (a square of ``marker_px``); when both sides are taken, a label height
    further up or down, in steps of :data:`LABEL_STEPS` (lowest point first).  A moved label
    stays joined to its point by its thin line."""
    from matplotlib.transforms import Bbox

    renderer = ax.figure.canvas.get_renderer()
    frame = ax.get_window_extent(renderer)
    half = marker_px / 2
    placed = [Bbox.from_extents(x - half, y - half, x + half, y + half)
              for x, y in (ax.transData.transform(label.xy) for label in labels)]
    for label in sorted(labels, key=lambda a: ax.transData.transform(a.xy)[1]):
        height_pt = 1.25 * label.get_fontsize()
        choice = None
        for step in LABEL_STEPS:
            for side in (1, -1):
                label.xyann = (4 * side, 2 + step * height_pt - (height_pt if step < 0 else 0))
                label.set_horizontalalignment("left" if side > 0 else "right")
                box = _text_box(label, renderer)
                if _inside(box, frame) and not any(box.overlaps(other) for other in placed):
                    choice = box
                    break
            if choice is not None:
                break
        if choice is None:  # no room anywhere: beside the point (layout_problems reports it)
            label.xyann = (4, 2)
            label.set_horizontalalignment("left")
            choice = _text_box(label, renderer)
        placed.append(choice)


def _log_scale(ax, which: str) -> None:
    """The ``which`` (``"x"`` or ``"y"``) axis logarithmic, with plain numbers at 1, 2 and 5 times
    powers of ten and no minor labels."""
    getattr(ax, f"set_{which}scale")("log")
    axis = getattr(ax, f"{which}axis")
    axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FormatStrFormatter("%g"))
    axis.set_minor_formatter(NullFormatter())


def _cost_scale(ax, values: list[float]) -> None:
    """Logarithmic when the costs span more than a decade; plain numbers on the ticks either way."""
    if values and min(values) > 0 and max(values) / min(values) > 10:
        _log_scale(ax, "x")
    else:
        ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))


@_styled
def speed_accuracy(entries: list[dict], fronts: dict[str, list[str]], title: str, path: Path) -> str:
    """ΔE against render ratio and against fit time, one labelled point per model; ``entries`` hold
    ``model, method`` and ``render_ratio``/``fit_time_s`` and ``image_delta_e2000_mean``; ``fronts``
    the Pareto front's models per cost key, drawn as a dashed step line."""
    fig, axes = _figure(FULL_WIDTH_PX, 500, 1, 2)
    panels = []
    for ax, cost_key in zip(axes[0], COST_AXES):
        named, labels, methods = {}, [], []
        for e in entries:
            if e.get(cost_key) is None or e.get(ACCURACY_METRIC) is None:
                continue
            x, y = e[cost_key], e[ACCURACY_METRIC]
            named[e["model"]] = (x, y)
            methods.append(e["method"])
            ax.scatter(x, y, color=METHOD_COLOURS.get(e["method"], "grey"), s=36, zorder=3)
            label = ax.annotate(e["model"], (x, y), fontsize=LABEL_PT, xytext=(4, 2), textcoords="offset points",
                                arrowprops={"arrowstyle": "-", "lw": 0.5, "color": "grey", "shrinkA": 0, "shrinkB": 3})
            label.set_in_layout(False)
            labels.append(label)
        front = fronts.get(cost_key, [])
        if front:
            xs, ys = zip(*(named[n] for n in front))
            ax.step(xs, ys, where="post", color="k", lw=1, ls="--")
        _cost_scale(ax, [x for x, _ in named.values()])
        ax.margins(x=0.12)
        highest = max((y for _, y in named.values()), default=0.0)
        ax.set_ylim(0, 1.15 * highest if highest > 0 else 1.0)  # from 0 (no ΔE is below), room above for labels
        ax.set_xlabel(COST_AXES[cost_key])
        ax.set_ylabel("mean ΔE2000 vs truth render")
        ax.grid(alpha=0.3, which="both")
        handles = [plt.Line2D([], [], marker="o", ls="", color=c, label=m) for m, c in METHOD_COLOURS.items()
                   if m in methods]
        handles += [plt.Line2D([], [], color="k", lw=1, ls="--", label="Pareto front")] if front else []
        if handles:
            _legend_above(ax, len(handles), handles)
        else:  # no variant of the study has this cost (speed_accuracy: false everywhere)
            ax.text(0.5, 0.5, "no model with this cost", transform=ax.transAxes, ha="center", va="center")
        panels.append((ax, labels))
    fig.suptitle(title)
    fig.canvas.draw()  # the layout fixes where the axes lie; labels are placed inside them after
    for ax, labels in panels:
        place_labels(ax, labels)
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


def _legend_above(ax, columns: int, handles: list | None = None) -> None:
    """The panel's legend in a band above its axes (the figure's layout makes room for it)."""
    ax.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.5, 1.01), ncol=columns, frameon=False)


def _box_legend_handles() -> list:
    return [Patch(facecolor="lightgrey", edgecolor="k", label="quartiles, whiskers 1.5 IQR"),
            plt.Line2D([], [], color="k", label="median")]


@_styled
def box_by_condition(points: list[dict], models: list[str], conditions: list, condition_of, label_of,
                     title: str, path: Path) -> str:
    """Box plots of :data:`THRESHOLD_METRIC` per condition (x) and model (boxes side by side, one
    colour each — a model named after a method has that method's colour of the scatter charts —
    named in the legend), over seeds and materials; cells without an error value are left out and
    counted in the title."""
    fig, axes = _figure(HALF_WIDTH_PX, 420)
    ax = axes[0, 0]
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
        colour = METHOD_COLOURS.get(model, plt.cm.tab10(k % 10))  # a method's own colour, as in the scatters
        if data:
            parts = ax.boxplot(data, positions=positions, widths=width * 0.9, patch_artist=True, manage_ticks=False,
                               medianprops={"color": "k"})
            for box in parts["boxes"]:
                box.set_facecolor(colour)
                box.set_alpha(0.6)
        ax.plot([], [], color=colour, lw=8, alpha=0.6, label=model)
    ax.set_xticks(range(len(conditions)), [label_of(c) for c in conditions])
    ax.set_xlim(-0.5, len(conditions) - 0.5)
    _log_scale(ax, "y")
    ax.set_ylabel("hemisphere log-cos RMSE vs truth")
    fig.suptitle(title + (f"\n({missing} cells without an error: failed before evaluation)" if missing else ""))
    _legend_above(ax, min(3, len(models)))
    ax.grid(alpha=0.3, axis="y")
    fig.canvas.draw()
    rotate_crowded_ticks(ax)
    return _save(fig, path)


@_styled
def group_boxes(values: dict[str, list[float]], title: str, path: Path) -> str:
    """One horizontal box per member of a variant group (``values``: member label → its
    :data:`THRESHOLD_METRIC` values over seeds and materials), the labels written out on the left."""
    labels = list(values)
    fig, axes = _figure(HALF_WIDTH_PX, 130 + 40 * len(labels))
    ax = axes[0, 0]
    kept = [i for i, label in enumerate(labels) if values[label]]
    ax.boxplot([values[labels[i]] for i in kept], positions=kept, orientation="horizontal", widths=0.6, patch_artist=True,
               manage_ticks=False, boxprops={"facecolor": "lightgrey"}, medianprops={"color": "k"})
    ax.set_yticks(range(len(labels)), labels)
    ax.set_ylim(len(labels) - 0.5, -0.5)
    _log_scale(ax, "x")
    ax.set_xlabel("hemisphere log-cos RMSE vs truth")
    fig.suptitle(title)
    ax.grid(alpha=0.3, axis="x")
    _legend_above(ax, 2, _box_legend_handles())
    return _save(fig, path)


@_styled
def failure_map(rows: list[dict], path: Path) -> str:
    """Model × condition grid: failed/cells and the causes' letters in each square, coloured by the
    failed fraction (colour bar), conditions from most pairs to fewest; the letters used are spelled
    out in the title."""
    models = list(dict.fromkeys(r["model"] for r in rows))
    pairs = {r["condition"]: r["pairs"] if "pairs" in r else NAMED_PAIRS[r["condition"].partition(" ")[0]]
             for r in rows}  # a study.json written before rows recorded their pairs has only DS1..DS4
    conditions = sorted(pairs, key=lambda condition: _condition_order(condition, pairs[condition]))
    grid = np.full((len(models), len(conditions)), np.nan)
    fig, axes = _figure(min(FULL_WIDTH_PX, 330 + 125 * len(conditions)), 170 + 30 * len(models))
    ax = axes[0, 0]
    used = set()
    for r in rows:
        i, j = models.index(r["model"]), conditions.index(r["condition"])
        grid[i, j] = r["failed"] / r["cells"]
        used.update(r["causes"])
        letters = " ".join(CAUSE_LETTERS.get(c, ("?", c))[0] + str(n) for c, n in sorted(r["causes"].items()))
        ax.text(j, i, f"{r['failed']}/{r['cells']}" + (f"  {letters}" if letters else ""), ha="center", va="center",
                fontsize=LABEL_PT, color="white" if grid[i, j] > 0.5 else "black")
    shown = ax.imshow(grid, cmap="Reds", vmin=0, vmax=1, aspect="auto")
    fig.colorbar(shown, ax=ax, label="failed fraction of the cells", fraction=0.04, pad=0.02)
    ax.set_xticks(range(len(conditions)), conditions)
    ax.set_yticks(range(len(models)), models)
    key = ", ".join(f"{CAUSE_LETTERS[c][0]}: {CAUSE_LETTERS[c][1]}" for c in CAUSE_LETTERS if c in used)
    ax.set_title("failed cells / cells" + (f" (causes — {key})" if key else ""))
    fig.canvas.draw()
    rotate_crowded_ticks(ax)
    return _save(fig, path)


#: The y axis of each metric of the pair curves.
CURVE_AXES = {THRESHOLD_METRIC: "hemisphere log-cos RMSE vs truth", ACCURACY_METRIC: "mean ΔE2000 vs truth render"}
#: Line and marker of each family of the pair curves (:data:`~neuralbrdf.study.aggregate.CURVE_FAMILIES`).
CURVE_STYLES = {"named": {"ls": "-", "marker": "o"}, "files": {"ls": "--", "marker": "s"}}


def _materials(count: int) -> str:
    return f"{count} material{'s' if count != 1 else ''}"


@_styled
def pair_curves(curves: dict[str, list[dict]], title: str, path: Path) -> str:
    """Error against the number of measured pairs (log x), one panel per metric of ``curves``
    (metric → :func:`~neuralbrdf.study.aggregate.pair_curves`): per model a colour, per family a
    line style, the median over materials joined and the quartiles as a band; each number of pairs
    a tick; one legend below the panels.  The title says over how many materials the medians are,
    or each line's label where lines differ."""
    fig, axes = _figure(FULL_WIDTH_PX if len(curves) > 1 else HALF_WIDTH_PX, 500, 1, len(curves))
    models = list(dict.fromkeys(c["model"] for lines in curves.values() for c in lines))
    colours = {m: METHOD_COLOURS.get(m, plt.cm.tab10(k % 10)) for k, m in enumerate(models)}
    counts = {(c["model"], c["family"]): max(row["materials"] for row in c["rows"]) for lines in curves.values()
              for c in lines}
    shared = len(set(counts.values())) == 1
    handles = {}
    for ax, (metric, lines) in zip(axes[0], curves.items()):
        ticks = sorted({row["pairs"] for c in lines for row in c["rows"]})
        for c in lines:
            x = [row["pairs"] for row in c["rows"]]
            label = f"{c['model']}, {CURVE_FAMILIES[c['family']]}" + (
                "" if shared else f" ({_materials(counts[(c['model'], c['family'])])})")
            handles[label], = ax.plot(x, [row["median"] for row in c["rows"]], color=colours[c["model"]], lw=1.5, ms=5,
                                      label=label, **CURVE_STYLES[c["family"]])
            ax.fill_between(x, [row["q1"] for row in c["rows"]], [row["q3"] for row in c["rows"]],
                            color=colours[c["model"]], alpha=0.15, lw=0)
        _log_scale(ax, "x")
        _log_scale(ax, "y")
        ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlim(min(ticks) / 1.3, max(ticks) * 1.3)
        ax.set_xlabel("measured direction pairs (log scale)")
        ax.set_ylabel(CURVE_AXES[metric])
        ax.grid(alpha=0.3, which="both")
    over = _materials(next(iter(counts.values()))) if shared else "each line's materials"
    fig.suptitle(f"{title}\nmedian over {over}, band from first to third quartile")
    fig.legend(handles=list(handles.values()), loc="outside lower center", frameon=False,
               ncol=min(len(handles), 4 if len(curves) > 1 else 2))
    fig.canvas.draw()
    for ax in axes[0]:
        rotate_crowded_ticks(ax)
    return _save(fig, path)


def _condition_order(condition: str, pairs: int):
    """Plans from most pairs to fewest (DS1..DS4 before a plan file of as many), each from no noise up."""
    plan, _, rest = condition.partition(" ")
    return -pairs, plan not in NAMED_PAIRS, plan, float(rest.split("%")[0]) if rest else 0.0


def _style_of(index: int) -> dict:
    """Colour and marker of the ``index``-th line: ten colours, then the next marker."""
    return {"color": plt.cm.tab10(index % 10), "marker": MARKERS[(index // 10) % len(MARKERS)]}


@_styled
def rel_rmse_vs_angle(rows: list[dict], material: str, path: Path) -> str:
    """Glossy relative RMSE per incident angle (report Figs. 4.6/4.7, 4.13/4.14), one line per
    model (``rows``: ``model`` and its ``per_angle``), named in the legend above the axes."""
    fig, axes = _figure(HALF_WIDTH_PX, 330 + 22 * ((len(rows) + 2) // 3))
    ax = axes[0, 0]
    for i, r in enumerate(rows):
        angles = r["per_angle"]
        values = [np.nan if v is None else v for v in angles["glossy_rel_rmse"]]
        ax.plot(angles["theta_i_deg"], values, ms=4, lw=1.2, label=r["model"], **_style_of(i))
    _log_scale(ax, "y")
    ax.set_xlabel("incident angle θi (degrees, signed)")
    ax.set_ylabel("glossy relative RMSE")
    fig.suptitle(f"{material}: relative RMSE per incident angle")
    _legend_above(ax, 3)
    ax.grid(alpha=0.3, which="both")
    return _save(fig, path)


PER_CHANNEL_COLUMNS = 3


@_styled
def per_channel_boxes(rows: list[dict], material: str, path: Path) -> str:
    """Per model a panel (named in its title): box plots over incident angles of the glossy
    relative RMSE per wavelength or RGB channel (report Fig. 5.3), one legend for all panels."""
    columns = min(PER_CHANNEL_COLUMNS, len(rows))
    n_rows = (len(rows) + columns - 1) // columns
    fig, axes = _figure(FULL_WIDTH_PX, 60 + 250 * n_rows, n_rows, columns)
    for ax in axes.flat[len(rows):]:
        fig.delaxes(ax)
    for k, (ax, r) in enumerate(zip(axes.flat, rows)):
        matrix = np.array([[np.nan if v is None else v for v in row] for row in r["per_angle"]["per_channel"]])
        channels = r["per_angle"]["channels"]
        ax.boxplot([col[np.isfinite(col)] for col in matrix.T], widths=0.6, manage_ticks=False, patch_artist=True,
                   boxprops={"facecolor": "lightgrey"}, flierprops={"markersize": 3}, medianprops={"color": "k"})
        every = 5 if len(channels) > 10 else 1
        ticks = range(0, len(channels), every)
        ax.set_xticks([i + 1 for i in ticks], [f"{channels[i]:g}" if not isinstance(channels[i], str) else channels[i]
                                               for i in ticks])
        ax.set_xlim(0.3, len(channels) + 0.7)
        ax.set_title(r["model"])
        ax.grid(alpha=0.3, axis="y")
        if k % columns == 0:
            ax.set_ylabel("glossy rel. RMSE")
        if k + columns >= len(rows):
            ax.set_xlabel("wavelength (nm)" if not isinstance(channels[0], str) else "channel")
    fig.suptitle(f"{material}: relative RMSE per channel, boxes over incident angles")
    fig.legend(handles=_box_legend_handles(), loc="outside lower center", ncol=2, frameon=False)
    return _save(fig, path)
