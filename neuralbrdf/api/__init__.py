"""The Python API: read a material, fit a model to it, export, load, evaluate and render.

Every name here is also at the package's top level (``neuralbrdf.read``, ``neuralbrdf.fit``, ...),
imported on first use: ``import neuralbrdf`` loads neither PyTorch nor Mitsuba.  The API is the one
door to the library: each ``neuralbrdf`` command parses its options, makes one call here and prints
(:mod:`neuralbrdf.cli`), so a script and a shell command do the same thing::

    import neuralbrdf as nb

    gold = nb.read("virtual:gold")                        # or a table, GCMS raw + reference, .h5, .binary, .bsdf
    result = nb.fit("spectral_mlp", gold, run_dir="runs/gold")
    model = result.export("gold.onnx")                    # a validated ONNX file (docs/formats.md#onnx-model-files)
    f = model(wi, wo, wavelength)                         # BRDF in sr^-1, as numpy
    truth = nb.truth(gold, "gold_truth.onnx")
    scores = nb.evaluate(model, truth, "gold_eval")       # hemisphere, in-plane and image errors
    image = nb.render_image(model, "gold.png")            # linear RGB [H, W, 3]

Fits run through the same YAML configs and Lightning modules as ``neuralbrdf train`` (the configs
stay the single source of hyper-parameters): :data:`FIT_KINDS` names the config of each kind,
``overrides`` change single values, handed to the run as data (the values ``--key value`` sets on
the command line, typed).  Bad input raises
:class:`~neuralbrdf.errors.InputError` (one line naming the file, row or key); a fit that runs
and fails raises :class:`~neuralbrdf.errors.FitFailed`.  Units: angles in degrees, wavelengths
in nm, BRDF values in sr⁻¹ without the cosine factor; directions are unit vectors in the local
frame, ``z`` the normal, both pointing away from the surface (docs/formats.md#conventions).

The names live in modules by theme: :mod:`~neuralbrdf.api.materials` (:func:`read`),
:mod:`~neuralbrdf.api.fitting`, :mod:`~neuralbrdf.api.model_files` (export, load, truth),
:mod:`~neuralbrdf.api.rendering` (evaluate, render), :mod:`~neuralbrdf.api.tables` (simulate,
calibrate, to_rgb, sample, plot, demo), :mod:`~neuralbrdf.api.plans`,
:mod:`~neuralbrdf.api.level_of_detail`, :mod:`~neuralbrdf.api.studies` and
:mod:`~neuralbrdf.api.explore` (view).
"""

from neuralbrdf.api.explore import view
from neuralbrdf.api.fitting import FIT_KINDS, FitResult, fit
from neuralbrdf.api.level_of_detail import ladder, ladder_dir, select
from neuralbrdf.api.materials import Source, read
from neuralbrdf.api.model_files import ExportFailed, Model, export, load, truth
from neuralbrdf.api.plans import acquire, design_plan, next_pairs, watch_next_pairs, write_plan
from neuralbrdf.api.rendering import RenderFailed, evaluate, render_image
from neuralbrdf.api.studies import study, study_report
from neuralbrdf.api.tables import (calibrate, demo, demo_outputs, plot, regenerate_default_data, sample, simulate,
                                   stand_ins, to_rgb)

__all__ = ["ExportFailed", "FIT_KINDS", "FitResult", "Model", "RenderFailed", "Source", "acquire", "calibrate",
           "demo", "demo_outputs", "design_plan", "evaluate", "export", "fit", "ladder", "ladder_dir", "load",
           "next_pairs", "plot", "read", "regenerate_default_data", "render_image", "sample", "select", "simulate",
           "stand_ins", "study", "study_report", "to_rgb", "truth", "view", "watch_next_pairs", "write_plan"]
