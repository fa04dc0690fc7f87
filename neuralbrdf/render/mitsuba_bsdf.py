"""The ``neuralbrdf`` Mitsuba 3 BSDF: render any model file of the ONNX contract (docs/formats.md#onnx-model-files, docs/mitsuba-plugin.md).

Usage from a user's own script::

    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")          # or llvm_ad_spectral, cuda_ad_rgb, cuda_ad_spectral
    from neuralbrdf.render import register
    register()                              # once per variant; idempotent
    bsdf = mi.load_dict({"type": "neuralbrdf", "filename": "gold.onnx", "backend": "drjit"})

Properties
----------
``filename``
    The ``.onnx`` model (resolved through Mitsuba's file resolver, so relative to the scene file).
    It is validated (:func:`neuralbrdf.kinds.load_model`) when the scene loads.
``backend``
    ``drjit`` (default): the graph is interpreted as Dr.Jit arithmetic
    (:mod:`~neuralbrdf.render.drjit_onnx`) and fuses into the render kernel; works in Mitsuba's
    default symbolic mode.  ``onnxruntime``: one ``InferenceSession.run`` per wavefront call of
    ``eval``/``eval_pdf``/``sample`` (two for a spectral model whose graph splits at the
    wavelength, :mod:`~neuralbrdf.render.onnx_split`: the direction features once per lane),
    which needs Dr.Jit's wavefront mode::

        dr.set_flag(dr.JitFlag.SymbolicLoops, False)
        dr.set_flag(dr.JitFlag.SymbolicCalls, False)

    (checked at every call, with an error saying so).  Not differentiable.
``rgb_tolerance``
    Spectral models in RGB variants only: held-out rms relative error of the reduced
    spectrum → sRGB rule fitted at load (default 1e-3; ``0`` integrates all 31 wavelengths
    exactly, at 31 network evaluations per query).  See *Colour* below.

``rgb_head``, ``fast``
    Booleans choosing a fast path of the file instead of ``f`` (default: the RGB head of a
    spectral model in RGB variants when the file has one; ``fast`` off):
    :mod:`~neuralbrdf.render.fast_paths`.  ``to_string`` names the output evaluated.

``proposal``
    Optional: another model file whose sampling proposal this BSDF uses instead of its own
    (resolved like ``filename``).  Any valid proposal leaves the image's expectation unchanged;
    ``neuralbrdf select`` renders a cheaper stand-in with its parent's proposal so that, at
    matched seeds, both trace the same paths and their image difference is the stand-in's
    bias, not Monte Carlo noise (:mod:`neuralbrdf.lod.select`).

Any other property fails loading (Mitsuba reports unreferenced properties).

Methods: ``eval`` returns ``f · cos θo``; ``sample`` draws from the fitted lobe mixture of
:mod:`~neuralbrdf.render.sampling` and returns ``f cos θo / pdf``; ``pdf`` is that mixture's
density; ``eval_pdf`` evaluates the network once for both.  Everything is 0 unless ``wi`` and
``wo`` are above the horizon (a one-sided reflector: flags ``GlossyReflection | FrontSide``).

Colour
------
=========================  ==============================================================
model / variant            what the BSDF returns
=========================  ==============================================================
RGB model, RGB variant     the model's linear sRGB values
spectral, spectral         the model at the ray's own wavelengths (``si.wavelengths``),
                           clamped to the model's wavelength range
RGB model, spectral        upsampled per sample like Mitsuba's unbounded RGB textures:
                           ``s = 2 max(rgb)``, coefficients of ``rgb / s`` from Mitsuba's
                           ``data/srgb.coeff`` (Jakob & Hanika 2019), value ``× s``
spectral model, RGB        integrated to linear sRGB like measurements (docs/formats.md#spectral-to-linear-srgb):
                           CIE 1931 2° observer × D65 on 400–700 nm at 10 nm (model clamped
                           to its range), IEC 61966-2-1 matrix, negatives clipped to 0 —
                           through a reduced rule with this model's few wavelengths
=========================  ==============================================================

The last row makes a flat spectrum ``c`` render as about ``(c, c, c)`` and keeps RGB renders of
spectral models consistent with the project's own sRGB conversion
(:mod:`neuralbrdf.data.colorimetry`).  The full rule costs 31 network evaluations per query;
at load the plugin fits a rule on a few of the 31 wavelengths that reproduces it on the model's
own spectra (:mod:`~neuralbrdf.render.spectral_quadrature`, held-out rms relative error ≤
``rgb_tolerance``, 1e-3 by default;
``to_string`` reports the rule and its error), evaluated unrolled in the drjit backend and as
one stacked run in onnxruntime.

The sampling proposal named by the model's kind (:attr:`neuralbrdf.kinds.Kind.proposal`) is
fitted when the scene loads, probing the model with onnxruntime: a GGX mixture
fitted to it for the neural kinds (:func:`~neuralbrdf.render.sampling.fit_neural_mixture`), the
analytic lobe for ABC (:func:`~neuralbrdf.render.sampling.fit_abc_mixture`).
"""

from __future__ import annotations

import math
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import onnx
import onnxruntime

from neuralbrdf import kinds
from neuralbrdf.atomic import file_version
from neuralbrdf.errors import InputError
from neuralbrdf.limits import DRJIT_MAX_MULTIPLY_ADDS, file_problem
from neuralbrdf.render.drjit_onnx import DrJitGraph
from neuralbrdf.onnx_contract import (
    INPUT_WAVELENGTH,
    INPUT_WI,
    INPUT_WO,
    OUTPUT_F,
    OnnxModel,
    matrix_multiply_adds,
)
from neuralbrdf.render.fast_paths import FAST_PROPERTY, RGB_HEAD_PROPERTY, chosen_output, flag
from neuralbrdf.render.onnx_split import split_at_wavelength
from neuralbrdf.render.sampling import LobeMixture, fit_proposal, probe_direction_pairs
from neuralbrdf.render.spectral_quadrature import (
    DEFAULT_RMS_TOLERANCE,
    SRGB_GRID_NM,
    ReducedQuadrature,
    fit_reduced_quadrature,
    srgb_weights,
)

PLUGIN_NAME = "neuralbrdf"
BACKENDS = ("drjit", "onnxruntime")
DEFAULT_BACKEND = "drjit"


#: Wavelengths (nm, spread over the model's range) averaged when probing a spectral model.
_PROBE_WAVELENGTH_COUNT = 5

_REGISTERED_VARIANTS: set[str] = set()
#: Per variant: a one-entry ``UInt32`` counter of clamped model evaluations (:func:`clamped_values`).
_CLAMPED: dict[str, object] = {}
_BSDF_CLASSES: dict[str, type] = {}
_UPSAMPLERS: dict[str, _SrgbUpsampler] = {}


def scene_load_error(error: RuntimeError, path) -> InputError:
    """The :class:`InputError` for Mitsuba's failure to load the scene ``path``; a missing
    ``neuralbrdf`` plugin gets the call that registers it instead of Mitsuba's bare message."""
    message = str(error)
    if f'Plugin "{PLUGIN_NAME}" not found' in message:
        variant = mi.variant()
        return InputError(
            f"the scene uses the {PLUGIN_NAME!r} BSDF, which is not registered in Mitsuba variant {variant!r}: "
            f"call neuralbrdf.render.register() after mi.set_variant({variant!r}) and before loading the scene "
            "(again after every change of variant); neuralbrdf render does this itself",
            path=path,
        )
    # Mitsuba's last line is the cause (a plugin's own exception message ends its traceback)
    return InputError(f"cannot load the scene: {message.strip().splitlines()[-1] if message.strip() else type(error).__name__}",
                      path=path)


def register() -> None:
    """Register the ``neuralbrdf`` BSDF plugin for the current Mitsuba variant (idempotent), and
    ``neuralbrdf_measured`` (:mod:`~neuralbrdf.render.measured_bsdf`) beside it.

    Supported: JIT variants (``llvm_*``, ``cuda_*``) with RGB or spectral colour, unpolarised.
    """
    variant = mi.variant()
    if variant is None:
        raise RuntimeError("select a Mitsuba variant (mi.set_variant) before registering 'neuralbrdf'")
    if variant in _REGISTERED_VARIANTS:
        return
    jit = variant.startswith(("llvm_", "cuda_"))
    if not jit or "polarized" in variant or not ("_rgb" in variant or "_spectral" in variant):
        raise RuntimeError(
            f"the neuralbrdf BSDF does not support Mitsuba variant {variant!r}; use an unpolarised "
            "RGB or spectral JIT variant (llvm_ad_rgb, llvm_ad_spectral, cuda_ad_rgb, cuda_ad_spectral)"
        )
    from neuralbrdf.render.measured_bsdf import register_measured

    cls = _bsdf_class(variant)
    mi.register_bsdf(PLUGIN_NAME, lambda props: cls(props))
    register_measured()
    _REGISTERED_VARIANTS.add(variant)


# --------------------------------------------------------------------------- clamping


def _clamp_counter():
    variant = mi.variant()
    if variant not in _CLAMPED:
        _CLAMPED[variant] = dr.zeros(mi.UInt32, 1)
    return _CLAMPED[variant]


def clamped_values() -> int:
    """Model evaluations (lanes) in the current variant whose value was negative or not finite
    and was clamped to 0 since :func:`reset_clamped_values` (evaluates pending kernels)."""
    return int(_clamp_counter()[0])


def reset_clamped_values() -> None:
    """Start counting clamped evaluations afresh (the render command does so before rendering)."""
    _CLAMPED[mi.variant()] = dr.zeros(mi.UInt32, 1)


def _nonnegative(columns: list) -> list:
    """``columns`` with negative and non-finite values set to 0; lanes with any such value are
    counted (:func:`clamped_values`).  The load-time probe of
    :func:`neuralbrdf.kinds.load_model` refuses models it finds negative; this
    guarantees that no negative radiance reaches an image where the probe did not look."""
    out, bad = [], None
    for column in columns:
        if isinstance(column, (int, float)):
            out.append(float(column) if math.isfinite(column) and column >= 0 else 0.0)
            continue
        ok = (column >= 0) & dr.isfinite(column)
        bad = ~ok if bad is None else bad | ~ok
        out.append(dr.select(ok, column, 0.0))
    if bad is not None:
        dr.scatter_reduce(dr.ReduceOp.Add, _clamp_counter(), mi.UInt32(1), mi.UInt32(0), active=bad)
    return out


def _nonnegative_rows(values: np.ndarray, lanes: int) -> np.ndarray:
    """:func:`_nonnegative` for onnxruntime's NumPy output whose rows are ``lanes`` lanes repeated."""
    bad = ~(np.isfinite(values) & (values >= 0))
    if not bad.any():
        return values
    count = int(bad.reshape(-1, lanes, int(np.prod(values.shape[1:], dtype=int))).any(axis=(0, 2)).sum())
    dr.scatter_reduce(dr.ReduceOp.Add, _clamp_counter(), mi.UInt32(count), mi.UInt32(0))
    return np.where(bad, 0.0, values).astype(values.dtype)


# --------------------------------------------------------------------------- backends


def _check_wavefront_mode() -> None:
    if (
        dr.flag(dr.JitFlag.SymbolicLoops)
        or dr.flag(dr.JitFlag.SymbolicCalls)
        or dr.flag(dr.JitFlag.SymbolicScope)
    ):
        raise RuntimeError(
            "the neuralbrdf backend 'onnxruntime' runs the network outside Dr.Jit, once per "
            "wavefront, so Dr.Jit must render in wavefront mode: call "
            "dr.set_flag(dr.JitFlag.SymbolicLoops, False) and "
            "dr.set_flag(dr.JitFlag.SymbolicCalls, False) before rendering, or use backend 'drjit'"
        )


def _lane_count(*arrays) -> int:
    return max(dr.width(a) for a in arrays)


def _rows(vector: mi.Vector3f, n: int, copies: int = 1) -> np.ndarray:
    """``[copies · n, 3]`` float32 rows of a Dr.Jit 3-vector, the ``n`` lanes repeated ``copies``
    times (a width-1 vector broadcast); interleaved and tiled by Dr.Jit in one kernel, faster
    than transposing and tiling in NumPy."""
    if dr.width(vector) != n:
        vector = vector + dr.zeros(mi.Vector3f, n)
    flat = dr.tile(dr.ravel(vector), copies) if copies > 1 else dr.ravel(vector)
    return flat.numpy().reshape(copies * n, 3)


def _stacked_column(values: list, n: int) -> np.ndarray:
    """``[len(values) · n]`` float32: the columns one after the other (Dr.Jit arrays of width
    ``n`` or 1, or Python floats)."""
    if all(isinstance(v, (int, float)) for v in values):
        return np.repeat(np.asarray(values, dtype=np.float32), n)
    columns = [mi.Float(v) + dr.zeros(mi.Float, n) if dr.width(v) != n else mi.Float(v) for v in values]
    return dr.concat(columns).numpy()


class _OnnxRuntimeBackend:
    """One ``InferenceSession.run`` per call, all lanes and wavelengths stacked in one batch.

    A spectral model whose graph splits at the wavelength (:mod:`~neuralbrdf.render.onnx_split`)
    runs in two: its direction part once over the ``n`` lanes, its wavelength part over the
    ``k · n`` stacked rows; used only where the parts reproduce the whole graph exactly on the
    probe pairs at load.
    """

    name = "onnxruntime"

    def __init__(self, model: OnnxModel, session: onnxruntime.InferenceSession) -> None:
        self.session = session
        self.split, self.parts = None, None
        split = split_at_wavelength(model.proto) if model.is_spectral else None
        if split is not None:
            parts = (_session(split.directions), _session(split.wavelengths))
            low, high = model.wavelength_range_nm
            nm = np.linspace(low - 20.0, high + 20.0, 4)
            if split.agrees(session, *parts, *probe_direction_pairs(), nm):
                self.split, self.parts = split, parts
        #: Session runs per ``rgb``/``spectral``/``integrated`` call.
        self.runs_per_call = 1 if self.split is None else 2

    def rgb(self, wi: mi.Vector3f, wo: mi.Vector3f) -> list[mi.Float]:
        _check_wavefront_mode()
        n = _lane_count(wi, wo)
        (f,) = self.session.run([OUTPUT_F], {INPUT_WI: _rows(wi, n), INPUT_WO: _rows(wo, n)})
        f = _nonnegative_rows(f, n)
        return [mi.Float(np.ascontiguousarray(f[:, c])) for c in range(3)]

    def _spectral_values(self, wi: mi.Vector3f, wo: mi.Vector3f, wavelengths: list) -> np.ndarray:
        """``[k, n]`` values at ``k`` wavelength columns (Dr.Jit arrays or floats, nm)."""
        _check_wavefront_mode()
        n = _lane_count(wi, wo, *[w for w in wavelengths if not isinstance(w, float)])
        k = len(wavelengths)
        stacked = _stacked_column(wavelengths, n)
        if self.split is None:
            feeds = {INPUT_WI: _rows(wi, n, k), INPUT_WO: _rows(wo, n, k), INPUT_WAVELENGTH: stacked}
            (f,) = self.session.run([OUTPUT_F], feeds)
        else:
            direction_part, wavelength_part = self.parts
            cut = direction_part.run(list(self.split.cut), {INPUT_WI: _rows(wi, n), INPUT_WO: _rows(wo, n)})
            feeds = {name: self.split.repeat(values, k) for name, values in zip(self.split.cut, cut)}
            (f,) = wavelength_part.run([OUTPUT_F], {**feeds, INPUT_WAVELENGTH: stacked})
        return _nonnegative_rows(f, n).reshape(k, n)

    def spectral(self, wi: mi.Vector3f, wo: mi.Vector3f, wavelengths: list) -> list[mi.Float]:
        return [mi.Float(np.ascontiguousarray(v)) for v in self._spectral_values(wi, wo, wavelengths)]

    def integrated(self, wi: mi.Vector3f, wo: mi.Vector3f, rule: ReducedQuadrature) -> list[mi.Float]:
        """``Σ_k f(λ_k) V[k, c]`` for ``c`` = 0, 1, 2, from one run over all nodes ``λ_k``."""
        values = self._spectral_values(wi, wo, list(rule.wavelengths_nm))
        channels = rule.weights.T @ values.astype(np.float64)
        return [mi.Float(channels[c].astype(np.float32)) for c in range(3)]


def check_drjit_budget(model: OnnxModel) -> None:
    """Refuse a graph the ``drjit`` backend cannot compile in reasonable time and memory: above
    :data:`~neuralbrdf.limits.DRJIT_MAX_MULTIPLY_ADDS` unrolled multiply-adds per evaluation,
    counted before anything is compiled."""
    count = matrix_multiply_adds(model.proto)
    if count > DRJIT_MAX_MULTIPLY_ADDS:
        raise InputError(
            f"the network unrolls to {count} multiply-adds per evaluation, above the drjit backend's budget of "
            f"{DRJIT_MAX_MULTIPLY_ADDS} (neuralbrdf.limits.DRJIT_MAX_MULTIPLY_ADDS): use backend 'onnxruntime'",
            path=model.path,
        )


class _DrJitBackend:
    """The graph as Dr.Jit arithmetic inside the kernel (see :mod:`~neuralbrdf.render.drjit_onnx`)."""

    name = "drjit"

    def __init__(self, model: OnnxModel) -> None:
        check_drjit_budget(model)
        self.graph = DrJitGraph.from_model(model)

    def rgb(self, wi: mi.Vector3f, wo: mi.Vector3f) -> list:
        return _nonnegative(self.graph(wi, wo))

    def spectral(self, wi: mi.Vector3f, wo: mi.Vector3f, wavelengths: list) -> list:
        # The parts that depend on wi, wo only are issued once for all wavelengths.
        return _nonnegative(self.graph.at_wavelengths(wi, wo, wavelengths))

    def integrated(self, wi: mi.Vector3f, wo: mi.Vector3f, rule: ReducedQuadrature) -> list:
        """``Σ_k f(λ_k) V[k, c]``, the network unrolled once per node (weights as literals); one
        clamp count for all nodes (one atomic update per call, not one per node)."""
        channels = [0.0, 0.0, 0.0]
        for f, weights in zip(self.spectral(wi, wo, list(rule.wavelengths_nm)), rule.weights):
            channels = [dr.fma(f, float(w), c) for w, c in zip(weights, channels)]
        return channels


def _session(source: Path | onnx.ModelProto) -> onnxruntime.InferenceSession:
    """A CPU session (of a file or a model) whose threads sleep between runs instead of
    spinning: in wavefront mode Dr.Jit's kernels run between the calls, and spinning threads
    would compete with them (``benchmarks/README.md``, design measurements)."""
    options = onnxruntime.SessionOptions()
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    model = source.SerializeToString() if isinstance(source, onnx.ModelProto) else str(source)
    return onnxruntime.InferenceSession(model, options, providers=["CPUExecutionProvider"])


def _numpy_spectra(session: onnxruntime.InferenceSession, wi: np.ndarray, wo: np.ndarray, wavelengths) -> np.ndarray:
    """``[k, n]`` values of a spectral model at ``n`` NumPy direction pairs and ``k`` wavelengths
    (nm), from one run (load-time probing)."""
    feeds = {
        INPUT_WI: np.tile(wi, (len(wavelengths), 1)),
        INPUT_WO: np.tile(wo, (len(wavelengths), 1)),
        INPUT_WAVELENGTH: np.repeat(wavelengths, len(wi)).astype(np.float32),
    }
    (f,) = session.run([OUTPUT_F], feeds)
    return f.reshape(len(wavelengths), len(wi))


def fit_rgb_rule(model: OnnxModel, session: onnxruntime.InferenceSession, rms_tolerance: float) -> ReducedQuadrature:
    """The reduced spectrum → linear sRGB rule of a spectral model (module docstring)."""
    low, high = model.wavelength_range_nm
    grid = np.clip(SRGB_GRID_NM, low, high)
    spectra = _numpy_spectra(session, *probe_direction_pairs(), grid).T
    return fit_reduced_quadrature(spectra, grid, srgb_weights(), rms_tolerance)


def _probe_function(model: OnnxModel, session: onnxruntime.InferenceSession):
    """Channel- (or wavelength-) averaged ``f`` through onnxruntime, for fitting the sampler."""

    def brdf(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        if not model.is_spectral:
            (f,) = session.run([OUTPUT_F], {INPUT_WI: wi, INPUT_WO: wo})
            return f.mean(axis=1)
        wavelengths = np.linspace(*model.wavelength_range_nm, _PROBE_WAVELENGTH_COUNT)
        return _numpy_spectra(session, wi, wo, wavelengths).mean(axis=0)

    return brdf


# --------------------------------------------------------------------------- colour


class _SrgbUpsampler:
    """Mitsuba's RGB → spectrum model (Jakob & Hanika 2019), vectorised over lanes.

    ``mi.srgb_model_fetch`` only takes one scalar colour; this is the same trilinear lookup in
    Mitsuba's ``data/srgb.coeff`` table (``rgb2spec_fetch``) written with Dr.Jit gathers, so that
    a BRDF value that varies per ray can be upsampled inside the kernel.  Exact greys get the
    flat spectrum in closed form, ``c = (0, 0, (g - 1/2) / sqrt(g (1 - g)))``, as Mitsuba 3.9's
    own fetch does (the table is 2e-4 off there).
    """

    def __init__(self) -> None:
        path = Path(str(mi.file_resolver().resolve("data/srgb.coeff")))
        raw = path.read_bytes()
        if raw[:4] != b"SPEC":
            raise InputError("not an RGB2Spec coefficient table", path=path)
        res = int(np.frombuffer(raw, dtype=np.uint32, count=1, offset=4)[0])
        scale = np.frombuffer(raw, dtype=np.float32, count=res, offset=8)
        data = np.frombuffer(raw, dtype=np.float32, count=3 * res**3 * 3, offset=8 + 4 * res)
        self.res = res
        self.scale = mi.Float(np.array(scale))
        self.data = mi.Float(np.array(data))

    def coefficients(self, rgb: mi.Color3f) -> mi.Vector3f:
        """Model coefficients of colours in [0, 1] (clamped), as ``rgb2spec_fetch``."""
        res = self.res
        rgb = dr.clip(rgb, 0.0, 1.0)
        r, g, b = rgb.x, rgb.y, rgb.z
        # Largest component; later channels win ties, as in rgb2spec_fetch.
        g_wins = g >= r
        i = dr.select(g_wins, mi.UInt32(1), mi.UInt32(0))
        z = dr.select(g_wins, g, r)
        b_wins = b >= z
        i = dr.select(b_wins, mi.UInt32(2), i)
        z = dr.select(b_wins, b, z)
        x_src = dr.select(i == 0, g, dr.select(i == 1, b, r))  # rgb[(i + 1) % 3]
        y_src = dr.select(i == 0, b, dr.select(i == 1, r, g))  # rgb[(i + 2) % 3]
        inv = (res - 1) / dr.maximum(z, 1e-30)
        x, y = x_src * inv, y_src * inv
        xi = dr.minimum(mi.UInt32(x), res - 2)
        yi = dr.minimum(mi.UInt32(y), res - 2)
        first_above = dr.binary_search(
            0, res - 1, lambda idx: dr.gather(mi.Float, self.scale, idx) <= z
        )
        zi = mi.UInt32(dr.clip(mi.Int32(first_above) - 1, 0, res - 2))
        x1, y1 = x - mi.Float(xi), y - mi.Float(yi)
        s0 = dr.gather(mi.Float, self.scale, zi)
        s1 = dr.gather(mi.Float, self.scale, zi + 1)
        z1 = (z - s0) / (s1 - s0)
        base = ((i * res + zi) * res + yi) * res + xi

        def corner(dz, dy, dx):
            return dr.gather(mi.Vector3f, self.data, base + dz * res * res + dy * res + dx)

        def lerp(a, b_, t):
            return dr.fma(b_ - a, t, a)

        c00 = lerp(corner(0, 0, 0), corner(0, 0, 1), x1)
        c01 = lerp(corner(0, 1, 0), corner(0, 1, 1), x1)
        c10 = lerp(corner(1, 0, 0), corner(1, 0, 1), x1)
        c11 = lerp(corner(1, 1, 0), corner(1, 1, 1), x1)
        coeff = lerp(lerp(c00, c01, y1), lerp(c10, c11, y1), z1)
        black = dr.gather(mi.Vector3f, self.data, mi.UInt32(0))
        coeff = dr.select(z > 0, coeff, black)
        # 1/2 + x / (2 sqrt(1 + x²)) = g for x = (g - 1/2) / sqrt(g (1 - g)); ±inf at 0 and 1.
        flat = mi.Vector3f(0.0, 0.0, (g - 0.5) / dr.sqrt(g * (1.0 - g)))
        return dr.select((r == g) & (g == b), flat, coeff)

    def spectrum(self, rgb: mi.Color3f, wavelengths: mi.Spectrum) -> mi.Spectrum:
        """Unbounded RGB upsampled like Mitsuba's bitmap textures: scale to max 0.5, rescale."""
        scale = 2.0 * dr.max(rgb, axis=0)
        coeff = self.coefficients(rgb / dr.maximum(scale, 1e-8))
        return mi.srgb_model_eval(mi.Array3f(coeff), wavelengths) * scale


def _upsampler() -> _SrgbUpsampler:
    variant = mi.variant()
    if variant not in _UPSAMPLERS:
        _UPSAMPLERS[variant] = _SrgbUpsampler()
    return _UPSAMPLERS[variant]


# --------------------------------------------------------------------------- the BSDF


def _read_properties(props: mi.Properties) -> tuple[Path, str, float]:
    if "filename" not in props:
        raise InputError("the neuralbrdf BSDF needs a 'filename' property (the .onnx model)")
    filename = str(props.get("filename"))
    backend = str(props.get("backend", DEFAULT_BACKEND))
    if backend not in BACKENDS:
        raise InputError(
            f"unknown backend {backend!r}; expected one of {list(BACKENDS)}", key="backend"
        )
    rgb_tolerance = float(props.get("rgb_tolerance", DEFAULT_RMS_TOLERANCE))
    if not 0.0 <= rgb_tolerance < 1.0:
        raise InputError(
            f"rgb_tolerance must be in [0, 1) (0: all 31 wavelengths), got {rgb_tolerance}",
            key="rgb_tolerance",
        )
    return Path(str(mi.file_resolver().resolve(filename))), backend, rgb_tolerance


def _proposal_path(props: mi.Properties) -> Path | None:
    """The ``proposal`` property (module docstring), resolved, or ``None``."""
    if "proposal" not in props:
        return None
    path = Path(str(mi.file_resolver().resolve(str(props.get("proposal")))))
    if not path.is_file():
        raise InputError(file_problem(path) or "no such model file for the 'proposal' property", path=path,
                         key="proposal")
    return path


#: Load-time work per model file (:func:`_load_time_work`), keyed by the file as it was read
#: (:attr:`~neuralbrdf.onnx_contract.OnnxModel.version`).
_LOAD_TIME_CACHE: dict[tuple, object] = {}
#: Entries kept; the oldest goes first.
_LOAD_TIME_CACHE_SIZE = 64


def validated_model(path: Path) -> OnnxModel:
    """:func:`neuralbrdf.kinds.load_model` of ``path``, reused while the file is unchanged (same size,
    time, inode).  The file is read once per version: a file replaced while a scene loads is either
    the old model or the new one, never parts of both."""
    if not path.is_file():
        raise InputError(file_problem(path) or "no such ONNX model file", path=path)
    found = _LOAD_TIME_CACHE.get(("model", file_version(path)))
    if found is None:
        found = kinds.load_model(path)
        _remember(("model", found.version), found)
    return found


def _remember(key: tuple, value) -> None:
    if len(_LOAD_TIME_CACHE) >= _LOAD_TIME_CACHE_SIZE:
        del _LOAD_TIME_CACHE[next(iter(_LOAD_TIME_CACHE))]
    _LOAD_TIME_CACHE[key] = value


def _load_time_work(model: OnnxModel, rgb_tolerance: float, proposal: OnnxModel | None = None,
                    output: str = OUTPUT_F) -> tuple[OnnxModel, LobeMixture, ReducedQuadrature | None]:
    """The model as read, cut to the ``output`` the plugin evaluates (``f`` or a fast path,
    :meth:`~neuralbrdf.onnx_contract.OnnxModel.output_view`), the fitted sampling proposal (of the
    ``proposal`` model if given, else of the model's ``f``) and (spectral output, RGB variant) its
    sRGB rule.  Each is computed once per file version — the proposal per file alone (it depends
    on neither variant nor tolerance), the rule per file, output and tolerance — so a scene loaded
    again (the selector of :mod:`neuralbrdf.lod.select` loads one scene many times, with stand-ins
    sampling like their parent) skips the probing, and a model sampled with another file's
    proposal never fits its own."""
    view_key = ("output", model.version, output)
    if view_key not in _LOAD_TIME_CACHE:
        _remember(view_key, model.output_view(output))
    view = _LOAD_TIME_CACHE[view_key]
    mixture = _fitted_proposal(proposal or model)
    rgb_rule = None
    if view.is_spectral and not mi.is_spectral:
        key = ("rgb_rule", model.version, output, rgb_tolerance)
        if key not in _LOAD_TIME_CACHE:
            _remember(key, fit_rgb_rule(view, _session(view.proto), rgb_tolerance))
        rgb_rule = _LOAD_TIME_CACHE[key]
    return view, mixture, rgb_rule


def _fitted_proposal(model: OnnxModel) -> LobeMixture:
    """The sampling proposal of ``model`` (its kind's), fitted to onnxruntime probes."""
    key = ("proposal", model.version)
    if key not in _LOAD_TIME_CACHE:
        probe = _probe_function(model, _session(model.proto))
        _remember(key, fit_proposal(kinds.get(model.kind).proposal, probe, model.details))
    return _LOAD_TIME_CACHE[key]


def _bsdf_class(variant: str) -> type:
    """The BSDF class for ``variant`` (a Python BSDF derives from that variant's ``mi.BSDF``)."""
    if variant in _BSDF_CLASSES:
        return _BSDF_CLASSES[variant]

    class NeuralBSDF(mi.BSDF):
        """Mitsuba BSDF evaluating an ONNX BRDF model (module docstring)."""

        def __init__(self, props: mi.Properties) -> None:
            mi.BSDF.__init__(self, props)
            path, backend, rgb_tolerance = _read_properties(props)
            proposal = _proposal_path(props)
            read = validated_model(path)  # everything below uses this one reading of the file
            self.output = chosen_output(read, mi.is_spectral, flag(props, FAST_PROPERTY, False),
                                        flag(props, RGB_HEAD_PROPERTY, True))
            self.model, self.mixture, self.rgb_rule = _load_time_work(
                read, rgb_tolerance, None if proposal is None else validated_model(proposal), self.output)
            if backend == "onnxruntime":
                self.backend = _OnnxRuntimeBackend(self.model, _session(self.model.proto))
            else:
                self.backend = _DrJitBackend(self.model)
            self._spectral_variant = mi.is_spectral
            self.m_flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            self.m_components = [self.m_flags]

        # -- the BRDF value in the variant's colour representation

        def _brdf(self, si: mi.SurfaceInteraction3f, wo: mi.Vector3f) -> mi.Spectrum:
            """``f`` (no cosine, not masked) as a ``mi.Spectrum``, one network evaluation."""
            model, backend = self.model, self.backend
            if self._spectral_variant:
                if model.is_spectral:
                    low, high = model.wavelength_range_nm
                    n = dr.size_v(mi.Spectrum)
                    wavelengths = [dr.clip(si.wavelengths[k], low, high) for k in range(n)]
                    return mi.Spectrum(*backend.spectral(si.wi, wo, wavelengths))
                rgb = mi.Color3f(*backend.rgb(si.wi, wo))
                return _upsampler().spectrum(rgb, si.wavelengths)
            if model.is_spectral:
                channels = backend.integrated(si.wi, wo, self.rgb_rule)
                return mi.Spectrum(*[dr.maximum(c, 0.0) for c in channels])
            return mi.Spectrum(*backend.rgb(si.wi, wo))

        @staticmethod
        def _enabled(ctx: mi.BSDFContext) -> bool:
            return ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0)

        def _above(self, si, wo, active):
            cos_o = mi.Frame3f.cos_theta(wo)
            return active & (mi.Frame3f.cos_theta(si.wi) > 0) & (cos_o > 0), cos_o

        # -- the BSDF interface

        def eval(self, ctx, si, wo, active=True):
            if not self._enabled(ctx):
                return mi.Spectrum(0.0)
            valid, cos_o = self._above(si, wo, active)
            return dr.select(valid, self._brdf(si, wo) * cos_o, 0.0)

        def pdf(self, ctx, si, wo, active=True):
            if not self._enabled(ctx):
                return mi.Float(0.0)
            return dr.select(active, self.mixture.pdf(si.wi, wo), 0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            if not self._enabled(ctx):
                return mi.Spectrum(0.0), mi.Float(0.0)
            valid, cos_o = self._above(si, wo, active)
            value = dr.select(valid, self._brdf(si, wo) * cos_o, 0.0)
            return value, dr.select(active, self.mixture.pdf(si.wi, wo), 0.0)

        def sample(self, ctx, si, sample1, sample2, active=True):
            bs = dr.zeros(mi.BSDFSample3f)
            if not self._enabled(ctx):
                return bs, mi.Spectrum(0.0)
            wo, pdf, valid = self.mixture.sample(si.wi, sample1, sample2)
            valid &= active
            value = self._brdf(si, wo) * mi.Frame3f.cos_theta(wo) / pdf
            bs.wo = wo
            bs.pdf = dr.select(valid, pdf, 0.0)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
            bs.sampled_component = mi.UInt32(0)
            return bs, dr.select(valid, value, 0.0)

        def to_string(self):
            model = self.model
            spectral = (
                f"spectral {model.wavelength_range_nm[0]:g}-{model.wavelength_range_nm[1]:g} nm"
                if model.is_spectral
                else "RGB"
            )
            return (
                "NeuralBRDF[\n"
                f"  filename = {str(model.path)!r},\n"
                f"  kind = {model.kind}, material = {model.material!r}, {spectral},\n"
                f"  output = {self.output},\n"
                f"  backend = {self.backend.name},\n"
                f"  proposal = {self.mixture.describe()}\n"
                + (f"  to sRGB = {self.rgb_rule.describe()}\n" if self.rgb_rule else "")
                + "]"
            )

    _BSDF_CLASSES[variant] = NeuralBSDF
    return NeuralBSDF
