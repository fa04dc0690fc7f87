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

The model is traced, checked against PyTorch with onnxruntime and written atomically by
:func:`neuralbrdf.onnx_export.write_model` (see there for the probes and the tolerance).

Exit status: 0 written; 2 bad input (unreadable or foreign checkpoint, unknown material: one
line naming the file and key); 1 the exported graph failed validation (one line, nothing
written).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from neuralbrdf.atomic import command_inputs
from neuralbrdf.errors import InputError, one_line
from neuralbrdf.lightning.checkpoint_io import check_weights_match, read_checkpoint
from neuralbrdf.models.abc import ABCParameters
from neuralbrdf.models.directional import AbcOnDirections, NlbWithLatent, SpectralMlpOnDirections
from neuralbrdf.onnx_export import Exportable, ExportReport, ExportValidationError, write_model
from neuralbrdf.render.onnx_contract import AbcMetadata, contract_metadata

KIND_KEY = "neuralbrdf_kind"
#: LightningModule class of a checkpoint without ``neuralbrdf_kind`` -> its kind.
_CLASS_KINDS = {"SpectralMlpModule": "spectral_mlp", "LatentFitModule": "nlb"}


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


# --------------------------------------------------------------------------- export


def export(ckpt: str | Path, out: str | Path, material: str | None = None) -> ExportReport:
    """Export checkpoint ``ckpt`` to ``out`` (module docstring); nothing is written on failure."""
    return write_model(load_exportable(ckpt, material), out)


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
