"""Unit slips a BRDF table's own numbers betray: radians for degrees, µm or Å for nm, percent or
a cosine-weighted quantity for the BRDF.

A table that passes every format check can still be wrong by a unit: read as degrees, angles in
radians put every sample within 1.6° of the normal, and a fit to them renders a glowing sphere.
:func:`check_units` refuses a table whose numbers have the signature of one of these slips, each
chosen to be impossible (or absurd) for a BRDF measured in the documented units, and measured to
pass every table of the project's own data — the virtual materials on DS1–DS4 and the Löw et al.
set, with and without instrument noise, and the 76 NBRDF proxies (MERL and RGL) on DS1, DS2 and
the Löw et al. set (docs/robustness.md gives the margins):

* **angles in radians** — every polar angle at most π/2 + :data:`RADIAN_TOLERANCE` on a table of
  :data:`MIN_ROWS` rows or more (in degrees, a whole measurement within 1.6° of the normal);
* **azimuths in radians** — every azimuth at most 2π + :data:`RADIAN_TOLERANCE`, not all zero
  (in degrees, every direction within 6.3° of the x-z half-plane ``φ = 0``);
* **wavelengths in µm** — every wavelength below :data:`MICROMETRE_LIMIT_NM` (100 nm is extreme
  ultraviolet; 0.4–0.7 are µm);
* **wavelengths in Å** — every wavelength within :data:`ANGSTROM_RANGE` (3000–11000: 300–1100 nm
  in Å, the range of visible and near-infrared goniospectrophotometers; as nm, mid-infrared with
  no visible light at all);
* **percent or another scale** — the median BRDF away from both the mirror and the retro-reflection
  direction (Rusinkiewicz ``θh`` above :data:`OFF_SPECULAR_THETA_H_DEG`, ``θd`` above
  :data:`OFF_RETRO_THETA_D_DEG``, at least :data:`MIN_OFF_SPECULAR_ROWS` rows) above
  :data:`MAX_OFF_SPECULAR_BRDF_SR` sr⁻¹: a surface that bright over most of the hemisphere would
  reflect about π times the light that falls on it (a white diffuse surface is 1/π ≈ 0.32 sr⁻¹);
  a reflectance factor in percent is 100π times the BRDF of a diffuse surface;
* **BRDF × cos θ** — a BRDF is reciprocal, ``f(wi, wo) = f(wo, wi)`` (Helmholtz); a table holding
  ``f cos θo`` (or ``f cos θi``) is not, and the ratio of its reciprocal pairs is the ratio of
  their cosines.  Flagged when, of :data:`MIN_RECIPROCAL_PAIRS` or more reciprocal pairs whose
  cosines differ by a factor :data:`MIN_COSINE_RATIO` or more, a fraction
  :data:`COSINE_PAIR_FRACTION` is closer to that ratio than to reciprocity.

Not detected, because a real BRDF can look the same: a reflectance factor given for the BRDF
(a factor π, within the range of real materials), ``f cos θi cos θo`` (reciprocal), elevation
angles (from the surface) for polar angles (the mirror direction stays ``θr = θi``).

A table that is right after all is read with ``trust_units``; each door names its own option for
it in the message (:func:`overridden_by`): ``--trust-units`` on the command line,
``--data.trust_units true`` for a fit, ``trust_units=True`` in Python.
"""

from __future__ import annotations

import contextlib
import math

import numpy as np

from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import half_diff_angles

#: Fewer rows than this may all lie within 1.6° of the normal; the angle checks need this many.
MIN_ROWS = 6
#: Angles (radians, i.e. degrees read as radians) this far beyond π/2 or 2π still count as radians.
RADIAN_TOLERANCE = 1e-3
#: Every wavelength below this (nm) reads as µm.
MICROMETRE_LIMIT_NM = 100.0
#: Every wavelength within this range (nm) reads as Å.
ANGSTROM_RANGE = (3000.0, 11000.0)
#: "Away from the mirror direction": Rusinkiewicz half-vector angle above this (degrees) ...
OFF_SPECULAR_THETA_H_DEG = 25.0
#: ... and away from retro-reflection: difference angle above this (degrees).
OFF_RETRO_THETA_D_DEG = 10.0
#: The percent check needs this many rows away from the mirror and retro directions.
MIN_OFF_SPECULAR_ROWS = 5
#: Largest plausible median BRDF (sr⁻¹) away from the mirror and retro directions (π × 1: a
#: surface reflecting about π times the light it receives; the project's brightest, a white
#: paper of the RGL database, is 0.27).
MAX_OFF_SPECULAR_BRDF_SR = 1.0
#: Reciprocal pairs whose cosines differ at least by this factor test for a cosine weight ...
MIN_COSINE_RATIO = 1.25
#: ... when there are this many of them (both values above 1e-3 of the table's maximum) ...
MIN_RECIPROCAL_PAIRS = 20
#: ... and this fraction of them follows the cosine ratio rather than reciprocity.
COSINE_PAIR_FRACTION = 0.8
#: Values below this fraction of the table's largest are too close to 0 to compare as ratios.
RATIO_FLOOR = 1e-3
#: Angles are matched into reciprocal pairs on this grid (degrees).
PAIR_GRID_DEG = 1e-4

DEFAULT_OVERRIDE = "trust_units=True"


class UnitsError(InputError):
    """A table whose numbers betray a unit slip (:func:`check_units`).  The message ends with how
    to read it as it is anyway: ``override``, the option of the door the table came through."""

    def __init__(self, finding: str, *, path: str | None, column: str | None = None,
                 override: str = DEFAULT_OVERRIDE) -> None:
        self.finding, self.override = finding, override
        super().__init__(f"{finding}; or, if the table is right, read it with {override}", path=path, column=column)

    def overridden_by(self, override: str) -> UnitsError:
        """The same finding, naming ``override`` (e.g. ``--trust-units``) as the way past it."""
        return UnitsError(self.finding, path=self.path, column=self.column, override=override)


def _radian_polar_angles(table: BrdfTable) -> tuple[str, str] | None:
    theta = np.stack([table.theta_i, table.theta_o])
    if table.n_rows < MIN_ROWS or theta.max() > math.pi / 2 + RADIAN_TOLERANCE:
        return None
    column = "theta_i" if table.theta_i.max() >= table.theta_o.max() else "theta_o"
    return (f"angles look like radians: the largest polar angle of {table.n_rows} rows is {theta.max():.4g}, and "
            "angles are degrees (0-90); convert them to degrees (x 180/pi)", column)


def _radian_azimuths(table: BrdfTable) -> tuple[str, str] | None:
    phi = np.stack([table.phi_i, table.phi_o])
    if table.n_rows < MIN_ROWS or not 0 < phi.max() <= 2 * math.pi + RADIAN_TOLERANCE:
        return None
    column = "phi_i" if table.phi_i.max() >= table.phi_o.max() else "phi_o"
    return (f"azimuths look like radians: the largest azimuth of {table.n_rows} rows is {phi.max():.4g}, and "
            "angles are degrees (0-360); convert them to degrees (x 180/pi)", column)


def _wavelength_unit(table: BrdfTable) -> tuple[str, str] | None:
    if not table.is_spectral:
        return None
    low, high = float(table.wavelengths.min()), float(table.wavelengths.max())
    span = f"the wavelength columns run {low:g}-{high:g}, and wavelengths are nm (400-700 for the visible)"
    if high < MICROMETRE_LIMIT_NM:
        return f"wavelengths look like micrometres: {span}; write them in nm (x 1000)", table.channel_names[0]
    if ANGSTROM_RANGE[0] <= low and high <= ANGSTROM_RANGE[1]:
        return f"wavelengths look like angstroms: {span}; write them in nm (/ 10)", table.channel_names[0]
    return None


def _row_values(table: BrdfTable) -> np.ndarray:
    """Each row's BRDF averaged over its channels, sr⁻¹ ``[N]``."""
    return table.values.mean(axis=1)


def _percent_scale(table: BrdfTable) -> tuple[str, None] | None:
    theta_h, _, theta_d, _ = half_diff_angles(*table.vectors())
    away = (theta_h > OFF_SPECULAR_THETA_H_DEG) & (theta_d > OFF_RETRO_THETA_D_DEG)
    if away.sum() < MIN_OFF_SPECULAR_ROWS:
        return None
    median = float(np.median(_row_values(table)[away]))
    if median <= MAX_OFF_SPECULAR_BRDF_SR:
        return None
    return (f"BRDF values look like percent or another scale: away from the mirror and retro-reflection directions "
            f"({int(away.sum())} rows) their median is {median:.3g} sr^-1, which would reflect about {math.pi * median:.3g} "
            f"times the light that falls on the surface (a white diffuse surface is 1/pi = 0.32 sr^-1); divide a "
            "percentage by 100 and a reflectance factor by pi", None)


def reciprocal_pairs(table: BrdfTable) -> tuple[np.ndarray, np.ndarray]:
    """Row indices ``(a, b)`` of the pairs of rows that hold the same directions swapped, ``wi`` of
    one the ``wo`` of the other (isotropy assumed: matched on ``θi``, ``θo`` and ``|φo − φi|``);
    each pair once, rows with ``θi = θo`` excluded."""
    delta_phi = np.mod(table.phi_o - table.phi_i, 360.0)
    delta_phi = np.minimum(delta_phi, 360.0 - delta_phi)
    grid = [np.rint(a / PAIR_GRID_DEG).astype(np.int64) for a in (table.theta_i, table.theta_o, delta_phi)]
    theta_base, phi_base = (int(np.rint(limit / PAIR_GRID_DEG)) + 1 for limit in (90.0, 180.0))

    def key(first, second, third):  # one "digit" per angle: unique int64 keys (below 1.5e18)
        return (first * theta_base + second) * phi_base + third

    keys, swapped = key(*grid), key(grid[1], grid[0], grid[2])
    order = np.argsort(keys, kind="stable")
    position = np.clip(np.searchsorted(keys[order], swapped), 0, len(keys) - 1)
    partner = order[position]
    rows = np.arange(table.n_rows)
    found = (keys[partner] == swapped) & (partner > rows)
    return rows[found], partner[found]


def _cosine_weighted(table: BrdfTable) -> tuple[str, None] | None:
    a, b = reciprocal_pairs(table)
    values = _row_values(table)
    log_cos_ratio = np.log(np.cos(np.radians(table.theta_o[a])) / np.cos(np.radians(table.theta_i[a])))
    floor = RATIO_FLOOR * values.max()
    usable = (np.abs(log_cos_ratio) >= math.log(MIN_COSINE_RATIO)) & (values[a] > floor) & (values[b] > floor)
    if usable.sum() < MIN_RECIPROCAL_PAIRS:
        return None
    a, b, log_cos_ratio = a[usable], b[usable], log_cos_ratio[usable]
    log_ratio = np.log(values[a] / values[b])  # both above the floor: finite
    for sign, weight in ((1.0, "cos theta_o"), (-1.0, "cos theta_i")):
        follows = float(np.mean(np.abs(log_ratio - sign * log_cos_ratio) < np.abs(log_ratio)))
        if follows >= COSINE_PAIR_FRACTION:
            return (f"values look like BRDF x {weight}: of {int(usable.sum())} reciprocal pairs (the same two directions "
                    f"swapped) {100 * follows:.0f} % differ by the ratio of {weight}, where a BRDF is reciprocal, "
                    f"f(wi, wo) = f(wo, wi); divide the values by {weight}", None)
    return None


#: The checks in the order they are tried (the first finding is reported).
CHECKS = (_radian_polar_angles, _radian_azimuths, _wavelength_unit, _percent_scale, _cosine_weighted)


def unit_problem(table: BrdfTable) -> tuple[str, str | None] | None:
    """The first unit slip the table's numbers betray (module docstring): ``(finding, column)``, or
    ``None``."""
    for check in CHECKS:
        found = check(table)
        if found:
            return found
    return None


def check_units(table: BrdfTable, trust_units: bool = False) -> BrdfTable:
    """``table``, unless its numbers betray a unit slip (:func:`unit_problem`): then
    :class:`UnitsError` naming its source; ``trust_units`` skips the checks."""
    found = None if trust_units else unit_problem(table)
    if found:
        raise UnitsError(found[0], path=table.source, column=found[1])
    return table


@contextlib.contextmanager
def overridden_by(override: str):
    """Within this block, a :class:`UnitsError` names ``override`` (the option of the door the
    table came through, e.g. ``--trust-units``) as the way to read the table as it is."""
    try:
        yield
    except UnitsError as error:
        raise error.overridden_by(override) from None
