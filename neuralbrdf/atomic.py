"""Atomic, guarded output files: an output is written whole or not at all, and never destroys
anything but an earlier output (docs/robustness.md).

Every writer in neuralbrdf goes through :func:`atomic_paths` (or its one-file forms
:func:`atomic_path` and :func:`atomic_write`):

* **Nothing half-written.** The writer writes temporary files beside the targets; they are
  renamed into place only when the writer finished without error.  Several targets (a PNG and
  its EXR) are committed together: if one rename fails the others are rolled back to what was
  there before, so a multi-file output appears all-or-nothing.  Folders created for a failed
  output are removed again.
* **Inputs are never outputs.** Inside a :func:`command_inputs` scope (every command line of the
  project opens one) the readers record each file they read (:func:`note_input`); an output that
  *is* one of those files — the same path, a hard link or a symbolic link to it — is refused
  with :class:`~neuralbrdf.errors.OutputError` before anything is written.
* **Only regular files are replaced.** An existing output that is a directory, a device, a FIFO
  or a socket is refused.  A symbolic link is *written through*: the file it points to is
  replaced and the link stays (:func:`output_target`).
* **Temporary files are recognisable.** They are named ``.<target name>.neuralbrdf-tmp-<pid>-…``
  (:data:`TEMP_MARKER`), so a temporary file left by a killed command is removed by the next
  write of the same target once its process is gone, and is easy to spot by hand.
* **Errors name the target.** A write that fails for the machine's sake (a full disk, a
  read-only file system, no permission: :data:`~neuralbrdf.errors.ENVIRONMENT_ERRNOS`) becomes an
  :class:`~neuralbrdf.errors.EnvironmentFailure` ``TARGET: cannot write: no space left on device``
  (exit status 3), any other ``OSError`` an :class:`~neuralbrdf.errors.OutputError` (exit status
  2), both naming the target, never the temporary file.  Writers in native code report a full
  disk in their own words (``torch.save``'s ``basic_ios::clear: iostream error``, an HDF5 or
  OpenEXR error): an exception from the writer while the target's file system has less than
  :data:`FULL_DISK_BYTES` free is taken for a full disk (:func:`full_disk`).
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

from neuralbrdf.errors import ENVIRONMENT_ERRNOS, EnvironmentFailure, InputError, OutputError

#: A file system with less free space than this after a writer failed is taken to be full (bytes).
FULL_DISK_BYTES = 64 * 1024

#: Part of every temporary file name: ``.<target name>.neuralbrdf-tmp-<pid>-<random><suffix>``.
TEMP_MARKER = ".neuralbrdf-tmp-"

#: Files read by the current command: ``(st_dev, st_ino) -> path as given``; ``None`` outside a
#: :func:`command_inputs` scope (library use: a script may rewrite a file it read).
_INPUTS: contextvars.ContextVar[dict[tuple[int, int], str] | None] = contextvars.ContextVar(
    "neuralbrdf_command_inputs", default=None
)


# --------------------------------------------------------------------------- inputs


@contextlib.contextmanager
def command_inputs() -> Iterator[None]:
    """Scope of one command: files read inside it (:func:`note_input`) cannot be its outputs."""
    token = _INPUTS.set({})
    try:
        yield
    finally:
        _INPUTS.reset(token)


def note_input(path: str | os.PathLike[str]) -> None:
    """Record ``path`` as an input of the current command (no-op outside a scope or if missing)."""
    inputs = _INPUTS.get()
    if inputs is None:
        return
    try:
        info = os.stat(path)
    except (OSError, ValueError):
        return
    inputs.setdefault((info.st_dev, info.st_ino), str(path))


def file_version(path: str | os.PathLike[str]) -> tuple[str, int, int, int]:
    """``(resolved path, size, modification time ns, inode)``: a cache key for what a file holds
    now — another file written at the same path (atomically: a new inode) gives another key."""
    info = os.stat(path)
    return str(Path(path).resolve()), info.st_size, info.st_mtime_ns, info.st_ino


# --------------------------------------------------------------------------- checks


def _kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def output_target(target: str | os.PathLike[str]) -> Path:
    """The file that writing ``target`` replaces, after the checks of the module docstring.

    A symbolic link resolves to the file it points to (written through); raises
    :class:`~neuralbrdf.errors.OutputError` naming ``target`` for an output that is an input of
    the current command or an existing non-regular file.  Nothing is written.
    """
    target = Path(target)
    if str(target) in ("", "."):
        raise OutputError("empty output path", path=target)
    real = Path(os.path.realpath(target)) if target.is_symlink() else target
    try:
        info = os.stat(real)
    except FileNotFoundError:
        return real
    except OSError as error:
        raise OutputError(f"cannot write: {error.strerror or error}", path=target) from None
    if not stat.S_ISREG(info.st_mode):
        raise OutputError(f"exists and is {_kind(info.st_mode)}; refusing to replace it with a file", path=target)
    inputs = _INPUTS.get() or {}
    source = inputs.get((info.st_dev, info.st_ino))
    if source is not None:
        same = "" if os.path.abspath(source) == os.path.abspath(target) else f" ({source})"
        raise OutputError(
            f"is also an input of this command{same}; refusing to overwrite it: choose another output",
            path=target,
        )
    return real


def check_outputs(*targets: str | os.PathLike[str]) -> list[Path]:
    """:func:`output_target` of each target, plus a check that no two are the same file; also that
    each target's folder can be written (created if missing).  Commands that compute for long
    call this first so that a bad output fails before the work, not after."""
    reals = [output_target(target) for target in targets]
    seen: dict[str, str] = {}
    for target, real in zip(targets, reals):
        key = os.path.abspath(real)
        if key in seen:
            raise OutputError(f"is given twice as an output (also as {seen[key]})", path=target)
        seen[key] = str(target)
        folder = _existing_ancestor(real.parent)
        if not folder.is_dir():
            raise OutputError(f"cannot write: {folder} is not a folder", path=target)
        if not os.access(folder, os.W_OK | os.X_OK):
            raise EnvironmentFailure(f"cannot write: folder {folder} is not writable", path=target, errno=errno.EACCES)
    return reals


def _existing_ancestor(folder: Path) -> Path:
    folder = Path(os.path.abspath(folder))
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    return folder


# --------------------------------------------------------------------------- temporary files


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True
    return True


def remove_stale_temporaries(target: str | os.PathLike[str]) -> list[Path]:
    """Delete temporary files of ``target`` left by processes that no longer run; return them."""
    target = Path(target)
    removed = []
    try:
        candidates = list(target.parent.glob(f".{glob_escape(target.name)}{TEMP_MARKER}*"))
    except OSError:
        return removed
    for candidate in candidates:
        pid_text = candidate.name.rsplit(TEMP_MARKER, 1)[-1].split("-", 1)[0]
        if pid_text.isdigit() and int(pid_text) != os.getpid() and not _pid_alive(int(pid_text)):
            with contextlib.suppress(OSError):
                candidate.unlink()
                removed.append(candidate)
    return removed


def glob_escape(name: str) -> str:
    """``name`` with glob metacharacters made literal."""
    return "".join(f"[{c}]" if c in "*?[" else c for c in name)


def _temporary_beside(real: Path, role: str = "") -> Path:
    fd, name = tempfile.mkstemp(
        prefix=f".{real.name}{TEMP_MARKER}{os.getpid()}-{role}", suffix=real.suffix, dir=real.parent
    )
    os.close(fd)
    return Path(name)


def _make_folders(folder: Path) -> list[Path]:
    """Create ``folder`` and missing parents; return the ones created, deepest first."""
    missing = []
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    for path in reversed(missing):
        path.mkdir(exist_ok=True)
    return missing


def environment_oserror(error: BaseException | None) -> OSError | None:
    """The ``OSError`` of the machine's making (:data:`~neuralbrdf.errors.ENVIRONMENT_ERRNOS`) that is
    ``error`` or caused it, if any."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, OSError) and error.errno in ENVIRONMENT_ERRNOS:
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


def _free_bytes(folder: Path) -> int | None:
    """Bytes this process may still write in ``folder``'s file system (``None``: unknown)."""
    try:
        info = os.statvfs(folder)
    except (OSError, AttributeError):
        return None
    blocks = info.f_bfree if os.geteuid() == 0 else info.f_bavail  # root may use the reserved blocks
    return blocks * info.f_frsize


def full_disk(folder: str | os.PathLike[str]) -> bool:
    """Whether ``folder``'s file system has less than :data:`FULL_DISK_BYTES` free (module docstring)."""
    free = _free_bytes(_existing_ancestor(Path(folder)))
    return free is not None and free < FULL_DISK_BYTES


def environment_failure(error: BaseException, target: str | os.PathLike[str]) -> EnvironmentFailure | None:
    """``error`` as :class:`~neuralbrdf.errors.EnvironmentFailure` naming ``target`` when the machine
    caused it (an ``OSError`` of :data:`~neuralbrdf.errors.ENVIRONMENT_ERRNOS` behind it, or a
    :func:`full_disk` under ``target``), else ``None``."""
    if isinstance(error, EnvironmentFailure):
        return error
    cause = environment_oserror(error)
    if cause is not None:
        return EnvironmentFailure.of(cause, target)
    if isinstance(error, Exception) and full_disk(Path(target).parent):
        return EnvironmentFailure("cannot write: no space left on device", path=target, errno=errno.ENOSPC)
    return None


def _output_error(error: BaseException, target: Path, temporaries: list[Path]) -> OutputError:
    if isinstance(error, OSError):
        reason = error.strerror or str(error)
    else:
        reason = str(error)
    for tmp in temporaries:
        reason = reason.replace(str(tmp), str(target)).replace(tmp.name, target.name)
    return OutputError(f"cannot write: {reason}", path=target)


def _commit(moves: list[tuple[Path, Path]]) -> None:
    """``os.replace`` each ``(tmp, real)``; on a failure restore the targets already replaced."""
    done: list[tuple[Path, Path | None]] = []
    try:
        for tmp, real in moves:
            backup = None
            if len(moves) > 1 and real.exists():
                backup = _temporary_beside(real, "backup-")
                backup.unlink()
                try:
                    os.link(real, backup)
                except OSError:
                    shutil.copy2(real, backup)
            done.append((real, backup))
            os.replace(tmp, real)
    except BaseException:
        for real, backup in reversed(done):
            with contextlib.suppress(OSError):
                if backup is not None:
                    os.replace(backup, real)
                else:
                    real.unlink(missing_ok=True)
        raise
    finally:
        for _, backup in done:
            if backup is not None:
                backup.unlink(missing_ok=True)


# --------------------------------------------------------------------------- writers


@contextlib.contextmanager
def atomic_paths(*targets: str | os.PathLike[str], replaces_input: bool = False) -> Iterator[list[Path]]:
    """Yield one temporary path per target; on success move them all onto their targets.

    Every target is checked first (:func:`check_outputs`; ``replaces_input=True`` lets a target
    be an input of the command, for a file a run updates in place such as a resumed run's
    ``last.ckpt``); each temporary file keeps its target's suffix so that writers detecting the
    format by extension (matplotlib, Mitsuba) still work.
    Raises :class:`~neuralbrdf.errors.OutputError` naming the target for refused outputs and
    :class:`~neuralbrdf.errors.EnvironmentFailure` (or ``OutputError``) for errors while writing
    (module docstring); nothing is left behind on any error.
    """
    given = [Path(target) for target in targets]
    if replaces_input:
        token = _INPUTS.set(None)
        try:
            reals = check_outputs(*given)
        finally:
            _INPUTS.reset(token)
    else:
        reals = check_outputs(*given)
    created: list[Path] = []
    temporaries: list[Path] = []
    current = given[0] if given else Path()
    try:
        for target, real in zip(given, reals):
            current = target
            created += _make_folders(real.parent)
            remove_stale_temporaries(real)
            tmp = _temporary_beside(real)
            temporaries.append(tmp)
            # mkstemp creates 0600; give the output the permissions an ordinary open() would.
            umask = os.umask(0)
            os.umask(umask)
            tmp.chmod(0o666 & ~umask)
        yield list(temporaries)
        current = given[0]
        _commit(list(zip(temporaries, reals)))
    except InputError:
        _clean_up(temporaries, created)
        raise
    except Exception as error:
        current = next((target for target, tmp in zip(given, temporaries) if tmp.name in str(error)), current)
        # a full disk is judged before the temporaries, which fill it, are removed
        failure = environment_failure(error, current)
        _clean_up(temporaries, created)
        if failure is not None:
            raise failure from None
        if isinstance(error, OSError) or any(str(tmp) in str(error) or tmp.name in str(error) for tmp in temporaries):
            raise _output_error(error, current, temporaries) from None
        raise
    except BaseException:
        _clean_up(temporaries, created)
        raise
    finally:
        _clean_up(temporaries, [])


def _clean_up(temporaries: list[Path], created_folders: list[Path]) -> None:
    """Remove the temporary files, then the folders made for them (deepest first) if empty."""
    for tmp in temporaries:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
    for folder in created_folders:
        with contextlib.suppress(OSError):
            folder.rmdir()


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike[str], replaces_input: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; move it onto ``target`` on success.

    Use this for writers that want a path (matplotlib, h5py, onnx); see :func:`atomic_paths`.
    """
    with atomic_paths(target, replaces_input=replaces_input) as (tmp,):
        yield tmp


@contextlib.contextmanager
def atomic_write(target: str | os.PathLike[str], mode: str = "w", **open_kwargs) -> Iterator:
    """Open a temporary file for writing; it replaces ``target`` only if the block succeeds."""
    if "newline" not in open_kwargs and "b" not in mode:
        open_kwargs["newline"] = ""
    with atomic_path(target) as tmp:
        with open(tmp, mode, **open_kwargs) as handle:
            yield handle
