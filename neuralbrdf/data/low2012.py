"""Löw et al.'s (2012) published ABC fits of the MERL materials (docs/formats.md#löw-et-als-abc-fits).

J. Löw, J. Kronander, A. Ynnerman, J. Unger, "BRDF models for accurate and efficient rendering
of glossy surfaces", ACM TOG 31(1), 2012: RGB parameters of the ABC model
(:class:`~neuralbrdf.physics.abc.AbcParameters`, docs/models.md#abc) fitted to all MERL samples.
"""

from __future__ import annotations

import os

from neuralbrdf.data.csvio import read_csv_rows
from neuralbrdf.errors import InputError
from neuralbrdf.physics.abc import AbcParameters

#: Column order of Löw et al.'s published fits (docs/formats.md#löw-et-als-abc-fits).
LOW2012_COLUMNS = ("material", "kd_r", "kd_g", "kd_b", "A_r", "A_g", "A_b", "B", "C", "eta")


def load_low2012_parameters(path: str | os.PathLike[str]) -> dict[str, AbcParameters]:
    """Löw et al.'s (2012) published RGB ABC fits, ``{material: AbcParameters}``.

    The CSV has the header :data:`LOW2012_COLUMNS` and one row per material; every defect
    (missing or unknown column, non-numeric or out-of-range cell, duplicated or empty material)
    raises :class:`InputError` with the file, line and column.  ``eta`` near 100 marks a fit
    that ran into Löw's bound (tungsten-carbide); it is loaded as published.
    """
    path = str(path)
    header, rows, lines = read_csv_rows(path)
    if header is None:
        raise InputError("empty file: expected a header line", path=path, line=1)
    header = [name.strip() for name in header]
    for name in LOW2012_COLUMNS:
        if name not in header:
            raise InputError("missing column", path=path, line=1, column=name)
    for name in header:
        if name not in LOW2012_COLUMNS or header.count(name) > 1:
            raise InputError(
                f"unexpected or duplicated column; expected {', '.join(LOW2012_COLUMNS)}", path=path, line=1, column=name
            )
    if not rows:
        raise InputError("no data rows after the header", path=path, line=2)
    fits = {}
    for row, line in zip(rows, lines):
        if len(row) != len(header):
            raise InputError(f"row has {len(row)} cells but the header has {len(header)}", path=path, line=line)
        cells = dict(zip(header, (cell.strip() for cell in row)))
        material = cells.pop("material")
        if not material:
            raise InputError("empty material name", path=path, line=line, column="material")
        if material in fits:
            raise InputError(f"material {material!r} listed twice", path=path, line=line, column="material")
        numbers = {}
        for name, cell in cells.items():
            try:
                numbers[name] = float(cell)
            except ValueError:
                raise InputError(f"not a number: {cell!r}", path=path, line=line, column=name) from None
        try:
            fits[material] = AbcParameters(
                kd=[numbers["kd_r"], numbers["kd_g"], numbers["kd_b"]],
                A=[numbers["A_r"], numbers["A_g"], numbers["A_b"]],
                B=numbers["B"],
                C=numbers["C"],
                eta=numbers["eta"],
            )
        except InputError as error:
            raise InputError(error.reason, path=path, line=line, column=error.key) from None  # a parameter named as its column
    return fits
