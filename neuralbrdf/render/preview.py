"""Render a model file (docs/formats.md#onnx-model-files) in the shipped material-preview scene with Mitsuba 3 (docs/mitsuba-plugin.md).

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
:func:`render` sets for it.  :func:`within_drjit_budget` switches a model too large for the
``drjit`` backend (:data:`~neuralbrdf.limits.DRJIT_MAX_MULTIPLY_ADDS`) to ``onnxruntime``.

**Limits.** :func:`render` checks the resolution against the memory the image and one pass
would need (:func:`check_render_size`, refused above :data:`MEMORY_FRACTION` of this machine's
memory) before it loads anything; :func:`set_variant` turns a variant that cannot start (a
``cuda_*`` one without a CUDA device) into one :class:`~neuralbrdf.errors.InputError`.
:func:`write_images` writes the PNG and the EXR together or neither.

The command line is ``export/render.py``; ``neuralbrdf evaluate`` renders through here too.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from neuralbrdf.atomic import atomic_paths, full_disk
from neuralbrdf.console import progress as progress_bar
from neuralbrdf.errors import InputError, one_line
from neuralbrdf.limits import DRJIT_MAX_MULTIPLY_ADDS
from neuralbrdf.render import DEFAULT_VARIANT
from neuralbrdf.render.spectral_quadrature import DEFAULT_RMS_TOLERANCE

SCENE_DIR = Path(__file__).resolve().parent / "scenes"
SCENE_FILE = SCENE_DIR / "material_preview.xml"
NEURAL_MATERIAL = "materials/neuralbrdf.xml"
#: The same, sampled with another model file's proposal (:attr:`Material.proposal`).
NEURAL_MATERIAL_MATCHED = "materials/neuralbrdf_matched.xml"
#: An RGL measurement through Mitsuba's ``measured`` plugin (:mod:`~neuralbrdf.render.measured_bsdf`),
#: sampled with a model file's proposal.
MEASURED_MATERIAL_MATCHED = "materials/measured_matched.xml"
#: Built-in Mitsuba materials selectable with ``--reference-bsdf``: name -> scene file.
REFERENCE_BSDFS = {"roughconductor": "materials/roughconductor.xml", "diffuse": "materials/diffuse.xml"}
BACKENDS = ("drjit", "onnxruntime")
#: Paths traced per pass by default in symbolic mode (one fused kernel: little memory per path) ...
PASS_LANES_SYMBOLIC = 2**22
#: ... and in wavefront mode, where every intermediate array of a bounce is stored, and the
#: onnxruntime backend batches up to 31 wavelengths per path (spectral model, RGB variant):
#: 512 x 512 x 256 spp then peaks at about 2 GB.
PASS_LANES_WAVEFRONT = 2**19
DEFAULT_MAX_DEPTH = 5
#: Bytes per pixel of the image buffers: Mitsuba's film (5 float32), the float64 pass sum and
#: weighted pass (2 × 3 float64), the float32 result and the bitmaps written (3 float32 + 3 bytes).
IMAGE_BYTES_PER_PIXEL = 5 * 4 + 2 * 3 * 8 + 3 * 4 + 3 * 4 + 3
#: Bytes per path of a pass, measured (module docstring): symbolic mode ...
PATH_BYTES_SYMBOLIC = 96
#: ... and wavefront mode (onnxruntime backend).
PATH_BYTES_WAVEFRONT = 4096
#: Largest share of this machine's physical memory a render may plan to use.
MEMORY_FRACTION = 0.75


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


#: Oldest LLVM whose shared library Mitsuba's ``llvm_*`` variants can render with: older ones
#: fail while compiling render kernels ("LLVM ERROR: Cannot select ... fmaximum", abort).
MIN_LLVM_VERSION = (19, 0, 0)


def check_llvm(variant: str) -> None:
    """One clear :class:`InputError` before rendering when an ``llvm_*`` variant would run on an
    LLVM older than :data:`MIN_LLVM_VERSION` (instead of an abort deep in kernel compilation)."""
    if not variant.startswith("llvm_"):
        return
    try:
        version = tuple(dr.detail.llvm_version())
    except Exception:  # no LLVM at all: mi.set_variant says so itself
        return
    if version < MIN_LLVM_VERSION:
        raise InputError(
            f"Mitsuba's {variant} needs LLVM >= 19 as a shared library, but Dr.Jit loaded LLVM "
            f"{'.'.join(map(str, version))}, which aborts while compiling render kernels: install LLVM 19 "
            "(Debian: apt-get install libllvm19) or set DRJIT_LIBLLVM_PATH to its libLLVM.so.19"
        )


def set_variant(variant: str) -> None:
    """Select a Mitsuba variant and register the ``neuralbrdf`` BSDF in it."""
    from neuralbrdf.render import register

    if variant not in mi.variants():
        raise InputError(f"unknown Mitsuba variant {variant!r}; this build has {', '.join(mi.variants())}")
    check_llvm(variant)
    try:
        mi.set_variant(variant)
        register()
        mi.Float(0.0).numpy()  # the variant's JIT backend must start here (a cuda_* one needs a GPU)
    except Exception as error:  # ImportError for a CUDA variant on a CPU machine, RuntimeError ...
        cpu = " (no CUDA device here? use an llvm_* variant)" if variant.startswith("cuda_") else ""
        raise InputError(f"cannot render in Mitsuba variant {variant!r}{cpu}: {one_line(error)}") from None


@dataclass(frozen=True)
class Material:
    """What the sphere carries: a model file through a backend, a built-in reference BSDF, or an RGL
    ``measurement`` (``.bsdf``) through Mitsuba's ``measured`` plugin; ``proposal``: another model
    file whose sampling proposal the model (or measurement: required) uses (the plugins' ``proposal``
    property: same expectation, paths matched to that file's renders)."""

    model: Path | None = None
    backend: str = "drjit"
    reference_bsdf: str | None = None
    rgb_tolerance: float = DEFAULT_RMS_TOLERANCE
    proposal: Path | None = None
    #: The plugin's ``fast`` and ``rgb_head`` properties (:mod:`neuralbrdf.render.fast_paths`).
    fast: bool = False
    rgb_head: bool = True
    measurement: Path | None = None

    def __post_init__(self) -> None:
        if sum(x is not None for x in (self.model, self.reference_bsdf, self.measurement)) != 1:
            raise InputError("give one of a model file, a reference BSDF or a measurement")
        if self.measurement is not None and self.proposal is None:
            raise InputError("a measurement renders with a model file's sampling proposal")
        if self.backend not in BACKENDS:
            raise InputError(f"unknown backend {self.backend!r}; expected one of {', '.join(BACKENDS)}")
        if self.proposal is not None and self.model is None and self.measurement is None:
            raise InputError("a sampling proposal needs a model file or a measurement")
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
        if self.measurement is not None:
            return {"material": MEASURED_MATERIAL_MATCHED, "measurement": str(Path(self.measurement).resolve()),
                    "proposal": str(Path(self.proposal).resolve())}
        parameters = {
            "material": NEURAL_MATERIAL,
            "model": str(Path(self.model).resolve()),
            "backend": self.backend,
            "rgb_tolerance": repr(float(self.rgb_tolerance)),
            "fast": str(self.fast).lower(),
            "rgb_head": str(self.rgb_head).lower(),
        }
        if self.proposal is not None:
            parameters.update(material=NEURAL_MATERIAL_MATCHED, proposal=str(Path(self.proposal).resolve()))
        return parameters

    def describe(self) -> str:
        if self.reference_bsdf is not None:
            return f"built-in {self.reference_bsdf}"
        if self.measurement is not None:
            return f"{Path(self.measurement).name} (Mitsuba's measured plugin)"
        return f"{Path(self.model).name} ({self.backend}{', fast path' if self.fast else ''})"


#: Options of every scene load here (:func:`load_scene`, :meth:`~neuralbrdf.render.scene_file.SceneFile.load`):
#: serially and without Mitsuba's object merging, i.e. in file order.  With them the preview's two
#: area lights came out in either order, by memory address (2-3 of 30 loads in one process), and a
#: render of a fixed seed drew its light samples from the other light — one of two different images,
#: which broke every comparison at matched seeds.  The price: identical shapes are not merged.
FILE_ORDER_LOADING = {"parallel": False, "optimize": False}


def load_scene(material: Material, resolution: int, max_depth: int = DEFAULT_MAX_DEPTH) -> mi.Scene:
    """The material-preview scene with ``material``, for the current variant, loaded in file order
    (:data:`FILE_ORDER_LOADING`)."""
    if material.model is not None:
        from neuralbrdf.render.load_time import validated_model

        validated_model(material.model)  # one clear InputError before Mitsuba wraps it (the plugin reuses it)
    try:
        return mi.load_file(
            str(SCENE_FILE), **FILE_ORDER_LOADING, resolution=str(resolution), max_depth=str(max_depth),
            **material.scene_parameters()
        )
    except InputError:
        raise
    except RuntimeError as error:
        from neuralbrdf.render.mitsuba_bsdf import scene_load_error

        raise scene_load_error(error, SCENE_FILE) from None


def machine_memory_bytes() -> int:
    """Physical memory of this machine in bytes."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def render_memory_bytes(resolution: int, spp_per_pass: int, wavefront: bool) -> int:
    """Memory a render plans to hold at once: the image buffers and one pass's paths."""
    pixels = resolution * resolution
    per_path = PATH_BYTES_WAVEFRONT if wavefront else PATH_BYTES_SYMBOLIC
    return pixels * IMAGE_BYTES_PER_PIXEL + pixels * spp_per_pass * per_path


def check_render_size(resolution: int, spp_per_pass: int, wavefront: bool) -> None:
    """Refuse (before any rendering) a render that would need more than :data:`MEMORY_FRACTION` of
    this machine's memory, or more paths per pass than Mitsuba's 32-bit indices can count."""
    need, have = render_memory_bytes(resolution, spp_per_pass, wavefront), machine_memory_bytes()
    lanes = resolution * resolution * spp_per_pass
    if need > MEMORY_FRACTION * have or lanes >= 2**32:
        raise InputError(
            f"--resolution {resolution} ({resolution}x{resolution}, {spp_per_pass} spp per pass) would need about "
            f"{need / 2**30:.3g} GiB and {lanes} paths per pass; this machine has {have / 2**30:.3g} GiB "
            f"(limit {MEMORY_FRACTION:.0%}) and a pass holds < 2^32 paths"
        )


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
    with dr_mode(wavefront), progress_bar(
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
    per_pass = spp_per_pass or default_spp_per_pass(resolution, material.needs_wavefront)
    if per_pass < 1:
        raise InputError(f"spp_per_pass must be a positive integer, got {per_pass}")
    check_render_size(resolution, min(per_pass, spp), material.needs_wavefront)
    set_variant(variant)
    scene = load_scene(material, resolution, max_depth)
    return render_passes(scene, spp, per_pass, seed, material.needs_wavefront, progress)


def within_drjit_budget(material: Material) -> Material:
    """``material``, switched to the onnxruntime backend (with a message on stderr) when its model
    is too large for the drjit backend (:data:`~neuralbrdf.limits.DRJIT_MAX_MULTIPLY_ADDS`)."""
    if material.model is None or material.backend != "drjit":
        return material
    from neuralbrdf.kinds import load_model
    from neuralbrdf.onnx_contract import matrix_multiply_adds

    count = matrix_multiply_adds(load_model(material.model).proto)
    if count <= DRJIT_MAX_MULTIPLY_ADDS:
        return material
    print(
        f"note: {material.model} unrolls to {count} multiply-adds per evaluation, above the drjit backend's "
        f"budget of {DRJIT_MAX_MULTIPLY_ADDS}; rendering with backend 'onnxruntime'",
        file=sys.stderr,
    )
    return dataclasses.replace(material, backend="onnxruntime")


def write_images(image: np.ndarray, png: str | Path, exr: str | Path | None = None) -> None:
    """8-bit sRGB PNG of a linear RGB image (values clipped to [0, 1]) and, if ``exr`` is given,
    the linear float32 RGB OpenEXR; written atomically, both or neither, and each read back
    (:func:`_write_checked`)."""
    bitmap = mi.Bitmap(np.ascontiguousarray(image, dtype=np.float32), mi.Bitmap.PixelFormat.RGB)
    srgb = bitmap.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)
    targets = [png] if exr is None else [png, exr]
    with atomic_paths(*targets) as temporaries:
        _write_checked(srgb, temporaries[0])
        if exr is not None:
            _write_checked(bitmap, temporaries[1])


def _write_checked(bitmap, path: Path) -> None:
    """``bitmap.write(path)``, then the file read back: Mitsuba's PNG writer reports no error when
    the disk fills and leaves an empty file, which must not be put in place as the image."""
    bitmap.write(str(path))
    try:
        whole = tuple(mi.Bitmap(str(path)).size()) == tuple(bitmap.size())
    except RuntimeError:
        whole = False
    if not whole:
        raise OSError(errno.ENOSPC if full_disk(path.parent) else errno.EIO, "the image file written is not readable")
