"""Training of the spectral MLP (report §5.1.1–5.1.2; docs/models.md#spectral-mlp, docs/evaluate.md#metrics).

* **Loss** — report Eq. 5.1's weighting, :func:`neuralbrdf.losses.exp_weighted_loss`:
  ``mean(max(exp(-gamma |theta_i - theta_r|), weight_floor) · r²)`` with ``gamma``, the unit of
  the angle difference (default 3 per radian; the report's per-degree form leaves the diffuse
  region without gradient, docs/models.md#spectral-mlp), the residual ``r`` and the floor from the config.  The
  module's defaults (``residual="linear"``, ``weight_floor=0``) are Eq. 5.1 exactly
  (``configs/spectral_mlp_paper.yaml``); ``configs/spectral_mlp.yaml`` chooses the residual
  that fits the whole in-plane range (docs/design.md, "Spectral MLP loss").
* **Optimiser** — Adam with a decaying learning rate, both injected from the config
  (``optimizer`` and ``lr_scheduler``, stepped once per epoch); one optimiser step per batch of
  ``data.batch_size`` samples, taken by :meth:`SpectralMlpModule.training_step` over an epoch's
  batches (manual optimisation: Lightning's gradient clipping and accumulation do not apply).
* **Metrics** on the evaluation split (:mod:`neuralbrdf.metrics`, report Eq. 4.3 over the glossy
  region ``|theta_i - theta_r| <= 10°``, entries with ``f_mea`` below ``rel_rmse_floor``
  excluded and counted):

  - ``<split>/loss`` — the configured loss over every sample of the split;
  - ``<split>/rel_rmse_glossy`` — Eq. 4.3 per wavelength over all glossy samples of the split,
    averaged over wavelengths (:func:`~neuralbrdf.metrics.relative_rmse`);
  - ``<split>/rel_rmse_glossy_median`` — the median of the Fig. 5.3 box-plot data: one Eq. 4.3
    value per (incident angle, wavelength) over that angle's glossy samples
    (:func:`~neuralbrdf.metrics.relative_rmse_by_channel`), median over all of them — the
    report's "median glossy relative RMSE" over the test incident angles;
  - ``<split>/rel_rmse_excluded`` — glossy entries left out for being below the floor.

  ``<split>`` is ``val`` (checkpoint selection; the report's test split, see
  :mod:`neuralbrdf.lightning.measurement_data`) or ``test``.
* ``metrics.json`` also gets the shared names of docs/evaluate.md#metrics for the best checkpoint
  (:meth:`SpectralMlpModule.metrics_json_extras`): ``fit/inplane_glossy_rel_rmse``,
  ``fit/inplane_diffuse_rel_rmse`` and, for the shipped virtual measurements,
  ``fit/hemisphere_logcos_rmse``.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import numpy as np
import pytorch_lightning as pl
import torch
from pytorch_lightning.cli import LRSchedulerCallable, OptimizerCallable

from neuralbrdf import metrics
from neuralbrdf.errors import InputError
from neuralbrdf.lightning.common import WritesKind, scheduled_optimizer
from neuralbrdf.lightning.measurement_data import SpectralSamples, flatten_samples
from neuralbrdf.losses import ANGLE_UNITS, RESIDUALS, exp_weighted_loss
from neuralbrdf.models.spectral_mlp import Activation, OutputActivation, SpectralMLP

#: ``(cos θ, φ)`` strata of the hemisphere estimate a training run writes (``neuralbrdf evaluate``: 16 × 20).
TRAINING_HEMISPHERE_STRATA = (8, 10)


#: Data and ``wavelength_range_nm`` ends within this many nm agree.
RANGE_TOLERANCE_NM = 1e-6


def check_wavelength_range(wavelengths_nm, range_nm: Sequence[float], where) -> None:
    """Refuse data whose wavelengths are not the span ``range_nm`` the model declares (exported as
    its range, which renderers and evaluations query): data outside it would be fitted and then
    never asked for, a range wider than the data claims wavelengths the model never saw."""
    low, high = float(np.min(wavelengths_nm)), float(np.max(wavelengths_nm))
    if abs(low - range_nm[0]) > RANGE_TOLERANCE_NM or abs(high - range_nm[1]) > RANGE_TOLERANCE_NM:
        raise InputError(f"holds {low:g}-{high:g} nm but model.wavelength_range_nm is {range_nm[0]:g}-"
                         f"{range_nm[1]:g} nm, the range the fitted model declares; give "
                         f"--model.wavelength_range_nm '[{low:g}, {high:g}]'", path=where)


class SpectralMlpModule(WritesKind, pl.LightningModule):
    """Fits a :class:`~neuralbrdf.models.spectral_mlp.SpectralMLP` with an Eq. 5.1-weighted loss.

    Parameters
    ----------
    hidden, hidden_layers, activation, output, angle_range_deg, wavelength_range_nm:
        The network's (see :class:`~neuralbrdf.models.spectral_mlp.SpectralMLP`).
    gamma:
        Eq. 5.1 weight decay rate per ``angle_unit`` of ``|theta_i - theta_r|``.
    angle_unit:
        ``"radians"`` or ``"degrees"`` (the report's literal form).
    residual, residual_epsilon_sr, weight_floor:
        The loss's residual (:data:`neuralbrdf.losses.RESIDUALS`; ``"linear"`` is Eq. 5.1), the
        BRDF value (sr⁻¹) added to both sides of the ``relative`` and ``log`` residuals, and
        the smallest weight a sample gets (0: Eq. 5.1's weight).
    rel_rmse_floor:
        Measured values (sr⁻¹) below this are left out of the Eq. 4.3 metrics.
    optimizer, lr_scheduler:
        Factories called with the parameters and the optimiser (config ``class_path`` entries);
        the scheduler steps once per epoch.
    """

    KIND = "spectral_mlp"

    def __init__(
        self,
        hidden: int = 10,
        hidden_layers: int = 3,
        activation: Activation = "tanh",
        output: OutputActivation = "softplus",
        angle_range_deg: Sequence[float] = (-90.0, 90.0),
        wavelength_range_nm: Sequence[float] = (400.0, 700.0),
        gamma: float = 3.0,
        angle_unit: Literal[ANGLE_UNITS] = "radians",
        residual: Literal[RESIDUALS] = "linear",
        residual_epsilon_sr: float = 1e-3,
        weight_floor: float = 0.0,
        rel_rmse_floor: float = metrics.DEFAULT_FLOOR,
        optimizer: OptimizerCallable = torch.optim.Adam,
        lr_scheduler: LRSchedulerCallable | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters(ignore=["optimizer", "lr_scheduler"])
        self.automatic_optimization = False  # training_step steps through an epoch's batches itself
        self.network = SpectralMLP(hidden, hidden_layers, activation, output, angle_range_deg, wavelength_range_nm)
        self.optimizer_factory = optimizer
        self.lr_scheduler_factory = lr_scheduler
        self._evaluated: list[tuple[SpectralSamples, torch.Tensor]] = []
        if angle_unit not in ANGLE_UNITS:
            raise InputError(f"angle_unit must be one of {', '.join(ANGLE_UNITS)}, got {angle_unit!r}")
        if residual not in RESIDUALS:
            raise InputError(f"residual must be one of {', '.join(RESIDUALS)}, got {residual!r}")
        if not residual_epsilon_sr > 0 or not 0.0 <= weight_floor <= 1.0:
            raise InputError(
                f"residual_epsilon_sr must be > 0 sr⁻¹ and weight_floor in [0, 1], got {residual_epsilon_sr} "
                f"and {weight_floor}"
            )
        for name, value in (("gamma", gamma), ("rel_rmse_floor", rel_rmse_floor)):
            if not (np.isfinite(value) and value >= 0):
                raise InputError(f"model.{name} must be a finite number >= 0, got {value}", key=f"model.{name}")

    def prepare_data(self) -> None:
        # the data module has read its measurement; nothing of the run is written yet
        measurement = getattr(self.trainer.datamodule, "measurement", None) if self._trainer is not None else None
        if measurement is not None:
            table = measurement()[0]
            check_wavelength_range(table.wavelengths, self.hparams.wavelength_range_nm,
                                   getattr(self.trainer.datamodule, "path", None) or table.source)

    def forward(self, theta_i_deg, theta_r_deg, wavelength_nm):
        return self.network(theta_i_deg, theta_r_deg, wavelength_nm)

    def _loss(self, batch: SpectralSamples) -> tuple[torch.Tensor, torch.Tensor]:
        pred = self.network(batch.theta_i_deg, batch.theta_r_deg, batch.wavelength_nm)
        h = self.hparams
        loss = exp_weighted_loss(
            pred, batch.brdf, batch.theta_i_deg, batch.theta_r_deg, h.gamma, h.angle_unit,
            h.residual, h.residual_epsilon_sr, h.weight_floor,
        )
        return pred, loss

    def on_train_epoch_start(self) -> None:
        self._train_loss_sum, self._train_samples = torch.zeros(()), 0

    def training_step(self, batches: list[SpectralSamples] | SpectralSamples, batch_idx: int) -> torch.Tensor:
        """One optimiser step per batch of ``batches`` (an epoch's, from the data module's
        :class:`~neuralbrdf.lightning.measurement_data.EpochOfBatches`, or one batch); returns their
        sample-weighted mean loss.  ``train/loss`` is that mean over the epoch, logged at its end:
        the training loop's per-item cost and per-step logging were three quarters of the fit
        (thousands of steps of a 3×10 network)."""
        optimizer = self.optimizers()
        total, count = torch.zeros(()), 0
        for batch in [batches] if isinstance(batches, SpectralSamples) else batches:
            _, loss = self._loss(batch)
            optimizer.zero_grad()
            self.manual_backward(loss)
            optimizer.step()
            total, count = total + loss.detach() * len(batch.brdf), count + len(batch.brdf)
        self._train_loss_sum, self._train_samples = self._train_loss_sum + total, self._train_samples + count
        return total / max(count, 1)

    def on_train_epoch_end(self) -> None:
        if self._train_samples:
            self.log("train/loss", self._train_loss_sum / self._train_samples)
        scheduler = self.lr_schedulers()
        if scheduler is not None:
            scheduler.step()

    def _evaluation_step(self, batch: SpectralSamples, split: str) -> None:
        pred, loss = self._loss(batch)
        self.log(f"{split}/loss", loss, on_epoch=True, batch_size=len(batch.brdf))
        self._evaluated.append((batch, pred))

    def _evaluation_epoch_end(self, split: str) -> None:
        samples = SpectralSamples(*(torch.cat(c) for c in zip(*(batch for batch, _ in self._evaluated))))
        pred = torch.cat([p for _, p in self._evaluated])
        self._evaluated.clear()
        for name, value in metrics.glossy_relative_rmse_of_samples(samples, pred, self.hparams.rel_rmse_floor).items():
            self.log(f"{split}/{name}", value)

    def validation_step(self, batch: SpectralSamples, batch_idx: int) -> None:
        self._evaluation_step(batch, "val")

    def on_validation_epoch_end(self) -> None:
        self._evaluation_epoch_end("val")

    def test_step(self, batch: SpectralSamples, batch_idx: int) -> None:
        self._evaluation_step(batch, "test")

    def on_test_epoch_end(self) -> None:
        self._evaluation_epoch_end("test")

    def metrics_json_extras(self) -> dict:
        """The shared metric names (docs/evaluate.md#metrics) of the checkpoint that export uses (``best``).

        ``inplane_glossy_rel_rmse`` and ``inplane_diffuse_rel_rmse`` on the whole measurement it
        was given (both splits); for the shipped virtual measurements, ``hemisphere_logcos_rmse``
        against the virtual truth over 6 400 stratified hemisphere pairs (8 × 10 strata: a quick
        estimate of ``neuralbrdf evaluate``'s 102 400, within 1 % of it for the gold MLP).
        """
        from neuralbrdf.evaluation.scores import TorchEvaluator, fit_scores, hemisphere_scores
        from neuralbrdf.evaluation.truth import load_truth
        from neuralbrdf.models.directional import SpectralMlpOnDirections

        datamodule = self.trainer.datamodule
        network = copy.deepcopy(self.network)
        best = getattr(self.trainer.checkpoint_callback, "best_model_path", "")
        if best and Path(best).is_file():
            state = torch.load(best, map_location="cpu", weights_only=True)["state_dict"]
            network.load_state_dict({k.removeprefix("network."): v for k, v in state.items()})
        table, theta_i, theta_r = datamodule.measurement()
        samples = flatten_samples(table, theta_i, theta_r)
        with torch.no_grad():
            pred = network(samples.theta_i_deg, samples.theta_r_deg, samples.wavelength_nm).numpy().reshape(len(theta_i), -1)
        scores = fit_scores(pred.astype(np.float64), table.values, theta_i, theta_r)
        if datamodule.hparams.path is None:
            truth = load_truth(f"virtual:{datamodule.hparams.virtual}")
            hemisphere = hemisphere_scores(TorchEvaluator(SpectralMlpOnDirections(network), True),
                                           TorchEvaluator(truth.module, True), strata=TRAINING_HEMISPHERE_STRATA)
            scores["hemisphere_logcos_rmse"] = hemisphere["hemisphere_logcos_rmse"]
        return scores

    def configure_optimizers(self):
        return scheduled_optimizer([(self.parameters(), 1.0)], self.optimizer_factory, self.lr_scheduler_factory, "epoch")
