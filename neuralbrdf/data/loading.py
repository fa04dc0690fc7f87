"""One entry point for measured data, used by the command line and training configs (docs/formats.md).

:func:`load_measurement` accepts either a BRDF sample table (docs/formats.md#brdf-sample-table; header
``theta_i, phi_i, ...``) or a GCMS raw file (docs/formats.md#gcms-raw-measurement; header ``theta_i, theta_r, 390, ...``),
told apart by the header.  A GCMS raw file needs its Munsell N9 reference file and is calibrated
(report Eq. 2.3); a table is already a BRDF and must not be given one.
"""

from __future__ import annotations

import os

from neuralbrdf.data.calibration import calibrate
from neuralbrdf.data.gcms import GCMS_ANGLE_COLUMNS, gcms_from_csv, read_gcms
from neuralbrdf.data.csvio import read_numeric_csv
from neuralbrdf.data.table import BrdfTable, table_from_csv
from neuralbrdf.errors import InputError


def load_measurement(
    path: str | os.PathLike[str], reference: str | os.PathLike[str] | None = None
) -> BrdfTable:
    """The BRDF table in ``path``: read as is, or calibrated against ``reference`` if GCMS raw.

    Raises :class:`InputError` for a missing or malformed file, a GCMS raw file without
    ``reference``, or a table given one.
    """
    csv_file = read_numeric_csv(path)
    if csv_file.header[:2] != GCMS_ANGLE_COLUMNS:
        if reference is not None:
            raise InputError(
                "is a BRDF sample table, which needs no Munsell reference; "
                f"drop the reference {reference}",
                path=path,
            )
        return table_from_csv(csv_file)
    if reference is None:
        raise InputError(
            "is a GCMS raw file (header theta_i, theta_r, 390..730): pass the Munsell N9 reference "
            "file measured at the same geometries to calibrate it",
            path=path,
        )
    return calibrate(gcms_from_csv(csv_file), read_gcms(reference))
