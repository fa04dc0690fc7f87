"""Fitting models to BRDF sample tables: the ABC model (:mod:`neuralbrdf.fitting.abc_fit`)."""

from neuralbrdf.fitting.abc_fit import AbcBounds, AbcFitResult, fit_abc

__all__ = ["AbcBounds", "AbcFitResult", "fit_abc"]
