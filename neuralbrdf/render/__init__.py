"""Rendering of exported models in Mitsuba 3 (docs/mitsuba-plugin.md); the file contract is :mod:`neuralbrdf.onnx_contract`.

* :mod:`~neuralbrdf.render.drjit_onnx` — the graph evaluated as Dr.Jit arithmetic (``drjit``
  backend);
* :mod:`~neuralbrdf.render.sampling` — the cosine + glossy-lobe proposals and their fit;
* :mod:`~neuralbrdf.render.mitsuba_bsdf` — the ``neuralbrdf`` BSDF plugin; call
  :func:`register` after ``mi.set_variant``;
* :mod:`~neuralbrdf.render.measured_bsdf` — ``neuralbrdf_measured``, an RGL measurement as a truth;
* :mod:`~neuralbrdf.render.load_time` — what both plugins work out once per model file;
* :mod:`~neuralbrdf.render.preview` — scenes, variants and renders (``neuralbrdf render``).
"""

import importlib

#: The Mitsuba variant ``neuralbrdf render``, ``neuralbrdf evaluate`` and the Python API use unless
#: told otherwise.  Spectral, because the product is: a spectral model is evaluated at each path's
#: own wavelengths, as it was trained, where an RGB variant integrates it to sRGB through a fitted
#: few-wavelength rule (an approximation within ``rgb_tolerance``); an RGB model renders in it too,
#: upsampled per sample as Mitsuba upsamples every RGB texture.  ``--variant llvm_ad_rgb`` is faster.
DEFAULT_VARIANT = "llvm_ad_spectral"

#: Public names -> the submodule defining them, imported on first use: importing this package
#: must not load Mitsuba and Dr.Jit (seconds), which only the BSDF plugin needs.
_LAZY = {"register": "mitsuba_bsdf"}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
