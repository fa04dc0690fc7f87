"""Checks of the API's arguments, each a one-line :class:`~neuralbrdf.errors.InputError` naming the argument."""

from __future__ import annotations

import math
import os
from pathlib import Path

from neuralbrdf.errors import InputError

PathLike = str | os.PathLike[str]


def as_path(value, name: str, expected: str = "a file path (str or os.PathLike)") -> Path:
    """``value`` as a :class:`~pathlib.Path`, or :class:`InputError` naming the argument ``name``."""
    if isinstance(value, (str, os.PathLike)):
        return Path(value)
    raise InputError(f"{name}: expected {expected}, got {type(value).__name__} {value!r}")


def check_text(name: str, value, optional: bool = True) -> None:
    """:class:`InputError` naming the argument ``name`` unless ``value`` is a string (or ``None``)."""
    if not (isinstance(value, str) or (optional and value is None)):
        expected = "a string or None" if optional else "a string"
        raise InputError(f"{name}: expected {expected}, got {type(value).__name__} {value!r}")


def check_integers(**values) -> None:
    """:class:`InputError` naming the first of ``values`` that is neither an integer nor ``None``."""
    for name, value in values.items():
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)):
            raise InputError(f"{name} must be an integer, got {type(value).__name__} {value!r}")


def check_flags(**values) -> None:
    """:class:`InputError` naming the first of ``values`` that is not a real ``bool`` (``"no"`` and
    ``0`` are not flags: a string would be true)."""
    for name, value in values.items():
        if not isinstance(value, bool):
            raise InputError(f"{name}: expected True or False, got {type(value).__name__} {value!r}")


def check_numbers(**values) -> None:
    """:class:`InputError` naming the first of ``values`` that is neither a finite real number nor ``None``."""
    for name, value in values.items():
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not math.isfinite(value)):
            raise InputError(f"{name}: expected a finite number, got {type(value).__name__} {value!r}")


def check_positive(**values) -> None:
    check_integers(**values)
    for name, value in values.items():
        if value is not None and value < 1:
            raise InputError(f"{name} must be a positive integer, got {value!r}")
