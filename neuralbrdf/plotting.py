"""Figures of in-plane BRDF data (report Figs. 4.4–4.5 and 5.2 style).

Left panel: the BRDF (linear sRGB channels, sr⁻¹, log scale) against the signed outgoing angle
``theta_r`` for a few incident angles, the report's in-plane view.  Right panel (spectral
tables only): the spectral BRDF at the mirror direction ``theta_r = theta_i`` for the same
incident angles, coloured by their sRGB appearance.
"""

from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from neuralbrdf.atomic import atomic_path  # noqa: E402
from neuralbrdf.data.table import BrdfTable  # noqa: E402

DEFAULT_THETA_I_DEG = (-45.0, -15.0, 15.0, 45.0)
CHANNEL_COLOURS = ("tab:red", "tab:green", "tab:blue")


def _nearest_available(requested, available):
    return sorted({float(available[np.argmin(np.abs(available - t))]) for t in requested})


def plot_inplane(table: BrdfTable, out_png: str | os.PathLike[str], theta_i_deg=DEFAULT_THETA_I_DEG, title=None):
    """Write a PNG of ``table``'s in-plane slices (nearest available incident angles)."""
    ti, tr = table.inplane_angles()
    rgb = table.to_rgb().values
    chosen = _nearest_available(theta_i_deg, np.unique(np.round(ti, 6)))
    ncols = 2 if table.is_spectral else 1
    fig, axes = plt.subplots(1, ncols, figsize=(6 * ncols, 4.2), squeeze=False)
    ax = axes[0, 0]
    styles = ("-", "--", ":", "-.")
    for k, angle in enumerate(chosen):
        sel = np.isclose(ti, angle)
        order = np.argsort(tr[sel])
        for c, colour in enumerate(CHANNEL_COLOURS):
            ax.plot(
                tr[sel][order],
                np.clip(rgb[sel][order, c], 1e-6, None),
                styles[k % len(styles)],
                color=colour,
                label=f"θi = {angle:g}°" if c == 0 else None,
            )
    ax.set_yscale("log")
    ax.set_xlabel("θr (degrees, signed; mirror at θr = θi)")
    ax.set_ylabel("BRDF, linear sRGB (sr⁻¹)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    if table.is_spectral:
        ax = axes[0, 1]
        for angle in chosen:
            sel = np.flatnonzero(np.isclose(ti, angle))
            mirror = sel[np.argmin(np.abs(tr[sel] - angle))]
            colour = np.clip(rgb[mirror] / max(rgb[mirror].max(), 1e-12), 0, 1)
            ax.plot(table.wavelengths, table.values[mirror], color=colour, label=f"θi = θr = {angle:g}°")
        ax.set_xlabel("wavelength (nm)")
        ax.set_ylabel("BRDF at the mirror direction (sr⁻¹)")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.suptitle(title or table.source, fontsize=10)
    fig.tight_layout()
    with atomic_path(out_png) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
