"""A measurement table's samples as the viewer draws them beside the models.

Only rows whose two directions lie in one plane with the normal (the goniospectrophotometer's
plane of incidence, at any azimuth) are drawn.  Each is named by its signed in-plane angles
``(θi, θr)`` (:meth:`neuralbrdf.data.table.BrdfTable.inplane_angles`; mirror at ``θr = θi``) and
turned to ``θi >= 0``: an isotropic BRDF has ``f(θi, θr) = f(−θi, −θr)`` (a half turn about the
normal), so a sample at negative ``θi`` is drawn at ``(−θi, −θr)``.
"""

from __future__ import annotations

import warnings

import numpy as np

from neuralbrdf.data.colorimetry import colour_problem
from neuralbrdf.data.table import BrdfTable
from neuralbrdf.explorer.models import channel_of_rgb

#: A sample lies on a slice or at a picked pair when its angles are within this many degrees.
ANGLE_TOLERANCE_DEG = 0.5


class Measured:
    """The in-plane samples of ``table`` (module docstring)."""

    def __init__(self, table: BrdfTable, label: str) -> None:
        self.label = label
        self.source = table.source
        rows = table.in_plane_mask()
        theta_i, theta_r = (angle[rows] for angle in table.inplane_angles())
        flip = theta_i < 0
        self.theta_i = np.where(flip, -theta_i, theta_i)
        self.theta_r = np.where(flip, -theta_r, theta_r)
        self.values = table.values[rows]
        self.wavelengths = table.wavelengths
        #: Why a spectral table has no colour (:func:`~neuralbrdf.data.colorimetry.colour_problem`), else ``None``.
        self.no_colour = None if not self.is_spectral else colour_problem(
            (float(self.wavelengths[0]), float(self.wavelengths[-1])), "the measurement")
        self.rgb = None
        if self.no_colour is None:
            with warnings.catch_warnings():  # out-of-gamut samples are clipped to 0 by to_rgb; a view needs no warning
                warnings.simplefilter("ignore")
                self.rgb = table.to_rgb().values[rows]
        self.n_rows, self.n_dropped = int(rows.sum()), int((~rows).sum())

    @property
    def is_spectral(self) -> bool:
        return self.wavelengths is not None

    def incident_angles(self) -> list[float]:
        """The distinct ``θi`` (degrees, ``>= 0``) that were measured."""
        return sorted({round(float(t), 3) for t in self.theta_i})

    def channel(self, rows: np.ndarray, channel: str, wavelength_nm: float) -> np.ndarray | None:
        """Values of ``rows`` (a mask or indices) in one channel (:data:`~neuralbrdf.explorer.models.CHANNELS`):
        at a wavelength by linear interpolation between the table's columns (``None`` for an RGB table,
        and for a colour of a table without one)."""
        if channel != "wavelength" and self.rgb is None:
            return None
        if channel == "wavelength":
            if not self.is_spectral:
                return None
            return np.array([np.interp(wavelength_nm, self.wavelengths, row) for row in self.values[rows]])
        return channel_of_rgb(self.rgb[rows], channel)

    def on_slice(self, theta_i: float) -> np.ndarray:
        """Mask of the samples at incidence ``theta_i`` (within :data:`ANGLE_TOLERANCE_DEG`)."""
        return np.abs(self.theta_i - theta_i) <= ANGLE_TOLERANCE_DEG

    def at_pair(self, theta_i: float, theta_r: float) -> int | None:
        """Index of the sample nearest the in-plane pair ``(θi, θr)`` within the tolerance, else ``None``."""
        distance = np.maximum(np.abs(self.theta_i - theta_i), np.abs(self.theta_r - theta_r))
        if not len(distance) or distance.min() > ANGLE_TOLERANCE_DEG:
            return None
        return int(np.argmin(distance))
