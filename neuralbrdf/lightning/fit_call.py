"""A fit handed its configuration as data, its result handed back as an object: ``nb.fit``'s run.

``neuralbrdf train fit --config X --key value`` parses a command line; :func:`fit_run` takes the
same run as data: the config files (shipped names or YAML files, an overlay's base put before it
as on the command line) and a mapping of overrides (``{"trainer.max_epochs": 5, "data.sources":
[{"virtual": "gold"}]}``; dotted keys or nested mappings), which jsonargparse validates as the
typed values they are (no trip through text).  The run is :class:`~neuralbrdf.lightning.train_cli.NeuralBrdfCLI`'s:
the same run directory, files, locks, checks and failures as ``neuralbrdf train fit``
(:mod:`neuralbrdf.lightning.run`), and the same exceptions as its
:func:`~neuralbrdf.lightning.run.train`.  A message about an override names it as the flag that
would set it (``--model.n_start: AbcFitModule has no option 'n_start'``), a key from a config file
by its file.

It returns a :class:`FitRun`: the run directory, the status and metrics the run wrote to its
``metrics.json`` (kept as they were written, not read back) and the checkpoint to export.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from jsonargparse import ActionConfigFile, ArgumentError, Namespace

from neuralbrdf.atomic import command_inputs
from neuralbrdf.configs_dir import config_not_found, overlay_base, resolve_config
from neuralbrdf.errors import FitFailed, InputError
from neuralbrdf.lightning.config_errors import describe as describe_config_error
from neuralbrdf.lightning.failures import run_failure
from neuralbrdf.lightning.metrics_json import MetricsJson, strict_json
from neuralbrdf.lightning.run import _quiet, fitted_checkpoint
from neuralbrdf.lightning.train_cli import NeuralBrdfCLI

SUBCOMMAND = "fit"


@dataclass(frozen=True)
class FitRun:
    """A finished fit: where it ran, what it wrote to ``metrics.json`` (``status`` among them: ``ok``;
    a failed fit raises instead) and the checkpoint it leaves to export (``None`` if it saved none
    named best or fitted)."""

    run_dir: Path
    checkpoint: Path | None
    metrics: dict[str, Any] = field(repr=False)


def config_files(names: list[str]) -> list[Path]:
    """The config files of ``names`` (shipped names or YAML files,
    :func:`~neuralbrdf.configs_dir.resolve_config`), each overlay's base put before it when not
    given; every one a readable UTF-8 text file, else :class:`InputError` naming it."""
    files: list[Path] = []
    for name in names:
        path = resolve_config(name)
        base = overlay_base(path) if path.is_file() else None
        if base is not None and base.resolve() not in {f.resolve() for f in files}:
            files.append(base)
        files.append(path)
    for path in files:
        try:
            path.read_bytes().decode("utf-8")
        except FileNotFoundError:
            raise config_not_found(path) from None
        except UnicodeDecodeError as error:
            raise InputError(f"not a YAML configuration: not UTF-8 text ({error.reason} at byte {error.start})",
                             path=path) from None
        except OSError as error:
            raise InputError(f"cannot read the configuration ({error.strerror or error})", path=path) from None
    return files


def _as_given(files: list[Path], overrides: Mapping[str, Any]) -> list[str]:
    """Where each key was given, in the form the messages read it
    (:func:`~neuralbrdf.lightning.config_errors.where`): the config files, then each override as
    the flag that sets it, with its value as a message quotes it."""
    given = [SUBCOMMAND]
    for path in files:
        given += ["--config", str(path)]
    for key, value in overrides.items():
        given += [f"--{key}", str(value)]
    return given


class _DataFitCLI(NeuralBrdfCLI):
    """:class:`NeuralBrdfCLI` parsing a fit from config files and a mapping of overrides."""

    def __init__(self, files: list[Path], overrides: Mapping[str, Any], given: list[str]) -> None:
        self._files = files
        self._given = given
        self.written: dict[str, Any] = {}
        super().__init__(args=dict(overrides))

    def parse_arguments(self, parser, args) -> None:
        # jsonargparse reads a config file given in a mapping at the top level, not the subcommand's:
        # the files are applied to the fit's parser as ``--config FILE`` is, then the overrides over them
        self._args = self._given  # how messages name the keys (NeuralBrdfCLI's checks)
        fit_parser = self._subcommand_parsers[SUBCOMMAND]
        config = Namespace()
        for path in self._files:
            ActionConfigFile.apply_config(fit_parser, config, "config", str(path))
        self.config = Namespace(subcommand=SUBCOMMAND, **{SUBCOMMAND: fit_parser.parse_object(args, namespace=config)})

    def instantiate_trainer(self, **kwargs):
        trainer = super().instantiate_trainer(**kwargs)
        for callback in trainer.callbacks:
            if isinstance(callback, MetricsJson):
                callback._write = self._recorded(callback._write)
        return trainer

    def _recorded(self, write):
        """``MetricsJson``'s writer, also keeping what it writes (the run's result, without reading it back)."""

        def recorded(trainer, metrics: dict, merge: bool) -> None:
            write(trainer, metrics, merge)
            self.written = {**(self.written if merge else {}), **strict_json(metrics)}

        return recorded


def fit_run(configs: list[str], overrides: Mapping[str, Any], verbose: bool = False) -> FitRun:
    """Fit with the config files ``configs`` and ``overrides`` (module docstring; the run's own keys
    too: ``run_dir``, ``overwrite``, ``num_threads``) in this process.  Raises what
    :func:`~neuralbrdf.lightning.run.train` raises: :class:`InputError` for bad input (a key that
    does not parse in one line naming it), :class:`FitFailed` for a fit that ran and failed,
    :class:`~neuralbrdf.errors.EnvironmentFailure` for a file the machine could not write and
    :class:`Interrupted` for Ctrl-C or SIGTERM."""
    files: list[Path] = []
    try:
        with _quiet(verbose):
            files = config_files(configs)
            with command_inputs():
                cli = _DataFitCLI(files, overrides, _as_given(files, overrides))
    except FitFailed:
        raise
    except ArgumentError as exc:  # the configuration does not parse: one line naming the key
        parser = getattr(exc, "neuralbrdf_parsers", {}).get(SUBCOMMAND)
        raise describe_config_error(str(exc), _as_given(files, overrides), files, parser) from None
    except BaseException as exc:
        failure = run_failure(exc)
        if failure is None:
            raise
        raise failure from (exc if isinstance(failure, FitFailed) else None)
    return FitRun(cli.run_dir, fitted_checkpoint(cli.run_dir), cli.written)
