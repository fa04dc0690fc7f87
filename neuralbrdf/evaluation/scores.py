"""A model scored against its truth over the whole hemisphere and the in-plane grid (docs/evaluate.md).

Metric names are fixed (:data:`DIRECTION_METRICS`) and shared by ``neuralbrdf evaluate``,
training runs' ``metrics.json`` and the study:

* ``hemisphere_logcos_rmse`` — ``sqrt(mean((ln(1 + f cos θi) − ln(1 + f̂ cos θi))²))`` (docs/evaluate.md#metrics) and
  ``hemisphere_rel_rmse`` — relative RMSE (report Eq. 4.3, channel mean, truth values below
  :data:`~neuralbrdf.metrics.DEFAULT_FLOOR` excluded) — over :func:`hemisphere_pairs`:
  :data:`HEMISPHERE_STRATA` jittered strata of ``(cos θ, φ)`` per direction, every incident
  stratum paired with every outgoing one (102 400 pairs), ``θ <= 80°``, fixed seed;
* ``inplane_glossy_rel_rmse`` (``|θi − θr| <= 10°``, the report's region) and
  ``inplane_diffuse_rel_rmse`` (the rest) over the in-plane grid :func:`inplane_pairs`: signed
  ``θi, θr`` every 1° within ±60°.

**What is compared.** Two spectral models compare their spectra at the 31 wavelengths 400, 410,
…, 700 nm (every wavelength a channel; the in-plane errors are also given per wavelength).
Otherwise both sides compare in linear sRGB: a spectral side is converted through
:mod:`neuralbrdf.data.colorimetry` (CIE 1931 2°, D65, docs/formats.md#spectral-to-linear-srgb).

Models are :class:`Evaluator` objects: an ``.onnx`` file through onnxruntime
(:class:`OnnxEvaluator`), a torch module on directions (:class:`TorchEvaluator`) or, as a truth,
an RGL ``.bsdf`` measurement through Mitsuba's ``measured`` plugin (:class:`MeasurementEvaluator`);
:class:`MemoEvaluator` remembers another's values, for a truth scored against many models;
:func:`truth_evaluator` opens a truth file of either kind.
"""

from __future__ import annotations

import copy
import hashlib
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from neuralbrdf.data.colorimetry import spectral_to_linear_srgb
from neuralbrdf.data.calibration import CALIBRATED_WAVELENGTHS_NM
from neuralbrdf.data.plans import is_glossy
from neuralbrdf.data.rgl_bsdf import SUFFIX as RGL_SUFFIX
from neuralbrdf.data.rgl_bsdf import RglBsdf
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import inplane_to_vectors, spherical_to_vector
from neuralbrdf.metrics import DEFAULT_FLOOR, hemisphere_logcos_rmse, masked_relative_rmse

#: Wavelengths (nm) at which spectra are compared: the measurement grid (docs/formats.md#gcms-raw-measurement).
COMPARISON_WAVELENGTHS_NM = np.arange(400.0, 701.0, 10.0)
#: Largest polar angle (degrees) of the hemisphere pairs.
HEMISPHERE_MAX_THETA_DEG = 80.0
#: ``(cos θ, φ)`` strata per direction; pairs = (product)².
HEMISPHERE_STRATA = (16, 20)
#: Most hemisphere pairs :func:`hemisphere_pairs` makes (ten times the default's 102 400: a spectral
#: comparison holds 31 float64 values per pair and side, ~250 MB each at this size).
MAX_HEMISPHERE_PAIRS = 1_048_576
#: In-plane grid: signed angles within ±limit, every step (degrees).
INPLANE_LIMIT_DEG = 60.0
INPLANE_STEP_DEG = 1.0
#: The fixed names of the direction metrics.
DIRECTION_METRICS = (
    "hemisphere_logcos_rmse",
    "hemisphere_rel_rmse",
    "inplane_glossy_rel_rmse",
    "inplane_diffuse_rel_rmse",
)
#: Rows per evaluation call (bounds memory for 31-wavelength spectra).
CHUNK_ROWS = 2**16


class Evaluator(Protocol):
    """A BRDF model on directions: ``values(wi, wo, wavelength)`` -> ``[N]`` (spectral) or ``[N, 3]``."""

    is_spectral: bool

    def values(self, wi: np.ndarray, wo: np.ndarray, wavelength: np.ndarray | None) -> np.ndarray: ...


class OnnxEvaluator:
    """An ``.onnx`` model file (docs/formats.md#onnx-model-files) evaluated with onnxruntime: its ``f``, or one of its fast
    paths (``output``; ``model`` is then the file cut to that output, ``f_rgb`` an RGB model, and
    ``file`` the whole file); a spectral model at wavelengths clamped to its declared range, as the
    renderer evaluates it (docs/mitsuba-plugin.md), so the scores measure what renders."""

    def __init__(self, path: str | Path, output: str = "f") -> None:
        import onnxruntime

        from neuralbrdf.kinds import load_model

        self.file = load_model(path)
        self.model = self.file.output_view(output)
        self.is_spectral = self.model.is_spectral
        self.session = onnxruntime.InferenceSession(
            self.model.proto.SerializeToString(), providers=["CPUExecutionProvider"]
        )

    def values(self, wi, wo, wavelength=None):
        feeds = {"wi": wi.astype(np.float32), "wo": wo.astype(np.float32)}
        if self.is_spectral:
            feeds["wavelength"] = np.clip(wavelength, *self.model.wavelength_range_nm).astype(np.float32)
        return self.session.run(["f"], feeds)[0].astype(np.float64)


@dataclass(frozen=True)
class MeasurementFile:
    """What an evaluation records of a measurement file, as it records a model file's
    (:class:`~neuralbrdf.onnx_contract.OnnxModel`): kind ``measurement``."""

    path: Path
    material: str
    wavelength_range_nm: tuple[float, float] | None
    sha256: str
    kind: str = "measurement"


class MeasurementEvaluator:
    """An RGL ``.bsdf`` measurement as a truth: Mitsuba's ``measured`` plugin, values clipped at 0
    (:mod:`neuralbrdf.data.rgl_bsdf`); a spectral file read at the report's bands, 400–700 nm."""

    def __init__(self, path: str | Path) -> None:
        self.brdf = RglBsdf.load(path)
        self.is_spectral = self.brdf.is_spectral
        bands = (float(CALIBRATED_WAVELENGTHS_NM[0]), float(CALIBRATED_WAVELENGTHS_NM[-1]))
        self.model = MeasurementFile(Path(path), self.brdf.name, bands if self.is_spectral else None,
                                     hashlib.sha256(Path(path).read_bytes()).hexdigest())

    def values(self, wi, wo, wavelength=None):
        return self.brdf.values(wi, wo, wavelength)


def is_measurement(path: str | Path) -> bool:
    """Whether a truth file is a measurement (an RGL ``.bsdf``) rather than a model file."""
    return Path(path).suffix == RGL_SUFFIX


def truth_evaluator(path: str | Path) -> OnnxEvaluator | MeasurementEvaluator:
    """A truth file opened as an :class:`Evaluator`: a model file (``.onnx``) or an RGL measurement."""
    return MeasurementEvaluator(path) if is_measurement(path) else OnnxEvaluator(path)


class TorchEvaluator:
    """A torch module on directions (:mod:`neuralbrdf.models.directional`, a truth), evaluated in
    float64 on a copy (the module itself is left as it is)."""

    def __init__(self, module: torch.nn.Module, is_spectral: bool) -> None:
        self.module = copy.deepcopy(module).double().eval()
        self.is_spectral = is_spectral

    def values(self, wi, wo, wavelength=None):
        module = self.module
        inputs = [torch.from_numpy(np.asarray(wi, dtype=np.float64)), torch.from_numpy(np.asarray(wo, dtype=np.float64))]
        if self.is_spectral:
            inputs.append(torch.from_numpy(np.asarray(wavelength, dtype=np.float64)))
        with torch.no_grad():
            return module(*inputs).numpy()


class MemoEvaluator:
    """Another evaluator whose values are remembered per distinct input (keyed by the inputs'
    bytes), for a truth scored against many models on the same fixed direction pairs; at most
    ``entries`` inputs are kept, the least recently used dropped first.  The values handed out
    are read-only arrays (shared between calls)."""

    def __init__(self, inner: Evaluator, entries: int = 8) -> None:
        self.inner = inner
        self.is_spectral = inner.is_spectral
        self.entries = entries
        self._values: OrderedDict[bytes, np.ndarray] = OrderedDict()

    def __getattr__(self, name):  # the inner evaluator's other attributes (``model`` of an OnnxEvaluator)
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    def values(self, wi, wo, wavelength=None):
        digest = hashlib.blake2b(digest_size=20)
        for array in (wi, wo) + ((wavelength,) if self.is_spectral else ()):
            array = np.ascontiguousarray(array)
            digest.update(f"{array.dtype.str}{array.shape}".encode())
            digest.update(array.data)
        key = digest.digest()
        if key in self._values:
            self._values.move_to_end(key)
            return self._values[key]
        value = np.asarray(self.inner.values(wi, wo, wavelength))
        value.flags.writeable = False
        self._values[key] = value
        while len(self._values) > self.entries:
            self._values.popitem(last=False)
        return value


def check_strata(strata: tuple[int, int], key: str = "hemisphere strata") -> None:
    """:class:`InputError` unless ``strata`` are two positive integers giving at most
    :data:`MAX_HEMISPHERE_PAIRS` pairs."""
    if len(strata) != 2 or any(isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1 for n in strata):
        raise InputError(f"{key}: expected two positive integers [n_cos, n_phi], got {list(strata)}")
    pairs = (int(strata[0]) * int(strata[1])) ** 2
    if pairs > MAX_HEMISPHERE_PAIRS:
        raise InputError(f"{key} {list(strata)} give {pairs} direction pairs; at most {MAX_HEMISPHERE_PAIRS}")


def hemisphere_pairs(seed: int = 0, strata: tuple[int, int] = HEMISPHERE_STRATA) -> tuple[np.ndarray, np.ndarray]:
    """Stratified direction pairs ``wi, wo`` ``[N, 3]`` (module docstring), ``N = (16·20)²`` by default."""
    check_strata(strata)
    rng = np.random.default_rng(seed)
    n_cos, n_phi = strata
    per_direction = n_cos * n_phi
    cos_low = np.cos(np.radians(HEMISPHERE_MAX_THETA_DEG))
    cos_cell, phi_cell = np.meshgrid(np.arange(n_cos), np.arange(n_phi), indexing="ij")
    cells = np.stack([cos_cell.ravel(), phi_cell.ravel()], axis=1)
    i_cell = np.repeat(cells, per_direction, axis=0)
    o_cell = np.tile(cells, (per_direction, 1))

    def directions(cell):
        u = (cell + rng.uniform(size=cell.shape)) / np.array([n_cos, n_phi])
        cos_theta = cos_low + u[:, 0] * (1.0 - cos_low)
        return spherical_to_vector(np.degrees(np.arccos(cos_theta)), 360.0 * u[:, 1])

    return directions(i_cell), directions(o_cell)


def inplane_pairs() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(theta_i, theta_r, wi, wo)`` of the in-plane grid (signed degrees; module docstring)."""
    steps = round(2 * INPLANE_LIMIT_DEG / INPLANE_STEP_DEG) + 1
    angles = np.linspace(-INPLANE_LIMIT_DEG, INPLANE_LIMIT_DEG, steps)
    theta_i, theta_r = (a.ravel() for a in np.meshgrid(angles, angles, indexing="ij"))
    wi, wo = inplane_to_vectors(theta_i, theta_r)
    return theta_i, theta_r, wi, wo


def compares_spectra(model: Evaluator, truth: Evaluator) -> bool:
    """Whether the two are compared as spectra (both spectral) rather than in linear sRGB."""
    return model.is_spectral and truth.is_spectral


def compared_values(evaluator: Evaluator, wi: np.ndarray, wo: np.ndarray, spectral: bool) -> np.ndarray:
    """``[N, 31]`` spectra at :data:`COMPARISON_WAVELENGTHS_NM` (``spectral``) or ``[N, 3]`` linear sRGB."""
    chunks = []
    for start in range(0, len(wi), CHUNK_ROWS):
        chunk_wi, chunk_wo = wi[start : start + CHUNK_ROWS], wo[start : start + CHUNK_ROWS]
        if not evaluator.is_spectral:
            chunks.append(evaluator.values(chunk_wi, chunk_wo, None))
            continue
        n, w = len(chunk_wi), len(COMPARISON_WAVELENGTHS_NM)
        spectra = evaluator.values(
            np.repeat(chunk_wi, w, axis=0), np.repeat(chunk_wo, w, axis=0), np.tile(COMPARISON_WAVELENGTHS_NM, n)
        ).reshape(n, w)
        chunks.append(spectra if spectral else spectral_to_linear_srgb(spectra, COMPARISON_WAVELENGTHS_NM))
    values = np.concatenate(chunks)
    if not np.all(np.isfinite(values)):
        raise ValueError("the model returned non-finite BRDF values")
    return values


@dataclass(frozen=True)
class DirectionScores:
    """The four direction metrics and what they were computed on."""

    metrics: dict[str, float]
    comparison: str
    n_hemisphere_pairs: int
    n_inplane_pairs: int
    #: Spectral comparisons: in-plane glossy/diffuse relative RMSE per wavelength.
    per_wavelength: dict[str, list[float]] | None

    def to_dict(self) -> dict:
        return {
            **self.metrics,
            "comparison": self.comparison,
            "n_hemisphere_pairs": self.n_hemisphere_pairs,
            "n_inplane_pairs": self.n_inplane_pairs,
            "per_wavelength": self.per_wavelength,
        }


def _finite_or_none(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def hemisphere_scores(
    model: Evaluator, truth: Evaluator, seed: int = 0, strata: tuple[int, int] = HEMISPHERE_STRATA
) -> dict[str, float]:
    """``hemisphere_logcos_rmse`` and ``hemisphere_rel_rmse`` over :func:`hemisphere_pairs`."""
    spectral = compares_spectra(model, truth)
    wi, wo = hemisphere_pairs(seed, strata)
    pred, target = compared_values(model, wi, wo, spectral), compared_values(truth, wi, wo, spectral)
    theta_i = np.degrees(np.arccos(np.clip(wi[:, 2], -1.0, 1.0)))
    rows = np.ones(len(wi), dtype=bool)
    return {
        "hemisphere_logcos_rmse": hemisphere_logcos_rmse(np.clip(pred, 0.0, None), target, theta_i),
        "hemisphere_rel_rmse": masked_relative_rmse(pred, target, rows, DEFAULT_FLOOR, "hemisphere").value,
    }


def inplane_scores(pred: np.ndarray, target: np.ndarray, theta_i: np.ndarray, theta_r: np.ndarray):
    """``(metrics, per_channel)``: glossy and diffuse relative RMSE of in-plane samples ``[N, C]``."""
    glossy = is_glossy(theta_i, theta_r)
    regions = {"inplane_glossy_rel_rmse": (glossy, "glossy"), "inplane_diffuse_rel_rmse": (~glossy, "diffuse")}
    metrics, per_channel = {}, {}
    for name, (rows, region) in regions.items():
        result = masked_relative_rmse(pred, target, rows, DEFAULT_FLOOR, region)
        metrics[name], per_channel[name] = result.value, [_finite_or_none(v) for v in result.per_channel]
    return metrics, per_channel


def direction_scores(
    model: Evaluator, truth: Evaluator, seed: int = 0, strata: tuple[int, int] = HEMISPHERE_STRATA
) -> DirectionScores:
    """The four metrics of :data:`DIRECTION_METRICS` of ``model`` against ``truth``
    (``strata``: fewer hemisphere pairs, for quick checks; the fixed names mean the default)."""
    spectral = compares_spectra(model, truth)
    theta_i, theta_r, wi, wo = inplane_pairs()
    inplane, per_channel = inplane_scores(
        compared_values(model, wi, wo, spectral), compared_values(truth, wi, wo, spectral), theta_i, theta_r
    )
    per_wavelength = {"wavelength_nm": COMPARISON_WAVELENGTHS_NM.tolist(), **per_channel} if spectral else None
    n_cos, n_phi = strata
    return DirectionScores(
        metrics={**hemisphere_scores(model, truth, seed, strata), **inplane},
        comparison="spectral (31 wavelengths, 400-700 nm)" if spectral else "linear sRGB",
        n_hemisphere_pairs=(n_cos * n_phi) ** 2,
        n_inplane_pairs=len(theta_i),
        per_wavelength=per_wavelength,
    )


def fit_scores(pred_fit, fit_values, theta_i, theta_r, pred_truth=None, truth_values=None,
               truth_theta_i=None) -> dict[str, float | None]:
    """The metrics every training run writes to ``metrics.json`` under these names (docs/evaluate.md#metrics).

    ``inplane_glossy_rel_rmse`` and ``inplane_diffuse_rel_rmse`` of ``pred_fit`` against the
    values ``[N, C]`` the model was given, at signed in-plane angles ``theta_i, theta_r`` (rows off
    the plane of incidence count by their in-plane equivalent, ``|θi − θr| = 2 θh``); a region
    without a sample above the floor gives ``None``.  With a truth (values on the fit's evaluation
    plan, by default the dense Löw set, of a virtual material or NBRDF proxy, the model's values
    there and the incident polar angles), ``plan_logcos_rmse``: the log-cosine RMSE on that plan's
    pairs, named apart from ``neuralbrdf evaluate``'s ``hemisphere_logcos_rmse`` over stratified
    hemisphere pairs (docs/evaluate.md#metrics), a different number for the same model.
    """
    glossy = is_glossy(theta_i, theta_r)
    metrics: dict[str, float | None] = {}
    for name, rows, region in (("inplane_glossy_rel_rmse", glossy, "glossy"),
                               ("inplane_diffuse_rel_rmse", ~glossy, "diffuse")):
        try:
            metrics[name] = masked_relative_rmse(pred_fit, fit_values, rows, DEFAULT_FLOOR, region).value
        except ValueError:
            metrics[name] = None
    if truth_values is not None:
        metrics["plan_logcos_rmse"] = hemisphere_logcos_rmse(np.clip(pred_truth, 0.0, None), truth_values,
                                                             truth_theta_i)
    return metrics
