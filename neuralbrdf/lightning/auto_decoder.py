"""What the two auto-decoder pretrainings — the NLB (:mod:`~neuralbrdf.lightning.nlb_module`) and the
spectral NLB (:mod:`~neuralbrdf.lightning.nlb_spectral_module`) — share: the LightningModule base
:class:`AutoDecoderPretraining` (loss, validation metrics, optimiser), and the reading and writing of
their pretrained checkpoints (weights, architecture, class path and the latents' material names,
no training state).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytorch_lightning as pl
import torch
from pytorch_lightning.cli import LRSchedulerCallable, OptimizerCallable

from neuralbrdf import metrics
from neuralbrdf.checkpoints import check_weights_match, read_checkpoint, write_checkpoint
from neuralbrdf.errors import InputError
from neuralbrdf.lightning.common import scheduled_optimizer
from neuralbrdf.lightning.corpus_data import CorpusSamples
from neuralbrdf.losses import check_loss_domain, nlb_loss

NETWORK_PREFIX = "network."


class AutoDecoderPretraining(pl.LightningModule):
    """What every auto-decoder pretraining shares (:mod:`neuralbrdf.lightning.nlb_module`): the
    checks of ``loss_domain`` and ``latent_lr_scale``, the loss, the validation metrics, the
    corpus-size check, the material names stored in checkpoints and the optimiser.

    Subclasses build ``self.network`` and ``self.latents`` (a module holding every material's
    codes, ``len()`` the number of materials), compute a batch's prediction in ``forward`` and
    continue a previous run in ``_warm_start(names)``; their hyper-parameters include
    ``loss_domain``, ``latent_lr_scale`` and ``warm_start``.
    """

    def __init__(self, optimizer: OptimizerCallable, lr_scheduler: LRSchedulerCallable | None,
                 loss_domain: str, latent_lr_scale: float) -> None:
        super().__init__()
        check_loss_domain(loss_domain)
        if not latent_lr_scale > 0:
            raise InputError(f"must be positive, got {latent_lr_scale}", key="latent_lr_scale")
        self.optimizer_factory = optimizer
        self.lr_scheduler_factory = lr_scheduler
        self._val_sums: list[torch.Tensor] = []
        self.material_names: list[str] = []

    def _warm_start(self, names: list[str]) -> None:
        raise NotImplementedError

    def setup(self, stage: str) -> None:
        data = getattr(self.trainer, "datamodule", None)
        corpus_size = getattr(data, "n_materials", None)
        if corpus_size is not None and corpus_size != len(self.latents):
            raise InputError(
                f"the model has {len(self.latents)} latents but the corpus has {corpus_size} materials "
                "(analytic + measured proxies and their blends); set model.n_materials to that",
                key="model.n_materials",
            )
        self.material_names = list(getattr(data, "material_names", ()))
        if self.hparams.warm_start and stage == "fit":
            self._warm_start(self.material_names)

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        """Store the latents' material names (``analytic:<i>``, ``merl:<name>``, …), when known."""
        if self.material_names:
            checkpoint["material_names"] = self.material_names

    def training_step(self, batch: CorpusSamples, batch_idx: int) -> torch.Tensor:
        loss = nlb_loss(self(batch), batch.f, batch.wi, self.hparams.loss_domain)
        self.log("train/loss", loss, on_step=True, on_epoch=True, batch_size=len(batch.f), sync_dist=True)
        return loss

    def validation_step(self, batch: CorpusSamples, batch_idx: int) -> None:
        pred = self(batch)
        n = len(batch.f)
        for domain, name in (("log_cosine", "l1_logcos"), ("linear", "l1_linear")):
            self.log(f"val/{name}", nlb_loss(pred, batch.f, batch.wi, domain), batch_size=n, sync_dist=True)
        theta_i = torch.rad2deg(torch.acos(batch.wi[:, 2].clamp(-1.0, 1.0)))
        rmse = metrics.hemisphere_logcos_rmse(pred, batch.f, theta_i)
        self._val_sums.append(torch.tensor([rmse * rmse * n, n], dtype=torch.float64, device=pred.device))

    def on_validation_epoch_end(self) -> None:
        if not self._val_sums:
            return
        sums = torch.stack(self._val_sums).sum(0)
        self._val_sums.clear()
        sums = self.trainer.strategy.reduce(sums, reduce_op="sum")
        self.log("val/logcos_rmse", torch.sqrt(sums[0] / sums[1]).float())

    def configure_optimizers(self):
        groups = [(self.network.parameters(), 1.0), (self.latents.parameters(), self.hparams.latent_lr_scale)]
        return scheduled_optimizer(groups, self.optimizer_factory, self.lr_scheduler_factory, "epoch")


def read_pretraining_checkpoint(path: Path, what: str) -> tuple[dict, dict, dict]:
    """The checkpoint at ``path``, its hyper-parameters and its state dict, else :class:`InputError`
    (``what`` names the expected file)."""
    checkpoint = read_checkpoint(path, what)
    hparams, state = checkpoint.get("hyper_parameters"), checkpoint.get("state_dict")
    if not isinstance(hparams, dict) or not isinstance(state, dict):
        raise InputError("not a Lightning checkpoint (no state_dict / hyper_parameters)", path=path)
    return checkpoint, hparams, state


def network_from_state(build, state: dict, path: Path) -> torch.nn.Module:
    """``build()`` with the ``network.*`` weights of ``state`` loaded, in eval mode; weights that do
    not fit the architecture are an :class:`InputError`."""
    check_weights_match(build, state, path, NETWORK_PREFIX)
    network = build()
    try:
        network.load_state_dict({k[len(NETWORK_PREFIX):]: v for k, v in state.items() if k.startswith(NETWORK_PREFIX)})
    except RuntimeError as exc:
        raise InputError(f"network weights do not match its hyper-parameters: {exc}", path=path) from None
    return network.eval()


def material_names(checkpoint: dict, rows: int, noun: str, path: Path) -> tuple[str, ...]:
    """The material names a checkpoint stores for its ``rows`` latents (``noun``: what the messages call
    them); empty for checkpoints written before names were stored."""
    names = tuple(str(n) for n in checkpoint.get("material_names", ()))
    if names and len(names) != rows:
        raise InputError(f"{len(names)} material names for {rows} {noun}", path=path)
    return names


def write_pretraining_checkpoint(module: type, hyper_parameters: dict, state: dict, names,
                                 path: str | os.PathLike[str]) -> Path:
    """Write a checkpoint of the pretraining ``module`` that its loader and a warm start read: the
    weights and latents ``state``, the ``hyper_parameters`` (architecture, ``n_materials``) with the
    module's class path (from which Lightning rebuilds it for ``--ckpt_path``) and the latents'
    ``names``; no optimiser or loop state.  Written atomically (a failed write leaves no file)."""
    path = Path(path)
    class_path = f"{module.__module__}.{module.__qualname__}"
    checkpoint = {"state_dict": state, "pytorch-lightning_version": pl.__version__,
                  "hyper_parameters": {**hyper_parameters, "_class_path": class_path},
                  "material_names": list(names)}
    write_checkpoint(checkpoint, path)
    return path
