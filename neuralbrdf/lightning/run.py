"""Training runs: the ``train.py`` command line, its run directory and ``metrics.json``.

``neuralbrdf train fit|validate|test --config X [--key value ...]`` (or ``python train.py …``;
``X`` a shipped config's name or any YAML file, :mod:`neuralbrdf.configs_dir`) is a
:class:`~pytorch_lightning.cli.LightningCLI` in subclass mode: the model and the data module are
named by ``class_path`` in the YAML, so every model kind (spectral MLP, ABC, NLB) trains through
the same entry point; any option can be overridden on the command line (``--data.path FILE``,
``--trainer.max_epochs 5``).

This module is the command (:func:`main`, :func:`train`); it is built from
:mod:`~neuralbrdf.lightning.train_cli` (the LightningCLI subclass), :mod:`~neuralbrdf.lightning.run_dir`
(run directories), :mod:`~neuralbrdf.lightning.metrics_json` and :mod:`~neuralbrdf.lightning.fit_health`
(the callbacks), :mod:`~neuralbrdf.lightning.checkpoint_io` (the atomic checkpoint writer) and
:mod:`~neuralbrdf.lightning.failures` (how a command ended).

**Run directory.** ``--run_dir DIR``, else ``trainer.default_root_dir`` if the config sets it,
else — for ``validate``/``test`` with ``--ckpt_path RUN/checkpoints/X.ckpt`` — ``RUN``, else
``runs/<config stem>/<YYYYmmdd-HHMMSS>`` (a ``-1``, ``-2``, … suffix if taken).  A run writes
there:

* ``config.yaml`` — the resolved config (``SaveConfigCallback``);
* ``checkpoints/`` — from the config's ``ModelCheckpoint`` (best and last), each written
  whole or not at all (:class:`~neuralbrdf.lightning.checkpoint_io.AtomicCheckpointIO`);
* ``metrics.csv`` and ``hparams.yaml`` — the :class:`~pytorch_lightning.loggers.CSVLogger`
  (unless the config names another logger), written at every logged step;
* ``metrics.json`` — :class:`~neuralbrdf.lightning.metrics_json.MetricsJson`.

``validate`` and ``test`` write their ``config.yaml``/``metrics.csv`` under ``<run>/validate/``
and ``<run>/test/`` so the training logs survive, and merge their metrics into the same
``metrics.json``.

**One command per run directory.** Every ``fit``, ``validate`` and ``test`` holds an exclusive lock
on its run directory from start to end (:func:`~neuralbrdf.folder_lock.folder_lock`): a second
command on the same directory while one runs is refused at once with status 2 (two fits into one
``--run_dir`` would interleave their logs; two ``--overwrite`` fits would each replace the other).

**A run never overwrites another run.** ``fit`` into a directory that already holds a run
(:data:`~neuralbrdf.lightning.run_dir.RUN_ENTRIES`) is refused unless ``--resume`` (continue from
its ``checkpoints/last.ckpt``, or ``--ckpt_path``; ``metrics.csv`` is appended to,
``metrics.json`` merged and ``fit/wall_time_s`` summed over the sessions) or ``--overwrite``
(the new run is written beside the old one and put in its place when whole: a fit that failed
is whole, an interrupted or killed one leaves the old run).  A start that fails (bad input)
leaves no run directory behind.  What a killed command left in the directory is repaired by the
next one, which says so (:mod:`neuralbrdf.lightning.run_dir`).  ``metrics.json`` says
``"status": "running"`` while a fit runs, so a fit that was killed says so.

**Settings that make a fit endless or meaningless** (``trainer.max_epochs: -1`` without another
limit, a learning rate of 0, …) are refused before the run directory exists
(:mod:`neuralbrdf.lightning.fit_settings`).

**A failed fit is a failure** (:class:`~neuralbrdf.lightning.fit_health.FitHealth`, added to every
``fit``): a non-finite training loss or monitored metric, a network whose gradients are all
exactly zero for a whole epoch (dead or saturated units, e.g. after a too-large learning rate), or
a module that reports its own failure (``fit_failure()``, e.g. the ABC fit), or a
:data:`~neuralbrdf.lightning.failures.DATA_FAILURES` error
raised inside the fit ends the command with status 1 and one line ``neuralbrdf train: error: fit
failed: <cause>``; ``metrics.json`` then holds ``"status": "failed"`` and ``"cause"``, and no
checkpoint named ``best*`` is left (``last.ckpt`` stays, for inspection).  A successful fit
writes ``"status": "ok"``; a fit stopped by Ctrl-C or SIGTERM ``"status": "interrupted"`` (its
checkpoints stay, to ``--resume`` from; exit status 130 or 143); a fit the machine stopped (a
full disk: exit status 3) ``"status": "environment"`` with its ``"cause"``.  ``metrics.json`` is strict
JSON: a non-finite number is written as ``null``.

Bad input (a missing or malformed ``--data.path``, a missing or truncated checkpoint, a
configuration file that is not YAML, an invalid hyper-parameter raised as
:class:`~neuralbrdf.errors.InputError`) ends the command with a one-line message and status 2; a
file the machine could not write (a full disk) with one naming it and status 3
(:mod:`neuralbrdf.errors`).
"""

from __future__ import annotations

import contextlib
import json
import logging
import sys
import warnings
from pathlib import Path

from jsonargparse import ArgumentError

from neuralbrdf.atomic import command_inputs
from neuralbrdf.errors import (EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK, EnvironmentFailure, FitFailed, InputError,
                               Interrupted, error_line, exit_status)
from neuralbrdf.configs_dir import config_not_found, overlay_base, resolve_config
from neuralbrdf.console import clean_warnings
from neuralbrdf.lightning.common import WritesKind
from neuralbrdf.lightning.config_errors import describe as describe_config_error
from neuralbrdf.lightning.failures import run_failure
from neuralbrdf.lightning.metrics_json import METRICS_FILE
from neuralbrdf.lightning.train_cli import PROG, NeuralBrdfCLI, config_args
from neuralbrdf.lightning.train_help import help_text


def _resolve_config_files(args: list[str]) -> list[str]:
    """``args`` with each config named by a shipped config's name replaced by its file
    (:func:`~neuralbrdf.configs_dir.resolve_config`) and an overlay's base config put before it when
    not given (:func:`~neuralbrdf.configs_dir.overlay_base`); every config must be a readable UTF-8
    text file (jsonargparse shows a traceback for a binary one)."""
    rest, names = config_args(args)
    configs: list[Path] = []
    for name in names:
        path = resolve_config(name)
        base = overlay_base(path) if path.is_file() else None
        if base is not None and base.resolve() not in {c.resolve() for c in configs}:
            configs.append(base)
        configs.append(path)
    # the subcommand stays first; the configs come before every other option, which override them
    head = rest[:1] if rest and not rest[0].startswith("-") else []
    resolved = [*head, *(a for path in configs for a in ("--config", str(path))), *rest[len(head):]]
    for path in configs:
        try:
            Path(path).read_bytes().decode("utf-8")
        except FileNotFoundError:
            raise config_not_found(path) from None
        except UnicodeDecodeError as error:
            raise InputError(f"not a YAML configuration: not UTF-8 text ({error.reason} at byte {error.start})", path=path) from None
        except OSError as error:
            raise InputError(f"cannot read the configuration ({error.strerror or error})", path=path) from None
    return resolved


#: Loggers of Lightning's start-up lines (GPU/TPU/HPU available, tips), silenced unless --verbose.
LIGHTNING_LOGGERS = ("pytorch_lightning", "lightning", "lightning_fabric", "lightning.pytorch")


@contextlib.contextmanager
def _quiet(verbose: bool):
    """Notices that say nothing about the run off (:func:`_ignore_noise`) and, unless ``verbose``,
    Lightning's INFO lines and library deprecation notices; restored afterwards (other warnings
    still show)."""
    loggers = [logging.getLogger(name) for name in LIGHTNING_LOGGERS]
    levels = [logger.level for logger in loggers]
    with warnings.catch_warnings():
        _ignore_noise()
        if not verbose:
            for logger in loggers:
                logger.setLevel(logging.WARNING)
            warnings.filterwarnings("ignore", category=DeprecationWarning)
            warnings.filterwarnings("ignore", category=FutureWarning)
            warnings.filterwarnings("ignore", message=r".*(smaller than the logging interval|LeafSpec).*")
        try:
            yield
        finally:
            for logger, level in zip(loggers, levels):
                logger.setLevel(level)


def _failed_run(exc: BaseException) -> str:
    """`` (run: DIR)`` for a failed fit whose run directory holds its metrics.json, else ``""``."""
    run_dir = getattr(exc, "neuralbrdf_run_dir", None)
    return f" (run: {run_dir}; its {METRICS_FILE} holds the cause)" if run_dir and (run_dir / METRICS_FILE).is_file() else ""


def fitted_checkpoint(run_dir: Path) -> Path | None:
    """The checkpoint a finished fit leaves to export: ``checkpoints/best.ckpt``, or a latent
    fit's ``fitted.ckpt``; ``None`` if there is none (a failed fit)."""
    checkpoints = sorted((Path(run_dir) / "checkpoints").glob("*.ckpt"))
    return next((c for c in checkpoints if c.stem in ("best", "fitted")), None)


def _summary(cli: NeuralBrdfCLI) -> str:
    """Where a finished run is, its fit metrics and how to export it."""
    lines = [f"run: {cli.run_dir}"]
    path = cli.run_dir / METRICS_FILE
    metrics = json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}
    shown = [(k, v) for k, v in sorted(metrics.items()) if isinstance(v, float) and k.startswith(
        ("fit/inplane", "fit/hemisphere", "fit/plan", "fit/val/", "test/", "validate/", "fit/materials/"))]
    if shown:
        lines.append("metrics: " + ", ".join(f"{k} {v:.4g}" for k, v in shown[:12])
                     + (f" (+{len(shown) - 12} more in {path})" if len(shown) > 12 else ""))
    best = fitted_checkpoint(cli.run_dir) if cli.subcommand == "fit" else None
    if best is not None:
        chosen = getattr(cli.trainer, "checkpoint_callback", None)
        score = getattr(chosen, "best_model_score", None)
        on = f" (chosen on {chosen.monitor}: {float(score):.4g}; the fit/val metrics above are the last epoch's)" if (
            score is not None and chosen.monitor and best.stem == "best") else ""
        lines.append(f"checkpoint: {best}{on}")
    if best is not None and isinstance(cli.model, WritesKind):  # a fitted model, not a pretraining
        names = list(getattr(cli.model, "material_names", None) or [])
        material = f" --material NAME (one file per material: {', '.join(names)})" if len(names) > 1 else ""
        lines.append(f"export: neuralbrdf export --ckpt {best} --out MODEL.onnx{material}")
    return "\n".join(lines)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``train.py``; returns the exit status (2 on bad input).  Warnings are
    printed as one line each (:func:`neuralbrdf.console.clean_warnings`)."""
    with clean_warnings():
        return _main(args)


def _ignore_noise() -> None:
    """Warning filters for notices of Lightning and jsonargparse that say nothing about the run."""
    # The data are in-memory tensors: worker processes would only add start-up time.
    warnings.filterwarnings("ignore", message=r".*does not have many workers.*")
    # The CSV log shares the run directory with config.yaml, written just before it.
    warnings.filterwarnings("ignore", message=r"Experiment logs directory .* exists and is not empty")
    # validate/test restore a checkpoint whose ModelCheckpoint state names the fit's folder; the
    # evaluation stages write no checkpoints, so the "dirpath has changed" notice is noise.
    warnings.filterwarnings("ignore", message=r"The dirpath has changed from")
    # ``args`` is always given (config names resolved), also when run from train.py's command line.
    warnings.filterwarnings("ignore", message=r"LightningCLI's args parameter is intended")
    # The ABC fit runs its own bounded optimiser (SciPy), not a torch one.
    warnings.filterwarnings("ignore", message=r".*configure_optimizers` returned `None`")


def train(args: list[str], verbose: bool = False) -> NeuralBrdfCLI:
    """Run ``args`` (``fit|validate|test --config X [--key value ...]``) in this process and return
    the finished LightningCLI (its ``run_dir``, ``model``, ``trainer``).  Raises
    :class:`~neuralbrdf.errors.InputError` for bad input, a configuration that does not parse
    included (one line: :mod:`~neuralbrdf.lightning.config_errors`), :class:`FitFailed` for a
    fit that ran and failed (its ``neuralbrdf_run_dir`` names the run whose metrics.json says why),
    :class:`~neuralbrdf.errors.EnvironmentFailure` for a file the machine could not write and
    :class:`~neuralbrdf.errors.Interrupted` for Ctrl-C or SIGTERM (which Lightning turns into
    ``SystemExit``)."""
    try:
        with _quiet(verbose):
            args = _resolve_config_files(list(args))
            with command_inputs():
                return NeuralBrdfCLI(args=args)
    except FitFailed:
        raise
    except ArgumentError as exc:  # the configuration does not parse: one line naming the key
        parser = getattr(exc, "neuralbrdf_parsers", {}).get(args[0] if args else "")
        raise describe_config_error(str(exc), args, config_args(args)[1], parser) from None
    except BaseException as exc:
        failure = run_failure(exc)
        if failure is None:
            raise
        raise failure from (exc if isinstance(failure, FitFailed) else None)


def _main(args: list[str] | None) -> int:
    args = sys.argv[1:] if args is None else list(args)
    if not args or args[0] in ("-h", "--help"):
        print(help_text(), file=sys.stdout if args else sys.stderr)
        return EXIT_OK if args else EXIT_BAD_INPUT
    try:
        cli = train([arg for arg in args if arg != "--verbose"], verbose="--verbose" in args)
    except FitFailed as failure:
        print(error_line(PROG, f"fit failed: {failure}{_failed_run(failure)}"), file=sys.stderr)
        return EXIT_FAILED
    except (InputError, EnvironmentFailure, Interrupted) as error:
        print(error_line(PROG, error), file=sys.stderr)
        return exit_status(error)
    if cli.subcommand is not None and cli.run_dir is not None:
        print(_summary(cli), file=sys.stderr)
    return EXIT_OK
