"""What the single-material fits made in one training step share (the ABC, ``auto`` and ``pca``
fits: docs/models.md): no optimiser of Lightning's, the evaluation of the fitted model on the
material's samples and its truth, and the ``best`` checkpoint written once at the end.

A subclass fits in its first ``training_step`` and implements :meth:`OneStepFit.fitted_values`
(the fitted model at a table's pairs, ``None`` before the fit or after a failed one).  The
evaluation logs ``fit_logcos_rmse`` on the samples and, with a truth, ``plan_logcos_rmse`` on its
plan (:func:`~neuralbrdf.metrics.hemisphere_logcos_rmse`, Eq. 4.1's log-cosine error, the
predictions clipped at 0 as everywhere the metric is computed), and keeps the shared
:func:`~neuralbrdf.evaluation.scores.fit_scores` in ``scores`` for ``metrics.json``.  A failed
fit says why in ``failure`` (read by :class:`~neuralbrdf.lightning.fit_health.FitHealth`).
"""

from __future__ import annotations

import os

import numpy as np
import pytorch_lightning as pl

from neuralbrdf.data.table import BrdfTable
from neuralbrdf.evaluation.scores import fit_scores
from neuralbrdf.metrics import hemisphere_logcos_rmse
from neuralbrdf.sources import MaterialData


class OneStepFit(pl.LightningModule):
    """Base of a fit made in one training step (module docstring)."""

    def __init__(self) -> None:
        super().__init__()
        self.automatic_optimization = False
        #: :func:`~neuralbrdf.evaluation.scores.fit_scores` of the last evaluation.
        self.scores: dict[str, float | None] = {}
        #: Why the fit failed (one line), else ``None``.
        self.failure: str | None = None

    def configure_optimizers(self):
        return None  # the fit runs its own solver

    def fitted_values(self, table: BrdfTable) -> np.ndarray | None:
        """The fitted model at ``table``'s pairs ``[N, C]`` (sr⁻¹); ``None`` when there is none."""
        raise NotImplementedError

    def _evaluate(self, material: MaterialData, stage: str) -> None:
        fit, truth = material.fit, material.truth
        pred = self.fitted_values(fit)
        if pred is None:
            return  # sanity check before the fit, or a failed fit
        self.log(f"{stage}/fit_logcos_rmse", hemisphere_logcos_rmse(np.clip(pred, 0.0, None), fit.values, fit.theta_i),
                 batch_size=1)
        pred_truth = None
        if truth is not None:
            if truth.is_spectral and not fit.is_spectral:
                truth = truth.to_rgb()
            pred_truth = self.fitted_values(truth)
            self.log(f"{stage}/plan_logcos_rmse",
                     hemisphere_logcos_rmse(np.clip(pred_truth, 0.0, None), truth.values, truth.theta_i), batch_size=1)
        self.scores = fit_scores(pred, fit.values, *fit.inplane_angles(), pred_truth,
                                 None if truth is None else truth.values, None if truth is None else truth.theta_i)

    def validation_step(self, material: MaterialData, batch_idx: int) -> None:
        self._evaluate(material, "val")

    def test_step(self, material: MaterialData, batch_idx: int) -> None:
        self._evaluate(material, "test")

    def has_model(self) -> bool:
        """Whether the fit gave a model to checkpoint."""
        raise NotImplementedError

    def on_train_end(self) -> None:
        # one fit and no optimiser step: ModelCheckpoint, which saves per global step, never writes
        # "best"; the single fit is both best and last
        callback = self.trainer.checkpoint_callback
        if callback is not None and callback.dirpath is not None and self.has_model():
            self.trainer.save_checkpoint(os.path.join(callback.dirpath, f"{callback.filename or 'best'}.ckpt"))

    def fit_failure(self) -> str | None:
        """Why the fit failed, if it did (read by :class:`~neuralbrdf.lightning.fit_health.FitHealth`)."""
        return self.failure
