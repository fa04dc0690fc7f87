"""The ABC fit run (docs/models.md#abc; report §4.1.1) as a Lightning module for ``train.py``.

The fit itself is :func:`neuralbrdf.fitting.abc_fit.fit_abc` (bounded multi-start
minimisation of ``L_cus``, Eq. 4.2); this module runs it once on the material of
:class:`~neuralbrdf.lightning.material_data.SingleMaterialData`, logs its outcome and, where the source has a dense ground truth
(NBRDF proxies, virtual stand-ins), the log-cosine RMSE on the pairs of ``eval_plan``
(``plan_logcos_rmse``; ``neuralbrdf evaluate``'s ``hemisphere_logcos_rmse`` is another number).

``metrics.json`` gets the shared names of :func:`~neuralbrdf.evaluation.scores.fit_scores`
(``fit/inplane_glossy_rel_rmse``, ``fit/inplane_diffuse_rel_rmse``, and
``fit/plan_logcos_rmse`` with a truth), ``fit/abc/parameters`` (kd, A per channel; B, C, eta), ``fit/abc/success``,
``fit/abc/failure_reason`` and ``fit/abc/gaussian_limit`` (the lobe ended in the limit ``C -> ∞``,
stored as ``C = 1e4``; :mod:`neuralbrdf.fitting.abc_fit`): a failed fit is reported as failed (and warned about), never
passed off as a result.  Checkpoints carry ``neuralbrdf_kind = "abc"`` (:class:`~neuralbrdf.lightning.common.WritesKind`), ``abc_parameters`` and
``material`` for the exporter (:mod:`neuralbrdf.kinds.abc`).
"""

from __future__ import annotations

import numpy as np
from pytorch_lightning.utilities import rank_zero_warn

from neuralbrdf.errors import InputError
from neuralbrdf.fitting.abc_fit import AbcBounds, AbcFitResult, fit_abc
from neuralbrdf.lightning.common import WritesKind
from neuralbrdf.lightning.one_step_fit import OneStepFit
from neuralbrdf.physics.abc import AbcParameters
from neuralbrdf.sources import MaterialData, require_lobe


class AbcFitModule(WritesKind, OneStepFit):
    """Fits ABC parameters once (first training step); evaluates them in val/test.

    Parameters mirror :func:`~neuralbrdf.fitting.abc_fit.fit_abc`; ``bounds`` overrides fields
    of :class:`~neuralbrdf.fitting.abc_fit.AbcBounds` (e.g. ``{eta: [1.01, 10]}``; keys A, sharpness, C, eta).
    """

    def __init__(
        self, n_starts: int = 8, seed: int = 0, max_evaluations: int = 500, bounds: dict | None = None
    ) -> None:
        super().__init__()
        for key, value, least in (("n_starts", n_starts, 1), ("max_evaluations", max_evaluations, 1), ("seed", seed, 0)):
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise InputError(f"expected an integer >= {least}, got {value!r}", key=f"model.{key}")
        self.save_hyperparameters()
        self.bounds = AbcBounds.from_config(bounds)
        self.result: AbcFitResult | None = None
        self.parameters_: AbcParameters | None = None
        self.material_name: str | None = None

    def prepare_data(self) -> None:
        # after the data module read the material, before the run writes anything: a material
        # without a lobe is refused as bad input, not fitted into a failure at the lobe's bounds
        material = getattr(self.trainer.datamodule, "material", None) if self._trainer is not None else None
        if isinstance(material, MaterialData) and self.trainer.state.fn == "fit":
            require_lobe(material.fit, material.fit.source or material.name, "ABC")

    def training_step(self, material: MaterialData, batch_idx: int) -> None:
        if self.result is None:
            self.result = fit_abc(
                material.fit,
                n_starts=self.hparams.n_starts,
                seed=self.hparams.seed,
                bounds=self.bounds,
                max_evaluations=self.hparams.max_evaluations,
            )
            self.parameters_ = self.result.parameters
            self.material_name = material.name
            if not self.result.success:
                rank_zero_warn(f"ABC fit of {material.name} FAILED: {self.result.failure_reason}")
        self.log("train/loss", self.result.loss, batch_size=1)
        self.log("train/success", float(self.result.success), batch_size=1)
        self.log("train/wall_time_s", self.result.wall_time_s, batch_size=1)

    def fitted_values(self, table):
        return None if self.parameters_ is None else self.parameters_.evaluate(*table.vectors())

    def has_model(self) -> bool:
        return self.parameters_ is not None

    def fit_failure(self) -> str | None:
        """Why the fit failed, if it did (read by :class:`~neuralbrdf.lightning.fit_health.FitHealth`)."""
        if self.result is None or self.result.success:
            return None
        return f"ABC fit of {self.material_name}: {self.result.failure_reason}"

    def metrics_json_extras(self) -> dict:
        """Non-scalar results for ``metrics.json`` (read by :class:`~neuralbrdf.lightning.metrics_json.MetricsJson`)."""
        if self.result is None:
            return {}
        return {
            **self.scores,
            "abc/material": self.material_name,
            "abc/parameters": self.result.parameters.to_dict(),
            "abc/success": bool(self.result.success),
            "abc/failure_reason": self.result.failure_reason,
            "abc/gaussian_limit": bool(self.result.gaussian_limit),
            "abc/start_losses": [None if not np.isfinite(x) else float(x) for x in self.result.start_losses],
        }

    KIND = "abc"

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        super().on_save_checkpoint(checkpoint)
        if self.parameters_ is not None:
            checkpoint["abc_parameters"] = self.parameters_.to_dict()
            checkpoint["material"] = self.material_name
            checkpoint["abc_fit"] = {"success": self.result.success, "failure_reason": self.result.failure_reason}

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        if "abc_parameters" in checkpoint:
            self.parameters_ = AbcParameters.from_dict(checkpoint["abc_parameters"], source="checkpoint")
            self.material_name = checkpoint.get("material")
