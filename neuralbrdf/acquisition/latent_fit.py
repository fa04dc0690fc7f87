"""The spectral NLB's latent fit of one measurement, in process: what ``plan next`` fits and linearises (docs/how-many-measurements.md).

``neuralbrdf train fit --config nlb_spectral`` runs its fit through Lightning and writes a run
folder.  Deciding what to measure next needs the fitted codes at once, many times in a session
and without files, so :func:`fit_table` builds the same
:class:`~neuralbrdf.lightning.nlb_spectral_fit.SpectralLatentFitModule` from the same config
(its ``model.init_args``; ``overrides`` change single keys) and runs its small-fit path
(:meth:`~neuralbrdf.lightning.nlb_spectral_fit.SpectralLatentFitModule.fit_samples`: screened
starts, then one L-BFGS run): the codes ``train fit`` reaches for a table of up to
``data.full_batch_values`` values (a spectral DS1 measurement), which every table of a session
that measures a fraction of the pairs is.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from neuralbrdf.data.table import BrdfTable
from neuralbrdf.lightning.config_models import spectral_latent_fit
from neuralbrdf.lightning.latent_fit_data import FitSamples, table_samples as _samples
from neuralbrdf.lightning.nlb_spectral_fit import SpectralLatentFitModule
from neuralbrdf.models.directional import SpectralNlbWithCodes
from neuralbrdf.models.nlb_spectral import SpectralNlbNetwork

#: The shipped config of the fit.
FIT_CONFIG = "nlb_spectral"


@dataclass(frozen=True)
class FittedCodes:
    """One material fitted by the spectral NLB: the frozen ``network``, its ``shared`` code ``[ds]``
    and node codes ``[n_nodes, dc]`` (R, G, B for an RGB fit), the nodes' wavelengths (``None``:
    RGB), the ``interpolation`` ``[channels, n_nodes]`` from nodes to the measured channels, each
    channel's ``scale`` (the mean ``ln(1 + f cos θi)`` of its samples, the fit's normaliser) and
    the fit's final ``loss``."""

    name: str
    network: SpectralNlbNetwork
    shared: torch.Tensor
    nodes: torch.Tensor
    node_wavelengths_nm: tuple[float, ...] | None
    interpolation: torch.Tensor
    scale: torch.Tensor
    loss: float

    @property
    def parameters(self) -> torch.Tensor:
        """The codes as one vector ``[ds + n_nodes · dc]``: shared code first, then the node codes."""
        return torch.cat([self.shared, self.nodes.reshape(-1)])

    def model(self) -> SpectralNlbWithCodes:
        """The fitted material as a function of directions (and wavelengths): the exported graph's module."""
        return SpectralNlbWithCodes(self.network, self.shared, self.nodes, self.node_wavelengths_nm)


def fit_module(config: str = FIT_CONFIG, overrides: Mapping[str, Any] | None = None) -> SpectralLatentFitModule:
    """A fresh :class:`SpectralLatentFitModule` of ``config`` with ``overrides`` of its ``model.init_args``
    (:func:`~neuralbrdf.lightning.config_models.spectral_latent_fit`)."""
    return spectral_latent_fit(config, overrides)


def table_samples(table: BrdfTable) -> FitSamples:
    """A table's samples as a spectral fit sees them (band by band) or an RGB one (per channel)."""
    return _samples(0, table, table.is_spectral)


def fit_table(table: BrdfTable, name: str = "material", *, config: str = FIT_CONFIG,
              overrides: Mapping[str, Any] | None = None, module: SpectralLatentFitModule | None = None) -> FittedCodes:
    """Fit ``table`` (module docstring); ``module``: a :func:`fit_module` to reuse (its network
    and start candidates are loaded once for a whole session)."""
    module = module or fit_module(config, overrides)
    samples = table_samples(table)
    wavelengths = None if not table.is_spectral else np.asarray(table.wavelengths, dtype=np.float64)
    losses = module.fit_samples([name], samples, wavelengths)
    nodes = module.node_wavelengths_nm
    return FittedCodes(name, module.network, module.latents.shared[0].detach().clone(),
                       module.latents.channels[0].detach().clone(),
                       None if nodes is None else tuple(float(w) for w in nodes),
                       module._interpolation.clone(), module._channel_scale[0].clone(), float(losses[0]))
