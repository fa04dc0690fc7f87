"""Kind ``spectral_mlp``: the report's in-plane spectral MLP (§5.1), queried on directions.

Checkpoints come from :class:`~neuralbrdf.lightning.spectral_mlp_module.SpectralMlpModule`
(``train.py fit --config configs/spectral_mlp.yaml``); the network is rebuilt from the
checkpoint's hyper-parameters as a plain :class:`~neuralbrdf.models.spectral_mlp.SpectralMLP`
and exported as :class:`~neuralbrdf.models.directional.SpectralMlpOnDirections` (inputs ``wi, wo,
wavelength``, output ``f [N]``; the in-plane mapping of docs/models.md#spectral-mlp inside the graph).  Sampling:
a GGX mixture fitted to the model.
"""

from __future__ import annotations

import inspect
from pathlib import Path

from neuralbrdf.errors import InputError
from neuralbrdf.kinds import Exportable, Kind, contract_metadata, module_class_name, pick_material, provenance

#: Prefix of the network's tensors in the Lightning module's state dict.
_PREFIX = "network."


def _material(checkpoint: dict) -> str:
    data = checkpoint.get("datamodule_hyper_parameters") or {}
    if data.get("path"):
        return Path(str(data["path"])).stem
    # ``virtual_material``: the key's name in checkpoints written before the sources vocabulary
    return str(data.get("virtual") or data.get("virtual_material") or "spectral_mlp")


def from_checkpoint(checkpoint: dict, path: Path, material: str | None) -> Exportable:
    from neuralbrdf.checkpoints import check_weights_match
    from neuralbrdf.models.directional import SpectralMlpOnDirections
    from neuralbrdf.models.spectral_mlp import SpectralMLP

    for key in ("state_dict", "hyper_parameters"):
        if key not in checkpoint:
            raise InputError("spectral MLP checkpoint lacks this key", path=path, key=key)
    accepted = inspect.signature(SpectralMLP).parameters
    hparams = {k: v for k, v in dict(checkpoint["hyper_parameters"]).items() if k in accepted}
    state = checkpoint["state_dict"]
    check_weights_match(lambda: SpectralMLP(**hparams), state, path, _PREFIX)
    network = SpectralMLP(**hparams)
    network.load_state_dict({k[len(_PREFIX):]: v for k, v in state.items() if k.startswith(_PREFIX)})
    name = pick_material([_material(checkpoint)], material, path)
    directional = SpectralMlpOnDirections(network)
    wavelength_range = directional.wavelength_range_nm
    metadata = contract_metadata(KIND.name, name, provenance(checkpoint, path), wavelength_range_nm=wavelength_range)
    return Exportable(directional, KIND.name, name, metadata, wavelength_range)


def _recognises(checkpoint: dict) -> bool:
    return module_class_name(checkpoint) == "SpectralMlpModule"


KIND = Kind(
    name="spectral_mlp",
    summary="the report's 3x10 spectral MLP on in-plane angles and wavelength (docs/models.md#spectral-mlp)",
    spectral_only=True,
    from_checkpoint=from_checkpoint,
    recognises=_recognises,
)
