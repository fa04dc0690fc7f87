"""``neuralbrdf export`` (and ``export/to_onnx.py``): a checkpoint to the ONNX file of SPEC §6.

    neuralbrdf export --ckpt RUN.ckpt --out MODEL.onnx [--material NAME]

The checkpoint's kind (:mod:`neuralbrdf.kinds`; its ``neuralbrdf_kind`` entry, or the layout of
older files) builds the model on directions; :func:`neuralbrdf.onnx_export.write_model` traces
it, checks it against PyTorch with onnxruntime and writes it atomically.

Exit status: 0 written; 2 bad input (unreadable or foreign checkpoint, unknown material: one
line naming the file and key); 1 the exported graph failed validation (one line, nothing
written).
"""

from __future__ import annotations

import argparse
import sys

from neuralbrdf import kinds
from neuralbrdf.atomic import command_inputs
from neuralbrdf.errors import InputError
from neuralbrdf.onnx_export import ExportValidationError, export_checkpoint


def _kinds_help() -> str:
    trained = [kinds.get(name) for name in kinds.names() if kinds.get(name).from_checkpoint is not None]
    return "Checkpoint kinds: " + "; ".join(f"{kind.name}: {kind.summary}" for kind in trained) + "."


def build_parser(prog: str = "neuralbrdf export") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Export a trained checkpoint (spectral MLP, NLB latent fit or ABC fit) to one self-contained "
        "ONNX file (SPEC §6), validated against PyTorch with onnxruntime before it is written. Exit status: 0 "
        "written, 2 bad input, 1 the graph failed validation (nothing written).",
        epilog=_kinds_help(),
    )
    parser.add_argument("--ckpt", required=True, help="checkpoint (.ckpt) of train.py or of a latent fit")
    parser.add_argument(
        "--out", required=True,
        help="output .onnx file (never the checkpoint itself; a symbolic link is written through)",
    )
    parser.add_argument(
        "--material", default=None, help="material to export (required when the checkpoint holds several)"
    )
    return parser


def main(argv: list[str] | None = None, prog: str = "neuralbrdf export") -> int:
    args = build_parser(prog).parse_args(argv)
    try:
        with command_inputs():  # --out may not be the checkpoint it reads (neuralbrdf.atomic)
            report = export_checkpoint(args.ckpt, args.out, args.material)
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
