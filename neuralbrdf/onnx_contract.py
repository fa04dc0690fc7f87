"""The ONNX file contract between exported models and the renderers (docs/formats.md#onnx-model-files).

Every trained model (spectral MLP, NLB, ABC) exports to one self-contained ``.onnx`` file that
:func:`neuralbrdf.kinds.load_model` validates at scene load, so that a bad file fails with one clear
:class:`~neuralbrdf.errors.InputError` naming the file and what is wrong, never mid-render.

Graph interface
---------------
* inputs ``wi`` and ``wo``: ``float32 [N, 3]``, unit vectors in the local shading frame (``z`` the
  normal), both pointing away from the surface (docs/formats.md#conventions); spectral models add ``wavelength``:
  ``float32 [N]`` in nm.  ``N`` is dynamic (a named or unnamed dimension, never a number).
* output ``f``: ``float32 [N, 3]`` (RGB models, linear sRGB) or ``float32 [N]`` (spectral
  models), in sr⁻¹, without the cosine factor, and 0 when either direction is below the horizon.
* everything needed to evaluate is inside the graph (input normalisation, in-plane mapping,
  baked latent, output activation); initialisers must be finite.
* optional **fast paths**, further outputs that stand in for ``f`` at a fraction of its cost
  (docs/select.md), each under the same rules as ``f`` (shape, finite, >= 0, 0 below the horizon):
  ``f_rgb`` ``float32 [N, 3]`` (spectral models only; computed from ``wi`` and ``wo`` alone): the
  model's linear sRGB as the renderer integrates it in RGB variants (docs/formats.md#spectral-to-linear-srgb), evaluated once per
  query; ``f_fast``: a cheaper copy of ``f`` (same inputs, same shape).  Each is described by
  metadata entries ``neuralbrdf.<output>.*`` (:data:`FAST_PATH_KEYS`, :func:`fast_path_key`):
  what it approximates, its error against ``f`` and its relative cost.  :func:`output_model`
  cuts one output out of the graph, as a model whose only output is ``f``.

Metadata (``ModelProto.metadata_props``, all values strings)
------------------------------------------------------------
=================================  ===========================================================
key                                value
=================================  ===========================================================
``neuralbrdf.kind``                a registered kind (:mod:`neuralbrdf.kinds`): ``spectral_mlp``,
                                   ``nlb``, ``abc``, ``reference`` (a truth), ...
``neuralbrdf.format_version``      ``1`` (:data:`FORMAT_VERSION`)
``neuralbrdf.material``            material name, non-empty
``neuralbrdf.provenance``          short free text: config, data plan, training run
``neuralbrdf.wavelength_min``      spectral models only: lowest valid wavelength, nm
``neuralbrdf.wavelength_max``      spectral models only: highest valid wavelength, nm (> min)
``neuralbrdf.<kind>.*``            keys of one kind, read and checked by that kind's module
                                   (e.g. the ABC parameters of :mod:`neuralbrdf.kinds.abc`)
``neuralbrdf.<output>.*``          one fast path's entries (``f_rgb``, ``f_fast``): ``approximates``
                                   (free text), ``hemisphere_logcos_rmse`` (error against ``f``,
                                   its linear sRGB for ``f_rgb``; >= 0), ``relative_cost``
                                   (Dr.Jit cost per query over ``f``'s; > 0); optionally
                                   ``image_delta_e2000_mean`` (mean CIEDE2000 of a render through
                                   it against one of ``f`` on the same paths; >= 0) and
                                   ``image_check`` (free text: that render's scene and settings)
=================================  ===========================================================

Spectral models are those with a ``wavelength`` input.  Exporters build the metadata with
:func:`neuralbrdf.kinds.contract_metadata` (this module's :func:`generic_metadata` plus the kind's
checks), which writes exactly what :func:`neuralbrdf.kinds.load_model` reads.

This module checks the part of the contract every kind shares (:func:`load_generic_model`,
:func:`generic_metadata`) and never imports Mitsuba, Dr.Jit or PyTorch.
:func:`neuralbrdf.kinds.load_model` adds the checks of the file's kind (its name registered, its
own keys, spectral where the kind requires it); renderers and evaluators open models through that.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
import onnxruntime
from onnx import numpy_helper

from neuralbrdf.atomic import note_input
from neuralbrdf.errors import InputError
from neuralbrdf.limits import MAX_ONNX_BYTES, MAX_ONNX_WEIGHT_ELEMENTS, check_file_size, file_problem

#: Version of this contract written to and required in ``neuralbrdf.format_version``.
FORMAT_VERSION = "1"

KIND_KEY = "neuralbrdf.kind"
FORMAT_VERSION_KEY = "neuralbrdf.format_version"
MATERIAL_KEY = "neuralbrdf.material"
PROVENANCE_KEY = "neuralbrdf.provenance"
WAVELENGTH_MIN_KEY = "neuralbrdf.wavelength_min"
WAVELENGTH_MAX_KEY = "neuralbrdf.wavelength_max"
REQUIRED_KEYS = (KIND_KEY, FORMAT_VERSION_KEY, MATERIAL_KEY, PROVENANCE_KEY)



def kind_key(kind: str, name: str) -> str:
    """The metadata key ``neuralbrdf.<kind>.<name>`` of a kind's own entry."""
    return f"neuralbrdf.{kind}.{name}"


INPUT_WI = "wi"
INPUT_WO = "wo"
INPUT_WAVELENGTH = "wavelength"
OUTPUT_F = "f"
#: The fast paths (module docstring): a spectral model's linear sRGB, once per query ...
OUTPUT_RGB = "f_rgb"
#: ... and a cheaper copy of ``f``.
OUTPUT_FAST = "f_fast"
FAST_PATH_OUTPUTS = (OUTPUT_RGB, OUTPUT_FAST)
#: Metadata namespaces ``neuralbrdf.<name>.*`` any kind may carry besides its own and its fast
#: paths' (``ladder``: a rung's parent, error and cost, :mod:`neuralbrdf.lod.ladder`).
SHARED_NAMESPACES = ("ladder",)
#: Metadata fields of a fast path, ``neuralbrdf.<output>.<field>`` (:func:`fast_path_key`).
FAST_PATH_KEYS = ("approximates", "hemisphere_logcos_rmse", "relative_cost")
#: Optional metadata fields of a fast path: its image error against ``f`` and where it was measured.
FAST_PATH_IMAGE_KEYS = ("image_delta_e2000_mean", "image_check")


def fast_path_key(output: str, field: str) -> str:
    """The metadata key ``neuralbrdf.<output>.<field>`` of a fast path's entry."""
    return f"neuralbrdf.{output}.{field}"


@dataclass(frozen=True)
class FastPath:
    """A fast-path output of a model file and what its metadata says about it."""

    output: str
    approximates: str
    hemisphere_logcos_rmse: float
    relative_cost: float
    #: Mean CIEDE2000 of a render through the fast path against ``f`` (``None``: not measured) ...
    image_delta_e2000_mean: float | None = None
    #: ... in this render (scene, variant, size, samples).
    image_check: str | None = None

    def describe(self) -> str:
        image = ("" if self.image_delta_e2000_mean is None else
                 f", image ΔE2000 {self.image_delta_e2000_mean:.2g} against f ({self.image_check})")
        return (f"{self.output}: {self.approximates} (log-cos RMSE {self.hemisphere_logcos_rmse:.2g} against "
                f"{'the sRGB integral of f' if self.output == OUTPUT_RGB else 'f'}, cost {self.relative_cost:.2f} of f"
                f"{image})")


@dataclass(frozen=True)
class OnnxModel:
    """A validated model file.

    Attributes
    ----------
    path:
        The ``.onnx`` file.
    kind:
        The ``neuralbrdf.kind`` metadata value (checked against the registry by
        :func:`neuralbrdf.kinds.load_model`).
    is_spectral:
        ``True`` when the graph takes ``wavelength`` and returns ``f`` of shape ``[N]``.
    wavelength_range_nm:
        ``(min, max)`` valid wavelengths in nm for spectral models, else ``None``.
    material, provenance:
        The metadata strings of the same names.
    metadata:
        Every ``metadata_props`` entry.
    proto:
        The loaded ``onnx.ModelProto``.
    details:
        What the kind's module read from its own metadata keys (e.g. the ABC parameters), set
        by :func:`neuralbrdf.kinds.load_model`; ``None`` here.
    sha256:
        SHA-256 (hex) of the bytes the model was read from.
    version:
        The file as it was read (:func:`~neuralbrdf.atomic.file_version` of the open file): a cache
        key for everything derived from this model, which a file written later at the same path
        (another inode, size or time) never shares.  The file is read once; the proto, the digest
        and this key all describe the same bytes.
    fast_paths:
        The file's fast-path outputs by name (module docstring), checked like ``f``.
    """

    path: Path
    kind: str
    is_spectral: bool
    wavelength_range_nm: tuple[float, float] | None
    material: str
    provenance: str
    metadata: dict[str, str]
    proto: onnx.ModelProto
    details: object | None = None
    sha256: str = ""
    version: tuple = ()
    fast_paths: Mapping[str, FastPath] = dataclasses.field(default_factory=dict)

    @property
    def n_channels(self) -> int:
        """3 for RGB models, 1 for spectral ones (one value per wavelength)."""
        return 1 if self.is_spectral else 3

    def output_view(self, output: str = OUTPUT_F) -> OnnxModel:
        """This model with ``output`` as its only output ``f`` (:func:`output_model`): what a renderer
        evaluates to use a fast path (``f_rgb`` is an RGB model), or ``f`` without the fast paths."""
        if output != OUTPUT_F and output not in self.fast_paths:
            raise InputError(f"the model has no output {output!r}; it has {[OUTPUT_F, *self.fast_paths]}",
                             path=self.path)
        if output == OUTPUT_F and not self.fast_paths:
            return self
        rgb = output == OUTPUT_RGB
        return dataclasses.replace(
            self, proto=output_model(self.proto, output), fast_paths={},
            is_spectral=self.is_spectral and not rgb, wavelength_range_nm=None if rgb else self.wavelength_range_nm)


def generic_metadata(
    kind: str,
    material: str,
    provenance: str,
    *,
    wavelength_range_nm: tuple[float, float] | None = None,
    kind_metadata: Mapping[str, str] | None = None,
) -> dict[str, str]:
    """The ``metadata_props`` entries every kind shares, validated like :func:`load_generic_model` does.

    ``kind_metadata`` holds the kind's own entries; their keys must start with
    ``neuralbrdf.<kind>.`` (:func:`kind_key`).
    """
    metadata = {
        KIND_KEY: kind,
        FORMAT_VERSION_KEY: FORMAT_VERSION,
        MATERIAL_KEY: material,
        PROVENANCE_KEY: provenance,
    }
    if wavelength_range_nm is not None:
        metadata[WAVELENGTH_MIN_KEY] = repr(float(wavelength_range_nm[0]))
        metadata[WAVELENGTH_MAX_KEY] = repr(float(wavelength_range_nm[1]))
    for key, value in (kind_metadata or {}).items():
        if not key.startswith(kind_key(kind, "")):
            raise InputError(f"a {kind} model's own metadata keys start with {kind_key(kind, '')!r}", key=key)
        metadata[key] = str(value)
    _check_metadata(metadata, "<metadata>", is_spectral=wavelength_range_nm is not None)
    return metadata


def load_generic_model(path: str | os.PathLike[str]) -> OnnxModel:
    """Load ``path`` and check it against the contract of docs/formats.md#onnx-model-files (see the module docstring).

    Raises :class:`InputError` naming the file for a missing or unreadable file, a file that is
    not ONNX or fails the ONNX checker, wrong input or output names, dtypes or ranks, a fixed
    batch size, missing or malformed metadata, non-finite initialisers or constants, and a graph
    that onnxruntime cannot run or whose trial evaluation breaks the output contract (shape,
    zero below the horizon; :func:`probe_directions`) or that is negative or not finite anywhere on
    the dense stratified probe of :func:`dense_probe` (near-mirror and grazing pairs included).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(file_problem(path) or "no such ONNX model file", path=path)
    note_input(path)
    check_file_size(path, MAX_ONNX_BYTES, "ONNX model file")
    try:
        with open(path, "rb") as handle:  # read once: every check and use below sees these bytes
            info = os.fstat(handle.fileno())
            data = handle.read(MAX_ONNX_BYTES + 1)
    except OSError as error:
        raise InputError(f"cannot read the model file ({error.strerror or error})", path=path) from None
    if len(data) > MAX_ONNX_BYTES:
        raise InputError(f"ONNX model file larger than the limit of {MAX_ONNX_BYTES} bytes", path=path)
    try:
        # External data (weights in other files) is never followed: the contract is one file.
        proto = onnx.load_model_from_string(data)
    except Exception as error:  # onnx raises protobuf DecodeError, ...
        raise InputError(f"not an ONNX model ({type(error).__name__}: {error})", path=path) from None
    if not proto.graph.node and not proto.graph.output:
        raise InputError("not an ONNX model (no graph)", path=path)
    _check_tensor_sizes(proto.graph, path)
    try:
        onnx.checker.check_model(proto)
    except onnx.checker.ValidationError as error:
        raise InputError(f"invalid ONNX graph: {error}", path=path) from None
    except UnicodeDecodeError:  # the checker's message quotes a name that is not UTF-8 (found by fuzzing)
        raise InputError("invalid ONNX graph: a name or string in it is not UTF-8 text", path=path) from None

    is_spectral = _check_interface(proto.graph, path)
    metadata = {entry.key: entry.value for entry in proto.metadata_props}
    kind, wavelength_range = _check_metadata(metadata, path, is_spectral)
    fast_paths = _fast_paths(metadata, [vi.name for vi in proto.graph.output[1:]], path)
    _check_finite_constants(proto.graph, path)
    _check_constant_shapes(proto.graph, path)
    _check_trial_evaluation(proto if not fast_paths else output_model(proto, OUTPUT_F), path, wavelength_range)
    for output in fast_paths:
        _check_fast_path(proto, output, path, wavelength_range)
    return OnnxModel(
        path=path,
        kind=kind,
        is_spectral=is_spectral,
        wavelength_range_nm=wavelength_range,
        material=metadata[MATERIAL_KEY],
        provenance=metadata[PROVENANCE_KEY],
        metadata=metadata,
        proto=proto,
        sha256=hashlib.sha256(data).hexdigest(),
        version=(str(path.resolve()), info.st_size, info.st_mtime_ns, info.st_ino),
        fast_paths=fast_paths,
    )


# --------------------------------------------------------------------------- interface


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


def _check_interface(graph: onnx.GraphProto, path) -> bool:
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


# --------------------------------------------------------------------------- metadata


def metadata_float(metadata: Mapping[str, str], key: str, path) -> float:
    """The finite number stored under ``key``, else :class:`InputError` naming the file and key."""
    text = metadata[key]
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"metadata value {text!r} is not a number", path=path, key=key) from None
    if not math.isfinite(value):
        raise InputError(f"metadata value {text!r} is not finite", path=path, key=key)
    return value


def metadata_float_list(metadata: Mapping[str, str], key: str, path) -> tuple[float, ...]:
    """The non-empty JSON list of finite numbers >= 0 under ``key``, else :class:`InputError`."""
    text = metadata[key]
    try:
        values = json.loads(text)
    except json.JSONDecodeError:
        raise InputError(f"metadata value {text!r} is not JSON", path=path, key=key) from None
    if (
        not isinstance(values, list)
        or not values
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
    ):
        raise InputError(
            f"metadata value {text!r} must be a non-empty JSON list of numbers", path=path, key=key
        )
    values = tuple(float(v) for v in values)
    if not all(math.isfinite(v) and v >= 0.0 for v in values):
        raise InputError(f"metadata value {text!r} must be finite and >= 0", path=path, key=key)
    return values


def _fast_paths(metadata: Mapping[str, str], outputs: Sequence[str], path) -> dict[str, FastPath]:
    """The fast paths of the graph's extra ``outputs`` from their metadata entries (module
    docstring), checked; an entry for an output the graph lacks is an error too."""
    described = {key.split(".")[1] for key in metadata
                 if key.startswith("neuralbrdf.") and key.count(".") == 2 and key.split(".")[1] in FAST_PATH_OUTPUTS}
    orphans = sorted(described - set(outputs))
    if orphans:
        raise InputError(f"metadata describes the fast path {orphans[0]!r}, which the graph does not output",
                         path=path, key=fast_path_key(orphans[0], FAST_PATH_KEYS[0]))
    found = {}
    for output in outputs:
        missing = [fast_path_key(output, field) for field in FAST_PATH_KEYS if fast_path_key(output, field) not in metadata]
        if missing:
            raise InputError(f"the fast path {output!r} lacks its metadata entry", path=path, key=missing[0])
        error = metadata_float(metadata, fast_path_key(output, "hemisphere_logcos_rmse"), path)
        cost = metadata_float(metadata, fast_path_key(output, "relative_cost"), path)
        for field, value, ok, rule in (("hemisphere_logcos_rmse", error, error >= 0, ">= 0"),
                                       ("relative_cost", cost, cost > 0, "> 0")):
            if not ok:
                raise InputError(f"metadata value {value!r} must be {rule}", path=path, key=fast_path_key(output, field))
        image_key = fast_path_key(output, FAST_PATH_IMAGE_KEYS[0])
        image = metadata_float(metadata, image_key, path) if image_key in metadata else None
        if image is not None and not image >= 0:
            raise InputError(f"metadata value {image!r} must be >= 0", path=path, key=image_key)
        found[output] = FastPath(output, metadata[fast_path_key(output, "approximates")], error, cost, image,
                                 metadata.get(fast_path_key(output, FAST_PATH_IMAGE_KEYS[1])))
    return found


def _check_metadata(metadata: Mapping[str, str], path, is_spectral: bool):
    """Return ``(kind, wavelength_range_nm)`` or raise :class:`InputError`."""
    missing = [key for key in REQUIRED_KEYS if key not in metadata]
    if missing:
        raise InputError(f"missing metadata keys {missing} (docs/formats.md#onnx-model-files)", path=path)
    kind = metadata[KIND_KEY]
    if not kind.isidentifier():
        raise InputError(f"model kind {kind!r} is not a name (letters, digits, '_')", path=path, key=KIND_KEY)
    version = metadata[FORMAT_VERSION_KEY]
    if version != FORMAT_VERSION:
        raise InputError(
            f"format version {version!r} is not supported (this library reads {FORMAT_VERSION!r})",
            path=path,
            key=FORMAT_VERSION_KEY,
        )
    if not metadata[MATERIAL_KEY].strip():
        raise InputError("material name is empty", path=path, key=MATERIAL_KEY)
    foreign = sorted(key for key in metadata if key.startswith("neuralbrdf.") and key.count(".") >= 2
                     and key.split(".")[1] not in (kind, *FAST_PATH_OUTPUTS, *SHARED_NAMESPACES))
    if foreign:  # e.g. a fitted model whose kind was edited to 'reference': its own keys say what it is
        raise InputError(f"metadata key {foreign[0]!r} belongs to kind {foreign[0].split('.')[1]!r}, but the file "
                         f"declares kind {kind!r}", path=path, key=KIND_KEY)
    wavelength_keys = [k for k in (WAVELENGTH_MIN_KEY, WAVELENGTH_MAX_KEY) if k in metadata]
    wavelength_range = None
    if is_spectral:
        missing = [k for k in (WAVELENGTH_MIN_KEY, WAVELENGTH_MAX_KEY) if k not in metadata]
        if missing:
            raise InputError(f"spectral model lacks metadata keys {missing}", path=path)
        low = metadata_float(metadata, WAVELENGTH_MIN_KEY, path)
        high = metadata_float(metadata, WAVELENGTH_MAX_KEY, path)
        if not 0.0 < low < high:
            raise InputError(
                f"wavelength range {low:g}..{high:g} nm is empty or not positive",
                path=path,
                key=WAVELENGTH_MAX_KEY,
            )
        wavelength_range = (low, high)
    elif wavelength_keys:
        raise InputError(
            f"RGB model (no 'wavelength' input) carries spectral metadata {wavelength_keys}",
            path=path,
        )
    return kind, wavelength_range


# --------------------------------------------------------------------------- weights


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


def _check_tensor_sizes(graph: onnx.GraphProto, path) -> None:
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


def _check_constant_shapes(graph: onnx.GraphProto, path) -> None:
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


def _check_finite_constants(graph: onnx.GraphProto, path) -> None:
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


# --------------------------------------------------------------------------- trial evaluation


def probe_directions(n_above: int = 64, n_below: int = 16, seed: int = 0):
    """Deterministic probe pairs ``(wi, wo, below)``: ``n_above`` pairs with both directions
    above the horizon, then ``n_below`` pairs with one of them below (``below`` marks those)."""
    rng = np.random.default_rng(seed)
    n = n_above + n_below
    wi = rng.normal(size=(n, 3))
    wo = rng.normal(size=(n, 3))
    wi[:, 2] = np.abs(wi[:, 2]) + 0.05
    wo[:, 2] = np.abs(wo[:, 2]) + 0.05
    below = np.arange(n) >= n_above
    flip_wi = below & (np.arange(n) % 2 == 0)
    wi[flip_wi, 2] *= -1.0
    wo[below & ~flip_wi, 2] *= -1.0
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    return wi.astype(np.float32), wo.astype(np.float32), below


#: Dense load-time probe (:func:`dense_probe`): strata of the incident polar angle ...
PROBE_THETA_I_STRATA = 18
#: ... and, per incident stratum, of the outgoing polar angle × azimuth.
PROBE_OUT_STRATA = (18, 36)
#: Incident angles (one per degree, 0°–89°) probed at and around their mirror direction ...
PROBE_MIRROR_THETA_I = 90
#: ... at these angular offsets from the mirror (degrees) ...
PROBE_MIRROR_OFFSETS_DEG = (0.0, 0.01, 0.1, 0.3, 1.0, 3.0)
#: ... in this many azimuths around it.
PROBE_MIRROR_AZIMUTHS = 8
#: Grazing probe: both polar angles in [85°, 89.99°], strata per angle and of the azimuth.
PROBE_GRAZING_STRATA = (8, 8, 16)
#: Wavelengths (spread over a spectral model's range, both ends included) of the dense probe.
PROBE_WAVELENGTHS = 8


def _stratified(rng, low: float, high: float, count: int) -> np.ndarray:
    """One jittered sample in each of ``count`` equal strata of [low, high]."""
    edges = np.linspace(low, high, count + 1)
    return edges[:-1] + rng.uniform(0.0, 1.0, count) * np.diff(edges)


def _rotated(theta_deg, phi_deg, azimuth_deg) -> np.ndarray:
    from neuralbrdf.geometry import spherical_to_vector

    return spherical_to_vector(np.asarray(theta_deg, dtype=np.float64), np.asarray(phi_deg) + azimuth_deg)


def dense_probe(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Direction pairs ``(wi, wo, near_mirror)`` (float32 ``[M, 3]``, bool ``[M]``) of the load-time
    sign and finiteness check, all above the horizon (about 16 000 pairs):

    * a stratified hemisphere: :data:`PROBE_THETA_I_STRATA` strata of ``θi`` in [0°, 89.9°], each
      with :data:`PROBE_OUT_STRATA` strata of ``θo`` × ``φo``, jittered, the whole pair rotated
      by a random azimuth (isotropy is not assumed);
    * near-mirror pairs, where glossy models peak and fits overshoot: ``θi`` = 0.5°, 1.5°, …,
      89.5° with ``wo`` the mirror direction tilted by each of :data:`PROBE_MIRROR_OFFSETS_DEG`
      in :data:`PROBE_MIRROR_AZIMUTHS` directions (kept when above the horizon);
    * grazing pairs: both polar angles in [85°, 89.99°] (:data:`PROBE_GRAZING_STRATA`).
    """
    rng = np.random.default_rng(seed)
    wi, wo = [], []
    n_theta, n_phi = PROBE_OUT_STRATA
    for theta_i in _stratified(rng, 0.0, 89.9, PROBE_THETA_I_STRATA):
        theta_o = np.repeat(_stratified(rng, 0.0, 89.9, n_theta), n_phi)
        phi_o = np.tile(_stratified(rng, 0.0, 360.0, n_phi), n_theta)
        azimuth = rng.uniform(0.0, 360.0)
        wo.append(_rotated(theta_o, phi_o, azimuth))
        wi.append(np.repeat(_rotated(theta_i, 0.0, azimuth)[None], len(theta_o), axis=0))
    n_hemisphere = sum(len(w) for w in wi)
    theta_i = np.arange(PROBE_MIRROR_THETA_I) + 0.5
    offsets = np.asarray(PROBE_MIRROR_OFFSETS_DEG)
    around = np.arange(PROBE_MIRROR_AZIMUTHS) * 360.0 / PROBE_MIRROR_AZIMUTHS
    ti, offset, turn = (a.ravel() for a in np.meshgrid(theta_i, offsets, around, indexing="ij"))
    keep = (offset > 0) | (turn == 0)  # the exact mirror once per angle
    ti, offset, turn = ti[keep], offset[keep], turn[keep]
    # The mirror of (θi, 0°) is (θi, 180°); tilt it by ``offset`` towards azimuth ``turn`` about itself.
    mirror = _rotated(ti, 180.0, 0.0)
    tangent_a = np.stack([-np.cos(np.radians(ti)), np.zeros_like(ti), -np.sin(np.radians(ti))], axis=1)
    tangent_b = np.stack([np.zeros_like(ti), np.ones_like(ti), np.zeros_like(ti)], axis=1)
    tilt, spin = np.radians(offset)[:, None], np.radians(turn)[:, None]
    out = np.cos(tilt) * mirror + np.sin(tilt) * (np.cos(spin) * tangent_a + np.sin(spin) * tangent_b)
    above = out[:, 2] > 1e-6
    wi.append(_rotated(ti[above], 0.0, 0.0))
    wo.append(out[above])
    n_mirror = int(above.sum())
    n_t, _, n_p = PROBE_GRAZING_STRATA
    grazing_i = _stratified(rng, 85.0, 89.99, n_t)
    grazing_o = _stratified(rng, 85.0, 89.99, n_t)
    gi, go, gp = (a.ravel() for a in np.meshgrid(grazing_i, grazing_o, _stratified(rng, 0.0, 360.0, n_p), indexing="ij"))
    wi.append(_rotated(gi, 0.0, 0.0))
    wo.append(_rotated(go, gp, 0.0))
    wi, wo = np.concatenate(wi), np.concatenate(wo)
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    near_mirror = np.zeros(len(wi), dtype=bool)
    near_mirror[n_hemisphere : n_hemisphere + n_mirror] = True
    return wi.astype(np.float32), wo.astype(np.float32), near_mirror


def _check_dense_probe(session, path, wavelength_range) -> None:
    """Sign and finiteness of ``f`` over :func:`dense_probe` (every wavelength of
    :data:`PROBE_WAVELENGTHS` for spectral models); the first offending pair is named."""
    wi, wo, near_mirror = dense_probe()
    wavelengths = [None] if wavelength_range is None else np.linspace(*wavelength_range, PROBE_WAVELENGTHS)
    for wavelength in wavelengths:
        feeds = {INPUT_WI: wi, INPUT_WO: wo}
        if wavelength is not None:
            feeds[INPUT_WAVELENGTH] = np.full(len(wi), wavelength, dtype=np.float32)
        try:
            (f,) = session.run([OUTPUT_F], feeds)
        except Exception as error:
            raise InputError(f"onnxruntime fails to evaluate the graph: {error}", path=path) from None
        values = f.reshape(len(wi), -1)
        bad = ~(values >= 0) | ~np.isfinite(values)
        rows = np.flatnonzero(bad.any(axis=1))
        if rows.size:
            row = int(rows[np.argmin(np.nan_to_num(values[rows].min(axis=1), nan=-np.inf))])
            worst = values[row][bad[row]][0]
            theta_i = np.degrees(np.arccos(np.clip(wi[row, 2], -1, 1)))
            theta_o = np.degrees(np.arccos(np.clip(wo[row, 2], -1, 1)))
            where = " (near the mirror direction)" if near_mirror[row] else ""
            at = "" if wavelength is None else f" at {wavelength:g} nm"
            kind = "not finite" if not np.isfinite(worst) else "negative"
            raise InputError(
                f"output 'f' is {kind} ({worst:g} sr^-1) at {rows.size} of {len(wi)} probe pairs{at}, e.g. "
                f"theta_i = {theta_i:.2f} deg, theta_o = {theta_o:.2f} deg{where}; a BRDF is finite and >= 0",
                path=path,
            )


def input_dependencies(graph: onnx.GraphProto) -> dict[str, frozenset[str]]:
    """For every tensor of ``graph``, the graph inputs it depends on (nodes visited in topological
    order); :class:`ValueError` for a cycle or a tensor nothing produces."""
    depends: dict[str, frozenset[str]] = {vi.name: frozenset([vi.name]) for vi in graph.input}
    for init in graph.initializer:
        depends[init.name] = frozenset()
    pending = list(graph.node)
    while pending:
        ready = [n for n in pending if all(not i or i in depends for i in n.input)]
        if not ready:
            raise ValueError("the graph has a cycle or reads a tensor nothing produces")
        for node in ready:
            inputs = frozenset().union(*(depends[i] for i in node.input if i))
            for name in node.output:
                depends[name] = inputs
        pending = [n for n in pending if n not in ready]
    return depends


def output_model(proto: onnx.ModelProto, output: str) -> onnx.ModelProto:
    """The part of ``proto`` that computes ``output``, as a model whose only output is ``f`` (an
    ``Identity`` renames a fast path) and whose inputs are the graph inputs it reads: the nodes,
    initialisers and inputs ``output`` depends on, nothing else."""
    graph = proto.graph
    producer = {name: node for node in graph.node for name in node.output}
    needed, pending, nodes = set(), [output], []
    while pending:
        name = pending.pop()
        if name in needed or not name:
            continue
        needed.add(name)
        node = producer.get(name)
        if node is not None and node not in nodes:
            nodes.append(node)
            pending.extend(node.input)
    nodes = [node for node in graph.node if node in nodes]  # graph order is topological
    (declared,) = [vi for vi in graph.output if vi.name == output]
    result = onnx.ValueInfoProto()
    result.CopyFrom(declared)
    if output != OUTPUT_F:
        nodes.append(onnx.helper.make_node("Identity", [output], [OUTPUT_F], name=f"{output}_as_f"))
        result.name = OUTPUT_F
    initializers = [init for init in graph.initializer if init.name in needed]
    inputs = [vi for vi in graph.input if vi.name in needed and vi.name not in {init.name for init in initializers}]
    cut = onnx.helper.make_graph(nodes, f"{graph.name}:{output}", inputs, [result], initializers)
    model = onnx.helper.make_model(cut, opset_imports=proto.opset_import)
    model.ir_version = proto.ir_version
    return model


def _check_fast_path(proto: onnx.ModelProto, output: str, path, wavelength_range) -> None:
    """A fast path evaluated like ``f`` (:func:`_check_trial_evaluation`) on its own graph
    (:func:`output_model`); ``f_rgb`` must not read the wavelength."""
    model = output_model(proto, output)
    reads_wavelength = any(vi.name == INPUT_WAVELENGTH for vi in model.graph.input)
    if output == OUTPUT_RGB and reads_wavelength:
        raise InputError(f"output {output!r} depends on 'wavelength'; the linear sRGB is a function of wi, wo alone",
                         path=path)
    try:
        _check_trial_evaluation(model, path, wavelength_range if reads_wavelength else None)
    except InputError as error:
        raise InputError(f"fast path {output!r}: {error.reason}", path=path) from None


def _check_trial_evaluation(proto: onnx.ModelProto, path, wavelength_range) -> None:
    """Run the graph on :func:`probe_directions` (shape, zero below the horizon) and on
    :func:`dense_probe` (sign and finiteness) with onnxruntime and check its output."""
    try:
        session = onnxruntime.InferenceSession(
            proto.SerializeToString(), providers=["CPUExecutionProvider"]
        )
    except Exception as error:  # onnxruntime raises its own Fail/InvalidGraph types
        raise InputError(f"onnxruntime cannot load the graph: {error}", path=path) from None
    wi, wo, below = probe_directions()
    feeds = {INPUT_WI: wi, INPUT_WO: wo}
    expected_shape: tuple[int, ...] = (len(wi), 3)
    if wavelength_range is not None:
        feeds[INPUT_WAVELENGTH] = np.linspace(*wavelength_range, len(wi)).astype(np.float32)
        expected_shape = (len(wi),)
    try:
        (f,) = session.run([OUTPUT_F], feeds)
    except Exception as error:
        raise InputError(f"onnxruntime fails to evaluate the graph: {error}", path=path) from None
    if f.shape != expected_shape:
        raise InputError(
            f"output 'f' has shape {list(f.shape)} for {len(wi)} direction pairs, expected "
            f"{list(expected_shape)}",
            path=path,
        )
    if not np.all(np.isfinite(f)):
        raise InputError("output 'f' is not finite at some probe directions", path=path)
    if np.any(f < 0):
        raise InputError(
            f"output 'f' is negative (min {f.min():g} sr^-1) at some probe directions", path=path
        )
    if np.any(f[below] != 0):
        raise InputError(
            "output 'f' is not 0 when a direction is below the horizon (docs/formats.md#onnx-model-files)", path=path
        )
    _check_dense_probe(session, path, wavelength_range)
