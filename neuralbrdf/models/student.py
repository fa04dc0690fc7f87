"""A small network on Rusinkiewicz coordinates that stands in for a costlier model (docs/select.md).

What a *fast path* evaluates instead of its parent inside the render kernel: the parent's linear
sRGB for a spectral model in an RGB variant (one evaluation per query instead of one per
wavelength of the sRGB rule), or a compact copy of an NLB.  It is distilled from the parent's
own values (:func:`neuralbrdf.lod.distill.distill_student`), never trained on measurements.

Inputs are the baked table's coordinates (:func:`~neuralbrdf.models.baked_table.table_coordinates`):
``a_h = (1 − cos θh)^(1/4)`` (MERL's square-root spacing: a specular lobe becomes wide in it),
``a_d = cos θd`` and ``a_p = |cos φd|`` — all an isotropic, reciprocal BRDF depends on, computed
without ``acos`` or ``atan`` — each mapped onto [-1, 1], plus, for a spectral student, the
wavelength normalised over the model's range.  ``hidden_layers`` layers of ``hidden`` units
(activation ``tanh`` or ``relu``) and a linear layer give ``y``; the BRDF is ``exp(y)`` (RGB: 3
channels; spectral: 1), 0 below the horizon.  The exponential lets a few units span diffuse
levels of 0.01 sr⁻¹ and specular peaks of 10³ sr⁻¹; the distillation fits ``y`` in the log
domain.  ``y`` is clipped to [:data:`LOG_F_MIN`, :data:`LOG_F_MAX`] so that the output stays
finite in float32.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from neuralbrdf.models.baked_table import table_coordinates
from neuralbrdf.models.nlb import above_horizon

#: Hidden activations by name.
ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU}
#: Bounds of ``ln f`` (f in sr⁻¹): 4.5e-5 to 8.9e6.
LOG_F_MIN = -10.0
LOG_F_MAX = 16.0
#: Initial output bias: the student starts at 0.05 sr⁻¹ everywhere, a typical diffuse level.
INITIAL_LOG_F = math.log(0.05)


class DirectionalStudent(nn.Module):
    """``f(wi, wo[, λ])`` ``[N, 3]`` (RGB) or ``[N]`` (spectral, ``wavelength_range_nm`` given)
    of a ``hidden_layers × hidden`` MLP on table coordinates (module docstring)."""

    def __init__(self, hidden: int, hidden_layers: int, wavelength_range_nm: tuple[float, float] | None = None,
                 activation: str = "tanh") -> None:
        super().__init__()
        if hidden < 1 or hidden_layers < 1:
            raise ValueError(f"a student needs >= 1 hidden layer of >= 1 unit, got {hidden_layers} x {hidden}")
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {', '.join(ACTIVATIONS)}, got {activation!r}")
        self.hidden, self.hidden_layers, self.activation = hidden, hidden_layers, activation
        self.wavelength_range_nm = None if wavelength_range_nm is None else tuple(float(w) for w in wavelength_range_nm)
        inputs = 3 if self.wavelength_range_nm is None else 4
        layers: list[nn.Module] = []
        for index in range(hidden_layers):
            layers += [nn.Linear(inputs if index == 0 else hidden, hidden), ACTIVATIONS[activation]()]
        output = nn.Linear(hidden, 3 if self.wavelength_range_nm is None else 1)
        with torch.no_grad():
            output.weight.mul_(0.1)
            output.bias.fill_(INITIAL_LOG_F)
        self.mlp = nn.Sequential(*layers, output)

    @property
    def is_spectral(self) -> bool:
        return self.wavelength_range_nm is not None

    def features(self, wi: torch.Tensor, wo: torch.Tensor, wavelength: torch.Tensor | None = None) -> torch.Tensor:
        """``[N, 3 or 4]``: the coordinates on [-1, 1] the MLP reads (module docstring)."""
        columns = [2.0 * u - 1.0 for u in table_coordinates(wi, wo)]
        if self.is_spectral:
            low, high = self.wavelength_range_nm
            columns.append(2.0 * (torch.clamp(wavelength, low, high) - low) / (high - low) - 1.0)
        return torch.stack(columns, dim=-1)

    def log_f(self, features: torch.Tensor) -> torch.Tensor:
        """``ln f`` ``[N, 3]`` or ``[N]`` from :meth:`features`, clipped (module docstring)."""
        y = torch.clamp(self.mlp(features), LOG_F_MIN, LOG_F_MAX)
        return y if not self.is_spectral else y[:, 0]

    def forward(self, wi: torch.Tensor, wo: torch.Tensor, wavelength: torch.Tensor | None = None) -> torch.Tensor:
        f = torch.exp(self.log_f(self.features(wi, wo, wavelength)))
        mask = above_horizon(wi, wo)
        return torch.where(mask if self.is_spectral else mask[:, None], f, torch.zeros_like(f))

    def describe(self) -> str:
        channels = "spectral" if self.is_spectral else "RGB"
        return f"{channels} student {self.hidden_layers}x{self.hidden} {self.activation} on (a_h, a_d, a_p)"
