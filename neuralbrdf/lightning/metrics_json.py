"""``metrics.json``, the result file of a training run (docs/formats.md): the :class:`MetricsJson`
callback that writes every stage's final metrics into it, the statuses it records and its strict,
atomic writer (:func:`write_metrics`)."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping
from pathlib import Path

import pytorch_lightning as pl
import torch

from neuralbrdf.atomic import atomic_write
from neuralbrdf.errors import InputError

METRICS_FILE = "metrics.json"
STATUS_OK, STATUS_FAILED, STATUS_RUNNING, STATUS_INTERRUPTED = "ok", "failed", "running", "interrupted"
#: A fit the machine stopped (a full disk, a file it could not write): not the fit's failure.
STATUS_ENVIRONMENT = "environment"


def scalar(value) -> float | int:
    """A logged value (a tensor or a number) as a Python number."""
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


def is_resuming(trainer: pl.Trainer) -> bool:
    """Whether ``trainer`` continues a fit from a checkpoint (``fit --resume``)."""
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
        if is_resuming(trainer) and path.exists():  # a resumed run: its time so far counts
            try:
                earlier = json.loads(path.read_text(encoding="utf-8")).get("fit/wall_time_s")
            except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
                earlier = None
            if isinstance(earlier, (int, float)) and math.isfinite(earlier):
                self._earlier_wall_time_s = float(earlier)
        # until the fit ends: a run whose fit was killed says so (its checkpoints stay, to --resume)
        self._write(trainer, {"status": STATUS_RUNNING, "cause": None}, merge=is_resuming(trainer))

    def on_fit_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        metrics = {f"fit/{name}": scalar(value) for name, value in trainer.callback_metrics.items()}
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
                metrics["fit/best_model_score"] = scalar(checkpoint.best_model_score)
        # A resumed fit adds to its run's metrics; a new fit starts a new file.
        self._write(trainer, metrics, merge=is_resuming(trainer))

    def _evaluation_end(self, trainer: pl.Trainer, stage: str) -> None:
        metrics = {
            f"{stage}/{name.split('/', 1)[-1]}": scalar(value) for name, value in trainer.callback_metrics.items()
        }
        self._write(trainer, metrics, merge=True)

    def on_validation_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        if trainer.state.fn == "validate":
            self._evaluation_end(trainer, "validate")

    def on_test_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self._evaluation_end(trainer, "test")
