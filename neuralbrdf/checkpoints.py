"""Reading checkpoint files with errors that name the file (shared by loaders and the exporter),
and writing them whole or not at all (:func:`write_checkpoint`).

Checkpoints are untrusted input (docs/robustness.md): they are size-checked before reading
(:data:`~neuralbrdf.limits.MAX_CHECKPOINT_BYTES`), loaded with ``weights_only`` (never
unpickled), and a model described by their hyper-parameters is first built on PyTorch's meta
device (no memory) and compared with the weights (:func:`check_weights_match`), so that a
hidden width of 60 000 is refused before anything is allocated.
"""

from __future__ import annotations

import os
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path

import torch
from torch import nn

from neuralbrdf.atomic import atomic_path, note_input
from neuralbrdf.errors import InputError, one_line
from neuralbrdf.limits import MAX_CHECKPOINT_BYTES, MAX_MODEL_PARAMETERS, check_file_size, file_problem

#: First bytes of a zip archive, the container of ``torch.save`` files.
ZIP_MAGIC = b"PK\x03\x04"
#: First byte of a pickle (protocol 2 and later), the container of legacy ``torch.save`` files.
PICKLE_PROTOCOL_OPCODE = b"\x80"


def write_checkpoint(checkpoint: dict, path: str | os.PathLike[str], replaces_input: bool = False) -> None:
    """``torch.save`` of ``checkpoint`` to ``path`` through :func:`~neuralbrdf.atomic.atomic_path`
    (``replaces_input``: see there).  Written through a Python file, so that a full disk is the
    ``OSError`` it is (``torch.save`` to a path reports it as ``basic_ios::clear: iostream
    error``), raised as :class:`~neuralbrdf.errors.EnvironmentFailure` naming ``path``."""
    with atomic_path(path, replaces_input=replaces_input) as temporary, open(temporary, "wb") as handle:
        torch.save(checkpoint, handle)


def read_checkpoint(path: str | os.PathLike[str], what: str = "checkpoint") -> dict:
    """The checkpoint dictionary (tensors on the CPU, ``weights_only``), else :class:`InputError`.

    ``what`` names the expected file in the messages (e.g. ``"pretrained NLB checkpoint"``).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(file_problem(path) or f"{what} not found", path=path)
    note_input(path)
    check_file_size(path, MAX_CHECKPOINT_BYTES, "checkpoint")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises many kinds for corrupt or foreign files
        raise InputError(f"not a readable PyTorch checkpoint{_why_unreadable(path, error)}", path=path) from None
    if not isinstance(checkpoint, dict):
        raise InputError(f"not a checkpoint dictionary (found {type(checkpoint).__name__})", path=path)
    return checkpoint


def _why_unreadable(path: Path, error: Exception) -> str:
    """``": <reason>"`` for a file ``torch.load`` refused (empty, cut short, not PyTorch's), else torch's
    own reason in parentheses."""
    size = path.stat().st_size
    if size == 0:
        return ": the file is empty (0 bytes)"
    with open(path, "rb") as handle:
        head = handle.read(len(ZIP_MAGIC))
    cut_short = f": cut short or damaged ({size} bytes; the end of the data is missing); copy or save it again"
    if head == ZIP_MAGIC and not zipfile.is_zipfile(path):
        return cut_short  # a zip archive without its closing directory
    if head != ZIP_MAGIC and not head.startswith(PICKLE_PROTOCOL_OPCODE):
        return f": {size} bytes that are neither a zip archive (the PyTorch format) nor a legacy PyTorch pickle"
    return cut_short if isinstance(error, EOFError) else f" ({one_line(error)})"


def check_weights_match(
    build: Callable[[], nn.Module], state_dict: Mapping, path: str | os.PathLike[str], prefix: str = ""
) -> None:
    """Check, without allocating, that ``build()`` makes a model whose tensors are in ``state_dict``.

    ``build`` runs under ``torch.device("meta")``; its parameter count must not exceed
    :data:`~neuralbrdf.limits.MAX_MODEL_PARAMETERS` and every tensor of its state dict must be in
    ``state_dict`` under ``prefix + name`` with the same shape.  Raises :class:`InputError`
    naming the file and the first mismatching key.
    """
    try:
        with torch.device("meta"):
            module = build()
    except InputError as error:
        raise InputError(f"invalid hyper-parameters: {error.reason}", path=path, column=error.column, key=error.key) from None
    except Exception as error:  # a constructor rejecting foreign hyper-parameters
        raise InputError(f"hyper-parameters do not describe a model ({one_line(error)})", path=path) from None
    expected = module.state_dict()
    count = sum(tensor.numel() for tensor in expected.values())
    if count > MAX_MODEL_PARAMETERS:
        raise InputError(
            f"hyper-parameters describe a model of {count} parameters, above the limit of {MAX_MODEL_PARAMETERS} "
            "(neuralbrdf.limits.MAX_MODEL_PARAMETERS); refusing to build it",
            path=path,
        )
    for name, tensor in expected.items():
        key = prefix + name
        found = state_dict.get(key) if isinstance(state_dict, Mapping) else None
        if not isinstance(found, torch.Tensor):
            raise InputError("the weights lack this tensor of the model its hyper-parameters describe", path=path, key=key)
        if tuple(found.shape) != tuple(tensor.shape):
            raise InputError(
                f"weight of shape {list(found.shape)} where the hyper-parameters need {list(tensor.shape)}",
                path=path,
                key=key,
            )
