"""GCMS raw measurements (docs/formats.md#gcms-raw-measurement; report §2.1.1 and §3.2).

What a Murakami GCMS-3B style goniospectrophotometer exports: CSV with signed in-plane
``theta_i, theta_r`` (degrees, docs/formats.md#conventions) and one column per wavelength 390–730 nm at 10 nm
(35 bands) holding the radiance factor beta (unitless).  The header is exactly
``theta_i,theta_r,390,400,...,730``.

Reading is strict (file, line and column in every error): angles must lie in [-90°, 90°], every
cell must be a finite number and no ``(theta_i, theta_r)`` pair may repeat.  Negative beta is
accepted here (sensor noise on dark samples); the Munsell reference's positivity is checked
where it matters, in :func:`neuralbrdf.data.calibration.calibrate`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from neuralbrdf.data.csvio import (
    CellProblem,
    NumericCsv,
    as_float_array,
    first_flagged_cell,
    format_wavelength,
    parse_wavelength,
    read_numeric_csv,
    write_numeric_csv,
)
from neuralbrdf.errors import InputError

GCMS_WAVELENGTHS_NM = np.arange(390.0, 731.0, 10.0)
GCMS_ANGLE_COLUMNS = ("theta_i", "theta_r")
GCMS_HEADER = (*GCMS_ANGLE_COLUMNS, *(format_wavelength(w) for w in GCMS_WAVELENGTHS_NM.tolist()))
#: Geometries closer than this (degrees) in both angles are the same pair.
PAIR_RESOLUTION_DEG = 1e-6


def pair_keys(theta_i, theta_r) -> np.ndarray:
    """Integer keys ``[N, 2]`` of in-plane pairs on a :data:`PAIR_RESOLUTION_DEG` lattice."""
    return np.rint(np.stack([theta_i, theta_r], axis=1) / PAIR_RESOLUTION_DEG).astype(np.int64)


def _gcms_cell_problem(theta_i, theta_r, beta, lines=None) -> CellProblem | None:
    """First non-finite cell, angle outside [-90, 90] or repeated geometry (``[N]``, ``[N, 35]``).

    ``lines`` (file line of each row), if given, locates the first occurrence of a repeat.
    """
    angles = np.stack([theta_i, theta_r], axis=1)
    cells = np.concatenate([angles, beta], axis=1)
    problem = first_flagged_cell(
        ~np.isfinite(cells), GCMS_HEADER, lambda r, k: f"non-finite value {cells[r, k]}"
    )
    if problem:
        return problem
    problem = first_flagged_cell(
        np.abs(angles) > 90,
        GCMS_ANGLE_COLUMNS,
        lambda r, k: f"angle {angles[r, k]:g}° outside [-90, 90] degrees",
    )
    if problem:
        return problem
    _, first, inverse = np.unique(
        pair_keys(theta_i, theta_r), axis=0, return_index=True, return_inverse=True
    )
    first_of_row = first[inverse.reshape(-1)]
    repeats = first_of_row != np.arange(len(theta_i))

    def where_first(r: int) -> str:
        row = first_of_row[r]
        return f"at row {row}" if lines is None else f"on line {lines[row]}"

    return first_flagged_cell(
        repeats[:, None],
        [None],
        lambda r, k: (
            f"duplicated geometry (theta_i, theta_r) = ({theta_i[r]:g}, {theta_r[r]:g}), "
            f"first seen {where_first(r)}"
        ),
    )


@dataclass
class GcmsMeasurement:
    """One GCMS raw file.

    Construction converts the arrays to float64 and validates them (shapes, finiteness, angle
    range, unique geometries), raising :class:`InputError` naming ``source``.

    Attributes
    ----------
    theta_i, theta_r:
        Signed in-plane angles in degrees, shape ``[N]``.
    beta:
        Radiance factor (unitless) ``[N, 35]`` at :data:`GCMS_WAVELENGTHS_NM`.
    source:
        Path or description for error messages.
    lines:
        1-based file line of each row when read from a file (for error messages), else ``None``.
    """

    theta_i: np.ndarray
    theta_r: np.ndarray
    beta: np.ndarray
    source: str = field(default="<memory>")
    lines: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.source = str(self.source)
        self.theta_i = as_float_array("theta_i", self.theta_i, 1, self.source)
        self.theta_r = as_float_array("theta_r", self.theta_r, 1, self.source)
        self.beta = as_float_array("beta", self.beta, 2, self.source)
        n_rows = self.beta.shape[0]
        if self.beta.shape != (n_rows, GCMS_WAVELENGTHS_NM.size):
            raise InputError(
                f"beta must be [N, {GCMS_WAVELENGTHS_NM.size}], got {self.beta.shape}",
                path=self.source,
            )
        for name in GCMS_ANGLE_COLUMNS:
            shape = getattr(self, name).shape
            if shape != (n_rows,):
                raise InputError(
                    f"{name} has shape {shape} but beta has {n_rows} rows", path=self.source
                )
        if self.lines is not None and np.shape(self.lines) != (n_rows,):
            raise InputError(f"lines must have one entry per row ({n_rows})", path=self.source)
        problem = _gcms_cell_problem(self.theta_i, self.theta_r, self.beta, self.lines)
        if problem:
            raise problem.to_error(self.source, self.lines)

    @property
    def wavelengths(self) -> np.ndarray:
        return GCMS_WAVELENGTHS_NM

    @property
    def n_rows(self) -> int:
        return self.beta.shape[0]


def read_gcms(path: str | os.PathLike[str]) -> GcmsMeasurement:
    """Read a GCMS raw file (docs/formats.md#gcms-raw-measurement), rejecting any defect with file, line and column."""
    return gcms_from_csv(read_numeric_csv(path))


def gcms_from_csv(csv_file: NumericCsv) -> GcmsMeasurement:
    """The GCMS measurement held by a parsed CSV file (see :func:`read_gcms`)."""
    header = csv_file.header
    if header[:2] != GCMS_ANGLE_COLUMNS:
        wrong = next((got for got, want in zip(header, GCMS_ANGLE_COLUMNS) if got != want), None)
        raise csv_file.header_error(
            f"a GCMS raw file starts with columns theta_i, theta_r; found {', '.join(header[:2])}",
            column=wrong,
        )
    names = header[2:]
    expected = GCMS_WAVELENGTHS_NM.tolist()
    if [parse_wavelength(name) for name in names] != expected:
        first_wrong = next(
            (got for got, want in zip(names, expected) if parse_wavelength(got) != want), None
        )
        raise csv_file.header_error(
            f"wavelength columns must be exactly 390, 400, ..., 730 nm (35 columns, step 10); "
            f"found {len(names)}: {', '.join(names) or 'none'}",
            column=first_wrong,
        )
    theta_i, theta_r, beta = csv_file.data[:, 0], csv_file.data[:, 1], csv_file.data[:, 2:]
    return GcmsMeasurement(theta_i, theta_r, beta, source=csv_file.path, lines=csv_file.lines)


def write_gcms(measurement: GcmsMeasurement, path: str | os.PathLike[str]) -> None:
    """Write a GCMS raw file atomically; numbers round-trip exactly."""
    data = np.concatenate(
        [np.stack([measurement.theta_i, measurement.theta_r], axis=1), measurement.beta], axis=1
    )
    write_numeric_csv(path, GCMS_HEADER, data)
