"""The :class:`FitHealth` callback, added to every ``fit``: a fit that is not producing a model ends as
:class:`~neuralbrdf.errors.FitFailed` (a non-finite loss or monitored metric, gradients all zero for an
epoch, a model no better than predicting 0, or the module's own ``fit_failure()``), its ``best*``
checkpoints removed and ``metrics.json`` saying why (:mod:`neuralbrdf.lightning.run`)."""

from __future__ import annotations

import contextlib
import json
import math
import os
from collections.abc import Mapping
from pathlib import Path

import pytorch_lightning as pl
import torch
from pytorch_lightning.callbacks import ModelCheckpoint

from neuralbrdf.errors import EnvironmentFailure, FitFailed, one_line
from neuralbrdf.lightning.failures import environment_failure, input_error, interruption, signal_name
from neuralbrdf.lightning.metrics_json import (METRICS_FILE, STATUS_ENVIRONMENT, STATUS_FAILED, STATUS_INTERRUPTED,
                                               is_resuming, scalar, write_metrics)

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
                value = scalar(value)
                if math.isfinite(value):
                    self._best_relative_errors[name] = min(value, self._best_relative_errors.get(name, math.inf))
        for callback in trainer.checkpoint_callbacks:
            value = trainer.callback_metrics.get(callback.monitor) if callback.monitor else None
            if value is not None and not math.isfinite(scalar(value)):
                raise FitFailed(
                    f"the monitored metric {callback.monitor} is {scalar(value)} after epoch {trainer.current_epoch} "
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
        if trainer.state.fn != "fit" or input_error(exception) is not None or not trainer.is_global_zero:
            return
        signal_number = interruption(exception)
        if signal_number is not None:  # not a failure: the checkpoints stay, to --resume from
            with contextlib.suppress(EnvironmentFailure):
                write_metrics(Path(trainer.default_root_dir) / self.filename,
                              {"status": STATUS_INTERRUPTED, "cause": f"interrupted by {signal_name(signal_number)}",
                               "fit/epochs": trainer.current_epoch}, merge=True)
            return
        cause = str(exception) if isinstance(exception, FitFailed) else one_line(exception)
        if isinstance(exception, Exception):
            exception.neuralbrdf_fit_failure = cause  # read by main() for the one-line report
        for callback in trainer.checkpoint_callbacks:
            if isinstance(callback, ModelCheckpoint) and callback.dirpath and os.path.isdir(callback.dirpath):
                for best in Path(callback.dirpath).glob("best*.ckpt"):
                    best.unlink(missing_ok=True)
        metrics = {f"fit/{name}": scalar(value) for name, value in trainer.callback_metrics.items()}
        status = STATUS_FAILED if environment_failure(exception) is None else STATUS_ENVIRONMENT
        metrics.update({"status": status, "cause": cause, "fit/epochs": trainer.current_epoch})
        metrics.pop("fit/best_model_path", None)
        extras = getattr(pl_module, "metrics_json_extras", None)
        if extras is not None:
            metrics.update({f"fit/{name}": value for name, value in extras().items()})
        path = Path(trainer.default_root_dir) / self.filename
        try:
            if not is_resuming(trainer):
                path.unlink(missing_ok=True)  # a new fit's metrics.json describes only it
            write_metrics(path, metrics, merge=True)
            if not is_resuming(trainer):
                return
            # metrics.json of the resumed run may name the best checkpoint just removed.
            merged = json.loads(path.read_text(encoding="utf-8"))
            merged.pop("fit/best_model_path", None)
            merged.pop("fit/best_model_score", None)
            write_metrics(path, merged, merge=False)
        except EnvironmentFailure:
            pass  # the disk that stopped the fit keeps its record too: the command's error line says why
