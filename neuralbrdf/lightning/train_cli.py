"""``neuralbrdf train``'s :class:`~pytorch_lightning.cli.LightningCLI` (:class:`NeuralBrdfCLI`): its
own options (``--run_dir``, ``--num_threads``, ``--resume``, ``--overwrite``), the run directory
it locks, prepares and finishes (:mod:`neuralbrdf.lightning.run_dir`), the checkpoint it checks
before Lightning reads it, and the logger, checkpoint plugin and callbacks it gives the trainer.
The command around it is :mod:`neuralbrdf.lightning.run`."""

from __future__ import annotations

import contextlib
import shutil
import warnings
from collections.abc import Mapping
from pathlib import Path

import pytorch_lightning as pl
import torch
from jsonargparse import ActionYesNo
from pytorch_lightning.cli import LightningCLI
from pytorch_lightning.loggers import CSVLogger

from neuralbrdf.checkpoints import read_checkpoint
from neuralbrdf.console import on_terminal
from neuralbrdf.errors import InputError
from neuralbrdf.folder_lock import folder_lock
from neuralbrdf.lightning.checkpoint_io import AtomicCheckpointIO
from neuralbrdf.lightning.failures import fit_failure, input_error
from neuralbrdf.lightning.fit_health import FitHealth
from neuralbrdf.lightning.fit_settings import check_fit_settings
from neuralbrdf.lightning.progress import EpochLines
from neuralbrdf.lightning.run_dir import (RUN_ENTRIES, fresh_run_dir, held_run, holds_run, join_logs, recover,
                                          remove_entry, set_aside_log, staging_dir, swap_in)

#: The command as a user types it, in its error lines (:func:`~neuralbrdf.errors.error_line`).
PROG = "neuralbrdf train"
SUBCOMMANDS = ("fit", "validate", "test")
#: ``--ckpt_path`` values Lightning resolves itself rather than as files.
LIGHTNING_CKPT_NAMES = ("best", "last", "hpc", "registry")


def config_args(args: list[str]) -> tuple[list[str], list[str]]:
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


class NeuralBrdfCLI(LightningCLI):
    """``train.py``'s LightningCLI: run directory, CSV log, thread count (:mod:`neuralbrdf.lightning.run`)."""

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

    # -- the run directory (:mod:`neuralbrdf.lightning.run`, :mod:`neuralbrdf.lightning.run_dir`)

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
            if fit_failure(exc) is not None:
                swap_in(self.run_dir, self._staging)
            else:
                shutil.rmtree(self._staging, ignore_errors=True)
            self._staging = None
            return
        if input_error(exc) is None:
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
                raise InputError(f"{held_run(run_dir)}; pass --resume to continue it from checkpoints/last.ckpt or "
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
        """The run directory (:mod:`neuralbrdf.lightning.run`) and, for a fresh one, the outermost folder made for it."""
        if config.get("run_dir"):
            return Path(config.run_dir), None
        if config.trainer.get("default_root_dir"):
            return Path(config.trainer.default_root_dir), None
        ckpt_path = config.get("ckpt_path")
        if self.subcommand != "fit" and ckpt_path and Path(ckpt_path).parent.name == "checkpoints":
            return Path(ckpt_path).parent.parent, None
        return fresh_run_dir(config.get("config"))

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
            check_fit_settings(config, self._args, config_args(self._args)[1])
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
