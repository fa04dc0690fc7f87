"""The ONNX contract (docs/formats.md#onnx-model-files): valid files load, every kind of broken file fails at load time
with an InputError that names the file and the problem."""

import math

import numpy as np
import torch
import onnx
import pytest
from onnx import TensorProto

import onnx_fixtures as fx
from neuralbrdf.errors import InputError
from neuralbrdf.kinds import contract_metadata, load_model
from neuralbrdf.kinds.abc import A_KEY as ABC_A_KEY
from neuralbrdf.kinds.abc import B_KEY as ABC_B_KEY
from neuralbrdf.kinds.abc import KD_KEY as ABC_KD_KEY
from neuralbrdf.kinds.abc import AbcMetadata
from neuralbrdf.onnx_contract import (
    FORMAT_VERSION,
    FORMAT_VERSION_KEY,
    KIND_KEY,
    MATERIAL_KEY,
    WAVELENGTH_MAX_KEY,
    probe_directions,
)

ABC = AbcMetadata(kd=(0.1, 0.2, 0.3), A=(1.0, 0.9, 0.8), B=40.0, C=1.5, eta=1.5)


def expect_error(path, *fragments):
    with pytest.raises(InputError) as info:
        load_model(path)
    message = str(info.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, message
    return message


# --------------------------------------------------------------------------- valid files


def test_valid_rgb_model_loads_with_its_metadata(tmp_path):
    path = fx.save(fx.tiny_rgb_model(fx.rgb_metadata("nlb", "brass")), tmp_path / "m.onnx")
    model = load_model(path)
    assert model.path == path
    assert (model.kind, model.material, model.is_spectral, model.n_channels) == ("nlb", "brass", False, 3)
    assert model.wavelength_range_nm is None and model.details is None
    assert model.provenance == "tests/onnx_fixtures.py"
    assert model.metadata[FORMAT_VERSION_KEY] == FORMAT_VERSION
    assert isinstance(model.proto, onnx.ModelProto)


def test_valid_spectral_model_loads_with_its_wavelength_range(tmp_path):
    path = fx.write_spectral_lambert(tmp_path / "s.onnx", wavelength_range=(410.0, 690.0))
    model = load_model(path)
    assert model.is_spectral and model.n_channels == 1
    assert model.kind == "spectral_mlp"
    assert model.wavelength_range_nm == (410.0, 690.0)


def test_abc_parameters_round_trip_through_metadata(tmp_path):
    path = fx.write_abc_like(tmp_path / "abc.onnx", ABC)
    model = load_model(path)
    assert model.kind == "abc"
    assert model.details == ABC


def test_torch_exports_with_symbolic_inner_dims_are_accepted(tmp_path):
    # torch declares f as [N, dynamic] for expand(N, 3); the trial evaluation checks it is 3.
    path = fx.write_lambert(tmp_path / "lambert.onnx")
    declared = onnx.load(str(path)).graph.output[0].type.tensor_type.shape.dim
    assert not declared[1].HasField("dim_value")
    assert load_model(path).n_channels == 3


def test_probe_directions_are_unit_and_mark_the_below_horizon_pairs():
    wi, wo, below = probe_directions(n_above=10, n_below=6)
    np.testing.assert_allclose(np.linalg.norm(wi, axis=1), 1.0, rtol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(wo, axis=1), 1.0, rtol=1e-6)
    assert below.sum() == 6
    assert np.all((wi[~below, 2] > 0) & (wo[~below, 2] > 0))
    assert np.all((wi[below, 2] < 0) | (wo[below, 2] < 0))


# --------------------------------------------------------------------------- broken files


def test_missing_file(tmp_path):
    expect_error(tmp_path / "absent.onnx", "no such ONNX model file")


def test_not_onnx(tmp_path):
    path = tmp_path / "notes.onnx"
    path.write_text("theta_i,theta_r\n1,2\n")
    expect_error(path, "not an ONNX model")


@pytest.mark.parametrize(
    ("changes", "fragment"),
    [
        ({"wi_name": "w_in"}, "graph inputs are ['w_in', 'wo']"),
        ({"input_dtype": TensorProto.DOUBLE}, "input 'wi' must be float32, found DOUBLE"),
        ({"wi_dims": ["N", 3, 1]}, "input 'wi' has rank 3, expected [N, 3]"),
        ({"wi_dims": ["N", 4]}, "input 'wi' has dimension 1 = 4, expected [N, 3]"),
        ({"wi_dims": [8, 3]}, "fixed batch size 8"),
        ({"output_name": "brdf"}, "graph outputs are ['brdf']; expected ['f'], optionally followed by fast paths"),
    ],
)
def test_wrong_interface(tmp_path, changes, fragment):
    path = fx.save(fx.tiny_rgb_model(**changes), tmp_path / "bad.onnx")
    expect_error(path, fragment)


def test_missing_metadata(tmp_path):
    path = fx.save(fx.tiny_rgb_model(metadata={}), tmp_path / "bare.onnx")
    message = expect_error(path, "missing metadata keys")
    for key in (KIND_KEY, FORMAT_VERSION_KEY, MATERIAL_KEY):
        assert key in message


@pytest.mark.parametrize(
    ("key", "value", "fragment"),
    [
        (KIND_KEY, "gan", "unknown model kind 'gan'"),
        (FORMAT_VERSION_KEY, "2", "format version '2' is not supported"),
        (MATERIAL_KEY, "  ", "material name is empty"),
    ],
)
def test_bad_metadata_value_names_the_key(tmp_path, key, value, fragment):
    metadata = {**fx.rgb_metadata(), key: value}
    path = fx.save(fx.tiny_rgb_model(metadata), tmp_path / "m.onnx")
    message = expect_error(path, fragment)
    assert key in message


def test_spectral_model_without_wavelength_range(tmp_path):
    path = fx.write_spectral_lambert(tmp_path / "s.onnx")
    model = onnx.load(str(path))
    kept = [p for p in model.metadata_props if p.key != WAVELENGTH_MAX_KEY]
    del model.metadata_props[:]
    model.metadata_props.extend(kept)
    expect_error(fx.save(model, path), "spectral model lacks metadata keys", WAVELENGTH_MAX_KEY)


def test_rgb_model_with_spectral_kind(tmp_path):
    metadata = {**fx.rgb_metadata(), KIND_KEY: "spectral_mlp"}
    path = fx.save(fx.tiny_rgb_model(metadata), tmp_path / "m.onnx")
    expect_error(path, "spectral_mlp model must take a 'wavelength' input")


@pytest.mark.parametrize(
    ("key", "value", "fragment"),
    [
        (ABC_KD_KEY, "[0.1, 0.2", "is not JSON"),
        (ABC_KD_KEY, "[0.1, 0.2]", "needs 3 values, found 2"),
        (ABC_A_KEY, "[1, -1, 1]", "must be finite and >= 0"),
        (ABC_B_KEY, "wide", "is not a number"),
        (ABC_B_KEY, "-3", "must be >= 0"),
    ],
)
def test_bad_abc_metadata(tmp_path, key, value, fragment):
    metadata = {**contract_metadata("abc", "m", "p", kind_metadata=ABC.entries()), key: value}
    path = fx.save(fx.tiny_rgb_model(metadata), tmp_path / "abc.onnx")
    message = expect_error(path, fragment)
    assert key in message


def test_abc_without_parameters(tmp_path):
    metadata = {**fx.rgb_metadata(), KIND_KEY: "abc"}
    path = fx.save(fx.tiny_rgb_model(metadata), tmp_path / "abc.onnx")
    expect_error(path, "ABC model lacks metadata keys", ABC_KD_KEY)


def test_a_kind_edited_away_from_its_own_metadata_is_refused(tmp_path):
    """A fitted ABC file whose kind is edited to 'reference' would pass as a ground truth; its own
    keys say what it is."""
    metadata = {**contract_metadata("abc", "m", "p", kind_metadata=ABC.entries()), KIND_KEY: "reference"}
    path = fx.save(fx.tiny_rgb_model(metadata), tmp_path / "edited.onnx")
    expect_error(path, f"metadata key {ABC_A_KEY!r} belongs to kind 'abc', but the file declares kind 'reference'")


def test_ladder_metadata_is_allowed_on_any_kind(tmp_path):
    metadata = {**fx.rgb_metadata("nlb", "brass"), "neuralbrdf.ladder.rung": "fast"}
    assert load_model(fx.save(fx.tiny_rgb_model(metadata), tmp_path / "rung.onnx")).kind == "nlb"


def test_nan_weights(tmp_path):
    weight = np.full((6, 3), 0.1, dtype=np.float32)
    weight[2, 1] = math.nan
    path = fx.save(fx.tiny_rgb_model(weight=weight), tmp_path / "nan.onnx")
    expect_error(path, "weight tensor 'W' holds 1 non-finite value")


def test_negative_output_is_refused(tmp_path):
    model = fx.tiny_rgb_model(weight=np.full((6, 3), -0.1, dtype=np.float32), op="Identity")
    expect_error(fx.save(model, tmp_path / "neg.onnx"), "output 'f' is negative")


def test_output_must_vanish_below_the_horizon(tmp_path):
    path = fx.save(fx.tiny_rgb_model(mask=False), tmp_path / "unmasked.onnx")
    expect_error(path, "not 0 when a direction is below the horizon")


def test_graph_onnxruntime_cannot_run(tmp_path):
    # A wrong inner dimension that only shows when the graph runs: W is [5, 3] for 6 inputs.
    path = fx.save(fx.tiny_rgb_model(weight=np.ones((5, 3))), tmp_path / "shape.onnx")
    expect_error(path, "onnxruntime")


def test_contract_metadata_refuses_what_load_model_refuses():
    with pytest.raises(InputError, match="unknown model kind"):
        contract_metadata("gan", "m", "p")
    with pytest.raises(InputError, match="spectral_mlp model must take a 'wavelength' input"):
        contract_metadata("spectral_mlp", "m", "p")
    with pytest.raises(InputError, match="ABC model lacks metadata keys"):
        contract_metadata("abc", "m", "p")
    with pytest.raises(InputError, match="start with 'neuralbrdf.nlb.'"):
        contract_metadata("nlb", "m", "p", kind_metadata=ABC.entries())
    with pytest.raises(InputError, match="wavelength range"):
        contract_metadata("spectral_mlp", "m", "p", wavelength_range_nm=(700.0, 400.0))


# --------------------------------------------------------------------------- damaged and hostile files


class _NegativeNearMirror(torch.nn.Module):
    """0.2 sr^-1 everywhere except within ~1° of the mirror direction, where it dips to -0.3."""

    def forward(self, wi, wo):
        mirror = torch.stack([-wi[:, 0], -wi[:, 1], wi[:, 2]], dim=1)
        cos = (mirror * wo).sum(dim=1, keepdim=True)
        f = 0.2 - 0.5 * torch.exp(-(1.0 - cos) * 2.0e4)
        above = (wi[:, 2:3] > 0) & (wo[:, 2:3] > 0)
        return torch.where(above, f, torch.zeros_like(f)).expand(-1, 3)


def test_the_old_80_direction_probe_misses_a_negative_mirror_spike_the_dense_probe_finds(tmp_path):
    """A model negative only near the mirror direction is refused at load."""
    import onnx_fixtures as fx
    import onnxruntime

    path = fx.export_module(_NegativeNearMirror(), tmp_path / "spike.onnx", fx.rgb_metadata("nlb"), spectral=False)
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    wi, wo, _ = probe_directions()
    assert session.run(["f"], {"wi": wi, "wo": wo})[0].min() >= 0  # the sparse probe sees nothing
    with pytest.raises(InputError, match=r"negative .*near the mirror direction"):
        load_model(path)


def test_dense_probe_covers_mirror_and_grazing_directions():
    from neuralbrdf.onnx_contract import dense_probe

    wi, wo, near_mirror = dense_probe()
    assert len(wi) > 10_000 and np.all(wi[:, 2] > 0) and np.all(wo[:, 2] > 0)
    np.testing.assert_allclose(np.linalg.norm(wi, axis=1), 1, atol=1e-6)
    mirror = wi * np.array([-1, -1, 1], dtype=np.float32)
    offset = np.degrees(np.arccos(np.clip((mirror * wo).sum(axis=1), -1, 1)))
    assert near_mirror.sum() > 3000 and offset[near_mirror].max() < 3.01 and np.sum(offset < 0.05) >= 90
    theta = np.degrees(np.arccos(np.minimum(wi[:, 2], wo[:, 2])))
    assert np.sum(theta > 85) > 1000


def test_external_weight_data_is_refused_before_it_is_read(tmp_path):
    """A file claiming GBs of external data is refused without reading them."""
    from onnx import TensorProto

    model = fx.tiny_rgb_model()
    weight = model.graph.initializer[0]
    weight.ClearField("raw_data")
    del weight.float_data[:]
    weight.data_location = TensorProto.EXTERNAL
    for key, value in (("location", "/dev/zero"), ("offset", "0"), ("length", str(8 * 2**30))):
        entry = weight.external_data.add()
        entry.key, entry.value = key, value
    path = tmp_path / "external.onnx"
    path.write_bytes(model.SerializeToString())
    with pytest.raises(InputError, match="external file .*'/dev/zero'.* self-contained"):
        load_model(path)


def test_declared_sizes_and_file_size_are_bounded(tmp_path, monkeypatch):
    from neuralbrdf.onnx_contract import model as contract_model, weights

    model = fx.tiny_rgb_model()
    path = tmp_path / "m.onnx"
    path.write_bytes(model.SerializeToString())
    monkeypatch.setattr(weights, "MAX_ONNX_WEIGHT_ELEMENTS", 4)
    with pytest.raises(InputError, match="declare more than 4 elements"):
        load_model(path)
    monkeypatch.setattr(contract_model, "MAX_ONNX_BYTES", 16)
    with pytest.raises(InputError, match="exceeds the limit"):
        load_model(path)


def test_a_constant_shape_creating_a_huge_tensor_is_refused_before_onnxruntime(tmp_path, monkeypatch):
    """A 1e10-element ``ConstantOfShape`` would be folded (allocated) by onnxruntime at session start."""
    from onnx import helper, numpy_helper

    from neuralbrdf.onnx_contract import model as contract_model

    model = fx.tiny_rgb_model()
    model.graph.initializer.append(numpy_helper.from_array(np.array([100_000, 100_000], dtype=np.int64), "big"))
    model.graph.node.append(helper.make_node("ConstantOfShape", ["big"], ["huge"], name="fill"))
    path = tmp_path / "huge.onnx"
    path.write_bytes(model.SerializeToString())
    monkeypatch.setattr(contract_model, "check_trial_evaluation", lambda *a: pytest.fail("ran the graph"))
    with pytest.raises(InputError, match="ConstantOfShape node 'fill' creates a tensor of 10000000000 elements"):
        load_model(path)


def test_a_name_that_is_not_utf8_is_an_input_error(tmp_path):
    """Found by tests/test_fuzz.py: one flipped bit in a node name made the ONNX checker raise
    UnicodeDecodeError (its message quotes the name) instead of a located InputError."""
    raw = bytearray(fx.tiny_rgb_model().SerializeToString())
    raw[9] ^= 1 << 7
    path = tmp_path / "flipped.onnx"
    path.write_bytes(bytes(raw))
    with pytest.raises(InputError, match="not UTF-8 text"):
        load_model(path)
