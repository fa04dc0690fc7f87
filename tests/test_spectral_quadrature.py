"""The reduced spectrum → sRGB rule (render.spectral_quadrature) reproduces the full 31-wavelength
integral of docs/formats.md#spectral-to-linear-srgb: exactly for spectra in a small span, within its stated tolerance for a
model rendered through the plugin, and falls back to the full rule when spectra do not compress."""

import numpy as np
import onnxruntime
import pytest

import onnx_fixtures as fx
from neuralbrdf.data.colorimetry import XYZ_TO_LINEAR_SRGB, spectral_to_linear_srgb, xyz_weights
from neuralbrdf.render.spectral_quadrature import DEFAULT_RMS_TOLERANCE, MAX_TO_RMS, fit_reduced_quadrature

GRID = np.arange(400.0, 701.0, 10.0)
WEIGHTS = xyz_weights(GRID) @ XYZ_TO_LINEAR_SRGB.T
rng = np.random.default_rng(5)


def gaussian(centre, width):
    return np.exp(-0.5 * ((GRID - centre) / width) ** 2)


def test_spectra_in_a_three_dimensional_span_need_three_wavelengths():
    basis = np.stack([gaussian(450, 40), gaussian(550, 60), np.ones_like(GRID)])
    spectra = rng.uniform(0.0, 1.0, (500, 3)) @ basis
    rule = fit_reduced_quadrature(spectra, GRID, WEIGHTS)
    assert rule.size <= 3 and rule.rms_relative_error < 1e-9
    fresh = rng.uniform(0.0, 1.0, (50, 3)) @ basis
    nodes = [int(np.flatnonzero(GRID == w)[0]) for w in rule.wavelengths_nm]
    np.testing.assert_allclose(fresh[:, nodes] @ rule.weights, spectral_to_linear_srgb(fresh, GRID), rtol=1e-8, atol=1e-12)


def test_flat_spectra_need_one_wavelength_weighted_by_the_column_sums():
    spectra = rng.uniform(0.1, 2.0, (100, 1)) * np.ones_like(GRID)
    rule = fit_reduced_quadrature(spectra, GRID, WEIGHTS)
    assert rule.size == 1
    np.testing.assert_allclose(rule.weights[0], WEIGHTS.sum(axis=0), rtol=1e-9)


def test_white_noise_spectra_keep_almost_every_wavelength():
    spectra = rng.uniform(0.0, 1.0, (400, len(GRID)))
    rule = fit_reduced_quadrature(spectra, GRID, WEIGHTS)
    # Only the ends, where the colour matching functions vanish, can be dropped.
    assert rule.size >= 25 and rule.max_relative_error <= MAX_TO_RMS * DEFAULT_RMS_TOLERANCE


def test_incompressible_spectra_keep_the_full_rule():
    weights = rng.uniform(0.5, 1.0, (len(GRID), 3))  # every wavelength counts alike
    spectra = rng.uniform(0.0, 1.0, (400, len(GRID)))
    rule = fit_reduced_quadrature(spectra, GRID, weights)
    assert rule.size == len(GRID) and rule.max_relative_error == 0.0
    np.testing.assert_array_equal(rule.weights, weights)


def test_zero_tolerance_is_the_full_rule_and_looser_tolerances_need_fewer_wavelengths():
    basis = np.stack([gaussian(c, 50) for c in (420, 480, 540, 600, 660)])
    spectra = rng.uniform(0.0, 1.0, (600, 5)) @ basis
    full = fit_reduced_quadrature(spectra, GRID, WEIGHTS, rms_tolerance=0.0)
    assert full.size == len(GRID) and full.rms_relative_error == 0.0
    np.testing.assert_array_equal(full.weights, WEIGHTS)
    sizes = [fit_reduced_quadrature(spectra, GRID, WEIGHTS, rms_tolerance=t).size for t in (1e-6, 1e-3, 3e-2)]
    assert sizes[0] >= sizes[1] >= sizes[2] and sizes[2] < sizes[0]


@pytest.mark.parametrize(
    "spectra, weights, message",
    [
        (np.ones((10, 30)), WEIGHTS, "do not match"),
        (np.ones((10, 31)), WEIGHTS[:, :2], "do not match"),
        (np.full((10, 31), np.nan), WEIGHTS, "finite"),
        (np.ones((1, 31)), WEIGHTS, "two probe"),
    ],
)
def test_bad_arguments_are_refused(spectra, weights, message):
    with pytest.raises(ValueError, match=message):
        fit_reduced_quadrature(spectra, GRID, weights)


@pytest.mark.parametrize("tolerance", [-1e-3, 1.0])
def test_bad_tolerance_is_refused(tolerance):
    with pytest.raises(ValueError, match="rms_tolerance"):
        fit_reduced_quadrature(np.ones((4, 31)), GRID, WEIGHTS, rms_tolerance=tolerance)


@pytest.mark.parametrize("backend", ["drjit", "onnxruntime"])
@pytest.mark.parametrize("tolerance", [DEFAULT_RMS_TOLERANCE, 0.0])
def test_plugin_rule_reproduces_the_full_integral_on_fresh_directions(tmp_path, backend, tolerance):
    """The rule fitted at load agrees with the 31-wavelength integral away from its probe set;
    ``rgb_tolerance = 0`` is that integral to float32 rounding."""
    mi = pytest.importorskip("mitsuba")
    dr = pytest.importorskip("drjit")
    mi.set_variant("llvm_ad_rgb")
    from neuralbrdf.render import register

    register()
    path = fx.write_inplane_spectral(tmp_path / "inplane.onnx")
    bsdf = mi.load_dict(
        {"type": "neuralbrdf", "filename": str(path), "backend": backend, "rgb_tolerance": tolerance}
    )
    assert "of 31 wavelengths" in str(bsdf)
    assert bsdf.rgb_rule.size == 31 if tolerance == 0 else bsdf.rgb_rule.size < 31
    n = 2000
    wi = rng.normal(size=(n, 3))
    wo = rng.normal(size=(n, 3))
    for v in (wi, wo):
        v[:, 2] = np.abs(v[:, 2]) + 0.05
        v /= np.linalg.norm(v, axis=1, keepdims=True)
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(wi.T.astype(np.float32))
    with dr.scoped_set_flag(dr.JitFlag.SymbolicCalls, backend == "drjit"), dr.scoped_set_flag(
        dr.JitFlag.SymbolicLoops, backend == "drjit"
    ):
        value = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wo.T.astype(np.float32))).numpy().T
    value = value / wo[:, 2:3]
    session = onnxruntime.InferenceSession(str(path))
    feeds = {
        "wi": np.tile(wi, (len(GRID), 1)).astype(np.float32),
        "wo": np.tile(wo, (len(GRID), 1)).astype(np.float32),
        "wavelength": np.repeat(GRID, n).astype(np.float32),
    }
    spectra = session.run(None, feeds)[0].reshape(len(GRID), n).T
    exact = np.clip(spectral_to_linear_srgb(spectra.astype(np.float64), GRID), 0.0, None)
    scale = np.linalg.norm(exact, axis=1) + 1e-3 * np.linalg.norm(exact, axis=1).max()
    errors = np.linalg.norm(value - exact, axis=1) / scale
    if tolerance == 0:
        assert errors.max() < 1e-5
    else:
        assert np.sqrt(np.mean(errors**2)) < 3 * tolerance
        assert errors.max() < 3 * MAX_TO_RMS * tolerance
