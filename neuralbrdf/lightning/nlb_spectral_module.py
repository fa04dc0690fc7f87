"""Auto-decoder pretraining of the spectral NLB network (docs/models.md#spectral-nlb; :mod:`neuralbrdf.models.nlb_spectral`).

The channel-agnostic decoder and the codes of every corpus material — one shared code and one
channel code per colour channel — are optimised jointly on the batches of
:mod:`neuralbrdf.lightning.corpus_data` (the analytic corpus and the measured proxies of one or
more labs), exactly as :class:`~neuralbrdf.lightning.nlb_module.NlbPretrainModule` trains the
RGB network (:class:`~neuralbrdf.lightning.auto_decoder.AutoDecoderPretraining`: L1 of
``ln(1 + f cos θi)``, Adam, a learning rate decaying per epoch, checkpoints chosen on the
validation directions of the training materials).  Each RGB channel of a training material is a
monochrome BRDF of its own: the decoder never sees which colour it decodes, only the channel
code, which is what lets a fit give it wavelength bands instead (:mod:`~neuralbrdf.lightning.nlb_spectral_fit`).

:func:`load_spectral_pretrained` reads a checkpoint of this module back as the network and its
codes; :func:`save_spectral_pretrained` writes one without the training state (how the shipped
file is made).
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from pytorch_lightning.cli import LRSchedulerCallable, OptimizerCallable

from neuralbrdf.errors import InputError
from neuralbrdf.lightning.auto_decoder import (
    AutoDecoderPretraining,
    material_names,
    network_from_state,
    read_pretraining_checkpoint,
    write_pretraining_checkpoint,
)
from neuralbrdf.lightning.corpus_data import CorpusSamples
from neuralbrdf.models.nlb_spectral import SpectralLatentTable, SpectralNlbConfig, SpectralNlbNetwork

#: Colour channels of the corpus materials (one channel code each).
CORPUS_CHANNELS = 3
_DEFAULT = SpectralNlbConfig()


class SpectralNlbPretrainModule(AutoDecoderPretraining):
    """Joint training of the spectral NLB decoder and the corpus codes (module docstring).

    Parameters
    ----------
    n_materials:
        Materials of the corpus; must equal the data module's.
    shared_dim, channel_dim, width, depth, channel_layer, half_vector:
        The network's architecture (:class:`~neuralbrdf.models.nlb_spectral.SpectralNlbConfig`).
    latent_init:
        Constant every code starts from (Fan et al.).
    latent_lr_scale:
        Learning rate of the codes relative to the network's.
    loss_domain:
        ``"log_cosine"`` (default) or ``"linear"``.
    warm_start:
        A checkpoint of this module with the same architecture to continue from: its network,
        and its codes for the materials of the same name (the others start at its centroid).
    optimizer, lr_scheduler:
        Factories from the config; the scheduler steps once per epoch.
    """

    def __init__(
        self,
        n_materials: int = 1024,
        shared_dim: int = _DEFAULT.shared_dim,
        channel_dim: int = _DEFAULT.channel_dim,
        width: int = _DEFAULT.width,
        depth: int = _DEFAULT.depth,
        channel_layer: int = _DEFAULT.channel_layer,
        half_vector: bool = _DEFAULT.half_vector,
        latent_init: float = 0.0,
        latent_lr_scale: float = 1.0,
        loss_domain: str = "log_cosine",
        warm_start: str | None = None,
        optimizer: OptimizerCallable = torch.optim.Adam,
        lr_scheduler: LRSchedulerCallable | None = None,
    ) -> None:
        super().__init__(optimizer, lr_scheduler, loss_domain, latent_lr_scale)
        self.save_hyperparameters(ignore=["optimizer", "lr_scheduler"])
        self.network = SpectralNlbNetwork(shared_dim, channel_dim, width, depth, channel_layer, half_vector)
        self.latents = SpectralLatentTable(n_materials, shared_dim, channel_dim, CORPUS_CHANNELS, latent_init)

    def forward(self, batch: CorpusSamples) -> torch.Tensor:
        shared, channels = self.latents(batch.material)
        return self.network(batch.wi, batch.wo, shared, channels)

    def _warm_start(self, names: list[str]) -> None:
        path = self.hparams.warm_start
        previous = load_spectral_pretrained(path)
        if previous.network.config != self.network.config:
            raise InputError(f"warm start from a {previous.network.config} network into a {self.network.config} one",
                             path=path)
        self.network.load_state_dict(previous.network.state_dict())
        rows = {name: i for i, name in enumerate(previous.names)}
        with torch.no_grad():
            self.latents.shared.copy_(previous.shared.mean(0).expand_as(self.latents.shared))
            self.latents.channels.copy_(previous.channels.mean(0).expand_as(self.latents.channels))
            for i, name in enumerate(names):
                if name in rows:
                    self.latents.shared[i] = previous.shared[rows[name]]
                    self.latents.channels[i] = previous.channels[rows[name]]


@dataclass(frozen=True)
class PretrainedSpectralNlb:
    """A pretrained spectral NLB: the ``network`` (eval mode), the corpus codes — ``shared``
    ``[M, shared_dim]`` and ``channels`` ``[M, 3, channel_dim]`` — and their material ``names``."""

    network: SpectralNlbNetwork
    shared: torch.Tensor
    channels: torch.Tensor
    source: str
    names: tuple[str, ...] = ()

    @property
    def channel_codes(self) -> torch.Tensor:
        """Every channel code of the corpus, ``[3 M, channel_dim]``."""
        return self.channels.reshape(-1, self.channels.shape[-1])


def load_spectral_pretrained(path: str | os.PathLike[str]) -> PretrainedSpectralNlb:
    """Network and codes of a :class:`SpectralNlbPretrainModule` checkpoint, else :class:`InputError`."""
    path = Path(path)
    checkpoint, hparams, state = read_pretraining_checkpoint(path, "pretrained spectral NLB checkpoint")
    try:
        config = SpectralNlbConfig(*(hparams[f.name] for f in SpectralNlbConfig.__dataclass_fields__.values()))
        shared, channels = state["latents.shared"].float(), state["latents.channels"].float()
    except KeyError as exc:
        raise InputError(f"not a spectral NLB pretraining checkpoint: missing {exc.args[0]!r}", path=path) from None
    except InputError as error:
        raise InputError(f"invalid architecture: {error.reason}", path=path, column=error.column, key=error.key) from None
    network = network_from_state(lambda: SpectralNlbNetwork(**asdict(config)), state, path)
    if shared.ndim != 2 or channels.ndim != 3 or len(shared) != len(channels) \
            or shared.shape[1] != config.shared_dim or channels.shape[2] != config.channel_dim:
        raise InputError(f"codes of shapes {list(shared.shape)} and {list(channels.shape)} do not fit {config}",
                         path=path)
    names = material_names(checkpoint, len(shared), "codes", path)
    return PretrainedSpectralNlb(network, shared, channels, str(path), names)


def save_spectral_pretrained(pretrained: PretrainedSpectralNlb, path: str | os.PathLike[str]) -> Path:
    """Write ``pretrained`` as a checkpoint that :func:`load_spectral_pretrained` and a warm start
    read (weights, architecture, class path, names; no optimiser state), atomically."""
    state = {f"network.{k}": v.detach().clone() for k, v in pretrained.network.state_dict().items()}
    state["latents.shared"] = pretrained.shared.detach().clone()
    state["latents.channels"] = pretrained.channels.detach().clone()
    hyper_parameters = {**asdict(pretrained.network.config), "n_materials": len(pretrained.shared)}
    return write_pretraining_checkpoint(SpectralNlbPretrainModule, hyper_parameters, state, pretrained.names, path)
