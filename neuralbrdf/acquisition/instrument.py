"""What an in-plane goniospectrophotometer can measure: the candidate pairs of a designed plan (docs/how-many-measurements.md).

An in-plane instrument (report §2.1.1) turns its source arm to ``theta_i`` and its detector arm to
``theta_r`` (signed in-plane angles, docs/formats.md#conventions), each in steps of
:attr:`Instrument.step_deg` up to :attr:`Instrument.max_theta_deg` from the normal; near
retro-reflection (``theta_r = -theta_i``) the detector would block the source, so pairs with
``|theta_i + theta_r| < retro_band_deg`` cannot be measured.

An isotropic, reciprocal BRDF takes one value on each orbit of the in-plane symmetries
``(ti, tr) -> (-ti, -tr)`` (mirror of the plane) and ``(ti, tr) -> (tr, ti)`` (Helmholtz
reciprocity): measuring two pairs of one orbit measures one value twice.  The
candidates are therefore one *representative* per orbit (:func:`canonical_pairs`: the pair with
``theta_i >= |theta_r|``, so the source arm stands at the larger angle); every instrument limit
above is symmetric under both maps, so a representative is measurable exactly when its orbit is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from neuralbrdf.errors import InputError

#: Angles of one orbit closer than this (degrees) are the same angle.
ANGLE_TOLERANCE_DEG = 1e-6
#: The largest polar angle an instrument may reach: beyond it the pair grazes the surface.
MAX_THETA_LIMIT_DEG = 85.0


def canonical_pairs(theta_i_deg, theta_r_deg) -> tuple[np.ndarray, np.ndarray]:
    """The representative of each pair's orbit (module docstring): ``(|a|, s b)`` with ``|a| >= |b|``,
    where ``a, b`` are the pair's angles ordered by magnitude and ``s`` carries the pair's relative
    sign (mirror side or retro side)."""
    ti = np.asarray(theta_i_deg, dtype=np.float64)
    tr = np.asarray(theta_r_deg, dtype=np.float64)
    swap = np.abs(tr) > np.abs(ti)
    large, small = np.where(swap, tr, ti), np.where(swap, ti, tr)
    sign = np.where(large < 0, -1.0, 1.0)
    return np.abs(large), sign * small + 0.0  # + 0.0: no negative zero


def pair_keys(theta_i_deg, theta_r_deg) -> np.ndarray:
    """Integer keys ``[N, 2]`` of the pairs' orbits: equal exactly for pairs of one orbit."""
    ti, tr = canonical_pairs(theta_i_deg, theta_r_deg)
    return np.round(np.stack([ti, tr], axis=1) / ANGLE_TOLERANCE_DEG).astype(np.int64)


@dataclass(frozen=True)
class Instrument:
    """The limits of an in-plane instrument (module docstring); angles in degrees."""

    max_theta_deg: float = 60.0
    step_deg: float = 1.0
    retro_band_deg: float = 0.0

    def __post_init__(self) -> None:
        for name, low, high in (("max_theta_deg", 0.0, MAX_THETA_LIMIT_DEG), ("step_deg", 0.0, 90.0),
                                ("retro_band_deg", -math.inf, 180.0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise InputError(f"expected a number of degrees, got {value!r}", key=name)
            if not (low < value <= high) and not (name == "retro_band_deg" and 0.0 <= value <= high):
                raise InputError(f"expected {'0 <=' if name == 'retro_band_deg' else f'{low:g} <'} value <= "
                                 f"{high:g} degrees, got {value:g}", key=name)
        if self.step_deg > self.max_theta_deg:
            raise InputError(f"a step of {self.step_deg:g}° leaves no angle but 0° within the largest angle "
                             f"{self.max_theta_deg:g}°", key="step_deg")

    def angles(self) -> np.ndarray:
        """The angles (degrees) either arm can stand at: multiples of the step within the largest angle."""
        count = int(math.floor(self.max_theta_deg / self.step_deg + 1e-9))
        return self.step_deg * np.arange(-count, count + 1, dtype=np.float64)

    def measurable(self, theta_i_deg, theta_r_deg) -> np.ndarray:
        """Which pairs lie within the arms' range and outside the blocked band (ignoring the step)."""
        ti = np.asarray(theta_i_deg, dtype=np.float64)
        tr = np.asarray(theta_r_deg, dtype=np.float64)
        limit = self.max_theta_deg + ANGLE_TOLERANCE_DEG
        return (np.abs(ti) <= limit) & (np.abs(tr) <= limit) & \
            (np.abs(ti + tr) >= self.retro_band_deg - ANGLE_TOLERANCE_DEG)

    def candidates(self) -> tuple[np.ndarray, np.ndarray]:
        """One measurable representative per orbit on the instrument's grid, ``(theta_i, theta_r)``
        sorted by ``theta_i`` then ``theta_r``; :class:`InputError` when the limits leave none."""
        grid = self.angles()
        ti, tr = (a.ravel() for a in np.meshgrid(grid, grid, indexing="ij"))
        keep = (ti >= np.abs(tr) - ANGLE_TOLERANCE_DEG) & (ti >= 0) & self.measurable(ti, tr)
        ti, tr = canonical_pairs(ti[keep], tr[keep])
        _, first = np.unique(pair_keys(ti, tr), axis=0, return_index=True)
        ti, tr = ti[np.sort(first)], tr[np.sort(first)]
        if not len(ti):
            raise InputError(f"these limits leave no pair to measure (largest angle {self.max_theta_deg:g}°, step "
                             f"{self.step_deg:g}°, retro-reflection band {self.retro_band_deg:g}°)", key="retro_band_deg")
        order = np.lexsort((tr, ti))
        return ti[order], tr[order]
