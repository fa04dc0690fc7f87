"""The short ``neuralbrdf train --help`` (and ``train.py --help``): configs and data options.

LightningCLI's own ``fit --help`` lists every Trainer option (hundreds of lines) and none of the
data module's, because the data module is chosen by the config.  This help names the shipped
configs (the first line of each file's leading comment) and, for each data module those
configs use, its options as ``--data.NAME`` with the module's own documentation (units
included), read from the class docstring so that it cannot drift from the code.
"""

from __future__ import annotations

import importlib
import inspect
import re
import textwrap

import yaml

from neuralbrdf.configs_dir import overlay_base, shipped_configs

USAGE = """\
usage: neuralbrdf train {fit,validate,test} --config CONFIG [--data.KEY VALUE ...] [--run_dir DIR]
       (python train.py ... is the same command)

Train, validate or test a model from a YAML config (LightningCLI). CONFIG is a shipped config by
name (e.g. abc, spectral_mlp) or any YAML file; several --config files are merged in order, the
options after them override them. Any config value can be overridden on the command line: --data.path FILE,
--trainer.max_epochs 5, --model.gamma 1.0.
"""

COMMON = """\
run options:
  --run_dir DIR            run directory (default runs/<config>/<timestamp>); never overwritten
  --resume / --overwrite   continue the run in --run_dir from its last.ckpt / replace it
  --seed_everything N      seed of the run
  --trainer.max_epochs N   training length
  --ckpt_path FILE         validate/test: the checkpoint to evaluate
  --verbose                keep Lightning's start-up lines, tips and deprecation warnings

The run writes config.yaml, checkpoints/, metrics.csv and metrics.json; export the checkpoint
with: neuralbrdf export --ckpt RUN/checkpoints/best.ckpt --out MODEL.onnx
Every Lightning option: neuralbrdf train fit --config CONFIG --help
"""


def _leading_comment(text: str) -> list[str]:
    lines = []
    for line in text.splitlines():
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("#").strip())
    return lines


#: A sentence ends at ". " not preceded by these abbreviations.
_SENTENCE_END = re.compile(r"(?<!\bal)(?<!\bEq)(?<!\be\.g)(?<!\bi\.e)\.\s")


def _summary(comment: list[str]) -> str:
    """The first sentence of the comment's first paragraph (up to a command example or blank)."""
    words = []
    for line in comment:
        if not line or line.startswith(("python ", "neuralbrdf ")):
            break
        words.append(line)
    text = " ".join(words)
    return _SENTENCE_END.split(text, maxsplit=1)[0].rstrip(".:")


def plain(text: str) -> str:
    """Docstring markup as terminal text: ``x`` and :role:`~a.b.x` become x."""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", lambda m: m.group(1).rsplit(".", 1)[-1] if "~" in m.group(0) else m.group(1), text)
    return text.replace("``", "")


def _data_class(config: dict) -> str | None:
    data = config.get("data") if isinstance(config, dict) else None
    return data.get("class_path") if isinstance(data, dict) else None


def parameter_docs(class_path: str) -> list[tuple[str, str]]:
    """``(names, description)`` of the numpydoc ``Parameters`` section of ``class_path``'s docstring."""
    module_name, _, class_name = class_path.rpartition(".")
    cls = getattr(importlib.import_module(module_name), class_name)
    doc = inspect.getdoc(cls) or ""
    match = re.search(r"Parameters\n-+\n(.*?)(\n\n[A-Z][a-z]+\n-+\n|\Z)", doc, flags=re.S)
    if not match:
        return []
    entries, names, text = [], None, []
    for line in match.group(1).splitlines():
        if line and not line.startswith(" "):
            if names:
                entries.append((names, " ".join(text)))
            names, text = line.rstrip(":"), []
        elif line.strip():
            text.append(line.strip())
    if names:
        entries.append((names, " ".join(text)))
    return entries


def help_text() -> str:
    """The whole help (module docstring)."""
    out = [USAGE, "shipped configs (--config NAME):"]
    data_classes: dict[str, list[str]] = {}
    for path in shipped_configs():
        text = path.read_text(encoding="utf-8")
        summary = _summary([line for line in _leading_comment(text) if not line.startswith("overlay of:")])
        base = overlay_base(path)
        if base is not None:
            summary = f"[overlay: {path.stem} alone loads {base.stem} first] {summary}"
        out.extend(textwrap.wrap(plain(summary), 96, initial_indent=f"  {path.stem:<24}", subsequent_indent=" " * 26))
        class_path = _data_class(yaml.safe_load(text) or {})
        if class_path:
            data_classes.setdefault(class_path, []).append(path.stem)
    for class_path, users in data_classes.items():
        out.append(f"\ndata options of {', '.join(users)} ({class_path.rsplit('.', 1)[-1]}):")
        for names, description in parameter_docs(class_path):
            flags = ", ".join(f"--data.{name.strip()}" for name in names.split(","))
            out.append(f"  {flags}")
            out.extend(textwrap.wrap(plain(description), 92, initial_indent="      ", subsequent_indent="      "))
    out.append("")
    out.append(COMMON)
    return "\n".join(out)
