"""Export to the ONNX contract (docs/formats.md#onnx-model-files): the direction-space models of
``neuralbrdf.models.directional`` against independent computations, and ``neuralbrdf export`` (``export/to_onnx.py``) —
PyTorch = onnxruntime = Dr.Jit on every kind's file, ``load_model`` accepts it, a graph that does
not reproduce PyTorch is never written, bad checkpoints exit 2 with one line."""

import math
import subprocess
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np
import onnx
import onnxruntime
import pytest
import pytorch_lightning as pl
import torch
from drjit.llvm import Float

from neuralbrdf.geometry import half_diff_angles, inplane_to_vectors
from neuralbrdf.lightning.spectral_mlp_module import SpectralMlpModule
from neuralbrdf.physics.abc import AbcParameters, abc_brdf
from neuralbrdf.models.directional import (
    AbcOnDirections,
    NlbWithLatent,
    SpectralMlpOnDirections,
    rusinkiewicz_theta_h_d,
)
from neuralbrdf.models.nlb import NlbConfig, NlbNetwork
from neuralbrdf import kinds, onnx_export
from neuralbrdf.cli import export_command
from neuralbrdf.render.drjit_onnx import DrJitGraph
from neuralbrdf.kinds import load_model
from neuralbrdf.kinds import contract_metadata

ROOT = Path(__file__).resolve().parents[1]



RTOL = onnx_export.RELATIVE_TOLERANCE
ATOL = onnx_export.ABSOLUTE_FLOOR_SR
NLB_CONFIG = NlbConfig(latent_dim=4, width=16, depth=2, residual=False, half_vector=True)
ABC_RGB = AbcParameters(kd=[0.1, 0.2, 0.3], A=[0.5, 0.8, 1.0], B=20.0, C=1.5, eta=1.5)
ABC_SPECTRAL = AbcParameters(
    kd=np.linspace(0.05, 0.4, 7),
    A=np.array([0.2, 0.9, 0.4, 1.2, 0.7, 0.3, 1.0]),
    B=40.0,
    C=1.2,
    eta=1.6,
    wavelengths=np.array([400.0, 430.0, 480.0, 520.0, 600.0, 650.0, 700.0]),  # irregular
)


# --------------------------------------------------------------------------- inputs


def hemisphere(rng, n):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 1e-3
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def random_pairs(n=2000, seed=7):
    rng = np.random.default_rng(seed)
    wi, wo = hemisphere(rng, n), hemisphere(rng, n)
    wo[: n // 4] = wi[: n // 4] * [-1, -1, 1]  # mirror pairs: the specular peak
    wavelengths = rng.uniform(360.0, 740.0, n)  # beyond the models' ranges on both sides
    return wi.astype(np.float32), wo.astype(np.float32), wavelengths.astype(np.float32)


# --------------------------------------------------------------------------- checkpoints


def structured_mlp(seed=0):
    """A spectral MLP with weights large enough to give a strongly varying function."""
    torch.manual_seed(seed)
    module = SpectralMlpModule(wavelength_range_nm=(420.0, 680.0))
    with torch.no_grad():
        for parameter in module.network.layers.parameters():
            parameter.mul_(2.5)
    return module


def spectral_mlp_checkpoint(path, module=None):
    module = module or structured_mlp()
    checkpoint = {
        "state_dict": module.state_dict(),
        "hyper_parameters": {**dict(module.hparams), "_class_path": f"{module.__module__}.SpectralMlpModule"},
        "datamodule_hyper_parameters": {"path": None, "virtual": "gold", "batch_size": 128},
        "pytorch-lightning_version": pl.__version__,
        "epoch": 4,
        "global_step": 100,
    }
    module.on_save_checkpoint(checkpoint)
    torch.save(checkpoint, path)
    return path


def random_nlb(seed=1):
    """A small NLB network with every weight random (its output layer starts at zero)."""
    torch.manual_seed(seed)
    network = NlbNetwork(**asdict(NLB_CONFIG))
    with torch.no_grad():
        for parameter in network.parameters():
            parameter.copy_(torch.randn_like(parameter) * 0.5)
    return network


def nlb_checkpoint(path, names=("brass", "nylon"), seed=1):
    """The layout of a LatentFitModule checkpoint (read by neuralbrdf.kinds.nlb)."""
    network = random_nlb(seed)
    state = {f"network.{key}": value for key, value in network.state_dict().items()}
    state["latents.latents"] = torch.randn(len(names), NLB_CONFIG.latent_dim) * 2
    checkpoint = {
        "neuralbrdf_kind": "nlb",
        "material_names": list(names),
        "nlb_config": asdict(NLB_CONFIG),
        "state_dict": state,
        "hyper_parameters": {"loss_domain": "log_cosine"},
        "datamodule_hyper_parameters": {"plan": "DS2", "sources": [{"nbrdf": f"{n}.h5"} for n in names]},
    }
    torch.save(checkpoint, path)
    return path


def abc_checkpoint(path, parameters=ABC_RGB, material="fitted-abc"):
    torch.save({"neuralbrdf_kind": "abc", "abc_parameters": parameters.to_dict(), "material": material}, path)
    return path


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    d = tmp_path_factory.mktemp("checkpoints")
    return {
        "spectral_mlp": spectral_mlp_checkpoint(d / "smlp.ckpt"),
        "nlb": nlb_checkpoint(d / "nlb.ckpt"),
        "abc": abc_checkpoint(d / "abc.ckpt"),
        "abc_spectral": abc_checkpoint(d / "abc_spectral.ckpt", ABC_SPECTRAL, "spectral-abc"),
    }


CASES = {
    "spectral_mlp": ("spectral_mlp", None),
    "nlb": ("nlb", "nylon"),
    "abc": ("abc", None),
    "abc_spectral": ("abc_spectral", None),
}


@pytest.fixture(scope="module")
def exported(checkpoints, tmp_path_factory):
    d = tmp_path_factory.mktemp("exported")
    files = {}
    for case, (checkpoint, material) in CASES.items():
        out = d / f"{case}.onnx"
        args = ["--ckpt", str(checkpoints[checkpoint]), "--out", str(out)]
        assert export_command.main(args + (["--material", material] if material else [])) == 0
        files[case] = out
    return files


# --------------------------------------------------------------------------- directional models


def test_half_diff_angles_match_the_rotation_construction():
    """atan-of-ratios formulas vs geometry.half_diff_angles (atan2 and explicit rotations)."""
    wi, wo, _ = random_pairs(500, seed=3)
    theta_h, theta_d = rusinkiewicz_theta_h_d(torch.from_numpy(wi).double(), torch.from_numpy(wo).double())
    ref_h, _, ref_d, _ = half_diff_angles(wi.astype(np.float64), wo.astype(np.float64))
    np.testing.assert_allclose(np.degrees(theta_h.numpy()), ref_h, atol=1e-9)
    np.testing.assert_allclose(np.degrees(theta_d.numpy()), ref_d, atol=1e-9)


def test_spectral_mlp_in_plane_query_is_the_mlp_at_the_canonical_pair():
    """In plane, (ti, tr) maps to (θd + θh, θd − θh) with the closed forms of docs/formats.md#conventions."""
    mlp = structured_mlp().network
    model = SpectralMlpOnDirections(mlp)
    rng = np.random.default_rng(0)
    ti, tr = rng.uniform(-60.0, 60.0, (2, 400))
    wavelength = torch.from_numpy(rng.uniform(450.0, 650.0, 400))
    wi, wo = inplane_to_vectors(torch.from_numpy(ti), torch.from_numpy(tr))
    theta_h, theta_d = np.abs(ti - tr) / 2, np.abs(ti + tr) / 2
    with torch.no_grad():
        got = model(wi.float(), wo.float(), wavelength.float()).double()
        canonical = (torch.from_numpy(theta_d + theta_h).float(), torch.from_numpy(theta_d - theta_h).float())
        expected = mlp(*canonical, wavelength.float())
    np.testing.assert_allclose(got.numpy(), expected.double().numpy(), rtol=2e-4)


def test_spectral_mlp_on_directions_is_isotropic_reciprocal_clamped_and_zero_below():
    model = SpectralMlpOnDirections(structured_mlp().network)
    wi, wo, wavelength = (torch.from_numpy(a).double() for a in random_pairs(300, seed=4))
    wi, wo = (v / v.norm(dim=1, keepdim=True) for v in (wi, wo))  # unit in float64
    model.double()
    angle = 1.234
    rotation = torch.tensor(
        [[math.cos(angle), -math.sin(angle), 0.0], [math.sin(angle), math.cos(angle), 0.0], [0.0, 0.0, 1.0]],
        dtype=torch.float64,
    )
    with torch.no_grad():
        f = model(wi, wo, wavelength)
        np.testing.assert_allclose(model(wi @ rotation.T, wo @ rotation.T, wavelength), f, rtol=1e-9)
        np.testing.assert_allclose(model(wo, wi, wavelength), f, rtol=1e-9)
        low, high = model.wavelength_range_nm
        for outside, edge in ((low - 80.0, low), (high + 80.0, high)):
            np.testing.assert_array_equal(
                model(wi, wo, torch.full_like(wavelength, outside)), model(wi, wo, torch.full_like(wavelength, edge))
            )
        below = wo * torch.tensor([1.0, 1.0, -1.0], dtype=torch.float64)
        assert torch.all(model(wi, below, wavelength) == 0) and torch.all(model(below, wi, wavelength) == 0)
        assert torch.all(f > 0)


def test_nlb_with_latent_is_the_network_with_that_latent_as_a_constant():
    network = random_nlb()
    latent = torch.randn(NLB_CONFIG.latent_dim)
    model = NlbWithLatent(network, latent)
    assert [name for name, _ in model.named_parameters()] == [f"network.{n}" for n, _ in network.named_parameters()]
    assert "latent" in dict(model.named_buffers())
    wi, wo, _ = (torch.from_numpy(a) for a in random_pairs(100))
    with torch.no_grad():  # the latent folded into the input bias: equal up to rounding
        torch.testing.assert_close(model(wi, wo), network(wi, wo, latent), rtol=1e-5, atol=1e-7)
        below = wo * torch.tensor([1.0, 1.0, -1.0], dtype=wo.dtype)
        assert torch.all(model(wi, below) == 0)
    with pytest.raises(ValueError, match="latent has 3 values"):
        NlbWithLatent(network, torch.zeros(3))


def test_spectral_abc_interpolates_its_parameters_linearly_in_wavelength():
    """Against abc_brdf with kd(λ), A(λ) from np.interp (irregular grid, clamped ends)."""
    model = AbcOnDirections(ABC_SPECTRAL).double()
    wi, wo, wavelength = (a.astype(np.float64) for a in random_pairs(400, seed=9))
    wavelength[:7] = ABC_SPECTRAL.wavelengths  # the nodes themselves
    grid = ABC_SPECTRAL.wavelengths
    kd = np.interp(wavelength, grid, ABC_SPECTRAL.kd)
    A = np.interp(wavelength, grid, ABC_SPECTRAL.A)
    p = ABC_SPECTRAL
    parts = abc_brdf(wi, wo, np.array([1.0, 0.0]), np.array([0.0, 1.0]), p.B, p.C, p.eta)
    expected = kd * parts[:, 0] + A * parts[:, 1]
    with torch.no_grad():
        got = model(torch.from_numpy(wi), torch.from_numpy(wo), torch.from_numpy(wavelength)).numpy()
    np.testing.assert_allclose(got, expected, rtol=1e-6)
    rgb = AbcOnDirections(ABC_RGB)
    with torch.no_grad():
        np.testing.assert_allclose(
            rgb(torch.from_numpy(wi).float(), torch.from_numpy(wo).float()).numpy(),
            ABC_RGB.evaluate(wi, wo),
            rtol=1e-4,
        )


# --------------------------------------------------------------------------- exported files


@pytest.mark.parametrize("case", list(CASES))
def test_exported_file_passes_load_model_with_the_contract_metadata(exported, case):
    model = load_model(exported[case])
    expected_kind = {"abc_spectral": "abc"}.get(case, case)
    assert model.kind == expected_kind
    materials = {"spectral_mlp": "gold", "nlb": "nylon", "abc": "fitted-abc", "abc_spectral": "spectral-abc"}
    assert model.material == materials[case]
    assert model.is_spectral == (case in ("spectral_mlp", "abc_spectral"))
    if case == "spectral_mlp":
        assert model.wavelength_range_nm == (420.0, 680.0)
        assert "epoch 4" in model.provenance and '"virtual":"gold"' in model.provenance
    if case == "nlb":
        assert '"plan":"DS2"' in model.provenance
    if case.startswith("abc"):
        assert model.details.B == pytest.approx({"abc": ABC_RGB, "abc_spectral": ABC_SPECTRAL}[case].B)
    if case == "abc_spectral":
        assert model.wavelength_range_nm == (400.0, 700.0) and len(model.details.kd) == 7
    dims = model.proto.graph.input[0].type.tensor_type.shape.dim
    assert dims[0].dim_param and not dims[0].HasField("dim_value")  # dynamic batch


@pytest.mark.parametrize("case", list(CASES))
def test_pytorch_onnxruntime_and_drjit_agree_on_the_exported_file(exported, checkpoints, case):
    checkpoint, material = CASES[case]
    module = kinds.load_exportable(checkpoints[checkpoint], material).module
    wi, wo, wavelength = random_pairs()
    spectral = load_model(exported[case]).is_spectral
    feeds = {"wi": wi, "wo": wo, **({"wavelength": wavelength} if spectral else {})}
    with torch.no_grad():
        reference = module(*(torch.from_numpy(v) for v in feeds.values())).numpy()
    session = onnxruntime.InferenceSession(str(exported[case]), providers=["CPUExecutionProvider"])
    ort = session.run(["f"], feeds)[0]
    graph = DrJitGraph(onnx.load(str(exported[case])))
    columns = graph(
        [Float(wi[:, k]) for k in range(3)],
        [Float(wo[:, k]) for k in range(3)],
        Float(wavelength) if spectral else None,
    )
    drjit = np.stack([np.full(len(wi), c, np.float32) if isinstance(c, float) else c.numpy() for c in columns], -1)
    drjit = drjit.reshape(reference.shape)
    assert np.all(np.isfinite(reference)) and reference.max() > 0
    for name, values in (("onnxruntime", ort), ("drjit", drjit)):
        excess = np.abs(values - reference) / (RTOL * np.abs(reference) + ATOL)
        assert excess.max() <= 1.0, f"{name}: worst error {excess.max():.2f}x the allowed 1e-5 relative"


def test_nlb_latents_select_the_material(exported, checkpoints, tmp_path):
    brass = tmp_path / "brass.onnx"
    assert export_command.main(["--ckpt", str(checkpoints["nlb"]), "--out", str(brass), "--material", "brass"]) == 0
    wi, wo, _ = random_pairs(64)
    run = lambda path: onnxruntime.InferenceSession(str(path)).run(["f"], {"wi": wi, "wo": wo})[0]  # noqa: E731
    assert not np.allclose(run(brass), run(exported["nlb"]), rtol=1e-3)
    fitted = kinds.load_exportable(checkpoints["nlb"], "brass").module
    with torch.no_grad():
        np.testing.assert_allclose(run(brass), fitted(torch.from_numpy(wi), torch.from_numpy(wo)).numpy(), rtol=1e-5)


class _Activation(torch.nn.Module):
    def __init__(self, fn):
        super().__init__()
        self.fn = fn

    def forward(self, wi, wo):
        return self.fn(wi) + (wo - wo)


@pytest.mark.parametrize(
    "name, fn, exact",
    [
        ("expm1", lambda x: torch.expm1(16.0 * x), lambda x: np.expm1(16.0 * x)),
        ("softplus", lambda x: torch.nn.functional.softplus(30.0 * x), lambda x: np.logaddexp(0.0, 30.0 * x)),
        (
            "softplus beta 2 threshold 5",
            lambda x: torch.nn.functional.softplus(30.0 * x, beta=2.0, threshold=5.0),
            lambda x: np.where(60.0 * x > 5.0, 30.0 * x, np.logaddexp(0.0, 60.0 * x) / 2.0),
        ),
    ],
)
def test_activations_are_exported_to_float32_accuracy_in_both_backends(name, fn, exact):
    """expm1 has no ONNX operator and ONNX Softplus loses small values in float32; the exporter's
    replacements keep a few ulps in onnxruntime and in the Dr.Jit interpretation."""
    x = np.concatenate([np.geomspace(1e-9, 1.0, 2000), -np.geomspace(1e-9, 1.0, 2000)])
    wi = np.repeat(x[:, None], 3, axis=1).astype(np.float32)
    proto = onnx_export.trace(onnx_export.Exportable(_Activation(fn), "nlb", name, {}, None))
    ort = onnxruntime.InferenceSession(proto.SerializeToString()).run(None, {"wi": wi, "wo": wi})[0][:, 0]
    columns = DrJitGraph(proto)([Float(wi[:, k]) for k in range(3)], [Float(wi[:, k]) for k in range(3)])
    reference = exact(wi[:, 0].astype(np.float64))
    # Rounding the scaled argument z costs e^z up to |z| ulps (|z| <= 30): 2e-6 relative.
    np.testing.assert_allclose(ort, reference, rtol=2e-6)
    np.testing.assert_allclose(columns[0].numpy(), reference, rtol=2e-6)


# --------------------------------------------------------------------------- refusals


def _no_output_left(directory: Path, name: str) -> bool:
    """Neither ``name`` nor an atomic-write temporary of it (``.<stem>.*``) in ``directory``."""
    temporaries = [p for p in directory.iterdir() if p.name.startswith(f".{Path(name).stem}.")]
    return not (directory / name).exists() and not temporaries


def test_export_refuses_a_graph_that_does_not_reproduce_pytorch(checkpoints, tmp_path, monkeypatch, capsys):
    trace = onnx_export.trace

    def corrupted_trace(exportable):
        proto = trace(exportable)
        weight = [init for init in proto.graph.initializer if len(init.dims) == 2][-1]  # output layer
        values = onnx.numpy_helper.to_array(weight) * np.float32(1.0 + 1e-4)
        weight.CopyFrom(onnx.numpy_helper.from_array(values, weight.name))
        return proto

    monkeypatch.setattr(onnx_export, "trace", corrupted_trace)
    out = tmp_path / "corrupt.onnx"
    with pytest.raises(onnx_export.ExportValidationError, match="differs from PyTorch"):
        onnx_export.export_checkpoint(checkpoints["spectral_mlp"], out)
    assert export_command.main(["--ckpt", str(checkpoints["spectral_mlp"]), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not written" in err
    assert _no_output_left(tmp_path, out.name)


def test_export_refuses_a_file_that_load_model_rejects(checkpoints, tmp_path, monkeypatch):
    trace = onnx_export.trace

    def without_metadata(exportable):
        proto = trace(exportable)
        del proto.metadata_props[:]
        return proto

    monkeypatch.setattr(onnx_export, "trace", without_metadata)
    out = tmp_path / "nometa.onnx"
    with pytest.raises(onnx_export.ExportValidationError, match="contract check: missing metadata"):
        onnx_export.export_checkpoint(checkpoints["abc"], out)
    assert _no_output_left(tmp_path, out.name)


def test_sharp_abc_lobes_export(tmp_path):
    """Löw et al.'s sharp lobes (B ~ 1e5) need 1 - cos θh without cancellation in float32."""
    sharp = AbcParameters(kd=[0.011, 0.035, 0.104], A=[1191.4, 1099.3, 1082.1], B=255869.0, C=1.0847, eta=1.475)
    onnx_export.export_checkpoint(abc_checkpoint(tmp_path / "sharp.ckpt", sharp, "blue-acrylic"), tmp_path / "sharp.onnx")


def _write_garbage(path):
    if path.is_dir():
        path = path / "garbage.ckpt"
    path.write_bytes(b"this is not a checkpoint\n")
    return path


def _saved(directory: Path, obj) -> Path:
    path = directory / "saved.ckpt"
    torch.save(obj, path)
    return path


def _edited(make, edit):
    """A case maker: the checkpoint ``make(path)`` writes, changed in place by ``edit(checkpoint)``."""

    def build(directory: Path) -> Path:
        path = make(directory / "edited.ckpt")
        checkpoint = torch.load(path, weights_only=True)
        edit(checkpoint)
        torch.save(checkpoint, path)
        return path

    return build


_resized_spectral_mlp = _edited(
    spectral_mlp_checkpoint, lambda c: c["state_dict"].__setitem__("network.layers.0.weight", torch.zeros(4, 3))
)
#: Hyper-parameters asking for ~7e9 weights, refused before allocation.
_huge_spectral_mlp = _edited(spectral_mlp_checkpoint, lambda c: c["hyper_parameters"].__setitem__("hidden", 60_000))
_huge_nlb = _edited(nlb_checkpoint, lambda c: c["nlb_config"].__setitem__("width", 60_000))


def test_out_equal_to_the_checkpoint_is_refused_and_the_checkpoint_kept(tmp_path, capsys):
    """``--out c.ckpt --ckpt c.ckpt`` must not replace the checkpoint."""
    path = spectral_mlp_checkpoint(tmp_path / "c.ckpt")
    before = path.read_bytes()
    assert export_command.main(["--ckpt", str(path), "--out", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is also an input of this command" in err, err
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.ckpt"]


NEGATIVE_ALBEDO = {**ABC_RGB.to_dict(), "kd": [0.1, -0.2, 0.3]}

#: case -> (make the checkpoint in a directory, extra arguments, expected message)
BAD_CHECKPOINTS = {
    "missing file": (lambda d: d / "missing.ckpt", [], "checkpoint not found"),
    "not a checkpoint": (_write_garbage, [], "not a readable PyTorch checkpoint"),
    "not a dictionary": (lambda d: _saved(d, [1, 2]), [], "not a checkpoint dictionary"),
    "unknown kind": (lambda d: _saved(d, {"state_dict": {}}), [], "unknown checkpoint kind"),
    "spectral mlp without weights": (
        lambda d: _saved(d, {"neuralbrdf_kind": "spectral_mlp", "hyper_parameters": {}}),
        [],
        "lacks this key",
    ),
    "spectral mlp of the wrong shape": (_resized_spectral_mlp, [], "where the hyper-parameters need [10, 3]"),
    "spectral mlp 60000 units wide": (_huge_spectral_mlp, [], "above the limit"),
    "nlb 60000 units wide": (_huge_nlb, ["--material", "brass"], "above the limit"),
    "several nlb materials, none chosen": (lambda d: nlb_checkpoint(d / "n.ckpt"), [], "choose one with --material"),
    "unknown nlb material": (lambda d: nlb_checkpoint(d / "n.ckpt"), ["--material", "gold"], "no material 'gold'"),
    "nlb without latents": (
        lambda d: _saved(d, {"neuralbrdf_kind": "nlb", "material_names": ["a"]}),
        [],
        "not a latent-fit checkpoint",
    ),
    "abc without parameters": (lambda d: _saved(d, {"neuralbrdf_kind": "abc", "material": "x"}), [], "abc_parameters"),
    "abc with a negative albedo": (
        lambda d: _saved(d, {"neuralbrdf_kind": "abc", "material": "x", "abc_parameters": NEGATIVE_ALBEDO}),
        [],
        "negative value",
    ),
}


@pytest.mark.parametrize("case", list(BAD_CHECKPOINTS))
def test_bad_checkpoint_exits_2_with_one_line_naming_it(case, tmp_path, capsys):
    make, extra, message = BAD_CHECKPOINTS[case]
    path = make(tmp_path)
    out = tmp_path / "model.onnx"
    assert export_command.main(["--ckpt", str(path), "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("neuralbrdf export: error: ") and str(path) in err, err
    assert message in err, err
    assert _no_output_left(tmp_path, out.name)


def test_command_line_exit_status_and_message(tmp_path):
    bad = _write_garbage(tmp_path / "bad.ckpt")
    result = subprocess.run(
        [sys.executable, str(ROOT / "export" / "to_onnx.py"), "--ckpt", str(bad), "--out", str(tmp_path / "m.onnx")],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "not a readable PyTorch checkpoint" in result.stderr
    assert not (tmp_path / "m.onnx").exists()


class _CancellingNetwork(torch.nn.Module):
    """``f = exp(y + 0.5)`` where ``y`` is a difference of two equal sums of terms of size ~300: zero
    in exact arithmetic, float32 rounding (~4e-3) in practice — a well-defined model whose float32
    evaluation order matters, like deep networks with exponential outputs at grazing angles
    (a correct NLB latent fit of nylon would be refused at 1.1e-5 relative by a bound without it)."""

    def __init__(self) -> None:
        super().__init__()
        generator = torch.Generator().manual_seed(0)
        self.w1 = torch.nn.Parameter(torch.randn(6, 64, generator=generator) * 300)
        self.w2 = torch.nn.Parameter(torch.randn(64, 1, generator=generator))

    def forward(self, wi, wo):
        x = torch.cat([wi, wo], -1)
        y = ((x @ self.w1) @ self.w2)[:, 0] - (x @ (self.w1 @ self.w2))[:, 0]
        f = torch.exp(y + 0.5)
        return torch.where((wi[:, 2] > 0) & (wo[:, 2] > 0), f, torch.zeros_like(f))[:, None].expand(-1, 3)


def test_export_check_allows_the_models_own_float32_rounding_and_still_refuses_a_wrong_graph(tmp_path, monkeypatch):
    module = _CancellingNetwork().eval().requires_grad_(False)
    exportable = onnx_export.Exportable(module, "nlb", "cancel", contract_metadata("nlb", "cancel", "test"), None)
    proto = onnx_export.trace(exportable)
    n_probes, _, max_rel = onnx_export.validate(proto, exportable)
    assert max_rel > 10 * RTOL  # beyond the contract's 1e-5: only the float32 allowance lets it pass
    monkeypatch.setattr(onnx_export, "FLOAT32_ERROR_FACTOR", 0.0)
    with pytest.raises(onnx_export.ExportValidationError, match="differs from PyTorch"):
        onnx_export.validate(proto, exportable)
    monkeypatch.undo()
    # a graph 5 % off (the offset 0.5 -> 0.55) is far outside that allowance (~1.5 % here)
    offset = next(n for n in proto.graph.node if n.op_type == "Constant"
                  and onnx.numpy_helper.to_array(n.attribute[0].t).size == 1
                  and float(onnx.numpy_helper.to_array(n.attribute[0].t)) == 0.5)
    offset.attribute[0].t.CopyFrom(onnx.numpy_helper.from_array(np.array(0.55, dtype=np.float32)))
    with pytest.raises(onnx_export.ExportValidationError, match="own float32 rounding error"):
        onnx_export.validate(proto, exportable)


def test_export_readme_names_the_checkpoints_runs_write():
    """export/README.md told users to export a latent fit's last.ckpt, which latent runs never write."""
    import yaml

    readme = (ROOT / "export" / "README.md").read_text()
    config = yaml.safe_load((ROOT / "configs" / "nlb_latent.yaml").read_text())
    checkpoint = next(c["init_args"] for c in config["trainer"]["callbacks"] if c["class_path"].endswith("ModelCheckpoint"))
    nlb_lines = [line for line in readme.splitlines() if "--material" in line and "to_onnx.py" in line]
    assert nlb_lines and all(f"checkpoints/{checkpoint['filename']}.ckpt" in line for line in nlb_lines)
    assert checkpoint.get("save_last") is False and "last.ckpt --out brass" not in readme
