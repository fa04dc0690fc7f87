"""The names of the ONNX file contract (:mod:`neuralbrdf.onnx_contract`): its version, the graph's
inputs and outputs, the fast-path outputs and the metadata keys."""

from __future__ import annotations

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
#: The fast paths (:mod:`neuralbrdf.onnx_contract`): a spectral model's linear sRGB, once per query ...
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
