"""One entry point for measured data, used by the command line and training configs (docs/formats.md).

Three file formats hold a measurement, told apart by their header alone (docs/formats.md):

* a BRDF sample table (:mod:`neuralbrdf.data.table`; header ``theta_i, phi_i, theta_o, phi_o``,
  spherical angles);
* a signed in-plane BRDF table (:mod:`neuralbrdf.data.inplane_table`; header
  ``theta_i_signed, theta_r_signed``);
* a GCMS raw file (:mod:`neuralbrdf.data.gcms`; header exactly ``theta_i, theta_r, 390, ..., 730``):
  a radiance factor, which needs its Munsell N9 reference file and is calibrated (report Eq. 2.3).

A table is already a BRDF and must not be given a reference.  Every table read here, calibrated
or not, passes the unit checks of :mod:`neuralbrdf.data.units` unless ``trust_units``.
"""

from __future__ import annotations

import os

from neuralbrdf.data.calibration import calibrate
from neuralbrdf.data.csvio import NumericCsv, parse_wavelength, read_numeric_csv
from neuralbrdf.data.gcms import GCMS_ANGLE_COLUMNS, GCMS_WAVELENGTHS_NM, gcms_from_csv, read_gcms
from neuralbrdf.data.inplane_table import inplane_table_from_csv, is_inplane_header
from neuralbrdf.data.table import INPLANE_ANGLE_COLUMNS, BrdfTable, table_from_csv
from neuralbrdf.data.units import check_units
from neuralbrdf.errors import InputError


def _is_gcms(csv_file: NumericCsv) -> bool:
    """Whether the file is GCMS raw: ``theta_i, theta_r`` then GCMS's own bands, nothing else.  A
    file that starts ``theta_i, theta_r`` with other columns is neither GCMS raw nor a table."""
    if csv_file.header[:2] != GCMS_ANGLE_COLUMNS:
        return False
    values = csv_file.header[2:]
    if [parse_wavelength(name) for name in values] != GCMS_WAVELENGTHS_NM.tolist():
        raise csv_file.header_error(
            f"starts theta_i, theta_r like a GCMS raw file, whose columns are the radiance factor at 390, 400, ..., "
            f"730 nm, but holds {', '.join(values[:4])}{', ...' if len(values) > 4 else ''}; a table of calibrated "
            f"BRDF values at signed in-plane angles names them {', '.join(INPLANE_ANGLE_COLUMNS)} (docs/formats.md)",
            column=next((got for got, want in zip(values, GCMS_WAVELENGTHS_NM) if parse_wavelength(got) != want),
                        None),
        )
    return True


def _table(csv_file: NumericCsv) -> BrdfTable:
    """The BRDF table of a parsed table file, spherical or signed in-plane."""
    return inplane_table_from_csv(csv_file) if is_inplane_header(csv_file.header) else table_from_csv(csv_file)


def read_brdf_table(path: str | os.PathLike[str], trust_units: bool = False) -> BrdfTable:
    """A BRDF table file — spherical or signed in-plane — checked for unit slips unless
    ``trust_units`` (:class:`~neuralbrdf.data.units.UnitsError`).  A GCMS raw file is refused:
    it is not a BRDF until calibrated (:func:`load_measurement`)."""
    csv_file = read_numeric_csv(path)
    if _is_gcms(csv_file):
        raise InputError("is a GCMS raw file (a radiance factor, not a BRDF): calibrate it against its Munsell N9 "
                         "reference first (neuralbrdf calibrate)", path=path)
    return check_units(_table(csv_file), trust_units)


def load_measurement(
    path: str | os.PathLike[str], reference: str | os.PathLike[str] | None = None, trust_units: bool = False
) -> BrdfTable:
    """The BRDF table in ``path``: read as is, or calibrated against ``reference`` if GCMS raw;
    either way checked for unit slips unless ``trust_units``.

    Raises :class:`InputError` for a missing or malformed file, a GCMS raw file without
    ``reference``, a table given one, or a unit slip (:class:`~neuralbrdf.data.units.UnitsError`).
    """
    csv_file = read_numeric_csv(path)
    if not _is_gcms(csv_file):
        if reference is not None:
            raise InputError(
                "is a BRDF sample table, which needs no Munsell reference; "
                f"drop the reference {reference}",
                path=path,
            )
        return check_units(_table(csv_file), trust_units)
    if reference is None:
        raise InputError(
            "is a GCMS raw file (header theta_i, theta_r, 390..730): pass the Munsell N9 reference "
            "file measured at the same geometries to calibrate it",
            path=path,
        )
    return check_units(calibrate(gcms_from_csv(csv_file), read_gcms(reference)), trust_units)
