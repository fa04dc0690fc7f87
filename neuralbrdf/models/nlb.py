"""NLB representation network: a BRDF decoded from a material latent (docs/models.md#nlb).

After J. Fan, B. Wang, M. Hašan, J. Yang, L.-Q. Yan, "Neural Layered BRDFs", SIGGRAPH 2022
Conference Proceedings (report §2.2.2, Eq. 2.9)::

    g1(wi, wo, V) = f(wi, wo)

an MLP over the Cartesian directions ``wi, wo`` (6 values, local frame of docs/formats.md#conventions) concatenated
with a material latent ``V``, trained as an auto-decoder: the network weights and one latent per
training material are optimised jointly (:class:`LatentTable` holds the latents, initialised to a
constant as in Fan et al.).  A new material is then represented by optimising its latent alone
(docs/models.md#latent-fit-rgb-nlb).

Choices of this implementation:

* **Output activation** ``f = expm1(softplus(y))`` per RGB channel: never negative, and
  ``ln(1 + f) = softplus(y)``, so the network works in the log domain in which BRDFs — diffuse
  levels of 0.01 sr⁻¹ next to specular peaks of 10⁴ sr⁻¹ — are well conditioned.
* **Keeping the output alive.**  For ``y -> -inf`` the gradient ``d f / d y ≈ e^y`` vanishes,
  and Adam's scale-free steps do drive ``y`` there: most corpus samples are dark, so the first
  updates push every output down, overshoot to ``y < -100`` where ``e^y`` underflows, and the
  network freezes at an all-black solution.  Two measures prevent it: the output layer
  starts with zero weights and the bias :data:`INITIAL_PRE_ACTIVATION` (``f = 0.05`` sr⁻¹
  everywhere, a typical diffuse level), so there is no initial overshoot; and ``y`` is
  clipped to [:data:`PRE_ACTIVATION_MIN`, :data:`LOG1P_F_MAX`], which keeps the output finite
  (below ``8.9e6`` sr⁻¹) and above a floor of ``3e-7`` sr⁻¹ that is zero for any practical
  purpose; the clip is straight-through (a channel beyond a bound gets the gradient of
  softplus at the bound, never exactly zero).  Measured on 2400-step runs: without the zero
  initialisation learning rate 1e-2 froze at the all-black solution (``val/logcos_rmse``
  1.27) and 3e-3 lost its first 200 steps; with it, 1e-2 reaches 0.065.  A unit gradient beyond
  the floor instead (a stronger pull back) made training diverge.
* **Horizon.** ``f = 0`` exactly when ``wi_z <= 0`` or ``wo_z <= 0`` (docs/formats.md#onnx-model-files).
* **Optional half-vector features** (``half_vector=True``): the unit half vector
  ``h = normalize(wi + wo)`` appended to the 6 direction values.  It is a function of ``wi, wo``
  computed inside the model (and so inside any exported graph); a compact network otherwise
  spends most of its capacity learning the peak's location ``n·h``.
* Sizes: :data:`COMPACT` (CPU-rendering default) and :data:`PAPER` (Fan et al.: 256 wide, 16
  residual layers after the input layer).  ``depth`` counts the hidden layers of ``width``
  units, the input layer included.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import torch
from torch import nn
from torch.nn import functional as F

from neuralbrdf.errors import InputError

#: Cap on ``ln(1 + f)``: outputs stay below ``e^16 - 1 ≈ 8.9e6`` sr⁻¹ (finite in float32).
LOG1P_F_MAX = 16.0
#: Floor on the output pre-activation: ``f >= expm1(softplus(-15)) ≈ 3.06e-7`` sr⁻¹.
PRE_ACTIVATION_MIN = -15.0
#: Initial output bias, ``softplus⁻¹(ln(1 + 0.05)) = ln(0.05)``: the network starts at 0.05 sr⁻¹.
INITIAL_PRE_ACTIVATION = math.log(0.05)

#: Added under the square root when normalising ``wi + wo`` (vanishes only below the horizon).
_HALF_EPS = 1e-12


@dataclass(frozen=True)
class NlbConfig:
    """Architecture of an :class:`NlbNetwork`.

    Attributes
    ----------
    latent_dim:
        Size of the material latent ``V``.
    width:
        Units per hidden layer.
    depth:
        Number of hidden layers (>= 1).  The first maps the input to ``width``; each further one
        is ``width -> width`` (a residual block ``x + relu(W x + b)`` when ``residual``).
    residual:
        Residual connections on the ``width -> width`` layers (Fan et al.'s network).
    half_vector:
        Append ``h = normalize(wi + wo)`` (3 values) to the 6 direction inputs.
    """

    latent_dim: int = 16
    width: int = 64
    depth: int = 4
    residual: bool = False
    half_vector: bool = True

    def __post_init__(self) -> None:
        for name in ("latent_dim", "width", "depth"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise InputError(f"must be a positive integer, got {value!r}", key=name)

    @property
    def direction_features(self) -> int:
        return 9 if self.half_vector else 6


#: Default for CPU rendering (docs/models.md#nlb: the paper size is far too slow on CPU): 48 wide, 3
#: layers, ~6 k weights; 5184 multiply-adds per query with the latent folded into the input bias
#: (:meth:`NlbNetwork.split_input_layer`).  Chosen by held-out error against evaluation cost
#: among 32×4, 32×5, 48×3 and 64×4 (docs/design.md, "NLB network size").
COMPACT = NlbConfig(latent_dim=16, width=48, depth=3, residual=False, half_vector=True)
#: Fan et al. (2022): 256 wide, an input layer then 16 residual layers (~1.06 M weights),
#: Cartesian directions only.
PAPER = NlbConfig(latent_dim=32, width=256, depth=17, residual=True, half_vector=False)


def above_horizon(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """Boolean ``[...]``: both directions strictly above the surface (``z > 0``)."""
    return (wi[..., 2] > 0) & (wo[..., 2] > 0)


def direction_inputs(wi: torch.Tensor, wo: torch.Tensor, half_vector: bool) -> torch.Tensor:
    """Direction features ``[..., 6]`` (``wi, wo``) or, with ``half_vector``, ``[..., 9]`` (``wi, wo, h``)."""
    if not half_vector:
        return torch.cat([wi, wo], dim=-1)
    s = wi + wo
    h = s * torch.rsqrt((s * s).sum(-1, keepdim=True) + _HALF_EPS)
    return torch.cat([wi, wo, h], dim=-1)


def log1p_output(pre_activation: torch.Tensor) -> torch.Tensor:
    """``ln(1 + f) = softplus(y)`` of the output pre-activation ``y``, with the straight-through clip
    of ``y`` to [:data:`PRE_ACTIVATION_MIN`, :data:`LOG1P_F_MAX`] (module docstring): the value of
    the bound, the gradient of softplus at the bound."""
    y = pre_activation
    return F.softplus(y + (y.clamp(PRE_ACTIVATION_MIN, LOG1P_F_MAX) - y).detach())


def masked_brdf(wi: torch.Tensor, wo: torch.Tensor, log1p_f: torch.Tensor) -> torch.Tensor:
    """``f = expm1(log1p_f)`` ``[..., C]``, 0 where either direction is below the horizon."""
    f = torch.expm1(log1p_f)
    return torch.where(above_horizon(wi, wo)[..., None], f, torch.zeros_like(f))


class NlbNetwork(nn.Module):
    """``g1(wi, wo, V) -> f``: RGB BRDF in sr⁻¹ from directions and a material latent.

    Parameters mirror :class:`NlbConfig` (keyword arguments, so a YAML ``init_args`` block or
    ``NlbNetwork(**dataclasses.asdict(config))`` both work).
    """

    def __init__(
        self,
        latent_dim: int = COMPACT.latent_dim,
        width: int = COMPACT.width,
        depth: int = COMPACT.depth,
        residual: bool = COMPACT.residual,
        half_vector: bool = COMPACT.half_vector,
    ) -> None:
        super().__init__()
        self.config = NlbConfig(latent_dim, width, depth, residual, half_vector)
        self.input_layer = nn.Linear(self.config.direction_features + latent_dim, width)
        self.hidden_layers = nn.ModuleList(nn.Linear(width, width) for _ in range(depth - 1))
        self.output_layer = nn.Linear(width, 3)
        nn.init.zeros_(self.output_layer.weight)
        nn.init.constant_(self.output_layer.bias, INITIAL_PRE_ACTIVATION)

    @property
    def latent_dim(self) -> int:
        return self.config.latent_dim

    def features(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """Direction features ``[..., 6]`` (``wi, wo``) or ``[..., 9]`` (``wi, wo, h``)."""
        return direction_inputs(wi, wo, self.config.half_vector)

    def log1p_f(self, wi: torch.Tensor, wo: torch.Tensor, latent: torch.Tensor) -> torch.Tensor:
        """``ln(1 + f)`` of the raw network, ``[..., 3]``, without the horizon mask."""
        x = torch.cat([self.features(wi, wo), latent.expand(*wi.shape[:-1], -1)], dim=-1)
        return self.decode(self.input_layer(x))

    def decode(self, input_pre_activation: torch.Tensor) -> torch.Tensor:
        """``ln(1 + f)`` ``[..., 3]`` from the input layer's pre-activation ``[..., width]``."""
        x = F.relu(input_pre_activation)
        for layer in self.hidden_layers:
            y = F.relu(layer(x))
            x = x + y if self.config.residual else y
        return log1p_output(self.output_layer(x))

    def split_input_layer(self, latent: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The input layer for one fixed ``latent`` ``[latent_dim]``: its direction weights
        ``[width, features]`` and the bias ``W_latent · latent + b`` ``[width]`` the latent folds
        into, so that ``input_layer([features, latent]) = features · Wᵀ + bias`` costs no
        multiply-adds for the latent (how :class:`~neuralbrdf.models.directional.NlbWithLatent`
        evaluates a fitted material)."""
        n = self.config.direction_features
        weight = self.input_layer.weight
        return weight[:, :n], weight[:, n:] @ latent + self.input_layer.bias

    def masked(self, wi: torch.Tensor, wo: torch.Tensor, log1p_f: torch.Tensor) -> torch.Tensor:
        """``f = expm1(log1p_f)``, 0 where either direction is below the horizon."""
        return masked_brdf(wi, wo, log1p_f)

    def forward(self, wi: torch.Tensor, wo: torch.Tensor, latent: torch.Tensor) -> torch.Tensor:
        """RGB BRDF ``[..., 3]`` in sr⁻¹ (no cosine), 0 where either direction is below the horizon.

        ``wi, wo`` are unit vectors ``[..., 3]`` in the local frame (docs/formats.md#conventions); ``latent`` is
        ``[..., latent_dim]`` (one latent per row) or ``[latent_dim]`` (shared by every row).
        """
        if wi.shape != wo.shape or wi.shape[-1] != 3:
            raise InputError(f"wi and wo must both be [..., 3], got {tuple(wi.shape)} and {tuple(wo.shape)}")
        if latent.shape[-1] != self.latent_dim:
            raise InputError(f"latent must end in {self.latent_dim} values, got shape {tuple(latent.shape)}")
        return self.masked(wi, wo, self.log1p_f(wi, wo, latent))

    def parameter_count(self) -> int:
        return sum(p.numel() for p in self.parameters())


class LatentTable(nn.Module):
    """Per-material latents ``[n_materials, latent_dim]``, all initialised to ``init_value``.

    An ``nn.Embedding``-like table (Fan et al. initialise every latent to the same constant;
    the materials' gradients then pull them apart).  ``names`` (optional) label the rows.
    """

    def __init__(
        self,
        n_materials: int,
        latent_dim: int,
        init_value: float = 0.0,
        names: list[str] | tuple[str, ...] | None = None,
    ) -> None:
        super().__init__()
        if n_materials < 1:
            raise InputError(f"a latent table needs at least one material, got {n_materials}")
        if not math.isfinite(init_value):
            raise InputError(f"latent init_value must be finite, got {init_value}")
        if names is not None:
            names = tuple(str(n) for n in names)
            if len(names) != n_materials:
                raise InputError(f"{len(names)} names for {n_materials} latents")
            if len(set(names)) != len(names):
                raise InputError(f"material names must be unique, got {list(names)}")
        self.names = names
        self.latents = nn.Parameter(torch.full((n_materials, latent_dim), float(init_value)))

    def __len__(self) -> int:
        return self.latents.shape[0]

    def forward(self, index: torch.Tensor) -> torch.Tensor:
        """Latents of the materials ``index`` (any integer shape ``S``) as ``[*S, latent_dim]``."""
        return self.latents[index]

    def latent(self, name: str) -> torch.Tensor:
        """The latent ``[latent_dim]`` of a named material."""
        if self.names is None or name not in self.names:
            raise InputError(f"no latent named {name!r}; known: {list(self.names or ())}")
        return self.latents[self.names.index(name)]


def resize_latent(
    network: NlbNetwork, latents: torch.Tensor, latent_dim: int, generator: torch.Generator | None = None
) -> tuple[NlbNetwork, torch.Tensor]:
    """The same network and corpus ``latents`` ``[M, d]`` re-expressed with ``latent_dim`` values.

    Only the input layer's latent columns ``W_V`` change, so that a warm start can continue a
    pretrained network at another latent size (the study's latent-size sweep):

    * **Smaller** (principal-component truncation): with the latents' mean ``μ`` and their
      ``latent_dim`` leading principal directions ``P`` ``[d, latent_dim]``, the new latents are
      ``(V - μ) P`` and the layer takes ``W_V P`` and the bias ``b + W_V μ``.  The network's
      output on a new latent equals the old output on ``μ + P Pᵀ (V - μ)``, the projection of
      the old latent — exact when the latents span no more than ``latent_dim`` directions.
    * **Larger** (padding): the new latents are the old ones followed by zeros, so every output
      is unchanged; the new columns of ``W_V`` are uniform in ±1/√(the old layer's fan-in), like
      a fresh layer's weights (``generator``), so that the padded latent values receive gradients
      when training goes on.
    """
    old_dim = network.latent_dim
    config = replace(network.config, latent_dim=latent_dim)
    if latents.ndim != 2 or latents.shape[1] != old_dim:
        raise InputError(f"latents must be [materials, {old_dim}], got {tuple(latents.shape)}")
    resized = NlbNetwork(**asdict(config))
    resized.load_state_dict({k: v for k, v in network.state_dict().items() if not k.startswith("input_layer.")},
                            strict=False)
    n = config.direction_features
    weight, bias = network.input_layer.weight.detach(), network.input_layer.bias.detach()
    w_latent = weight[:, n:]
    latents = latents.detach().to(weight.dtype)
    with torch.no_grad():
        if latent_dim <= old_dim:
            mean = latents.mean(0)
            centred = latents - mean
            # eigenvectors of the scatter matrix: old_dim of them even for fewer materials than that
            _, vectors = torch.linalg.eigh(centred.T @ centred)
            basis = vectors.flip(1)[:, :latent_dim]  # [old_dim, latent_dim], leading directions first
            new_latents = centred @ basis
            resized.input_layer.weight.copy_(torch.cat([weight[:, :n], w_latent @ basis], dim=1))
            resized.input_layer.bias.copy_(bias + w_latent @ mean)
        else:
            bound = 1.0 / math.sqrt(n + old_dim)
            extra = (torch.rand(weight.shape[0], latent_dim - old_dim, generator=generator,
                                device=weight.device) * 2 - 1) * bound
            new_latents = torch.cat([latents, latents.new_zeros(len(latents), latent_dim - old_dim)], dim=1)
            resized.input_layer.weight.copy_(torch.cat([weight, extra.to(weight.dtype)], dim=1))
            resized.input_layer.bias.copy_(bias)
    return resized.to(weight.device, weight.dtype).train(network.training), new_latents
