"""Trace a model on directions into the self-contained ONNX file of docs/formats.md#onnx-model-files, check it, write it.

Any :class:`torch.nn.Module` that maps unit directions ``wi, wo`` ``[N, 3]`` (and, for spectral
models, wavelengths ``[N]`` in nm) to the BRDF in sr⁻¹ — the modules of
:mod:`neuralbrdf.models.directional` and the truths of :mod:`neuralbrdf.evaluation.truth` — is
wrapped in an :class:`Exportable` with its contract metadata and written by :func:`write_model`:

1. :func:`trace` — ``torch.onnx.export`` (TorchScript exporter, opset :data:`OPSET`, dynamic
   batch ``N``) with float32-accurate replacements for ``expm1`` and ``softplus``;
2. :func:`validate` — onnxruntime and PyTorch evaluate it on :func:`validation_probes` (random
   hemisphere pairs, mirror pairs, grazing pairs, pairs below the horizon, wavelengths inside and
   outside the model's range) and must agree within the float32 accuracy of the model itself
   (:func:`float32_error_allowance`);
3. the file appears atomically, after :func:`neuralbrdf.kinds.load_model` (the whole contract, its
   kind's part included) accepted it, or not at all.

Checkpoints become an :class:`~neuralbrdf.kinds.Exportable` through their kind
(:func:`neuralbrdf.kinds.load_exportable`); :func:`export_checkpoint` is ``neuralbrdf export``.
"""

from __future__ import annotations

import copy
import io
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
import onnxruntime
import torch
from onnx import helper
from torch.onnx import symbolic_helper

from neuralbrdf.atomic import atomic_path
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import inplane_to_vectors, normalize, reflect, spherical_to_vector
from neuralbrdf.kinds import Exportable, load_exportable, load_model
from neuralbrdf.onnx_contract import INPUT_WAVELENGTH, INPUT_WI, INPUT_WO, OUTPUT_F

#: ONNX opset of exported graphs.
OPSET = 17
#: Largest accepted ``|f_ort - f_torch| / |f_torch|`` (docs/formats.md#onnx-model-files) ...
RELATIVE_TOLERANCE = 1e-5
#: ... above this absolute floor in sr⁻¹ (float32 rounding of values near 0).
ABSOLUTE_FLOOR_SR = 1e-8
#: onnxruntime may differ from PyTorch by this multiple of the model's own float32 rounding error.
FLOAT32_ERROR_FACTOR = 4.0
#: Nanometres by which validation wavelengths reach past the model's range (clamping is checked).
WAVELENGTH_OVERSHOOT_NM = 40.0

class ExportValidationError(RuntimeError):
    """The traced graph does not reproduce the PyTorch model; nothing was written."""


@dataclass(frozen=True)
class ExportReport:
    """What :func:`export` wrote and how closely onnxruntime matched PyTorch."""

    path: Path
    kind: str
    material: str
    n_probes: int
    max_abs_error: float
    max_rel_error: float


# --------------------------------------------------------------------------- tracing


#: Below this ``|x|`` the exported ``expm1`` uses its Taylor polynomial (see :func:`_expm1_symbolic`).
EXPM1_SERIES_LIMIT = 0.5
#: Taylor coefficients ``1/n!``, ``n = 1..9``: truncation error below 1e-9 relative for ``|x| < 0.5``.
_EXPM1_COEFFICIENTS = [1.0 / math.factorial(n) for n in range(1, 10)]


def _constant(g, value: float):
    return g.op("Constant", value_t=torch.tensor(value, dtype=torch.float32))


def _expm1_symbolic(g, x):
    """``expm1`` (no ONNX operator) to float32 accuracy in every backend.

    ``x · Σ_{n=1..9} x^{n-1}/n!`` (Horner) for ``|x| < 0.5``, else ``exp(x) − 1`` (which loses at
    most one bit there).
    """
    series = _constant(g, _EXPM1_COEFFICIENTS[-1])
    for coefficient in reversed(_EXPM1_COEFFICIENTS[:-1]):
        series = g.op("Add", g.op("Mul", series, x), _constant(g, coefficient))
    series = g.op("Mul", series, x)
    direct = g.op("Sub", g.op("Exp", x), _constant(g, 1.0))
    small = g.op("Less", g.op("Abs", x), _constant(g, EXPM1_SERIES_LIMIT))
    return g.op("Where", small, series, direct)


def _log1p_of_unit_interval(g, e):
    """``log1p(e)`` for ``e`` in [0, 1] as Kahan's ``ln(u) e / (u − 1)``, ``u = 1 + e`` (``e`` where
    ``u`` rounds to 1): accurate to a few ulps wherever ``ln`` is accurate near 1
    (Higham, *Accuracy and Stability of Numerical Algorithms*, 2nd ed., §1.14.1)."""
    u = g.op("Add", e, _constant(g, 1.0))
    d = g.op("Sub", u, _constant(g, 1.0))
    accurate = g.op("Div", g.op("Mul", g.op("Log", u), e), d)
    return g.op("Where", g.op("Equal", d, _constant(g, 0.0)), e, accurate)


@symbolic_helper.parse_args("v", "f", "f")
def _softplus_symbolic(g, x, beta, threshold):
    """torch's ``softplus(x, beta, threshold)`` as ``(relu(z) + log1p(e^{−|z|})) / beta``, ``z = beta x``
    (``x`` where ``z > threshold``), instead of ONNX ``Softplus``: ``ln(1 + e^{−|z|})`` as written in
    float32 loses ``e^{−|z|}`` to rounding (1e-3 relative at ``z = −10`` in Dr.Jit's
    interpretation), which the NLB's ``expm1(softplus(y))`` output would expose."""
    z = g.op("Mul", x, _constant(g, beta))
    tail = _log1p_of_unit_interval(g, g.op("Exp", g.op("Neg", g.op("Abs", z))))
    value = g.op("Div", g.op("Add", g.op("Relu", z), tail), _constant(g, beta))
    return g.op("Where", g.op("Greater", z, _constant(g, threshold)), x, value)


def _input_names(spectral: bool) -> list[str]:
    return [INPUT_WI, INPUT_WO, INPUT_WAVELENGTH] if spectral else [INPUT_WI, INPUT_WO]


def trace(exportable: Exportable) -> onnx.ModelProto:
    """The module as an ONNX graph with the contract's names, dynamic ``N`` and metadata."""
    torch.onnx.register_custom_op_symbolic("aten::expm1", _expm1_symbolic, OPSET)
    torch.onnx.register_custom_op_symbolic("aten::softplus", _softplus_symbolic, OPSET)
    names = _input_names(exportable.is_spectral)
    feeds = validation_probes(exportable.wavelength_range_nm, n_random=5)
    args = tuple(torch.from_numpy(feeds[name]) for name in names)
    buffer = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tracer warnings about Python-side shape checks
        torch.onnx.export(
            exportable.module,
            args,
            buffer,
            input_names=names,
            output_names=[OUTPUT_F],
            dynamic_axes={name: {0: "N"} for name in [*names, OUTPUT_F]},
            opset_version=OPSET,
            dynamo=False,
        )
    proto = onnx.load_from_string(buffer.getvalue())
    helper.set_model_props(proto, exportable.metadata)
    proto.doc_string = f"neuralbrdf {exportable.kind} model of {exportable.material!r} (docs/formats.md#onnx-model-files)"
    return proto


# --------------------------------------------------------------------------- validation


def validation_probes(
    wavelength_range_nm: tuple[float, float] | None, n_random: int = 4096, seed: int = 0
) -> dict[str, np.ndarray]:
    """Inputs on which onnxruntime must reproduce PyTorch, float32 feeds by input name.

    ``n_random`` pairs uniform over the hemisphere, as many mirror pairs (``wo`` the reflection
    of ``wi``, where specular peaks are), in-plane pairs (signed angles in ±89°), grazing pairs
    (both polar angles in [85°, 89.99°]), and a quarter as many pairs with ``wi`` or ``wo`` below
    the horizon.  Wavelengths (spectral models) are uniform over the model's range widened by
    :data:`WAVELENGTH_OVERSHOOT_NM` on both sides, and include both ends exactly.
    """
    rng = np.random.default_rng(seed)
    n = n_random

    def hemisphere(count, theta_low_deg=0.0, theta_high_deg=90.0):
        cos_theta = rng.uniform(np.cos(np.radians(theta_high_deg)), np.cos(np.radians(theta_low_deg)), count)
        return spherical_to_vector(np.degrees(np.arccos(cos_theta)), rng.uniform(0.0, 360.0, count))

    wi_mirror = hemisphere(n)
    wi_plane, wo_plane = inplane_to_vectors(*rng.uniform(-89.0, 89.0, (2, n)))
    n_below = max(n // 4, 2)
    wi_below, wo_below = hemisphere(n_below), hemisphere(n_below)
    wi_below[::2, 2] *= -1.0
    wo_below[1::2, 2] *= -1.0
    pairs = [
        (hemisphere(n), hemisphere(n)),
        (wi_mirror, reflect(wi_mirror)),
        (wi_plane, wo_plane),
        (hemisphere(n, 85.0, 89.99), hemisphere(n, 85.0, 89.99)),
        (wi_below, wo_below),
    ]
    wi, wo = (normalize(np.concatenate(column)).astype(np.float32) for column in zip(*pairs))
    feeds = {INPUT_WI: wi, INPUT_WO: wo}
    if wavelength_range_nm is not None:
        low, high = wavelength_range_nm
        wavelengths = rng.uniform(low - WAVELENGTH_OVERSHOOT_NM, high + WAVELENGTH_OVERSHOOT_NM, len(wi))
        wavelengths[:2] = (low, high)
        feeds[INPUT_WAVELENGTH] = wavelengths.astype(np.float32)
    return feeds


def float32_error_allowance(exportable: Exportable, inputs: list[torch.Tensor], expected: np.ndarray) -> np.ndarray:
    """Per output entry, how far a correct float32 evaluation of the model may stray, in sr⁻¹.

    The model is evaluated once more in float64 (a deep copy); ``e = |f_float32 − f_float64|`` is
    the float32 rounding error of PyTorch's own evaluation at each probe, and ``r`` the largest
    ``e / |f|`` over the probes, the model's float32 accuracy where it is worst conditioned
    (networks with an exponential output and large cancelling pre-activations reach 1e-5 to
    1e-3 near grazing mirror pairs).  One probe's ``e`` is one sample of a rounding error that
    another evaluation order can exceed, hence ``r |f|`` beside it.
    onnxruntime runs the same arithmetic in another order, so it may differ from PyTorch by
    :data:`FLOAT32_ERROR_FACTOR` times ``e + r |f|`` on top of the contract's
    ``RELATIVE_TOLERANCE |f| + ABSOLUTE_FLOOR_SR``.  A model that cannot run in float64 gets
    no allowance beyond the contract's.
    """
    try:
        double = copy.deepcopy(exportable.module).double()
        with torch.no_grad():
            exact = double(*(x.double() for x in inputs)).numpy()
    except (RuntimeError, TypeError):
        return np.zeros_like(expected)
    if exact.shape != expected.shape or not np.all(np.isfinite(exact)):
        return np.zeros_like(expected)
    rounding = np.abs(expected - exact)
    significant = np.abs(exact) > ABSOLUTE_FLOOR_SR
    worst_relative = float(np.max(rounding[significant] / np.abs(exact[significant]))) if np.any(significant) else 0.0
    return FLOAT32_ERROR_FACTOR * (rounding + worst_relative * np.abs(expected))


def validate(proto: onnx.ModelProto, exportable: Exportable) -> tuple[int, float, float]:
    """Compare onnxruntime with PyTorch on :func:`validation_probes`.

    Returns ``(n_probes, max_abs_error, max_rel_error)``; raises
    :class:`ExportValidationError` when PyTorch's output is not finite or when any value misses
    ``|f_ort - f_torch| <= RELATIVE_TOLERANCE |f_torch| + ABSOLUTE_FLOOR_SR + allowance``, the
    allowance being the model's own float32 rounding error (:func:`float32_error_allowance`).
    """
    feeds = validation_probes(exportable.wavelength_range_nm)
    names = _input_names(exportable.is_spectral)
    inputs = [torch.from_numpy(feeds[name]) for name in names]
    with torch.no_grad():
        expected = exportable.module(*inputs).numpy().astype(np.float64)
    if not np.all(np.isfinite(expected)):
        raise ExportValidationError(f"the PyTorch model of {exportable.material!r} is not finite at some probe inputs")
    session = onnxruntime.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"])
    (got,) = session.run([OUTPUT_F], {name: feeds[name] for name in names})
    if got.shape != expected.shape:
        raise ExportValidationError(f"onnxruntime returns shape {list(got.shape)}, PyTorch {list(expected.shape)}")
    error = np.abs(got - expected)  # NaN where onnxruntime is not finite
    allowance = float32_error_allowance(exportable, inputs, expected)
    allowed = RELATIVE_TOLERANCE * np.abs(expected) + ABSOLUTE_FLOOR_SR + allowance
    relative = error / np.maximum(np.abs(expected), ABSOLUTE_FLOOR_SR)
    failing = ~(error <= allowed)
    if np.any(failing):
        badness = np.where(failing, np.nan_to_num(error / allowed, nan=np.inf), 0.0)
        worst = np.unravel_index(np.argmax(badness), error.shape)
        row = worst[0]
        raise ExportValidationError(
            f"onnxruntime differs from PyTorch by {error[worst]:.3g} sr^-1 ({relative[worst]:.3g} relative) at probe "
            f"{row} (wi={feeds[INPUT_WI][row].tolist()}, wo={feeds[INPUT_WO][row].tolist()}); allowed "
            f"{RELATIVE_TOLERANCE:g} relative + {ABSOLUTE_FLOOR_SR:g} sr^-1 + {allowance[worst]:.3g} sr^-1 "
            "(the model's own float32 rounding error there)"
        )
    return len(feeds[INPUT_WI]), float(error.max()), float(relative.max())


def write_model(exportable: Exportable, out: str | Path) -> ExportReport:
    """Trace, validate and atomically write ``exportable`` to ``out``; nothing is written on failure."""
    proto = trace(exportable)
    n_probes, max_abs, max_rel = validate(proto, exportable)
    out = Path(out)
    with atomic_path(out) as tmp:
        save_checked(proto, tmp, "the graph")
    return ExportReport(out, exportable.kind, exportable.material, n_probes, max_abs, max_rel)


def save_checked(proto: onnx.ModelProto, path: Path, what: str) -> None:
    """Save ``proto`` at ``path`` and run the contract check the renderer runs at scene load;
    :class:`ExportValidationError` naming ``what`` when the file fails it."""
    onnx.save(proto, str(path))
    try:
        load_model(path)
    except InputError as error:
        raise ExportValidationError(f"{what} fails the ONNX contract check: {error.reason}") from None


# --------------------------------------------------------------------------- fast paths


def _prefixed(graph: onnx.GraphProto, prefix: str, output: str) -> tuple[list, list]:
    """The nodes and initialisers of a traced ``graph`` with every internal name prefixed by
    ``prefix`` (the contract's inputs keep theirs) and its output ``f`` renamed ``output``."""
    shared = {INPUT_WI, INPUT_WO, INPUT_WAVELENGTH, ""}

    def name(tensor: str) -> str:
        if tensor == OUTPUT_F:
            return output
        return tensor if tensor in shared else prefix + tensor

    nodes = []
    for node in graph.node:
        renamed = onnx.NodeProto()
        renamed.CopyFrom(node)
        renamed.name = prefix + node.name
        renamed.input[:] = [name(i) for i in node.input]
        renamed.output[:] = [name(o) for o in node.output]
        nodes.append(renamed)
    initializers = []
    for init in graph.initializer:
        renamed = onnx.TensorProto()
        renamed.CopyFrom(init)
        renamed.name = name(init.name)
        initializers.append(renamed)
    return nodes, initializers


def with_fast_paths(proto: onnx.ModelProto, fast_paths: dict[str, onnx.ModelProto],
                    metadata: dict[str, str]) -> onnx.ModelProto:
    """``proto`` with each traced model of ``fast_paths`` (output name -> a graph of the contract,
    e.g. from :func:`trace`) added as a further output of that name (fast paths, docs/export-render.md#fast-paths), its
    tensors prefixed by the output's name; ``metadata`` entries are added to the file's.  The
    graphs share the inputs ``wi``, ``wo`` (and ``wavelength``); a fast path reads only those it
    needs.  :class:`ValueError` when ``proto`` already has an output of one of those names."""
    combined = onnx.ModelProto()
    combined.CopyFrom(proto)
    graph = combined.graph
    present = sorted({output.name for output in graph.output} & set(fast_paths))
    if present:
        raise ValueError(f"the model already has the fast path {present[0]!r}")
    opsets = {o.domain: o.version for o in proto.opset_import}
    for output, fast in fast_paths.items():
        if {o.domain: o.version for o in fast.opset_import}.get("", OPSET) != opsets.get("", OPSET):
            raise ValueError(f"the fast path {output!r} uses another opset than the model")
        nodes, initializers = _prefixed(fast.graph, f"{output}/", output)
        graph.node.extend(nodes)
        graph.initializer.extend(initializers)
        declared = onnx.ValueInfoProto()
        declared.CopyFrom(fast.graph.output[0])
        declared.name = output
        graph.output.append(declared)
    entries = {entry.key: entry.value for entry in proto.metadata_props}
    entries.update(metadata)
    helper.set_model_props(combined, entries)
    return combined


def export_checkpoint(ckpt: str | Path, out: str | Path, material: str | None = None) -> ExportReport:
    """Export checkpoint ``ckpt`` to the ``.onnx`` file ``out``; nothing is written on failure."""
    return write_model(load_exportable(ckpt, material), out)
