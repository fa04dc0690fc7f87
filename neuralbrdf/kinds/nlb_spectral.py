"""Kind ``nlb_spectral``: a latent fit of the spectral NLB network (docs/models.md#spectral-nlb).

Checkpoints come from :class:`~neuralbrdf.lightning.nlb_spectral_fit.SpectralLatentFitModule`:
the frozen channel-agnostic network (:mod:`neuralbrdf.models.nlb_spectral`), per material a
shared code and channel codes, the materials' names and the channel codes' wavelength nodes.
One ``.onnx`` file is exported per material, its codes baked into the graph
(:class:`~neuralbrdf.models.directional.SpectralNlbWithCodes`): a spectral model with a
``wavelength`` input when the fit was spectral, else an RGB one.  Sampling: a GGX mixture fitted
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

    from neuralbrdf.models.nlb_spectral import SpectralNlbNetwork

_FIT_KEYS = ("spectral_nlb_config", "material_names", "state_dict", "node_wavelengths_nm")
_PREFIX = "network."


@dataclass(frozen=True)
class FittedSpectralNlb:
    """Fitted materials: the frozen ``network``, per name a shared code ``[shared_dim]`` and channel
    codes ``[K, channel_dim]``, and the codes' ``node_wavelengths_nm`` (``None``: R, G, B)."""

    network: SpectralNlbNetwork
    shared: dict[str, torch.Tensor]
    channels: dict[str, torch.Tensor]
    node_wavelengths_nm: tuple[float, ...] | None
    source: str

    def model(self, name: str):
        """The material ``name`` as a function of directions (the exported graph's module)."""
        from neuralbrdf.models.directional import SpectralNlbWithCodes

        return SpectralNlbWithCodes(self.network, self.shared[name], self.channels[name], self.node_wavelengths_nm)


def _fitted(checkpoint: dict, path: Path) -> FittedSpectralNlb:
    from neuralbrdf.checkpoints import check_weights_match
    from neuralbrdf.models.nlb_spectral import SpectralNlbNetwork

    missing = [key for key in _FIT_KEYS if key not in checkpoint]
    if missing:
        raise InputError(f"not a spectral NLB fit checkpoint (SpectralLatentFitModule): missing {missing[0]!r}",
                         path=path)
    try:
        names, state, config = checkpoint["material_names"], checkpoint["state_dict"], checkpoint["spectral_nlb_config"]
        check_weights_match(lambda: SpectralNlbNetwork(**config), state, path, _PREFIX)
        network = SpectralNlbNetwork(**config)
        shared, channels = state["latents.shared"].float(), state["latents.channels"].float()
        nodes = checkpoint["node_wavelengths_nm"]
        nodes = None if nodes is None else tuple(float(w) for w in nodes)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"not a spectral NLB fit checkpoint: {exc}", path=path) from None
    expected_channels = 3 if nodes is None else len(nodes)
    if len(names) != len(shared) or channels.ndim != 3 or channels.shape[:2] != (len(names), expected_channels):
        raise InputError(f"codes of shapes {list(shared.shape)} and {list(channels.shape)} do not fit "
                         f"{len(names)} materials with {expected_channels} channel codes", path=path)
    network.load_state_dict({k[len(_PREFIX):]: v for k, v in state.items() if k.startswith(_PREFIX)})
    network.requires_grad_(False).eval()
    return FittedSpectralNlb(network, dict(zip(names, shared)), dict(zip(names, channels)), nodes, str(path))


def load_fitted_spectral(path: str | os.PathLike[str]) -> FittedSpectralNlb:
    """The network and named codes of a spectral NLB fit checkpoint, else :class:`InputError`."""
    from neuralbrdf.checkpoints import read_checkpoint

    path = Path(path)
    return _fitted(read_checkpoint(path, "fitted spectral NLB checkpoint"), path)


def from_checkpoint(checkpoint: dict, path: Path, material: str | None) -> Exportable:
    fitted = _fitted(checkpoint, path)
    name = pick_material(list(fitted.shared), material, path)
    module = fitted.model(name)
    wavelength_range = module.wavelength_range_nm if module.is_spectral else None
    metadata = contract_metadata(KIND.name, name, provenance(checkpoint, path), wavelength_range_nm=wavelength_range)
    return Exportable(module, KIND.name, name, metadata, wavelength_range)


def _recognises(checkpoint: dict) -> bool:
    return module_class_name(checkpoint) == "SpectralLatentFitModule" or "spectral_nlb_config" in checkpoint


KIND = Kind(
    name="nlb_spectral",
    summary="a latent fit of the spectral NLB network, spectral for spectral measurements and RGB for "
            "RGB ones, one file per material (docs/models.md#spectral-nlb)",
    from_checkpoint=from_checkpoint,
    recognises=_recognises,
)
