"""The ``auto`` fit (docs/models.md#auto): the ABC fit and the spectral NLB's latent fit of one
measurement, and the one of the two that fits the measured pairs better.

A user with one measurement cannot know whether their material is close to ABC's analytic form
(paints, rubbers, fabrics, diffuse standards, where ABC's error can be half the prior's) or
beyond it (where the spectral NLB's prior wins).  This module fits both candidates to the same
samples, each as its own kind's shipped config fits it (``abc_config`` and
``nlb_spectral_config``, read by :mod:`neuralbrdf.lightning.config_models`; the ABC fit of Löw
et al. 2012, Eq. 4.2, from ``abc_starts`` starts, and the latent-only fit of the spectral NLB), and keeps the candidate whose
log-cosine RMSE on the measured samples (:func:`~neuralbrdf.metrics.hemisphere_logcos_rmse` over
the table's pairs and channels: the error the report's Eq. 4.1 weighs, the same number for
either candidate) is lower.  A candidate that cannot fit (ABC on a surface without a lobe, or an
ABC fit that failed) is not chosen; when neither fits, the fit fails.

Why a choice and not a blend or a cross-validated choice: on the validation materials a convex
blend with its weight fitted to the measured pairs, hedged choices and fixed blends were each
measured against this rule (docs/design.md "Never worse than ABC", benchmarks/auto.py); the
choice was as good or better on every summary and is the simplest.  The two fits run side by side
(ABC's in a thread), so the choice costs about the slower of the two.

``metrics.json`` gets ``fit/auto/choice``, ``fit/auto/inplane_logcos_rmse`` (per candidate),
``fit/auto/abc_failure`` (why ABC was not a candidate, else ``None``) and ``fit/auto/fit_s`` (per
candidate), beside the shared :func:`~neuralbrdf.evaluation.scores.fit_scores` of the chosen
model.  Checkpoints carry ``neuralbrdf_kind = "auto"``, ``auto_choice``, ``auto_inplane_logcos_rmse``,
``material``, the ABC parameters (``abc_parameters``, when ABC fitted) and the spectral NLB fit
(``nlb_spectral_fit``: the entries of a spectral NLB fit checkpoint) for the exporter
(:mod:`neuralbrdf.kinds.auto`).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict

import numpy as np

from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError
from neuralbrdf.fitting.abc_fit import fit_abc
from neuralbrdf.lightning.common import WritesKind, values_at_table
from neuralbrdf.lightning.one_step_fit import OneStepFit
from neuralbrdf.lightning.config_models import ABC_CONFIG, SPECTRAL_NLB_CONFIG, abc_settings, spectral_latent_fit
from neuralbrdf.lightning.latent_fit_data import table_samples
from neuralbrdf.metrics import hemisphere_logcos_rmse
from neuralbrdf.models.directional import SpectralNlbWithCodes
from neuralbrdf.physics.abc import AbcParameters
from neuralbrdf.sources import MaterialData, require_lobe

#: The candidates, by kind name, in the order a tie is broken (the analytic model first).
CANDIDATES = ("abc", "nlb_spectral")
#: The words of the fit's failure when neither candidate gave a model (read by the study's cells).
NEITHER_FITTED = "neither candidate fitted"


def _nlb_values(model: SpectralNlbWithCodes, table: BrdfTable) -> np.ndarray:
    """``model`` at ``table``'s pairs ``[N, C]``: at its bands (spectral) or in linear sRGB."""
    return values_at_table(model, table, model.is_spectral)


def choose(errors: dict[str, float | None]) -> str | None:
    """The candidate of lowest in-plane error among those that fitted (``None``: did not), ties
    to the earlier of :data:`CANDIDATES`; ``None`` when none did."""
    fitted = [kind for kind in CANDIDATES if errors.get(kind) is not None and np.isfinite(errors[kind])]
    if not fitted:
        return None
    return min(fitted, key=lambda kind: (errors[kind], CANDIDATES.index(kind)))


class AutoFitModule(WritesKind, OneStepFit):
    """Fits both candidates once (first training step) and keeps the better (module docstring).

    Parameters
    ----------
    abc_config:
        The config whose ``model.init_args`` the ABC candidate is fitted with (a shipped name or a
        YAML file); default the shipped ``abc``.
    nlb_spectral_config:
        The same for the spectral NLB candidate; default the shipped ``nlb_spectral``.
    abc_starts:
        Starts of the ABC candidate's fit instead of its config's ``n_starts`` (``None``: the
        config's); the rest of the ABC settings are the config's.
    """

    KIND = "auto"

    def __init__(self, abc_config: str = ABC_CONFIG, nlb_spectral_config: str = SPECTRAL_NLB_CONFIG,
                 abc_starts: int | None = None) -> None:
        super().__init__()
        if abc_starts is not None and (isinstance(abc_starts, bool) or not isinstance(abc_starts, int)
                                       or abc_starts < 1):
            raise InputError(f"expected an integer >= 1 or null, got {abc_starts!r}", key="model.abc_starts")
        self.save_hyperparameters()
        # both configs read and their settings checked before the run writes anything; the NLB's module
        # is built again for the fit (_fit_nlb): built here, inside LightningCLI's instantiation, it
        # would record this module's hyperparameters as its own
        self._abc_arguments = abc_settings(abc_config)
        if abc_starts is not None:
            self._abc_arguments["n_starts"] = abc_starts
        spectral_latent_fit(nlb_spectral_config)
        self.material_name: str | None = None
        self.choice: str | None = None
        self.errors: dict[str, float | None] = {}
        self.fit_seconds: dict[str, float] = {}
        self.abc_failure: str | None = None
        self.abc_parameters: AbcParameters | None = None
        self.nlb_model: SpectralNlbWithCodes | None = None
        self.nlb_checkpoint: dict | None = None

    # ------------------------------------------------------------------ the fit

    def _fit_abc(self, table: BrdfTable) -> None:
        began = time.perf_counter()
        try:
            require_lobe(table, table.source or self.material_name, "ABC")
        except InputError as error:
            self.abc_failure = error.reason
            return
        result = fit_abc(table, **self._abc_arguments)
        self.fit_seconds["abc"] = time.perf_counter() - began
        if not result.success:
            self.abc_failure = result.failure_reason
            return
        self.abc_parameters = result.parameters
        self.errors["abc"] = hemisphere_logcos_rmse(result.parameters.evaluate(*table.vectors()), table.values,
                                                    table.theta_i)

    def _fit_nlb(self, table: BrdfTable) -> None:
        began = time.perf_counter()
        module = spectral_latent_fit(self.hparams.nlb_spectral_config)
        wavelengths = np.asarray(table.wavelengths, dtype=np.float64) if table.is_spectral else None
        module.fit_samples([self.material_name], table_samples(0, table, table.is_spectral), wavelengths)
        nodes = module.node_wavelengths_nm
        self.nlb_model = SpectralNlbWithCodes(
            module.network, module.latents.shared[0].detach().clone(), module.latents.channels[0].detach().clone(),
            None if nodes is None else tuple(float(w) for w in nodes)).eval()
        self.nlb_checkpoint = {
            "spectral_nlb_config": asdict(module.network.config),
            "material_names": [self.material_name],
            "node_wavelengths_nm": None if nodes is None else [float(w) for w in nodes],
            "state_dict": {key: value.detach().clone() for key, value in module.state_dict().items()},
        }
        self.fit_seconds["nlb_spectral"] = time.perf_counter() - began
        pred = np.clip(_nlb_values(self.nlb_model, table), 0.0, None)
        self.errors["nlb_spectral"] = hemisphere_logcos_rmse(pred, table.values, table.theta_i)

    def training_step(self, material: MaterialData, batch_idx: int) -> None:
        if self.choice is None:
            self.material_name = material.name
            self.errors = {kind: None for kind in CANDIDATES}
            # the two fits side by side: ABC's optimiser in a thread while the NLB's runs here (both
            # mostly in PyTorch kernels that release the GIL; torch runs single-threaded, num_threads: 1)
            with ThreadPoolExecutor(max_workers=1, thread_name_prefix="abc-fit") as pool:
                abc_done = pool.submit(self._fit_abc, material.fit)
                self._fit_nlb(material.fit)
                abc_done.result()
            self.choice = choose(self.errors)
            if self.choice is None:
                self.failure = (f"auto fit of {self.material_name}: {NEITHER_FITTED} (ABC: {self.abc_failure}; "
                                f"spectral NLB: in-plane error {self.errors['nlb_spectral']})")
                return
        self.log("train/loss", float(self.errors[self.choice]), batch_size=1)

    def fitted_values(self, table: BrdfTable) -> np.ndarray | None:
        """The chosen model at ``table``'s pairs ``[N, C]`` (sr⁻¹); ``None`` before the choice."""
        if self.choice is None:
            return None
        if self.choice == "abc":
            return self.abc_parameters.evaluate(*table.vectors())
        return _nlb_values(self.nlb_model, table)

    def has_model(self) -> bool:
        return self.choice is not None

    def metrics_json_extras(self) -> dict:
        """Non-scalar results for ``metrics.json`` (read by :class:`~neuralbrdf.lightning.metrics_json.MetricsJson`)."""
        if self.choice is None:
            return {}
        return {
            **self.scores,
            "auto/material": self.material_name,
            "auto/choice": self.choice,
            "auto/inplane_logcos_rmse": dict(self.errors),
            "auto/abc_failure": self.abc_failure,
            "auto/fit_s": dict(self.fit_seconds),
            **({"auto/abc_parameters": self.abc_parameters.to_dict()} if self.abc_parameters is not None else {}),
        }

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        super().on_save_checkpoint(checkpoint)
        if self.choice is None:
            return
        checkpoint["material"] = self.material_name
        checkpoint["auto_choice"] = self.choice
        checkpoint["auto_inplane_logcos_rmse"] = dict(self.errors)
        checkpoint["nlb_spectral_fit"] = self.nlb_checkpoint
        if self.abc_parameters is not None:
            checkpoint["abc_parameters"] = self.abc_parameters.to_dict()
