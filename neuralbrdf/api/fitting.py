"""Fitting: :func:`fit` a model of a kind to a material through the kind's training config."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from neuralbrdf.api.arguments import PathLike, as_path, check_flags
from neuralbrdf.api.materials import Source, read
from neuralbrdf.api.model_files import Model, export
from neuralbrdf.errors import InputError

#: Fit kinds and the shipped config each runs (``configs/NAME.yaml``): a new kind is one entry.
FIT_KINDS: dict[str, str] = {
    "auto": "auto",
    "abc": "abc",
    "spectral_mlp": "spectral_mlp",
    "nlb": "nlb_latent",
    "nlb_spectral": "nlb_spectral",
    "pca": "pca",
}


@dataclass(frozen=True)
class FitResult:
    """A finished fit: its run directory (config.yaml, checkpoints/, metrics.csv, metrics.json),
    the checkpoint to export and the metrics the run wrote to ``metrics.json`` (``status`` among them)."""

    kind: str
    run_dir: Path
    checkpoint: Path
    metrics: dict[str, Any] = field(repr=False)

    def export(self, out: PathLike, material: str | None = None, *, fast: bool | None = None, rgb_head: bool = True,
               config: str = "default") -> Model:
        """:func:`export` of this fit's checkpoint (the same file, checks and defaults)."""
        return export(self.checkpoint, out, material, fast=fast, rgb_head=rgb_head, config=config)


def _data_options(config: str, source: Source) -> dict[str, Any]:
    """The overrides that hand ``source`` to the data module of ``config``: its own ``data.*`` keys
    when it takes them, else one entry of its ``data.sources`` list."""
    import yaml

    from neuralbrdf.configs_dir import overlay_base, resolve_config
    from neuralbrdf.lightning.config_errors import class_options

    path = resolve_config(config)
    if not path.is_file():
        from neuralbrdf.configs_dir import config_not_found

        raise config_not_found(config)
    class_path = None
    for file in (overlay_base(path), path):
        if file is not None:
            data = (yaml.safe_load(file.read_text(encoding="utf-8")) or {}).get("data")
            class_path = data.get("class_path", class_path) if isinstance(data, dict) else class_path
    accepted = class_options(class_path) if class_path else []
    options = source.options()
    if set(options) <= set(accepted):
        return {f"data.{key}": value for key, value in options.items()}
    if "sources" in accepted:
        return {"data.sources": [options]}
    from neuralbrdf.sources import SAMPLED_KEYS

    takes = [key for key in ("path", "reference", *SAMPLED_KEYS, "virtual") if key in accepted]
    raise InputError(f"the {Path(config).stem} config's data module takes {', '.join(takes)}; "
                     f"{source.location} is a {source.kind} source")


def fit(kind: str, data: Source | PathLike | None = None, *, config: PathLike | None = None,
        run_dir: PathLike | None = None, overrides: Mapping[str, Any] | None = None,
        overwrite: bool = False) -> FitResult:
    """Fit a model of ``kind`` (:data:`FIT_KINDS`: ``auto``, ``abc``, ``spectral_mlp``, ``nlb``, ``nlb_spectral``, ``pca``) to ``data``
    (a :class:`Source` or what :func:`read` takes; ``None``: the config's own data) through the
    kind's shipped config, or ``config`` (a shipped name or a YAML file); ``overrides`` sets config
    keys to values, typed as the config's (``{"trainer.max_epochs": 5}``, what ``--trainer.max_epochs 5``
    sets; a message about one names it so).  The run gets them as data
    (:func:`~neuralbrdf.lightning.fit_call.fit_run`).  ``run_dir``: where the run
    is written (default ``runs/<config>/<timestamp>``); a run there is replaced only with
    ``overwrite``.  Raises :class:`~neuralbrdf.errors.FitFailed` when the fit fails.

    >>> import tempfile, neuralbrdf as nb
    >>> quick = {"model.n_starts": 1, "data.eval_plan": None}     # one start, no hemisphere score: seconds
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     result = nb.fit("abc", "virtual:gold", run_dir=f"{folder}/abc", overrides=quick)
    ...     print(result.checkpoint.name, result.metrics["status"], result.metrics["fit/abc/success"])
    best.ckpt ok True
    >>> nb.fit("abc", "virtual:gold", overrides={"model.n_start": 1})
    Traceback (most recent call last):
    neuralbrdf.errors.InputError: --model.n_start: AbcFitModule has no option 'n_start'; did you mean n_starts? (valid: bounds, max_evaluations, n_starts, seed)
    """
    import torch

    from neuralbrdf.data.units import overridden_by
    from neuralbrdf.lightning.fit_call import fit_run

    if not isinstance(kind, str) or kind not in FIT_KINDS:
        raise InputError(f"unknown fit kind {kind!r}; expected one of {', '.join(FIT_KINDS)}")
    check_flags(overwrite=overwrite)
    config = os.fspath(as_path(config, "config", "a shipped config's name or a YAML file")) if config is not None \
        else FIT_KINDS[kind]
    if run_dir is not None:
        as_path(run_dir, "run_dir")
    if overrides is not None and not isinstance(overrides, Mapping):
        raise InputError(f"overrides: expected a mapping of config keys to values such as {{'trainer.max_epochs': 5}}, "
                         f"got {type(overrides).__name__} {overrides!r}")
    if data is not None and not isinstance(data, Source):
        as_path(data, "data", "a Source, a file path or 'virtual:NAME'")
    with overridden_by(f"nb.fit({kind!r}, nb.read(..., trust_units=True))"):
        source = read(data) if data is not None and not isinstance(data, Source) else data
    settings = {} if source is None else _data_options(config, source)
    settings.update(overrides or {})
    if run_dir is not None:
        settings["run_dir"] = os.fspath(run_dir)
    if overwrite:
        settings["overwrite"] = True
    threads = torch.get_num_threads()
    try:
        run = fit_run([config], settings)
    finally:
        torch.set_num_threads(threads)  # a config's num_threads holds for its run only
    if run.checkpoint is None:
        raise InputError(f"the fit left no checkpoint to export in {run.run_dir / 'checkpoints'}; the {config} "
                         "config must save one named best or fitted")
    return FitResult(kind, run.run_dir, run.checkpoint, run.metrics)
