"""``neuralbrdf plan next``: from what is measured so far, the pairs to measure next and how good the fit is now (docs/how-many-measurements.md).

1. **Fit** the measurement with the spectral NLB (:mod:`neuralbrdf.acquisition.latent_fit`: the
   codes ``neuralbrdf train fit --config nlb_spectral`` reaches).
2. **Linearise** the fitted material (:mod:`neuralbrdf.acquisition.nlb_linear`) and form the
   posterior of its codes after the measured values (a Laplace approximation: Gaussian prior of
   the pretrained codes, each value with the relative ``noise`` of the design settings):
   ``P = (P₀⁻¹ + Σ Jᵀ J / σ²)⁻¹`` (:func:`~neuralbrdf.acquisition.linear_design.posterior_covariance`).
3. **Choose** the ``count`` pairs of the instrument not measured yet (no pair of an orbit already
   measured, :mod:`neuralbrdf.acquisition.instrument`) that lower the expected relative
   hemisphere error most, one after the other
   (:func:`~neuralbrdf.acquisition.linear_design.greedy_design` on this one material).
4. **Estimate** the fit's error now: the posterior's spread of ``ln(1 + f cos θi)`` over the
   hemisphere, ``s = √tr(H P)`` in the units of ``hemisphere_logcos_rmse``, turned into an estimate
   and an interval by the calibration of :class:`EstimateSettings` — the quantiles of
   ``ln(true / s)`` over simulated sessions on the prior's training materials, and the same for
   the preview scene's ΔE2000 (``benchmarks/acquisition_calibration.py``; the interval is checked
   against the true errors of validation materials, ``benchmarks/acquisition.py``).  A target
   ΔE is met (*enough*) when the interval's upper end is within it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from neuralbrdf.acquisition.design import SCALE_FLOOR, DesignSettings
from neuralbrdf.acquisition.instrument import Instrument, pair_keys
from neuralbrdf.acquisition.latent_fit import FittedCodes, fit_module, fit_table
from neuralbrdf.acquisition.linear_design import LinearisedProblem, expected_errors, greedy_design, posterior_covariance
from neuralbrdf.acquisition.nlb_linear import SpectralNlbLinearisation, code_covariance
from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError


@dataclass(frozen=True)
class EstimateSettings:
    """The calibration of the error estimate (``configs/acquisition/default.yaml``, section ``estimate``):
    quantiles of ``ln(true / s)`` for the hemisphere log-cos RMSE, and of ``ln(ΔE / s)`` for the
    preview scene's mean CIEDE2000, at the interval's ends and middle (module docstring)."""

    interval: float                                  # the interval's coverage (0.8: from the 10 % to the 90 % quantile)
    logcos_quantiles: tuple[float, float, float]     # low end, middle, high end of ln(true / s)
    delta_e_quantiles: tuple[float, float, float]    # the same for ln(ΔE2000 / s)


@dataclass(frozen=True)
class Interval:
    """An estimate and its interval (``low``, ``high``)."""

    estimate: float
    low: float
    high: float


@dataclass(frozen=True)
class NextPairs:
    """What ``plan next`` answers: the pairs to measure next (signed degrees, in order), the spread
    ``s`` of the current fit, the estimates of its hemisphere log-cos RMSE and preview ΔE2000, the
    fit itself and the pairs measured so far."""

    theta_i: np.ndarray
    theta_r: np.ndarray
    spread: float
    logcos: Interval
    delta_e: Interval
    fitted: FittedCodes
    measured: int

    def enough(self, target_delta_e: float | None) -> bool | None:
        """Whether the interval's upper end of ΔE2000 is within ``target_delta_e`` (``None``: no target)."""
        return None if target_delta_e is None else self.delta_e.high <= target_delta_e


def interval(spread: float, quantiles: tuple[float, float, float]) -> Interval:
    low, middle, high = quantiles
    return Interval(spread * float(np.exp(middle)), spread * float(np.exp(low)), spread * float(np.exp(high)))


def measured_pairs(table: BrdfTable) -> tuple[np.ndarray, np.ndarray]:
    """The signed in-plane pairs of a table's in-plane rows (out-of-plane rows have none)."""
    rows = table.in_plane_mask()
    theta_i, theta_r = table.inplane_angles()
    return np.asarray(theta_i)[rows], np.asarray(theta_r)[rows]


def next_pairs(table: BrdfTable, count: int, instrument: Instrument, design: DesignSettings, estimate: EstimateSettings,
               *, module=None, name: str = "material") -> NextPairs:
    """The answer of ``plan next`` for a measured ``table`` (module docstring); ``module``: a
    :func:`~neuralbrdf.acquisition.latent_fit.fit_module` to reuse."""
    from neuralbrdf.evaluation.scores import hemisphere_pairs

    if table.n_rows < 1:
        raise InputError("holds no measured pair", path=table.source)
    theta_i, theta_r = instrument.candidates()
    done = {tuple(key) for key in pair_keys(*measured_pairs(table))}
    free = np.array([tuple(key) not in done for key in pair_keys(theta_i, theta_r)])
    if not isinstance(count, int) or isinstance(count, bool) or not 1 <= count <= int(free.sum()):
        raise InputError(f"expected a number of pairs from 1 to {int(free.sum())} (the pairs this instrument can still "
                         f"measure), got {count!r}", key="--count")
    module = module or fit_module()
    fitted = fit_table(table, name, module=module)
    linearisation = SpectralNlbLinearisation(fitted.network, fitted.interpolation)
    theta = fitted.parameters
    scale = fitted.scale.double().clamp_min(SCALE_FLOOR)                              # [K]
    as_tensor = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
    noise = (design.noise * scale)[None, :, None]
    measured = linearisation.jacobians(theta, *(as_tensor(v) for v in table.vectors())).double() / noise
    pretrained = module.pretrained
    prior = code_covariance(pretrained.shared, pretrained.channel_codes, linearisation.n_nodes)[None]
    covariance = posterior_covariance(prior, measured[None])
    hwi, hwo = (as_tensor(v) for v in hemisphere_pairs(design.seed, design.hemisphere_strata))
    jh = linearisation.jacobians(theta, hwi, hwo).double()
    absolute = torch.einsum("qki,qkj->ij", jh, jh)[None] / (jh.shape[0] * jh.shape[1])
    spread = float(expected_errors(covariance, absolute)[0].clamp_min(0.0).sqrt())
    relative = jh / scale[None, :, None]
    hemisphere = torch.einsum("qki,qkj->ij", relative, relative)[None] / (jh.shape[0] * jh.shape[1])
    from neuralbrdf.geometry import inplane_to_vectors

    ci, cr = theta_i[free], theta_r[free]
    candidates = linearisation.jacobians(theta, *(as_tensor(v) for v in inplane_to_vectors(ci, cr))).double() / noise
    chosen = np.asarray(greedy_design(LinearisedProblem(candidates[None], hemisphere, covariance), count).chosen)
    return NextPairs(ci[chosen], cr[chosen], spread, interval(spread, estimate.logcos_quantiles),
                     interval(spread, estimate.delta_e_quantiles), fitted, table.n_rows)

