"""Ground-truth materials as models on directions, exportable to the ONNX contract (docs/evaluate.md, docs/formats.md#onnx-model-files).

Every material the project ships or reads has a truth: the analytic BRDF of a virtual material
(:mod:`neuralbrdf.virtual.materials`, docs/measure.md#the-virtual-goniospectrophotometer) or the network of an NBRDF proxy of a MERL
material (:mod:`neuralbrdf.data.nbrdf`, Sztrajman et al. 2021, docs/formats.md#nbrdf-proxy).  Here each becomes an
``nn.Module`` with the interface of :mod:`neuralbrdf.models.directional`, so that it exports to
one ``.onnx`` file of kind ``reference`` and renders through the same plugin, sampler and seeds
as a fitted model: image differences then measure the model, not the renderer.

* :class:`VirtualMaterialTruth` — spectral, ``f(wi, wo, λ) [N]``.  The material's per-wavelength
  quantities (albedo, gold's complex index, ...) are tabulated every :data:`TRUTH_STEP_NM` nm on
  :data:`TRUTH_RANGE_NM` and interpolated linearly in wavelength; the BRDF formula itself is the
  library's own (``brdf_from_spectra``), evaluated in the graph.  On the grid the truth equals
  the library's evaluation to float32 rounding; between nodes the interpolation differs from
  colour-science's Sprague interpolation of the ColorChecker spectra by well under 1 %.  The
  range is that of the project's colour pipeline (docs/formats.md#spectral-to-linear-srgb, 400–700 nm) and of every fitted
  spectral model; wavelengths outside are clamped to it, as the contract says.
* :class:`NbrdfTruth` — RGB, ``f(wi, wo) [N, 3]``: the NBRDF network (6→21→21→3, ReLU, ``exp(x) −
  1``) on the Rusinkiewicz half/difference vectors, clamped at 0 and 0 below the horizon.
* :class:`MerlTruth` — RGB, ``f(wi, wo) [N, 3]``: a MERL ``.binary`` measurement (Matusik et al.
  2003), its table looked up by MERL's nearest-cell rule.

``SOURCE`` strings name a truth: ``virtual:NAME`` (``gold``, ``gonio``, ``cyan``, ``magenta``,
``munsell_n9``), the path of an NBRDF weight file ``NAME.h5`` or of a MERL file ``NAME.binary``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from neuralbrdf.data.merl_binary import MerlBrdf
from neuralbrdf.data.nbrdf import DENSE_LAYERS, NbrdfNetwork, nbrdf_input
from neuralbrdf.errors import InputError
from neuralbrdf.models.directional import LinearInWavelength
from neuralbrdf.models.nlb import above_horizon
from neuralbrdf.onnx_export import Exportable, ExportReport, write_model
from neuralbrdf.kinds import contract_metadata
from neuralbrdf.virtual.materials import MATERIALS, get_material

#: Wavelength range (nm) of the virtual truths: the project's colour pipeline (docs/formats.md#spectral-to-linear-srgb).
TRUTH_RANGE_NM = (400.0, 700.0)
#: Spacing (nm) of the wavelength tables a virtual truth interpolates.
TRUTH_STEP_NM = 5.0
VIRTUAL_PREFIX = "virtual:"
#: The kind written to ``neuralbrdf.kind`` (docs/formats.md#onnx-model-files).
REFERENCE_KIND = "reference"


def truth_grid_nm() -> np.ndarray:
    """The wavelength nodes (nm) of the virtual truths' tables."""
    low, high = TRUTH_RANGE_NM
    return np.linspace(low, high, round((high - low) / TRUTH_STEP_NM) + 1)


class VirtualMaterialTruth(nn.Module):
    """``f(wi, wo, λ)`` ``[N]`` in sr⁻¹ of a virtual material (module docstring)."""

    def __init__(self, material, grid_nm=None) -> None:
        super().__init__()
        grid = truth_grid_nm() if grid_nm is None else np.asarray(grid_nm, dtype=np.float64)
        self.material = material
        self.interpolation_weights = LinearInWavelength(grid)
        self.wavelength_range_nm = self.interpolation_weights.wavelength_range_nm
        self.spectrum_names = tuple(material.spectra(grid))
        for name, values in material.spectra(grid).items():
            self.register_buffer(f"spectrum_{name}", torch.as_tensor(np.asarray(values, dtype=np.float64)).float())

    def forward(self, wi: torch.Tensor, wo: torch.Tensor, wavelength: torch.Tensor) -> torch.Tensor:
        weights = self.interpolation_weights(wavelength)
        spectra = {name: (weights @ getattr(self, f"spectrum_{name}"))[:, None] for name in self.spectrum_names}
        f = self.material.brdf_from_spectra(wi, wo, spectra)[:, 0]
        return torch.where(above_horizon(wi, wo), f, torch.zeros_like(f))


class NbrdfTruth(nn.Module):
    """``f(wi, wo)`` ``[N, 3]`` (linear sRGB, sr⁻¹) of an NBRDF proxy network."""

    def __init__(self, network: NbrdfNetwork) -> None:
        super().__init__()
        self.name = network.name
        self.activations = tuple(activation for _, activation in DENSE_LAYERS)
        for layer, (kernel, bias) in enumerate(zip(network.kernels, network.biases)):
            self.register_buffer(f"kernel{layer}", torch.as_tensor(np.array(kernel)).float())
            self.register_buffer(f"bias{layer}", torch.as_tensor(np.array(bias)).float())

    def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        x = nbrdf_input(wi, wo)
        for layer, activation in enumerate(self.activations):
            x = x @ getattr(self, f"kernel{layer}") + getattr(self, f"bias{layer}")
            if activation == "relu":
                x = torch.relu(x)
        f = torch.relu(torch.expm1(x))  # exp(x) - 1 without float32 cancellation near 0
        return torch.where(above_horizon(wi, wo)[:, None], f, torch.zeros_like(f))


class MerlTruth(nn.Module):
    """``f(wi, wo)`` ``[N, 3]`` (linear sRGB, sr⁻¹) of a MERL measurement, looked up in its table by
    MERL's own nearest-cell rule (:mod:`neuralbrdf.data.merl_binary`, ``BRDFRead.cpp``).

    The Rusinkiewicz angles come from the half vector ``h`` and the difference vector (``wi`` in
    ``h``'s frame: turned by ``−φh`` about the normal, then by ``−θh`` about ``y``) without
    ``atan2``: ``φd mod 180° = atan(d_y / d_x)``, plus 180° when negative.  Indices are computed in
    float32, so a pair within float32 rounding of a cell boundary may land in the neighbouring
    cell.  Cells MERL did not measure (negative) give 0, as :meth:`MerlBrdf.evaluate` does."""

    def __init__(self, brdf) -> None:
        super().__init__()
        self.name = brdf.name
        self.shape = tuple(brdf.values.shape[1:])
        cells = np.clip(brdf.values.reshape(3, -1).T, 0.0, None)  # [n_h * n_d * n_phi, 3], unmeasured -> 0
        self.register_buffer("cells", torch.as_tensor(cells, dtype=torch.float32))

    def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        n_h, n_d, n_phi = self.shape
        h = wi + wo
        h = h / torch.clamp(torch.linalg.vector_norm(h, dim=-1, keepdim=True), min=1e-20)
        sin_h = torch.sqrt(h[:, 0] * h[:, 0] + h[:, 1] * h[:, 1])
        cos_phi_h = torch.where(sin_h > 1e-12, h[:, 0] / torch.clamp(sin_h, min=1e-12), torch.ones_like(sin_h))
        sin_phi_h = torch.where(sin_h > 1e-12, h[:, 1] / torch.clamp(sin_h, min=1e-12), torch.zeros_like(sin_h))
        x1 = cos_phi_h * wi[:, 0] + sin_phi_h * wi[:, 1]
        y1 = cos_phi_h * wi[:, 1] - sin_phi_h * wi[:, 0]
        cos_h = h[:, 2]
        x2 = cos_h * x1 - sin_h * wi[:, 2]
        z2 = sin_h * x1 + cos_h * wi[:, 2]
        degrees = 180.0 / math.pi
        theta_h = torch.acos(torch.clamp(cos_h, -1.0, 1.0)) * degrees
        theta_d = torch.acos(torch.clamp(z2, -1.0, 1.0)) * degrees
        x2 = torch.where(torch.abs(x2) < 1e-30, torch.full_like(x2, 1e-30), x2)
        phi_d = torch.atan(y1 / x2) * degrees
        phi_d = torch.where(phi_d < 0.0, phi_d + 180.0, phi_d)
        i_h = torch.clamp(torch.floor(torch.sqrt(torch.clamp(theta_h, min=0.0) / 90.0 * n_h * n_h)), 0.0, n_h - 1.0)
        i_d = torch.clamp(torch.floor(theta_d / 90.0 * n_d), 0.0, n_d - 1.0)
        i_phi = torch.clamp(torch.floor(phi_d / 180.0 * n_phi), 0.0, n_phi - 1.0)
        f = self.cells[((i_h * n_d + i_d) * n_phi + i_phi).long()]
        return torch.where(above_horizon(wi, wo)[:, None], f, torch.zeros_like(f))


@dataclass(frozen=True)
class Truth:
    """A ground truth: its module on directions, material name, provenance and spectral range."""

    module: nn.Module
    material: str
    provenance: str
    wavelength_range_nm: tuple[float, float] | None

    @property
    def is_spectral(self) -> bool:
        return self.wavelength_range_nm is not None

    def exportable(self) -> Exportable:
        metadata = contract_metadata(
            REFERENCE_KIND, self.material, self.provenance, wavelength_range_nm=self.wavelength_range_nm
        )
        return Exportable(self.module.eval().requires_grad_(False), REFERENCE_KIND, self.material, metadata,
                          self.wavelength_range_nm)


def load_truth(source: str) -> Truth:
    """The truth named by ``source`` (``virtual:NAME`` or an NBRDF ``NAME.h5``; module docstring)."""
    source = str(source)
    if source.startswith(VIRTUAL_PREFIX):
        material = get_material(source[len(VIRTUAL_PREFIX):])
        module = VirtualMaterialTruth(material)
        provenance = (
            f"ground truth {source}: analytic BRDF of neuralbrdf.virtual ({type(material).__name__}), "
            f"spectra tabulated every {TRUTH_STEP_NM:g} nm and interpolated linearly"
        )
        return Truth(module, material.name, provenance, module.wavelength_range_nm)
    path = Path(source)
    if path.suffix == ".binary":
        brdf = MerlBrdf.load(path)
        provenance = (f"ground truth MERL measurement {path.name} (Matusik et al. 2003), nearest cell of its "
                      "90x90x180 table, unmeasured cells 0")
        return Truth(MerlTruth(brdf), brdf.name, provenance, None)
    if path.suffix not in (".h5", ".json"):
        raise InputError(
            f"unknown truth source {source!r}; expected virtual:NAME ({', '.join(MATERIALS)}), an NBRDF "
            "weight file NAME.h5 or a MERL measurement NAME.binary"
        )
    network = NbrdfNetwork.load(path)
    provenance = (
        f"ground truth NBRDF proxy {path.name} (Sztrajman et al. 2021, fit of the MERL material "
        f"{network.name}, Matusik et al. 2003, CC BY-SA 4.0)"
    )
    return Truth(NbrdfTruth(network), network.name, provenance, None)


def export_truth(source: str, out: str | Path) -> ExportReport:
    """Write the truth named by ``source`` to ``out`` as a ``reference`` model (docs/formats.md#onnx-model-files, docs/evaluate.md)."""
    return write_model(load_truth(source).exportable(), out)
