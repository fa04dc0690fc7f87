"""Which output of a model file the ``neuralbrdf`` BSDF evaluates: ``f`` or one of its fast paths.

A model file may carry fast paths beside ``f`` (docs/formats.md#onnx-model-files; ``neuralbrdf export`` adds them,
:mod:`neuralbrdf.lod.fast_paths`): ``f_rgb``, a spectral model's linear sRGB evaluated once per
query, and ``f_fast``, a compact copy of ``f``.  Two plugin properties choose
(:func:`chosen_output`):

``rgb_head`` (boolean, default ``true``)
    A spectral model in an RGB variant evaluates ``f_rgb`` when the file has it, instead of
    integrating ``f`` to sRGB through a rule on a few wavelengths (``rgb_tolerance``).
``fast`` (boolean, default ``false``)
    Evaluate the fast path: ``f_fast`` (in an RGB variant, a spectral model's ``f_rgb`` when the
    file has it and ``rgb_head`` is on, else ``f_fast`` through the sRGB rule).  A file without
    one is refused, naming the command that adds it.

The sampling proposal stays the one fitted to ``f``, so a fast path and its parent rendered with
the same seed trace the same paths and their image difference is the fast path's own error.
Booleans may also be given as strings (``"true"``, ``"false"``), as scene editing writes them.
"""

from __future__ import annotations

from neuralbrdf.errors import InputError
from neuralbrdf.onnx_contract import OUTPUT_F, OUTPUT_FAST, OUTPUT_RGB, OnnxModel

FAST_PROPERTY = "fast"
RGB_HEAD_PROPERTY = "rgb_head"
#: How to add the fast paths to a model file (named in error messages).
ADD_COMMAND = "neuralbrdf export --model MODEL.onnx --out NEW.onnx --fast"


def flag(props, name: str, default: bool) -> bool:
    """Boolean property ``name`` of Mitsuba properties ``props`` (or a mapping), else ``default``."""
    if name not in props:
        return default
    value = props.get(name) if hasattr(props, "get") else props[name]
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text not in ("true", "false"):
        raise InputError(f"expected true or false, got {value!r}", key=name)
    return text == "true"


def chosen_output(model: OnnxModel, spectral_variant: bool, fast: bool, rgb_head: bool) -> str:
    """The output the plugin evaluates for ``model`` (module docstring)."""
    rgb_head_applies = model.is_spectral and not spectral_variant and rgb_head and OUTPUT_RGB in model.fast_paths
    if rgb_head_applies:
        return OUTPUT_RGB
    if not fast:
        return OUTPUT_F
    if OUTPUT_FAST not in model.fast_paths:
        raise InputError(f"property '{FAST_PROPERTY}' asks for a fast path and the model has none; add one with "
                         f"'{ADD_COMMAND}'", path=model.path, key=FAST_PROPERTY)
    return OUTPUT_FAST
