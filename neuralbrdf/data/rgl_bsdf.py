"""Measured BRDFs of the RGL material database (Dupuy & Jakob 2018, *An adaptive parameterization
for efficient material acquisition and rendering*, EPFL; data CC0): ``NAME_rgb.bsdf`` and
``NAME_spec.bsdf``.

**Format.** A Mitsuba ``tensor_file`` (:mod:`neuralbrdf.data.tensor_file`) with the fields
Mitsuba 3's ``measured`` BSDF plugin (``src/bsdfs/measured.cpp``) and the RGL's reader
``powitacq`` read: ``description`` (``u8`` text), ``theta_i`` and ``phi_i`` (``f32``, radians:
the incident directions measured; one ``phi_i`` = isotropic), ``ndf`` and ``sigma`` (``f32``
2-D: the microfacet distribution and its projected area), ``vndf`` and ``luminance`` (``f32``
``[n_φi, n_θi, ·, ·]``: the warps of the adaptive parameterisation), ``jacobian`` (``u8 [1]``),
and either ``rgb`` (``f32 [n_φi, n_θi, 3, n, n]``, linear sRGB) or ``spectra`` (``f32 [n_φi,
n_θi, n_λ, n, n]``) with ``wavelengths`` (``f32 [n_λ]``, nm).  Other fields (``version``,
``valid``: a bitmask of the cells the instrument saw) are not used.  :meth:`RglBsdf.load` checks
every field Mitsuba reads — names, types, ranks, shapes, finite values, positive warps,
isotropy — so that every bad file is one :class:`~neuralbrdf.errors.InputError` naming the file
before Mitsuba is called.  Anisotropic files (several ``phi_i``) are refused.

**Evaluation** is Mitsuba's own ``measured`` plugin (the independent renderer of the data): RGB
files in ``llvm_ad_rgb``, spectral files in ``llvm_ad_spectral`` (Mitsuba loads each kind only
in its own variant), which interpolates linearly between the file's ``theta_i`` and, for spectral
files, between its wavelengths.  Directions follow the library's convention (docs/formats.md):
``wi`` towards the light, ``wo`` towards the viewer.  The measurement's ``theta_i`` is the light's
direction, which the plugin takes as ``si.wi``; its ``eval`` includes the cosine of ``wo``, so
``f(wi, wo) = eval(si.wi = wi, wo) / cos θo`` in sr⁻¹.  The data is not reciprocal
(``f(wi, wo) ≠ f(wo, wi)`` for peaked materials), so this order matters.

**Negative values.**  Real RGB files store negative channels where a measured spectrum lies
outside the sRGB gamut.  Every value evaluated from a file is clipped to 0 — the rule of the
RGL's own reader ``powitacq``, which clamps each interpolated channel — and loading a file with
negative stored values warns once with their count, fraction and most negative value.  Spectral
files are clipped by the same rule (the database's spectra are not negative).

**Bands.**  A spectral file is read at the report's bands, 400–700 nm every 10 nm
(:data:`~neuralbrdf.data.calibration.CALIBRATED_WAVELENGTHS_NM`); a file that does not cover them
is refused.
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from neuralbrdf.atomic import file_version
from neuralbrdf.data.calibration import CALIBRATED_WAVELENGTHS_NM
from neuralbrdf.data.plans import plan_label, plan_spherical
from neuralbrdf.data.table import BrdfTable
from neuralbrdf.data.tensor_file import read_tensor_file, shown, write_tensor_file
from neuralbrdf.errors import InputError, one_line
from neuralbrdf.geometry import spherical_pair_to_vectors

SUFFIX = ".bsdf"
#: Mitsuba variant in which the ``measured`` plugin loads each kind of file.
RGB_VARIANT = "llvm_ad_rgb"
SPECTRAL_VARIANT = "llvm_ad_spectral"
#: Fields every file needs, with their dtype and rank (Mitsuba's ``measured.cpp`` checks).
COMMON_FIELDS = {
    "description": ("u1", 1),
    "theta_i": ("<f4", 1),
    "phi_i": ("<f4", 1),
    "ndf": ("<f4", 2),
    "sigma": ("<f4", 2),
    "vndf": ("<f4", 4),
    "luminance": ("<f4", 4),
    "jacobian": ("u1", 1),
}
#: Direction pairs per call of the plugin (bounds Dr.Jit's memory).
CHUNK_PAIRS = 1 << 18

#: Negative values of a distribution field (``ndf``, ``sigma``, ``vndf``, ``luminance``) within this
#: fraction of its largest value are float round-off, not a broken file: the database's
#: ``ilm_solo_m_68_rgb.bsdf`` holds a luminance of -3.98e-10.
NEGATIVE_TOLERANCE = 1e-6


@dataclass(frozen=True)
class NegativeValues:
    """Negative stored values of a file: how many, of how many, and the most negative."""

    count: int
    total: int
    most_negative: float

    def describe(self, path: Path, field: str) -> str:
        return (f"{path}: {self.count} of {self.total} stored {field} values ({self.count / self.total:.1%}) are "
                f"negative (colours outside sRGB; most negative {self.most_negative:.3g}); every value evaluated "
                "from it is clipped to 0, as the RGL's reader powitacq does")


@dataclass(frozen=True, eq=False)
class RglBsdf:
    """A checked RGL measurement (module docstring); values come from Mitsuba's ``measured`` plugin."""

    name: str
    path: Path
    description: str
    theta_i_deg: np.ndarray
    #: The file's own bands (nm) for a spectral file, ``None`` for an RGB file.
    wavelengths_nm: np.ndarray | None
    negative: NegativeValues | None

    @property
    def is_spectral(self) -> bool:
        return self.wavelengths_nm is not None

    @property
    def variant(self) -> str:
        """The Mitsuba variant its ``measured`` plugin loads in."""
        return SPECTRAL_VARIANT if self.is_spectral else RGB_VARIANT

    @classmethod
    def load(cls, path: str | PathLike[str]) -> RglBsdf:
        """Read and check ``path`` (module docstring); warns once about negative stored values."""
        path = Path(path)
        fields = read_tensor_file(path)
        spectral = _check_fields(fields, path)
        values_field = "spectra" if spectral else "rgb"
        values = fields[values_field]
        negative = None
        if (values < 0).any():
            negative = NegativeValues(int((values < 0).sum()), int(values.size), float(values.min()))
            warnings.warn(negative.describe(path, values_field), stacklevel=2)
        description = bytes(fields["description"]).decode("utf-8", errors="replace").strip("\0 ")
        return cls(
            name=path.stem,
            path=path,
            description=description,
            theta_i_deg=np.degrees(fields["theta_i"].astype(np.float64)),
            wavelengths_nm=fields["wavelengths"].astype(np.float64) if spectral else None,
            negative=negative,
        )

    def evaluate(self, wi, wo, wavelengths_nm=None) -> np.ndarray:
        """BRDF in sr⁻¹ at unit direction pairs ``wi`` (light), ``wo`` (viewer) ``[N, 3]``: ``[N, 3]``
        linear sRGB for an RGB file; ``[N, W]`` at ``wavelengths_nm`` (default the report's 31 bands)
        for a spectral file.  Clipped at 0; 0 unless both directions are above the horizon."""
        wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
        if self.is_spectral:
            wavelengths_nm = CALIBRATED_WAVELENGTHS_NM if wavelengths_nm is None else np.asarray(wavelengths_nm, float)
        elif wavelengths_nm is not None:
            raise ValueError(f"{self.path} is an RGB measurement: it has no wavelengths")
        chunks = [self._chunk(wi[s:s + CHUNK_PAIRS], wo[s:s + CHUNK_PAIRS], wavelengths_nm)
                  for s in range(0, len(wi), CHUNK_PAIRS)]
        eval_cos = np.concatenate(chunks) if chunks else np.zeros((0, 3 if wavelengths_nm is None else
                                                                       len(wavelengths_nm)))
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        f = np.where(above[:, None], eval_cos / np.where(above, wo[:, 2], 1.0)[:, None], 0.0)
        return np.clip(f, 0.0, None)

    def values(self, wi, wo, wavelength=None) -> np.ndarray:
        """The evaluator interface of :mod:`neuralbrdf.evaluation.scores`: ``[N, 3]``, or ``[N]`` at
        one wavelength per row (nm) for a spectral file."""
        if not self.is_spectral:
            return self.evaluate(wi, wo)
        wavelength = np.asarray(wavelength, dtype=np.float64)
        out = np.empty(len(wavelength))
        for nm in np.unique(wavelength):
            rows = wavelength == nm
            out[rows] = self.evaluate(np.asarray(wi)[rows], np.asarray(wo)[rows], [nm])[:, 0]
        return out

    def _chunk(self, wi: np.ndarray, wo: np.ndarray, wavelengths_nm) -> np.ndarray:
        """``eval`` of the plugin (``f · cos θo``, not clipped) at up to :data:`CHUNK_PAIRS` pairs."""
        import drjit as dr

        with mitsuba_variant(self.variant) as mi:
            bsdf = _plugin(self)
            si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
            si.wi = mi.Vector3f(*(mi.Float(wi[:, k].astype(np.float32)) for k in range(3)))
            wo_ = mi.Vector3f(*(mi.Float(wo[:, k].astype(np.float32)) for k in range(3)))
            context = mi.BSDFContext()
            if wavelengths_nm is None:
                return np.asarray(bsdf.eval(context, si, wo_), dtype=np.float64).T
            columns = []
            lanes = dr.size_v(mi.Spectrum)
            for start in range(0, len(wavelengths_nm), lanes):
                group = [float(nm) for nm in wavelengths_nm[start:start + lanes]]
                # opaque: one kernel for every wavelength, not one compiled per literal value
                padded = group + group[-1:] * (lanes - len(group))
                si.wavelengths = mi.Spectrum(*(dr.opaque(mi.Float, nm) for nm in padded))
                columns.append(np.asarray(bsdf.eval(context, si, wo_), dtype=np.float64)[: len(group)])
            return np.concatenate(columns).T


_PLUGINS: dict[tuple, object] = {}


def measured_plugin(brdf: RglBsdf):
    """Mitsuba's ``measured`` BSDF of a checked file, in the current variant (of the file's kind)."""
    import mitsuba as mi

    try:
        return mi.load_dict({"type": "measured", "filename": str(brdf.path.resolve())})
    except RuntimeError as error:
        raise InputError(f"Mitsuba's measured plugin refused it: {one_line(error)}", path=brdf.path) from None


def _plugin(brdf: RglBsdf):
    """:func:`measured_plugin`, kept while the file is unchanged."""
    import mitsuba as mi

    key = (file_version(brdf.path), mi.variant())
    if key not in _PLUGINS:
        _PLUGINS.clear()  # one file at a time: a plugin holds the whole table
        _PLUGINS[key] = measured_plugin(brdf)
    return _PLUGINS[key]


@contextlib.contextmanager
def mitsuba_variant(variant: str) -> Iterator[object]:
    """``mitsuba`` with ``variant`` selected; the variant selected before is restored afterwards."""
    import mitsuba as mi

    previous = mi.variant()
    mi.set_variant(variant)
    try:
        yield mi
    finally:
        if previous is not None and previous != variant:
            mi.set_variant(previous)


def _fail(path: Path, field: str, message: str) -> InputError:
    return InputError(f"field {field!r}: {message}", path=path)


def _check_fields(fields: dict[str, np.ndarray], path: Path) -> bool:
    """Check what Mitsuba's ``measured`` plugin reads (module docstring); whether the file is spectral."""
    spectral = "spectra" in fields
    values_field = "spectra" if spectral else "rgb"
    required = {**COMMON_FIELDS, values_field: ("<f4", 5), **({"wavelengths": ("<f4", 1)} if spectral else {})}
    missing = [name for name in required if name not in fields]
    if missing or (spectral and "rgb" in fields):
        names = [shown(name) for name in list(fields)[:12]]
        more = f" and {len(fields) - len(names)} more" if len(fields) > len(names) else ""
        found = ", ".join(names) + more or "none"
        raise InputError(f"not an RGL measured BRDF: missing field(s) {', '.join(missing) or 'none'} (it has {found}); "
                         "expected description, theta_i, phi_i, ndf, sigma, vndf, luminance, jacobian and either rgb "
                         "or spectra with wavelengths", path=path)
    for name, (dtype, rank) in required.items():
        array = fields[name]
        if array.dtype != np.dtype(dtype) or array.ndim != rank:
            raise _fail(path, name, f"expected {np.dtype(dtype).name} of rank {rank}, got {array.dtype.name} of shape "
                        f"{list(array.shape)}")
        if array.dtype.kind == "f" and not np.all(np.isfinite(array)):
            index = np.unravel_index(int(np.argmax(~np.isfinite(array))), array.shape)
            raise _fail(path, name, f"non-finite value {array[index]} at index {list(map(int, index))}")
    n_phi, n_theta = len(fields["phi_i"]), len(fields["theta_i"])
    if n_phi != 1:
        raise _fail(path, "phi_i", f"{n_phi} incident azimuths: an anisotropic measurement; only isotropic files (one "
                    "phi_i) are read")
    theta = fields["theta_i"].astype(np.float64)
    if n_theta < 1:
        raise _fail(path, "theta_i", "no incident angle; expected increasing angles within [0, pi/2] rad")
    wrong = (theta < 0) | (theta > np.pi / 2 + 1e-4) | np.concatenate([[False], np.diff(theta) <= 0])
    if wrong.any():
        first = int(np.argmax(wrong))
        raise _fail(path, "theta_i", f"expected increasing incident angles within [0, pi/2] rad, got "
                    f"{theta[first]:.6g} at index {first} ({int(wrong.sum())} of {n_theta} out of order or range)")
    values, luminance, vndf = fields[values_field], fields["luminance"], fields["vndf"]
    channels = len(fields["wavelengths"]) if spectral else 3
    n = luminance.shape[2]
    expected = {
        "vndf": (n_phi, n_theta, *vndf.shape[2:]),
        "luminance": (n_phi, n_theta, n, n),
        values_field: (n_phi, n_theta, channels, n, n),
        "jacobian": (1,),
    }
    for name, shape in expected.items():
        if fields[name].shape != shape:
            raise _fail(path, name, f"expected shape {list(shape)} (from phi_i, theta_i, luminance"
                        f"{', wavelengths' if spectral else ''}), got {list(fields[name].shape)}")
    for name in ("ndf", "sigma", "vndf", "luminance"):
        array = fields[name]
        if min(array.shape[-2:]) < 2:
            raise _fail(path, name, f"a grid needs at least 2 x 2 nodes, got {list(array.shape)}")
        if array.min() < -NEGATIVE_TOLERANCE * max(float(array.max()), 0.0):
            raise _fail(path, name, f"negative value {float(array.min()):.3g}; a distribution is >= 0")
        if name in ("vndf", "luminance") and np.any(array.sum(axis=(-2, -1)) <= 0):
            raise _fail(path, name, "a slice sums to 0; every incident direction needs a distribution to sample")
    if fields["jacobian"][0] and not (fields["sigma"] > 0).all():
        raise _fail(path, "sigma", "a projected area of 0, which the plugin divides by")
    if spectral:
        bands = fields["wavelengths"].astype(np.float64)
        if np.any(np.diff(bands) <= 0):
            raise _fail(path, "wavelengths", "expected increasing wavelengths (nm)")
        low, high = CALIBRATED_WAVELENGTHS_NM[0], CALIBRATED_WAVELENGTHS_NM[-1]
        if bands[0] > low or bands[-1] < high:
            raise _fail(path, "wavelengths", f"covers {bands[0]:g}-{bands[-1]:g} nm; the report's bands {low:g}-"
                        f"{high:g} nm need a file that covers them")
    return spectral


def sample_rgl(brdf: RglBsdf, plan_name: str) -> BrdfTable:
    """:class:`BrdfTable` of a measurement on a sampling plan: spectral at the report's 31 bands for a
    spectral file, linear sRGB for an RGB file (sr⁻¹)."""
    angles = plan_spherical(plan_name)
    wi, wo = spherical_pair_to_vectors(*angles)
    if brdf.is_spectral:
        return BrdfTable(*angles, brdf.evaluate(wi, wo), CALIBRATED_WAVELENGTHS_NM.copy(),
                         source=f"rgl:{brdf.name}:{plan_label(plan_name)}")
    return BrdfTable(*angles, values=brdf.evaluate(wi, wo), source=f"rgl:{brdf.name}:{plan_label(plan_name)}")


def write_rgl_bsdf(path: str | PathLike[str], *, theta_i_deg, ndf, sigma, vndf, luminance, values,
                   wavelengths_nm=None, description: str = "", jacobian: bool = True) -> None:
    """Write an isotropic RGL measurement (module docstring) from its arrays: ``theta_i_deg`` ``[n_θi]``,
    ``ndf`` and ``sigma`` 2-D, ``vndf`` ``[n_θi, a, b]``, ``luminance`` ``[n_θi, n, n]`` and ``values``
    ``[n_θi, 3, n, n]`` (RGB) or ``[n_θi, n_λ, n, n]`` with ``wavelengths_nm`` (spectral)."""
    f32 = lambda array: np.asarray(array, dtype="<f4")  # noqa: E731
    fields = {
        "description": np.frombuffer(description.encode(), dtype="u1"),
        "phi_i": f32([0.0]),
        "theta_i": f32(np.radians(theta_i_deg)),
        "ndf": f32(ndf),
        "sigma": f32(sigma),
        "vndf": f32(vndf)[None],
        "luminance": f32(luminance)[None],
        "jacobian": np.array([int(jacobian)], dtype="u1"),
    }
    if wavelengths_nm is None:
        fields["rgb"] = f32(values)[None]
    else:
        fields.update(wavelengths=f32(wavelengths_nm), spectra=f32(values)[None])
    write_tensor_file(path, fields)
