"""``neuralbrdf train fit --data.path TABLE`` refuses a bad table before Lightning is imported.

Importing Lightning takes most of the ten seconds a refused fit used to take; other commands refuse
the same table in a second or two.  For a fit of the shipped configs, :func:`refused_table` reads
the table as every fit's data module reads it (:func:`~neuralbrdf.sources.load_fit_measurement`)
first.  A config file of the user's own may set more of the data than the flags say: its fit checks
the table itself, as before.
"""

from __future__ import annotations

import sys

from neuralbrdf.atomic import command_inputs
from neuralbrdf.errors import EXIT_BAD_INPUT, InputError, error_line


def option_values(argv: list[str], option: str) -> list[str]:
    """The values given to ``option`` in ``argv`` (``--key value`` or ``--key=value``), in order."""
    return [argv[i + 1] if arg == option else arg.split("=", 1)[1] for i, arg in enumerate(argv)
            if (arg == option and i + 1 < len(argv)) or arg.startswith(option + "=")]


def refused_table(argv: list[str]) -> int | None:
    """The exit status of ``train`` with ``argv`` when its ``--data.path`` table is refused (the
    error line printed), else ``None`` (module docstring)."""
    from neuralbrdf.configs_dir import CONFIGS_DIR, resolve_config

    paths = option_values(argv, "--data.path")
    configs = option_values(argv, "--config")
    if argv[:1] != ["fit"] or not paths or not configs or not all(
            resolve_config(c).resolve().is_relative_to(CONFIGS_DIR.resolve()) for c in configs):
        return None
    from neuralbrdf.data.units import overridden_by
    from neuralbrdf.lightning.common import TRUST_UNITS_OPTION
    from neuralbrdf.sources import load_fit_measurement

    reference = (option_values(argv, "--data.reference") or [None])[-1]
    trust_units = (option_values(argv, "--data.trust_units") or ["false"])[-1].lower() in ("true", "yes", "on", "1")
    try:
        with command_inputs(), overridden_by(TRUST_UNITS_OPTION):
            load_fit_measurement(paths[-1], None if reference in (None, "null") else reference, trust_units)
    except InputError as error:
        print(error_line("neuralbrdf train", error), file=sys.stderr)
        return EXIT_BAD_INPUT
    return None
