"""Level of detail (docs/select.md): the cost :func:`ladder` of a model file, and the per-material
:func:`select`-ion of its rungs in a scene within an image tolerance."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from neuralbrdf.api.arguments import PathLike, as_path


def ladder_dir(model: PathLike, out_dir: PathLike | None = None) -> Path:
    """Where :func:`ladder` writes the ladder of ``model``: ``out_dir``, else ``MODEL.ladder`` beside
    the model (where :func:`select` looks first)."""
    from neuralbrdf.lod.select import default_ladder_dir

    model = as_path(model, "model", "a model file (.onnx) path")
    return as_path(out_dir, "out_dir", "a folder path") if out_dir is not None else default_ladder_dir(model)


def ladder(model: PathLike, out_dir: PathLike | None = None, *, config: PathLike = "default",
           tables: list[tuple[int, int, int, int]] | None = None, students: list[tuple[int, int]] | None = None,
           log=print) -> dict:
    """Make the cost ladder of the model file ``model``: an ABC fit to its own dense samples, the
    model baked into tables (node counts ``(theta_h, theta_d, phi_d, lambda)`` each) and, for a
    spectral model, smaller spectral MLPs distilled from it (``(hidden layers, units)`` each), each a
    model file recording its hemisphere log-cos RMSE against the parent and its Dr.Jit cost per
    query; ``tables``/``students`` default to the ``ladder`` section of ``config`` (a shipped name or
    a YAML file; ``[]``: none).  Writes ``out_dir`` (:func:`ladder_dir`) with
    ``ladder.json``, together or not at all; ``log`` gets each progress line.  Returns ladder.json's
    content."""
    from neuralbrdf.lod.config import load_lod_config
    from neuralbrdf.lod.ladder import build_ladder

    out_dir = ladder_dir(model, out_dir)
    settings = load_lod_config(config).ladder
    if tables is not None:
        settings = dataclasses.replace(settings, tables=tuple(tuple(t) for t in tables))
    if students is not None:
        settings = dataclasses.replace(settings, students=tuple(tuple(s) for s in students))
    return build_ladder(model, out_dir, settings, log=log)


def select(scene: PathLike, out: PathLike, *, ladders: list[PathLike] = (), config: PathLike = "default",
           tolerance: float | None = None, object_tolerance: float | None = None, variant: str | None = None,
           resolution: int | None = None, spp: int | None = None, max_spp: int | None = None,
           seed: int | None = None, log=print) -> dict:
    """Pick, per ``neuralbrdf`` material of ``scene``, the cheapest rung of its ladder (among
    ``ladders`` and ``MODEL.ladder`` beside each model) whose contribution keeps the whole image's mean
    CIEDE2000 within ``tolerance`` and the material's own pixels within ``object_tolerance``, and
    verify it.  The settings default to the ``select`` section of ``config``; ``max_spp`` is at
    least ``spp``.  Writes ``out`` (the scene pointing at the chosen rungs) and ``out`` with suffix
    ``.json``; ``log`` gets each progress line.  Returns the JSON's content."""
    from neuralbrdf.lod.config import load_lod_config
    from neuralbrdf.lod.select import select as run_selection

    given = {"tolerance": tolerance, "object_tolerance": object_tolerance, "variant": variant,
             "resolution": resolution, "spp": spp, "max_spp": max_spp, "seed": seed}
    settings = load_lod_config(config).select
    settings = dataclasses.replace(settings, **{name: value for name, value in given.items() if value is not None})
    settings = dataclasses.replace(settings, max_spp=max(settings.max_spp, settings.spp))
    return run_selection(as_path(scene, "scene", "a Mitsuba scene file path"), out,
                         settings, [Path(d) for d in ladders], log=log)
