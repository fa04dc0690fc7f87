"""Pretraining corpus of the NLB representation network: random analytic materials (docs/models.md#nlb).

Fan et al. (2022, "Neural Layered BRDFs") pretrain their representation network on many
materials; this project generates its own from physically based analytic families with
randomised parameters.  No measured material enters this corpus; the pretraining config mixes
in MERL proxies separately (:mod:`neuralbrdf.data.proxy_corpus`), never the held-out subset or
the report's five materials, which measure how the network generalises to real materials.

A material is a diffuse base plus up to :data:`MAX_LOBES` specular lobes, all RGB, in sr⁻¹::

    f = albedo/π · T(cos θi) T(cos θo)  +  Σ_l lobe_l(wi, wo)

* Diffuse base: Lambert (``T = 1``) or Lambert under a smooth dielectric coat,
  ``T(cos θ) = 1 - F_dielectric(cos θ, η_coat)`` (the coat's transmission on the way in and
  out; reciprocal, darkens towards grazing as plastics do).
* Lobes (``h = normalize(wi + wo)``, Fresnel at ``wi·h``):

  - ``ggx``: Walter et al. (2007) Eq. 20 with the GGX distribution and separable Smith
    shadowing (:func:`neuralbrdf.physics.microfacet.microfacet_brdf`);
  - ``beckmann``: the same with the Beckmann distribution (Walter et al. Eq. 25) and its exact
    Smith masking (:func:`neuralbrdf.physics.microfacet.beckmann_smith_g1`, Walter et al. Eq. 24 / Heitz 2014 Eq. 72);
  - ``abc``: the ABC model's specular term (Löw et al. 2012, docs/models.md#abc) with a dielectric
    Fresnel term, its ``A`` set from a target albedo through the lobe integral
    (:func:`abc_lobe_integral`).

  GGX and Beckmann lobes take a dielectric Fresnel term (``η``) or a conductor one (complex
  RGB index ``η + i k``); each lobe carries an RGB weight.

* **Thin films** (``thin_film_probability`` > 0): that share of the dielectric GGX/Beckmann
  lobes reflect through a thin dielectric film on their dielectric (the Airy reflectance of
  :func:`neuralbrdf.physics.thin_film.thin_film_reflectance`: interference pigments, coated
  flakes), film index in :data:`FILM_INDEX_RANGE`, thickness in :data:`FILM_THICKNESS_RANGE_NM`.
  Interference depends on wavelength, so each material's channels then stand for wavelengths
  (:attr:`CorpusMaterials.channel_wavelength`: near the dominant wavelengths of the sRGB
  primaries, jittered by ± :data:`CHANNEL_WAVELENGTH_JITTER_NM`), and its colour changes with
  angle as a goniochromatic ink's does.  These draws come from a generator of their own, so a
  corpus without films is the same with or without this option.

Four archetypes (``ARCHETYPES``) set which parts a material has: ``diffuse`` (Lambert only),
``plastic`` (coated Lambert + one dielectric lobe), ``metal`` (one conductor lobe, sometimes a
faint diffuse base) and ``layered`` (coated Lambert + a sharp dielectric clear coat + a broad
dielectric or conductor lobe: metallic paints, lacquered surfaces).  Every part is reciprocal,
so is every material.  Parameter ranges are the module constants below.

Direction pairs (:meth:`CorpusMaterials.sample_directions`) cover the whole hemisphere and the
specular peaks: a ``uniform_fraction`` of pairs has ``wi`` and ``wo`` uniform on the hemisphere
(solid angle, so grazing angles are well represented); the rest have ``wi`` uniform and ``wo``
the reflection of ``wi`` about a half vector drawn from a GGX distribution matched to one of the
material's lobes (widened by a random factor in :data:`SAMPLING_SPREAD`), so that even the
sharpest peaks are sampled.  The joint density of these pairs is symmetric in ``wi, wo``.

Everything is NumPy float64 and seeded (:func:`generate_materials`, :func:`sample_batch`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from neuralbrdf.errors import InputError
from neuralbrdf.geometry import dot, normalize
from neuralbrdf.physics.abc import abc_brdf
from neuralbrdf.physics.fresnel import fresnel_conductor, fresnel_dielectric
from neuralbrdf.physics.microfacet import microfacet_brdf
from neuralbrdf.physics.thin_film import thin_film_reflectance

MAX_LOBES = 2

#: Lobe kinds, indexed by :attr:`CorpusMaterials.lobe_kind` (0 = slot unused).
LOBE_KINDS = ("none", "ggx", "beckmann", "abc")
LOBE_NONE, LOBE_GGX, LOBE_BECKMANN, LOBE_ABC = range(4)

ARCHETYPES = ("diffuse", "plastic", "metal", "layered")
#: Default archetype probabilities, in the order of :data:`ARCHETYPES`.
DEFAULT_ARCHETYPE_WEIGHTS = (0.15, 0.35, 0.25, 0.25)

#: Diffuse albedo (per-material level; channels scaled down from it for colour).
ALBEDO_RANGE = (0.01, 0.9)
#: Roughness ``alpha`` (log-uniform) of single lobes, of layered clear coats and base lobes.
ALPHA_RANGE = (0.01, 0.6)
COAT_ALPHA_RANGE = (0.01, 0.1)
BASE_ALPHA_RANGE = (0.15, 0.8)
#: Dielectric relative index (uniform) and conductor complex index per channel (uniform).
ETA_DIELECTRIC_RANGE = (1.3, 1.8)
ETA_CONDUCTOR_RANGE = (0.1, 2.0)
K_CONDUCTOR_RANGE = (1.5, 8.0)
#: ABC exponent ``C`` (uniform); with probability ``ABC_TAIL_PROBABILITY`` a lobe is instead a
#: narrow spike on a heavy tail (``C`` in ``ABC_TAIL_C_RANGE``, ``B`` in ``ABC_TAIL_B_RANGE``,
#: log-uniform), the regime of Löw et al.'s fits of fabrics.
ABC_C_RANGE = (0.8, 2.2)
ABC_TAIL_PROBABILITY = 0.2
ABC_TAIL_C_RANGE = (0.05, 0.3)
ABC_TAIL_B_RANGE = (1e4, 1e7)
#: Target normal-incidence albedo (before Fresnel) of an ABC lobe: sets ``A``.
ABC_ALBEDO_RANGE = (0.5, 1.5)
#: Widening of the importance-sampling distribution relative to a lobe's own width.
SAMPLING_SPREAD = (1.0, 2.5)
#: GGX half-maximum angle of ``D`` is ``GGX_HALF_WIDTH · alpha`` for small ``alpha``:
#: ``1 / (alpha² + θ²)²`` halves at ``θ² = (√2 - 1) alpha²``.
GGX_HALF_WIDTH = math.sqrt(math.sqrt(2.0) - 1.0)
#: Sampling widths are clipped to this range of GGX ``alpha``.
SAMPLING_ALPHA_RANGE = (2e-3, 1.0)
#: Thin films on dielectric lobes: film index (uniform) and thickness in nm (uniform).
FILM_INDEX_RANGE = (1.8, 2.6)
FILM_THICKNESS_RANGE_NM = (100.0, 700.0)
#: Wavelengths (nm) the R, G, B channels stand for in thin-film interference, and their jitter.
CHANNEL_WAVELENGTHS_NM = (610.0, 550.0, 465.0)
CHANNEL_WAVELENGTH_JITTER_NM = 25.0


# ------------------------------------------------------------------------------- physics


def abc_lobe_integral(b, c, points: int = 2048):
    """``∫ (1 + B (1 - cos θh))^(-C) dω_o`` over the hemisphere at normal incidence (sr).

    At ``wi = n``, ``θh = θo / 2``; with ``x = 1 - cos θh``, ``dω_o = 2π · 4 (1 - x) dx`` for
    ``x`` in ``[0, 1 - cos 45°]``.  Trapezoid rule on a logarithmic grid of ``x`` (the
    integrand varies on the scale ``1/B``); ``b, c`` broadcast, the result has their shape.
    """
    b = np.asarray(b, dtype=np.float64)[..., None]
    c = np.asarray(c, dtype=np.float64)[..., None]
    x_max = 1.0 - math.cos(math.pi / 4.0)
    x = np.concatenate([[0.0], np.geomspace(1e-14, x_max, points)])
    integrand = 8.0 * math.pi * (1.0 - x) * (1.0 + b * x) ** (-c)
    return np.trapezoid(integrand, x, axis=-1)


def abc_specular(wi, wo, a_rgb, b, c, eta):
    """ABC specular term (docs/models.md#abc without the ``kd/π`` part), RGB ``[N, 3]``, sr⁻¹::

        A · F(η, wi·h) · G / (π cos θi cos θo (1 + B (1 - n·h))^C)

    with per-sample ``A`` ``[N, 3]`` and ``B, C, η`` ``[N]``: :func:`neuralbrdf.physics.abc.abc_brdf`
    evaluated for a unit one-channel ``A`` (its scalars broadcast against the samples), then
    scaled per sample.  0 below the horizon.
    """
    return abc_brdf(wi, wo, np.zeros(1), np.ones(1), b, c, eta) * a_rgb


# ------------------------------------------------------------------------------- materials


@dataclass(frozen=True)
class CorpusMaterials:
    """Parameters of ``M`` corpus materials (arrays, float64 unless stated).

    Attributes
    ----------
    archetype:
        ``[M]`` int, index into :data:`ARCHETYPES`.
    albedo:
        ``[M, 3]`` diffuse albedo (the Lambert term is ``albedo / π``).
    coat_eta:
        ``[M]`` relative index of the dielectric coat over the diffuse base; 0 = no coat.
    lobe_kind:
        ``[M, L]`` int, index into :data:`LOBE_KINDS` (0 = unused slot).
    lobe_conductor:
        ``[M, L]`` bool, conductor (``eta + i k``) rather than dielectric (``eta``) Fresnel.
    lobe_alpha:
        ``[M, L]`` roughness of GGX/Beckmann lobes; for ABC lobes the GGX ``alpha`` of the
        same half-maximum width (used for importance sampling only).
    lobe_weight:
        ``[M, L, 3]`` RGB factor of the lobe (the ABC ``A`` for ABC lobes).
    lobe_eta, lobe_k:
        ``[M, L, 3]`` Fresnel index per channel (``k`` = 0 for dielectrics).
    lobe_b, lobe_c:
        ``[M, L]`` ABC shape parameters ``B, C`` (unused for other kinds).
    lobe_film_nm, lobe_film_index:
        ``[M, L]`` thickness (nm; 0 = no film) and index of a thin film on a dielectric lobe.
    channel_wavelength:
        ``[M, 3]`` wavelength (nm) each channel stands for in thin-film interference.
    """

    archetype: np.ndarray
    albedo: np.ndarray
    coat_eta: np.ndarray
    lobe_kind: np.ndarray
    lobe_conductor: np.ndarray
    lobe_alpha: np.ndarray
    lobe_weight: np.ndarray
    lobe_eta: np.ndarray
    lobe_k: np.ndarray
    lobe_b: np.ndarray
    lobe_c: np.ndarray
    lobe_film_nm: np.ndarray
    lobe_film_index: np.ndarray
    channel_wavelength: np.ndarray

    def __len__(self) -> int:
        return self.archetype.shape[0]

    def subset(self, index) -> CorpusMaterials:
        """The materials ``index`` (integer array or boolean mask) as a new corpus."""
        return replace(self, **{f.name: getattr(self, f.name)[index] for f in fields(self)})

    def evaluate(self, material, wi, wo) -> np.ndarray:
        """RGB BRDF ``[N, 3]`` (sr⁻¹) of materials ``material`` ``[N]`` at pairs ``wi, wo`` ``[N, 3]``.

        Exactly 0 where either direction is at or below the horizon.
        """
        material = np.asarray(material)
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        cos_i, cos_o = wi[:, 2], wo[:, 2]
        above = (cos_i > 0.0) & (cos_o > 0.0)
        f = self._diffuse(material, cos_i, cos_o)
        for slot in range(self.lobe_kind.shape[1]):
            kinds = self.lobe_kind[material, slot]
            for kind in (LOBE_GGX, LOBE_BECKMANN, LOBE_ABC):
                rows = np.flatnonzero((kinds == kind) & above)
                if rows.size:
                    f[rows] += self._lobe(kind, material[rows], slot, wi[rows], wo[rows])
        return np.where(above[:, None], f, 0.0)

    def _diffuse(self, material, cos_i, cos_o) -> np.ndarray:
        eta = self.coat_eta[material]
        coated = eta > 0.0
        safe_eta = np.where(coated, eta, 1.5)
        transmission = (1.0 - fresnel_dielectric(cos_i, safe_eta)) * (1.0 - fresnel_dielectric(cos_o, safe_eta))
        transmission = np.where(coated, transmission, 1.0)
        return self.albedo[material] / math.pi * transmission[:, None]

    def _lobe(self, kind, material, slot, wi, wo) -> np.ndarray:
        weight = self.lobe_weight[material, slot]
        eta = self.lobe_eta[material, slot]
        if kind == LOBE_ABC:
            return abc_specular(wi, wo, weight, self.lobe_b[material, slot], self.lobe_c[material, slot], eta[:, 0])
        k = self.lobe_k[material, slot]
        conductor = self.lobe_conductor[material, slot][:, None]
        film = self.lobe_film_nm[material, slot][:, None]

        def fresnel(cos_d):
            c = cos_d[:, None]
            dielectric = fresnel_dielectric(c, eta)
            if np.any(film > 0.0):
                # a film of thickness 0 is the bare interface (the Airy formula's own limit)
                film_index = self.lobe_film_index[material, slot][:, None]
                coated = thin_film_reflectance(c, self.channel_wavelength[material], film_index, film,
                                               np.maximum(eta, 1.0))
                dielectric = np.where(film > 0.0, coated, dielectric)
            return weight * np.where(conductor, fresnel_conductor(c, eta, k), dielectric)

        alpha = self.lobe_alpha[material, slot]
        return microfacet_brdf(wi, wo, alpha, fresnel, distribution="ggx" if kind == LOBE_GGX else "beckmann")

    def sample_directions(self, material, rng: np.random.Generator, uniform_fraction: float = 0.5):
        """Unit pairs ``(wi, wo)``, each ``[N, 3]``, for materials ``material`` ``[N]`` (module docstring).

        All directions are strictly above the horizon.
        """
        material = np.asarray(material)
        n = material.shape[0]
        wi = uniform_hemisphere(rng, n)
        wo = uniform_hemisphere(rng, n)
        # Pick one of the material's lobes per sample; materials without lobes stay uniform.
        n_lobes = (self.lobe_kind[material] != LOBE_NONE).sum(axis=1)
        slot = np.minimum((rng.random(n) * n_lobes).astype(np.int64), np.maximum(n_lobes - 1, 0))
        importance = (rng.random(n) >= uniform_fraction) & (n_lobes > 0)
        alpha = self.lobe_alpha[material, slot] * rng.uniform(*SAMPLING_SPREAD, size=n)
        h = sample_ggx_normal(rng, np.clip(alpha, *SAMPLING_ALPHA_RANGE))
        cos_ih = dot(wi, h)
        reflected = 2.0 * cos_ih[:, None] * h - wi
        valid = importance & (cos_ih > 0.0) & (reflected[:, 2] > 1e-6)
        wo = np.where(valid[:, None], normalize(reflected), wo)
        return wi, wo


def uniform_hemisphere(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` unit vectors uniform in solid angle on the upper hemisphere (``z > 0``)."""
    z = 1.0 - rng.random(n)  # (0, 1]
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = 2.0 * math.pi * rng.random(n)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def sample_ggx_normal(rng: np.random.Generator, alpha) -> np.ndarray:
    """Microfacet normals ``[N, 3]`` with density ``D_GGX(h) cos θh`` (inverse CDF), ``alpha`` ``[N]``."""
    alpha = np.asarray(alpha, dtype=np.float64)
    u = rng.random(alpha.shape)
    tan2 = alpha * alpha * u / (1.0 - u)
    cos_t = 1.0 / np.sqrt(1.0 + tan2)
    sin_t = np.sqrt(np.clip(1.0 - cos_t * cos_t, 0.0, None))
    phi = 2.0 * math.pi * rng.random(alpha.shape)
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=1)


# ------------------------------------------------------------------------------- generation


def log_uniform(rng, low, high, size):
    """``size`` draws log-uniform on ``[low, high]``."""
    return np.exp(rng.uniform(math.log(low), math.log(high), size=size))


def _colour(rng, level, n):
    """RGB ``[n, 3]`` whose largest channel is ``level``; a third of them grey."""
    chroma = rng.uniform(0.05, 1.0, size=(n, 3))
    chroma = np.where(rng.random((n, 1)) < 1.0 / 3.0, 1.0, chroma / chroma.max(axis=1, keepdims=True))
    return level[:, None] * chroma


def _abc_shape(rng, alpha):
    """ABC ``(B, C)`` of lobes with GGX-equivalent width ``alpha`` ``[n]``, or heavy-tailed ones."""
    n = alpha.shape[0]
    c = rng.uniform(*ABC_C_RANGE, size=n)
    # Half maximum of (1 + B (1 - cos θ))^-C at 1 - cos θ = (2^(1/C) - 1) / B ≈ θ²/2.
    half_width = GGX_HALF_WIDTH * alpha
    b = 2.0 * (2.0 ** (1.0 / c) - 1.0) / half_width**2
    tail = rng.random(n) < ABC_TAIL_PROBABILITY
    c = np.where(tail, rng.uniform(*ABC_TAIL_C_RANGE, size=n), c)
    b = np.where(tail, log_uniform(rng, *ABC_TAIL_B_RANGE, n), b)
    width = np.sqrt(2.0 * (2.0 ** (1.0 / c) - 1.0) / b)
    return b, c, width / GGX_HALF_WIDTH


def _white(n):
    return np.ones((n, 3))


def _fill_lobe(rng, params, rows, slot, kinds, alpha, conductor, weight):
    """Write lobe ``slot`` of materials ``rows``: kind, Fresnel, width and RGB weight.

    Returns the lobes' (first-channel) Fresnel index, the coat index of coated diffuse bases.
    """
    n = rows.size
    kind = rng.choice(np.asarray(kinds), size=n)
    kind = np.where(conductor, np.where(kind == LOBE_ABC, LOBE_GGX, kind), kind)  # ABC is dielectric
    eta_d = np.repeat(rng.uniform(*ETA_DIELECTRIC_RANGE, size=(n, 1)), 3, axis=1)
    eta_c = rng.uniform(*ETA_CONDUCTOR_RANGE, size=(n, 3))
    k_c = rng.uniform(*K_CONDUCTOR_RANGE, size=(n, 3))
    b, c, abc_alpha = _abc_shape(rng, alpha)
    abc = kind == LOBE_ABC
    a_abc = math.pi * rng.uniform(*ABC_ALBEDO_RANGE, size=n) / abc_lobe_integral(b, c)
    params["lobe_kind"][rows, slot] = kind
    params["lobe_conductor"][rows, slot] = conductor
    params["lobe_alpha"][rows, slot] = np.where(abc, abc_alpha, alpha)
    params["lobe_weight"][rows, slot] = np.where(abc[:, None], a_abc[:, None] * weight, weight)
    params["lobe_eta"][rows, slot] = np.where(conductor[:, None], eta_c, eta_d)
    params["lobe_k"][rows, slot] = np.where(conductor[:, None], k_c, 0.0)
    params["lobe_b"][rows, slot] = np.where(abc, b, 0.0)
    params["lobe_c"][rows, slot] = np.where(abc, c, 0.0)
    return params["lobe_eta"][rows, slot, 0]


def generate_materials(n_materials: int, seed: int, archetype_weights=DEFAULT_ARCHETYPE_WEIGHTS,
                       thin_film_probability: float = 0.0) -> CorpusMaterials:
    """``n_materials`` random materials, reproducible from ``seed`` (module docstring).

    ``archetype_weights``: relative probabilities of :data:`ARCHETYPES`, in that order;
    ``thin_film_probability``: share of the dielectric GGX/Beckmann lobes under a thin film.
    """
    if not 0.0 <= thin_film_probability <= 1.0:
        raise InputError(f"must lie in [0, 1], got {thin_film_probability}", key="thin_film_probability")
    if not isinstance(n_materials, int) or n_materials < 1:
        raise InputError(f"n_materials must be a positive integer, got {n_materials!r}", key="n_materials")
    weights = np.asarray(archetype_weights, dtype=np.float64)
    valid = weights.shape == (len(ARCHETYPES),) and np.all(np.isfinite(weights)) and np.all(weights >= 0)
    if not valid or weights.sum() <= 0:
        raise InputError(
            f"archetype_weights must be {len(ARCHETYPES)} non-negative numbers ({', '.join(ARCHETYPES)}) "
            f"with a positive sum, got {list(archetype_weights)}",
            key="archetype_weights",
        )
    rng = np.random.default_rng(seed)
    m, slots = n_materials, MAX_LOBES
    archetype = rng.choice(len(ARCHETYPES), size=m, p=weights / weights.sum())
    params = {
        "lobe_kind": np.zeros((m, slots), dtype=np.int64),
        "lobe_conductor": np.zeros((m, slots), dtype=bool),
        "lobe_alpha": np.ones((m, slots)),
        "lobe_weight": np.zeros((m, slots, 3)),
        "lobe_eta": np.ones((m, slots, 3)),
        "lobe_k": np.zeros((m, slots, 3)),
        "lobe_b": np.zeros((m, slots)),
        "lobe_c": np.zeros((m, slots)),
    }
    albedo = _colour(rng, log_uniform(rng, *ALBEDO_RANGE, m), m)
    coat_eta = np.zeros(m)
    all_kinds = (LOBE_GGX, LOBE_BECKMANN, LOBE_ABC)

    plastic = np.flatnonzero(archetype == ARCHETYPES.index("plastic"))
    eta = _fill_lobe(rng, params, plastic, 0, all_kinds, log_uniform(rng, *ALPHA_RANGE, plastic.size),
                     np.zeros(plastic.size, bool), _white(plastic.size))
    coat_eta[plastic] = eta

    metal = np.flatnonzero(archetype == ARCHETYPES.index("metal"))
    _fill_lobe(rng, params, metal, 0, (LOBE_GGX, LOBE_BECKMANN), log_uniform(rng, *ALPHA_RANGE, metal.size),
               np.ones(metal.size, bool), _white(metal.size) * rng.uniform(0.7, 1.0, size=(metal.size, 1)))
    faint = rng.random(metal.size) < 0.5
    albedo[metal] = np.where(faint[:, None], albedo[metal] * 0.03, 0.0)

    layered = np.flatnonzero(archetype == ARCHETYPES.index("layered"))
    n = layered.size
    eta = _fill_lobe(rng, params, layered, 0, all_kinds, log_uniform(rng, *COAT_ALPHA_RANGE, n),
                     np.zeros(n, bool), _white(n))
    coat_eta[layered] = eta
    metallic = rng.random(n) < 0.5
    base_weight = np.where(metallic[:, None], _colour(rng, rng.uniform(0.1, 0.5, size=n), n), 1.0)
    _fill_lobe(rng, params, layered, 1, all_kinds, log_uniform(rng, *BASE_ALPHA_RANGE, n), metallic, base_weight)
    albedo[layered] *= 0.6
    params.update(_thin_films(np.random.default_rng([seed, 1]), params, thin_film_probability))
    return CorpusMaterials(archetype=archetype, albedo=albedo, coat_eta=coat_eta, **params)


def _thin_films(rng, params, probability: float) -> dict[str, np.ndarray]:
    """Films on a ``probability`` share of the dielectric GGX/Beckmann lobes, and each material's
    channel wavelengths (module docstring), from a generator of their own."""
    kind = params["lobe_kind"]
    m = kind.shape[0]
    film_nm, film_index = np.zeros(kind.shape), np.ones(kind.shape)
    wavelength = np.broadcast_to(np.asarray(CHANNEL_WAVELENGTHS_NM), (m, 3)).copy()
    if probability > 0.0:
        eligible = np.isin(kind, (LOBE_GGX, LOBE_BECKMANN)) & ~params["lobe_conductor"]
        coated = eligible & (rng.random(kind.shape) < probability)
        film_nm = np.where(coated, rng.uniform(*FILM_THICKNESS_RANGE_NM, size=kind.shape), 0.0)
        film_index = np.where(coated, rng.uniform(*FILM_INDEX_RANGE, size=kind.shape), 1.0)
        wavelength += rng.uniform(-CHANNEL_WAVELENGTH_JITTER_NM, CHANNEL_WAVELENGTH_JITTER_NM, size=(m, 3))
    return {"lobe_film_nm": film_nm, "lobe_film_index": film_index, "channel_wavelength": wavelength}


# ------------------------------------------------------------------------------- batches


@dataclass(frozen=True)
class CorpusBatch:
    """Samples of corpus materials: ``material`` ``[N]`` int, ``wi, wo`` ``[N, 3]``, ``f`` ``[N, 3]`` sr⁻¹."""

    material: np.ndarray
    wi: np.ndarray
    wo: np.ndarray
    f: np.ndarray


def sample_batch(
    materials: CorpusMaterials, size: int, rng: np.random.Generator, uniform_fraction: float = 0.5
) -> CorpusBatch:
    """``size`` samples: materials uniform at random, directions by :meth:`~CorpusMaterials.sample_directions`."""
    if not 0.0 <= uniform_fraction <= 1.0:
        raise InputError(f"uniform_fraction must lie in [0, 1], got {uniform_fraction}", key="uniform_fraction")
    material = rng.integers(0, len(materials), size=size)
    wi, wo = materials.sample_directions(material, rng, uniform_fraction)
    return CorpusBatch(material, wi, wo, materials.evaluate(material, wi, wo))
