"""Models as functions of directions: the interface of the ONNX contract (docs/formats.md#onnx-model-files).

Every trained model becomes an ``nn.Module`` that maps unit directions ``wi, wo`` ``[N, 3]``
(local frame, ``z`` the normal, both pointing away from the surface; docs/formats.md#conventions) — and, for
spectral models, wavelengths ``[N]`` in nm — to the BRDF ``f`` in sr⁻¹ (no cosine factor),
with everything needed for evaluation baked in.  These modules are what ``export/to_onnx.py``
traces into ``.onnx`` files, and what Python-side evaluation (hemisphere metrics, plots) calls,
so that both see the same function.

* :class:`SpectralMlpOnDirections` — the in-plane spectral MLP of the report (§5.1) queried out of
  plane through the Rusinkiewicz (1998) half/difference angles: any pair maps to its *in-plane
  equivalent* ``ti = θd + θh``, ``tr = θd − θh`` (docs/formats.md#conventions, docs/models.md#spectral-mlp; the bivariate approximation of
  isotropic BRDFs, Romeiro et al. 2008).
* :class:`NlbWithLatent` — the NLB representation network (Fan et al. 2022) with one fitted
  material latent baked in as a constant (docs/models.md).
* :class:`AbcOnDirections` — the ABC model (Löw et al. 2012, docs/models.md#abc) with fixed parameters;
  per-wavelength parameters are interpolated linearly in wavelength.
* :class:`SpectralNlbWithCodes` — a fitted material of the spectral NLB
  (:mod:`neuralbrdf.models.nlb_spectral`), RGB or spectral, its codes baked in.

All return exactly 0 when either direction is at or below the horizon (``z <= 0``).  Only
operators that ONNX (opset 17) has and that :mod:`neuralbrdf.render.drjit_onnx` interprets are
used: no ``atan2`` (ONNX has none), no ``floor`` or integer indexing.
"""

from __future__ import annotations

import copy
import math

import torch
from torch import nn
from torch.nn import functional as F

from neuralbrdf.physics.abc import AbcParameters, abc_brdf
from neuralbrdf.models.nlb import NlbNetwork, above_horizon, direction_inputs, log1p_output, masked_brdf
from neuralbrdf.models.nlb_spectral import SpectralNlbNetwork
from neuralbrdf.models.spectral_mlp import SpectralMLP

#: Range (degrees) the in-plane equivalent angles are clamped to before the spectral MLP sees
#: them: the in-plane domain of docs/formats.md#conventions.  Far out of plane ``θd + θh`` can exceed 90°.
INPLANE_LIMIT_DEG = 90.0

#: Floor on the denominators of the half-angle formulas; only reached at or below the horizon.
_TINY = 1e-30


def _norm(v: torch.Tensor) -> torch.Tensor:
    return torch.sqrt((v * v).sum(-1))


def rusinkiewicz_theta_h_d(wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Half and difference polar angles ``(θh, θd)`` in radians of unit direction pairs ``[..., 3]``.

    Written with ``atan`` of ratios of lengths, accurate near 0 and without ``atan2`` (absent
    from ONNX), from ``s = wi + wo`` (the unnormalised half vector) and ``t = wi − wo``:

    * ``θh``, the polar angle of ``s``: ``tan θh = |s_xy| / s_z``;
    * ``θd``, the angle between ``wi`` and the half vector, half the angle ``γ`` between ``wi``
      and ``wo``: ``tan θd = |t| / |s|`` (``|wi ± wo| = 2 cos(γ/2), 2 sin(γ/2)`` for unit vectors).

    Valid for both directions above the horizon (``s_z > 0``); elsewhere the values are finite
    but meaningless (callers mask them).
    """
    s = wi + wo
    theta_h = torch.atan(_norm(s[..., :2]) / torch.clamp(s[..., 2], min=_TINY))
    theta_d = torch.atan(_norm(wi - wo) / torch.clamp(_norm(s), min=_TINY))
    return theta_h, theta_d


class SpectralMlpOnDirections(nn.Module):
    """``f(wi, wo, λ)`` ``[N]`` of an in-plane :class:`SpectralMLP` (docs/models.md#spectral-mlp, docs/formats.md#onnx-model-files).

    The pair is replaced by its in-plane equivalent ``(ti, tr) = (θd + θh, θd − θh)`` in degrees
    (:func:`rusinkiewicz_theta_h_d`), the representative with ``ti >= |tr|`` — for an in-plane
    pair this is the pair itself or its image under the isotropy/reciprocity symmetries of
    docs/formats.md#conventions.  Both angles are clamped to ±:data:`INPLANE_LIMIT_DEG`, wavelengths to the model's
    range (:attr:`SpectralMLP.wavelength_range_nm`), and ``f = 0`` below the horizon.
    """

    def __init__(self, mlp: SpectralMLP) -> None:
        super().__init__()
        self.mlp = mlp
        low, high = mlp.wavelength_range_nm
        self.wavelength_range_nm = (low, high)

    def inplane_equivalent_deg(self, wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Clamped signed in-plane angles ``(ti, tr)`` (degrees) the MLP is queried at."""
        theta_h, theta_d = rusinkiewicz_theta_h_d(wi, wo)
        to_deg = 180.0 / math.pi
        theta_i = torch.clamp((theta_d + theta_h) * to_deg, -INPLANE_LIMIT_DEG, INPLANE_LIMIT_DEG)
        theta_r = torch.clamp((theta_d - theta_h) * to_deg, -INPLANE_LIMIT_DEG, INPLANE_LIMIT_DEG)
        return theta_i, theta_r

    def forward(self, wi: torch.Tensor, wo: torch.Tensor, wavelength: torch.Tensor) -> torch.Tensor:
        theta_i, theta_r = self.inplane_equivalent_deg(wi, wo)
        low, high = self.wavelength_range_nm
        f = self.mlp(theta_i, theta_r, torch.clamp(wavelength, low, high))
        return torch.where(above_horizon(wi, wo), f, torch.zeros_like(f))


class NlbWithLatent(nn.Module):
    """``f(wi, wo)`` ``[N, 3]`` (linear sRGB) of an :class:`NlbNetwork` with a fixed latent.

    ``latent`` (``[latent_dim]``) is copied into a buffer.  It is folded into the input layer's
    bias (:meth:`NlbNetwork.split_input_layer`), so the traced graph spends no multiply-adds on
    it (``latent_dim × width`` fewer per query); the rest of the network is used as it is (its
    own horizon mask and output activation).
    """

    def __init__(self, network: NlbNetwork, latent: torch.Tensor) -> None:
        super().__init__()
        latent = torch.as_tensor(latent, dtype=torch.float32).detach().reshape(-1)
        if latent.numel() != network.latent_dim:
            raise ValueError(f"latent has {latent.numel()} values, the network takes {network.latent_dim}")
        self.network = network
        self.register_buffer("latent", latent.clone())
        with torch.no_grad():
            weight, bias = network.split_input_layer(self.latent)
        self.register_buffer("direction_weight", weight.clone())
        self.register_buffer("input_bias", bias.clone())

    def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        pre_activation = F.linear(self.network.features(wi, wo), self.direction_weight, self.input_bias)
        return self.network.masked(wi, wo, self.network.decode(pre_activation))


class LinearInWavelength(nn.Module):
    """Weights ``[N, K]`` of piecewise-linear interpolation on an increasing wavelength grid ``[K]``.

    A sum of hat functions, ``w_k(λ) = clip(min(1 + (λ − λ_k)/w⁻_k, 1 − (λ − λ_k)/w⁺_k), 0, 1)``
    (``w⁻_k, w⁺_k`` the grid steps left and right of node ``k``), with ``λ`` clamped to the grid:
    exact linear interpolation on any increasing grid without ``floor`` or integer indexing, so
    that it exports to ONNX and runs in the Dr.Jit backend.  ``weights @ table`` interpolates a
    table ``[K]``.
    """

    def __init__(self, grid_nm) -> None:
        super().__init__()
        grid = torch.as_tensor(grid_nm, dtype=torch.float64).reshape(-1)
        if grid.numel() > 1 and not bool(torch.all(grid[1:] > grid[:-1])):
            raise ValueError(f"wavelength grid must increase, got {grid.tolist()}")
        steps = grid[1:] - grid[:-1]
        one = torch.ones(1, dtype=grid.dtype)  # outer widths of the end nodes: unused (clamped), not 0
        self.register_buffer("grid", grid.float())
        self.register_buffer("inv_left", (1.0 / torch.cat([one, steps])).float())
        self.register_buffer("inv_right", (1.0 / torch.cat([steps, one])).float())
        self.wavelength_range_nm = (float(grid[0]), float(grid[-1]))

    def forward(self, wavelength: torch.Tensor) -> torch.Tensor:
        low, high = self.wavelength_range_nm
        offset = torch.clamp(wavelength, low, high)[:, None] - self.grid
        return torch.clamp(torch.minimum(1.0 + offset * self.inv_left, 1.0 - offset * self.inv_right), 0.0, 1.0)


class AbcOnDirections(nn.Module):
    """The ABC BRDF (docs/models.md#abc) with fixed parameters, as a function of directions.

    RGB parameters (``wavelengths is None``): ``forward(wi, wo) -> [N, 3]``.  Spectral
    parameters: ``forward(wi, wo, wavelength) -> [N]``, with ``kd`` and ``A`` interpolated
    linearly between the parameter wavelengths (clamped to their range, :class:`LinearInWavelength`).
    """

    def __init__(self, parameters: AbcParameters) -> None:
        super().__init__()
        self.B, self.C, self.eta = parameters.B, parameters.C, parameters.eta
        self.register_buffer("kd", torch.as_tensor(parameters.kd, dtype=torch.float32))
        self.register_buffer("A", torch.as_tensor(parameters.A, dtype=torch.float32))
        self.is_spectral = parameters.wavelengths is not None
        if self.is_spectral:
            try:
                self.interpolation_weights = LinearInWavelength(parameters.wavelengths)
            except ValueError as error:
                raise ValueError(f"ABC wavelengths: {error}") from None
            self.wavelength_range_nm = self.interpolation_weights.wavelength_range_nm

    def forward(self, wi: torch.Tensor, wo: torch.Tensor, wavelength: torch.Tensor | None = None) -> torch.Tensor:
        if not self.is_spectral:
            return abc_brdf(wi, wo, self.kd, self.A, self.B, self.C, self.eta)
        if wavelength is None:
            raise ValueError("spectral ABC parameters need wavelengths")
        weights = self.interpolation_weights(wavelength)
        # One channel of unit kd and one of unit A: f = kd(λ) f_d + A(λ) f_s.
        unit = torch.tensor([1.0, 0.0], dtype=wi.dtype)
        parts = abc_brdf(wi, wo, unit, 1.0 - unit, self.B, self.C, self.eta)
        return parts[..., 0] * (weights @ self.kd) + parts[..., 1] * (weights @ self.A)


class SpectralNlbWithCodes(nn.Module):
    """A fitted material of the spectral NLB (:class:`SpectralNlbNetwork`) as a function of directions.

    ``shared`` ``[shared_dim]`` and ``channels`` ``[K, channel_dim]`` are the material's codes;
    ``node_wavelengths_nm`` the wavelengths of the ``K`` channel codes of a spectral fit, or
    ``None`` for an RGB fit (``K`` = 3: R, G, B).  Everything the codes determine is baked into
    constants, and the network's weights are copied beside them: the shared code into the input
    layer's bias (no multiply-adds for it, as :class:`NlbWithLatent`) and each channel code into
    its FiLM scale and shift ``film_scale``, ``film_shift`` ``[K, width]``.

    * RGB: ``forward(wi, wo) -> [N, 3]``, the channels decoded one after the other from the
      shared pre-activation;
    * spectral: ``forward(wi, wo, wavelength) -> [N]``, the FiLM scale and shift interpolated
      linearly in wavelength between the nodes (clamped to their range, :class:`LinearInWavelength`)
      — the same interpolation as the fit's.  The FiLM is affine in the code and the interpolation
      weights sum to 1, so interpolating the node tables (``2 K units`` multiply-adds per
      wavelength) and applying the FiLM to the interpolated code (``K channel_dim + 2 channel_dim
      units``) give the same values; :attr:`interpolates_codes` picks the cheaper, which is the code
      when it has fewer dimensions than there are nodes.

    **Units this material never uses.**  A material's codes leave many ReLU units of the shared
    network inactive over the whole hemisphere (for the shipped network and the four virtual
    materials, 13–22 of the 48 units of each of the last two layers).  :meth:`unit_peaks` finds
    each unit's largest ReLU input over given direction pairs, and :meth:`without_units` the same
    function with the units that never fire removed (their rows and the next layer's columns):
    fewer multiply-adds per query at the same values, up to float32 rounding
    (:func:`neuralbrdf.kinds.nlb_spectral.export_module` checks that on other pairs).  At the channel layer a
    unit's input is piecewise linear in wavelength between the nodes, so its peak over all
    wavelengths is its peak over the node codes.
    """

    def __init__(self, network: SpectralNlbNetwork, shared: torch.Tensor, channels: torch.Tensor,
                 node_wavelengths_nm=None) -> None:
        super().__init__()
        shared = torch.as_tensor(shared, dtype=torch.float32).detach().reshape(-1)
        channels = torch.as_tensor(channels, dtype=torch.float32).detach()
        if shared.numel() != network.shared_dim or channels.ndim != 2 or channels.shape[1] != network.channel_dim:
            raise ValueError(f"codes of shapes {list(shared.shape)} and {list(channels.shape)} do not fit the network "
                             f"(shared {network.shared_dim}, channel {network.channel_dim})")
        self.half_vector = network.config.half_vector
        self.channel_layer = network.config.channel_layer
        self.node_wavelengths_nm = None if node_wavelengths_nm is None else tuple(float(w) for w in node_wavelengths_nm)
        self.is_spectral = node_wavelengths_nm is not None
        if self.is_spectral:
            self.interpolation_weights = LinearInWavelength(node_wavelengths_nm)
            self.wavelength_range_nm = self.interpolation_weights.wavelength_range_nm
            if len(self.interpolation_weights.grid) != len(channels):
                raise ValueError(f"{len(channels)} channel codes for {len(self.interpolation_weights.grid)} nodes")
        elif len(channels) != 3:
            raise ValueError(f"an RGB fit has 3 channel codes, got {len(channels)}")
        n = network.config.direction_features
        with torch.no_grad():
            weight = network.input_layer.weight
            weights = [weight[:, :n], *(layer.weight for layer in network.hidden_layers), network.output_layer.weight]
            biases = [weight[:, n:] @ shared + network.input_layer.bias,
                      *(layer.bias for layer in network.hidden_layers), network.output_layer.bias]
            scale, shift = network.film(channels)
        #: Hidden layers; layer ``i`` is ``weight_i``, ``bias_i``, and layer ``depth`` the output layer.
        self.depth = network.config.depth
        for i, (weight, bias) in enumerate(zip(weights, biases)):
            self.register_buffer(f"weight_{i}", weight.detach().clone())
            self.register_buffer(f"bias_{i}", bias.detach().clone())
        self.register_buffer("film_scale", scale.detach().clone())
        self.register_buffer("film_shift", shift.detach().clone())
        # the FiLM itself, ``scale = G c + 1`` and ``shift = U c``, for codes interpolated in wavelength
        self.register_buffer("node_codes", channels.clone())
        self.register_buffer("film_scale_weight", network.channel_scale.weight.detach().clone())
        self.register_buffer("film_scale_bias", torch.ones(scale.shape[-1]))
        self.register_buffer("film_shift_weight", network.channel_shift.weight.detach().clone())

    def _layer(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        return getattr(self, f"weight_{i}"), getattr(self, f"bias_{i}")

    def _shared_pre_activation(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """``a_L`` ``[N, units]`` of the channel layer (:mod:`neuralbrdf.models.nlb_spectral`)."""
        a = F.linear(direction_inputs(wi, wo, self.half_vector), *self._layer(0))
        for i in range(1, self.channel_layer + 1):
            a = F.linear(F.relu(a), *self._layer(i))
        return a

    def _decode(self, pre: torch.Tensor, scale: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
        """``ln(1 + f)`` ``[...]`` from ``a_L`` and a channel's FiLM scale and shift, broadcast together."""
        x = F.relu(pre * scale + shift)
        for i in range(self.channel_layer + 1, self.depth):
            x = F.relu(F.linear(x, *self._layer(i)))
        return log1p_output(F.linear(x, *self._layer(self.depth)))[..., 0]

    def forward(self, wi: torch.Tensor, wo: torch.Tensor, wavelength: torch.Tensor | None = None) -> torch.Tensor:
        pre = self._shared_pre_activation(wi, wo)
        if not self.is_spectral:
            return masked_brdf(wi, wo, self._decode(pre[:, None, :], self.film_scale, self.film_shift))
        if wavelength is None:
            raise ValueError("a spectral fit needs wavelengths")
        weights = self.interpolation_weights(wavelength)
        if self.interpolates_codes:
            code = weights @ self.node_codes
            scale = F.linear(code, self.film_scale_weight, self.film_scale_bias)
            shift = F.linear(code, self.film_shift_weight)
        else:
            scale, shift = weights @ self.film_scale, weights @ self.film_shift
        log1p_f = self._decode(pre, scale, shift)
        return masked_brdf(wi, wo, log1p_f[:, None])[:, 0]

    @property
    def interpolates_codes(self) -> bool:
        """Whether a spectral query interpolates the channel code and applies the FiLM to it (fewer
        multiply-adds than interpolating the scale and shift tables; class docstring)."""
        nodes, code_dim = self.node_codes.shape
        units = self.film_scale.shape[-1]
        return nodes * code_dim + 2 * code_dim * units < 2 * nodes * units

    @property
    def units(self) -> list[int]:
        """Units of each hidden layer."""
        return [self._layer(i)[0].shape[0] for i in range(self.depth)]

    @torch.no_grad()
    def unit_peaks(self, wi: torch.Tensor, wo: torch.Tensor) -> list[torch.Tensor]:
        """Per hidden layer, each unit's largest ReLU input over the pairs ``wi, wo`` ``[N, 3]`` and
        every channel code (class docstring): a unit whose peak is ``<= 0`` never fires there."""
        a = F.linear(direction_inputs(wi, wo, self.half_vector), *self._layer(0))
        peaks = []
        for i in range(self.depth):
            if i > 0:
                a = F.linear(F.relu(a), *self._layer(i))
            if i == self.channel_layer:  # [N, K, units]: one row per channel code
                a = a[:, None, :] * self.film_scale + self.film_shift
            peaks.append(a.reshape(-1, a.shape[-1]).amax(0))
        return peaks

    def without_units(self, keep: list[torch.Tensor]) -> SpectralNlbWithCodes:
        """A copy with only the units ``keep`` (a boolean mask per hidden layer) of each hidden layer."""
        pruned = copy.deepcopy(self)
        for i in range(self.depth + 1):
            weight, bias = self._layer(i)
            if i < self.depth:
                weight, bias = weight[keep[i]], bias[keep[i]]
            if i > 0:
                weight = weight[:, keep[i - 1]]
            setattr(pruned, f"weight_{i}", weight.clone())
            setattr(pruned, f"bias_{i}", bias.clone())
        film_units = keep[self.channel_layer]
        for name in ("film_scale", "film_shift"):
            setattr(pruned, name, getattr(self, name)[:, film_units].clone())
        for name in ("film_scale_weight", "film_scale_bias", "film_shift_weight"):
            setattr(pruned, name, getattr(self, name)[film_units].clone())
        return pruned
