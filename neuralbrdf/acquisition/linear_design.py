"""Greedy Bayesian optimal design on a linearised model: which pairs reduce the expected hemisphere error most (docs/how-many-measurements.md).

A fit estimates a material's parameters ``θ`` (a latent code, ABC's parameters, PCA
coefficients) from its measured values ``y(p, θ)`` at pairs ``p``, in the fit's own domain
(``ln(1 + f cos θi)`` per channel).  Linearised at ``θ`` — ``y(p, θ + δ) ≈ y(p, θ) + J(p) δ``,
``J(p)`` ``[K channels, D]`` — with a Gaussian prior ``δ ~ N(0, P₀)`` and measurement noise of
standard deviation ``σ`` per value, the posterior after measuring the pairs ``S`` is Gaussian
with covariance (Chaloner & Verdinelli 1995, *Bayesian experimental design: a review*, §2.1)::

    P(S) = (P₀⁻¹ + Σ_{p ∈ S} J(p)ᵀ J(p) / σ²)⁻¹

and the expected squared error of the fitted model over the hemisphere is ``tr(H P(S))``, where
``H = mean_q J(q)ᵀ J(q)`` over hemisphere pairs ``q`` and channels: the Bayesian *I-optimal*
(integrated prediction variance) criterion.  A nonlinear model has one ``J`` per material, so
the design minimises the criterion averaged over a set of materials (a prior over materials;
Chaloner & Larntz 1989's pseudo-Bayesian design).

:func:`greedy_design` adds one pair at a time, the one that lowers the mean criterion most.
Adding ``p`` updates the covariance by a rank-``K`` correction (Woodbury)::

    P ← P − P Jᵀ S⁻¹ J P,   S = σ² I + J P Jᵀ,   gain(p) = tr(S⁻¹ J P H P Jᵀ)

so each step costs one small solve per (material, candidate), whatever the number of pairs
chosen.  The criterion is a monotone supermodular-like set function for which greedy selection
is the standard near-optimal choice (Krause, Singh & Guestrin 2008).  A pair may be chosen again:
with noise a repeated measurement still lowers the variance, and it is up to the caller to
forbid repeats (``allow_repeats``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

#: Materials × candidates handled in one batch of the greedy step (bounds its memory, ~100 MB).
BATCH_ENTRIES = 2**16
#: Candidates whose gains a lazy greedy step evaluates again (:func:`greedy_design`).
LAZY_CANDIDATES = 64


@dataclass(frozen=True)
class LinearisedProblem:
    """The design problem of :func:`greedy_design`, in float64.

    ``jacobians`` ``[M, C, K, D]``: per material ``m`` and candidate ``c`` the Jacobian of the
    ``K`` values a measurement gives, already divided by their noise (so ``σ = 1``);
    ``hemisphere`` ``[M, D, D]``: each material's ``H`` (weighted as the caller wants materials
    to count); ``covariance`` ``[M, D, D]``: each material's covariance before the design (the
    prior, or the posterior of what was measured already)."""

    jacobians: torch.Tensor
    hemisphere: torch.Tensor
    covariance: torch.Tensor

    def __post_init__(self) -> None:
        m, c, k, d = self.jacobians.shape
        if self.hemisphere.shape != (m, d, d) or self.covariance.shape != (m, d, d):
            raise ValueError(f"jacobians {tuple(self.jacobians.shape)} need hemisphere and covariance [{m}, {d}, {d}], "
                             f"got {tuple(self.hemisphere.shape)} and {tuple(self.covariance.shape)}")


@dataclass(frozen=True)
class Design:
    """The chosen candidates in order, the criterion (mean over materials of ``tr(H P)``) before the
    first and after each, and each material's final covariance ``[M, D, D]``."""

    chosen: list[int]
    criterion: list[float]
    covariance: torch.Tensor


def expected_errors(covariance: torch.Tensor, hemisphere: torch.Tensor) -> torch.Tensor:
    """``tr(H_m P_m)`` per material ``[M]``: the expected squared error over the hemisphere."""
    return torch.einsum("mij,mji->m", hemisphere, covariance)


def posterior_covariance(covariance: torch.Tensor, jacobians: torch.Tensor) -> torch.Tensor:
    """The covariance ``[M, D, D]`` after measuring, per material, the values of ``jacobians``
    ``[M, N, K, D]`` (noise 1), from ``covariance`` ``[M, D, D]``: the information form
    ``(P⁻¹ + Σ Jᵀ J)⁻¹``."""
    rows = jacobians.reshape(jacobians.shape[0], -1, jacobians.shape[-1]).double()
    precision = torch.linalg.inv(covariance) + rows.transpose(1, 2) @ rows
    inverse = torch.linalg.inv(precision)
    return 0.5 * (inverse + inverse.transpose(1, 2))


def _gains(problem: LinearisedProblem, covariance: torch.Tensor, subset: torch.Tensor | None = None) -> torch.Tensor:
    """``gain(p)`` of the candidates ``subset`` (default all), summed over materials (module docstring)."""
    jacobians = problem.jacobians if subset is None else problem.jacobians[:, subset]
    m, c, k, d = jacobians.shape
    php = covariance @ problem.hemisphere @ covariance
    gains = torch.zeros(c, dtype=torch.float64)
    per_material = max(1, BATCH_ENTRIES // max(c, 1))
    eye = torch.eye(k, dtype=torch.float64)
    for start in range(0, m, per_material):
        stop = min(m, start + per_material)
        step = max(1, BATCH_ENTRIES // (stop - start))
        for first in range(0, c, step):
            j = jacobians[start:stop, first:first + step].double()               # [b, c, K, D]
            s = torch.einsum("mckd,mde,mcle->mckl", j, covariance[start:stop], j) + eye
            # tr(S⁻¹ J M Jᵀ) = Σ (Y M) ∘ Y with Y = L⁻¹ J, S = L Lᵀ
            y = torch.linalg.solve_triangular(torch.linalg.cholesky(s), j, upper=False)
            gains[first:first + step] += (torch.einsum("mckd,mde->mcke", y, php[start:stop]) * y).sum((0, 2, 3))
    return gains


def greedy_design(problem: LinearisedProblem, budget: int, *, allow_repeats: bool = False,
                  progress: Callable[[int], None] | None = None) -> Design:
    """``budget`` candidates chosen one at a time, each lowering the mean criterion most (module
    docstring); ``progress(i)`` is called after the ``i``-th.

    Gains are evaluated lazily (Minoux 1978): a gain only falls as pairs are added (a measurement
    tells less the more is known), so after the first step only the :data:`LAZY_CANDIDATES`
    candidates of largest earlier gain are evaluated again, and the best of them is taken when no
    other candidate's earlier gain exceeds its gain now; otherwise every gain is evaluated again."""
    m, c = problem.jacobians.shape[:2]
    if not allow_repeats and budget > c:
        raise ValueError(f"a budget of {budget} pairs needs as many candidates, got {c}")
    covariance = problem.covariance.double().clone()
    hemisphere = problem.hemisphere.double()
    chosen: list[int] = []
    criterion = [float(expected_errors(covariance, hemisphere).mean())]
    bounds = _gains(problem, covariance)
    for step in range(budget):
        if step:
            if not allow_repeats:
                bounds[chosen] = -torch.inf
            order = torch.argsort(bounds, descending=True)
            top = order[:LAZY_CANDIDATES]
            bounds[top] = _gains(problem, covariance, top)
            best_top = top[int(torch.argmax(bounds[top]))]
            rest = order[LAZY_CANDIDATES:]
            if len(rest) and bounds[best_top] < bounds[rest].max():
                bounds = _gains(problem, covariance)
        if not allow_repeats:
            bounds[chosen] = -torch.inf
        best = int(torch.argmax(bounds))
        j = problem.jacobians[:, best].double()                                 # [M, K, D]
        jp = j @ covariance
        s = jp @ j.transpose(1, 2) + torch.eye(j.shape[1], dtype=torch.float64)
        covariance = covariance - jp.transpose(1, 2) @ torch.linalg.solve(s, jp)
        covariance = 0.5 * (covariance + covariance.transpose(1, 2))
        chosen.append(best)
        criterion.append(float(expected_errors(covariance, hemisphere).mean()))
        if progress is not None:
            progress(step + 1)
    return Design(chosen, criterion, covariance)
