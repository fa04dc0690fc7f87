"""The model files a viewer shows, each evaluated by onnxruntime in whatever quantity a view asks for.

A :class:`ViewedModel` is one ``.onnx`` file checked against the whole contract
(:func:`neuralbrdf.kinds.load_model`) with one onnxruntime session of its ``f`` (never a fast path:
the viewer shows the model itself), created once.  A view asks it for one *channel*
(:data:`CHANNELS`):

* ``wavelength`` — ``f`` at one wavelength (nm; spectral models only, clamped to the model's range
  as the renderer clamps it);
* ``R``, ``G``, ``B`` — a channel of the linear sRGB value, and ``Y`` — its luminance (CIE Y, the
  second row of the IEC 61966-2-1 sRGB → XYZ matrix).  An RGB model gives its own values; a spectral
  model's spectrum is integrated to linear sRGB (CIE 1931 2°, D65; :mod:`neuralbrdf.data.colorimetry`)
  through the few-wavelength rule the renderer uses in RGB variants
  (:func:`neuralbrdf.render.spectral_quadrature.fit_reduced_quadrature`, fitted here to the model's
  own spectra on the contract's dense probe, within a held-out relative error of 10⁻³ of the
  31-wavelength integral), so that a colour costs a handful of evaluations per direction pair.
  A spectral model whose range does not hold the observer's weight over 400–700 nm has no colour
  (the rule of :func:`neuralbrdf.data.colorimetry.colour_problem`, as for ``to-rgb`` and an
  exported RGB head): the views leave it out of ``R``, ``G``, ``B`` and ``Y`` and say why.

All values are BRDF values in sr⁻¹ without the cosine factor.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import colour
import numpy as np
import onnxruntime

from neuralbrdf.data.colorimetry import colour_problem
from neuralbrdf.errors import InputError
from neuralbrdf.kinds import load_model
from neuralbrdf.kinds.reference import KIND as REFERENCE
from neuralbrdf.onnx_contract import INPUT_WAVELENGTH, INPUT_WI, INPUT_WO, OUTPUT_F, OnnxModel, dense_probe
from neuralbrdf.render.spectral_quadrature import (
    DEFAULT_RMS_TOLERANCE,
    SRGB_GRID_NM,
    ReducedQuadrature,
    fit_reduced_quadrature,
    srgb_weights,
)

#: What a view can ask a model for (module docstring).
CHANNELS = ("wavelength", "Y", "R", "G", "B")
#: Luminance of linear sRGB: row Y of the IEC 61966-2-1 sRGB → XYZ matrix.
LUMINANCE = np.array(colour.RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ[1], dtype=np.float64)
#: The kind a truth must be: a ground truth of ``neuralbrdf export-truth``.
TRUTH_KIND = REFERENCE.name
#: Every this many pairs of the contract's dense probe fit the sRGB rule of a spectral model.
RULE_PROBE_STRIDE = 4


def session(model: OnnxModel) -> onnxruntime.InferenceSession:
    """A CPU session of the model's ``f`` whose threads sleep between requests instead of spinning."""
    options = onnxruntime.SessionOptions()
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return onnxruntime.InferenceSession(model.output_view().proto.SerializeToString(), options,
                                        providers=["CPUExecutionProvider"])


def channel_of_rgb(rgb: np.ndarray, channel: str) -> np.ndarray:
    """One of ``Y``, ``R``, ``G``, ``B`` of linear sRGB values ``[N, 3]``."""
    return rgb @ LUMINANCE if channel == "Y" else rgb[:, "RGB".index(channel)]


@dataclass
class ViewedModel:
    """One model file as the viewer shows it (module docstring)."""

    label: str
    role: str  # "model" or "truth"
    model: OnnxModel
    session: onnxruntime.InferenceSession = field(repr=False)
    rule: ReducedQuadrature | None = field(default=None, repr=False)
    #: Why a spectral model has no colour (:func:`~neuralbrdf.data.colorimetry.colour_problem`), else ``None``.
    no_colour: str | None = None

    @classmethod
    def load(cls, path: str | Path, label: str, role: str = "model") -> ViewedModel:
        """Check ``path`` and open it; a truth (``role="truth"``) must be of kind :data:`TRUTH_KIND`."""
        model = load_model(path)
        if role == "truth" and model.kind != TRUTH_KIND:
            raise InputError(f"is a model of kind {model.kind!r}; a truth must be kind {TRUTH_KIND!r} (a ground truth "
                             "written by 'neuralbrdf export-truth'); show it as a model instead", path=path)
        viewed = cls(label, role, model, session(model))
        if model.is_spectral:
            viewed.no_colour = colour_problem(model.wavelength_range_nm, "the model")
            if viewed.no_colour is None:
                viewed.rule = viewed._fit_rule()
        return viewed

    @property
    def is_spectral(self) -> bool:
        return self.model.is_spectral

    def has(self, channel: str) -> bool:
        """Whether the model has values in ``channel`` (:data:`CHANNELS`; ``colour``: linear sRGB)."""
        return self.is_spectral if channel == "wavelength" else self.no_colour is None

    def _run(self, wi: np.ndarray, wo: np.ndarray, wavelength: np.ndarray | None = None) -> np.ndarray:
        feeds = {INPUT_WI: np.asarray(wi, dtype=np.float32), INPUT_WO: np.asarray(wo, dtype=np.float32)}
        if wavelength is not None:
            feeds[INPUT_WAVELENGTH] = np.clip(wavelength, *self.model.wavelength_range_nm).astype(np.float32)
        return self.session.run([OUTPUT_F], feeds)[0].astype(np.float64)

    def spectra(self, wi: np.ndarray, wo: np.ndarray, wavelengths_nm) -> np.ndarray:
        """``[N, K]`` values of a spectral model at ``K`` wavelengths (nm), in one run."""
        wavelengths_nm = np.asarray(wavelengths_nm, dtype=np.float64)
        n, k = len(wi), len(wavelengths_nm)
        values = self._run(np.tile(wi, (k, 1)), np.tile(wo, (k, 1)), np.repeat(wavelengths_nm, n))
        return values.reshape(k, n).T

    def _fit_rule(self) -> ReducedQuadrature:
        """The rule, fitted on probe spectra scaled to unit colour: every direction's colour counts
        alike, the dim ones (a diffuse term's colour) as much as the specular peak."""
        wi, wo, _ = dense_probe()
        grid = np.clip(SRGB_GRID_NM, *self.model.wavelength_range_nm)
        spectra = self.spectra(wi[::RULE_PROBE_STRIDE], wo[::RULE_PROBE_STRIDE], grid)
        weights = srgb_weights()
        norm = np.linalg.norm(spectra @ weights, axis=1)
        spectra = spectra[norm > 0] / norm[norm > 0, None]
        return fit_reduced_quadrature(spectra, grid, weights, DEFAULT_RMS_TOLERANCE)

    def linear_srgb(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``[N, 3]`` linear sRGB in sr⁻¹ (module docstring); out-of-gamut negatives clipped to 0."""
        if not self.is_spectral:
            return self._run(wi, wo)
        spectra = np.clip(self.spectra(wi, wo, self.rule.wavelengths_nm), 0.0, None)
        return np.clip(spectra @ self.rule.weights, 0.0, None)

    def channel(self, wi: np.ndarray, wo: np.ndarray, channel: str, wavelength_nm: float) -> np.ndarray | None:
        """``[N]`` values of ``channel`` (:data:`CHANNELS`); ``None`` where the model has none (:meth:`has`)."""
        if not self.has(channel):
            return None
        if channel == "wavelength":
            return self.spectra(wi, wo, [wavelength_nm])[:, 0]
        return channel_of_rgb(self.linear_srgb(wi, wo), channel)

    def describe(self) -> dict:
        """What the page lists about the file: its name, kind, material, spectral range and every
        metadata entry (fast paths and their recorded error and cost, kind parameters, ladder
        numbers, provenance)."""
        model = self.model
        return {
            "label": self.label,
            "role": self.role,
            "file": str(model.path),
            "kind": model.kind,
            "material": model.material,
            "spectral": model.is_spectral,
            "wavelength_range_nm": list(model.wavelength_range_nm) if model.is_spectral else None,
            "fast_paths": [path.describe() for path in model.fast_paths.values()],
            "rgb_rule": self.rule.describe() if self.rule is not None else None,
            "no_colour": self.no_colour,
            "metadata": dict(sorted(model.metadata.items())),
        }
