"""MERL ``.binary`` files: a file written by the test from a known analytic BRDF reads back, is
looked up by MERL's own index rule, samples through ``neuralbrdf sample``, and bad files are
refused before their data is read."""

import math

import numpy as np
import pytest

from neuralbrdf.cli.main import main as cli
from neuralbrdf.data.merl_binary import CHANNEL_SCALES, MERL_SHAPE, MerlBrdf, write_merl
from neuralbrdf.data.table import read_table
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import spherical_to_vector

ALBEDO = np.array([0.2, 0.4, 0.6])


def _cell_centre_angles():
    """``(theta_h, theta_d, phi_d)`` in degrees at the centre of every MERL cell (MERL's own inverse)."""
    n_h, n_d, n_phi = MERL_SHAPE
    i_h, i_d, i_phi = np.meshgrid(np.arange(n_h), np.arange(n_d), np.arange(n_phi), indexing="ij")
    theta_h = (i_h + 0.5) ** 2 / 90.0  # i_h = floor(sqrt(90 theta_h))
    return theta_h, (i_d + 0.5) * 90.0 / n_d, (i_phi + 0.5) * 180.0 / n_phi


def _blinn_lobe(theta_h_deg):
    return 3.0 * np.cos(np.radians(theta_h_deg)) ** 40


@pytest.fixture(scope="module")
def merl_file(tmp_path_factory):
    theta_h, _, _ = _cell_centre_angles()
    values = ALBEDO[:, None, None, None] / math.pi + _blinn_lobe(theta_h)[None]
    values[:, :, -1, :] = -1.0  # theta_d ~ 90: "not measured", as in real MERL files
    path = tmp_path_factory.mktemp("merl") / "analytic.binary"
    write_merl(values, path)
    return path


def test_header_scales_and_layout(merl_file):
    raw = np.fromfile(merl_file, dtype="<i4", count=3)
    assert raw.tolist() == [90, 90, 180]
    stored = np.fromfile(merl_file, dtype="<f8", offset=12)
    # channel-major; the first stored value is R at cell (0, 0, 0), divided by MERL's 1/1500
    assert stored.size == 3 * 90 * 90 * 180
    theta_h0 = 0.25 / 90.0
    assert stored[0] == pytest.approx((ALBEDO[0] / math.pi + _blinn_lobe(theta_h0)) / CHANNEL_SCALES[0])
    brdf = MerlBrdf.load(merl_file)
    assert brdf.values.shape == (3, 90, 90, 180) and brdf.name == "analytic"


def test_lookup_follows_merls_index_rule_and_reproduces_the_brdf(merl_file):
    brdf = MerlBrdf.load(merl_file)
    rng = np.random.default_rng(0)
    n = 5000
    theta = np.degrees(np.arccos(rng.uniform(np.cos(np.radians(70)), 1, (2, n))))
    wi = spherical_to_vector(theta[0], rng.uniform(0, 360, n))
    wo = spherical_to_vector(theta[1], rng.uniform(0, 360, n))
    i_h, i_d, i_phi = brdf.cell_indices(wi, wo)
    from neuralbrdf.geometry import half_diff_angles

    theta_h, _, theta_d, phi_d = half_diff_angles(wi, wo)
    # MERL's BRDFRead.cpp, written out independently
    np.testing.assert_array_equal(i_h, np.minimum((np.sqrt(theta_h / 90.0 * 90 * 90)).astype(int), 89))
    np.testing.assert_array_equal(i_d, np.minimum((theta_d / 90.0 * 90).astype(int), 89))
    np.testing.assert_array_equal(i_phi, np.minimum(((phi_d % 180.0) / 180.0 * 180).astype(int), 179))
    f = brdf.evaluate(wi, wo)
    # the value written at that cell's centre, and close to the BRDF at the pair itself
    cell_theta_h = (i_h + 0.5) ** 2 / 90.0
    np.testing.assert_allclose(f, ALBEDO / math.pi + _blinn_lobe(cell_theta_h)[:, None], rtol=1e-12)
    np.testing.assert_allclose(f, ALBEDO / math.pi + _blinn_lobe(theta_h)[:, None], rtol=0.15)


def test_unmeasured_cells_are_warned_about_and_zero(merl_file):
    brdf = MerlBrdf.load(merl_file)
    # grazing mirror pair: theta_h = 0, theta_d ~ 89.9 -> the last theta_d row, marked unmeasured
    wi = spherical_to_vector(np.array([89.9, 30.0]), np.array([0.0, 0.0]))
    wo = spherical_to_vector(np.array([89.9, 30.0]), np.array([180.0, 180.0]))
    with pytest.warns(UserWarning, match="1 of 2 direction pairs fall in cells MERL did not measure"):
        f = brdf.evaluate(wi, wo)
    assert np.all(f[0] == 0.0) and np.all(f[1] > 0.0)


def test_sample_command_reads_binary_virtual_and_refuses_bad_files(merl_file, tmp_path, capsys):
    out = tmp_path / "s.csv"
    assert cli(["sample", str(merl_file), "--plan", "DS3", "--out", str(out)]) == 0
    table = read_table(out)
    assert table.n_rows == 57 and table.wavelengths is None and np.all(table.values > 0)
    assert cli(["sample", "virtual:cyan", "--plan", "DS4", "--out", str(tmp_path / "v.csv")]) == 0
    assert read_table(tmp_path / "v.csv").wavelengths is not None
    bad = tmp_path / "bad.binary"
    bad.write_bytes(np.array([90, 90, 180], dtype="<i4").tobytes() + b"\0" * 80)
    assert cli(["sample", str(bad), "--plan", "DS3", "--out", str(tmp_path / "b.csv")]) == 2
    err = capsys.readouterr().err
    assert "bad.binary" in err and "exactly" in err and not (tmp_path / "b.csv").exists()
    huge = tmp_path / "huge.binary"
    huge.write_bytes(np.array([90000, 90000, 180000], dtype="<i4").tobytes())
    with pytest.raises(InputError, match="dimensions"):
        MerlBrdf.load(huge)


# --------------------------------------------------------------------------- a MERL file as a truth


def test_the_merl_truth_module_follows_merls_lookup(merl_file):
    import torch

    from neuralbrdf.evaluation.truth import MerlTruth

    brdf = MerlBrdf.load(merl_file)
    rng = np.random.default_rng(1)
    n = 20000
    theta = np.degrees(np.arccos(rng.uniform(0.02, 1, (2, n))))
    wi = spherical_to_vector(theta[0], rng.uniform(0, 360, n))
    wo = spherical_to_vector(theta[1], rng.uniform(0, 360, n))
    expected = brdf.evaluate(wi, wo)  # no pair reaches the unmeasured theta_d cells (below 87 deg here)
    got = MerlTruth(brdf)(torch.tensor(wi, dtype=torch.float32), torch.tensor(wo, dtype=torch.float32)).numpy()
    same = np.isclose(got, expected, rtol=1e-5, atol=1e-7).all(axis=1)
    assert same.mean() > 0.999  # float32 indices may land a pair on a cell boundary in the next cell
    grazing_i = spherical_to_vector(np.array([89.8]), np.array([0.0]))  # theta_d ~ 89.8: a cell MERL did not measure
    grazing_o = spherical_to_vector(np.array([89.8]), np.array([180.0]))
    with pytest.warns(UserWarning, match="did not measure"):
        assert not brdf.evaluate(grazing_i, grazing_o).any()
    assert not MerlTruth(brdf)(torch.tensor(grazing_i).float(), torch.tensor(grazing_o).float()).any()
    below = wi.copy()
    below[:, 2] *= -1
    assert not MerlTruth(brdf)(torch.tensor(below[:5]).float(), torch.tensor(wo[:5]).float()).any()


def test_export_truth_and_the_api_take_a_merl_file(merl_file, tmp_path, capsys):
    import neuralbrdf as nb

    out = tmp_path / "analytic_truth.onnx"
    assert cli(["export-truth", str(merl_file), "--out", str(out)]) == 0
    assert "reference model of 'analytic'" in capsys.readouterr().out
    truth = nb.load(out)
    assert (truth.kind, truth.material, truth.is_spectral) == ("reference", "analytic", False)
    wi = spherical_to_vector(np.array([30.0, 10.0]), np.array([0.0, 90.0]))
    wo = spherical_to_vector(np.array([30.0, 50.0]), np.array([180.0, 0.0]))
    assert np.allclose(truth(wi, wo), MerlBrdf.load(merl_file).evaluate(wi, wo), rtol=1e-5)
    assert nb.truth(nb.read(merl_file), tmp_path / "again.onnx").material == "analytic"


def test_a_merl_file_is_a_material_source_and_a_study_truth(merl_file, tmp_path):
    from neuralbrdf.sources import load_material
    from neuralbrdf.study.cell import write_data
    from neuralbrdf.study.profile import load_profile

    material = load_material(merl=str(merl_file), plan="DS2", eval_plan="DS1")
    assert material.name == "analytic" and material.fit.n_rows == 185 and material.truth.n_rows == 1001
    spec = {"cell": {"plan": "DS3", "noise": 0.0, "seed": 0}, "plan": "DS3",
            "material": {"table": None, "truth": str(merl_file)}}
    assert read_table(write_data(spec, tmp_path / "data" / "analytic.csv")).n_rows == 57
    profile = tmp_path / "merl.yaml"
    profile.write_text(f"render: {{spp: 2, resolution: 16}}\ncost: {{spp: 2, resolution: 16, repeats: 1, batch: 4096}}\n"
                       f"materials:\n  - {{name: analytic, truth: {merl_file}}}\n"
                       "variants:\n  - {name: abc, method: abc, config: configs/abc.yaml}\n")
    assert load_profile(str(profile)).materials[0].truth == str(merl_file)
