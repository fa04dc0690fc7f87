"""Render an exported model (SPEC §6) in the shipped material-preview scene with Mitsuba 3 (SPEC §7).

    python export/render.py --model MODEL.onnx --out IMAGE.png [--exr] [--variant llvm_ad_rgb]
        [--backend drjit|onnxruntime] [--spp 64] [--resolution 256] [--seed 0] [--rgb-tolerance 1e-3]
    python export/render.py --reference-bsdf roughconductor --out REF.png ...

The scene, passes, memory and backends are those of :mod:`neuralbrdf.render.preview` (the
scene ships inside the package: ``neuralbrdf/render/scenes/material_preview.xml``).

**Spectral models in RGB variants** are integrated to sRGB through the plugin's reduced rule
(``--rgb-tolerance``, its held-out rms relative error, default 1e-3; ``0`` for all 31
wavelengths), see :mod:`neuralbrdf.render.mitsuba_bsdf`.

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
from neuralbrdf.render.preview import (
    BACKENDS,
    DEFAULT_MAX_DEPTH,
    DEFAULT_VARIANT,
    MEMORY_FRACTION,
    PASS_LANES_SYMBOLIC,
    PASS_LANES_WAVEFRONT,
    REFERENCE_BSDFS,
    Material,
    default_spp_per_pass,
    load_scene,
    mi,
    pass_sizes,
    render,
    render_passes,
    set_variant,
    within_drjit_budget,
    write_images,
)
from neuralbrdf.render.spectral_quadrature import DEFAULT_RMS_TOLERANCE

__all__ = [
    "Material", "default_spp_per_pass", "load_scene", "pass_sizes", "render", "render_passes", "set_variant",
    "write_images", "within_drjit_budget", "PASS_LANES_WAVEFRONT", "mi",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="export/render.py",
        description="Render an exported .onnx BRDF model (or a built-in reference BSDF) in the material-preview "
        "scene shipped in neuralbrdf/render/scenes/material_preview.xml.",
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--model", help="exported model file (.onnx, SPEC §6)")
    source.add_argument("--reference-bsdf", choices=sorted(REFERENCE_BSDFS), help="render a built-in BSDF instead")
    parser.add_argument(
        "--out", required=True,
        help="output PNG (8-bit sRGB); never the model file, a directory or a device; a symbolic link is "
        "written through (the file it points to is replaced)",
    )
    parser.add_argument(
        "--exr", action="store_true", help="also write the linear image as OUT with suffix .exr (both or neither)"
    )
    parser.add_argument("--variant", default=DEFAULT_VARIANT, help=f"Mitsuba variant (default {DEFAULT_VARIANT})")
    parser.add_argument("--backend", choices=BACKENDS, default="drjit", help="model evaluation (default drjit)")
    parser.add_argument(
        "--rgb-tolerance",
        type=float,
        default=DEFAULT_RMS_TOLERANCE,
        help="spectral models in RGB variants: held-out rms relative error of the fitted few-wavelength "
        f"sRGB rule (default {DEFAULT_RMS_TOLERANCE:g}; 0: integrate all 31 wavelengths)",
    )
    parser.add_argument("--spp", type=int, default=64, help="samples per pixel (default 64)")
    parser.add_argument(
        "--resolution", type=int, default=256,
        help=f"image width = height in pixels (default 256; refused before rendering if the image and one pass "
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
    parser.add_argument("--max-depth", type=int, default=DEFAULT_MAX_DEPTH, help="path length limit (default 5)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    out = Path(args.out)
    written = [out, out.with_suffix(".exr")] if args.exr else [out]
    try:
        with command_inputs():
            if out.suffix.lower() != ".png":
                raise InputError("the output must be a .png file (add --exr for a linear EXR beside it)", path=out)
            material = Material(
                model=None if args.model is None else Path(args.model),
                backend=args.backend,
                reference_bsdf=args.reference_bsdf,
                rgb_tolerance=args.rgb_tolerance,
            )
            material = within_drjit_budget(material)  # reads the model: an input from here on
            check_outputs(*written)
            start = time.perf_counter()
            from neuralbrdf.render.mitsuba_bsdf import clamped_values, reset_clamped_values

            set_variant(args.variant)
            reset_clamped_values()
            image = render(
                material, args.variant, args.spp, args.resolution, args.seed, args.spp_per_pass, args.max_depth,
                progress=not args.quiet,
            )
            elapsed = time.perf_counter() - start
            clamped = clamped_values()
            if not np.all(np.isfinite(image)):
                print(f"error: the render of {material.describe()} is not finite; nothing written", file=sys.stderr)
                return 1
            write_images(image, out, written[1] if args.exr else None)
    except InputError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if clamped:
        print(
            f"warning: {clamped} evaluations of {material.describe()} were negative or not finite and were "
            "clamped to 0 (the model is wrong somewhere its load-time probe did not look)",
            file=sys.stderr,
        )
    print(
        f"rendered {material.describe()} in {args.variant}, {args.resolution}x{args.resolution} at {args.spp} spp "
        f"in {elapsed:.1f} s; wrote {', '.join(map(str, written))}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
