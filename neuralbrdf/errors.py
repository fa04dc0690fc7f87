"""Error types shared by every layer of neuralbrdf.

Bad input must fail with a message that names the file, the row or key and what was expected
(never a NaN that travels on).  :class:`InputError` carries that location so the command line
can print it as one line.
"""

from __future__ import annotations

from os import PathLike


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


class OutputError(InputError):
    """An output path that cannot or must not be written: an input of the same command, an
    existing non-regular file, an unwritable folder (see :mod:`neuralbrdf.atomic`).  ``path`` is
    the output as the user gave it, never a temporary file."""


class FitFailed(RuntimeError):
    """A fit that ran but produced no usable model (a non-finite loss, a dead network, a failed
    ABC optimisation); the message is the one-line cause."""


def one_line(error: BaseException, limit: int = 300) -> str:
    """``Type: message`` of any exception on one line, shortened to ``limit`` characters."""
    text = " ".join(line.strip() for line in str(error).splitlines() if line.strip())
    text = text if len(text) <= limit else text[: limit - 3] + "..."
    return f"{type(error).__name__}: {text}" if text else type(error).__name__
