"""The level-of-detail settings (docs/select.md) from one YAML file, by default the shipped ``configs/lod/default.yaml``.

Three sections: ``ladder`` (:class:`~neuralbrdf.lod.ladder.LadderSettings`, with the students'
training in ``ladder.distill``: :class:`~neuralbrdf.lod.distill.DistillSettings`), ``select``
(:class:`~neuralbrdf.lod.select.SelectSettings`) and ``fast_paths`` (the fast paths
``neuralbrdf export`` embeds in a model file: :class:`~neuralbrdf.lod.fast_paths.FastPathSettings`).  The file is the only place their values are
written down: every key of a section is required (except ``ladder.error_strata``, the
metric's own definition, :data:`~neuralbrdf.evaluation.scores.HEMISPHERE_STRATA` unless given),
an unknown key or a value of the wrong type is an :class:`~neuralbrdf.errors.InputError` naming
the file and the key (:mod:`neuralbrdf.settings_file`).  ``neuralbrdf ladder``, ``neuralbrdf select`` and ``neuralbrdf export`` read it (``--config`` names
another, a path or a shipped name) and their options override single values
(:func:`dataclasses.replace`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from neuralbrdf.lod.distill import DistillSettings
from neuralbrdf.lod.fast_paths import FastPathSettings
from neuralbrdf.lod.ladder import LadderSettings
from neuralbrdf.lod.select import SelectSettings
from neuralbrdf.settings_file import load_sections

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
    path, sections = load_sections(name, CONFIG_FOLDER, SECTIONS, "level-of-detail config")
    return LodConfig(path, **sections)
