"""Split a spectral model's graph where the wavelength enters, for the onnxruntime backend.

Mitsuba asks a spectral BSDF for the ray's 4 wavelengths (or, in RGB variants, the sRGB rule's
few nodes) at the same direction pair.  The plugin's ``onnxruntime`` backend stacks the ``k``
wavelengths into one run of ``k · n`` rows, so the graph's direction features — the ``[N, 3]``
slices, sums and ``atan`` of the spectral MLP — were computed ``k`` times.
:func:`split_at_wavelength` cuts the graph in two ONNX models:

* the **direction part**: every node that depends on ``wi``/``wo`` but not on ``wavelength``
  (and the constant nodes it uses), from ``wi, wo [n, 3]`` to the *cut tensors* — its results
  that wavelength-dependent nodes read;
* the **wavelength part**: every node that depends on ``wavelength``, from the cut tensors
  (each repeated ``k`` times along the batch axis) and ``wavelength [k · n]`` to ``f``.

The two run the same operators on the same values as the whole graph; the backend uses the split
only if it reproduces the whole graph exactly on probe inputs, each cut tensor holding one row
per pair (:meth:`WavelengthSplit.agrees`).  A graph whose cut tensors are not per-sample
``[N, ...]`` tensors (a shape computed from the inputs, say) is not split.  What it saves:
``benchmarks/README.md``, design measurements.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import onnx
from onnx import helper, shape_inference

from neuralbrdf.onnx_contract import INPUT_WAVELENGTH, INPUT_WI, INPUT_WO, OUTPUT_F, input_dependencies


@dataclass(frozen=True)
class WavelengthSplit:
    """The direction part, the wavelength part and the names of the tensors passed between them."""

    directions: onnx.ModelProto
    wavelengths: onnx.ModelProto
    cut: tuple[str, ...]

    @staticmethod
    def repeat(values: np.ndarray, k: int) -> np.ndarray:
        """A cut tensor of ``n`` rows repeated ``k`` times along the batch axis (``k · n`` rows)."""
        return np.tile(values, (k,) + (1,) * (values.ndim - 1))

    def agrees(self, whole, directions, wavelengths, wi: np.ndarray, wo: np.ndarray, nm: np.ndarray) -> bool:
        """Whether the parts (onnxruntime sessions ``directions``, ``wavelengths``) reproduce the
        session ``whole`` exactly at the pairs ``wi, wo [n, 3]`` and the ``k`` wavelengths ``nm``,
        every cut tensor having one row per pair."""
        k, n = len(nm), len(wi)
        stacked = np.repeat(np.asarray(nm, dtype=np.float32), n)
        (expected,) = whole.run(
            [OUTPUT_F], {INPUT_WI: np.tile(wi, (k, 1)), INPUT_WO: np.tile(wo, (k, 1)), INPUT_WAVELENGTH: stacked}
        )
        cut = directions.run(list(self.cut), {INPUT_WI: wi, INPUT_WO: wo})
        if any(np.ndim(values) == 0 or len(values) != n for values in cut):
            return False
        feeds = {name: self.repeat(values, k) for name, values in zip(self.cut, cut)}
        (got,) = wavelengths.run([OUTPUT_F], {**feeds, INPUT_WAVELENGTH: stacked})
        return got.shape == expected.shape and bool(np.array_equal(got, expected, equal_nan=True))


def _part(name, nodes, constant_nodes, inputs, outputs, proto) -> onnx.ModelProto:
    """A model of ``nodes`` with the constants they read (constant nodes, initializers)."""
    read = {i for n in nodes for i in n.input}
    constants = [n for n in constant_nodes if set(n.output) & read]
    read |= {i for n in constants for i in n.input}
    initializers = [init for init in proto.graph.initializer if init.name in read]
    graph = helper.make_graph(constants + nodes, name, inputs, outputs, initializers)
    model = helper.make_model(graph, opset_imports=proto.opset_import)
    model.ir_version = proto.ir_version
    return model


def split_at_wavelength(proto: onnx.ModelProto) -> WavelengthSplit | None:
    """The split of a spectral model's graph (module docstring), or ``None`` where it does not
    apply: an RGB model, an output that does not depend on the wavelength, no direction work to
    share, a wavelength-dependent node reading ``wi`` or ``wo`` itself, or a cut tensor that is
    not a per-sample ``[N, ...]`` tensor."""
    graph = proto.graph
    inputs = {vi.name: vi for vi in graph.input}
    if INPUT_WAVELENGTH not in inputs or {INPUT_WI, INPUT_WO} - set(inputs):
        return None
    depends = input_dependencies(graph)
    if INPUT_WAVELENGTH not in depends[OUTPUT_F]:
        return None
    constant_nodes = [n for n in graph.node if not depends[n.output[0]]]
    direction_nodes = [n for n in graph.node if depends[n.output[0]] and INPUT_WAVELENGTH not in depends[n.output[0]]]
    wavelength_nodes = [n for n in graph.node if INPUT_WAVELENGTH in depends[n.output[0]]]
    produced = {o for n in direction_nodes for o in n.output}
    cut = list(dict.fromkeys(i for n in wavelength_nodes for i in n.input if i in produced))
    if not cut or any(i in (INPUT_WI, INPUT_WO) for n in wavelength_nodes for i in n.input):
        return None
    inferred = shape_inference.infer_shapes(proto)
    types = {vi.name: vi.type.tensor_type for vi in inferred.graph.value_info}
    cut_types = []
    for name in cut:
        tensor = types.get(name)
        if tensor is None or not tensor.elem_type:
            return None
        if tensor.HasField("shape") and (not tensor.shape.dim or tensor.shape.dim[0].HasField("dim_value")):
            return None  # a scalar or a tensor of fixed length (a shape, say): not per-sample rows
        cut_types.append(helper.make_tensor_value_info(name, tensor.elem_type, None))
    directions = _part(
        "directions", direction_nodes, constant_nodes, [inputs[INPUT_WI], inputs[INPUT_WO]], cut_types, proto
    )
    wavelengths = _part(
        "wavelengths", wavelength_nodes, constant_nodes, [*cut_types, inputs[INPUT_WAVELENGTH]], list(graph.output), proto
    )
    return WavelengthSplit(directions, wavelengths, tuple(cut))
