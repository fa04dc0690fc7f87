"""The signed in-plane BRDF table: calibrated BRDF values at the angles a goniospectrophotometer
writes (docs/formats.md, *In-plane BRDF table*).

CSV with a header ``theta_i_signed, theta_r_signed`` — signed in-plane angles in degrees, the
report's convention (:mod:`neuralbrdf.geometry`: ``wi = (sin θi, 0, cos θi)``,
``wo = (−sin θr, 0, cos θr)``, the mirror direction at ``θr = θi``) — then either ``R, G, B``
(linear sRGB, sr⁻¹) or one column per wavelength in nm (a regular, increasing grid), and an
optional ``weight`` column: the BRDF sample table of :mod:`neuralbrdf.data.table` with the
geometry written as signed angles instead of spherical ones.  It becomes the same
:class:`~neuralbrdf.data.table.BrdfTable` (the sign of ``θi`` kept, as
:func:`~neuralbrdf.geometry.inplane_to_spherical` stores it).

The angle columns are named apart from a GCMS raw file's ``theta_i, theta_r`` on purpose: a GCMS
raw file holds a radiance factor that needs its Munsell reference, this table holds the BRDF
itself, and the header alone says which a file is (:func:`neuralbrdf.data.loading.load_measurement`),
never its values.  Reading is as strict as for the spherical table: every defect names the file,
the line and the column; angles must lie in [−90°, 90°].
"""

from __future__ import annotations

import os

import numpy as np

from neuralbrdf.data.csvio import NumericCsv, first_flagged_cell, read_numeric_csv
from neuralbrdf.data.table import (
    INPLANE_ANGLE_COLUMNS,
    THETA_RANGE_HINT,
    WEIGHT_COLUMN,
    BrdfTable,
    conflicting_repeat,
    required_columns,
    value_columns,
    value_problem,
    write_with_geometry,
)
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import inplane_to_spherical


def is_inplane_header(header) -> bool:
    """Whether a CSV header is that of a signed in-plane BRDF table (its angle columns)."""
    return any(name in header for name in INPLANE_ANGLE_COLUMNS)


def read_inplane_table(path: str | os.PathLike[str]) -> BrdfTable:
    """Read a signed in-plane BRDF table, rejecting any defect with file, line and column."""
    return inplane_table_from_csv(read_numeric_csv(path))


def inplane_table_from_csv(csv_file: NumericCsv) -> BrdfTable:
    """The BRDF table held by a parsed signed in-plane CSV file (see :func:`read_inplane_table`)."""
    value_names, wavelengths = value_columns(csv_file, INPLANE_ANGLE_COLUMNS)
    required_columns(csv_file, INPLANE_ANGLE_COLUMNS, "an in-plane table")
    angles = np.stack([csv_file.column(name) for name in INPLANE_ANGLE_COLUMNS], axis=1)
    values = np.stack([csv_file.column(name) for name in value_names], axis=1)
    weight = csv_file.column(WEIGHT_COLUMN) if WEIGHT_COLUMN in csv_file.header else None
    problem = (
        first_flagged_cell(np.abs(angles) > 90, INPLANE_ANGLE_COLUMNS,
                           lambda r, k: f"angle {angles[r, k]:g}° outside [-90, 90] degrees ({THETA_RANGE_HINT})")
        or value_problem(values, value_names, weight)
        or conflicting_repeat(angles, values, weight, csv_file.lines, INPLANE_ANGLE_COLUMNS)
    )
    if problem:
        raise problem.to_error(csv_file.path, csv_file.lines)
    return BrdfTable(*inplane_to_spherical(angles[:, 0], angles[:, 1]), values, wavelengths, weight, csv_file.path)


def write_inplane_table(table: BrdfTable, path: str | os.PathLike[str]) -> None:
    """Write an in-plane ``table`` atomically as a signed in-plane table; numbers round-trip
    exactly.  :class:`InputError` when a row lies out of the plane of incidence."""
    out_of_plane = np.flatnonzero(~table.in_plane_mask())
    if out_of_plane.size:
        raise InputError(f"row {int(out_of_plane[0])} is out of the plane of incidence; an in-plane table holds "
                         "in-plane rows only", path=table.source)
    write_with_geometry(table, INPLANE_ANGLE_COLUMNS, np.stack(table.inplane_angles(), axis=1), path)
