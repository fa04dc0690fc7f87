"""Scoring and rendering a model: :func:`evaluate` against a truth, :func:`render_image` in a scene."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import TYPE_CHECKING

from neuralbrdf.api.arguments import (PathLike, as_path, check_flags, check_integers, check_numbers, check_positive,
                                      check_text)
from neuralbrdf.api.model_files import Model, model_path
from neuralbrdf.errors import InputError
from neuralbrdf.render import DEFAULT_VARIANT

if TYPE_CHECKING:
    import numpy as np


def evaluate(model: Model | PathLike, truth: Model | PathLike, out_dir: PathLike, *, scene: PathLike | None = None,
             material: str | None = None, variant: str | None = None, spp: int = 256,
             resolution: int | None = None, seed: int = 0, backend: str = "drjit", fast: bool = False,
             images: bool = True) -> dict:
    """Score ``model`` against ``truth`` (docs/evaluate.md): log-cosine and relative RMSE over the
    hemisphere, relative RMSE in the in-plane glossy and diffuse regions, and, with ``images``, the
    image errors (ΔE2000 mean and p95, PSNR) of both rendered with the same seeds in the material
    preview or in ``scene`` (any Mitsuba scene using the ``neuralbrdf`` BSDF; ``material`` names the
    one that carries model, then truth).  ``truth``: a reference model file, or an RGL measurement
    ``NAME.bsdf``, scored and rendered through Mitsuba's own ``measured`` plugin.  ``variant``:
    default ``llvm_ad_spectral``, or for a measurement the variant of its kind (``llvm_ad_rgb`` for
    an RGB file).  Writes ``out_dir/evaluation.json`` (and the images) and
    returns its content.  ``resolution``: default 128 in the preview, the scene's own film in a scene;
    ``fast``: render the model's fast path ``f_fast`` (``neuralbrdf export --fast``).  The model's
    fast paths are always scored against its ``f`` (``result["fast_paths"]``).

    >>> import tempfile, neuralbrdf as nb
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     gold = nb.truth("virtual:gold", f"{folder}/gold.onnx")
    ...     cyan = nb.truth("virtual:cyan", f"{folder}/cyan.onnx")
    ...     scores = nb.evaluate(cyan, gold, f"{folder}/eval", images=False)   # directions only
    >>> round(scores["hemisphere_logcos_rmse"], 2), round(scores["inplane_glossy_rel_rmse"], 2)  # a diffuse ink is no gold
    (0.16, 0.89)
    """
    from neuralbrdf.evaluation.evaluate import DEFAULT_RESOLUTION, RenderSettings, SceneTarget, measurement_variant
    from neuralbrdf.evaluation.evaluate import evaluate as run_evaluation

    check_integers(spp=spp, resolution=resolution, seed=seed)  # their values: checked by the evaluation
    check_text("variant", variant)
    check_text("material", material)
    check_text("backend", backend, optional=False)
    check_flags(fast=fast, images=images)
    variant = measurement_variant(model_path(truth, "truth"), variant)
    settings = RenderSettings(variant, spp, DEFAULT_RESOLUTION if resolution is None else resolution, seed, backend,
                              fast)  # checked by the evaluation before any work
    target = None if scene is None else SceneTarget(as_path(scene, "scene", "a Mitsuba scene file path"), material,
                                                    resolution)
    if target is None and material is not None:
        raise InputError("material names a material of a scene: give the scene too")
    result = run_evaluation(model_path(model, "model"), model_path(truth, "truth"),
                            as_path(out_dir, "out_dir", "a folder path"), settings, render_images=images, scene=target)
    for note in result["notes"]:  # a truth that is no ground truth, a model scored against itself
        warnings.warn(note, stacklevel=2)
    return result


class RenderFailed(RuntimeError):
    """A render that produced a non-finite image (nothing was written)."""


def render_image(model: Model | PathLike | None = None, out: PathLike | None = None, *, scene: PathLike | None = None,
           material: str | None = None, reference_bsdf: str | None = None, variant: str = DEFAULT_VARIANT,
           spp: int = 64, resolution: int | None = None, seed: int = 0, backend: str | None = None,
           rgb_tolerance: float | None = None, max_depth: int | None = None, spp_per_pass: int | None = None,
           exr: bool = False, fast: bool = False, progress: bool = False) -> np.ndarray:
    """Render ``model`` (a :class:`Model` or ``.onnx`` file; or Mitsuba's built-in
    ``reference_bsdf``) in the material-preview scene, or in ``scene`` (any Mitsuba scene file using
    the ``neuralbrdf`` BSDF; with ``model``, the ``neuralbrdf`` material ``material`` carries it,
    without, the scene renders as it is).  Returns the linear RGB image ``[H, W, 3]``; with ``out``
    (``.png``) also writes the 8-bit sRGB PNG and, with ``exr``, the linear EXR beside it (both or
    neither).  Defaults: 256² in the preview (a scene's own film), path depth 5 (a scene's own),
    the ``drjit`` backend; ``rgb_tolerance``: spectral models in RGB variants (see ``neuralbrdf
    render --help``); ``fast``: each model's fast path ``f_fast`` (``neuralbrdf export --fast``;
    refused for a model without one, in a scene such models render full with a warning).
    Raises :class:`RenderFailed` for a non-finite image.

    >>> import tempfile, neuralbrdf as nb
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     gold = nb.truth("virtual:gold", f"{folder}/gold.onnx")
    ...     image = nb.render_image(gold, f"{folder}/gold.png", spp=2, resolution=8)
    >>> image.shape, image.dtype
    ((8, 8, 3), dtype('float32'))
    """
    import numpy as np

    from neuralbrdf.atomic import check_outputs, command_inputs
    from neuralbrdf.render.mitsuba_bsdf import clamped_values, reset_clamped_values
    from neuralbrdf.render.preview import set_variant, write_images

    check_positive(spp=spp, resolution=resolution, max_depth=max_depth, spp_per_pass=spp_per_pass)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    check_text("variant", variant, optional=False)
    for name, value in (("material", material), ("reference_bsdf", reference_bsdf), ("backend", backend)):
        check_text(name, value)
    check_numbers(rgb_tolerance=rgb_tolerance)
    check_flags(exr=exr, fast=fast, progress=progress)
    written = []
    if out is not None:
        out = as_path(out, "out", "an output image (.png) path")
        if out.suffix.lower() != ".png":
            raise InputError("the output must be a .png file (with exr, a linear EXR is written beside it)", path=out)
        written = [out, out.with_suffix(".exr")] if exr else [out]
    with command_inputs():  # an output may not be one of the inputs (the model, the scene)
        if scene is not None:
            draw = _scene_renderer(as_path(scene, "scene", "a Mitsuba scene file path"),
                                   None if model is None else model_path(model, "model"), material, resolution,
                                   max_depth, backend, rgb_tolerance, spp, spp_per_pass, fast)
        else:
            draw = _preview_renderer(None if model is None else model_path(model, "model"), reference_bsdf, resolution,
                                     max_depth, backend, rgb_tolerance, variant, fast)
        check_outputs(*written)
        set_variant(variant)
        reset_clamped_values()
        image = draw(variant, spp, seed, spp_per_pass, progress)
        if not np.all(np.isfinite(image)):
            raise RenderFailed("the render is not finite; nothing written")
        if out is not None:
            write_images(image, out, written[1] if exr else None)
    clamped = clamped_values()
    if clamped:
        warnings.warn(f"{clamped} model evaluations were negative or not finite and were clamped to 0 (the model is "
                      "wrong somewhere its load-time probe did not look)", stacklevel=2)
    return image


def _preview_renderer(model: Path | None, reference_bsdf: str | None, resolution, max_depth, backend, rgb_tolerance,
                      variant: str, fast: bool):
    """The preview scene's render, its material checked now (before any output is touched)."""
    from neuralbrdf.render.preview import DEFAULT_MAX_DEPTH, Material, render as render_preview, within_drjit_budget
    from neuralbrdf.render.spectral_quadrature import DEFAULT_RMS_TOLERANCE

    if (model is None) == (reference_bsdf is None):
        raise InputError("render a model or a built-in reference BSDF (or a scene)")
    material = within_drjit_budget(Material(
        model=model, backend=backend or "drjit", reference_bsdf=reference_bsdf,
        rgb_tolerance=DEFAULT_RMS_TOLERANCE if rgb_tolerance is None else rgb_tolerance, fast=fast,
    ))
    if fast:
        if model is None:
            raise InputError("fast renders a model's fast path; give a model or a scene", key="fast")
        from neuralbrdf.kinds import load_model
        from neuralbrdf.render.fast_paths import chosen_output

        chosen_output(load_model(model), "_spectral" in variant, True, True)  # one line if it has none

    def draw(variant, spp, seed, spp_per_pass, progress):
        return render_preview(material, variant, spp, resolution or 256, seed, spp_per_pass,
                              max_depth or DEFAULT_MAX_DEPTH, progress=progress)

    return draw


def _scene_renderer(scene: Path, model: Path | None, material: str | None, resolution, max_depth, backend,
                    rgb_tolerance, spp, spp_per_pass, fast: bool):
    """A user's scene with the options given applied (the others left as the scene has them)."""
    from neuralbrdf.render.preview import check_render_size
    from neuralbrdf.render.scene_file import SceneFile, render_scene_file

    scene_file = SceneFile(scene)
    names = [m.name for m in scene_file.materials()]
    if model is not None:
        from neuralbrdf.evaluation.evaluate import SceneTarget

        scene_file.set_model(SceneTarget(scene, material).material_name(), model)
    elif material is not None:
        raise InputError("material names where a model goes: give the model too")
    elif not names:
        warnings.warn(f"{scene} has no neuralbrdf material; rendering it as it is", stacklevel=3)
    if resolution is not None:
        check_render_size(resolution, min(spp, spp_per_pass or spp), False)
        scene_file.set_resolution(resolution)
    if max_depth is not None:
        scene_file.set_max_depth(max_depth)
    if backend is not None:
        scene_file.set_all("backend", backend)
    if rgb_tolerance is not None:
        scene_file.set_all("rgb_tolerance", repr(float(rgb_tolerance)))
    if fast:
        _set_fast(scene_file)

    def draw(variant, spp, seed, spp_per_pass, progress):
        return render_scene_file(scene_file, spp, seed, spp_per_pass, progress=progress)[0]

    return draw


def _set_fast(scene_file) -> None:
    """``fast`` in a scene: property ``fast`` on every material whose model has a fast path."""
    from neuralbrdf.kinds import load_model
    from neuralbrdf.onnx_contract import OUTPUT_FAST
    from neuralbrdf.render.fast_paths import ADD_COMMAND, FAST_PROPERTY

    without = []
    for material in scene_file.materials():
        if OUTPUT_FAST in load_model(material.model).fast_paths:
            scene_file.set_property(material.element, FAST_PROPERTY, "true")
        else:
            without.append(material.name)
    if without:
        warnings.warn(f"fast: {', '.join(without)} {'has' if len(without) == 1 else 'have'} no fast path and "
                      f"{'renders' if len(without) == 1 else 'render'} full (add one: {ADD_COMMAND})", stacklevel=4)
