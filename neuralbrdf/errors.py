"""Error types shared by every layer of neuralbrdf, and the exit status each one gives a command.

Bad input must fail with a message that names the file, the row or key and what was expected
(never a NaN that travels on).  :class:`InputError` carries that location so the command line
can print it as one line; :class:`EnvironmentFailure` does the same for a machine that could
not do what was asked (a full disk).  Every command ends with one of the exit statuses below and
prints a failure as one line of the form :func:`error_line` (docs/robustness.md, "Exit status").
"""

from __future__ import annotations

import errno
import os
from os import PathLike

#: The command did what was asked.
EXIT_OK = 0
#: The command ran and its result failed: a fit that failed, an export that failed its
#: validation, a render that is not finite, a study with failed or crashed cells (an unexpected
#: error, a bug, also ends with 1 and its traceback).
EXIT_FAILED = 1
#: The user's input is wrong: a file, a row, an option, a config key, an output that may not be
#: written; nothing was written.
EXIT_BAD_INPUT = 2
#: The machine could not do it: no space left on device, permission denied, a read-only file
#: system, an I/O error; the same command may succeed elsewhere or once that is fixed.
EXIT_ENVIRONMENT = 3

#: ``errno`` values of a write that failed for the machine's sake, not the user's (:class:`EnvironmentFailure`).
ENVIRONMENT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO,
                                errno.EFBIG, errno.ENOMEM, errno.EMFILE, errno.ENFILE, errno.EBUSY, errno.ETXTBSY})


class InputError(ValueError):
    """Invalid user input: a file, row, column or key that does not meet the contract.

    Parameters
    ----------
    message:
        What is wrong and what was expected.
    path:
        The offending file, if any.
    line:
        1-based line number in that file (the header is line 1), if known.
    column:
        Column of a table (CSV), if known.
    key:
        Key of a configuration, metadata entry or other mapping (``model.n_starts``), or a
        command-line option (``--material``), if known; shown as ``key '...'`` (``option '--...'``).
    """

    def __init__(
        self,
        message: str,
        *,
        path: str | PathLike[str] | None = None,
        line: int | None = None,
        column: str | None = None,
        key: str | None = None,
    ) -> None:
        self.path = None if path is None else str(path)
        self.line = line
        self.column = column
        self.key = key
        self.reason = message
        super().__init__(self._format())

    def _format(self) -> str:
        where = []
        if self.path is not None:
            where.append(self.path)
        if self.line is not None:
            where.append(f"line {self.line}")
        if self.column is not None:
            where.append(f"column {self.column!r}")
        if self.key is not None:
            where.append(f"{'option' if self.key.startswith('--') else 'key'} {self.key!r}")
        prefix = ", ".join(where)
        return f"{prefix}: {self.reason}" if prefix else self.reason

    def named(self, key: str) -> InputError:
        """This error naming ``key`` instead of its own (an argument of :mod:`neuralbrdf.api` as the
        option of the command that called it: ``plan`` as ``--plan``)."""
        self.key = key
        self.args = (self._format(),)
        return self


class OutputError(InputError):
    """An output path that cannot or must not be written: an input of the same command, an
    existing non-regular file, an unwritable folder (see :mod:`neuralbrdf.atomic`).  ``path`` is
    the output as the user gave it, never a temporary file."""


class EnvironmentFailure(RuntimeError):
    """The machine, not the input, stopped the command: a file that could not be written for want
    of space, permission or a working disk (``errno`` one of :data:`ENVIRONMENT_ERRNOS`).  The
    message names the file: ``PATH: cannot write: no space left on device``.  Not an
    :class:`InputError`: the command was right, and a study reruns a cell that ended so."""

    def __init__(self, message: str, *, path: str | PathLike[str] | None = None, errno: int | None = None) -> None:
        self.path = None if path is None else str(path)
        self.reason = message
        self.errno = errno
        super().__init__(message if self.path is None else f"{self.path}: {message}")

    @classmethod
    def of(cls, error: OSError, path: str | PathLike[str] | None, what: str = "cannot write") -> EnvironmentFailure:
        """``PATH: WHAT: no space left on device`` for the ``OSError`` ``error``."""
        reason = os.strerror(error.errno) if error.errno else str(error)
        return cls(f"{what}: {reason[:1].lower()}{reason[1:]}", path=path, errno=error.errno)


class Interrupted(KeyboardInterrupt):
    """A command stopped by a signal before it finished: Ctrl-C (``SIGINT``) or ``SIGTERM`` (what
    ``timeout`` and job schedulers send).  Its exit status is ``128 + signal_number``, the shell's
    own for a command a signal ended."""

    def __init__(self, signal_number: int, message: str) -> None:
        self.signal_number = signal_number
        super().__init__(message)


class FitFailed(RuntimeError):
    """A fit that ran but produced no usable model (a non-finite loss, a dead network, a failed
    ABC optimisation); the message is the one-line cause."""


def one_line(error: BaseException, limit: int = 300) -> str:
    """``Type: message`` of any exception on one line, shortened to ``limit`` characters."""
    text = " ".join(line.strip() for line in str(error).splitlines() if line.strip())
    text = text if len(text) <= limit else text[: limit - 3] + "..."
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


def exit_status(error: BaseException) -> int:
    """The exit status a command ends with for ``error`` (module docstring)."""
    if isinstance(error, InputError):
        return EXIT_BAD_INPUT
    if isinstance(error, EnvironmentFailure):
        return EXIT_ENVIRONMENT
    if isinstance(error, Interrupted):
        return 128 + error.signal_number
    return EXIT_FAILED


def error_line(prog: str, message: object) -> str:
    """The one line every command prints for a failure: ``PROG: error: MESSAGE`` (``PROG`` the
    command as typed, e.g. ``neuralbrdf train``: argparse's own form for a bad command line)."""
    return f"{prog}: error: {message}"
