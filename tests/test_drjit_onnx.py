"""The Dr.Jit interpretation of ONNX graphs agrees with onnxruntime (docs/mitsuba-plugin.md: same file,
same results) and refuses, at construction, what it cannot map onto per-sample columns."""

import numpy as np
import onnx
import onnxruntime
import pytest
from drjit.llvm import Float
from onnx import TensorProto, helper

import onnx_fixtures as fx
from neuralbrdf.errors import InputError
from neuralbrdf.render.drjit_onnx import SUPPORTED_OPS, DrJitGraph, tanh
from neuralbrdf.kinds import load_model
from neuralbrdf.kinds.abc import AbcMetadata

N = 4096
rng = np.random.default_rng(11)


def random_directions(n, n_below):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2])
    v[:n_below, 2] *= -1.0
    return v.astype(np.float32)


WI = random_directions(N, 64)
WO = random_directions(N, 0)[::-1].copy()
WAVELENGTHS = rng.uniform(380.0, 720.0, N).astype(np.float32)


def run_both(path):
    """``(drjit, onnxruntime)`` outputs ``[N, C]`` of the model file on the shared inputs."""
    model = load_model(path)
    graph = DrJitGraph.from_model(model)
    feeds = {"wi": WI, "wo": WO}
    if model.is_spectral:
        feeds["wavelength"] = WAVELENGTHS
    reference = onnxruntime.InferenceSession(str(path)).run(None, feeds)[0].reshape(N, -1)
    columns = graph(
        [Float(WI[:, k]) for k in range(3)],
        [Float(WO[:, k]) for k in range(3)],
        Float(WAVELENGTHS) if model.is_spectral else None,
    )
    ours = np.stack(
        [np.full(N, c, np.float32) if isinstance(c, float) else c.numpy() for c in columns], axis=-1
    )
    return ours, reference, graph


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("drjit_onnx")
    return {
        "op_zoo": fx.save(fx.op_zoo_model(), d / "zoo.onnx"),
        "op_zoo_spectral": fx.save(fx.op_zoo_model(spectral=True), d / "zoo_spectral.onnx"),
        "nlb_like": fx.write_nlb_like(d / "nlb.onnx"),
        "inplane_spectral": fx.write_inplane_spectral(d / "inplane.onnx"),
        "lambert": fx.write_lambert(d / "lambert.onnx"),
        "spectral_lambert": fx.write_spectral_lambert(d / "spectral_lambert.onnx"),
        "ggx": fx.write_ggx_glossy(d / "ggx.onnx", alpha=0.15),
        "abc": fx.write_abc_like(d / "abc.onnx", AbcMetadata((0.1, 0.2, 0.3), (1.0, 0.8, 0.6), 60.0, 1.3, 1.5)),
        "table": fx.write_table(d / "table.onnx", spectral=False),
        "table_spectral": fx.write_table(d / "table_spectral.onnx", spectral=True),
    }


# Relative parity 1e-5, with an absolute floor of 1e-6 of the output's scale for values that
# come out of cancellation in the last layer (there float32 rounding is amplified in both).
@pytest.mark.parametrize(
    "name",
    ["op_zoo", "op_zoo_spectral", "nlb_like", "inplane_spectral", "lambert", "spectral_lambert", "table",
     "table_spectral"],
)
def test_parity_with_onnxruntime(files, name):
    ours, reference, _ = run_both(files[name])
    assert np.all(np.isfinite(ours))
    np.testing.assert_allclose(ours, reference, rtol=1e-5, atol=1e-6 * np.abs(reference).max())
    below = (WI[:, 2] <= 0) | (WO[:, 2] <= 0)
    assert np.all(ours[below] == 0)


@pytest.mark.parametrize("name", ["ggx", "abc"])
def test_parity_on_sharp_analytic_lobes(files, name):
    """Near the peak ``1 + B (1 - n·h)`` and GGX's ``cos²θh (α² - 1) + 1`` are ill-conditioned in
    ``h``: a 1-ulp difference in the normalised half vector moves ``f`` by ~1e-5, in either
    implementation; parity is checked at 1e-4 there."""
    ours, reference, _ = run_both(files[name])
    np.testing.assert_allclose(ours, reference, rtol=1e-4, atol=1e-6 * np.abs(reference).max())


def test_multiply_adds_count_the_unrolled_weights(files):
    graph = DrJitGraph.from_model(load_model(files["nlb_like"]))
    width, latent = 16, 4
    assert graph.multiply_adds == (6 + latent) * width + width * width + width * 3


def test_python_scalars_evaluate_like_one_row(files):
    model = load_model(files["inplane_spectral"])
    graph = DrJitGraph.from_model(model)
    value = graph(WI[100].tolist(), WO[100].tolist(), float(WAVELENGTHS[100]))[0]
    session = onnxruntime.InferenceSession(str(files["inplane_spectral"]))
    reference = session.run(None, {"wi": WI[100:101], "wo": WO[100:101], "wavelength": WAVELENGTHS[100:101]})
    assert value == pytest.approx(float(reference[0][0]), rel=1e-5)


@pytest.mark.parametrize("name", ["nlb_like", "op_zoo_spectral"])
def test_one_graph_serves_plain_and_ad_arrays_in_turn(files, name):
    """Weights and coefficients become literals of each array type once (drjit_onnx._affine): a graph
    called with AD, then plain, then AD columns again returns each call's own type (no literal of
    another type leaks in) and the same values."""
    from drjit.llvm.ad import Float as AdFloat

    model = load_model(files[name])
    graph = DrJitGraph.from_model(model)

    def call(array):
        wavelength = array(WAVELENGTHS) if model.is_spectral else None
        return graph([array(WI[:, k]) for k in range(3)], [array(WO[:, k]) for k in range(3)], wavelength)

    types = (AdFloat, Float, AdFloat)
    results = [call(array) for array in types]
    for columns, array in zip(results, types):
        assert all(isinstance(c, (float, array)) for c in columns)
        assert any(isinstance(c, array) for c in columns)
    for columns in results[1:]:
        for ours, first in zip(columns, results[0]):
            if not isinstance(first, float):
                np.testing.assert_array_equal(ours.numpy(), first.numpy())


# --------------------------------------------------------------------------- refusals


def graph_model(nodes, initializers=(), output_dims=("N", 3)) -> onnx.ModelProto:
    graph = helper.make_graph(
        nodes,
        "g",
        [
            helper.make_tensor_value_info("wi", TensorProto.FLOAT, ["N", 3]),
            helper.make_tensor_value_info("wo", TensorProto.FLOAT, ["N", 3]),
        ],
        [helper.make_tensor_value_info("f", TensorProto.FLOAT, list(output_dims))],
        list(initializers),
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", fx.OPSET)])


def expect_refusal(model, *fragments):
    with pytest.raises(InputError) as info:
        DrJitGraph(model, "model.onnx")
    message = str(info.value)
    assert message.startswith("model.onnx: ")
    for fragment in fragments:
        assert fragment in message, message


def test_unsupported_operator_is_named_with_its_node():
    assert "HardSigmoid" not in SUPPORTED_OPS
    expect_refusal(fx.tiny_rgb_model(op="HardSigmoid"), "unsupported ONNX operator 'HardSigmoid'", "node 'activation'")


def test_gather_along_the_batch_axis_is_refused():
    nodes = [
        helper.make_node("Gather", ["wi", "first"], ["row"], axis=0, name="row"),
        helper.make_node("Add", ["wo", "row"], ["f"], name="sum"),
    ]
    model = graph_model(nodes, [fx._const("first", [0], np.int64)])
    expect_refusal(model, "node 'row' (Gather)", "batch axis")


def test_concat_with_an_unexpanded_constant_is_refused():
    nodes = [helper.make_node("Concat", ["wi", "c"], ["f"], axis=0, name="cat")]
    model = graph_model(nodes, [fx._const("c", np.ones((1, 3)))])
    expect_refusal(model, "node 'cat' (Concat)", "Expand the constants first")


def test_arithmetic_on_the_batch_size_is_refused():
    nodes = [
        helper.make_node("Shape", ["wi"], ["shape"], name="shape"),
        helper.make_node("Mul", ["shape", "two"], ["doubled"], name="double"),
        helper.make_node("ConstantOfShape", ["doubled"], ["f"], name="zeros"),
    ]
    model = graph_model(nodes, [fx._const("two", [2, 1], np.int64)])
    expect_refusal(model, "node 'zeros' (ConstantOfShape)", "arithmetic on the batch size")


def test_wrong_output_shape_is_refused():
    nodes = [helper.make_node("Slice", ["wi", "s0", "s2", "ax1"], ["f"], name="xy")]
    inits = [fx._const("s0", [0], np.int64), fx._const("s2", [2], np.int64), fx._const("ax1", [1], np.int64)]
    expect_refusal(graph_model(nodes, inits), "output 'f' evaluates to per-sample shape [2]", "expected [3]")


def test_non_finite_trial_value_is_refused():
    nodes = [
        helper.make_node("Sub", ["wi", "wi"], ["zero"], name="zero"),
        helper.make_node("Log", ["zero"], ["f"], name="log"),
    ]
    expect_refusal(graph_model(nodes), "expected finite BRDF values")


def test_rational_tanh_matches_tanh_and_onnxruntime():
    """The kernel's tanh is within a few float32 ulp of tanh and equals onnxruntime's Tanh."""
    x = np.concatenate([np.linspace(-12.0, 12.0, 400_001), [0.0, 1e-30, -1e-8, 8.99, 9.0, 50.0]])
    x = x.astype(np.float32)
    ours = tanh(Float(x)).numpy().astype(np.float64)
    exact = np.tanh(x.astype(np.float64))
    assert np.max(np.abs(ours - exact)) < 5e-7
    tiny = np.abs(x) < 1e-3
    assert np.max(np.abs(ours[tiny] - exact[tiny]) / np.maximum(np.abs(exact[tiny]), 1e-38)) < 5e-7
    graph = helper.make_graph(
        [helper.make_node("Tanh", ["x"], ["y"])],
        "tanh",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [None])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [None])],
    )
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    (reference,) = onnxruntime.InferenceSession(proto.SerializeToString()).run(None, {"x": x})
    assert np.max(np.abs(ours - reference)) < 2e-7
