"""Fast paths inside an exported model file (docs/formats.md#onnx-model-files, docs/select.md): ``neuralbrdf export`` adds them.

A fast path is a further output of the model's own ``.onnx`` file that stands in for ``f`` at a
fraction of its cost, so that a user does not pay for the full network where a picture does not
need it (the Mitsuba plugin picks the output; :mod:`neuralbrdf.render.fast_paths`):

* ``f_rgb`` — **the RGB head** of a spectral model: its linear sRGB as the plugin integrates it
  in RGB variants (docs/formats.md#spectral-to-linear-srgb: CIE 1931 2°, D65, 31 wavelengths, negatives clipped), evaluated
  once per query instead of once per wavelength of the sRGB rule.  Any spectral file of the
  contract gets one, whatever its kind: it is distilled from the file itself.  The plugin uses
  it in RGB variants unless told not to.  It is made only for a model whose wavelength range
  holds at least :data:`~neuralbrdf.data.colorimetry.MIN_OBSERVER_COVERAGE` of each of the
  observer's X, Y, Z weights over 400–700 nm (:func:`rgb_head_problem`): a model of 800–900 nm would otherwise get a head
  distilled from its own value at 800 nm, clamped there for every wavelength of the conversion.
* ``f_fast`` — **a compact copy** of ``f`` (RGB, or spectral for spectral models): what the
  plugin evaluates when asked (property ``fast``, ``neuralbrdf render --fast``), and a rung of
  ``neuralbrdf select`` (:func:`neuralbrdf.lod.ladder.embedded_ladder`).

Both are :class:`~neuralbrdf.models.student.DirectionalStudent` networks distilled from the
model (:func:`~neuralbrdf.lod.distill.distill_student`; the teacher's samples of
:func:`~neuralbrdf.lod.distill.teacher_samples`, for ``f_rgb`` the exact 31-wavelength integral
:func:`~neuralbrdf.lod.distill.rgb_teacher`).  Each records in the file's metadata (keys
``neuralbrdf.<output>.*`` of docs/formats.md#onnx-model-files) what it approximates, its error against its teacher —
``hemisphere_logcos_rmse`` (docs/evaluate.md#metrics) on the hemisphere pairs of
:func:`~neuralbrdf.evaluation.scores.hemisphere_scores`, the student in float64 — and its
relative cost: the operations of the student's Dr.Jit kernel over the model's
(:func:`~neuralbrdf.study.cost.drjit_operation_count`), for ``f_rgb`` over the model's times the
wavelength count of the plugin's default sRGB rule (the evaluations per query the head
replaces).  The cost is counted, not timed, and the distillation is seeded, so exporting one
checkpoint twice writes the same bytes (a timed cost varied 0.10–0.14 between runs of one
export; ``neuralbrdf ladder`` times its rungs).  A student whose error exceeds
``max_hemisphere_logcos_rmse`` is not embedded: :class:`FastPathError` says so, and
``neuralbrdf export`` writes nothing.

**Where users look.**  Each fast path is also rendered against ``f`` (:func:`image_errors`): the
material-preview scene through the fast path and through ``f`` at the same seed — both outputs of
one file, so both trace the same paths and the difference is the fast path's own error — in
``llvm_ad_spectral`` for a spectral ``f_fast``, in ``llvm_ad_rgb`` otherwise (``f_rgb`` against
``f`` integrated by the plugin's sRGB rule).  The mean CIEDE2000 and the render's settings are
recorded (``image_delta_e2000_mean``, ``image_check``), and a fast path whose mean exceeds
``image_check.max_delta_e2000_mean`` is refused like one beyond the hemisphere bound.

The settings are ``configs/lod/default.yaml``, section ``fast_paths`` (:mod:`neuralbrdf.lod.config`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx

from neuralbrdf.atomic import atomic_path
from neuralbrdf.data.colorimetry import colour_problem
from neuralbrdf.errors import InputError
from neuralbrdf.evaluation.scores import HEMISPHERE_STRATA, OnnxEvaluator, TorchEvaluator, hemisphere_scores
from neuralbrdf.kinds import Exportable, load_model
from neuralbrdf.lod.distill import DistillSettings, distill_student, rgb_teacher, teacher_samples
from neuralbrdf.onnx_contract import OUTPUT_F, OUTPUT_FAST, OUTPUT_RGB, FastPath, fast_path_key
from neuralbrdf.onnx_export import save_checked, trace, validate, with_fast_paths


def rgb_head_problem(wavelength_range_nm: tuple[float, float] | None) -> str | None:
    """Why a model of this wavelength range (``None``: RGB) gets no RGB head ``f_rgb``, or ``None``
    when it may have one (module docstring)."""
    if wavelength_range_nm is None:
        return "an RGB head (f_rgb) is for spectral models; this model is RGB"
    problem = colour_problem(wavelength_range_nm, "the model")
    return None if problem is None else f"{problem}, so it gets no RGB head (f_rgb); render it in a spectral variant"


class FastPathError(ValueError):
    """The fast path ``output`` could not be made within its error bound; nothing was written."""

    def __init__(self, message: str, output: str) -> None:
        super().__init__(message)
        self.output = output


@dataclass(frozen=True)
class StudentShape:
    """Size of a student network: ``hidden_layers`` layers of ``hidden`` units, ``activation``."""

    hidden_layers: int
    hidden: int
    activation: str


@dataclass(frozen=True)
class ImageCheck:
    """The renders that measure a fast path's image error against ``f`` (module docstring)."""

    resolution: int
    spp: int
    seed: int
    #: A fast path whose mean CIEDE2000 against ``f`` exceeds this is refused (:class:`FastPathError`).
    max_delta_e2000_mean: float


@dataclass(frozen=True)
class FastPathSettings:
    """How the fast paths are made (values: ``configs/lod/default.yaml``, section ``fast_paths``)."""

    rgb_head: StudentShape
    fast: StudentShape
    distill: DistillSettings
    #: A student with a larger error against its teacher is refused (:class:`FastPathError`).
    max_hemisphere_logcos_rmse: float
    image_check: ImageCheck
    #: ``(cos θ, φ)`` strata of the hemisphere pairs of the recorded error (docs/evaluate.md#metrics by default).
    error_strata: tuple[int, int] = HEMISPHERE_STRATA


def _student(parent: OnnxEvaluator, output: str, settings: FastPathSettings) -> tuple[Exportable, str, float]:
    """The distilled student of ``output`` as an exportable model, its description and its error."""
    model = parent.model
    teacher = rgb_teacher(parent) if output == OUTPUT_RGB else parent
    range_nm = model.wavelength_range_nm if teacher.is_spectral else None
    shape = settings.rgb_head if output == OUTPUT_RGB else settings.fast
    samples = teacher_samples(teacher, settings.distill.n_pairs, settings.distill.seed, range_nm)
    module = distill_student(samples, shape.hidden, shape.hidden_layers, shape.activation, settings.distill, range_nm)
    error = float(hemisphere_scores(TorchEvaluator(module, teacher.is_spectral), teacher, strata=settings.error_strata)
                  ["hemisphere_logcos_rmse"])
    what = "linear sRGB of f (31-wavelength integral, docs/formats.md#spectral-to-linear-srgb)" if output == OUTPUT_RGB else "f"
    describes = f"{module.describe()} distilled from {settings.distill.n_pairs} samples of the {what}"
    if not error <= settings.max_hemisphere_logcos_rmse:
        raise FastPathError(f"the {output} student's error against the model, hemisphere log-cos RMSE {error:.3g}, "
                            f"is above the bound {settings.max_hemisphere_logcos_rmse:g} (fast_paths."
                            "max_hemisphere_logcos_rmse)", output)
    # only traced to be merged into the model's graph: the file keeps the model's own metadata
    return Exportable(module, model.kind, model.material, {}, range_nm), describes, error


def _rgb_rule_size(parent: OnnxEvaluator) -> int:
    """Wavelengths of the plugin's default sRGB rule for this spectral model (evaluations per RGB query)."""
    from neuralbrdf.render.load_time import fit_rgb_rule
    from neuralbrdf.render.spectral_quadrature import DEFAULT_RMS_TOLERANCE

    return fit_rgb_rule(parent.model, parent.session, DEFAULT_RMS_TOLERANCE).size


#: Queries of the evaluation whose Dr.Jit kernel is counted (the count does not depend on it).
COUNTED_QUERIES = 1024


def operation_counts(protos: dict[str, onnx.ModelProto], spectral: bool) -> dict[str, int]:
    """Operations of the Dr.Jit kernel that evaluates each graph's output (spectral graphs: one
    wavelength per query), :func:`~neuralbrdf.study.cost.drjit_operation_count`."""
    from neuralbrdf.render.drjit_onnx import DrJitGraph
    from neuralbrdf.study.cost import drjit_inputs, drjit_operation_count, probe_inputs

    inputs = drjit_inputs(probe_inputs(COUNTED_QUERIES, spectral), spectral)
    return {name: drjit_operation_count(DrJitGraph(proto), inputs) for name, proto in protos.items()}


def add_fast_paths(model_path: str | Path, out: str | Path, outputs: tuple[str, ...], settings: FastPathSettings,
                   log=print) -> list[FastPath]:
    """Write ``out``: the model file ``model_path`` with the fast paths ``outputs`` (``f_rgb``,
    ``f_fast``) added (module docstring), atomically and only after the contract check accepted
    it; nothing is written on failure (:class:`FastPathError`,
    :class:`~neuralbrdf.onnx_export.ExportValidationError`,
    :class:`~neuralbrdf.errors.InputError`)."""
    model_path = Path(model_path)
    parent = OnnxEvaluator(model_path)
    model = parent.model
    for output in outputs:
        if output not in (OUTPUT_RGB, OUTPUT_FAST):
            raise ValueError(f"unknown fast path {output!r}")
        problem = rgb_head_problem(model.wavelength_range_nm) if output == OUTPUT_RGB else None
        if problem is not None:
            raise InputError(problem, path=model_path)
        if output in parent.file.fast_paths:
            raise InputError(f"the model already has the fast path {output!r}", path=model_path)
    traced, entries, reports = {}, {}, []
    for output in outputs:
        log(f"{output}: distilling ({settings.distill.steps} steps) ...")
        exportable, describes, error = _student(parent, output, settings)
        proto = trace(exportable)
        validate(proto, exportable)  # onnxruntime reproduces the student: ExportValidationError otherwise
        traced[output] = proto
        entries[output] = (describes, error)
        log(f"{output}: {describes}; log-cos RMSE {error:.4f}")
    costs = operation_counts({OUTPUT_F: model.proto, **traced}, model.is_spectral)
    per_query = {OUTPUT_FAST: costs[OUTPUT_F]}
    if OUTPUT_RGB in traced:
        per_query[OUTPUT_RGB] = costs[OUTPUT_F] * _rgb_rule_size(parent)
    metadata = {}
    for output, (describes, error) in entries.items():
        relative = costs[output] / per_query[output]
        metadata.update({fast_path_key(output, "approximates"): describes,
                         fast_path_key(output, "hemisphere_logcos_rmse"): repr(error),
                         fast_path_key(output, "relative_cost"): repr(relative)})
    combined = with_fast_paths(parent.file.proto, traced, metadata)
    out = Path(out)
    with atomic_path(out) as tmp:
        save_checked(combined, tmp, "the file with fast paths")
        check = settings.image_check
        for output, (delta_e, where) in image_errors(tmp, outputs, check).items():
            log(f"{output}: image ΔE2000 mean {delta_e:.3f} against f ({where})")
            if not delta_e <= check.max_delta_e2000_mean:
                raise FastPathError(f"the {output} student renders ΔE2000 {delta_e:.3g} (mean) away from the model, "
                                    f"above the bound {check.max_delta_e2000_mean:g} (fast_paths.image_check."
                                    "max_delta_e2000_mean)", output)
            entries[output] += (delta_e, where)
            metadata.update({fast_path_key(output, "image_delta_e2000_mean"): repr(delta_e),
                             fast_path_key(output, "image_check"): where})
        onnx.save(with_fast_paths(parent.file.proto, traced, metadata), str(tmp))
        for output, (describes, error, delta_e, where) in entries.items():
            reports.append(FastPath(output, describes, error, float(metadata[fast_path_key(output, "relative_cost")]),
                                    delta_e, where))
    return reports


def image_errors(path: Path, outputs: tuple[str, ...], check: ImageCheck) -> dict[str, tuple[float, str]]:
    """Per fast path of the file ``path``: the mean CIEDE2000 of the preview scene rendered through
    it against the render of ``f`` (same seed, same paths), and where (module docstring)."""
    from neuralbrdf.evaluation.images import image_scores
    from neuralbrdf.render.preview import Material, render

    spectral = load_model(path).is_spectral
    found, f_images = {}, {}
    for output in outputs:
        variant = "llvm_ad_spectral" if output == OUTPUT_FAST and spectral else "llvm_ad_rgb"
        if variant not in f_images:
            f_images[variant] = render(Material(model=path, rgb_head=False), variant, check.spp, check.resolution,
                                       check.seed)
        image = render(Material(model=path, fast=output == OUTPUT_FAST, rgb_head=output == OUTPUT_RGB), variant,
                       check.spp, check.resolution, check.seed)
        metrics, _ = image_scores(image, f_images[variant])
        found[output] = (metrics["image_delta_e2000_mean"],
                         f"material-preview scene, {variant}, {check.resolution} px, {check.spp} spp, seed {check.seed}, "
                         "the same paths as f")
    return found

