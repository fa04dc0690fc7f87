"""The graph's weights under the contract (:mod:`neuralbrdf.onnx_contract`), checked without running
anything: one self-contained file within the size limits (:func:`check_tensor_sizes`,
:func:`check_constant_shapes`), finite constants (:func:`check_finite_constants`), and what an
unrolled evaluation costs (:func:`matrix_multiply_adds`)."""

from __future__ import annotations

import math

import numpy as np
import onnx
from onnx import numpy_helper

from neuralbrdf.errors import InputError
from neuralbrdf.limits import MAX_ONNX_WEIGHT_ELEMENTS


def _tensor_protos(graph: onnx.GraphProto):
    """``(name, TensorProto)`` of every initialiser and tensor attribute, subgraphs included."""
    for init in graph.initializer:
        yield init.name, init
    for node in graph.node:
        for attribute in node.attribute:
            name = f"{node.name or node.op_type}.{attribute.name}"
            if attribute.type == onnx.AttributeProto.TENSOR:
                yield name, attribute.t
            elif attribute.type == onnx.AttributeProto.TENSORS:
                for k, tensor in enumerate(attribute.tensors):
                    yield f"{name}[{k}]", tensor
            elif attribute.type == onnx.AttributeProto.GRAPH:
                yield from _tensor_protos(attribute.g)
            elif attribute.type == onnx.AttributeProto.GRAPHS:
                for subgraph in attribute.graphs:
                    yield from _tensor_protos(subgraph)


def check_tensor_sizes(graph: onnx.GraphProto, path) -> None:
    """Refuse external data and declared sizes above the limit, before any tensor is read."""
    total = 0
    for name, tensor in _tensor_protos(graph):
        if tensor.data_location == onnx.TensorProto.EXTERNAL or tensor.external_data:
            location = next((entry.value for entry in tensor.external_data if entry.key == "location"), "?")
            raise InputError(
                f"weight tensor {name!r} keeps its data in an external file ({location!r}); a model must be "
                "one self-contained file (docs/formats.md#onnx-model-files)",
                path=path,
            )
        if any(d < 0 for d in tensor.dims):
            raise InputError(f"weight tensor {name!r} has a negative dimension {list(tensor.dims)}", path=path)
        total += math.prod(tensor.dims)
        if total > MAX_ONNX_WEIGHT_ELEMENTS:
            raise InputError(
                f"weight tensors declare more than {MAX_ONNX_WEIGHT_ELEMENTS} elements (limit "
                f"neuralbrdf.limits.MAX_ONNX_WEIGHT_ELEMENTS; {name!r} has shape {list(tensor.dims)})",
                path=path,
            )


#: Operators that create a tensor of a size given by a shape input (input index): a constant
#: shape is bounded like the weights, before onnxruntime folds or runs it.
_SIZED_BY_INPUT = {"ConstantOfShape": 0, "Expand": 1, "Tile": 1}


def check_constant_shapes(graph: onnx.GraphProto, path) -> None:
    constants = {init.name: init for init in graph.initializer}
    for node in graph.node:
        if node.op_type == "Constant":
            for attribute in node.attribute:
                if attribute.type == onnx.AttributeProto.TENSOR:
                    constants[node.output[0]] = attribute.t
    for node in graph.node:
        index = _SIZED_BY_INPUT.get(node.op_type)
        if index is None or len(node.input) <= index or node.input[index] not in constants:
            continue
        shape = numpy_helper.to_array(constants[node.input[index]])
        if shape.dtype.kind not in "iu":
            continue
        elements = math.prod(int(d) for d in shape.ravel() if d > 0)
        if elements > MAX_ONNX_WEIGHT_ELEMENTS:
            raise InputError(
                f"{node.op_type} node {node.name or node.output[0]!r} creates a tensor of {elements} elements "
                f"(shape {shape.tolist()}), above the limit of {MAX_ONNX_WEIGHT_ELEMENTS} "
                "(neuralbrdf.limits.MAX_ONNX_WEIGHT_ELEMENTS)",
                path=path,
            )


def _constant_tensors(graph: onnx.GraphProto):
    """``(name, array)`` of every initialiser and ``Constant`` node value, subgraphs included."""
    for init in graph.initializer:
        yield init.name, numpy_helper.to_array(init)
    for node in graph.node:
        for attribute in node.attribute:
            name = f"{node.name or node.op_type}.{attribute.name}"
            if attribute.type == onnx.AttributeProto.TENSOR:
                yield name, numpy_helper.to_array(attribute.t)
            elif attribute.type == onnx.AttributeProto.FLOAT:
                yield name, np.asarray([attribute.f])
            elif attribute.type == onnx.AttributeProto.FLOATS:
                yield name, np.asarray(attribute.floats)
            elif attribute.type == onnx.AttributeProto.GRAPH:
                yield from _constant_tensors(attribute.g)


def matrix_multiply_adds(proto: onnx.ModelProto) -> int:
    """Non-zero constant weights of the graph's ``MatMul``/``Gemm`` nodes: the multiply-adds one
    evaluation costs when unrolled (what the ``drjit`` backend compiles), counted without
    running anything."""
    constants = {init.name: init for init in proto.graph.initializer}
    for node in proto.graph.node:
        if node.op_type == "Constant":
            for attribute in node.attribute:
                if attribute.type == onnx.AttributeProto.TENSOR:
                    constants[node.output[0]] = attribute.t
    total = 0
    for node in proto.graph.node:
        if node.op_type in ("MatMul", "Gemm"):
            for name in node.input[:2]:
                if name in constants:
                    total += int(np.count_nonzero(numpy_helper.to_array(constants[name])))
    return total


def check_finite_constants(graph: onnx.GraphProto, path) -> None:
    try:
        constants = list(_constant_tensors(graph))
    except Exception as error:  # numpy_helper: data length inconsistent with the declared shape
        raise InputError(f"malformed weight tensor ({type(error).__name__}: {error})", path=path) from None
    for name, array in constants:
        if np.issubdtype(array.dtype, np.floating) and not np.all(np.isfinite(array)):
            bad = int(np.size(array) - np.count_nonzero(np.isfinite(array)))
            raise InputError(
                f"weight tensor {name!r} holds {bad} non-finite value(s) (NaN or inf)", path=path
            )
