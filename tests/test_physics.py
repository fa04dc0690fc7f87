"""Microfacet distributions, thin-film interference and optical constants against independent
computations: Monte Carlo integrals, closed forms, a characteristic-matrix thin-film solver and
Mitsuba's data files read directly."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.integrate
import torch

from neuralbrdf.errors import InputError
from neuralbrdf.geometry import inplane_to_vectors, spherical_to_vector
from neuralbrdf.physics.fresnel import fresnel_conductor, fresnel_dielectric
from neuralbrdf.physics.microfacet import (
    beckmann_distribution,
    ggx_distribution,
    ggx_smith_g1,
    microfacet_brdf,
)
from neuralbrdf.physics.optical_constants import complex_index, gold_complex_index, mitsuba_ior_dir
from neuralbrdf.physics.thin_film import thin_film_reflectance

N_MC = 400_000


def uniform_hemisphere(n: int, seed: int) -> np.ndarray:
    """Uniformly distributed unit vectors on the upper hemisphere (pdf 1 / 2π)."""
    u = np.random.default_rng(seed).random((n, 2))
    cos_t = u[:, 0]
    sin_t = np.sqrt(1.0 - cos_t**2)
    phi = 2.0 * math.pi * u[:, 1]
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=1)


def mc_hemisphere_integral(samples: np.ndarray) -> tuple[float, float]:
    """Estimate and standard error of ``∫ g dω`` from values ``g`` at uniform directions."""
    weighted = 2.0 * math.pi * samples
    return float(weighted.mean()), float(weighted.std() / math.sqrt(samples.size))


# --------------------------------------------------------------------------- distributions


@pytest.mark.parametrize("distribution", [ggx_distribution, beckmann_distribution])
@pytest.mark.parametrize("alpha", [0.3, 0.6, 1.0])
def test_normal_distribution_projected_area_is_one(distribution, alpha):
    h = uniform_hemisphere(N_MC, seed=1)
    estimate, error = mc_hemisphere_integral(distribution(h[:, 2], alpha) * h[:, 2])
    assert error < 0.01
    assert abs(estimate - 1.0) < 4.0 * error


def test_ggx_smith_weak_white_furnace():
    """∫ G1(wo) max(0, wo·h) D(h) dω_h = cos θo (Heitz 2014, JCGT 3(2)): D and G1 agree."""
    alpha = 0.5
    h = uniform_hemisphere(N_MC, seed=2)
    for theta_o in (0.0, 40.0, 75.0):
        wo = spherical_to_vector(np.array(theta_o), np.array(30.0))
        projected = np.clip(h @ wo, 0.0, None)
        g = ggx_smith_g1(np.array(wo[2]), alpha) * projected * ggx_distribution(h[:, 2], alpha)
        estimate, error = mc_hemisphere_integral(g)
        assert abs(estimate - wo[2]) < 4.0 * error + 1e-12, theta_o


def test_distribution_closed_forms():
    alpha = 0.2
    # At the pole both are 1 / (π α²); GGX with α = 1 is uniform, 1 / π.
    for distribution in (ggx_distribution, beckmann_distribution):
        assert distribution(np.array(1.0), alpha) == pytest.approx(1.0 / (math.pi * alpha**2))
    cos = np.linspace(0.05, 1.0, 7)
    np.testing.assert_allclose(ggx_distribution(cos, 1.0), 1.0 / math.pi)
    # Beckmann in its textbook form exp(-tan²/α²) / (π α² cos⁴).
    tan2 = (1.0 - cos**2) / cos**2
    expected = np.exp(-tan2 / alpha**2) / (math.pi * alpha**2 * cos**4)
    np.testing.assert_allclose(beckmann_distribution(cos, alpha), expected, rtol=1e-12)
    # Zero at and below the horizon.
    for distribution in (ggx_distribution, beckmann_distribution):
        np.testing.assert_array_equal(distribution(np.array([0.0, -0.5]), alpha), 0.0)


def test_ggx_g1_matches_lambda_form():
    """G1 = 1 / (1 + Λ), Λ = (-1 + sqrt(1 + α² tan²θ)) / 2 (Heitz 2014)."""
    alpha = 0.35
    cos = np.linspace(0.02, 1.0, 50)
    lam = 0.5 * (-1.0 + np.sqrt(1.0 + alpha**2 * (1.0 - cos**2) / cos**2))
    np.testing.assert_allclose(ggx_smith_g1(cos, alpha), 1.0 / (1.0 + lam), rtol=1e-12)
    np.testing.assert_array_equal(ggx_smith_g1(np.array([0.0, -0.3]), alpha), 0.0)


# --------------------------------------------------------------------------- the BRDF


def constant_fresnel(value):
    return lambda cos_d: value + 0.0 * cos_d


def test_microfacet_brdf_at_normal_mirror():
    """Normal incidence, mirror direction: f = F D(0) G1(1)² / 4 = F / (4 π α²)."""
    wi, wo = inplane_to_vectors(np.array([0.0]), np.array([0.0]))
    f = microfacet_brdf(wi, wo, 0.3, constant_fresnel(0.5))
    assert f[0] == pytest.approx(0.5 / (4.0 * math.pi * 0.09), rel=1e-12)


def test_microfacet_brdf_reciprocal_and_zero_below_horizon():
    rng = np.random.default_rng(3)
    wi = uniform_hemisphere(1000, seed=4)
    wo = uniform_hemisphere(1000, seed=5)

    def schlick(cos_d):
        return 0.04 + 0.96 * (1.0 - cos_d) ** 5

    np.testing.assert_allclose(microfacet_brdf(wi, wo, 0.2, schlick), microfacet_brdf(wo, wi, 0.2, schlick))
    below = wo * np.array([1.0, 1.0, -1.0])
    np.testing.assert_array_equal(microfacet_brdf(wi, below, 0.2, schlick), 0.0)
    np.testing.assert_array_equal(microfacet_brdf(below, wi, 0.2, schlick), 0.0)
    # Exactly opposite grazing directions (wi + wo = 0) give 0, not NaN.
    grazing = np.array([[1.0, 0.0, 0.0]])
    assert microfacet_brdf(grazing, -grazing, 0.2, schlick)[0] == 0.0
    # Spectral Fresnel [N, W] broadcasts; each column is the scalar BRDF scaled.
    scales = rng.random(4)
    spectral = microfacet_brdf(wi, wo, 0.2, lambda c: c[:, None] * 0 + scales)
    scalar = microfacet_brdf(wi, wo, 0.2, constant_fresnel(1.0))
    np.testing.assert_allclose(spectral, scalar[:, None] * scales)


def test_microfacet_brdf_torch_matches_numpy_and_differentiates():
    wi = uniform_hemisphere(64, seed=6)
    wo = uniform_hemisphere(64, seed=7)
    expected = microfacet_brdf(wi, wo, 0.25, lambda c: fresnel_dielectric(c, 1.5))
    alpha = torch.tensor(0.25, dtype=torch.float64, requires_grad=True)
    got = microfacet_brdf(
        torch.from_numpy(wi), torch.from_numpy(wo), alpha, lambda c: fresnel_dielectric(c, 1.5)
    )
    np.testing.assert_allclose(got.detach().numpy(), expected, rtol=1e-12)
    got.sum().backward()
    assert torch.isfinite(alpha.grad)


def directional_albedo_mc(theta_i: float, alpha: float) -> tuple[float, float]:
    """MC estimate of ∫ f cos θo dωo for the microfacet BRDF with F = 1."""
    wi = spherical_to_vector(np.array(theta_i), np.array(0.0))[None, :]
    wo = uniform_hemisphere(N_MC, seed=8)
    f = microfacet_brdf(np.broadcast_to(wi, wo.shape), wo, alpha, constant_fresnel(1.0))
    return mc_hemisphere_integral(f * wo[:, 2])


def test_microfacet_albedo_at_normal_incidence_matches_quadrature():
    """At normal incidence wo = reflect(n, h) has θo = 2 θh and dωo = 4 cos θh dωh, so
    E = ∫₀^{π/4} D(θh) G1(cos 2θh) cos θh 2π sin θh dθh (GGX in its tan form, Walter Eq. 33)."""
    alpha = 0.5

    def integrand(theta_h):
        tan2 = math.tan(theta_h) ** 2
        d = alpha**2 / (math.pi * math.cos(theta_h) ** 4 * (alpha**2 + tan2) ** 2)
        theta_o = 2.0 * theta_h
        g1 = 2.0 / (1.0 + math.sqrt(1.0 + alpha**2 * math.tan(theta_o) ** 2))
        return d * g1 * math.cos(theta_h) * 2.0 * math.pi * math.sin(theta_h)

    expected, _ = scipy.integrate.quad(integrand, 0.0, math.pi / 4.0)
    estimate, error = directional_albedo_mc(0.0, alpha)
    assert error < 0.01
    assert abs(estimate - expected) < 4.0 * error


@pytest.mark.parametrize("theta_i", [30.0, 60.0, 85.0])
def test_microfacet_albedo_with_unit_fresnel_is_at_most_one(theta_i):
    """White furnace: with F = 1 single scattering loses energy, never gains it."""
    estimate, error = directional_albedo_mc(theta_i, 0.5)
    assert error < 0.01
    assert estimate < 1.0 + 3.0 * error


# --------------------------------------------------------------------------- Fresnel


def test_conductor_fresnel_at_normal_incidence():
    n, k = gold_complex_index(np.array([400.0, 500.0, 600.0, 700.0]))
    expected = ((n - 1.0) ** 2 + k**2) / ((n + 1.0) ** 2 + k**2)
    np.testing.assert_allclose(fresnel_conductor(np.ones(4), n, k), expected, rtol=1e-12)


# --------------------------------------------------------------------------- thin films


def characteristic_matrix_reflectance(cos0, wavelength, n0, n1, d, n2, polarisation):
    """Reflectance of one film from Born & Wolf's characteristic matrix (§1.6.2), complex maths."""
    sin0 = math.sqrt(1.0 - cos0**2)
    cos1 = np.sqrt(1.0 - (n0 * sin0 / n1) ** 2 + 0j)
    cos2 = np.sqrt(1.0 - (n0 * sin0 / n2) ** 2 + 0j)
    if polarisation == "s":
        p0, p1, p2 = n0 * cos0, n1 * cos1, n2 * cos2
    else:
        p0, p1, p2 = cos0 / n0, cos1 / n1, cos2 / n2
    beta = 2.0 * math.pi * n1 * d * cos1 / wavelength
    m = np.array([[np.cos(beta), -1j * np.sin(beta) / p1], [-1j * p1 * np.sin(beta), np.cos(beta)]])
    r = ((m[0, 0] + m[0, 1] * p2) * p0 - (m[1, 0] + m[1, 1] * p2)) / (
        (m[0, 0] + m[0, 1] * p2) * p0 + (m[1, 0] + m[1, 1] * p2)
    )
    return abs(r) ** 2


@pytest.mark.parametrize(
    "n1, d, n2, n0", [(2.4, 260.0, 1.58, 1.0), (1.38, 120.0, 1.9, 1.0), (1.7, 500.0, 1.45, 1.33)]
)
def test_thin_film_matches_characteristic_matrix(n1, d, n2, n0):
    for cos0 in (1.0, 0.8, 0.4, 0.1):
        for wavelength in (400.0, 533.0, 700.0):
            expected = 0.5 * sum(
                characteristic_matrix_reflectance(cos0, wavelength, n0, n1, d, n2, pol) for pol in "sp"
            )
            got = thin_film_reflectance(np.array(cos0), np.array(wavelength), n1, d, n2, n0)
            assert got == pytest.approx(expected, rel=1e-10, abs=1e-14)


def test_thin_film_degenerate_cases_equal_bare_substrate():
    cos = np.linspace(0.0, 1.0, 21)[:, None]
    wavelengths = np.arange(400.0, 701.0, 50.0)[None, :]
    bare = fresnel_dielectric(cos, 1.58) + 0.0 * wavelengths
    np.testing.assert_allclose(thin_film_reflectance(cos, wavelengths, 2.4, 0.0, 1.58), bare, atol=1e-12)
    np.testing.assert_allclose(thin_film_reflectance(cos, wavelengths, 1.58, 300.0, 1.58), bare, atol=1e-12)


def test_quarter_wave_film_at_normal_incidence():
    n0, nf, ns, wavelength = 1.0, 1.38, 1.52, 550.0
    thickness = wavelength / (4.0 * nf)
    got = thin_film_reflectance(np.array(1.0), np.array(wavelength), nf, thickness, ns, n0)
    assert got == pytest.approx(((n0 * ns - nf**2) / (n0 * ns + nf**2)) ** 2, rel=1e-12)


def test_thin_film_rejects_bad_parameters():
    cos, wl = np.array([1.0]), np.array([500.0])
    with pytest.raises(InputError, match="thickness_nm"):
        thin_film_reflectance(cos, wl, 1.5, -1.0, 1.5)
    with pytest.raises(InputError, match="film_index"):
        thin_film_reflectance(cos, wl, 0.9, 100.0, 1.5)
    with pytest.raises(InputError, match="wavelength"):
        thin_film_reflectance(cos, np.array([0.0]), 1.5, 100.0, 1.5)


# --------------------------------------------------------------------------- optical constants


def test_gold_index_reads_mitsuba_files():
    eta_table = np.loadtxt(mitsuba_ior_dir() / "Au.eta.spd", comments="#")
    k_table = np.loadtxt(mitsuba_ior_dir() / "Au.k.spd", comments="#")
    row = 20
    n, k = gold_complex_index(np.array([eta_table[row, 0]]))
    assert n[0] == eta_table[row, 1] and k[0] == k_table[row, 1]
    midpoint = 0.5 * (eta_table[row, 0] + eta_table[row + 1, 0])
    n, k = gold_complex_index(np.array([midpoint]))
    assert n[0] == pytest.approx(0.5 * (eta_table[row, 1] + eta_table[row + 1, 1]))
    assert k[0] == pytest.approx(0.5 * (k_table[row, 1] + k_table[row + 1, 1]))


def test_gold_reflects_red_more_than_blue():
    """Gold's normal-incidence reflectance rises from ~0.4 in the blue to > 0.9 in the red."""
    n, k = gold_complex_index(np.array([450.0, 650.0]))
    reflectance = fresnel_conductor(np.ones(2), n, k)
    assert reflectance[0] < 0.5 and reflectance[1] > 0.9


def test_optical_constants_reject_bad_requests():
    with pytest.raises(InputError, match="outside the table's range"):
        gold_complex_index(np.array([500.0, 200.0]))
    with pytest.raises(InputError, match="no optical constants for 'Unobtainium'"):
        complex_index("Unobtainium", np.array([500.0]))
