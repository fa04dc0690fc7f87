"""Settings files: YAML sections read into frozen dataclasses, every key checked (docs/select.md#settings, docs/how-many-measurements.md).

A settings file (``configs/lod/default.yaml``, ``configs/acquisition/default.yaml``) is the only
place its values are written down: each top-level section becomes one dataclass, every field
without a default is required, an unknown section or key or a value of the wrong type is an
:class:`~neuralbrdf.errors.InputError` naming the file and the key (``ladder.students[1]``).
Values are typed by the dataclass's annotations: ``int``, ``float`` (integers accepted),
``bool``, ``str``, ``X | None``, ``tuple[X, ...]``, fixed tuples and nested dataclasses.
"""

from __future__ import annotations

import dataclasses
import os
import types
import typing
from pathlib import Path

import yaml

from neuralbrdf.configs_dir import resolve_config
from neuralbrdf.errors import InputError
from neuralbrdf.limits import file_problem


def load_sections(name: str | os.PathLike[str], folder: str, sections: dict[str, type], what: str) -> tuple[Path, dict]:
    """The file ``name`` (a YAML file, or a shipped config of ``configs/folder``) and its checked
    ``sections`` (section name → dataclass); ``what`` names the kind of file in errors."""
    path = resolve_config(name, folder)
    if not Path(path).is_file():
        raise InputError(f"{file_problem(path) or 'no such ' + what}; expected a YAML file or a shipped name like "
                         "'default'", path=path)
    try:
        raw = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        raise InputError(f"not valid YAML ({error})", path=path) from None
    built = {section: build(cls, (raw or {}).get(section) if isinstance(raw, dict) else raw, section, path)
             for section, cls in sections.items()}
    unknown = sorted(set(raw) - set(sections)) if isinstance(raw, dict) else []
    if unknown:
        raise InputError(f"unknown section; expected {', '.join(sections)}", path=path, key=unknown[0])
    return Path(path), built


def build(cls, mapping, key: str, path):
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
        return build(hint, value, key, path)
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
