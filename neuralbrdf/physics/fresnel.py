"""Fresnel reflectance of smooth interfaces (unpolarised light).

* Dielectric: the exact form used by Cook & Torrance (1982) and by the ABC model (report
  Eq. 2.6, Löw et al. 2012) with ``c = cos theta`` and ``g = sqrt(eta² - 1 + c²)`` (the report
  drops the square root; docs/models.md#abc restores it)::

      F = (g - c)² / (2 (g + c)²) · (1 + ((c (g + c) - 1) / (c (g - c) + 1))²)

  Total internal reflection (``eta² - 1 + c² < 0``, only for ``eta < 1``) gives ``F = 1``.
* Conductor: the exact unpolarised reflectance for a complex index ``eta + i k`` (e.g. Born &
  Wolf, *Principles of Optics*, §14.2; the form used by PBRT-v3 ``FrConductor``).

Vectorised over NumPy arrays and torch tensors.  ``cos_theta`` is the cosine between the
incident direction and the (micro)surface normal, clipped to [0, 1].
"""

from __future__ import annotations

from neuralbrdf.geometry import array_namespace_of


def fresnel_dielectric(cos_theta, eta):
    """Exact unpolarised Fresnel reflectance of a dielectric with relative index ``eta``."""
    xp = array_namespace_of(cos_theta, eta)
    c = xp.clip(cos_theta, 0.0, 1.0)
    g2 = eta * eta - 1.0 + c * c
    tir = g2 <= 0.0
    g = xp.sqrt(xp.clip(g2, 0.0, None))
    a = (g - c) / (g + c + 1e-30)
    b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    f = 0.5 * a * a * (1.0 + b * b)
    return xp.where(tir, xp.ones_like(f), f)


def fresnel_conductor(cos_theta, eta, k):
    """Exact unpolarised Fresnel reflectance of a conductor with complex index ``eta + i k``."""
    xp = array_namespace_of(cos_theta, eta, k)
    c = xp.clip(cos_theta, 0.0, 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    t0 = eta * eta - k * k - s2
    a2b2 = xp.sqrt(t0 * t0 + 4.0 * eta * eta * k * k)
    a = xp.sqrt(xp.clip(0.5 * (a2b2 + t0), 0.0, None))
    t1 = a2b2 + c2
    t2 = 2.0 * c * a
    rs = (t1 - t2) / (t1 + t2)
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    rp = rs * (t3 - t4) / (t3 + t4)
    return 0.5 * (rs + rp)
