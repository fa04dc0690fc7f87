"""Export a trained model checkpoint to the self-contained ONNX file of SPEC §6.

    python export/to_onnx.py --ckpt RUN.ckpt --out MODEL.onnx [--material NAME]

Checkpoint kinds (``checkpoint["neuralbrdf_kind"]``; older files are recognised by their layout):

* ``spectral_mlp`` — a :class:`~neuralbrdf.lightning.spectral_mlp_module.SpectralMlpModule` run
  (``train.py fit --config configs/spectral_mlp.yaml``), exported as
  :class:`~neuralbrdf.models.directional.SpectralMlpOnDirections`: inputs ``wi, wo,
  wavelength``, output ``f [N]``, the in-plane mapping of SPEC §4.4 inside the graph;
* ``nlb`` — a latent fit (:func:`~neuralbrdf.lightning.latent_fit_module.load_fitted`): one file
  per fitted material, the latent baked in (:class:`~neuralbrdf.models.directional.NlbWithLatent`);
  ``--material`` picks one when the checkpoint holds several;
* ``abc`` — an ABC fit: ``checkpoint["abc_parameters"]`` (:meth:`ABCParameters.to_dict`) and
  ``checkpoint["material"]`` (:class:`~neuralbrdf.models.directional.AbcOnDirections`; RGB, or
  spectral with a ``wavelength`` input when the parameters have wavelengths).

The graph is traced with ``torch.onnx.export`` (TorchScript exporter, opset :data:`OPSET`,
dynamic batch ``N``), then **validated before anything is written**: onnxruntime and PyTorch
evaluate it on :func:`validation_probes` (random hemisphere pairs, mirror pairs, grazing pairs,
pairs below the horizon, wavelengths inside and outside the model's range) and must agree to
``|f_ort − f_torch| <= 1e-5 |f_torch| + 1e-8 sr⁻¹`` (:data:`RELATIVE_TOLERANCE`,
:data:`ABSOLUTE_FLOOR_SR`); then :func:`neuralbrdf.render.onnx_contract.load_model` must accept the
file.  The output appears atomically or not at all.

Exit status: 0 written; 2 bad input (unreadable or foreign checkpoint, unknown material: one
line naming the file and key); 1 the exported graph failed validation (one line, nothing
written).
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
import onnxruntime
import torch
from onnx import helper
from torch import nn
from torch.onnx import symbolic_helper

from neuralbrdf.atomic import atomic_path, command_inputs
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import inplane_to_vectors, normalize, reflect, spherical_to_vector
from neuralbrdf.lightning.checkpoint_io import check_weights_match, one_line, read_checkpoint
from neuralbrdf.models.abc import ABCParameters
from neuralbrdf.models.directional import AbcOnDirections, NlbWithLatent, SpectralMlpOnDirections
from neuralbrdf.render.onnx_contract import (
    INPUT_WAVELENGTH,
    INPUT_WI,
    INPUT_WO,
    OUTPUT_F,
    AbcMetadata,
    contract_metadata,
    load_model,
)

#: ONNX opset of exported graphs.
OPSET = 17
#: Largest accepted ``|f_ort - f_torch| / |f_torch|`` (SPEC §6) ...
RELATIVE_TOLERANCE = 1e-5
#: ... above this absolute floor in sr⁻¹ (float32 rounding of values near 0).
ABSOLUTE_FLOOR_SR = 1e-8
#: Nanometres by which validation wavelengths reach past the model's range (clamping is checked).
WAVELENGTH_OVERSHOOT_NM = 40.0

KIND_KEY = "neuralbrdf_kind"
#: LightningModule class of a checkpoint without ``neuralbrdf_kind`` -> its kind.
_CLASS_KINDS = {"SpectralMlpModule": "spectral_mlp", "LatentFitModule": "nlb"}


class ExportValidationError(RuntimeError):
    """The traced graph does not reproduce the PyTorch model; nothing was written."""


@dataclass(frozen=True)
class Exportable:
    """A model ready to trace: the module, its contract metadata and whether it is spectral."""

    module: nn.Module
    kind: str
    material: str
    metadata: dict[str, str]
    wavelength_range_nm: tuple[float, float] | None

    @property
    def is_spectral(self) -> bool:
        return self.wavelength_range_nm is not None


@dataclass(frozen=True)
class ExportReport:
    """What :func:`export` wrote and how closely onnxruntime matched PyTorch."""

    path: Path
    kind: str
    material: str
    n_probes: int
    max_abs_error: float
    max_rel_error: float


# --------------------------------------------------------------------------- checkpoints


def checkpoint_kind(checkpoint: dict, path: Path) -> str:
    """``spectral_mlp``, ``nlb`` or ``abc`` from ``neuralbrdf_kind`` or the module class."""
    kind = checkpoint.get(KIND_KEY)
    if kind is None:
        class_path = str((checkpoint.get("hyper_parameters") or {}).get("_class_path", ""))
        kind = _CLASS_KINDS.get(class_path.rsplit(".", 1)[-1])
        if kind is None and "material_names" in checkpoint and "nlb_config" in checkpoint:
            kind = "nlb"
    if kind not in ("spectral_mlp", "nlb", "abc"):
        found = "no such key" if kind is None else repr(kind)
        raise InputError(
            f"unknown checkpoint kind ({found}); expected 'spectral_mlp', 'nlb' or 'abc'", path=path, column=KIND_KEY
        )
    return kind


def _compact_json(value) -> str:
    def clean(v):
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items() if k != "_instantiator"}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        return v if isinstance(v, (str, int, float, bool, type(None))) else str(v)

    return json.dumps(clean(value), sort_keys=True, separators=(",", ":"))


def provenance(checkpoint: dict, path: Path) -> str:
    """Short provenance: checkpoint file, epoch/step, model and data configuration."""
    parts = [f"checkpoint {path.name}"]
    if "epoch" in checkpoint:
        parts.append(f"epoch {checkpoint['epoch']} step {checkpoint.get('global_step', '?')}")
    for key, label in (("hyper_parameters", "model"), ("datamodule_hyper_parameters", "data")):
        if checkpoint.get(key):
            parts.append(f"{label} {_compact_json(dict(checkpoint[key]))}")
    return "; ".join(parts)


def _pick_material(available: list[str], requested: str | None, path: Path) -> str:
    if requested is None:
        if len(available) != 1:
            raise InputError(
                f"the checkpoint holds {len(available)} materials {available}; choose one with --material", path=path
            )
        return available[0]
    if requested not in available:
        raise InputError(f"no material {requested!r} in the checkpoint; it holds {available}", path=path)
    return requested


def _spectral_mlp_material(checkpoint: dict) -> str:
    data = checkpoint.get("datamodule_hyper_parameters") or {}
    if data.get("path"):
        return Path(str(data["path"])).stem
    return str(data.get("virtual_material") or "spectral_mlp")


def _spectral_mlp(checkpoint: dict, path: Path, material: str | None) -> Exportable:
    from neuralbrdf.lightning.spectral_mlp_module import SpectralMlpModule

    for key in ("state_dict", "hyper_parameters"):
        if key not in checkpoint:
            raise InputError("spectral MLP checkpoint lacks this key", path=path, column=key)
    hparams = {k: v for k, v in dict(checkpoint["hyper_parameters"]).items() if not str(k).startswith("_")}
    check_weights_match(lambda: SpectralMlpModule(**hparams), checkpoint["state_dict"], path)
    module = SpectralMlpModule.load_from_checkpoint(path, map_location="cpu")
    name = _pick_material([_spectral_mlp_material(checkpoint)], material, path)
    directional = SpectralMlpOnDirections(module.network)
    metadata = contract_metadata(
        "spectral_mlp", name, provenance(checkpoint, path), wavelength_range_nm=directional.wavelength_range_nm
    )
    return Exportable(directional, "spectral_mlp", name, metadata, directional.wavelength_range_nm)


def _nlb(checkpoint: dict, path: Path, material: str | None) -> Exportable:
    from neuralbrdf.lightning.latent_fit_module import load_fitted

    fitted = load_fitted(path)
    name = _pick_material(list(fitted.latents), material, path)
    module = NlbWithLatent(fitted.network, fitted.latents[name])
    metadata = contract_metadata("nlb", name, provenance(checkpoint, path))
    return Exportable(module, "nlb", name, metadata, None)


def _abc(checkpoint: dict, path: Path, material: str | None) -> Exportable:
    for key in ("abc_parameters", "material"):
        if key not in checkpoint:
            raise InputError("ABC checkpoint lacks this key", path=path, column=key)
    parameters = ABCParameters.from_dict(checkpoint["abc_parameters"], source=str(path))
    name = _pick_material([str(checkpoint["material"])], material, path)
    module = AbcOnDirections(parameters)
    wavelength_range = module.wavelength_range_nm if module.is_spectral else None
    abc = AbcMetadata(
        kd=tuple(parameters.kd.tolist()),
        A=tuple(parameters.A.tolist()),
        B=parameters.B,
        C=parameters.C,
        eta=parameters.eta,
    )
    metadata = contract_metadata(
        "abc", name, provenance(checkpoint, path), wavelength_range_nm=wavelength_range, abc=abc
    )
    return Exportable(module, "abc", name, metadata, wavelength_range)


def load_exportable(ckpt: str | Path, material: str | None = None) -> Exportable:
    """The model of checkpoint ``ckpt`` as a function of directions, with its metadata."""
    path = Path(ckpt)
    checkpoint = read_checkpoint(path)
    kind = checkpoint_kind(checkpoint, path)
    builder = {"spectral_mlp": _spectral_mlp, "nlb": _nlb, "abc": _abc}[kind]
    try:
        exportable = builder(checkpoint, path, material)
    except InputError as error:
        if error.path is None:  # raised by a constructor that does not know the file
            raise InputError(error.reason, path=path, column=error.column) from None
        raise
    except (KeyError, TypeError, ValueError, RuntimeError, AttributeError) as error:
        # Lightning's loader and load_state_dict on a checkpoint of the right kind but wrong content
        raise InputError(f"not a valid {kind} checkpoint ({one_line(error)})", path=path) from None
    exportable.module.eval().requires_grad_(False)
    return exportable


# --------------------------------------------------------------------------- tracing


#: Below this ``|x|`` the exported ``expm1`` uses its Taylor polynomial (see :func:`_expm1_symbolic`).
EXPM1_SERIES_LIMIT = 0.5
#: Taylor coefficients ``1/n!``, ``n = 1..9``: truncation error below 1e-9 relative for ``|x| < 0.5``.
_EXPM1_COEFFICIENTS = [1.0 / math.factorial(n) for n in range(1, 10)]


def _constant(g, value: float):
    return g.op("Constant", value_t=torch.tensor(value, dtype=torch.float32))


def _expm1_symbolic(g, x):
    """``expm1`` (no ONNX operator) to float32 accuracy in every backend.

    ``x · Σ_{n=1..9} x^{n-1}/n!`` (Horner) for ``|x| < 0.5``, else ``exp(x) − 1`` (which loses at
    most one bit there).
    """
    series = _constant(g, _EXPM1_COEFFICIENTS[-1])
    for coefficient in reversed(_EXPM1_COEFFICIENTS[:-1]):
        series = g.op("Add", g.op("Mul", series, x), _constant(g, coefficient))
    series = g.op("Mul", series, x)
    direct = g.op("Sub", g.op("Exp", x), _constant(g, 1.0))
    small = g.op("Less", g.op("Abs", x), _constant(g, EXPM1_SERIES_LIMIT))
    return g.op("Where", small, series, direct)


def _log1p_of_unit_interval(g, e):
    """``log1p(e)`` for ``e`` in [0, 1] as Kahan's ``ln(u) e / (u − 1)``, ``u = 1 + e`` (``e`` where
    ``u`` rounds to 1): accurate to a few ulps wherever ``ln`` is accurate near 1
    (Higham, *Accuracy and Stability of Numerical Algorithms*, 2nd ed., §1.14.1)."""
    u = g.op("Add", e, _constant(g, 1.0))
    d = g.op("Sub", u, _constant(g, 1.0))
    accurate = g.op("Div", g.op("Mul", g.op("Log", u), e), d)
    return g.op("Where", g.op("Equal", d, _constant(g, 0.0)), e, accurate)


@symbolic_helper.parse_args("v", "f", "f")
def _softplus_symbolic(g, x, beta, threshold):
    """torch's ``softplus(x, beta, threshold)`` as ``(relu(z) + log1p(e^{−|z|})) / beta``, ``z = beta x``
    (``x`` where ``z > threshold``), instead of ONNX ``Softplus``: ``ln(1 + e^{−|z|})`` as written in
    float32 loses ``e^{−|z|}`` to rounding (1e-3 relative at ``z = −10`` in Dr.Jit's
    interpretation), which the NLB's ``expm1(softplus(y))`` output would expose."""
    z = g.op("Mul", x, _constant(g, beta))
    tail = _log1p_of_unit_interval(g, g.op("Exp", g.op("Neg", g.op("Abs", z))))
    value = g.op("Div", g.op("Add", g.op("Relu", z), tail), _constant(g, beta))
    return g.op("Where", g.op("Greater", z, _constant(g, threshold)), x, value)


def _input_names(spectral: bool) -> list[str]:
    return [INPUT_WI, INPUT_WO, INPUT_WAVELENGTH] if spectral else [INPUT_WI, INPUT_WO]


def trace(exportable: Exportable) -> onnx.ModelProto:
    """The module as an ONNX graph with the contract's names, dynamic ``N`` and metadata."""
    torch.onnx.register_custom_op_symbolic("aten::expm1", _expm1_symbolic, OPSET)
    torch.onnx.register_custom_op_symbolic("aten::softplus", _softplus_symbolic, OPSET)
    names = _input_names(exportable.is_spectral)
    feeds = validation_probes(exportable.wavelength_range_nm, n_random=5)
    args = tuple(torch.from_numpy(feeds[name]) for name in names)
    buffer = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tracer warnings about Python-side shape checks
        torch.onnx.export(
            exportable.module,
            args,
            buffer,
            input_names=names,
            output_names=[OUTPUT_F],
            dynamic_axes={name: {0: "N"} for name in [*names, OUTPUT_F]},
            opset_version=OPSET,
            dynamo=False,
        )
    proto = onnx.load_from_string(buffer.getvalue())
    helper.set_model_props(proto, exportable.metadata)
    proto.doc_string = f"neuralbrdf {exportable.kind} model of {exportable.material!r} (SPEC §6)"
    return proto


# --------------------------------------------------------------------------- validation


def validation_probes(
    wavelength_range_nm: tuple[float, float] | None, n_random: int = 4096, seed: int = 0
) -> dict[str, np.ndarray]:
    """Inputs on which onnxruntime must reproduce PyTorch, float32 feeds by input name.

    ``n_random`` pairs uniform over the hemisphere, as many mirror pairs (``wo`` the reflection
    of ``wi``, where specular peaks are), in-plane pairs (signed angles in ±89°), grazing pairs
    (both polar angles in [85°, 89.99°]), and a quarter as many pairs with ``wi`` or ``wo`` below
    the horizon.  Wavelengths (spectral models) are uniform over the model's range widened by
    :data:`WAVELENGTH_OVERSHOOT_NM` on both sides, and include both ends exactly.
    """
    rng = np.random.default_rng(seed)
    n = n_random

    def hemisphere(count, theta_low_deg=0.0, theta_high_deg=90.0):
        cos_theta = rng.uniform(np.cos(np.radians(theta_high_deg)), np.cos(np.radians(theta_low_deg)), count)
        return spherical_to_vector(np.degrees(np.arccos(cos_theta)), rng.uniform(0.0, 360.0, count))

    wi_mirror = hemisphere(n)
    wi_plane, wo_plane = inplane_to_vectors(*rng.uniform(-89.0, 89.0, (2, n)))
    n_below = max(n // 4, 2)
    wi_below, wo_below = hemisphere(n_below), hemisphere(n_below)
    wi_below[::2, 2] *= -1.0
    wo_below[1::2, 2] *= -1.0
    pairs = [
        (hemisphere(n), hemisphere(n)),
        (wi_mirror, reflect(wi_mirror)),
        (wi_plane, wo_plane),
        (hemisphere(n, 85.0, 89.99), hemisphere(n, 85.0, 89.99)),
        (wi_below, wo_below),
    ]
    wi, wo = (normalize(np.concatenate(column)).astype(np.float32) for column in zip(*pairs))
    feeds = {INPUT_WI: wi, INPUT_WO: wo}
    if wavelength_range_nm is not None:
        low, high = wavelength_range_nm
        wavelengths = rng.uniform(low - WAVELENGTH_OVERSHOOT_NM, high + WAVELENGTH_OVERSHOOT_NM, len(wi))
        wavelengths[:2] = (low, high)
        feeds[INPUT_WAVELENGTH] = wavelengths.astype(np.float32)
    return feeds


def validate(proto: onnx.ModelProto, exportable: Exportable) -> tuple[int, float, float]:
    """Compare onnxruntime with PyTorch on :func:`validation_probes`.

    Returns ``(n_probes, max_abs_error, max_rel_error)``; raises
    :class:`ExportValidationError` when PyTorch's output is not finite or when any value misses
    ``|f_ort - f_torch| <= RELATIVE_TOLERANCE |f_torch| + ABSOLUTE_FLOOR_SR``.
    """
    feeds = validation_probes(exportable.wavelength_range_nm)
    names = _input_names(exportable.is_spectral)
    with torch.no_grad():
        expected = exportable.module(*(torch.from_numpy(feeds[name]) for name in names)).numpy().astype(np.float64)
    if not np.all(np.isfinite(expected)):
        raise ExportValidationError(f"the PyTorch model of {exportable.material!r} is not finite at some probe inputs")
    session = onnxruntime.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"])
    (got,) = session.run([OUTPUT_F], {name: feeds[name] for name in names})
    if got.shape != expected.shape:
        raise ExportValidationError(f"onnxruntime returns shape {list(got.shape)}, PyTorch {list(expected.shape)}")
    error = np.abs(got - expected)  # NaN where onnxruntime is not finite
    allowed = RELATIVE_TOLERANCE * np.abs(expected) + ABSOLUTE_FLOOR_SR
    relative = error / np.maximum(np.abs(expected), ABSOLUTE_FLOOR_SR)
    failing = ~(error <= allowed)
    if np.any(failing):
        badness = np.where(failing, np.nan_to_num(error / allowed, nan=np.inf), 0.0)
        worst = np.unravel_index(np.argmax(badness), error.shape)
        row = worst[0]
        raise ExportValidationError(
            f"onnxruntime differs from PyTorch by {error[worst]:.3g} sr^-1 ({relative[worst]:.3g} relative) at probe "
            f"{row} (wi={feeds[INPUT_WI][row].tolist()}, wo={feeds[INPUT_WO][row].tolist()}); allowed "
            f"{RELATIVE_TOLERANCE:g} relative + {ABSOLUTE_FLOOR_SR:g} sr^-1"
        )
    return len(feeds[INPUT_WI]), float(error.max()), float(relative.max())


# --------------------------------------------------------------------------- export


def export(ckpt: str | Path, out: str | Path, material: str | None = None) -> ExportReport:
    """Export checkpoint ``ckpt`` to ``out`` (module docstring); nothing is written on failure."""
    exportable = load_exportable(ckpt, material)
    proto = trace(exportable)
    n_probes, max_abs, max_rel = validate(proto, exportable)
    out = Path(out)
    with atomic_path(out) as tmp:
        onnx.save(proto, str(tmp))
        try:
            load_model(tmp)  # the contract check the renderer runs at scene load
        except InputError as error:
            raise ExportValidationError(f"the graph fails the ONNX contract check: {error.reason}") from None
    return ExportReport(out, exportable.kind, exportable.material, n_probes, max_abs, max_rel)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="export/to_onnx.py",
        description="Export a spectral MLP, NLB latent-fit or ABC checkpoint to one ONNX file (SPEC §6), "
        "validated against PyTorch with onnxruntime before it is written.",
    )
    parser.add_argument("--ckpt", required=True, help="checkpoint (.ckpt) of train.py or of a fit")
    parser.add_argument(
        "--out", required=True,
        help="output .onnx file (never the checkpoint itself; a symbolic link is written through)",
    )
    parser.add_argument(
        "--material", default=None, help="material to export (required when the checkpoint holds several)"
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        with command_inputs():  # --out may not be the checkpoint it reads (neuralbrdf.atomic)
            report = export(args.ckpt, args.out, args.material)
    except InputError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except ExportValidationError as error:
        print(f"error: {args.out} not written: {error}", file=sys.stderr)
        return 1
    print(
        f"wrote {report.path}: {report.kind} model of {report.material!r}; onnxruntime vs PyTorch on "
        f"{report.n_probes} probes: max error {report.max_abs_error:.2g} sr^-1, {report.max_rel_error:.2g} relative"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
