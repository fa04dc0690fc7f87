"""Latent-only fitting of new materials on a frozen NLB network (SPEC §4.3; report §4.2).

As in Fan et al. (2022) and the report: load the pretrained network
(:func:`~neuralbrdf.lightning.nlb_module.load_pretrained`), freeze every weight, and optimise
only one latent per material with an L1 loss, Adam and an exponentially decaying learning rate
(config ``optimizer``/``lr_scheduler``, stepped every step).  Many materials are fitted at once:
one latent table, every material's samples in one full batch per step (or, for very large
plans, a random subset of ``data.batch_size`` samples per step).

The L1 is taken on ``ln(1 + f cos θi)`` by default (``loss_domain``, as in pretraining,
:mod:`~neuralbrdf.lightning.nlb_module`; it fitted better than the raw L1, (``benchmarks/README.md``, design measurements)).
The report's recipe is ``loss_domain: linear``, ``init_candidates: 0``,
``early_stop_patience: null`` (``configs/nlb_latent_report.yaml``).

**Start** (``init_candidates``).  With 0, every latent starts at the centroid of the
pretrained ones.  Otherwise each material starts from the pretrained code, among the centroid,
every MERL proxy code and ``init_candidates`` analytic codes (evenly spaced in the table), with
the lowest loss on its own fitting samples: a start already near the material, so a few
hundred steps suffice and fits do not end in the centroid's basin.  The code with the lowest
loss *at the start* is not always the one whose basin fits best (measured: from the centroid
some metals ended with a third less in-plane loss), so with ``init_starts`` S > 1 the centroid
and the S − 1 best codes are each optimised for ``init_screen_steps`` steps (the config's
optimiser, all materials and starts at once) and each material continues from the start with
the lowest loss after them (on at most :data:`SCREEN_SAMPLES` of its samples).  Selection uses
the fitting samples only, never the truth.

**Latent prior** (``latent_prior_weight``, ``latent_prior_codes``).  Each material's loss gets
``latent_prior_weight · P(z)``, the negative log-density per dimension of a Gaussian fitted to
pretrained codes (:mod:`neuralbrdf.models.latent_prior`): a MAP fit that keeps the code among
those the network learned.  ``latent_prior_codes: measured`` fits the Gaussian to the codes of
the measured materials (``merl:``) and their blends (``merl-blend:``,
:mod:`neuralbrdf.data.proxy_corpus`); ``all`` to every code, the analytic corpus included.
Screening and the fit minimise the same loss.  Measured on the held-out MERL materials in the
README (*NLB latent prior*).

**Early stopping** (``early_stop_patience``).  The fit stops when the training loss has not
improved by a relative ``early_stop_tolerance`` for that many steps.

**The fit's last step is always evaluated** (:class:`ValidateFinalStep`): validation runs after
the final step (the last epoch, or an early stop) whatever ``check_val_every_n_epoch`` is, so
the metrics logged last — and ``checkpoints/fitted.ckpt``, saved at the end of validation —
describe the latents the fit ends with.

**Sources**: :class:`~neuralbrdf.lightning.latent_fit_data.LatentFitData` (the vocabulary of
:mod:`neuralbrdf.sources`).

**Metrics** (logged at every validation, so ``metrics.json`` holds the final values under
``fit/``):

* ``fit_logcos_rmse/<name>`` — the hemisphere log-cosine RMSE (SPEC §5) of the fit on the
  material's own fitting samples;
* for NBRDF sources, ``hemisphere_logcos_rmse/<name>`` — the same metric against the proxy on
  ``eval_plan`` (default the Löw et al. set, SPEC §3): how well the fit generalises;
* and, when ``low2012_abc`` lists the proxy's material, ``abc_low2012/hemisphere_logcos_rmse/<name>``
  — Löw et al.'s published full-data ABC fit (SPEC §2.4) on the same plan, the reference to beat;
* ``hemisphere_logcos_rmse/mean`` over the NBRDF sources.

The frozen weights are checked bit for bit against the checkpoint at the end of every fit
(:meth:`LatentFitModule.on_fit_end`).  A checkpoint of this module is a self-contained fitted
material set — the network, the latents and their names — read back by :func:`neuralbrdf.kinds.nlb.load_fitted`
(e.g. for export).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict

import numpy as np
import pytorch_lightning as pl
import torch
from pytorch_lightning.cli import LRSchedulerCallable, OptimizerCallable

from neuralbrdf import metrics
from neuralbrdf.errors import InputError
from neuralbrdf.lightning.common import WritesKind, scheduled_optimizer
from neuralbrdf.lightning.latent_fit_data import EvalSet, FitSamples
from neuralbrdf.lightning.nlb_module import PretrainedNlb, load_pretrained
from neuralbrdf.losses import check_loss_domain, log_cosine, nlb_loss
from neuralbrdf.models.latent_prior import gaussian_of_codes, latent_prior_penalty
from neuralbrdf.models.nlb import LatentTable
from neuralbrdf.shipped import resolve_pretrained

#: How the default checkpoint is made (for the error message when it is missing; README, *Latent 32 from
#: scratch with proxy blends*).
PRETRAIN_COMMAND = ("python train.py fit --config configs/nlb_pretrain.yaml --model.latent_dim 32 "
                    "--data.proxy_blends 1024 --model.n_materials 5155")

#: Name prefixes of the pretrained codes of measured materials (:attr:`ProxyMaterials.material_names`).
MEASURED_PREFIXES = ("merl:", "merl-blend:")
#: Values of ``latent_prior_codes``: the codes the prior's Gaussian is fitted to (module docstring).
PRIOR_CODES = ("measured", "all")

#: At most this many of the fitting samples (a fixed random subset) take part in the screening of starts.
SCREEN_SAMPLES = 65536


def _theta_i_deg(wi: torch.Tensor) -> torch.Tensor:
    return torch.rad2deg(torch.acos(wi[:, 2].clamp(-1.0, 1.0)))


class LatentFitModule(WritesKind, pl.LightningModule):
    """Optimises one latent per material on a frozen pretrained NLB network (module docstring).

    Parameters
    ----------
    checkpoint:
        :class:`~neuralbrdf.lightning.nlb_module.NlbPretrainModule` checkpoint, or the name of
        a shipped one (``nlb_compact``, ``nlb_64x4``, …); ``None``: the default
        (:data:`~neuralbrdf.shipped.PRETRAINED_DEFAULT`).
    latent_init:
        Constant every latent starts from; ``None``: the centroid of the pretrained corpus
        latents.
    loss_domain:
        ``"log_cosine"`` (L1 of ``ln(1 + f cos θi)``) or ``"linear"`` (raw L1, as Fan et al.).
    init_candidates:
        Analytic pretrained codes tried as starts besides the centroid and the MERL codes
        (module docstring); 0: start at ``latent_init``.
    init_starts:
        Starts screened per material (module docstring); 1: the best code alone.
    init_screen_steps:
        Optimiser steps of the screening of ``init_starts`` > 1 starts.
    early_stop_patience:
        Steps without a relative loss improvement of ``early_stop_tolerance`` after which
        the fit stops; ``None``: run every step.
    latent_prior_weight:
        Weight of the latent prior ``P(z)`` in each material's loss (module docstring); 0: none
        (this class's default; ``configs/nlb_latent.yaml`` sets 0.01, chosen for the default network).
    latent_prior_codes:
        The pretrained codes the prior's Gaussian is fitted to: ``"measured"`` or ``"all"``.
    optimizer, lr_scheduler:
        Factories from the config; the scheduler steps every step.
    """

    def __init__(
        self,
        checkpoint: str | None = None,
        latent_init: float | None = None,
        loss_domain: str = "log_cosine",
        init_candidates: int = 0,
        init_starts: int = 1,
        init_screen_steps: int = 100,
        early_stop_patience: int | None = None,
        early_stop_tolerance: float = 1e-3,
        latent_prior_weight: float = 0.0,
        latent_prior_codes: str = "all",
        optimizer: OptimizerCallable = torch.optim.Adam,
        lr_scheduler: LRSchedulerCallable | None = None,
    ) -> None:
        super().__init__()
        check_loss_domain(loss_domain, "model.loss_domain")
        if not isinstance(init_candidates, int) or init_candidates < 0:
            raise InputError(f"must be a non-negative integer, got {init_candidates!r}", column="model.init_candidates")
        for key, value in (("init_starts", init_starts), ("init_screen_steps", init_screen_steps)):
            if not isinstance(value, int) or value < 1:
                raise InputError(f"must be a positive integer, got {value!r}", column=f"model.{key}")
        if init_starts > 1 and not init_candidates:
            raise InputError("several starts need start candidates (model.init_candidates > 0)",
                             column="model.init_starts")
        if init_candidates and latent_init is not None:
            raise InputError("latent_init and init_candidates exclude each other", column="model.init_candidates")
        if early_stop_patience is not None and (not isinstance(early_stop_patience, int) or early_stop_patience < 1):
            raise InputError(f"must be a positive integer or null, got {early_stop_patience!r}",
                             column="model.early_stop_patience")
        if not early_stop_tolerance >= 0:
            raise InputError(f"must be non-negative, got {early_stop_tolerance}", column="model.early_stop_tolerance")
        if isinstance(latent_prior_weight, bool) or not (isinstance(latent_prior_weight, (int, float))
                                                         and math.isfinite(latent_prior_weight)
                                                         and latent_prior_weight >= 0):
            raise InputError(f"must be a finite non-negative number, got {latent_prior_weight!r}",
                             column="model.latent_prior_weight")
        if latent_prior_codes not in PRIOR_CODES:
            raise InputError(f"must be one of {', '.join(PRIOR_CODES)}, got {latent_prior_codes!r}",
                             column="model.latent_prior_codes")
        path = resolve_pretrained(checkpoint)
        if checkpoint is None and not path.is_file():
            raise InputError(f"the default pretrained NLB checkpoint is missing; make it with `{PRETRAIN_COMMAND}`, "
                             "save its checkpoints/best.ckpt there with neuralbrdf.lightning.nlb_module.save_pretrained, "
                             "or set model.checkpoint", path=path)
        self.save_hyperparameters(ignore=["optimizer", "lr_scheduler"])
        pretrained = load_pretrained(path)
        # Frozen by requires_grad alone: nothing in the network depends on train/eval mode.
        self.network = pretrained.network.requires_grad_(False).train()
        self._frozen_reference = {k: v.clone() for k, v in self.network.state_dict().items()}
        start = pretrained.latent_mean
        self._start = start if latent_init is None else torch.full_like(start, latent_init)
        self._candidates = start_candidates(pretrained, init_candidates) if init_candidates else None
        self._pretrained_name = path.name
        # Buffers (not saved): they move with the module to the fit's device.
        prior = gaussian_of_codes(prior_codes(pretrained, latent_prior_codes, path)) if latent_prior_weight else (None, None)
        self.register_buffer("_prior_mean", prior[0], persistent=False)
        self.register_buffer("_prior_precision", prior[1], persistent=False)
        self._best_loss = math.inf
        self._steps_since_best = 0
        self.latents: LatentTable | None = None
        self.optimizer_factory = optimizer
        self.lr_scheduler_factory = lr_scheduler
        self.material_names: list[str] = []

    def build_latents(self, names: Sequence[str]) -> None:
        """One latent per material, all at the starting point."""
        self.material_names = list(names)
        self.latents = LatentTable(len(names), self.network.latent_dim, 0.0, names)
        with torch.no_grad():
            self.latents.latents.copy_(self._start.expand(len(names), -1))

    def setup(self, stage: str) -> None:
        if self.latents is None:
            data = getattr(self.trainer, "datamodule", None)
            if data is None or not hasattr(data, "material_names"):
                raise InputError("the latent fit needs a LatentFitData data module (data.class_path)", column="data")
            self.build_latents(data.material_names)
            if self._candidates is not None:
                self.choose_starts(data.train_samples)

    def _material_losses(self, samples: FitSamples, codes: torch.Tensor) -> torch.Tensor:
        """Loss of each material's samples under ``codes`` ``[S, n, d]`` (S codes per material): ``[S, n]``."""
        n_starts, n = codes.shape[:2]
        pred = self.network(samples.wi.repeat(n_starts, 1), samples.wo.repeat(n_starts, 1),
                            codes[:, samples.material].reshape(-1, codes.shape[-1])).reshape(n_starts, -1, 3)
        target = samples.f
        if self.hparams.loss_domain == "log_cosine":
            cos_i = samples.wi[:, 2]
            pred, target = log_cosine(pred.reshape(-1, 3), cos_i.repeat(n_starts)).reshape(n_starts, -1, 3), \
                log_cosine(target, cos_i)
        error = (pred - target).abs().mean(2)
        counts = torch.zeros(n).index_add_(0, samples.material, torch.ones(len(samples.material)))
        return torch.zeros(n_starts, n).index_add_(1, samples.material, error) / counts + self._prior_terms(codes)

    def _prior_terms(self, codes: torch.Tensor) -> torch.Tensor | float:
        """``latent_prior_weight · P(z)`` of each code ``[..., d]``: ``[...]`` (0 without a prior)."""
        if self._prior_mean is None:
            return 0.0
        return self.hparams.latent_prior_weight * latent_prior_penalty(codes, self._prior_mean, self._prior_precision)

    def choose_starts(self, samples: FitSamples) -> None:
        """Set each material's latent to its best start (module docstring)."""
        n = len(self.material_names)
        with torch.no_grad():
            losses = torch.cat([self._material_losses(samples, code.expand(1, n, -1)) for code in self._candidates])
        starts = self.hparams.init_starts
        if starts == 1:
            with torch.no_grad():
                self.latents.latents.copy_(self._candidates[losses.argmin(0)])
            return
        # The centroid (candidate 0) and the best starts - 1 other codes, optimised side by side.
        best_others = 1 + losses[1:].argsort(0)[: starts - 1]
        shortlist = torch.cat([torch.zeros(1, n, dtype=torch.long), best_others])
        if len(samples.f) > SCREEN_SAMPLES:  # very large plans: a fixed random subset
            keep = torch.randperm(len(samples.f), generator=torch.Generator().manual_seed(0))[:SCREEN_SAMPLES]
            samples = FitSamples(*(column[keep] for column in samples))
        codes = self._candidates[shortlist].clone().requires_grad_(True)
        optimizer = self.optimizer_factory([codes])
        with torch.enable_grad():
            for _ in range(self.hparams.init_screen_steps):
                optimizer.zero_grad()
                self._material_losses(samples, codes).sum().backward()
                optimizer.step()
        with torch.no_grad():
            final = self._material_losses(samples, codes)
            self.latents.latents.copy_(codes[final.argmin(0), torch.arange(n)])

    def configure_callbacks(self):
        return [ValidateFinalStep()]

    KIND = "nlb"

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        super().on_save_checkpoint(checkpoint)
        checkpoint["material_names"] = self.material_names
        checkpoint["pretrained_network"] = self._pretrained_name
        checkpoint["nlb_config"] = asdict(self.network.config)

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        self.build_latents(checkpoint["material_names"])

    def predict(self, samples: FitSamples) -> torch.Tensor:
        return self.network(samples.wi, samples.wo, self.latents(samples.material))

    def training_step(self, batch: FitSamples, batch_idx: int) -> torch.Tensor:
        loss = nlb_loss(self.predict(batch), batch.f, batch.wi, self.hparams.loss_domain)
        if self._prior_mean is not None:
            # The data loss is a mean over the batch's samples; the prior term is too (each sample
            # carries its material's, computed once per material), so each material's share of the
            # loss is (its data loss + its prior term) in proportion to its samples in the batch: the
            # same minimum per material as in screening.
            loss = loss + self._prior_terms(self.latents.latents)[batch.material].mean()
        self.log("train/loss", loss, on_step=False, on_epoch=True, batch_size=len(batch.f))
        self._track_convergence(float(loss.detach()))
        return loss

    def _track_convergence(self, loss: float) -> None:
        patience = self.hparams.early_stop_patience
        if patience is None:
            return
        if loss < self._best_loss * (1.0 - self.hparams.early_stop_tolerance):
            self._best_loss, self._steps_since_best = loss, 0
        else:
            self._steps_since_best += 1
        if self._steps_since_best >= patience:
            self.trainer.should_stop = True

    def validation_step(self, item: EvalSet, batch_idx: int) -> None:
        fit_pred = self.predict(item.fit)
        fit_rmse = metrics.hemisphere_logcos_rmse(fit_pred, item.fit.f, _theta_i_deg(item.fit.wi))
        self.log(f"fit_logcos_rmse/{item.name}", fit_rmse, batch_size=1)
        truth_pred = None if item.truth is None else self.predict(item.truth)
        self._record_scores(item, fit_pred, truth_pred)
        if item.truth is None:
            return
        theta_i = _theta_i_deg(item.truth.wi)
        rmse = metrics.hemisphere_logcos_rmse(truth_pred, item.truth.f, theta_i)
        self.log(f"hemisphere_logcos_rmse/{item.name}", rmse, batch_size=1)
        self._eval_rmse.append(rmse)
        if item.abc is not None:
            abc_rmse = metrics.hemisphere_logcos_rmse(item.abc, item.truth.f, theta_i)
            self.log(f"abc_low2012/hemisphere_logcos_rmse/{item.name}", abc_rmse, batch_size=1)

    def on_validation_epoch_start(self) -> None:
        self._eval_rmse: list[float] = []
        self._scores: dict[str, dict[str, float | None]] = {}

    def _record_scores(self, item: EvalSet, fit_pred: torch.Tensor, truth_pred: torch.Tensor | None) -> None:
        """The shared metric names (SPEC §9) of one material, kept for :meth:`metrics_json_extras`."""
        from neuralbrdf.evaluation.scores import fit_scores
        from neuralbrdf.geometry import inplane_equivalent

        as_numpy = lambda t: t.detach().cpu().double().numpy()  # noqa: E731
        theta_i, theta_r = inplane_equivalent(as_numpy(item.fit.wi), as_numpy(item.fit.wo))
        truth = {}
        if item.truth is not None:
            truth = dict(pred_truth=as_numpy(truth_pred), truth_values=as_numpy(item.truth.f),
                         truth_theta_i=as_numpy(_theta_i_deg(item.truth.wi)))
        self._scores[item.name] = fit_scores(as_numpy(fit_pred), as_numpy(item.fit.f), theta_i, theta_r, **truth)

    def metrics_json_extras(self) -> dict:
        """Per material ``materials/<name>/<metric>`` and, under the bare names, the mean over the
        materials (the material itself for a single fit) of the last validation (the fitted model)."""
        scores = getattr(self, "_scores", {})
        extras = {f"materials/{name}/{key}": value for name, values in scores.items() for key, value in values.items()}
        for key in sorted({key for values in scores.values() for key in values}):
            present = [values[key] for values in scores.values() if values.get(key) is not None]
            extras[key] = float(np.mean(present)) if present else None
        return extras

    def on_validation_epoch_end(self) -> None:
        if self._eval_rmse:
            self.log("hemisphere_logcos_rmse/mean", float(np.mean(self._eval_rmse)))

    def on_fit_end(self) -> None:
        for key, value in self.network.state_dict().items():
            if not torch.equal(value.cpu(), self._frozen_reference[key]):
                raise RuntimeError(f"frozen NLB weight {key} changed during the latent fit")

    def configure_optimizers(self):
        groups = [(self.latents.parameters(), 1.0)]
        return scheduled_optimizer(groups, self.optimizer_factory, self.lr_scheduler_factory, "step")


def start_candidates(pretrained: PretrainedNlb, n_analytic: int) -> torch.Tensor:
    """Candidate starting codes ``[K, latent_dim]``: the centroid, every measured MERL proxy code
    (``merl:``) and ``n_analytic`` of the other codes (analytic, then proxy blends where the
    network was pretrained with them) evenly spaced in the table (module docstring)."""
    merl = [i for i, name in enumerate(pretrained.names) if name.startswith("merl:")]
    analytic = [i for i in range(len(pretrained.latents)) if i not in set(merl)]
    picked = [analytic[int(j)] for j in np.linspace(0, len(analytic) - 1, min(n_analytic, len(analytic)))]
    return torch.cat([pretrained.latent_mean[None], pretrained.latents[merl + picked]])


def prior_codes(pretrained: PretrainedNlb, which: str, path) -> torch.Tensor:
    """The pretrained codes the latent prior is fitted to (module docstring): ``[M, latent_dim]``."""
    codes = pretrained.latents
    if which == "measured":
        codes = codes[[i for i, name in enumerate(pretrained.names) if name.startswith(MEASURED_PREFIXES)]]
    dim = pretrained.latents.shape[1]
    if len(codes) <= dim:  # fewer codes than dimensions + 1: a singular covariance
        kind = "codes of measured materials (names merl:…, merl-blend:…)" if which == "measured" else "codes"
        raise InputError(f"has {len(codes)} {kind} in {dim} latent dimensions; the latent prior's Gaussian needs "
                         f"more than {dim}: set model.latent_prior_codes: all, or model.latent_prior_weight: 0",
                         path=path)
    return codes


class ValidateFinalStep(pl.Callback):
    """Runs validation after the fit's last step — the end of the last epoch or an early stop —
    whatever ``trainer.check_val_every_n_epoch`` says, so the last logged metrics and the
    checkpoint saved at validation end are those of the final latents (issue 13, class 4).

    Lightning validates only in epochs that are multiples of ``check_val_every_n_epoch``;
    switching it to 1 before the epoch loop's validation check of the final step makes that
    step one.
    """

    def on_train_batch_end(self, trainer: pl.Trainer, pl_module, outputs, batch, batch_idx: int) -> None:
        last_batch = trainer.fit_loop.epoch_loop.batch_progress.is_last_batch
        last_epoch = trainer.max_epochs is not None and trainer.current_epoch + 1 >= trainer.max_epochs
        if trainer.should_stop or (last_batch and last_epoch):
            trainer.check_val_every_n_epoch = 1

