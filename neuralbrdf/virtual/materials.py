"""Physically based stand-ins for the report's packaging materials (docs/measure.md#the-virtual-goniospectrophotometer; report §3.2).

The Gold, Gonio, Cyan and Magenta prints measured by Sole et al. (2021, *The Visual Computer*
37(8)) are not public.  Each stand-in here is an analytic spectral BRDF with the character the
report describes (Cyan and Magenta mostly diffuse, Gold and Gonio highly specular, Gonio
goniochromatic), plus the Munsell N9 white reference of the calibration (report Eq. 2.3).

Every material has a ``name`` and ``brdf(wi, wo, wavelengths_nm)``: unit directions ``[N, 3]``
(local frame of :mod:`neuralbrdf.geometry`) and wavelengths ``[W]`` in nm to a float64 BRDF
``[N, W]`` in sr⁻¹, zero when either direction is at or below the horizon.  The same formula is
split in two for other evaluators: ``spectra(wavelengths_nm)``, the named per-wavelength
quantities of the material (albedo, complex index, ...; ``[W]`` NumPy arrays), and
``brdf_from_spectra(wi, wo, spectra)``, the BRDF from those quantities through the array API
(NumPy or torch), with the spectra broadcasting against ``[N, 1]``: ``[1, W]`` gives the grid
``[N, W]`` of ``brdf``, ``[N, 1]`` one wavelength per direction pair (the ground-truth models of
:mod:`neuralbrdf.evaluation.truth`).  Specular lobes are
GGX microfacet reflection (:func:`neuralbrdf.physics.microfacet.microfacet_brdf`, Walter et al.
2007) with Smith shadowing, so every material is reciprocal and isotropic.  Diffuse spectra are
ColorChecker patches from colour-science (``SDS_COLOURCHECKERS['BabelColor Average']``, 380–730
nm), resampled with colour's own (Sprague) interpolation.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass

import colour
import numpy as np

from neuralbrdf.errors import InputError
from neuralbrdf.geometry import array_namespace_of
from neuralbrdf.physics.fresnel import fresnel_conductor, fresnel_dielectric
from neuralbrdf.physics.microfacet import microfacet_brdf
from neuralbrdf.physics.optical_constants import gold_complex_index
from neuralbrdf.physics.thin_film import thin_film_reflectance

COLOURCHECKER = "BabelColor Average"


def colourchecker_reflectance(patch: str, wavelengths_nm: np.ndarray) -> np.ndarray:
    """Spectral reflectance ``[W]`` of a ColorChecker patch, Sprague-interpolated by colour.

    Raises :class:`InputError` for wavelengths outside the patch's measured range (380–730 nm).
    """
    sd = colour.SDS_COLOURCHECKERS[COLOURCHECKER][patch]
    lo, hi = float(sd.wavelengths[0]), float(sd.wavelengths[-1])
    if np.any((wavelengths_nm < lo) | (wavelengths_nm > hi)):
        raise InputError(
            f"ColorChecker patch {patch!r} is tabulated on {lo:g}–{hi:g} nm; "
            f"got wavelengths {wavelengths_nm.min():g}–{wavelengths_nm.max():g} nm"
        )
    return np.clip(np.asarray(sd[wavelengths_nm], dtype=np.float64), 0.0, None)


def _checked_inputs(wi, wo, wavelengths_nm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    wavelengths = np.asarray(wavelengths_nm, dtype=np.float64)
    if wi.ndim != 2 or wi.shape[-1] != 3 or wi.shape != wo.shape:
        raise InputError(f"wi and wo must both be [N, 3] arrays, got {wi.shape} and {wo.shape}")
    if not (np.all(np.isfinite(wi)) and np.all(np.isfinite(wo))):
        raise InputError("wi and wo must be finite unit vectors")
    if wavelengths.ndim != 1 or not np.all(wavelengths > 0) or not np.all(np.isfinite(wavelengths)):
        raise InputError(
            f"wavelengths_nm must be a 1-D array of positive, finite nm; got shape {wavelengths.shape}"
        )
    return wi, wo, wavelengths


def _lambertian(wi, wo, albedo):
    """``albedo / π`` where both directions are above the horizon, else 0 (array API)."""
    xp = array_namespace_of(wi, wo, albedo)
    above = (wi[..., 2] > 0.0) & (wo[..., 2] > 0.0)
    one = xp.ones_like(wi[..., 2])
    return xp.where(above, one / math.pi, one * 0.0)[..., None] * albedo


def _grid_spectra(spectra: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Spectra ``[W]`` as ``[1, W]`` rows, so that ``brdf_from_spectra`` returns ``[N, W]``."""
    return {name: np.asarray(values, dtype=np.float64)[None, :] for name, values in spectra.items()}


@dataclass(frozen=True)
class LambertianReference:
    """Munsell N9 white reference: an ideal Lambertian reflector of reflectance 0.79.

    The report calibrates against a Munsell N9 sheet taken to reflect 79 % of a perfect
    reflecting diffuser at every wavelength and angle (report §2.1.1, Eq. 2.3), i.e. a constant
    BRDF ``0.79 / π`` sr⁻¹.  Real N9 sheets are slightly glossy and not perfectly flat
    spectrally; the stand-in is the idealisation that Eq. 2.3 assumes, so that calibration
    against it is exact.
    """

    name: str = "munsell_n9"
    reflectance: float = 0.79

    def spectra(self, wavelengths_nm) -> dict[str, np.ndarray]:
        return {"albedo": np.full(np.shape(wavelengths_nm), self.reflectance)}

    def brdf_from_spectra(self, wi, wo, spectra):
        return _lambertian(wi, wo, spectra["albedo"])

    def brdf(self, wi, wo, wavelengths_nm) -> np.ndarray:
        wi, wo, wavelengths = _checked_inputs(wi, wo, wavelengths_nm)
        return self.brdf_from_spectra(wi, wo, _grid_spectra(self.spectra(wavelengths)))


class _DiffuseAndSpecular(abc.ABC):
    """``f = rho_d(lambda) / π + w_s · F D G / (4 cos_i cos_o)``: Lambertian base plus a GGX lobe.

    Subclasses provide ``name``, ``alpha`` (GGX roughness) and the two spectra, and may
    override the lobe's weight ``specular_weight``.
    """

    name: str
    alpha: float
    specular_weight: float = 1.0

    @abc.abstractmethod
    def diffuse_albedo(self, wavelengths_nm: np.ndarray) -> np.ndarray:
        """Lambertian albedo ``[W]`` of the base."""

    @abc.abstractmethod
    def fresnel_spectra(self, wavelengths_nm: np.ndarray) -> dict[str, np.ndarray]:
        """The per-wavelength quantities ``[W]`` the Fresnel term needs (may be empty)."""

    @abc.abstractmethod
    def fresnel(self, cos_theta_d, spectra):
        """Fresnel reflectance of the microfacets at ``cos_theta_d = wi·h`` ``[N, 1]`` from
        :meth:`spectra` shaped ``[1, W]`` or ``[N, 1]`` (array API); broadcasts to ``[N, W]``."""

    def spectra(self, wavelengths_nm) -> dict[str, np.ndarray]:
        return {"albedo": self.diffuse_albedo(wavelengths_nm), **self.fresnel_spectra(wavelengths_nm)}

    def brdf_from_spectra(self, wi, wo, spectra):
        lobe = microfacet_brdf(wi, wo, self.alpha, lambda cos_d: self.fresnel(cos_d[..., None], spectra))
        return _lambertian(wi, wo, spectra["albedo"]) + self.specular_weight * lobe

    def brdf(self, wi, wo, wavelengths_nm) -> np.ndarray:
        wi, wo, wavelengths = _checked_inputs(wi, wo, wavelengths_nm)
        values = self.brdf_from_spectra(wi, wo, _grid_spectra(self.spectra(wavelengths)))
        return np.broadcast_to(values, (wi.shape[0], wavelengths.size)).copy()


@dataclass(frozen=True)
class GlossyInk(_DiffuseAndSpecular):
    """Process ink (cyan, magenta): a diffuse pigment layer under a smooth-ish clear binder.

    Light scattered by the pigment gives a Lambertian base whose albedo is the ColorChecker patch
    of the same name (BabelColor average).  The binder/air interface adds a weak rough
    dielectric reflection: a GGX lobe (roughness ``alpha``) with the exact unpolarised dielectric
    Fresnel term of index ``eta`` ≈ 1.5 (4 % at normal incidence, rising towards grazing), flat
    in wavelength, so the highlight has the illuminant's colour and the chromaticity barely
    changes with angle.  The two terms are added without energy exchange (a common, slightly
    energy-gaining simplification that keeps the BRDF reciprocal).
    """

    name: str
    patch: str
    alpha: float = 0.25
    eta: float = 1.5

    def diffuse_albedo(self, wavelengths_nm):
        return colourchecker_reflectance(self.patch, wavelengths_nm)

    def fresnel_spectra(self, wavelengths_nm):
        return {}

    def fresnel(self, cos_theta_d, spectra):
        return fresnel_dielectric(cos_theta_d, self.eta)


@dataclass(frozen=True)
class MetallicInk(_DiffuseAndSpecular):
    """Gold metallic ink: gold flakes covering most of the surface, a yellow binder elsewhere.

    A fraction ``metal_fraction`` of the surface is rough gold: a GGX lobe (roughness ``alpha``)
    whose Fresnel term is the exact conductor reflectance of gold's spectral complex index
    ``n + i k`` (Mitsuba's ``Au`` tables, luxpop / Palik), high in the red and low in the blue,
    which gives the highlight its gold colour.  The remaining area is a diffusely reflecting
    binder with the ColorChecker ``yellow`` spectrum.  The area-weighted mix of two
    energy-conserving BRDFs conserves energy.
    """

    name: str = "gold"
    alpha: float = 0.2
    metal_fraction: float = 0.9
    binder_patch: str = "yellow"

    @property
    def specular_weight(self) -> float:
        return self.metal_fraction

    def diffuse_albedo(self, wavelengths_nm):
        binder = colourchecker_reflectance(self.binder_patch, wavelengths_nm)
        return (1.0 - self.metal_fraction) * binder

    def fresnel_spectra(self, wavelengths_nm):
        n, k = gold_complex_index(wavelengths_nm)
        return {"n": n, "k": k}

    def fresnel(self, cos_theta_d, spectra):
        return fresnel_conductor(cos_theta_d, spectra["n"], spectra["k"])


@dataclass(frozen=True)
class GoniochromaticInk(_DiffuseAndSpecular):
    """Goniochromatic (interference) ink: thin-film coated flakes over a greenish-blue base.

    Effect pigments are platelets of mica (index ≈ 1.58) coated with a thin layer of titanium
    dioxide (≈ 2.4).  Light reflected at the top and bottom of the coating interferes, so the
    flakes' reflectance is the Airy reflectance of the film
    (:func:`neuralbrdf.physics.thin_film.thin_film_reflectance`), whose peaks move to shorter
    wavelengths as the angle inside the film grows.  With a 260 nm film the specular highlight
    is greenish-blue near normal incidence and turns blue-violet towards 60°.  The flakes lie
    roughly parallel to the surface (a GGX lobe of roughness ``alpha`` with the film reflectance
    as its Fresnel term); the ink underneath scatters diffusely with a darkened ColorChecker
    ``bluish green`` spectrum.  Dispersion of the indices is ignored.
    """

    name: str = "gonio"
    alpha: float = 0.15
    film_index: float = 2.4
    film_thickness_nm: float = 260.0
    substrate_index: float = 1.58
    base_patch: str = "bluish green"
    base_scale: float = 0.4

    def diffuse_albedo(self, wavelengths_nm):
        return self.base_scale * colourchecker_reflectance(self.base_patch, wavelengths_nm)

    def fresnel_spectra(self, wavelengths_nm):
        return {"wavelength_nm": np.asarray(wavelengths_nm, dtype=np.float64)}

    def fresnel(self, cos_theta_d, spectra):
        return thin_film_reflectance(
            cos_theta_d, spectra["wavelength_nm"], self.film_index, self.film_thickness_nm, self.substrate_index
        )


MATERIALS = {
    material.name: material
    for material in (
        LambertianReference(),
        GlossyInk(name="cyan", patch="cyan"),
        GlossyInk(name="magenta", patch="magenta"),
        MetallicInk(),
        GoniochromaticInk(),
    )
}

#: Validation materials: the same physical families with other spectra and parameters (a dark
#: blue and two other inks, a rougher gold ink with less metal, two other interference films).
#: Settings of spectral fits are chosen on these, never on the four stand-ins above, which are
#: the test materials of the report and the study.  No shipped measurement: simulate one
#: (``neuralbrdf simulate --material val-blue --plan DS3``).
VALIDATION_MATERIALS = {
    material.name: material
    for material in (
        GlossyInk(name="val-blue", patch="purplish blue", alpha=0.18),
        GlossyInk(name="val-orange", patch="orange", alpha=0.3, eta=1.6),
        GlossyInk(name="val-green", patch="green", alpha=0.12),
        MetallicInk(name="val-gold-rough", alpha=0.35, metal_fraction=0.75, binder_patch="orange yellow"),
        GoniochromaticInk(name="val-gonio-violet", alpha=0.2, film_thickness_nm=340.0, base_patch="purple",
                          base_scale=0.5),
        GoniochromaticInk(name="val-gonio-thin", alpha=0.1, film_thickness_nm=180.0, base_patch="blue",
                          base_scale=0.3),
    )
}

#: The white reference every measurement session is calibrated against.
REFERENCE_MATERIAL = "munsell_n9"


def get_material(name: str):
    """The stand-in or validation material called ``name``; :class:`InputError` listing the valid names otherwise."""
    try:
        return MATERIALS[name] if name in MATERIALS else VALIDATION_MATERIALS[name]
    except (KeyError, TypeError):
        raise InputError(
            f"unknown virtual material {name!r}; expected one of {', '.join([*MATERIALS, *VALIDATION_MATERIALS])}"
        ) from None
