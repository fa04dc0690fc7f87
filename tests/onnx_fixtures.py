"""Small ONNX models that follow the contract of docs/formats.md#onnx-model-files, for the render tests.

The renderer must not depend on the project's model and export code, so these fixtures are
written here from scratch: tiny torch modules exported with ``torch.onnx.export`` (the
TorchScript exporter, which yields the ``Shape``/``Expand``/``Where`` patterns real exports have)
and graphs assembled with ``onnx.helper`` (for the operators torch does not emit and for broken
files).  Every module returns 0 when either direction is below the horizon, as the contract asks.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import TensorProto, helper, numpy_helper
from torch import nn
from torch.nn import functional as F

from neuralbrdf.kinds.abc import AbcMetadata
from neuralbrdf.kinds import contract_metadata

OPSET = 17


def _above(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """``[N, 1]`` mask: both directions strictly above the horizon."""
    return (wi[:, 2:3] > 0) & (wo[:, 2:3] > 0)


def _half_vector(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    return F.normalize(wi + wo, dim=-1)


class NlbLikeMlp(nn.Module):
    """RGB MLP over ``(wi, wo, latent)`` with the latent baked in (docs/models.md#nlb shape, tiny)."""

    def __init__(self, latent_dim: int = 4, width: int = 16, seed: int = 0) -> None:
        super().__init__()
        generator = torch.Generator().manual_seed(seed)
        self.latent = nn.Parameter(torch.randn(1, latent_dim, generator=generator))
        self.layers = nn.ModuleList(
            [nn.Linear(6 + latent_dim, width), nn.Linear(width, width), nn.Linear(width, 3)]
        )
        with torch.no_grad():
            for layer in self.layers:
                layer.weight.copy_(torch.randn(layer.weight.shape, generator=generator) * 0.6)
                layer.bias.copy_(torch.randn(layer.bias.shape, generator=generator) * 0.3)

    def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        x = torch.cat([wi, wo, self.latent.expand(wi.shape[0], -1)], dim=-1)
        x = torch.relu(self.layers[0](x))
        x = F.leaky_relu(self.layers[1](x), 0.1)
        y = F.softplus(self.layers[2](x))
        return torch.where(_above(wi, wo), y, torch.zeros_like(y))


class InPlaneSpectralMlp(nn.Module):
    """Spectral MLP on the in-plane equivalent pair (docs/models.md#spectral-mlp), mapping computed in-graph.

    ``theta_h = atan(|h_xy| / h_z)``, ``theta_d = acos(wi·h)``, ``ti = theta_d + theta_h``,
    ``tr = theta_d - theta_h`` (radians), normalised with the wavelength, through a 3x10 MLP.
    """

    def __init__(self, wavelength_range=(400.0, 700.0), seed: int = 1) -> None:
        super().__init__()
        generator = torch.Generator().manual_seed(seed)
        self.low, self.high = wavelength_range
        self.layers = nn.ModuleList(
            [nn.Linear(3, 10), nn.Linear(10, 10), nn.Linear(10, 10), nn.Linear(10, 1)]
        )
        with torch.no_grad():
            for layer in self.layers:
                layer.weight.copy_(torch.randn(layer.weight.shape, generator=generator) * 0.8)
                layer.bias.copy_(torch.randn(layer.bias.shape, generator=generator) * 0.2)

    def forward(self, wi: torch.Tensor, wo: torch.Tensor, wavelength: torch.Tensor) -> torch.Tensor:
        h = _half_vector(wi, wo)
        sin_h = torch.sqrt(h[:, 0] ** 2 + h[:, 1] ** 2)
        theta_h = torch.atan(sin_h / h[:, 2])
        theta_d = torch.acos(torch.clamp((wi * h).sum(-1), -1.0, 1.0))
        lam = torch.clamp(wavelength, self.low, self.high)
        x = torch.stack(
            [
                (theta_d + theta_h) / (math.pi / 2),
                (theta_d - theta_h) / (math.pi / 2),
                (lam - self.low) / (self.high - self.low) * 2.0 - 1.0,
            ],
            dim=-1,
        )
        for layer in self.layers[:-1]:
            x = torch.tanh(layer(x))
        y = torch.exp(self.layers[-1](x)).squeeze(-1) * 0.1
        return torch.where(_above(wi, wo)[:, 0], y, torch.zeros_like(y))


class Lambert(nn.Module):
    """``f = albedo / pi`` (RGB)."""

    def __init__(self, albedo=(0.8, 0.5, 0.2)) -> None:
        super().__init__()
        self.register_buffer("value", torch.tensor([albedo], dtype=torch.float32) / math.pi)

    def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        y = self.value.expand(wi.shape[0], 3)
        return torch.where(_above(wi, wo), y, torch.zeros_like(y))


class SpectralLambert(nn.Module):
    """``f(λ) = (a + b (λ - 400) / 300) / pi`` (spectral), λ in nm, unclamped."""

    def __init__(self, a: float = 0.2, b: float = 0.6) -> None:
        super().__init__()
        self.a, self.b = a, b

    def forward(self, wi: torch.Tensor, wo: torch.Tensor, wavelength: torch.Tensor) -> torch.Tensor:
        y = (self.a + self.b * (wavelength - 400.0) / 300.0) / math.pi
        return torch.where(_above(wi, wo)[:, 0], y, torch.zeros_like(y))


def ggx_d(cos_h: torch.Tensor, alpha: float) -> torch.Tensor:
    a2 = alpha * alpha
    denom = cos_h * cos_h * (a2 - 1.0) + 1.0
    return a2 / (math.pi * denom * denom)


def ggx_g1(cos_v: torch.Tensor, alpha: float) -> torch.Tensor:
    a2 = alpha * alpha
    return 2.0 * cos_v / (cos_v + torch.sqrt(a2 + (1.0 - a2) * cos_v * cos_v))


class GgxGlossy(nn.Module):
    """Lambert plus a GGX lobe without Fresnel: ``kd/pi + ks D G1 G1 / (4 cos_i cos_o)``."""

    def __init__(self, alpha: float = 0.15, kd=(0.2, 0.1, 0.05), ks=(0.6, 0.7, 0.8)) -> None:
        super().__init__()
        self.alpha = alpha
        self.register_buffer("kd", torch.tensor([kd], dtype=torch.float32) / math.pi)
        self.register_buffer("ks", torch.tensor([ks], dtype=torch.float32))

    def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        above = _above(wi, wo)
        ci = torch.clamp(wi[:, 2:3], 1e-4, 1.0)
        co = torch.clamp(wo[:, 2:3], 1e-4, 1.0)
        h = _half_vector(wi, wo)
        lobe = ggx_d(h[:, 2:3], self.alpha) * ggx_g1(ci, self.alpha) * ggx_g1(co, self.alpha) / (4 * ci * co)
        y = self.kd + self.ks * lobe
        return torch.where(above, y, torch.zeros_like(y))


class AbcLike(nn.Module):
    """The ABC model of docs/models.md#abc with the Fresnel factor taken as 1 (enough for the sampler).

    ``f = kd/pi + A G / (pi cos_i cos_o (1 + B (1 - n·h))^C)``, V-cavity ``G``.
    """

    def __init__(self, params: AbcMetadata) -> None:
        super().__init__()
        self.B, self.C = params.B, params.C
        self.register_buffer("kd", torch.tensor([params.kd], dtype=torch.float32) / math.pi)
        self.register_buffer("A", torch.tensor([params.A], dtype=torch.float32) / math.pi)

    def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        above = _above(wi, wo)
        ci = torch.clamp(wi[:, 2:3], 1e-4, 1.0)
        co = torch.clamp(wo[:, 2:3], 1e-4, 1.0)
        h = _half_vector(wi, wo)
        nh = h[:, 2:3]
        oh = torch.clamp((wo * h).sum(-1, keepdim=True), 1e-4, 1.0)
        g = torch.minimum(torch.ones_like(nh), torch.minimum(2 * nh * co / oh, 2 * nh * ci / oh))
        d = torch.pow(1.0 + self.B * (1.0 - nh), -self.C)
        y = self.kd + self.A * g * d / (ci * co)
        return torch.where(above, y, torch.zeros_like(y))


def export_module(module: nn.Module, path: Path, metadata: dict[str, str], spectral: bool) -> Path:
    """Export ``module`` with the contract's names and dynamic batch, then attach metadata."""
    n = 7
    wi = F.normalize(torch.rand(n, 3) + torch.tensor([0.0, 0.0, 0.2]), dim=-1)
    wo = F.normalize(torch.rand(n, 3) + torch.tensor([0.0, 0.0, 0.2]), dim=-1)
    args = (wi, wo, torch.linspace(400.0, 700.0, n)) if spectral else (wi, wo)
    names = ["wi", "wo", "wavelength"] if spectral else ["wi", "wo"]
    dynamic = {name: {0: "N"} for name in [*names, "f"]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            module.eval(),
            args,
            str(path),
            input_names=names,
            output_names=["f"],
            dynamic_axes=dynamic,
            opset_version=OPSET,
            dynamo=False,
        )
    model = onnx.load(str(path))
    helper.set_model_props(model, metadata)
    onnx.save(model, str(path))
    return path


def rgb_metadata(kind: str = "nlb", material: str = "fixture") -> dict[str, str]:
    return contract_metadata(kind, material, "tests/onnx_fixtures.py")


def spectral_metadata(kind: str = "spectral_mlp", wavelength_range=(400.0, 700.0)) -> dict[str, str]:
    return contract_metadata(kind, "fixture", "tests/onnx_fixtures.py", wavelength_range_nm=wavelength_range)


def write_nlb_like(path: Path) -> Path:
    return export_module(NlbLikeMlp(), path, rgb_metadata("nlb"), spectral=False)


def write_inplane_spectral(path: Path) -> Path:
    return export_module(InPlaneSpectralMlp(), path, spectral_metadata(), spectral=True)


def write_lambert(path: Path, albedo=(0.8, 0.5, 0.2)) -> Path:
    return export_module(Lambert(albedo), path, rgb_metadata("nlb"), spectral=False)


def write_spectral_lambert(path: Path, a: float = 0.2, b: float = 0.6, wavelength_range=(400.0, 700.0)) -> Path:
    return export_module(
        SpectralLambert(a, b), path, spectral_metadata("spectral_mlp", wavelength_range), spectral=True
    )


def write_ggx_glossy(path: Path, alpha: float = 0.15) -> Path:
    return export_module(GgxGlossy(alpha), path, rgb_metadata("nlb"), spectral=False)


def write_abc_like(path: Path, params: AbcMetadata) -> Path:
    metadata = contract_metadata("abc", "fixture-abc", "tests/onnx_fixtures.py", kind_metadata=params.entries())
    return export_module(AbcLike(params), path, metadata, spectral=False)


def write_table(path: Path, spectral: bool, nodes=(6, 5, 4, 5), seed: int = 3) -> Path:
    """A ``table`` model with random node values (the interpreter's table reads, every corner)."""
    from neuralbrdf.kinds.table import NODES_KEY, nodes_text
    from neuralbrdf.models.baked_table import BakedTable

    shape = tuple(nodes) if spectral else (*nodes[:3], 3)
    values = torch.rand(shape, generator=torch.Generator().manual_seed(seed)) + 0.1
    wavelength_range = (400.0, 700.0) if spectral else None
    metadata = contract_metadata("table", "fixture-table", "tests/onnx_fixtures.py", wavelength_range_nm=wavelength_range,
                                 kind_metadata={NODES_KEY: nodes_text(shape if spectral else shape[:3])})
    return export_module(BakedTable(values, wavelength_range), path, metadata, spectral=spectral)


# --------------------------------------------------------------------------- onnx.helper graphs


def _const(name: str, values, dtype=np.float32) -> onnx.TensorProto:
    return numpy_helper.from_array(np.asarray(values, dtype=dtype), name)


def op_zoo_model(spectral: bool = False) -> onnx.ModelProto:
    """A graph that exercises the interpreter's operators beyond what torch emits above.

    Per-sample features of ``wi, wo`` go through Slice/Gather/Split/Squeeze/Unsqueeze/Reshape/
    Flatten/Concat, the elementwise set (Sub, Div, Neg, Sigmoid, Tanh, Exp, Log, Sqrt, Abs, Pow,
    Max, Min, Clip, Asin, Cos, Sin, Acos, Atan, comparisons, And/Or/Not, Where, Cast, Identity),
    ReduceSum, ReduceMean, MatMul and Gemm, then a positive output masked below the horizon.
    """
    nodes = [
        helper.make_node("Constant", [], ["c_half"], value=_const("c_half", 0.5)),
        helper.make_node("Slice", ["wi", "s0", "s2", "ax1"], ["wi_xy"]),  # [N,2]
        helper.make_node("Gather", ["wo", "idx_z"], ["wo_z"], axis=1),  # [N]
        helper.make_node("Split", ["wi", "split3"], ["wix", "wiy", "wiz"], axis=1),  # [N,1] x3
        helper.make_node("Squeeze", ["wiz", "ax1"], ["wiz_s"]),  # [N]
        helper.make_node("Unsqueeze", ["wo_z", "ax1"], ["wo_z1"]),  # [N,1]
        helper.make_node("Reshape", ["wiz_s", "shape_m1_1"], ["wiz_r"]),  # [N,1]
        helper.make_node("Mul", ["wi", "wo"], ["prod"]),
        helper.make_node("ReduceSum", ["prod", "ax1"], ["cos_io"], keepdims=1),  # [N,1]
        helper.make_node("ReduceMean", ["wo"], ["mean_wo"], axes=[-1], keepdims=1),  # [N,1], opset < 18: axes attribute
        helper.make_node("Sub", ["wiz_r", "wo_z1"], ["dz"]),
        helper.make_node("Abs", ["dz"], ["adz"]),
        helper.make_node("Add", ["wo_z1", "c_two"], ["den"]),
        helper.make_node("Div", ["dz", "den"], ["q"]),
        helper.make_node("Neg", ["q"], ["nq"]),
        helper.make_node("Sigmoid", ["nq"], ["sq"]),
        helper.make_node("Tanh", ["cos_io"], ["tc"]),
        helper.make_node("Exp", ["tc"], ["etc"]),
        helper.make_node("Log", ["den"], ["lden"]),
        helper.make_node("Sqrt", ["den"], ["sden"]),
        helper.make_node("Pow", ["den", "c_pow"], ["pden"]),
        helper.make_node("Max", ["q", "c_half", "nq"], ["mx"]),
        helper.make_node("Min", ["q", "tc"], ["mn"]),
        helper.make_node("Clip", ["cos_io", "c_m1", "c_p1"], ["cl"]),
        helper.make_node("Acos", ["cl"], ["acl"]),
        helper.make_node("Asin", ["cl"], ["asl"]),
        helper.make_node("Atan", ["q"], ["atq"]),
        helper.make_node("Cos", ["atq"], ["catq"]),
        helper.make_node("Sin", ["acl"], ["sacl"]),
        helper.make_node("Greater", ["q", "c_zero"], ["g0"]),
        helper.make_node("Less", ["cos_io", "c_half"], ["l0"]),
        helper.make_node("GreaterOrEqual", ["wo_z1", "c_half"], ["ge0"]),
        helper.make_node("LessOrEqual", ["adz", "c_half"], ["le0"]),
        helper.make_node("Equal", ["g0", "l0"], ["eq0"]),
        helper.make_node("And", ["g0", "l0"], ["and0"]),
        helper.make_node("Or", ["ge0", "le0"], ["or0"]),
        helper.make_node("Not", ["eq0"], ["not0"]),
        helper.make_node("Cast", ["or0"], ["or_f"], to=TensorProto.FLOAT),
        helper.make_node("Where", ["and0", "sq", "etc"], ["w0"]),
        helper.make_node("Where", ["not0", "w0", "c_half"], ["w1"]),
        helper.make_node("Identity", ["w1"], ["w1i"]),
        helper.make_node("Concat", ["wi_xy", "dz", "q", "sq", "tc", "etc", "lden", "sden", "pden",
                                    "mx", "mn", "acl", "asl", "catq", "sacl", "or_f", "w1i", "mean_wo"],
                         ["feat"], axis=-1),  # [N,19]
        helper.make_node("Flatten", ["feat"], ["feat2"], axis=1),
        helper.make_node("MatMul", ["feat2", "W1"], ["h1"]),
        helper.make_node("Relu", ["h1"], ["r1"]),
        helper.make_node("Gemm", ["r1", "W2", "b2"], ["h2"], transB=1, alpha=0.7, beta=1.3),
        helper.make_node("Softplus", ["h2"], ["sp"]),
        helper.make_node("Greater", ["wiz_r", "c_zero"], ["up_i"]),
        helper.make_node("Greater", ["wo_z1", "c_zero"], ["up_o"]),
        helper.make_node("And", ["up_i", "up_o"], ["up"]),
        helper.make_node("Where", ["up", "sp", "c_zero"], ["f_rgb"]),
    ]
    rng = np.random.default_rng(3)
    initializers = [
        _const("s0", [0], np.int64),
        _const("s2", [2], np.int64),
        _const("ax1", [1], np.int64),
        _const("idx_z", 2, np.int64),
        _const("split3", [1, 1, 1], np.int64),
        _const("shape_m1_1", [-1, 1], np.int64),
        _const("c_two", 2.0),
        _const("c_pow", 1.7),
        _const("c_m1", -1.0),
        _const("c_p1", 1.0),
        _const("c_zero", 0.0),
        _const("W1", rng.normal(0, 0.5, (19, 12))),
        _const("W2", rng.normal(0, 0.5, (3, 12))),
        _const("b2", rng.normal(0, 0.2, (3,))),
    ]
    inputs = [
        helper.make_tensor_value_info("wi", TensorProto.FLOAT, ["N", 3]),
        helper.make_tensor_value_info("wo", TensorProto.FLOAT, ["N", 3]),
    ]
    if spectral:
        # f(λ) = mean(f_rgb) * (1 + (λ - 550) / 500), reduced over the last axis.
        nodes += [
            helper.make_node("ReduceSum", ["f_rgb", "ax1"], ["f_sum"], keepdims=0),
            helper.make_node("Sub", ["wavelength", "c_550"], ["dl"]),
            helper.make_node("Div", ["dl", "c_500"], ["dl2"]),
            helper.make_node("Add", ["dl2", "c_p1"], ["tilt"]),
            helper.make_node("Mul", ["f_sum", "tilt"], ["f3"]),
            helper.make_node("Div", ["f3", "c_three"], ["f"]),
        ]
        initializers += [_const("c_550", 550.0), _const("c_500", 500.0), _const("c_three", 3.0)]
        inputs.append(helper.make_tensor_value_info("wavelength", TensorProto.FLOAT, ["N"]))
        output = helper.make_tensor_value_info("f", TensorProto.FLOAT, ["N"])
    else:
        nodes.append(helper.make_node("Identity", ["f_rgb"], ["f"]))
        output = helper.make_tensor_value_info("f", TensorProto.FLOAT, ["N", 3])
    graph = helper.make_graph(nodes, "op_zoo", inputs, [output], initializers)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
    model.ir_version = 8
    helper.set_model_props(model, spectral_metadata() if spectral else rgb_metadata())
    return model


def tiny_rgb_model(metadata: dict[str, str] | None = None, **changes) -> onnx.ModelProto:
    """``f = relu(concat(wi, wo) @ W)``, 0 below the horizon, built by hand.

    ``changes`` break parts of the contract: ``wi_name``, ``output_name``, ``input_dtype``,
    ``wi_dims`` (the declared dims of ``wi``), ``weight`` (the weight matrix), ``op`` (the
    activation's op type), ``mask=False`` (no zero below the horizon).
    """
    wi_name = changes.get("wi_name", "wi")
    output_name = changes.get("output_name", "f")
    dtype = changes.get("input_dtype", TensorProto.FLOAT)
    wi_dims = changes.get("wi_dims", ["N", 3])
    weight = changes.get("weight", np.full((6, 3), 0.1, dtype=np.float32))
    mask = changes.get("mask", True)
    activation = "act" if mask else output_name
    nodes = [
        helper.make_node("Concat", [wi_name, "wo"], ["x"], axis=1, name="concat"),
        helper.make_node("MatMul", ["x", "W"], ["y"], name="matmul"),
        helper.make_node(changes.get("op", "Relu"), ["y"], [activation], name="activation"),
    ]
    if mask:
        nodes += [
            helper.make_node("Gather", [wi_name, "two"], ["wi_z"], axis=1, name="wi_z"),
            helper.make_node("Gather", ["wo", "two"], ["wo_z"], axis=1, name="wo_z"),
            helper.make_node("Greater", ["wi_z", "zero"], ["wi_up"], name="wi_up"),
            helper.make_node("Greater", ["wo_z", "zero"], ["wo_up"], name="wo_up"),
            helper.make_node("And", ["wi_up", "wo_up"], ["up"], name="up"),
            helper.make_node("Unsqueeze", ["up", "one"], ["up1"], name="up1"),
            helper.make_node("Where", ["up1", activation, "zero"], [output_name], name="mask"),
        ]
    graph = helper.make_graph(
        nodes,
        "tiny",
        [
            helper.make_tensor_value_info(wi_name, dtype, wi_dims),
            helper.make_tensor_value_info("wo", dtype, ["N", 3]),
        ],
        [helper.make_tensor_value_info(output_name, TensorProto.FLOAT, ["N", 3])],
        [
            numpy_helper.from_array(np.asarray(weight, dtype=np.float32), "W"),
            _const("two", 2, np.int64),
            _const("one", [1], np.int64),
            _const("zero", 0.0),
        ],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
    model.ir_version = 8
    helper.set_model_props(model, rgb_metadata() if metadata is None else metadata)
    return model


def save(model: onnx.ModelProto, path: Path) -> Path:
    onnx.save(model, str(path))
    return path
