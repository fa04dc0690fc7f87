"""Reading checkpoint files with errors that name the file (shared by loaders and the exporter)."""

from __future__ import annotations

import os
from pathlib import Path

import torch

from neuralbrdf.atomic import note_input
from neuralbrdf.errors import InputError
from neuralbrdf.limits import MAX_CHECKPOINT_BYTES, check_file_size


def one_line(error: BaseException, limit: int = 300) -> str:
    """``Type: message`` on one line, shortened to ``limit`` characters."""
    text = " ".join(line.strip() for line in str(error).splitlines() if line.strip())
    text = text if len(text) <= limit else text[: limit - 3] + "..."
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


def read_checkpoint(path: str | os.PathLike[str], what: str = "checkpoint") -> dict:
    """The checkpoint dictionary (tensors on the CPU, ``weights_only``), else :class:`InputError`.

    ``what`` names the expected file in the messages (e.g. ``"pretrained NLB checkpoint"``).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} not found", path=path)
    note_input(path)
    check_file_size(path, MAX_CHECKPOINT_BYTES, "checkpoint")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises many kinds for corrupt or foreign files
        raise InputError(f"not a readable PyTorch checkpoint ({one_line(error)})", path=path) from None
    if not isinstance(checkpoint, dict):
        raise InputError(f"not a checkpoint dictionary (found {type(checkpoint).__name__})", path=path)
    return checkpoint
