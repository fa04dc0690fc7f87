"""Auto-decoder pretraining of the NLB representation network (docs/models.md#nlb; Fan et al. 2022).

The network weights (:class:`~neuralbrdf.models.nlb.NlbNetwork`) and one latent per corpus
material (:class:`~neuralbrdf.models.nlb.LatentTable`, all initialised to ``latent_init``) are
optimised jointly on batches of :mod:`neuralbrdf.lightning.corpus_data`, as in Fan et al.: L1
loss, Adam, learning rate ×0.9 per epoch (the optimiser and the scheduler come from the config).

**Loss domain** (``loss_domain``).  Fan et al. take the L1 distance of raw BRDF values
(``"linear"``).  The default, ``"log_cosine"``, is the L1 distance of ``ln(1 + f cos θi)``:
the quantity of the hemisphere log-cosine RMSE (docs/evaluate.md#metrics) and of Löw et al.'s fitting loss
(report Eq. 4.2), so training and evaluation agree.  Over this corpus, whose values span
10⁻⁴ to 10⁷ sr⁻¹ (sharp peaks, grazing ABC tails), the raw L1 does not train: its per-sample
gradient through the output scales with the predicted value, so the few bright samples drive
every update; the comparison that decided it is in ``benchmarks/README.md`` (design
measurements).  Both L1s are
logged on the validation batches (``val/l1_logcos``, ``val/l1_linear``) whichever is trained,
with ``val/logcos_rmse`` (the metric of docs/evaluate.md#metrics over the validation samples; under DDP the
per-process mean squares are averaged, weighted by count).

:func:`load_pretrained` reads a checkpoint of this module back as a plain network and latent
table, which is how the latent fit (:mod:`neuralbrdf.lightning.latent_fit_module`) and the
exporters use it; :func:`save_pretrained` writes one without the training state (the optimiser's
moments triple a checkpoint's size), which is how the shipped files are made.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, replace
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
from neuralbrdf.models.nlb import COMPACT, LatentTable, NlbConfig, NlbNetwork, resize_latent

class NlbPretrainModule(AutoDecoderPretraining):
    """Joint training of the NLB network and the corpus latents (module docstring).

    Parameters
    ----------
    n_materials:
        Rows of the latent table; must equal the data module's corpus size.
    latent_dim, width, depth, residual, half_vector:
        The network's architecture (:class:`~neuralbrdf.models.nlb.NlbConfig`).
    latent_init:
        Constant every latent starts from (Fan et al.).
    latent_lr_scale:
        Learning rate of the latents relative to the network's.
    loss_domain:
        ``"log_cosine"`` (default) or ``"linear"`` (Fan et al.'s raw L1).
    warm_start:
        A pretraining checkpoint of the same architecture to continue from: its network
        weights, and its latents for the materials of the same name (unnamed checkpoints:
        the first rows, the analytic materials); the other latents start at its centroid.
        A checkpoint that differs only in ``latent_dim`` is first re-expressed at this
        module's latent size (:func:`~neuralbrdf.models.nlb.resize_latent`: principal
        components when smaller, zero padding when larger).
    optimizer, lr_scheduler:
        Factories from the config; the scheduler steps once per epoch.
    """

    def __init__(
        self,
        n_materials: int = 1024,
        latent_dim: int = COMPACT.latent_dim,
        width: int = COMPACT.width,
        depth: int = COMPACT.depth,
        residual: bool = COMPACT.residual,
        half_vector: bool = COMPACT.half_vector,
        latent_init: float = 0.0,
        latent_lr_scale: float = 1.0,
        loss_domain: str = "log_cosine",
        warm_start: str | None = None,
        optimizer: OptimizerCallable = torch.optim.Adam,
        lr_scheduler: LRSchedulerCallable | None = None,
    ) -> None:
        super().__init__(optimizer, lr_scheduler, loss_domain, latent_lr_scale)
        self.save_hyperparameters(ignore=["optimizer", "lr_scheduler"])
        self.network = NlbNetwork(latent_dim, width, depth, residual, half_vector)
        self.latents = LatentTable(n_materials, latent_dim, latent_init)

    def _warm_start(self, names: list[str]) -> None:
        """Copy the network and the matching latents of ``hparams.warm_start`` (class docstring)."""
        path = self.hparams.warm_start
        previous = load_pretrained(path)
        if replace(previous.network.config, latent_dim=self.network.latent_dim) != self.network.config:
            raise InputError(f"warm start from a {previous.network.config} network into a {self.network.config} one",
                             path=path)
        if previous.network.latent_dim != self.network.latent_dim:
            generator = torch.Generator().manual_seed(0)
            network, latents = resize_latent(previous.network, previous.latents, self.network.latent_dim, generator)
            previous = PretrainedNlb(network, latents, previous.source, previous.names)
        self.network.load_state_dict(previous.network.state_dict())
        known = previous.names or tuple(f"analytic:{i}" for i in range(len(previous.latents)))
        rows = {name: i for i, name in enumerate(known)}
        with torch.no_grad():
            self.latents.latents.copy_(previous.latent_mean.expand_as(self.latents.latents))
            for i, name in enumerate(names):
                if name in rows:
                    self.latents.latents[i] = previous.latents[rows[name]]

    def forward(self, batch: CorpusSamples) -> torch.Tensor:
        return self.network(batch.wi, batch.wo, self.latents(batch.material))


@dataclass(frozen=True)
class PretrainedNlb:
    """A pretrained NLB: the ``network`` (eval mode) and its corpus ``latents`` ``[M, latent_dim]``.

    ``names`` label the latents (``analytic:<i>``, ``merl:<name>``); empty for checkpoints
    written before the names were stored.
    """

    network: NlbNetwork
    latents: torch.Tensor
    source: str
    names: tuple[str, ...] = ()

    @property
    def latent_mean(self) -> torch.Tensor:
        """Centroid ``[latent_dim]`` of the corpus latents."""
        return self.latents.mean(0)


def load_pretrained(path: str | os.PathLike[str]) -> PretrainedNlb:
    """Network and latents of an :class:`NlbPretrainModule` checkpoint (``.ckpt``).

    Raises :class:`InputError` when the file is missing or is not such a checkpoint.
    """
    path = Path(path)
    checkpoint, hparams, state = read_pretraining_checkpoint(path, "pretrained NLB checkpoint")
    try:
        config = NlbConfig(*(hparams[k] for k in ("latent_dim", "width", "depth", "residual", "half_vector")))
        latents = state["latents.latents"].float()
    except KeyError as exc:
        raise InputError(f"not an NLB pretraining checkpoint: missing {exc.args[0]!r}", path=path) from None
    network = network_from_state(lambda: NlbNetwork(**asdict(config)), state, path)
    names = material_names(checkpoint, len(latents), "latents", path)
    return PretrainedNlb(network, latents, str(path), names)


def save_pretrained(pretrained: PretrainedNlb, path: str | os.PathLike[str]) -> Path:
    """Write ``pretrained`` as a checkpoint that :func:`load_pretrained` and a warm start read:
    the weights, the architecture (and the module's class path, from which Lightning rebuilds it for
    ``--ckpt_path``) and the latents' names, no optimiser or loop state.
    Written atomically (a failed write leaves no file)."""
    state = {f"network.{k}": v.detach().clone() for k, v in pretrained.network.state_dict().items()}
    state["latents.latents"] = pretrained.latents.detach().clone()
    hyper_parameters = {**asdict(pretrained.network.config), "n_materials": len(pretrained.latents)}
    return write_pretraining_checkpoint(NlbPretrainModule, hyper_parameters, state, pretrained.names, path)
