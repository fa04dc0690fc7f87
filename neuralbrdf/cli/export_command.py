"""``neuralbrdf export`` (and ``export/to_onnx.py``): a checkpoint to the ONNX file of SPEC §6, with
its fast paths.

    neuralbrdf export --ckpt RUN.ckpt --out MODEL.onnx [--material NAME] [--fast | --no-fast] [--no-rgb-head]
    neuralbrdf export --model MODEL.onnx --out NEW.onnx [--fast | --no-fast] [--no-rgb-head]

The checkpoint's kind (:mod:`neuralbrdf.kinds`; its ``neuralbrdf_kind`` entry, or the layout of
older files) builds the model on directions; :func:`neuralbrdf.onnx_export.write_model` traces
it, checks it against PyTorch with onnxruntime and writes it atomically.

**Fast paths** (:mod:`neuralbrdf.lod.fast_paths`), distilled from the model and embedded in the
same file: a spectral model gets its RGB head ``f_rgb`` (its linear sRGB, once per query: what
the renderer uses in RGB variants) unless ``--no-rgb-head``; ``--fast`` adds ``f_fast``, a
compact copy of any model (the renderer's ``--fast``), which a spectral NLB model gets unless
``--no-fast`` (:attr:`neuralbrdf.kinds.Kind.fast_by_default`).  Each distillation takes about half
a minute on one idle core; its error against the model and relative cost are printed and recorded in the
file.  ``--model`` adds fast paths to a file that has none of those asked for, e.g. a spectral
model exported elsewhere.  Settings: ``configs/lod/default.yaml``, section ``fast_paths``
(``--config`` names another file).

Exit status: 0 written; 2 bad input (unreadable or foreign checkpoint or model, unknown material,
nothing to add: one line naming the file and key); 1 the exported graph failed validation or a
fast path missed its error bound (one line, nothing written).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from neuralbrdf import kinds
from neuralbrdf.atomic import check_outputs, command_inputs
from neuralbrdf.errors import InputError
from neuralbrdf.onnx_contract import OUTPUT_FAST, OUTPUT_RGB
from neuralbrdf.onnx_export import ExportValidationError, write_model


def _kinds_help() -> str:
    trained = [kinds.get(name) for name in kinds.names() if kinds.get(name).from_checkpoint is not None]
    return "Checkpoint kinds: " + "; ".join(f"{kind.name}: {kind.summary}" for kind in trained) + "."


def build_parser(prog: str = "neuralbrdf export") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Export a trained checkpoint (spectral MLP, ABC fit, or a latent fit of the NLB or the spectral "
        "NLB) to one self-contained "
        "ONNX file (SPEC §6), validated against PyTorch with onnxruntime before it is written, with fast paths "
        "distilled from it (a spectral model's RGB head by default; --fast: a compact copy). Exit status: 0 "
        "written, 2 bad input, 1 the graph failed validation or a fast path its error bound (nothing written).",
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
    parser.add_argument("--fast", action="store_true",
                        help="add f_fast: a compact network distilled from the model (render it with --fast); "
                        "spectral NLB models get it unless --no-fast")
    parser.add_argument("--no-fast", action="store_true", help="no f_fast, even for a kind that gets one by default")
    parser.add_argument("--no-rgb-head", action="store_true",
                        help="spectral models: no f_rgb (RGB renders then integrate the spectrum, several "
                        "evaluations per query)")
    parser.add_argument("--config", default="default",
                        help="level-of-detail settings, section 'fast_paths' (default: the shipped configs/lod/default.yaml)")
    return parser


def _wanted(kind: str, is_spectral: bool, present, args) -> tuple[str, ...]:
    """The fast paths to add to a model of ``kind`` (spectral or not, with the fast paths ``present``)."""
    wanted = []
    if is_spectral and not args.no_rgb_head and OUTPUT_RGB not in present:
        wanted.append(OUTPUT_RGB)
    if args.fast or (kinds.get(kind).fast_by_default and not args.no_fast and OUTPUT_FAST not in present):
        wanted.append(OUTPUT_FAST)
    return tuple(wanted)


def _export(args) -> None:
    """Write ``--out`` (module docstring); raises what :func:`main` turns into an exit status."""
    from neuralbrdf.lod.config import load_lod_config
    from neuralbrdf.lod.fast_paths import add_fast_paths

    out = Path(args.out)
    if args.model is not None:
        if args.material is not None:
            raise InputError("--material goes with --ckpt (a model file holds one material)", column="--material")
        model = kinds.load_model(args.model)
        wanted = _wanted(model.kind, model.is_spectral, model.fast_paths, args)
        if not wanted:
            raise InputError("nothing to add: ask for --fast, or give a spectral model without an RGB head",
                             path=args.model)
    else:
        exportable = kinds.load_exportable(args.ckpt, args.material)
        wanted = _wanted(exportable.kind, exportable.is_spectral, (), args)
    check_outputs(out)  # after the inputs are read: an output may not be one of them
    settings = load_lod_config(args.config).fast_paths if wanted else None
    with tempfile.TemporaryDirectory(prefix="neuralbrdf-export-") as work:
        source = Path(args.model) if args.model is not None else out if not wanted else Path(work) / out.name
        if args.ckpt is not None:
            report = write_model(exportable, source)
            print(f"{'wrote ' + str(out) if source == out else 'exported'}: {report.kind} model of {report.material!r}; "
                  f"onnxruntime vs PyTorch on {report.n_probes} probes: max error {report.max_abs_error:.2g} sr^-1, "
                  f"{report.max_rel_error:.2g} relative")
        if not wanted:
            return
        reports = add_fast_paths(source, out, wanted, settings, log=lambda line: print(f"  {line}"))
    print(f"wrote {out} with fast paths: " + "; ".join(
        f"{r.output} (log-cos RMSE {r.hemisphere_logcos_rmse:.4f} against the model, relative cost {r.relative_cost:.2f})"
        for r in reports))


def main(argv: list[str] | None = None, prog: str = "neuralbrdf export") -> int:
    args = build_parser(prog).parse_args(argv)
    from neuralbrdf.lod.fast_paths import FastPathError

    try:
        with command_inputs():  # --out may not be the checkpoint or model it reads (neuralbrdf.atomic)
            _export(args)
    except InputError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except (ExportValidationError, FastPathError) as error:
        print(f"error: {args.out} not written: {error}", file=sys.stderr)
        return 1
    return 0
