"""Sampling plans of docs/measure.md#sampling-plans (report Tables 4.1, 5.1, 6.1, 6.2)."""

import numpy as np
import pytest

from neuralbrdf.data import plans
from neuralbrdf.errors import InputError


@pytest.mark.parametrize("name, count", [("DS1", 1001), ("DS2", 185), ("DS3", 57), ("DS4", 6)])
def test_in_plane_plan_counts_and_uniqueness(name, count):
    ti, tr = plans.in_plane_plan(name)
    assert len(ti) == count
    assert len(set(zip(ti.tolist(), tr.tolist()))) == count
    assert np.all(np.abs(ti) <= 60) and np.all(np.abs(tr) <= 60)


def test_ds4_pairs_are_table_6_2():
    ti, tr = plans.in_plane_plan("DS4")
    assert ti.tolist() == [30.0] * 6
    assert tr.tolist() == [-60.0, -20.0, 20.0, 28.0, 36.0, 60.0]


def _count_by_rule(ti_step, diffuse_step, glossy_step):
    """Independent brute-force count: enumerate a 0.5° lattice and keep the pairs the rule admits."""
    count = 0
    for ti in np.arange(-60, 60.01, ti_step):
        lo = max(ti - 10, -60)
        for tr in np.arange(-60, 60.01, 0.5):
            glossy = abs(ti - tr) <= 10
            on_glossy_grid = abs(((tr - lo) / glossy_step) - round((tr - lo) / glossy_step)) < 1e-9
            on_diffuse_grid = abs(((tr + 60) / diffuse_step) - round((tr + 60) / diffuse_step)) < 1e-9
            count += (glossy and on_glossy_grid) or (not glossy and on_diffuse_grid)
    return count


@pytest.mark.parametrize("name", ["DS1", "DS2", "DS3"])
def test_counts_follow_from_the_window_rule(name):
    grid = plans.IN_PLANE_GRIDS[name]
    assert _count_by_rule(grid.theta_i_step, grid.diffuse_step, grid.glossy_step) == len(plans.in_plane_plan(name)[0])


def test_glossy_samples_use_the_fine_step():
    ti, tr = plans.in_plane_plan("DS1")
    sel = ti == 0
    glossy = np.sort(tr[sel][plans.is_glossy(ti[sel], tr[sel])])
    np.testing.assert_array_equal(glossy, np.arange(-10, 11, 1.0))
    diffuse = tr[sel][~plans.is_glossy(ti[sel], tr[sel])]
    assert np.all(np.mod(diffuse, 5) == 0)


def test_low_plan_size_and_coverage():
    ti, pi, to, po = plans.low_plan()
    assert len(ti) == 230_400 == 256 * 900
    assert len(np.unique(ti)) == 8 and np.all(pi == 0)
    assert to.min() > 0 and to.max() < 90 and po.min() > 0 and po.max() < 360
    assert len(np.unique(to)) == 90 and len(np.unique(po)) == 320


def test_plan_spherical_is_in_range():
    for name in ("DS1", "DS2", "DS3", "DS4", "low"):
        ti, pi, to, po = plans.plan_spherical(name)
        assert np.all((ti >= 0) & (ti <= 90) & (to >= 0) & (to <= 90))
        assert np.all((pi >= 0) & (pi < 360) & (po >= 0) & (po < 360))


def test_spectral_mlp_split_is_table_5_1():
    ti, _ = plans.in_plane_plan("DS1")
    test = plans.spectral_mlp_split(ti)
    assert sorted(set(ti[test].tolist())) == [-50.0, -35.0, -20.0, -5.0, 10.0, 25.0, 40.0, 55.0]
    assert len(set(ti[~test].tolist())) == 25 - 8
    # all theta_r of one theta_i go to the same split
    for angle in np.unique(ti):
        assert len(set(test[ti == angle].tolist())) == 1


def test_every_third_theta_i_split_reproduces_table_5_1_on_ds1_and_generalises():
    ti, _ = plans.in_plane_plan("DS1")
    np.testing.assert_array_equal(plans.every_third_theta_i_split(ti), plans.spectral_mlp_split(ti))
    # Any order and repeated angles: the distinct angles are counted, not the rows.
    angles = np.array([40.0, -20.0, 0.0, 40.0, 10.0, 25.0, -20.0, 70.0])  # sorted: -20 0 10 25 40 70
    np.testing.assert_array_equal(
        plans.every_third_theta_i_split(angles), [False, False, False, False, True, False, False, True]
    )
    assert not plans.every_third_theta_i_split(np.array([30.0, 30.0, -30.0])).any()


def test_unknown_plan_is_rejected_with_the_valid_names():
    with pytest.raises(InputError, match="DS1"):
        plans.plan_spherical("DS9")


# --------------------------------------------------------------------------- plan files


def _write(path, text):
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize("name", ["DS3", "DS4", "low"])
def test_a_plan_file_written_by_the_plan_command_is_that_plan(tmp_path, name):
    from neuralbrdf.cli.main import main

    out = tmp_path / f"{name}.csv"
    assert main(["plan", name, "--out", str(out)]) == 0
    for got, expected in zip(plans.plan_spherical(str(out)), plans.plan_spherical(name)):
        np.testing.assert_allclose(got, expected, atol=1e-6)
    if name != "low":
        for got, expected in zip(plans.in_plane_plan(out), plans.in_plane_plan(name)):
            np.testing.assert_allclose(got, expected, atol=1e-6)
    assert plans.check_plan(out) == str(out) and plans.plan_label(out) == name


def test_a_plan_file_keeps_its_own_pairs_and_signs(tmp_path):
    path = _write(tmp_path / "mine.csv", "theta_i,theta_r\n30,20\n-10,5\n0,-45\n")
    ti, tr = plans.in_plane_plan(path)
    assert ti.tolist() == [30.0, -10.0, 0.0] and tr.tolist() == [20.0, 5.0, -45.0]
    from neuralbrdf.geometry import spherical_to_inplane

    back = spherical_to_inplane(*plans.plan_spherical(path))
    np.testing.assert_allclose(back[0], ti, atol=1e-9)
    np.testing.assert_allclose(back[1], tr, atol=1e-9)


@pytest.mark.parametrize("text, match", [
    ("theta_i,theta_r\n30,20\n-10,5\n30,20\n", r"line 4: the pair \(30°, 20°\) is listed twice \(first on line 2\)"),
    ("theta_i,theta_r\n30,95\n", r"line 2, column 'theta_r': angle 95° outside \[-90, 90\]"),
    ("theta_i,theta_o\n30,20\n", "a plan file needs the columns theta_i,theta_r"),
    ("theta_i,theta_r,R\n30,20,1\n", "column 'R': unexpected column in a plan file"),
    ("theta_i,theta_r\n30,nan\n", "line 2, column 'theta_r': non-finite"),
    ("theta_i,phi_i,theta_o,phi_o\n30,0,20,360\n", r"column 'phi_o': angle 360° outside \[0, 360\)"),
])
def test_a_bad_plan_file_is_refused_naming_line_and_column(tmp_path, text, match):
    path = _write(tmp_path / "bad.csv", text)
    with pytest.raises(InputError, match=match):
        plans.check_plan(path, "--plan")


def test_an_out_of_plane_plan_is_refused_where_the_instrument_measures(tmp_path):
    path = _write(tmp_path / "sph.csv", "theta_i,phi_i,theta_o,phi_o\n30,0,20,180\n30,0,20,90\n")
    assert len(plans.plan_spherical(path)[0]) == 2  # a truth can be sampled anywhere
    with pytest.raises(InputError, match="1 of 2 pairs lie out of the plane of incidence .the first on data row 2."):
        plans.check_plan(path, "--plan", in_plane=True)
    with pytest.raises(InputError, match="the low set is out of the plane"):
        plans.check_plan("low", "--plan", in_plane=True)


def test_a_name_that_is_no_plan_and_no_file_names_the_choices():
    with pytest.raises(InputError, match="option '--plan': unknown plan 'DS9'; expected DS1, DS2, DS3, DS4, low, or a "
                                         "plan file"):
        plans.check_plan("DS9", "--plan")
    with pytest.raises(InputError, match="missing.csv: file not found"):
        plans.check_plan("missing.csv", "--plan")


def test_every_plan_option_takes_a_plan_file(tmp_path, capsys):
    from neuralbrdf.cli.main import main
    from neuralbrdf.data.gcms import read_gcms
    from neuralbrdf.data.table import read_table

    plan = _write(tmp_path / "three.csv", "theta_i,theta_r\n30,30\n-20,40\n50,-50\n")
    assert main(["sample", "virtual:gold", "--plan", plan, "--out", str(tmp_path / "t.csv")]) == 0
    assert read_table(tmp_path / "t.csv").n_rows == 3
    assert main(["simulate", "--material", "gold", "--plan", plan, "--out", str(tmp_path / "raw.csv")]) == 0
    raw = read_gcms(tmp_path / "raw.csv")
    assert raw.theta_i.tolist() == [30.0, -20.0, 50.0] and raw.theta_r.tolist() == [30.0, 40.0, -50.0]
    assert "on three (3 pairs)" in capsys.readouterr().out
