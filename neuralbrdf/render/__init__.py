"""Rendering of exported models: the ONNX contract (SPEC §6) and the Mitsuba 3 BSDF (SPEC §7).

* :mod:`~neuralbrdf.render.onnx_contract` — what an exported ``.onnx`` file must hold, checked
  by :func:`load_model` at scene load;
* :mod:`~neuralbrdf.render.drjit_onnx` — the graph evaluated as Dr.Jit arithmetic (``drjit``
  backend);
* :mod:`~neuralbrdf.render.sampling` — the cosine + glossy-lobe proposal and its fit;
* :mod:`~neuralbrdf.render.mitsuba_bsdf` — the ``neuralbrdf`` BSDF plugin; call
  :func:`register` after ``mi.set_variant``.
"""

from neuralbrdf.render.mitsuba_bsdf import register
from neuralbrdf.render.onnx_contract import OnnxModel, load_model

__all__ = ["OnnxModel", "load_model", "register"]
