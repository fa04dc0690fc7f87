"""The recorded program of a graph (``neuralbrdf.render.drjit_program``) issues exactly the column
operations the interpreter issues: same values, bit for bit, without interpreting the graph again."""

import drjit as dr
import numpy as np
import pytest
from drjit.llvm import Float

import onnx_fixtures as fx
from neuralbrdf.render.drjit_onnx import DrJitGraph
from neuralbrdf.render.drjit_program import Recording, Register, apply
from neuralbrdf.kinds import load_model

rng = np.random.default_rng(5)
N = 512


def columns(values: np.ndarray) -> list:
    return [Float(values[:, k]) for k in range(values.shape[1])]


def directions(n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    return (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)


WI, WO = directions(N), directions(N)
WAVELENGTHS = rng.uniform(380.0, 720.0, N).astype(np.float32)


def test_apply_calls_through_on_values_and_records_on_registers():
    assert apply(dr.fma, 2.0, 3.0, 1.0) == 7.0
    recording = Recording()
    x, y = recording.new_register(), recording.new_register()
    product = apply(dr.fma, x, 3.0, y)
    assert type(product) is Register and len(recording.instructions) == 1
    unused = apply(dr.sqrt, x)  # noqa: F841 - dropped by compile: no output depends on it
    total = apply(lambda a, b: a + b, product, 0.5)
    program = recording.compile([x, y], [total, 1.25])
    assert program.instruction_count == 2
    a, b = Float(1.0, 2.0, -4.0), Float(0.5, 0.25, 8.0)
    got, constant = program(a, b)
    np.testing.assert_array_equal(got.numpy(), (dr.fma(a, 3.0, b) + 0.5).numpy())
    assert constant == 1.25
    assert program(2.0, 1.0) == [7.5, 1.25]  # Python floats run through the same operations


@pytest.fixture(scope="module")
def graphs(tmp_path_factory):
    d = tmp_path_factory.mktemp("drjit_program")
    paths = {
        "op_zoo": fx.save(fx.op_zoo_model(), d / "zoo.onnx"),
        "op_zoo_spectral": fx.save(fx.op_zoo_model(spectral=True), d / "zoo_spectral.onnx"),
        "nlb_like": fx.write_nlb_like(d / "nlb.onnx"),
        "inplane_spectral": fx.write_inplane_spectral(d / "inplane.onnx"),
    }
    return {name: DrJitGraph.from_model(load_model(path)) for name, path in paths.items()}


def interpreted(graph: DrJitGraph, wi, wo, wavelength):
    inputs = {"wi": wi, "wo": wo}
    if wavelength is not None:
        inputs["wavelength"] = wavelength
    return graph._run(inputs)


def as_numpy(column) -> np.ndarray:
    return np.full(N, column, np.float32) if isinstance(column, float) else column.numpy()


@pytest.mark.parametrize(
    "name, wavelength_kind",
    [
        ("op_zoo", None),
        ("nlb_like", None),
        ("op_zoo_spectral", "array"),
        ("op_zoo_spectral", "python float"),  # the sRGB rule's nodes in RGB variants
        ("inplane_spectral", "array"),
        ("inplane_spectral", "python float"),
    ],
)
def test_replay_equals_the_interpreter_bit_for_bit(graphs, name, wavelength_kind):
    graph = graphs[name]
    wavelength = {None: None, "array": Float(WAVELENGTHS), "python float": 561.5}[wavelength_kind]
    replayed = graph(columns(WI), columns(WO), wavelength)
    reference = interpreted(graph, columns(WI), columns(WO), wavelength)
    assert len(replayed) == len(reference)
    for ours, theirs in zip(replayed, reference):
        np.testing.assert_array_equal(as_numpy(ours), as_numpy(theirs))


def test_a_call_does_not_interpret_the_graph_again(graphs, monkeypatch):
    graph = graphs["inplane_spectral"]

    def interpret(*args, **kwargs):
        raise AssertionError("the graph was interpreted again")

    monkeypatch.setattr(graph, "_run", interpret)
    (f,) = graph(columns(WI), columns(WO), Float(WAVELENGTHS))
    assert np.all(np.isfinite(f.numpy()))


def test_a_varying_input_copies_only_the_instructions_that_depend_on_it():
    recording = Recording()
    x, w = recording.new_register(), recording.new_register()
    shared = apply(dr.fma, x, 2.0, 1.0)  # depends on x only: issued once
    out = apply(lambda a, b: a * b + 0.5, shared, w)
    program = recording.compile([x, w], [out, shared], varying=w, copies=3)
    assert program.instruction_count == 1 + 3
    a = Float(1.0, 2.0, -4.0)
    ws = [Float(0.5, 1.0, 2.0), 3.0, Float(-1.0, 0.0, 1.0)]
    got = program(a, *ws)
    assert len(got) == 6  # (out, shared) of each copy
    for k, w_k in enumerate(ws):
        np.testing.assert_array_equal(as_array(got[2 * k]), as_array(dr.fma(a, 2.0, 1.0) * w_k + 0.5))
        assert got[2 * k + 1] is got[1]  # the same column, not a copy


def as_array(column) -> np.ndarray:
    return column.numpy() if hasattr(column, "numpy") else np.asarray(column)


@pytest.mark.parametrize("name", ["op_zoo_spectral", "inplane_spectral"])
def test_several_wavelengths_in_one_call_equal_one_call_each_bit_for_bit(graphs, name):
    graph = graphs[name]
    wavelengths = [Float(WAVELENGTHS), Float(WAVELENGTHS[::-1].copy()), 561.5, Float(WAVELENGTHS + 3.0)]
    together = graph.at_wavelengths(columns(WI), columns(WO), wavelengths)
    assert len(together) == len(wavelengths)
    for got, wavelength in zip(together, wavelengths):
        (expected,) = graph(columns(WI), columns(WO), wavelength)
        np.testing.assert_array_equal(as_numpy(got), as_numpy(expected))
    with pytest.raises(ValueError, match="RGB model"):
        graphs["nlb_like"].at_wavelengths(columns(WI), columns(WO), [550.0])
