"""A virtual goniospectrophotometer producing GCMS raw measurements (docs/formats.md#gcms-raw-measurement, docs/measure.md#the-virtual-goniospectrophotometer).

It stands in for the Murakami GCMS-3B of the report (§2.1.1, §3.2).  For a material with BRDF
``f`` (:mod:`neuralbrdf.virtual.materials`) and a signed in-plane geometry it reports, at the 35
GCMS wavelengths (390–730 nm)::

    beta_raw(λ) = π f(λ) · R(λ) · (1 + noise_rel · n1) + noise_abs · n2,    n1, n2 ~ N(0, 1)

``π f`` is the radiance factor (a perfect reflecting diffuser, ``f = 1/π``, has ``beta = 1``),
and ``R(λ)`` is the instrument's spectral response (:func:`instrument_response`): a
tungsten-halogen lamp (Planck radiator at 2856 K, the CIE illuminant A temperature) seen by a
silicon photodiode, normalised to 1 at its maximum on the GCMS grid.  ``R`` is common to the
sample and to the Munsell N9 reference, so calibration (report Eq. 2.3,
``f = 0.79/π · beta_sample / beta_munsell``) cancels it — which is what the virtual instrument
exists to exercise.

Noise is seeded: each material has its own stream, ``numpy.random.default_rng([seed,
crc32(name)])``, created on first use and advancing with every measurement, so a sample and its
reference never share noise, repeated measurements of a material differ, and a new instrument
with the same seed repeats the same session exactly.

The shipped measurements (``neuralbrdf/data/default/<material>_DS1.csv``) come from
:func:`regenerate_default_data` with :data:`DEFAULT_NOISE_REL`, :data:`DEFAULT_NOISE_ABS` and
:data:`DEFAULT_SEED`.
"""

from __future__ import annotations

import math
import zlib
from pathlib import Path

import numpy as np
from tqdm import tqdm

from neuralbrdf.data.gcms import GCMS_WAVELENGTHS_NM, GcmsMeasurement, write_gcms
from neuralbrdf.data.plans import in_plane_plan
from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import inplane_to_spherical, inplane_to_vectors
from neuralbrdf.virtual.materials import MATERIALS, get_material

#: Relative (multiplicative) noise of the shipped data: 1 % standard deviation, the order of a
#: goniospectrophotometer's repeatability.
DEFAULT_NOISE_REL = 0.01
#: Additive noise of the shipped data (radiance-factor units): a dark-signal floor of 1e-4.
DEFAULT_NOISE_ABS = 1e-4
#: Seed of the shipped data.
DEFAULT_SEED = 2026
#: Plan of the shipped data (docs/measure.md#sampling-plans).
DEFAULT_PLAN = "DS1"
#: Folder of the shipped GCMS raw files.
DEFAULT_DATA_DIR = Path(__file__).resolve().parents[1] / "data" / "default"
#: Decimals kept in the shipped files: 1e-6 in beta, 100 times below the additive noise.
DEFAULT_DATA_DECIMALS = 6

#: Wavelengths (nm) of :meth:`VirtualGoniospectrophotometer.ground_truth`, those of a
#: calibrated table (docs/formats.md#gcms-raw-measurement).
GROUND_TRUTH_WAVELENGTHS_NM = np.arange(400.0, 701.0, 10.0)

#: Colour temperature (K) of the tungsten-halogen lamp (CIE illuminant A).
LAMP_TEMPERATURE_K = 2856.0
#: Second radiation constant ``c2 = h c / k`` in nm·K (the value CIE 15 uses for illuminant A).
SECOND_RADIATION_CONSTANT_NM_K = 1.4388e7
#: Silicon photodiode quantum-efficiency model ``QE = 1 - exp(-(λ - cutoff) / scale)``: losses
#: to surface recombination grow towards the blue.
DETECTOR_QE_CUTOFF_NM = 300.0
DETECTOR_QE_SCALE_NM = 100.0


def _lamp_and_detector(wavelengths_nm: np.ndarray) -> np.ndarray:
    """Unnormalised lamp spectral radiance (Planck) times detector responsivity (∝ λ · QE)."""
    planck = wavelengths_nm**-5.0 / np.expm1(
        SECOND_RADIATION_CONSTANT_NM_K / (wavelengths_nm * LAMP_TEMPERATURE_K)
    )
    quantum_efficiency = 1.0 - np.exp(-(wavelengths_nm - DETECTOR_QE_CUTOFF_NM) / DETECTOR_QE_SCALE_NM)
    return planck * wavelengths_nm * quantum_efficiency


_RESPONSE_SCALE = float(_lamp_and_detector(GCMS_WAVELENGTHS_NM).max())


def instrument_response(wavelengths_nm) -> np.ndarray:
    """Relative spectral response ``R(λ)`` of lamp and detector, 1 at its GCMS-grid maximum.

    Defined above the detector cutoff (300 nm); smooth and increasing over 390–730 nm (from
    about 0.02 to 1).
    """
    wavelengths = np.asarray(wavelengths_nm, dtype=np.float64)
    if not np.all(wavelengths > DETECTOR_QE_CUTOFF_NM) or not np.all(np.isfinite(wavelengths)):
        raise InputError(
            f"the instrument response is defined for finite wavelengths above "
            f"{DETECTOR_QE_CUTOFF_NM:g} nm"
        )
    return _lamp_and_detector(wavelengths) / _RESPONSE_SCALE


def _inplane_angles(theta_i, theta_r) -> tuple[np.ndarray, np.ndarray]:
    theta_i = np.asarray(theta_i, dtype=np.float64)
    theta_r = np.asarray(theta_r, dtype=np.float64)
    if theta_i.ndim != 1 or theta_i.shape != theta_r.shape or theta_i.size == 0:
        raise InputError(
            f"theta_i and theta_r must be non-empty 1-D arrays of equal length, got shapes "
            f"{theta_i.shape} and {theta_r.shape}"
        )
    for name, angles in (("theta_i", theta_i), ("theta_r", theta_r)):
        bad = np.flatnonzero(~(np.abs(angles) < 90.0))
        if bad.size:
            raise InputError(
                f"{name}[{bad[0]}] = {angles[bad[0]]!r}: signed in-plane angles must lie in "
                f"(-90, 90) degrees",
                key=name,
            )
    return theta_i, theta_r


class VirtualGoniospectrophotometer:
    """A seeded, noisy GCMS-style instrument measuring the virtual materials.

    Parameters
    ----------
    noise_rel:
        Standard deviation of the multiplicative Gaussian noise (0.01 = 1 %).
    noise_abs:
        Standard deviation of the additive Gaussian noise, in radiance-factor units.
    seed:
        Seed of the per-material noise streams (see the module docstring).
    """

    def __init__(self, noise_rel: float = 0.0, noise_abs: float = 0.0, seed: int = 0) -> None:
        for name, value in (("noise_rel", noise_rel), ("noise_abs", noise_abs)):
            if not (math.isfinite(value) and value >= 0.0):
                raise InputError(f"{name} must be a finite number >= 0, got {value!r}", key=name)
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise InputError(f"seed must be a non-negative integer, got {seed!r}", key="seed")
        self.noise_rel = float(noise_rel)
        self.noise_abs = float(noise_abs)
        self.seed = int(seed)
        self._streams: dict[str, np.random.Generator] = {}

    def _stream(self, material_name: str) -> np.random.Generator:
        if material_name not in self._streams:
            key = zlib.crc32(material_name.encode("utf-8"))
            self._streams[material_name] = np.random.default_rng([self.seed, key])
        return self._streams[material_name]

    def measure(self, material_name: str, theta_i, theta_r) -> GcmsMeasurement:
        """Raw GCMS measurement of a material at signed in-plane angles (degrees, ``[N]``)."""
        material = get_material(material_name)
        theta_i, theta_r = _inplane_angles(theta_i, theta_r)
        wi, wo = inplane_to_vectors(theta_i, theta_r)
        response = instrument_response(GCMS_WAVELENGTHS_NM)
        clean = math.pi * material.brdf(wi, wo, GCMS_WAVELENGTHS_NM) * response
        rng = self._stream(material.name)
        relative = rng.standard_normal(clean.shape)
        additive = rng.standard_normal(clean.shape)
        beta = clean * (1.0 + self.noise_rel * relative) + self.noise_abs * additive
        source = (
            f"virtual GCMS: {material.name} (seed {self.seed}, noise_rel {self.noise_rel:g}, "
            f"noise_abs {self.noise_abs:g})"
        )
        return GcmsMeasurement(theta_i, theta_r, beta, source=source)

    def measure_plan(self, material_name: str, plan_name: str) -> GcmsMeasurement:
        """Raw GCMS measurement of a material on an in-plane plan (DS1–DS4, docs/measure.md#sampling-plans)."""
        return self.measure(material_name, *in_plane_plan(plan_name))

    @staticmethod
    def ground_truth(material_name: str, theta_i, theta_r) -> BrdfTable:
        """Noiseless spectral BRDF (sr⁻¹, 400–700 nm at 10 nm) at signed in-plane angles.

        Rows are in input order; angles become spherical with
        :func:`neuralbrdf.geometry.inplane_to_spherical`, as calibration does.
        """
        material = get_material(material_name)
        theta_i, theta_r = _inplane_angles(theta_i, theta_r)
        values = material.brdf(*inplane_to_vectors(theta_i, theta_r), GROUND_TRUTH_WAVELENGTHS_NM)
        return BrdfTable(
            *inplane_to_spherical(theta_i, theta_r),
            values,
            GROUND_TRUTH_WAVELENGTHS_NM.copy(),
            source=f"virtual ground truth: {material.name}",
        )


def default_data_path(material: str, plan: str = DEFAULT_PLAN) -> Path:
    """Path of a shipped GCMS raw file: ``neuralbrdf/data/default/{material}_{plan}.csv``."""
    get_material(material)
    in_plane_plan(plan)
    return DEFAULT_DATA_DIR / f"{material}_{plan}.csv"


def regenerate_default_data(out_dir=None, progress: bool = True) -> list[Path]:
    """Write the shipped DS1 GCMS raw files of all five materials; return their paths.

    Uses a fresh instrument with the default noise and seed, measuring the materials in the
    order of :data:`~neuralbrdf.virtual.materials.MATERIALS`, so the output is reproducible.
    Beta is stored to :data:`DEFAULT_DATA_DECIMALS` decimals.  ``out_dir`` defaults to
    :data:`DEFAULT_DATA_DIR`.
    """
    folder = DEFAULT_DATA_DIR if out_dir is None else Path(out_dir)
    instrument = VirtualGoniospectrophotometer(DEFAULT_NOISE_REL, DEFAULT_NOISE_ABS, DEFAULT_SEED)
    paths = []
    for name in tqdm(MATERIALS, desc="virtual GCMS", unit="material", disable=not progress):
        raw = instrument.measure_plan(name, DEFAULT_PLAN)
        stored = np.round(raw.beta, DEFAULT_DATA_DECIMALS)
        path = folder / f"{name}_{DEFAULT_PLAN}.csv"
        write_gcms(GcmsMeasurement(raw.theta_i, raw.theta_r, stored, source=raw.source), path)
        paths.append(path)
    return paths
