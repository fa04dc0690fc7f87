"""The ``neuralbrdf`` Mitsuba BSDF (docs/mitsuba-plugin.md): values against onnxruntime, sampling against its pdf
(``mitsuba.chi2``), colour handling in RGB and spectral variants, one onnxruntime run per
wavefront call, and small renders against each other and against Mitsuba's ``diffuse``."""

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import onnxruntime
import pytest
from onnx import TensorProto, helper
from scipy import integrate

import onnx_fixtures as fx
from neuralbrdf.data.colorimetry import spectral_to_linear_srgb
from neuralbrdf.render.drjit_onnx import DrJitGraph
from neuralbrdf.physics.microfacet import microfacet_brdf
from neuralbrdf.render import mitsuba_bsdf, register
from neuralbrdf.kinds.abc import AbcMetadata
from neuralbrdf.render.sampling import (
    GLOSSY_WEIGHT_RANGE,
    AbcLobe,
    GgxLobe,
    abc_reflection_pdf,
    fit_neural_mixture,
    ggx_reflection_pdf,
)

VARIANTS = ["llvm_ad_rgb", "llvm_ad_spectral"]
BACKENDS = ["drjit", "onnxruntime"]
ABC_CASES = {
    "C=1": AbcMetadata((0.1, 0.1, 0.1), (1.0, 1.0, 1.0), 50.0, 1.0, 1.5),
    "C<1": AbcMetadata((0.05, 0.05, 0.05), (1.0, 1.0, 1.0), 300.0, 0.6, 1.5),
    "C>1": AbcMetadata((0.3, 0.2, 0.1), (1.0, 1.0, 1.0), 20.0, 2.5, 1.5),
}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("mitsuba_bsdf")
    paths = {
        "ggx": fx.write_ggx_glossy(d / "ggx.onnx", alpha=0.3),
        "nlb_like": fx.write_nlb_like(d / "nlb.onnx"),
        "lambert": fx.write_lambert(d / "lambert.onnx", albedo=(0.8, 0.5, 0.2)),
        "spectral_lambert": fx.write_spectral_lambert(d / "slambert.onnx", wavelength_range=(450.0, 650.0)),
        "inplane": fx.write_inplane_spectral(d / "inplane.onnx"),
    }
    for name, params in ABC_CASES.items():
        paths[f"abc {name}"] = fx.write_abc_like(d / f"abc_{len(paths)}.onnx", params)
    return paths


@pytest.fixture(params=VARIANTS)
def variant(request):
    mi.set_variant(request.param)
    register()
    return request.param


@pytest.fixture
def wavefront():
    """Dr.Jit wavefront mode (needed by the onnxruntime backend), restored afterwards."""
    saved = dr.flag(dr.JitFlag.SymbolicLoops), dr.flag(dr.JitFlag.SymbolicCalls)
    dr.set_flag(dr.JitFlag.SymbolicLoops, False)
    dr.set_flag(dr.JitFlag.SymbolicCalls, False)
    yield
    dr.set_flag(dr.JitFlag.SymbolicLoops, saved[0])
    dr.set_flag(dr.JitFlag.SymbolicCalls, saved[1])


def load(path, backend="drjit"):
    return mi.load_dict({"type": "neuralbrdf", "filename": str(path), "backend": backend})


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_pairs(n, seed=5):
    """Unit directions, the first eight with ``wi`` or ``wo`` below the horizon."""
    rng = np.random.default_rng(seed)
    wi = unit(rng.normal(size=(n, 3)) * [1, 1, 0.5] + [0, 0, 0.6])
    wo = unit(rng.normal(size=(n, 3)) * [1, 1, 0.5] + [0, 0, 0.6])
    wi[:, 2] = np.abs(wi[:, 2])
    wo[:, 2] = np.abs(wo[:, 2])
    wi[:4, 2] *= -1
    wo[4:8, 2] *= -1
    return wi.astype(np.float32), wo.astype(np.float32)


def interaction(wi, wavelengths=None):
    si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
    si.wi = mi.Vector3f(wi.T)
    if mi.is_spectral:
        if wavelengths is None:
            wavelengths = np.tile([420.0, 510.0, 590.0, 680.0], (len(wi), 1))
        si.wavelengths = mi.Spectrum(np.asarray(wavelengths, dtype=np.float32).T)
    return si


def spectrum_rows(value) -> np.ndarray:
    return np.asarray(value.numpy()).T


# --------------------------------------------------------------------------- loading


def test_register_is_idempotent_and_checks_properties(variant, files):
    register()
    assert "NeuralBRDF[" in str(load(files["ggx"]))
    with pytest.raises(Exception, match="unreferenced property"):
        mi.load_dict({"type": "neuralbrdf", "filename": str(files["ggx"]), "albedo": 0.5})
    with pytest.raises(Exception, match="unknown backend 'torch'"):
        load(files["ggx"], backend="torch")
    with pytest.raises(Exception, match="needs a 'filename' property"):
        mi.load_dict({"type": "neuralbrdf"})
    with pytest.raises(Exception, match=r"rgb_tolerance must be in \[0, 1\)"):
        mi.load_dict({"type": "neuralbrdf", "filename": str(files["ggx"]), "rgb_tolerance": -0.1})


def test_bad_file_fails_at_scene_load_naming_it(variant, tmp_path):
    missing = tmp_path / "missing.onnx"
    with pytest.raises(Exception, match="no such ONNX model file") as info:
        load(missing)
    assert str(missing) in str(info.value)


def test_unsupported_operator_fails_the_drjit_backend_only(variant, tmp_path, wavefront):
    path = fx.save(fx.tiny_rgb_model(op="HardSigmoid"), tmp_path / "erf.onnx")
    with pytest.raises(Exception, match="unsupported ONNX operator 'HardSigmoid'"):
        load(path, "drjit")
    assert "onnxruntime" in str(load(path, "onnxruntime"))


def _large_model():
    rng = np.random.default_rng(0)
    sizes = [6, 400, 300, 3]
    nodes = [helper.make_node("Concat", ["wi", "wo"], ["x0"], axis=1)]
    weights = []
    for i, (k, m) in enumerate(zip(sizes[:-1], sizes[1:])):
        nodes.append(helper.make_node("MatMul", [f"x{i}", f"W{i}"], [f"y{i}"]))
        nodes.append(helper.make_node("Relu", [f"y{i}"], [f"x{i + 1}" if i < 2 else "f"]))
        weights.append(fx._const(f"W{i}", rng.normal(0, 0.1, (k, m))))
    model = helper.make_model(
        helper.make_graph(
            nodes,
            "large",
            [helper.make_tensor_value_info(n, TensorProto.FLOAT, ["N", 3]) for n in ("wi", "wo")],
            [helper.make_tensor_value_info("f", TensorProto.FLOAT, ["N", 3])],
            weights,
        ),
        opset_imports=[helper.make_opsetid("", fx.OPSET)],
    )
    return model


def test_drjit_backend_refuses_networks_above_its_budget_before_compiling(monkeypatch):
    """The size is counted from the weights, and refused, before any unrolling."""
    from types import SimpleNamespace

    from neuralbrdf.errors import InputError

    model = SimpleNamespace(proto=_large_model(), path="large.onnx")
    assert mitsuba_bsdf.matrix_multiply_adds(model.proto) == 6 * 400 + 400 * 300 + 300 * 3
    monkeypatch.setattr(mitsuba_bsdf.DrJitGraph, "from_model", lambda m: pytest.fail("compiled before the check"))
    monkeypatch.setattr(mitsuba_bsdf, "DRJIT_MAX_MULTIPLY_ADDS", 100_000)
    with pytest.raises(InputError, match="123300 multiply-adds .* budget of 100000 .* use backend 'onnxruntime'"):
        mitsuba_bsdf._DrJitBackend(model)


# --------------------------------------------------------------------------- values


@pytest.mark.parametrize("backend", BACKENDS)
def test_eval_is_f_cos_theta_o_and_eval_pdf_matches(files, backend, wavefront):
    mi.set_variant("llvm_ad_rgb")
    register()
    bsdf = load(files["nlb_like"], backend)
    wi, wo = random_pairs(256)
    si, ctx = interaction(wi), mi.BSDFContext()
    wo_dr = mi.Vector3f(wo.T)
    value = spectrum_rows(bsdf.eval(ctx, si, wo_dr))
    f = onnxruntime.InferenceSession(str(files["nlb_like"])).run(None, {"wi": wi, "wo": wo})[0]
    expected = f * np.clip(wo[:, 2:3], 0.0, None) * ((wi[:, 2:3] > 0) & (wo[:, 2:3] > 0))
    np.testing.assert_allclose(value, expected, rtol=1e-5, atol=1e-7)
    both = bsdf.eval_pdf(ctx, si, wo_dr)
    np.testing.assert_array_equal(spectrum_rows(both[0]), value)
    np.testing.assert_array_equal(both[1].numpy(), bsdf.pdf(ctx, si, wo_dr).numpy())
    assert np.all(both[1].numpy()[:8] == 0)


@pytest.mark.parametrize("backend", BACKENDS)
def test_sample_returns_eval_over_pdf(variant, files, backend, wavefront):
    bsdf = load(files["ggx"], backend)
    n = 512
    wi, _ = random_pairs(n)
    si, ctx = interaction(wi), mi.BSDFContext()
    rng = np.random.default_rng(2)
    bs, weight = bsdf.sample(ctx, si, mi.Float(rng.random(n)), mi.Point2f(rng.random((2, n))))
    value, pdf = bsdf.eval_pdf(ctx, si, bs.wo)
    valid = bs.pdf.numpy() > 0
    assert valid.sum() > 0.8 * n and not valid[:4].any()
    np.testing.assert_allclose(bs.pdf.numpy(), pdf.numpy(), rtol=1e-5)
    expected = spectrum_rows(value)[valid] / pdf.numpy()[valid, None]
    np.testing.assert_allclose(spectrum_rows(weight)[valid], expected, rtol=1e-4)
    assert np.all(spectrum_rows(weight)[~valid] == 0)


def test_spectral_model_is_evaluated_at_the_ray_wavelengths_clamped(files):
    mi.set_variant("llvm_ad_spectral")
    register()
    bsdf = load(files["spectral_lambert"])  # (0.2 + 0.6 (λ - 400) / 300) / π on 450..650 nm
    wi = np.array([[0.3, 0.0, 0.954]] * 2, dtype=np.float32)
    wavelengths = np.array([[380.0, 500.0, 600.0, 720.0], [450.0, 449.0, 651.0, 650.0]])
    wo = unit([[-0.5, 0.2, 0.8], [0.1, 0.0, 0.99]]).astype(np.float32)
    value = spectrum_rows(bsdf.eval(mi.BSDFContext(), interaction(wi, wavelengths), mi.Vector3f(wo.T)))
    clamped = np.clip(wavelengths, 450.0, 650.0)
    expected = (0.2 + 0.6 * (clamped - 400.0) / 300.0) / math.pi * wo[:, 2:3]
    np.testing.assert_allclose(value, expected, rtol=1e-5)


def test_spectral_model_in_rgb_variant_integrates_like_the_measurements(files):
    mi.set_variant("llvm_ad_rgb")
    register()
    bsdf = load(files["spectral_lambert"])
    wi = np.array([[0.0, 0.0, 1.0]], dtype=np.float32)
    value = spectrum_rows(bsdf.eval(mi.BSDFContext(), interaction(wi), mi.Vector3f(0, 0, 1)))[0]
    grid = np.arange(400.0, 701.0, 10.0)
    spectrum = (0.2 + 0.6 * (np.clip(grid, 450.0, 650.0) - 400.0) / 300.0) / math.pi
    np.testing.assert_allclose(value, np.clip(spectral_to_linear_srgb(spectrum, grid), 0, None), rtol=1e-4)


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_model_file_replaced_while_the_scene_loads_is_read_once(tmp_path, monkeypatch, backend, wavefront):
    """The file is swapped (atomically, spectral for RGB) right after the plugin read it: validation,
    proposal, sRGB rule and session all come from that one reading, so the BSDF is the spectral
    model throughout (reading the file again for the session or the proposal mixed the two)."""
    import os

    from neuralbrdf import kinds

    path = fx.write_spectral_lambert(tmp_path / "model.onnx", wavelength_range=(450.0, 650.0))
    replacement = fx.write_lambert(tmp_path / "replacement.onnx", albedo=(0.9, 0.1, 0.1))
    read = kinds.load_model

    def read_then_replace(source):
        model = read(source)
        if replacement.exists():
            os.replace(replacement, path)
        return model

    monkeypatch.setattr(kinds, "load_model", read_then_replace)
    mi.set_variant("llvm_ad_rgb")
    register()
    bsdf = load(path, backend)
    assert not replacement.exists() and bsdf.model.is_spectral
    wi = np.array([[0.0, 0.0, 1.0]], dtype=np.float32)
    value = spectrum_rows(bsdf.eval(mi.BSDFContext(), interaction(wi), mi.Vector3f(0, 0, 1)))[0]
    grid = np.arange(400.0, 701.0, 10.0)
    spectrum = (0.2 + 0.6 * (np.clip(grid, 450.0, 650.0) - 400.0) / 300.0) / math.pi
    np.testing.assert_allclose(value, np.clip(spectral_to_linear_srgb(spectrum, grid), 0, None), rtol=1e-4)
    assert "spectral 450-650 nm" in bsdf.to_string()


def test_flat_spectrum_renders_as_grey_in_rgb_variant(tmp_path):
    mi.set_variant("llvm_ad_rgb")
    register()
    bsdf = load(fx.write_spectral_lambert(tmp_path / "flat.onnx", a=0.5, b=0.0))
    wi = np.array([[0.0, 0.0, 1.0]], dtype=np.float32)
    value = spectrum_rows(bsdf.eval(mi.BSDFContext(), interaction(wi), mi.Vector3f(0, 0, 1)))[0]
    np.testing.assert_allclose(value, 0.5 / math.pi, rtol=0.02)


def test_rgb_upsampling_matches_mitsubas_scalar_model():
    mi.set_variant("llvm_ad_spectral")
    upsampler = mitsuba_bsdf._upsampler()
    rng = np.random.default_rng(4)
    colours = np.concatenate([rng.random((200, 3)), [[0.0, 0.4, 0.4], [1.0, 0.0, 0.5]]])
    ours = upsampler.coefficients(mi.Color3f(colours.T.astype(np.float32))).numpy().T
    reference = np.array([list(mi.srgb_model_fetch(mi.ScalarColor3f(*c))) for c in colours])
    np.testing.assert_allclose(ours, reference, rtol=2e-4, atol=1e-4 * np.abs(reference).max())
    # Exact greys: flat spectra of that value, as Mitsuba 3.9's closed form gives.
    wavelengths = mi.Spectrum(400.0, 500.0, 600.0, 700.0)
    for grey in (0.0, 1e-6, 0.3, 0.5, 0.999, 1.0):
        ours = mi.srgb_model_eval(mi.Array3f(upsampler.coefficients(mi.Color3f(grey))), wavelengths)
        mitsuba = mi.srgb_model_eval(mi.Array3f(mi.srgb_model_fetch(mi.ScalarColor3f(grey))), wavelengths)
        np.testing.assert_allclose(ours.numpy(), grey, rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(ours.numpy(), mitsuba.numpy(), rtol=1e-5, atol=1e-7)


def test_rgb_model_in_spectral_variant_follows_mitsubas_unbounded_upsampling(files):
    mi.set_variant("llvm_ad_spectral")
    register()
    bsdf = load(files["lambert"])  # albedo (0.8, 0.5, 0.2)
    wi = np.array([[0.0, 0.0, 1.0]], dtype=np.float32)
    wavelengths = np.array([[420.0, 510.0, 590.0, 680.0]])
    value = spectrum_rows(bsdf.eval(mi.BSDFContext(), interaction(wi, wavelengths), mi.Vector3f(0, 0, 1)))[0]
    rgb = np.array([0.8, 0.5, 0.2]) / math.pi
    scale = 2 * rgb.max()
    coeff = mi.srgb_model_fetch(mi.ScalarColor3f(*(rgb / scale)))
    expected = [mi.srgb_model_eval(mi.Array3f(coeff), mi.Spectrum(w)).numpy().ravel()[0] * scale for w in wavelengths[0]]
    np.testing.assert_allclose(value, expected, rtol=1e-4)


# --------------------------------------------------------------------------- onnxruntime calls


@pytest.fixture
def count_runs(monkeypatch):
    counts = {"runs": 0}
    original = onnxruntime.InferenceSession.run

    def counting_run(self, *args, **kwargs):
        counts["runs"] += 1
        return original(self, *args, **kwargs)

    monkeypatch.setattr(onnxruntime.InferenceSession, "run", counting_run)
    return counts


@pytest.mark.parametrize("model", ["nlb_like", "inplane"])
def test_one_onnxruntime_run_per_wavefront_call(variant, files, model, wavefront, count_runs):
    bsdf = load(files[model], "onnxruntime")
    wi, wo = random_pairs(1000)
    si, ctx, wo_dr = interaction(wi), mi.BSDFContext(), mi.Vector3f(wo.T)
    calls = [
        lambda: bsdf.eval(ctx, si, wo_dr),
        lambda: bsdf.eval_pdf(ctx, si, wo_dr),
        lambda: bsdf.sample(ctx, si, mi.Float(np.full(1000, 0.5)), mi.Point2f(0.3, 0.6)),
    ]
    runs_per_call = bsdf.backend.runs_per_call  # 2 for a spectral graph split at the wavelength
    assert runs_per_call == (2 if model == "inplane" else 1)
    for call in calls:
        before = count_runs["runs"]
        dr.eval(call())
        assert count_runs["runs"] == before + runs_per_call
    before = count_runs["runs"]
    bsdf.pdf(ctx, si, wo_dr)
    assert count_runs["runs"] == before


def test_render_runs_onnxruntime_once_per_bsdf_call(files, wavefront, count_runs, monkeypatch):
    mi.set_variant("llvm_ad_spectral")
    register()
    cls = mitsuba_bsdf._bsdf_class(mi.variant())
    calls = {"n": 0}
    for name in ("eval", "eval_pdf", "sample"):
        original = getattr(cls, name)

        def counted(self, *args, _original=original, **kwargs):
            calls["n"] += 1
            return _original(self, *args, **kwargs)

        monkeypatch.setattr(cls, name, counted)
    scene = mi.load_dict(sphere_scene({"type": "neuralbrdf", "filename": str(files["ggx"]), "backend": "onnxruntime"}, size=16, spp=4))
    before = count_runs["runs"]
    mi.render(scene)
    assert calls["n"] >= 2
    assert count_runs["runs"] - before == calls["n"]


def test_onnxruntime_backend_explains_symbolic_mode(files):
    mi.set_variant("llvm_ad_rgb")
    register()
    assert dr.flag(dr.JitFlag.SymbolicCalls)
    bsdf = load(files["ggx"], "onnxruntime")
    wi, wo = random_pairs(8)
    with pytest.raises(RuntimeError, match=r"dr.set_flag\(dr.JitFlag.SymbolicLoops, False\)"):
        bsdf.eval(mi.BSDFContext(), interaction(wi), mi.Vector3f(wo.T))


# --------------------------------------------------------------------------- sampling


def chi2_passes(path, theta_i_deg):
    wi = mi.ScalarVector3f(math.sin(math.radians(theta_i_deg)), 0.0, math.cos(math.radians(theta_i_deg)))
    sample_func, pdf_func = mi.chi2.BSDFAdapter("neuralbrdf", {"type": "neuralbrdf", "filename": str(path)}, wi=wi)
    test = mi.chi2.ChiSquareTest(
        domain=mi.chi2.SphericalDomain(),
        sample_func=sample_func,
        pdf_func=pdf_func,
        sample_dim=3,
        sample_count=400_000,
        res=61,
    )
    return test.run(0.01, quiet=True), test.messages


@pytest.mark.parametrize("theta_i", [10.0, 45.0, 75.0])
@pytest.mark.parametrize("model", ["ggx", *[f"abc {name}" for name in ABC_CASES]])
def test_chi2_sample_matches_pdf(files, model, theta_i):
    mi.set_variant("llvm_ad_rgb")
    register()
    passed, messages = chi2_passes(files[model], theta_i)
    assert passed, messages


@pytest.mark.parametrize(("B", "C"), [(50.0, 1.0), (50.0, 1.0 + 1e-10), (300.0, 0.6), (20.0, 2.5), (1e-6, 3.0), (1e-12, 3.0)])
def test_abc_normalisation_and_inverse_cdf(B, C):
    """Against quadrature of ``(1 + B x)^(-C)`` over ``x = 1 - cos θh`` (``dω_h = dx dφ``)."""
    mi.set_variant("llvm_ad_rgb")
    lobe = AbcLobe(B, C)
    density = lambda x: (1.0 + B * x) ** (-C)  # noqa: E731
    total = integrate.quad(density, 0.0, 1.0, epsabs=0, epsrel=1e-12)[0]
    assert lobe.normalization == pytest.approx(2 * math.pi * total, rel=1e-9)
    u = np.array([0.01, 0.2, 0.5, 0.9, 0.999])
    x = lobe._inverse_cdf(mi.Float(u)).numpy()
    cdf = [integrate.quad(density, 0.0, xi, epsabs=0, epsrel=1e-12)[0] / total for xi in x]
    np.testing.assert_allclose(cdf, u, rtol=2e-5, atol=1e-6)


#: ABC shapes from uniform to very sharp (Löw's nylon: B 3334, C 0.89; phenolic-like B up to 8e6).
ABC_SHAPES = [(0.0, 1.0), (1e-14, 2.0), (3.0, 1.0), (3.0, 1.0 + 1e-10), (3.0, 2.0), (50.0, 1.3), (3334.45, 0.886752),
              (1e6, 0.1), (1e6, 5.0), (8e6, 0.08)]


@pytest.mark.parametrize(("B", "C"), ABC_SHAPES)
def test_abc_normalisation_matches_quadrature_for_extreme_shapes(B, C):
    """``Z / 2π = ∫_0^1 (1 + B x)^(-C) dx``, by quadrature in ``t = ln(1 + B x)`` (resolves the peak)."""
    mi.set_variant("llvm_ad_rgb")
    if B == 0.0:
        integral = 1.0
    else:
        integral = integrate.quad(lambda t: math.exp((1.0 - C) * t) / B, 0.0, math.log1p(B), epsabs=0, epsrel=1e-12)[0]
    assert AbcLobe(B, C).normalization == pytest.approx(2 * math.pi * integral, rel=1e-9)


@pytest.mark.parametrize(("B", "C"), [(20.0, 1.5), (5.0, 1.0), (0.0, 3.0)])
def test_abc_half_vector_density_integrates_to_one_by_monte_carlo(B, C):
    rng = np.random.default_rng(6)
    v = rng.normal(size=(400_000, 3))
    h = v / np.linalg.norm(v, axis=1, keepdims=True)
    h[:, 2] = np.abs(h[:, 2])  # uniform on the upper hemisphere, density 1/2π
    estimate = AbcLobe(B, C).density(h[:, 0], h[:, 1], h[:, 2], np).mean() * 2 * math.pi
    assert estimate == pytest.approx(1.0, rel=1e-2)


def test_numpy_ggx_pdf_of_the_fit_matches_mitsubas_sampler_pdf():
    mi.set_variant("llvm_ad_rgb")
    wi, wo = random_pairs(300)
    ours = ggx_reflection_pdf(wi.astype(np.float64), wo.astype(np.float64), 0.25)
    mitsuba = GgxLobe(0.25).pdf(mi.Vector3f(wi.T), mi.Vector3f(wo.T)).numpy()
    np.testing.assert_allclose(ours, mitsuba, rtol=2e-4, atol=1e-6)


@pytest.mark.parametrize("alpha", [0.02, 0.05, 0.2])
def test_fit_recovers_the_roughness_of_a_sharp_ggx_lobe(alpha):
    def ggx(wi, wo):
        return microfacet_brdf(wi.astype(np.float64), wo.astype(np.float64), alpha, lambda c: 1.0 + 0.0 * c)

    mixture = fit_neural_mixture(ggx)
    assert mixture.lobe.alpha == pytest.approx(alpha, rel=0.15)
    assert min(mixture.glossy_weights) >= 0.85


def test_fit_of_a_lambertian_model_keeps_to_cosine_sampling():
    mixture = fit_neural_mixture(lambda wi, wo: np.full(len(wi), 0.25))
    assert all(w == GLOSSY_WEIGHT_RANGE[0] for w in mixture.glossy_weights)


@pytest.mark.parametrize(("model", "max_variance_ratio"), [("ggx", 0.2), ("abc C>1", 0.2), ("abc C=1", 1.0)])
def test_fitted_proposal_estimates_the_albedo_with_less_variance_than_cosine(files, model, max_variance_ratio):
    """Both estimators of ``∫ f cos θo dωo`` at θi = 45° agree (unbiased); the fitted one is less
    noisy, by far for compact lobes (heavy-tailed ABC lobes, C <= 1, gain less)."""
    mi.set_variant("llvm_ad_rgb")
    register()
    bsdf = load(files[model])
    n = 200_000
    wi = np.tile(unit([1.0, 0.0, 1.0]).astype(np.float32), (n, 1))
    si, ctx = interaction(wi), mi.BSDFContext()
    rng = np.random.default_rng(9)
    u = mi.Point2f(rng.random((2, n)))
    _, weight = bsdf.sample(ctx, si, mi.Float(rng.random(n)), u)
    fitted = spectrum_rows(weight).mean(axis=1)
    wo = mi.warp.square_to_cosine_hemisphere(u)
    cosine = spectrum_rows(bsdf.eval(ctx, si, wo)).mean(axis=1) * math.pi / np.maximum(wo.z.numpy(), 1e-12)
    error = 4 * math.sqrt(fitted.var() / n + cosine.var() / n)
    assert abs(fitted.mean() - cosine.mean()) < error
    assert fitted.var() < max_variance_ratio * cosine.var()


@pytest.mark.parametrize("name", list(ABC_CASES))
def test_numpy_abc_pdf_of_the_fit_matches_the_sampler_pdf(name):
    mi.set_variant("llvm_ad_rgb")
    params = ABC_CASES[name]
    lobe = AbcLobe(params.B, params.C)
    wi, wo = random_pairs(300)
    ours = abc_reflection_pdf(wi.astype(np.float64), wo.astype(np.float64), lobe)
    np.testing.assert_allclose(ours, lobe.pdf(mi.Vector3f(wi.T), mi.Vector3f(wo.T)).numpy(), rtol=2e-4, atol=1e-6)


# --------------------------------------------------------------------------- renders


def sphere_scene(bsdf, size=32, spp=16):
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 3},
        "sensor": {
            "type": "perspective",
            "fov": 35,
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": spp},
        },
        "sphere": {"type": "sphere", "bsdf": bsdf},
        "light": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
    }


def render(bsdf, seed=0, symbolic=True):
    saved = dr.flag(dr.JitFlag.SymbolicLoops), dr.flag(dr.JitFlag.SymbolicCalls)
    dr.set_flag(dr.JitFlag.SymbolicLoops, symbolic)
    dr.set_flag(dr.JitFlag.SymbolicCalls, symbolic)
    try:
        return np.array(mi.render(mi.load_dict(sphere_scene(bsdf)), seed=seed))
    finally:
        dr.set_flag(dr.JitFlag.SymbolicLoops, saved[0])
        dr.set_flag(dr.JitFlag.SymbolicCalls, saved[1])


@pytest.mark.parametrize("model", ["ggx", "inplane"])
def test_backends_render_alike(variant, files, model):
    """Same samples, same network: the images agree far inside the Monte Carlo noise."""
    bsdf = {"type": "neuralbrdf", "filename": str(files[model])}
    fused = render({**bsdf, "backend": "drjit"}, seed=3, symbolic=True)
    wavefront_image = render({**bsdf, "backend": "onnxruntime"}, seed=3, symbolic=False)
    assert np.all(np.isfinite(fused)) and fused.mean() > 0.05
    assert np.sqrt(np.mean((fused - wavefront_image) ** 2)) <= 1e-3 * fused.mean()


def test_lambertian_model_renders_like_mitsubas_diffuse(variant, files):
    albedo = [0.8, 0.5, 0.2]
    neural = render({"type": "neuralbrdf", "filename": str(files["lambert"])}, seed=1)
    diffuse_bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo}}
    diffuse = render(diffuse_bsdf, seed=1)
    noise = np.sqrt(np.mean((diffuse - render(diffuse_bsdf, seed=2)) ** 2))
    assert np.sqrt(np.mean((neural - diffuse) ** 2)) <= 1.5 * noise
    np.testing.assert_allclose(neural.mean(axis=(0, 1)), diffuse.mean(axis=(0, 1)), rtol=0.02)
    # A convex Lambertian sphere under unit sky radiance reflects exactly its albedo.
    centre = neural[10:22, 10:22].reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(centre, albedo, rtol=0.03)
