"""Spectral NLB: a channel-agnostic NLB decoder with a shared and a per-channel latent (docs/models.md#spectral-nlb).

The NLB representation network of Fan et al. (2022, "Neural Layered BRDFs"; report §2.2.2,
Eq. 2.9) decodes ``g1(wi, wo, V) = f`` with RGB output.  Its released network already holds a
latent per colour channel and shares the decoder between them.  This module makes that the
design, so that one network serves any number of channels — the three of an RGB measurement
or the wavelength bands of a spectral one::

    g(wi, wo, s, c) = f          one output, the BRDF of one channel (sr⁻¹)

* ``s`` (``shared_dim``): the material's **shared code**, common to all its channels — the
  geometry of its lobes (roughness, layering, Fresnel shape);
* ``c`` (``channel_dim``): one **channel code** per channel (R, G, B, or per wavelength) — how
  that channel differs (albedo, lobe weight, the colour of a conductor's Fresnel term).

A spectral material is a shared code and channel codes at a few **wavelength nodes**; the code
of any wavelength is their linear interpolation (:class:`~neuralbrdf.models.directional.LinearInWavelength`),
which is how an exported spectral model is evaluated at a ray's own wavelengths.

Architecture (``depth`` hidden layers of ``width`` units, the input layer first)::

    a_0 = W_0 [features(wi, wo), s] + b_0
    a_k = W_k relu(a_{k-1}) + b_k                       k = 1 .. channel_layer
    x   = relu(a_L ⊙ (1 + G c) + U c)                   L = channel_layer: FiLM by the channel code
    x   = relu(W_k x + b_k)                             k = L + 1 .. depth - 1
    ln(1 + f) = softplus(w · x + b)                     straight-through clip (neuralbrdf.models.nlb)

The channel code modulates one layer (feature-wise linear modulation, Perez et al. 2018,
"FiLM: Visual Reasoning with a General Conditioning Layer"): everything before it depends on
the directions and the shared code only and is computed once per direction pair, whatever the
number of channels.  With the default ``channel_layer = depth - 1`` the per-channel work is a
scale, a shift and one dot product, so an RGB evaluation costs what the RGB NLB does.
``G`` starts at zero (a pure shift) and the output layer at zero weights and the bias of
:data:`~neuralbrdf.models.nlb.INITIAL_PRE_ACTIVATION`, as in :mod:`neuralbrdf.models.nlb`.

Outputs are exactly 0 when either direction is at or below the horizon (docs/formats.md#onnx-model-files).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn
from torch.nn import functional as F

from neuralbrdf.errors import InputError
from neuralbrdf.models.nlb import INITIAL_PRE_ACTIVATION, direction_inputs, log1p_output, masked_brdf


@dataclass(frozen=True)
class SpectralNlbConfig:
    """Architecture of a :class:`SpectralNlbNetwork` (module docstring).

    Attributes
    ----------
    shared_dim, channel_dim:
        Sizes of the shared code ``s`` and of each channel code ``c``.
    width, depth:
        Units per hidden layer and number of hidden layers (the input layer included).
    channel_layer:
        Index (0 .. depth - 1) of the hidden layer the channel code modulates.
    half_vector:
        Append ``h = normalize(wi + wo)`` to the 6 direction inputs.
    """

    shared_dim: int = 32
    channel_dim: int = 8
    width: int = 48
    depth: int = 3
    channel_layer: int = 2
    half_vector: bool = True

    def __post_init__(self) -> None:
        for name in ("shared_dim", "channel_dim", "width", "depth"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise InputError(f"must be a positive integer, got {value!r}", key=name)
        layer = self.channel_layer
        if not isinstance(layer, int) or isinstance(layer, bool) or not 0 <= layer < self.depth:
            raise InputError(f"must be an integer in [0, depth - 1 = {self.depth - 1}], got {layer!r}",
                             key="channel_layer")

    @property
    def direction_features(self) -> int:
        return 9 if self.half_vector else 6


class SpectralNlbNetwork(nn.Module):
    """``g(wi, wo, s, c) -> f``: the BRDF of each channel from directions, a shared code and
    channel codes (module docstring).  Keyword arguments mirror :class:`SpectralNlbConfig`."""

    def __init__(
        self,
        shared_dim: int = SpectralNlbConfig.shared_dim,
        channel_dim: int = SpectralNlbConfig.channel_dim,
        width: int = SpectralNlbConfig.width,
        depth: int = SpectralNlbConfig.depth,
        channel_layer: int = SpectralNlbConfig.channel_layer,
        half_vector: bool = SpectralNlbConfig.half_vector,
    ) -> None:
        super().__init__()
        self.config = SpectralNlbConfig(shared_dim, channel_dim, width, depth, channel_layer, half_vector)
        self.input_layer = nn.Linear(self.config.direction_features + shared_dim, width)
        self.hidden_layers = nn.ModuleList(nn.Linear(width, width) for _ in range(depth - 1))
        self.channel_scale = nn.Linear(channel_dim, width, bias=False)
        self.channel_shift = nn.Linear(channel_dim, width, bias=False)
        self.output_layer = nn.Linear(width, 1)
        nn.init.zeros_(self.channel_scale.weight)
        nn.init.zeros_(self.output_layer.weight)
        nn.init.constant_(self.output_layer.bias, INITIAL_PRE_ACTIVATION)

    @property
    def shared_dim(self) -> int:
        return self.config.shared_dim

    @property
    def channel_dim(self) -> int:
        return self.config.channel_dim

    def shared_pre_activation(self, wi: torch.Tensor, wo: torch.Tensor, shared: torch.Tensor,
                              index: torch.Tensor | None = None) -> torch.Tensor:
        """Pre-activation ``a_L`` ``[..., width]`` of the channel layer: directions and shared code only.

        ``shared`` is one code per pair (or one for all); with ``index`` ``[N]`` it is a table of
        codes ``[M, shared_dim]`` and pair ``i`` takes code ``index[i]``: the codes' share of the
        input layer is then computed once per code, not once per pair."""
        features = direction_inputs(wi, wo, self.config.half_vector)
        n = features.shape[-1]
        weight = self.input_layer.weight
        codes = F.linear(shared, weight[:, n:], self.input_layer.bias)
        a = F.linear(features, weight[:, :n]) + (codes if index is None else codes[index])
        for layer in self.hidden_layers[: self.config.channel_layer]:
            a = layer(F.relu(a))
        return a

    def film(self, channel: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(1 + G c, U c)``, each ``[..., width]``, of channel codes ``[..., channel_dim]``."""
        return 1.0 + self.channel_scale(channel), self.channel_shift(channel)

    def decode(self, shared_pre: torch.Tensor, scale: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
        """``ln(1 + f)`` ``[...]`` from ``a_L`` and a channel's FiLM ``(scale, shift)``, broadcast together."""
        # one fused pass for the modulation and the ReLU in place: the [pairs, channels, width]
        # tensors are the bulk of a spectral fit's arithmetic (docs/design.md#the-spectral-nlbs-fit-time)
        x = F.relu(torch.addcmul(shift, shared_pre, scale), inplace=True)
        for layer in self.hidden_layers[self.config.channel_layer:]:
            x = F.relu(layer(x))
        return log1p_output(self.output_layer(x))[..., 0]

    def log1p_f(self, wi: torch.Tensor, wo: torch.Tensor, shared: torch.Tensor, channel: torch.Tensor) -> torch.Tensor:
        """``ln(1 + f)`` ``[N, C]`` without the horizon mask (arguments as :meth:`forward`)."""
        pre = self.shared_pre_activation(wi, wo, shared)
        scale, shift = self.film(channel)
        return self.decode(pre[..., None, :], scale, shift)

    def forward(self, wi: torch.Tensor, wo: torch.Tensor, shared: torch.Tensor, channel: torch.Tensor) -> torch.Tensor:
        """BRDF ``[N, C]`` in sr⁻¹ (no cosine) of ``C`` channels, 0 below the horizon.

        ``wi, wo`` ``[N, 3]`` unit vectors (local frame, docs/formats.md#conventions); ``shared`` ``[N, shared_dim]``
        or ``[shared_dim]``; ``channel`` ``[N, C, channel_dim]`` or ``[C, channel_dim]``.
        """
        if wi.shape != wo.shape or wi.ndim != 2 or wi.shape[-1] != 3:
            raise InputError(f"wi and wo must both be [N, 3], got {tuple(wi.shape)} and {tuple(wo.shape)}")
        if shared.shape[-1] != self.shared_dim:
            raise InputError(f"shared code must end in {self.shared_dim} values, got shape {tuple(shared.shape)}")
        if channel.ndim not in (2, 3) or channel.shape[-1] != self.channel_dim:
            raise InputError(f"channel codes must be [N, C, {self.channel_dim}] or [C, {self.channel_dim}], "
                             f"got shape {tuple(channel.shape)}")
        return masked_brdf(wi, wo, self.log1p_f(wi, wo, shared, channel))

    def parameter_count(self) -> int:
        return sum(p.numel() for p in self.parameters())


class SpectralLatentTable(nn.Module):
    """Per-material codes: a shared code ``[M, shared_dim]`` and ``n_channels`` channel codes
    ``[M, n_channels, channel_dim]``, all initialised to ``init_value`` (Fan et al.); ``names``
    (optional, unique) label the materials."""

    def __init__(self, n_materials: int, shared_dim: int, channel_dim: int, n_channels: int = 3,
                 init_value: float = 0.0, names: list[str] | tuple[str, ...] | None = None) -> None:
        super().__init__()
        if n_materials < 1 or n_channels < 1:
            raise InputError(f"a code table needs materials and channels, got {n_materials} and {n_channels}")
        if names is not None:
            names = tuple(str(n) for n in names)
            if len(names) != n_materials or len(set(names)) != n_materials:
                raise InputError(f"need {n_materials} unique names, got {list(names)}")
        self.names = names
        self.shared = nn.Parameter(torch.full((n_materials, shared_dim), float(init_value)))
        self.channels = nn.Parameter(torch.full((n_materials, n_channels, channel_dim), float(init_value)))

    def __len__(self) -> int:
        return self.shared.shape[0]

    def forward(self, index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Codes of materials ``index`` ``[N]``: shared ``[N, shared_dim]``, channels ``[N, C, channel_dim]``."""
        return self.shared[index], self.channels[index]
