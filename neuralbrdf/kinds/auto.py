"""Kind ``auto``: the candidate an ``auto`` fit chose, ABC or the spectral NLB (docs/models.md#auto).

Checkpoints come from :class:`~neuralbrdf.lightning.auto_fit.AutoFitModule`; the exported graph is
the chosen candidate's, exactly as its own kind exports it (:mod:`neuralbrdf.kinds.abc`,
:mod:`neuralbrdf.kinds.nlb_spectral`: an ABC graph, or the spectral NLB without its silent units),
under kind ``auto`` with the choice and what it was made on in the file's metadata:

=========================================  ========================================================
key                                        value
=========================================  ========================================================
``neuralbrdf.auto.choice``                 ``abc`` or ``nlb_spectral``
``neuralbrdf.auto.inplane_logcos_rmse``    JSON object: each candidate's log-cosine RMSE on the
                                           measured samples (``null``: it did not fit)
``neuralbrdf.auto.abc.<key>``              the chosen ABC's parameters (``kd``, ``A``, ``B``, ``C``,
                                           ``eta``; as ``neuralbrdf.abc.<key>``)
``neuralbrdf.auto.nlb_spectral.<key>``     the chosen spectral NLB's entries (``hidden_units``)
=========================================  ========================================================

Sampling: the chosen kind's proposal (proposal ``chosen``: the analytic ABC lobe, or a GGX mixture
fitted to the model).  ``neuralbrdf export`` adds the fast path ``f_fast`` by default when the
spectral NLB was chosen, as for that kind (an ABC graph already renders at analytic cost).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from neuralbrdf import kinds as registry
from neuralbrdf.errors import InputError
from neuralbrdf.kinds import Exportable, Kind, contract_metadata, pick_material, provenance
from neuralbrdf.kinds import abc as abc_kind
from neuralbrdf.kinds import nlb_spectral as nlb_kind
from neuralbrdf.onnx_contract import kind_key

NAME = "auto"
CHOICE_KEY = kind_key(NAME, "choice")
ERRORS_KEY = kind_key(NAME, "inplane_logcos_rmse")
#: The candidates a file may hold, by kind name.
CANDIDATES = (abc_kind.NAME, nlb_kind.KIND.name)


@dataclass(frozen=True)
class AutoMetadata:
    """What an ``auto`` file says of its choice: the ``choice``, each candidate's in-plane error,
    the chosen kind's sampling ``proposal`` and its own details (:attr:`Kind.read_metadata`)."""

    choice: str
    inplane_logcos_rmse: dict[str, float | None]
    proposal: str
    chosen_details: object


def _nested(choice: str) -> str:
    """The prefix of the chosen kind's entries inside an ``auto`` file."""
    return kind_key(NAME, f"{choice}.")


def _entries(choice: str, chosen_metadata: Mapping[str, str]) -> dict[str, str]:
    """The chosen kind's own entries (``neuralbrdf.<choice>.*``) moved under ``neuralbrdf.auto.<choice>.*``."""
    own = kind_key(choice, "")
    return {_nested(choice) + key[len(own):]: value for key, value in chosen_metadata.items() if key.startswith(own)}


def read_metadata(metadata: Mapping[str, str], path, is_spectral: bool) -> AutoMetadata:
    """The choice and the chosen kind's details, else :class:`InputError` naming the key."""
    if CHOICE_KEY not in metadata:
        raise InputError("an auto model must say which candidate it holds", path=path, key=CHOICE_KEY)
    choice = metadata[CHOICE_KEY]
    if choice not in CANDIDATES:
        raise InputError(f"unknown choice {choice!r}; expected one of {list(CANDIDATES)}", path=path, key=CHOICE_KEY)
    try:
        errors = json.loads(metadata.get(ERRORS_KEY, "{}"))
    except json.JSONDecodeError:
        errors = None
    if not isinstance(errors, dict) or any(not isinstance(v, (int, float, type(None))) or isinstance(v, bool)
                                           for v in errors.values()):
        raise InputError("expected a JSON object of numbers or null per candidate", path=path, key=ERRORS_KEY)
    prefix = _nested(choice)
    chosen = {kind_key(choice, key[len(prefix):]): value for key, value in metadata.items() if key.startswith(prefix)}
    try:
        details = registry.get(choice).read_metadata(chosen, path, is_spectral)
    except InputError as error:  # name the key as this file spells it
        key = error.key if error.key is None else prefix + error.key[len(kind_key(choice, "")):]
        raise InputError(error.reason, path=path, key=key) from None
    return AutoMetadata(choice, {str(k): v for k, v in errors.items()}, registry.get(choice).proposal, details)


def wants_fast(metadata: Mapping[str, str]) -> bool:
    """Whether ``neuralbrdf export`` adds ``f_fast`` by default: as the chosen kind would."""
    choice = metadata.get(CHOICE_KEY)
    return choice in CANDIDATES and registry.get(choice).fast_default(metadata)


def from_checkpoint(checkpoint: dict, path: Path, material: str | None) -> Exportable:
    for key in ("auto_choice", "material", "auto_inplane_logcos_rmse"):
        if key not in checkpoint:
            raise InputError("auto checkpoint lacks this key", path=path, key=key)
    choice, name = checkpoint["auto_choice"], str(checkpoint["material"])
    name = pick_material([name], material, path)
    text = provenance(checkpoint, path)
    if choice == abc_kind.NAME:
        from neuralbrdf.physics.abc import AbcParameters

        if "abc_parameters" not in checkpoint:
            raise InputError("an auto checkpoint that chose ABC lacks its parameters", path=path, key="abc_parameters")
        chosen = abc_kind.exportable(AbcParameters.from_dict(checkpoint["abc_parameters"], source=str(path)), name, text)
    elif choice == nlb_kind.KIND.name:
        fit = checkpoint.get("nlb_spectral_fit")
        if not isinstance(fit, dict):
            raise InputError("an auto checkpoint that chose the spectral NLB lacks its fit", path=path,
                             key="nlb_spectral_fit")
        fitted = nlb_kind.fitted_from(fit, path)
        chosen = nlb_kind.exportable(fitted.model(pick_material(list(fitted.shared), name, path)), name, text)
    else:
        raise InputError(f"unknown choice {choice!r}; expected one of {list(CANDIDATES)}", path=path, key="auto_choice")
    errors = {str(k): (None if v is None else float(v)) for k, v in checkpoint["auto_inplane_logcos_rmse"].items()}
    own = {CHOICE_KEY: choice, ERRORS_KEY: json.dumps(errors, sort_keys=True), **_entries(choice, chosen.metadata)}
    metadata = contract_metadata(NAME, name, text, wavelength_range_nm=chosen.wavelength_range_nm, kind_metadata=own)
    return Exportable(chosen.module, NAME, name, metadata, chosen.wavelength_range_nm)


KIND = Kind(
    name=NAME,
    summary="the better of an ABC fit and a spectral NLB fit of one measurement on its measured pairs, as that "
            "kind's graph (docs/models.md#auto)",
    read_metadata=read_metadata,
    proposal="chosen",
    from_checkpoint=from_checkpoint,
    recognises=lambda checkpoint: "auto_choice" in checkpoint,
    scalar_parameters=0,
    wants_fast=wants_fast,
)
