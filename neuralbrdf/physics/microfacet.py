"""Microfacet reflection: GGX and Beckmann normal distributions, Smith shadowing, the BRDF.

Implements the reflection part of Walter, Marschner, Li & Torrance (2007), *Microfacet models
for refraction through rough surfaces* (EGSR):

* GGX / Trowbridge–Reitz distribution (Eq. 33)::

      D(h) = alpha² / (pi cos⁴θh (alpha² + tan²θh)²) = alpha² / (pi (cos²θh (alpha² - 1) + 1)²)

* Beckmann distribution (Eq. 25)::

      D(h) = exp(-tan²θh / alpha²) / (pi alpha² cos⁴θh)

* Smith's masking for GGX (Eq. 34), ``G1(v) = 2 cosθv / (cosθv + sqrt(alpha² + (1 - alpha²)
  cos²θv))``, and for Beckmann (Eq. 24, exact; NumPy only, it needs ``erf``), and the separable
  shadowing–masking ``G2(wi, wo) = G1(wi) G1(wo)`` (Eq. 23);
* the reflection BRDF (Eq. 20)::

      f(wi, wo) = F(wi·h) D(h) G2(wi, wo) / (4 cosθi cosθo),   h = normalize(wi + wo).

Both distributions are normalised so that ``∫ D(h) cosθh dω_h = 1`` over the hemisphere.
``alpha`` is the roughness (the distributions' width parameter; no remapping).  Directions follow
:mod:`neuralbrdf.geometry` (unit vectors ``[..., 3]``, ``z`` the normal, both pointing away from
the surface); the BRDF is zero when either direction is at or below the horizon.  Everything is
vectorised over NumPy arrays and torch tensors (array API).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy.special import erf

from neuralbrdf.geometry import array_namespace_of, dot, half_vector_above


def ggx_distribution(cos_theta_h, alpha):
    """GGX (Trowbridge–Reitz) normal distribution ``D(h)`` in sr⁻¹; zero for ``cosθh <= 0``."""
    xp = array_namespace_of(cos_theta_h, alpha)
    c2 = cos_theta_h * cos_theta_h
    a2 = alpha * alpha
    denom = c2 * (a2 - 1.0) + 1.0
    d = a2 / (math.pi * denom * denom)
    return xp.where(cos_theta_h > 0.0, d, xp.zeros_like(d))


def beckmann_distribution(cos_theta_h, alpha):
    """Beckmann normal distribution ``D(h)`` in sr⁻¹; zero for ``cosθh <= 0``."""
    xp = array_namespace_of(cos_theta_h, alpha)
    positive = cos_theta_h > 0.0
    c2 = xp.where(positive, cos_theta_h * cos_theta_h, xp.ones_like(cos_theta_h))
    a2 = alpha * alpha
    tan2 = (1.0 - c2) / c2
    d = xp.exp(-tan2 / a2) / (math.pi * a2 * c2 * c2)
    return xp.where(positive, d, xp.zeros_like(d))


def ggx_smith_g1(cos_theta, alpha):
    """Smith masking ``G1`` of GGX for a direction at ``cosθ`` to the macro-normal.

    Zero for ``cosθ <= 0``.  Valid for directions on the visible side of the microfacet
    (``v·h > 0``), which always holds for the half vector of a reflection pair.
    """
    xp = array_namespace_of(cos_theta, alpha)
    positive = cos_theta > 0.0
    c = xp.where(positive, xp.clip(cos_theta, 0.0, 1.0), xp.ones_like(cos_theta))
    a2 = alpha * alpha
    g1 = 2.0 * c / (c + xp.sqrt(a2 + (1.0 - a2) * c * c))
    return xp.where(positive, g1, xp.zeros_like(g1))


def beckmann_smith_g1(cos_theta, alpha):
    """Exact Smith masking of the Beckmann distribution (Walter et al. 2007 Eq. 24).

    ``G1 = 1 / (1 + Λ(a))``, ``Λ(a) = (erf(a) - 1)/2 + exp(-a²) / (2 a √π)``,
    ``a = cos θ / (alpha sin θ)``; ``G1 = 1`` at the pole and 0 for ``cos θ <= 0``.
    """
    cos_theta = np.asarray(cos_theta, dtype=np.float64)
    positive = cos_theta > 0.0
    c = np.clip(cos_theta, 1e-12, 1.0)
    sin_theta = np.sqrt(np.clip(1.0 - c * c, 0.0, None))
    with np.errstate(divide="ignore"):
        a = np.where(sin_theta > 0.0, c / (alpha * sin_theta), np.inf)
    a_safe = np.where(np.isfinite(a), a, 1.0)
    lam = 0.5 * (erf(a_safe) - 1.0) + np.exp(-a_safe * a_safe) / (2.0 * a_safe * math.sqrt(math.pi))
    lam = np.where(np.isfinite(a), lam, 0.0)
    return np.where(positive, 1.0 / (1.0 + lam), 0.0)


#: ``(D, G1)`` of each normal distribution, for :func:`microfacet_brdf`.
DISTRIBUTIONS = {
    "ggx": (ggx_distribution, ggx_smith_g1),
    "beckmann": (beckmann_distribution, beckmann_smith_g1),
}


def microfacet_brdf(wi, wo, alpha, fresnel_fn: Callable, distribution: str = "ggx"):
    """Microfacet reflection BRDF ``F D G2 / (4 cosθi cosθo)`` in sr⁻¹ (Walter et al. Eq. 20).

    Parameters
    ----------
    wi, wo:
        Unit directions ``[..., 3]`` (toward the light and the viewer).
    alpha:
        Roughness, a positive scalar or an array broadcasting with ``[...]``.
    fresnel_fn:
        Maps ``cosθd = wi·h`` of shape ``[...]`` to the Fresnel reflectance, of shape ``[...]``
        or ``[..., W]`` (one value per wavelength or channel).
    distribution:
        ``"ggx"`` or ``"beckmann"`` (:data:`DISTRIBUTIONS`; Beckmann is NumPy only).

    Returns
    -------
    The BRDF with the Fresnel term's shape; zero where ``wi`` or ``wo`` is at or below the
    horizon.
    """
    distribution_fn, smith_g1 = DISTRIBUTIONS[distribution]
    xp = array_namespace_of(wi, wo)
    cos_i = wi[..., 2]
    cos_o = wo[..., 2]
    h, above = half_vector_above(wi, wo)
    cos_d = xp.clip(dot(wi, h), 0.0, 1.0)
    safe_ci = xp.where(above, cos_i, xp.ones_like(cos_i))
    safe_co = xp.where(above, cos_o, xp.ones_like(cos_o))
    geometric = (
        distribution_fn(h[..., 2], alpha)
        * smith_g1(safe_ci, alpha)
        * smith_g1(safe_co, alpha)
        / (4.0 * safe_ci * safe_co)
    )
    geometric = xp.where(above, geometric, xp.zeros_like(geometric))
    fresnel = fresnel_fn(cos_d)
    if fresnel.ndim > geometric.ndim:
        geometric = geometric[..., None]
    return fresnel * geometric
