"""What ``neuralbrdf evaluate`` says about a model file's fast paths (docs/formats.md#onnx-model-files, docs/select.md).

For every fast path of the file (``f_rgb``, ``f_fast``; :mod:`neuralbrdf.lod.fast_paths`):
what its metadata records (what it approximates, its error against ``f``, its relative cost)
and its error against ``f`` measured again — ``hemisphere_logcos_rmse`` on the evaluation's own
hemisphere pairs, against ``f``'s exact 31-wavelength linear sRGB for ``f_rgb`` — so that a file
whose record does not hold shows it.  When the render itself evaluated a fast path (``f_rgb`` in
RGB variants, ``f_fast`` with ``--fast``), the image's difference to a render of ``f`` at the same
seed and paths is reported too (:func:`image_against_f`): what the fast path changes in the
picture.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from neuralbrdf.evaluation.images import image_scores
from neuralbrdf.evaluation.scores import HEMISPHERE_STRATA, OnnxEvaluator, hemisphere_scores
from neuralbrdf.onnx_contract import OUTPUT_RGB, OnnxModel


def rendered_output(model: OnnxModel, variant: str, fast: bool) -> str:
    """The output the plugin evaluates for ``model`` in ``variant`` (its defaults, ``fast`` asked or not)."""
    from neuralbrdf.render.fast_paths import chosen_output

    return chosen_output(model, "_spectral" in variant, fast, rgb_head=True)


def fast_path_scores(path: str | Path, strata: tuple[int, int] = HEMISPHERE_STRATA) -> dict[str, dict]:
    """Per fast path of the file ``path``: its recorded metadata and its measured error (module docstring)."""
    from neuralbrdf.render.spectral_quadrature import RuleRgbEvaluator, full_rule

    parent = OnnxEvaluator(path)
    scores = {}
    for output, recorded in parent.file.fast_paths.items():
        teacher = RuleRgbEvaluator(parent, full_rule(parent.model.wavelength_range_nm)) if output == OUTPUT_RGB else parent
        measured = hemisphere_scores(OnnxEvaluator(path, output), teacher, strata=strata)["hemisphere_logcos_rmse"]
        scores[output] = {
            "approximates": recorded.approximates,
            "recorded_hemisphere_logcos_rmse": recorded.hemisphere_logcos_rmse,
            "hemisphere_logcos_rmse": float(measured),
            "relative_cost": recorded.relative_cost,
        }
    return scores


def image_against_f(fast_image: np.ndarray, f_image: np.ndarray) -> dict[str, float]:
    """Image metrics (the names of docs/evaluate.md#metrics) of a render through a fast path against the render of ``f``."""
    metrics, _ = image_scores(fast_image, f_image)
    return metrics

