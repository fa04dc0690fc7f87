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
* :class:`MeasuredTruth` — an RGL ``.bsdf`` measurement (Dupuy & Jakob 2018;
  :mod:`neuralbrdf.data.rgl_bsdf`), spectral (400–700 nm) or RGB as the file: Mitsuba's
  ``measured`` plugin resampled on a dense table (:func:`rgl_truth`), its resampling error
  against the plugin measured when it is made and written into the file's metadata.

``SOURCE`` strings name a truth: ``virtual:NAME`` (``gold``, ``gonio``, ``cyan``, ``magenta``,
``munsell_n9``), the path of an NBRDF weight file ``NAME.h5``, of a MERL file ``NAME.binary`` or of
an RGL file ``NAME.bsdf``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from neuralbrdf.data.merl_binary import MerlBrdf
from neuralbrdf.data.calibration import CALIBRATED_WAVELENGTHS_NM
from neuralbrdf.data.nbrdf import DENSE_LAYERS, NbrdfNetwork, nbrdf_input
from neuralbrdf.data.rgl_bsdf import SUFFIX as RGL_SUFFIX
from neuralbrdf.data.rgl_bsdf import RglBsdf
from neuralbrdf.errors import InputError
from neuralbrdf.evaluation.scores import TorchEvaluator, compared_values, hemisphere_pairs
from neuralbrdf.metrics import hemisphere_logcos_rmse
from neuralbrdf.models.baked_table import BakedTable, bake_values
from neuralbrdf.models.directional import LinearInWavelength
from neuralbrdf.models.nlb import above_horizon
from neuralbrdf.onnx_contract import kind_key
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
#: Nodes ``(θh, θd, φd)`` of an RGL measurement's resampled table (``axes="measured"`` of
#: :mod:`neuralbrdf.models.baked_table`), times the report's 31 bands for a spectral file: 1.2 MB
#: (RGB) or 12 MB (spectral) of float32 in the ``.onnx`` file.
RGL_TABLE_NODES = (90, 45, 24)
#: ``(cos θ, φ)`` strata of the pairs on which the resampling is checked against the plugin:
#: (10 · 15)² = 22 500 pairs of :func:`~neuralbrdf.evaluation.scores.hemisphere_pairs`.
RESAMPLING_STRATA = (10, 15)
#: Metadata entries of a resampled measurement (the ``reference`` kind's own, ``neuralbrdf.reference.*``).
RESAMPLING_LOGCOS_KEY = kind_key(REFERENCE_KIND, "resampling_logcos_rmse")
RESAMPLING_MEDIAN_KEY = kind_key(REFERENCE_KIND, "resampling_median_rel_error")
RESAMPLING_PAIRS_KEY = kind_key(REFERENCE_KIND, "resampling_pairs")
TABLE_NODES_KEY = kind_key(REFERENCE_KIND, "table_nodes")


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


class MeasuredTruth(nn.Module):
    """``f(wi, wo[, λ])`` of an RGL measurement: a table of ``f · cos θo`` — the quantity Mitsuba's
    ``measured`` plugin stores and interpolates, smooth up to the horizon — divided by ``cos θo``."""

    def __init__(self, table: BakedTable) -> None:
        super().__init__()
        self.table = table
        self.wavelength_range_nm = table.wavelength_range_nm

    def forward(self, wi: torch.Tensor, wo: torch.Tensor, wavelength: torch.Tensor | None = None) -> torch.Tensor:
        cos_o = torch.clamp(wo[:, 2], min=1e-6)  # the table is 0 at and below the horizon
        f_cos = self.table(wi, wo, wavelength)
        return f_cos / (cos_o if f_cos.ndim == 1 else cos_o[:, None])


@dataclass(frozen=True)
class Truth:
    """A ground truth: its module on directions, material name, provenance, spectral range and
    the ``reference`` kind's own metadata entries (a resampled measurement's nodes and error)."""

    module: nn.Module
    material: str
    provenance: str
    wavelength_range_nm: tuple[float, float] | None
    kind_metadata: dict[str, str] = field(default_factory=dict)

    @property
    def is_spectral(self) -> bool:
        return self.wavelength_range_nm is not None

    def exportable(self) -> Exportable:
        metadata = contract_metadata(
            REFERENCE_KIND, self.material, self.provenance, wavelength_range_nm=self.wavelength_range_nm,
            kind_metadata=self.kind_metadata,
        )
        return Exportable(self.module.eval().requires_grad_(False), REFERENCE_KIND, self.material, metadata,
                          self.wavelength_range_nm)


class _TimesCosine:
    """An evaluator's values times ``cos θo``: what the measured table stores."""

    def __init__(self, evaluator) -> None:
        self.evaluator, self.is_spectral = evaluator, evaluator.is_spectral

    def values(self, wi, wo, wavelength=None):
        f = self.evaluator.values(wi, wo, wavelength)
        return f * (wo[:, 2] if f.ndim == 1 else wo[:, 2:3])


def rgl_truth(path: Path) -> Truth:
    """The truth of an RGL measurement (module docstring): the plugin's ``f · cos θo`` baked at the
    nodes of :data:`RGL_TABLE_NODES` (and the report's 31 bands), checked against the plugin on the
    :data:`RESAMPLING_STRATA` hemisphere pairs."""
    brdf = RglBsdf.load(path)
    bands = CALIBRATED_WAVELENGTHS_NM
    wavelength_range = (float(bands[0]), float(bands[-1])) if brdf.is_spectral else None
    nodes = RGL_TABLE_NODES + ((len(bands),) if brdf.is_spectral else ())
    values = bake_values(_TimesCosine(brdf), nodes, wavelength_range, axes="measured")
    module = MeasuredTruth(BakedTable(torch.as_tensor(values, dtype=torch.float32), wavelength_range, axes="measured"))
    wi, wo = hemisphere_pairs(seed=1, strata=RESAMPLING_STRATA)
    resampled = compared_values(TorchEvaluator(module, brdf.is_spectral), wi, wo, brdf.is_spectral)
    measured = compared_values(brdf, wi, wo, brdf.is_spectral)
    logcos = hemisphere_logcos_rmse(resampled, measured, np.degrees(np.arccos(wi[:, 2])))
    above = measured > 1e-3
    median = float(np.median(np.abs(resampled[above] - measured[above]) / measured[above]))
    shown = " x ".join(str(n) for n in nodes)
    provenance = (
        f"ground truth RGL measurement {path.name} ({brdf.description}; RGL material database, Dupuy & Jakob 2018, "
        f"CC0): Mitsuba's measured plugin resampled on a {shown} table (theta_h, theta_d, phi_d"
        f"{', wavelength' if brdf.is_spectral else ''}), f cos(theta_o) interpolated, negative values clipped to 0; "
        f"hemisphere log-cos RMSE {logcos:.2g} against the plugin on {len(wi)} pairs"
    )
    details = {RESAMPLING_LOGCOS_KEY: f"{logcos:.6g}", RESAMPLING_MEDIAN_KEY: f"{median:.6g}",
               RESAMPLING_PAIRS_KEY: str(len(wi)), TABLE_NODES_KEY: shown}
    return Truth(module, brdf.name, provenance, wavelength_range, details)


def describe_resampling(kind_metadata: dict[str, str]) -> str:
    """One line on a resampled measurement's table and its error against the plugin (from its metadata)."""
    return (f"resampling of Mitsuba's measured plugin on a {kind_metadata[TABLE_NODES_KEY]} table: hemisphere log-cos "
            f"RMSE {float(kind_metadata[RESAMPLING_LOGCOS_KEY]):.2g}, median relative error "
            f"{float(kind_metadata[RESAMPLING_MEDIAN_KEY]):.2g} (values > 1e-3 sr^-1) on "
            f"{kind_metadata[RESAMPLING_PAIRS_KEY]} hemisphere pairs")


def load_truth(source: str) -> Truth:
    """The truth named by ``source`` (module docstring)."""
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
    if path.suffix == RGL_SUFFIX:
        return rgl_truth(path)
    if path.suffix not in (".h5", ".json"):
        raise InputError(
            f"unknown truth source {source!r}; expected virtual:NAME ({', '.join(MATERIALS)}), an NBRDF "
            "weight file NAME.h5, a MERL measurement NAME.binary or an RGL measurement NAME.bsdf"
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
