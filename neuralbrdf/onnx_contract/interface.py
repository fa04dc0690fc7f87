"""The graph's interface under the contract (:mod:`neuralbrdf.onnx_contract`): input and output names,
dtypes and shapes, the batch dimension dynamic (:func:`check_interface`)."""

from __future__ import annotations

from collections.abc import Sequence

import onnx

from neuralbrdf.errors import InputError
from neuralbrdf.onnx_contract.schema import (FAST_PATH_OUTPUTS, INPUT_WAVELENGTH, INPUT_WI, INPUT_WO, OUTPUT_F,
                                             OUTPUT_RGB)


def _dims(value_info) -> list[int | None] | None:
    """Static dims of a tensor value (``None`` for a dynamic one), or ``None`` without a shape."""
    tensor_type = value_info.type.tensor_type
    if not tensor_type.HasField("shape"):
        return None
    return [d.dim_value if d.HasField("dim_value") else None for d in tensor_type.shape.dim]


def _check_tensor(value_info, expected_dims: Sequence[int | None], role: str, path) -> None:
    """Check dtype float32 and the shape ``[N, *expected_dims[1:]]`` with ``N`` dynamic."""
    name = value_info.name
    elem_type = value_info.type.tensor_type.elem_type
    if elem_type != onnx.TensorProto.FLOAT:
        dtype = onnx.TensorProto.DataType.Name(elem_type) if elem_type else "no type"
        raise InputError(f"{role} {name!r} must be float32, found {dtype}", path=path)
    dims = _dims(value_info)
    expected = "[N" + "".join(f", {d}" for d in expected_dims[1:]) + "]"
    if dims is None:
        raise InputError(f"{role} {name!r} declares no shape; expected {expected}", path=path)
    if len(dims) != len(expected_dims):
        raise InputError(
            f"{role} {name!r} has rank {len(dims)}, expected {expected} (rank {len(expected_dims)})",
            path=path,
        )
    if dims[0] is not None:
        raise InputError(
            f"{role} {name!r} has a fixed batch size {dims[0]}; the first dimension must be "
            f"dynamic ({expected})",
            path=path,
        )
    # A symbolic inner dimension (torch exports some) is checked by the trial evaluation.
    for axis, (got, want) in enumerate(zip(dims[1:], expected_dims[1:]), start=1):
        if got is not None and got != want:
            raise InputError(
                f"{role} {name!r} has dimension {axis} = {got}, expected {expected}", path=path
            )


def check_interface(graph: onnx.GraphProto, path) -> bool:
    """Validate the inputs and output; return whether the model is spectral."""
    initializer_names = {init.name for init in graph.initializer}
    inputs = {vi.name: vi for vi in graph.input if vi.name not in initializer_names}
    names = sorted(inputs)
    allowed = ({INPUT_WI, INPUT_WO}, {INPUT_WI, INPUT_WO, INPUT_WAVELENGTH})
    if set(names) not in allowed:
        raise InputError(
            f"graph inputs are {names}; expected ['wi', 'wo'] (RGB models) or "
            "['wavelength', 'wi', 'wo'] (spectral models)",
            path=path,
        )
    is_spectral = INPUT_WAVELENGTH in inputs
    _check_tensor(inputs[INPUT_WI], (None, 3), "input", path)
    _check_tensor(inputs[INPUT_WO], (None, 3), "input", path)
    if is_spectral:
        _check_tensor(inputs[INPUT_WAVELENGTH], (None,), "input", path)

    outputs = [vi.name for vi in graph.output]
    if (not outputs or outputs[0] != OUTPUT_F or len(set(outputs)) != len(outputs)
            or any(name not in FAST_PATH_OUTPUTS for name in outputs[1:])):
        raise InputError(f"graph outputs are {outputs}; expected ['f'], optionally followed by fast paths "
                         f"{list(FAST_PATH_OUTPUTS)}", path=path)
    expected = (None,) if is_spectral else (None, 3)
    _check_tensor(graph.output[0], expected, "output", path)
    for value_info in graph.output[1:]:
        if value_info.name == OUTPUT_RGB and not is_spectral:
            raise InputError(f"output {OUTPUT_RGB!r} is the linear sRGB of a spectral model; this model is RGB "
                             "(no 'wavelength' input)", path=path)
        _check_tensor(value_info, (None, 3) if value_info.name == OUTPUT_RGB else expected, "output", path)
    return is_spectral
