"""MERL NBRDF proxies as NLB pretraining materials, with a fixed held-out subset (SPEC §2.4, §4.2).

Fan et al. (2022) pretrain their representation network on measured materials; the analytic
corpus (:mod:`neuralbrdf.data.corpus`) alone leaves the network's prior far from real
materials.  This module adds the MERL proxies of ``../shared/data/merl-nbrdf`` (Sztrajman et
al. 2021 fits of the MERL measurements, Matusik et al. 2003; MERL data CC BY-SA 4.0) to the
pretraining batches — all of them except

* the report's five materials (:data:`~neuralbrdf.data.nbrdf.REPORT_MATERIALS`), the project's
  latent-fitting test materials, and
* :data:`HELD_OUT`, ten materials spread over the MERL families (2 diffuse, 2 plastic/phenolic,
  2 metal, 3 paint of which 2 metallic, 1 wood) on which the latent fit's generalisation is
  measured (``benchmarks/models.py``).

Neither group is ever sampled here (:func:`pretraining_proxy_names` refuses them).  Samples are
drawn on the fly, never stored; the data stays in ``../shared``.

Direction pairs (:func:`sample_proxy_directions`): a ``uniform_fraction`` has ``wi`` and ``wo``
uniform in solid angle on the hemisphere (a third of them beyond 70° from the normal: grazing
directions are well covered); the rest have ``wi`` uniform and ``wo`` the reflection of ``wi``
about a GGX half vector whose roughness is log-uniform in :data:`PROXY_SAMPLING_ALPHA` (the
proxies' lobe widths are not known in closed form, so every width from near-mirror to broad is
sampled).
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np

from neuralbrdf.data.corpus import CorpusBatch, log_uniform, sample_ggx_normal, uniform_hemisphere
from neuralbrdf.data.nbrdf import REPORT_MATERIALS, NbrdfNetwork, available_materials
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
#: Every MERL material the pretraining must not see.
NEVER_PRETRAINED = REPORT_MATERIALS + HELD_OUT
#: GGX roughness range (log-uniform) of the half vectors of importance-sampled proxy pairs.
PROXY_SAMPLING_ALPHA = (0.003, 0.5)


def pretraining_proxy_names(data_dir: str | PathLike[str]) -> tuple[str, ...]:
    """The proxies of ``data_dir`` usable for pretraining: all but :data:`NEVER_PRETRAINED`."""
    return tuple(n for n in available_materials(data_dir) if n not in NEVER_PRETRAINED)


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
    """Loaded NBRDF proxies, addressed as materials ``0 .. len - 1`` (the order of ``names``)."""

    def __init__(self, data_dir: str | PathLike[str], names: tuple[str, ...]) -> None:
        forbidden = sorted(set(names) & set(NEVER_PRETRAINED))
        if forbidden:
            raise InputError(f"{forbidden} are held out of pretraining (neuralbrdf.data.proxy_corpus)",
                             path=data_dir)
        if not names:
            raise InputError("no NBRDF proxy to pretrain on", path=data_dir)
        self.names = tuple(names)
        self.networks = tuple(NbrdfNetwork.load(Path(data_dir) / f"{name}.h5") for name in self.names)

    def __len__(self) -> int:
        return len(self.networks)

    def evaluate(self, material, wi, wo) -> np.ndarray:
        """RGB BRDF ``[N, 3]`` (sr⁻¹) of proxies ``material`` ``[N]`` at pairs ``wi, wo``."""
        f = np.zeros((len(material), 3))
        for index in np.unique(material):
            rows = np.flatnonzero(material == index)
            f[rows] = self.networks[index].evaluate(wi[rows], wo[rows])
        return f

    def sample_batch(self, size: int, rng: np.random.Generator, uniform_fraction: float) -> CorpusBatch:
        """``size`` samples, proxies uniform at random, pairs by :func:`sample_proxy_directions`."""
        material = rng.integers(0, len(self), size=size)
        wi, wo = sample_proxy_directions(rng, size, uniform_fraction)
        return CorpusBatch(material, wi, wo, self.evaluate(material, wi, wo))
