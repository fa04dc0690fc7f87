"""The baked-table model (docs/select.md; :mod:`neuralbrdf.models.baked_table`): its Rusinkiewicz
coordinates against an explicit rotation, its nodes against the coordinates, its interpolation
against functions it must reproduce exactly, and baking (:mod:`neuralbrdf.lod.bake`) against
analytic parents."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import onnx_fixtures as fx
from neuralbrdf.evaluation.scores import OnnxEvaluator, hemisphere_scores
from neuralbrdf.kinds import load_model
from neuralbrdf.lod.bake import bake_table
from neuralbrdf.models.baked_table import BakedTable, node_directions, table_coordinates
from neuralbrdf.onnx_export import write_model

rng = np.random.default_rng(5)


def upper_directions(n):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 1e-3
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def rusinkiewicz_by_rotation(wi, wo):
    """``(θh, θd, φd)`` the textbook way: rotate ``wi`` by ``−φh`` about z and ``−θh`` about y."""
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    theta_h, phi_h = np.arccos(np.clip(h[:, 2], -1, 1)), np.arctan2(h[:, 1], h[:, 0])
    c, s = np.cos(-phi_h), np.sin(-phi_h)
    x, y = c * wi[:, 0] - s * wi[:, 1], s * wi[:, 0] + c * wi[:, 1]
    c, s = np.cos(-theta_h), np.sin(-theta_h)
    d = np.stack([c * x + s * wi[:, 2], y, -s * x + c * wi[:, 2]], axis=1)
    return theta_h, np.arccos(np.clip(d[:, 2], -1, 1)), np.arctan2(d[:, 1], d[:, 0])


def test_coordinates_match_an_explicit_rotation():
    wi, wo = upper_directions(5000), upper_directions(5000)
    theta_h, theta_d, phi_d = rusinkiewicz_by_rotation(wi, wo)
    a_h, a_d, a_p = (c.numpy() for c in table_coordinates(torch.tensor(wi), torch.tensor(wo)))
    np.testing.assert_allclose(a_h, (1 - np.cos(theta_h)) ** 0.25, atol=1e-6)
    np.testing.assert_allclose(a_d, np.cos(theta_d), atol=1e-6)
    away = np.sin(theta_h) > 1e-3  # φd is undefined at the mirror direction
    np.testing.assert_allclose(a_p[away], np.abs(np.cos(phi_d[away])), atol=1e-5)


def test_coordinates_are_reciprocal():
    wi, wo = torch.tensor(upper_directions(1000)), torch.tensor(upper_directions(1000))
    for forward, backward in zip(table_coordinates(wi, wo), table_coordinates(wo, wi)):
        torch.testing.assert_close(forward, backward)


def test_nodes_sit_at_their_coordinates():
    nodes = (7, 5, 4)
    wi, wo = node_directions(nodes)
    np.testing.assert_allclose(np.linalg.norm(wi, axis=1), 1.0, atol=1e-12)
    grid = np.stack([g.ravel() for g in np.meshgrid(*(np.linspace(0, 1, n) for n in nodes), indexing="ij")], axis=1)
    ours = np.stack([c.numpy() for c in table_coordinates(torch.tensor(wi), torch.tensor(wo))], axis=1)
    # θd = 90° makes wo = −wi (no half vector); φd means nothing at θh = 0 or θd = 0
    pair = grid[:, 1] > 0
    np.testing.assert_allclose(ours[pair, :2], grid[pair, :2], atol=1e-6)
    defined = pair & (grid[:, 0] > 0) & (grid[:, 1] < 1)
    np.testing.assert_allclose(ours[defined], grid[defined], atol=1e-6)


def multilinear(a_h, a_d, a_p, a_l):
    """A function the table reproduces exactly: linear in each coordinate separately."""
    return 0.5 + a_h + 2 * a_d * a_p + 0.3 * a_h * a_d * a_p * a_l + 0.2 * a_l


def test_interpolation_reproduces_a_multilinear_function():
    nodes = (5, 4, 3, 6)
    axes = np.meshgrid(*(np.linspace(0, 1, n) for n in nodes), indexing="ij")
    table = BakedTable(torch.tensor(multilinear(*axes)), (400.0, 700.0))
    wi, wo = upper_directions(3000), upper_directions(3000)
    wavelength = rng.uniform(400.0, 700.0, 3000)
    coordinates = [c.numpy() for c in table_coordinates(torch.tensor(wi), torch.tensor(wo))]
    expected = multilinear(*coordinates, (wavelength - 400.0) / 300.0)
    ours = table(torch.tensor(wi, dtype=torch.float32), torch.tensor(wo, dtype=torch.float32),
                 torch.tensor(wavelength, dtype=torch.float32)).numpy()
    np.testing.assert_allclose(ours, expected, rtol=2e-5, atol=1e-5)


def test_rgb_table_interpolates_each_channel_and_is_zero_below_the_horizon():
    nodes = (4, 3, 3)
    axes = np.meshgrid(*(np.linspace(0, 1, n) for n in nodes), indexing="ij")
    channels = np.stack([multilinear(*axes, 0.0), 2 * axes[0] + 0.1, 1 - axes[1] * axes[2] + 0.1], axis=-1)
    table = BakedTable(torch.tensor(channels))
    wi, wo = upper_directions(500), upper_directions(500)
    wo[:50, 2] *= -1
    a_h, a_d, a_p = (c.numpy() for c in table_coordinates(torch.tensor(wi), torch.tensor(wo)))
    expected = np.stack([multilinear(a_h, a_d, a_p, 0.0), 2 * a_h + 0.1, 1 - a_d * a_p + 0.1], axis=-1)
    expected[:50] = 0.0
    ours = table(torch.tensor(wi, dtype=torch.float32), torch.tensor(wo, dtype=torch.float32)).numpy()
    np.testing.assert_allclose(ours, expected, rtol=2e-5, atol=1e-5)


@pytest.mark.parametrize("values", [np.zeros((1, 3, 3, 3)), -np.ones((2, 2, 2, 3)), np.full((2, 2, 2, 3), np.nan)])
def test_bad_tables_are_refused(values):
    with pytest.raises(ValueError):
        BakedTable(torch.tensor(values))


def test_baking_a_spectral_lambertian_is_exact(tmp_path):
    """A Lambertian that is linear in wavelength lies in the table's interpolation space: baked at
    the coarsest grid, it is reproduced to float32 rounding everywhere above the horizon."""
    parent = OnnxEvaluator(fx.write_spectral_lambert(tmp_path / "lambert.onnx", a=0.2, b=0.6))
    path = tmp_path / "table.onnx"
    write_model(bake_table(parent, (2, 2, 2, 2), "lambert", "test"), path)
    model = load_model(path)
    assert model.kind == "table" and model.details == (2, 2, 2, 2)
    wi, wo = upper_directions(2000), upper_directions(2000)
    wavelength = rng.uniform(400.0, 700.0, 2000)
    np.testing.assert_allclose(OnnxEvaluator(path).values(wi, wo, wavelength), parent.values(wi, wo, wavelength),
                               rtol=1e-5)


def test_a_finer_table_follows_a_glossy_lobe_more_closely(tmp_path):
    parent = OnnxEvaluator(fx.write_ggx_glossy(tmp_path / "ggx.onnx", alpha=0.15))
    errors = []
    for nodes in ((8, 6, 4), (32, 16, 8)):
        path = tmp_path / f"table{nodes[0]}.onnx"
        write_model(bake_table(parent, nodes, "ggx", "test"), path)
        errors.append(hemisphere_scores(OnnxEvaluator(path), parent, strata=(8, 10))["hemisphere_logcos_rmse"])
    assert errors[1] < 0.5 * errors[0], errors
    assert errors[1] < 0.02, errors


def test_measured_axes_invert_their_nodes_and_tell_wi_from_wo():
    """``axes="measured"``: θd uniform, φd over [0°, 180°]; the table coordinates of the node directions
    are the nodes, and exchanging wi and wo maps a_p to 1 − a_p (the reciprocal axes cannot tell them apart)."""
    nodes = (5, 6, 7)
    grid = np.stack(np.meshgrid(*(np.linspace(0, 1, n) for n in nodes), indexing="ij"), -1).reshape(-1, 3)
    regular = (grid[:, 0] > 0) & (grid[:, 1] > 0) & (grid[:, 1] < 1)  # φd is undefined at θh = 0, θd = 0 or 90°
    wi, wo = node_directions(nodes, "measured")
    theta_d = np.degrees(np.arccos(np.clip(np.sum(wi * (wi + wo), axis=1) / np.linalg.norm(wi + wo, axis=1), -1, 1)))
    np.testing.assert_allclose(theta_d[regular], 90.0 * grid[regular, 1], atol=1e-6)
    forward = np.stack([c.numpy() for c in table_coordinates(torch.tensor(wi), torch.tensor(wo), "measured")], axis=1)
    np.testing.assert_allclose(forward[regular], grid[regular], atol=1e-9)
    backward = table_coordinates(torch.tensor(wo), torch.tensor(wi), "measured")[2].numpy()
    np.testing.assert_allclose(backward[regular], 1.0 - grid[regular, 2], atol=1e-9)
    reciprocal = [table_coordinates(torch.tensor(a), torch.tensor(b))[2].numpy() for a, b in ((wi, wo), (wo, wi))]
    np.testing.assert_allclose(reciprocal[0], reciprocal[1], atol=1e-9)
