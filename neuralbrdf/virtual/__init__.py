"""A virtual goniospectrophotometer and physically based stand-in materials (docs/measure.md#the-virtual-goniospectrophotometer)."""

from neuralbrdf.virtual.instrument import (
    DEFAULT_NOISE_ABS,
    DEFAULT_NOISE_REL,
    DEFAULT_SEED,
    VirtualGoniospectrophotometer,
    default_data_path,
    instrument_response,
    regenerate_default_data,
)
from neuralbrdf.virtual.materials import MATERIALS, REFERENCE_MATERIAL, get_material

__all__ = [
    "DEFAULT_NOISE_ABS",
    "DEFAULT_NOISE_REL",
    "DEFAULT_SEED",
    "MATERIALS",
    "REFERENCE_MATERIAL",
    "VirtualGoniospectrophotometer",
    "default_data_path",
    "get_material",
    "instrument_response",
    "regenerate_default_data",
]
