"""Training of the spectral MLP (report §5.1.1–5.1.2; SPEC §4.4, §5).

* **Loss** — report Eq. 5.1, :func:`neuralbrdf.losses.exp_weighted_mse`:
  ``mean(exp(-gamma |theta_i - theta_r|) (f_mea - f_pred)²)`` with ``gamma`` and the unit of the
  angle difference from the config (default 3 per radian; the report's per-degree form leaves
  the diffuse region without gradient, SPEC §4.4).
* **Optimiser** — Adam with a decaying learning rate, both injected from the config
  (``optimizer`` and ``lr_scheduler``, stepped once per epoch).
* **Metrics** on the evaluation split (:mod:`neuralbrdf.metrics`, report Eq. 4.3 over the glossy
  region ``|theta_i - theta_r| <= 10°``, entries with ``f_mea`` below ``rel_rmse_floor``
  excluded and counted):

  - ``<split>/loss`` — Eq. 5.1 over every sample of the split;
  - ``<split>/rel_rmse_glossy`` — Eq. 4.3 per wavelength over all glossy samples of the split,
    averaged over wavelengths (:func:`~neuralbrdf.metrics.relative_rmse`);
  - ``<split>/rel_rmse_glossy_median`` — the median of the Fig. 5.3 box-plot data: one Eq. 4.3
    value per (incident angle, wavelength) over that angle's glossy samples
    (:func:`~neuralbrdf.metrics.relative_rmse_by_channel`), median over all of them — the
    report's "median glossy relative RMSE" over the test incident angles;
  - ``<split>/rel_rmse_excluded`` — glossy entries left out for being below the floor.

  ``<split>`` is ``val`` (checkpoint selection; the report's test split, see
  :mod:`neuralbrdf.lightning.measurement_data`) or ``test``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
import pytorch_lightning as pl
import torch
from pytorch_lightning.cli import LRSchedulerCallable, OptimizerCallable

from neuralbrdf import metrics
from neuralbrdf.errors import InputError
from neuralbrdf.lightning.measurement_data import SpectralSamples
from neuralbrdf.losses import ANGLE_UNITS, exp_weighted_mse
from neuralbrdf.models.spectral_mlp import Activation, OutputActivation, SpectralMLP


def glossy_relative_rmse(samples: SpectralSamples, pred: torch.Tensor, floor: float) -> dict[str, float]:
    """``rel_rmse_glossy``, ``rel_rmse_glossy_median`` and ``rel_rmse_excluded`` of flat samples.

    The samples (any order) are pivoted by ``pair_index`` and wavelength to a ``[direction
    pairs, wavelengths]`` table, the layout :mod:`neuralbrdf.metrics` expects; every pair must
    carry every wavelength.
    """
    theta_i, theta_r, wavelength, target = (column.detach().cpu().double().numpy() for column in samples[:4])
    pairs, first, row = np.unique(samples.pair_index.cpu().numpy(), return_index=True, return_inverse=True)
    wavelengths, column = np.unique(wavelength, return_inverse=True)
    shape = (len(pairs), len(wavelengths))
    if len(target) != shape[0] * shape[1]:
        raise ValueError(f"{len(target)} samples do not fill {shape[0]} direction pairs × {shape[1]} wavelengths")
    table_pred, table_target = np.full(shape, np.nan), np.full(shape, np.nan)
    table_pred[row, column] = pred.detach().cpu().double().numpy()
    table_target[row, column] = target
    arguments = (table_pred, table_target, theta_i[first], theta_r[first], floor)
    overall = metrics.relative_rmse(*arguments)
    by_angle = metrics.relative_rmse_by_channel(*arguments)
    return {
        "rel_rmse_glossy": overall.value,
        "rel_rmse_glossy_median": float(np.nanmedian(by_angle.per_theta_i)),
        "rel_rmse_excluded": float(overall.n_excluded),
    }


class SpectralMlpModule(pl.LightningModule):
    """Fits a :class:`~neuralbrdf.models.spectral_mlp.SpectralMLP` with the report's Eq. 5.1 loss.

    Parameters
    ----------
    hidden, hidden_layers, activation, output, angle_range_deg, wavelength_range_nm:
        The network's (see :class:`~neuralbrdf.models.spectral_mlp.SpectralMLP`).
    gamma:
        Eq. 5.1 weight decay rate per ``angle_unit`` of ``|theta_i - theta_r|``.
    angle_unit:
        ``"radians"`` or ``"degrees"`` (the report's literal form).
    rel_rmse_floor:
        Measured values (sr⁻¹) below this are left out of the Eq. 4.3 metrics.
    optimizer, lr_scheduler:
        Factories called with the parameters and the optimiser (config ``class_path`` entries);
        the scheduler steps once per epoch.
    """

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
        rel_rmse_floor: float = metrics.DEFAULT_FLOOR,
        optimizer: OptimizerCallable = torch.optim.Adam,
        lr_scheduler: LRSchedulerCallable | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters(ignore=["optimizer", "lr_scheduler"])
        self.network = SpectralMLP(hidden, hidden_layers, activation, output, angle_range_deg, wavelength_range_nm)
        self.optimizer_factory = optimizer
        self.lr_scheduler_factory = lr_scheduler
        self._evaluated: list[tuple[SpectralSamples, torch.Tensor]] = []
        if angle_unit not in ANGLE_UNITS:
            raise InputError(f"angle_unit must be one of {', '.join(ANGLE_UNITS)}, got {angle_unit!r}")
        for name, value in (("gamma", gamma), ("rel_rmse_floor", rel_rmse_floor)):
            if not (np.isfinite(value) and value >= 0):
                raise InputError(f"model.{name} must be a finite number >= 0, got {value}", column=name)

    def forward(self, theta_i_deg, theta_r_deg, wavelength_nm):
        return self.network(theta_i_deg, theta_r_deg, wavelength_nm)

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        # Read by export/to_onnx.py to pick the exporter (SPEC §6 kinds).
        checkpoint["neuralbrdf_kind"] = "spectral_mlp"

    def _loss(self, batch: SpectralSamples) -> tuple[torch.Tensor, torch.Tensor]:
        pred = self.network(batch.theta_i_deg, batch.theta_r_deg, batch.wavelength_nm)
        loss = exp_weighted_mse(
            pred, batch.brdf, batch.theta_i_deg, batch.theta_r_deg, self.hparams.gamma, self.hparams.angle_unit
        )
        return pred, loss

    def training_step(self, batch: SpectralSamples, batch_idx: int) -> torch.Tensor:
        _, loss = self._loss(batch)
        self.log("train/loss", loss, on_step=False, on_epoch=True, batch_size=len(batch.brdf))
        return loss

    def _evaluation_step(self, batch: SpectralSamples, split: str) -> None:
        pred, loss = self._loss(batch)
        self.log(f"{split}/loss", loss, on_epoch=True, batch_size=len(batch.brdf))
        self._evaluated.append((batch, pred))

    def _evaluation_epoch_end(self, split: str) -> None:
        samples = SpectralSamples(*(torch.cat(c) for c in zip(*(batch for batch, _ in self._evaluated))))
        pred = torch.cat([p for _, p in self._evaluated])
        self._evaluated.clear()
        for name, value in glossy_relative_rmse(samples, pred, self.hparams.rel_rmse_floor).items():
            self.log(f"{split}/{name}", value)

    def validation_step(self, batch: SpectralSamples, batch_idx: int) -> None:
        self._evaluation_step(batch, "val")

    def on_validation_epoch_end(self) -> None:
        self._evaluation_epoch_end("val")

    def test_step(self, batch: SpectralSamples, batch_idx: int) -> None:
        self._evaluation_step(batch, "test")

    def on_test_epoch_end(self) -> None:
        self._evaluation_epoch_end("test")

    def configure_optimizers(self):
        optimizer = self.optimizer_factory(self.parameters())
        if self.lr_scheduler_factory is None:
            return optimizer
        scheduler = self.lr_scheduler_factory(optimizer)
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "epoch"}}
