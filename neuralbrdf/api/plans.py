"""Plans and measuring a fraction of the pairs: :func:`write_plan`, :func:`design_plan`,
:func:`next_pairs` (and :func:`watch_next_pairs` of a file that grows), a simulated :func:`acquire` session."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from neuralbrdf.api.arguments import (PathLike, as_path, check_flags, check_integers, check_numbers, check_positive,
                                      check_text)
from neuralbrdf.api.materials import Source, read
from neuralbrdf.errors import InputError


def write_plan(plan: str | PathLike, out: PathLike) -> tuple:
    """Write the plan ``plan`` as a plan file ``out``, the pairs an operator measures: one of the
    report's DS1-DS4 or an in-plane plan file as signed in-plane ``theta_i, theta_r``, ``low`` (the
    Löw et al. set) as spherical ``theta_i, phi_i, theta_o, phi_o`` (degrees,
    docs/how-many-measurements.md).  Returns the columns written.

    >>> import tempfile, neuralbrdf as nb
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     theta_i, theta_r = nb.write_plan("DS4", f"{folder}/ds4.csv")
    >>> len(theta_i)
    6
    """
    from neuralbrdf.data import plans

    plan = plans.check_plan(plan, "plan")
    columns = plans.low_plan() if plan == "low" else plans.in_plane_plan(plan)
    plans.write_plan(columns, as_path(out, "out", "an output plan file (.csv) path"))
    return columns


def _instrument(max_theta: float, step: float, retro_band: float):
    from neuralbrdf.acquisition.instrument import Instrument

    return Instrument(max_theta, step, retro_band)


def _acquisition_config(config: PathLike, overrides: Mapping[str, Any] | None, section: str):
    """The ``section`` of an acquisition config (a shipped name or a YAML file) with ``overrides``."""
    import dataclasses

    from neuralbrdf.acquisition.settings import load_acquisition_config

    as_path(config, "config", "a shipped config's name or a YAML file")
    settings = getattr(load_acquisition_config(config), section)
    if overrides is None:
        return settings
    if not isinstance(overrides, Mapping):
        raise InputError(f"overrides: expected a mapping of {section} settings, got {type(overrides).__name__}")
    fields = {f.name for f in dataclasses.fields(settings)}
    for key in overrides:
        if key not in fields:
            raise InputError(f"unknown {section} setting; expected one of {', '.join(sorted(fields))}", key=str(key))
    return dataclasses.replace(settings, **overrides)


def design_plan(budget: int, out: PathLike | None = None, *, kind: str = "nlb_spectral", max_theta: float = 60.0,
                step: float = 1.0, retro_band: float = 0.0, config: PathLike = "default",
                overrides: Mapping[str, Any] | None = None, progress: bool = False):
    """``budget`` in-plane pairs for an instrument that reaches ``max_theta`` degrees in steps of
    ``step`` degrees and cannot measure within ``retro_band`` degrees of retro-reflection, chosen
    with the prior of ``kind`` (``nlb_spectral``, ``abc`` or ``pca``) to lower the expected hemisphere error of its fit most
    (docs/how-many-measurements.md); with ``out``, also written as a plan file (the format of
    ``neuralbrdf plan DS3``), pairs in the order to measure them.  ``overrides``: settings of the
    config's ``design`` section (``{"seed": 1}``).  Returns the
    :class:`~neuralbrdf.acquisition.design.PlanDesign`.

    >>> import neuralbrdf as nb
    >>> plan = nb.design_plan(3, step=10.0, overrides={"blends": 0, "analytic": 0})   # a coarse instrument: seconds
    >>> len(plan.theta_i), plan.predicted_error[0] > plan.predicted_error[-1]
    (3, True)
    >>> nb.design_plan(0)
    Traceback (most recent call last):
    neuralbrdf.errors.InputError: option '--budget': expected a number of pairs from 1 to 3721 (the distinct pairs this instrument can measure), got 0
    """
    from neuralbrdf.acquisition.design import design

    check_integers(budget=budget)
    check_text("kind", kind, optional=False)
    check_numbers(max_theta=max_theta, step=step, retro_band=retro_band)
    check_flags(progress=progress)
    settings = _acquisition_config(config, overrides, "design")
    instrument = _instrument(max_theta, step, retro_band)
    if out is not None:
        from neuralbrdf.atomic import check_outputs

        check_outputs(as_path(out, "out", "an output plan file (.csv) path"))
    plan = design(kind, budget, instrument, settings, progress=progress)
    if out is not None:
        from neuralbrdf.data.plans import write_plan

        write_plan((plan.theta_i, plan.theta_r), out)
    return plan


def next_pairs(measurement: Source | PathLike, count: int = 1, out: PathLike | None = None, *,
               reference: PathLike | None = None, max_theta: float = 60.0, step: float = 1.0, retro_band: float = 0.0,
               config: PathLike = "default"):
    """From a ``measurement`` (a :class:`Source` or what :func:`read` takes, with its GCMS
    ``reference``), the ``count`` pairs of the instrument to measure next and the current fit's
    error, estimated with an interval (docs/how-many-measurements.md); with ``out``, the pairs are
    also written as a plan file.  Returns :class:`~neuralbrdf.acquisition.next_pairs.NextPairs`
    (``.enough(target_delta_e)`` says whether a target is met).

    >>> import tempfile, neuralbrdf as nb
    >>> with tempfile.TemporaryDirectory() as folder:               # gold measured on DS4's 6 pairs
    ...     table = nb.simulate("gold", f"{folder}/gold.csv", plan="DS4", truth=True)
    ...     gold = nb.read(f"{folder}/gold.csv")
    >>> answer = nb.next_pairs(gold, count=2, step=5.0)
    >>> answer.measured, len(answer.theta_i), answer.logcos.low < answer.logcos.estimate < answer.logcos.high
    (6, 2, True)
    """
    if isinstance(measurement, Source) and reference is not None:
        raise InputError("reference goes with a GCMS raw file path, not with a Source (read it with its reference)")
    asker = _NextPairsAsker(count, out, max_theta, step, retro_band, config)
    return asker.answer(measurement if isinstance(measurement, Source) else read(measurement, reference))


class _NextPairsAsker:
    """:func:`next_pairs`'s settings checked once, and its answer for any measurement."""

    def __init__(self, count: int, out: PathLike | None, max_theta: float, step: float, retro_band: float,
                 config: PathLike, module=None) -> None:
        from neuralbrdf.acquisition.settings import load_acquisition_config

        check_integers(count=count)
        check_numbers(max_theta=max_theta, step=step, retro_band=retro_band)
        self.settings = load_acquisition_config(as_path(config, "config", "a shipped config's name or a YAML file"))
        if out is not None:
            from neuralbrdf.atomic import check_outputs

            check_outputs(as_path(out, "out", "an output plan file (.csv) path"))
        self.count, self.out, self.module = count, out, module
        self.instrument = _instrument(max_theta, step, retro_band)

    def answer(self, measurement: Source):
        from neuralbrdf.acquisition.next_pairs import next_pairs as answer

        result = answer(measurement.samples, self.count, self.instrument, self.settings.design, self.settings.estimate,
                        module=self.module, name=measurement.name)
        if self.out is not None:
            from neuralbrdf.data.plans import write_plan

            write_plan((result.theta_i, result.theta_r), self.out)
        return result


def watch_next_pairs(measurement: PathLike, count: int = 1, out: PathLike | None = None, *,
                     reference: PathLike | None = None, max_theta: float = 60.0, step: float = 1.0,
                     retro_band: float = 0.0, config: PathLike = "default", on_answer=None, on_error=None,
                     poll_s: float = 0.5, reads: int | None = None) -> int:
    """:func:`next_pairs` for the file ``measurement`` now and again each time it changes, in one
    process: the pretrained network and the fit's starts are loaded once, so each answer costs a
    warm call, not a new command's imports and loading (a user at the instrument appends the
    pairs just measured and has the next ones in seconds; docs/how-many-measurements.md).
    ``on_answer(answer)`` gets each :class:`~neuralbrdf.acquisition.next_pairs.NextPairs` (with
    ``out``, also written as a plan file); a read or fit that fails — a file caught half-written,
    say — goes to ``on_error(error)`` (an :class:`InputError`) and watching goes on.  The file is
    looked at every ``poll_s`` seconds; ``reads``: stop after this many answers and errors
    (``None``: until interrupted).  Returns the number of reads.

    >>> import tempfile, neuralbrdf as nb
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     table = nb.simulate("gold", f"{folder}/gold.csv", plan="DS4", truth=True)
    ...     nb.watch_next_pairs(f"{folder}/gold.csv", step=10.0, reads=1,
    ...                         on_answer=lambda answer: print(answer.measured, len(answer.theta_i)))
    6 1
    1
    """
    import time

    from neuralbrdf.acquisition.latent_fit import fit_module

    path = as_path(measurement, "measurement", "a measured table file (.csv)")
    if not os.path.isfile(path):
        raise InputError("no such file to watch", path=path)
    check_numbers(poll_s=poll_s)
    if not poll_s > 0:
        raise InputError(f"poll_s: expected a positive number of seconds, got {poll_s!r}")
    check_positive(reads=reads)
    asker = _NextPairsAsker(count, out, max_theta, step, retro_band, config, module=fit_module())
    seen, done = None, 0
    while reads is None or done < reads:
        try:
            stat = os.stat(path)
            state = (stat.st_mtime_ns, stat.st_size)
        except OSError:
            state = None                               # replaced by the instrument's software: look again
        if state is not None and state != seen:
            seen, done = state, done + 1
            try:
                result = asker.answer(read(path, reference))
            except InputError as error:
                if on_error is not None:
                    on_error(error)
            else:
                if on_answer is not None:
                    on_answer(result)
            continue
        time.sleep(poll_s)
    return done


def acquire(source: PathLike, out_dir: PathLike | None = None, *, start: PathLike | None = None,
            target_delta_e: float | None = None, max_pairs: int | None = None, count: int | None = None,
            noise: float | None = None, seed: int | None = None, render: bool = True, max_theta: float = 60.0,
            step: float = 1.0, retro_band: float = 0.0, config: PathLike = "default", overwrite: bool = False,
            progress=None):
    """A simulated session on a material with a truth (``virtual:NAME``, an NBRDF ``.h5``, a MERL
    ``.binary``, an RGL ``.bsdf``): measure ``start`` (a plan name or file; default the config's),
    fit, ask :func:`next_pairs` for ``count`` more, measure them with the virtual instrument's
    ``noise``, until the estimated preview ΔE2000 is within ``target_delta_e`` or ``max_pairs`` are
    measured (docs/how-many-measurements.md).  ``render``: the true ΔE2000 of every step (preview
    renders; without, the true hemisphere error only).  With ``out_dir``: writes ``acquire.json``,
    ``acquire.png`` (the curve of true and estimated error against the pairs), ``plan.csv``,
    ``measurement.csv`` and ``model.onnx``, refusing a folder that holds them unless ``overwrite``.
    ``progress(step)`` is called after each step.  Returns the
    :class:`~neuralbrdf.acquisition.session.SessionResult`.

    >>> import neuralbrdf as nb
    >>> session = nb.acquire("virtual:val-blue", start="DS4", max_pairs=7, render=False, step=10.0)
    >>> [step.pairs for step in session.steps], session.stopped
    ([6, 7], 'the budget of 7 pairs is spent')
    """
    from neuralbrdf.acquisition.session import check_session_outputs, run_session, write_session
    from neuralbrdf.acquisition.settings import load_acquisition_config
    from neuralbrdf.data.plans import check_plan

    settings = load_acquisition_config(as_path(config, "config", "a shipped config's name or a YAML file"))
    check_integers(max_pairs=max_pairs, count=count, seed=seed)
    check_numbers(target_delta_e=target_delta_e, noise=noise, max_theta=max_theta, step=step, retro_band=retro_band)
    check_flags(render=render, overwrite=overwrite)
    if progress is not None and not callable(progress):
        raise InputError(f"progress: expected a function called after each step, got {type(progress).__name__}")
    changes = {key: value for key, value in (("start", None if start is None else check_plan(start, "start",
                                                                                                in_plane=True)),
                                             ("max_pairs", max_pairs), ("count", count), ("noise", noise),
                                             ("seed", seed)) if value is not None}
    import dataclasses

    session = dataclasses.replace(settings.session, **changes)
    if out_dir is not None:
        check_session_outputs(as_path(out_dir, "out_dir", "a folder path"), overwrite)
    result = run_session(os.fspath(as_path(source, "source", "'virtual:NAME' or a file path")), session,
                         _instrument(max_theta, step, retro_band), settings.design, settings.estimate, target_delta_e,
                         render=render, progress=progress)
    if out_dir is not None:
        write_session(result, Path(out_dir))
    return result
