"""How a training command ended, read from the exception that ended it: a fit that ran and failed
(:func:`fit_failure`), bad input (:func:`input_error`), a file the machine could not write
(:func:`environment_failure`) or Ctrl-C and SIGTERM (:func:`interruption`); each becomes one line and
its exit status (:mod:`neuralbrdf.errors`)."""

from __future__ import annotations

import signal

from pytorch_lightning.utilities.exceptions import SIGTERMException

from neuralbrdf.atomic import environment_oserror
from neuralbrdf.errors import EnvironmentFailure, FitFailed, InputError, Interrupted

#: Errors raised inside a fit that mean the data cannot support it (e.g. no measured value above
#: the metric's floor in all-zero data): reported like :class:`FitFailed`, in one line, exit 1.
#: Any other exception is a bug and keeps its traceback (``metrics.json`` still says failed).
DATA_FAILURES = (ValueError, ArithmeticError)


def interruption(exc: BaseException) -> int | None:
    """The signal that stopped a command, if ``exc`` is how Lightning reports one: SIGTERM as
    ``SIGTERMException``, Ctrl-C as ``KeyboardInterrupt`` (or the ``sys.exit(1)`` it becomes)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, SIGTERMException):
            return signal.SIGTERM
        if isinstance(exc, KeyboardInterrupt):
            return signal.SIGINT
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def signal_name(number: int) -> str:
    return {signal.SIGINT: "Ctrl-C (SIGINT)"}.get(number, signal.Signals(number).name)


def fit_failure(exc: BaseException) -> str | None:
    """The one-line cause of a fit that ran and failed (:class:`FitFailed`, or a
    :data:`DATA_FAILURES` error :class:`~neuralbrdf.lightning.fit_health.FitHealth` recorded), else ``None``."""
    if isinstance(exc, FitFailed):
        return str(exc)
    cause = getattr(exc, "neuralbrdf_fit_failure", None)
    return cause if cause is not None and isinstance(exc, DATA_FAILURES) else None


def environment_failure(exc: BaseException) -> EnvironmentFailure | None:
    """The :class:`~neuralbrdf.errors.EnvironmentFailure` behind ``exc``, or one made of the
    ``OSError`` of the machine's making behind it (a log that Lightning writes itself), naming
    its file or else the run directory; ``None`` otherwise."""
    seen = set()
    cause = exc
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, EnvironmentFailure):
            return cause
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    oserror = environment_oserror(exc)
    if oserror is None:
        return None
    return EnvironmentFailure.of(oserror, oserror.filename or getattr(exc, "neuralbrdf_run_dir", None))


def input_error(exc: BaseException) -> InputError | None:
    """The :class:`InputError` behind ``exc`` (jsonargparse wraps errors raised by constructors)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, InputError):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def run_failure(exc: BaseException) -> BaseException | None:
    """What an exception out of a run means to its caller, ``None`` where it stays as it is: bad
    input or the machine (:func:`input_error`, :func:`environment_failure`), a failed fit
    (:class:`FitFailed` with the run's folder), or Ctrl-C or SIGTERM (:class:`Interrupted`, which
    Lightning raises as ``SystemExit``)."""
    if isinstance(exc, Exception):
        error = input_error(exc) or environment_failure(exc)
        if error is not None:
            return error
        cause = fit_failure(exc)
        if cause is None:
            return None
        failure = FitFailed(cause)
        failure.neuralbrdf_run_dir = getattr(exc, "neuralbrdf_run_dir", None)
        return failure
    signal_number = interruption(exc)
    if signal_number is None:
        return None
    run_dir = getattr(exc, "neuralbrdf_run_dir", None)
    kept = f"; {run_dir} keeps what the run saved (a fit: --resume continues it)" if run_dir else ""
    return Interrupted(signal_number, f"interrupted by {signal_name(signal_number)}{kept}")

