"""A fit's settings read from its config file, for fits that run without a trainer.

``neuralbrdf train fit`` builds a fit's module from the ``model.init_args`` of its YAML config.
The fits that run in process — the spectral NLB's latent fit of ``plan next``
(:mod:`neuralbrdf.acquisition.latent_fit`) and both candidates of the ``auto`` fit
(:mod:`neuralbrdf.lightning.auto_fit`) — read the same keys from the same files, so a config stays
the single source of a fit's hyperparameters: :func:`model_settings` reads them (the config's
overlay base first), :func:`spectral_latent_fit` builds the spectral NLB's module and
:func:`abc_settings` the ABC fit's arguments.
"""

from __future__ import annotations

import functools
import inspect
import importlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from neuralbrdf.configs_dir import config_not_found, overlay_base, resolve_config
from neuralbrdf.errors import InputError
from neuralbrdf.lightning.nlb_spectral_fit import SpectralLatentFitModule

#: The shipped configs of the two in-process fits.
SPECTRAL_NLB_CONFIG = "nlb_spectral"
ABC_CONFIG = "abc"


def model_settings(config: str, module_class: type) -> dict:
    """The ``model.init_args`` of ``config`` (a shipped name or a YAML file; its overlay base first),
    which must configure ``module_class``; else :class:`InputError` naming the file."""
    path = resolve_config(config)
    if not Path(path).is_file():
        raise config_not_found(config)
    settings: dict = {}
    for file in (overlay_base(path), path):
        if file is None:
            continue
        model = (yaml.safe_load(Path(file).read_text(encoding="utf-8")) or {}).get("model") or {}
        if model.get("class_path", "").rpartition(".")[2] not in ("", module_class.__name__):
            raise InputError(f"is a {model['class_path']} config; expected a {module_class.__name__} one", path=file)
        settings.update(model.get("init_args") or {})
    return settings


def _factory(spec: Any):
    """A callable from a config's ``{class_path, init_args}`` (the optimiser of the screening)."""
    if not isinstance(spec, Mapping) or "class_path" not in spec:
        raise InputError(f"expected {{class_path: ..., init_args: ...}}, got {spec!r}", key="model.init_args.optimizer")
    module, _, name = str(spec["class_path"]).rpartition(".")
    return functools.partial(getattr(importlib.import_module(module), name), **(spec.get("init_args") or {}))


def spectral_latent_fit(config: str = SPECTRAL_NLB_CONFIG,
                        overrides: Mapping[str, Any] | None = None) -> SpectralLatentFitModule:
    """A fresh :class:`SpectralLatentFitModule` of ``config`` with ``overrides`` of its ``model.init_args``."""
    settings = {**model_settings(config, SpectralLatentFitModule), **(overrides or {})}
    unknown = sorted(set(overrides or {}) - set(settings) - {"optimizer", "lr_scheduler"})
    if unknown:
        raise InputError("unknown setting of the spectral NLB fit", key=f"model.{unknown[0]}")
    optimizer = _factory(settings.pop("optimizer", {"class_path": "torch.optim.Adam"}))
    settings.pop("lr_scheduler", None)  # steps no optimiser in a small fit
    return SpectralLatentFitModule(**settings, optimizer=optimizer)


def abc_settings(config: str = ABC_CONFIG) -> dict[str, Any]:
    """The keyword arguments of :func:`~neuralbrdf.fitting.abc_fit.fit_abc` that ``config`` sets
    (checked as :class:`AbcFitModule` checks them; the module's defaults for keys it leaves out)."""
    from neuralbrdf.lightning.abc_module import AbcFitModule  # not imported by plan next's spectral fit

    settings = model_settings(config, AbcFitModule)
    module = AbcFitModule(**settings)
    defaults = {name: p.default for name, p in inspect.signature(AbcFitModule).parameters.items()}
    return {**{key: value for key, value in {**defaults, **settings}.items() if key != "bounds"},
            "bounds": module.bounds}
