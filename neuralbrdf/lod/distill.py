"""Stand-ins trained on a model's own samples (docs/select.md): the parent is the teacher.

* :func:`teacher_samples` — the parent evaluated (onnxruntime) where a renderer queries it: half
  the direction pairs cosine-distributed over the hemisphere, half near the mirror direction
  (``wo`` the mirror of ``wi`` tilted by a log-uniform 0.05°–40°, where glossy lobes live), and
  for spectral models a wavelength per pair, uniform over the model's range.
* :func:`distill_spectral_mlp` — a smaller :class:`~neuralbrdf.models.spectral_mlp.SpectralMLP`
  (fewer layers/units) queried out of plane like the full one
  (:class:`~neuralbrdf.models.directional.SpectralMlpOnDirections`), fitted to the teacher's
  values by Adam on the log residual ``ln(f̂ + ε) − ln(f + ε)`` (the default training loss of the
  spectral MLP, docs/design.md, *Spectral MLP loss*: a ratio costs the same at every BRDF level).
* :func:`distill_student` — a :class:`~neuralbrdf.models.student.DirectionalStudent` (RGB or
  spectral, on Rusinkiewicz coordinates) fitted the same way: the fast paths of an exported file
  (:mod:`neuralbrdf.lod.fast_paths`) — an RGB head of a spectral model, whose teacher is the
  model's linear sRGB (:func:`rgb_teacher`), or a compact copy of an NLB.
* :func:`abc_table` — the same samples as a :class:`~neuralbrdf.data.table.BrdfTable` (spherical
  angles, one column per wavelength of :data:`ABC_WAVELENGTHS_NM` or R, G, B), for
  :func:`~neuralbrdf.fitting.abc_fit.fit_abc`.

Teacher-student distillation (Hinton et al. 2015) here is plain regression on the teacher's
outputs: the teacher is known everywhere, so there is no data to hold out, only the error
against the parent over the whole hemisphere, which the ladder measures afterwards.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from neuralbrdf.data.table import BrdfTable
from neuralbrdf.geometry import normalize, reflect, vector_to_spherical
from neuralbrdf.models.directional import SpectralMlpOnDirections
from neuralbrdf.models.spectral_mlp import SpectralMLP
from neuralbrdf.models.student import DirectionalStudent

#: Wavelengths (nm) of a spectral ABC stand-in's ``kd`` and ``A``: every 25 nm (13 nodes; the
#: graph interpolates linearly between them, a cost per node, so half the measurement grid's 31).
ABC_WAVELENGTHS_NM = np.arange(400.0, 701.0, 25.0)
#: Largest polar angle (degrees) of the teacher's samples (grazing beyond it is extrapolation).
MAX_THETA_DEG = 85.0
#: Tilts (degrees) of the near-mirror samples away from the mirror direction: log-uniform range.
MIRROR_TILT_DEG = (0.05, 40.0)
#: ε (sr⁻¹) of the log residual.
LOG_EPSILON_SR = 1e-3


@dataclass(frozen=True)
class DistillSettings:
    """Training of a student network (values: ``configs/lod/default.yaml``, ``ladder.distill``; a few
    seconds to a minute on one core)."""

    n_pairs: int
    steps: int
    batch: int
    lr: float
    #: The learning rate decays exponentially to ``lr × final_lr_fraction`` over the steps.
    final_lr_fraction: float
    seed: int


def _cosine_hemisphere(rng, count: int) -> np.ndarray:
    """Cosine-distributed directions with ``θ <= MAX_THETA_DEG``."""
    sin2_max = np.sin(np.radians(MAX_THETA_DEG)) ** 2
    u1, u2 = rng.uniform(size=count) * sin2_max, rng.uniform(size=count)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - u1)], axis=1)


def sample_pairs(n_pairs: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Direction pairs ``wi, wo`` ``[n_pairs, 3]`` (float64): half over the hemisphere, half near the
    mirror direction (module docstring); pairs whose ``wo`` falls below the horizon are replaced
    by hemisphere pairs."""
    rng = np.random.default_rng(seed)
    half = n_pairs // 2
    wi = _cosine_hemisphere(rng, n_pairs)
    wo = _cosine_hemisphere(rng, n_pairs)
    mirror = reflect(wi[half:])
    tilt = np.radians(np.exp(rng.uniform(*np.log(MIRROR_TILT_DEG), size=n_pairs - half)))
    spin = rng.uniform(0.0, 2 * np.pi, size=n_pairs - half)
    # Two unit vectors perpendicular to the mirror direction.
    helper = np.where(np.abs(mirror[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    t1 = normalize(np.cross(mirror, helper))
    t2 = np.cross(mirror, t1)
    tilted = np.cos(tilt)[:, None] * mirror + np.sin(tilt)[:, None] * (
        np.cos(spin)[:, None] * t1 + np.sin(spin)[:, None] * t2
    )
    theta = np.degrees(np.arccos(np.clip(tilted[:, 2], -1.0, 1.0)))
    keep = theta < MAX_THETA_DEG
    wo[half:][keep] = tilted[keep]
    return wi, normalize(wo)


@dataclass(frozen=True)
class TeacherSamples:
    """The parent's values at direction pairs (and wavelengths, nm, for spectral parents)."""

    wi: np.ndarray
    wo: np.ndarray
    wavelength: np.ndarray | None
    values: np.ndarray  # [N] spectral, [N, 3] RGB


def teacher_samples(evaluator, n_pairs: int, seed: int = 0, wavelength_range_nm=None) -> TeacherSamples:
    """``evaluator`` (an :class:`~neuralbrdf.evaluation.scores.Evaluator`) on :func:`sample_pairs`."""
    wi, wo = sample_pairs(n_pairs, seed)
    wavelength = None
    if evaluator.is_spectral:
        rng = np.random.default_rng(seed + 1)
        wavelength = rng.uniform(*wavelength_range_nm, size=n_pairs)
    values = evaluator.values(wi, wo, wavelength)
    if not np.all(np.isfinite(values)):
        raise ValueError("the parent model returned non-finite values on its own samples")
    return TeacherSamples(wi, wo, wavelength, np.clip(values, 0.0, None))


def _fit_log_residual(predict, parameters, features: tuple[torch.Tensor, ...], values: np.ndarray,
                      settings: DistillSettings, what: str) -> None:
    """Adam on ``mean((ln(predict(rows) + ε) − ln(f + ε))²)`` over random batches of the teacher's
    samples; ``features`` are per-sample tensors computed once, ``predict`` maps their rows to
    the student's values.  :class:`ValueError` when the loss is not finite at the end.  Runs on
    one torch thread: a student this small loses more to the threads' synchronisation than it
    gains (``benchmarks/README.md``, design measurements)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        loss = _adam_steps(predict, parameters, features, values, settings)
    finally:
        torch.set_num_threads(threads)
    if not torch.isfinite(loss):
        raise ValueError(f"distillation of the {what} diverged (loss {float(loss)})")


def _adam_steps(predict, parameters, features, values: np.ndarray, settings: DistillSettings) -> torch.Tensor:
    """The optimisation of :func:`_fit_log_residual`; the last batch's loss."""
    target = torch.log(torch.from_numpy(values).float() + LOG_EPSILON_SR)
    optimizer = torch.optim.Adam(parameters, lr=settings.lr)
    decay = settings.final_lr_fraction ** (1.0 / max(settings.steps, 1))
    scheduler = torch.optim.lr_scheduler.ExponentialLR(optimizer, decay)
    generator = torch.Generator().manual_seed(settings.seed)
    n = len(target)
    loss = torch.tensor(0.0)
    for _ in range(settings.steps):
        rows = torch.randint(0, n, (min(settings.batch, n),), generator=generator)
        predicted = predict(*(feature[rows] for feature in features))
        loss = torch.mean((torch.log(predicted + LOG_EPSILON_SR) - target[rows]) ** 2)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        scheduler.step()
    return loss


def distill_spectral_mlp(
    samples: TeacherSamples,
    hidden: int,
    hidden_layers: int,
    wavelength_range_nm: tuple[float, float],
    settings: DistillSettings,
) -> SpectralMlpOnDirections:
    """A ``hidden_layers × hidden`` spectral MLP fitted to a spectral teacher (module docstring)."""
    if samples.wavelength is None:
        raise ValueError("a spectral MLP student needs a spectral teacher")
    torch.manual_seed(settings.seed)
    student = SpectralMlpOnDirections(
        SpectralMLP(hidden=hidden, hidden_layers=hidden_layers, wavelength_range_nm=wavelength_range_nm)
    )
    wi = torch.from_numpy(samples.wi).float()
    wo = torch.from_numpy(samples.wo).float()
    wavelength = torch.from_numpy(samples.wavelength).float()
    # The in-plane equivalent angles do not depend on the weights: computed once.
    with torch.no_grad():
        theta_i, theta_r = student.inplane_equivalent_deg(wi, wo)
    _fit_log_residual(student.mlp, student.parameters(), (theta_i, theta_r, wavelength), samples.values, settings,
                      f"{hidden_layers}x{hidden} student")
    return student.eval()


def distill_student(samples: TeacherSamples, hidden: int, hidden_layers: int, activation: str,
                    settings: DistillSettings, wavelength_range_nm: tuple[float, float] | None = None
                    ) -> DirectionalStudent:
    """A :class:`~neuralbrdf.models.student.DirectionalStudent` fitted to the teacher's values:
    RGB (``samples.values`` ``[N, 3]``) or spectral (``[N]`` with ``wavelength_range_nm``)."""
    if (samples.wavelength is None) != (wavelength_range_nm is None):
        raise ValueError("a spectral student needs a spectral teacher and its wavelength range, an RGB one neither")
    torch.manual_seed(settings.seed)
    student = DirectionalStudent(hidden, hidden_layers, wavelength_range_nm, activation)
    wavelength = None if samples.wavelength is None else torch.from_numpy(samples.wavelength).float()
    with torch.no_grad():  # the coordinates do not depend on the weights: computed once
        features = student.features(torch.from_numpy(samples.wi).float(), torch.from_numpy(samples.wo).float(),
                                    wavelength)
    _fit_log_residual(lambda x: torch.exp(student.log_f(x)), student.parameters(), (features,), samples.values,
                      settings, student.describe())
    return student.eval()


def rgb_teacher(evaluator):
    """The linear sRGB a spectral ``evaluator`` (an :class:`~neuralbrdf.evaluation.scores.OnnxEvaluator`)
    renders as in RGB variants: the plugin's rule of docs/formats.md#spectral-to-linear-srgb on all 31 wavelengths, exactly
    (:func:`~neuralbrdf.render.spectral_quadrature.full_rule`), negatives clipped; an RGB
    evaluator as it is."""
    from neuralbrdf.render.spectral_quadrature import RuleRgbEvaluator, full_rule

    if not evaluator.is_spectral:
        return evaluator
    return RuleRgbEvaluator(evaluator, full_rule(evaluator.model.wavelength_range_nm))


def abc_table(evaluator, n_pairs: int, seed: int = 0, source: str = "<parent samples>") -> BrdfTable:
    """The parent on :func:`sample_pairs` as a BRDF table (spectral at :data:`ABC_WAVELENGTHS_NM`,
    clamped to the model's range by the model itself, or RGB)."""
    wi, wo = sample_pairs(n_pairs, seed)
    if evaluator.is_spectral:
        w = len(ABC_WAVELENGTHS_NM)
        values = evaluator.values(
            np.repeat(wi, w, axis=0), np.repeat(wo, w, axis=0), np.tile(ABC_WAVELENGTHS_NM, len(wi))
        ).reshape(len(wi), w)
        wavelengths = ABC_WAVELENGTHS_NM
    else:
        values, wavelengths = evaluator.values(wi, wo, None), None
    theta_i, phi_i = vector_to_spherical(wi)
    theta_o, phi_o = vector_to_spherical(wo)
    return BrdfTable(theta_i, phi_i, theta_o, phi_o, np.clip(values, 0.0, None), wavelengths, source=source)

