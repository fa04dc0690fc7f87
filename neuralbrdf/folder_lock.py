"""One process at a time in an output folder: an exclusive lock held for a command's whole life.

A training run directory and a study folder are written by one command over minutes or hours;
a second command writing into the same folder at the same time would interleave their files (a
CSV log with another run's rows, a cell folder cleared under a running fit).  :func:`folder_lock`
takes an advisory lock (``flock``) on the file :data:`LOCK_FILE` inside the folder and refuses,
at once and in one line, when another process holds it.  The kernel drops the lock when the
holding process ends, however it ends (killed, crashed), so a lock is never left stale; a child
process given the lock's file descriptor (:attr:`FolderLock.fd`) keeps the folder locked until
it ends too.  The file itself stays (deleting it could let two processes lock two different
files of the same name); it holds the process id of the last holder, for the message.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from neuralbrdf.errors import ENVIRONMENT_ERRNOS, EnvironmentFailure, InputError

#: The lock file inside a locked folder.
LOCK_FILE = ".neuralbrdf.lock"


@dataclass(frozen=True)
class FolderLock:
    """A held lock: the folder, the outermost folder this lock created (``None``: it existed), and
    the lock file's descriptor."""

    folder: Path
    created: Path | None
    fd: int


def outermost_missing(folder: str | os.PathLike[str]) -> Path | None:
    """The outermost of ``folder`` and its parents that does not exist (what creating ``folder``
    with its parents adds); ``None`` when ``folder`` exists."""
    folder, missing = Path(folder), None
    while not folder.exists() and folder != folder.parent:
        missing, folder = folder, folder.parent
    return missing


def _holder(path: Path) -> str:
    try:
        pid = int(path.read_text(encoding="ascii").strip() or "0")
    except (OSError, ValueError):
        return "another process"
    try:
        os.kill(pid, 0)
    except ProcessLookupError:  # the holder ended; a child it passed the lock to still runs
        return f"a process started by process {pid}, which has ended"
    except (PermissionError, OverflowError):
        pass
    return f"process {pid}"


def _open_locked(path: Path) -> int | None:
    """A descriptor of ``path`` locked by this process, ``None`` when another holds the lock."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return None
        except BaseException:
            os.close(fd)
            raise
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:  # not a file another holder removed (with its folder) after we opened it
            return fd
        os.close(fd)


def _failure(what: str, error: OSError, folder: Path) -> InputError | EnvironmentFailure:
    """``FOLDER: WHAT: reason``: the machine's failure (a full disk, no permission) or bad input."""
    if error.errno in ENVIRONMENT_ERRNOS:
        return EnvironmentFailure.of(error, folder, what)
    return InputError(f"{what}: {error.strerror or error}", path=folder)


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike[str], what: str) -> Iterator[FolderLock]:
    """Hold the exclusive lock of ``folder`` (created with its parents if missing) for the block.

    ``what`` names the user of the folder in the refusal, e.g. ``"training run"``:
    :class:`InputError` ``FOLDER: in use by another training run (process 1234); wait for it to
    end or choose another folder``.  A folder this call created and the block left empty (only
    the lock file), with the parents it created, is removed again.
    """
    folder = Path(folder)
    created = outermost_missing(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise InputError("exists and is not a folder", path=folder) from None
    except OSError as error:
        raise _failure("cannot create the folder", error, folder) from None
    path = folder / LOCK_FILE
    try:
        fd = _open_locked(path)
    except OSError as error:
        raise _failure("cannot lock the folder", error, folder) from None
    if fd is None:
        raise InputError(f"in use by another {what} ({_holder(path)}); wait for it to end or choose another folder",
                         path=folder)
    try:
        with contextlib.suppress(OSError):  # the holder's id is for messages only (a full disk may refuse it)
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
        yield FolderLock(folder, created, fd)
    finally:
        if created is not None and folder.is_dir() and [p.name for p in folder.iterdir()] == [LOCK_FILE]:
            path.unlink(missing_ok=True)
            with contextlib.suppress(OSError):
                for empty in (folder, *folder.parents):
                    empty.rmdir()
                    if empty == created:
                        break
        os.close(fd)
