"""Strict CSV reading and writing shared by the project's file formats (docs/formats.md).

Every defect is an :class:`~neuralbrdf.errors.InputError` naming the file, the line (the header
is line 1) and the column.  Blank lines are skipped; no data row is ever dropped.  Writers go
through :func:`neuralbrdf.atomic.atomic_write` and write numbers with ``repr`` so they
round-trip exactly.
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass

import numpy as np

from neuralbrdf.atomic import atomic_write, note_input
from neuralbrdf.errors import InputError
from neuralbrdf.limits import MAX_CSV_BYTES, check_file_size

#: Wavelength steps may differ by this fraction of the first step and still count as regular.
REGULAR_GRID_RTOL = 1e-6


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


def read_csv_rows(
    path: str, header_only: bool = False
) -> tuple[list[str] | None, list[list[str]], list[int]]:
    """Header row, data rows and their file lines; blank lines skipped; OS errors → InputError."""
    rows, lines = [], []
    note_input(path)
    check_file_size(path, MAX_CSV_BYTES, "CSV file")
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
    return _header_names(read_csv_rows(path, header_only=True)[0], path)


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
    header_row, rows, lines = read_csv_rows(path)
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


def as_float_array(name: str, array, ndim: int, source: str) -> np.ndarray:
    """``array`` as a contiguous float64 array of ``ndim`` dimensions, else :class:`InputError`."""
    array = np.asarray(array)
    if array.dtype.kind not in "fiu":
        raise InputError(f"{name} must hold real numbers, got dtype {array.dtype}", path=source)
    if array.ndim != ndim:
        raise InputError(f"{name} must be {ndim}-D, got shape {array.shape}", path=source)
    return np.ascontiguousarray(array, dtype=np.float64)
