"""The spectral BRDF MLP of the report, §5.1 (S. Chitnis, *Simplifying BRDF Acquisition*).

``f(theta_i, theta_r, lambda)``: signed in-plane angles in degrees (docs/formats.md#conventions: ``wi = (sin ti, 0,
cos ti)``, ``wo = (-sin tr, 0, cos tr)``, mirror at ``tr = ti``) and a wavelength in nm in, one
BRDF value in sr⁻¹ out.  Report Fig. 5.1: the three inputs are normalised, pass three hidden
layers of 10 units and give one output.

Choices the report leaves open (docs/models.md#spectral-mlp), each a constructor argument:

* **Normalisation** maps each input linearly onto [-1, 1] over a stated range — by default the
  whole in-plane domain [-90°, 90°] and 400–700 nm, the calibrated GCMS band
  (:data:`neuralbrdf.data.calibration.CALIBRATED_WAVELENGTHS_NM`).  The constants are buffers,
  so they travel in ``state_dict``, checkpoints and an exported graph; they do not depend on
  the training data, so a model is usable without it.
* **Hidden activation** ``tanh`` by default: the most reliable across seeds in the comparison
  of ``benchmarks/README.md`` (design measurements); a 3×10 ReLU net has too few linear pieces
  for the specular peak across wavelengths.
* **Output activation** ``softplus`` by default (``exp`` available): both keep the BRDF
  non-negative; ``exp`` fitted worse in the same comparison, since the MSE gradient is
  multiplied by the (large) prediction near the peak.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import torch
from torch import nn

from neuralbrdf.errors import InputError

#: Hidden-layer activations by config name.
ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "silu": nn.SiLU, "elu": nn.ELU}
#: Output activations (each maps the reals onto the non-negative reals) by config name.
OUTPUTS = {"softplus": nn.functional.softplus, "exp": torch.exp}
#: Config types naming the keys above (Literal subscripted by a tuple lists its items).
Activation = Literal[tuple(ACTIVATIONS)]
OutputActivation = Literal[tuple(OUTPUTS)]


def _choice(name: str, value: str, options) -> None:
    if value not in options:
        raise InputError(f"{name} must be one of {', '.join(options)}, got {value!r}")


def _range(name: str, bounds: Sequence[float]) -> tuple[float, float]:
    low, high = (float(b) for b in bounds)
    if not low < high:
        raise InputError(f"{name} must be an increasing pair (low, high), got {tuple(bounds)}")
    return low, high


class SpectralMLP(nn.Module):
    """Spectral in-plane BRDF network (report Fig. 5.1): ``(ti, tr, lambda) -> f`` in sr⁻¹.

    Parameters
    ----------
    hidden:
        Units per hidden layer (report: 10).
    hidden_layers:
        Number of hidden layers (report: 3).
    activation:
        Hidden activation, a key of :data:`ACTIVATIONS`.
    output:
        Non-negative output activation, ``"softplus"`` or ``"exp"``.
    angle_range_deg:
        Signed angle range mapped onto [-1, 1] for both ``theta_i`` and ``theta_r``.
    wavelength_range_nm:
        Wavelength range mapped onto [-1, 1]; also the model's nominal spectral range.
    """

    def __init__(
        self,
        hidden: int = 10,
        hidden_layers: int = 3,
        activation: Activation = "tanh",
        output: OutputActivation = "softplus",
        angle_range_deg: Sequence[float] = (-90.0, 90.0),
        wavelength_range_nm: Sequence[float] = (400.0, 700.0),
    ) -> None:
        super().__init__()
        _choice("activation", activation, ACTIVATIONS)
        _choice("output", output, OUTPUTS)
        if hidden < 1 or hidden_layers < 1:
            raise InputError(f"hidden and hidden_layers must be >= 1, got {hidden} and {hidden_layers}")
        angle_low, angle_high = _range("angle_range_deg", angle_range_deg)
        wavelength_low, wavelength_high = _range("wavelength_range_nm", wavelength_range_nm)
        low = torch.tensor([angle_low, angle_low, wavelength_low])
        high = torch.tensor([angle_high, angle_high, wavelength_high])
        # x_normalised = (x - input_center) / input_half_width, each input onto [-1, 1].
        self.register_buffer("input_center", (low + high) / 2)
        self.register_buffer("input_half_width", (high - low) / 2)

        layers: list[nn.Module] = []
        width_in = 3
        for _ in range(hidden_layers):
            layers += [nn.Linear(width_in, hidden), ACTIVATIONS[activation]()]
            width_in = hidden
        layers.append(nn.Linear(width_in, 1))
        self.layers = nn.Sequential(*layers)
        self.output_activation = output

    @property
    def wavelength_range_nm(self) -> tuple[float, float]:
        """The wavelength range (nm) the inputs are normalised over."""
        center, half = float(self.input_center[2]), float(self.input_half_width[2])
        return center - half, center + half

    def normalise(self, theta_i_deg: torch.Tensor, theta_r_deg: torch.Tensor, wavelength_nm: torch.Tensor):
        """Network input ``[N, 3]``: each of the ``[N]`` inputs mapped linearly onto [-1, 1]."""
        # Column by column, so that an exported graph does scalar arithmetic on [N] tensors
        # (onnxruntime broadcasts [N, 3] against [3] far slower; same values).
        columns = (theta_i_deg, theta_r_deg, wavelength_nm)
        return torch.stack(
            [(x - self.input_center[k]) / self.input_half_width[k] for k, x in enumerate(columns)], dim=-1
        )

    def forward(self, theta_i_deg: torch.Tensor, theta_r_deg: torch.Tensor, wavelength_nm: torch.Tensor):
        """BRDF ``[N]`` in sr⁻¹ (>= 0) at signed in-plane angles (degrees) and wavelengths (nm)."""
        features = self.normalise(theta_i_deg, theta_r_deg, wavelength_nm)
        # Squeezed before the output activation: its ops then run on [N], not [N, 1] (same values;
        # onnxruntime broadcasts scalars against [N, 1] far slower).
        return OUTPUTS[self.output_activation](self.layers(features).squeeze(-1))
