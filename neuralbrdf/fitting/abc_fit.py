"""Fitting the ABC model to a BRDF sample table (report §4.1.1, SPEC §4.1).

Following the report (after Löw et al. 2012):

1. ``kd = π · min(f)`` per channel — the specular term is non-negative and smallest far from
   the mirror direction, so the smallest measured value estimates the diffuse level ``kd/π``.
2. ``A`` (per channel), ``B``, ``C`` and ``η`` minimise ``L_cus`` (report Eq. 4.2,
   :func:`neuralbrdf.losses.log_cosine_loss`) within bounds, from several starts; the best
   start wins.

**Optimiser.**  SciPy's truncated-Newton method with box bounds (TNC) on a loss and gradient
computed by torch (float64, autograd through :func:`neuralbrdf.physics.abc.abc_brdf`,
vectorised over the samples).  A box-bounded optimiser was chosen over torch's LBFGS with a
squashing reparametrisation because a parameter that wants to leave the box then ends *on* the
bound, where it is detected and reported, instead of creeping towards it with a vanishing
gradient.  TNC rather than L-BFGS-B: both find the same minima here, but L-BFGS-B's small
BLAS/LAPACK calls go through SciPy's multithreaded OpenBLAS, whose thread wake-ups dominate the
fit time on a loaded machine; TNC is self-contained C (``benchmarks/README.md``, design measurements).  ``A``, ``B`` and
``η`` are optimised as logarithms (they span decades: Löw's ``B`` runs from 12 to 8·10⁶), ``C``
as is.  The loss is divided by that of the diffuse-only model (``kd/π`` everywhere) so that
the optimiser's tolerances see a quantity of order one.

**Starts.**  ``B``, ``C``, ``η`` are drawn uniformly (``log B``, ``C``, ``log η``) from a
plausible sub-box of the bounds (:attr:`AbcBounds.start_box`) with the seeded generator, the
first start at the sub-box centre; given those, each channel's ``A`` starts at the best of a
log-spaced grid (the loss separates over channels for fixed ``B, C, η``).

**Threads.**  The tensors are small (a DS1 RGB table is 1001 × 3), so torch's intra-op
threads only add synchronisation (``benchmarks/README.md``, design measurements).  :func:`fit_abc` therefore runs torch single-threaded and restores the previous thread
count when it returns (``torch.set_num_threads`` is process-wide).

**Failure.**  A result has ``success = False`` and a ``failure_reason`` when the best start's
loss or parameters are non-finite, when no start's optimiser reported convergence, when a
parameter ends within 0.1 % of the box width of a bound (in the optimised coordinates), or when
the loss did not improve on the start point or on the diffuse-only model (e.g. data with no
specular signal).  The parameters are still returned for inspection.
"""

from __future__ import annotations

import math
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import scipy.optimize
import torch

from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError
from neuralbrdf.losses import log_cosine_loss, log_cosine_terms
from neuralbrdf.physics.abc import AbcParameters, abc_brdf

#: A parameter within this fraction of its box width from a bound counts as pinned.
PINNED_FRACTION = 1e-3

#: Relative loss decrease below which a fit "did not improve".
IMPROVEMENT_RTOL = 1e-6

#: Number of log-spaced values tried for each channel's starting ``A``.
A_GRID_SIZE = 97


@dataclass(frozen=True)
class AbcBounds:
    """Box bounds of the fitted parameters (``A`` per channel, ``B``, ``C``, ``eta``).

    ``start_box`` is the sub-box of ``(B, C, eta)`` that random starts are drawn from.
    """

    A: tuple[float, float] = (1e-8, 1e6)
    B: tuple[float, float] = (1e-3, 1e9)
    C: tuple[float, float] = (1e-3, 10.0)
    eta: tuple[float, float] = (1.001, 100.0)
    start_box: dict = field(
        default_factory=lambda: {"B": (10.0, 1e6), "C": (0.2, 2.5), "eta": (1.2, 3.0)}
    )

    def __post_init__(self) -> None:
        for name in ("A", "B", "C", "eta"):
            lo, hi = getattr(self, name)
            if not (0 < lo < hi and math.isfinite(hi)):
                raise ValueError(f"bounds for {name} must satisfy 0 < low < high < inf, got {(lo, hi)}")
            if name in self.start_box:
                s_lo, s_hi = self.start_box[name]
                if not lo <= s_lo <= s_hi <= hi:
                    raise ValueError(f"start_box for {name} {(s_lo, s_hi)} must lie within the bounds {(lo, hi)}")


@dataclass(frozen=True, eq=False)
class AbcFitResult:
    """Outcome of :func:`fit_abc`.

    Attributes
    ----------
    parameters:
        The best start's parameters (also when the fit failed, for inspection).
    loss:
        Its ``L_cus`` (report Eq. 4.2) on the table.
    baseline_loss:
        ``L_cus`` of the diffuse-only model ``kd/π``.
    success:
        True only when none of the failure conditions (module docstring) holds.
    failure_reason:
        ``None`` on success, else every condition that failed, ``"; "``-separated.
    start_losses:
        ``[n_starts]`` final ``L_cus`` of every start (NaN where non-finite).
    message:
        The optimiser's message for the best start.
    n_evaluations:
        Loss-and-gradient evaluations over all starts.
    wall_time_s:
        Wall-clock time of the fit in seconds.
    """

    parameters: AbcParameters
    loss: float
    baseline_loss: float
    success: bool
    failure_reason: str | None
    start_losses: np.ndarray
    message: str
    n_evaluations: int
    wall_time_s: float


class _Problem:
    """The table as float64 tensors and the scaled L_cus over ``z = (log A, log B, C, log eta)``."""

    def __init__(self, table: BrdfTable, bounds: AbcBounds) -> None:
        wi, wo = table.vectors()
        self.wi = torch.from_numpy(wi)
        self.wo = torch.from_numpy(wo)
        self.target = torch.from_numpy(table.values)
        self.theta_i = torch.from_numpy(table.theta_i)
        self.theta_o = torch.from_numpy(table.theta_o)
        self.weight = None if table.weight is None else torch.from_numpy(table.weight)
        if table.weight is not None and not table.weight.sum() > 0:
            raise InputError("every weight is zero: nothing to fit", path=table.source, column="weight")
        self.kd = math.pi * self.target.min(dim=0).values
        self.n_channels = table.values.shape[1]
        lows, highs = zip(
            *([np.log(bounds.A)] * self.n_channels + [np.log(bounds.B), bounds.C, np.log(bounds.eta)])
        )
        self.lower, self.upper = np.array(lows, dtype=np.float64), np.array(highs, dtype=np.float64)
        self.baseline_loss = self.loss_of(self.kd / math.pi + torch.zeros_like(self.target))
        self.scale = self.baseline_loss if self.baseline_loss > 0 else 1.0
        self.n_evaluations = 0

    def loss_of(self, pred: torch.Tensor) -> float:
        return float(log_cosine_loss(pred, self.target, self.theta_i, self.theta_o, self.weight))

    def unpack(self, z):
        c = self.n_channels
        return torch.exp(z[:c]), torch.exp(z[c]), z[c + 1], torch.exp(z[c + 2])

    def predict(self, z):
        return abc_brdf(self.wi, self.wo, self.kd, *self.unpack(z))

    def scaled_loss_and_grad(self, z_np: np.ndarray) -> tuple[float, np.ndarray]:
        self.n_evaluations += 1
        z = torch.tensor(z_np, dtype=torch.float64, requires_grad=True)
        loss = log_cosine_loss(self.predict(z), self.target, self.theta_i, self.theta_o, self.weight) / self.scale
        loss.backward()
        value, grad = float(loss.detach()), z.grad.numpy().copy()
        if not (math.isfinite(value) and np.all(np.isfinite(grad))):
            # An infinite value makes the line search back off; a NaN would poison it.
            return math.inf, np.zeros_like(z_np)
        return value, grad

    def start(self, B: float, C: float, eta: float) -> np.ndarray:
        """Start vector: the given shape, each channel's ``A`` the best of a log grid."""
        log_a = np.linspace(self.lower[0], self.upper[0], A_GRID_SIZE)
        with torch.no_grad():
            one = torch.ones(1, dtype=torch.float64)
            lobe = abc_brdf(self.wi, self.wo, 0.0 * one, one, B, C, eta)  # [N, 1]: specular term for A = 1
            pred = self.kd / math.pi + torch.exp(torch.from_numpy(log_a))[:, None] * lobe[:, :, None]  # [N, grid, C]
            n_rows = pred.shape[0]
            terms = log_cosine_terms(
                pred.reshape(n_rows, -1), self.target.repeat(1, A_GRID_SIZE), self.theta_i, self.theta_o
            ).reshape(n_rows, A_GRID_SIZE, self.n_channels)
            weight = torch.ones(n_rows, dtype=torch.float64) if self.weight is None else self.weight
            per_channel = (weight[:, None, None] * terms).sum(dim=0)  # [grid, C]
        best = torch.nan_to_num(per_channel, nan=math.inf).argmin(dim=0).numpy()
        return np.concatenate([log_a[best], [math.log(B), C, math.log(eta)]])

    def pinned(self, z: np.ndarray) -> list[str]:
        names = [f"A[{k}]" for k in range(self.n_channels)] + ["B", "C", "eta"]
        margin = PINNED_FRACTION * (self.upper - self.lower)
        found = []
        for name, value, lo, hi, tol in zip(names, z, self.lower, self.upper, margin):
            if value <= lo + tol:
                found.append(f"{name} at its lower bound")
            elif value >= hi - tol:
                found.append(f"{name} at its upper bound")
        return found


def _start_shapes(bounds: AbcBounds, n_starts: int, seed: int) -> list[tuple[float, float, float]]:
    """``(B, C, eta)`` of every start: the start box's centre, then seeded uniform draws."""
    rng = np.random.default_rng(seed)
    (b_lo, b_hi), (c_lo, c_hi), (e_lo, e_hi) = (bounds.start_box[k] for k in ("B", "C", "eta"))
    centre = (math.sqrt(b_lo * b_hi), 0.5 * (c_lo + c_hi), math.sqrt(e_lo * e_hi))
    draws = [
        (
            math.exp(rng.uniform(math.log(b_lo), math.log(b_hi))),
            rng.uniform(c_lo, c_hi),
            math.exp(rng.uniform(math.log(e_lo), math.log(e_hi))),
        )
        for _ in range(n_starts - 1)
    ]
    return [centre, *draws]


@contextmanager
def _single_threaded_torch():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def fit_abc(
    table: BrdfTable,
    n_starts: int = 8,
    seed: int = 0,
    bounds: AbcBounds | None = None,
    max_evaluations: int = 500,
) -> AbcFitResult:
    """Fit the ABC model to ``table`` (RGB or spectral; ``A`` per channel) — module docstring.

    ``L_cus`` uses the table's spherical polar angles (``theta_i``, ``theta_o``) and its
    ``weight`` column when present.  ``max_evaluations`` caps the loss evaluations of each
    start (a start that reaches it has not converged).  Deterministic for a given ``seed``.
    """
    if n_starts < 1:
        raise ValueError(f"n_starts must be >= 1, got {n_starts}")
    bounds = AbcBounds() if bounds is None else bounds
    with _single_threaded_torch():
        return _fit(table, n_starts, seed, bounds, max_evaluations)


def _fit(table: BrdfTable, n_starts: int, seed: int, bounds: AbcBounds, max_evaluations: int) -> AbcFitResult:
    began = time.perf_counter()
    problem = _Problem(table, bounds)
    box = list(zip(problem.lower, problem.upper))
    runs = []
    for B, C, eta in _start_shapes(bounds, n_starts, seed):
        z0 = problem.start(B, C, eta)
        start_value, _ = problem.scaled_loss_and_grad(z0)
        run = scipy.optimize.minimize(
            problem.scaled_loss_and_grad, z0, jac=True, method="TNC", bounds=box,
            options={"maxfun": max_evaluations},
        )
        runs.append((run, start_value))
    finals = np.array([run.fun * problem.scale if math.isfinite(run.fun) else np.nan for run, _ in runs])
    converged = [i for i, (run, _) in enumerate(runs) if run.success and math.isfinite(run.fun)]
    candidates = converged or [i for i in range(len(runs)) if math.isfinite(runs[i][0].fun)] or [0]
    best = min(candidates, key=lambda i: runs[i][0].fun)
    run, start_value = runs[best]

    A, B, C, eta = (t.numpy() for t in problem.unpack(torch.from_numpy(run.x)))
    loss = problem.loss_of(problem.predict(torch.from_numpy(run.x)))
    # TNC keeps x inside the (finite) box, so the parameters are finite and valid.
    parameters = AbcParameters(problem.kd.numpy(), A, float(B), float(C), float(eta), table.wavelengths)

    reasons = []
    if not (math.isfinite(loss) and np.all(np.isfinite(run.x))):
        reasons.append(f"non-finite loss or parameters (loss {loss})")
    if not converged:
        reasons.append(f"no start converged (best start: {run.message})")
    reasons += problem.pinned(run.x)
    if problem.baseline_loss == 0.0:
        reasons.append("no specular signal: the diffuse term kd/π = min(f) already fits the data exactly")
    elif not loss < (1.0 - IMPROVEMENT_RTOL) * problem.baseline_loss:
        reasons.append(f"no improvement over the diffuse-only model (loss {loss:.4g} vs {problem.baseline_loss:.4g})")
    if not run.fun < (1.0 - IMPROVEMENT_RTOL) * start_value:
        reasons.append("no improvement over the start point")
    return AbcFitResult(
        parameters=parameters,
        loss=loss,
        baseline_loss=problem.baseline_loss,
        success=not reasons,
        failure_reason="; ".join(reasons) or None,
        start_losses=finals,
        message=str(run.message),
        n_evaluations=problem.n_evaluations,
        wall_time_s=time.perf_counter() - began,
    )

