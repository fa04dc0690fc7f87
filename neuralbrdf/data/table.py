"""The BRDF sample table, the project's one interchange format (SPEC §2.1).

CSV with a header: ``theta_i, phi_i, theta_o, phi_o`` (degrees, spherical, SPEC §1), then
either ``R, G, B`` (linear sRGB, sr⁻¹) or one column per wavelength named by its value in nm
(a regular, increasing grid), and an optional ``weight`` column.  One row per direction pair.
Columns are found by name; :func:`write_table` writes them in that canonical order.

Reading is strict: every defect is an :class:`~neuralbrdf.errors.InputError` naming the file,
the line (the header is line 1) and the column.  The only repair is for measurement noise:
negative BRDF values no lower than ``-max(1e-6 · max|value|, 1e-9)`` are clipped to 0 with a
warning giving their count; anything more negative is an error.  Blank lines are skipped; no
data row is ever dropped.

This module also holds the strict numeric-CSV reader and writer shared with the GCMS raw format
(:mod:`neuralbrdf.data.gcms`).
"""

from __future__ import annotations

import csv
import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from neuralbrdf.atomic import atomic_write
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import spherical_to_inplane, spherical_pair_to_vectors

RGB_CHANNELS = ("R", "G", "B")
ANGLE_COLUMNS = ("theta_i", "phi_i", "theta_o", "phi_o")
WEIGHT_COLUMN = "weight"

#: Negative values down to ``-max(NEGATIVE_RTOL · max|value|, NEGATIVE_ATOL)`` count as noise.
NEGATIVE_RTOL = 1e-6
NEGATIVE_ATOL = 1e-9
#: Wavelength steps may differ by this fraction of the first step and still count as regular.
REGULAR_GRID_RTOL = 1e-6


# --------------------------------------------------------------------------- numeric CSV files


@dataclass(frozen=True)
class NumericCsv:
    """A CSV file of finite numbers under a header of unique, non-empty names.

    ``data`` is ``[N, K]`` float64 (every cell finite); ``lines[n]`` is the 1-based line of data
    row ``n`` in the file (the header is line 1), for error messages.
    """

    path: str
    header: tuple[str, ...]
    data: np.ndarray
    lines: np.ndarray

    def column(self, name: str) -> np.ndarray:
        return self.data[:, self.header.index(name)]

    def header_error(self, message: str, column: str | None = None) -> InputError:
        return InputError(message, path=self.path, line=1, column=column)


def _read_rows(
    path: str, header_only: bool = False
) -> tuple[list[str] | None, list[list[str]], list[int]]:
    """Header row, data rows and their file lines; blank lines skipped; OS errors → InputError."""
    rows, lines = [], []
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            reader = csv.reader(handle)
            header = next(reader, None)
            for row in [] if header_only else reader:
                if not row or (len(row) == 1 and not row[0].strip()):
                    continue
                rows.append(row)
                lines.append(reader.line_num)
    except FileNotFoundError:
        raise InputError("file not found", path=path) from None
    except IsADirectoryError:
        raise InputError("is a directory, expected a CSV file", path=path) from None
    except UnicodeDecodeError as exc:
        raise InputError(f"not a UTF-8 text file ({exc.reason})", path=path) from None
    except csv.Error as exc:
        raise InputError(f"malformed CSV: {exc}", path=path, line=reader.line_num) from None
    return header, rows, lines


def _header_names(header_row: list[str] | None, path: str) -> tuple[str, ...]:
    if header_row is None:
        raise InputError("empty file: expected a header line", path=path, line=1)
    return tuple(name.strip() for name in header_row)


def read_csv_header(path: str | os.PathLike[str]) -> tuple[str, ...]:
    """Column names on line 1 of a CSV file, stripped; only that line is read."""
    path = str(path)
    return _header_names(_read_rows(path, header_only=True)[0], path)


def _first_unparsable_cell(rows: list[list[str]]) -> tuple[int, int]:
    """(row, column) of the first cell ``float`` rejects; only called once parsing has failed."""
    for r, row in enumerate(rows):
        for c, cell in enumerate(row):
            try:
                float(cell)
            except ValueError:
                return r, c
    raise AssertionError("no unparsable cell found")  # pragma: no cover


def read_numeric_csv(path: str | os.PathLike[str]) -> NumericCsv:
    """Parse a header plus rows of numbers, rejecting every malformed cell with its location.

    Rejected: missing file, empty file, blank or duplicated header names, rows with a wrong
    number of cells (e.g. a truncated last line), non-numeric or empty cells, NaN and ±inf.
    """
    path = str(path)
    header_row, rows, lines = _read_rows(path)
    header = _header_names(header_row, path)
    if not any(header):
        raise InputError("line 1 is blank: expected the header", path=path, line=1)
    for k, name in enumerate(header):
        if not name:
            raise InputError(f"header cell {k + 1} is empty", path=path, line=1)
        if name in header[:k]:
            raise InputError("duplicated column name", path=path, line=1, column=name)
    if not rows:
        raise InputError("no data rows after the header", path=path, line=2)

    width = len(header)
    for row, line in zip(rows, lines):
        if len(row) < width:
            raise InputError(
                f"row has {len(row)} of {width} cells (truncated line?)",
                path=path, line=line, column=header[len(row)],
            )
        if len(row) > width:
            raise InputError(
                f"row has {len(row)} cells but the header has {width}", path=path, line=line
            )
    try:
        data = np.array(rows, dtype=np.float64)
    except ValueError:
        r, c = _first_unparsable_cell(rows)
        raise InputError(
            f"not a number: {rows[r][c]!r}", path=path, line=lines[r], column=header[c]
        ) from None
    bad = np.argwhere(~np.isfinite(data))
    if bad.size:
        r, c = bad[0]
        raise InputError(
            f"non-finite value {rows[r][c].strip()!r}", path=path, line=lines[r], column=header[c]
        )
    return NumericCsv(path, header, data, np.asarray(lines, dtype=np.int64))


def write_numeric_csv(path: str | os.PathLike[str], header, data: np.ndarray) -> None:
    """Write ``header`` and ``data`` ``[N, K]`` atomically; numbers round-trip exactly (repr)."""
    rows = np.asarray(data, dtype=np.float64).tolist()
    body = "\n".join(",".join(map(repr, row)) for row in rows)
    with atomic_write(path) as handle:
        handle.write(",".join(header) + "\n" + body + "\n")


def format_wavelength(wavelength_nm: float) -> str:
    """Column name of a wavelength: ``"400"`` for whole numbers, else the shortest exact form."""
    short = f"{wavelength_nm:g}"
    return short if float(short) == wavelength_nm else repr(float(wavelength_nm))


def parse_wavelength(name: str) -> float | None:
    """The wavelength (nm) a column name denotes, or ``None`` if it is not a number."""
    try:
        return float(name)
    except ValueError:
        return None


def wavelength_grid_problem(wavelengths_nm) -> tuple[int, str] | None:
    """First defect of a wavelength grid that must be regular and increasing, else ``None``.

    Returns ``(index, message)`` where ``index`` is the offending entry, so that callers can name
    the column or key.  Checks finiteness, duplicates, order and a constant step (relative
    tolerance 1e-6 of the step).
    """
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    if wl.ndim != 1 or wl.size == 0:
        return 0, f"wavelengths must be a non-empty 1-D array, got shape {wl.shape}"
    bad = np.flatnonzero(~np.isfinite(wl))
    if bad.size:
        return int(bad[0]), f"wavelength {wl[bad[0]]} nm is not finite"
    if wl.size == 1:
        return None
    steps = np.diff(wl)
    repeated = np.flatnonzero(steps == 0)
    if repeated.size:
        return int(repeated[0] + 1), f"wavelength {wl[repeated[0]]:g} nm is duplicated"
    backwards = np.flatnonzero(steps < 0)
    if backwards.size:
        k = int(backwards[0] + 1)
        return k, f"wavelengths must increase: {wl[k - 1]:g} nm is followed by {wl[k]:g} nm"
    irregular = np.flatnonzero(np.abs(steps - steps[0]) > REGULAR_GRID_RTOL * steps[0])
    if irregular.size:
        k = int(irregular[0] + 1)
        return k, (
            f"wavelength grid must be regular: step {steps[0]:g} nm, but {wl[k - 1]:g} nm is "
            f"followed by {wl[k]:g} nm"
        )
    return None


# --------------------------------------------------------------------------- row validation


@dataclass(frozen=True)
class CellProblem:
    """The first invalid cell of an array-backed record: 0-based ``row``, ``column`` name, why."""

    row: int
    column: str | None
    message: str

    def to_error(self, source: str, lines: np.ndarray | None = None) -> InputError:
        """An :class:`InputError` at the file line of the row if known, else naming the row."""
        if lines is None:
            return InputError(f"row {self.row}: {self.message}", path=source, column=self.column)
        return InputError(self.message, path=source, line=int(lines[self.row]), column=self.column)


def first_flagged_cell(mask: np.ndarray, names, message) -> CellProblem | None:
    """First ``True`` of ``mask`` ``[N, K]`` in row order; ``message(row, k)`` explains it."""
    hits = np.argwhere(mask)
    if not hits.size:
        return None
    row, k = (int(i) for i in hits[0])
    return CellProblem(row, names[k], message(row, k))


def negative_noise_tolerance(values: np.ndarray) -> float:
    """Largest magnitude of a negative value still treated as noise (clipped, not an error)."""
    scale = float(np.max(np.abs(values))) if values.size else 0.0
    return max(NEGATIVE_RTOL * scale, NEGATIVE_ATOL)


def _table_cell_problem(angles, values, channel_names, weight) -> CellProblem | None:
    """First non-finite cell, angle out of range, value below the noise tolerance or bad weight.

    ``angles`` is ``[N, 4]`` in :data:`ANGLE_COLUMNS` order, ``values`` ``[N, C]``.
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
            f"angle {angles[r, k]:g}° outside {'[0, 90]' if is_theta[k] else '[0, 360)'} degrees"
        ),
    )
    if problem:
        return problem
    tolerance = negative_noise_tolerance(values)
    problem = first_flagged_cell(
        values < -tolerance,
        channel_names,
        lambda r, k: (
            f"negative BRDF value {values[r, k]:g} beyond the noise tolerance -{tolerance:.3g} "
            f"(max({NEGATIVE_RTOL:g} × max|value|, {NEGATIVE_ATOL:g}))"
        ),
    )
    if problem or weight is None:
        return problem
    return first_flagged_cell(
        weight[:, None] < 0, [WEIGHT_COLUMN], lambda r, k: f"negative weight {weight[r]:g}"
    )


def as_float_array(name: str, array, ndim: int, source: str) -> np.ndarray:
    """``array`` as a contiguous float64 array of ``ndim`` dimensions, else :class:`InputError`."""
    array = np.asarray(array)
    if array.dtype.kind not in "fiu":
        raise InputError(f"{name} must hold real numbers, got dtype {array.dtype}", path=source)
    if array.ndim != ndim:
        raise InputError(f"{name} must be {ndim}-D, got shape {array.shape}", path=source)
    return np.ascontiguousarray(array, dtype=np.float64)


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
        """Unit direction vectors ``(wi, wo)``, each ``[N, 3]``, in the local frame (SPEC §1)."""
        return spherical_pair_to_vectors(self.theta_i, self.phi_i, self.theta_o, self.phi_o)

    def inplane_angles(self) -> tuple[np.ndarray, np.ndarray]:
        """Signed in-plane ``(theta_i, theta_r)`` in degrees of every row.

        Exact (sign of ``theta_i`` included) for rows in the plane of incidence, the Rusinkiewicz
        in-plane equivalent elsewhere (:func:`neuralbrdf.geometry.spherical_to_inplane`); far out
        of plane ``theta_i`` can exceed 90°.
        """
        return spherical_to_inplane(self.theta_i, self.phi_i, self.theta_o, self.phi_o)

    def to_rgb(self) -> BrdfTable:
        """Linear-sRGB version of a spectral table (SPEC §2.3); an RGB table is returned as is.

        Spectra outside the sRGB gamut give negative channels; they are clipped to 0 (the table
        holds BRDF values) with a warning giving their count.
        """
        # Imported on use: plain table I/O should not pay for importing colour-science.
        from neuralbrdf.data.colorimetry import spectral_to_linear_srgb

        if not self.is_spectral:
            return self
        rgb = spectral_to_linear_srgb(self.values, self.wavelengths)
        negative = rgb < 0
        if negative.any():
            warnings.warn(
                f"{self.source}: clipped {int(negative.sum())} negative linear-sRGB value(s) "
                f"(spectra outside the sRGB gamut, down to {rgb.min():.3g}) to 0",
                stacklevel=2,
            )
            rgb = np.where(negative, 0.0, rgb)
        weight = None if self.weight is None else self.weight.copy()
        return BrdfTable(
            self.theta_i.copy(), self.phi_i.copy(), self.theta_o.copy(), self.phi_o.copy(),
            rgb, None, weight, f"{self.source} (linear sRGB)",
        )


# --------------------------------------------------------------------------- file I/O

GCMS_HINT = " (a GCMS raw file? load it with load_measurement and its Munsell reference)"


def _value_columns(csv_file: NumericCsv) -> tuple[list[str], np.ndarray | None]:
    """Names of the value columns in file order, and the wavelengths (``None`` for RGB)."""
    rgb, spectral = [], []
    for name in csv_file.header:
        if name in ANGLE_COLUMNS or name == WEIGHT_COLUMN:
            continue
        if name in RGB_CHANNELS:
            rgb.append(name)
        elif parse_wavelength(name) is not None:
            spectral.append(name)
        else:
            hint = GCMS_HINT if name == "theta_r" else ""
            raise csv_file.header_error(
                f"unknown column; expected {', '.join(ANGLE_COLUMNS)}, then R, G, B or wavelengths "
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


def read_table(path: str | os.PathLike[str]) -> BrdfTable:
    """Read a BRDF sample table (SPEC §2.1), rejecting any defect with file, line and column."""
    return table_from_csv(read_numeric_csv(path))


def table_from_csv(csv_file: NumericCsv) -> BrdfTable:
    """The BRDF sample table held by a parsed CSV file (see :func:`read_table`)."""
    value_names, wavelengths = _value_columns(csv_file)
    for name in ANGLE_COLUMNS:
        if name not in csv_file.header:
            raise csv_file.header_error(
                f"missing required column; a table starts {', '.join(ANGLE_COLUMNS)}", column=name
            )
    weight = csv_file.column(WEIGHT_COLUMN) if WEIGHT_COLUMN in csv_file.header else None
    values = np.stack([csv_file.column(name) for name in value_names], axis=1)
    angles = np.stack([csv_file.column(name) for name in ANGLE_COLUMNS], axis=1)
    # Validate here too so that errors carry file lines rather than row indices.
    problem = _table_cell_problem(angles, values, value_names, weight)
    if problem:
        raise problem.to_error(csv_file.path, csv_file.lines)
    return BrdfTable(*angles.T, values, wavelengths, weight, csv_file.path)


def write_table(table: BrdfTable, path: str | os.PathLike[str]) -> None:
    """Write ``table`` atomically in the canonical column order; numbers round-trip exactly."""
    header = [*ANGLE_COLUMNS, *table.channel_names]
    data = np.concatenate([table._angles(), table.values], axis=1)
    if table.weight is not None:
        header.append(WEIGHT_COLUMN)
        data = np.concatenate([data, table.weight[:, None]], axis=1)
    write_numeric_csv(path, header, data)
