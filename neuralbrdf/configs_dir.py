"""The shipped YAML configs (``configs/`` of the repository, installed as ``neuralbrdf/configs``).

``neuralbrdf train --config abc`` and study profiles name them without a path; a path that
exists is always used as it is.  An *overlay* changes a few values of another config and says
so in its leading comment (``# overlay of: NAME``); ``--config OVERLAY`` alone then loads
``NAME`` first (:func:`overlay_base`).
"""

from __future__ import annotations

import difflib
import os
import re
from pathlib import Path

from neuralbrdf.errors import InputError

#: Folder of the shipped training configs (study profiles in its ``study/``).
CONFIGS_DIR = Path(__file__).resolve().parent / "configs"
#: The leading-comment line of an overlay naming its base config.
_OVERLAY = re.compile(r"^#\s*overlay of:\s*(\S+)\s*$")


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


def overlay_base(path: str | os.PathLike[str]) -> Path | None:
    """The config an overlay file applies to (its ``# overlay of: NAME`` line, resolved like a
    ``--config`` name next to the overlay or among the shipped configs), else ``None``."""
    for line in Path(path).read_text(encoding="utf-8", errors="replace").splitlines():
        if not line.startswith("#"):
            return None
        match = _OVERLAY.match(line.strip())
        if match:
            beside = Path(path).parent / Path(match.group(1)).name
            beside = beside if beside.suffix == ".yaml" else beside.with_suffix(".yaml")
            return beside if beside.is_file() else resolve_config(match.group(1))
    return None


def config_not_found(name: str | os.PathLike[str], folder: str = "", what: str = "configuration") -> InputError:
    """The error for a ``--config`` that is neither a file nor a shipped config: it lists the
    shipped names (and the nearest one) so that the next command can be right."""
    shipped = [path.stem for path in shipped_configs(folder)]
    nearest = difflib.get_close_matches(Path(name).stem, shipped, n=1, cutoff=0.5)
    hint = f"did you mean {nearest[0]}? " if nearest else ""
    return InputError(
        f"no such {what} file, and no shipped {what} of that name; {hint}shipped: {', '.join(shipped)} "
        "(or the path of a YAML file)",
        path=name,
    )
