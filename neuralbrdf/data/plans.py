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

**Plan files.**  Wherever a plan is asked for, a CSV file of pairs may stand in for a name: the
format ``neuralbrdf plan`` writes — signed in-plane ``theta_i, theta_r`` (degrees, in [-90, 90];
the format of DS1–DS4 and of designed plans, :mod:`neuralbrdf.acquisition`) or spherical
``theta_i, phi_i, theta_o, phi_o`` (the ``low`` set's).  A file is read strictly (file, line
and column named on any defect) and may not list a pair twice.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neuralbrdf.errors import InputError
from neuralbrdf.geometry import inplane_to_spherical, spherical_to_inplane

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
#: What a plan argument may be, for help texts and errors.
PLAN_HELP = "DS1, DS2, DS3, DS4, low, or a plan file (CSV of theta_i,theta_r pairs, as 'neuralbrdf plan' writes)"
#: Columns of an in-plane plan file (signed angles, degrees) and of a spherical one.
INPLANE_PLAN_COLUMNS = ("theta_i", "theta_r")
SPHERICAL_PLAN_COLUMNS = ("theta_i", "phi_i", "theta_o", "phi_o")
#: In-plane angles of two rows closer than this (degrees) are the same pair.
SAME_PAIR_DEG = 1e-6


def _grid(start: float, stop: float, step: float) -> np.ndarray:
    """Inclusive arithmetic grid (exact for the integer-degree steps used here)."""
    count = int(np.floor((stop - start) / step + 1e-9)) + 1
    return start + step * np.arange(count, dtype=np.float64)


def is_glossy(theta_i_deg, theta_r_deg) -> np.ndarray:
    """The report's glossy region ``|theta_i - theta_r| <= 10°`` (signed in-plane angles)."""
    return np.abs(np.asarray(theta_i_deg) - np.asarray(theta_r_deg)) <= GLOSSY_WINDOW_DEG + 1e-9


def in_plane_plan(name: str | os.PathLike[str] | Plan) -> tuple[np.ndarray, np.ndarray]:
    """Signed in-plane ``(theta_i, theta_r)`` arrays (degrees) of DS1, DS2, DS3, DS4, a plan file
    (module docstring) or a :class:`Plan`, whose pairs all lie in the plane of incidence."""
    if isinstance(name, Plan):
        return name.in_plane()
    if is_plan_file(name):
        return read_plan_file(name).in_plane()
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


def plan_spherical(name: str | os.PathLike[str] | Plan) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Any plan — named, a file or a :class:`Plan` — as spherical ``(theta_i, phi_i, theta_o, phi_o)``
    arrays (degrees)."""
    if isinstance(name, Plan):
        return name.spherical
    if is_plan_file(name):
        return read_plan_file(name).spherical
    if name == "low":
        return low_plan()
    if name not in PLAN_NAMES:
        raise InputError(f"unknown plan {name!r}; expected {PLAN_HELP}")
    return inplane_to_spherical(*in_plane_plan(name))


def is_plan_file(plan) -> bool:
    """Whether ``plan`` names a file rather than one of :data:`PLAN_NAMES` (a path, or a string that
    is no plan name)."""
    return isinstance(plan, os.PathLike) or (isinstance(plan, str) and plan not in PLAN_NAMES)


def check_plan(plan, key: str | None = None, *, in_plane: bool = False) -> str | Plan:
    """``plan`` as the rest of the library takes it: a plan name as it is, a plan file as its path
    once read without fault (:func:`read_plan_file`), a :class:`Plan` as it is; ``in_plane``: a plan
    the instrument can measure (no ``low``, no out-of-plane pairs).  :class:`InputError` naming
    ``key`` otherwise."""
    if isinstance(plan, Plan):
        if in_plane:
            plan.in_plane()
        return plan
    if not isinstance(plan, (str, os.PathLike)):
        raise InputError(f"expected a plan ({PLAN_HELP}), got {type(plan).__name__} {plan!r}", key=key)
    if not is_plan_file(plan):
        if in_plane and plan == "low":
            raise InputError("the low set is out of the plane of incidence; expected DS1..DS4 or an in-plane plan "
                             "file", key=key)
        return plan
    text = os.fspath(plan)
    try:
        read = read_plan_file(text)
    except InputError as error:
        if error.path is not None:  # the file, line and column say where
            raise
        raise InputError(error.reason, key=key) from None
    if in_plane:
        read.in_plane()
    return text


def shipped_plan(path: str | os.PathLike[str]) -> str | os.PathLike[str]:
    """``configs/plans/NAME.csv`` names a shipped plan file (the designed plans of
    docs/how-many-measurements.md) wherever the command runs, unless such a file lies there."""
    from neuralbrdf.configs_dir import CONFIGS_DIR

    parts = Path(path).parts
    if parts[:1] == ("configs",) and not Path(path).exists() and (CONFIGS_DIR.joinpath(*parts[1:])).is_file():
        return str(CONFIGS_DIR.joinpath(*parts[1:]))
    return path


def plan_label(plan) -> str:
    """A short name of a plan for tables and file names: its name, a plan file's stem or a
    :class:`Plan`'s label."""
    if isinstance(plan, Plan):
        return plan.label
    return Path(plan).stem if is_plan_file(plan) else str(plan)


@dataclass(frozen=True)
class Plan:
    """Direction pairs that stand for a plan: ``spherical`` angle arrays (degrees) and a ``label``
    (a plan file's path, or what a caller names them); ``signed``: in-plane pairs as signed
    angles where they came so (``None`` for spherical ones)."""

    label: str
    spherical: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
    signed: tuple[np.ndarray, np.ndarray] | None

    @classmethod
    def of_pairs(cls, theta_i_deg, theta_r_deg, label: str) -> Plan:
        """The signed in-plane pairs ``theta_i_deg, theta_r_deg`` (degrees) as a plan named ``label``."""
        signed = tuple(np.asarray(a, dtype=np.float64).ravel() for a in (theta_i_deg, theta_r_deg))
        return cls(label, inplane_to_spherical(*signed), signed)

    def __len__(self) -> int:
        return len(self.spherical[0])

    def in_plane(self) -> tuple[np.ndarray, np.ndarray]:
        """Signed ``(theta_i, theta_r)``; :class:`InputError` when a pair lies out of the plane of incidence."""
        if self.signed is not None:
            return self.signed
        from neuralbrdf.geometry import IN_PLANE_TOLERANCE, spherical_pair_to_vectors

        wi, wo = spherical_pair_to_vectors(*self.spherical)
        out = np.flatnonzero((np.abs(wi[:, 1]) >= IN_PLANE_TOLERANCE) | (np.abs(wo[:, 1]) >= IN_PLANE_TOLERANCE))
        if out.size:
            raise InputError(f"{out.size} of {len(self)} pairs lie out of the plane of incidence (the first on data "
                             f"row {int(out[0]) + 1}); an in-plane instrument needs an in-plane plan "
                             f"({', '.join(INPLANE_PLAN_COLUMNS)})", path=self.label)
        return spherical_to_inplane(*self.spherical)


def read_plan_file(path: str | os.PathLike[str]) -> Plan:
    """Read a plan file (module docstring): every defect an :class:`InputError` naming the file,
    line and column; a pair listed twice (up to :data:`SAME_PAIR_DEG`) names both lines."""
    from neuralbrdf.data.csvio import read_numeric_csv

    path = shipped_plan(path)
    if not Path(path).exists() and Path(path).suffix.lower() != ".csv":
        raise InputError(f"unknown plan {os.fspath(path)!r}; expected {PLAN_HELP}")
    csv_file = read_numeric_csv(path)
    header = set(csv_file.header)
    if set(SPHERICAL_PLAN_COLUMNS) <= header:
        columns, signed = SPHERICAL_PLAN_COLUMNS, False
    elif set(INPLANE_PLAN_COLUMNS) <= header:
        columns, signed = INPLANE_PLAN_COLUMNS, True
    else:
        raise csv_file.header_error(f"a plan file needs the columns {','.join(INPLANE_PLAN_COLUMNS)} (signed "
                                    f"in-plane, degrees) or {','.join(SPHERICAL_PLAN_COLUMNS)}; got "
                                    f"{','.join(csv_file.header)}")
    extra = [name for name in csv_file.header if name not in columns]
    if extra:
        raise csv_file.header_error(f"unexpected column in a plan file; expected only {','.join(columns)}",
                                    column=extra[0])
    angles = np.stack([csv_file.column(name) for name in columns], axis=1)
    limits = [(-90.0, 90.0)] * 2 if signed else [(0.0, 90.0), (0.0, 360.0), (0.0, 90.0), (0.0, 360.0)]
    for k, (name, (low, high)) in enumerate(zip(columns, limits)):
        bad = np.flatnonzero((angles[:, k] < low) | (angles[:, k] > high) | ((high == 360.0) & (angles[:, k] == 360.0)))
        if bad.size:
            kind = "[0, 360)" if high == 360.0 else f"[{low:g}, {high:g}]"
            raise InputError(f"angle {angles[bad[0], k]:g}° outside {kind} degrees", path=csv_file.path,
                             line=int(csv_file.lines[bad[0]]), column=name)
    spherical = tuple(angles.T) if not signed else inplane_to_spherical(angles[:, 0], angles[:, 1])
    key = np.round(angles / SAME_PAIR_DEG).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    first_of = first[inverse.ravel()]
    repeated = np.flatnonzero(first_of != np.arange(len(key)))
    if repeated.size:
        row = int(repeated[0])
        pair = ", ".join(f"{a:g}°" for a in angles[row])
        raise InputError(f"the pair ({pair}) is listed twice (first on line {int(csv_file.lines[first_of[row]])}); "
                         "a plan measures each pair once", path=csv_file.path, line=int(csv_file.lines[row]))
    return Plan(csv_file.path, tuple(np.asarray(a, dtype=np.float64) for a in spherical),
                    (angles[:, 0].copy(), angles[:, 1].copy()) if signed else None)


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


def write_plan(columns, path: str | os.PathLike[str]) -> None:
    """Write a plan file (module docstring) atomically: ``columns`` are the signed in-plane
    ``(theta_i, theta_r)`` or the spherical ``(theta_i, phi_i, theta_o, phi_o)`` arrays (degrees),
    rounded to 1e-6°."""
    import csv

    from neuralbrdf.atomic import atomic_write

    header = INPLANE_PLAN_COLUMNS if len(columns) == 2 else SPHERICAL_PLAN_COLUMNS
    with atomic_write(path) as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(np.round(np.stack([np.asarray(c, dtype=np.float64) for c in columns], axis=1), 6).tolist())
