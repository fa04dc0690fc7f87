"""Atomic output files: a file is either written whole or not at all.

Every writer in neuralbrdf goes through :func:`atomic_write`, which writes into a temporary
file beside the target and renames it into place only when the writer finished without error,
so a failed command never leaves a half-written output behind.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; move it onto ``target`` on success.

    Use this for writers that want a path (matplotlib, h5py, onnx); the temporary file keeps
    the target's suffix so format detection by extension still works.
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(
        prefix=f".{target.stem}.", suffix=f".tmp{target.suffix}", dir=target.parent
    )
    os.close(fd)
    tmp = Path(tmp_name)
    # mkstemp creates 0600; give the output the permissions an ordinary open() would.
    umask = os.umask(0)
    os.umask(umask)
    tmp.chmod(0o666 & ~umask)
    try:
        yield tmp
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


@contextlib.contextmanager
def atomic_write(target: str | os.PathLike[str], mode: str = "w", **open_kwargs) -> Iterator:
    """Open a temporary file for writing; it replaces ``target`` only if the block succeeds."""
    if "newline" not in open_kwargs and "b" not in mode:
        open_kwargs["newline"] = ""
    with atomic_path(target) as tmp:
        with open(tmp, mode, **open_kwargs) as handle:
            yield handle
