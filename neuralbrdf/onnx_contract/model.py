"""A validated model file (:class:`OnnxModel`) and how one is read and checked against the contract
(:func:`load_generic_model`, :mod:`neuralbrdf.onnx_contract`)."""

from __future__ import annotations

import dataclasses
import hashlib
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import onnx

from neuralbrdf.atomic import note_input
from neuralbrdf.errors import InputError
from neuralbrdf.limits import MAX_ONNX_BYTES, check_file_size, file_problem
from neuralbrdf.onnx_contract.graph import output_model
from neuralbrdf.onnx_contract.interface import check_interface
from neuralbrdf.onnx_contract.metadata import FastPath, check_metadata, read_fast_paths
from neuralbrdf.onnx_contract.schema import MATERIAL_KEY, OUTPUT_F, OUTPUT_RGB, PROVENANCE_KEY
from neuralbrdf.onnx_contract.trial import check_fast_path, check_trial_evaluation
from neuralbrdf.onnx_contract.weights import check_constant_shapes, check_finite_constants, check_tensor_sizes


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
        The file's fast-path outputs by name (:mod:`neuralbrdf.onnx_contract`), checked like ``f``.
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


def load_generic_model(path: str | os.PathLike[str]) -> OnnxModel:
    """Load ``path`` and check it against the contract of docs/formats.md#onnx-model-files
    (:mod:`neuralbrdf.onnx_contract`).

    Raises :class:`InputError` naming the file for a missing or unreadable file, a file that is
    not ONNX or fails the ONNX checker, wrong input or output names, dtypes or ranks, a fixed
    batch size, missing or malformed metadata, non-finite initialisers or constants, and a graph
    that onnxruntime cannot run or whose trial evaluation breaks the output contract (shape,
    zero below the horizon; :func:`~neuralbrdf.onnx_contract.probe_directions`) or that is negative
    or not finite anywhere on the dense stratified probe of :func:`~neuralbrdf.onnx_contract.dense_probe`
    (near-mirror and grazing pairs included).
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
    check_tensor_sizes(proto.graph, path)
    try:
        onnx.checker.check_model(proto)
    except onnx.checker.ValidationError as error:
        raise InputError(f"invalid ONNX graph: {error}", path=path) from None
    except UnicodeDecodeError:  # the checker's message quotes a name that is not UTF-8 (found by fuzzing)
        raise InputError("invalid ONNX graph: a name or string in it is not UTF-8 text", path=path) from None

    is_spectral = check_interface(proto.graph, path)
    metadata = {entry.key: entry.value for entry in proto.metadata_props}
    kind, wavelength_range = check_metadata(metadata, path, is_spectral)
    fast_paths = read_fast_paths(metadata, [vi.name for vi in proto.graph.output[1:]], path)
    check_finite_constants(proto.graph, path)
    check_constant_shapes(proto.graph, path)
    check_trial_evaluation(proto if not fast_paths else output_model(proto, OUTPUT_F), path, wavelength_range)
    for output in fast_paths:
        check_fast_path(proto, output, path, wavelength_range)
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
