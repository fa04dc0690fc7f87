"""NBRDF reader and evaluator (docs/formats.md#nbrdf-proxy; Sztrajman et al. 2021) on the MERL proxies.

The references here are independent of the module: a per-sample pure-Python evaluation with
explicit rotation matrices and weights read straight from h5py, a Monte Carlo albedo, and
symmetries of isotropic BRDFs.
"""

import base64
import json
import math
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from neuralbrdf.data.nbrdf import (
    REPORT_MATERIALS,
    NbrdfNetwork,
    available_materials,
    nbrdf_input,
    sample_directions,
    sample_plan,
)
from neuralbrdf.data.plans import in_plane_plan
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import inplane_to_vectors

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "merl-nbrdf"
pytestmark = pytest.mark.skipif(
    not DATA.is_dir(), reason=f"NBRDF reference data not found at {DATA} (docs/formats.md#nbrdf-proxy)"
)

GLOSSY = ("tungsten-carbide", "brass", "blue-acrylic", "specular-black-phenolic")


def random_upper_directions(rng, count):
    v = rng.normal(size=(count, 3))
    v[:, 2] = np.abs(v[:, 2]) + 1e-3
    return v / np.linalg.norm(v, axis=1, keepdims=True)


# ---------------------------------------------------------------- scalar reference

def rot_z(angle):
    c, s = math.cos(angle), math.sin(angle)
    return [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]


def rot_y(angle):
    c, s = math.cos(angle), math.sin(angle)
    return [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]


def mat_vec(m, v):
    return [sum(m[r][k] * v[k] for k in range(3)) for r in range(3)]


def read_layers(path):
    """Weights as nested lists, read with h5py independently of the module under test."""
    with h5py.File(path, "r") as f:
        return [
            (f[f"{n}/{n}/kernel:0"][()].tolist(), f[f"{n}/{n}/bias:0"][()].tolist())
            for n in ("dense_1", "dense_2", "dense_3")
        ]


def reference_brdf(layers, wi, wo):
    """One sample, pure Python: Rusinkiewicz rotation with explicit matrices, plain-loop MLP."""
    s = [wi[k] + wo[k] for k in range(3)]
    norm = math.sqrt(sum(c * c for c in s))
    h = [c / norm for c in s]
    theta_h = math.acos(h[2])
    phi_h = math.atan2(h[1], h[0])
    d = mat_vec(rot_y(-theta_h), mat_vec(rot_z(-phi_h), list(wi)))
    x = [math.sin(theta_h), 0.0, math.cos(theta_h), *d]
    for index, (kernel, bias) in enumerate(layers):
        y = [bias[j] + sum(x[i] * kernel[i][j] for i in range(len(x))) for j in range(len(bias))]
        x = [max(v, 0.0) for v in y] if index < 2 else y
    return [max(math.exp(v) - 1.0, 0.0) for v in x]


@pytest.mark.parametrize("material", ["brass", "nylon"])
def test_vectorised_evaluation_matches_scalar_reference(material):
    rng = np.random.default_rng(7)
    wi = random_upper_directions(rng, 200)
    wo = random_upper_directions(rng, 200)
    network = NbrdfNetwork.load(DATA / f"{material}.h5")
    layers = read_layers(DATA / f"{material}.h5")
    expected = np.array([reference_brdf(layers, a, b) for a, b in zip(wi.tolist(), wo.tolist())])
    np.testing.assert_allclose(network.evaluate(wi, wo), expected, rtol=1e-5, atol=1e-12)
    assert np.count_nonzero(expected) > 300  # the comparison is not between clamped zeros


def test_network_input_is_half_vector_at_phi_zero_and_unit_difference():
    rng = np.random.default_rng(3)
    wi = random_upper_directions(rng, 100)
    wo = random_upper_directions(rng, 100)
    x = nbrdf_input(wi, wo)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    np.testing.assert_allclose(x[:, 0], np.sqrt(1 - h[:, 2] ** 2), atol=1e-12)
    assert np.all(x[:, 1] == 0)
    np.testing.assert_allclose(x[:, 2], h[:, 2], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(x[:, 3:], axis=1), 1.0, atol=1e-12)
    # d is wi in the frame whose pole is h: its z is cos(theta_d) = wi . h
    np.testing.assert_allclose(x[:, 5], np.sum(wi * h, axis=1), atol=1e-12)


# ---------------------------------------------------------------- symmetries and torch

@pytest.fixture(scope="module")
def brass():
    return NbrdfNetwork.load(DATA / "brass.json")


def test_isotropy_rotation_about_normal(brass):
    rng = np.random.default_rng(11)
    wi = random_upper_directions(rng, 500)
    wo = random_upper_directions(rng, 500)
    angle = rng.uniform(0, 2 * np.pi, size=(500, 1))
    c, s = np.cos(angle), np.sin(angle)

    def rotate(v):
        return np.stack([c[:, 0] * v[:, 0] - s[:, 0] * v[:, 1],
                         s[:, 0] * v[:, 0] + c[:, 0] * v[:, 1], v[:, 2]], axis=1)

    np.testing.assert_allclose(brass.evaluate(rotate(wi), rotate(wo)), brass.evaluate(wi, wo),
                               rtol=1e-8, atol=1e-12)


def test_mirror_configuration_is_the_in_plane_limit_and_rotation_invariant(brass):
    """At theta_h = 0 phi_h is undefined; the module fixes phi_h = phi_i (see nbrdf_input)."""
    theta = np.array([10.0, 30.0, 55.0])
    near, nearer = (brass.evaluate(*inplane_to_vectors(theta, theta - step))
                    for step in (2e-3, 1e-3))
    exact = brass.evaluate(*inplane_to_vectors(theta, theta))
    # the lobe is steep (0.3 % per 0.001°): extrapolate the approach linearly to the mirror
    np.testing.assert_allclose(exact, 2 * nearer - near, rtol=1e-4)
    # the same pairs given as spherical angles at several azimuths (rounding noise in h_x, h_y)
    for phi in (0.0, 37.0, 90.0, 180.0, 291.0):
        phi_i, phi_o = np.full(3, phi), np.full(3, (phi + 180.0) % 360.0)
        table = sample_directions(brass, theta, phi_i, theta, phi_o)
        np.testing.assert_allclose(table.values, exact, rtol=1e-9)


def test_torch_matches_numpy_and_keeps_gradients(brass):
    rng = np.random.default_rng(5)
    wi = random_upper_directions(rng, 300)
    wo = random_upper_directions(rng, 300)
    expected = brass.evaluate(wi, wo)
    wi_t = torch.tensor(wi, requires_grad=True)
    out = brass.evaluate(wi_t, torch.tensor(wo))
    assert isinstance(out, torch.Tensor) and out.dtype == torch.float64
    np.testing.assert_allclose(out.detach().numpy(), expected, rtol=1e-12, atol=1e-14)
    out.sum().backward()
    assert torch.isfinite(wi_t.grad).all() and wi_t.grad.abs().sum() > 0
    out32 = brass.evaluate(torch.tensor(wi, dtype=torch.float32),
                           torch.tensor(wo, dtype=torch.float32))
    assert out32.dtype == torch.float32
    np.testing.assert_allclose(out32.numpy(), expected, rtol=2e-3, atol=1e-5)


def test_chunked_evaluation_equals_single_pass(brass):
    rng = np.random.default_rng(9)
    wi = random_upper_directions(rng, 101)
    wo = random_upper_directions(rng, 101)
    np.testing.assert_allclose(brass.evaluate(wi, wo, chunk_rows=7), brass.evaluate(wi, wo),
                               rtol=1e-12)
    batched = brass.evaluate(wi.reshape(101, 1, 3), wo.reshape(101, 1, 3))
    assert batched.shape == (101, 1, 3)
    assert brass.evaluate(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0, 3)


def test_below_horizon_is_exactly_zero(brass):
    up = np.array([0.3, 0.1, 0.9])
    for below in ([0.3, 0.1, -0.9], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]):
        pairs = (np.array([up, below]), np.array([below, up]))
        assert np.array_equal(brass.evaluate(*pairs), np.zeros((2, 3)))
        zeros = torch.zeros(2, 3, dtype=torch.float64)
        assert torch.equal(brass.evaluate(*map(torch.tensor, pairs)), zeros)


def test_wrong_direction_shape_is_rejected(brass):
    with pytest.raises(InputError, match=r"\[\.\.\., 3\]"):
        brass.evaluate(np.ones((4, 2)), np.ones((4, 2)))


# ---------------------------------------------------------------- physically sensible values

def mc_albedo(network, theta_i_deg, samples_per_strategy, rng):
    """Directional albedo ``int f cos dwo`` per channel with its standard error.

    Balance-heuristic mixture of cosine-weighted hemisphere sampling and uniform cones of
    2° and 10° around the mirror direction (the lobes are far narrower than a degree).
    """
    t = math.radians(theta_i_deg)
    wi = np.array([math.sin(t), 0.0, math.cos(t)])
    mirror = np.array([-wi[0], -wi[1], wi[2]])
    tangent = np.array([math.cos(t), 0.0, math.sin(t)])
    bitangent = np.cross(mirror, tangent)
    cone_cos = [math.cos(math.radians(a)) for a in (2.0, 10.0)]

    n = samples_per_strategy
    u, v = rng.random(n), rng.random(n)
    r, phi = np.sqrt(u), 2 * np.pi * v
    cosine = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u)], axis=1)
    cones = []
    for cmax in cone_cos:
        ca = 1 - rng.random(n) * (1 - cmax)
        sa, beta = np.sqrt(1 - ca * ca), 2 * np.pi * rng.random(n)
        cones.append(ca[:, None] * mirror + sa[:, None] * (np.cos(beta)[:, None] * tangent
                                                           + np.sin(beta)[:, None] * bitangent))
    wo = np.concatenate([cosine, *cones])
    pdf = np.clip(wo[:, 2], 0, None) / np.pi
    alpha_cos = wo @ mirror
    for cmax in cone_cos:
        pdf = pdf + (alpha_cos >= cmax) / (2 * np.pi * (1 - cmax))
    pdf = pdf / 3
    integrand = network.evaluate(wi, wo) * np.clip(wo[:, 2], 0, None)[:, None] / pdf[:, None]
    return integrand.mean(0), integrand.std(0) / math.sqrt(len(wo))


@pytest.mark.parametrize("material", REPORT_MATERIALS)
def test_report_materials_are_physically_sensible(material):
    network = NbrdfNetwork.load(DATA / f"{material}.h5")
    rng = np.random.default_rng(1)
    wi, wo = random_upper_directions(rng, 2000), random_upper_directions(rng, 2000)
    f = network.evaluate(wi, wo)
    assert np.all(np.isfinite(f)) and np.all(f >= 0)

    # in-plane mirror peak vs the off-specular (back-scatter) direction at theta_i = 30°
    peak, off = network.evaluate(*inplane_to_vectors(np.array([30.0, 30.0]),
                                                     np.array([30.0, -30.0])))
    margin = 100.0 if material in GLOSSY else 2.0  # nylon: a weak sheen (ratio ≈ 3.7)
    assert np.all(peak > margin * off), (peak, off)

    # measured albedo at 30°: 0.009 (phenolic) .. 0.25 (nylon); all well below 1
    albedo, stderr = mc_albedo(network, 30.0, 20000, rng)
    assert np.all(stderr < 0.05 * albedo), (albedo, stderr)
    assert np.all(albedo > 0) and np.all(albedo + 3 * stderr <= 1.0), albedo


# ---------------------------------------------------------------- plans and listing

def test_sample_plan_matches_in_plane_evaluation(brass, capsys):
    table = sample_plan(brass, "DS3", progress=True)
    assert "NBRDF brass" in capsys.readouterr().err
    ti, tr = in_plane_plan("DS3")
    assert table.values.shape == (57, 3) and table.values.dtype == np.float64
    assert table.wavelengths is None and "brass" in table.source
    np.testing.assert_allclose(table.values, brass.evaluate(*inplane_to_vectors(ti, tr)),
                               rtol=1e-9, atol=1e-12)


def test_sample_directions_on_spherical_angles(brass):
    table = sample_directions(brass, [30.0, 45.0], [0.0, 90.0], [30.0, 45.0], [180.0, 270.0])
    # both rows are mirror configurations: the same theta_h = 0 peak family as in-plane
    expected = brass.evaluate(*inplane_to_vectors(np.array([30.0, 45.0]), np.array([30.0, 45.0])))
    np.testing.assert_allclose(table.values, expected, rtol=1e-9)
    assert table.theta_o.tolist() == [30.0, 45.0]


def test_available_materials_lists_stems():
    names = available_materials(DATA)
    assert len(names) == 50 and list(names) == sorted(names)
    assert set(REPORT_MATERIALS) <= set(names)
    assert NbrdfNetwork.load(DATA / "nylon.h5").name == "nylon"
    with pytest.raises(InputError, match="not found"):
        available_materials(DATA / "no-such-folder")


# ---------------------------------------------------------------- bad files

@pytest.fixture
def copy_pair(tmp_path):
    shutil.copy(DATA / "brass.h5", tmp_path / "brass.h5")
    shutil.copy(DATA / "brass.json", tmp_path / "brass.json")
    return tmp_path / "brass.h5", tmp_path / "brass.json"


def expect_error(path, *fragments):
    with pytest.raises(InputError) as info:
        NbrdfNetwork.load(path)
    message = str(info.value)
    for fragment in fragments:
        assert fragment in message, message
    return message


def test_copied_pair_loads(copy_pair):
    h5, js = copy_pair
    assert NbrdfNetwork.load(js).kernels[0].shape == (6, 21)


@pytest.mark.parametrize("size", [0, 1000])
def test_empty_or_truncated_h5(copy_pair, size):
    h5, _ = copy_pair
    h5.write_bytes(h5.read_bytes()[:size])
    expect_error(h5, str(h5), "HDF5")


def test_wrong_dataset_name(copy_pair):
    h5, js = copy_pair
    with h5py.File(h5, "r+") as f:
        f.move("dense_2/dense_2/kernel:0", "dense_2/dense_2/weights:0")
    expect_error(js, str(h5), "dense_2/dense_2/kernel:0", "missing dataset")


def test_wrong_kernel_shape(copy_pair):
    h5, _ = copy_pair
    with h5py.File(h5, "r+") as f:
        del f["dense_1/dense_1/kernel:0"]
        f["dense_1/dense_1/kernel:0"] = np.zeros((6, 20), np.float32)
    expect_error(h5, str(h5), "dense_1/dense_1/kernel:0", "(6, 21)")


def test_nan_weight(copy_pair):
    h5, _ = copy_pair
    with h5py.File(h5, "r+") as f:
        f["dense_3/dense_3/bias:0"][1] = np.nan
    expect_error(h5, str(h5), "dense_3/dense_3/bias:0", "finite")


def edit_json(path, edit):
    model = json.loads(path.read_text())
    edit(model)
    path.write_text(json.dumps(model))


@pytest.mark.parametrize(
    "edit, key",
    [
        (lambda m: m["config"]["layers"][1]["config"].update(units=32),
         "config.layers[1].config.units"),
        (lambda m: m["config"]["layers"][0]["config"].update(activation="tanh"),
         "config.layers[0].config.activation"),
        (lambda m: m["config"]["layers"][2]["config"].update(activation="relu"),
         "config.layers[2].config.activation"),
        (lambda m: m["config"]["layers"][0]["config"].update(batch_input_shape=[None, 5]),
         "batch_input_shape"),
        (lambda m: m["config"]["layers"].pop(3), "config.layers"),
        (lambda m: m.update(class_name="Model"), "class_name"),
        (lambda m: m["config"]["layers"][3]["config"].update(
            function=[base64.b64encode(b"log1p").decode(), None, None]), "function"),
    ],
)
def test_json_with_a_different_architecture(copy_pair, edit, key):
    h5, js = copy_pair
    edit_json(js, edit)
    expect_error(h5, str(js), key, "expected")


def test_invalid_json_text(copy_pair):
    _, js = copy_pair
    js.write_text('{"class_name": "Sequential",\n "config": ')
    expect_error(js, str(js), "line 2", "invalid JSON")


def test_missing_json_sibling(copy_pair):
    h5, js = copy_pair
    js.unlink()
    expect_error(h5, str(js), "not found")


def test_nonexistent_path_and_wrong_suffix(tmp_path, monkeypatch):
    expect_error(tmp_path / "nothing.h5", str(tmp_path / "nothing.h5"), "not found")
    monkeypatch.chdir(tmp_path)  # a relative path: the error says where it looked
    expect_error(Path("data/nothing.h5"), f"not found at {tmp_path / 'data' / 'nothing.h5'} (relative to the folder")
    expect_error(tmp_path / "brass.csv", str(tmp_path / "brass.csv"), "NAME.h5")
