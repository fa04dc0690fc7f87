"""Spectral complex refractive indices ``n + i k`` from the tables shipped with Mitsuba 3.

Mitsuba's Python package carries measured optical constants in ``data/ior/<NAME>.eta.spd`` (real
part ``n``) and ``<NAME>.k.spd`` (extinction ``k``): text files whose ``#`` lines are comments
and whose data lines hold a vacuum wavelength in nm and a value. The gold tables (``Au``) say in
their header that they come from the luxpop.com database of optical constants, which compiles
its metal data from Palik, *Handbook of Optical Constants of Solids* (Academic Press, 1985). The
header labels the first column "Lambda (A)", but the values (298.8–885.6) are nanometres, which
is how Mitsuba reads them. Values are linearly interpolated onto the requested wavelengths
(``numpy.interp``); a wavelength outside a table's range is an error, never an extrapolation.
"""

from __future__ import annotations

import functools
import importlib.metadata
from pathlib import Path

import numpy as np

from neuralbrdf.errors import InputError

GOLD = "Au"


def mitsuba_ior_dir() -> Path:
    """Folder of Mitsuba's optical-constant tables (``<mitsuba package>/data/ior``).

    Found through the installed distribution's files, without importing Mitsuba (whose module
    object replaces itself once a variant is set, so import-system look-ups are unreliable).
    """
    try:
        folder = Path(importlib.metadata.distribution("mitsuba").locate_file("mitsuba/data/ior"))
    except importlib.metadata.PackageNotFoundError:
        raise InputError("the mitsuba package is not installed; its data/ior tables are needed") from None
    if not folder.is_dir():
        raise InputError(f"the installed mitsuba package has no optical-constant folder {folder}")
    return folder


@functools.lru_cache(maxsize=None)
def read_spd(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a two-column ``.spd`` table: ``(wavelengths_nm, values)``, strictly increasing."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise InputError(f"cannot read optical-constant table: {exc.strerror}", path=path) from None
    rows = []
    for number, line in enumerate(lines, start=1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        fields = text.split()
        try:
            if len(fields) != 2:
                raise ValueError
            rows.append((float(fields[0]), float(fields[1])))
        except ValueError:
            raise InputError(
                f"expected two numbers (wavelength in nm, value), got {text!r}",
                path=path, line=number,
            ) from None
    if len(rows) < 2:
        raise InputError("an optical-constant table needs at least two data lines", path=path)
    table = np.asarray(rows, dtype=np.float64)
    if not np.all(np.isfinite(table)) or not np.all(np.diff(table[:, 0]) > 0):
        raise InputError("wavelengths must be finite and strictly increasing", path=path)
    return table[:, 0], table[:, 1]


def complex_index(material: str, wavelengths_nm) -> tuple[np.ndarray, np.ndarray]:
    """``(n, k)`` of a Mitsuba ``data/ior`` material (e.g. ``"Au"``) at ``wavelengths_nm``.

    Returns two float64 arrays shaped like ``wavelengths_nm``.  Raises :class:`InputError` for an
    unknown material or a wavelength outside the table's range.
    """
    folder = mitsuba_ior_dir()
    wavelengths = np.asarray(wavelengths_nm, dtype=np.float64)
    result = []
    for part in ("eta", "k"):
        path = folder / f"{material}.{part}.spd"
        if not path.is_file():
            known = sorted(p.name.split(".")[0] for p in folder.glob("*.eta.spd"))
            raise InputError(
                f"no optical constants for {material!r} in Mitsuba's data/ior; "
                f"known: {', '.join(known)}"
            )
        table_nm, values = read_spd(path)
        outside = ~((wavelengths >= table_nm[0]) & (wavelengths <= table_nm[-1]))
        if np.any(outside):
            raise InputError(
                f"wavelength {float(wavelengths[outside].flat[0]):g} nm is outside the table's range "
                f"[{table_nm[0]:.1f}, {table_nm[-1]:.1f}] nm",
                path=path,
            )
        result.append(np.interp(wavelengths, table_nm, values))
    return result[0], result[1]


def gold_complex_index(wavelengths_nm) -> tuple[np.ndarray, np.ndarray]:
    """``(n, k)`` of gold at ``wavelengths_nm`` (Mitsuba's ``Au`` tables, luxpop / Palik)."""
    return complex_index(GOLD, wavelengths_nm)
