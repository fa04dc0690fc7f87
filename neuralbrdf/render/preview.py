"""Render a model file (SPEC §6) in the shipped material-preview scene with Mitsuba 3 (SPEC §7).

The scene is ``scenes/material_preview.xml`` beside this module (a sphere on a checkerboard
floor, constant sky plus two area lights, all procedural); the material comes from
``scenes/materials/`` — ``neuralbrdf.xml`` for a model file, or one of Mitsuba's built-in BSDFs
(:data:`REFERENCE_BSDFS`, the baselines of ``benchmarks/run.py``).

**Passes.** The sample budget is split into passes of at most :data:`PASS_LANES_SYMBOLIC`
paths (:data:`PASS_LANES_WAVEFRONT` for the onnxruntime backend), each an ``mi.render`` call
with its own seed (drawn from ``seed``); the image is their sample-weighted mean.  Memory
therefore depends on the pass size, not on ``spp`` (measured peak resident memory at 512 x
512: 0.34 GB with ``drjit``, 0.78 GB with ``onnxruntime`` for a spectral MLP in
``llvm_ad_rgb``, the worst case).

**Backends.** ``drjit`` renders in Dr.Jit's default symbolic mode (the network fused into the
kernel); ``onnxruntime`` needs wavefront mode (``SymbolicLoops``/``SymbolicCalls`` off), which
:func:`render` sets for it.

The command line is ``export/render.py``; ``neuralbrdf evaluate`` renders through here too.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
from tqdm import tqdm

from neuralbrdf.atomic import atomic_path
from neuralbrdf.errors import InputError
from neuralbrdf.render.spectral_quadrature import DEFAULT_RMS_TOLERANCE

SCENE_DIR = Path(__file__).resolve().parent / "scenes"
SCENE_FILE = SCENE_DIR / "material_preview.xml"
NEURAL_MATERIAL = "materials/neuralbrdf.xml"
#: Built-in Mitsuba materials selectable with ``--reference-bsdf``: name -> scene file.
REFERENCE_BSDFS = {"roughconductor": "materials/roughconductor.xml", "diffuse": "materials/diffuse.xml"}
BACKENDS = ("drjit", "onnxruntime")
DEFAULT_VARIANT = "llvm_ad_rgb"
#: Paths traced per pass by default in symbolic mode (one fused kernel: little memory per path) ...
PASS_LANES_SYMBOLIC = 2**22
#: ... and in wavefront mode, where every intermediate array of a bounce is stored, and the
#: onnxruntime backend batches up to 31 wavelengths per path (spectral model, RGB variant):
#: 512 x 512 x 256 spp then peaks at about 2 GB.
PASS_LANES_WAVEFRONT = 2**19
DEFAULT_MAX_DEPTH = 5


@contextlib.contextmanager
def dr_mode(wavefront: bool) -> Iterator[None]:
    """Dr.Jit wavefront mode (symbolic loops and calls off) or symbolic mode, restored afterwards."""
    saved = dr.flag(dr.JitFlag.SymbolicLoops), dr.flag(dr.JitFlag.SymbolicCalls)
    dr.set_flag(dr.JitFlag.SymbolicLoops, not wavefront)
    dr.set_flag(dr.JitFlag.SymbolicCalls, not wavefront)
    try:
        yield
    finally:
        dr.set_flag(dr.JitFlag.SymbolicLoops, saved[0])
        dr.set_flag(dr.JitFlag.SymbolicCalls, saved[1])


def set_variant(variant: str) -> None:
    """Select a Mitsuba variant and register the ``neuralbrdf`` BSDF in it."""
    from neuralbrdf.render import register

    if variant not in mi.variants():
        raise InputError(f"unknown Mitsuba variant {variant!r}; this build has {', '.join(mi.variants())}")
    mi.set_variant(variant)
    try:
        register()
    except RuntimeError as error:
        raise InputError(str(error)) from None


@dataclass(frozen=True)
class Material:
    """What the sphere carries: a model file through a backend, or a built-in reference BSDF."""

    model: Path | None = None
    backend: str = "drjit"
    reference_bsdf: str | None = None
    rgb_tolerance: float = DEFAULT_RMS_TOLERANCE

    def __post_init__(self) -> None:
        if (self.model is None) == (self.reference_bsdf is None):
            raise InputError("give either a model file or a reference BSDF")
        if self.backend not in BACKENDS:
            raise InputError(f"unknown backend {self.backend!r}; expected one of {', '.join(BACKENDS)}")
        if self.reference_bsdf is not None and self.reference_bsdf not in REFERENCE_BSDFS:
            raise InputError(
                f"unknown reference BSDF {self.reference_bsdf!r}; expected one of {', '.join(REFERENCE_BSDFS)}"
            )

    @property
    def needs_wavefront(self) -> bool:
        return self.model is not None and self.backend == "onnxruntime"

    def scene_parameters(self) -> dict[str, str]:
        if self.reference_bsdf is not None:
            return {"material": REFERENCE_BSDFS[self.reference_bsdf]}
        return {
            "material": NEURAL_MATERIAL,
            "model": str(Path(self.model).resolve()),
            "backend": self.backend,
            "rgb_tolerance": repr(float(self.rgb_tolerance)),
        }

    def describe(self) -> str:
        if self.reference_bsdf is not None:
            return f"built-in {self.reference_bsdf}"
        return f"{Path(self.model).name} ({self.backend})"


def load_scene(material: Material, resolution: int, max_depth: int = DEFAULT_MAX_DEPTH) -> mi.Scene:
    """The material-preview scene with ``material``, for the current variant."""
    if material.model is not None:
        from neuralbrdf.render import load_model

        load_model(material.model)  # one clear InputError before Mitsuba wraps it
    try:
        return mi.load_file(
            str(SCENE_FILE), resolution=str(resolution), max_depth=str(max_depth), **material.scene_parameters()
        )
    except InputError:
        raise
    except RuntimeError as error:
        raise InputError(f"cannot load the scene: {str(error).splitlines()[-1]}", path=SCENE_FILE) from None


def pass_sizes(spp: int, spp_per_pass: int) -> list[int]:
    """Samples per pixel of each pass: full passes of ``spp_per_pass`` and the remainder."""
    full, rest = divmod(spp, spp_per_pass)
    return [spp_per_pass] * full + ([rest] if rest else [])


def default_spp_per_pass(resolution: int, wavefront: bool) -> int:
    """Samples per pixel per pass that keep a pass within the default path budget."""
    lanes = PASS_LANES_WAVEFRONT if wavefront else PASS_LANES_SYMBOLIC
    return max(1, lanes // (resolution * resolution))


def render_passes(
    scene: mi.Scene, spp: int, spp_per_pass: int, seed: int = 0, wavefront: bool = False, progress: bool = False
) -> np.ndarray:
    """Linear RGB image ``[H, W, 3]`` (float32): the sample-weighted mean of the passes.

    Each pass is one ``mi.render`` with its own seed from ``numpy.random.SeedSequence(seed)``.
    """
    sizes = pass_sizes(spp, spp_per_pass)
    seeds = np.random.SeedSequence(seed).generate_state(len(sizes))
    total = None
    with dr_mode(wavefront), tqdm(
        total=spp, unit="spp", desc="render", disable=not progress, file=sys.stderr, leave=False
    ) as bar:
        for size, pass_seed in zip(sizes, seeds):
            image = mi.render(scene, spp=int(size), seed=int(pass_seed))
            weighted = np.asarray(image, dtype=np.float64) * (size / spp)
            total = weighted if total is None else total + weighted
            bar.update(size)
    return total.astype(np.float32)


def render(
    material: Material,
    variant: str = DEFAULT_VARIANT,
    spp: int = 64,
    resolution: int = 256,
    seed: int = 0,
    spp_per_pass: int | None = None,
    max_depth: int = DEFAULT_MAX_DEPTH,
    progress: bool = False,
) -> np.ndarray:
    """Render ``material`` in the preview scene; linear RGB ``[H, W, 3]``."""
    for name, value in (("spp", spp), ("resolution", resolution), ("max_depth", max_depth)):
        if value < 1:
            raise InputError(f"{name} must be a positive integer, got {value}")
    set_variant(variant)
    scene = load_scene(material, resolution, max_depth)
    per_pass = spp_per_pass or default_spp_per_pass(resolution, material.needs_wavefront)
    if per_pass < 1:
        raise InputError(f"spp_per_pass must be a positive integer, got {per_pass}")
    return render_passes(scene, spp, per_pass, seed, material.needs_wavefront, progress)


def write_png(image: np.ndarray, path: str | Path) -> None:
    """8-bit sRGB PNG of a linear RGB image (values clipped to [0, 1]), written atomically."""
    bitmap = mi.Bitmap(np.ascontiguousarray(image, dtype=np.float32), mi.Bitmap.PixelFormat.RGB)
    srgb = bitmap.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)
    with atomic_path(path) as tmp:
        srgb.write(str(tmp))


def write_exr(image: np.ndarray, path: str | Path) -> None:
    """Linear float32 RGB OpenEXR, written atomically."""
    bitmap = mi.Bitmap(np.ascontiguousarray(image, dtype=np.float32), mi.Bitmap.PixelFormat.RGB)
    with atomic_path(path) as tmp:
        bitmap.write(str(tmp))
