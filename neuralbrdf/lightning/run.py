"""Training runs: the ``train.py`` command line, its run directory and ``metrics.json``.

``neuralbrdf train fit|validate|test --config X [--key value ...]`` (or ``python train.py …``;
``X`` a shipped config's name or any YAML file, :mod:`neuralbrdf.configs_dir`) is a
:class:`~pytorch_lightning.cli.LightningCLI` in subclass mode: the model and the data module are
named by ``class_path`` in the YAML, so every model kind (spectral MLP, ABC, NLB) trains through
the same entry point; any option can be overridden on the command line (``--data.path FILE``,
``--trainer.max_epochs 5``).

**Run directory.** ``--run_dir DIR``, else ``trainer.default_root_dir`` if the config sets it,
else — for ``validate``/``test`` with ``--ckpt_path RUN/checkpoints/X.ckpt`` — ``RUN``, else
``runs/<config stem>/<YYYYmmdd-HHMMSS>`` (a ``-1``, ``-2``, … suffix if taken).  A run writes
there:

* ``config.yaml`` — the resolved config (``SaveConfigCallback``);
* ``checkpoints/`` — from the config's ``ModelCheckpoint`` (best and last), each written
  whole or not at all (:class:`AtomicCheckpointIO`);
* ``metrics.csv`` and ``hparams.yaml`` — the :class:`~pytorch_lightning.loggers.CSVLogger`
  (unless the config names another logger), written at every logged step;
* ``metrics.json`` — :class:`MetricsJson`.

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

**A failed fit is a failure** (:class:`FitHealth`, added to every ``fit``): a non-finite
training loss or monitored metric, a network whose gradients are all exactly zero for a whole
epoch (dead or saturated units, e.g. after a too-large learning rate), or a module that reports
its own failure (``fit_failure()``, e.g. the ABC fit), or a :data:`DATA_FAILURES` error
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
import math
import os
import shutil
import signal
import sys
import time
import warnings
from collections.abc import Mapping
from datetime import datetime
from pathlib import Path

import pytorch_lightning as pl
import torch
from jsonargparse import ActionYesNo, ArgumentError
from pytorch_lightning.callbacks import ModelCheckpoint
from pytorch_lightning.cli import LightningCLI
from pytorch_lightning.loggers import CSVLogger
from pytorch_lightning.plugins.io import TorchCheckpointIO
from pytorch_lightning.utilities.exceptions import SIGTERMException

from neuralbrdf.atomic import atomic_write, command_inputs, environment_oserror
from neuralbrdf.errors import (EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK, EnvironmentFailure, FitFailed, InputError,
                               Interrupted, error_line, exit_status, one_line)
from neuralbrdf.checkpoints import read_checkpoint, write_checkpoint
from neuralbrdf.configs_dir import config_not_found, overlay_base, resolve_config
from neuralbrdf.console import clean_warnings, on_terminal
from neuralbrdf.folder_lock import folder_lock, outermost_missing
from neuralbrdf.lightning.common import WritesKind
from neuralbrdf.lightning.config_errors import describe as describe_config_error
from neuralbrdf.lightning.fit_settings import check_fit_settings
from neuralbrdf.lightning.progress import EpochLines
from neuralbrdf.lightning.run_dir import (RUN_ENTRIES, holds_run, join_logs, recover, remove_entry, run_entries,
                                          set_aside_log, staging_dir, swap_in)
from neuralbrdf.lightning.train_help import help_text

#: The command as a user types it, in its error lines (:func:`~neuralbrdf.errors.error_line`).
PROG = "neuralbrdf train"
METRICS_FILE = "metrics.json"
RUNS_ROOT = Path("runs")
SUBCOMMANDS = ("fit", "validate", "test")
STATUS_OK, STATUS_FAILED, STATUS_RUNNING, STATUS_INTERRUPTED = "ok", "failed", "running", "interrupted"
#: A fit the machine stopped (a full disk, a file it could not write): not the fit's failure.
STATUS_ENVIRONMENT = "environment"
#: ``--ckpt_path`` values Lightning resolves itself rather than as files.
LIGHTNING_CKPT_NAMES = ("best", "last", "hpc", "registry")


def _number(value) -> float | int:
    value = value.item() if isinstance(value, torch.Tensor) else value
    return value if isinstance(value, int) else float(value)


def strict_json(value):
    """``value`` with every non-finite float replaced by ``None`` (JSON has no NaN/Infinity)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {key: strict_json(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict_json(item) for item in value]
    return value


def write_metrics(path: Path, metrics: dict, merge: bool) -> None:
    """Write ``metrics`` (merged into the existing file if ``merge``) as strict JSON, atomically."""
    merged = {}
    if merge and path.exists():
        try:
            merged = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(f"cannot merge metrics into it: not valid JSON ({exc})", path=path) from None
    merged.update(metrics)
    with atomic_write(path) as handle:
        json.dump(strict_json(merged), handle, indent=2, sort_keys=True, allow_nan=False)
        handle.write("\n")


#: Errors raised inside a fit that mean the data cannot support it (e.g. no measured value above
#: the metric's floor in all-zero data): reported like :class:`FitFailed`, in one line, exit 1.
#: Any other exception is a bug and keeps its traceback (``metrics.json`` still says failed).
DATA_FAILURES = (ValueError, ArithmeticError)


def _is_resuming(trainer: pl.Trainer) -> bool:
    return trainer.ckpt_path is not None and trainer.state.fn == "fit"


class MetricsJson(pl.Callback):
    """Writes the final metrics of every stage to ``<trainer.default_root_dir>/metrics.json``.

    Keys are ``<stage>/<metric>``.  After ``fit``: every logged metric as ``fit/<name>``
    (``fit/train/loss``, ``fit/val/rel_rmse_glossy_median`` of the last epoch) plus
    ``fit/best_model_score``, ``fit/best_model_path`` (relative to the run directory if inside it),
    ``fit/epochs``, ``fit/wall_time_s`` (from the module's set-up, where a latent fit screens its
    starts, to the end of the fit; data loading excluded) and whatever the module's optional
    ``metrics_json_extras()`` returns (non-scalar results such as fitted parameters); ``fit`` starts a new file (a new model makes earlier
    evaluations stale).  After ``validate``/``test``: the logged ``val/x``/``test/x`` as
    ``validate/x``/``test/x``, merged into the existing file.  Writes are atomic.
    """

    def __init__(self, filename: str = METRICS_FILE) -> None:
        self.filename = filename
        self._fit_started = 0.0
        self._earlier_wall_time_s = 0.0

    def path(self, trainer: pl.Trainer) -> Path:
        return Path(trainer.default_root_dir) / self.filename

    def _write(self, trainer: pl.Trainer, metrics: dict, merge: bool) -> None:
        if trainer.is_global_zero:
            write_metrics(self.path(trainer), metrics, merge)

    def setup(self, trainer: pl.Trainer, pl_module: pl.LightningModule, stage: str) -> None:
        # the clock starts before the module's own set-up: a latent fit screens its starts there
        if stage == "fit":
            self._fit_started = time.perf_counter()

    def on_fit_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self._earlier_wall_time_s = 0.0
        path = self.path(trainer)
        if _is_resuming(trainer) and path.exists():  # a resumed run: its time so far counts
            try:
                earlier = json.loads(path.read_text(encoding="utf-8")).get("fit/wall_time_s")
            except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
                earlier = None
            if isinstance(earlier, (int, float)) and math.isfinite(earlier):
                self._earlier_wall_time_s = float(earlier)
        # until the fit ends: a run whose fit was killed says so (its checkpoints stay, to --resume)
        self._write(trainer, {"status": STATUS_RUNNING, "cause": None}, merge=_is_resuming(trainer))

    def on_fit_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        metrics = {f"fit/{name}": _number(value) for name, value in trainer.callback_metrics.items()}
        metrics["status"] = STATUS_OK
        metrics["cause"] = None
        metrics["fit/epochs"] = trainer.current_epoch
        extras = getattr(pl_module, "metrics_json_extras", None)
        if extras is not None:
            metrics.update({f"fit/{name}": value for name, value in extras().items()})
        metrics["fit/wall_time_s"] = self._earlier_wall_time_s + time.perf_counter() - self._fit_started
        checkpoint = trainer.checkpoint_callback
        if checkpoint is not None and checkpoint.best_model_path:
            best, root = Path(checkpoint.best_model_path).resolve(), Path(trainer.default_root_dir).resolve()
            metrics["fit/best_model_path"] = str(best.relative_to(root) if best.is_relative_to(root) else best)
            if checkpoint.best_model_score is not None:
                metrics["fit/best_model_score"] = _number(checkpoint.best_model_score)
        # A resumed fit adds to its run's metrics; a new fit starts a new file.
        self._write(trainer, metrics, merge=_is_resuming(trainer))

    def _evaluation_end(self, trainer: pl.Trainer, stage: str) -> None:
        metrics = {
            f"{stage}/{name.split('/', 1)[-1]}": _number(value) for name, value in trainer.callback_metrics.items()
        }
        self._write(trainer, metrics, merge=True)

    def on_validation_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        if trainer.state.fn == "validate":
            self._evaluation_end(trainer, "validate")

    def on_test_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self._evaluation_end(trainer, "test")


#: Validation metrics whose name holds this are relative errors (report Eq. 4.3): predicting 0
#: everywhere scores exactly 1 ...
RELATIVE_ERROR_MARK = "rel_rmse"
#: ... so a best score at or above this marks a model no better than predicting 0: one whose
#: output collapsed to 0 (a dead network), or one that never came within 10 % of the signal (too few
#: optimiser steps; an output that overshoots scores above 1).  The full study's worst kept fit
#: scores 0.56 at its best; the 3x10 spectral MLP fitted to the RGL felt's 57 DS3 pairs in 30 Adam
#: steps (a grey sphere, image ΔE2000 7.3) scores 0.99.
NO_BETTER_THAN_ZERO = 0.9


class FitHealth(pl.Callback):
    """Ends a fit that is not producing a model with :class:`FitFailed` (module docstring).

    Checks, in order of occurrence: every training loss is finite; some parameter gradient is
    non-zero in every epoch (automatic optimisation only); the monitored metric of every
    validation is finite; after training, every validation relative error (``val/*rel_rmse*``,
    monitored or not) came below :data:`NO_BETTER_THAN_ZERO` at its best (predicting 0 scores 1),
    and the module's optional ``fit_failure()`` returns no reason.  On any error of a started fit (except bad input) it removes the ``best*``
    checkpoints and writes ``metrics.json`` with ``"status": "failed"`` and ``"cause"``.
    """

    def __init__(self, filename: str = METRICS_FILE) -> None:
        self.filename = filename
        self._steps = 0
        self._learning = False
        self._best_relative_errors: dict[str, float] = {}

    def on_train_epoch_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self._steps, self._learning = 0, False

    def on_after_backward(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self._steps += 1
        if not self._learning:
            self._learning = any(p.grad is not None and bool(p.grad.any()) for p in pl_module.parameters())

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        loss = outputs.get("loss") if isinstance(outputs, Mapping) else outputs
        if isinstance(loss, torch.Tensor) and not bool(torch.isfinite(loss).all()):
            raise FitFailed(
                f"non-finite training loss ({loss.detach().flatten()[0].item()}) in epoch {trainer.current_epoch}, "
                f"step {trainer.global_step}"
            )

    def on_train_epoch_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        if self._steps and not self._learning:
            raise FitFailed(
                f"the network stopped learning: every gradient was exactly 0 in epoch {trainer.current_epoch} "
                f"({self._steps} steps; dead or saturated units, e.g. after a too-large learning rate)"
            )

    def on_validation_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        if trainer.sanity_checking or trainer.state.fn != "fit":
            return
        for name, value in trainer.callback_metrics.items():
            if name.startswith("val/") and RELATIVE_ERROR_MARK in name and "excluded" not in name:
                value = _number(value)
                if math.isfinite(value):
                    self._best_relative_errors[name] = min(value, self._best_relative_errors.get(name, math.inf))
        for callback in trainer.checkpoint_callbacks:
            value = trainer.callback_metrics.get(callback.monitor) if callback.monitor else None
            if value is not None and not math.isfinite(_number(value)):
                raise FitFailed(
                    f"the monitored metric {callback.monitor} is {_number(value)} after epoch {trainer.current_epoch} "
                    "(no sample to score? all-zero data?)"
                )

    def on_train_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        worst = max(self._best_relative_errors.items(), key=lambda item: item[1], default=None)
        if worst is not None and worst[1] >= NO_BETTER_THAN_ZERO:
            name, best = worst
            raise FitFailed(
                f"the model is no better than predicting 0 (best {name} = {best:.4g}, where predicting 0 "
                f"scores 1 and a fit must come below {NO_BETTER_THAN_ZERO:g}): dead or saturated units (e.g. a "
                "too-large learning rate) or too few optimiser steps for the data"
            )
        fit_failure = getattr(pl_module, "fit_failure", None)
        reason = fit_failure() if fit_failure is not None else None
        if reason:
            raise FitFailed(reason)

    def on_exception(self, trainer: pl.Trainer, pl_module: pl.LightningModule, exception: BaseException) -> None:
        if trainer.state.fn != "fit" or _input_error(exception) is not None or not trainer.is_global_zero:
            return
        signal_number = _interruption(exception)
        if signal_number is not None:  # not a failure: the checkpoints stay, to --resume from
            with contextlib.suppress(EnvironmentFailure):
                write_metrics(Path(trainer.default_root_dir) / self.filename,
                              {"status": STATUS_INTERRUPTED, "cause": f"interrupted by {_signal_name(signal_number)}",
                               "fit/epochs": trainer.current_epoch}, merge=True)
            return
        cause = str(exception) if isinstance(exception, FitFailed) else one_line(exception)
        if isinstance(exception, Exception):
            exception.neuralbrdf_fit_failure = cause  # read by main() for the one-line report
        for callback in trainer.checkpoint_callbacks:
            if isinstance(callback, ModelCheckpoint) and callback.dirpath and os.path.isdir(callback.dirpath):
                for best in Path(callback.dirpath).glob("best*.ckpt"):
                    best.unlink(missing_ok=True)
        metrics = {f"fit/{name}": _number(value) for name, value in trainer.callback_metrics.items()}
        status = STATUS_FAILED if _environment_failure(exception) is None else STATUS_ENVIRONMENT
        metrics.update({"status": status, "cause": cause, "fit/epochs": trainer.current_epoch})
        metrics.pop("fit/best_model_path", None)
        extras = getattr(pl_module, "metrics_json_extras", None)
        if extras is not None:
            metrics.update({f"fit/{name}": value for name, value in extras().items()})
        path = Path(trainer.default_root_dir) / self.filename
        try:
            if not _is_resuming(trainer):
                path.unlink(missing_ok=True)  # a new fit's metrics.json describes only it
            write_metrics(path, metrics, merge=True)
            if not _is_resuming(trainer):
                return
            # metrics.json of the resumed run may name the best checkpoint just removed.
            merged = json.loads(path.read_text(encoding="utf-8"))
            merged.pop("fit/best_model_path", None)
            merged.pop("fit/best_model_score", None)
            write_metrics(path, merged, merge=False)
        except EnvironmentFailure:
            pass  # the disk that stopped the fit keeps its record too: the command's error line says why


class AtomicCheckpointIO(TorchCheckpointIO):
    """Checkpoints written whole or not at all (:func:`~neuralbrdf.checkpoints.write_checkpoint`): a
    run killed while saving never leaves a truncated ``last.ckpt`` or ``best.ckpt``, and a full
    disk is one line naming the file.

    ``moved``: ``(folder, final folder)`` of a run written in a staging folder and moved into
    place when whole (``fit --overwrite``, :mod:`~neuralbrdf.lightning.run_dir`): the callbacks'
    state records the paths the checkpoints will have, so that a later ``--resume`` keeps its
    best checkpoint's score.
    """

    def __init__(self, moved: tuple[Path, Path] | None = None) -> None:
        super().__init__()
        # as given and resolved: Lightning keeps the paths in the form it was handed them
        self.moved = [] if moved is None else [(str(a), str(b)) for a, b in (moved, [p.resolve() for p in moved])]

    def _moved(self, value):
        if isinstance(value, str):
            for old, new in self.moved:
                if value == old or value.startswith(old + os.sep):
                    return new + value[len(old):]
        if isinstance(value, Mapping):
            return {self._moved(key): self._moved(item) for key, item in value.items()}
        return value

    def save_checkpoint(self, checkpoint: dict, path, storage_options=None) -> None:
        if storage_options is not None:
            raise TypeError(f"{type(self).__name__} takes no storage_options")
        if self.moved and "callbacks" in checkpoint:
            checkpoint = {**checkpoint, "callbacks": self._moved(checkpoint["callbacks"])}
        write_checkpoint(checkpoint, path, replaces_input=True)  # a resumed run replaces its last.ckpt


def _fresh_run_dir(config_paths) -> tuple[Path, Path]:
    """A new folder ``runs/<config stem>/<timestamp>[-N]``, created here (two commands started in the
    same second get two folders), and the outermost folder created for it."""
    stem = Path(str(config_paths[-1])).stem if config_paths else "run"
    base = RUNS_ROOT / stem / datetime.now().strftime("%Y%m%d-%H%M%S")
    candidate, suffix = base, 0
    while True:
        created = outermost_missing(candidate)
        try:
            candidate.mkdir(parents=True)
            return candidate, created or candidate
        except FileExistsError:
            suffix += 1
            candidate = base.with_name(f"{base.name}-{suffix}")


class NeuralBrdfCLI(LightningCLI):
    """``train.py``'s LightningCLI: run directory, CSV log, thread count (module docstring)."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("subclass_mode_model", True)
        kwargs.setdefault("subclass_mode_data", True)
        kwargs.setdefault("auto_configure_optimizers", False)
        # parse errors are raised (main() reports them in one line), and usage names this command
        kwargs.setdefault("parser_kwargs", {"prog": PROG, "exit_on_error": False, "allow_abbrev": False,
                                            **{name: {"exit_on_error": False, "allow_abbrev": False}
                                               for name in SUBCOMMANDS}})
        self._args = [str(arg) for arg in kwargs.get("args") or []]  # the command line, for messages naming a key
        self.run_dir: Path | None = None
        self._fit_dir: Path | None = None  # where the trainer writes: the run directory, or fit --overwrite's staging
        self._created_folder: Path | None = None  # the outermost folder made for the run directory
        self._staging: Path | None = None
        self._earlier_log: Path | None = None
        self._empty_at_start = False  # a fit into a folder that held no run
        self._run_dir_lock = contextlib.ExitStack()
        with self._run_dir_lock:  # held from before_instantiate_classes to the end of the command
            try:
                super().__init__(*args, **kwargs)
            except BaseException as exc:
                self._end_after_failure(exc)
                exc.neuralbrdf_run_dir = self.run_dir  # where a failed fit's metrics.json says why
                exc.neuralbrdf_parsers = getattr(self, "_subcommand_parsers", {})  # the valid names of a bad key
                raise
            self._end()

    # -- the run directory (module docstring; :mod:`neuralbrdf.lightning.run_dir`)

    def _end(self) -> None:
        """A finished command: a resumed run's log joined, a replacement run put in place."""
        if self._earlier_log is not None:
            join_logs(self.run_dir, self._earlier_log)
            self._earlier_log = None
        if self._staging is not None:
            swap_in(self.run_dir, self._staging)
            self._staging = None

    def _end_after_failure(self, exc: BaseException) -> None:
        """A command that failed: a failed fit is a whole run (it replaces the old one with its
        cause); a start refused as bad input leaves the run directory as it found it; anything
        else (an interruption, a full disk, a bug) leaves the run that was there."""
        if self.run_dir is None:
            return
        if self._earlier_log is not None:
            join_logs(self.run_dir, self._earlier_log)
            self._earlier_log = None
        if self._staging is not None:
            if _fit_failure(exc) is not None:
                swap_in(self.run_dir, self._staging)
            else:
                shutil.rmtree(self._staging, ignore_errors=True)
            self._staging = None
            return
        if _input_error(exc) is None:
            return
        if self._created_folder is not None:
            shutil.rmtree(self._created_folder, ignore_errors=True)
        elif self._empty_at_start:  # what this start wrote into a folder that held no run
            for entry in RUN_ENTRIES:
                remove_entry(self.run_dir / entry)

    def _prepare_fit_dir(self, config) -> None:
        run_dir = self.run_dir
        if config.get("resume") and config.get("overwrite"):
            raise InputError("--resume and --overwrite exclude each other")
        if config.get("resume"):
            last = run_dir / "checkpoints" / "last.ckpt"
            ckpt = Path(config.ckpt_path) if config.get("ckpt_path") else last
            if not config.get("ckpt_path") and not last.exists():
                raise InputError("--resume: no run to resume here (checkpoints/last.ckpt not found)", path=run_dir)
            read_checkpoint(ckpt, "checkpoint to resume from")
            config.ckpt_path = str(ckpt)
            self._earlier_log = set_aside_log(run_dir)  # this session's log starts afresh, then both join
            return
        self._empty_at_start = not holds_run(run_dir)
        if not self._empty_at_start:
            if not config.get("overwrite"):
                raise InputError(f"{_held_run(run_dir)}; pass --resume to continue it from checkpoints/last.ckpt or "
                                 "--overwrite to replace it", path=run_dir)
            callbacks = config.trainer.get("callbacks") or []
            fixed = [c for c in (callbacks if isinstance(callbacks, list) else [callbacks])
                     if getattr(getattr(c, "init_args", None), "dirpath", None)]
            if fixed:  # the new run's checkpoints would land among the old run's
                raise InputError(f"--overwrite writes the new run beside the old one, but the config fixes "
                                 f"{fixed[0].class_path.rsplit('.', 1)[-1]}'s dirpath ({fixed[0].init_args.dirpath}); "
                                 "leave dirpath unset (checkpoints/ of the run directory) or choose another --run_dir",
                                 path=run_dir)
            self._staging = staging_dir(run_dir)  # the old run stays until the new one is whole
            self._staging.mkdir()
            self._fit_dir = self._staging

    @staticmethod
    def subcommands() -> dict[str, set[str]]:
        return {name: spec for name, spec in LightningCLI.subcommands().items() if name in SUBCOMMANDS}

    def add_arguments_to_parser(self, parser) -> None:
        parser.add_argument(
            "--run_dir", type=str | None, default=None,
            help="Run directory for config, checkpoints, logs and metrics.json "
            "(default: trainer.default_root_dir, the checkpoint's run, or runs/<config stem>/<timestamp>).",
        )
        parser.add_argument(
            "--num_threads", type=int | None, default=None,
            help="torch.set_num_threads for the run (default: torch's own choice).",
        )
        parser.add_argument(
            "--resume", action=ActionYesNo, default=False,
            help="fit: continue the run in --run_dir from its checkpoints/last.ckpt (or --ckpt_path), appending "
            "to metrics.csv and summing the wall time. Without --resume or --overwrite an existing run is refused.",
        )
        parser.add_argument(
            "--overwrite", action=ActionYesNo, default=False,
            help="fit: replace the run already in --run_dir; the new run is written beside it and takes its place "
            "when whole (a run that fails to start, is interrupted or killed leaves the old one).",
        )

    def _resolve_run_dir(self, config) -> tuple[Path, Path | None]:
        """The run directory (module docstring) and, for a fresh one, the outermost folder made for it."""
        if config.get("run_dir"):
            return Path(config.run_dir), None
        if config.trainer.get("default_root_dir"):
            return Path(config.trainer.default_root_dir), None
        ckpt_path = config.get("ckpt_path")
        if self.subcommand != "fit" and ckpt_path and Path(ckpt_path).parent.name == "checkpoints":
            return Path(ckpt_path).parent.parent, None
        return _fresh_run_dir(config.get("config"))

    def _parse_ckpt_path(self) -> None:
        # Lightning reads --ckpt_path right after parsing and lets its hyper-parameters replace the
        # config's model: a missing, truncated or foreign file is refused first, in one line naming it.
        subcommand = self.config.get("subcommand")
        ckpt_path = self.config[subcommand].get("ckpt_path") if subcommand else None
        if ckpt_path and (ckpt_path not in LIGHTNING_CKPT_NAMES or Path(ckpt_path).is_file()):
            what = "checkpoint to resume from" if subcommand == "fit" else "checkpoint to evaluate"
            hparams = read_checkpoint(ckpt_path, what).get("hyper_parameters")
            trained = hparams.get("_class_path") if isinstance(hparams, Mapping) else None
            configured = getattr(self.config[subcommand].get("model"), "class_path", None)
            if trained and configured and trained != configured:
                raise InputError(
                    f"{what} holds a {trained.rsplit('.', 1)[-1]} model but the config's model is "
                    f"{configured.rsplit('.', 1)[-1]}; give the config it was trained with",
                    path=ckpt_path,
                )
        super()._parse_ckpt_path()

    def before_instantiate_classes(self) -> None:
        config = self.config[self.subcommand]
        if config.get("num_threads"):
            torch.set_num_threads(config.num_threads)
        if self.subcommand == "fit":  # before the run directory: an endless or empty fit is refused at once
            check_fit_settings(config, self._args, _config_args(self._args)[1])
        self.run_dir, fresh = self._resolve_run_dir(config)
        lock = self._run_dir_lock.enter_context(folder_lock(self.run_dir, "training run"))
        self._created_folder = fresh or lock.created
        self._fit_dir = self.run_dir
        for note in recover(self.run_dir):  # what commands killed in this directory left behind
            warnings.warn(f"{self.run_dir}: {note}", stacklevel=2)
        if self.subcommand == "fit":
            self._prepare_fit_dir(config)
        self.save_config_kwargs = {"overwrite": True, **self.save_config_kwargs}

    def instantiate_trainer(self, **kwargs) -> pl.Trainer:
        kwargs["default_root_dir"] = str(self._fit_dir)
        if self._get(self.config_init, "trainer", {}).get("logger") in (None, True):
            version = "" if self.subcommand == "fit" else self.subcommand
            # every logged step reaches the file: a killed run keeps its log up to its last step
            kwargs["logger"] = CSVLogger(self._fit_dir, name="", version=version, flush_logs_every_n_steps=1)
        if not self._get(self.config_init, "trainer", default={}).get("plugins"):
            moved = None if self._fit_dir == self.run_dir else (self._fit_dir, self.run_dir)
            kwargs["plugins"] = [AtomicCheckpointIO(moved)]
        trainer = self._get(self.config_init, "trainer", default={})
        added = [FitHealth()] if self.subcommand == "fit" else []
        if trainer.get("enable_progress_bar") is not False and not on_terminal():
            added.append(EpochLines())  # a log gets one line per epoch, not a redrawn bar
        if added:
            configured = trainer.get("callbacks") or []
            kwargs["callbacks"] = [*(configured if isinstance(configured, list) else [configured]), *added]
        return super().instantiate_trainer(**kwargs)


def _interruption(exc: BaseException) -> int | None:
    """The signal that stopped a command, if ``exc`` is how Lightning reports one: SIGTERM as
    ``SIGTERMException``, Ctrl-C as ``KeyboardInterrupt`` (or the ``sys.exit(1)`` it becomes)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, SIGTERMException):
            return signal.SIGTERM
        if isinstance(exc, KeyboardInterrupt):
            return signal.SIGINT
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def _signal_name(number: int) -> str:
    return {signal.SIGINT: "Ctrl-C (SIGINT)"}.get(number, signal.Signals(number).name)


def _fit_failure(exc: BaseException) -> str | None:
    """The one-line cause of a fit that ran and failed (:class:`FitFailed`, or a
    :data:`DATA_FAILURES` error :class:`FitHealth` recorded), else ``None``."""
    if isinstance(exc, FitFailed):
        return str(exc)
    cause = getattr(exc, "neuralbrdf_fit_failure", None)
    return cause if cause is not None and isinstance(exc, DATA_FAILURES) else None


def _held_run(run_dir: Path) -> str:
    """What the run in ``run_dir`` holds, for the refusal of a fit that would replace it."""
    listing = ", ".join(run_entries(run_dir))
    try:
        status = json.loads((run_dir / METRICS_FILE).read_text(encoding="utf-8")).get("status")
    except (OSError, ValueError, AttributeError):
        status = None
    if status in (STATUS_OK, STATUS_FAILED):
        return f"already holds a run ({listing})"
    why = {STATUS_RUNNING: f"its {METRICS_FILE} says it is still running, but no command runs in it: it was killed",
           STATUS_INTERRUPTED: "it was interrupted",
           STATUS_ENVIRONMENT: f"the machine stopped it (its {METRICS_FILE} says why)"}.get(
        status, f"no {METRICS_FILE}: it ended before its fit did, or was killed")
    return f"already holds a run that did not finish ({listing}; {why})"


def _environment_failure(exc: BaseException) -> EnvironmentFailure | None:
    """The :class:`~neuralbrdf.errors.EnvironmentFailure` behind ``exc``, or one made of the
    ``OSError`` of the machine's making behind it (a log that Lightning writes itself), naming
    its file or else the run directory; ``None`` otherwise."""
    seen = set()
    cause = exc
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, EnvironmentFailure):
            return cause
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    oserror = environment_oserror(exc)
    if oserror is None:
        return None
    return EnvironmentFailure.of(oserror, oserror.filename or getattr(exc, "neuralbrdf_run_dir", None))


def _input_error(exc: BaseException) -> InputError | None:
    """The :class:`InputError` behind ``exc`` (jsonargparse wraps errors raised by constructors)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, InputError):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def _config_args(args: list[str]) -> tuple[list[str], list[str]]:
    """``(the other arguments, the config files named)``: ``--config X``, ``--config=X``, ``-c X``."""
    rest, configs, k = [], [], 0
    while k < len(args):
        if args[k] in ("--config", "-c") and k + 1 < len(args):
            configs.append(args[k + 1])
            k += 2
            continue
        if args[k].startswith("--config="):
            configs.append(args[k].split("=", 1)[1])
        else:
            rest.append(args[k])
        k += 1
    return rest, configs


def _resolve_config_files(args: list[str]) -> list[str]:
    """``args`` with each config named by a shipped config's name replaced by its file
    (:func:`~neuralbrdf.configs_dir.resolve_config`) and an overlay's base config put before it when
    not given (:func:`~neuralbrdf.configs_dir.overlay_base`); every config must be a readable UTF-8
    text file (jsonargparse shows a traceback for a binary one)."""
    rest, names = _config_args(args)
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
        raise describe_config_error(str(exc), args, _config_args(args)[1], parser) from None
    except Exception as exc:
        error = _input_error(exc) or _environment_failure(exc)
        if error is not None:
            raise error from None
        cause = _fit_failure(exc)
        if cause is None:
            raise
        failure = FitFailed(cause)
        failure.neuralbrdf_run_dir = getattr(exc, "neuralbrdf_run_dir", None)
        raise failure from exc
    except BaseException as exc:  # Ctrl-C or SIGTERM (Lightning makes them SystemExit), else as it is
        signal_number = _interruption(exc)
        if signal_number is None:
            raise
        run_dir = getattr(exc, "neuralbrdf_run_dir", None)
        kept = f"; {run_dir} keeps what the run saved (a fit: --resume continues it)" if run_dir else ""
        raise Interrupted(signal_number, f"interrupted by {_signal_name(signal_number)}{kept}") from None


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
