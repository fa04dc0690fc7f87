"""Kind ``nlb_spectral``: a latent fit of the spectral NLB network (docs/models.md#spectral-nlb).

Checkpoints come from :class:`~neuralbrdf.lightning.nlb_spectral_fit.SpectralLatentFitModule`:
the frozen channel-agnostic network (:mod:`neuralbrdf.models.nlb_spectral`), per material a
shared code and channel codes, the materials' names and the channel codes' wavelength nodes.
One ``.onnx`` file is exported per material, its codes baked into the graph
(:class:`~neuralbrdf.models.directional.SpectralNlbWithCodes`): a spectral model with a
``wavelength`` input when the fit was spectral, else an RGB one, without the hidden units the
material never uses (:func:`export_module`; the file's ``neuralbrdf.nlb_spectral.hidden_units``
says how many are left).  ``neuralbrdf export`` adds its fast path ``f_fast`` by default
(:attr:`~neuralbrdf.kinds.Kind.fast_by_default`).  Sampling: a GGX mixture fitted to the model.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from neuralbrdf.errors import InputError
from neuralbrdf.kinds import Exportable, Kind, contract_metadata, module_class_name, pick_material, provenance
from neuralbrdf.onnx_contract import kind_key

if TYPE_CHECKING:
    import torch

    from neuralbrdf.models.directional import SpectralNlbWithCodes
    from neuralbrdf.models.nlb_spectral import SpectralNlbNetwork

_FIT_KEYS = ("spectral_nlb_config", "material_names", "state_dict", "node_wavelengths_nm")
_PREFIX = "network."
#: Uniformly random direction pairs (besides the contract's dense probe) on which a hidden unit
#: must never fire to be left out of the exported graph, and as many others on which the graph
#: without them is checked against the whole network.
UNIT_SEARCH_PAIRS = 2**18
#: Largest relative change of ``f`` that leaving the silent units out may make on the check's
#: pairs (float32 rounding of the reordered sums is ~1e-6); above it the whole network is exported.
PRUNED_RELATIVE_TOLERANCE = 1e-4


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


def fitted_from(checkpoint: dict, path: Path) -> FittedSpectralNlb:
    """The fitted materials of a spectral NLB fit checkpoint's entries (or an ``auto`` checkpoint's
    ``nlb_spectral_fit``), else :class:`InputError` naming ``path``."""
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
    return fitted_from(read_checkpoint(path, "fitted spectral NLB checkpoint"), path)


def _pairs(count: int, seed: int):
    """The contract's dense probe (:func:`~neuralbrdf.onnx_contract.dense_probe`: stratified, near the
    mirror, grazing) and ``count`` uniformly random pairs, as float32 tensors ``[N, 3]``."""
    import numpy as np
    import torch

    from neuralbrdf.onnx_contract import dense_probe

    rng = np.random.default_rng(seed)
    wi, wo, _ = dense_probe(seed)
    random = rng.normal(size=(2, count, 3))
    random[..., 2] = np.abs(random[..., 2])
    random /= np.linalg.norm(random, axis=-1, keepdims=True)
    return (torch.from_numpy(np.concatenate([a, b]).astype(np.float32)) for a, b in zip((wi, wo), random))


def _in_chunks(*tensors, size: int = 2**14):
    """Consecutive slices of ``size`` rows of ``tensors`` (bounded memory for ``[N, K, units]``)."""
    for start in range(0, len(tensors[0]), size):
        yield tuple(t[start:start + size] for t in tensors)


def export_module(module: SpectralNlbWithCodes) -> tuple[SpectralNlbWithCodes, str]:
    """``module`` without the hidden units that never fire on the contract's dense probe and
    :data:`UNIT_SEARCH_PAIRS` random pairs
    (:meth:`~neuralbrdf.models.directional.SpectralNlbWithCodes.unit_peaks`; the most active unit
    of a layer is always kept), checked on as many other pairs at random wavelengths; the whole
    module where leaving them out changes ``f`` by more than :data:`PRUNED_RELATIVE_TOLERANCE`.
    Also the units kept per layer, as the metadata entry says them."""
    import torch

    chunks = [module.unit_peaks(wi, wo) for wi, wo in _in_chunks(*_pairs(UNIT_SEARCH_PAIRS, seed=0))]
    peaks = [torch.stack(layer).amax(0) for layer in zip(*chunks)]
    keep = [(peak > 0) | (peak == peak.max()) for peak in peaks]
    pruned = module.without_units(keep)
    arguments = list(_pairs(UNIT_SEARCH_PAIRS, seed=1))
    if module.is_spectral:
        low, high = module.wavelength_range_nm
        order = torch.randperm(len(arguments[0]), generator=torch.Generator().manual_seed(1))
        arguments.append(torch.linspace(low, high, len(arguments[0]))[order])
    change = 0.0
    with torch.no_grad():
        for chunk in _in_chunks(*arguments):
            whole, without = module(*chunk), pruned(*chunk)
            change = max(change, float(((without - whole).abs() / whole.abs().clamp_min(1e-3)).max()))
    total = module.units
    if not change <= PRUNED_RELATIVE_TOLERANCE:
        return module, " ".join(f"{n}/{n}" for n in total)
    return pruned, " ".join(f"{int(k.sum())}/{n}" for k, n in zip(keep, total))


def exportable(module: SpectralNlbWithCodes, name: str, provenance_text: str) -> Exportable:
    """A fitted material (its module on directions) as the exporter takes it: without its silent
    units (:func:`export_module`), with the contract's metadata."""
    module, units = export_module(module)
    wavelength_range = module.wavelength_range_nm if module.is_spectral else None
    metadata = contract_metadata(KIND.name, name, provenance_text, wavelength_range_nm=wavelength_range,
                                 kind_metadata={kind_key(KIND.name, "hidden_units"): units})
    return Exportable(module, KIND.name, name, metadata, wavelength_range)


def from_checkpoint(checkpoint: dict, path: Path, material: str | None) -> Exportable:
    fitted = fitted_from(checkpoint, path)
    name = pick_material(list(fitted.shared), material, path)
    return exportable(fitted.model(name), name, provenance(checkpoint, path))


def _recognises(checkpoint: dict) -> bool:
    return module_class_name(checkpoint) == "SpectralLatentFitModule" or "spectral_nlb_config" in checkpoint


KIND = Kind(
    name="nlb_spectral",
    summary="a latent fit of the spectral NLB network, spectral for spectral measurements and RGB for "
            "RGB ones, one file per material (docs/models.md#spectral-nlb)",
    from_checkpoint=from_checkpoint,
    recognises=_recognises,
    fast_by_default=True,  # its f renders at ~1.7x roughconductor, its f_fast at ~1.1x (docs/design.md)
)
