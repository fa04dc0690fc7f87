"""Conventions of docs/formats.md#conventions checked against independent constructions."""

import math

import numpy as np
import pytest
import torch

from neuralbrdf import geometry as g

rng = np.random.default_rng(7)


def random_hemisphere(n):
    theta = np.degrees(np.arccos(rng.uniform(0.02, 1.0, n)))
    phi = rng.uniform(0.0, 360.0, n)
    return theta, phi


def test_spherical_vector_round_trip():
    theta, phi = random_hemisphere(500)
    v = g.spherical_to_vector(theta, phi)
    np.testing.assert_allclose(np.linalg.norm(v, axis=-1), 1.0, atol=1e-12)
    theta2, phi2 = g.vector_to_spherical(v)
    np.testing.assert_allclose(theta2, theta, atol=1e-9)
    np.testing.assert_allclose(phi2, phi, atol=1e-9)
    assert np.all((phi2 >= 0) & (phi2 < 360))


def test_inplane_vectors_follow_report_convention():
    wi, wo = g.inplane_to_vectors(np.array([30.0]), np.array([30.0]))
    # theta_r = theta_i is the mirror direction
    np.testing.assert_allclose(wo, g.reflect(wi), atol=1e-15)
    np.testing.assert_allclose(wi[0], [0.5, 0.0, math.sqrt(3) / 2], atol=1e-15)


def test_inplane_to_spherical_gives_the_vectors_back():
    ti = rng.uniform(-89, 89, 300)
    tr = rng.uniform(-89, 89, 300)
    wi, wo = g.inplane_to_vectors(ti, tr)
    sph = g.inplane_to_spherical(ti, tr)
    wi2, wo2 = g.spherical_pair_to_vectors(*sph)
    # isotropic rotation about z: polar angles and the angle between the directions survive
    np.testing.assert_allclose(wi2[:, 2], wi[:, 2], atol=1e-12)
    np.testing.assert_allclose(wo2[:, 2], wo[:, 2], atol=1e-12)
    np.testing.assert_allclose(g.dot(wi2, wo2), g.dot(wi, wo), atol=1e-12)
    np.testing.assert_allclose(wi2, wi, atol=1e-12)  # exact vectors, not merely equivalent ones
    np.testing.assert_allclose(wo2, wo, atol=1e-12)


@pytest.mark.parametrize(
    "ti, tr, phi_i, phi_o",
    [(30, 20, 0, 180), (30, -20, 0, 0), (-30, -20, 180, 0), (-30, 20, 180, 180), (0, 10, 0, 180), (10, 0, 0, 0)],
)
def test_inplane_azimuths_are_those_of_the_vectors(ti, tr, phi_i, phi_o):
    sph = g.inplane_to_spherical(np.array([ti * 1.0]), np.array([tr * 1.0]))
    assert (sph[1][0], sph[3][0]) == (phi_i, phi_o)
    # phi_o - phi_i = 180 exactly when theta_r has the sign of theta_i (docs/formats.md#conventions)
    assert (abs(phi_o - phi_i) == 180) == (tr * (1 if ti >= 0 else -1) > 0)


def test_spherical_to_inplane_inverts_inplane_to_spherical_with_signs():
    ti = np.concatenate([rng.uniform(-89, 89, 300), [0.0, 0.0, -45.0, 60.0]])
    tr = np.concatenate([rng.uniform(-89, 89, 300), [0.0, -30.0, 0.0, 60.0]])
    back = g.spherical_to_inplane(*g.inplane_to_spherical(ti, tr))
    np.testing.assert_allclose(back[0], ti, atol=1e-9)
    np.testing.assert_allclose(back[1], tr, atol=1e-9)


def test_spherical_to_inplane_reads_the_rotated_spec_form_and_out_of_plane_pairs():
    # the report's phi_i = 0 form (docs/formats.md#conventions) of (-30, -20) is (30, 20): the mirror image, same BRDF value
    back = g.spherical_to_inplane(np.array([30.0]), np.array([0.0]), np.array([20.0]), np.array([180.0]))
    assert np.allclose(back, [[30.0], [20.0]])
    theta_i, phi_i = random_hemisphere(100)
    theta_o, phi_o = random_hemisphere(100)
    back = g.spherical_to_inplane(theta_i, phi_i, theta_o, phi_o)
    expected = g.inplane_equivalent(*g.spherical_pair_to_vectors(theta_i, phi_i, theta_o, phi_o))
    np.testing.assert_allclose(back, expected, atol=1e-9)


def test_half_diff_closed_form_for_inplane_pairs():
    ti = rng.uniform(-80, 80, 400)
    tr = rng.uniform(-80, 80, 400)
    wi, wo = g.inplane_to_vectors(ti, tr)
    th, _, td, _ = g.half_diff_angles(wi, wo)
    th_c, td_c = g.inplane_half_diff_angles(ti, tr)
    np.testing.assert_allclose(th, th_c, atol=1e-7)
    np.testing.assert_allclose(td, td_c, atol=1e-7)


def _rot(axis, angle):
    c, s = math.cos(angle), math.sin(angle)
    if axis == "z":
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def test_difference_vector_matches_explicit_rotation_matrices():
    ti_, pi_ = random_hemisphere(50)
    to_, po_ = random_hemisphere(50)
    wi, wo = g.spherical_pair_to_vectors(ti_, pi_, to_, po_)
    h, d = g.half_diff_vectors(wi, wo)
    for k in range(50):
        hk = (wi[k] + wo[k]) / np.linalg.norm(wi[k] + wo[k])
        theta_h = math.acos(hk[2])
        phi_h = math.atan2(hk[1], hk[0])
        dk = _rot("y", -theta_h) @ _rot("z", -phi_h) @ wi[k]
        np.testing.assert_allclose(h[k], hk, atol=1e-12)
        np.testing.assert_allclose(d[k], dk, atol=1e-12)
        # rotating h the same way lands on the pole
        np.testing.assert_allclose(_rot("y", -theta_h) @ _rot("z", -phi_h) @ hk, [0, 0, 1], atol=1e-12)


def test_inplane_equivalent_preserves_half_diff_angles():
    ti_, pi_ = random_hemisphere(300)
    to_, po_ = random_hemisphere(300)
    wi, wo = g.spherical_pair_to_vectors(ti_, pi_, to_, po_)
    th, _, td, _ = g.half_diff_angles(wi, wo)
    ei, er = g.inplane_equivalent(wi, wo)
    th2, td2 = g.inplane_half_diff_angles(ei, er)
    np.testing.assert_allclose(th2, th, atol=1e-7)
    np.testing.assert_allclose(td2, td, atol=1e-7)


def test_inplane_equivalent_of_inplane_pairs_is_a_symmetric_image():
    ti = rng.uniform(-80, 80, 300)
    tr = rng.uniform(-80, 80, 300)
    ei, er = g.inplane_equivalent(*g.inplane_to_vectors(ti, tr))
    images = np.stack([[ti, tr], [tr, ti], [-ti, -tr], [-tr, -ti]])  # reciprocity x mirror
    hit = np.isclose(images[:, 0], ei, atol=1e-6) & np.isclose(images[:, 1], er, atol=1e-6)
    assert hit.any(axis=0).all()


def test_half_diff_invariant_under_isotropic_rotation_and_swap():
    ti_, pi_ = random_hemisphere(200)
    to_, po_ = random_hemisphere(200)
    base = g.half_diff_angles(*g.spherical_pair_to_vectors(ti_, pi_, to_, po_))
    rotated = g.half_diff_angles(*g.spherical_pair_to_vectors(ti_, (pi_ + 77) % 360, to_, (po_ + 77) % 360))
    swapped = g.half_diff_angles(*g.spherical_pair_to_vectors(to_, po_, ti_, pi_))
    for a, b in ((base, rotated), (base, swapped)):
        np.testing.assert_allclose(a[0], b[0], atol=1e-7)  # theta_h
        np.testing.assert_allclose(a[2], b[2], atol=1e-7)  # theta_d


def test_torch_and_numpy_agree_and_torch_differentiates():
    ti = rng.uniform(-80, 80, 64)
    tr = rng.uniform(-80, 80, 64)
    ref = g.inplane_equivalent(*g.inplane_to_vectors(ti, tr))
    t_ti = torch.tensor(ti, requires_grad=True)
    out = g.inplane_equivalent(*g.inplane_to_vectors(t_ti, torch.tensor(tr)))
    np.testing.assert_allclose(out[0].detach().numpy(), ref[0], atol=1e-9)
    out[0].sum().backward()
    assert torch.isfinite(t_ti.grad).all()


def test_half_diff_to_vectors_inverts_half_diff_angles():
    rng = np.random.default_rng(3)
    theta_h, theta_d = rng.uniform(1, 89, 500), rng.uniform(1, 89, 500)
    phi_d, phi_h = rng.uniform(1, 359, 500), rng.uniform(1, 359, 500)
    wi, wo = g.half_diff_to_vectors(theta_h, theta_d, phi_d, phi_h)
    np.testing.assert_allclose(np.linalg.norm(wi, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(wo, axis=1), 1.0, atol=1e-12)
    back = g.half_diff_angles(wi, wo)
    for got, want in zip(back, (theta_h, phi_h, theta_d, phi_d)):
        np.testing.assert_allclose(got, want, atol=1e-8)


def test_half_diff_to_vectors_at_phi_d_90_stays_above_the_horizon_and_in_plane_at_0():
    theta_h, theta_d = (a.ravel() for a in np.meshgrid(np.linspace(0.5, 89.5, 90), np.linspace(0.5, 89.5, 90)))
    wi, wo = g.half_diff_to_vectors(theta_h, theta_d, np.full_like(theta_h, 90.0))
    assert np.all(wi[:, 2] > 0) and np.all(wo[:, 2] > 0)
    wi, wo = g.half_diff_to_vectors(np.array([10.0]), np.array([30.0]), np.array([0.0]))  # in plane: ti = 40, tr = 20
    ref_i, ref_o = g.inplane_to_vectors(np.array([40.0]), np.array([20.0]))
    np.testing.assert_allclose(wi, ref_i, atol=1e-12)
    np.testing.assert_allclose(wo, ref_o, atol=1e-12)
