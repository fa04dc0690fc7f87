"""The ABC microfacet BRDF of Löw, Kronander, Ynnerman & Unger (2012) and its parameters.

J. Löw, J. Kronander, A. Ynnerman, J. Unger, "BRDF models for accurate and efficient rendering
of glossy surfaces", ACM TOG 31(1), 2012 — in the form of the report (S. Chitnis, *Simplifying
BRDF Acquisition*, Eqs. 2.5–2.8, 4.1) as docs/models.md#abc states it::

    f(wi, wo) = kd/π + A · F(η, wi·h) · G / (π · cos ti · cos to · (1 + B (1 - n·h))^C)

* ``kd`` (diffuse albedo) and ``A`` (specular scale) per channel (RGB or wavelength); the
  normal-distribution shape ``B``, ``C`` and the index of refraction ``η`` are scalars.  The
  ``1/π`` on the specular term makes Löw's published parameters usable as they are.
* ``F``: exact unpolarised dielectric Fresnel (:func:`neuralbrdf.physics.fresnel.fresnel_dielectric`)
  at ``c = wi·h = wo·h``.
* ``G = min(1, 2(n·h)(n·wo)/(wo·h), 2(n·h)(n·wi)/(wo·h))`` (Cook–Torrance V-cavity).
* ``h = normalize(wi + wo)``; ``f = 0`` when either direction is at or below the horizon.

**Grazing angles.**  ``G / (cos ti cos to)`` is evaluated as ``min(1/(cos ti cos to),
2(n·h)/((wo·h) cos ti), 2(n·h)/((wo·h) cos to))``, which cancels the cosines analytically: the
BRDF stays finite as one direction goes to the horizon.  Only the grazing *mirror*
configuration (both cosines and ``wo·h`` -> 0) truly diverges, like ``1/(cos ti cos to)``; there
the three denominators are clamped at :data:`COS_EPS` = 1e-4 (within 0.006° of the horizon),
which caps the specular term at ``A/(π · 1e-8)`` and keeps gradients finite.  Above that the
formula is exact.

**Sharpness and the Gaussian limit.**  For narrow lobes ``(1 + B x)^(-C)`` (``x = 1 - cos θh``)
depends on ``B`` and ``C`` mostly through their product: near the peak it is ``exp(-B·C·x)``, and
as ``C -> ∞`` with ``B·C`` fixed it tends to ``exp(-B·C·x) ≈ exp(-B·C·θh²/2)``, a Gaussian in
``θh``.  Lobes that fall off at least that fast (Beckmann, Blinn–Phong) are fitted best *in that
limit*.  :func:`abc_brdf_by_sharpness` writes the same BRDF in the coordinates ``sharpness = B·C``
and ``tail = 1/C``, where ``tail = 0`` is the limit itself, exactly; the fit
(:mod:`neuralbrdf.fitting.abc_fit`) works in them.

Its importance sampler is the renderer's (:class:`neuralbrdf.render.sampling.AbcLobe`); Löw's
published fits are read by :func:`neuralbrdf.data.low2012.load_low2012_parameters`.

Functions work on NumPy arrays and torch tensors (array API); torch inputs keep their autograd
graph.  Directions follow :mod:`neuralbrdf.geometry` (unit ``[..., 3]``, ``z`` the normal).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from array_api_compat import array_namespace, device

from neuralbrdf.errors import InputError
from neuralbrdf.geometry import array_namespace_of, half_vector_above
from neuralbrdf.physics.fresnel import fresnel_dielectric

#: Clamp (dimensionless) on ``cos ti``, ``cos to`` and ``wo·h`` in the specular denominators.
COS_EPS = 1e-4

#: Below this ``y``, :func:`abc_brdf_by_sharpness` takes ``ln(1 + y) / y`` from its series
#: ``1 - y/2 + y²/3`` (truncation error below 1e-18).
LOG1P_SERIES_BELOW = 1e-6


def _channel_vector(xp, values, like):
    """``values`` ``[C]`` as an array of ``like``'s namespace (kept as is if already one)."""
    try:
        if array_namespace(values) is xp:
            return values
    except TypeError:
        pass
    return xp.asarray(values, dtype=like.dtype, device=device(like))


# --------------------------------------------------------------------------- the BRDF


def abc_brdf(wi, wo, kd, A, B, C, eta):
    """ABC BRDF in sr⁻¹ (docs/models.md#abc), shape ``[..., n_channels]``.

    Parameters
    ----------
    wi, wo:
        Unit directions ``[..., 3]`` (toward the light and the viewer), local frame.
    kd, A:
        Diffuse albedo and specular scale per channel, ``[n_channels]``.
    B, C, eta:
        Scalars (Python floats or 0-d arrays): distribution width, fall-off exponent, index of
        refraction.
    """
    return _abc(wi, wo, kd, A, eta, lambda x: (1.0 + B * x) ** (-C))


def abc_brdf_by_sharpness(wi, wo, kd, A, sharpness, tail, eta):
    """:func:`abc_brdf` with ``B = sharpness · tail`` and ``C = 1 / tail`` (module docstring).

    The normal distribution is ``exp(-C ln(1 + B x)) = exp(-sharpness · x · L(sharpness · tail · x))``
    with ``L(y) = ln(1 + y) / y`` and ``L(0) = 1``: finite, smooth and differentiable down to
    ``tail = 0``, the Gaussian limit ``exp(-sharpness · (1 - cos θh))``.  ``sharpness > 0``,
    ``tail >= 0`` (scalars, like :func:`abc_brdf`'s ``B, C``).
    """

    def distribution(x):
        xp = array_namespace_of(x)
        y = sharpness * tail * x
        small = y < LOG1P_SERIES_BELOW
        y_safe = xp.where(small, xp.ones_like(y), y)
        log1p_ratio = xp.where(small, 1.0 - y / 2.0 + y * y / 3.0, xp.log1p(y_safe) / y_safe)
        return xp.exp(-sharpness * x * log1p_ratio)

    return _abc(wi, wo, kd, A, eta, distribution)


def _abc(wi, wo, kd, A, eta, distribution):
    """The ABC BRDF with the normal distribution ``distribution(1 - cos θh)``."""
    xp = array_namespace_of(wi, wo)
    kd = _channel_vector(xp, kd, wi)
    A = _channel_vector(xp, A, wi)
    if kd.ndim != 1 or tuple(A.shape) != tuple(kd.shape):
        raise ValueError(f"kd and A must both be [n_channels], got {tuple(kd.shape)} and {tuple(A.shape)}")
    cos_i = wi[..., 2]
    cos_o = wo[..., 2]
    h, above = half_vector_above(wi, wo)
    # From s = wi + wo without cancellation (sharp lobes have B ~ 1e5, float32 inputs):
    # 1 - cos θh = |s_xy|² / (|s| (|s| + s_z)) and wo·h = |s| / 2.
    s = xp.where(above[..., None], wi + wo, h)
    s_norm = xp.linalg.vector_norm(s, axis=-1)
    one_minus_cos_h = (s[..., 0] ** 2 + s[..., 1] ** 2) / (s_norm * (s_norm + s[..., 2]))
    cos_h = xp.clip(h[..., 2], 0.0, 1.0)
    cos_d = xp.clip(0.5 * s_norm, 0.0, 1.0)
    one = xp.ones_like(cos_i)
    safe_i = xp.where(above, xp.clip(cos_i, COS_EPS, 1.0), one)
    safe_o = xp.where(above, xp.clip(cos_o, COS_EPS, 1.0), one)
    safe_d = xp.clip(cos_d, COS_EPS, 1.0)
    # G / (cos ti cos to) with the cosines cancelled analytically (module docstring).
    g_over_cos = xp.minimum(
        1.0 / (safe_i * safe_o),
        xp.minimum(2.0 * cos_h / (safe_d * safe_i), 2.0 * cos_h / (safe_d * safe_o)),
    )
    specular = fresnel_dielectric(cos_d, eta) * g_over_cos * distribution(one_minus_cos_h) / math.pi
    specular = xp.where(above, specular, xp.zeros_like(specular))
    diffuse = xp.where(above, one / math.pi, xp.zeros_like(cos_i))
    return diffuse[..., None] * kd + specular[..., None] * A


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True, eq=False)
class AbcParameters:
    """The ABC model's parameters (docs/models.md#abc), validated on construction.

    Attributes
    ----------
    kd:
        ``[n_channels]`` diffuse albedo (the diffuse BRDF is ``kd/π``), >= 0.
    A:
        ``[n_channels]`` specular scale, >= 0.
    B:
        Width of the normal distribution (larger is sharper), >= 0.
    C:
        Fall-off exponent of the normal distribution, >= 0.
    eta:
        Index of refraction of the Fresnel term, > 0.
    wavelengths:
        ``None`` for RGB (R, G, B channels), else the channels' wavelengths in nm.
    """

    kd: np.ndarray
    A: np.ndarray
    B: float
    C: float
    eta: float
    wavelengths: np.ndarray | None = None

    def __post_init__(self) -> None:
        def vector(name):
            try:
                value = np.asarray(getattr(self, name), dtype=np.float64)
            except (TypeError, ValueError):
                raise InputError(f"expected a list of numbers, got {getattr(self, name)!r}", key=name) from None
            if value.ndim != 1 or value.size == 0:
                raise InputError(f"expected a non-empty 1-D list, got shape {value.shape}", key=name)
            if not np.all(np.isfinite(value)):
                raise InputError("non-finite value", key=name)
            return value

        def scalar(name, minimum, inclusive):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise InputError(f"expected a number, got {value!r}", key=name) from None
            if not math.isfinite(value) or value < minimum or (not inclusive and value == minimum):
                bound = f">= {minimum:g}" if inclusive else f"> {minimum:g}"
                raise InputError(f"expected a finite number {bound}, got {value!r}", key=name)
            return value

        kd, A = vector("kd"), vector("A")
        if A.shape != kd.shape:
            raise InputError(f"A has {A.size} channels but kd has {kd.size}", key="A")
        for name, value in (("kd", kd), ("A", A)):
            if np.any(value < 0):
                raise InputError(f"negative value {value.min():g}; expected >= 0", key=name)
        object.__setattr__(self, "kd", kd)
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "B", scalar("B", 0.0, True))
        object.__setattr__(self, "C", scalar("C", 0.0, True))
        object.__setattr__(self, "eta", scalar("eta", 0.0, False))
        if self.wavelengths is not None:
            wavelengths = vector("wavelengths")
            if wavelengths.shape != kd.shape:
                raise InputError(f"{wavelengths.size} wavelengths for {kd.size} channels", key="wavelengths")
            object.__setattr__(self, "wavelengths", wavelengths)
        elif kd.size != 3:
            raise InputError(f"{kd.size} channels without wavelengths; RGB parameters have 3", key="kd")

    @property
    def n_channels(self) -> int:
        return int(self.kd.size)

    def evaluate(self, wi, wo):
        """:func:`abc_brdf` with these parameters (NumPy or torch directions)."""
        return abc_brdf(wi, wo, self.kd, self.A, self.B, self.C, self.eta)

    def to_dict(self) -> dict:
        """JSON-ready dictionary; :meth:`from_dict` reads it back exactly."""
        return {
            "kd": self.kd.tolist(),
            "A": self.A.tolist(),
            "B": self.B,
            "C": self.C,
            "eta": self.eta,
            "wavelengths": None if self.wavelengths is None else self.wavelengths.tolist(),
        }

    @classmethod
    def from_dict(cls, mapping, source: str = "<dict>") -> AbcParameters:
        """Parameters from a mapping with keys kd, A, B, C, eta (and optionally wavelengths).

        Missing, unknown or invalid keys raise :class:`InputError` naming ``source`` and the key.
        """
        if not isinstance(mapping, dict):
            raise InputError(f"expected a mapping of ABC parameters, got {type(mapping).__name__}", path=source)
        required = ("kd", "A", "B", "C", "eta")
        for key in required:
            if key not in mapping:
                raise InputError("missing ABC parameter", path=source, key=key)
        for key in mapping:
            if key not in (*required, "wavelengths"):
                raise InputError(f"unknown key; expected {', '.join(required)}, wavelengths", path=source, key=key)
        try:
            return cls(**{key: mapping[key] for key in (*required, "wavelengths") if key in mapping})
        except InputError as error:
            raise InputError(error.reason, path=source, column=error.column, key=error.key) from None
