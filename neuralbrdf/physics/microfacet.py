"""Microfacet reflection: GGX and Beckmann normal distributions, Smith shadowing, the BRDF.

Implements the reflection part of Walter, Marschner, Li & Torrance (2007), *Microfacet models
for refraction through rough surfaces* (EGSR):

* GGX / Trowbridge–Reitz distribution (Eq. 33)::

      D(h) = alpha² / (pi cos⁴θh (alpha² + tan²θh)²) = alpha² / (pi (cos²θh (alpha² - 1) + 1)²)

* Beckmann distribution (Eq. 25)::

      D(h) = exp(-tan²θh / alpha²) / (pi alpha² cos⁴θh)

* Smith's masking for GGX (Eq. 34), ``G1(v) = 2 cosθv / (cosθv + sqrt(alpha² + (1 - alpha²)
  cos²θv))``, and the separable shadowing–masking ``G2(wi, wo) = G1(wi) G1(wo)`` (Eq. 23);
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

from array_api_compat import array_namespace

from neuralbrdf.geometry import dot, normalize


def _ns(*xs):
    return array_namespace(*[x for x in xs if not isinstance(x, (int, float))])


def ggx_distribution(cos_theta_h, alpha):
    """GGX (Trowbridge–Reitz) normal distribution ``D(h)`` in sr⁻¹; zero for ``cosθh <= 0``."""
    xp = _ns(cos_theta_h, alpha)
    c2 = cos_theta_h * cos_theta_h
    a2 = alpha * alpha
    denom = c2 * (a2 - 1.0) + 1.0
    d = a2 / (math.pi * denom * denom)
    return xp.where(cos_theta_h > 0.0, d, xp.zeros_like(d))


def beckmann_distribution(cos_theta_h, alpha):
    """Beckmann normal distribution ``D(h)`` in sr⁻¹; zero for ``cosθh <= 0``."""
    xp = _ns(cos_theta_h, alpha)
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
    xp = _ns(cos_theta, alpha)
    positive = cos_theta > 0.0
    c = xp.where(positive, xp.clip(cos_theta, 0.0, 1.0), xp.ones_like(cos_theta))
    a2 = alpha * alpha
    g1 = 2.0 * c / (c + xp.sqrt(a2 + (1.0 - a2) * c * c))
    return xp.where(positive, g1, xp.zeros_like(g1))


def ggx_smith_g2(cos_theta_i, cos_theta_o, alpha):
    """Separable Smith shadowing–masking ``G2 = G1(wi) G1(wo)`` for GGX."""
    return ggx_smith_g1(cos_theta_i, alpha) * ggx_smith_g1(cos_theta_o, alpha)


def microfacet_brdf(wi, wo, alpha, fresnel_fn: Callable):
    """GGX microfacet reflection BRDF ``F D G2 / (4 cosθi cosθo)`` in sr⁻¹ (Walter et al. Eq. 20).

    Parameters
    ----------
    wi, wo:
        Unit directions ``[..., 3]`` (toward the light and the viewer).
    alpha:
        GGX roughness, a positive scalar or an array broadcasting with ``[...]``.
    fresnel_fn:
        Maps ``cosθd = wi·h`` of shape ``[...]`` to the Fresnel reflectance, of shape ``[...]``
        or ``[..., W]`` (one value per wavelength or channel).

    Returns
    -------
    The BRDF with the Fresnel term's shape; zero where ``wi`` or ``wo`` is at or below the
    horizon.
    """
    xp = _ns(wi, wo)
    cos_i = wi[..., 2]
    cos_o = wo[..., 2]
    above = (cos_i > 0.0) & (cos_o > 0.0)
    # Below the horizon wi + wo may vanish; use the normal there so nothing divides by zero.
    zero = xp.zeros_like(cos_i)
    pole = xp.stack([zero, zero, zero + 1.0], axis=-1)
    h = normalize(xp.where(above[..., None], wi + wo, pole))
    cos_d = xp.clip(dot(wi, h), 0.0, 1.0)
    safe_ci = xp.where(above, cos_i, xp.ones_like(cos_i))
    safe_co = xp.where(above, cos_o, xp.ones_like(cos_o))
    geometric = (
        ggx_distribution(h[..., 2], alpha)
        * ggx_smith_g2(safe_ci, safe_co, alpha)
        / (4.0 * safe_ci * safe_co)
    )
    geometric = xp.where(above, geometric, xp.zeros_like(geometric))
    fresnel = fresnel_fn(cos_d)
    if fresnel.ndim > geometric.ndim:
        geometric = geometric[..., None]
    return fresnel * geometric
