"""Evaluate an ONNX BRDF graph as Dr.Jit arithmetic, so that it fuses into the render kernel.

This is the ``drjit`` backend of the Mitsuba plugin (docs/mitsuba-plugin.md): the weights are read out of the
same ``.onnx`` file that onnxruntime runs and the graph is *interpreted* node by node in
topological order, each operation issuing Dr.Jit operations.  Dr.Jit records them into its trace,
so the network becomes part of the one kernel that traces rays, in Mitsuba's default symbolic
mode as well as in wavefront mode.

Representation
--------------
Every graph tensor has a leading batch axis of dynamic size ``N`` (one entry per ray) or is a
constant:

* a **per-sample tensor** ``[N, *inner]`` is a NumPy *object* array of shape ``inner`` whose cells
  are Dr.Jit arrays of width ``N`` (one "column" each) or Python scalars (a column that is the same
  for every sample, e.g. a baked latent code or ``zeros_like``);
* a **constant** (initialiser, ``Constant`` node, shape computation) is an ordinary NumPy array,
  and operations on constants only are folded with NumPy.

Matrix products are unrolled with the weights baked in as literals, ``y_j = b_j + Σ_i x_i W_ij``
(``dr.fma``, zero weights skipped; constant columns fold into the bias), so the kernel holds one
multiply-add per non-zero weight.  This suits the project's compact networks; a paper-size NLB
(~1 M weights) would produce a kernel too large to compile quickly — use the onnxruntime
backend for those (:attr:`DrJitGraph.multiply_adds` reports the size).

**Interpreted once.**  The interpretation runs once, at construction, on placeholder columns;
every column operation it issues goes through :func:`~neuralbrdf.render.drjit_program.apply` and
is recorded into one straight-line Python function (:mod:`~neuralbrdf.render.drjit_program`),
which each call replays: the same Dr.Jit operations in the same order (the same kernel), without
the NumPy bookkeeping of the interpretation (``benchmarks/README.md``, design measurements).
Mitsuba traces a BSDF again in every render pass, so this is paid per pass, not per sample.  An operator therefore computes on columns only through
:func:`_map_cells` or :func:`~neuralbrdf.render.drjit_program.apply`; a Dr.Jit function called
directly on a placeholder raises ``TypeError`` when the graph is loaded.

Shape computations that torch's exporter emits (``Shape`` → ``Gather`` → ``Concat`` →
``Expand``/``ConstantOfShape``/``Reshape``) are folded with the batch size represented by the
marker :data:`SYMBOLIC_BATCH`; arithmetic on the batch size itself is not supported.

Supported operators (default ONNX domain): MatMul, Gemm, Add, Sub, Mul, Div, Neg, Reciprocal,
Relu, LeakyRelu, Tanh, Sigmoid, Softplus, Exp, Log, Sqrt, Abs, Pow (constant exponent), Max,
Min, Clip, Where, Greater, Less, GreaterOrEqual, LessOrEqual, Equal, And, Or, Not, Concat,
Slice, Gather, Split (constant indices, not along the batch axis), Unsqueeze, Squeeze, Reshape,
Flatten (keeping the batch axis first), Expand, Shape, ConstantOfShape, Identity, Cast (float and
bool), Constant, Acos, Asin, Atan, Cos, Sin, Floor, ReduceSum, ReduceMean, ReduceL2 (not over the batch
axis).  Table lookups (:mod:`neuralbrdf.models.baked_table`): a per-sample float tensor ``Cast`` to
INT32/INT64 becomes index columns, and ``Gather`` of a constant ``[K]`` or ``[K, C]`` table at
per-sample indices ``[N]`` is one ``dr.gather`` per column from a buffer uploaded once.  Anything else is an :class:`~neuralbrdf.errors.InputError` at construction, naming the
operator and the node; so are shape errors, found by a trial evaluation on one sample.

Elementwise semantics follow onnxruntime's CPU kernels where they differ from the textbook
formula (``Softplus`` and ``Sigmoid`` in their overflow-safe forms).  ``Tanh`` is the 13/6-degree
rational interpolant on [-9, 9] that onnxruntime's MLAS library (``MlasComputeTanh``) and Eigen
(``generic_fast_tanh_float``) evaluate — a few float32 ulp from tanh and cheaper inside a
kernel than Dr.Jit's ``dr.tanh`` (``benchmarks/README.md``, design measurements), which matters because the spectral MLP's 30 activations are
most of its cost.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import drjit as dr
import numpy as np
import onnx
from onnx import helper, numpy_helper

from neuralbrdf.errors import InputError
from neuralbrdf.onnx_contract import (
    INPUT_WAVELENGTH,
    INPUT_WI,
    INPUT_WO,
    OUTPUT_F,
    OnnxModel,
)
from neuralbrdf.render.drjit_program import Recording, apply

#: Stands for the dynamic batch size ``N`` inside folded shape tensors (a prime no real
#: dimension reaches).
SYMBOLIC_BATCH = 2**31 - 1

#: Largest static dimension a folded shape may hold; bigger values mean arithmetic was done on
#: :data:`SYMBOLIC_BATCH`.
_MAX_STATIC_DIM = 2**24

#: Directions (and wavelength, nm) of the trial evaluation run at construction.
_TRIAL_INPUTS = {
    INPUT_WI: (0.3, 0.4, math.sqrt(0.75)),
    INPUT_WO: (-0.5, 0.1, math.sqrt(0.74)),
    INPUT_WAVELENGTH: 550.0,
}


class _NodeError(Exception):
    """A node cannot be interpreted; becomes an :class:`InputError` naming the node."""


class _Batch:
    """A per-sample tensor ``[N, *inner]``: object array of columns, see the module docstring."""

    __slots__ = ("cells", "is_bool")

    def __init__(self, cells: np.ndarray, is_bool: bool = False) -> None:
        self.cells = cells
        self.is_bool = is_bool

    @property
    def rank(self) -> int:
        return 1 + self.cells.ndim


def _empty_cells(shape) -> np.ndarray:
    return np.empty(tuple(shape), dtype=object)


def _map_cells(fn: Callable, *arrays: np.ndarray) -> np.ndarray:
    """Apply ``fn`` cell by cell to object arrays of one shape (never lets NumPy see a column)."""
    out = _empty_cells(arrays[0].shape)
    for index in np.ndindex(out.shape):
        out[index] = apply(fn, *(a[index] for a in arrays))
    return out


def _constant_cells(array: np.ndarray) -> np.ndarray:
    """Object array of Python scalars from a NumPy array."""
    array = np.asarray(array)
    out = _empty_cells(array.shape)
    for index in np.ndindex(array.shape):
        out[index] = array[index].item()
    return out


def _is_batch(value) -> bool:
    return isinstance(value, _Batch)


def _require_const(value, what: str) -> np.ndarray:
    if value is None or _is_batch(value):
        raise _NodeError(f"{what} must be a constant (known when the graph is loaded)")
    return value


def _axes_list(value) -> list[int]:
    return [int(a) for a in np.asarray(value).reshape(-1)]


def _normalize_axis(axis: int, rank: int) -> int:
    if not -rank <= axis < rank:
        raise _NodeError(f"axis {axis} is out of range for rank {rank}")
    return axis % rank


def _batch_axes(axes: Sequence[int], rank: int, op: str) -> list[int]:
    """Axes of a per-sample tensor normalised to ``[1, rank)``; the batch axis is refused."""
    normalized = [_normalize_axis(a, rank) for a in axes]
    if 0 in normalized:
        raise _NodeError(f"{op} along the batch axis (axis 0) is not supported")
    return normalized


# --------------------------------------------------------------------------- elementwise


def _aligned_cells(value, inner_ndim: int) -> np.ndarray:
    """Cells of ``value`` aligned to per-sample tensors of ``inner_ndim`` inner axes."""
    if _is_batch(value):
        if value.cells.ndim != inner_ndim:
            raise _NodeError(
                f"per-sample tensors of ranks {value.rank} and {inner_ndim + 1} cannot be "
                "broadcast together (the batch axes would not line up)"
            )
        return value.cells
    array = np.asarray(value)
    if array.ndim > inner_ndim:
        leading = array.shape[: array.ndim - inner_ndim]
        if array.ndim > inner_ndim + 1 or any(d != 1 for d in leading):
            raise _NodeError(
                f"constant of shape {list(array.shape)} does not broadcast against a per-sample "
                f"tensor of rank {inner_ndim + 1} without changing the batch axis"
            )
        array = array.reshape(array.shape[array.ndim - inner_ndim :])
    return _constant_cells(array)


def _elementwise(operands, numpy_fn: Callable, cell_fn: Callable, result_bool: bool):
    """Broadcast ``operands`` (ONNX/NumPy rules) and apply the op: folded or per column."""
    if not any(_is_batch(v) for v in operands):
        return np.asarray(numpy_fn(*operands))
    inner_ndim = max(v.cells.ndim for v in operands if _is_batch(v))
    cells = [_aligned_cells(v, inner_ndim) for v in operands]
    try:
        cells = np.broadcast_arrays(*cells)
    except ValueError:
        shapes = [list(c.shape) for c in cells]
        raise _NodeError(f"inner shapes {shapes} do not broadcast") from None
    return _Batch(_map_cells(cell_fn, *cells), result_bool)


def _not(x):
    return (not x) if isinstance(x, (bool, np.bool_)) else ~x


def _truediv(a, b):
    """``a / b`` with IEEE semantics also for Python floats (the trial evaluation uses them)."""
    if isinstance(b, (int, float)) and b == 0 and isinstance(a, (int, float)):
        if a == 0 or math.isnan(a):
            return math.nan
        return math.copysign(math.inf, a) * math.copysign(1.0, b)
    return a / b


def _relu(x):
    return dr.maximum(x, 0.0)


#: Odd numerator (x¹ … x¹³) and even denominator (x⁰ … x⁶) coefficients of the rational tanh,
#: as in onnxruntime's ``MlasTanhConstants`` / Eigen's ``generic_fast_tanh_float``.
_TANH_NUMERATOR = (
    4.89352455891786e-03,
    6.37261928875436e-04,
    1.48572235717979e-05,
    5.12229709037114e-08,
    -8.60467152213735e-11,
    2.00018790482477e-13,
    -2.76076847742355e-16,
)
_TANH_DENOMINATOR = (
    4.89352518554385e-03,
    2.26843463243900e-03,
    1.18534705686654e-04,
    1.19825839466702e-06,
)
#: Beyond this |x|, tanh(x) is ±1 in float32.
_TANH_CLAMP = 9.0


class _Literals:
    """Constants (Python floats) and, per Dr.Jit array type, the same constants as literals of that
    type, made at the first call with it.  An operation given a literal array, not a float, skips
    the conversion at every trace: tracing is paid per render pass and a float argument costs ~50 %
    more per ``dr.fma`` (``benchmarks/README.md``, design measurements).  The kernel is the same."""

    __slots__ = ("values", "by_type")

    def __init__(self, values: Sequence[float]) -> None:
        self.values = tuple(values)
        self.by_type: dict[type, list[Any]] = {}

    def of(self, kind: type | None) -> Sequence[Any]:
        """The constants as literals of array type ``kind``; the floats themselves for ``None``."""
        if kind is None:
            return self.values
        if kind not in self.by_type:
            self.by_type[kind] = [kind(v) for v in self.values]
        return self.by_type[kind]


_TANH_NUMERATOR_LITERALS = _Literals(_TANH_NUMERATOR)
_TANH_DENOMINATOR_LITERALS = _Literals(_TANH_DENOMINATOR)


def _horner(x, coefficients: _Literals):
    """``Σ_k c_k x^k`` by Horner's rule (``dr.fma``; for arrays on literals of their type)."""
    terms = coefficients.of(None if isinstance(x, (int, float)) else type(x))
    result = terms[-1]
    for c in reversed(terms[:-1]):
        result = dr.fma(x, result, c)
    return result


def tanh(x):
    """Rational tanh (module docstring); ``x`` a Dr.Jit array or a Python float."""
    x = dr.clip(x, -_TANH_CLAMP, _TANH_CLAMP)
    x2 = x * x
    return x * _horner(x2, _TANH_NUMERATOR_LITERALS) / _horner(x2, _TANH_DENOMINATOR_LITERALS)


def _sigmoid(x):
    e = dr.exp(-dr.abs(x))
    return dr.select(x >= 0, 1.0 / (1.0 + e), e / (1.0 + e))


def _softplus(x):
    # max(x, 0) + log1p(exp(-|x|)), with Kahan's accurate log1p (Dr.Jit has none):
    # log1p(e) = e where 1 + e rounds to 1, else log(1 + e) · e / ((1 + e) - 1).
    e = dr.exp(-dr.abs(x))
    u = 1.0 + e
    return dr.maximum(x, 0.0) + dr.select(u == 1.0, e, dr.log(u) * e / (u - 1.0))


def _np_sigmoid(a):
    return 1.0 / (1.0 + np.exp(-a))


def _np_softplus(a):
    return np.logaddexp(0.0, a)


def _np_div(a, b):
    if np.issubdtype(np.result_type(a, b), np.integer):
        return np.trunc(np.divide(a, b)).astype(np.result_type(a, b))
    return np.divide(a, b)


_UNARY: dict[str, tuple[Callable, Callable]] = {
    "Neg": (np.negative, operator.neg),
    "Abs": (np.abs, dr.abs),
    "Relu": (lambda a: np.maximum(a, 0), _relu),
    "Sigmoid": (_np_sigmoid, _sigmoid),
    "Softplus": (_np_softplus, _softplus),
    "Tanh": (np.tanh, tanh),
    "Exp": (np.exp, dr.exp),
    "Log": (np.log, dr.log),
    "Sqrt": (np.sqrt, dr.sqrt),
    "Floor": (np.floor, lambda x: float(math.floor(x)) if isinstance(x, (int, float)) else dr.floor(x)),
    "Reciprocal": (np.reciprocal, lambda x: _truediv(1.0, x)),
    "Acos": (np.arccos, dr.acos),
    "Asin": (np.arcsin, dr.asin),
    "Atan": (np.arctan, dr.atan),
    "Cos": (np.cos, dr.cos),
    "Sin": (np.sin, dr.sin),
}

_BINARY: dict[str, tuple[Callable, Callable]] = {
    "Add": (np.add, operator.add),
    "Sub": (np.subtract, operator.sub),
    "Mul": (np.multiply, operator.mul),
    "Div": (_np_div, _truediv),
}

_COMPARE: dict[str, tuple[Callable, Callable]] = {
    "Greater": (np.greater, operator.gt),
    "Less": (np.less, operator.lt),
    "GreaterOrEqual": (np.greater_equal, operator.ge),
    "LessOrEqual": (np.less_equal, operator.le),
    "Equal": (np.equal, operator.eq),
    "And": (np.logical_and, operator.and_),
    "Or": (np.logical_or, operator.or_),
}

_VARIADIC: dict[str, tuple[Callable, Callable]] = {
    "Max": (np.maximum, dr.maximum),
    "Min": (np.minimum, dr.minimum),
}


def _unary(op):
    numpy_fn, cell_fn = _UNARY[op]
    return lambda ins, at, ctx: [_elementwise(ins[:1], numpy_fn, cell_fn, False)]


def _binary(op):
    numpy_fn, cell_fn = _BINARY[op]
    return lambda ins, at, ctx: [_elementwise(ins[:2], numpy_fn, cell_fn, False)]


def _compare(op):
    numpy_fn, cell_fn = _COMPARE[op]
    return lambda ins, at, ctx: [_elementwise(ins[:2], numpy_fn, cell_fn, True)]


def _variadic(op):
    numpy_fn, cell_fn = _VARIADIC[op]

    def run(ins, at, ctx):
        result = ins[0]
        for other in ins[1:]:
            result = _elementwise([result, other], numpy_fn, cell_fn, False)
        return [result]

    return run


def _op_not(ins, at, ctx):
    return [_elementwise(ins[:1], np.logical_not, _not, True)]


def _op_leaky_relu(ins, at, ctx):
    alpha = float(at.get("alpha", 0.01))
    return [
        _elementwise(
            ins[:1],
            lambda a: np.where(a >= 0, a, a * alpha),
            lambda x: dr.select(x >= 0, x, x * alpha),
            False,
        )
    ]


def _op_pow(ins, at, ctx):
    base, exponent = ins[0], ins[1]
    if _is_batch(exponent):
        raise _NodeError("Pow needs a constant exponent")
    return [_elementwise([base, exponent], np.power, dr.power, False)]


def _op_clip(ins, at, ctx):
    x = ins[0]
    low = ins[1] if len(ins) > 1 and ins[1] is not None else at.get("min")
    high = ins[2] if len(ins) > 2 and ins[2] is not None else at.get("max")
    if low is not None:
        x = _elementwise([x, _require_const(low, "Clip min")], np.maximum, dr.maximum, False)
    if high is not None:
        x = _elementwise([x, _require_const(high, "Clip max")], np.minimum, dr.minimum, False)
    return [x]


def _op_where(ins, at, ctx):
    cond, a, b = ins
    result_bool = a.is_bool if _is_batch(a) else np.asarray(a).dtype == np.bool_
    return [_elementwise([cond, a, b], np.where, dr.select, result_bool)]


def _cast_cell_to_float(x):
    return (1.0 if x else 0.0) if isinstance(x, (bool, np.bool_)) else dr.select(x, 1.0, 0.0)


def _op_cast(ins, at, ctx):
    x = ins[0]
    to = int(at["to"])
    if not _is_batch(x):
        return [np.asarray(x).astype(helper.tensor_dtype_to_np_dtype(to))]
    if to in (onnx.TensorProto.FLOAT, onnx.TensorProto.DOUBLE):
        if x.is_bool:
            return [_Batch(_map_cells(_cast_cell_to_float, x.cells), False)]
        return [x]
    if to == onnx.TensorProto.BOOL:
        if x.is_bool:
            return [x]
        return [_Batch(_map_cells(lambda c: c != 0, x.cells), True)]
    if to in _INDEX_TYPES and not x.is_bool:
        return [_Batch(_map_cells(_to_index, x.cells), False)]
    name = onnx.TensorProto.DataType.Name(to)
    raise _NodeError(f"Cast of a per-sample tensor to {name} is not supported (only FLOAT, BOOL and, for "
                     "Gather indices, INT32/INT64)")


#: Integer types a per-sample float tensor may be cast to: table indices, read by :func:`_op_gather`.
_INDEX_TYPES = (onnx.TensorProto.INT32, onnx.TensorProto.INT64)


def _to_index(x):
    """A float column as table indices (truncated toward zero, as ONNX ``Cast``): ``UInt32``
    columns (Dr.Jit's gather index type; the graphs that cast clamp their indices to >= 0)."""
    if isinstance(x, (int, float)):
        return int(x)
    return dr.uint32_array_t(type(x))(x)


# --------------------------------------------------------------------------- constants, shapes


def _op_constant(ins, at, ctx):
    for key in ("value", "value_float", "value_floats", "value_int", "value_ints"):
        if key in at:
            value = at[key]
            if key == "value":
                return [np.asarray(value)]
            dtype = np.float32 if "float" in key else np.int64
            return [np.asarray(value, dtype=dtype)]
    raise _NodeError(f"Constant with attributes {sorted(at)} is not supported")


def _op_identity(ins, at, ctx):
    return [ins[0]]


def _op_shape(ins, at, ctx):
    x = ins[0]
    dims = [SYMBOLIC_BATCH, *x.cells.shape] if _is_batch(x) else list(np.shape(x))
    start = int(at.get("start", 0))
    end = at.get("end")
    return [np.asarray(dims[start : None if end is None else int(end)], dtype=np.int64)]


def _shape_entries(shape, what: str, allow_negative: bool = False) -> list[int]:
    """Entries of a folded shape tensor, refusing arithmetic done on the batch size."""
    entries = _axes_list(_require_const(shape, what))
    for value in entries:
        low = -1 if allow_negative else 0
        if value != SYMBOLIC_BATCH and not low <= value < _MAX_STATIC_DIM:
            raise _NodeError(
                f"{what} {entries} holds {value}: arithmetic on the batch size is not supported"
            )
    return entries


def _split_batch_shape(entries: list[int], what: str) -> tuple[bool, list[int]]:
    """``(has_batch, rest)`` for a shape whose first entry may be the batch size."""
    if SYMBOLIC_BATCH in entries[1:]:
        raise _NodeError(f"{what} {entries} moves the batch axis away from axis 0")
    if entries and entries[0] == SYMBOLIC_BATCH:
        return True, entries[1:]
    return False, entries


def _op_constant_of_shape(ins, at, ctx):
    entries = _shape_entries(ins[0], "ConstantOfShape shape")
    value = np.asarray(at.get("value", np.zeros(1, dtype=np.float32))).reshape(-1)[0]
    has_batch, rest = _split_batch_shape(entries, "ConstantOfShape shape")
    if not has_batch:
        return [np.full(entries, value)]
    cells = _empty_cells(rest)
    cells.fill(value.item())
    return [_Batch(cells, bool(value.dtype == np.bool_))]


def _op_expand(ins, at, ctx):
    x = ins[0]
    entries = _shape_entries(ins[1], "Expand shape")
    has_batch, rest = _split_batch_shape(entries, "Expand shape")
    if not _is_batch(x) and not has_batch:
        array = np.asarray(x)
        return [np.broadcast_to(array, np.broadcast_shapes(array.shape, tuple(entries))).copy()]
    if not _is_batch(x):
        # A constant broadcast over the batch: its leading axis (if any) must be 1.
        array = np.asarray(x)
        if array.ndim > len(entries):
            raise _NodeError(f"Expand of shape {list(array.shape)} to {entries} moves the batch axis")
        cells = _aligned_cells(array, len(rest))
        cells = cells.reshape((1,) * (len(rest) - cells.ndim) + cells.shape)
        x = _Batch(cells, array.dtype == np.bool_)
    # ONNX aligns shapes to the right: a target as long as [N, *inner] names the batch axis first.
    if len(entries) > x.rank or (has_batch and len(entries) != x.rank):
        raise _NodeError(f"Expand to {entries} moves the batch axis of a rank-{x.rank} tensor")
    if len(entries) == x.rank:
        if entries[0] not in (1, SYMBOLIC_BATCH):
            raise _NodeError(f"Expand to {entries} fixes the batch size")
        entries = entries[1:]
    try:
        shape = np.broadcast_shapes(x.cells.shape, tuple(entries))
    except ValueError:
        raise _NodeError(f"cannot expand inner shape {list(x.cells.shape)} to {entries}") from None
    return [_Batch(np.broadcast_to(x.cells, shape).copy(), x.is_bool)]


def _op_reshape(ins, at, ctx):
    x = ins[0]
    entries = _shape_entries(ins[1], "Reshape shape", allow_negative=True)
    allow_zero = int(at.get("allowzero", 0))
    if not _is_batch(x):
        if SYMBOLIC_BATCH in entries:
            raise _NodeError("Reshape of a constant to the batch size is not supported")
        array = np.asarray(x)
        if not allow_zero:
            entries = [array.shape[i] if e == 0 else e for i, e in enumerate(entries)]
        return [array.reshape(entries)]
    full = [SYMBOLIC_BATCH, *x.cells.shape]
    if not allow_zero:
        entries = [full[i] if e == 0 and i < len(full) else e for i, e in enumerate(entries)]
    if not entries or entries[0] not in (SYMBOLIC_BATCH, -1):
        raise _NodeError(f"Reshape to {entries} does not keep the batch axis first")
    rest = entries[1:]
    if SYMBOLIC_BATCH in rest:
        raise _NodeError(f"Reshape to {entries} moves the batch axis")
    size = math.prod(x.cells.shape)
    if rest.count(-1) + (entries[0] == -1) > 1:
        raise _NodeError(f"Reshape to {entries} has more than one inferred dimension")
    if -1 in rest:
        known = math.prod(d for d in rest if d != -1)
        if known == 0 or size % known:
            raise _NodeError(f"cannot reshape inner shape {list(x.cells.shape)} to {entries}")
        rest = [size // known if d == -1 else d for d in rest]
    if math.prod(rest) != size:
        raise _NodeError(
            f"Reshape of inner shape {list(x.cells.shape)} to {entries} changes the batch size"
        )
    return [_Batch(x.cells.reshape(rest), x.is_bool)]


def _op_flatten(ins, at, ctx):
    x = ins[0]
    axis = int(at.get("axis", 1))
    if not _is_batch(x):
        array = np.asarray(x)
        axis = axis + array.ndim if axis < 0 else axis
        return [array.reshape(math.prod(array.shape[:axis]), math.prod(array.shape[axis:]))]
    axis = axis + x.rank if axis < 0 else axis
    if axis == 0 or math.prod(x.cells.shape[: axis - 1]) != 1:
        raise _NodeError(f"Flatten at axis {axis} merges the batch axis with others")
    return [_Batch(x.cells.reshape(math.prod(x.cells.shape[axis - 1 :])), x.is_bool)]


def _axes_input(ins, at, index: int) -> list[int] | None:
    """Axes from input ``index`` (opset >= 13) or the ``axes`` attribute (older opsets)."""
    if len(ins) > index and ins[index] is not None:
        return _axes_list(_require_const(ins[index], "axes"))
    if "axes" in at:
        return [int(a) for a in at["axes"]]
    return None


def _op_squeeze(ins, at, ctx):
    x = ins[0]
    axes = _axes_input(ins, at, 1)
    if not _is_batch(x):
        return [np.squeeze(np.asarray(x), axis=None if axes is None else tuple(axes))]
    if axes is None:
        axes = [i + 1 for i, d in enumerate(x.cells.shape) if d == 1]
    axes = _batch_axes(axes, x.rank, "Squeeze")
    if any(x.cells.shape[a - 1] != 1 for a in axes):
        raise _NodeError(f"Squeeze of axes {axes} that are not of size 1")
    return [_Batch(np.squeeze(x.cells, axis=tuple(a - 1 for a in axes)), x.is_bool)]


def _op_unsqueeze(ins, at, ctx):
    x = ins[0]
    axes = _axes_input(ins, at, 1)
    if axes is None:
        raise _NodeError("Unsqueeze without axes")
    if not _is_batch(x):
        array = np.asarray(x)
        out_rank = array.ndim + len(axes)
        return [np.expand_dims(array, tuple(_normalize_axis(a, out_rank) for a in axes))]
    axes = _batch_axes(axes, x.rank + len(axes), "Unsqueeze")
    return [_Batch(np.expand_dims(x.cells, tuple(a - 1 for a in axes)), x.is_bool)]


def _op_concat(ins, at, ctx):
    axis = int(at["axis"])
    if not any(_is_batch(v) for v in ins):
        return [np.concatenate([np.asarray(v) for v in ins], axis=axis)]
    if not all(_is_batch(v) for v in ins):
        raise _NodeError("Concat of per-sample tensors with constants (Expand the constants first)")
    ranks = {v.rank for v in ins}
    if len(ranks) != 1:
        raise _NodeError(f"Concat of tensors of ranks {sorted(ranks)}")
    axis = _batch_axes([axis], ranks.pop(), "Concat")[0]
    try:
        cells = np.concatenate([v.cells for v in ins], axis=axis - 1)
    except ValueError as error:
        raise _NodeError(f"Concat: {error}") from None
    return [_Batch(cells, all(v.is_bool for v in ins))]


def _slice_params(ins, at):
    if len(ins) > 1:
        starts = _axes_list(_require_const(ins[1], "Slice starts"))
        ends = _axes_list(_require_const(ins[2], "Slice ends"))
        axes = _axes_list(ins[3]) if len(ins) > 3 and ins[3] is not None else None
        steps = _axes_list(ins[4]) if len(ins) > 4 and ins[4] is not None else None
    else:
        starts, ends = list(at["starts"]), list(at["ends"])
        axes = list(at["axes"]) if "axes" in at else None
        steps = None
    axes = list(range(len(starts))) if axes is None else axes
    steps = [1] * len(starts) if steps is None else steps
    return starts, ends, axes, steps


def _op_slice(ins, at, ctx):
    x = ins[0]
    starts, ends, axes, steps = _slice_params(ins, at)
    rank = x.rank if _is_batch(x) else np.ndim(x)
    index = [slice(None)] * rank
    for start, end, axis, step in zip(starts, ends, axes, steps):
        axis = _normalize_axis(axis, rank)
        if _is_batch(x) and axis == 0:
            if start != 0 or step != 1 or end < SYMBOLIC_BATCH:
                raise _NodeError("Slice along the batch axis (axis 0) is not supported")
            continue
        index[axis] = slice(start, end, step)
    if not _is_batch(x):
        return [np.asarray(x)[tuple(index)]]
    return [_Batch(x.cells[tuple(index[1:])], x.is_bool)]


class _TableColumn:
    """One column of a constant table read with per-sample indices; its Dr.Jit array is made once
    per array type (uploaded once per scene load, not per trace)."""

    __slots__ = ("values", "arrays")

    def __init__(self, values: np.ndarray) -> None:
        self.values = np.ascontiguousarray(values, dtype=np.float32)
        self.arrays: dict[type, Any] = {}

    def array(self, float_type: type):
        if float_type not in self.arrays:
            self.arrays[float_type] = float_type(self.values)
        return self.arrays[float_type]


def _read_table(column: _TableColumn, index):
    if isinstance(index, int):
        return float(column.values[index])
    float_type = dr.float32_array_t(type(index))
    return dr.gather(float_type, column.array(float_type), index)


def _op_gather_per_sample(table, indices: _Batch, axis: int, ctx: _RunContext):
    """``Gather`` of a constant ``table`` ``[K, *inner]`` along axis 0 at per-sample indices ``[N]``:
    one Dr.Jit gather per inner column."""
    table = np.asarray(table)
    if axis != 0 or indices.cells.ndim != 0 or table.ndim not in (1, 2) or indices.is_bool:
        raise _NodeError("Gather with per-sample indices reads a constant [K] or [K, C] table along axis 0 "
                         f"at indices [N]; got a table of shape {list(table.shape)}, axis {axis}, indices of "
                         f"rank {indices.rank}")
    columns = [table] if table.ndim == 1 else [table[:, j] for j in range(table.shape[1])]
    cells = _empty_cells(() if table.ndim == 1 else (table.shape[1],))
    for j, column in enumerate(columns):
        # one buffer per table column, however many nodes read it (a table's 2^D corners)
        key = (id(table), j)
        if key not in ctx.tables:
            ctx.tables[key] = _TableColumn(column)
        cells[() if table.ndim == 1 else j] = apply(_read_table, ctx.tables[key], indices.cells[()])
    return [_Batch(cells, False)]


def _op_gather(ins, at, ctx):
    x = ins[0]
    if _is_batch(ins[1]) and not _is_batch(x):
        return _op_gather_per_sample(x, ins[1], int(at.get("axis", 0)), ctx)
    indices = _require_const(ins[1], "Gather indices").astype(np.int64)
    axis = int(at.get("axis", 0))
    if not _is_batch(x):
        return [np.take(np.asarray(x), indices, axis=axis)]
    axis = _batch_axes([axis], x.rank, "Gather")[0]
    try:
        cells = np.take(x.cells, indices, axis=axis - 1)
    except IndexError as error:
        raise _NodeError(f"Gather: {error}") from None
    # Taking one cell of a 1-D array returns the column itself, not an array.
    return [_Batch(cells if isinstance(cells, np.ndarray) else _scalar_cells(cells), x.is_bool)]


def _scalar_cells(cell) -> np.ndarray:
    cells = _empty_cells(())
    cells[()] = cell
    return cells


def _op_split(ins, at, ctx):
    x = ins[0]
    axis = int(at.get("axis", 0))
    if len(ins) > 1 and ins[1] is not None:
        sizes = _axes_list(_require_const(ins[1], "Split sizes"))
    elif "split" in at:
        sizes = [int(s) for s in at["split"]]
    else:
        sizes = None
    n_out = len(ctx.node.output)
    if not _is_batch(x):
        array = np.asarray(x)
        sizes = sizes or [array.shape[axis] // n_out] * n_out
        return np.split(array, np.cumsum(sizes)[:-1], axis=axis)
    axis = _batch_axes([axis], x.rank, "Split")[0]
    length = x.cells.shape[axis - 1]
    if sizes is None:
        chunk = -(-length // n_out)
        sizes = [min(chunk, length - i * chunk) for i in range(n_out)]
    if sum(sizes) != length:
        raise _NodeError(f"Split sizes {sizes} do not add up to {length}")
    parts = np.split(x.cells, np.cumsum(sizes)[:-1], axis=axis - 1)
    return [_Batch(p, x.is_bool) for p in parts]


# --------------------------------------------------------------------------- reductions, products


def _op_reduce(kind: str):
    def run(ins, at, ctx):
        x = ins[0]
        axes = _axes_input(ins, at, 1)
        keepdims = bool(int(at.get("keepdims", 1)))
        if not axes:
            if int(at.get("noop_with_empty_axes", 0)):
                return [x]
            axes = None
        if not _is_batch(x):
            array = np.asarray(x)
            axis = None if axes is None else tuple(axes)
            if kind == "ReduceL2":
                return [np.sqrt(np.sum(array * array, axis=axis, keepdims=keepdims))]
            reduce = np.mean if kind == "ReduceMean" else np.sum
            return [reduce(array, axis=axis, keepdims=keepdims)]
        if axes is None:
            raise _NodeError(f"{kind} over all axes would sum over the batch")
        axes = sorted(set(_batch_axes(axes, x.rank, kind)))
        inner_axes = [a - 1 for a in axes]
        kept = [a for a in range(x.cells.ndim) if a not in inner_axes]
        moved = np.transpose(x.cells, kept + inner_axes)
        count = math.prod(x.cells.shape[a] for a in inner_axes)
        flat = moved.reshape(*moved.shape[: len(kept)], count)
        out = _empty_cells(flat.shape[:-1])
        for index in np.ndindex(out.shape):
            terms = flat[index]
            out[index] = apply(_reduce_cells(kind, count), *terms)
        if keepdims:
            out = np.expand_dims(out, tuple(inner_axes))
        return [_Batch(out, False)]

    return run


def _reduce_cells(kind: str, count: int) -> Callable:
    """The reduction of ``count`` columns, as one operation on them."""

    def run(*terms):
        if kind == "ReduceL2":
            total = terms[0] * terms[0]
            for t in terms[1:]:
                total = dr.fma(t, t, total)
            return dr.sqrt(total)
        total = terms[0]
        for t in terms[1:]:
            total = total + t
        return _truediv(total, count) if kind == "ReduceMean" else total

    return run


def _affine(bias: float, weights: Sequence[float]) -> Callable:
    """``bias + Σ_i x_i w_i`` as one operation on the columns ``x_i``: ``dr.fma`` per column in
    order (on literals of the columns' array type, :class:`_Literals`), Python arithmetic where a
    column is a Python float."""
    constants = _Literals((bias, *weights))

    def run(*columns):
        kind = next((type(x) for x in columns if not isinstance(x, (int, float))), None)
        acc, *terms = constants.of(kind)
        for x, w, term in zip(columns, weights, terms):
            acc = acc + x * w if isinstance(x, (int, float)) else dr.fma(x, term, acc)
        return acc

    return run


def _linear(columns: np.ndarray, weights: np.ndarray, bias: np.ndarray | None, ctx) -> np.ndarray:
    """``y_j = b_j + Σ_i x_i W_ij`` over the last inner axis, weights baked in as literals."""
    k, m = weights.shape
    if columns.shape[-1] != k:
        raise _NodeError(
            f"inner dimension {columns.shape[-1]} does not match weights of shape {[k, m]}"
        )
    out = _empty_cells((*columns.shape[:-1], m))
    for lead in np.ndindex(columns.shape[:-1]):
        x = columns[lead]
        for j in range(m):
            terms = [i for i in range(k) if weights[i, j] != 0.0]
            ctx.multiply_adds += len(terms)
            row = _affine(0.0 if bias is None else float(bias[j]), [float(weights[i, j]) for i in terms])
            out[(*lead, j)] = apply(row, *(x[i] for i in terms))
    return out


def _op_matmul(ins, at, ctx):
    a, b = ins
    if not _is_batch(a) and not _is_batch(b):
        return [np.matmul(a, b)]
    if _is_batch(b) or np.ndim(b) not in (1, 2):
        raise _NodeError(
            "MatMul needs a per-sample left operand and a constant 1-D or 2-D right operand"
        )
    b = np.asarray(b, dtype=np.float64)
    if b.ndim == 1:
        return [_Batch(_linear(a.cells, b[:, None], None, ctx)[..., 0], False)]
    return [_Batch(_linear(a.cells, b, None, ctx), False)]


def _op_gemm(ins, at, ctx):
    a, b = ins[0], ins[1]
    c = ins[2] if len(ins) > 2 else None
    alpha = float(at.get("alpha", 1.0))
    beta = float(at.get("beta", 1.0))
    trans_a, trans_b = int(at.get("transA", 0)), int(at.get("transB", 0))
    if not _is_batch(a) and not _is_batch(b) and not _is_batch(c):
        a = np.asarray(a).T if trans_a else np.asarray(a)
        b = np.asarray(b).T if trans_b else np.asarray(b)
        return [alpha * (a @ b) + (0.0 if c is None else beta * np.asarray(c))]
    if not _is_batch(a) or trans_a or a.rank != 2 or _is_batch(b) or _is_batch(c):
        raise _NodeError("Gemm needs a per-sample [N, K] A (transA = 0) and constant B and C")
    weights = np.asarray(b, dtype=np.float64)
    weights = alpha * (weights.T if trans_b else weights)
    bias = None
    if c is not None:
        c = np.asarray(c, dtype=np.float64)
        if c.ndim == 2 and c.shape[0] != 1:
            raise _NodeError(f"Gemm bias of shape {list(c.shape)} varies along the batch axis")
        bias = beta * np.broadcast_to(c.reshape(-1) if c.ndim else c, (weights.shape[1],))
    return [_Batch(_linear(a.cells, weights, bias, ctx), False)]


_OPS: dict[str, Callable] = {
    **{op: _unary(op) for op in _UNARY},
    **{op: _binary(op) for op in _BINARY},
    **{op: _compare(op) for op in _COMPARE},
    **{op: _variadic(op) for op in _VARIADIC},
    "Not": _op_not,
    "LeakyRelu": _op_leaky_relu,
    "Pow": _op_pow,
    "Clip": _op_clip,
    "Where": _op_where,
    "Cast": _op_cast,
    "Constant": _op_constant,
    "Identity": _op_identity,
    "Shape": _op_shape,
    "ConstantOfShape": _op_constant_of_shape,
    "Expand": _op_expand,
    "Reshape": _op_reshape,
    "Flatten": _op_flatten,
    "Squeeze": _op_squeeze,
    "Unsqueeze": _op_unsqueeze,
    "Concat": _op_concat,
    "Slice": _op_slice,
    "Gather": _op_gather,
    "Split": _op_split,
    "ReduceSum": _op_reduce("ReduceSum"),
    "ReduceMean": _op_reduce("ReduceMean"),
    "ReduceL2": _op_reduce("ReduceL2"),
    "MatMul": _op_matmul,
    "Gemm": _op_gemm,
}

#: Operator types the interpreter accepts (default ONNX domain).
SUPPORTED_OPS = frozenset(_OPS)


# --------------------------------------------------------------------------- the graph


class _RunContext:
    __slots__ = ("node", "multiply_adds", "tables")

    def __init__(self) -> None:
        self.node = None
        self.multiply_adds = 0
        self.tables: dict[tuple[int, int], _TableColumn] = {}  # (id of a constant table, column)


def _attributes(node: onnx.NodeProto) -> dict[str, Any]:
    values = {}
    for attribute in node.attribute:
        value = helper.get_attribute_value(attribute)
        if isinstance(value, onnx.TensorProto):
            value = numpy_helper.to_array(value)
        values[attribute.name] = value
    return values


def _node_label(node: onnx.NodeProto, index: int) -> str:
    return f"node {node.name!r} ({node.op_type})" if node.name else f"node #{index} ({node.op_type})"


def _topological_order(graph: onnx.GraphProto, available: set[str], source) -> list[int]:
    """Indices of ``graph.node`` so that every node comes after the producers of its inputs."""
    producers = {name: i for i, node in enumerate(graph.node) for name in node.output}
    order, state = [], {}

    def visit(i: int) -> None:
        if state.get(i) == "done":
            return
        if state.get(i) == "active":
            raise InputError(f"graph has a cycle through {_node_label(graph.node[i], i)}", path=source)
        state[i] = "active"
        for name in graph.node[i].input:
            if name and name not in available:
                if name not in producers:
                    raise InputError(
                        f"{_node_label(graph.node[i], i)} reads {name!r}, which nothing produces",
                        path=source,
                    )
                visit(producers[name])
        state[i] = "done"
        order.append(i)

    for i in range(len(graph.node)):
        visit(i)
    return order


class DrJitGraph:
    """An ONNX BRDF graph compiled for evaluation with Dr.Jit arrays (see the module docstring).

    Parameters
    ----------
    proto:
        The model; the contract of docs/formats.md#onnx-model-files is assumed
        (:func:`~neuralbrdf.onnx_contract.load_generic_model` checks it).
    source:
        File name used in error messages.

    Attributes
    ----------
    multiply_adds:
        Non-zero weights of the matrix products, i.e. multiply-adds per evaluation at most
        (columns that are the same for every sample, such as a baked latent, fold into the bias).

    Raises
    ------
    InputError
        For an unsupported operator, a node the interpreter cannot map onto per-sample columns,
        or a graph whose trial evaluation is not finite; the message names the node.
    """

    def __init__(self, proto: onnx.ModelProto, source: str | Path = "<model>") -> None:
        self.source = str(source)
        graph = proto.graph
        self._constants = {init.name: numpy_helper.to_array(init) for init in graph.initializer}
        self.input_names = tuple(vi.name for vi in graph.input if vi.name not in self._constants)
        self.output_name = graph.output[0].name
        for i, node in enumerate(graph.node):
            if node.domain not in ("", "ai.onnx") or node.op_type not in _OPS:
                domain = f" of domain {node.domain!r}" if node.domain not in ("", "ai.onnx") else ""
                raise InputError(
                    f"unsupported ONNX operator {node.op_type!r}{domain} in {_node_label(node, i)}; "
                    f"the drjit backend supports {', '.join(sorted(SUPPORTED_OPS))} "
                    "(use backend 'onnxruntime' for other graphs)",
                    path=self.source,
                )
        available = set(self._constants) | set(self.input_names)
        order = _topological_order(graph, available, self.source)
        self._nodes = [(graph.node[i], i, _attributes(graph.node[i])) for i in order]
        self._program = self._record()
        trial = self._program(*self._input_columns({name: _TRIAL_INPUTS[name] for name in self.input_names}))
        if not all(math.isfinite(float(v)) for v in trial):
            raise InputError(
                f"the graph evaluates to {[float(v) for v in trial]} at a regular direction pair; "
                "expected finite BRDF values",
                path=self.source,
            )

    @classmethod
    def from_model(cls, model: OnnxModel) -> DrJitGraph:
        """Compile a validated model file."""
        return cls(model.proto, model.path)

    def __call__(self, wi: Sequence[Any], wo: Sequence[Any], wavelength: Any = None) -> list[Any]:
        """``f`` columns (3 for RGB models, 1 for spectral ones) for direction columns ``wi, wo``.

        ``wi`` and ``wo`` are sequences of three Dr.Jit arrays (x, y, z; e.g. a ``Vector3f``),
        ``wavelength`` a Dr.Jit array in nm for spectral models.  Columns that the graph does not
        make depend on its inputs come back as Python floats.
        """
        inputs = {INPUT_WI: wi, INPUT_WO: wo}
        if INPUT_WAVELENGTH in self.input_names:
            if wavelength is None:
                raise ValueError(f"{self.source}: this spectral model needs wavelengths")
            inputs[INPUT_WAVELENGTH] = wavelength
        return self._program(*self._input_columns(inputs))

    def at_wavelengths(self, wi: Sequence[Any], wo: Sequence[Any], wavelengths: Sequence[Any]) -> list[Any]:
        """``f`` of a spectral model at each of ``wavelengths`` (Dr.Jit arrays or floats, nm): one
        column per wavelength, as ``[self(wi, wo, w)[0] for w in wavelengths]`` with the
        instructions that depend on the directions alone issued once
        (:meth:`~neuralbrdf.render.drjit_program.Recording.compile`, ``varying``)."""
        if INPUT_WAVELENGTH not in self.input_names:
            raise ValueError(f"{self.source}: an RGB model has no wavelength input")
        count = len(wavelengths)
        if count not in self._programs_at:
            recording, inputs, outputs = self._recorded
            self._programs_at[count] = recording.compile(inputs, outputs, inputs[-1], count)
        return self._programs_at[count](*wi, *wo, *wavelengths)

    def _input_columns(self, inputs: Mapping[str, Any]) -> list[Any]:
        """The input columns in the program's order: ``wi`` x, y, z, ``wo`` x, y, z, wavelength."""
        columns = [*inputs[INPUT_WI], *inputs[INPUT_WO]]
        if len(columns) != 6:
            raise ValueError(f"{self.source}: wi and wo need three columns each")
        if INPUT_WAVELENGTH in self.input_names:
            columns.append(inputs[INPUT_WAVELENGTH])
        return columns

    def _record(self) -> Callable[..., list[Any]]:
        """Interpret the graph once on placeholder columns and compile the column operations it
        issues into a straight-line function (:mod:`~neuralbrdf.render.drjit_program`)."""
        recording = Recording()
        inputs = {name: [recording.new_register() for _ in range(3)] for name in (INPUT_WI, INPUT_WO)}
        if INPUT_WAVELENGTH in self.input_names:
            inputs[INPUT_WAVELENGTH] = recording.new_register()
        outputs = self._run(inputs)
        self._recorded = (recording, self._input_columns(inputs), outputs)
        self._programs_at: dict[int, Callable[..., list[Any]]] = {}
        return recording.compile(self._input_columns(inputs), outputs)

    def _run(self, inputs: Mapping[str, Any]) -> list[Any]:
        """Interpret the graph node by node on input columns (values or registers)."""
        values: dict[str, Any] = dict(self._constants)
        for name, columns in inputs.items():
            if name in (INPUT_WI, INPUT_WO):
                cells = _empty_cells((3,))
                for k in range(3):
                    cells[k] = columns[k]
            else:
                cells = _scalar_cells(columns)
            values[name] = _Batch(cells)
        ctx = _RunContext()
        for node, index, attributes in self._nodes:
            ctx.node = node
            args = [values[name] if name else None for name in node.input]
            try:
                outputs = _OPS[node.op_type](args, attributes, ctx)
            except _NodeError as error:
                raise InputError(f"{_node_label(node, index)}: {error}", path=self.source) from None
            for name, value in zip(node.output, outputs):
                if name:
                    values[name] = value
        self.multiply_adds = ctx.multiply_adds
        return self._output_columns(values[self.output_name])

    def _output_columns(self, value) -> list[Any]:
        expected = (3,) if INPUT_WAVELENGTH not in self.input_names else ()
        if _is_batch(value):
            cells, is_bool = value.cells, value.is_bool
        else:
            array = np.asarray(value)
            cells, is_bool = _aligned_cells(array, len(expected)), array.dtype == np.bool_
        if cells.shape != expected or is_bool:
            raise InputError(
                f"output {OUTPUT_F!r} evaluates to per-sample shape {list(cells.shape)}"
                f"{' of booleans' if is_bool else ''}; expected {list(expected)} floats",
                path=self.source,
            )
        return [cells[index] for index in np.ndindex(cells.shape)]
