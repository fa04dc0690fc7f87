"""Importance sampling for the ``neuralbrdf`` Mitsuba BSDF (docs/models.md#abc, docs/mitsuba-plugin.md).

The proposal is a one-sample mixture (Veach 1997, §9.2.1) of cosine-weighted hemisphere sampling
and a glossy lobe around the mirror direction::

    p(wo | wi) = w(θi) · p_lobe(wo | wi) + (1 - w(θi)) · cos θo / π

With probability ``w(θi)`` the glossy lobe draws ``wo``, otherwise the cosine lobe; ``sample``
returns the full mixture density, so that ``f cos θo / p`` is the estimator's weight.  Both
lobes reflect a half vector ``h`` about ``wi`` (``wo = 2 (wi·h) h - wi``, Jacobian
``1 / (4 wo·h)``, Walter et al. 2007, Eq. 14):

* :class:`GgxLobe` — GGX visible-normal sampling (Heitz 2018) through Mitsuba's
  ``MicrofacetDistribution``; the lobe for neural models, with a fitted roughness.
* :class:`AbcLobe` — the ABC normal distribution of Löw et al. (2012), docs/models.md#abc, sampled
  exactly by its closed-form inverse CDF.  With ``x = 1 - cos θh`` (``dω_h = dx dφ``)::

      p_h(h) = (1 + B x)^(-C) / Z,  Z = 2π ((1 + B)^(1-C) - 1) / (B (1 - C))   (C ≠ 1)
                                     Z = 2π ln(1 + B) / B                      (C = 1)
      x(u)   = ((1 + u ((1 + B)^(1-C) - 1))^(1/(1-C)) - 1) / B              (C ≠ 1)
      x(u)   = ((1 + B)^u - 1) / B                                          (C = 1)

  The inverse CDF runs in double precision (it cancels badly in float32 near ``C = 1``), the
  ``C = 1`` form is used for ``|(1 - C) ln(1 + B)| < 1e-8``, and ``B < 1e-9`` is uniform in ``x``.

**Fitting the proposal** (load time, :func:`fit_proposal` with the name the model's kind gives:
``fitted_ggx`` is :func:`fit_neural_mixture`, ``abc_lobe`` is :func:`fit_abc_mixture`).
The model is probed with onnxruntime at incident angles ``θi`` of :data:`PROBE_THETA_I_DEG`
(``φi = 0``; isotropy assumed) on a deterministic quadrature over half vectors (log-spaced
``θh`` from 0.06° to 90°, so that sharp lobes are resolved; uniform ``φh``), reflected into
``wo``.  The proposal should be proportional to the integrand's BRDF part ``f cos θo``, so the
lobe and the weights maximise the cross-entropy

    Σ_θi Σ_k t_k ln p(wo_k | wi),   t ∝ f cos θo dωo normalised per incident angle,

i.e. minimise the KL divergence from the normalised ``f cos θo`` to the mixture ``p`` (the
criterion of cross-entropy importance sampling, Rubinstein & Kroese 2004).  The glossy weight
``w(θi)`` is chosen per probe angle among :data:`WEIGHT_CANDIDATES` (clamped to
:data:`GLOSSY_WEIGHT_RANGE` so that both lobes keep samples; the cosine lobe guarantees
``p > 0`` wherever ``f > 0``) and interpolated linearly in ``cos θi`` in between; neural models
also choose the GGX roughness among :data:`ALPHA_CANDIDATES` (one for all angles), ABC keeps
its analytic lobe.

Channels are averaged (RGB) or wavelengths averaged (spectral) before fitting: the proposal is
shared by all channels.  The lobe is centred on the mirror direction; models whose gloss sits
elsewhere (retro-reflection) are still sampled correctly, only with more variance.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import drjit as dr
import mitsuba as mi
import numpy as np

from neuralbrdf.physics.microfacet import ggx_distribution, ggx_smith_g1

if TYPE_CHECKING:
    from neuralbrdf.kinds.abc import AbcMetadata

#: Incident polar angles (degrees) at which the model is probed to fit the proposal.
PROBE_THETA_I_DEG = (0.0, 30.0, 50.0, 65.0, 80.0)

#: Bounds on the probability of sampling the glossy lobe.
GLOSSY_WEIGHT_RANGE = (0.1, 0.9)

#: Candidate probabilities of the glossy lobe, within :data:`GLOSSY_WEIGHT_RANGE`.
WEIGHT_CANDIDATES = np.linspace(*GLOSSY_WEIGHT_RANGE, 33)

#: Candidate GGX roughness values of the fit.
ALPHA_CANDIDATES = np.geomspace(0.005, 1.0, 64)

#: ``B`` below this samples the ABC distribution as uniform in ``x = 1 - cos θh``.
ABC_B_UNIFORM = 1e-9

#: ``|(1 - C) ln(1 + B)|`` below this uses the ``C = 1`` forms.
ABC_C_ONE_EPS = 1e-8

#: A ``brdf(wi, wo)`` probe: float32 ``[M, 3]`` directions to ``[M]`` channel-averaged values.
ProbeFunction = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _reflect(wi: mi.Vector3f, h: mi.Vector3f) -> mi.Vector3f:
    return 2.0 * dr.dot(wi, h) * h - wi


# --------------------------------------------------------------------------- lobes


@dataclass(frozen=True)
class GgxLobe:
    """GGX visible-normal reflection lobe of roughness ``alpha``."""

    alpha: float

    def _distribution(self) -> mi.MicrofacetDistribution:
        return mi.MicrofacetDistribution(mi.MicrofacetType.GGX, self.alpha, True)

    def sample(self, wi: mi.Vector3f, u: mi.Point2f) -> tuple[mi.Vector3f, mi.Bool]:
        """A reflected direction and whether the draw is usable (``wi`` above the horizon)."""
        m, _ = self._distribution().sample(wi, u)
        return _reflect(wi, m), mi.Frame3f.cos_theta(wi) > 0

    def pdf(self, wi: mi.Vector3f, wo: mi.Vector3f) -> mi.Float:
        """Density of :meth:`sample` over the solid angle of ``wo`` (0 below the horizon)."""
        h = dr.normalize(wi + wo)
        cos_oh = dr.dot(wo, h)
        valid = (mi.Frame3f.cos_theta(wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0) & (cos_oh > 0)
        pdf = self._distribution().pdf(wi, h) / (4.0 * cos_oh)
        return dr.select(valid, pdf, 0.0)

    def describe(self) -> str:
        return f"GGX(alpha={self.alpha:.4g})"


@dataclass(frozen=True)
class AbcLobe:
    """The ABC normal distribution ``(1 + B (1 - cos θh))^(-C)`` sampled by its inverse CDF."""

    B: float
    C: float

    @property
    def _log1p_b(self) -> float:
        return math.log1p(self.B)

    @property
    def _exponent(self) -> float:
        """``a = (1 - C) ln(1 + B)``: the CDF is ``((1 + B x)^(1-C) - 1) / expm1(a)``."""
        return (1.0 - self.C) * self._log1p_b

    @property
    def normalization(self) -> float:
        """``Z = ∫ (1 + B (1 - cos θh))^(-C) dω_h`` over the hemisphere (sr)."""
        if self.B < ABC_B_UNIFORM:
            return 2.0 * math.pi
        a = self._exponent
        if abs(a) < ABC_C_ONE_EPS:
            return 2.0 * math.pi * self._log1p_b / self.B
        return 2.0 * math.pi * math.expm1(a) / (self.B * (1.0 - self.C))

    def _inverse_cdf(self, u: mi.Float) -> mi.Float:
        """``x = 1 - cos θh`` for a uniform ``u``, in double precision."""
        u64 = mi.Float64(u)
        if self.B < ABC_B_UNIFORM:
            x = u64
        elif abs(self._exponent) < ABC_C_ONE_EPS:
            x = (dr.exp(u64 * self._log1p_b) - 1.0) / self.B
        else:
            k = math.expm1(self._exponent)
            x = (dr.exp(dr.log(1.0 + u64 * k) / (1.0 - self.C)) - 1.0) / self.B
        return dr.clip(mi.Float(x), 0.0, 1.0)

    def sample(self, wi: mi.Vector3f, u: mi.Point2f) -> tuple[mi.Vector3f, mi.Bool]:
        """A reflected direction and whether it is usable (``wi`` above ``h`` and the horizon)."""
        x = self._inverse_cdf(u.x)
        cos_h = 1.0 - x
        sin_h = dr.sqrt(dr.maximum(x * (2.0 - x), 0.0))
        sin_phi, cos_phi = dr.sincos(2.0 * dr.pi * u.y)
        h = mi.Vector3f(sin_h * cos_phi, sin_h * sin_phi, cos_h)
        valid = (mi.Frame3f.cos_theta(wi) > 0) & (dr.dot(wi, h) > 0)
        return _reflect(wi, h), valid

    def half_vector_pdf(self, h: mi.Vector3f) -> mi.Float:
        """``p_h(h)`` over the solid angle of ``h``; 0 for ``h`` below the horizon."""
        return dr.select(h.z > 0, self.density(h.x, h.y, h.z, dr), 0.0)

    def density(self, hx, hy, hz, xp):
        """``p_h`` of unit half vectors above the horizon, in the array module ``xp`` (Dr.Jit or NumPy).

        ``x = 1 - cos θh`` is taken as ``(hx² + hy²) / (1 + hz)``, without cancellation.
        """
        x = (hx * hx + hy * hy) / (1.0 + hz)
        return xp.exp(-self.C * xp.log(1.0 + self.B * x)) / self.normalization

    def pdf(self, wi: mi.Vector3f, wo: mi.Vector3f) -> mi.Float:
        """Density of :meth:`sample` over the solid angle of ``wo`` (0 below the horizon)."""
        h = dr.normalize(wi + wo)
        cos_oh = dr.dot(wo, h)
        valid = (mi.Frame3f.cos_theta(wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0) & (cos_oh > 0)
        return dr.select(valid, self.half_vector_pdf(h) / (4.0 * cos_oh), 0.0)

    def describe(self) -> str:
        return f"ABC(B={self.B:.4g}, C={self.C:.4g})"


@dataclass(frozen=True)
class LobeMixture:
    """One-sample MIS mixture of ``lobe`` and cosine sampling.

    ``glossy_weights[k]`` is the probability of the glossy lobe at ``cos θi = cos_nodes[k]``
    (increasing); between nodes it is linear in ``cos θi``, beyond them constant.
    """

    lobe: GgxLobe | AbcLobe
    cos_nodes: tuple[float, ...]
    glossy_weights: tuple[float, ...]

    def glossy_weight(self, cos_i: mi.Float) -> mi.Float:
        weight = dr.full(mi.Float, self.glossy_weights[0], dr.width(cos_i))
        for k in range(len(self.cos_nodes) - 1):
            c0, c1 = self.cos_nodes[k], self.cos_nodes[k + 1]
            w0, w1 = self.glossy_weights[k], self.glossy_weights[k + 1]
            t = dr.clip((cos_i - c0) / (c1 - c0), 0.0, 1.0)
            weight = dr.select(cos_i >= c0, w0 + (w1 - w0) * t, weight)
        return weight

    def pdf(self, wi: mi.Vector3f, wo: mi.Vector3f) -> mi.Float:
        """Mixture density over the solid angle of ``wo``; 0 unless both are above the horizon."""
        cos_i = mi.Frame3f.cos_theta(wi)
        cos_o = mi.Frame3f.cos_theta(wo)
        w = self.glossy_weight(cos_i)
        pdf = w * self.lobe.pdf(wi, wo) + (1.0 - w) * cos_o * dr.inv_pi
        return dr.select((cos_i > 0) & (cos_o > 0), pdf, 0.0)

    def sample(
        self, wi: mi.Vector3f, u_lobe: mi.Float, u_dir: mi.Point2f
    ) -> tuple[mi.Vector3f, mi.Float, mi.Bool]:
        """``(wo, pdf, valid)``: ``u_lobe`` picks the lobe, ``u_dir`` the direction in it."""
        cos_i = mi.Frame3f.cos_theta(wi)
        wo_glossy, ok_glossy = self.lobe.sample(wi, u_dir)
        wo_cosine = mi.warp.square_to_cosine_hemisphere(u_dir)
        choose_glossy = u_lobe < self.glossy_weight(cos_i)
        wo = dr.select(choose_glossy, wo_glossy, wo_cosine)
        pdf = self.pdf(wi, wo)
        valid = (cos_i > 0) & (mi.Frame3f.cos_theta(wo) > 0) & (pdf > 0)
        valid &= dr.select(choose_glossy, ok_glossy, True)
        return wo, pdf, valid

    def describe(self) -> str:
        weights = ", ".join(f"{w:.3g}" for w in self.glossy_weights)
        nodes = ", ".join(f"{c:.3g}" for c in self.cos_nodes)
        return f"{self.lobe.describe()} + cosine, glossy weight [{weights}] at cos θi [{nodes}]"


# --------------------------------------------------------------------------- probing and fitting


@dataclass(frozen=True)
class _Probe:
    """Quadrature over outgoing directions for each probe incident direction."""

    wi: np.ndarray  # [P, 3]
    wo: np.ndarray  # [P, M, 3]
    d_omega_o: np.ndarray  # [P, M] solid angle of each cell of wo, 0 where unusable
    cos_o: np.ndarray  # [P, M]


def _probe_quadrature(n_theta: int = 64, n_phi: int = 48) -> _Probe:
    """Half-vector cells (log-spaced ``θh``, uniform ``φh``) reflected into ``wo`` per probe."""
    edges = np.concatenate([[0.0], np.geomspace(1e-3, math.pi / 2, n_theta)])
    cos_edges = np.cos(edges)
    cos_mid = 0.5 * (cos_edges[:-1] + cos_edges[1:])
    d_omega_theta = cos_edges[:-1] - cos_edges[1:]
    phi = (np.arange(n_phi) + 0.5) * (2.0 * math.pi / n_phi)
    sin_mid = np.sqrt(1.0 - cos_mid**2)
    h = np.stack(
        [
            np.outer(sin_mid, np.cos(phi)),
            np.outer(sin_mid, np.sin(phi)),
            np.outer(cos_mid, np.ones_like(phi)),
        ],
        axis=-1,
    ).reshape(-1, 3)
    d_omega_h = np.repeat(d_omega_theta, n_phi) * (2.0 * math.pi / n_phi)

    theta_i = np.radians(np.asarray(PROBE_THETA_I_DEG))
    wi = np.stack([np.sin(theta_i), np.zeros_like(theta_i), np.cos(theta_i)], axis=-1)
    cos_ih = wi @ h.T  # [P, M]
    wo = 2.0 * cos_ih[..., None] * h[None] - wi[:, None, :]
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    usable = (cos_ih > 0) & (wo[..., 2] > 0)
    d_omega_o = np.where(usable, 4.0 * cos_ih * d_omega_h[None], 0.0)
    return _Probe(wi=wi, wo=wo, d_omega_o=d_omega_o, cos_o=np.clip(wo[..., 2], 0.0, None))


def probe_direction_pairs() -> tuple[np.ndarray, np.ndarray]:
    """``(wi, wo)`` float32 ``[M, 3]``: the usable pairs of the probe quadrature, both above the
    horizon (dense around the mirror direction; used to fit other load-time approximations)."""
    probe = _probe_quadrature()
    usable = probe.d_omega_o > 0
    n_dirs = probe.d_omega_o.shape[1]
    wi = np.repeat(probe.wi, n_dirs, axis=0)[usable.reshape(-1)]
    return wi.astype(np.float32), probe.wo[usable].astype(np.float32)


def _probe_values(brdf: ProbeFunction, probe: _Probe) -> np.ndarray:
    """``f`` on the probe quadrature, ``[P, M]``, from one call of ``brdf``."""
    n_probe, n_dirs = probe.d_omega_o.shape
    wi = np.repeat(probe.wi, n_dirs, axis=0).astype(np.float32)
    wo = probe.wo.reshape(-1, 3).astype(np.float32)
    values = np.asarray(brdf(wi, wo), dtype=np.float64).reshape(n_probe, n_dirs)
    return np.where(probe.d_omega_o > 0, np.clip(values, 0.0, None), 0.0)


def _mixture(lobe, weights: np.ndarray) -> LobeMixture:
    cos_nodes = np.cos(np.radians(PROBE_THETA_I_DEG))
    order = np.argsort(cos_nodes)
    return LobeMixture(
        lobe=lobe,
        cos_nodes=tuple(float(c) for c in cos_nodes[order]),
        glossy_weights=tuple(float(weights[i]) for i in order),
    )


def ggx_reflection_pdf(wi: np.ndarray, wo: np.ndarray, alpha: float) -> np.ndarray:
    """NumPy density of :meth:`GgxLobe.sample`: ``G1(wi) D(h) / (4 cos θi)`` (``wi·h = wo·h``).

    Visible-normal density ``G1(wi) (wi·h) D(h) / cos θi`` (Heitz 2018, Eq. 3) times the
    reflection Jacobian ``1 / (4 wo·h)``; 0 unless both directions are above the horizon.
    """
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    cos_i = wi[..., 2]
    above = (cos_i > 0) & (wo[..., 2] > 0)
    safe_cos_i = np.where(above, cos_i, 1.0)
    pdf = ggx_smith_g1(safe_cos_i, alpha) * ggx_distribution(h[..., 2], alpha) / (4.0 * safe_cos_i)
    return np.where(above, pdf, 0.0)


def abc_reflection_pdf(wi: np.ndarray, wo: np.ndarray, lobe: AbcLobe) -> np.ndarray:
    """NumPy density of :meth:`AbcLobe.sample`: ``p_h(h) / (4 wo·h)``, 0 below the horizon."""
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    cos_oh = np.sum(wo * h, axis=-1)
    above = (wi[..., 2] > 0) & (wo[..., 2] > 0) & (cos_oh > 0)
    density = lobe.density(h[..., 0], h[..., 1], h[..., 2], np)
    return np.where(above, density / (4.0 * np.where(above, cos_oh, 1.0)), 0.0)


def _best_weights(target: np.ndarray, lobe_pdf: np.ndarray, cosine_pdf: np.ndarray):
    """``(score, weights)``: per probe angle the glossy weight of :data:`WEIGHT_CANDIDATES` with
    the largest cross-entropy ``Σ_k t_k ln(w p_lobe + (1 - w) cos θo / π)``, and its sum."""
    keep = target > 0
    scores = np.zeros((len(WEIGHT_CANDIDATES), len(target)))
    for i, w in enumerate(WEIGHT_CANDIDATES):
        mixture = w * lobe_pdf + (1.0 - w) * cosine_pdf
        scores[i] = np.sum(np.where(keep, target * np.log(np.where(keep, mixture, 1.0)), 0.0), axis=1)
    best = np.argmax(scores, axis=0)
    return float(scores[best, np.arange(len(target))].sum()), WEIGHT_CANDIDATES[best]


def _fit(brdf: ProbeFunction, lobes: list, lobe_pdf: Callable) -> LobeMixture:
    """The candidate lobe and per-angle weights that best sample ``f cos θo`` (module docstring)."""
    probe = _probe_quadrature()
    f = _probe_values(brdf, probe)
    target = f * probe.cos_o * probe.d_omega_o
    totals = target.sum(axis=1, keepdims=True)
    target = np.divide(target, totals, out=np.zeros_like(target), where=totals > 0)
    wi = np.broadcast_to(probe.wi[:, None, :], probe.wo.shape)
    cosine_pdf = probe.cos_o / math.pi
    fits = [_best_weights(target, lobe_pdf(wi, probe.wo, lobe), cosine_pdf) for lobe in lobes]
    best = int(np.argmax([score for score, _ in fits]))
    return _mixture(lobes[best], fits[best][1])


def fit_neural_mixture(brdf: ProbeFunction) -> LobeMixture:
    """GGX roughness and glossy weights fitted to a model probed through ``brdf``."""
    lobes = [GgxLobe(float(alpha)) for alpha in ALPHA_CANDIDATES]
    return _fit(brdf, lobes, lambda wi, wo, lobe: ggx_reflection_pdf(wi, wo, lobe.alpha))


def fit_abc_mixture(brdf: ProbeFunction, abc: AbcMetadata) -> LobeMixture:
    """The analytic ABC lobe of ``abc`` with glossy weights fitted to the model through ``brdf``."""
    return _fit(brdf, [AbcLobe(abc.B, abc.C)], abc_reflection_pdf)


#: Proposals by name, as kinds declare them (:attr:`neuralbrdf.kinds.Kind.proposal`):
#: ``(probe, details) -> LobeMixture`` with the file's kind details (:func:`fit_proposal`).
PROPOSALS: dict[str, Callable[[ProbeFunction, object], LobeMixture]] = {
    "fitted_ggx": lambda brdf, details: fit_neural_mixture(brdf),
    "abc_lobe": fit_abc_mixture,
    # a file holding another kind's model (kind auto): that kind's proposal, fitted to its details
    "chosen": lambda brdf, details: fit_proposal(details.proposal, brdf, details.chosen_details),
}


def fit_proposal(name: str, brdf: ProbeFunction, details: object = None) -> LobeMixture:
    """The proposal ``name`` of :data:`PROPOSALS` fitted to the model probed through ``brdf``."""
    if name not in PROPOSALS:
        raise ValueError(f"unknown sampling proposal {name!r}; expected one of {sorted(PROPOSALS)}")
    return PROPOSALS[name](brdf, details)
