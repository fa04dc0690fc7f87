"""Losses (report Eqs. 4.2, 5.1) and metrics (Eq. 4.3, hemisphere log-cosine RMSE) against hand computations."""

import math

import numpy as np
import pytest
import torch

from neuralbrdf.losses import (
    RESIDUALS,
    exp_weighted_loss,
    exp_weighted_mse,
    l1_loss,
    log_cosine_loss,
    log_cosine_terms,
)
from neuralbrdf.metrics import (
    hemisphere_logcos_rmse,
    relative_rmse,
    relative_rmse_by_channel,
    relative_rmse_by_theta_i,
)

# --------------------------------------------------------------------------- Eq. 5.1

TI = [30.0, 30.0]
TR = [40.0, 30.0]  # |ti - tr| = 10°, 0°
PRED = [1.0, 0.5]
TARGET = [0.5, 0.0]  # squared errors 0.25, 0.25


@pytest.mark.parametrize(
    "unit, off_specular_weight",
    [("radians", math.exp(-3.0 * 10.0 * math.pi / 180.0)), ("degrees", math.exp(-30.0))],
)
def test_exp_weighted_mse_by_hand(unit, off_specular_weight):
    expected = (0.25 * off_specular_weight + 0.25 * 1.0) / 2
    t = torch.tensor
    got = exp_weighted_mse(t(PRED), t(TARGET), t(TI), t(TR), gamma=3.0, angle_unit=unit)
    assert float(got) == pytest.approx(expected, rel=1e-6)
    got_np = exp_weighted_mse(*(np.array(a) for a in (PRED, TARGET, TI, TR)), gamma=3.0, angle_unit=unit)
    assert float(got_np) == pytest.approx(expected, rel=1e-12)


def test_exp_weighted_mse_default_is_radians_and_weights_broadcast_over_channels():
    pred = np.array([[1.0, 2.0], [0.5, 1.5]])
    target = np.array([[0.5, 0.0], [0.0, 0.0]])
    w = np.array([math.exp(-3.0 * math.radians(10.0)), 1.0])
    expected = np.mean(w[:, None] * (pred - target) ** 2)
    assert float(exp_weighted_mse(pred, target, np.array(TI), np.array(TR))) == pytest.approx(expected, rel=1e-12)


def test_exp_weighted_mse_rejects_unknown_unit_and_shape_mismatch():
    a = np.array(PRED)
    with pytest.raises(ValueError, match="angle_unit"):
        exp_weighted_mse(a, a, np.array(TI), np.array(TR), angle_unit="gradians")
    with pytest.raises(ValueError, match="shape"):
        exp_weighted_mse(a, a[:1], np.array(TI), np.array(TR))
    with pytest.raises(ValueError, match="angles"):
        exp_weighted_mse(a, a, np.array(TI[:1]), np.array(TR[:1]))


def test_exp_weighted_mse_gradient_matches_finite_differences():
    pred = torch.tensor([[1.0, 2.0], [0.5, 1.5]], dtype=torch.float64, requires_grad=True)
    target = torch.tensor([[0.5, 0.0], [0.0, 0.0]], dtype=torch.float64)
    ti, tr = torch.tensor(TI, dtype=torch.float64), torch.tensor(TR, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda p: exp_weighted_mse(p, target, ti, tr), (pred,))


# --------------------------------------------------------------------------- Eq. 5.1's weighting, other residuals

# Three samples [N, 2]: on the mirror direction, 10° off it, 90° off it (signed in-plane angles).
RES_TI = [20.0, 20.0, 30.0]
RES_TR = [20.0, 30.0, -60.0]
RES_PRED = [[2.0, 1.0], [0.5, 0.02], [0.03, 0.011]]
RES_TARGET = [[1.5, 1.2], [0.4, 0.01], [0.01, 0.012]]


def _residual_by_hand(residual, pred, target, theta_i, eps):
    if residual == "linear":
        return pred - target
    if residual == "relative":
        return (pred - target) / (target + eps)
    if residual == "log":
        return math.log(pred + eps) - math.log(target + eps)
    c = math.cos(math.radians(theta_i))
    return math.log(1.0 + c * pred) - math.log(1.0 + c * target)


def _loss_by_hand(residual, gamma, eps, floor):
    total = 0.0
    for ti, tr, pred_row, target_row in zip(RES_TI, RES_TR, RES_PRED, RES_TARGET):
        weight = max(math.exp(-gamma * abs(ti - tr) * math.pi / 180.0), floor)
        for p, t in zip(pred_row, target_row):
            total += weight * _residual_by_hand(residual, p, t, ti, eps) ** 2
    return total / (len(RES_TI) * 2)


@pytest.mark.parametrize("residual", RESIDUALS)
@pytest.mark.parametrize("floor", [0.0, 0.3])
def test_exp_weighted_loss_by_hand(residual, floor):
    expected = _loss_by_hand(residual, 3.0, 1e-3, floor)
    args = (RES_PRED, RES_TARGET, RES_TI, RES_TR)
    got_np = exp_weighted_loss(*map(np.array, args), residual=residual, epsilon_sr=1e-3, weight_floor=floor)
    got_torch = exp_weighted_loss(
        *(torch.tensor(a, dtype=torch.float64) for a in args), residual=residual, epsilon_sr=1e-3, weight_floor=floor
    )
    assert float(got_np) == pytest.approx(expected, rel=1e-12)
    assert float(got_torch) == pytest.approx(expected, rel=1e-12)


def test_exp_weighted_loss_floor_changes_only_weights_below_it():
    # The 90°-off sample's weight exp(-3 pi/2) = 0.009 is raised to 0.3; the 10°-off one (0.59) is not.
    args = [np.array(a) for a in (RES_PRED, RES_TARGET, RES_TI, RES_TR)]
    plain, floored = (exp_weighted_loss(*args, residual="relative", weight_floor=f) for f in (0.0, 0.3))
    far = np.mean(((args[0][2] - args[1][2]) / (args[1][2] + 1e-3)) ** 2) / 3
    assert float(floored - plain) == pytest.approx((0.3 - math.exp(-1.5 * math.pi)) * far, rel=1e-12)


def test_relative_and_log_residuals_weigh_equal_ratios_alike_at_every_scale():
    # A 10 % over-estimate costs the same at 10 sr⁻¹ (glossy peak) and 0.01 sr⁻¹ (diffuse) up to eps.
    ti, tr = np.zeros(2), np.zeros(2)
    target = np.array([10.0, 0.01])
    for residual in ("relative", "log"):
        terms = [float(exp_weighted_loss(1.1 * target[k : k + 1], target[k : k + 1], ti[:1], tr[:1], residual=residual, epsilon_sr=1e-9)) for k in range(2)]
        assert terms[0] == pytest.approx(terms[1], rel=1e-6)
    linear = [float(exp_weighted_mse(1.1 * target[k : k + 1], target[k : k + 1], ti[:1], tr[:1])) for k in range(2)]
    assert linear[0] / linear[1] == pytest.approx(1e6)


def test_exp_weighted_loss_linear_without_floor_is_eq_5_1():
    args = [np.array(a) for a in (RES_PRED, RES_TARGET, RES_TI, RES_TR)]
    for unit in ("radians", "degrees"):
        assert float(exp_weighted_loss(*args, 2.0, unit)) == float(exp_weighted_mse(*args, 2.0, unit))


@pytest.mark.parametrize(
    "kwargs, match",
    [({"residual": "huber"}, "residual"), ({"epsilon_sr": 0.0}, "epsilon_sr"), ({"weight_floor": 1.5}, "weight_floor")],
)
def test_exp_weighted_loss_rejects_bad_options(kwargs, match):
    a = np.array(RES_PRED)
    with pytest.raises(ValueError, match=match):
        exp_weighted_loss(a, a, np.array(RES_TI), np.array(RES_TR), **kwargs)


@pytest.mark.parametrize("residual", RESIDUALS)
def test_exp_weighted_loss_gradient_matches_finite_differences(residual):
    pred = torch.tensor(RES_PRED, dtype=torch.float64, requires_grad=True)
    target = torch.tensor(RES_TARGET, dtype=torch.float64)
    ti, tr = torch.tensor(RES_TI, dtype=torch.float64), torch.tensor(RES_TR, dtype=torch.float64)
    assert torch.autograd.gradcheck(
        lambda p: exp_weighted_loss(p, target, ti, tr, residual=residual, weight_floor=0.1), (pred,)
    )


# --------------------------------------------------------------------------- Eq. 4.2


def test_log_cosine_loss_by_hand():
    # theta_o given as a signed in-plane angle (-90°): the weight is sin |theta_o| = 1.
    theta_i, theta_o = np.array([0.0, 60.0]), np.array([30.0, -90.0])
    target, pred = np.array([1.0, 2.0]), np.array([0.0, 1.0])
    term0 = (math.log(2.0) - math.log(1.0)) ** 2 * 0.5  # cos 0 = 1, sin 30° = 1/2
    term1 = (math.log(1.0 + 0.5 * 2.0) - math.log(1.0 + 0.5 * 1.0)) ** 2 * 1.0  # cos 60° = 1/2
    assert float(log_cosine_loss(pred, target, theta_i, theta_o)) == pytest.approx((term0 + term1) / 2, rel=1e-12)
    weighted = log_cosine_loss(pred, target, theta_i, theta_o, weight=np.array([1.0, 3.0]))
    assert float(weighted) == pytest.approx((term0 + 3.0 * term1) / 4, rel=1e-12)
    # [N, C]: a second channel identical to the first leaves the mean unchanged; torch agrees.
    both = [torch.tensor(np.stack([a, a], axis=1)) for a in (pred, target)]
    got = log_cosine_loss(*both, torch.tensor(theta_i), torch.tensor(theta_o))
    assert float(got) == pytest.approx((term0 + term1) / 2, rel=1e-12)
    assert log_cosine_terms(*both, torch.tensor(theta_i), torch.tensor(theta_o)).shape == (2, 2)


def test_l1_loss_by_hand():
    assert float(l1_loss(np.array([[1.0, -1.0], [0.0, 2.0]]), np.zeros((2, 2)))) == pytest.approx(1.0)
    assert float(l1_loss(torch.tensor([3.0]), torch.tensor([1.0]))) == pytest.approx(2.0)


# --------------------------------------------------------------------------- Eq. 4.3

# Row 2 is 15° off specular (not glossy); row 3's channel 0 is below the floor.
RR_TI = np.array([30.0, 30.0, 30.0, 30.0, 0.0])
RR_TR = np.array([30.0, 35.0, 45.0, 25.0, 0.0])
RR_TARGET = np.array([[1.0, 1.0], [2.0, 1.0], [3.0, 1.0], [1e-6, 1.0], [4.0, 1.0]])
RR_PRED = np.array([[1.1, 2.0], [1.8, 1.0], [100.0, 7.0], [5.0, 1.0], [4.0, 1.5]])


def test_relative_rmse_by_hand_with_floor_exclusion():
    result = relative_rmse(RR_PRED, RR_TARGET, RR_TI, RR_TR, floor=1e-4)
    ch0 = math.sqrt((0.1**2 + 0.1**2 + 0.0**2) / 3)  # rows 0, 1, 4
    ch1 = math.sqrt((1.0**2 + 0.0 + 0.0 + 0.5**2) / 4)  # rows 0, 1, 3, 4
    np.testing.assert_allclose(result.per_channel, [ch0, ch1], rtol=1e-12)
    assert result.value == pytest.approx((ch0 + ch1) / 2, rel=1e-12)
    assert (result.n_used, result.n_excluded) == (7, 1)
    # A floor above 1.0 excludes every entry of channel 1 and all but two of channel 0.
    high = relative_rmse(RR_PRED, RR_TARGET, RR_TI, RR_TR, floor=1.5)
    assert np.isnan(high.per_channel[1]) and high.n_excluded == 6
    assert high.value == pytest.approx(math.sqrt(0.1**2 / 2), rel=1e-12)


def test_relative_rmse_per_incident_angle_and_per_channel():
    by_angle = relative_rmse_by_theta_i(torch.tensor(RR_PRED), RR_TARGET, RR_TI, RR_TR, floor=1e-4)
    np.testing.assert_array_equal(by_angle.theta_i, [0.0, 30.0])
    expected = np.array([[0.0, 0.5], [0.1, math.sqrt(1.0 / 3)]])
    np.testing.assert_allclose(by_angle.per_channel, expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(by_angle.value, expected.mean(axis=1), rtol=1e-12)
    np.testing.assert_array_equal(by_angle.n_excluded, [[0, 0], [1, 0]])
    by_channel = relative_rmse_by_channel(RR_PRED, RR_TARGET, RR_TI, RR_TR, floor=1e-4)
    np.testing.assert_allclose(by_channel.per_theta_i, expected.T, rtol=1e-12, atol=1e-15)
    # A fully excluded (angle, channel) cell is NaN, left out of the channel mean and the box.
    target = RR_TARGET.copy()
    target[4, 0] = 0.0
    by_angle = relative_rmse_by_theta_i(RR_PRED, target, RR_TI, RR_TR)
    assert np.isnan(by_angle.per_channel[0, 0]) and by_angle.value[0] == pytest.approx(0.5)
    boxes = relative_rmse_by_channel(RR_PRED, target, RR_TI, RR_TR).boxes()
    assert [len(b) for b in boxes] == [1, 2]


def test_relative_rmse_rejects_bad_input():
    with pytest.raises(ValueError, match="no glossy sample"):
        relative_rmse(RR_PRED, np.zeros_like(RR_TARGET), RR_TI, RR_TR)
    with pytest.raises(ValueError, match="floor"):
        relative_rmse(RR_PRED, RR_TARGET, RR_TI, RR_TR, floor=0.0)
    bad = RR_PRED.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        relative_rmse(bad, RR_TARGET, RR_TI, RR_TR)


def test_hemisphere_logcos_rmse_by_hand():
    pred = np.array([[0.0, 1.0], [2.0, 2.0]])
    target = np.array([[1.0, 1.0], [0.0, 2.0]])
    theta_i = np.array([60.0, 0.0])
    residuals = [math.log(1.5), 0.0, -math.log(3.0), 0.0]
    expected = math.sqrt(sum(r * r for r in residuals) / 4)
    assert hemisphere_logcos_rmse(pred, target, theta_i) == pytest.approx(expected, rel=1e-12)
    assert hemisphere_logcos_rmse(torch.tensor(pred[:, 0]), torch.tensor(target[:, 0]), theta_i) == pytest.approx(
        math.sqrt((residuals[0] ** 2 + residuals[2] ** 2) / 2), rel=1e-12
    )
