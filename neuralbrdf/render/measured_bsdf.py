"""The ``neuralbrdf_measured`` Mitsuba BSDF: an RGL measurement rendered by Mitsuba's own ``measured``
plugin, as the truth of ``neuralbrdf evaluate --truth NAME.bsdf`` (docs/evaluate.md).

A thin wrapper: ``eval`` is the ``measured`` plugin's ``eval`` (``f · cos θo``, the plugin's
``si.wi`` the measurement's light direction, :mod:`neuralbrdf.data.rgl_bsdf`) clipped at 0 — the
policy every other reading of the file follows (``sample``, ``read``, ``export-truth`` and the
hemisphere scores), so that image and direction scores compare a model with the same values.  The
file is checked by :meth:`~neuralbrdf.data.rgl_bsdf.RglBsdf.load` before Mitsuba reads it.

Properties: ``filename`` (the ``.bsdf``) and, optionally, ``proposal``: a model file whose fitted
sampling proposal (:mod:`neuralbrdf.render.sampling`) is used instead of the plugin's own
luminance/VNDF sampling.  Any valid proposal leaves the image's expectation unchanged; the
evaluation renders the truth with the *model's* proposal, so that at matched seeds model and truth
trace the same paths and their image difference is the model's error rather than Monte Carlo noise
(:mod:`neuralbrdf.evaluation.evaluate`).

Mitsuba reads RGB files only in RGB variants and spectral files only in spectral ones; a file in
the other kind of variant is one :class:`~neuralbrdf.errors.InputError`.
"""

from __future__ import annotations

from pathlib import Path

import drjit as dr
import mitsuba as mi

from neuralbrdf.data.rgl_bsdf import RglBsdf, measured_plugin
from neuralbrdf.errors import InputError
from neuralbrdf.render.load_time import fitted_proposal, proposal_path, validated_model

PLUGIN_NAME = "neuralbrdf_measured"

_CLASSES: dict[str, type] = {}


def register_measured() -> None:
    """Register ``neuralbrdf_measured`` in the current Mitsuba variant (idempotent)."""
    variant = mi.variant()
    if variant not in _CLASSES:
        _CLASSES[variant] = _measured_class()
        cls = _CLASSES[variant]
        mi.register_bsdf(PLUGIN_NAME, lambda props: cls(props))


def _measurement(props: mi.Properties) -> RglBsdf:
    if "filename" not in props:
        raise InputError(f"the {PLUGIN_NAME} BSDF needs a 'filename' property (the .bsdf measurement)")
    brdf = RglBsdf.load(Path(str(mi.file_resolver().resolve(str(props.get("filename"))))))
    if brdf.is_spectral != mi.is_spectral:
        raise InputError(f"an {'spectral' if brdf.is_spectral else 'RGB'} measurement renders in a "
                         f"{brdf.variant.split('_')[-1]} variant such as {brdf.variant}, not in {mi.variant()}",
                         path=brdf.path)
    return brdf


def _measured_class() -> type:
    """The BSDF class for the current variant (a Python BSDF derives from that variant's ``mi.BSDF``)."""

    class MeasuredBSDF(mi.BSDF):
        """Mitsuba's ``measured`` BSDF, clipped at 0, optionally sampled with a model's proposal (module
        docstring)."""

        def __init__(self, props: mi.Properties) -> None:
            mi.BSDF.__init__(self, props)
            self.brdf = _measurement(props)
            proposal = proposal_path(props)
            self.mixture = None if proposal is None else fitted_proposal(validated_model(proposal))
            self.measured = measured_plugin(self.brdf)
            self.m_flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            self.m_components = [self.m_flags]

        def eval(self, ctx, si, wo, active=True):
            return dr.maximum(self.measured.eval(ctx, si, wo, active), 0.0)

        def pdf(self, ctx, si, wo, active=True):
            if self.mixture is None:
                return self.measured.pdf(ctx, si, wo, active)
            if not ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0):
                return mi.Float(0.0)
            return dr.select(active, self.mixture.pdf(si.wi, wo), 0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            if self.mixture is None:
                bs, weight = self.measured.sample(ctx, si, sample1, sample2, active)
                return bs, dr.maximum(weight, 0.0)
            bs = dr.zeros(mi.BSDFSample3f)
            if not ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0):
                return bs, mi.Spectrum(0.0)
            wo, pdf, valid = self.mixture.sample(si.wi, sample1, sample2)
            valid &= active
            bs.wo = wo
            bs.pdf = dr.select(valid, pdf, 0.0)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
            bs.sampled_component = mi.UInt32(0)
            return bs, dr.select(valid, self.eval(ctx, si, wo, valid) / pdf, 0.0)

        def to_string(self):
            sampling = "the measured plugin's own" if self.mixture is None else self.mixture.describe()
            return (f"MeasuredNeuralbrdf[\n  filename = {str(self.brdf.path)!r},\n  {self.brdf.description!r}, "
                    f"{'spectral' if self.brdf.is_spectral else 'RGB'}, negative values clipped to 0,\n"
                    f"  sampling = {sampling}\n]")

    return MeasuredBSDF
