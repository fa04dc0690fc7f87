"""Airy reflectance of a single thin dielectric film on a dielectric substrate.

Three media: ambient (index ``n0``, default air), a film of index ``n1`` and thickness ``d`` (nm),
and a semi-infinite substrate of index ``n2``, all real (non-absorbing).  Summing the multiple
reflections inside the film gives the Airy amplitude reflectance for each polarisation (Born &
Wolf, *Principles of Optics*, 7th ed., §1.6.4; Heavens, *Optical Properties of Thin Solid
Films*, 1955, ch. 4)::

    r = (r01 + r12 e^{i delta}) / (1 + r01 r12 e^{i delta}),   delta = 4 pi n1 d cos(theta1) / lambda

whose squared modulus, with real interface coefficients, is::

    R = (r01² + r12² + 2 r01 r12 cos delta) / (1 + r01² r12² + 2 r01 r12 cos delta).

``r01``, ``r12`` are the Fresnel amplitude coefficients of the ambient/film and film/substrate
interfaces (s: ``(na ca - nb cb) / (na ca + nb cb)``, p: ``(nb ca - na cb) / (nb ca + na cb)``),
with the angles inside the film and the substrate from Snell's law.  The unpolarised reflectance
is ``(R_s + R_p) / 2``.  Indices must not be below the ambient's, so no interface totally
reflects and every coefficient stays real.  Vectorised over NumPy arrays and torch tensors.
"""

from __future__ import annotations

import math

import numpy as np

from neuralbrdf.errors import InputError
from neuralbrdf.geometry import array_namespace_of


def _snell_cos(xp, sin2_ambient, ratio):
    """``cos`` of the refracted angle in a medium of index ``n = n0 / ratio``."""
    return xp.sqrt(xp.clip(1.0 - ratio * ratio * sin2_ambient, 0.0, 1.0))


def _airy(r01, r12, cos_delta):
    num = r01 * r01 + r12 * r12 + 2.0 * r01 * r12 * cos_delta
    den = 1.0 + r01 * r01 * r12 * r12 + 2.0 * r01 * r12 * cos_delta
    return num / den


def _check_parameter(name: str, value, minimum: float):
    """``value`` (a number, or a NumPy array broadcasting with the angles) if every entry is a
    finite number >= ``minimum``, else :class:`InputError`."""
    array = np.asarray(value, dtype=np.float64)
    if not (np.all(np.isfinite(array)) and np.all(array >= minimum)):
        raise InputError(f"{name} must be finite numbers >= {minimum:g}, got {value!r}")
    return float(array) if array.ndim == 0 else array


def thin_film_reflectance(
    cos_theta,
    wavelength_nm,
    film_index: float,
    thickness_nm: float,
    substrate_index: float,
    ambient_index: float = 1.0,
):
    """Unpolarised Airy reflectance of a dielectric film on a dielectric substrate.

    Parameters
    ----------
    cos_theta:
        Cosine of the incidence angle in the ambient medium (clipped to [0, 1]).
    wavelength_nm:
        Vacuum wavelength in nm, broadcasting with ``cos_theta`` (e.g. ``cos[:, None]`` with
        wavelengths ``[W]`` gives ``[N, W]``).
    film_index, thickness_nm, substrate_index, ambient_index:
        Real refractive indices and the film thickness in nm.  ``film_index`` and
        ``substrate_index`` must be at least ``ambient_index``.  The first three may be NumPy
        arrays broadcasting with ``cos_theta`` (one film per sample); ``ambient_index`` is a number.

    Returns
    -------
    Reflectance in [0, 1], the broadcast shape of ``cos_theta`` and ``wavelength_nm``.
    """
    n0 = float(_check_parameter("ambient_index", ambient_index, 1e-6))
    n1 = _check_parameter("film_index", film_index, n0)
    n2 = _check_parameter("substrate_index", substrate_index, n0)
    d = _check_parameter("thickness_nm", thickness_nm, 0.0)
    xp = array_namespace_of(cos_theta, wavelength_nm)
    wavelength_nm = xp.asarray(wavelength_nm)
    if not bool(xp.all(wavelength_nm > 0.0)):
        raise InputError("wavelength_nm must be positive (nm)")
    c0 = xp.clip(cos_theta, 0.0, 1.0)
    sin2 = 1.0 - c0 * c0
    c1 = _snell_cos(xp, sin2, n0 / n1)
    c2 = _snell_cos(xp, sin2, n0 / n2)
    cos_delta = xp.cos(4.0 * math.pi * n1 * d * c1 / wavelength_nm)
    r01_s = (n0 * c0 - n1 * c1) / (n0 * c0 + n1 * c1)
    r12_s = (n1 * c1 - n2 * c2) / (n1 * c1 + n2 * c2)
    r01_p = (n1 * c0 - n0 * c1) / (n1 * c0 + n0 * c1)
    r12_p = (n2 * c1 - n1 * c2) / (n2 * c1 + n1 * c2)
    return 0.5 * (_airy(r01_s, r12_s, cos_delta) + _airy(r01_p, r12_p, cos_delta))
