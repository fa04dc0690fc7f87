"""neuralbrdf: spectral neural BRDF modelling from few in-plane measurements.

Implements the pipeline of S. Chitnis, *Simplifying BRDF Acquisition* (IIT Bombay): GCMS-style
in-plane spectral measurements calibrated against a Munsell N9 white, compact models (ABC
microfacet, NLB latent representation network, 3x10 spectral MLP) fitted to few samples, and
their deployment to ONNX and Mitsuba 3.  Conventions are those of ``SPEC.md`` §1 and are
documented in :mod:`neuralbrdf.geometry`.
"""

__version__ = "0.1.0"
