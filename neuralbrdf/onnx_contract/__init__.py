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

This package checks the part of the contract every kind shares (:func:`load_generic_model`,
:func:`generic_metadata`) and never imports Mitsuba, Dr.Jit or PyTorch.
:func:`neuralbrdf.kinds.load_model` adds the checks of the file's kind (its name registered, its
own keys, spectral where the kind requires it); renderers and evaluators open models through that.

Its modules, each importable from here:

* :mod:`~neuralbrdf.onnx_contract.schema` — the names: version, inputs, outputs, metadata keys;
* :mod:`~neuralbrdf.onnx_contract.model` — :class:`OnnxModel` and :func:`load_generic_model`;
* :mod:`~neuralbrdf.onnx_contract.interface` — input and output names, dtypes and shapes;
* :mod:`~neuralbrdf.onnx_contract.metadata` — the shared entries, the fast paths' entries;
* :mod:`~neuralbrdf.onnx_contract.weights` — sizes and finiteness of the weights, their cost;
* :mod:`~neuralbrdf.onnx_contract.probes` — the direction pairs a file is tried on;
* :mod:`~neuralbrdf.onnx_contract.trial` — the trial evaluation with onnxruntime;
* :mod:`~neuralbrdf.onnx_contract.graph` — tensor dependencies, one output cut out as a model.
"""

from neuralbrdf.onnx_contract.graph import input_dependencies, output_model
from neuralbrdf.onnx_contract.metadata import FastPath, generic_metadata, metadata_float, metadata_float_list
from neuralbrdf.onnx_contract.model import OnnxModel, load_generic_model
from neuralbrdf.onnx_contract.probes import (PROBE_GRAZING_STRATA, PROBE_MIRROR_AZIMUTHS, PROBE_MIRROR_OFFSETS_DEG,
                                             PROBE_MIRROR_THETA_I, PROBE_OUT_STRATA, PROBE_THETA_I_STRATA,
                                             PROBE_WAVELENGTHS, dense_probe, probe_directions)
from neuralbrdf.onnx_contract.schema import (FAST_PATH_IMAGE_KEYS, FAST_PATH_KEYS, FAST_PATH_OUTPUTS, FORMAT_VERSION,
                                             FORMAT_VERSION_KEY, INPUT_WAVELENGTH, INPUT_WI, INPUT_WO, KIND_KEY,
                                             MATERIAL_KEY, OUTPUT_F, OUTPUT_FAST, OUTPUT_RGB, PROVENANCE_KEY,
                                             REQUIRED_KEYS, SHARED_NAMESPACES, WAVELENGTH_MAX_KEY, WAVELENGTH_MIN_KEY,
                                             fast_path_key, kind_key)
from neuralbrdf.onnx_contract.weights import matrix_multiply_adds

__all__ = [
    "FAST_PATH_IMAGE_KEYS", "FAST_PATH_KEYS", "FAST_PATH_OUTPUTS", "FORMAT_VERSION", "FORMAT_VERSION_KEY",
    "INPUT_WAVELENGTH", "INPUT_WI", "INPUT_WO", "KIND_KEY", "MATERIAL_KEY", "OUTPUT_F", "OUTPUT_FAST", "OUTPUT_RGB",
    "PROBE_GRAZING_STRATA", "PROBE_MIRROR_AZIMUTHS", "PROBE_MIRROR_OFFSETS_DEG", "PROBE_MIRROR_THETA_I",
    "PROBE_OUT_STRATA", "PROBE_THETA_I_STRATA", "PROBE_WAVELENGTHS", "PROVENANCE_KEY", "REQUIRED_KEYS",
    "SHARED_NAMESPACES", "WAVELENGTH_MAX_KEY", "WAVELENGTH_MIN_KEY", "FastPath", "OnnxModel", "dense_probe",
    "fast_path_key", "generic_metadata", "input_dependencies", "kind_key", "load_generic_model",
    "matrix_multiply_adds", "metadata_float", "metadata_float_list", "output_model", "probe_directions",
]
