"""The shipped YAML configs (``configs/`` of the repository, installed as ``neuralbrdf/configs``).

``neuralbrdf train --config abc`` and study profiles name them without a path; a path that
exists is always used as it is.
"""

from __future__ import annotations

import os
from pathlib import Path

#: Folder of the shipped training configs (study profiles in its ``study/``).
CONFIGS_DIR = Path(__file__).resolve().parent / "configs"


def shipped_configs(folder: str = "") -> list[Path]:
    """The shipped ``*.yaml`` files of ``CONFIGS_DIR/folder``, sorted by name."""
    return sorted((CONFIGS_DIR / folder).glob("*.yaml"))


def resolve_config(name: str | os.PathLike[str], folder: str = "") -> Path:
    """``name`` if it is a file, else the shipped config it names (``abc``, ``abc.yaml`` or
    ``configs/abc.yaml``); ``name`` unchanged when neither exists (the caller reports it)."""
    path = Path(name)
    if path.is_file():
        return path
    parts = path.parts[1:] if path.parts[:1] == ("configs",) else path.parts
    shipped = CONFIGS_DIR / folder / Path(*parts) if parts else None
    if shipped is not None and shipped.suffix != ".yaml":
        shipped = shipped.with_suffix(".yaml")
    return shipped if shipped is not None and shipped.is_file() else path
