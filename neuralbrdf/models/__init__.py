"""BRDF models (SPEC §4): the ABC microfacet model (:mod:`neuralbrdf.models.abc`)."""

from neuralbrdf.models.abc import ABCModel, ABCParameters, abc_brdf, load_low2012_parameters

__all__ = ["ABCModel", "ABCParameters", "abc_brdf", "load_low2012_parameters"]
