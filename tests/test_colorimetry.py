"""Spectral → XYZ → linear sRGB (docs/formats.md#spectral-to-linear-srgb, report Eq. 2.4), checked against colour-science."""

import colour
import numpy as np
import pytest
import torch

from neuralbrdf.data import colorimetry
from neuralbrdf.errors import InputError

GRID_400_700 = np.arange(400.0, 701.0, 10.0)
CHECKER = colour.SDS_COLOURCHECKERS["BabelColor Average"]

# colour-science narrates its own reshaping in the reference pipeline.
pytestmark = pytest.mark.filterwarnings("ignore::colour.utilities.ColourRuntimeWarning")


def _colour_reference_rgb(sd, shape):
    """colour-science's own pipeline: Integration XYZ (reflectance scale 100) → linear sRGB."""
    xyz = colour.sd_to_XYZ(
        sd,
        colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"],
        colour.SDS_ILLUMINANTS["D65"],
        method="Integration",
        shape=shape,
    ) / 100.0
    rgb = colour.XYZ_to_RGB(xyz, "sRGB", chromatic_adaptation_transform=None, apply_cctf_encoding=False)
    return xyz, rgb


@pytest.mark.parametrize("c", [0.0, 0.05, 1.0 / np.pi, 3.7])
def test_flat_spectrum_has_y_equal_c_and_maps_to_grey(c):
    values = np.full((2, GRID_400_700.size), c)
    xyz = colorimetry.spectral_to_xyz(values, GRID_400_700)
    np.testing.assert_allclose(xyz[:, 1], c, rtol=1e-12, atol=1e-15)
    rgb = colorimetry.spectral_to_linear_srgb(values, GRID_400_700)
    np.testing.assert_allclose(rgb, c, rtol=0.01, atol=1e-15)


def test_flat_spectrum_has_the_d65_chromaticity():
    xyz = colorimetry.spectral_to_xyz(np.ones(GRID_400_700.size), GRID_400_700)
    xy = xyz[:2] / xyz.sum()
    d65 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    np.testing.assert_allclose(xy, d65, atol=2e-3)


PATCHES = ["dark skin", "blue sky", "foliage", "orange", "cyan", "magenta", "neutral 5 (.70 D)"]


@pytest.mark.parametrize("patch", PATCHES)
def test_colourchecker_patch_matches_colour_pipeline(patch):
    shape = colour.SpectralShape(400, 700, 10)
    sd = CHECKER[patch].copy().trim(shape)
    reflectance = sd[GRID_400_700]
    xyz_ref, rgb_ref = _colour_reference_rgb(sd, shape)
    np.testing.assert_allclose(colorimetry.spectral_to_xyz(reflectance, GRID_400_700), xyz_ref, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(
        colorimetry.spectral_to_linear_srgb(reflectance, GRID_400_700), rgb_ref, rtol=1e-6, atol=1e-9
    )


def test_other_regular_grid_matches_colour_pipeline():
    shape = colour.SpectralShape(380, 780, 5)
    sd = CHECKER["yellow green"].copy().align(shape)
    _, rgb_ref = _colour_reference_rgb(sd, shape)
    rgb = colorimetry.spectral_to_linear_srgb(sd.values, shape.wavelengths)
    np.testing.assert_allclose(rgb, rgb_ref, rtol=1e-6, atol=1e-9)


def test_xyz_to_srgb_is_the_iec_matrix():
    xyz = np.array([[0.2, 0.3, 0.4], [0.9505, 1.0, 1.089]])
    expected = colour.XYZ_to_RGB(xyz, "sRGB", chromatic_adaptation_transform=None, apply_cctf_encoding=False)
    np.testing.assert_allclose(colorimetry.xyz_to_linear_srgb(xyz), expected, rtol=1e-12)
    # IEC 61966-2-1 first row, as published.
    np.testing.assert_allclose(colorimetry.XYZ_TO_LINEAR_SRGB[0], [3.2406, -1.5372, -0.4986], atol=1e-4)


def test_torch_batch_matches_numpy_and_keeps_gradient():
    rng = np.random.default_rng(0)
    values = rng.uniform(0, 1, size=(4, 5, GRID_400_700.size))
    expected = colorimetry.spectral_to_linear_srgb(values, GRID_400_700)
    tensor = torch.tensor(values, requires_grad=True)
    rgb = colorimetry.spectral_to_linear_srgb(tensor, GRID_400_700)
    assert rgb.shape == (4, 5, 3)
    np.testing.assert_allclose(rgb.detach().numpy(), expected, rtol=1e-12)
    rgb[..., 1].sum().backward()
    assert torch.all(torch.isfinite(tensor.grad)) and tensor.grad.abs().sum() > 0


def test_weights_are_cached_and_read_only():
    weights = colorimetry.xyz_weights(GRID_400_700)
    assert colorimetry.xyz_weights(GRID_400_700.copy()) is weights
    with pytest.raises(ValueError):
        weights[0, 0] = 1.0


@pytest.mark.parametrize(
    "wavelengths, match",
    [
        (np.array([400.0, 410.0, 430.0, 440.0]), "regular"),
        (np.array([400.0, 420.0, 410.0]), "increase"),
        (np.array([400.0, 400.0, 410.0]), "duplicated"),
        (np.arange(300.0, 401.0, 10.0), "360"),
        (np.arange(800.0, 901.0, 10.0), "830"),
        (np.array([550.0]), "two wavelengths"),
        (np.array([400.0, np.nan]), "finite"),
    ],
)
def test_bad_grids_are_input_errors(wavelengths, match):
    with pytest.raises(InputError, match=match):
        colorimetry.spectral_to_xyz(np.ones(wavelengths.size), wavelengths)


def test_band_count_mismatch_is_input_error():
    with pytest.raises(InputError, match="30 bands but 31 wavelengths"):
        colorimetry.spectral_to_linear_srgb(np.ones((2, 30)), GRID_400_700)
