"""Spectral MLP (report §5.1; docs/models.md#spectral-mlp): network, in-plane sample data, Table 5.1 split, metrics."""

from typing import get_args

import numpy as np
import pytest
import torch

from neuralbrdf.data.calibration import calibrate
from neuralbrdf.data.gcms import write_gcms
from neuralbrdf.data.plans import SPECTRAL_MLP_TEST_THETA_I, in_plane_plan
from neuralbrdf.data.table import BrdfTable, write_table
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import inplane_to_spherical
from neuralbrdf.lightning.measurement_data import (
    MeasurementDataModule,
    SpectralSamples,
    load_inplane_spectral,
)
from neuralbrdf.lightning.spectral_mlp_module import SpectralMlpModule
from neuralbrdf.metrics import glossy_relative_rmse_of_samples as glossy_relative_rmse
from neuralbrdf.models.spectral_mlp import ACTIVATIONS, OUTPUTS, Activation, OutputActivation, SpectralMLP
from neuralbrdf.virtual.instrument import VirtualGoniospectrophotometer

WAVELENGTHS = np.arange(400.0, 701.0, 10.0)


# --------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def gcms_session(tmp_path_factory):
    """A noisy virtual DS1 session of gold: (sample GCMS raw path, Munsell reference path)."""
    folder = tmp_path_factory.mktemp("gcms")
    instrument = VirtualGoniospectrophotometer(noise_rel=0.01, noise_abs=1e-4, seed=7)
    paths = []
    for name in ("gold", "munsell_n9"):
        path = folder / f"{name}.csv"
        write_gcms(instrument.measure_plan(name, "DS1"), path)
        paths.append(path)
    return tuple(paths)


def spectral_table(theta_i, theta_r, values=None, source="<test>"):
    values = np.full((len(theta_i), len(WAVELENGTHS)), 0.3) if values is None else values
    return BrdfTable(*inplane_to_spherical(np.asarray(theta_i), np.asarray(theta_r)), values, WAVELENGTHS, source=source)


# --------------------------------------------------------------------------- the network


def test_config_types_name_exactly_the_implemented_activations():
    assert set(get_args(Activation)) == set(ACTIVATIONS)
    assert set(get_args(OutputActivation)) == set(OUTPUTS)


def test_inputs_are_mapped_onto_the_unit_interval():
    model = SpectralMLP(angle_range_deg=(-60.0, 60.0), wavelength_range_nm=(380.0, 780.0))
    x = model.normalise(torch.tensor([-60.0, 0.0, 30.0]), torch.tensor([60.0, -30.0, 0.0]), torch.tensor([380.0, 580.0, 780.0]))
    expected = torch.tensor([[-1.0, 1.0, -1.0], [0.0, -0.5, 0.0], [0.5, 0.0, 1.0]])
    torch.testing.assert_close(x, expected)
    assert model.wavelength_range_nm == (380.0, 780.0)


def test_normalisation_constants_survive_a_state_dict_round_trip():
    torch.manual_seed(0)
    trained = SpectralMLP(angle_range_deg=(-60.0, 60.0), wavelength_range_nm=(450.0, 650.0))
    fresh = SpectralMLP()
    args = (torch.tensor([10.0, -40.0]), torch.tensor([12.0, 30.0]), torch.tensor([500.0, 610.0]))
    assert not torch.allclose(fresh(*args), trained(*args))
    fresh.load_state_dict(trained.state_dict())
    assert fresh.wavelength_range_nm == (450.0, 650.0)
    torch.testing.assert_close(fresh.input_center, trained.input_center)
    torch.testing.assert_close(fresh(*args), trained(*args))


def test_architecture_is_three_hidden_layers_of_ten():
    model = SpectralMLP()
    linear = [m for m in model.modules() if isinstance(m, torch.nn.Linear)]
    assert [(m.in_features, m.out_features) for m in linear] == [(3, 10), (10, 10), (10, 10), (10, 1)]
    assert sum(p.numel() for p in model.parameters()) == 4 * 10 + 2 * 110 + 11


@pytest.mark.parametrize("activation", sorted(ACTIVATIONS))
@pytest.mark.parametrize("output", sorted(OUTPUTS))
@pytest.mark.parametrize("weight_scale", [1.0, 4.0])
def test_output_is_non_negative_and_finite_on_the_whole_domain(activation, output, weight_scale):
    torch.manual_seed(3)
    model = SpectralMLP(activation=activation, output=output)
    with torch.no_grad():
        for p in model.parameters():
            p.mul_(weight_scale)
    ti, tr, wl = torch.meshgrid(
        torch.linspace(-90, 90, 61), torch.linspace(-90, 90, 61), torch.linspace(400, 700, 31), indexing="ij"
    )
    with torch.no_grad():
        f = model(ti.reshape(-1), tr.reshape(-1), wl.reshape(-1))
    assert f.shape == (61 * 61 * 31,)
    assert torch.isfinite(f).all() and (f >= 0).all()


@pytest.mark.parametrize(
    "kwargs",
    [{"activation": "sigmoid"}, {"output": "relu"}, {"hidden": 0}, {"wavelength_range_nm": (700.0, 400.0)}],
)
def test_bad_network_options_are_input_errors(kwargs):
    with pytest.raises(InputError):
        SpectralMLP(**kwargs)


def test_module_rejects_an_unknown_angle_unit():
    with pytest.raises(InputError, match="angle_unit"):
        SpectralMlpModule(angle_unit="grad")


@pytest.mark.parametrize(
    "kwargs, match",
    [({"residual": "huber"}, "residual"), ({"residual_epsilon_sr": 0.0}, "residual_epsilon_sr"), ({"weight_floor": -0.1}, "weight_floor")],
)
def test_module_rejects_bad_loss_options(kwargs, match):
    with pytest.raises(InputError, match=match):
        SpectralMlpModule(**kwargs)


@pytest.mark.parametrize("residual", ["linear", "log"])
def test_module_loss_is_the_configured_residual(residual):
    torch.manual_seed(0)
    module = SpectralMlpModule(residual=residual, residual_epsilon_sr=1e-3, weight_floor=0.02)
    theta_i, theta_r = torch.tensor([30.0, 30.0, -10.0]), torch.tensor([30.0, -40.0, 50.0])
    wavelength, brdf = torch.tensor([450.0, 550.0, 650.0]), torch.tensor([5.0, 0.02, 0.01])
    batch = SpectralSamples(theta_i, theta_r, wavelength, brdf, torch.arange(3))
    pred, loss = module._loss(batch)
    weight = torch.clamp(torch.exp(-3.0 * torch.deg2rad((theta_i - theta_r).abs())), min=0.02)
    r = pred - brdf if residual == "linear" else torch.log(pred + 1e-3) - torch.log(brdf + 1e-3)
    torch.testing.assert_close(loss, torch.mean(weight * r**2))


# --------------------------------------------------------------------------- signed in-plane angles


def test_table_angles_round_trip_with_their_signs(tmp_path):
    ti, tr = in_plane_plan("DS2")
    path = tmp_path / "t.csv"
    write_table(spectral_table(ti, tr), path)
    _, back_i, back_r = load_inplane_spectral(path)
    np.testing.assert_allclose(back_i, ti, atol=1e-9)
    np.testing.assert_allclose(back_r, tr, atol=1e-9)


def test_table_angles_accept_any_azimuth_of_the_plane_and_reject_out_of_plane_rows(tmp_path):
    # wi at phi = 90°, wo at phi = 270° (mirror side), and a normal-incidence row at any azimuth.
    table = BrdfTable([30.0, 0.0], [90.0, 0.0], [20.0, 40.0], [270.0, 123.0], np.full((2, 31), 0.1), WAVELENGTHS)
    write_table(table, tmp_path / "plane.csv")
    _, theta_i, theta_r = load_inplane_spectral(tmp_path / "plane.csv")
    np.testing.assert_allclose(theta_i, [30.0, 40.0])  # the second row's representative pair
    np.testing.assert_allclose(theta_r, [20.0, 0.0], atol=1e-9)
    skew = BrdfTable([30.0, 30.0], [0.0, 0.0], [20.0, 20.0], [180.0, 90.0], np.full((2, 31), 0.1), WAVELENGTHS)
    write_table(skew, tmp_path / "skew.csv")
    with pytest.raises(InputError, match="row 1: out of plane"):
        load_inplane_spectral(tmp_path / "skew.csv")


def test_gcms_raw_keeps_the_signed_incident_angles_row_for_row(gcms_session):
    sample, reference = gcms_session
    table, theta_i, theta_r = load_inplane_spectral(sample, reference)
    plan_i, plan_r = in_plane_plan("DS1")
    np.testing.assert_array_equal(theta_i, plan_i)
    np.testing.assert_array_equal(theta_r, plan_r)
    # The table's rows are the calibrated raw rows in the same order.
    from neuralbrdf.data.gcms import read_gcms

    np.testing.assert_array_equal(table.values, calibrate(read_gcms(sample), read_gcms(reference)).values)


def test_rgb_tables_are_rejected(tmp_path):
    path = tmp_path / "rgb.csv"
    write_table(BrdfTable(*inplane_to_spherical(np.array([10.0]), np.array([5.0])), np.ones((1, 3))), path)
    with pytest.raises(InputError, match="RGB"):
        load_inplane_spectral(path)


# --------------------------------------------------------------------------- the Table 5.1 split


def test_split_follows_table_5_1_with_whole_incident_angles(gcms_session):
    data = MeasurementDataModule(*map(str, gcms_session), batch_size=64)
    data.setup("fit")
    test_angles = set(np.unique(data.test_samples.theta_i_deg.numpy()).tolist())
    train_angles = set(np.unique(data.train_samples.theta_i_deg.numpy()).tolist())
    assert test_angles == set(SPECTRAL_MLP_TEST_THETA_I)
    assert train_angles == set(np.arange(-60.0, 61.0, 5.0).tolist()) - test_angles
    plan_i, _ = in_plane_plan("DS1")
    n_test_pairs = int(np.isin(plan_i, SPECTRAL_MLP_TEST_THETA_I).sum())
    assert len(data.test_samples.brdf) == n_test_pairs * 31
    assert len(data.train_samples.brdf) == (len(plan_i) - n_test_pairs) * 31
    # Every wavelength of a direction pair goes with it.
    for samples in (data.train_samples, data.test_samples):
        assert len(samples.brdf) % 31 == 0
        np.testing.assert_array_equal(samples.wavelength_nm.reshape(-1, 31)[0].numpy(), WAVELENGTHS)


def test_a_table_splits_like_its_gcms_raw_file(tmp_path, gcms_session):
    table, _, _ = load_inplane_spectral(*gcms_session)
    path = tmp_path / "gold_table.csv"
    write_table(table, path)
    from_table = MeasurementDataModule(str(path))
    from_raw = MeasurementDataModule(*map(str, gcms_session))
    for data in (from_table, from_raw):
        data.setup("fit")
    for split in ("train_samples", "test_samples"):
        for a, b in zip(getattr(from_table, split), getattr(from_raw, split)):
            np.testing.assert_allclose(a.numpy(), b.numpy(), atol=1e-5)
    test = from_table.test_samples
    assert set(np.unique(test.theta_i_deg.numpy()).tolist()) == set(SPECTRAL_MLP_TEST_THETA_I)
    # A uniform 10 % over-estimate has relative RMSE 0.1 in every group.
    result = glossy_relative_rmse(test, 1.1 * test.brdf.double(), floor=1e-4)
    assert result["rel_rmse_glossy"] == pytest.approx(0.1) and result["rel_rmse_glossy_median"] == pytest.approx(0.1)


def test_training_batches_cover_the_train_split_once_per_epoch(gcms_session):
    data = MeasurementDataModule(*map(str, gcms_session), batch_size=1000)
    data.setup("fit")
    (batches,) = list(data.train_dataloader())  # one item per epoch: its batches
    assert all(isinstance(b, SpectralSamples) for b in batches)
    assert [len(b.brdf) for b in batches[:-1]] == [1000] * (len(batches) - 1)
    seen = torch.cat([b.brdf for b in batches])
    torch.testing.assert_close(seen.sort().values, data.train_samples.brdf.sort().values)
    assert not torch.equal(seen, data.train_samples.brdf)  # shuffled
    (again,) = list(data.train_dataloader())
    assert not torch.equal(torch.cat([b.brdf for b in again]), seen)  # afresh every epoch
    (whole,) = list(data.val_dataloader())
    torch.testing.assert_close(whole.brdf, data.test_samples.brdf)


def test_a_small_split_is_drawn_again_until_the_epoch_holds_min_steps_batches(gcms_session):
    plain = MeasurementDataModule(*map(str, gcms_session), batch_size=1000)
    plain.setup("fit")
    n = len(plain.train_samples.brdf)
    steps = -(-n // 1000)
    unchanged = MeasurementDataModule(*map(str, gcms_session), batch_size=1000, min_steps_per_epoch=steps)
    unchanged.setup("fit")
    torch.manual_seed(3)
    (expected,) = list(plain.train_dataloader())
    torch.manual_seed(3)
    (same,) = list(unchanged.train_dataloader())  # already that many batches: the same draws
    assert [torch.equal(a.brdf, b.brdf) for a, b in zip(same, expected)] == [True] * steps
    data = MeasurementDataModule(*map(str, gcms_session), batch_size=1000, min_steps_per_epoch=3 * steps)
    data.setup("fit")
    (batches,) = list(data.train_dataloader())
    assert [len(b.brdf) for b in batches] == [1000] * (3 * steps)
    seen = torch.cat([b.brdf for b in batches])
    # successive permutations: every sample in each of the first full passes over the split
    for k in range(2):
        torch.testing.assert_close(seen[k * n:(k + 1) * n].sort().values, data.train_samples.brdf.sort().values)
    with pytest.raises(InputError, match="data.min_steps_per_epoch"):
        MeasurementDataModule(*map(str, gcms_session), min_steps_per_epoch=0)


def test_evaluation_batches_hold_whole_direction_pairs(gcms_session):
    data = MeasurementDataModule(*map(str, gcms_session), eval_batch_size=100)
    data.setup("test")
    batches = list(data.test_dataloader())
    assert {len(b.brdf) for b in batches[:-1]} == {4 * 31}
    assert all(len(b.brdf) % 31 == 0 and len(torch.unique(b.pair_index)) == len(b.brdf) // 31 for b in batches)
    torch.testing.assert_close(torch.cat([b.brdf for b in batches]), data.test_samples.brdf)


def test_table_5_1_on_a_plan_without_its_angles_is_an_input_error(tmp_path):
    ti, tr = in_plane_plan("DS2")  # theta_i every 15°: none of Table 5.1's test angles
    path = tmp_path / "ds2.csv"
    write_table(spectral_table(ti, tr), path)
    with pytest.raises(InputError, match="no row falls in the Table 5.1 test split.*data.test_split"):
        MeasurementDataModule(str(path), test_split="table_5_1").setup("fit")


def test_every_third_split_needs_three_incident_angles(tmp_path):
    ti, tr = in_plane_plan("DS4")
    path = tmp_path / "ds4.csv"
    write_table(spectral_table(ti, tr), path)
    with pytest.raises(InputError, match="no row falls in the every_third_theta_i test split"):
        MeasurementDataModule(str(path), test_split="every_third_theta_i").setup("fit")


def test_unknown_test_split_is_an_input_error():
    with pytest.raises(InputError, match="test_split"):
        MeasurementDataModule(test_split="random")


@pytest.mark.parametrize(
    "plan, rule, test_theta_i",
    [
        ("DS1", "table_5_1", SPECTRAL_MLP_TEST_THETA_I),
        ("DS2", "every_third_theta_i", (-30.0, 15.0, 60.0)),
        ("DS3", "every_third_theta_i", (0.0,)),
        ("DS4", "none", ()),
    ],
)
def test_auto_split_per_plan(tmp_path, plan, rule, test_theta_i):
    ti, tr = in_plane_plan(plan)
    path = tmp_path / f"{plan}.csv"
    write_table(spectral_table(ti, tr), path)
    data = MeasurementDataModule(str(path))
    data.setup("fit")
    assert data.resolved_test_split == rule
    train_angles = np.unique(data.train_samples.theta_i_deg.numpy())
    if rule == "none":  # validation and test run on the training data
        assert set(train_angles) == set(ti)
        torch.testing.assert_close(data.test_samples.brdf, data.train_samples.brdf)
        assert len(data.train_samples.brdf) == len(ti) * 31
        return
    test_angles = np.unique(data.test_samples.theta_i_deg.numpy())
    np.testing.assert_allclose(test_angles, sorted(test_theta_i))
    assert set(train_angles) == set(ti) - set(test_theta_i)
    assert len(data.train_samples.brdf) + len(data.test_samples.brdf) == len(ti) * 31


def test_default_data_is_the_shipped_virtual_gold():
    data = MeasurementDataModule()
    assert data.path.endswith("gold_DS1.csv") and data.reference.endswith("munsell_n9_DS1.csv")


# --------------------------------------------------------------------------- metrics of the evaluation split


def _reference_metrics(theta_i, theta_r, pred, target):
    """Per (theta_i, wavelength) Eq. 4.3 over glossy pairs, by explicit loops."""
    groups = []
    for angle in np.unique(theta_i):
        rows = (theta_i == angle) & (np.abs(theta_i - theta_r) <= 10)
        for c in range(pred.shape[1]):
            ratio = (pred[rows, c] - target[rows, c]) / target[rows, c]
            groups.append(np.sqrt(np.mean(ratio**2)))
    glossy = np.abs(theta_i - theta_r) <= 10
    per_channel = np.sqrt(np.mean(((pred[glossy] - target[glossy]) / target[glossy]) ** 2, axis=0))
    return np.mean(per_channel), np.median(groups)


def test_glossy_metrics_match_a_direct_computation_in_any_sample_order():
    rng = np.random.default_rng(1)
    theta_i, theta_r = in_plane_plan("DS3")
    target = rng.uniform(0.1, 2.0, (len(theta_i), 4))
    pred = target * (1 + rng.normal(0, 0.1, target.shape))
    wavelengths = np.array([400.0, 500.0, 600.0, 700.0])
    rows = np.arange(len(theta_i))
    flat = [np.repeat(theta_i, 4), np.repeat(theta_r, 4), np.tile(wavelengths, len(theta_i)), target.reshape(-1), np.repeat(rows, 4)]
    order = rng.permutation(len(flat[0]))
    samples = SpectralSamples(*(torch.as_tensor(c[order]) for c in flat))
    result = glossy_relative_rmse(samples, torch.as_tensor(pred.reshape(-1)[order]), floor=1e-4)
    assert result["rel_rmse_glossy_median"] != pytest.approx(result["rel_rmse_glossy"], rel=1e-3)
    mean, median = _reference_metrics(theta_i, theta_r, pred, target)
    assert result["rel_rmse_glossy"] == pytest.approx(mean, rel=1e-12)
    assert result["rel_rmse_glossy_median"] == pytest.approx(median, rel=1e-12)
    assert result["rel_rmse_excluded"] == 0


def test_glossy_metrics_need_every_wavelength_of_every_pair():
    columns = ([0.0, 0.0, 5.0], [0.0, 0.0, 5.0], [400.0, 500.0, 400.0], [1.0, 1.0, 1.0], [0, 0, 1])
    samples = SpectralSamples(*(torch.tensor(v) for v in columns))
    with pytest.raises(ValueError, match="do not fill"):
        glossy_relative_rmse(samples, torch.ones(3), floor=1e-4)


def test_training_step_takes_one_adam_step_per_batch_of_the_epoch(gcms_session):
    """An epoch handed over at once trains exactly like its batches one by one (same order)."""
    import copy

    from neuralbrdf.losses import exp_weighted_loss

    data = MeasurementDataModule(*map(str, gcms_session), batch_size=500)
    data.setup("fit")
    (batches,) = list(data.train_dataloader())
    batches = batches[:3]
    module = SpectralMlpModule(gamma=1.0, residual="log")
    reference = copy.deepcopy(module.network)
    optimizer = torch.optim.Adam(module.parameters(), lr=0.02)
    module.optimizers = lambda: optimizer
    module.manual_backward = lambda loss: loss.backward()
    module.on_train_epoch_start()
    mean = module.training_step(batches, 0)
    reference_optimizer = torch.optim.Adam(reference.parameters(), lr=0.02)
    losses = []
    for batch in batches:
        pred = reference(batch.theta_i_deg, batch.theta_r_deg, batch.wavelength_nm)
        loss = exp_weighted_loss(pred, batch.brdf, batch.theta_i_deg, batch.theta_r_deg, 1.0, "radians", "log", 1e-3, 0.0)
        reference_optimizer.zero_grad()
        loss.backward()
        reference_optimizer.step()
        losses.append((loss.item(), len(batch.brdf)))
    for ours, theirs in zip(module.network.parameters(), reference.parameters()):
        torch.testing.assert_close(ours, theirs, rtol=0, atol=0)
    expected = sum(l * n for l, n in losses) / sum(n for _, n in losses)
    assert mean.item() == pytest.approx(expected, rel=1e-6)
