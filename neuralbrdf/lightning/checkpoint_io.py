"""Checkpoints of a training run written whole or not at all (:class:`AtomicCheckpointIO`, the
trainer's checkpoint plugin)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from pytorch_lightning.plugins.io import TorchCheckpointIO

from neuralbrdf.checkpoints import write_checkpoint


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
