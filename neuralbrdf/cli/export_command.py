"""``neuralbrdf export`` (and ``export/to_onnx.py``): a checkpoint to the ONNX file of docs/formats.md#onnx-model-files, with
its fast paths.

    neuralbrdf export --ckpt RUN.ckpt --out MODEL.onnx [--material NAME] [--fast | --no-fast] [--no-rgb-head]
    neuralbrdf export --model MODEL.onnx --out NEW.onnx [--fast | --no-fast] [--no-rgb-head]

The command is one call of :func:`neuralbrdf.api.export` (``nb.export``, the path ``FitResult.export``
takes too: same file, same printed checks, same defaults): the checkpoint's kind builds the model
on directions, which is traced, checked against PyTorch with onnxruntime
and written atomically, with its **fast paths** (:mod:`neuralbrdf.lod.fast_paths`) distilled
from it and embedded in the same file: a spectral model gets its RGB head ``f_rgb`` (its linear
sRGB, once per query: what the renderer uses in RGB variants) unless ``--no-rgb-head``;
``--fast`` adds ``f_fast``, a compact copy of any model (the renderer's ``--fast``), which a
spectral NLB model gets unless ``--no-fast`` (:attr:`neuralbrdf.kinds.Kind.fast_by_default`).  Each
distillation takes several seconds on one idle core; its error against the model and counted
relative cost are printed and recorded in the file.  ``--model`` adds fast paths to a file that
has none of those asked for, e.g. a spectral model exported elsewhere.  Settings:
``configs/lod/default.yaml``, section ``fast_paths`` (``--config`` names another file).

Exit status (docs/robustness.md): 0 written; 2 bad input (unreadable or foreign checkpoint or
model, unknown material, nothing to add: one line naming the file and key); 1 the exported graph
failed validation or a fast path missed its error bound; 3 the output could not be written (no
space left on device, no permission); one line each, nothing written.
"""

from __future__ import annotations

import argparse
import sys

from neuralbrdf import kinds
from neuralbrdf.errors import EXIT_FAILED, EXIT_OK, EnvironmentFailure, InputError, error_line, exit_status


def _kinds_help() -> str:
    trained = [kinds.get(name) for name in kinds.names() if kinds.get(name).from_checkpoint is not None]
    return "Checkpoint kinds: " + "; ".join(f"{kind.name}: {kind.summary}" for kind in trained) + "."


def build_parser(prog: str = "neuralbrdf export") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog, allow_abbrev=False,
        description="Export a trained checkpoint (spectral MLP, ABC fit, or a latent fit of the NLB or the spectral "
        "NLB) to one self-contained "
        "ONNX file (docs/formats.md#onnx-model-files), validated against PyTorch with onnxruntime before it is written, with fast paths "
        "distilled from it (a spectral model's RGB head by default; --fast: a compact copy). Exit status: 0 "
        "written, 2 bad input, 1 the graph failed validation or a fast path its error bound, 3 the output could "
        "not be written (no space left on device, no permission); nothing written unless 0.",
        epilog=_kinds_help(),
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--ckpt", help="checkpoint (.ckpt) of train.py or of a latent fit")
    source.add_argument("--model", help="an exported model file (.onnx) to add fast paths to")
    parser.add_argument(
        "--out", required=True,
        help="output .onnx file (never the checkpoint or model read; a symbolic link is written through)",
    )
    parser.add_argument(
        "--material", default=None, help="material to export (required when the checkpoint holds several)"
    )
    fast = parser.add_mutually_exclusive_group()
    fast.add_argument("--fast", dest="fast", action="store_true", default=None,
                      help="add f_fast: a compact network distilled from the model (render it with --fast); "
                      "spectral NLB models get it unless --no-fast")
    fast.add_argument("--no-fast", dest="fast", action="store_false",
                      help="no f_fast, even for a kind that gets one by default")
    parser.add_argument("--no-rgb-head", action="store_true",
                        help="spectral models: no f_rgb (RGB renders then integrate the spectrum, several "
                        "evaluations per query)")
    parser.add_argument("--config", default="default",
                        help="level-of-detail settings, section 'fast_paths' (default: the shipped configs/lod/default.yaml)")
    return parser


def main(argv: list[str] | None = None, prog: str = "neuralbrdf export") -> int:
    args = build_parser(prog).parse_args(argv)
    from neuralbrdf import api

    try:
        api.export(args.ckpt, args.out, args.material, model=args.model, fast=args.fast, rgb_head=not args.no_rgb_head,
                   config=args.config)
    except api.ExportFailed as failed:
        print(error_line(prog, f"{args.out} not written: {failed.failure}"), file=sys.stderr)
        return EXIT_FAILED
    except (InputError, EnvironmentFailure) as error:
        print(error_line(prog, error), file=sys.stderr)
        return exit_status(error)
    return EXIT_OK
