"""What every latent-only fit on a frozen pretrained network shares (docs/models.md#latent-fit-rgb-nlb; report §4.2).

A latent-only fit (Fan et al. 2022) freezes a pretrained auto-decoder and optimises only the
codes of new materials, all in one batch.  :class:`LatentOnlyFit` holds the parts that do not
depend on the network or on how a material's codes are laid out — the RGB NLB's single latent
(:class:`~neuralbrdf.lightning.latent_fit_module.LatentFitModule`) or the spectral NLB's shared
code and channel codes (:class:`~neuralbrdf.lightning.nlb_spectral_fit.SpectralLatentFitModule`):

* **starts**: with start candidates, each material starts from the candidate with the lowest
  loss on its own fitting samples; with ``init_starts`` S > 1 the first candidate (the
  centroid) and the S − 1 best others are each optimised for ``init_screen_steps`` steps, all
  materials and starts at once, and each material continues from the start with the lowest
  loss after them.  Candidates and starts are compared on the samples of
  :meth:`LatentOnlyFit.screening_samples`; selection uses the fitting samples only, never the
  truth;
* **loss**: each material's data loss (the mean of its samples' errors) plus its prior term —
  the same criterion in screening and in training, where each sample carries its material's
  prior term so that every material keeps its own minimum whatever the plans' sizes;
* **early stopping** (``early_stop_patience``): stop when the training loss has not improved
  by a relative ``early_stop_tolerance`` for that many steps;
* **small fits by L-BFGS** (``full_batch_iterations``, where a subclass offers it): when every
  step sees every sample, each material's codes are optimised by L-BFGS (Nocedal 1980;
  strong-Wolfe line search) on its samples — one run of at most ``full_batch_iterations``
  iterations per material, all in the fit's one step — instead of the configured optimiser's
  hundreds of steps.  Per material, because the materials are independent problems: one run over
  all of them shares its line search, and on the RGL validation split that left satin_blue at a
  hemisphere error 1.5 times its own run's.  Larger fits (random batches) keep the configured
  optimiser and schedule; the screening of starts uses the configured optimiser either way;
* **the fit's last step is always evaluated** (:class:`ValidateFinalStep`), and the metrics of
  the last validation are the fitted model's: per material the fit's log-cosine RMSE on its
  fitting samples, against a truth where there is one, and the shared metric names of docs/evaluate.md#metrics;
* the frozen weights are checked bit for bit at the end of the fit.

A subclass provides the codes (:meth:`LatentOnlyFit.code_parameters`, built by
:meth:`LatentOnlyFit.build_codes`), the per-sample errors under any set of codes
(:meth:`LatentOnlyFit.sample_errors`), the prior terms and :meth:`LatentOnlyFit.predict`.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence

import numpy as np
import pytorch_lightning as pl
import torch
from pytorch_lightning.cli import LRSchedulerCallable, OptimizerCallable

from neuralbrdf import metrics
from neuralbrdf.errors import InputError
from neuralbrdf.lightning.common import scheduled_optimizer
from neuralbrdf.lightning.latent_fit_data import EvalSet, FitSamples

#: Correction pairs L-BFGS keeps (``torch.optim.LBFGS`` ``history_size``; :func:`lbfgs`).
LBFGS_HISTORY = 10

#: At most this many of the fitting samples (a fixed random subset) take part in the screening of
#: several starts (:meth:`LatentOnlyFit.screening_samples`, unless a subclass says otherwise).
SCREEN_SAMPLES = 65536

#: Candidate starts are scored together (:meth:`LatentOnlyFit.choose_starts`), as many to an
#: evaluation as keep it within about this many values (candidates × samples × channels; at least
#: one candidate): a single spectral material screened on 2048 values has its ~120 candidates scored
#: 16 at a time, a fit that scores them on every sample of a large table one at a time.
CANDIDATE_VALUES = 2**15


def theta_i_deg(wi: torch.Tensor) -> torch.Tensor:
    """Incident polar angle (degrees) of unit directions ``[N, 3]``."""
    return torch.rad2deg(torch.acos(wi[:, 2].clamp(-1.0, 1.0)))


def check_fit_settings(init_candidates: int, init_starts: int, init_screen_steps: int,
                       early_stop_patience: int | None, early_stop_tolerance: float) -> None:
    """:class:`InputError` naming the ``model.*`` key of the first invalid setting."""
    if not isinstance(init_candidates, int) or init_candidates < 0:
        raise InputError(f"must be a non-negative integer, got {init_candidates!r}", key="model.init_candidates")
    for key, value in (("init_starts", init_starts), ("init_screen_steps", init_screen_steps)):
        if not isinstance(value, int) or value < 1:
            raise InputError(f"must be a positive integer, got {value!r}", key=f"model.{key}")
    if init_starts > 1 and not init_candidates:
        raise InputError("several starts need start candidates (model.init_candidates > 0)",
                         key="model.init_starts")
    if early_stop_patience is not None and (not isinstance(early_stop_patience, int) or early_stop_patience < 1):
        raise InputError(f"must be a positive integer or null, got {early_stop_patience!r}",
                         key="model.early_stop_patience")
    if not early_stop_tolerance >= 0:
        raise InputError(f"must be non-negative, got {early_stop_tolerance}", key="model.early_stop_tolerance")


def lbfgs(codes: list[torch.Tensor], iterations: int) -> torch.optim.LBFGS:
    """L-BFGS over ``codes`` for at most ``iterations`` iterations per ``step(closure)``, with a
    strong-Wolfe line search (unit initial step)."""
    return torch.optim.LBFGS(codes, lr=1.0, max_iter=iterations, history_size=LBFGS_HISTORY,
                             line_search_fn="strong_wolfe")


def check_weight(value, key: str) -> None:
    """:class:`InputError` unless ``value`` is a finite non-negative number (a loss weight)."""
    if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
        raise InputError(f"must be a finite non-negative number, got {value!r}", key=key)


class LatentOnlyFit(pl.LightningModule):
    """Base of the latent-only fits (module docstring).  Subclasses set ``self.network`` through
    :meth:`freeze`, call :meth:`save_hyperparameters` with ``init_starts``,
    ``init_screen_steps``, ``early_stop_patience`` and ``early_stop_tolerance`` among them, and
    set ``self._candidates`` (a list of tensors ``[K, ...]``, one per code tensor, candidate 0 the
    centroid) or ``None``."""

    def __init__(self, optimizer: OptimizerCallable, lr_scheduler: LRSchedulerCallable | None) -> None:
        super().__init__()
        self.optimizer_factory = optimizer
        self.lr_scheduler_factory = lr_scheduler
        self.material_names: list[str] = []
        self._candidates: list[torch.Tensor] | None = None
        self._best_loss = math.inf
        self._steps_since_best = 0
        self._full_batch = False

    # ------------------------------------------------------------------ what a subclass provides

    def build_codes(self, names: Sequence[str]) -> None:
        """Create the codes of the materials ``names``, all at the starting point."""
        raise NotImplementedError

    def code_parameters(self) -> list[torch.nn.Parameter]:
        """The trained code tensors, each ``[n_materials, ...]``."""
        raise NotImplementedError

    def sample_errors(self, samples: FitSamples, codes: list[torch.Tensor]) -> torch.Tensor:
        """Per-sample data error ``[S, N]`` under ``S`` sets of codes (each tensor ``[S, n, ...]``)."""
        raise NotImplementedError

    def prior_terms(self, codes: list[torch.Tensor]) -> torch.Tensor | float:
        """Prior term of each material's codes ``[..., n]`` (0 without a prior)."""
        return 0.0

    def predict(self, samples: FitSamples) -> torch.Tensor:
        """The fitted model's values at ``samples``' directions, ``[N, C]`` in sr⁻¹."""
        raise NotImplementedError

    # ------------------------------------------------------------------ shared machinery

    def freeze(self, network: torch.nn.Module) -> None:
        """Use ``network`` frozen (by ``requires_grad`` alone: nothing in it depends on train mode)."""
        self.network = network.requires_grad_(False).train()
        self._frozen_reference = {k: v.clone() for k, v in self.network.state_dict().items()}

    def setup(self, stage: str) -> None:
        if not self.material_names:
            data = getattr(self.trainer, "datamodule", None)
            if data is None or not hasattr(data, "material_names"):
                raise InputError("the latent fit needs a LatentFitData data module (data.class_path)", key="data")
            self._full_batch = bool(getattr(data, "full_batch", False))
            self.build_codes(data.material_names)
            if self._candidates is not None:
                self.choose_starts(data.train_samples)

    def material_losses(self, samples: FitSamples, codes: list[torch.Tensor]) -> torch.Tensor:
        """Loss of each material under ``S`` sets of codes: data loss + prior term, ``[S, n]``."""
        errors = self.sample_errors(samples, codes)
        n = codes[0].shape[1]
        counts = torch.zeros(n).index_add_(0, samples.material, torch.ones(len(samples.material)))
        data = torch.zeros(len(errors), n).index_add_(1, samples.material, errors) / counts
        return data + self.prior_terms(codes)

    def screening_samples(self, samples: FitSamples) -> FitSamples:
        """The fitting samples the starts are chosen on: with several starts and very large plans,
        a fixed random subset of :data:`SCREEN_SAMPLES` of them; else all."""
        if self.hparams.init_starts > 1 and len(samples.f) > SCREEN_SAMPLES:
            keep = torch.randperm(len(samples.f), generator=torch.Generator().manual_seed(0))[:SCREEN_SAMPLES]
            return FitSamples(*(column[keep] for column in samples))
        return samples

    def choose_starts(self, samples: FitSamples) -> None:
        """Set each material's codes to its best start (module docstring)."""
        n = len(self.material_names)
        candidates = self._candidates
        samples = self.screening_samples(samples)
        count, chunk = len(candidates[0]), max(1, CANDIDATE_VALUES // samples.f.numel())
        with torch.no_grad():  # [K, n]: candidates scored `chunk` at a time, as so many starts
            losses = torch.cat([self.material_losses(samples, [c[k:k + chunk, None].expand(-1, n, *c.shape[1:])
                                                               for c in candidates])
                                for k in range(0, count, chunk)])
        starts = self.hparams.init_starts
        if starts == 1:
            with torch.no_grad():
                for parameter, c in zip(self.code_parameters(), candidates):
                    parameter.copy_(c[losses.argmin(0)])
            return
        # The centroid (candidate 0) and the best starts - 1 other codes, optimised side by side.
        best_others = 1 + losses[1:].argsort(0)[: starts - 1]
        shortlist = torch.cat([torch.zeros(1, n, dtype=torch.long), best_others])
        codes = [c[shortlist].clone().requires_grad_(True) for c in candidates]
        optimizer = self.optimizer_factory(codes)
        with torch.enable_grad():
            for _ in range(self.hparams.init_screen_steps):
                optimizer.zero_grad()
                self.material_losses(samples, codes).sum().backward()
                optimizer.step()
        with torch.no_grad():
            best = self.material_losses(samples, codes).argmin(0)
            for parameter, c in zip(self.code_parameters(), codes):
                parameter.copy_(c[best, torch.arange(n)])

    @property
    def uses_lbfgs(self) -> bool:
        """Optimised by L-BFGS (module docstring): a subclass's ``full_batch_iterations`` is set and
        every step sees every sample."""
        return self.hparams.get("full_batch_iterations") is not None and self._full_batch

    def on_fit_start(self) -> None:
        if self.uses_lbfgs:  # training_step returns None on purpose (Lightning warns unless told)
            warnings.filterwarnings("ignore", message="`training_step` returned `None`")

    def configure_callbacks(self):
        return [ValidateFinalStep()]

    def training_step(self, batch: FitSamples, batch_idx: int) -> torch.Tensor | None:
        if self.uses_lbfgs:  # the whole fit, in this one step; None: Lightning steps no optimiser
            losses = self.fit_each_by_lbfgs(batch)
            self.log("train/loss", float(np.mean(losses)), on_step=False, on_epoch=True, batch_size=len(batch.f))
            self.trainer.should_stop = True
            return None
        codes = self.code_parameters()
        loss = self.sample_errors(batch, [c[None] for c in codes]).mean()
        prior = self.prior_terms(codes)
        if torch.is_tensor(prior):
            # Each sample carries its material's prior term (computed once per material), so each
            # material's share of the loss is (its data loss + its prior term) in proportion to its
            # samples in the batch: the same minimum per material as in screening.
            loss = loss + prior[batch.material].mean()
        self.log("train/loss", loss, on_step=False, on_epoch=True, batch_size=len(batch.f))
        self._track_convergence(float(loss.detach()))
        return loss

    def fit_each_by_lbfgs(self, samples: FitSamples) -> list[float]:
        """Optimise each material's codes by :func:`lbfgs` on its own samples (module docstring);
        each material's final loss."""
        codes = self.code_parameters()
        losses = []
        for m in range(len(self.material_names)):
            own = samples.material == m
            mine = FitSamples(*(column[own] for column in samples))
            rows = [c[m].detach().clone().requires_grad_(True) for c in codes]
            optimizer = lbfgs(rows, self.hparams.full_batch_iterations)

            def closure() -> torch.Tensor:
                optimizer.zero_grad()
                table = [torch.cat([c[:m].detach(), r[None], c[m + 1:].detach()])[None] for c, r in zip(codes, rows)]
                loss = self.material_losses(mine, table)[0, m]
                loss.backward()
                return loss

            with torch.enable_grad():
                optimizer.step(closure)
                losses.append(float(closure().detach()))
            with torch.no_grad():
                for c, r in zip(codes, rows):
                    c[m] = r
        return losses

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
        fit_rmse = metrics.hemisphere_logcos_rmse(fit_pred, item.fit.f, theta_i_deg(item.fit.wi))
        self.log(f"fit_logcos_rmse/{item.name}", fit_rmse, batch_size=1)
        truth_pred = None if item.truth is None else self.predict(item.truth)
        self._record_scores(item, fit_pred, truth_pred)
        if item.truth is None:
            return
        theta_i = theta_i_deg(item.truth.wi)
        rmse = metrics.hemisphere_logcos_rmse(truth_pred, item.truth.f, theta_i)
        self.log(f"plan_logcos_rmse/{item.name}", rmse, batch_size=1)
        self._eval_rmse.append(rmse)
        if item.abc is not None:
            abc_rmse = metrics.hemisphere_logcos_rmse(item.abc, item.truth.f, theta_i)
            self.log(f"abc_low2012/plan_logcos_rmse/{item.name}", abc_rmse, batch_size=1)

    def on_validation_epoch_start(self) -> None:
        self._eval_rmse: list[float] = []
        self._scores: dict[str, dict[str, float | None]] = {}

    def _record_scores(self, item: EvalSet, fit_pred: torch.Tensor, truth_pred: torch.Tensor | None) -> None:
        """The shared metric names (docs/evaluate.md#metrics) of one material, kept for :meth:`metrics_json_extras`."""
        from neuralbrdf.evaluation.scores import fit_scores
        from neuralbrdf.geometry import inplane_equivalent

        as_numpy = lambda t: t.detach().cpu().double().numpy()  # noqa: E731
        theta_i, theta_r = inplane_equivalent(as_numpy(item.fit.wi), as_numpy(item.fit.wo))
        truth = {}
        if item.truth is not None:
            truth = dict(pred_truth=as_numpy(truth_pred), truth_values=as_numpy(item.truth.f),
                         truth_theta_i=as_numpy(theta_i_deg(item.truth.wi)))
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
            self.log("plan_logcos_rmse/mean", float(np.mean(self._eval_rmse)))

    def on_fit_end(self) -> None:
        for key, value in self.network.state_dict().items():
            if not torch.equal(value.cpu(), self._frozen_reference[key]):
                raise RuntimeError(f"frozen network weight {key} changed during the latent fit")

    def configure_optimizers(self):
        groups = [(self.code_parameters(), 1.0)]
        if self.uses_lbfgs:  # the configured optimiser, never stepped (fit_each_by_lbfgs)
            return self.optimizer_factory(self.code_parameters())
        return scheduled_optimizer(groups, self.optimizer_factory, self.lr_scheduler_factory, "step")


class ValidateFinalStep(pl.Callback):
    """Runs validation after the fit's last step — the end of the last epoch or an early stop —
    whatever ``trainer.check_val_every_n_epoch`` says, so the last logged metrics and the
    checkpoint saved at validation end are those of the final codes.

    Lightning validates only in epochs that are multiples of ``check_val_every_n_epoch``;
    switching it to 1 before the epoch loop's validation check of the final step makes that
    step one.
    """

    def on_train_batch_end(self, trainer: pl.Trainer, pl_module, outputs, batch, batch_idx: int) -> None:
        last_batch = trainer.fit_loop.epoch_loop.batch_progress.is_last_batch
        last_epoch = trainer.max_epochs is not None and trainer.current_epoch + 1 >= trainer.max_epochs
        if trainer.should_stop or (last_batch and last_epoch):
            trainer.check_val_every_n_epoch = 1
