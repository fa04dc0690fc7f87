"""Kind ``nlb``: a latent fit of the NLB representation network (Fan et al. 2022; docs/models.md#nlb).

Checkpoints come from :class:`~neuralbrdf.lightning.latent_fit_module.LatentFitModule`: the
frozen network, one latent per fitted material and the materials' names (:func:`load_fitted`).
One ``.onnx`` file is exported per material, its latent baked into the graph
(:class:`~neuralbrdf.models.directional.NlbWithLatent`; RGB).  Sampling: a GGX mixture fitted
to the model.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from neuralbrdf.errors import InputError
from neuralbrdf.kinds import Exportable, Kind, contract_metadata, module_class_name, pick_material, provenance

if TYPE_CHECKING:
    import torch

    from neuralbrdf.models.nlb import NlbNetwork

#: Entries a latent-fit checkpoint has beside Lightning's own.
_FIT_KEYS = ("nlb_config", "material_names", "state_dict")
_PREFIX = "network."


@dataclass(frozen=True)
class FittedNlb:
    """Fitted materials: the frozen ``network`` and one latent ``[latent_dim]`` per material name."""

    network: NlbNetwork
    latents: dict[str, torch.Tensor]
    source: str


def _fitted(checkpoint: dict, path: Path) -> FittedNlb:
    from neuralbrdf.checkpoints import check_weights_match
    from neuralbrdf.models.nlb import NlbNetwork

    missing = [key for key in _FIT_KEYS if key not in checkpoint]
    if missing:  # e.g. a pretraining checkpoint: it names its materials but has no nlb_config
        raise InputError(f"not a latent-fit checkpoint (LatentFitModule): missing {missing[0]!r}", path=path)
    try:
        names, state = checkpoint["material_names"], checkpoint["state_dict"]
        check_weights_match(lambda: NlbNetwork(**checkpoint["nlb_config"]), state, path, _PREFIX)
        network = NlbNetwork(**checkpoint["nlb_config"])
        latents = state["latents.latents"].float()
    except (KeyError, TypeError) as exc:
        raise InputError(f"not a latent-fit checkpoint (LatentFitModule): missing {exc}", path=path) from None
    network.load_state_dict({k[len(_PREFIX):]: v for k, v in state.items() if k.startswith(_PREFIX)})
    network.requires_grad_(False).eval()
    return FittedNlb(network, dict(zip(names, latents)), str(path))


def load_fitted(path: str | os.PathLike[str]) -> FittedNlb:
    """The network and named latents of a latent-fit checkpoint, else :class:`InputError`."""
    from neuralbrdf.checkpoints import read_checkpoint

    path = Path(path)
    return _fitted(read_checkpoint(path, "fitted NLB checkpoint"), path)


def from_checkpoint(checkpoint: dict, path: Path, material: str | None) -> Exportable:
    from neuralbrdf.models.directional import NlbWithLatent

    fitted = _fitted(checkpoint, path)
    name = pick_material(list(fitted.latents), material, path)
    module = NlbWithLatent(fitted.network, fitted.latents[name])
    metadata = contract_metadata(KIND.name, name, provenance(checkpoint, path))
    return Exportable(module, KIND.name, name, metadata, None)


def _recognises(checkpoint: dict) -> bool:
    return module_class_name(checkpoint) == "LatentFitModule" or ("material_names" in checkpoint and "nlb_config" in checkpoint)


KIND = Kind(
    name="nlb",
    summary="a latent fit of the NLB representation network, one file per material (docs/models.md#nlb)",
    from_checkpoint=from_checkpoint,
    recognises=_recognises,
)
