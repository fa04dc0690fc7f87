"""Check and open what a viewer shows: model files, a truth and a measurement table."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from neuralbrdf.data.table import BrdfTable
from neuralbrdf.explorer.measured import Measured
from neuralbrdf.explorer.models import ViewedModel
from neuralbrdf.explorer.views import Scene

PathLike = str | os.PathLike[str]


def labels(paths: Sequence[PathLike]) -> list[str]:
    """A name per file for legends: its file name, or the path as given where two names are alike."""
    names = [Path(p).name for p in paths]
    return [name if names.count(name) == 1 else os.fspath(path) for name, path in zip(names, paths)]


def open_scene(models: Sequence[PathLike], truth: PathLike | None = None, table: BrdfTable | None = None,
               table_label: str | None = None) -> Scene:
    """The files checked and opened (:class:`~neuralbrdf.errors.InputError` naming the first bad one):
    ``models`` (any kinds), ``truth`` (kind ``reference``) and the measurement ``table``."""
    paths = [*models] + ([truth] if truth is not None else [])
    names = labels(paths)
    viewed = [ViewedModel.load(path, name) for path, name in zip(models, names)]
    truth_model = ViewedModel.load(truth, names[-1], role="truth") if truth is not None else None
    measured = None
    if table is not None:
        measured = Measured(table, table_label or Path(str(table.source)).name)
    return Scene(viewed, truth_model, measured)

