"""Spectral BRDF → CIE XYZ → linear sRGB (docs/formats.md#spectral-to-linear-srgb; report §2.2, Eq. 2.4).

``X = k Σ f(λ) E(λ) x̄(λ)`` (likewise ``Y``, ``Z``) with ``k = 1 / Σ E(λ) ȳ(λ)`` over the
wavelengths of the data, ``E`` the CIE D65 illuminant and ``x̄, ȳ, z̄`` the CIE 1931 2°
observer, then the IEC 61966-2-1 XYZ → linear-sRGB matrix.  The report's ``k`` carries a
factor 100 (reflectance-factor scale); it is dropped here so that a flat spectrum
``f(λ) = c`` has ``Y = c`` exactly and maps to about ``(c, c, c)``: BRDF units (sr⁻¹) survive.

Tables come from colour-science (CMFs, illuminant, matrix), sampled onto the data's wavelength
grid with colour's own reshaping (``Align``: interpolation, constant extrapolation).  Sums are
plain Riemann sums on that grid, so the interval cancels in ``k``.

**One rule for every colour** (``to-rgb``, ``plot``, the viewer, an exported RGB head): a
spectrum is converted only when its wavelength range holds at least :data:`MIN_OBSERVER_COVERAGE`
of each of the observer's X, Y, Z weights over the sRGB conversion's 400–700 nm
(:func:`colour_problem`); a table of 500–800 nm would otherwise lose every blue.

All conversions accept NumPy arrays and PyTorch tensors (``[..., W]`` / ``[..., 3]``); torch
inputs keep their autograd graph.
"""

from __future__ import annotations

import functools

import colour
import numpy as np
from array_api_compat import array_namespace
from array_api_compat import device as array_device
from colour.colorimetry import reshape_msds, reshape_sd

from neuralbrdf.data.csvio import wavelength_grid_problem
from neuralbrdf.errors import InputError

CMFS_NAME = "CIE 1931 2 Degree Standard Observer"
ILLUMINANT_NAME = "D65"
#: Wavelength range (nm) covered by the CIE 1931 colour-matching functions.
CMFS_RANGE_NM = (360.0, 830.0)

#: Wavelengths (nm) on which a spectral model is integrated to sRGB (docs/formats.md#spectral-to-linear-srgb).
SRGB_GRID_NM = np.arange(400.0, 701.0, 10.0)
#: Least share of each of the CIE 1931 X, Y, Z weights (D65, on :data:`SRGB_GRID_NM`) that a
#: wavelength range must hold for a colour to be computed from it (module docstring).
MIN_OBSERVER_COVERAGE = 0.99

#: IEC 61966-2-1 (sRGB) XYZ → linear RGB matrix, ``rgb = M @ xyz``.
XYZ_TO_LINEAR_SRGB = np.array(colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB, dtype=np.float64)


def _check_grid(wavelengths_nm) -> np.ndarray:
    """The grid as float64 if it is regular, increasing, of 2+ bands and within 360–830 nm."""
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    problem = wavelength_grid_problem(wl)
    if problem is not None:
        raise InputError(problem[1])
    if wl.size < 2:
        raise InputError("colour conversion needs at least two wavelengths (a regular grid)")
    lo, hi = CMFS_RANGE_NM
    if wl[0] < lo or wl[-1] > hi:
        raise InputError(
            f"wavelengths {wl[0]:g}–{wl[-1]:g} nm leave the CIE 1931 observer's range "
            f"{lo:g}–{hi:g} nm"
        )
    return wl


@functools.lru_cache(maxsize=16)
def _xyz_weights(grid: tuple[float, ...]) -> np.ndarray:
    """``[W, 3]`` weights ``E x̄ / Σ E ȳ`` (columns X, Y, Z) on a validated regular grid."""
    wl = np.array(grid)
    shape = colour.SpectralShape(wl[0], wl[-1], (wl[-1] - wl[0]) / (wl.size - 1))
    if shape.wavelengths.size != wl.size or not np.allclose(shape.wavelengths, wl, atol=1e-6):
        raise InputError(
            f"colour-science cannot represent {wl.size} bands {wl[0]:g}..{wl[-1]:g} nm exactly"
        )
    cmfs = reshape_msds(colour.MSDS_CMFS[CMFS_NAME], shape).values
    illuminant = reshape_sd(colour.SDS_ILLUMINANTS[ILLUMINANT_NAME], shape).values
    weighted = illuminant[:, None] * cmfs
    weights = weighted / weighted[:, 1].sum()
    weights.flags.writeable = False
    return weights


def _matmul_constant(values, matrix: np.ndarray):
    """``values @ matrix`` for a NumPy or torch ``values``, the constant cast to match it."""
    xp = array_namespace(values)
    # A fresh copy: torch cannot wrap the cached read-only weights.
    constant = xp.asarray(np.array(matrix), dtype=values.dtype, device=array_device(values))
    return xp.matmul(values, constant)


def xyz_weights(wavelengths_nm) -> np.ndarray:
    """Read-only ``[W, 3]`` weights with ``xyz = values @ weights`` on this regular grid.

    Raises :class:`InputError` when the grid is irregular, unsorted or leaves 360–830 nm.
    """
    wl = _check_grid(wavelengths_nm)
    return _xyz_weights(tuple(wl.tolist()))


def spectral_to_xyz(values, wavelengths_nm):
    """CIE XYZ ``[..., 3]`` of spectral BRDF values ``[..., W]`` (Eq. 2.4 without the 100)."""
    weights = xyz_weights(wavelengths_nm)
    if values.shape[-1] != weights.shape[0]:
        raise InputError(
            f"spectral values have {values.shape[-1]} bands but {weights.shape[0]} wavelengths "
            "were given"
        )
    return _matmul_constant(values, weights)


def xyz_to_linear_srgb(xyz):
    """Linear sRGB ``[..., 3]`` of CIE XYZ ``[..., 3]`` (IEC 61966-2-1 matrix, no encoding)."""
    if xyz.shape[-1] != 3:
        raise InputError(f"XYZ arrays need a last axis of 3, got shape {tuple(xyz.shape)}")
    return _matmul_constant(xyz, XYZ_TO_LINEAR_SRGB.T)


def observer_coverage(wavelength_range_nm: tuple[float, float]) -> np.ndarray:
    """The share of each of the X, Y, Z weights of the sRGB conversion's grid (docs/formats.md#spectral-to-linear-srgb) that lies
    within ``wavelength_range_nm`` (``[3]``; the rest a colour would take by extrapolation)."""
    weights = xyz_weights(SRGB_GRID_NM)
    inside = (SRGB_GRID_NM >= wavelength_range_nm[0]) & (SRGB_GRID_NM <= wavelength_range_nm[1])
    return weights[inside].sum(axis=0) / weights.sum(axis=0)


def colour_problem(wavelength_range_nm: tuple[float, float], what: str) -> str | None:
    """Why ``what`` (``"the model"``, a table's file) of this wavelength range has no colour, or
    ``None`` when it has one (module docstring)."""
    coverage = observer_coverage(wavelength_range_nm)
    if coverage.min() >= MIN_OBSERVER_COVERAGE:
        return None
    low, high = wavelength_range_nm
    return (f"{what} covers {low:g}-{high:g} nm, which holds {100 * coverage.min():.3g} % of the CIE 1931 observer's "
            f"weight over the sRGB conversion's 400-700 nm (at least {100 * MIN_OBSERVER_COVERAGE:g} % needed): its "
            "RGB would be extrapolated")


def spectral_to_linear_srgb(values, wavelengths_nm):
    """Linear sRGB ``[..., 3]`` of spectral values ``[..., W]``; negative out of the sRGB gamut."""
    return xyz_to_linear_srgb(spectral_to_xyz(values, wavelengths_nm))
