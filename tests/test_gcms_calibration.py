"""GCMS raw files, Munsell calibration (docs/formats.md#gcms-raw-measurement, report Eq. 2.3) and load_measurement."""

import math
import warnings

import numpy as np
import pytest

from neuralbrdf.data.calibration import CALIBRATED_WAVELENGTHS_NM, MUNSELL_N9_REFLECTANCE, calibrate
from neuralbrdf.data.gcms import GCMS_HEADER, GCMS_WAVELENGTHS_NM, GcmsMeasurement, read_gcms, write_gcms
from neuralbrdf.data.loading import load_measurement
from neuralbrdf.data.plans import in_plane_plan
from neuralbrdf.data.table import read_table, write_table
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import inplane_to_spherical

KEPT = slice(1, 32)  # 400..700 nm inside 390..730 nm


def _session(seed=0, plan="DS3"):
    """A synthetic session: true BRDF f (400-700 nm), reference and sample measurements."""
    rng = np.random.default_rng(seed)
    ti, tr = in_plane_plan(plan)
    n = ti.size
    beta_reference = rng.uniform(0.5, 1.5, size=(n, 35))  # lamp/detector response varies per row
    f = rng.uniform(0.0, 2.0, size=(n, 31))
    beta_sample = rng.normal(0.0, 1.0, size=(n, 35))  # out-of-band columns: arbitrary, even negative
    beta_sample[:, KEPT] = math.pi * f / MUNSELL_N9_REFLECTANCE * beta_reference[:, KEPT]
    sample = GcmsMeasurement(ti, tr, beta_sample, source="sample.csv")
    reference = GcmsMeasurement(ti, tr, beta_reference, source="munsell.csv")
    return f, sample, reference


def _shuffled(measurement, rng):
    order = rng.permutation(measurement.n_rows)
    return GcmsMeasurement(
        measurement.theta_i[order], measurement.theta_r[order], measurement.beta[order], measurement.source
    )


def test_gcms_header_is_390_to_730_step_10():
    assert GCMS_HEADER[:3] == ("theta_i", "theta_r", "390") and GCMS_HEADER[-1] == "730" and len(GCMS_HEADER) == 37


def test_gcms_round_trip_is_exact(tmp_path):
    _, sample, _ = _session()
    path = tmp_path / "sample.csv"
    write_gcms(sample, path)
    back = read_gcms(path)
    np.testing.assert_array_equal(back.theta_i, sample.theta_i)
    np.testing.assert_array_equal(back.theta_r, sample.theta_r)
    np.testing.assert_array_equal(back.beta, sample.beta)
    assert back.source == str(path) and back.lines.tolist() == list(range(2, sample.n_rows + 2))
    assert (back.beta < 0).any(), "negative beta in a sample is noise, not an error"


def test_calibration_reproduces_the_brdf_with_shuffled_reference():
    f, sample, reference = _session()
    table = calibrate(sample, _shuffled(reference, np.random.default_rng(9)))
    np.testing.assert_allclose(table.values, f, rtol=1e-9, atol=1e-15)
    np.testing.assert_array_equal(table.wavelengths, np.arange(400.0, 701.0, 10.0))
    assert table.channel_names[0] == "400" and table.channel_names[-1] == "700" and table.values.shape[1] == 31
    expected_angles = inplane_to_spherical(sample.theta_i, sample.theta_r)
    for got, want in zip((table.theta_i, table.phi_i, table.theta_o, table.phi_o), expected_angles):
        np.testing.assert_array_equal(got, want)


def test_lambertian_sample_against_munsell_gives_albedo_over_pi():
    ti, tr = in_plane_plan("DS4")
    lamp = np.linspace(0.2, 1.0, 35)[None, :] * np.ones((ti.size, 1))
    albedo = 0.4
    # A Lambertian surface's radiance factor is its reflectance; the instrument scales both alike.
    reference = GcmsMeasurement(ti, tr, MUNSELL_N9_REFLECTANCE * lamp)
    sample = GcmsMeasurement(ti, tr, albedo * lamp)
    np.testing.assert_allclose(calibrate(sample, reference).values, albedo / math.pi, rtol=1e-12)


def test_sample_geometry_missing_from_reference_is_named(tmp_path):
    _, sample, reference = _session()
    write_gcms(sample, tmp_path / "sample.csv")
    keep = np.ones(reference.n_rows, bool)
    keep[5] = False
    partial = GcmsMeasurement(reference.theta_i[keep], reference.theta_r[keep], reference.beta[keep], "munsell.csv")
    with pytest.raises(InputError) as caught:
        calibrate(read_gcms(tmp_path / "sample.csv"), partial)
    message = str(caught.value)
    assert "sample.csv" in message and "line 7" in message and "munsell.csv" in message
    assert f"({sample.theta_i[5]:g}, {sample.theta_r[5]:g})" in message


@pytest.mark.parametrize("bad_value", [0.0, -0.2])
def test_non_positive_reference_is_named_by_file_line_and_wavelength(tmp_path, bad_value):
    _, sample, reference = _session()
    reference = _shuffled(reference, np.random.default_rng(3))
    reference.beta[4, GCMS_HEADER.index("550") - 2] = bad_value
    write_gcms(reference, tmp_path / "munsell.csv")
    with pytest.raises(InputError) as caught:
        calibrate(sample, read_gcms(tmp_path / "munsell.csv"))
    error = caught.value
    assert error.path == str(tmp_path / "munsell.csv") and error.line == 6 and error.column == "550"
    assert "line 6" in str(error) and "'550'" in str(error) and "positive" in str(error)


def test_reference_outside_400_700_is_not_used():
    f, sample, reference = _session()
    reference.beta[:, 0] = 0.0  # 390 nm
    reference.beta[:, -1] = -1.0  # 730 nm
    np.testing.assert_allclose(calibrate(sample, reference).values, f, rtol=1e-9)


def test_negative_calibrated_values_within_the_table_tolerance_are_clipped_with_count():
    """Noise within the BRDF table's tolerance (1e-6 × max|f| below 0) is clipped and counted."""
    f, sample, reference = _session()
    sample.beta[0, 1] = -1e-8
    sample.beta[3, 10] = -2e-8
    with pytest.warns(UserWarning, match="clipped 2 negative calibrated"):
        table = calibrate(sample, reference)
    assert table.values[0, 0] == 0.0 and table.values[3, 9] == 0.0
    np.testing.assert_allclose(table.values[1:3], f[1:3], rtol=1e-9)


@pytest.mark.parametrize("beta", [-1e-3, -1000.0])
def test_negative_calibrated_values_beyond_the_tolerance_are_refused_at_their_cell(tmp_path, beta):
    """A cell of -1000 (or -1e-3 among values of ~1) is not sensor noise."""
    _, sample, reference = _session()
    sample.beta[3, 10] = beta
    write_gcms(sample, tmp_path / "sample.csv")
    with pytest.raises(InputError, match="calibrates to a negative BRDF of .* beyond the noise tolerance") as caught:
        calibrate(read_gcms(tmp_path / "sample.csv"), reference)
    assert caught.value.path == str(tmp_path / "sample.csv")
    assert caught.value.line == 5 and caught.value.column == "490"  # beta column 10


def test_huge_noise_calibration_is_refused_not_half_zeroed(tmp_path):
    """``simulate --noise 1e6`` makes about half of beta negative: refused, not clipped to 0."""
    from neuralbrdf.cli.main import main

    for material in ("gold", "munsell_n9"):
        noise = "1e6" if material == "gold" else "0"
        assert main(["simulate", "--material", material, "--plan", "DS3", "--noise", noise,
                     "--out", str(tmp_path / f"{material}.csv")]) == 0
    out = tmp_path / "table.csv"
    assert main(["calibrate", str(tmp_path / "gold.csv"), "--reference", str(tmp_path / "munsell_n9.csv"),
                 "--out", str(out)]) == 2
    assert not out.exists()


GOOD_HEADER = ",".join(GCMS_HEADER)
GOOD_ROW = "30,20," + ",".join(["0.5"] * 35)

# name, text, expected line, expected column (None: not named), message fragment
BAD_GCMS = [
    ("missing 730", ",".join(GCMS_HEADER[:-1]) + "\n30,20," + ",".join(["0.5"] * 34) + "\n", 1, None,
     "found 34"),
    ("starts at 400", "theta_i,theta_r," + ",".join(str(w) for w in range(400, 750, 10)) + "\n" + GOOD_ROW + "\n",
     1, "400", "exactly 390"),
    ("step 5", "theta_i,theta_r," + ",".join(str(w) for w in range(390, 565, 5)) + "\n" + GOOD_ROW + "\n",
     1, "395", "step 10"),
    ("spherical header", "theta_i,phi_i," + ",".join(GCMS_HEADER[2:]) + "\n" + GOOD_ROW + "\n", 1, "phi_i",
     "starts with columns theta_i, theta_r"),
    ("angle above 90", f"{GOOD_HEADER}\n{GOOD_ROW}\n95,20," + ",".join(["0.5"] * 35) + "\n", 3, "theta_i",
     "outside [-90, 90]"),
    ("angle below -90", f"{GOOD_HEADER}\n30,-90.5," + ",".join(["0.5"] * 35) + "\n", 2, "theta_r",
     "outside [-90, 90]"),
    ("nan", f"{GOOD_HEADER}\n30,20,nan," + ",".join(["0.5"] * 34) + "\n", 2, "390", "non-finite"),
    ("non-numeric", f"{GOOD_HEADER}\n{GOOD_ROW}\n30,21,0.5,n/a," + ",".join(["0.5"] * 33) + "\n", 3, "400",
     "not a number: 'n/a'"),
    ("truncated", f"{GOOD_HEADER}\n{GOOD_ROW}\n30,25,0.5,0.5", 3, "410", "4 of 37 cells"),
    ("empty", "", 1, None, "empty file"),
    ("header only", f"{GOOD_HEADER}\n", 2, None, "no data rows"),
    ("duplicated pair", f"{GOOD_HEADER}\n{GOOD_ROW}\n30,10," + ",".join(["0.5"] * 35) + f"\n{GOOD_ROW}\n", 4,
     None, "duplicated geometry (theta_i, theta_r) = (30, 20), first seen on line 2"),
]


@pytest.mark.parametrize("name, text, line, column, fragment", BAD_GCMS, ids=[case[0] for case in BAD_GCMS])
def test_bad_gcms_files_are_rejected_with_file_line_and_column(tmp_path, name, text, line, column, fragment):
    path = tmp_path / "bad_gcms.csv"
    path.write_text(text)
    with pytest.raises(InputError) as caught:
        read_gcms(path)
    error = caught.value
    assert str(path) in str(error) and fragment in str(error)
    assert error.line == line and f"line {line}" in str(error)
    assert error.column == column


def test_in_memory_measurement_is_validated():
    with pytest.raises(InputError, match=r"beta must be \[N, 35\]"):
        GcmsMeasurement([0.0], [0.0], np.ones((1, 31)))
    with pytest.raises(InputError, match=r"^<memory>: row 1: duplicated geometry .* first seen at row 0"):
        GcmsMeasurement([10.0, 10.0], [5.0, 5.0 + 1e-9], np.ones((2, 35)))


def test_load_measurement_calibrates_gcms_and_reads_tables(tmp_path):
    f, sample, reference = _session(plan="DS4")
    write_gcms(sample, tmp_path / "sample.csv")
    write_gcms(_shuffled(reference, np.random.default_rng(1)), tmp_path / "munsell.csv")
    table = load_measurement(tmp_path / "sample.csv", reference=tmp_path / "munsell.csv")
    np.testing.assert_allclose(table.values, f, rtol=1e-9)
    assert table.source == str(tmp_path / "sample.csv")
    write_table(table, tmp_path / "table.csv")
    again = load_measurement(tmp_path / "table.csv")
    np.testing.assert_array_equal(again.values, read_table(tmp_path / "table.csv").values)
    np.testing.assert_array_equal(again.values, table.values)


def test_load_measurement_reference_rules(tmp_path):
    _, sample, reference = _session(plan="DS4")
    write_gcms(sample, tmp_path / "sample.csv")
    with pytest.raises(InputError, match="sample.csv: is a GCMS raw file.*Munsell N9 reference"):
        load_measurement(tmp_path / "sample.csv")
    write_table(calibrate(sample, reference), tmp_path / "table.csv")
    with pytest.raises(InputError, match="table.csv: is a BRDF sample table.*no Munsell reference"):
        load_measurement(tmp_path / "table.csv", reference=tmp_path / "sample.csv")
    with pytest.raises(InputError, match="absent.csv: file not found"):
        load_measurement(tmp_path / "absent.csv")
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(InputError, match="empty.csv, line 1: empty file"):
        load_measurement(tmp_path / "empty.csv")
    with pytest.raises(InputError, match="munsell_absent.csv: file not found"):
        load_measurement(tmp_path / "sample.csv", reference=tmp_path / "munsell_absent.csv")


def test_clean_calibration_emits_no_warning():
    _, sample, reference = _session()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        calibrate(sample, reference)


def test_calibrated_wavelengths_constant():
    np.testing.assert_array_equal(CALIBRATED_WAVELENGTHS_NM, GCMS_WAVELENGTHS_NM[KEPT])
