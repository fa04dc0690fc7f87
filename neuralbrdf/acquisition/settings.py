"""The settings of measuring a fraction of the pairs, from one YAML file: by default the shipped ``configs/acquisition/default.yaml`` (docs/how-many-measurements.md).

Sections: ``design`` (:class:`~neuralbrdf.acquisition.design.DesignSettings`, ``neuralbrdf plan
design``), ``estimate`` (:class:`~neuralbrdf.acquisition.next_pairs.EstimateSettings`, the error
estimate of ``neuralbrdf plan next``) and ``session`` (:class:`~neuralbrdf.acquisition.session.SessionSettings`,
``neuralbrdf acquire``).  Every key is required; an unknown key or a value of the wrong type is an
:class:`~neuralbrdf.errors.InputError` naming the file and the key (:mod:`neuralbrdf.settings_file`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from neuralbrdf.acquisition.design import DesignSettings
from neuralbrdf.acquisition.next_pairs import EstimateSettings
from neuralbrdf.acquisition.session import SessionSettings
from neuralbrdf.settings_file import load_sections

CONFIG_FOLDER = "acquisition"
DEFAULT_CONFIG = "default"
SECTIONS = {"design": DesignSettings, "estimate": EstimateSettings, "session": SessionSettings}


@dataclass(frozen=True)
class AcquisitionConfig:
    path: Path
    design: DesignSettings
    estimate: EstimateSettings
    session: SessionSettings


def load_acquisition_config(name: str | os.PathLike[str] = DEFAULT_CONFIG) -> AcquisitionConfig:
    """The checked settings of ``name`` (a YAML file or a shipped config's name; module docstring)."""
    path, sections = load_sections(name, CONFIG_FOLDER, SECTIONS, "acquisition config")
    return AcquisitionConfig(path, **sections)
