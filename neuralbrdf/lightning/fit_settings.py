"""Settings that would make a fit endless or meaningless, refused in one line before the run.

Lightning and PyTorch accept them and a run follows: ``trainer.max_epochs: -1`` is Lightning's
"no limit" (with neither ``trainer.max_steps`` nor ``trainer.max_time`` set, the fit never
ends) and ``null`` its default of 1000 epochs, which no config means; ``0`` epochs, steps or
training batches train nothing and save the untrained model as ``best``, a learning rate of 0 leaves the model as it started and one that is negative, infinite
or NaN ruins it, a validation that never runs never chooses the monitored checkpoint, a
learning-rate decay factor of 0 stops the optimiser after one step.  :func:`check_fit_settings`
looks at the parsed configuration of ``neuralbrdf train fit`` (and so of ``nb.fit(overrides=…)``)
and raises :class:`~neuralbrdf.errors.InputError` naming the key, where it was given (the flag or
the YAML file) and what is expected.  Settings a model or data module checks itself when it is
built (batch sizes, steps per epoch, loss weights) are refused there, also before the run.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from neuralbrdf.errors import InputError
from neuralbrdf.lightning.config_errors import given_at

#: Optimiser arguments and the values they must have (``lr`` in every torch optimiser).
OPTIMIZER_RULES = {"lr": "positive", "weight_decay": "non-negative", "momentum": "non-negative", "eps": "positive"}
#: Learning-rate scheduler arguments and the values they must have.
SCHEDULER_RULES = {"gamma": "positive", "step_size": "positive"}
_RULE_TEXT = {"positive": "a finite number > 0", "non-negative": "a finite number >= 0"}


def _get(namespace, *keys):
    """``namespace.k1.k2...`` (jsonargparse Namespace or dict), ``None`` where missing."""
    for key in keys:
        if namespace is None:
            return None
        namespace = namespace.get(key) if hasattr(namespace, "get") else getattr(namespace, key, None)
    return namespace


def _number(value) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value)


def _breaks_rule(value, rule: str) -> bool:
    number = _number(value)
    if number is None:
        return value is not None
    return not math.isfinite(number) or number < 0 or (rule == "positive" and number == 0)


def _monitored_checkpoints(trainer) -> list[str]:
    callbacks = _get(trainer, "callbacks") or []
    callbacks = callbacks if isinstance(callbacks, list) else [callbacks]
    return [str(_get(c, "init_args", "monitor")) for c in callbacks
            if str(_get(c, "class_path") or "").endswith("ModelCheckpoint") and _get(c, "init_args", "monitor")]


def _trainer_problems(trainer) -> list[tuple[str, object, str]]:
    problems = []
    epochs, steps, time_limit = (_get(trainer, k) for k in ("max_epochs", "max_steps", "max_time"))
    if epochs == 0:
        problems.append(("trainer.max_epochs", epochs, "trains no epoch (the untrained model would be saved as the "
                                                       "fit's result); give 1 or more"))
    elif epochs == -1 and steps in (None, -1) and time_limit is None:
        problems.append(("trainer.max_epochs", epochs, "-1 is Lightning's 'no limit', and neither trainer.max_steps "
                                                       "nor trainer.max_time is set: the fit would never end; give a "
                                                       "number of epochs >= 1"))
    elif epochs is None and steps in (None, -1) and time_limit is None:
        problems.append(("trainer.max_epochs", epochs, "null leaves the limit to Lightning's default of 1000 epochs, "
                                                       "and neither trainer.max_steps nor trainer.max_time is set; give "
                                                       "a number of epochs >= 1"))
    elif isinstance(epochs, int) and epochs < -1:
        problems.append(("trainer.max_epochs", epochs, "expected a number of epochs >= 1"))
    if steps == 0 or (isinstance(steps, int) and steps < -1):
        problems.append(("trainer.max_steps", steps, "trains no step; give -1 (no step limit) or a number of steps "
                                                     ">= 1"))
    # shown as numbers (0.0): jsonargparse parses "0" for these int | float options as an int or a float
    # depending on what else is installed (rich)
    batches = _number(_get(trainer, "limit_train_batches"))
    if batches is not None and not batches > 0:
        problems.append(("trainer.limit_train_batches", batches,
                         "no training step in an epoch: the fit would learn nothing; give a number of batches >= 1 "
                         "or a fraction in (0, 1]"))
    val_batches = _number(_get(trainer, "limit_val_batches"))
    monitored = _monitored_checkpoints(trainer)
    if val_batches is not None and not val_batches > 0 and monitored:
        problems.append(("trainer.limit_val_batches", val_batches,
                         f"no validation, so the checkpoint chosen on {monitored[0]} would never be chosen; give a "
                         "number of batches >= 1 or a fraction in (0, 1]"))
    for key in ("accumulate_grad_batches", "check_val_every_n_epoch"):
        value = _get(trainer, key)
        if isinstance(value, int) and not isinstance(value, bool) and value < 1:
            problems.append((f"trainer.{key}", value, "expected an integer >= 1"))
    return problems


def _argument_problems(part, prefix: str, rules: dict[str, str]) -> list[tuple[str, object, str]]:
    init_args = _get(part, "init_args")
    problems = []
    for name, rule in rules.items():
        value = _get(init_args, name)
        if value is not None and _breaks_rule(value, rule):
            what = {"lr": " (the learning rate)", "gamma": " (the learning rate's decay factor)"}.get(name, "")
            problems.append((f"{prefix}.{name}", value, f"expected {_RULE_TEXT[rule]}{what}"))
    return problems


def fit_setting_problems(config) -> list[tuple[str, object, str]]:
    """``(key, value, what is wrong)`` for every setting of a ``fit`` configuration (the
    subcommand's jsonargparse Namespace) that makes the fit endless or meaningless (module docstring)."""
    model_args = _get(config, "model", "init_args")
    return [*_trainer_problems(_get(config, "trainer")),
            *_argument_problems(_get(model_args, "optimizer"), "model.optimizer", OPTIMIZER_RULES),
            *_argument_problems(_get(model_args, "lr_scheduler"), "model.lr_scheduler", SCHEDULER_RULES)]


def check_fit_settings(config, args: Sequence[str], configs: Sequence[str | Path]) -> None:
    """Raise :class:`InputError` for the first of :func:`fit_setting_problems`, naming the key where
    it was given (``--key`` or ``FILE: key``, :func:`~neuralbrdf.lightning.config_errors.given_at`)."""
    for key, value, problem in fit_setting_problems(config):
        config_file, shown = given_at(key, args, configs)
        raise InputError(f"{shown} {value!r}: {problem}" if isinstance(value, str) else f"{shown} {value}: {problem}",
                         path=config_file)
