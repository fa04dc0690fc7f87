"""Sampling plans: which direction pairs an operator measures (docs/measure.md#sampling-plans).

In-plane plans follow the report's Tables 4.1, 6.1 and 6.2 (S. Chitnis, *Simplifying BRDF
Acquisition*): signed in-plane angles (:mod:`neuralbrdf.geometry`) with ``theta_i`` and
``theta_r`` in [-60°, 60°].  Each ``theta_i`` gets a *glossy* window ``|theta_i - theta_r| <=
10°`` sampled on a fine grid that starts at ``max(theta_i - 10, -60)``, and *diffuse* samples on
a coarse grid anchored at -60° strictly outside that window.  The window is the report's glossy
definition (§5.1.2); the report does not state the window used to build its plans and quotes
"~900" pairs for DS1, whereas this rule gives exactly 1001 / 185 / 57 pairs for DS1 / DS2 / DS3.

The Löw et al. (2012) "full gamut" set has 8 incident polar angles (5°, 15°, …, 75°, all at
``phi_i = 0``) times 28 800 outgoing directions on a 90 × 320 grid of cell centres in
``theta_o`` (1° steps) and ``phi_o`` (1.125° steps): 230 400 pairs.

The spectral MLP split (Table 5.1) puts whole incident angles in the test set; for plans
without Table 5.1's angles, :func:`every_third_theta_i_split` generalises it (on DS1's 5° grid
the two coincide).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from neuralbrdf.errors import InputError
from neuralbrdf.geometry import inplane_to_spherical

ANGLE_LIMIT_DEG = 60.0
GLOSSY_WINDOW_DEG = 10.0

#: Incident angles (degrees) of the spectral MLP's test split (report Table 5.1).
SPECTRAL_MLP_TEST_THETA_I = (-50.0, -35.0, -20.0, -5.0, 10.0, 25.0, 40.0, 55.0)


@dataclass(frozen=True)
class InPlaneGrid:
    """Step sizes (degrees) of an in-plane plan (report Tables 4.1 and 6.1)."""

    theta_i_step: float
    diffuse_step: float
    glossy_step: float


IN_PLANE_GRIDS = {
    "DS1": InPlaneGrid(5.0, 5.0, 1.0),
    "DS2": InPlaneGrid(15.0, 10.0, 2.0),
    "DS3": InPlaneGrid(30.0, 20.0, 3.0),
}

#: DS4 (report Table 6.2): six outgoing angles at one incident angle.
DS4_THETA_I = 30.0
DS4_THETA_R = (-60.0, -20.0, 20.0, 28.0, 36.0, 60.0)

LOW_THETA_I = tuple(5.0 + 10.0 * k for k in range(8))
LOW_N_THETA_O = 90
LOW_N_PHI_O = 320

PLAN_NAMES = ("DS1", "DS2", "DS3", "DS4", "low")


def _grid(start: float, stop: float, step: float) -> np.ndarray:
    """Inclusive arithmetic grid (exact for the integer-degree steps used here)."""
    count = int(np.floor((stop - start) / step + 1e-9)) + 1
    return start + step * np.arange(count, dtype=np.float64)


def is_glossy(theta_i_deg, theta_r_deg) -> np.ndarray:
    """The report's glossy region ``|theta_i - theta_r| <= 10°`` (signed in-plane angles)."""
    return np.abs(np.asarray(theta_i_deg) - np.asarray(theta_r_deg)) <= GLOSSY_WINDOW_DEG + 1e-9


def in_plane_plan(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Signed in-plane ``(theta_i, theta_r)`` arrays (degrees) of DS1, DS2, DS3 or DS4."""
    if name == "DS4":
        theta_r = np.array(DS4_THETA_R)
        return np.full_like(theta_r, DS4_THETA_I), theta_r
    try:
        grid = IN_PLANE_GRIDS[name]
    except KeyError:
        raise InputError(
            f"unknown in-plane plan {name!r}; expected one of DS1, DS2, DS3, DS4"
        ) from None
    lim = ANGLE_LIMIT_DEG
    diffuse = _grid(-lim, lim, grid.diffuse_step)
    pairs_i, pairs_r = [], []
    for theta_i in _grid(-lim, lim, grid.theta_i_step):
        lo = max(theta_i - GLOSSY_WINDOW_DEG, -lim)
        hi = min(theta_i + GLOSSY_WINDOW_DEG, lim)
        glossy = _grid(lo, hi, grid.glossy_step)
        outside = diffuse[~is_glossy(theta_i, diffuse)]
        theta_r = np.sort(np.concatenate([outside, glossy]))
        pairs_i.append(np.full_like(theta_r, theta_i))
        pairs_r.append(theta_r)
    return np.concatenate(pairs_i), np.concatenate(pairs_r)


def low_plan() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Spherical ``(theta_i, phi_i, theta_o, phi_o)`` (degrees) of the Löw et al. set."""
    theta_o = (np.arange(LOW_N_THETA_O) + 0.5) * (90.0 / LOW_N_THETA_O)
    phi_o = (np.arange(LOW_N_PHI_O) + 0.5) * (360.0 / LOW_N_PHI_O)
    ti, to, po = np.meshgrid(np.array(LOW_THETA_I), theta_o, phi_o, indexing="ij")
    ti, to, po = ti.ravel(), to.ravel(), po.ravel()
    return ti, np.zeros_like(ti), to, po


def plan_spherical(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Any plan as spherical ``(theta_i, phi_i, theta_o, phi_o)`` arrays (degrees)."""
    if name == "low":
        return low_plan()
    if name not in PLAN_NAMES:
        raise InputError(f"unknown plan {name!r}; expected one of {', '.join(PLAN_NAMES)}")
    return inplane_to_spherical(*in_plane_plan(name))


def spectral_mlp_split(theta_i_deg) -> np.ndarray:
    """Boolean mask, True where a sample belongs to the test split of report Table 5.1."""
    theta_i = np.asarray(theta_i_deg, dtype=np.float64)
    return np.isin(np.round(theta_i, 6), np.array(SPECTRAL_MLP_TEST_THETA_I))


def every_third_theta_i_split(theta_i_deg) -> np.ndarray:
    """Boolean test mask: every third measured incident angle, starting with the third.

    The distinct ``theta_i`` (rounded to 1e-6°) in ascending order are numbered 0, 1, 2, …;
    those numbered 2, 5, 8, … are test angles.  On DS1's 5° grid from -60° this is exactly
    report Table 5.1 (-50°, -35°, …, 55°).  As there, on a grid of ``n`` angles symmetric about
    0° the mirror twin ``-theta_i`` of a test angle stays in training unless ``n ≡ 2 (mod 3)``
    (DS1, n = 25; DS2, n = 9: test -30°, 15°, 60°; DS3, n = 5: test 0°, its own twin).  Fewer
    than three distinct angles give no test angle.
    """
    theta_i = np.round(np.asarray(theta_i_deg, dtype=np.float64), 6)
    angles = np.unique(theta_i)
    return np.isin(theta_i, angles[2::3])
