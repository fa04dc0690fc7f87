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
[0, 1]) and with ``--exr`` ``IMAGE.exr`` beside it (linear float32 RGB).

Exit status 2 with one line for bad input (missing or invalid model, unsupported variant,
invalid numbers).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from neuralbrdf.errors import InputError
from neuralbrdf.render.preview import (
    BACKENDS,
    DEFAULT_MAX_DEPTH,
    DEFAULT_VARIANT,
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
    write_exr,
    write_png,
)
from neuralbrdf.render.spectral_quadrature import DEFAULT_RMS_TOLERANCE

__all__ = [
    "Material", "default_spp_per_pass", "load_scene", "pass_sizes", "render", "render_passes", "set_variant",
    "write_exr", "write_png", "PASS_LANES_WAVEFRONT", "mi",
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
    parser.add_argument("--out", required=True, help="output PNG (8-bit sRGB)")
    parser.add_argument("--exr", action="store_true", help="also write the linear image as OUT with suffix .exr")
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
    parser.add_argument("--resolution", type=int, default=256, help="image width = height in pixels (default 256)")
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
    try:
        if out.suffix.lower() != ".png":
            raise InputError("the output must be a .png file (add --exr for a linear EXR beside it)", path=out)
        material = Material(
            model=None if args.model is None else Path(args.model),
            backend=args.backend,
            reference_bsdf=args.reference_bsdf,
            rgb_tolerance=args.rgb_tolerance,
        )
        start = time.perf_counter()
        image = render(
            material, args.variant, args.spp, args.resolution, args.seed, args.spp_per_pass, args.max_depth,
            progress=not args.quiet,
        )
        elapsed = time.perf_counter() - start
    except InputError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if not np.all(np.isfinite(image)):
        print(f"error: the render of {material.describe()} is not finite; nothing written", file=sys.stderr)
        return 1
    write_png(image, out)
    written = [str(out)]
    if args.exr:
        write_exr(image, out.with_suffix(".exr"))
        written.append(str(out.with_suffix(".exr")))
    print(
        f"rendered {material.describe()} in {args.variant}, {args.resolution}x{args.resolution} at {args.spp} spp "
        f"in {elapsed:.1f} s; wrote {', '.join(written)}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
