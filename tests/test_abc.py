"""ABC model (docs/models.md#abc): BRDF, parameters, Löw's fits and the fit (its sampler: test_mitsuba_bsdf)."""

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from neuralbrdf.data.plans import in_plane_plan, plan_spherical
from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError
from neuralbrdf.fitting import AbcBounds, fit_abc
from neuralbrdf.fitting.abc_fit import GAUSSIAN_LIMIT_C
from neuralbrdf.geometry import inplane_to_vectors, spherical_pair_to_vectors, spherical_to_vector
from neuralbrdf.metrics import hemisphere_logcos_rmse
from neuralbrdf.data.low2012 import load_low2012_parameters
from neuralbrdf.physics.abc import AbcParameters, abc_brdf, abc_brdf_by_sharpness
from neuralbrdf.physics.fresnel import fresnel_dielectric
from neuralbrdf.physics.microfacet import microfacet_brdf

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
LOW_CSV = DATA / "abc-low2012" / "low2012_abc_merl.csv"
needs_low = pytest.mark.skipif(not LOW_CSV.is_file(), reason=f"Löw et al. parameters not found at {LOW_CSV}")
REPORT_MATERIALS = ("tungsten-carbide", "nylon", "brass", "blue-acrylic", "specular-black-phenolic")

# Löw et al.'s published fits of two report materials (copied, so the tests below run without the data).
NYLON = AbcParameters(kd=[0.2327, 0.2325, 0.2074], A=[19.21563, 18.19409, 16.93832], B=3334.451788, C=0.886752, eta=1.38252)
PHENOLIC = AbcParameters(
    kd=[0.0014, 0.0017, 0.0019], A=[2866.69698, 2568.57011, 3042.95351], B=291094.225596, C=1.252478, eta=1.41541
)


# --------------------------------------------------------------------------- independent reference


def reference_fresnel(c, eta):
    """Report Eq. 2.6 with g = sqrt(eta² - 1 + c²), written out per sample."""
    g = math.sqrt(eta * eta - 1.0 + c * c)
    return (g - c) ** 2 / (2 * (g + c) ** 2) * (1 + (c * (g + c) - 1) ** 2 / (c * (g - c) + 1) ** 2)


def reference_abc(wi, wo, p: AbcParameters):
    """docs/models.md#abc in plain Python for one direction pair."""
    ci, co = wi[2], wo[2]
    if ci <= 0 or co <= 0:
        return [0.0] * p.n_channels
    s = [wi[k] + wo[k] for k in range(3)]
    norm = math.sqrt(sum(x * x for x in s))
    h = [x / norm for x in s]
    nh = h[2]
    oh = sum(wo[k] * h[k] for k in range(3))
    ih = sum(wi[k] * h[k] for k in range(3))
    G = min(1.0, 2 * nh * co / oh, 2 * nh * ci / oh)
    spec = reference_fresnel(ih, p.eta) * G / (math.pi * ci * co * (1 + p.B * (1 - nh)) ** p.C)
    return [kd / math.pi + a * spec for kd, a in zip(p.kd, p.A)]


def random_upper_directions(rng, n, min_cos=1e-3):
    """Uniform directions on the upper hemisphere with cos theta >= min_cos."""
    z = rng.uniform(min_cos, 1.0, n)
    phi = rng.uniform(0, 2 * math.pi, n)
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


# --------------------------------------------------------------------------- the BRDF


@pytest.mark.parametrize("params", [NYLON, PHENOLIC, AbcParameters([0.1, 0.2, 0.3], [2.0, 1.0, 0.5], 15.0, 2.0, 1.6)])
def test_abc_brdf_matches_an_independent_scalar_implementation(params):
    rng = np.random.default_rng(1)
    wi, wo = random_upper_directions(rng, 400), random_upper_directions(rng, 400)
    # plus exact and near mirror pairs, where the specular lobe peaks
    mirror = wi * np.array([-1.0, -1.0, 1.0])
    wi, wo = np.concatenate([wi, wi[:50], wi[50:100]]), np.concatenate([wo, mirror[:50], mirror[50:100] + 1e-3])
    wo = wo / np.linalg.norm(wo, axis=1, keepdims=True)
    expected = np.array([reference_abc(a, b, params) for a, b in zip(wi.tolist(), wo.tolist())])
    np.testing.assert_allclose(params.evaluate(wi, wo), expected, rtol=1e-10)
    got_torch = abc_brdf(torch.tensor(wi), torch.tensor(wo), torch.tensor(params.kd), torch.tensor(params.A),
                         params.B, params.C, params.eta)
    np.testing.assert_allclose(got_torch.numpy(), expected, rtol=1e-10)


def test_reciprocity_and_isotropy():
    rng = np.random.default_rng(2)
    wi, wo = random_upper_directions(rng, 1000), random_upper_directions(rng, 1000)
    f = NYLON.evaluate(wi, wo)
    np.testing.assert_allclose(NYLON.evaluate(wo, wi), f, rtol=1e-12)
    angle = 1.234
    rot = np.array([[math.cos(angle), -math.sin(angle), 0], [math.sin(angle), math.cos(angle), 0], [0, 0, 1]])
    np.testing.assert_allclose(NYLON.evaluate(wi @ rot.T, wo @ rot.T), f, rtol=1e-10)
    mirror_y = np.array([1.0, -1.0, 1.0])
    np.testing.assert_allclose(NYLON.evaluate(wi * mirror_y, wo * mirror_y), f, rtol=1e-12)
    # in-plane form of the same symmetries (docs/formats.md#conventions)
    ti, tr = in_plane_plan("DS1")
    f_plane = NYLON.evaluate(*inplane_to_vectors(ti, tr))
    np.testing.assert_allclose(NYLON.evaluate(*inplane_to_vectors(-ti, -tr)), f_plane, rtol=1e-12)
    np.testing.assert_allclose(NYLON.evaluate(*inplane_to_vectors(tr, ti)), f_plane, rtol=1e-12)


@pytest.mark.parametrize(
    "params",
    [NYLON, PHENOLIC, AbcParameters([0.0] * 3, [1e4] * 3, 1e8, 0.05, 100.0), AbcParameters([0.3] * 3, [1.0] * 3, 0.0, 0.0, 1.01)],
)
def test_finite_non_negative_on_a_dense_hemisphere_grid_including_grazing(params):
    theta = np.concatenate([np.linspace(0.0, 89.0, 90), [89.9, 89.99, 89.999, 90.0]])
    phi = np.linspace(0.0, 360.0, 25)[:-1]
    t, p = np.meshgrid(theta, phi, indexing="ij")
    dirs = spherical_to_vector(t.ravel(), p.ravel())
    i, o = np.meshgrid(np.arange(len(dirs)), np.arange(0, len(dirs), 7), indexing="ij")
    wi, wo = dirs[i.ravel()], dirs[o.ravel()]
    f = params.evaluate(wi, wo)
    assert np.all(np.isfinite(f)) and np.all(f >= 0)
    horizon = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
    assert np.all(f[horizon] == 0)
    # below the horizon is zero too
    below = wo * np.array([1.0, 1.0, -1.0])
    assert np.all(params.evaluate(wi, below) == 0)


def test_fresnel_factor_tends_to_one_at_grazing_and_gradients_stay_finite():
    p = AbcParameters([0.1] * 3, [1.0] * 3, 100.0, 1.5, 1.5)
    angles = np.array([60.0, 80.0, 89.0, 89.9, 89.99])
    wi, wo = inplane_to_vectors(angles, angles)  # mirror pairs: n·h = 1, G = 1, D = 1
    cos = np.cos(np.radians(angles))
    fresnel = (p.evaluate(wi, wo)[:, 0] - 0.1 / math.pi) * math.pi * cos * cos / 1.0
    np.testing.assert_allclose(fresnel, [reference_fresnel(c, 1.5) for c in cos], rtol=1e-9)
    assert np.all(np.diff(fresnel) > 0) and fresnel[-1] > 0.995
    leaves = {name: torch.tensor(np.atleast_1d(getattr(p, name)), dtype=torch.float64, requires_grad=True)
              for name in ("kd", "A", "B", "C", "eta")}
    f = abc_brdf(torch.tensor(wi), torch.tensor(wo), leaves["kd"], leaves["A"], leaves["B"][0], leaves["C"][0],
                 leaves["eta"][0])
    f.sum().backward()
    for name, leaf in leaves.items():
        assert torch.all(torch.isfinite(leaf.grad)), name


def test_the_sharpness_form_is_the_same_brdf_and_reaches_the_gaussian_limit():
    rng = np.random.default_rng(3)
    wi, wo = random_upper_directions(rng, 500), random_upper_directions(rng, 500)
    mirror = wi * np.array([-1.0, -1.0, 1.0]) + rng.normal(0.0, 0.02, wi.shape)
    wi, wo = np.concatenate([wi, wi]), np.concatenate([wo, mirror / np.linalg.norm(mirror, axis=1, keepdims=True)])
    kd, A = [0.1, 0.2], [2.0, 1.0]
    for B, C in ((21.0, 10.0), (3e5, 1.2), (3e6, 0.08), (0.5, 2.0)):
        np.testing.assert_allclose(abc_brdf_by_sharpness(wi, wo, kd, A, B * C, 1.0 / C, 1.5),
                                   abc_brdf(wi, wo, kd, A, B, C, 1.5), rtol=1e-12)
    # tail 0: exactly exp(-sharpness (1 - cos θh)), the limit C -> ∞ at a fixed B·C
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    lobe_only = abc_brdf_by_sharpness(wi, wo, [0.0], [1.0], 200.0, 0.0, 1.5)[:, 0]
    unit_lobe = abc_brdf(wi, wo, [0.0], [1.0], 0.0, 0.0, 1.5)[:, 0]  # distribution 1
    np.testing.assert_allclose(lobe_only, unit_lobe * np.exp(-200.0 * (1.0 - h[:, 2])), rtol=1e-12)
    # C = GAUSSIAN_LIMIT_C stands for the limit within 0.5 % wherever the lobe is above e^-10 of its peak
    near = abc_brdf(wi, wo, [0.0], [1.0], 200.0 / GAUSSIAN_LIMIT_C, GAUSSIAN_LIMIT_C, 1.5)[:, 0]
    upper_lobe = lobe_only >= math.exp(-10.0) * unit_lobe
    assert upper_lobe.sum() > 100
    np.testing.assert_allclose(near[upper_lobe], lobe_only[upper_lobe], rtol=0.005)
    # differentiable at the limit
    sharpness = torch.tensor(200.0, dtype=torch.float64, requires_grad=True)
    tail = torch.tensor(0.0, dtype=torch.float64, requires_grad=True)
    abc_brdf_by_sharpness(torch.tensor(wi), torch.tensor(wo), [0.0], [1.0], sharpness, tail, 1.5).sum().backward()
    assert torch.isfinite(sharpness.grad) and torch.isfinite(tail.grad) and tail.grad > 0


def test_parameters_round_trip_through_json():
    spectral = AbcParameters(kd=[0.1] * 31, A=[1.0] * 31, B=10, C=1, eta=1.5, wavelengths=np.arange(400, 701, 10))
    for params in (NYLON, spectral):
        again = AbcParameters.from_dict(json.loads(json.dumps(params.to_dict())))
        assert again.to_dict() == params.to_dict()


@pytest.mark.parametrize(
    "change, key",
    [
        ({"kd": [0.1, -0.2, 0.1]}, "kd"),
        ({"A": [1.0, 2.0]}, "A"),
        ({"B": "wide"}, "B"),
        ({"C": -1.0}, "C"),
        ({"eta": 0.0}, "eta"),
        ({"eta": float("nan")}, "eta"),
        ({"colour": 1}, "colour"),
    ],
)
def test_parameters_from_dict_rejects_bad_values_naming_the_key(change, key):
    mapping = {**NYLON.to_dict(), **change}
    with pytest.raises(InputError) as info:
        AbcParameters.from_dict(mapping, source="params.json")
    assert info.value.key == key and info.value.path == "params.json"
    missing = NYLON.to_dict()
    del missing["eta"]
    with pytest.raises(InputError, match="missing"):
        AbcParameters.from_dict(missing)


# --------------------------------------------------------------------------- Löw et al. 2012


@needs_low
def test_low2012_parameters_load_and_are_finite_for_the_report_materials():
    fits = load_low2012_parameters(LOW_CSV)
    assert len(fits) == 50
    assert fits["nylon"].to_dict() == NYLON.to_dict()
    wi, wo = spherical_pair_to_vectors(*plan_spherical("DS1"))
    grid_wi = random_upper_directions(np.random.default_rng(4), 2000, min_cos=1e-4)
    grid_wo = random_upper_directions(np.random.default_rng(5), 2000, min_cos=1e-4)
    for name in REPORT_MATERIALS:
        for a, b in ((wi, wo), (grid_wi, grid_wo)):
            f = fits[name].evaluate(a, b)
            assert np.all(np.isfinite(f)) and np.all(f > 0), name


@pytest.mark.parametrize(
    "text, line, column",
    [
        ("material,kd_r,kd_g,kd_b,A_r,A_g,A_b,B,C\nx,0,0,0,1,1,1,1,1\n", 1, "eta"),
        ("material,kd_r,kd_g,kd_b,A_r,A_g,A_b,B,C,eta,extra\nx,0,0,0,1,1,1,1,1,1,1\n", 1, "extra"),
        ("material,kd_r,kd_g,kd_b,A_r,A_g,A_b,B,C,eta\nx,0,0,0,1,1,1,1,1,1.5\ny,0,0,abc,1,1,1,1,1,1.5\n", 3, "kd_b"),
        ("material,kd_r,kd_g,kd_b,A_r,A_g,A_b,B,C,eta\nx,0,0,0,1,1,1,1,1,1.5\nx,0,0,0,1,1,1,1,1,1.5\n", 3, "material"),
        ("material,kd_r,kd_g,kd_b,A_r,A_g,A_b,B,C,eta\nx,0,0,0,1,1,1,-5,1,1.5\n", 2, "B"),
        ("material,kd_r,kd_g,kd_b,A_r,A_g,A_b,B,C,eta\n,0,0,0,1,1,1,5,1,1.5\n", 2, "material"),
    ],
)
def test_low2012_loader_rejects_bad_files_with_line_and_column(tmp_path, text, line, column):
    path = tmp_path / "fits.csv"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        load_low2012_parameters(path)
    assert (info.value.path, info.value.line, info.value.column) == (str(path), line, column)


def test_low2012_loader_rejects_missing_and_empty_files(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_low2012_parameters(tmp_path / "absent.csv")
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(InputError, match="empty"):
        load_low2012_parameters(tmp_path / "empty.csv")


# --------------------------------------------------------------------------- fitting


def table_from(params: AbcParameters, plan: str = "DS1") -> BrdfTable:
    angles = plan_spherical(plan)
    return BrdfTable(*angles, params.evaluate(*spherical_pair_to_vectors(*angles)), params.wavelengths)


def low_set_error(fitted: AbcParameters, truth: AbcParameters) -> float:
    angles = plan_spherical("low")
    wi, wo = spherical_pair_to_vectors(*angles)
    return hemisphere_logcos_rmse(fitted.evaluate(wi, wo), truth.evaluate(wi, wo), angles[0])


@pytest.mark.parametrize("truth", [NYLON, PHENOLIC])
def test_fit_recovers_known_parameters_from_noise_free_ds1(truth):
    table = table_from(truth)
    result = fit_abc(table, seed=0)
    assert result.success, result.failure_reason
    assert result.failure_reason is None and result.loss < 1e-3 * result.baseline_loss
    np.testing.assert_array_equal(result.parameters.kd, math.pi * table.values.min(axis=0))
    assert low_set_error(result.parameters, truth) < 0.01


def test_fit_works_on_spectral_tables_with_a_per_wavelength_a():
    wavelengths = np.arange(400.0, 701.0, 10.0)
    ramp = (wavelengths - 400.0) / 300.0
    truth = AbcParameters(kd=0.05 + 0.2 * ramp, A=40.0 * (1.2 - ramp), B=2000.0, C=1.1, eta=1.5, wavelengths=wavelengths)
    result = fit_abc(table_from(truth), n_starts=4)
    assert result.success, result.failure_reason
    assert result.parameters.n_channels == 31
    np.testing.assert_array_equal(result.parameters.wavelengths, wavelengths)
    assert low_set_error(result.parameters, truth) < 0.01


def test_fit_reports_failure_on_data_without_a_specular_lobe():
    angles = plan_spherical("DS1")
    for values in (np.zeros((1001, 3)), np.full((1001, 3), 0.2)):
        result = fit_abc(BrdfTable(*angles, values), n_starts=2)
        assert not result.success and "no specular signal" in result.failure_reason


def test_fit_reports_failure_on_impossible_data():
    angles = plan_spherical("DS1")
    ti, tr = in_plane_plan("DS1")
    rng = np.random.default_rng(10)
    cases = {
        "noise": rng.uniform(0.0, 1.0, (1001, 3)),
        # darkest at the mirror direction, brightest far from it
        "anti-specular": np.repeat((0.05 + np.abs(ti - tr) / 50.0)[:, None], 3, axis=1),
    }
    for name, values in cases.items():
        result = fit_abc(BrdfTable(*angles, values), n_starts=3)
        assert not result.success, name
        assert "bound" in result.failure_reason, (name, result.failure_reason)
        # every runaway says which parameter, its value, the bound and the option to change
        runaways = [reason for reason in result.failure_reason.split("; ") if "ran to its" in reason]
        assert runaways, (name, result.failure_reason)
        for reason in runaways:
            assert re.search(r"\(.*\d.*, bound [0-9.e+-]+\)", reason) and "--model.bounds." in reason, reason


def test_fit_validates_its_arguments():
    table = table_from(NYLON, "DS3")
    with pytest.raises(ValueError, match="n_starts"):
        fit_abc(table, n_starts=0)
    with pytest.raises(ValueError, match="bounds"):
        AbcBounds(sharpness=(10.0, 1.0))
    weighted = BrdfTable(table.theta_i, table.phi_i, table.theta_o, table.phi_o, table.values, weight=np.zeros(57))
    with pytest.raises(InputError, match="weight"):
        fit_abc(weighted)


# --------------------------------------------------------------------------- smooth materials: the Gaussian limit

ORANGE_KD = np.array([0.41, 0.13, 0.004])


def lambert_beckmann(wi, wo, alpha, eta=1.5):
    """An orange Lambertian base under one smooth dielectric Beckmann lobe (Walter et al. 2007)."""
    specular = microfacet_brdf(wi, wo, alpha, lambda c: fresnel_dielectric(c, eta), "beckmann")
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    return np.where(above[:, None], ORANGE_KD / math.pi + specular[:, None], 0.0)


def lambert_beckmann_table(alpha, plan="DS1") -> BrdfTable:
    angles = plan_spherical(plan)
    return BrdfTable(*angles, lambert_beckmann(*spherical_pair_to_vectors(*angles), alpha))


def hemisphere_error(parameters: AbcParameters, alpha) -> float:
    angles = plan_spherical("DS2")  # a cheap stand-in for the Low set: every fit here is in-plane
    wi, wo = spherical_pair_to_vectors(*angles)
    return hemisphere_logcos_rmse(parameters.evaluate(wi, wo), lambert_beckmann(wi, wo, alpha), angles[0])


@pytest.mark.parametrize("alpha", [0.05, 0.4])
def test_a_smooth_beckmann_material_fits_in_the_gaussian_limit(alpha):
    """Beckmann falls off faster than any finite C allows: in (B, C) the fit ran to C's bound."""
    result = fit_abc(lambert_beckmann_table(alpha), n_starts=4)
    assert result.success, result.failure_reason
    p = result.parameters
    assert result.gaussian_limit and p.C == GAUSSIAN_LIMIT_C
    # near the peak Beckmann is exp(-tan²θh / α²) ≈ exp(-2 (1 - cos θh) / α²): B·C ≈ 2 / α²
    assert p.B * p.C == pytest.approx(2.0 / alpha**2, rel=0.15)
    assert p.eta == pytest.approx(1.5, rel=0.03)
    np.testing.assert_allclose(p.kd, ORANGE_KD, rtol=0.02, atol=1e-3)
    assert hemisphere_error(p, alpha) < 0.02


def test_a_bounded_c_says_which_parameter_ran_away_and_what_to_try():
    result = fit_abc(lambert_beckmann_table(0.2), n_starts=4, bounds=AbcBounds(C=(1e-3, 10.0)))
    assert not result.success
    assert result.failure_reason.startswith("C ran to its upper bound (C = 10, B = ")
    assert "bound 10)" in result.failure_reason and "--model.bounds.C '[0.001, .inf]'" in result.failure_reason


def test_kd_ignores_rows_nobody_measured():
    """MERL's unmeasured cells are read as all-zero rows; one of them used to set kd to 0."""
    table = lambert_beckmann_table(0.2, "DS3")
    zero = np.zeros((4, 3))
    theta_o = np.array([89.5, 89.5, 89.5, 89.5])
    padded = BrdfTable(np.concatenate([table.theta_i, [75.0] * 4]), np.concatenate([table.phi_i, [0.0] * 4]),
                       np.concatenate([table.theta_o, theta_o]), np.concatenate([table.phi_o, [10.0, 90, 180, 270]]),
                       np.concatenate([table.values, zero]))
    result = fit_abc(padded, n_starts=4)
    np.testing.assert_allclose(result.parameters.kd, math.pi * table.values.min(axis=0))
    assert result.success, result.failure_reason


@pytest.mark.parametrize(
    "bounds, key, message",
    [
        ({"B": [1.0, 10.0]}, "model.bounds.B", "unknown bound; expected one of A, sharpness, C, eta"),
        ({"C": [1.0, "many"]}, "model.bounds.C", "expected [low, high]"),
        ({"C": [1.0]}, "model.bounds.C", "expected [low, high]"),
        ({"eta": [2.0, 1.5]}, "model.bounds.eta", "0 < low < high < inf"),
        ({"sharpness": [1.0, math.inf]}, "model.bounds.sharpness", "0 < low < high < inf"),
        ({"C": [2e4, math.inf]}, "model.bounds.C", "must be below 10000"),
    ],
)
def test_bounds_from_a_config_are_checked_naming_the_key(bounds, key, message):
    with pytest.raises(InputError, match=re.escape(message)) as info:
        AbcBounds.from_config(bounds)
    assert info.value.key == key
