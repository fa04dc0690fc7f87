"""GCMS radiance factors → absolute spectral BRDF (docs/formats.md#gcms-raw-measurement; report §2.1.1, Eq. 2.3).

The instrument reports a radiance factor ``beta`` relative to its own lamp and detector.  A
Munsell N9 white sheet, taken to reflect 79 % of a perfect reflecting diffuser (BRDF ``1/π``),
is measured at the same geometries, so per row and wavelength

    f = 0.79 / π · beta_sample / beta_munsell        (Eq. 2.3)

in sr⁻¹.  Rows are paired by geometry ``(theta_i, theta_r)`` (equal to 1e-6°), not by order.
Only 400–700 nm (31 bands) is kept; the reference must be strictly positive there on every row
a sample uses, and anything else is an :class:`~neuralbrdf.errors.InputError` naming the
reference file, line and wavelength.  Sensor noise on dark samples can make ``beta_sample``,
hence ``f``, slightly negative: values within the BRDF table's noise tolerance
(:func:`~neuralbrdf.data.table.negative_noise_tolerance`: ``max(1e-6 · max|f|, 1e-9)`` sr⁻¹ below
zero) are clipped to 0 with a warning giving their count; anything more negative is an error
naming the sample file, line and wavelength (a cell of −1000 is not sensor noise).
"""

from __future__ import annotations

import math

import numpy as np

from neuralbrdf.data.gcms import GCMS_HEADER, GCMS_WAVELENGTHS_NM, GcmsMeasurement, pair_keys
from neuralbrdf.data.csvio import CellProblem, first_flagged_cell
from neuralbrdf.data.table import BrdfTable, clip_negatives, negative_value_problem
from neuralbrdf.geometry import inplane_to_spherical

#: Reflectance of the Munsell N9 reference relative to a perfect diffuser (report §2.1.1).
MUNSELL_N9_REFLECTANCE = 0.79
#: Wavelengths (nm) kept after calibration: 400–700 at 10 nm, 31 bands.
CALIBRATED_WAVELENGTHS_NM = np.arange(400.0, 701.0, 10.0)


def _reference_rows(sample: GcmsMeasurement, reference: GcmsMeasurement) -> np.ndarray:
    """Index into ``reference`` of each sample row's geometry; a missing one is an error."""
    n_ref = reference.n_rows
    keys = np.concatenate(
        [pair_keys(reference.theta_i, reference.theta_r), pair_keys(sample.theta_i, sample.theta_r)]
    )
    _, pair_id = np.unique(keys, axis=0, return_inverse=True)
    pair_id = pair_id.reshape(-1)
    reference_row_of_pair = np.full(pair_id.max() + 1, -1)
    reference_row_of_pair[pair_id[:n_ref]] = np.arange(n_ref)
    rows = reference_row_of_pair[pair_id[n_ref:]]
    missing = np.flatnonzero(rows < 0)
    if missing.size:
        r = int(missing[0])
        raise CellProblem(
            r,
            None,
            f"geometry (theta_i, theta_r) = ({sample.theta_i[r]:g}, {sample.theta_r[r]:g}) has "
            f"no row in the reference {reference.source} ({missing.size} sample row(s) unmatched)",
        ).to_error(sample.source, sample.lines)
    return rows


def calibrate(sample: GcmsMeasurement, reference: GcmsMeasurement) -> BrdfTable:
    """Spectral BRDF (sr⁻¹, 400–700 nm) of ``sample`` calibrated by the Munsell ``reference``.

    Angles become spherical with :func:`neuralbrdf.geometry.inplane_to_spherical`; the rows keep
    the sample's order.
    """
    bands = np.isin(GCMS_WAVELENGTHS_NM, CALIBRATED_WAVELENGTHS_NM)
    band_names = [name for name, kept in zip(GCMS_HEADER[2:], bands) if kept]
    rows = _reference_rows(sample, reference)
    beta_reference = reference.beta[rows][:, bands]
    problem = first_flagged_cell(
        ~(beta_reference > 0),
        band_names,
        lambda r, k: f"Munsell reference beta must be positive, got {beta_reference[r, k]:g}",
    )
    if problem:
        raise CellProblem(int(rows[problem.row]), problem.column, problem.message).to_error(
            reference.source, reference.lines
        )
    brdf = MUNSELL_N9_REFLECTANCE / math.pi * sample.beta[:, bands] / beta_reference
    problem = negative_value_problem(
        brdf,
        band_names,
        lambda r, k: f"beta {sample.beta[r, bands][k]:g} calibrates to a negative BRDF of {brdf[r, k]:.4g} sr^-1,",
    )
    if problem:
        raise problem.to_error(sample.source, sample.lines)
    brdf = clip_negatives(brdf, sample.source, "calibrated BRDF value(s) (sensor noise, sr^-1)")
    angles = inplane_to_spherical(sample.theta_i, sample.theta_r)
    return BrdfTable(*angles, brdf, CALIBRATED_WAVELENGTHS_NM.copy(), source=sample.source)
