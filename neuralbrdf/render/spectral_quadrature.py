"""Fewer wavelengths for rendering a spectral model in an RGB variant (docs/formats.md#spectral-to-linear-srgb, docs/mitsuba-plugin.md).

In RGB variants the ``neuralbrdf`` BSDF returns a spectral model's linear sRGB value, the
integral of docs/formats.md#spectral-to-linear-srgb (CIE 1931 2° × D65, IEC 61966-2-1 matrix) on the 31-wavelength grid
400–700 nm at 10 nm::

    rgb_c(wi, wo) = Σ_{k=1..31} W[k, c] f(wi, wo, λ_k)

That is 31 network evaluations per query.  The spectra a trained model produces are smooth in
λ and span a low-dimensional space, so the same integral is reproduced by a few of the 31
wavelengths with re-fitted weights: an *empirical quadrature* for this model (the idea of
empirical interpolation and empirical cubature; Barrault et al. 2004, Hernández et al. 2017)::

    rgb_c ≈ Σ_{j=1..K} V[j, c] f(wi, wo, λ_{k_j})

:func:`fit_reduced_quadrature` chooses the nodes ``k_j`` greedily (each step adds the grid
wavelength that most reduces the fit error) and the weights ``V`` by least squares, on spectra
of the model itself, *relative* to each probe's colour so that dim directions count as much as
the specular peak.  It stops at the first ``K`` whose error on probes held out of the fit meets
the tolerance (root-mean-square ``rms_tolerance``, default :data:`DEFAULT_RMS_TOLERANCE`, and
largest :data:`MAX_TO_RMS` times that); the reached error is reported with the rule.  A model
whose spectra do not compress keeps all 31 wavelengths, and ``rms_tolerance = 0`` asks for
them: then the rule is the full integral, exactly.

:func:`full_rule` is the full integral itself, and :class:`RuleRgbEvaluator` evaluates a model
through a rule (what the plugin returns), for the fast paths and ladder rungs that are measured
against it.

Error measure: per probe, ``|rgb_K − rgb_31|₂ / (|rgb_31|₂ + floor)`` with ``floor`` =
:data:`RELATIVE_FLOOR` × the largest ``|rgb_31|₂`` among the probes (values far below the peak
are judged against it, not against themselves).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from neuralbrdf.data.colorimetry import SRGB_GRID_NM, XYZ_TO_LINEAR_SRGB, xyz_weights

#: Default held-out root-mean-square relative error the reduced rule must meet.
DEFAULT_RMS_TOLERANCE = 1e-3

#: The largest held-out relative error may be this many times the rms tolerance.
MAX_TO_RMS = 10.0

#: Floor of the relative error's denominator, as a fraction of the brightest probe colour.
RELATIVE_FLOOR = 1e-3

#: Fraction of the probes held out of the fit to measure its error.
HOLDOUT_FRACTION = 0.5


@dataclass(frozen=True)
class ReducedQuadrature:
    """``rgb = Σ_j weights[j] · f(wavelengths_nm[j])``, with its held-out error."""

    wavelengths_nm: tuple[float, ...]
    weights: np.ndarray  # [K, 3]
    rms_relative_error: float
    max_relative_error: float
    full_size: int

    @property
    def size(self) -> int:
        return len(self.wavelengths_nm)

    def describe(self) -> str:
        return (
            f"{self.size} of {self.full_size} wavelengths "
            f"({', '.join(f'{w:g}' for w in self.wavelengths_nm)} nm; held-out relative error "
            f"rms {self.rms_relative_error:.1e}, max {self.max_relative_error:.1e})"
        )


def _relative_errors(approx: np.ndarray, exact: np.ndarray, floor: float) -> np.ndarray:
    return np.linalg.norm(approx - exact, axis=1) / (np.linalg.norm(exact, axis=1) + floor)


def _solve(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares weights ``[K, 3]`` of ``a @ v ≈ b`` and the squared residual norm."""
    v, *_ = np.linalg.lstsq(a, b, rcond=None)
    r = a @ v - b
    return v, float(np.sum(r * r))


def fit_reduced_quadrature(
    spectra: np.ndarray,
    wavelengths_nm: np.ndarray,
    weights: np.ndarray,
    rms_tolerance: float = DEFAULT_RMS_TOLERANCE,
    seed: int = 0,
) -> ReducedQuadrature:
    """The smallest node subset of ``wavelengths_nm`` reproducing ``spectra @ weights``.

    Parameters
    ----------
    spectra:
        ``[M, W]`` model values of ``M`` probe direction pairs at the ``W`` grid wavelengths.
    wavelengths_nm:
        ``[W]`` grid, nm.
    weights:
        ``[W, 3]`` full rule (spectrum → linear sRGB).
    rms_tolerance:
        Held-out rms relative error to meet (module docstring); 0: the full rule.
    seed:
        Seed of the fit / held-out split of the probes.
    """
    spectra = np.asarray(spectra, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    n_probes, n_wavelengths = spectra.shape
    if weights.shape != (n_wavelengths, 3) or len(wavelengths_nm) != n_wavelengths:
        raise ValueError(
            f"spectra {spectra.shape}, wavelengths {len(wavelengths_nm)} and weights "
            f"{weights.shape} do not match ([M, W], [W], [W, 3])"
        )
    if n_probes < 2 or not np.all(np.isfinite(spectra)):
        raise ValueError("need at least two probe spectra, all finite")
    if not 0.0 <= rms_tolerance < 1.0:
        raise ValueError(f"rms_tolerance must be in [0, 1), got {rms_tolerance}")
    exact = spectra @ weights
    floor = RELATIVE_FLOOR * max(float(np.linalg.norm(exact, axis=1).max()), 1e-30)
    row_weights = 1.0 / (np.linalg.norm(exact, axis=1) + floor)
    order = np.random.default_rng(seed).permutation(n_probes)
    n_holdout = max(1, int(round(HOLDOUT_FRACTION * n_probes)))
    held, fit = order[:n_holdout], order[n_holdout:]
    # The fit rows, each scaled by its weight (relative least squares), and the held-out rows.
    fit_a = spectra[fit] * row_weights[fit, None]
    fit_b = exact[fit] * row_weights[fit, None]
    held_spectra, held_exact = spectra[held], exact[held]

    nodes: list[int] = []
    while rms_tolerance > 0 and len(nodes) < n_wavelengths:
        candidates = [k for k in range(n_wavelengths) if k not in nodes]
        solutions = [_solve(fit_a[:, nodes + [k]], fit_b) for k in candidates]
        best = int(np.argmin([residual for _, residual in solutions]))
        nodes.append(candidates[best])
        v = solutions[best][0]
        errors = _relative_errors(held_spectra[:, nodes] @ v, held_exact, floor)
        rms, worst = float(np.sqrt(np.mean(errors**2))), float(errors.max())
        if rms <= rms_tolerance and worst <= MAX_TO_RMS * rms_tolerance:
            break
    if len(nodes) in (0, n_wavelengths):
        nodes, v, rms, worst = list(range(n_wavelengths)), weights, 0.0, 0.0
    order_by_wavelength = np.argsort([wavelengths_nm[k] for k in nodes])
    nodes = [nodes[i] for i in order_by_wavelength]
    return ReducedQuadrature(
        wavelengths_nm=tuple(float(wavelengths_nm[k]) for k in nodes),
        weights=np.ascontiguousarray(v[order_by_wavelength]),
        rms_relative_error=rms,
        max_relative_error=worst,
        full_size=n_wavelengths,
    )


def srgb_weights() -> np.ndarray:
    """``[W, 3]`` weights from values on :data:`SRGB_GRID_NM` to linear sRGB (docs/formats.md#spectral-to-linear-srgb)."""
    return xyz_weights(SRGB_GRID_NM) @ XYZ_TO_LINEAR_SRGB.T


def full_rule(wavelength_range_nm: tuple[float, float]) -> ReducedQuadrature:
    """The whole integral of docs/formats.md#spectral-to-linear-srgb as a rule: all 31 grid wavelengths (clamped to a model's
    range, as the plugin clamps its queries) with their weights; error 0 by definition."""
    grid = np.clip(SRGB_GRID_NM, *wavelength_range_nm)
    return ReducedQuadrature(tuple(float(w) for w in grid), srgb_weights(), 0.0, 0.0, len(grid))


class RuleRgbEvaluator:
    """A spectral model's linear sRGB through a rule, negatives clipped (what the plugin returns in
    RGB variants): an RGB evaluator (``values(wi, wo)`` ``[N, 3]``) of a spectral ``parent``
    (an :class:`~neuralbrdf.evaluation.scores.Evaluator`), the rule's nodes evaluated in one call."""

    is_spectral = False

    def __init__(self, parent, rule: ReducedQuadrature) -> None:
        self.parent, self.rule = parent, rule

    def values(self, wi, wo, wavelength=None):
        n, k = len(wi), self.rule.size
        spectra = self.parent.values(np.tile(wi, (k, 1)), np.tile(wo, (k, 1)),
                                     np.repeat(np.asarray(self.rule.wavelengths_nm), n)).reshape(k, n)
        return np.clip(np.clip(spectra, 0.0, None).T @ self.rule.weights, 0.0, None)
