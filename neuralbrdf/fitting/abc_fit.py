"""Fitting the ABC model to a BRDF sample table (report §4.1.1, docs/models.md#abc).

Following the report (after Löw et al. 2012):

1. ``kd = π · min(f)`` per channel — the specular term is non-negative and smallest far from
   the mirror direction, so the smallest measured value estimates the diffuse level ``kd/π``.
   Rows whose every channel is exactly 0 do not count: they are directions nobody measured
   (MERL's unmeasured cells, which :mod:`neuralbrdf.data.merl_binary` writes as 0), and one
   such row would set ``kd`` to 0.
2. ``A`` (per channel), ``B``, ``C`` and ``η`` minimise ``L_cus`` (report Eq. 4.2,
   :func:`neuralbrdf.losses.log_cosine_loss`) within bounds, from several starts; the best
   start wins.

**Coordinates.**  The lobe ``(1 + B x)^(-C)``, ``x = 1 - cos θh``, is fitted as its *sharpness*
``B·C`` (the lobe is ``exp(-B·C·x)`` near its peak) and its *tail* ``1/C``
(:func:`neuralbrdf.physics.abc.abc_brdf_by_sharpness`).  For narrow lobes only the product
``B·C`` is well determined, and lobes that fall off at least as fast as a Gaussian in ``θh``
(Beckmann, Blinn–Phong: most smooth materials) are fitted best by ``C -> ∞``, the Gaussian limit
``exp(-B·C·x)``; in ``(B, C)`` such a fit runs off to the upper bound of ``C`` whatever that
bound is.  In these coordinates the limit is the point ``tail = 0``, reached and kept like any
other.  The optimiser sees ``log A``, ``log(B·C)``, ``s = ln(1 + 1/C)`` (``s = 0`` the Gaussian
limit, ``s ≈ 1/C`` for large ``C``, ``s ≈ -ln C`` for the heavy tails of small ``C``) and
``log η``.  A fit that ends in or near the limit is stored with ``C =``
:data:`GAUSSIAN_LIMIT_C` and ``B = B·C / C``: then ``(1 + B x)^(-C)`` differs from
``exp(-B·C·x)`` by a factor ``exp((B·C·x)² / 2C)``, below 1.005 wherever the lobe is above
``e^-10`` of its peak.  The loss and every check use the stored parameters.

**Optimiser.**  SciPy's truncated-Newton method with box bounds (TNC) on a loss and gradient
computed by torch (float64, autograd, vectorised over the samples).  A box-bounded optimiser
was chosen over torch's LBFGS with a squashing reparametrisation because a parameter that
wants to leave the box then ends *on* the bound, where it is detected and reported, instead of
creeping towards it with a vanishing gradient.  TNC rather than L-BFGS-B: both find the same
minima here, but L-BFGS-B's small BLAS/LAPACK calls go through SciPy's multithreaded OpenBLAS,
whose thread wake-ups dominate the fit time on a loaded machine; TNC is self-contained C
(``benchmarks/README.md``, design measurements).  The loss is divided by that of the
diffuse-only model (``kd/π`` everywhere) so that the optimiser's tolerances see a quantity of
order one.

**Starts.**  ``log(B·C)``, ``s`` and ``log η`` are drawn uniformly from a plausible sub-box of the
bounds (:attr:`AbcBounds.start_box`; its ``C`` range reaches the Gaussian limit) with the
seeded generator, the first start at the sub-box centre; given those, each channel's ``A``
starts at the best of a log-spaced grid (the loss separates over channels for a fixed lobe).

**Threads.**  The tensors are small (a DS1 RGB table is 1001 × 3), so torch's intra-op
threads only add synchronisation (``benchmarks/README.md``, design measurements).  :func:`fit_abc` therefore runs torch single-threaded and restores the previous thread
count when it returns (``torch.set_num_threads`` is process-wide).

**Failure.**  A result has ``success = False`` and a ``failure_reason`` when the best start's
loss or parameters are non-finite, when no start's optimiser reported convergence, when a
parameter ends within 0.1 % of the box width of a finite bound (in the optimised coordinates;
the reason names the parameter, its value, the bound and the option to change), or when the
loss did not improve on the start point or on the diffuse-only model (e.g. data with no
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
from neuralbrdf.physics.abc import AbcParameters, abc_brdf_by_sharpness

#: A parameter within this fraction of its box width from a bound counts as pinned.
PINNED_FRACTION = 1e-3

#: Relative loss decrease below which a fit "did not improve".
IMPROVEMENT_RTOL = 1e-6

#: Number of log-spaced values tried for each channel's starting ``A``.
A_GRID_SIZE = 97

#: ``C`` stored for a fit in (or beyond) the Gaussian limit (module docstring).
GAUSSIAN_LIMIT_C = 1e4

#: Bounded parameters besides ``A``, in the order of the optimised coordinates.
SHAPE_NAMES = ("sharpness", "C", "eta")


@dataclass(frozen=True)
class AbcBounds:
    """Bounds of the fitted parameters: ``A`` per channel, the lobe's ``sharpness = B·C``, ``C``, ``eta``.

    ``C``'s upper bound may be ``math.inf`` (the default): the fit may then reach the Gaussian
    limit (module docstring); the other bounds are finite.  ``start_box`` is the range of
    ``sharpness``, ``C`` and ``eta`` that random starts are drawn from, clipped to the bounds.
    """

    A: tuple[float, float] = (1e-8, 1e6)
    sharpness: tuple[float, float] = (1e-3, 1e9)
    C: tuple[float, float] = (1e-3, math.inf)
    eta: tuple[float, float] = (1.001, 100.0)
    start_box: dict = field(
        default_factory=lambda: {"sharpness": (10.0, 1e6), "C": (0.2, math.inf), "eta": (1.2, 3.0)}
    )

    def __post_init__(self) -> None:
        for name in ("A", *SHAPE_NAMES):
            lo, hi = getattr(self, name)
            if not (0 < lo < hi and (math.isfinite(hi) or name == "C")):
                rule = "0 < low < high (high may be .inf)" if name == "C" else "0 < low < high < inf"
                raise InputError(f"bounds must satisfy {rule}, got {[lo, hi]}", key=f"model.bounds.{name}")
        if not self.C[0] < GAUSSIAN_LIMIT_C:
            raise InputError(f"the lower bound of C must be below {GAUSSIAN_LIMIT_C:g}, the C of a Gaussian-limit "
                             f"fit; got {self.C[0]:g}", key="model.bounds.C")

    @classmethod
    def from_config(cls, bounds: dict | None) -> AbcBounds:
        """Bounds from a config's ``model.bounds`` mapping (any of A, sharpness, C, eta)."""
        fields = ("A", *SHAPE_NAMES)
        values = {}
        for key, pair in (bounds or {}).items():
            if key not in fields:
                raise InputError(f"unknown bound; expected one of {', '.join(fields)}", key=f"model.bounds.{key}")
            try:
                low, high = (float(v) for v in pair)
            except (TypeError, ValueError):
                raise InputError(f"expected [low, high], got {pair!r}", key=f"model.bounds.{key}") from None
            values[key] = (low, high)
        return cls(**values)


def _shape_coordinate(C: float) -> float:
    """``s = ln(1 + 1/C)``: 0 at the Gaussian limit ``C = ∞``."""
    return math.log1p(1.0 / C)


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
    gaussian_limit:
        Whether the lobe ended in the Gaussian limit (stored with ``C =`` :data:`GAUSSIAN_LIMIT_C`).
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
    gaussian_limit: bool
    start_losses: np.ndarray
    message: str
    n_evaluations: int
    wall_time_s: float


class _Problem:
    """The table as float64 tensors and the scaled L_cus over ``z = (log A, log(B·C), s, log eta)``."""

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
        measured = (self.target != 0).any(dim=1)
        self.kd = math.pi * self.target[measured if measured.any() else slice(None)].min(dim=0).values
        self.n_channels = table.values.shape[1]
        self.bounds = bounds
        c_lo, c_hi = bounds.C
        lows, highs = zip(
            *([np.log(bounds.A)] * self.n_channels),
            np.log(bounds.sharpness),
            (_shape_coordinate(c_hi), _shape_coordinate(c_lo)),
            np.log(bounds.eta),
        )
        self.lower, self.upper = np.array(lows, dtype=np.float64), np.array(highs, dtype=np.float64)
        self.baseline_loss = self.loss_of(self.kd / math.pi + torch.zeros_like(self.target))
        self.scale = self.baseline_loss if self.baseline_loss > 0 else 1.0
        self.n_evaluations = 0

    def loss_of(self, pred: torch.Tensor) -> float:
        return float(log_cosine_loss(pred, self.target, self.theta_i, self.theta_o, self.weight))

    def predict(self, z):
        c = self.n_channels
        return abc_brdf_by_sharpness(self.wi, self.wo, self.kd, torch.exp(z[:c]), torch.exp(z[c]),
                                     torch.expm1(z[c + 1]), torch.exp(z[c + 2]))

    def parameters(self, z: np.ndarray, wavelengths) -> tuple[AbcParameters, bool]:
        """The stored parameters of ``z`` and whether they are the Gaussian limit (module docstring)."""
        c = self.n_channels
        sharpness, tail = math.exp(z[c]), math.expm1(z[c + 1])
        limit = tail * GAUSSIAN_LIMIT_C <= 1.0
        C = GAUSSIAN_LIMIT_C if limit else 1.0 / tail
        # TNC keeps z inside the (finite) box, so the parameters are finite and valid.
        return AbcParameters(self.kd.numpy(), np.exp(z[:c]), sharpness / C, C, math.exp(z[c + 2]), wavelengths), limit

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

    def start(self, sharpness: float, s: float, eta: float) -> np.ndarray:
        """Start vector: the given lobe, each channel's ``A`` the best of a log grid."""
        log_a = np.linspace(self.lower[0], self.upper[0], A_GRID_SIZE)
        with torch.no_grad():
            one = torch.ones(1, dtype=torch.float64)
            lobe = abc_brdf_by_sharpness(self.wi, self.wo, 0.0 * one, one, sharpness, math.expm1(s), eta)  # A = 1
            pred = self.kd / math.pi + torch.exp(torch.from_numpy(log_a))[:, None] * lobe[:, :, None]  # [N, grid, C]
            n_rows = pred.shape[0]
            terms = log_cosine_terms(
                pred.reshape(n_rows, -1), self.target.repeat(1, A_GRID_SIZE), self.theta_i, self.theta_o
            ).reshape(n_rows, A_GRID_SIZE, self.n_channels)
            weight = torch.ones(n_rows, dtype=torch.float64) if self.weight is None else self.weight
            per_channel = (weight[:, None, None] * terms).sum(dim=0)  # [grid, C]
        best = torch.nan_to_num(per_channel, nan=math.inf).argmin(dim=0).numpy()
        return np.concatenate([log_a[best], [math.log(sharpness), s, math.log(eta)]])

    def runaways(self, z: np.ndarray, parameters: AbcParameters) -> list[str]:
        """One reason per parameter that ended on a finite bound: which, its value, the bound, what to try."""
        margin = PINNED_FRACTION * (self.upper - self.lower)
        at_lower = z <= self.lower + margin
        at_upper = (z >= self.upper - margin) & ~at_lower
        c = self.n_channels
        found = []
        for k in range(c):
            if at_lower[k] or at_upper[k]:
                found.append(_runaway("A", bool(at_upper[k]), parameters, self.bounds.A, k))
        for name, k in zip(SHAPE_NAMES, range(c, c + 3)):
            if not (at_lower[k] or at_upper[k]):
                continue
            upper = bool(at_lower[k] if name == "C" else at_upper[k])  # s runs opposite to C
            if name == "C" and upper and math.isinf(self.bounds.C[1]):
                continue  # the Gaussian limit, not a bound
            found.append(_runaway(name, upper, parameters, getattr(self.bounds, name)))
        return found


#: ``(parameter, ran to its upper bound)`` -> what that means and what to try (``{flag}``, the
#: ``--model.bounds`` option with the bounds that ``widen(low, high)`` gives).  No ``"; "``
#: inside: a fit's failure reasons are joined with it.
_RUNAWAY_ADVICE = {
    ("A", True): ("a specular peak brighter than the bounds allow, try {flag}", lambda lo, hi: (lo, hi * 1e3)),
    ("A", False): ("channel {k} shows no specular peak above kd/π, if that is right try {flag}",
                   lambda lo, hi: (lo * 1e-4, hi)),
    ("sharpness", True): ("the peak is narrower than the samples resolve: measure the mirror direction more finely "
                          "(DS1 has 1° glossy steps) or try {flag}", lambda lo, hi: (lo, hi * 1e3)),
    ("sharpness", False): ("no peak towards the mirror direction (diffuse data? angles in another convention?), "
                           "for flatter lobes try {flag}", lambda lo, hi: (lo * 1e-3, hi)),
    ("C", True): ("the lobe falls off as fast as a Gaussian in θh or faster (the limit C -> ∞ of "
                  "(1 + B(1 - cos θh))^-C), which {flag} allows", lambda lo, hi: (lo, math.inf)),
    ("C", False): ("the lobe's tail is heavier than (1 + B(1 - cos θh))^-C can follow, try {flag}",
                   lambda lo, hi: (lo * 1e-2, hi)),
    ("eta", True): ("the reflectance barely rises towards grazing angles, unlike a dielectric's Fresnel term "
                    "(a metal?), try {flag}", lambda lo, hi: (lo, hi * 10)),
    ("eta", False): ("the Fresnel term was driven to 0 at normal incidence (no peak near the normal: check the "
                     "data's angles), only for such a material try {flag}",
                     lambda lo, hi: (1.0 + (lo - 1.0) * 1e-2, hi)),
}


def _runaway(name: str, upper: bool, p: AbcParameters, bounds: tuple[float, float], k: int = 0) -> str:
    """The failure reason of parameter ``name`` (channel ``k`` of ``A``) that ran to a bound."""
    value = {
        "A": f"A[{k}] = {p.A[k]:.4g}",
        "sharpness": f"B·C = {p.B * p.C:.4g} with B = {p.B:.4g}, C = {p.C:.4g}",
        "C": f"C = {p.C:.4g}, B = {p.B:.4g}, B·C = {p.B * p.C:.4g}",
        "eta": f"eta = {p.eta:.4g}",
    }[name]
    subject = {"A": f"A[{k}]", "sharpness": "the lobe's sharpness B·C"}.get(name, name)
    why, widen = _RUNAWAY_ADVICE[name, upper]
    low, high = widen(*bounds)
    flag = f"--model.bounds.{name} '[{low:g}, {'.inf' if math.isinf(high) else f'{high:g}'}]'"
    side, bound = ("upper", bounds[1]) if upper else ("lower", bounds[0])
    return f"{subject} ran to its {side} bound ({value}, bound {bound:g}): {why.format(flag=flag, k=k)}"


def _start_shapes(bounds: AbcBounds, n_starts: int, seed: int) -> list[tuple[float, float, float]]:
    """``(B·C, s, eta)`` of every start: the start box's centre, then seeded uniform draws."""
    rng = np.random.default_rng(seed)
    (w_lo, w_hi), (c_lo, c_hi), (e_lo, e_hi) = (
        np.clip(bounds.start_box[k], *getattr(bounds, k)).tolist() for k in SHAPE_NAMES
    )
    s_lo, s_hi = _shape_coordinate(c_hi), _shape_coordinate(c_lo)
    centre = (math.sqrt(w_lo * w_hi), 0.5 * (s_lo + s_hi), math.sqrt(e_lo * e_hi))
    draws = [
        (
            math.exp(rng.uniform(math.log(w_lo), math.log(w_hi))),
            rng.uniform(s_lo, s_hi),
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
    for shape in _start_shapes(bounds, n_starts, seed):
        z0 = problem.start(*shape)
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

    parameters, gaussian_limit = problem.parameters(run.x, table.wavelengths)
    loss = problem.loss_of(parameters.evaluate(problem.wi, problem.wo))

    reasons = []
    if not (math.isfinite(loss) and np.all(np.isfinite(run.x))):
        reasons.append(f"non-finite loss or parameters (loss {loss})")
    if not converged:
        reasons.append(f"no start converged (best start: {run.message})")
    reasons += problem.runaways(run.x, parameters)
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
        gaussian_limit=gaussian_limit,
        start_losses=finals,
        message=str(run.message),
        n_evaluations=problem.n_evaluations,
        wall_time_s=time.perf_counter() - began,
    )
