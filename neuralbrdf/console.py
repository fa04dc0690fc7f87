"""What the command line shows a person or a log: warnings as one clean line each, progress as a
bar on a terminal and as a few plain lines elsewhere.

* :func:`clean_warnings` — within it every warning is printed once, as ``warning: MESSAGE`` on
  stderr: no source line, no file path into the package or site-packages, whichever library
  raised it (a gamut clip in the colour pipeline, a missing optional file in a data module);
  a file shipped with the package is named from ``neuralbrdf/`` on.
* :func:`progress` — a ``tqdm`` bar when stderr is a terminal; otherwise (a log file, a pipe, a
  notebook) a :class:`LineProgress` that prints one parseable line at most every
  :data:`LINE_INTERVAL_S` seconds, ``DESC: DONE/TOTAL UNIT (ELAPSED s)``, instead of a bar
  redrawn with carriage returns into the log.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
import warnings
from collections.abc import Iterable, Iterator

#: Seconds between two progress lines when the output is not a terminal.
LINE_INTERVAL_S = 30.0
#: The folder holding the installed package: files shipped in it are named from ``neuralbrdf/`` on.
_INSTALL_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep


def on_terminal() -> bool:
    """Whether a person watches the output: stdout and stderr are both terminals."""
    return all(stream is not None and stream.isatty() for stream in (sys.stdout, sys.stderr))


@contextlib.contextmanager
def clean_warnings() -> Iterator[None]:
    """Every warning within, printed once per distinct message as ``warning: MESSAGE`` (module
    docstring) and handed to a recorder around it, if any; filters added inside still apply, and
    everything is restored afterwards."""
    shown: set[str] = set()
    # Who receives warnings now: Python's own printer (replaced here), or a recorder such as
    # ``catch_warnings(record=True)`` or ``pytest.warns``, which still gets every one.
    recorder = warnings._showwarnmsg_impl
    recorder = None if getattr(recorder, "__module__", None) == "warnings" else recorder

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        text = " ".join(str(message).split()).replace(_INSTALL_ROOT, "")
        if text not in shown:
            shown.add(text)
            print(f"warning: {text}", file=file if file is not None else sys.stderr)
        if recorder is not None:
            recorder(warnings.WarningMessage(message, category, filename, lineno, file, line))

    with warnings.catch_warnings():
        warnings.simplefilter("default")
        warnings.showwarning = show
        yield


class LineProgress:
    """The part of ``tqdm``'s interface the package uses, printing plain lines (module docstring)."""

    def __init__(self, iterable: Iterable | None = None, *, total: int | None = None, desc: str = "",
                 unit: str = "it", disable: bool = False, file=None, **_ignored) -> None:
        self.iterable = iterable
        self.total = total if total is not None or iterable is None else _length(iterable)
        self.desc, self.unit, self.disable = desc, unit, disable
        self.file = file if file is not None else sys.stderr
        self.n = 0
        self.postfix = ""
        self._started = self._shown = time.monotonic()

    def __iter__(self):
        for item in self.iterable:
            yield item
            self.update()

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def update(self, n: int = 1) -> None:
        self.n += n
        now = time.monotonic()
        if not self.disable and now - self._shown >= LINE_INTERVAL_S:
            self._shown = now
            total = f"/{self.total}" if self.total is not None else ""
            postfix = f" {self.postfix}" if self.postfix else ""
            print(f"{self.desc}: {self.n}{total} {self.unit} ({now - self._started:.0f} s){postfix}", file=self.file,
                  flush=True)

    def set_postfix_str(self, text: str, refresh: bool = True) -> None:
        self.postfix = text

    def write(self, line: str, file=None) -> None:
        """``line`` on its own line (``tqdm.write``)."""
        print(line, file=file if file is not None else self.file, flush=True)

    def close(self) -> None:
        pass


def _length(iterable) -> int | None:
    try:
        return len(iterable)
    except TypeError:
        return None


def progress(iterable: Iterable | None = None, **kwargs):
    """``tqdm(iterable, **kwargs)`` on a terminal, else :class:`LineProgress` (module docstring)."""
    if on_terminal():
        from tqdm.auto import tqdm

        return tqdm(iterable, **kwargs)
    return LineProgress(iterable, **kwargs)
