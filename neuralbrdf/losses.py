"""Training and fitting losses of the report (S. Chitnis, *Simplifying BRDF Acquisition*).

* :func:`log_cosine_loss` (and its per-element :func:`log_cosine_terms`) — Eq. 4.2, the ABC fit's loss (after Löw et al. 2012)::

      L_cus = mean((ln(1 + cos ti f_mea) - ln(1 + cos ti f_pred))² · sin to)

* :func:`exp_weighted_mse` — Eq. 5.1, the spectral MLP's loss::

      L = mean(exp(-gamma |theta_i - theta_r|) · (f_mea - f_pred)²)

  with the angle difference in radians by default (docs/models.md#spectral-mlp: in degrees, gamma = 3 gives
  weights below 1e-13 ten degrees off specular, so the diffuse region gets no gradient).
* :func:`exp_weighted_loss` — Eq. 5.1's weighting with another residual ``r`` in place of
  ``f_mea - f_pred`` (:data:`RESIDUALS`) and an optional floor on the weight::

      L = mean(max(exp(-gamma |theta_i - theta_r|), weight_floor) · r(f_pred, f_mea)²)

  On linear values Eq. 5.1 fits the glossy peak (many sr⁻¹) and leaves the off-specular
  region (~0.01 sr⁻¹) almost unconstrained; a relative or logarithmic residual scores every
  region by its *relative* error (the comparison is in docs/design.md, *Spectral MLP loss*).
* :func:`l1_loss` — mean absolute error (Fan et al. 2022, the NLB latent fits);
* :func:`nlb_loss` — that L1 in the linear or the log-cosine domain (:func:`log_cosine`).

Every function takes ``pred`` and ``target`` of the same shape, ``[N]`` or ``[N, C]`` (one
column per channel or wavelength), and per-sample angles ``[N]`` in degrees that broadcast over
the channels; the mean runs over every element.  They work on torch tensors (autograd flows
through ``pred``) and NumPy arrays alike, and return a 0-d array of the input's kind.
"""

from __future__ import annotations

import math

from array_api_compat import array_namespace

from neuralbrdf.errors import InputError

DEG = math.pi / 180.0

#: Angle units accepted by :func:`exp_weighted_mse`.
ANGLE_UNITS = ("radians", "degrees")

#: Residuals of :func:`exp_weighted_loss` (``f`` measured, ``f̂`` predicted, sr⁻¹; ``eps`` the
#: ``epsilon_sr`` argument, a BRDF value below which relative differences stop mattering):
#:
#: * ``linear`` — ``f̂ - f`` (Eq. 5.1 as written);
#: * ``relative`` — ``(f̂ - f) / (f + eps)``;
#: * ``log`` — ``ln(f̂ + eps) - ln(f + eps)``;
#: * ``log_cosine`` — ``ln(1 + f̂ cos ti) - ln(1 + f cos ti)`` (the residual of Eq. 4.2).
RESIDUALS = ("linear", "relative", "log", "log_cosine")


def _check_pair(pred, target) -> None:
    if tuple(pred.shape) != tuple(target.shape):
        raise ValueError(f"pred has shape {tuple(pred.shape)} but target has {tuple(target.shape)}")
    if pred.ndim not in (1, 2):
        raise ValueError(f"pred and target must be [N] or [N, C], got shape {tuple(pred.shape)}")


def _per_sample(weight, like):
    """Broadcast a per-sample ``[N]`` weight against ``[N]`` or ``[N, C]`` values."""
    if tuple(weight.shape) != tuple(like.shape[:1]):
        raise ValueError(f"angles have shape {tuple(weight.shape)}, expected ({like.shape[0]},)")
    return weight if like.ndim == 1 else weight[:, None]


def exp_weighted_mse(pred, target, theta_i_deg, theta_r_deg, gamma: float = 3.0, angle_unit: str = "radians"):
    """Exponentially weighted MSE (report Eq. 5.1), weighting samples near the mirror direction.

    ``theta_i_deg, theta_r_deg`` are signed in-plane angles in degrees (docs/formats.md#conventions: the mirror
    direction is ``theta_r = theta_i``).  ``angle_unit`` is the unit in which ``|theta_i -
    theta_r|`` enters the exponent: ``"radians"`` (default, docs/models.md#spectral-mlp) or ``"degrees"`` (the
    report's literal form).
    """
    return exp_weighted_loss(pred, target, theta_i_deg, theta_r_deg, gamma, angle_unit, residual="linear")


def _residual(pred, target, theta_i_deg, residual: str, epsilon_sr: float, xp):
    if residual == "linear":
        return pred - target
    if residual == "relative":
        return (pred - target) / (target + epsilon_sr)
    if residual == "log":
        return xp.log(pred + epsilon_sr) - xp.log(target + epsilon_sr)
    cos_i = _per_sample(xp.cos(theta_i_deg * DEG), pred)
    return xp.log1p(cos_i * pred) - xp.log1p(cos_i * target)


def exp_weighted_loss(
    pred,
    target,
    theta_i_deg,
    theta_r_deg,
    gamma: float = 3.0,
    angle_unit: str = "radians",
    residual: str = "linear",
    epsilon_sr: float = 1e-3,
    weight_floor: float = 0.0,
):
    """Eq. 5.1's exponential weighting of a squared residual (module docstring).

    ``mean(max(exp(-gamma |theta_i - theta_r|), weight_floor) · r²)`` with ``r`` one of
    :data:`RESIDUALS`; ``residual="linear", weight_floor=0`` is :func:`exp_weighted_mse`.
    ``epsilon_sr`` (> 0, sr⁻¹) enters the ``relative`` and ``log`` residuals; ``weight_floor``
    (in [0, 1]) keeps a minimum weight far from the mirror direction.  Angles as in
    :func:`exp_weighted_mse`.
    """
    if angle_unit not in ANGLE_UNITS:
        raise ValueError(f"angle_unit must be one of {', '.join(ANGLE_UNITS)}, got {angle_unit!r}")
    if residual not in RESIDUALS:
        raise ValueError(f"residual must be one of {', '.join(RESIDUALS)}, got {residual!r}")
    if not epsilon_sr > 0:
        raise ValueError(f"epsilon_sr must be a positive BRDF value (sr⁻¹), got {epsilon_sr}")
    if not 0.0 <= weight_floor <= 1.0:
        raise ValueError(f"weight_floor must lie in [0, 1], got {weight_floor}")
    _check_pair(pred, target)
    xp = array_namespace(pred, target, theta_i_deg, theta_r_deg)
    difference = xp.abs(theta_i_deg - theta_r_deg)
    if angle_unit == "radians":
        difference = difference * DEG
    weight = _per_sample(xp.clip(xp.exp(-gamma * difference), weight_floor, None), pred)
    r = _residual(pred, target, theta_i_deg, residual, epsilon_sr, xp)
    return xp.mean(weight * r * r)


def log_cosine_terms(pred, target, theta_i_deg, theta_o_deg):
    """Per-element terms ``(ln(1 + cos ti f_mea) - ln(1 + cos ti f_pred))² · sin to`` of Eq. 4.2.

    Same shape as ``pred``; :func:`log_cosine_loss` is their mean.
    """
    _check_pair(pred, target)
    xp = array_namespace(pred, target, theta_i_deg, theta_o_deg)
    cos_i = _per_sample(xp.cos(theta_i_deg * DEG), pred)
    sin_o = _per_sample(xp.sin(xp.abs(theta_o_deg) * DEG), pred)
    residual = xp.log1p(cos_i * target) - xp.log1p(cos_i * pred)
    return residual * residual * sin_o


def log_cosine_loss(pred, target, theta_i_deg, theta_o_deg, weight=None):
    """Log-cosine loss ``L_cus`` (report Eq. 4.2, Löw et al. 2012) of BRDF values in sr⁻¹.

    ``theta_i_deg`` is the incident polar angle; ``theta_o_deg`` the outgoing one.  Signed
    in-plane angles are accepted too: the weight is ``sin |theta_o|`` (the polar angle, >= 0)
    and ``cos theta_i`` is even.  An optional non-negative per-sample ``weight`` ``[N]`` (e.g.
    a table's weight column) turns the mean into ``Σ w · term / Σ w`` over samples (a plain mean
    over channels); ``weight=None`` is Eq. 4.2 as written.
    """
    xp = array_namespace(pred, target, theta_i_deg, theta_o_deg)
    terms = log_cosine_terms(pred, target, theta_i_deg, theta_o_deg)
    if weight is None:
        return xp.mean(terms)
    return xp.mean(_per_sample(weight, pred) * terms) / xp.mean(weight)


def l1_loss(pred, target):
    """Mean absolute error over every element."""
    _check_pair(pred, target)
    xp = array_namespace(pred, target)
    return xp.mean(xp.abs(pred - target))


#: Domains of the NLB losses (:func:`nlb_loss`).
LOSS_DOMAINS = ("log_cosine", "linear")


def log_cosine(f, cos_theta_i):
    """``ln(1 + f cos θi)`` of RGB values ``[N, 3]`` with per-sample cosines ``[N]`` (clamped at 0)."""
    xp = array_namespace(f, cos_theta_i)
    return xp.log1p(f * xp.clip(cos_theta_i, 0.0, None)[:, None])


def check_loss_domain(domain: str, key: str = "loss_domain") -> str:
    """``domain`` if it is one of :data:`LOSS_DOMAINS`, else :class:`InputError` naming ``key``."""
    if domain not in LOSS_DOMAINS:
        raise InputError(f"unknown loss domain {domain!r}; expected one of {', '.join(LOSS_DOMAINS)}", key=key)
    return domain


def nlb_loss(pred, target, wi, domain: str):
    """L1 loss of RGB BRDF values ``[N, 3]`` in ``domain``: ``"log_cosine"`` (of ``ln(1 + f cos θi)``,
    ``cos θi = wi_z``) or ``"linear"`` (Fan et al. 2022's raw L1)."""
    if check_loss_domain(domain) == "linear":
        return l1_loss(pred, target)
    cos_i = wi[:, 2]
    return l1_loss(log_cosine(pred, cos_i), log_cosine(target, cos_i))
