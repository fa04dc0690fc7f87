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
