"""A training run's progress when its output is not a terminal: one line per epoch.

Lightning's progress bar redraws itself with carriage returns; written to a log file or a pipe
that becomes several lines of bar per epoch.  :class:`EpochLines` replaces it there
(:class:`~neuralbrdf.lightning.train_cli.NeuralBrdfCLI` adds it when :func:`neuralbrdf.console.on_terminal` is false and
the config enables the progress bar) with one parseable line per epoch on stderr::

    epoch 3/30 train/loss=0.01234 val/loss=0.004567 val/rel_rmse_glossy=0.0834 time_s=1.2
"""

from __future__ import annotations

import sys
import time

import pytorch_lightning as pl
import torch
from pytorch_lightning.callbacks import ProgressBar

#: Metrics per line at most (a latent fit logs per-material metrics too: those go to metrics.csv).
MAX_METRICS_PER_LINE = 8


def _value(value) -> float | None:
    value = value.item() if isinstance(value, torch.Tensor) and value.numel() == 1 else value
    return float(value) if isinstance(value, (int, float)) else None


def epoch_line(epoch: int, max_epochs: int | None, metrics: dict, seconds: float, stopping: bool = False) -> str:
    """``epoch E/N key=value ... time_s=S`` (module docstring); ``stopping``: the fit ends with this
    epoch, so a line ``epoch 1/6`` does not read as a fit cut short."""
    has_total = max_epochs is not None and max_epochs > 0
    total = f"/{max_epochs}" if has_total else ""
    pairs = [(name, _value(value)) for name, value in sorted(metrics.items())]
    shown = [f"{name}={value:.4g}" for name, value in pairs if value is not None][:MAX_METRICS_PER_LINE]
    line = " ".join([f"epoch {epoch + 1}{total}", *shown, f"time_s={seconds:.1f}"])
    if stopping and has_total and epoch + 1 < max_epochs:
        line += "; the fit is done: it stopped before its last epoch (early stopping, or a small fit's L-BFGS run)"
    return line


class EpochLines(ProgressBar):
    """Lightning's progress bar as one line per finished training epoch (module docstring)."""

    def __init__(self, file=None) -> None:
        super().__init__()
        self.file = file
        self._enabled = True
        self._epoch_started = 0.0

    def disable(self) -> None:
        self._enabled = False

    def enable(self) -> None:
        self._enabled = True

    def on_train_epoch_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self._epoch_started = time.perf_counter()

    def on_train_epoch_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        if not (self._enabled and trainer.is_global_zero):
            return
        line = epoch_line(trainer.current_epoch, trainer.max_epochs, dict(trainer.callback_metrics),
                          time.perf_counter() - self._epoch_started, stopping=trainer.should_stop)
        print(line, file=self.file if self.file is not None else sys.stderr, flush=True)
