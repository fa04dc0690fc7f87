"""Training runs: the ``train.py`` command line, its run directory and ``metrics.json``.

``python train.py fit|validate|test --config configs/X.yaml [--key value ...]`` is a
:class:`~pytorch_lightning.cli.LightningCLI` in subclass mode: the model and the data module are
named by ``class_path`` in the YAML, so every model kind (spectral MLP, ABC, NLB) trains through
the same entry point; any option can be overridden on the command line (``--data.path FILE``,
``--trainer.max_epochs 5``).

**Run directory.** ``--run_dir DIR``, else ``trainer.default_root_dir`` if the config sets it,
else — for ``validate``/``test`` with ``--ckpt_path RUN/checkpoints/X.ckpt`` — ``RUN``, else
``runs/<config stem>/<YYYYmmdd-HHMMSS>`` (a ``-1``, ``-2``, … suffix if taken).  A run writes
there:

* ``config.yaml`` — the resolved config (``SaveConfigCallback``);
* ``checkpoints/`` — from the config's ``ModelCheckpoint`` (best and last);
* ``metrics.csv`` and ``hparams.yaml`` — the :class:`~pytorch_lightning.loggers.CSVLogger`
  (unless the config names another logger);
* ``metrics.json`` — :class:`MetricsJson`.

``validate`` and ``test`` write their ``config.yaml``/``metrics.csv`` under ``<run>/validate/``
and ``<run>/test/`` so the training logs survive, and merge their metrics into the same
``metrics.json``.

Bad input (a missing or malformed ``--data.path``, an unknown option value raised as
:class:`~neuralbrdf.errors.InputError`) ends the command with a one-line message and status 2.
"""

from __future__ import annotations

import json
import sys
import time
import warnings
from datetime import datetime
from pathlib import Path

import pytorch_lightning as pl
import torch
from pytorch_lightning.cli import LightningCLI
from pytorch_lightning.loggers import CSVLogger

from neuralbrdf.atomic import atomic_write
from neuralbrdf.errors import InputError

METRICS_FILE = "metrics.json"
RUNS_ROOT = Path("runs")
SUBCOMMANDS = ("fit", "validate", "test")


def _number(value) -> float | int:
    value = value.item() if isinstance(value, torch.Tensor) else value
    return value if isinstance(value, int) else float(value)


class MetricsJson(pl.Callback):
    """Writes the final metrics of every stage to ``<trainer.default_root_dir>/metrics.json``.

    Keys are ``<stage>/<metric>``.  After ``fit``: every logged metric as ``fit/<name>``
    (``fit/train/loss``, ``fit/val/rel_rmse_glossy_median`` of the last epoch) plus
    ``fit/best_model_score``, ``fit/best_model_path`` (relative to the run directory if inside it),
    ``fit/epochs``, ``fit/wall_time_s`` and whatever the module's optional
    ``metrics_json_extras()`` returns (non-scalar results such as fitted parameters); ``fit`` starts a new file (a new model makes earlier
    evaluations stale).  After ``validate``/``test``: the logged ``val/x``/``test/x`` as
    ``validate/x``/``test/x``, merged into the existing file.  Writes are atomic.
    """

    def __init__(self, filename: str = METRICS_FILE) -> None:
        self.filename = filename
        self._fit_started = 0.0

    def path(self, trainer: pl.Trainer) -> Path:
        return Path(trainer.default_root_dir) / self.filename

    def _write(self, trainer: pl.Trainer, metrics: dict, merge: bool) -> None:
        if not trainer.is_global_zero:
            return
        path = self.path(trainer)
        merged = {}
        if merge and path.exists():
            try:
                merged = json.loads(path.read_text(encoding="utf-8"))
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                raise InputError(f"cannot merge metrics into it: not valid JSON ({exc})", path=path) from None
        merged.update(metrics)
        with atomic_write(path) as handle:
            json.dump(merged, handle, indent=2, sort_keys=True)
            handle.write("\n")

    def on_fit_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self._fit_started = time.perf_counter()

    def on_fit_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        metrics = {f"fit/{name}": _number(value) for name, value in trainer.callback_metrics.items()}
        metrics["fit/epochs"] = trainer.current_epoch
        extras = getattr(pl_module, "metrics_json_extras", None)
        if extras is not None:
            metrics.update({f"fit/{name}": value for name, value in extras().items()})
        metrics["fit/wall_time_s"] = time.perf_counter() - self._fit_started
        checkpoint = trainer.checkpoint_callback
        if checkpoint is not None and checkpoint.best_model_path:
            best, root = Path(checkpoint.best_model_path).resolve(), Path(trainer.default_root_dir).resolve()
            metrics["fit/best_model_path"] = str(best.relative_to(root) if best.is_relative_to(root) else best)
            if checkpoint.best_model_score is not None:
                metrics["fit/best_model_score"] = _number(checkpoint.best_model_score)
        self._write(trainer, metrics, merge=False)

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


def _fresh_run_dir(config_paths) -> Path:
    stem = Path(str(config_paths[-1])).stem if config_paths else "run"
    base = RUNS_ROOT / stem / datetime.now().strftime("%Y%m%d-%H%M%S")
    candidate, suffix = base, 0
    while candidate.exists():
        suffix += 1
        candidate = base.with_name(f"{base.name}-{suffix}")
    return candidate


class NeuralBrdfCLI(LightningCLI):
    """``train.py``'s LightningCLI: run directory, CSV log, thread count (module docstring)."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("subclass_mode_model", True)
        kwargs.setdefault("subclass_mode_data", True)
        kwargs.setdefault("auto_configure_optimizers", False)
        super().__init__(*args, **kwargs)

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

    def _resolve_run_dir(self, config) -> Path:
        if config.get("run_dir"):
            return Path(config.run_dir)
        if config.trainer.get("default_root_dir"):
            return Path(config.trainer.default_root_dir)
        ckpt_path = config.get("ckpt_path")
        if self.subcommand != "fit" and ckpt_path and Path(ckpt_path).parent.name == "checkpoints":
            return Path(ckpt_path).parent.parent
        return _fresh_run_dir(config.get("config"))

    def before_instantiate_classes(self) -> None:
        config = self.config[self.subcommand]
        if config.get("num_threads"):
            torch.set_num_threads(config.num_threads)
        self.run_dir = self._resolve_run_dir(config)
        self.save_config_kwargs = {"overwrite": True, **self.save_config_kwargs}

    def instantiate_trainer(self, **kwargs) -> pl.Trainer:
        kwargs["default_root_dir"] = str(self.run_dir)
        if self._get(self.config_init, "trainer", {}).get("logger") in (None, True):
            version = "" if self.subcommand == "fit" else self.subcommand
            kwargs["logger"] = CSVLogger(self.run_dir, name="", version=version)
        return super().instantiate_trainer(**kwargs)


def _input_error(exc: BaseException) -> InputError | None:
    """The :class:`InputError` behind ``exc`` (jsonargparse wraps errors raised by constructors)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, InputError):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def main(args: list[str] | None = None) -> int:
    """Entry point of ``train.py``; returns the exit status (2 on bad input)."""
    # The data are in-memory tensors: worker processes would only add start-up time.
    warnings.filterwarnings("ignore", message=r".*does not have many workers.*")
    # The CSV log shares the run directory with config.yaml, written just before it.
    warnings.filterwarnings("ignore", message=r"Experiment logs directory .* exists and is not empty")
    # validate/test restore a checkpoint whose ModelCheckpoint state names the fit's folder; the
    # evaluation stages write no checkpoints, so the "dirpath has changed" notice is noise.
    warnings.filterwarnings("ignore", message=r"The dirpath has changed from")
    # The ABC fit runs its own bounded optimiser (SciPy), not a torch one.
    warnings.filterwarnings("ignore", message=r".*configure_optimizers` returned `None`")
    try:
        NeuralBrdfCLI(args=args)
    except Exception as exc:
        error = _input_error(exc)
        if error is None:
            raise
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0
