"""Rendering of exported models: the ONNX contract (SPEC §6) and the Mitsuba 3 BSDF (SPEC §7).

* :mod:`~neuralbrdf.render.onnx_contract` — what every exported ``.onnx`` file must hold
  (:func:`neuralbrdf.kinds.load_model` adds each kind's own checks; the plugin runs both at
  scene load);
* :mod:`~neuralbrdf.render.drjit_onnx` — the graph evaluated as Dr.Jit arithmetic (``drjit``
  backend);
* :mod:`~neuralbrdf.render.sampling` — the cosine + glossy-lobe proposal and its fit;
* :mod:`~neuralbrdf.render.mitsuba_bsdf` — the ``neuralbrdf`` BSDF plugin; call
  :func:`register` after ``mi.set_variant``.
"""

import importlib

#: Public names -> the submodule defining them, imported on first use: checking or exporting a
#: file must not load Mitsuba and Dr.Jit (seconds), which only the BSDF plugin needs.
_LAZY = {"OnnxModel": "onnx_contract", "register": "mitsuba_bsdf"}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
