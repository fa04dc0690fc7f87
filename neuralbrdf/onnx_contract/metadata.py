"""The contract's metadata (``ModelProto.metadata_props``, :mod:`neuralbrdf.onnx_contract`): the entries
every kind shares, built (:func:`generic_metadata`) and checked (:func:`check_metadata`) alike, the
fast paths they describe (:class:`FastPath`, :func:`read_fast_paths`) and the number readers the
kinds use for their own entries."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from neuralbrdf.errors import InputError
from neuralbrdf.onnx_contract.schema import (FAST_PATH_IMAGE_KEYS, FAST_PATH_KEYS, FAST_PATH_OUTPUTS, FORMAT_VERSION,
                                             FORMAT_VERSION_KEY, KIND_KEY, MATERIAL_KEY, OUTPUT_RGB, PROVENANCE_KEY,
                                             REQUIRED_KEYS, SHARED_NAMESPACES, WAVELENGTH_MAX_KEY, WAVELENGTH_MIN_KEY,
                                             fast_path_key, kind_key)


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


def generic_metadata(
    kind: str,
    material: str,
    provenance: str,
    *,
    wavelength_range_nm: tuple[float, float] | None = None,
    kind_metadata: Mapping[str, str] | None = None,
) -> dict[str, str]:
    """The ``metadata_props`` entries every kind shares, validated like :func:`~neuralbrdf.onnx_contract.model.load_generic_model` does.

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
    check_metadata(metadata, "<metadata>", is_spectral=wavelength_range_nm is not None)
    return metadata


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


def read_fast_paths(metadata: Mapping[str, str], outputs: Sequence[str], path) -> dict[str, FastPath]:
    """The fast paths of the graph's extra ``outputs`` from their metadata entries
    (:mod:`neuralbrdf.onnx_contract`), checked; an entry for an output the graph lacks is an error too."""
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


def check_metadata(metadata: Mapping[str, str], path, is_spectral: bool):
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
