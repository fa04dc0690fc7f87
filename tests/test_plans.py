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
