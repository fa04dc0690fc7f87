"""``neuralbrdf evaluate``: a model file scored against a truth file where users look (docs/evaluate.md).

Direction metrics (:mod:`neuralbrdf.evaluation.scores`: whole hemisphere, in-plane glossy and
diffuse regions) and image metrics (:mod:`neuralbrdf.evaluation.images`) from rendering model
and truth in the material-preview scene (:mod:`neuralbrdf.render.preview`) with the same
variant, backend, seeds and passes.  Monte Carlo noise is stated, not hidden: the truth is
rendered a second time with other seeds and the same image metrics between the two truth
renders are reported as ``noise`` — the noise of one render.  Model and truth share their seeds
and their paths: the model samples directions with the *truth's* proposal (the plugin's
``proposal`` property, which leaves the image's expectation unchanged), so the two renders trace
the same paths and most of the noise is common to both and cancels in their difference (the
demo's gold model: ΔE mean 0.33 against a noise level of 1.9).  This needs a render of a fixed
seed to be one image: the preview scene loads its lights in file order
(:func:`~neuralbrdf.render.preview.load_scene`).  Without the shared proposal, a model whose own
proposal differs from the truth's traced other paths and its ΔE was about the noise level
whatever its accuracy (the quick study's NLB nylon: ΔE 4.85 at a noise of 4.3, 8 spp).

**Fast paths** (:mod:`neuralbrdf.evaluation.fast_paths`).  The direction metrics score the
model's ``f``; the image metrics score what the plugin renders, which is the file's RGB head
``f_rgb`` for a spectral model in an RGB variant, and ``f_fast`` with ``--fast``
(``rendered_output``).  ``fast_paths`` lists each fast path's recorded and measured error against
``f`` and, for the one rendered, its image metrics against a render of ``f`` at the same seed.

Outputs in ``DIR`` (all written together, or none: :func:`neuralbrdf.atomic.atomic_paths`): ``evaluation.json`` (strict JSON),
``model.png``, ``truth.png``, ``error_map.png`` (ΔE2000 per pixel, colour bar in ΔE units) and
``comparison.png`` (truth | model | ΔE side by side).

**Checked first** (:func:`check_settings`, before any metric is computed): the render settings
— an image :data:`MIN_RESOLUTION` to :data:`MAX_RESOLUTION` pixels wide that this machine can
render, a positive sample count, a non-negative seed, a Mitsuba variant that starts — and that
every output can be written.  ``evaluation.json`` records what was compared: both files' kinds,
materials, wavelength ranges and SHA-256, and ``notes`` for what a reader must know (a truth that
is not a ground truth, kind ``reference``, docs/evaluate.md#ground-truths: then the scores measure a difference between
two models).

**A measurement as the truth** (``--truth NAME.bsdf``, an RGL measurement: Dupuy & Jakob 2018).
The direction metrics evaluate Mitsuba's own ``measured`` plugin
(:class:`~neuralbrdf.evaluation.scores.MeasurementEvaluator`), not a resampling of it, and the
truth image is rendered by that plugin (the ``neuralbrdf_measured`` BSDF of
:mod:`neuralbrdf.render.measured_bsdf`: its ``eval``, clipped at 0 like every other reading of the
file).  Here the paths are matched the other way round: the model renders with its own proposal
and the measurement with the model's.  Mitsuba reads an RGB file only in an RGB variant and a
spectral file only in a spectral one, so the variant must be of the file's kind
(:func:`measurement_variant` gives the default).

**Your own scene** (:class:`SceneTarget`, ``neuralbrdf evaluate --scene SCENE.xml [--material
NAME]``): any Mitsuba scene that uses the ``neuralbrdf`` BSDF; the named material is pointed at
the model, then at the truth (:mod:`neuralbrdf.render.scene_file`), everything else in the scene
stays as it is, and the same seeds, shared proposal and noise measurement apply.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from neuralbrdf.atomic import atomic_paths, check_outputs, file_version
from neuralbrdf.errors import InputError
from neuralbrdf.evaluation.fast_paths import fast_path_scores, image_against_f, rendered_output
from neuralbrdf.evaluation.images import IMAGE_METRICS, displayed, image_scores
from neuralbrdf.evaluation.scores import (
    DIRECTION_METRICS,
    HEMISPHERE_STRATA,
    Evaluator,
    OnnxEvaluator,
    direction_scores,
    is_measurement,
    truth_evaluator as open_truth,
)
from neuralbrdf.onnx_contract import OUTPUT_F
from neuralbrdf.render import DEFAULT_VARIANT

DEFAULT_SPP = 256
DEFAULT_RESOLUTION = 128
#: Seed of the second truth render that measures the noise (the renders themselves use ``seed``).
NOISE_SEED_OFFSET = 1_000_003
#: ΔE2000 range of the error map's colour scale (fixed, so that maps compare across models).
ERROR_MAP_MAX_DELTA_E = 10.0
NOISE_DESCRIPTION = (
    "the same metrics between two renders of the truth with different seeds: the Monte Carlo noise of one render. "
    "Model and truth are rendered with the same seeds, so most of that noise is shared and cancels in their "
    "difference; a model error well below this level is still resolved"
)
#: The same for a measurement as the truth: its renders sample with the model's proposal (matched paths), so
#: the noise of its render depends on the model it is compared with.
NOISE_DESCRIPTION_MEASURED = (
    NOISE_DESCRIPTION + ". A measurement as the truth is rendered with the model's sampling proposal, so this "
    "noise is that of the truth sampled as this model samples: two models scored against one measurement state "
    "different noise levels"
)
FILES = ("evaluation.json", "model.png", "truth.png", "error_map.png", "comparison.png")
#: Narrowest evaluation image: the preview's sphere spans about 59 % of the width (a disc of about
#: 27 % of the pixels), so 16 pixels give it about 70; at a few pixels the image metrics score the
#: background.
MIN_RESOLUTION = 16
#: Widest evaluation image: the image metrics hold about twenty float64 copies of an image
#: (~0.5 KB per pixel), ~2 GB at 2048 x 2048.
MAX_RESOLUTION = 2048
#: The kind of a ground truth model file (docs/evaluate.md#ground-truths) ...
REFERENCE_KIND = "reference"
#: ... and of a measurement given as the truth (:class:`~neuralbrdf.evaluation.scores.MeasurementFile`).
MEASUREMENT_KIND = "measurement"


def measurement_variant(truth_path: str | Path, variant: str | None) -> str:
    """The variant to render with: ``variant`` if given, else :data:`DEFAULT_VARIANT`, or for a
    measured truth its own kind of variant (``llvm_ad_rgb`` for an RGB file, ``llvm_ad_spectral`` for
    a spectral one); :class:`InputError` for a measurement and a variant of the other kind."""
    if not is_measurement(truth_path):
        return variant or DEFAULT_VARIANT
    from neuralbrdf.data.rgl_bsdf import RglBsdf

    own = RglBsdf.load(truth_path).variant
    if variant is not None and ("_spectral" in variant) != ("_spectral" in own):
        kind = "spectral" if "_spectral" in own else "RGB"
        raise InputError(f"an {kind} measurement: Mitsuba's measured plugin renders it only in {kind} variants such "
                         f"as {own} (the default for it), not in {variant}", path=truth_path)
    return variant or own


@dataclass(frozen=True)
class RenderSettings:
    """How model and truth are rendered (the same for both)."""

    variant: str = DEFAULT_VARIANT
    spp: int = DEFAULT_SPP
    resolution: int = DEFAULT_RESOLUTION
    seed: int = 0
    backend: str = "drjit"
    #: Render the model's fast path ``f_fast`` (the plugin's ``fast`` property).
    fast: bool = False


def check_settings(settings: RenderSettings, model_path: Path, render_images: bool = True) -> None:
    """:class:`InputError` for render settings an evaluation of ``model_path`` cannot use (module
    docstring), before any work; with ``render_images`` the variant is selected and the render size
    checked against this machine."""
    if isinstance(settings.seed, bool) or not isinstance(settings.seed, int) or settings.seed < 0:
        raise InputError(f"--seed must be a non-negative integer, got {settings.seed!r}")
    if not render_images:
        return
    if settings.spp < 1:
        raise InputError(f"--spp must be a positive integer, got {settings.spp}")
    if not MIN_RESOLUTION <= settings.resolution <= MAX_RESOLUTION:
        why = (f"below {MIN_RESOLUTION} the sphere covers too few pixels for the image metrics to score it"
               if settings.resolution < MIN_RESOLUTION else "larger images are not needed to score a model")
        raise InputError(f"--resolution must be {MIN_RESOLUTION} to {MAX_RESOLUTION} pixels, got {settings.resolution} "
                         f"({why})")
    from neuralbrdf.render.preview import Material, check_render_size, default_spp_per_pass, set_variant

    wavefront = Material(model=model_path, backend=settings.backend).needs_wavefront
    check_render_size(settings.resolution, min(settings.spp, default_spp_per_pass(settings.resolution, wavefront)),
                      wavefront)
    set_variant(settings.variant)


@dataclass(frozen=True)
class SceneTarget:
    """A user's Mitsuba scene to render in instead of the preview (docs/mitsuba-plugin.md): its ``neuralbrdf``
    material named ``material`` (``None``: the scene's only one) carries the model, then the truth;
    ``resolution`` sets the film's width and height (``None``: the scene's own)."""

    path: Path
    material: str | None = None
    resolution: int | None = None

    def material_name(self) -> str:
        """The material swapped, checked against the scene (one clear error before any work)."""
        from neuralbrdf.render.scene_file import SceneFile

        names = [material.name for material in SceneFile(self.path).materials()]
        if not names:
            raise InputError("has no neuralbrdf material to put the model in", path=self.path)
        if self.material is None and len(names) > 1:
            raise InputError(f"has {len(names)} neuralbrdf materials ({', '.join(names)}); name one with --material",
                             path=self.path)
        if self.material is not None and self.material not in names:
            raise InputError(f"no neuralbrdf material named {self.material!r}; it has {', '.join(names)}",
                             path=self.path)
        return self.material or names[0]

    def render(self, model: Path, settings: RenderSettings, seed: int, proposal: Path | None,
               rgb_head: bool = True) -> np.ndarray:
        """The scene with ``model`` in the material (sampled with ``proposal``'s proposal, if given;
        through its fast path with ``settings.fast``; ``rgb_head=False``: a spectral file's ``f``
        even in RGB variants); a measurement ``model`` (``.bsdf``) replaces the material by Mitsuba's
        ``measured`` plugin, sampled with ``proposal``."""
        from neuralbrdf.render.fast_paths import FAST_PROPERTY, RGB_HEAD_PROPERTY
        from neuralbrdf.render.preview import set_variant
        from neuralbrdf.render.scene_file import SceneFile, render_scene_file

        scene_file = SceneFile(self.path)
        if is_measurement(model):
            scene_file.set_measurement(self.material_name(), model, proposal)
            if self.resolution is not None:
                scene_file.set_resolution(self.resolution)
            set_variant(settings.variant)
            return render_scene_file(scene_file, settings.spp, seed)[0]
        properties = {"backend": settings.backend}
        if proposal is not None:
            properties["proposal"] = str(Path(proposal).resolve())
        if settings.fast:
            properties[FAST_PROPERTY] = "true"
        if not rgb_head:
            properties[RGB_HEAD_PROPERTY] = "false"
        scene_file.set_model(self.material_name(), model, properties)
        if self.resolution is not None:
            scene_file.set_resolution(self.resolution)
        set_variant(settings.variant)
        return render_scene_file(scene_file, settings.spp, seed)[0]


def _render(path: Path, settings: RenderSettings, seed: int, proposal: Path | None = None,
            scene: SceneTarget | None = None, rgb_head: bool = True) -> np.ndarray:
    """One render of the preview scene, or of ``scene`` (``settings.fast``: the file's fast path
    ``f_fast``; ``rgb_head=False``: a spectral file's ``f`` even in RGB variants); a measurement
    ``path`` renders through Mitsuba's ``measured`` plugin with ``proposal``'s proposal."""
    from neuralbrdf.render.preview import Material, render

    if scene is not None:
        image = scene.render(path, settings, seed, proposal, rgb_head)
    elif is_measurement(path):
        image = render(Material(measurement=path, proposal=proposal), settings.variant, settings.spp,
                       settings.resolution, seed)
    else:
        material = Material(model=path, backend=settings.backend, proposal=proposal, fast=settings.fast,
                            rgb_head=rgb_head)
        image = render(material, settings.variant, settings.spp, settings.resolution, seed)
    if not np.all(np.isfinite(image)):
        raise ValueError(f"the render of {path} is not finite")
    return image


def _render_kept(kept: dict | None, path: Path, settings: RenderSettings, seed: int,
                 scene: SceneTarget | None = None, proposal: Path | None = None) -> np.ndarray:
    """:func:`_render` of a truth (its ``f``: ``--fast`` is the model's; a measurement with
    ``proposal``'s proposal), or its image kept in ``kept`` from an earlier call for the same file
    (path, size, modification time, inode: :func:`~neuralbrdf.atomic.file_version`), proposal file,
    settings, seed and scene (read-only: shared by later calls)."""
    own = replace(settings, fast=False)
    if kept is None:
        return _render(path, own, seed, proposal, scene)
    key = (file_version(path), None if proposal is None else file_version(proposal), own, seed,
           None if scene is None else (file_version(scene.path), scene))
    if key not in kept:
        image = _render(path, own, seed, proposal, scene)
        image.flags.writeable = False
        kept[key] = image
    return kept[key]


def _write_png(image: np.ndarray, path: Path) -> None:
    import matplotlib.pyplot as plt

    plt.imsave(path, displayed(image))


def _error_axes(ax, delta_e: np.ndarray, fig) -> None:
    shown = ax.imshow(delta_e, cmap="magma", vmin=0.0, vmax=ERROR_MAP_MAX_DELTA_E)
    ax.set_axis_off()
    bar = fig.colorbar(shown, ax=ax, fraction=0.046, pad=0.04, extend="max")
    bar.set_label("CIEDE2000 ΔE (1 ≈ just noticeable)")


def _write_error_map(delta_e: np.ndarray, title: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.2, 4.4))
    _error_axes(ax, delta_e, fig)
    ax.set_title(title, fontsize=9)
    fig.savefig(path, dpi=100, bbox_inches="tight", format="png")
    plt.close(fig)


def _write_comparison(model: np.ndarray, truth: np.ndarray, delta_e: np.ndarray, names: tuple[str, str],
                      summary: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 4.4))
    for ax, image, label in ((axes[0], truth, f"truth: {names[1]}"), (axes[1], model, f"model: {names[0]}")):
        ax.imshow(displayed(image))
        ax.set_title(label, fontsize=9)
        ax.set_axis_off()
    _error_axes(axes[2], delta_e, fig)
    axes[2].set_title("ΔE2000 model vs truth", fontsize=9)
    fig.suptitle(summary, fontsize=9)
    fig.savefig(path, dpi=100, bbox_inches="tight", format="png")
    plt.close(fig)


def _json_number(value):
    return None if value is None or not math.isfinite(value) else value


def evaluate(model_path: str | Path, truth_path: str | Path, out_dir: str | Path,
             settings: RenderSettings = RenderSettings(), render_images: bool = True,
             strata: tuple[int, int] = HEMISPHERE_STRATA, truth_evaluator: Evaluator | None = None,
             truth_renders: dict | None = None, scene: SceneTarget | None = None) -> dict:
    """Score ``model_path`` against ``truth_path`` and write ``out_dir`` (module docstring);
    ``strata``: fewer hemisphere pairs than the default, for quick studies and tests;
    ``truth_evaluator``: ``truth_path`` already loaded (a study keeps one per truth,
    :class:`~neuralbrdf.evaluation.scores.MemoEvaluator`); ``truth_renders``: a dictionary in which
    the truth's two renders are kept (by file, settings and seed) and found again when the same
    truth is evaluated with the same settings (a study's models of one material); ``scene``: render
    in a user's scene instead of the preview (:class:`SceneTarget`)."""
    model_path, truth_path, out_dir = Path(model_path), Path(truth_path), Path(out_dir)
    scene_material = scene.material_name() if scene is not None and render_images else None
    started = time.perf_counter()
    measured = is_measurement(truth_path)
    if measured and render_images:
        measurement_variant(truth_path, settings.variant)  # one line for a variant of the other kind
    check_settings(settings, model_path, render_images)
    check_outputs(*(out_dir / name for name in FILES[: 5 if render_images else 1]))
    model = OnnxEvaluator(model_path)
    truth = open_truth(truth_path) if truth_evaluator is None else truth_evaluator
    directions = direction_scores(model, truth, strata=strata)
    timings = {"directions_s": time.perf_counter() - started}
    result = {
        "model": str(model_path),
        "truth": str(truth_path),
        **_described("model", model.model),
        **_described("truth", truth.model),
        "notes": _notes(model.model, truth.model),
        **{name: directions.metrics[name] for name in DIRECTION_METRICS},
    }
    output = rendered_output(model.file, settings.variant, settings.fast) if render_images else OUTPUT_F
    fast_paths = fast_path_scores(model_path, strata)
    result.update(rendered_output=output if render_images else None, fast_paths=fast_paths)
    images = None
    if render_images:
        render_started = time.perf_counter()
        # matched paths: the model samples with the truth's proposal, a measurement with the model's
        model_proposal, truth_proposal = (None, model_path) if measured else (truth_path, None)
        model_image = _render(model_path, settings, settings.seed, model_proposal, scene)
        truth_image = _render_kept(truth_renders, truth_path, settings, settings.seed, scene, truth_proposal)
        truth_again = _render_kept(truth_renders, truth_path, settings, settings.seed + NOISE_SEED_OFFSET, scene,
                                   truth_proposal)
        timings["render_s"] = time.perf_counter() - render_started
        image_metrics, delta_e = image_scores(model_image, truth_image)
        noise, _ = image_scores(truth_again, truth_image)
        result.update(image_metrics)
        result["noise"] = {**noise, "what": NOISE_DESCRIPTION_MEASURED if measured else NOISE_DESCRIPTION}
        images = (model_image, truth_image, delta_e)
        if output != OUTPUT_F:  # what the fast path changes in the picture: f at the same seed and paths
            f_image = _render(model_path, replace(settings, fast=False), settings.seed, proposal=model_proposal,
                              scene=scene, rgb_head=False)
            fast_paths[output]["image_against_f"] = image_against_f(model_image, f_image)
    result.update(
        variant=settings.variant if render_images else None,
        backend=settings.backend if render_images else None,
        spp=settings.spp if render_images else None,
        resolution=(settings.resolution if scene is None else list(images[0].shape[1::-1])) if images else None,
        seed=settings.seed,
        direction_details=directions.to_dict(),
        timings_s={**timings, "total_s": time.perf_counter() - started},
    )
    if scene_material is not None:
        result.update(scene=str(scene.path), scene_material=scene_material)
    result = {key: _json_number(value) if isinstance(value, float) else value for key, value in result.items()}
    _write_outputs(result, images, (model_path.name, truth_path.name), out_dir)
    return result


def _described(role: str, model) -> dict:
    """What ``evaluation.json`` records of the model or the truth file (module docstring)."""
    return {f"{role}_kind": model.kind, f"{role}_material": model.material,
            f"{role}_wavelength_range_nm": None if model.wavelength_range_nm is None else list(model.wavelength_range_nm),
            f"{role}_sha256": model.sha256}


def _notes(model, truth) -> list[str]:
    """What a reader of the scores must know: a truth that is no ground truth, a model scored
    against itself."""
    notes = []
    if model.sha256 == truth.sha256:
        notes.append(f"the model {model.path} and the truth {truth.path} are the same model (SHA-256 "
                     f"{model.sha256[:12]}): every error is 0 by construction and says nothing of the model")
    elif truth.kind not in (REFERENCE_KIND, MEASUREMENT_KIND):
        notes.append(f"the truth {truth.path} is a {truth.kind!r} model, not a ground truth (kind {REFERENCE_KIND!r}): "
                     "the scores measure how two models differ, not how far the model is from the material")
    return notes


def _write_outputs(result: dict, images, names: tuple[str, str], out_dir: Path) -> None:
    files = FILES[: 5 if images else 1]
    with atomic_paths(*(out_dir / name for name in files)) as temporaries:
        paths = dict(zip(files, temporaries))
        paths["evaluation.json"].write_text(json.dumps(result, indent=2, allow_nan=False) + "\n")
        if images is not None:
            model_image, truth_image, delta_e = images
            _write_png(model_image, paths["model.png"])
            _write_png(truth_image, paths["truth.png"])
            mean, p95 = result["image_delta_e2000_mean"], result["image_delta_e2000_p95"]
            summary = (f"ΔE2000 mean {mean:.2f}, p95 {p95:.2f} (noise: mean {result['noise']['image_delta_e2000_mean']:.2f}); "
                       f"hemisphere log-cos RMSE {result['hemisphere_logcos_rmse']:.4f}; {result['variant']}, "
                       f"{result['spp']} spp")
            _write_error_map(delta_e, summary, paths["error_map.png"])
            _write_comparison(model_image, truth_image, delta_e, names, summary, paths["comparison.png"])


def format_table(result: dict) -> str:
    """The metrics of ``result`` as a plain-text table (what the command prints)."""
    rows = [(name, result.get(name)) for name in (*DIRECTION_METRICS, *IMAGE_METRICS) if name in result]
    noise = result.get("noise") or {}
    lines = [f"{'metric':<28}{'value':>12}{'noise (truth vs truth)':>26}"]
    for name, value in rows:
        shown = "inf" if value is None else f"{value:.4g}"
        noise_value = noise.get(name)
        noise_shown = "" if name not in noise else ("inf" if noise_value is None else f"{noise_value:.4g}")
        lines.append(f"{name:<28}{shown:>12}{noise_shown:>26}")
    if result.get("rendered_output") not in (None, OUTPUT_F):
        lines.append(f"(rendered through the fast path {result['rendered_output']})")
    for output, scores in (result.get("fast_paths") or {}).items():
        against_f = scores.get("image_against_f")
        lines.append(f"fast path {output}: log-cos RMSE against f {scores['hemisphere_logcos_rmse']:.4g} (recorded "
                     f"{scores['recorded_hemisphere_logcos_rmse']:.4g}), relative cost {scores['relative_cost']:.2f}"
                     + (f", image ΔE2000 mean against f {against_f['image_delta_e2000_mean']:.3g}" if against_f else ""))
    return "\n".join(lines)
