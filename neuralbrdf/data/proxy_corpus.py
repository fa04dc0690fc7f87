"""Measured NBRDF proxies as NLB pretraining materials, with fixed held-out subsets (docs/formats.md#nbrdf-proxy, docs/models.md#nlb).

Fan et al. (2022) pretrain their representation network on measured materials; the analytic
corpus (:mod:`neuralbrdf.data.corpus`) alone leaves the network's prior far from real
materials.  This module adds NBRDF proxies (Sztrajman et al. 2021) of two labs to the
pretraining batches: the MERL measurements (Matusik et al.
2003; MERL data CC BY-SA 4.0) and the RGL measurements (Dupuy &
Jakob 2018, another lab and instrument) of the reference data (README.md) — all of them except

* the report's five materials (:data:`~neuralbrdf.data.nbrdf.REPORT_MATERIALS`), the project's
  latent-fitting test materials,
* :data:`HELD_OUT`, ten MERL materials spread over the MERL families (2 diffuse, 2
  plastic/phenolic, 2 metal, 3 paint of which 2 metallic, 1 wood) on which the latent fit's
  generalisation is measured (``benchmarks/models.py``), and
* :data:`RGL_VALIDATION`, nine RGL materials spread over that database's families (felt, car
  coating, paint, plastic, iridescent paint, paper, satin, gem-like coating) on which the latent
  fit's settings are chosen: a validation split for another lab's materials.

No group is ever sampled here (:func:`pretraining_proxy_names` refuses them).  Each lab's
materials are named ``<lab>:<name>`` (``merl:brass``, ``rgl:satin_white_rgb``), the lab being
the data folder's name without ``-nbrdf``.  Samples are drawn on the fly, never stored; the proxy
files are read where they lie.

Direction pairs (:func:`sample_proxy_directions`): a ``uniform_fraction`` has ``wi`` and ``wo``
uniform in solid angle on the hemisphere (a third of them beyond 70° from the normal: grazing
directions are well covered); the rest have ``wi`` uniform and ``wo`` the reflection of ``wi``
about a GGX half vector whose roughness is log-uniform in :data:`PROXY_SAMPLING_ALPHA` (the
proxies' lobe widths are not known in closed form, so every width from near-mirror to broad is
sampled).

**Blends** (``n_blends``): the 35 measured materials are a sparse sample of real appearance;
the hypothesis is that a new material's latent lands between them, where only the analytic
corpus constrains the network.  ``n_blends`` further materials, fixed by ``seed``, fill that
gap (measured in docs/design.md, *The default network*): each is the
weighted geometric mean of two distinct proxies, ``f = f_j^a · f_k^(1 − a)`` per RGB channel
with ``a`` uniform in :data:`BLEND_WEIGHTS`.  In log space this interpolates lobe shapes (the
geometric mean of two Gaussian lobes is a Gaussian of intermediate width) rather than
superimposing two lobes as a linear mix would; it is a valid BRDF — non-negative, reciprocal
where both parents are, and (weighted AM–GM) never above the linear mix ``a f_j + (1 − a) f_k``,
so it conserves energy where the parents do (parent values are floored at :data:`BLEND_FLOOR`
under the logarithm, which can lift a blend of two near-zero values to at most that floor).
A ``blend_fraction`` of proxy samples comes from the blends, the rest from the measured proxies.
Blends are made within one lab (:class:`ProxyMaterials`); several labs are one set of
materials, each lab's share of the samples its share of the measured materials (:class:`ProxySet`).
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np

from neuralbrdf.data.corpus import CorpusBatch, log_uniform, sample_ggx_normal, uniform_hemisphere
from neuralbrdf.data.nbrdf import DENSE_LAYERS, REPORT_MATERIALS, NbrdfNetwork, available_materials, nbrdf_input
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import dot, normalize

#: MERL materials never used in pretraining: the held-out evaluation subset (by family).
HELD_OUT = (
    "pink-fabric2", "alumina-oxide",                   # diffuse
    "red-plastic", "specular-orange-phenolic",         # plastic / phenolic
    "nickel", "alum-bronze",                           # metal
    "gold-metallic-paint3", "silver-metallic-paint2",  # metallic paint
    "dark-blue-paint",                                 # paint
    "cherry-235",                                      # wood
)
#: RGL materials never used in pretraining: the validation split of the latent fit's settings.
RGL_VALIDATION = (
    "acrylic_felt_pink_rgb",                           # felt
    "cc_green_malachite_rgb",                          # coating
    "cm_white_rgb",                                    # white
    "colodur_napoli_4f_rgb",                           # paint
    "ilm_solo_m_68_rgb",                               # plastic
    "irid_flake_paint2_rgb",                           # iridescent paint
    "paper_green_rgb",                                 # paper
    "satin_blue_rgb",                                  # satin
    "vch_golden_yellow_rgb",                           # gem-like coating
)
#: Every measured material the pretraining must not see.
NEVER_PRETRAINED = REPORT_MATERIALS + HELD_OUT + RGL_VALIDATION
#: GGX roughness range (log-uniform) of the half vectors of importance-sampled proxy pairs.
PROXY_SAMPLING_ALPHA = (0.003, 0.5)
#: Range (uniform) of a blend's weight ``a`` on its first parent.
BLEND_WEIGHTS = (0.2, 0.8)
#: Floor (sr⁻¹) of the parents' values under the logarithm of a blend.
BLEND_FLOOR = 1e-6


def pretraining_proxy_names(data_dir: str | PathLike[str]) -> tuple[str, ...]:
    """The proxies of ``data_dir`` usable for pretraining: all but :data:`NEVER_PRETRAINED`."""
    return tuple(n for n in available_materials(data_dir) if n not in NEVER_PRETRAINED)


def lab_of(data_dir: str | PathLike[str]) -> str:
    """The lab a folder of proxies holds: its name without ``-nbrdf`` (``merl``, ``rgl``)."""
    return Path(data_dir).name.removesuffix("-nbrdf")


def is_measured_code(name: str) -> bool:
    """Whether a pretrained code's name is a measured material (``<lab>:<name>``), not a blend or analytic."""
    lab, _, rest = name.partition(":")
    return bool(rest) and lab != "analytic" and not lab.endswith("-blend")


def is_blend_code(name: str) -> bool:
    """Whether a pretrained code's name is a blend of measured materials (``<lab>-blend:…``)."""
    return name.partition(":")[0].endswith("-blend")


def sample_proxy_directions(rng: np.random.Generator, n: int, uniform_fraction: float):
    """``n`` unit pairs ``(wi, wo)`` above the horizon (module docstring)."""
    wi = uniform_hemisphere(rng, n)
    wo = uniform_hemisphere(rng, n)
    importance = rng.random(n) >= uniform_fraction
    h = sample_ggx_normal(rng, log_uniform(rng, *PROXY_SAMPLING_ALPHA, n))
    cos_ih = dot(wi, h)
    reflected = 2.0 * cos_ih[:, None] * h - wi
    valid = importance & (cos_ih > 0.0) & (reflected[:, 2] > 1e-6)
    return wi, np.where(valid[:, None], normalize(reflected), wo)


class ProxyMaterials:
    """Loaded NBRDF proxies and their blends, addressed as materials ``0 .. len - 1``: the
    measured proxies in the order of ``names``, then the ``n_blends`` blends (module docstring)."""

    def __init__(self, data_dir: str | PathLike[str], names: tuple[str, ...], n_blends: int = 0,
                 blend_fraction: float = 0.5, seed: int = 0) -> None:
        self.lab = lab_of(data_dir)
        forbidden = sorted(set(names) & set(NEVER_PRETRAINED))
        if forbidden:
            raise InputError(f"{forbidden} are held out of pretraining (neuralbrdf.data.proxy_corpus)",
                             path=data_dir)
        if not names:
            raise InputError("no NBRDF proxy to pretrain on", path=data_dir)
        if n_blends and len(names) < 2:
            raise InputError(f"blends need two proxies or more, got {len(names)}", path=data_dir)
        if not 0.0 <= blend_fraction <= 1.0:
            raise InputError(f"must lie in [0, 1], got {blend_fraction}", key="proxy_blend_fraction")
        self.names = tuple(names)
        self.networks = tuple(NbrdfNetwork.load(Path(data_dir) / f"{name}.h5") for name in self.names)
        # Every network's layers stacked, ``[materials, ...]``: one batched evaluation for all of them.
        self._kernels = [np.stack([net.kernels[i] for net in self.networks]) for i in range(len(DENSE_LAYERS))]
        self._biases = [np.stack([net.biases[i] for net in self.networks]) for i in range(len(DENSE_LAYERS))]
        rng = np.random.default_rng([seed, n_blends])
        first = rng.integers(0, len(names), n_blends)
        second = (first + rng.integers(1, max(len(names), 2), n_blends)) % len(names)  # never the first
        #: Blend ``b``: parents ``blend_parents[b]`` with weights ``blend_weights[b]`` and 1 − it.
        self.blend_parents = np.stack([first, second], axis=1)
        self.blend_weights = rng.uniform(*BLEND_WEIGHTS, n_blends)
        self.blend_fraction = blend_fraction

    def __len__(self) -> int:
        return len(self.networks) + len(self.blend_weights)

    @property
    def material_names(self) -> tuple[str, ...]:
        """``<lab>:<name>`` per measured proxy, then ``<lab>-blend:<a>*<name>+<1-a>*<name>``."""
        blends = (f"{self.lab}-blend:{a:.3f}*{self.names[j]}+{1 - a:.3f}*{self.names[k]}"
                  for (j, k), a in zip(self.blend_parents, self.blend_weights))
        return (*(f"{self.lab}:{n}" for n in self.names), *blends)

    def _measured(self, material, x) -> np.ndarray:
        """Each row's measured proxy ``material`` at network inputs ``x`` ``[N, 6]``
        (:func:`~neuralbrdf.data.nbrdf.nbrdf_input`), clamped at 0: what
        :meth:`NbrdfNetwork.evaluate` gives above the horizon, every network at once."""
        for layer, (_, activation) in enumerate(DENSE_LAYERS):
            x = np.einsum("ni,nij->nj", x, self._kernels[layer][material]) + self._biases[layer][material]
            if activation == "relu":
                x = np.maximum(x, 0.0)
        return np.maximum(np.exp(x) - 1.0, 0.0)

    def evaluate(self, material, wi, wo) -> np.ndarray:
        """RGB BRDF ``[N, 3]`` (sr⁻¹) of materials ``material`` ``[N]`` at pairs ``wi, wo``."""
        material = np.asarray(material)
        wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
        x = nbrdf_input(wi, wo)
        f = np.zeros((len(material), 3))
        measured = material < len(self.networks)
        f[measured] = self._measured(material[measured], x[measured])
        blend = np.flatnonzero(~measured)
        if len(blend):
            index = material[blend] - len(self.networks)
            weight = self.blend_weights[index][:, None]
            log_f = sum(w * np.log(np.maximum(self._measured(self.blend_parents[index, p], x[blend]), BLEND_FLOOR))
                        for p, w in ((0, weight), (1, 1.0 - weight)))
            f[blend] = np.exp(log_f)
        above = (wi[:, 2] > 0.0) & (wo[:, 2] > 0.0)
        return np.where(above[:, None], f, 0.0)

    def sample_batch(self, size: int, rng: np.random.Generator, uniform_fraction: float) -> CorpusBatch:
        """``size`` samples: a ``blend_fraction`` from the blends, the rest from the measured
        proxies, materials uniform at random within each; pairs by :func:`sample_proxy_directions`."""
        n_measured = len(self.networks)
        material = rng.integers(0, n_measured, size=size)
        if len(self.blend_weights):  # without blends the random stream is that of the measured proxies alone
            from_blend = rng.random(size) < self.blend_fraction
            material[from_blend] = n_measured + rng.integers(0, len(self.blend_weights), from_blend.sum())
        wi, wo = sample_proxy_directions(rng, size, uniform_fraction)
        return CorpusBatch(material, wi, wo, self.evaluate(material, wi, wo))


class ProxySet:
    """The proxies of several labs (one :class:`ProxyMaterials` each) as one set of materials:
    the labs' materials one after the other; a batch's samples split between the labs in
    proportion to their measured materials (module docstring)."""

    def __init__(self, labs: list[ProxyMaterials]) -> None:
        if not labs:
            raise InputError("no NBRDF proxy folder to pretrain on")
        self.labs = tuple(labs)
        measured = np.array([len(lab.networks) for lab in self.labs], dtype=np.float64)
        self.shares = measured / measured.sum()

    def __len__(self) -> int:
        return sum(len(lab) for lab in self.labs)

    @property
    def material_names(self) -> tuple[str, ...]:
        return tuple(name for lab in self.labs for name in lab.material_names)

    def sample_batch(self, size: int, rng: np.random.Generator, uniform_fraction: float) -> CorpusBatch:
        """``size`` samples; with one lab exactly :meth:`ProxyMaterials.sample_batch`."""
        if len(self.labs) == 1:
            return self.labs[0].sample_batch(size, rng, uniform_fraction)
        counts = rng.multinomial(size, self.shares)
        batches, offset = [], 0
        for lab, count in zip(self.labs, counts):
            batch = lab.sample_batch(int(count), rng, uniform_fraction)
            batches.append(CorpusBatch(batch.material + offset, batch.wi, batch.wo, batch.f))
            offset += len(lab)
        return CorpusBatch(*(np.concatenate([getattr(b, k) for b in batches]) for k in ("material", "wi", "wo", "f")))
