"""The level-of-detail settings (docs/select.md) from one YAML file, by default the shipped ``configs/lod/default.yaml``.

Three sections: ``ladder`` (:class:`~neuralbrdf.lod.ladder.LadderSettings`, with the students'
training in ``ladder.distill``: :class:`~neuralbrdf.lod.distill.DistillSettings`), ``select``
(:class:`~neuralbrdf.lod.select.SelectSettings`) and ``fast_paths`` (the fast paths
``neuralbrdf export`` embeds in a model file: :class:`~neuralbrdf.lod.fast_paths.FastPathSettings`).  The file is the only place their values are
written down: every key of a section is required (except ``ladder.error_strata``, the
metric's own definition, :data:`~neuralbrdf.evaluation.scores.HEMISPHERE_STRATA` unless given),
an unknown key or a value of the wrong type is an :class:`~neuralbrdf.errors.InputError` naming
the file and the key.  ``neuralbrdf ladder``, ``neuralbrdf select`` and ``neuralbrdf export`` read it (``--config`` names
another, a path or a shipped name) and their options override single values
(:func:`dataclasses.replace`).
"""

from __future__ import annotations

import dataclasses
import os
import types
import typing
from dataclasses import dataclass
from pathlib import Path

import yaml

from neuralbrdf.configs_dir import resolve_config
from neuralbrdf.errors import InputError
from neuralbrdf.lod.distill import DistillSettings
from neuralbrdf.lod.fast_paths import FastPathSettings
from neuralbrdf.lod.ladder import LadderSettings
from neuralbrdf.lod.select import SelectSettings

#: The shipped configs' folder (``configs/lod/``, apart from the training configs) and default name.
CONFIG_FOLDER = "lod"
DEFAULT_CONFIG = "default"
SECTIONS = {"ladder": LadderSettings, "select": SelectSettings, "fast_paths": FastPathSettings}


@dataclass(frozen=True)
class LodConfig:
    path: Path
    ladder: LadderSettings
    select: SelectSettings
    fast_paths: FastPathSettings


def load_lod_config(name: str | os.PathLike[str] = DEFAULT_CONFIG) -> LodConfig:
    """The checked settings of ``name`` (a YAML file or a shipped config's name; module docstring)."""
    path = resolve_config(name, CONFIG_FOLDER)
    if not Path(path).is_file():
        raise InputError("no such level-of-detail config; expected a YAML file or a shipped name like 'default'", path=path)
    try:
        raw = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        raise InputError(f"not valid YAML ({error})", path=path) from None
    sections = {name: _build(cls, (raw or {}).get(name) if isinstance(raw, dict) else raw, name, path)
                for name, cls in SECTIONS.items()}
    unknown = sorted(set(raw) - set(SECTIONS)) if isinstance(raw, dict) else []
    if unknown:
        raise InputError(f"unknown section; expected {', '.join(SECTIONS)}", path=path, key=unknown[0])
    return LodConfig(Path(path), **sections)


def _build(cls, mapping, key: str, path):
    """An instance of dataclass ``cls`` from ``mapping`` (checked keys and types)."""
    if not isinstance(mapping, dict):
        raise InputError(f"expected a mapping, got {type(mapping).__name__}", path=path, key=key)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    for name in mapping:
        if name not in fields:
            raise InputError(f"unknown key; expected one of {', '.join(fields)}", path=path, key=f"{key}.{name}")
    values = {}
    for name, field in fields.items():
        if name not in mapping:
            if field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
                raise InputError("missing", path=path, key=f"{key}.{name}")
            continue
        values[name] = _value(hints[name], mapping[name], f"{key}.{name}", path)
    return cls(**values)


def _value(hint, value, key: str, path):
    """``value`` checked against (and converted to) the type ``hint``."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if dataclasses.is_dataclass(hint):
        return _build(hint, value, key, path)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _value(inner, value, key, path)
    if origin is tuple:
        if not isinstance(value, list):
            raise InputError(f"expected a list, got {value!r}", path=path, key=key)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_value(args[0], item, f"{key}[{i}]", path) for i, item in enumerate(value))
        if len(value) != len(args):
            raise InputError(f"expected a list of {len(args)}, got {value!r}", path=path, key=key)
        return tuple(_value(a, item, f"{key}[{i}]", path) for i, (a, item) in enumerate(zip(args, value)))
    if isinstance(value, bool):  # YAML's true/false: a number field refuses it
        if hint is bool:
            return value
    elif hint is int and isinstance(value, int):
        return value
    elif hint is float and isinstance(value, (int, float)):
        return float(value)
    elif hint is str and isinstance(value, str):
        return value
    raise InputError(f"expected {getattr(hint, '__name__', hint)}, got {value!r}", path=path, key=key)
