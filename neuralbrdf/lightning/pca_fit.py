"""The ``pca`` fit (docs/models.md#pca): a new material's coefficients in the shipped PCA basis of
measured BRDFs (Nielsen, Jensen & Ramamoorthi 2015), by ridge least squares from its samples.

One material from :class:`~neuralbrdf.lightning.material_data.SingleMaterialData`, fitted in the
first training step (:func:`~neuralbrdf.models.pca_brdf.fit_channels`: the basis interpolated at
the measured pairs is the design matrix; each colour channel — R, G, B, or each band of a spectral
table — gets its own ``components`` coefficients, the ridge weight ``ridge`` trading them against
the training set's Gaussian prior).  The fitted material is a
:class:`~neuralbrdf.models.pca_brdf.PcaTable` — its mapped values baked into a
:class:`~neuralbrdf.models.baked_table.BakedTable` over the basis's nodes (and, for a spectral
table, over its bands), read by interpolation and unmapped — which is what is scored,
checkpointed and exported (:mod:`neuralbrdf.kinds.pca`).

A fit that cannot be made — no sample above the horizon, a non-finite value, a non-finite
solution — fails with that one-line cause (``fit_failure``) and leaves no ``best`` checkpoint.

``metrics.json`` gets the shared :func:`~neuralbrdf.evaluation.scores.fit_scores` and
``fit/pca/material``, ``fit/pca/components``, ``fit/pca/ridge``, ``fit/pca/channels``,
``fit/pca/inplane_logcos_rmse`` (on the measured samples), ``fit/pca/coefficients`` (per channel),
``fit/pca/basis_sha256`` and ``fit/pca/fit_s``.  Checkpoints carry ``neuralbrdf_kind = "pca"``,
``material``, ``pca_mapped`` (the mapped values at the nodes, ``[n_h, n_d, n_p, C]``),
``pca_mapping`` and ``pca_epsilon`` (the basis's mapping), ``pca_wavelength_range_nm`` (``None`` for
RGB), ``pca_coefficients``, ``pca_components``, ``pca_ridge`` and ``pca_basis_sha256``.
"""

from __future__ import annotations

import time

import numpy as np

from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError
from neuralbrdf.lightning.common import WritesKind, values_at_table
from neuralbrdf.lightning.one_step_fit import OneStepFit
from neuralbrdf.metrics import hemisphere_logcos_rmse
from neuralbrdf.models import pca_brdf
from neuralbrdf.models.pca_brdf import PcaTable
from neuralbrdf.sources import MaterialData


def table_values(model: PcaTable, table: BrdfTable) -> np.ndarray:
    """``model`` at ``table``'s pairs ``[N, C]``: at its bands (spectral model) or in linear sRGB."""
    return values_at_table(model, table, model.wavelength_range_nm is not None)


class PcaFitModule(WritesKind, OneStepFit):
    """Fits the PCA coefficients once (first training step); evaluates the baked table in val/test.

    Parameters
    ----------
    components:
        Principal components used (``K``, at most the basis file's).
    ridge:
        The ridge weight ``λ`` of ``‖Φ c − (y − μ)‖² + λ Σ_k (c_k / s_k)²`` (``≥ 0``).
    basis:
        The basis file (``None``: the shipped ``neuralbrdf/pretrained/pca_basis.npz``).
    """

    KIND = "pca"

    def __init__(self, components: int = 32, ridge: float = 0.003, basis: str | None = None) -> None:
        super().__init__()
        if isinstance(ridge, bool) or not isinstance(ridge, (int, float)) or not np.isfinite(ridge) or ridge < 0:
            raise InputError(f"expected a finite number >= 0, got {ridge!r}", key="model.ridge")
        self.save_hyperparameters()
        try:
            self.basis = pca_brdf.load_basis(basis).truncated(components)
        except InputError as error:
            key = None if error.key is None else ("model.components" if error.key == "components" else error.key)
            raise InputError(error.reason, path=error.path, key=key) from None
        self.material_name: str | None = None
        self.coefficients: np.ndarray | None = None
        self.wavelength_range_nm: tuple[float, float] | None = None
        #: ``{"model": PcaTable}`` once fitted (a dict, so that the table is no submodule of the run's state)
        self.fitted: dict[str, PcaTable] = {}
        self.inplane_error: float | None = None
        self.fit_seconds: float | None = None

    # ------------------------------------------------------------------ the fit

    def fit_table(self, table: BrdfTable) -> None:
        """Fit every channel of ``table``; on failure set :attr:`failure` (one line) and keep no model."""
        began = time.perf_counter()
        try:
            wi, wo = table.vectors()
            coefficients = pca_brdf.fit_channels(self.basis, wi, wo, table.values, float(self.hparams.ridge),
                                                 source=table.source)
            wavelength_range = (float(table.wavelengths[0]), float(table.wavelengths[-1])) if table.is_spectral else None
            model = pca_brdf.pca_table(self.basis, coefficients, wavelength_range).eval()
            error = hemisphere_logcos_rmse(table_values(model, table), table.values, table.theta_i)
        except (InputError, ValueError) as error:
            reason = error.reason if isinstance(error, InputError) else str(error)
            self.failure = f"PCA fit of {self.material_name}: {' '.join(reason.split())}"
            return
        if not np.isfinite(error):
            self.failure = f"PCA fit of {self.material_name}: the fitted model's in-plane error is not finite"
            return
        self.coefficients, self.wavelength_range_nm = coefficients, wavelength_range
        self.fitted["model"] = model
        self.inplane_error = float(error)
        self.fit_seconds = time.perf_counter() - began

    @property
    def model_(self) -> PcaTable | None:
        """The fitted material's table, ``None`` before the fit or after a failed one."""
        return self.fitted.get("model")

    def training_step(self, material: MaterialData, batch_idx: int) -> None:
        if self.model_ is None and self.failure is None:
            self.material_name = material.name
            self.fit_table(material.fit)
        if self.model_ is not None:
            self.log("train/loss", float(self.inplane_error), batch_size=1)

    def fitted_values(self, table: BrdfTable) -> np.ndarray | None:
        return None if self.model_ is None else table_values(self.model_, table)

    def has_model(self) -> bool:
        return self.model_ is not None

    def metrics_json_extras(self) -> dict:
        """Non-scalar results for ``metrics.json`` (read by :class:`~neuralbrdf.lightning.metrics_json.MetricsJson`)."""
        if self.model_ is None:
            return {}
        return {
            **self.scores,
            "pca/material": self.material_name,
            "pca/components": self.basis.n_components,
            "pca/ridge": float(self.hparams.ridge),
            "pca/channels": int(self.coefficients.shape[0]),
            "pca/inplane_logcos_rmse": self.inplane_error,
            "pca/coefficients": self.coefficients.tolist(),
            "pca/basis_sha256": self.basis.sha256,
            "pca/fit_s": self.fit_seconds,
        }

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        super().on_save_checkpoint(checkpoint)
        if self.model_ is None:
            return
        checkpoint["material"] = self.material_name
        checkpoint["pca_mapped"] = self.model_.mapped.detach().clone()
        checkpoint["pca_mapping"] = self.basis.mapping
        checkpoint["pca_epsilon"] = self.basis.epsilon
        checkpoint["pca_wavelength_range_nm"] = (None if self.wavelength_range_nm is None
                                                 else [float(w) for w in self.wavelength_range_nm])
        checkpoint["pca_coefficients"] = self.coefficients.tolist()
        checkpoint["pca_components"] = self.basis.n_components
        checkpoint["pca_ridge"] = float(self.hparams.ridge)
        checkpoint["pca_basis_sha256"] = self.basis.sha256
