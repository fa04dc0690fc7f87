"""NLB pretraining corpus (docs/models.md#nlb): analytic families, direction sampling, reproducibility.

Independent references: Heitz's (2014) projected-area identity for Smith masking, adaptive
quadrature (scipy) of the ABC lobe integral, the GGX CDF in closed form, Monte Carlo albedos,
and the symmetries of isotropic, reciprocal BRDFs.
"""

import dataclasses
import math

import numpy as np
import torch
import pytest
from scipy import integrate

from neuralbrdf.data.corpus import (
    ARCHETYPES,
    LOBE_ABC,
    LOBE_BECKMANN,
    LOBE_GGX,
    abc_lobe_integral,
    generate_materials,
    sample_batch,
    sample_ggx_normal,
    uniform_hemisphere,
)
from neuralbrdf.errors import InputError
from neuralbrdf.physics.microfacet import beckmann_smith_g1
from neuralbrdf.physics.abc import abc_brdf
from neuralbrdf.physics.microfacet import beckmann_distribution


@pytest.fixture(scope="module")
def materials():
    return generate_materials(400, seed=7)


def random_pairs(rng, n):
    return uniform_hemisphere(rng, n), uniform_hemisphere(rng, n)


def families(materials):
    """Material index sets of every family: archetypes and (lobe kind, Fresnel) combinations."""
    out = {name: np.flatnonzero(materials.archetype == i) for i, name in enumerate(ARCHETYPES)}
    kinds = materials.lobe_kind
    for kind, label in ((LOBE_GGX, "ggx"), (LOBE_BECKMANN, "beckmann"), (LOBE_ABC, "abc")):
        for conductor in (False, True):
            if kind == LOBE_ABC and conductor:
                continue
            has = ((kinds == kind) & (materials.lobe_conductor == conductor)).any(axis=1)
            out[f"{label}-{'conductor' if conductor else 'dielectric'}"] = np.flatnonzero(has)
    out["coated-diffuse"] = np.flatnonzero(materials.coat_eta > 0)
    out["two-lobe"] = np.flatnonzero((kinds != 0).sum(axis=1) == 2)
    return out


# ------------------------------------------------------------------------------- physics


@pytest.mark.parametrize("alpha", [0.05, 0.3, 0.8])
@pytest.mark.parametrize("theta_deg", [0.0, 40.0, 70.0, 85.0])
def test_beckmann_smith_g1_satisfies_the_projected_area_identity(alpha, theta_deg):
    # Heitz 2014 Eq. 5: G1(wo) ∫ max(0, wo·m) D(m) dm = cos θo for the exact Smith masking.
    t = math.radians(theta_deg)
    wo = np.array([math.sin(t), 0.0, math.cos(t)])
    theta_m = np.linspace(0.0, math.pi / 2, 1601)[1:-1]
    phi_m = np.linspace(0.0, 2 * math.pi, 801)[:-1]
    tm, pm = np.meshgrid(theta_m, phi_m, indexing="ij")
    m = np.stack([np.sin(tm) * np.cos(pm), np.sin(tm) * np.sin(pm), np.cos(tm)], axis=-1)
    integrand = np.maximum(m @ wo, 0.0) * beckmann_distribution(np.cos(tm), alpha) * np.sin(tm)
    projected = integrate.trapezoid(integrand.sum(axis=1) * (2 * math.pi / len(phi_m)), theta_m)
    assert beckmann_smith_g1(math.cos(t), alpha) == pytest.approx(math.cos(t) / projected, rel=2e-3)


def test_beckmann_smith_g1_limits():
    assert beckmann_smith_g1(1.0, 0.3) == 1.0
    assert beckmann_smith_g1(0.0, 0.3) == 0.0
    assert beckmann_smith_g1(-0.5, 0.3) == 0.0
    g = beckmann_smith_g1(np.linspace(0.01, 1, 50), 0.5)
    assert np.all(np.diff(g) >= 0)


@pytest.mark.parametrize("b, c", [(10.0, 1.5), (3e3, 0.9), (2e5, 1.2), (5e6, 0.1), (1.0, 2.0)])
def test_abc_lobe_integral_matches_quadrature_over_theta_o(b, c):
    # ∫ S(θh) dω_o at normal incidence, θh = θo/2, integrated directly in θo (split near the peak).
    def integrand(theta_o):
        return 2 * math.pi * (1 + b * (1 - math.cos(theta_o / 2))) ** (-c) * math.sin(theta_o)

    peak = min(math.pi / 2, 50 / math.sqrt(b))
    reference = sum(integrate.quad(integrand, lo, hi, limit=200)[0] for lo, hi in ((0, peak), (peak, math.pi / 2)))
    assert abc_lobe_integral(b, c) == pytest.approx(reference, rel=1e-4)


def test_ggx_normals_follow_the_closed_form_cdf():
    # Density D(h) cos θh: P(tan²θh <= t) = t / (alpha² + t).
    rng = np.random.default_rng(3)
    alpha = 0.2
    h = sample_ggx_normal(rng, np.full(200_000, alpha))
    np.testing.assert_allclose(np.linalg.norm(h, axis=1), 1.0, atol=1e-12)
    tan2 = (h[:, 0] ** 2 + h[:, 1] ** 2) / h[:, 2] ** 2
    for t in (0.001, 0.01, 0.04, 0.2, 1.0):
        assert np.mean(tan2 <= t) == pytest.approx(t / (alpha**2 + t), abs=4e-3)


# ------------------------------------------------------------------------------- materials


def test_every_family_is_present(materials):
    for name, index in families(materials).items():
        assert index.size >= 5, name


def test_every_family_is_reciprocal(materials):
    rng = np.random.default_rng(0)
    for name, index in families(materials).items():
        m = np.repeat(index, 50)
        wi, wo = random_pairs(rng, m.size)
        forward, backward = materials.evaluate(m, wi, wo), materials.evaluate(m, wo, wi)
        np.testing.assert_allclose(forward, backward, rtol=1e-10, atol=1e-14, err_msg=name)


def test_every_family_is_isotropic(materials):
    rng = np.random.default_rng(1)
    m = rng.integers(0, len(materials), 5000)
    wi, wo = random_pairs(rng, m.size)
    angle = rng.uniform(0, 2 * math.pi, m.size)
    c, s = np.cos(angle), np.sin(angle)

    def rotate(v):
        return np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]], axis=1)

    rotated = materials.evaluate(m, rotate(wi), rotate(wo))
    np.testing.assert_allclose(rotated, materials.evaluate(m, wi, wo), rtol=1e-8, atol=1e-12)


def test_values_are_finite_non_negative_and_zero_below_the_horizon(materials):
    rng = np.random.default_rng(2)
    m = rng.integers(0, len(materials), 20_000)
    wi, wo = random_pairs(rng, m.size)
    # grazing directions: cos θ down to 1e-9
    wi[:2000, 2] = np.geomspace(1e-9, 1e-2, 2000)
    wi[:2000] /= np.linalg.norm(wi[:2000], axis=1, keepdims=True)
    f = materials.evaluate(m, wi, wo)
    assert np.all(np.isfinite(f)) and np.all(f >= 0)
    assert np.mean(f.max(axis=1) > 0) > 0.9  # Beckmann lobes of bare metals underflow far off-peak
    below = wo.copy()
    below[:, 2] = -below[:, 2]
    assert np.all(materials.evaluate(m, wi, below) == 0)
    flat = wo.copy()
    flat[:, 2] = 0.0
    assert np.all(materials.evaluate(m, wi, flat) == 0)


def test_lambert_albedo_and_energy_bound(materials):
    rng = np.random.default_rng(4)
    n = 200_000
    wo = uniform_hemisphere(rng, n)
    wi = np.broadcast_to([0.0, 0.0, 1.0], (n, 3))
    diffuse = np.flatnonzero(materials.archetype == ARCHETYPES.index("diffuse"))[:3]
    rough = (materials.lobe_alpha >= 0.1).all(axis=1) & (materials.lobe_kind != LOBE_ABC).all(axis=1)
    smooth = np.flatnonzero(rough)[:12]  # lobes broad enough for uniform Monte Carlo
    for index in (*diffuse, *smooth):
        # albedo = ∫ f cos θo dωo, uniform sampling (pdf 1/2π)
        albedo = (materials.evaluate(np.full(n, index), wi, wo) * wo[:, 2:]).mean(axis=0) * 2 * math.pi
        if index in diffuse:
            np.testing.assert_allclose(albedo, materials.albedo[index], rtol=0.01)
        assert np.all(albedo <= 1.02), (index, albedo)


def test_abc_lobes_match_abc_brdf_per_material(materials):
    rng = np.random.default_rng(5)
    index = np.flatnonzero(materials.lobe_kind[:, 0] == LOBE_ABC)[:5]
    wi, wo = random_pairs(rng, 200)
    for i in index:
        single = materials.subset(np.array([i]))
        # keep only lobe 0 (ABC) of this material
        single = dataclasses.replace(single, albedo=np.zeros((1, 3)), lobe_kind=single.lobe_kind * np.array([[1, 0]]))
        b, c, eta = single.lobe_b[0, 0], single.lobe_c[0, 0], single.lobe_eta[0, 0, 0]
        expected = abc_brdf(wi, wo, np.zeros(3), single.lobe_weight[0, 0], b, c, eta)
        np.testing.assert_allclose(single.evaluate(np.zeros(200, int), wi, wo), expected, rtol=1e-12)


def test_generation_is_seeded():
    a, b, c = generate_materials(50, 11), generate_materials(50, 11), generate_materials(50, 12)
    for field in ("albedo", "lobe_kind", "lobe_alpha", "lobe_weight", "lobe_eta", "lobe_k", "lobe_b"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert not np.array_equal(a.albedo, c.albedo)
    x = sample_batch(a, 1000, np.random.default_rng(3))
    y = sample_batch(b, 1000, np.random.default_rng(3))
    for field in ("material", "wi", "wo", "f"):
        np.testing.assert_array_equal(getattr(x, field), getattr(y, field))


def test_archetype_weights_select_families():
    only_metal = generate_materials(30, 0, (0, 0, 1, 0))
    assert np.all(only_metal.archetype == ARCHETYPES.index("metal"))
    assert np.all(only_metal.lobe_conductor[:, 0])


@pytest.mark.parametrize(
    "kwargs, column",
    [({"n_materials": 0}, "n_materials"), ({"n_materials": 3, "archetype_weights": (1, 0, 0)}, "archetype_weights"),
     ({"n_materials": 3, "archetype_weights": (-1, 1, 1, 1)}, "archetype_weights")],
)
def test_bad_generation_arguments_raise(kwargs, column):
    kwargs.setdefault("seed", 0)
    with pytest.raises(InputError) as info:
        generate_materials(**kwargs)
    assert info.value.key == column


# ------------------------------------------------------------------------------- sampling


def test_samples_cover_the_hemisphere_and_the_specular_peaks(materials):
    rng = np.random.default_rng(6)
    batch = sample_batch(materials, 100_000, rng, uniform_fraction=0.5)
    for w in (batch.wi, batch.wo):
        np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-12)
        assert np.all(w[:, 2] > 0)
    # grazing coverage: uniform pairs alone put 10% of wo below cos θ = 0.1
    assert np.mean(batch.wo[:, 2] < 0.1) > 0.04
    # peaks: half vectors within 3° of the normal, ~0.14% for uniform pairs
    h = batch.wi + batch.wo
    cos_h = h[:, 2] / np.linalg.norm(h, axis=1)
    assert np.mean(cos_h > math.cos(math.radians(3))) > 0.1
    # every sample is the material's value at its directions
    np.testing.assert_array_equal(batch.f, materials.evaluate(batch.material, batch.wi, batch.wo))


def test_sample_batch_rejects_a_bad_uniform_fraction(materials):
    with pytest.raises(InputError):
        sample_batch(materials, 10, np.random.default_rng(0), uniform_fraction=1.5)


# ------------------------------------------------------------------------------- data module


def test_corpus_batches_are_generated_reproducibly_per_epoch_and_stream(materials):
    from neuralbrdf.lightning.corpus_data import CorpusBatches

    def batch(epoch=0, stream=0, index=0, seed=0):
        return CorpusBatches(materials, 64, 4, seed, stream, epoch)[index]

    first = batch()
    assert first.material.dtype == torch.long and first.wi.dtype == torch.float32 and first.f.shape == (64, 3)
    torch.testing.assert_close(batch().f, first.f, rtol=0, atol=0)
    for other in (batch(epoch=1), batch(stream=1), batch(index=1), batch(seed=1)):
        assert not torch.equal(other.wi, first.wi)
    with pytest.raises(IndexError):
        batch(index=4)


def test_corpus_data_module_checks_its_arguments():
    from neuralbrdf.lightning.corpus_data import CorpusDataModule

    data = CorpusDataModule(n_analytic=5, batch_size=8, batches_per_epoch=3, val_batches=2)
    assert data.n_materials == 5
    assert len(data.train_dataloader()) == 3 and len(data.val_dataloader()) == 2
    for bad in ({"n_analytic": 0}, {"batch_size": 1.5}, {"uniform_fraction": -0.1}):
        with pytest.raises(InputError):
            CorpusDataModule(**bad)


def test_thin_films_coat_some_dielectric_lobes_and_leave_the_rest_of_the_corpus_as_it_was():
    plain = generate_materials(300, seed=5)
    filmed = generate_materials(300, seed=5, thin_film_probability=0.5)
    for field in dataclasses.fields(plain):
        if field.name not in ("lobe_film_nm", "lobe_film_index", "channel_wavelength"):
            np.testing.assert_array_equal(getattr(plain, field.name), getattr(filmed, field.name))
    coated = filmed.lobe_film_nm > 0
    dielectric = np.isin(filmed.lobe_kind, (LOBE_GGX, LOBE_BECKMANN)) & ~filmed.lobe_conductor
    assert coated.any() and not (coated & ~dielectric).any()
    assert 0.3 < coated[dielectric].mean() < 0.7
    assert not (plain.lobe_film_nm > 0).any()
    with pytest.raises(InputError, match="thin_film_probability"):
        generate_materials(3, seed=0, thin_film_probability=1.5)


def test_a_thin_film_lobe_is_the_airy_reflectance_at_its_channels_wavelengths_and_stays_reciprocal():
    """A coated lobe over the same lobe without its film is the Airy reflectance over the bare
    dielectric Fresnel term, per channel at the channel's wavelength; swapping wi and wo changes nothing."""
    from neuralbrdf.physics.fresnel import fresnel_dielectric
    from neuralbrdf.physics.thin_film import thin_film_reflectance

    filmed = generate_materials(300, seed=5, thin_film_probability=0.5)
    m = int(np.flatnonzero(filmed.lobe_film_nm[:, 0] > 0)[0])
    bare = dataclasses.replace(filmed, lobe_film_nm=np.zeros_like(filmed.lobe_film_nm))
    rng = np.random.default_rng(3)
    wi, wo = random_pairs(rng, 500)
    material = np.full(500, m)
    lobe = lambda c: c._lobe(filmed.lobe_kind[m, 0], material, 0, wi, wo)  # noqa: E731
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    cos_d = (wi * h).sum(1)[:, None]
    eta = filmed.lobe_eta[m, 0]
    airy = thin_film_reflectance(cos_d, filmed.channel_wavelength[m], filmed.lobe_film_index[m, 0],
                                 filmed.lobe_film_nm[m, 0], eta[0])
    np.testing.assert_allclose(lobe(filmed), lobe(bare) * airy / fresnel_dielectric(cos_d, eta), rtol=1e-9, atol=1e-300)
    np.testing.assert_allclose(filmed.evaluate(material, wi, wo), filmed.evaluate(material, wo, wi), rtol=1e-10)
    # interference: the channels' ratio changes with angle (a goniochromatic colour shift)
    near, grazing = airy[cos_d[:, 0] > 0.95], airy[cos_d[:, 0] < 0.4]
    ratio = lambda r: r[:, 0] / r[:, 2]  # noqa: E731
    assert abs(np.median(ratio(near)) - np.median(ratio(grazing))) > 0.05
