"""The virtual goniospectrophotometer and its stand-in materials (docs/measure.md#the-virtual-goniospectrophotometer): symmetries, energy,
goniochromatism (CIE chromaticities from colour-science), the instrument response that
calibration must cancel, seeded noise and the shipped-data writer."""

from __future__ import annotations

import math

import colour
import numpy as np
import pytest

from neuralbrdf.data.calibration import calibrate
from neuralbrdf.data.gcms import GCMS_WAVELENGTHS_NM, read_gcms
from neuralbrdf.data.plans import in_plane_plan
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import inplane_to_vectors, normalize, spherical_to_vector
from neuralbrdf.physics.microfacet import ggx_distribution
from neuralbrdf.virtual import (
    DEFAULT_NOISE_ABS,
    DEFAULT_NOISE_REL,
    DEFAULT_SEED,
    MATERIALS,
    REFERENCE_MATERIAL,
    VirtualGoniospectrophotometer,
    default_data_path,
    get_material,
    instrument_response,
    regenerate_default_data,
)

WAVELENGTHS = np.arange(400.0, 701.0, 10.0)
MATERIAL_NAMES = sorted(MATERIALS)


def random_hemisphere(n: int, seed: int) -> np.ndarray:
    """Uniform unit vectors on the upper hemisphere."""
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return normalize(v * np.array([1.0, 1.0, 0.0]) + np.abs(v) * np.array([0.0, 0.0, 1.0]))


def rotate_z(v: np.ndarray, angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return v @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


# --------------------------------------------------------------------------- symmetries


@pytest.mark.parametrize("name", MATERIAL_NAMES)
def test_material_is_reciprocal_isotropic_and_dark_below_horizon(name):
    material = get_material(name)
    wi, wo = random_hemisphere(500, seed=1), random_hemisphere(500, seed=2)
    f = material.brdf(wi, wo, WAVELENGTHS)
    assert f.shape == (500, WAVELENGTHS.size) and f.dtype == np.float64
    assert np.all(np.isfinite(f)) and np.all(f >= 0)
    np.testing.assert_allclose(material.brdf(wo, wi, WAVELENGTHS), f, rtol=1e-12)
    rotated = material.brdf(rotate_z(wi, 1.1), rotate_z(wo, 1.1), WAVELENGTHS)
    np.testing.assert_allclose(rotated, f, rtol=1e-10)
    below = wo * np.array([1.0, 1.0, -1.0])
    np.testing.assert_array_equal(material.brdf(wi, below, WAVELENGTHS), 0.0)
    np.testing.assert_array_equal(material.brdf(below, wi, WAVELENGTHS), 0.0)


@pytest.mark.parametrize("name", MATERIAL_NAMES)
def test_in_plane_mirror_symmetry(name):
    theta_i, theta_r = in_plane_plan("DS2")
    material = get_material(name)
    f = material.brdf(*inplane_to_vectors(theta_i, theta_r), WAVELENGTHS)
    f_mirror = material.brdf(*inplane_to_vectors(-theta_i, -theta_r), WAVELENGTHS)
    np.testing.assert_allclose(f_mirror, f, rtol=1e-12)


def test_unknown_material_lists_valid_names():
    with pytest.raises(InputError, match="expected one of munsell_n9, cyan, magenta, gold, gonio"):
        get_material("silver")


def test_brdf_rejects_malformed_directions():
    with pytest.raises(InputError, match=r"\[N, 3\]"):
        get_material("gold").brdf(np.zeros((4, 2)), np.zeros((4, 2)), WAVELENGTHS)
    with pytest.raises(InputError, match="380–730 nm"):
        get_material("cyan").brdf(*inplane_to_vectors(np.array([0.0]), np.array([0.0])), np.array([800.0]))


# --------------------------------------------------------------------------- energy

SAMPLING_ALPHAS = (0.1, 0.3)


def sample_outgoing(wi: np.ndarray, n: int, rng) -> np.ndarray:
    """Equal mixture of cosine sampling and GGX half-vector sampling at each sampling alpha."""
    component = rng.integers(0, len(SAMPLING_ALPHAS) + 1, n)
    u = rng.random((n, 2))
    alpha = np.array((1.0, *SAMPLING_ALPHAS))[component]
    cos_h = 1.0 / np.sqrt(1.0 + alpha**2 * u[:, 0] / (1.0 - u[:, 0]))
    cos = np.where(component == 0, np.sqrt(u[:, 0]), cos_h)
    sin = np.sqrt(1.0 - cos**2)
    phi = 2.0 * math.pi * u[:, 1]
    v = np.stack([sin * np.cos(phi), sin * np.sin(phi), cos], axis=1)
    reflected = 2.0 * (v @ wi)[:, None] * v - wi
    return np.where((component == 0)[:, None], v, reflected)


def mixture_pdf(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Solid-angle density of :func:`sample_outgoing` (GGX part: D cos θh / (4 |wo·h|))."""
    h = normalize(wi + wo)
    pdf = np.clip(wo[:, 2], 0.0, None) / math.pi
    for alpha in SAMPLING_ALPHAS:
        pdf = pdf + ggx_distribution(h[:, 2], alpha) * h[:, 2] / (4.0 * np.abs((wo * h).sum(1)))
    return pdf / (len(SAMPLING_ALPHAS) + 1)


def directional_albedo(name: str, theta_i: float, n: int = 100_000):
    """MC estimate and standard error ``[W]`` of ∫ f(wi, wo) cos θo dωo."""
    wi = spherical_to_vector(np.array(theta_i), np.array(0.0))
    wo = sample_outgoing(wi, n, np.random.default_rng(7))
    above = wo[:, 2] > 0
    wo = np.where(above[:, None], wo, np.array([0.0, 0.0, 1.0]))
    weight = np.where(above, wo[:, 2] / mixture_pdf(wi, wo), 0.0)
    g = get_material(name).brdf(np.broadcast_to(wi, wo.shape), wo, WAVELENGTHS) * weight[:, None]
    return g.mean(0), g.std(0) / math.sqrt(n)


@pytest.mark.parametrize("theta_i", [0.0, 40.0, 80.0])
def test_munsell_albedo_is_079(theta_i):
    """Checks the estimator itself: the Lambertian reference reflects exactly 79 %."""
    albedo, error = directional_albedo(REFERENCE_MATERIAL, theta_i)
    assert np.all(error < 0.005)
    assert np.all(np.abs(albedo - 0.79) < 4.0 * error)


@pytest.mark.parametrize("theta_i", [0.0, 40.0, 80.0])
@pytest.mark.parametrize("name", ["cyan", "magenta", "gold", "gonio"])
def test_directional_albedo_at_most_one(name, theta_i):
    albedo, error = directional_albedo(name, theta_i)
    assert np.all(error < 0.005)
    assert np.all(albedo < 1.0 - 3.0 * error), albedo.max()


# --------------------------------------------------------------------------- colour

SHAPE = colour.SpectralShape(WAVELENGTHS[0], WAVELENGTHS[-1], 10.0)
CMFS = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(SHAPE)
D65 = colour.SDS_ILLUMINANTS["D65"].copy().align(SHAPE)


def chromaticity(spectrum: np.ndarray) -> np.ndarray:
    """CIE 1931 xy under D65 of a spectrum on :data:`WAVELENGTHS` (colour's integration)."""
    sd = colour.SpectralDistribution(dict(zip(WAVELENGTHS, spectrum)))
    return np.asarray(colour.XYZ_to_xy(colour.sd_to_XYZ(sd, CMFS, D65, method="Integration")))


#: The white point of this integration: the chromaticity of a flat spectrum.
WHITE_XY = chromaticity(np.ones(WAVELENGTHS.size))


def mirror_chromaticity(name: str, theta: float) -> np.ndarray:
    """xy of the BRDF in the mirror direction ``theta_r = theta_i``."""
    f = get_material(name).brdf(*inplane_to_vectors(np.array([theta]), np.array([theta])), WAVELENGTHS)[0]
    return chromaticity(f)


def hue_angle_deg(xy: np.ndarray) -> float:
    """Direction of a chromaticity seen from the white point (dominant-wavelength proxy)."""
    return math.degrees(math.atan2(xy[1] - WHITE_XY[1], xy[0] - WHITE_XY[0]))


def hue_change_deg(name: str) -> float:
    change = hue_angle_deg(mirror_chromaticity(name, 60.0)) - hue_angle_deg(mirror_chromaticity(name, 10.0))
    return abs((change + 180.0) % 360.0 - 180.0)


def test_gonio_highlight_changes_colour_with_angle():
    """Interference shifts the highlight from greenish-blue (10°) to blue-violet (60°)."""
    near, far = mirror_chromaticity("gonio", 10.0), mirror_chromaticity("gonio", 60.0)
    assert np.linalg.norm(far - near) > 0.05
    assert hue_change_deg("gonio") > 30.0
    assert hue_angle_deg(near) > 90.0  # greenish-blue: left of and above the white point


@pytest.mark.parametrize("name", ["cyan", "magenta"])
def test_process_ink_highlight_keeps_its_hue(name):
    """A colourless gloss only desaturates the ink (xy moves toward white on a straight line),
    so the hue seen from the white point stays put, unlike gonio's."""
    assert hue_change_deg(name) < 0.1


# --------------------------------------------------------------------------- the instrument


def test_instrument_response_is_smooth_positive_and_normalised():
    response = instrument_response(GCMS_WAVELENGTHS_NM)
    assert response.max() == pytest.approx(1.0) and response.min() > 0.01
    assert np.all(np.diff(response) > 0)
    with pytest.raises(InputError, match="300 nm"):
        instrument_response(np.array([250.0]))


@pytest.mark.parametrize("name", MATERIAL_NAMES)
def test_noiseless_beta_is_pi_f_times_response(name):
    theta_i, theta_r = in_plane_plan("DS3")
    measurement = VirtualGoniospectrophotometer().measure(name, theta_i, theta_r)
    f = get_material(name).brdf(*inplane_to_vectors(theta_i, theta_r), GCMS_WAVELENGTHS_NM)
    ratio = measurement.beta / (math.pi * f)
    response = instrument_response(GCMS_WAVELENGTHS_NM)
    np.testing.assert_allclose(ratio, np.broadcast_to(response, ratio.shape), rtol=1e-12)
    np.testing.assert_array_equal(measurement.theta_i, theta_i)
    np.testing.assert_array_equal(measurement.theta_r, theta_r)


@pytest.mark.parametrize("name", ["cyan", "gold", "gonio"])
def test_calibration_of_noiseless_measurement_recovers_ground_truth(name):
    instrument = VirtualGoniospectrophotometer()
    sample = instrument.measure_plan(name, "DS2")
    reference = instrument.measure_plan(REFERENCE_MATERIAL, "DS2")
    truth = instrument.ground_truth(name, *in_plane_plan("DS2"))
    calibrated = calibrate(sample, reference)
    np.testing.assert_allclose(calibrated.values, truth.values, rtol=1e-10)
    np.testing.assert_array_equal(calibrated.wavelengths, truth.wavelengths)


def test_ground_truth_table_angles_agree_with_the_brdf():
    theta_i, theta_r = in_plane_plan("DS3")
    table = VirtualGoniospectrophotometer.ground_truth("gonio", theta_i, theta_r)
    np.testing.assert_array_equal(table.wavelengths, WAVELENGTHS)
    assert table.n_rows == theta_i.size
    # Evaluate through the table's own spherical angles (phi_i = 0 after rotation): isotropy
    # makes it the same BRDF.
    via_table = get_material("gonio").brdf(*table.vectors(), WAVELENGTHS)
    np.testing.assert_allclose(via_table, table.values, rtol=1e-10)


def test_noise_has_the_requested_statistics_and_streams_are_independent():
    instrument = VirtualGoniospectrophotometer(noise_rel=0.02, noise_abs=0.0, seed=5)
    clean = VirtualGoniospectrophotometer()
    deviations = {}
    for name in ("cyan", REFERENCE_MATERIAL):
        noisy = instrument.measure_plan(name, "DS1").beta
        deviations[name] = (noisy / clean.measure_plan(name, "DS1").beta - 1.0).ravel()
        assert deviations[name].std() == pytest.approx(0.02, rel=0.03)
        assert abs(deviations[name].mean()) < 0.001
    assert abs(np.corrcoef(deviations["cyan"], deviations[REFERENCE_MATERIAL])[0, 1]) < 0.02

    additive = VirtualGoniospectrophotometer(noise_abs=1e-3, seed=5).measure_plan("gold", "DS1")
    residual = additive.beta - clean.measure_plan("gold", "DS1").beta
    assert residual.std() == pytest.approx(1e-3, rel=0.03)


def test_same_seed_repeats_and_other_seed_differs():
    def session(seed):
        instrument = VirtualGoniospectrophotometer(0.01, 1e-4, seed)
        return [instrument.measure_plan(name, "DS3").beta for name in ("gold", REFERENCE_MATERIAL, "gold")]

    first, again, other = session(11), session(11), session(12)
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    for a, c in zip(first, other):
        assert not np.allclose(a, c, rtol=1e-6, atol=0)
    # A repeated measurement within a session draws new noise.
    assert not np.allclose(first[0], first[2], rtol=1e-6, atol=0)


def test_instrument_rejects_bad_input():
    with pytest.raises(InputError, match="noise_rel"):
        VirtualGoniospectrophotometer(noise_rel=-0.1)
    with pytest.raises(InputError, match="seed"):
        VirtualGoniospectrophotometer(seed=1.5)
    instrument = VirtualGoniospectrophotometer()
    with pytest.raises(InputError, match=r"theta_r\[1\] = 95.0"):
        instrument.measure("gold", [10.0, 20.0], [10.0, 95.0])
    with pytest.raises(InputError, match="equal length"):
        instrument.measure("gold", [10.0, 20.0], [10.0])
    with pytest.raises(InputError, match="unknown virtual material"):
        instrument.measure_plan("chrome", "DS1")
    with pytest.raises(InputError, match="unknown plan .DS9.; expected DS1"):
        instrument.measure_plan("gold", "DS9")
    assert instrument.measure_plan("gonio", "DS4").n_rows == 6


# --------------------------------------------------------------------------- shipped data


def test_default_data_path():
    path = default_data_path("gold")
    assert path.name == "gold_DS1.csv" and path.parent.name == "default"
    assert default_data_path("cyan", "DS3").name == "cyan_DS3.csv"
    with pytest.raises(InputError):
        default_data_path("silver")
    with pytest.raises(InputError):
        default_data_path("gold", "DS7")


def test_regenerate_default_data_writes_readable_reproducible_files(tmp_path):
    paths = regenerate_default_data(tmp_path, progress=False)
    assert sorted(p.name for p in paths) == sorted(f"{name}_DS1.csv" for name in MATERIALS)
    instrument = VirtualGoniospectrophotometer(DEFAULT_NOISE_REL, DEFAULT_NOISE_ABS, DEFAULT_SEED)
    for path in paths:
        measured = instrument.measure_plan(path.name.removesuffix("_DS1.csv"), "DS1")
        stored = read_gcms(path)
        np.testing.assert_array_equal(stored.theta_i, measured.theta_i)
        np.testing.assert_allclose(stored.beta, measured.beta, rtol=0, atol=5.01e-7)


def test_shipped_default_data_is_up_to_date(tmp_path):
    shipped = [default_data_path(name) for name in MATERIALS]
    if not all(path.is_file() for path in shipped):
        pytest.skip("neuralbrdf/data/default/*_DS1.csv not generated yet (regenerate_default_data)")
    regenerated = regenerate_default_data(tmp_path, progress=False)
    for old, new in zip(shipped, regenerated):
        np.testing.assert_array_equal(read_gcms(old).beta, read_gcms(new).beta)


def test_validation_materials_are_found_apart_from_the_shipped_stand_ins_and_are_reciprocal():
    from neuralbrdf.virtual.materials import VALIDATION_MATERIALS

    assert len(VALIDATION_MATERIALS) == 6 and not set(VALIDATION_MATERIALS) & set(MATERIALS)
    wi, wo = random_hemisphere(300, 1), random_hemisphere(300, 2)
    for name, material in VALIDATION_MATERIALS.items():
        assert get_material(name) is material
        f = material.brdf(wi, wo, WAVELENGTHS)
        assert f.shape == (300, len(WAVELENGTHS)) and (f >= 0).all()
        np.testing.assert_allclose(f, material.brdf(wo, wi, WAVELENGTHS), rtol=1e-10)
    with pytest.raises(InputError, match="val-blue"):
        get_material("val-bleu")
