"""Error metrics of the report (S. Chitnis, *Simplifying BRDF Acquisition*; docs/evaluate.md#metrics).

**Relative RMSE (Eq. 4.3)**::

    L_rel-rmse = sqrt( (1/N) Σ_n ((f_pred,n - f_mea,n) / f_mea,n)² )

How this module reads it (report §4.1.3 and §5.1.2):

* ``n`` runs over the *glossy* samples only, ``|theta_i - theta_r| <= 10°``
  (:func:`neuralbrdf.data.plans.is_glossy`, signed in-plane angles).
* The RMSE is taken per channel (R, G, B or one wavelength) and the channel values are then
  averaged — "we average the error out over the three channels": the mean of per-channel RMSEs,
  not one RMSE over the pooled channel values.
* Per incident angle (Figs. 4.6, 4.7): the same, with ``n`` restricted to one ``theta_i``.
* Per wavelength (Fig. 5.3): "each datapoint is an average relative-rmse error across an
  incoming angle for several outgoing angles" — for every channel, one RMSE per incident angle
  over that angle's glossy samples; the box plot of a wavelength is the distribution of those
  values over the incident angles.
* **Floor.** Eq. 4.3 divides by ``f_mea``.  Entries (one sample of one channel) whose measured
  value is below ``floor`` (sr⁻¹, default :data:`DEFAULT_FLOOR` = 1e-4 sr⁻¹, a Lambertian
  albedo of 3e-4: below the diffuse level of the darkest MERL material, specular-black-phenolic
  at kd/π ≈ 4.5e-4 sr⁻¹, Löw et al.'s fit) are excluded and counted in
  ``n_excluded``; the report does not state its handling of such values.  A channel (or a
  channel of one incident angle) left with no entries has no RMSE: its value is NaN and it is
  left out of the channel average; if no entry at all survives, :class:`ValueError`.

**Hemisphere log-cosine RMSE** (docs/evaluate.md#metrics)::

    sqrt(mean((ln(1 + f cos ti) - ln(1 + f̂ cos ti))²))

over every sample and channel, e.g. of the Löw et al. set: how well an in-plane fit generalises
out of plane.

Inputs may be NumPy arrays or torch tensors (detached and converted to float64); values are
``[N]`` or ``[N, C]``, angles ``[N]`` in degrees.  Non-finite inputs raise :class:`ValueError`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from neuralbrdf.data.plans import is_glossy

#: Default floor (sr⁻¹) on the measured value below which Eq. 4.3 entries are excluded.
DEFAULT_FLOOR = 1e-4


def _as_float64(name: str, array) -> np.ndarray:
    if hasattr(array, "detach"):
        array = array.detach().cpu().numpy()
    array = np.asarray(array, dtype=np.float64)
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} holds non-finite values")
    return array


def _values_and_angles(pred, target, theta_i, theta_r=None):
    """``pred, target`` as ``[N, C]`` float64 and the angles as ``[N]``, all validated."""
    pred = _as_float64("pred", pred)
    target = _as_float64("target", target)
    if pred.shape != target.shape:
        raise ValueError(f"pred has shape {pred.shape} but target has {target.shape}")
    if pred.ndim not in (1, 2):
        raise ValueError(f"pred and target must be [N] or [N, C], got shape {pred.shape}")
    if pred.ndim == 1:
        pred, target = pred[:, None], target[:, None]
    angles = [_as_float64(name, a) for name, a in (("theta_i", theta_i), ("theta_r", theta_r)) if a is not None]
    for angle in angles:
        if angle.shape != (pred.shape[0],):
            raise ValueError(f"angles have shape {angle.shape}, expected ({pred.shape[0]},)")
    return pred, target, angles


@dataclass(frozen=True, eq=False)
class RelativeRmse:
    """Eq. 4.3 over the glossy region.

    Attributes
    ----------
    value:
        Mean over channels of ``per_channel`` (channels without entries left out).
    per_channel:
        ``[C]`` relative RMSE of each channel; NaN where every entry was excluded.
    n_used:
        Entries (sample × channel) that entered the RMSEs.
    n_excluded:
        Glossy entries excluded because ``f_mea < floor``.
    """

    value: float
    per_channel: np.ndarray
    n_used: int
    n_excluded: int


@dataclass(frozen=True, eq=False)
class RelativeRmseByThetaI:
    """Eq. 4.3 per incident angle, over each angle's glossy samples.

    Attributes
    ----------
    theta_i:
        ``[K]`` incident angles (degrees, sorted) that have glossy samples.
    value:
        ``[K]`` channel average of ``per_channel`` (NaN where a whole angle was excluded).
    per_channel:
        ``[K, C]`` relative RMSE per angle and channel; NaN where every entry was excluded.
    n_excluded:
        ``[K, C]`` entries excluded because ``f_mea < floor``.
    """

    theta_i: np.ndarray
    value: np.ndarray
    per_channel: np.ndarray
    n_excluded: np.ndarray


@dataclass(frozen=True, eq=False)
class RelativeRmseByChannel:
    """Eq. 4.3 per channel and incident angle, channel-major: the data of a per-wavelength box plot.

    Attributes
    ----------
    theta_i:
        ``[K]`` incident angles (degrees, sorted) that have glossy samples.
    per_theta_i:
        ``[C, K]``: row ``c`` holds one relative RMSE per incident angle (over that angle's
        glossy samples) for channel ``c``; NaN where every entry was excluded.
    n_excluded:
        ``[C, K]`` entries excluded because ``f_mea < floor``.
    """

    theta_i: np.ndarray
    per_theta_i: np.ndarray
    n_excluded: np.ndarray

    def boxes(self) -> list[np.ndarray]:
        """One array per channel of its per-angle values, NaN (fully excluded) entries dropped."""
        return [row[~np.isnan(row)] for row in self.per_theta_i]


def _rmse_over_rows(ratio_sq: np.ndarray, valid: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Per-channel RMSE ``[C]`` of the valid entries of ``rows``; NaN for a channel with none."""
    count = valid[rows].sum(axis=0)
    total = np.where(valid[rows], ratio_sq[rows], 0.0).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, np.sqrt(total / np.maximum(count, 1)), np.nan)


def _channel_mean(per_channel: np.ndarray) -> np.ndarray:
    """Mean over the last axis ignoring NaN; NaN (no warning) where every channel is NaN."""
    present = ~np.isnan(per_channel)
    count = present.sum(axis=-1)
    total = np.where(present, per_channel, 0.0).sum(axis=-1)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def _masked_ratios(pred, target, rows, floor):
    """``(valid, excluded, ratio_sq)`` ``[N, C]`` of Eq. 4.3 over the rows selected by ``rows`` ``[N]``."""
    if not floor > 0:
        raise ValueError(f"floor must be a positive BRDF value (sr⁻¹), got {floor}")
    valid = rows[:, None] & (target >= floor)
    excluded = rows[:, None] & ~valid
    safe_target = np.where(valid, target, 1.0)
    return valid, excluded, ((pred - target) / safe_target) ** 2


def _glossy_ratios(pred, target, theta_i, theta_r, floor):
    pred, target, (theta_i, theta_r) = _values_and_angles(pred, target, theta_i, theta_r)
    glossy = is_glossy(theta_i, theta_r)
    return (theta_i, glossy, *_masked_ratios(pred, target, glossy, floor))


def masked_relative_rmse(pred, target, rows, floor: float = DEFAULT_FLOOR, region: str = "selected") -> RelativeRmse:
    """Relative RMSE (Eq. 4.3) over the samples where ``rows`` (``[N]`` bool) holds, averaged over
    channels, entries below ``floor`` excluded and counted.  Raises :class:`ValueError` (naming
    ``region``) when no entry reaches the floor."""
    pred, target, _ = _values_and_angles(pred, target, None)
    rows = np.asarray(rows, dtype=bool)
    if rows.shape != (pred.shape[0],):
        raise ValueError(f"rows has shape {rows.shape}, expected ({pred.shape[0]},)")
    valid, excluded, ratio_sq = _masked_ratios(pred, target, rows, floor)
    if not valid.any():
        raise ValueError(
            f"no {region} sample with a measured value >= floor {floor:g} sr⁻¹ "
            f"({int(rows.sum())} {region} samples, {int(excluded.sum())} entries below the floor)"
        )
    per_channel = _rmse_over_rows(ratio_sq, valid, rows)
    return RelativeRmse(float(_channel_mean(per_channel)), per_channel, int(valid.sum()), int(excluded.sum()))


def relative_rmse(pred, target, theta_i, theta_r, floor: float = DEFAULT_FLOOR) -> RelativeRmse:
    """Relative RMSE (Eq. 4.3) over the glossy samples, averaged over channels.

    ``theta_i, theta_r`` are signed in-plane angles in degrees (only ``|theta_i - theta_r|``
    matters here, so :meth:`BrdfTable.inplane_angles
    <neuralbrdf.data.table.BrdfTable.inplane_angles>` will do).  Raises :class:`ValueError`
    when no glossy entry reaches the floor.
    """
    _, _, (theta_i, theta_r) = _values_and_angles(pred, target, theta_i, theta_r)
    return masked_relative_rmse(pred, target, is_glossy(theta_i, theta_r), floor, "glossy")


def relative_rmse_by_theta_i(pred, target, theta_i, theta_r, floor: float = DEFAULT_FLOOR) -> RelativeRmseByThetaI:
    """Relative RMSE (Eq. 4.3) per incident angle over its glossy samples (Figs. 4.6, 4.7).

    ``theta_i, theta_r`` are the signed in-plane angles as measured (e.g.
    :func:`neuralbrdf.data.plans.in_plane_plan`, or :meth:`BrdfTable.inplane_angles
    <neuralbrdf.data.table.BrdfTable.inplane_angles>` of an in-plane table, which decodes them
    exactly).
    """
    theta_i, glossy, valid, excluded, ratio_sq = _glossy_ratios(pred, target, theta_i, theta_r, floor)
    angles = np.unique(np.round(theta_i[glossy], 9))
    if angles.size == 0:
        raise ValueError("no glossy sample (|theta_i - theta_r| <= 10°)")
    group = np.round(theta_i, 9)
    per_channel = np.stack([_rmse_over_rows(ratio_sq, valid, glossy & (group == a)) for a in angles])
    n_excluded = np.stack([excluded[group == a].sum(axis=0) for a in angles])
    return RelativeRmseByThetaI(angles, _channel_mean(per_channel), per_channel, n_excluded)


def relative_rmse_by_channel(pred, target, theta_i, theta_r, floor: float = DEFAULT_FLOOR) -> RelativeRmseByChannel:
    """Per-wavelength (per-channel) view of :func:`relative_rmse_by_theta_i` (Fig. 5.3)."""
    by_angle = relative_rmse_by_theta_i(pred, target, theta_i, theta_r, floor)
    return RelativeRmseByChannel(by_angle.theta_i, by_angle.per_channel.T, by_angle.n_excluded.T)


def hemisphere_logcos_rmse(pred, target, theta_i_deg) -> float:
    """``sqrt(mean((ln(1 + f cos ti) - ln(1 + f̂ cos ti))²))`` over every sample and channel.

    ``theta_i_deg`` is the incident polar angle (a signed in-plane angle works too: the cosine
    is even).  BRDF values in sr⁻¹; a negative value with ``f cos ti <= -1`` raises.
    """
    pred, target, (theta_i,) = _values_and_angles(pred, target, theta_i_deg)
    cos_i = np.cos(np.deg2rad(theta_i))[:, None]
    if np.any(pred * cos_i <= -1.0) or np.any(target * cos_i <= -1.0):
        raise ValueError("f cos theta_i <= -1: the logarithm is undefined (negative BRDF values)")
    residual = np.log1p(cos_i * target) - np.log1p(cos_i * pred)
    return float(np.sqrt(np.mean(residual * residual)))


def _float64(values) -> np.ndarray:
    """A torch tensor (detached, on the CPU) or array-like as a float64 NumPy array."""
    if hasattr(values, "detach"):
        values = values.detach().cpu()
    return np.asarray(values, dtype=np.float64)


def glossy_relative_rmse_of_samples(samples, pred, floor: float = DEFAULT_FLOOR) -> dict[str, float]:
    """``rel_rmse_glossy``, ``rel_rmse_glossy_median`` and ``rel_rmse_excluded`` of flat samples.

    ``samples`` is a sequence whose first four entries are ``theta_i, theta_r`` (degrees),
    ``wavelength`` (nm) and the measured BRDF (sr⁻¹), one value per sample ``[N]``, with a
    ``pair_index`` attribute ``[N]`` (e.g. :class:`~neuralbrdf.lightning.measurement_data.SpectralSamples`);
    ``pred`` ``[N]`` the model's values.  Torch tensors or arrays.

    The samples (any order) are pivoted by ``pair_index`` and wavelength to a ``[direction
    pairs, wavelengths]`` table, the layout :func:`relative_rmse` expects; every pair must
    carry every wavelength.
    """
    theta_i, theta_r, wavelength, target = (_float64(column) for column in samples[:4])
    pairs, first, row = np.unique(_float64(samples.pair_index), return_index=True, return_inverse=True)
    wavelengths, column = np.unique(wavelength, return_inverse=True)
    shape = (len(pairs), len(wavelengths))
    if len(target) != shape[0] * shape[1]:
        raise ValueError(f"{len(target)} samples do not fill {shape[0]} direction pairs × {shape[1]} wavelengths")
    table_pred, table_target = np.full(shape, np.nan), np.full(shape, np.nan)
    table_pred[row, column] = _float64(pred)
    table_target[row, column] = target
    arguments = (table_pred, table_target, theta_i[first], theta_r[first], floor)
    overall = relative_rmse(*arguments)
    by_angle = relative_rmse_by_channel(*arguments)
    return {
        "rel_rmse_glossy": overall.value,
        "rel_rmse_glossy_median": float(np.nanmedian(by_angle.per_theta_i)),
        "rel_rmse_excluded": float(overall.n_excluded),
    }
