"""The ABC microfacet BRDF of Löw, Kronander, Ynnerman & Unger (2012) and its importance sampler.

J. Löw, J. Kronander, A. Ynnerman, J. Unger, "BRDF models for accurate and efficient rendering
of glossy surfaces", ACM TOG 31(1), 2012 — in the form of the report (S. Chitnis, *Simplifying
BRDF Acquisition*, Eqs. 2.5–2.8, 4.1) as fixed by SPEC §4.1::

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

**Importance sampling** (SPEC §4.1).  Half vectors are drawn from the ABC normal distribution
itself, with density over the solid angle of ``h``::

    p_h(h) = (1 + B (1 - cos θh))^(-C) / Z,   Z = 2π ∫_0^1 (1 + B x)^(-C) dx
           = 2π · ((1 + B)^(1-C) - 1) / (B (1 - C))        (C ≠ 1)
           = 2π · ln(1 + B) / B                             (C = 1),   -> 2π as B -> 0

With ``x = 1 - cos θh`` (``dω_h = dx dφ``) the marginal CDF inverts in closed form::

    x(u) = (exp(log1p(u · expm1((1-C) ln(1+B))) / (1-C)) - 1) / B     (C = 1: ((1+B)^u - 1)/B)

evaluated through ``log1p``/``expm1`` so that ``C -> 1`` and ``B -> 0`` are stable.  The
outgoing direction is ``wo = 2 (wi·h) h - wi`` with density ``p_h(h) / (4 |wo·h|)``; a
one-sample mixture with cosine-weighted hemisphere sampling covers the diffuse term.

Functions work on NumPy arrays and torch tensors (array API); torch inputs keep their autograd
graph.  Directions follow :mod:`neuralbrdf.geometry` (unit ``[..., 3]``, ``z`` the normal).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import torch
from array_api_compat import array_namespace, device
from torch import nn

from neuralbrdf.data.csvio import read_csv_rows
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import array_namespace_of, dot, half_vector_above, normalize
from neuralbrdf.physics.fresnel import fresnel_dielectric

#: Clamp (dimensionless) on ``cos ti``, ``cos to`` and ``wo·h`` in the specular denominators.
COS_EPS = 1e-4

#: ``B`` below this is treated as this value in the sampler (uniform to 1e-12 relative).
B_MIN_SAMPLING = 1e-12

#: ``|1 - C| ln(1 + B)`` below this uses the ``C = 1`` limit of the normalisation and inverse CDF.
_SERIES_EPS = 1e-8


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
    """ABC BRDF in sr⁻¹ (SPEC §4.1), shape ``[..., n_channels]``.

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
    distribution = (1.0 + B * one_minus_cos_h) ** (-C)
    specular = fresnel_dielectric(cos_d, eta) * g_over_cos * distribution / math.pi
    specular = xp.where(above, specular, xp.zeros_like(specular))
    diffuse = xp.where(above, one / math.pi, xp.zeros_like(cos_i))
    return diffuse[..., None] * kd + specular[..., None] * A


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True, eq=False)
class ABCParameters:
    """The ABC model's parameters (SPEC §4.1), validated on construction.

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
                raise InputError(f"expected a list of numbers, got {getattr(self, name)!r}", column=name) from None
            if value.ndim != 1 or value.size == 0:
                raise InputError(f"expected a non-empty 1-D list, got shape {value.shape}", column=name)
            if not np.all(np.isfinite(value)):
                raise InputError("non-finite value", column=name)
            return value

        def scalar(name, minimum, inclusive):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise InputError(f"expected a number, got {value!r}", column=name) from None
            if not math.isfinite(value) or value < minimum or (not inclusive and value == minimum):
                bound = f">= {minimum:g}" if inclusive else f"> {minimum:g}"
                raise InputError(f"expected a finite number {bound}, got {value!r}", column=name)
            return value

        kd, A = vector("kd"), vector("A")
        if A.shape != kd.shape:
            raise InputError(f"A has {A.size} channels but kd has {kd.size}", column="A")
        for name, value in (("kd", kd), ("A", A)):
            if np.any(value < 0):
                raise InputError(f"negative value {value.min():g}; expected >= 0", column=name)
        object.__setattr__(self, "kd", kd)
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "B", scalar("B", 0.0, True))
        object.__setattr__(self, "C", scalar("C", 0.0, True))
        object.__setattr__(self, "eta", scalar("eta", 0.0, False))
        if self.wavelengths is not None:
            wavelengths = vector("wavelengths")
            if wavelengths.shape != kd.shape:
                raise InputError(f"{wavelengths.size} wavelengths for {kd.size} channels", column="wavelengths")
            object.__setattr__(self, "wavelengths", wavelengths)
        elif kd.size != 3:
            raise InputError(f"{kd.size} channels without wavelengths; RGB parameters have 3", column="kd")

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
    def from_dict(cls, mapping, source: str = "<dict>") -> ABCParameters:
        """Parameters from a mapping with keys kd, A, B, C, eta (and optionally wavelengths).

        Missing, unknown or invalid keys raise :class:`InputError` naming ``source`` and the key.
        """
        if not isinstance(mapping, dict):
            raise InputError(f"expected a mapping of ABC parameters, got {type(mapping).__name__}", path=source)
        required = ("kd", "A", "B", "C", "eta")
        for key in required:
            if key not in mapping:
                raise InputError("missing ABC parameter", path=source, column=key)
        for key in mapping:
            if key not in (*required, "wavelengths"):
                raise InputError(f"unknown key; expected {', '.join(required)}, wavelengths", path=source, column=key)
        try:
            return cls(**{key: mapping[key] for key in (*required, "wavelengths") if key in mapping})
        except InputError as error:
            raise InputError(error.reason, path=source, column=error.column) from None


#: Column order of Löw et al.'s published fits (``../shared/data/abc-low2012``).
LOW2012_COLUMNS = ("material", "kd_r", "kd_g", "kd_b", "A_r", "A_g", "A_b", "B", "C", "eta")


def load_low2012_parameters(path: str | os.PathLike[str]) -> dict[str, ABCParameters]:
    """Löw et al.'s (2012) published RGB ABC fits, ``{material: ABCParameters}``.

    The CSV has the header :data:`LOW2012_COLUMNS` and one row per material; every defect
    (missing or unknown column, non-numeric or out-of-range cell, duplicated or empty material)
    raises :class:`InputError` with the file, line and column.  ``eta`` near 100 marks a fit
    that ran into Löw's bound (tungsten-carbide); it is loaded as published.
    """
    path = str(path)
    header, rows, lines = read_csv_rows(path)
    if header is None:
        raise InputError("empty file: expected a header line", path=path, line=1)
    header = [name.strip() for name in header]
    for name in LOW2012_COLUMNS:
        if name not in header:
            raise InputError("missing column", path=path, line=1, column=name)
    for name in header:
        if name not in LOW2012_COLUMNS or header.count(name) > 1:
            raise InputError(
                f"unexpected or duplicated column; expected {', '.join(LOW2012_COLUMNS)}", path=path, line=1, column=name
            )
    if not rows:
        raise InputError("no data rows after the header", path=path, line=2)
    fits = {}
    for row, line in zip(rows, lines):
        if len(row) != len(header):
            raise InputError(f"row has {len(row)} cells but the header has {len(header)}", path=path, line=line)
        cells = dict(zip(header, (cell.strip() for cell in row)))
        material = cells.pop("material")
        if not material:
            raise InputError("empty material name", path=path, line=line, column="material")
        if material in fits:
            raise InputError(f"material {material!r} listed twice", path=path, line=line, column="material")
        numbers = {}
        for name, cell in cells.items():
            try:
                numbers[name] = float(cell)
            except ValueError:
                raise InputError(f"not a number: {cell!r}", path=path, line=line, column=name) from None
        try:
            fits[material] = ABCParameters(
                kd=[numbers["kd_r"], numbers["kd_g"], numbers["kd_b"]],
                A=[numbers["A_r"], numbers["A_g"], numbers["A_b"]],
                B=numbers["B"],
                C=numbers["C"],
                eta=numbers["eta"],
            )
        except InputError as error:
            raise InputError(error.reason, path=path, line=line, column=error.column) from None
    return fits


# --------------------------------------------------------------------------- torch module


class ABCModel(nn.Module):
    """The ABC BRDF as a torch module: ``forward(wi, wo) -> [N, n_channels]`` in sr⁻¹.

    Holds ``kd``, ``A`` (``[n_channels]``) and ``B``, ``C``, ``eta`` (0-d) as parameters, in
    ``dtype``; the channel wavelengths (if any) as a buffer.  The parameters are unconstrained
    tensors: an optimiser that updates them must keep them in the model's domain.
    """

    def __init__(self, parameters: ABCParameters, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()

        def tensor(value):
            return nn.Parameter(torch.as_tensor(value, dtype=dtype))

        self.kd = tensor(parameters.kd)
        self.A = tensor(parameters.A)
        self.B = tensor(parameters.B)
        self.C = tensor(parameters.C)
        self.eta = tensor(parameters.eta)
        wavelengths = None if parameters.wavelengths is None else torch.as_tensor(parameters.wavelengths, dtype=dtype)
        self.register_buffer("wavelengths", wavelengths)

    def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        return abc_brdf(wi, wo, self.kd, self.A, self.B, self.C, self.eta)

    def abc_parameters(self) -> ABCParameters:
        """The current values as (validated) :class:`ABCParameters`."""

        def values(t):
            return t.detach().cpu().double().numpy()

        return ABCParameters(
            kd=values(self.kd),
            A=values(self.A),
            B=float(values(self.B)),
            C=float(values(self.C)),
            eta=float(values(self.eta)),
            wavelengths=None if self.wavelengths is None else values(self.wavelengths),
        )


# --------------------------------------------------------------------------- importance sampling


def _log_terms(B, C):
    """``B`` floored at :data:`B_MIN_SAMPLING`, ``ln(1 + B)`` and ``s = (1 - C) ln(1 + B)``."""
    if isinstance(B, (int, float)):
        B = max(float(B), B_MIN_SAMPLING)
        log_1pb = math.log1p(B)
    else:
        xp = array_namespace(B)
        B = xp.clip(B, B_MIN_SAMPLING, None)
        log_1pb = xp.log1p(B)
    return B, log_1pb, (1.0 - C) * log_1pb


def _expm1_over(s):
    """``expm1(s) / s``, 1 at ``s = 0`` (Python number or array)."""
    if isinstance(s, (int, float)):
        return 1.0 + 0.5 * s if abs(s) < _SERIES_EPS else math.expm1(s) / s
    xp = array_namespace(s)
    small = xp.abs(s) < _SERIES_EPS
    safe = xp.where(small, xp.ones_like(s), s)
    return xp.where(small, 1.0 + 0.5 * s, xp.expm1(safe) / safe)


def abc_distribution_normalization(B, C):
    """``Z = 2π ∫_0^1 (1 + B x)^(-C) dx`` (sr), the normaliser of the half-vector density.

    ``B`` and ``C`` are Python numbers (the result is a float) or 0-d arrays.
    """
    B, log_1pb, s = _log_terms(B, C)
    return 2.0 * math.pi * log_1pb / B * _expm1_over(s)


def abc_pdf_half_vector(h, B, C):
    """Density of :func:`abc_sample_half_vector` over the solid angle of ``h`` (sr⁻¹), ``[...]``.

    Zero for ``h`` at or below the horizon.
    """
    xp = array_namespace_of(h)
    cos_h = h[..., 2]
    density = (1.0 + B * (1.0 - xp.clip(cos_h, 0.0, 1.0))) ** (-C) / abc_distribution_normalization(B, C)
    return xp.where(cos_h > 0.0, density, xp.zeros_like(density))


def abc_sample_half_vector(u1, u2, B, C):
    """Half vectors ``[..., 3]`` with density ``∝ (1 + B (1 - cos θh))^(-C)`` (closed-form inverse CDF).

    ``u1`` picks ``cos θh`` and ``u2`` the azimuth; both uniform in [0, 1), same shape.
    """
    xp = array_namespace_of(u1, u2)
    B, log_1pb, s = _log_terms(B, C)
    s = s + xp.zeros_like(u1)
    near_one = xp.abs(s) < _SERIES_EPS
    safe_s = xp.where(near_one, xp.ones_like(s), s)
    # ln(1 + B x) = log1p(u expm1(s)) / (1 - C), written with s = (1 - C) ln(1 + B).
    log_1pbx = xp.where(near_one, u1 * log_1pb, xp.log1p(u1 * xp.expm1(safe_s)) * (log_1pb / safe_s))
    x = xp.clip(xp.expm1(log_1pbx) / B, 0.0, 1.0)
    cos_h = 1.0 - x
    sin_h = xp.sqrt(xp.clip(x * (2.0 - x), 0.0, None))
    phi = 2.0 * math.pi * u2
    return xp.stack([sin_h * xp.cos(phi), sin_h * xp.sin(phi), cos_h], axis=-1)


def sample_cosine_hemisphere(u1, u2):
    """Cosine-weighted directions ``[..., 3]`` on the upper hemisphere (density ``cos θ / π``)."""
    xp = array_namespace_of(u1, u2)
    r = xp.sqrt(u1)
    phi = 2.0 * math.pi * u2
    return xp.stack([r * xp.cos(phi), r * xp.sin(phi), xp.sqrt(xp.clip(1.0 - u1, 0.0, None))], axis=-1)


def _reflect_about(w, h):
    return 2.0 * dot(w, h)[..., None] * h - w


def abc_pdf_reflected(wi, wo, B, C):
    """Density over the solid angle of ``wo`` of ``wo = reflect(wi, h)``, ``h`` from the ABC sampler.

    ``p(wo) = p_h(h) / (4 |wo·h|)`` with ``h = ±normalize(wi + wo)`` taken in the upper
    hemisphere (the half vector that maps ``wi`` to ``wo``).  Defined on the whole sphere:
    half vectors with ``wi·h < 0`` send ``wo`` below the horizon, where the BRDF is zero, and
    this density still integrates to 1 over all ``wo``.
    """
    xp = array_namespace_of(wi, wo)
    h = normalize(wi + wo)
    h = xp.where(h[..., 2:3] < 0.0, -h, h)
    return abc_pdf_half_vector(h, B, C) / (4.0 * xp.abs(dot(wo, h)))


def abc_sample(wi, u_select, u1, u2, B, C, specular_probability: float):
    """Outgoing directions ``[..., 3]`` from the one-sample mixture of :func:`abc_pdf`.

    With probability ``specular_probability`` (``u_select < specular_probability``) ``wo`` is
    ``wi`` reflected about an ABC half vector drawn from ``(u1, u2)``, else a cosine-weighted
    direction drawn from the same ``(u1, u2)``.  Reflected directions can fall below the horizon
    (the BRDF is zero there).
    """
    xp = array_namespace_of(wi, u_select, u1, u2)
    reflected = _reflect_about(wi, abc_sample_half_vector(u1, u2, B, C))
    diffuse = sample_cosine_hemisphere(u1, u2)
    return xp.where((u_select < specular_probability)[..., None], reflected, diffuse)


def abc_pdf(wi, wo, B, C, specular_probability: float):
    """Density (sr⁻¹) of :func:`abc_sample`: ``p_s · p_reflected + (1 - p_s) · max(cos θo, 0) / π``."""
    xp = array_namespace_of(wi, wo)
    cosine = xp.clip(wo[..., 2], 0.0, None) / math.pi
    return specular_probability * abc_pdf_reflected(wi, wo, B, C) + (1.0 - specular_probability) * cosine


def specular_sampling_probability(parameters: ABCParameters, n_nodes: int = 1024, clip: float = 0.05) -> float:
    """Mixture weight of the specular lobe for :func:`abc_sample`: its share of the albedo at normal incidence.

    ``ρ_s = ∫ f_spec cos to dωo`` for ``wi = n`` reduces (``dωo = 4 (wo·h) dω_h``, ``wi·h = n·h``,
    ``G = min(1, 2 cos to)``) to ``8 · mean(A) · ∫ F(cos θh) G cos θh (1 + B x)^(-C) dx`` over
    ``x = 1 - cos θh`` with ``wo`` above the horizon; it is integrated by the midpoint rule in
    the sampler's own CDF coordinate.  ``ρ_d = mean(kd)``.  Returns ``ρ_s / (ρ_s + ρ_d)``
    clipped to ``[clip, 1 - clip]`` so both lobes keep some samples.
    """
    u = (np.arange(n_nodes) + 0.5) / n_nodes
    cos_h = abc_sample_half_vector(u, np.zeros_like(u), parameters.B, parameters.C)[:, 2]
    cos_o = 2.0 * cos_h * cos_h - 1.0
    shadowing = np.minimum(1.0, 2.0 * np.clip(cos_o, 0.0, None))
    integrand = fresnel_dielectric(cos_h, parameters.eta) * shadowing * cos_h
    integral = abc_distribution_normalization(parameters.B, parameters.C) / (2.0 * math.pi) * integrand.mean()
    rho_s = 8.0 * float(parameters.A.mean()) * integral
    rho_d = float(parameters.kd.mean())
    total = rho_s + rho_d
    share = rho_s / total if total > 0 else 0.5
    return float(np.clip(share, clip, 1.0 - clip))
