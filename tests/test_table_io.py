"""BRDF sample table (docs/formats.md#brdf-sample-table): the dataclass, its CSV reader/writer and every rejection."""

import re
import warnings

import numpy as np
import pytest

from neuralbrdf.data.plans import in_plane_plan
from neuralbrdf.data.table import BrdfTable, read_table, write_table
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import inplane_to_spherical

WAVELENGTHS = np.arange(400.0, 701.0, 10.0)


def _random_table(rng, n=7, spectral=False, weight=False):
    theta_i, theta_o = rng.uniform(0, 90, size=(2, n))
    phi_i, phi_o = rng.uniform(0, 360, size=(2, n))
    theta_o[0], phi_o[0] = 90.0, 0.0  # range edges are legal
    channels = WAVELENGTHS.size if spectral else 3
    values = rng.lognormal(-2, 2, size=(n, channels))
    values[1, 0] = 0.0
    return BrdfTable(
        theta_i, phi_i, theta_o, phi_o, values,
        wavelengths=WAVELENGTHS.copy() if spectral else None,
        weight=rng.uniform(0, 3, size=n) if weight else None,
    )


def _assert_same(a, b):
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "values", "wavelengths", "weight"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            np.testing.assert_array_equal(x, y, err_msg=name)


@pytest.mark.parametrize("spectral", [False, True])
@pytest.mark.parametrize("weight", [False, True])
def test_write_read_round_trip_is_exact(tmp_path, spectral, weight):
    table = _random_table(np.random.default_rng(1), spectral=spectral, weight=weight)
    path = tmp_path / "t.csv"
    write_table(table, path)
    back = read_table(path)
    _assert_same(table, back)
    assert back.source == str(path)
    assert back.is_spectral == spectral and back.n_rows == 7
    assert not list(tmp_path.glob(".*tmp*")), "atomic write left a temporary file"


def test_header_and_channel_names(tmp_path):
    spectral = _random_table(np.random.default_rng(2), spectral=True)
    assert spectral.channel_names[:3] == ["400", "410", "420"] and spectral.channel_names[-1] == "700"
    assert _random_table(np.random.default_rng(2)).channel_names == ["R", "G", "B"]
    write_table(spectral, tmp_path / "s.csv")
    header = (tmp_path / "s.csv").read_text().splitlines()[0]
    assert header == "theta_i,phi_i,theta_o,phi_o," + ",".join(str(int(w)) for w in WAVELENGTHS)


def test_columns_are_found_by_name_and_blank_lines_skipped(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text(
        "B, weight, theta_o,G,phi_o,theta_i,R,phi_i\n"
        "\n"
        "0.3,1,20,0.2,180,10,0.1,0\n"
        "\n"
        "3e-1,2,40.5,0.25,90,0,0.5,359.5\n"
    )
    table = read_table(path)
    np.testing.assert_array_equal(table.values, [[0.1, 0.2, 0.3], [0.5, 0.25, 0.3]])
    np.testing.assert_array_equal(table.theta_o, [20, 40.5])
    np.testing.assert_array_equal(table.phi_i, [0, 359.5])
    np.testing.assert_array_equal(table.weight, [1, 2])


def test_vectors_are_the_spherical_directions():
    table = _random_table(np.random.default_rng(3))
    wi, wo = table.vectors()
    t, p = np.radians(table.theta_o), np.radians(table.phi_o)
    np.testing.assert_allclose(wo, np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], 1), atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(wi, axis=1), 1.0)
    np.testing.assert_allclose(wi[:, 2], np.cos(np.radians(table.theta_i)))


def test_inplane_angles_of_inplane_rows_are_the_signed_pairs():
    ti, tr = in_plane_plan("DS2")
    table = BrdfTable(*inplane_to_spherical(ti, tr), np.ones((ti.size, 3)))
    a, b = table.inplane_angles()
    np.testing.assert_allclose(a, ti, atol=1e-9)
    np.testing.assert_allclose(b, tr, atol=1e-9)


def test_to_rgb_of_flat_spectrum_and_of_rgb_table():
    rgb_table = _random_table(np.random.default_rng(4))
    assert rgb_table.to_rgb() is rgb_table
    spectral = BrdfTable([10, 20], [0, 0], [30, 40], [180, 0], np.full((2, 31), 0.2), WAVELENGTHS, weight=[1, 2])
    converted = spectral.to_rgb()
    assert not converted.is_spectral and converted.channel_names == ["R", "G", "B"]
    np.testing.assert_allclose(converted.values, 0.2, rtol=0.01)
    np.testing.assert_array_equal(converted.weight, [1, 2])
    np.testing.assert_array_equal(converted.theta_o, [30, 40])


def test_to_rgb_clips_out_of_gamut_with_warning():
    narrow_green = np.zeros((1, 31))
    narrow_green[0, 10] = 1.0  # 500 nm: far outside the sRGB gamut (negative red)
    table = BrdfTable([0], [0], [0], [0], narrow_green, WAVELENGTHS)
    with pytest.warns(UserWarning, match="clipped 1 negative linear-sRGB"):
        rgb = table.to_rgb()
    assert rgb.values.min() == 0.0 and rgb.values.max() > 0


def test_constructor_converts_to_float64_and_rejects_bad_shapes():
    table = BrdfTable([1, 2], [0, 0], [3, 4], [0, 0], np.ones((2, 3), dtype=np.float32))
    assert table.values.dtype == np.float64 and table.theta_i.dtype == np.float64
    with pytest.raises(InputError, match="phi_o has shape"):
        BrdfTable([1, 2], [0, 0], [3, 4], [0], np.ones((2, 3)))
    with pytest.raises(InputError, match="needs 3 value columns"):
        BrdfTable([1], [0], [3], [0], np.ones((1, 31)))
    with pytest.raises(InputError, match="2 wavelengths for 3"):
        BrdfTable([1], [0], [3], [0], np.ones((1, 3)), wavelengths=[400, 410])
    with pytest.raises(InputError, match="real numbers"):
        BrdfTable(["a"], [0], [3], [0], np.ones((1, 3)))


def test_constructor_names_source_row_and_column():
    values = np.ones((3, 3))
    values[2, 1] = np.nan
    with pytest.raises(InputError, match=r"^lab\.csv, column 'G': row 2: non-finite"):
        BrdfTable([1, 2, 3], [0, 0, 0], [3, 4, 5], [0, 0, 0], values, source="lab.csv")
    with pytest.raises(InputError, match=r"column '420': wavelengths must increase"):
        BrdfTable([1], [0], [3], [0], np.ones((1, 3)), wavelengths=[400, 430, 420])


def test_small_negatives_are_clipped_with_a_count(tmp_path):
    path = tmp_path / "noisy.csv"
    path.write_text("theta_i,phi_i,theta_o,phi_o,R,G,B\n0,0,10,0,2.0,-1e-6,-5e-10\n0,0,20,0,1,1,-1e-6\n")
    with pytest.warns(UserWarning, match=r"noisy\.csv: clipped 3 slightly negative"):
        table = read_table(path)
    assert table.values.min() == 0.0
    np.testing.assert_array_equal(table.values[:, 0], [2.0, 1.0])


def test_file_without_negatives_reads_without_warnings(tmp_path):
    path = tmp_path / "clean.csv"
    write_table(_random_table(np.random.default_rng(5)), path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_table(path)


ANGLES = "theta_i,phi_i,theta_o,phi_o"
RGB_HEADER = f"{ANGLES},R,G,B"
GOOD_ROW = "10,0,20,180,0.1,0.2,0.3"

# name, file text, expected line (None: not applicable), expected column (None: not named), message fragment
BAD_TABLES = [
    ("missing column", "theta_i,phi_i,theta_o,R,G,B\n10,0,20,0.1,0.2,0.3\n", 1, "phi_o", "missing required"),
    ("unknown column", f"{RGB_HEADER},gloss\n{GOOD_ROW},1\n", 1, "gloss", "unknown column"),
    ("missing B", f"{ANGLES},R,G\n10,0,20,180,0.1,0.2\n", 1, "B", "missing RGB"),
    ("no values", f"{ANGLES}\n10,0,20,180\n", 1, None, "no value columns"),
    ("non-numeric", f"{RGB_HEADER}\n{GOOD_ROW}\n10,0,20,180,0.1,abc,0.3\n", 3, "G", "not a number: 'abc'"),
    ("empty cell", f"{RGB_HEADER}\n10,0,20,180,0.1,,0.3\n", 2, "G", "not a number: ''"),
    ("nan", f"{RGB_HEADER}\n{GOOD_ROW}\n{GOOD_ROW}\n10,0,20,180,nan,0.2,0.3\n", 4, "R", "non-finite value 'nan'"),
    ("inf angle", f"{RGB_HEADER}\n10,0,inf,180,0.1,0.2,0.3\n", 2, "theta_o", "non-finite"),
    ("overflow", f"{RGB_HEADER}\n10,0,20,180,0.1,0.2,1e999\n", 2, "B", "non-finite"),
    ("truncated", f"{RGB_HEADER}\n{GOOD_ROW}\n10,0,20,180,0.1", 3, "G", "5 of 7 cells"),
    ("too many cells", f"{RGB_HEADER}\n{GOOD_ROW},7\n", 2, None, "8 cells but the header has 7"),
    ("empty file", "", 1, None, "empty file"),
    ("blank header", "\n10,0,20,180,0.1,0.2,0.3\n", 1, None, "blank"),
    ("header only", f"{RGB_HEADER}\n", 2, None, "no data rows"),
    ("duplicated name", f"{ANGLES},R,G,B,R\n{GOOD_ROW},0.1\n", 1, "R", "duplicated column"),
    ("negative value", f"{RGB_HEADER}\n{GOOD_ROW}\n10,0,20,180,0.1,-0.01,0.3\n", 3, "G", "beyond the noise tolerance"),
    ("theta above 90", f"{RGB_HEADER}\n95,0,20,180,0.1,0.2,0.3\n", 2, "theta_i", "outside [0, 90]"),
    ("theta negative", f"{RGB_HEADER}\n{GOOD_ROW}\n10,0,-1,180,0.1,0.2,0.3\n", 3, "theta_o", "outside [0, 90]"),
    ("phi 360", f"{RGB_HEADER}\n10,0,20,360,0.1,0.2,0.3\n", 2, "phi_o", "outside [0, 360)"),
    ("phi negative", f"{RGB_HEADER}\n10,-5,20,0,0.1,0.2,0.3\n", 2, "phi_i", "outside [0, 360)"),
    ("duplicated wavelength", f"{ANGLES},400,400,410\n10,0,20,180,1,1,1\n", 1, "400", "duplicated"),
    ("same wavelength twice", f"{ANGLES},400,400.0,410\n10,0,20,180,1,1,1\n", 1, "400.0", "duplicated"),
    ("unsorted wavelengths", f"{ANGLES},400,420,410\n10,0,20,180,1,1,1\n", 1, "410", "must increase"),
    ("irregular wavelengths", f"{ANGLES},400,410,430\n10,0,20,180,1,1,1\n", 1, "430", "regular"),
    ("mixed RGB and spectral", f"{RGB_HEADER},400\n{GOOD_ROW},1\n", 1, "400", "mixes RGB"),
    ("negative weight", f"{RGB_HEADER},weight\n{GOOD_ROW},1\n{GOOD_ROW},-0.5\n", 3, "weight", "negative weight"),
    ("gcms file", "theta_i,theta_r,390\n10,20,0.5\n", 1, "theta_r", "a GCMS raw file starts theta_i, theta_r"),
    ("repeat with other values", f"{RGB_HEADER}\n{GOOD_ROW}\n10,0,20,200,0.1,0.2,0.3\n10,0,20,180,0.1,0.25,0.3\n", 4,
     None, "repeated geometry (theta_i, phi_i, theta_o, phi_o) = (10, 0, 20, 180) with different values than line 2"),
    ("repeat with other weight", f"{RGB_HEADER},weight\n{GOOD_ROW},1\n{GOOD_ROW},2\n", 3, None,
     "with different values than line 2"),
    ("line after blanks", f"{RGB_HEADER}\n\n{GOOD_ROW}\n\n\n10,0,20,180,x,0.2,0.3\n", 6, "R", "not a number"),
]


@pytest.mark.parametrize("name, text, line, column, fragment", BAD_TABLES, ids=[case[0] for case in BAD_TABLES])
def test_bad_tables_are_rejected_with_file_line_and_column(tmp_path, name, text, line, column, fragment):
    path = tmp_path / "bad_table.csv"
    path.write_text(text)
    with pytest.raises(InputError) as caught:
        read_table(path)
    error = caught.value
    message = str(error)
    assert str(path) in message and error.path == str(path)
    assert fragment in message
    assert error.line == line and f"line {line}" in message
    assert error.column == column
    if column is not None:
        assert f"column {column!r}" in message


def test_missing_file_names_the_path(tmp_path):
    path = tmp_path / "nowhere" / "t.csv"
    with pytest.raises(InputError, match=re.escape(str(path)) + ": file not found"):
        read_table(path)


def test_failed_write_leaves_existing_file_untouched(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("previous\n")
    table = _random_table(np.random.default_rng(6))
    table.values = np.ones((2, 2, 2))  # corrupted after construction: cannot be laid out as rows
    with pytest.raises(ValueError):
        write_table(table, path)
    assert path.read_text() == "previous\n"


def test_an_exact_repeat_is_kept_not_dropped(tmp_path):
    """Only repeats that disagree are refused; identical ones stay (no row dropped)."""
    path = tmp_path / "t.csv"
    path.write_text(f"{RGB_HEADER}\n{GOOD_ROW}\n{GOOD_ROW}\n")
    assert read_table(path).n_rows == 2


def test_oversized_and_endless_inputs_are_refused_before_reading(tmp_path, monkeypatch):
    """A CSV above the documented limit, or a FIFO/device, is never read."""
    import os

    from neuralbrdf.data import csvio

    path = tmp_path / "t.csv"
    path.write_text(f"{RGB_HEADER}\n{GOOD_ROW}\n")
    monkeypatch.setattr(csvio, "MAX_CSV_BYTES", 16)
    with pytest.raises(InputError, match="exceeds the limit of .* MiB"):
        read_table(path)
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)  # opening it for reading would block forever
    with pytest.raises(InputError, match="not a regular file"):
        read_table(fifo)
    with pytest.raises(InputError, match="not a regular file"):
        read_table("/dev/zero")
