"""``neuralbrdf render`` (and ``export/render.py``): an exported model (SPEC §6) in the shipped
material-preview scene, or any Mitsuba 3 scene that uses the ``neuralbrdf`` BSDF (SPEC §7).

    neuralbrdf render --model MODEL.onnx --out IMAGE.png [--exr] [--variant llvm_ad_rgb]
        [--backend drjit|onnxruntime] [--spp 64] [--resolution 256] [--seed 0] [--rgb-tolerance 1e-3] [--fast]
    neuralbrdf render --reference-bsdf roughconductor --out REF.png ...
    neuralbrdf render --scene SCENE.xml --out IMAGE.png [same options]

**Your own scene** (``--scene``): any Mitsuba 3 scene file; its ``neuralbrdf`` BSDFs name their
model files (relative to the scene file or absolute), see ``export/README.md``.  Options given
on the command line override the scene: ``--resolution`` sets every film's size,
``--max-depth`` the integrator's path length, ``--backend`` and ``--rgb-tolerance`` every
``neuralbrdf`` material's property; options not given leave the scene as it is
(:mod:`neuralbrdf.render.scene_file`).

The scene, passes, memory and backends are those of :mod:`neuralbrdf.render.preview` (the
scene ships inside the package: ``neuralbrdf/render/scenes/material_preview.xml``).

**Spectral models in RGB variants** are integrated to sRGB through the plugin's reduced rule
(``--rgb-tolerance``, its held-out rms relative error, default 1e-3; ``0`` for all 31
wavelengths), see :mod:`neuralbrdf.render.mitsuba_bsdf`.

**Fast paths** (:mod:`neuralbrdf.render.fast_paths`): a spectral model whose file has an RGB
head renders through it in RGB variants; ``--fast`` renders each model's compact copy
``f_fast`` (``neuralbrdf export --fast``) — a model without one is refused, or, in a scene,
stays full with a note.

**Backends.** ``drjit`` renders in Dr.Jit's default symbolic mode (the network fused into the
kernel); ``onnxruntime`` needs wavefront mode (``SymbolicLoops``/``SymbolicCalls`` off), which
this command sets for it.

**Outputs** are written atomically and synchronously: ``IMAGE.png`` (8-bit sRGB, clipped to
[0, 1]) and with ``--exr`` ``IMAGE.exr`` beside it (linear float32 RGB), both or neither
(:func:`neuralbrdf.atomic.atomic_paths`).  They are checked before rendering: an output that
is the model file, a directory, a device or in an unwritable folder is refused at once; a
symbolic link is written through.

**Limits.** ``--resolution`` is checked before rendering against the memory the image and one
pass would need (:func:`neuralbrdf.render.preview.check_render_size`) and refused above :data:`MEMORY_FRACTION` of
this machine's memory.  A model too large for the ``drjit`` backend
(:data:`~neuralbrdf.limits.DRJIT_MAX_MULTIPLY_ADDS`) is rendered with ``onnxruntime`` instead,
with a message.  Model values that are negative or not finite are clamped to 0 in the render
and counted; a non-zero count is reported on stderr (the model file's load-time probe refuses
models it finds negative, this catches the rest).

Exit status 2 with one line for bad input (missing or invalid model, unsupported or
unavailable variant — a ``cuda_*`` variant without a CUDA device —, invalid numbers, refused
outputs).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from neuralbrdf.atomic import check_outputs, command_inputs
from neuralbrdf.errors import InputError
from neuralbrdf.onnx_contract import OUTPUT_FAST
from neuralbrdf.render.preview import (
    BACKENDS,
    DEFAULT_MAX_DEPTH,
    DEFAULT_VARIANT,
    MEMORY_FRACTION,
    PASS_LANES_SYMBOLIC,
    PASS_LANES_WAVEFRONT,
    REFERENCE_BSDFS,
    Material,
    check_render_size,
    render,
    set_variant,
    within_drjit_budget,
    write_images,
)
from neuralbrdf.render.scene_file import SceneFile, render_scene_file
from neuralbrdf.render.spectral_quadrature import DEFAULT_RMS_TOLERANCE


def build_parser(prog: str = "neuralbrdf render") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Render an exported .onnx BRDF model (or a built-in reference BSDF) in the material-preview "
        "scene shipped in neuralbrdf/render/scenes/material_preview.xml.",
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--model", help="exported model file (.onnx, SPEC §6)")
    source.add_argument("--reference-bsdf", choices=sorted(REFERENCE_BSDFS), help="render a built-in BSDF instead")
    source.add_argument(
        "--scene", help="render this Mitsuba scene file instead of the preview scene (its neuralbrdf BSDFs name their "
        "models); options given override the scene's film size, max_depth and the materials' backend/rgb_tolerance",
    )
    parser.add_argument(
        "--out", required=True,
        help="output PNG (8-bit sRGB); never the model file, a directory or a device; a symbolic link is "
        "written through (the file it points to is replaced)",
    )
    parser.add_argument(
        "--exr", action="store_true", help="also write the linear image as OUT with suffix .exr (both or neither)"
    )
    parser.add_argument("--variant", default=DEFAULT_VARIANT, help=f"Mitsuba variant (default {DEFAULT_VARIANT})")
    parser.add_argument("--backend", choices=BACKENDS, default=None, help="model evaluation (default drjit)")
    parser.add_argument(
        "--rgb-tolerance",
        type=float,
        default=None,
        help="spectral models in RGB variants: held-out rms relative error of the fitted few-wavelength "
        f"sRGB rule (default {DEFAULT_RMS_TOLERANCE:g}; 0: integrate all 31 wavelengths)",
    )
    parser.add_argument(
        "--fast", action="store_true",
        help="render each model's fast path f_fast (neuralbrdf export --fast) instead of the full network; with "
        "--scene, the materials whose models have none stay full (named on stderr)",
    )
    parser.add_argument("--spp", type=int, default=64, help="samples per pixel (default 64)")
    parser.add_argument(
        "--resolution", type=int, default=None,
        help=f"image width = height in pixels (default 256, or the scene's own; refused before rendering if the image and one pass "
        f"would need more than {MEMORY_FRACTION * 100:.0f}%% of this machine's memory)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the pass seeds (default 0)")
    parser.add_argument(
        "--spp-per-pass",
        type=int,
        default=None,
        help=f"samples per pixel per pass (default: {PASS_LANES_SYMBOLIC} paths per pass, "
        f"{PASS_LANES_WAVEFRONT} for the onnxruntime backend)",
    )
    parser.add_argument("--max-depth", type=int, default=None,
                        help=f"path length limit (default {DEFAULT_MAX_DEPTH}, or the scene's own)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def render_scene(args, written: list[Path]) -> tuple[np.ndarray, float, str]:
    """``--scene``: the user's scene with the options given applied; ``(image, seconds, description)``."""
    for name in ("spp", "resolution", "max_depth", "spp_per_pass"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise InputError(f"--{name.replace('_', '-')} must be a positive integer, got {value}")
    scene_file = SceneFile(args.scene)
    if not scene_file.materials():
        print(f"note: {args.scene} has no neuralbrdf material; rendering it as it is", file=sys.stderr)
    if args.resolution is not None:
        check_render_size(args.resolution, min(args.spp, args.spp_per_pass or args.spp), False)
        scene_file.set_resolution(args.resolution)
    if args.max_depth is not None:
        scene_file.set_max_depth(args.max_depth)
    if args.backend is not None:
        scene_file.set_all("backend", args.backend)
    if args.rgb_tolerance is not None:
        scene_file.set_all("rgb_tolerance", repr(float(args.rgb_tolerance)))
    if args.fast:
        _set_fast(scene_file)
    check_outputs(*written)
    _start(args.variant)
    image, seconds = render_scene_file(scene_file, args.spp, args.seed, args.spp_per_pass, progress=not args.quiet)
    return image, seconds, f"scene {args.scene}"


def _set_fast(scene_file: SceneFile) -> None:
    """``--fast`` on a scene: property ``fast`` on every material whose model has a fast path."""
    from neuralbrdf.kinds import load_model
    from neuralbrdf.render.fast_paths import ADD_COMMAND, FAST_PROPERTY

    without = []
    for material in scene_file.materials():
        if OUTPUT_FAST in load_model(material.model).fast_paths:
            scene_file.set_property(material.element, FAST_PROPERTY, "true")
        else:
            without.append(material.name)
    if without:
        print(f"note: --fast: {', '.join(without)} {'has' if len(without) == 1 else 'have'} no fast path and "
              f"{'renders' if len(without) == 1 else 'render'} full (add one: {ADD_COMMAND})", file=sys.stderr)


def render_preview(args, written: list[Path]) -> tuple[np.ndarray, float, str]:
    """The material-preview scene with ``--model`` or ``--reference-bsdf``; ``(image, seconds, description)``."""
    args.resolution = 256 if args.resolution is None else args.resolution
    args.max_depth = DEFAULT_MAX_DEPTH if args.max_depth is None else args.max_depth
    material = Material(
        model=None if args.model is None else Path(args.model),
        backend=args.backend or "drjit",
        reference_bsdf=args.reference_bsdf,
        rgb_tolerance=DEFAULT_RMS_TOLERANCE if args.rgb_tolerance is None else args.rgb_tolerance,
        fast=args.fast,
    )
    material = within_drjit_budget(material)  # reads the model: an input from here on
    if args.fast:
        if args.model is None:
            raise InputError("--fast renders a model's fast path; give --model or --scene", column="--fast")
        from neuralbrdf.kinds import load_model
        from neuralbrdf.render.fast_paths import chosen_output

        chosen_output(load_model(args.model), "_spectral" in args.variant, True, True)  # one line if it has none
    check_outputs(*written)
    _start(args.variant)
    start = time.perf_counter()
    image = render(
        material, args.variant, args.spp, args.resolution, args.seed, args.spp_per_pass, args.max_depth,
        progress=not args.quiet,
    )
    return image, time.perf_counter() - start, f"{material.describe()}, {args.resolution}x{args.resolution}"


def _start(variant: str) -> None:
    """Select the variant (registering the plugin) and zero its clamped-evaluation count."""
    from neuralbrdf.render.mitsuba_bsdf import reset_clamped_values

    set_variant(variant)
    reset_clamped_values()


def main(argv: list[str] | None = None, prog: str = "neuralbrdf render") -> int:
    args = build_parser(prog).parse_args(argv)
    out = Path(args.out)
    written = [out, out.with_suffix(".exr")] if args.exr else [out]
    try:
        with command_inputs():
            if out.suffix.lower() != ".png":
                raise InputError("the output must be a .png file (add --exr for a linear EXR beside it)", path=out)
            draw = render_scene if args.scene is not None else render_preview
            image, elapsed, described = draw(args, written)
            from neuralbrdf.render.mitsuba_bsdf import clamped_values

            clamped = clamped_values()
            if not np.all(np.isfinite(image)):
                print(f"error: the render of {described} is not finite; nothing written", file=sys.stderr)
                return 1
            write_images(image, out, written[1] if args.exr else None)
    except InputError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if clamped:
        print(
            f"warning: {clamped} evaluations of {described} were negative or not finite and were "
            "clamped to 0 (the model is wrong somewhere its load-time probe did not look)",
            file=sys.stderr,
        )
    print(f"rendered {described} in {args.variant} at {args.spp} spp in {elapsed:.1f} s; wrote "
          f"{', '.join(map(str, written))}")
    return 0
