"""Figures of in-plane BRDF data (report Figs. 4.4–4.5 and 5.2 style).

Left panel: the BRDF (linear sRGB channels, sr⁻¹, log scale) against the signed outgoing angle
``theta_r`` for a few incident angles, the report's in-plane view.  Right panel (spectral
tables only): the spectral BRDF at the mirror direction ``theta_r = theta_i`` for the same
incident angles, coloured by their sRGB appearance.
"""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402

from neuralbrdf.atomic import atomic_path  # noqa: E402
from neuralbrdf.data.table import BrdfTable  # noqa: E402
from neuralbrdf.errors import InputError  # noqa: E402

DEFAULT_THETA_I_DEG = (-45.0, -15.0, 15.0, 45.0)
CHANNEL_COLOURS = ("tab:red", "tab:green", "tab:blue")


def _nearest_available(requested, available):
    return sorted({float(available[np.argmin(np.abs(available - t))]) for t in requested})


#: Output formats by file suffix (matplotlib writers).
FORMATS = {".png": "png", ".pdf": "pdf", ".svg": "svg"}
LINE_STYLES = ("-", "--", ":", "-.")
CHANNEL_NAMES = ("R", "G", "B")


def output_format(path: str | os.PathLike[str]) -> str:
    """The figure format named by ``path``'s suffix; :class:`InputError` for any other suffix."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise InputError(f"unsupported figure format {suffix or '(none)'!r}; expected one of {', '.join(FORMATS)}",
                         path=path)
    return FORMATS[suffix]


def _legend(ax, chosen, n_hidden: int) -> None:
    """One legend for the channels (colours) and one entry per incident angle (black line styles)."""
    handles = [Line2D([], [], color=colour, label=f"{name} channel") for name, colour in zip(CHANNEL_NAMES, CHANNEL_COLOURS)]
    handles += [Line2D([], [], color="black", linestyle=LINE_STYLES[k % len(LINE_STYLES)],
                       marker="v" if angle < 0 else None, markevery=8, label=f"θi = {angle:+g}°")
                for k, angle in enumerate(chosen)]
    if n_hidden:
        handles.append(Line2D([], [], linestyle="none", label=f"{n_hidden} value(s) ≤ 0 not drawn (log scale)"))
    ax.legend(handles=handles, fontsize=7, ncol=2)


def plot_inplane(table: BrdfTable, out: str | os.PathLike[str], theta_i_deg=DEFAULT_THETA_I_DEG, title=None):
    """Write a figure of ``table``'s in-plane slices (nearest available incident angles).

    The format follows ``out``'s suffix (:data:`FORMATS`).  Channels are told apart by colour and
    incident angles by line style (negative angles also by ``v`` markers); values ``<= 0`` cannot
    be drawn on the log axis and are left out (a gap), their count given in the legend.
    """
    file_format = output_format(out)
    ti, tr = table.inplane_angles()
    rgb = table.to_rgb().values
    chosen = _nearest_available(theta_i_deg, np.unique(np.round(ti, 6)))
    ncols = 2 if table.is_spectral else 1
    fig, axes = plt.subplots(1, ncols, figsize=(6 * ncols, 4.2), squeeze=False)
    ax = axes[0, 0]
    n_hidden = 0
    for k, angle in enumerate(chosen):
        sel = np.isclose(ti, angle)
        order = np.argsort(tr[sel])
        for c, colour in enumerate(CHANNEL_COLOURS):
            values = rgb[sel][order, c]
            n_hidden += int(np.sum(values <= 0))
            ax.plot(
                tr[sel][order],
                np.where(values > 0, values, np.nan),
                LINE_STYLES[k % len(LINE_STYLES)],
                color=colour,
                marker="v" if angle < 0 else None,
                markevery=8,
                markersize=4,
            )
    ax.set_yscale("log")
    ax.set_xlabel("θr (degrees, signed; mirror at θr = θi)")
    ax.set_ylabel("BRDF, linear sRGB (sr⁻¹)")
    _legend(ax, chosen, n_hidden)
    ax.grid(alpha=0.3)
    if table.is_spectral:
        ax = axes[0, 1]
        for k, angle in enumerate(chosen):
            sel = np.flatnonzero(np.isclose(ti, angle))
            mirror = sel[np.argmin(np.abs(tr[sel] - angle))]
            colour = np.clip(rgb[mirror] / max(rgb[mirror].max(), 1e-12), 0, 1)
            ax.plot(table.wavelengths, table.values[mirror], LINE_STYLES[k % len(LINE_STYLES)], color=colour,
                    label=f"θi = θr = {angle:+g}°")
        ax.set_xlabel("wavelength (nm)")
        ax.set_ylabel("BRDF at the mirror direction (sr⁻¹)")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.suptitle(title or table.source, fontsize=10)
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=120, format=file_format)
    plt.close(fig)
