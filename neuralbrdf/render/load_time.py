"""What the Mitsuba BSDFs work out once per model file when a scene loads, shared by the ``neuralbrdf``
plugin (:mod:`~neuralbrdf.render.mitsuba_bsdf`) and ``neuralbrdf_measured``
(:mod:`~neuralbrdf.render.measured_bsdf`): the validated model (:func:`validated_model`), its sampling
proposal fitted to onnxruntime probes (:func:`fitted_proposal`), the reduced spectrum → sRGB rule of a
spectral model (:func:`fit_rgb_rule`), the ``proposal`` property (:func:`proposal_path`), and the cache
that keeps each per file version (:func:`load_time_work`).
"""

from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import numpy as np
import onnx
import onnxruntime

from neuralbrdf import kinds
from neuralbrdf.atomic import file_version
from neuralbrdf.errors import InputError
from neuralbrdf.limits import file_problem
from neuralbrdf.onnx_contract import INPUT_WAVELENGTH, INPUT_WI, INPUT_WO, OUTPUT_F, OnnxModel
from neuralbrdf.render.sampling import LobeMixture, fit_proposal, probe_direction_pairs
from neuralbrdf.render.spectral_quadrature import SRGB_GRID_NM, ReducedQuadrature, fit_reduced_quadrature, srgb_weights

#: Wavelengths (nm, spread over the model's range) averaged when probing a spectral model.
_PROBE_WAVELENGTH_COUNT = 5


def onnx_session(source: Path | onnx.ModelProto) -> onnxruntime.InferenceSession:
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
    """The reduced spectrum → linear sRGB rule of a spectral model (*Colour* in
    :mod:`~neuralbrdf.render.mitsuba_bsdf`)."""
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


def proposal_path(props: mi.Properties) -> Path | None:
    """The ``proposal`` property (:mod:`~neuralbrdf.render.mitsuba_bsdf`), resolved, or ``None``."""
    if "proposal" not in props:
        return None
    path = Path(str(mi.file_resolver().resolve(str(props.get("proposal")))))
    if not path.is_file():
        raise InputError(file_problem(path) or "no such model file for the 'proposal' property", path=path,
                         key="proposal")
    return path


#: Load-time work per model file (:func:`load_time_work`), keyed by the file as it was read
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


def load_time_work(model: OnnxModel, rgb_tolerance: float, proposal: OnnxModel | None = None,
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
    mixture = fitted_proposal(proposal or model)
    rgb_rule = None
    if view.is_spectral and not mi.is_spectral:
        key = ("rgb_rule", model.version, output, rgb_tolerance)
        if key not in _LOAD_TIME_CACHE:
            _remember(key, fit_rgb_rule(view, onnx_session(view.proto), rgb_tolerance))
        rgb_rule = _LOAD_TIME_CACHE[key]
    return view, mixture, rgb_rule


def fitted_proposal(model: OnnxModel) -> LobeMixture:
    """The sampling proposal of ``model`` (its kind's), fitted to onnxruntime probes."""
    key = ("proposal", model.version)
    if key not in _LOAD_TIME_CACHE:
        probe = _probe_function(model, onnx_session(model.proto))
        _remember(key, fit_proposal(kinds.get(model.kind).proposal, probe, model.details))
    return _LOAD_TIME_CACHE[key]
