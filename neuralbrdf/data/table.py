"""The BRDF sample table, the project's one interchange format (docs/formats.md#brdf-sample-table).

CSV with a header: ``theta_i, phi_i, theta_o, phi_o`` (degrees, spherical, docs/formats.md#conventions), then
either ``R, G, B`` (linear sRGB, sr⁻¹) or one column per wavelength named by its value in nm
(a regular, increasing grid), and an optional ``weight`` column.  One row per direction pair.
Columns are found by name; :func:`write_table` writes them in that canonical order.

Reading is strict: every defect is an :class:`~neuralbrdf.errors.InputError` naming the file,
the line (the header is line 1) and the column.  The only repair is for measurement noise:
negative BRDF values no lower than ``-max(1e-6 · max|value|, 1e-9)`` are clipped to 0 with a
warning giving their count; anything more negative is an error.  A geometry repeated with different values is an
error naming both lines (exact repeats are kept).  Blank lines are skipped; no data row is ever
dropped.
"""

from __future__ import annotations

import os
import warnings
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
    wavelength_grid_problem,
    write_numeric_csv,
)
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import in_plane_of_incidence, spherical_pair_to_vectors, spherical_to_inplane

RGB_CHANNELS = ("R", "G", "B")
ANGLE_COLUMNS = ("theta_i", "phi_i", "theta_o", "phi_o")
#: The angles of the signed in-plane table (:mod:`neuralbrdf.data.inplane_table`).
INPLANE_ANGLE_COLUMNS = ("theta_i_signed", "theta_r_signed")
WEIGHT_COLUMN = "weight"

#: Negative values down to ``-max(NEGATIVE_RTOL · max|value|, NEGATIVE_ATOL)`` count as noise.
NEGATIVE_RTOL = 1e-6
NEGATIVE_ATOL = 1e-9


# --------------------------------------------------------------------------- row validation


def negative_noise_tolerance(values: np.ndarray) -> float:
    """Largest magnitude of a negative value still treated as noise (clipped, not an error)."""
    scale = float(np.max(np.abs(values))) if values.size else 0.0
    return max(NEGATIVE_RTOL * scale, NEGATIVE_ATOL)


def negative_value_problem(values: np.ndarray, channel_names, describe) -> CellProblem | None:
    """First value below ``-negative_noise_tolerance(values)``; ``describe(row, k)`` names it."""
    tolerance = negative_noise_tolerance(values)
    return first_flagged_cell(
        values < -tolerance,
        channel_names,
        lambda r, k: (
            f"{describe(r, k)} beyond the noise tolerance -{tolerance:.3g} "
            f"(max({NEGATIVE_RTOL:g} × max|value|, {NEGATIVE_ATOL:g}))"
        ),
    )


def clip_negatives(values: np.ndarray, source: str, what: str) -> np.ndarray:
    """``values`` with negatives set to 0, warning with their count and minimum if any."""
    negative = values < 0
    if not negative.any():
        return values
    warnings.warn(
        f"{source}: clipped {int(negative.sum())} negative {what}, down to {values.min():.3g}, to 0",
        stacklevel=3,
    )
    return np.where(negative, 0.0, values)


#: Geometries closer than this (degrees) in all four angles are the same direction pair.
PAIR_RESOLUTION_DEG = 1e-6


def conflicting_repeat(angles, values, weight, lines, angle_columns=ANGLE_COLUMNS) -> CellProblem | None:
    """First row repeating an earlier row's geometry with different values or weight.

    ``angles`` is ``[N, K]`` in the order of ``angle_columns`` (the geometry as the file writes it).
    Exact repeats are kept (they are the same measurement twice); conflicting ones are refused,
    as the GCMS reader refuses repeated geometries.
    """
    keys = np.rint(angles / PAIR_RESOLUTION_DEG).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    first_of_row = first[inverse.reshape(-1)]
    record = values if weight is None else np.concatenate([values, weight[:, None]], axis=1)
    conflicting = (first_of_row != np.arange(len(keys))) & np.any(record != record[first_of_row], axis=1)
    rows = np.flatnonzero(conflicting)
    if not rows.size:
        return None
    r = int(rows[0])
    earlier = f"row {first_of_row[r]}" if lines is None else f"line {lines[first_of_row[r]]}"
    geometry = ", ".join(f"{a:g}" for a in angles[r])
    return CellProblem(
        r, None, f"repeated geometry ({', '.join(angle_columns)}) = ({geometry}) with different values than {earlier}"
    )


def value_problem(values, channel_names, weight) -> CellProblem | None:
    """First BRDF value below the noise tolerance, or negative weight (cells already finite)."""
    problem = negative_value_problem(values, channel_names, lambda r, k: f"negative BRDF value {values[r, k]:g}")
    if problem or weight is None:
        return problem
    return first_flagged_cell(weight[:, None] < 0, [WEIGHT_COLUMN], lambda r, k: f"negative weight {weight[r]:g}")


#: Where a polar angle outside its range may come from (an angle that is not from the normal).
THETA_RANGE_HINT = "polar angles are measured from the normal"


def _table_cell_problem(angles, values, channel_names, weight, lines=None) -> CellProblem | None:
    """First non-finite cell, angle out of range, value below the noise tolerance, bad weight or
    conflicting repeated geometry (:func:`conflicting_repeat`).

    ``angles`` is ``[N, 4]`` in :data:`ANGLE_COLUMNS` order, ``values`` ``[N, C]``; ``lines`` (file
    line of each row), if given, locates the earlier row of a repeat.
    """
    names = [*ANGLE_COLUMNS, *channel_names]
    cells = np.concatenate([angles, values], axis=1)
    if weight is not None:
        names.append(WEIGHT_COLUMN)
        cells = np.concatenate([cells, weight[:, None]], axis=1)
    problem = first_flagged_cell(
        ~np.isfinite(cells), names, lambda r, k: f"non-finite value {cells[r, k]}"
    )
    if problem:
        return problem
    is_theta = np.array([True, False, True, False])
    below_top = np.where(is_theta, angles <= 90, angles < 360)
    problem = first_flagged_cell(
        (angles < 0) | ~below_top,
        ANGLE_COLUMNS,
        lambda r, k: (
            f"angle {angles[r, k]:g}° outside [0, 90] degrees ({THETA_RANGE_HINT}; signed in-plane angles go in "
            f"an in-plane table: {', '.join(INPLANE_ANGLE_COLUMNS)})" if is_theta[k]
            else f"angle {angles[r, k]:g}° outside [0, 360) degrees"
        ),
    )
    return problem or value_problem(values, channel_names, weight) or conflicting_repeat(angles, values, weight, lines)


# --------------------------------------------------------------------------- the table


@dataclass
class BrdfTable:
    """BRDF samples at direction pairs.

    Construction validates and normalises: arrays become float64 (integers are accepted),
    shapes must agree, every cell must be finite, angles in range, the wavelength grid regular
    and increasing, weights non-negative; violations raise :class:`InputError` naming
    ``source``.  Negative values within the noise tolerance (module docstring) are clipped to 0
    with a warning.

    Attributes
    ----------
    theta_i, phi_i, theta_o, phi_o:
        Spherical angles in degrees, shape ``[N]`` (float64).
    values:
        BRDF in sr⁻¹, shape ``[N, C]`` (float64), never multiplied by a cosine.
    wavelengths:
        ``None`` for RGB tables (``C == 3``, channels R, G, B), else the wavelengths in nm of
        the ``C`` spectral columns (float64, ``[C]``).
    weight:
        Optional per-row weight ``[N]``.
    source:
        Where the table came from (a path or a description), for error messages.
    """

    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    values: np.ndarray
    wavelengths: np.ndarray | None = None
    weight: np.ndarray | None = None
    source: str = field(default="<memory>")

    def __post_init__(self) -> None:
        self.source = str(self.source)
        for name in ANGLE_COLUMNS:
            setattr(self, name, as_float_array(name, getattr(self, name), 1, self.source))
        self.values = as_float_array("values", self.values, 2, self.source)
        if self.weight is not None:
            self.weight = as_float_array(WEIGHT_COLUMN, self.weight, 1, self.source)
        n_rows, n_channels = self.values.shape
        for name in (*ANGLE_COLUMNS, WEIGHT_COLUMN):
            array = getattr(self, name)
            if array is not None and array.shape != (n_rows,):
                raise InputError(
                    f"{name} has shape {array.shape} but values has {n_rows} rows", path=self.source
                )
        if self.wavelengths is None:
            if n_channels != 3:
                raise InputError(
                    f"an RGB table needs 3 value columns, got {n_channels} "
                    "(spectral tables need wavelengths)",
                    path=self.source,
                )
        else:
            self._check_wavelengths(n_channels)
        problem = _table_cell_problem(self._angles(), self.values, self.channel_names, self.weight)
        if problem:
            raise problem.to_error(self.source)
        self._clip_noise()

    def _check_wavelengths(self, n_channels: int) -> None:
        self.wavelengths = as_float_array("wavelengths", self.wavelengths, 1, self.source)
        if self.wavelengths.shape != (n_channels,):
            raise InputError(
                f"{self.wavelengths.size} wavelengths for {n_channels} value columns",
                path=self.source,
            )
        problem = wavelength_grid_problem(self.wavelengths)
        if problem:
            index, message = problem
            raise InputError(message, path=self.source, column=self.channel_names[index])

    def _clip_noise(self) -> None:
        negative = self.values < 0
        count = int(negative.sum())
        if count:
            warnings.warn(
                f"{self.source}: clipped {count} slightly negative BRDF value(s) (noise, no lower "
                f"than {self.values.min():.3g}) to 0",
                stacklevel=4,
            )
            self.values = np.where(negative, 0.0, self.values)

    def _angles(self) -> np.ndarray:
        return np.stack([self.theta_i, self.phi_i, self.theta_o, self.phi_o], axis=1)

    @property
    def is_spectral(self) -> bool:
        return self.wavelengths is not None

    @property
    def n_rows(self) -> int:
        return self.values.shape[0]

    @property
    def channel_names(self) -> list[str]:
        """``["R", "G", "B"]`` or the wavelength column names (``"400"``, ``"410"``, …)."""
        if self.wavelengths is None:
            return list(RGB_CHANNELS)
        return [format_wavelength(w) for w in self.wavelengths.tolist()]

    def vectors(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit direction vectors ``(wi, wo)``, each ``[N, 3]``, in the local frame (docs/formats.md#conventions)."""
        return spherical_pair_to_vectors(self.theta_i, self.phi_i, self.theta_o, self.phi_o)

    def inplane_angles(self) -> tuple[np.ndarray, np.ndarray]:
        """Signed in-plane ``(theta_i, theta_r)`` in degrees of every row.

        Exact (sign of ``theta_i`` included) for rows in the plane of incidence, the Rusinkiewicz
        in-plane equivalent elsewhere (:func:`neuralbrdf.geometry.spherical_to_inplane`); far out
        of plane ``theta_i`` can exceed 90°.
        """
        return spherical_to_inplane(self.theta_i, self.phi_i, self.theta_o, self.phi_o)

    def in_plane_mask(self) -> np.ndarray:
        """True for rows whose directions are coplanar with the normal (any azimuth of the plane)."""
        return in_plane_of_incidence(*self.vectors())

    def to_rgb(self) -> BrdfTable:
        """Linear-sRGB version of a spectral table (docs/formats.md#spectral-to-linear-srgb); an RGB table is returned as is.

        Spectra outside the sRGB gamut give negative channels; they are clipped to 0 (the table
        holds BRDF values) with a warning giving their count.  A table whose wavelengths do not
        hold the observer's weight over 400–700 nm has no colour
        (:func:`~neuralbrdf.data.colorimetry.colour_problem`): :class:`InputError` naming its source.
        """
        # Imported on use: plain table I/O should not pay for importing colour-science.
        from neuralbrdf.data.colorimetry import colour_problem, spectral_to_linear_srgb

        if not self.is_spectral:
            return self
        problem = colour_problem((float(self.wavelengths[0]), float(self.wavelengths[-1])), "the table")
        if problem is not None:
            raise InputError(f"{problem}; no colour is computed from it", path=self.source)
        try:
            linear = spectral_to_linear_srgb(self.values, self.wavelengths)
        except InputError as error:
            raise InputError(error.reason, path=self.source) if error.path is None else error from None
        rgb = clip_negatives(linear, self.source, "linear-sRGB value(s) (spectra outside the sRGB gamut)")
        weight = None if self.weight is None else self.weight.copy()
        return BrdfTable(
            self.theta_i.copy(), self.phi_i.copy(), self.theta_o.copy(), self.phi_o.copy(),
            rgb, None, weight, f"{self.source} (linear sRGB)",
        )


# --------------------------------------------------------------------------- file I/O

SIGNED_HINT = (f" (signed in-plane angles? an in-plane table names them {', '.join(INPLANE_ANGLE_COLUMNS)}; a GCMS raw "
               "file starts theta_i, theta_r, 390, ..., 730)")


def value_columns(csv_file: NumericCsv, angle_columns=ANGLE_COLUMNS) -> tuple[list[str], np.ndarray | None]:
    """Names of the value columns in file order, and the wavelengths (``None`` for RGB), of a
    table whose geometry is in ``angle_columns``."""
    rgb, spectral = [], []
    for name in csv_file.header:
        if name in angle_columns or name == WEIGHT_COLUMN:
            continue
        if name in RGB_CHANNELS:
            rgb.append(name)
        elif parse_wavelength(name) is not None:
            spectral.append(name)
        else:
            hint = SIGNED_HINT if name in ("theta_r", *INPLANE_ANGLE_COLUMNS) else ""
            raise csv_file.header_error(
                f"unknown column; expected {', '.join(angle_columns)}, then R, G, B or wavelengths "
                f"in nm, and optionally {WEIGHT_COLUMN}{hint}",
                column=name,
            )
    if rgb and spectral:
        raise csv_file.header_error(
            "mixes RGB (R, G, B) and spectral (wavelength) columns; a table holds one kind",
            column=spectral[0],
        )
    if not rgb and not spectral:
        raise csv_file.header_error(
            "no value columns: expected R, G, B or wavelength columns in nm (400, 410, …)"
        )
    if rgb:
        for name in RGB_CHANNELS:
            if name not in rgb:
                raise csv_file.header_error("missing RGB column", column=name)
        return list(RGB_CHANNELS), None
    wavelengths = np.array([parse_wavelength(name) for name in spectral])
    problem = wavelength_grid_problem(wavelengths)
    if problem:
        index, message = problem
        raise csv_file.header_error(message, column=spectral[index])
    return spectral, wavelengths


def required_columns(csv_file: NumericCsv, columns, what: str) -> None:
    """Refuse a header without every one of ``columns`` (``what`` names the format)."""
    for name in columns:
        if name not in csv_file.header:
            raise csv_file.header_error(f"missing required column; {what} starts {', '.join(columns)}", column=name)


def read_table(path: str | os.PathLike[str]) -> BrdfTable:
    """Read a BRDF sample table (docs/formats.md#brdf-sample-table), rejecting any defect with file, line and column."""
    return table_from_csv(read_numeric_csv(path))


def table_from_csv(csv_file: NumericCsv) -> BrdfTable:
    """The BRDF sample table held by a parsed CSV file (see :func:`read_table`)."""
    value_names, wavelengths = value_columns(csv_file)
    required_columns(csv_file, ANGLE_COLUMNS, "a table")
    weight = csv_file.column(WEIGHT_COLUMN) if WEIGHT_COLUMN in csv_file.header else None
    values = np.stack([csv_file.column(name) for name in value_names], axis=1)
    angles = np.stack([csv_file.column(name) for name in ANGLE_COLUMNS], axis=1)
    # Validate here too so that errors carry file lines rather than row indices.
    problem = _table_cell_problem(angles, values, value_names, weight, csv_file.lines)
    if problem:
        raise problem.to_error(csv_file.path, csv_file.lines)
    return BrdfTable(*angles.T, values, wavelengths, weight, csv_file.path)


def write_table(table: BrdfTable, path: str | os.PathLike[str]) -> None:
    """Write ``table`` atomically in the canonical column order; numbers round-trip exactly."""
    write_with_geometry(table, ANGLE_COLUMNS, table._angles(), path)


def write_with_geometry(table: BrdfTable, angle_columns, angles: np.ndarray, path: str | os.PathLike[str]) -> None:
    """Write ``table`` atomically with its geometry as ``angles`` ``[N, K]`` under ``angle_columns``,
    then its value columns and weight."""
    header = [*angle_columns, *table.channel_names]
    data = np.concatenate([angles, table.values], axis=1)
    if table.weight is not None:
        header.append(WEIGHT_COLUMN)
        data = np.concatenate([data, table.weight[:, None]], axis=1)
    write_numeric_csv(path, header, data)
