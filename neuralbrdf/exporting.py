"""The one export path: a checkpoint (or a model file that gets fast paths added) to one validated
``.onnx`` file (docs/formats.md#onnx-model-files) — what ``neuralbrdf export``, :func:`neuralbrdf.export` and
:meth:`neuralbrdf.FitResult.export` all run, so that the three write the same file and print the
same checks.

1. the checkpoint's kind (:func:`neuralbrdf.kinds.load_exportable`) builds the model on
   directions; :func:`~neuralbrdf.onnx_export.write_model` traces it, checks it against PyTorch
   with onnxruntime and against the file contract;
2. its fast paths (:mod:`neuralbrdf.lod.fast_paths`) are distilled from that file and embedded
   in it.

Defaults, the same at every door (docs/export-render.md):

* a spectral model whose range holds the CIE observer's weight over 400–700 nm gets its RGB head
  ``f_rgb`` (``rgb_head=True``, ``--no-rgb-head`` to leave it out; outside that range a warning
  says why it gets none): RGB renders then evaluate one small network per query instead of the model at every
  wavelength of the sRGB rule — the file's renders in RGB variants are that head's (its recorded
  error against the model's sRGB is printed and checked against a bound);
* a compact copy ``f_fast`` for the kinds that render much slower than an analytic model without
  one — the spectral NLB (:attr:`~neuralbrdf.kinds.Kind.fast_by_default`; ``fast=False``,
  ``--no-fast`` to leave it out) — and for any model with ``fast=True`` (``--fast``);
* fast-path settings from the shipped ``configs/lod/default.yaml`` (``config``).

A fast path added unasked — the RGB head, or ``f_fast`` by default — is an extra that never costs
the model: when its student misses its bound the model is written without it and a warning says
so in one line.  One asked for (``fast=True``, or fast paths added to a model file) fails the
export as before: nothing is written.

Every step is deterministic — seeded distillation, costs counted rather than timed, metadata that
names no temporary file — so one checkpoint exported twice with the same options gives the same
bytes.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

from neuralbrdf import kinds
from neuralbrdf.atomic import atomic_path, check_outputs, command_inputs
from neuralbrdf.errors import InputError
from neuralbrdf.onnx_contract import OUTPUT_FAST, OUTPUT_RGB, FastPath
from neuralbrdf.onnx_export import ExportReport, write_model

PathLike = str | os.PathLike[str]


@dataclass(frozen=True)
class Exported:
    """What :func:`export_model` wrote: the file, the model's own check (``None`` when fast paths
    were added to an existing file) and each fast path added."""

    path: Path
    model: ExportReport | None
    fast_paths: tuple[FastPath, ...]


def fast_paths_wanted(kind: str, metadata, wavelength_range_nm, present, fast: bool | None,
                      rgb_head: bool) -> tuple[tuple[str, ...], str | None]:
    """The fast paths to add to a model of ``kind`` (with this ``metadata`` and wavelength range, ``None``
    for RGB, with the fast paths ``present``); ``fast`` ``None``: ``f_fast`` when the kind gets it by
    default (:meth:`~neuralbrdf.kinds.Kind.fast_default`).  And why the RGB head is left out, when a
    spectral model outside the colour conversion's range would get one
    (:func:`~neuralbrdf.lod.fast_paths.rgb_head_problem`), else ``None``."""
    from neuralbrdf.lod.fast_paths import rgb_head_problem

    wanted, problem = [], None
    if wavelength_range_nm is not None and rgb_head and OUTPUT_RGB not in present:
        problem = rgb_head_problem(wavelength_range_nm)
        if problem is None:
            wanted.append(OUTPUT_RGB)
    if fast or (fast is None and kinds.get(kind).fast_default(metadata) and OUTPUT_FAST not in present):
        wanted.append(OUTPUT_FAST)
    return tuple(wanted), problem


def model_line(report: ExportReport, written: bool) -> str:
    """The printed check of an exported graph: onnxruntime against PyTorch."""
    return (f"{'wrote ' + str(report.path) if written else 'exported'}: {report.kind} model of {report.material!r}; "
            f"onnxruntime vs PyTorch on {report.n_probes} probes: max error {report.max_abs_error:.2g} sr^-1, "
            f"{report.max_rel_error:.2g} relative")


def fast_paths_line(out: Path, reports) -> str:
    """The printed check of the fast paths added: error against the model, counted cost."""
    return f"wrote {out} with fast paths: " + "; ".join(
        f"{r.output} (log-cos RMSE {r.hemisphere_logcos_rmse:.4f} against the model, cost {r.relative_cost:.2f} of "
        f"{'the sRGB rule' if r.output == OUTPUT_RGB else 'f'} in Dr.Jit operations)" for r in reports)


def export_model(out: PathLike, *, checkpoint: PathLike | None = None, model: PathLike | None = None,
                 material: str | None = None, fast: bool | None = None, rgb_head: bool = True, config: str = "default",
                 log=print) -> Exported:
    """Export ``checkpoint`` — or add fast paths to the model file ``model`` — to ``out`` (module
    docstring); ``material`` picks one of a latent fit's materials; ``log`` gets each printed line.

    Raises :class:`~neuralbrdf.errors.InputError` (bad input: an unreadable or foreign checkpoint or
    model, an unknown material, nothing to add), :class:`~neuralbrdf.onnx_export.ExportValidationError`
    or :class:`~neuralbrdf.lod.fast_paths.FastPathError` (the graph or a fast path failed its check);
    nothing is written then."""
    from neuralbrdf.lod.config import load_lod_config
    from neuralbrdf.lod.fast_paths import FastPathError, add_fast_paths

    if (checkpoint is None) == (model is None):
        raise InputError("export a checkpoint or add fast paths to a model file: give one of them")
    out = Path(out)
    with command_inputs():  # out may not be the checkpoint or model it reads (neuralbrdf.atomic)
        if model is not None:
            if material is not None:
                raise InputError("a material goes with a checkpoint (a model file holds one material)",
                                 key="--material")
            parent = kinds.load_model(model)
            wanted, problem = fast_paths_wanted(parent.kind, parent.metadata, parent.wavelength_range_nm,
                                                parent.fast_paths, fast, rgb_head)
            if not wanted:
                why = problem or ("it has its RGB head already" if OUTPUT_RGB in parent.fast_paths else
                                  "an RGB head is for spectral models" if parent.wavelength_range_nm is None else
                                  "no RGB head was asked for")
                raise InputError(f"nothing to add: {why}; ask for f_fast with fast (--fast)", path=model)
        else:
            exportable = kinds.load_exportable(checkpoint, material)
            wanted, problem = fast_paths_wanted(exportable.kind, exportable.metadata, exportable.wavelength_range_nm,
                                                (), fast, rgb_head)
        check_outputs(out)  # after the inputs are read: an output may not be one of them
        if problem is not None:
            warnings.warn(problem, stacklevel=2)
        settings = load_lod_config(config).fast_paths if wanted else None
        # the model alone goes to a working folder under out's own name, so no temporary name reaches the file
        with tempfile.TemporaryDirectory(prefix="neuralbrdf-export-") as work:
            source = Path(model) if model is not None else out if not wanted else Path(work) / out.name
            report = None
            if checkpoint is not None:
                report = write_model(exportable, source)
                log(model_line(report, written=source == out))
            if not wanted:
                return Exported(out, report, ())
            # the extras a checkpoint's export adds unasked: each may be left out, never the model
            optional = set() if checkpoint is None else {OUTPUT_RGB} | ({OUTPUT_FAST} if fast is None else set())
            while wanted:
                try:
                    reports = add_fast_paths(source, out, wanted, settings, log=lambda line: log(f"  {line}"))
                    break
                except FastPathError as error:
                    if error.output not in optional:
                        raise
                    warnings.warn(f"{out}: written without the optional fast path {error.output}: {error}",
                                  stacklevel=2)
                    wanted = tuple(output for output in wanted if output != error.output)
            else:
                with atomic_path(out) as tmp:
                    shutil.copyfile(source, tmp)
                log(f"wrote {out} without fast paths")
                return Exported(out, report, ())
    log(fast_paths_line(out, reports))
    return Exported(out, report, tuple(reports))
