"""A spectral graph split at the wavelength (``neuralbrdf.render.onnx_split``) evaluates exactly
like the whole graph, and graphs it cannot split are left whole."""

import numpy as np
import onnx
import onnxruntime
import pytest
from onnx import TensorProto, helper

import onnx_fixtures as fx
from neuralbrdf.render.onnx_split import split_at_wavelength

rng = np.random.default_rng(7)


def directions(n, n_below=0):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2])
    v[:n_below, 2] *= -1.0
    return v.astype(np.float32)


def session(model: onnx.ModelProto):
    return onnxruntime.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])


@pytest.fixture(scope="module")
def spectral_models(tmp_path_factory):
    d = tmp_path_factory.mktemp("split")
    return {
        "inplane_spectral": onnx.load(fx.write_inplane_spectral(d / "inplane.onnx")),
        "op_zoo_spectral": fx.op_zoo_model(spectral=True),
    }


@pytest.mark.parametrize("name", ["inplane_spectral", "op_zoo_spectral"])
def test_the_parts_evaluate_like_the_whole_graph(spectral_models, name):
    proto = spectral_models[name]
    split = split_at_wavelength(proto)
    assert split is not None and split.cut
    n, k = 500, 3
    wi, wo = directions(n, n_below=20), directions(n)
    nm = rng.uniform(380.0, 720.0, (k, n)).astype(np.float32)  # per-lane wavelengths, stacked
    (expected,) = session(proto).run(
        ["f"], {"wi": np.tile(wi, (k, 1)), "wo": np.tile(wo, (k, 1)), "wavelength": nm.reshape(-1)}
    )
    cut = session(split.directions).run(list(split.cut), {"wi": wi, "wo": wo})
    feeds = {name: split.repeat(values, k) for name, values in zip(split.cut, cut)}
    (got,) = session(split.wavelengths).run(["f"], {**feeds, "wavelength": nm.reshape(-1)})
    np.testing.assert_array_equal(got, expected)
    # the direction part holds no wavelength node, the wavelength part no direction input
    assert "wavelength" not in {i.name for i in split.directions.graph.input}
    assert {i.name for i in split.wavelengths.graph.input} == {*split.cut, "wavelength"}


def test_agrees_detects_parts_that_differ(spectral_models):
    proto = spectral_models["inplane_spectral"]
    split = split_at_wavelength(proto)
    whole, directions_part = session(proto), session(split.directions)
    wi, wo, nm = directions(64), directions(64), np.array([450.0, 600.0])
    assert split.agrees(whole, directions_part, session(split.wavelengths), wi, wo, nm)
    wrong = onnx.ModelProto()
    wrong.CopyFrom(split.wavelengths)  # f scaled by 1 + 1e-6
    for node in wrong.graph.node:
        node.output[:] = ["f_exact" if o == "f" else o for o in node.output]
    wrong.graph.initializer.append(fx._const("scale", 1.000001))
    wrong.graph.node.append(helper.make_node("Mul", ["f_exact", "scale"], ["f"]))
    assert not split.agrees(whole, directions_part, session(wrong), wi, wo, nm)


def spectral_graph(nodes, initializers=()):
    graph = helper.make_graph(
        nodes,
        "g",
        [
            helper.make_tensor_value_info("wi", TensorProto.FLOAT, ["N", 3]),
            helper.make_tensor_value_info("wo", TensorProto.FLOAT, ["N", 3]),
            helper.make_tensor_value_info("wavelength", TensorProto.FLOAT, ["N"]),
        ],
        [helper.make_tensor_value_info("f", TensorProto.FLOAT, ["N"])],
        list(initializers),
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", fx.OPSET)])


def test_graphs_that_do_not_split_are_left_whole(tmp_path):
    assert split_at_wavelength(fx.op_zoo_model()) is None  # RGB: no wavelength
    z = fx._const("z", 2, np.int64)
    no_wavelength = spectral_graph([helper.make_node("Gather", ["wi", "z"], ["f"], axis=1)], [z])
    assert split_at_wavelength(no_wavelength) is None  # f does not depend on it
    shape_cut = spectral_graph(
        [
            helper.make_node("Shape", ["wi"], ["shape"]),
            helper.make_node("Unsqueeze", ["wavelength", "axis"], ["column"]),
            helper.make_node("Expand", ["column", "shape"], ["wide"]),  # reads the shape of wi
            helper.make_node("ReduceSum", ["wide", "axis"], ["f"], keepdims=0),
        ],
        [fx._const("axis", [1], np.int64)],
    )
    assert split_at_wavelength(shape_cut) is None  # the cut would be a shape, not per-sample rows
    reads_wi = spectral_graph(
        [
            helper.make_node("Unsqueeze", ["wavelength", "axis"], ["column"]),
            helper.make_node("Mul", ["wi", "column"], ["scaled"]),  # a wavelength node reading wi
            helper.make_node("ReduceSum", ["scaled", "axis"], ["f"], keepdims=0),
        ],
        [fx._const("axis", [1], np.int64)],
    )
    assert split_at_wavelength(reads_wi) is None


def test_every_direction_result_a_wavelength_node_reads_is_cut():
    z = fx._const("z", 2, np.int64)
    proto = spectral_graph(
        [
            helper.make_node("Gather", ["wi", "z"], ["wiz"], axis=1),
            helper.make_node("Gather", ["wo", "z"], ["woz"], axis=1),
            helper.make_node("Mul", ["wiz", "woz"], ["cos"]),
            helper.make_node("Concat", ["wi", "wo"], ["both"], axis=1),
            helper.make_node("ReduceSum", ["both", "axis"], ["s"], keepdims=0),
            helper.make_node("Mul", ["s", "wavelength"], ["sw"]),
            helper.make_node("Mul", ["sw", "cos"], ["f"]),
        ],
        [z, fx._const("axis", [1], np.int64)],
    )
    split = split_at_wavelength(proto)
    assert split is not None and set(split.cut) == {"s", "cos"}
    wi, wo, nm = directions(32), directions(32), np.array([400.0, 550.0, 700.0])
    assert split.agrees(session(proto), session(split.directions), session(split.wavelengths), wi, wo, nm)
