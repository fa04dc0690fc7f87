"""One line for a training configuration that does not parse: the key, where it was given (the
flag or the YAML file) and the nearest valid names.

``neuralbrdf train`` parses its configuration with jsonargparse (LightningCLI), whose errors are
many lines long and, for an option of the model or data module, name a type union
(``Expected a <class 'NoneType'>``) rather than the option.  :func:`describe` turns such a
message into one :class:`~neuralbrdf.errors.InputError`::

    --model.n_start: AbcFitModule has no option 'n_start'; did you mean n_starts? (its options: bounds, max_evaluations, n_starts, seed)
    my.yaml: trainer.max_epoch: Trainer has no option 'max_epoch'; did you mean max_epochs? (...)
    --trainer.max_epochs: expected int, got 'abc'

Keys are shown without jsonargparse's ``init_args`` level (``model.n_starts`` and
``model.init_args.n_starts`` are the same key).  A key given in a config file and on the command
line is reported where jsonargparse meets it first: config files are read before the flags.
"""

from __future__ import annotations

import difflib
import importlib
import inspect
import re
from collections.abc import Iterable, Sequence
from pathlib import Path

import yaml

from neuralbrdf.errors import InputError

#: How many valid names a message lists in full; more are summarised by the nearest ones.
LISTED_NAMES = 16
#: jsonargparse's wrapper levels of a class given by ``class_path``.
_WRAPPERS = ("init_args", "dict_kwargs")

_UNKNOWN_IN_CLASS = re.compile(r"Option '([^']+)' is not accepted")
_CLASS_PATH = re.compile(r"class_path[=:]?\s*'([\w.]+)'")
_PARSER_KEY = re.compile(r'Parser key "([^"]+)"')
_NESTED = re.compile(r"NestedArg\(key='([^']+)'")
_UNKNOWN_OPTION = re.compile(r"does not accept option '([^']+)'")
_UNRECOGNIZED = re.compile(r"unrecognized arguments: (.*)")
_EXPECTED = re.compile(r"Expected a <class '(\w+)'>")
_GOT_VALUE = re.compile(r"(?:Got value|Given value): (.*?)(?:\. Got value: .*)?$", re.MULTILINE)
_INVALID_CHOICE = re.compile(r"invalid choice: '([^']*)' \(choose from (.*)\)")
_REQUIRED = re.compile(r"arguments are required: (\S+)")


def plain_key(key: str) -> str:
    """``key`` without jsonargparse's wrapper levels: ``model.init_args.n_starts`` -> ``model.n_starts``."""
    return ".".join(part for part in key.split(".") if part not in _WRAPPERS)


def flattened_keys(document, prefix: str = "") -> list[str]:
    """Every key path of a parsed YAML document (wrapper levels dropped), parents before children."""
    keys = []
    if isinstance(document, dict):
        for name, value in document.items():
            if name == "class_path":
                continue
            key = prefix if name in _WRAPPERS else (f"{prefix}.{name}" if prefix else str(name))
            if name not in _WRAPPERS:
                keys.append(key)
            keys.extend(flattened_keys(value, key))
    return keys


def config_keys(config: str | Path) -> list[str]:
    """:func:`flattened_keys` of a YAML file (none if it cannot be read)."""
    try:
        return flattened_keys(yaml.safe_load(Path(config).read_text(encoding="utf-8")))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return []


def class_options(class_path: str) -> list[str]:
    """The keyword arguments of ``class_path``'s constructor (what its ``init_args`` may hold)."""
    module_name, _, name = class_path.rpartition(".")
    try:
        cls = getattr(importlib.import_module(module_name), name)
        parameters = inspect.signature(cls.__init__).parameters.values()
    except (ImportError, AttributeError, TypeError, ValueError):
        return []
    kinds = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    # an optimizer's ``params`` come from the module, never from the configuration
    return [p.name for p in parameters if p.kind in kinds and p.name not in ("self", "params")]


def parser_options(parser, parent: str) -> list[str]:
    """The option names directly under ``parent`` (``""``: the top level) of a jsonargparse parser."""
    names = set()
    for action in getattr(parser, "_actions", []):
        dest = getattr(action, "dest", "") or ""
        if dest in ("help", "config", "==SUPPRESS==") or not dest:
            continue
        parts = plain_key(dest).split(".")
        if parent:
            head = parent.split(".")
            if parts[: len(head)] == head and len(parts) > len(head):
                names.add(parts[len(head)])
        else:
            names.add(parts[0])
    return sorted(names)


def where(key: str, args: Sequence[str], configs: Iterable[str | Path], value: str | None = None
          ) -> tuple[str | None, str]:
    """``(config file, how the key is shown)`` of the place ``key`` is given: the first config file
    that holds it (config files are read before the flags), else the command line (``--key``);
    with ``value``, the flag giving that value first (flags override the files); ``(None, key)``
    if neither."""
    given = _flag_values(key, args)
    if value is not None and value in given:
        return None, f"--{key}"
    for config in configs:
        if key in config_keys(config):
            return str(config), key
    return (None, f"--{key}") if given else (None, key)


def _flag_values(key: str, args: Sequence[str]) -> list[str]:
    """The values the command line ``args`` give ``key`` (``--key V`` or ``--key=V``), in order."""
    flags = [(arg, following) for arg, following in zip(args, [*args[1:], ""]) if arg.startswith("--")]
    flagged = [arg[2:].split("=", 1) if "=" in arg else [arg[2:], following] for arg, following in flags]
    return [given_value for name, given_value in flagged if plain_key(name) == key]


def given_at(key: str, args: Sequence[str], configs: Sequence[str | Path]) -> tuple[str | None, str]:
    """``(config file, how the key is shown)`` of the value of ``key`` in effect after parsing: a
    flag (``--key``; flags override the files), else the last config file that holds it, else
    ``(None, key)`` (a default)."""
    if _flag_values(key, args):
        return None, f"--{key}"
    for config in reversed(list(configs)):
        if key in config_keys(config):
            return str(config), key
    return None, key


def _names(bad: str, valid: Sequence[str]) -> str:
    """``; did you mean X?`` and the valid names (all of them when few)."""
    nearest = difflib.get_close_matches(bad, valid, n=3, cutoff=0.6)
    hint = f"; did you mean {', '.join(nearest[:-1])} or {nearest[-1]}?" if len(nearest) > 1 else (
        f"; did you mean {nearest[0]}?" if nearest else "")
    if valid and len(valid) <= LISTED_NAMES:
        return f"{hint} (valid: {', '.join(sorted(valid))})"
    if valid and not nearest:
        return f" (none close among {len(valid)} valid names)"
    return hint


#: Single-source options of the other data modules; the latent fits take such a source as a list of one.
_SOURCE_OPTIONS = ("nbrdf", "merl", "rgl", "virtual")


def _unknown(key: str, owner: str, valid: Sequence[str], args, configs) -> InputError:
    config, shown = where(key, args, configs)
    bad = key.rsplit(".", 1)[-1]
    prefix = f"{shown}: " if config is not None else ""
    what = f"{owner} has no option {bad!r}" if owner else f"no option {bad!r}"
    if "sources" in valid and bad in _SOURCE_OPTIONS:
        what += f"; one {bad} source is a list of one: --data.sources '[{{\"{bad}\": ...}}]'"
    return InputError(f"{prefix}{what}{_names(bad, valid)}", path=config if config is not None else shown)


def _bad_value(key: str, expected: list[str], value: str, args, configs) -> InputError:
    config, shown = where(key, args, configs, value.strip())
    prefix = f"{shown}: " if config is not None else ""
    types = " or ".join(dict.fromkeys(t for t in expected if t != "NoneType")) or "another value"
    return InputError(f"{prefix}expected {types}, got {value.strip()!r}", path=config if config is not None else shown)


def describe(message: str, args: Sequence[str], configs: Sequence[str | Path], parser=None) -> InputError:
    """The :class:`InputError` (one line) for jsonargparse's error ``message`` about the command
    line ``args`` (the config files already among them as ``--config FILE``) and the config files
    ``configs``; ``parser``: the subcommand's parser, for the valid names of non-class keys."""
    classes = _CLASS_PATH.findall(message)
    unknown = _UNKNOWN_IN_CLASS.findall(message)
    parser_keys = _PARSER_KEY.findall(message)
    if unknown and classes:  # an option of a class given by class_path (model, data, optimizer ...)
        class_path, bad = classes[-1], unknown[-1]
        nested = _NESTED.findall(message)
        key = plain_key(f"{parser_keys[0]}.{nested[0]}") if parser_keys and nested else None
        if key is None:  # given in a config file: the first key path there that ends with it
            key = next((k for config in configs for k in config_keys(config) if k.rsplit(".", 1)[-1] == bad),
                       f"{parser_keys[0]}.{bad}" if parser_keys else bad)
        owner = class_path.rsplit(".", 1)[-1]
        return _unknown(key, owner, class_options(class_path), args, configs)
    match = _UNKNOWN_OPTION.search(message) or _UNRECOGNIZED.search(message)
    if match:
        key = plain_key(match.group(1).split()[0].lstrip("-").split("=", 1)[0])
        parent = key.rpartition(".")[0]
        owner = {"trainer": "Trainer"}.get(parent, parent)
        return _unknown(key, owner, parser_options(parser, parent) if parser is not None else [], args, configs)
    match = _INVALID_CHOICE.search(message)
    if match:
        choices = re.findall(r"'([^']*)'", match.group(2))
        return InputError(f"unknown subcommand {match.group(1)!r}{_names(match.group(1), choices)}")
    match = _REQUIRED.search(message)
    if match and match.group(1).split(".")[-1] in ("model", "data"):
        return InputError(f"no {match.group(1).split('.')[-1]} given: name a config with --config NAME (a shipped "
                          "config, see neuralbrdf train --help) or a YAML file that sets its class_path")
    expected, values = _EXPECTED.findall(message), _GOT_VALUE.findall(message)
    if parser_keys and expected and values:
        nested = _NESTED.findall(message)
        key = plain_key(f"{parser_keys[0]}.{nested[0]}" if nested else
                        ".".join(dict.fromkeys(k for k in parser_keys)))
        return _bad_value(key, expected, values[0], args, configs)
    lines = [line.strip(" -") for line in message.splitlines() if line.strip(" -")]
    kept = [line for line in lines if not line.startswith(("Subtypes:", "Given value type:", "Errors:"))]
    return InputError("invalid configuration: " + "; ".join(kept or lines))

