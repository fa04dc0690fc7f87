"""neuralbrdf: spectral neural BRDF modelling from few in-plane measurements.

Implements the pipeline of S. Chitnis, *Simplifying BRDF Acquisition* (IIT Bombay): GCMS-style
in-plane spectral measurements calibrated against a Munsell N9 white, compact models (ABC
microfacet, NLB latent representation network, the spectral NLB, 3x10 spectral MLP) fitted to few
samples, and their deployment to ONNX and Mitsuba 3.  Conventions are those of docs/formats.md#conventions
and are implemented in :mod:`neuralbrdf.geometry`.

The Python API (:mod:`neuralbrdf.api`) is here at the top level: :func:`read`, :func:`fit`,
:func:`export`, :func:`load`, :func:`truth`, :func:`evaluate`, :func:`render_image`, :func:`view`, the
functions of measuring a fraction of the pairs, :func:`design_plan`, :func:`next_pairs`, :func:`watch_next_pairs`, :func:`acquire`, those of
measurement tables, :func:`simulate`, :func:`calibrate`, :func:`to_rgb`, :func:`sample`, :func:`plot`, :func:`demo`,
and of the level of detail, :func:`ladder`, :func:`select`: what each ``neuralbrdf`` command calls (``render`` is
the rendering subpackage, :mod:`neuralbrdf.render`).  Its names are imported on first use, so
``import neuralbrdf`` stays light (no PyTorch, no Mitsuba).
"""

from typing import TYPE_CHECKING

__version__ = "0.1.0"

#: Names of :mod:`neuralbrdf.api` offered here, and the error types a caller catches.
_API = ("ExportFailed", "FIT_KINDS", "FitResult", "Model", "RenderFailed", "Source", "acquire", "calibrate", "demo",
        "demo_outputs", "design_plan", "evaluate", "export", "fit", "ladder", "ladder_dir", "load", "next_pairs",
        "plot", "read", "regenerate_default_data", "render_image", "sample", "select", "simulate", "stand_ins",
        "study", "study_report", "to_rgb", "truth", "view", "watch_next_pairs", "write_plan")
_ERRORS = ("EnvironmentFailure", "FitFailed", "InputError", "Interrupted")

__all__ = [*_API, *_ERRORS]

if TYPE_CHECKING:
    from neuralbrdf.api import (FIT_KINDS, ExportFailed, FitResult, Model, RenderFailed, Source, acquire, calibrate,
                                demo, demo_outputs, design_plan, evaluate, export, fit, ladder, ladder_dir, load,
                                next_pairs, plot, read, regenerate_default_data, render_image, sample, select,
                                simulate, stand_ins, study, study_report, to_rgb, truth, view, watch_next_pairs,
                                write_plan)
    from neuralbrdf.errors import EnvironmentFailure, FitFailed, InputError, Interrupted


def __getattr__(name: str):
    if name in _API:
        from neuralbrdf import api

        return getattr(api, name)
    if name in _ERRORS:
        from neuralbrdf import errors

        return getattr(errors, name)
    raise AttributeError(f"module 'neuralbrdf' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
