"""``neuralbrdf render`` (and ``export/render.py``): an exported model (docs/formats.md#onnx-model-files) in the shipped
material-preview scene, or any Mitsuba 3 scene that uses the ``neuralbrdf`` BSDF (docs/mitsuba-plugin.md).

    neuralbrdf render --model MODEL.onnx --out IMAGE.png [--exr] [--variant llvm_ad_spectral]
        [--backend drjit|onnxruntime] [--spp 64] [--resolution 256] [--seed 0] [--rgb-tolerance 1e-3] [--fast]
    neuralbrdf render --reference-bsdf roughconductor --out REF.png ...
    neuralbrdf render --scene SCENE.xml --out IMAGE.png [same options]

**Your own scene** (``--scene``): any Mitsuba 3 scene file; its ``neuralbrdf`` BSDFs name their
model files (relative to the scene file or absolute), see ``export/README.md``.  Options given
on the command line override the scene: ``--resolution`` sets every film's size,
``--max-depth`` the integrator's path length, ``--backend`` and ``--rgb-tolerance`` every
``neuralbrdf`` material's property; options not given leave the scene as it is
(:mod:`neuralbrdf.render.scene_file`).

The work is :func:`neuralbrdf.api.render_image` (the same render from Python); the scene, passes,
memory and backends are those of :mod:`neuralbrdf.render.preview` (the scene ships inside the
package: ``neuralbrdf/render/scenes/material_preview.xml``).

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

Exit status (docs/robustness.md) 2 with one line for bad input (missing or invalid model,
unsupported or unavailable variant — a ``cuda_*`` variant without a CUDA device —, invalid
numbers, refused outputs), 1 for a render that is not finite, 3 for outputs the machine could not
write (no space left on device, no permission).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from neuralbrdf.console import clean_warnings
from neuralbrdf.errors import EXIT_FAILED, EXIT_OK, EnvironmentFailure, InputError, error_line, exit_status
from neuralbrdf.render import DEFAULT_VARIANT
from neuralbrdf.render.preview import (
    BACKENDS,
    DEFAULT_MAX_DEPTH,
    MEMORY_FRACTION,
    PASS_LANES_SYMBOLIC,
    PASS_LANES_WAVEFRONT,
    REFERENCE_BSDFS,
)
from neuralbrdf.render.spectral_quadrature import DEFAULT_RMS_TOLERANCE


def build_parser(prog: str = "neuralbrdf render") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog, allow_abbrev=False,
        description="Render an exported .onnx BRDF model (or a built-in reference BSDF) in the material-preview "
        "scene shipped in neuralbrdf/render/scenes/material_preview.xml.",
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--model", help="exported model file (.onnx, docs/formats.md#onnx-model-files)")
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


def main(argv: list[str] | None = None, prog: str = "neuralbrdf render") -> int:
    args = build_parser(prog).parse_args(argv)
    with clean_warnings():  # e.g. clamped model values: one line
        return _render(args, prog)


def _render(args: argparse.Namespace, prog: str) -> int:
    from neuralbrdf.api import RenderFailed, render_image
    from neuralbrdf.cli.commands import options

    out = Path(args.out)
    described = (f"scene {args.scene}" if args.scene is not None else
                 f"built-in {args.reference_bsdf}" if args.reference_bsdf is not None else Path(args.model).name)
    started = time.perf_counter()
    try:
        with options(fast="--fast"):
            render_image(args.model, out, scene=args.scene, reference_bsdf=args.reference_bsdf, variant=args.variant,
                         spp=args.spp, resolution=args.resolution, seed=args.seed, backend=args.backend,
                         rgb_tolerance=args.rgb_tolerance, max_depth=args.max_depth, spp_per_pass=args.spp_per_pass,
                         exr=args.exr, fast=args.fast, progress=not args.quiet)
    except (InputError, EnvironmentFailure) as error:
        print(error_line(prog, error), file=sys.stderr)
        return exit_status(error)
    except RenderFailed:
        print(error_line(prog, f"the render of {described} is not finite; nothing written"), file=sys.stderr)
        return EXIT_FAILED
    written = [out, out.with_suffix(".exr")] if args.exr else [out]
    print(f"rendered {described} in {args.variant} at {args.spp} spp in {time.perf_counter() - started:.1f} s; wrote "
          f"{', '.join(map(str, written))}")
    return EXIT_OK
