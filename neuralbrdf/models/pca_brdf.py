"""A PCA prior over measured BRDFs (Nielsen, Jensen & Ramamoorthi 2015, *On optimal, minimal BRDF
sampling for reflectance acquisition*, ACM TOG 34(6)), on the grid of a
:class:`~neuralbrdf.models.baked_table.BakedTable` (docs/models.md#pca).

**The basis.**  Every colour channel of every training material (:func:`training_proxies`: the
MERL and RGL NBRDF proxies outside :data:`~neuralbrdf.data.proxy_corpus.NEVER_PRETRAINED`) is one
monochrome BRDF: its values at the table's nodes (:func:`~neuralbrdf.models.baked_table.node_directions`,
lifted to the horizon as a baked table's are) are mapped to ``y = ln(1 + f)`` (``mapping
"log1p"``) or to Nielsen et al.'s ``y = ln(f cos θi cos θo + ε)`` (``"nielsen"``; their reference
BRDF's term is a fixed per-node offset, which the mean absorbs), and the principal components of
those vectors are the basis (:func:`build_basis`).  A channel, not a material, is one sample: one
basis serves the three channels of an RGB measurement and the bands of a spectral one.

**A material.**  Each channel ``j`` is ``y_j = μ + Σ_k c_jk b_k`` at the nodes, clipped to the
training set's range of ``y``.  The model (:class:`PcaTable`, made by :func:`pca_table`) reads
``y`` by the multilinear interpolation of a :class:`~neuralbrdf.models.baked_table.BakedTable` —
three channels for RGB, one column per wavelength node for spectral tables — and turns it back
into ``f`` (``expm1(y)``, or ``(e^y − ε) / (cos θi cos θo)``, ``≥ 0``; 0 below the horizon).
Interpolating ``y`` rather than ``f`` keeps the model linear in the coefficients at every pair, so
the fit below minimises the exported model's own error; interpolating ``f`` between nodes of a
sharp lobe overshoots its flank (midway between nodes of 10⁴ and 10² sr⁻¹: 5·10³ against the
10³ of interpolated logarithms).

**The fit** (:func:`fit_channels`).  The basis interpolated at the measured pairs (the table's own
multilinear weights, :func:`interpolation`) is the design matrix ``Φ`` ``[N, K]``; each channel's
coefficients minimise ``‖Φ c − (y − μ)‖² + λ Σ_k (c_k / s_k)²`` (:func:`ridge_coefficients`), ``s_k``
the standard deviation of the training channels' ``k``-th coefficient: the MAP estimate under
the training set's Gaussian prior, ``λ`` the variance of the mapped residual it is traded against.
With few pairs (six in DS4) the prior decides the components the pairs do not see.
"""

from __future__ import annotations

import hashlib
import io
import itertools
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from neuralbrdf.errors import InputError
from neuralbrdf.models.baked_table import BakedTable, lifted, node_directions, table_coordinates
from neuralbrdf.models.nlb import above_horizon
from neuralbrdf.shipped import PRETRAINED_DIR

#: The shipped basis (``benchmarks/pca_basis.py`` writes it).
BASIS_FILE = PRETRAINED_DIR / "pca_basis.npz"
#: The value mappings (module docstring).
MAPPINGS = ("log1p", "nielsen")
#: Version of the ``.npz`` layout.
FORMAT_VERSION = 1
_KEYS = ("format_version", "nodes", "mapping", "epsilon", "mean", "components", "scales",
         "explained_variance_ratio", "value_range", "materials")


# --------------------------------------------------------------------------- the mapping


def node_cosines(nodes: tuple[int, int, int]) -> np.ndarray:
    """``cos θi cos θo`` ``[P]`` at the table's (lifted) nodes."""
    wi, wo = node_directions(nodes)
    return lifted(wi)[:, 2] * lifted(wo)[:, 2]


def to_mapped(f: np.ndarray, cosines: np.ndarray, mapping: str, epsilon: float) -> np.ndarray:
    """``y`` of BRDF values ``f`` ``[..., C]`` (rows with ``cosines`` ``[...]``; module docstring)."""
    f = np.clip(np.asarray(f, dtype=np.float64), 0.0, None)
    if mapping == "log1p":
        return np.log1p(f)
    return np.log(f * np.asarray(cosines, dtype=np.float64)[..., None] + epsilon)


def from_mapped(y: np.ndarray, cosines: np.ndarray, mapping: str, epsilon: float) -> np.ndarray:
    """``f ≥ 0`` of mapped values ``y`` ``[..., C]`` (the inverse of :func:`to_mapped`)."""
    y = np.asarray(y, dtype=np.float64)
    if mapping == "log1p":
        return np.clip(np.expm1(y), 0.0, None)
    return np.clip((np.exp(y) - epsilon) / np.asarray(cosines, dtype=np.float64)[..., None], 0.0, None)


# --------------------------------------------------------------------------- the basis


@dataclass(frozen=True, eq=False)
class PcaBasis:
    """A PCA basis over a table grid (module docstring).

    ``mean`` ``[P]`` and ``components`` ``[K, P]`` (orthonormal rows) are mapped values at the
    ``nodes`` (``P = n_h n_d n_p``, C order); ``scales`` ``[K]`` the standard deviation of the
    training channels' coefficients; ``explained_variance_ratio`` ``[K]`` each component's share
    of the training set's variance; ``value_range`` the lowest and highest mapped value of the
    training set (a fitted material's nodes are clipped to it); ``materials`` the training
    materials (``<lab>:<name>``).
    """

    nodes: tuple[int, int, int]
    mapping: str
    epsilon: float
    mean: np.ndarray
    components: np.ndarray
    scales: np.ndarray
    explained_variance_ratio: np.ndarray
    value_range: tuple[float, float]
    materials: tuple[str, ...]
    sha256: str = ""
    source: str = "<memory>"

    @property
    def n_components(self) -> int:
        return int(self.components.shape[0])

    def truncated(self, k: int) -> PcaBasis:
        """The first ``k`` components (``1 ≤ k ≤`` :attr:`n_components`)."""
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= self.n_components:
            raise InputError(f"expected a number of components from 1 to {self.n_components} (the basis holds "
                             f"{self.n_components}), got {k!r}", path=self.source, key="components")
        k = int(k)
        return PcaBasis(self.nodes, self.mapping, self.epsilon, self.mean, self.components[:k], self.scales[:k],
                        self.explained_variance_ratio[:k], self.value_range, self.materials, self.sha256, self.source)

    def arrays(self) -> dict[str, np.ndarray]:
        """The ``.npz`` entries (:func:`save_basis`)."""
        return {
            "format_version": np.array(FORMAT_VERSION),
            "nodes": np.array(self.nodes, dtype=np.int64),
            "mapping": np.array(self.mapping),
            "epsilon": np.array(float(self.epsilon)),
            "mean": np.asarray(self.mean, dtype=np.float32),
            "components": np.asarray(self.components, dtype=np.float32),
            "scales": np.asarray(self.scales, dtype=np.float64),
            "explained_variance_ratio": np.asarray(self.explained_variance_ratio, dtype=np.float64),
            "value_range": np.asarray(self.value_range, dtype=np.float64),
            "materials": np.array(self.materials),
        }


def save_basis(basis: PcaBasis, path: str | os.PathLike[str]) -> str:
    """Write ``basis`` as a compressed ``.npz`` at ``path``; returns the file's sha256."""
    from neuralbrdf.atomic import atomic_write

    buffer = io.BytesIO()
    np.savez_compressed(buffer, **basis.arrays())
    data = buffer.getvalue()
    with atomic_write(Path(path), mode="wb") as handle:
        handle.write(data)
    return hashlib.sha256(data).hexdigest()


_LOADED: dict[tuple[str, int, int], PcaBasis] = {}


def load_basis(path: str | os.PathLike[str] | None = None) -> PcaBasis:
    """The basis of ``path`` (``None``: the shipped :data:`BASIS_FILE`), checked: every entry
    present, shapes agreeing, values finite, components orthonormal; :class:`InputError` naming
    the file and the entry otherwise.  Loaded once per file version."""
    path = Path(BASIS_FILE if path is None else path)
    if not path.is_file():
        raise InputError("PCA basis file not found (python benchmarks/pca_basis.py writes the shipped one)", path=path)
    stat = path.stat()
    cache_key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    if cache_key in _LOADED:
        return _LOADED[cache_key]
    data = path.read_bytes()
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            entries = {key: npz[key] for key in npz.files}
    except (OSError, ValueError) as error:
        raise InputError(f"not a PCA basis .npz ({error})", path=path) from None
    missing = [key for key in _KEYS if key not in entries]
    if missing:
        raise InputError(f"PCA basis lacks entries {missing}", path=path)
    if int(entries["format_version"]) != FORMAT_VERSION:
        raise InputError(f"format version {int(entries['format_version'])}, expected {FORMAT_VERSION}", path=path,
                         key="format_version")
    nodes = tuple(int(n) for n in entries["nodes"])
    mapping = str(entries["mapping"])
    mean = entries["mean"].astype(np.float64)
    components = entries["components"].astype(np.float64)
    scales = entries["scales"].astype(np.float64)
    ratio = entries["explained_variance_ratio"].astype(np.float64)
    value_range = tuple(float(v) for v in entries["value_range"])
    if len(nodes) != 3 or min(nodes) < 2:
        raise InputError(f"expected three node counts >= 2, got {list(nodes)}", path=path, key="nodes")
    if mapping not in MAPPINGS:
        raise InputError(f"unknown mapping {mapping!r}; expected one of {list(MAPPINGS)}", path=path, key="mapping")
    n_nodes = int(np.prod(nodes))
    for key, array, shape in (("mean", mean, (n_nodes,)), ("components", components, (len(scales), n_nodes)),
                              ("explained_variance_ratio", ratio, scales.shape), ("value_range", value_range, (2,))):
        if np.shape(array) != shape:
            raise InputError(f"expected shape {list(shape)}, got {list(np.shape(array))}", path=path, key=key)
    for key in ("mean", "components", "scales", "explained_variance_ratio", "value_range", "epsilon"):
        if not np.all(np.isfinite(entries[key])):
            raise InputError("holds non-finite values", path=path, key=key)
    if len(scales) == 0 or np.any(scales <= 0):
        raise InputError("expected one positive scale per component", path=path, key="scales")
    gram = components @ components.T
    if not np.allclose(gram, np.eye(len(scales)), atol=1e-4):
        raise InputError(f"components are not orthonormal (largest deviation {np.abs(gram - np.eye(len(scales))).max():.3g})",
                         path=path, key="components")
    basis = PcaBasis(nodes, mapping, float(entries["epsilon"]), mean, components, scales, ratio, value_range,
                     tuple(str(m) for m in entries["materials"]), hashlib.sha256(data).hexdigest(), str(path))
    _LOADED[cache_key] = basis
    return basis


def training_proxies(data_dirs: Sequence[str | os.PathLike[str]]) -> list[tuple[str, Path]]:
    """``(<lab>:<name>, file)`` of every proxy of ``data_dirs`` a prior may be built from: all but
    :data:`~neuralbrdf.data.proxy_corpus.NEVER_PRETRAINED`."""
    from neuralbrdf.data.proxy_corpus import lab_of, pretraining_proxy_names

    return [(f"{lab_of(folder)}:{name}", Path(folder) / f"{name}.h5")
            for folder in data_dirs for name in pretraining_proxy_names(folder)]


def proxy_node_values(file: str | os.PathLike[str], nodes: tuple[int, int, int]) -> np.ndarray:
    """An NBRDF proxy's RGB values ``[P, 3]`` at the table's lifted nodes."""
    from neuralbrdf.data.nbrdf import NbrdfNetwork

    wi, wo = node_directions(nodes)
    return NbrdfNetwork.load(file).evaluate(lifted(wi), lifted(wo))


def build_basis(channels: np.ndarray, materials: Sequence[str], nodes: tuple[int, int, int], n_components: int,
                mapping: str = "log1p", epsilon: float = 1e-3) -> PcaBasis:
    """The PCA basis of BRDF channels ``[S, P]`` (sr⁻¹ at the nodes, one row per channel of a
    training material) in ``mapping`` (module docstring), keeping ``n_components``."""
    if mapping not in MAPPINGS:
        raise ValueError(f"unknown mapping {mapping!r}; expected one of {MAPPINGS}")
    channels = np.asarray(channels, dtype=np.float64)
    mapped = to_mapped(channels.T, node_cosines(nodes), mapping, epsilon).T  # [S, P]
    mean = mapped.mean(axis=0)
    _, singular, vt = np.linalg.svd(mapped - mean, full_matrices=False)
    if not 1 <= n_components <= len(singular):
        raise ValueError(f"n_components must lie in 1..{len(singular)}, got {n_components}")
    variance = singular**2 / len(mapped)
    vt = vt[:n_components]
    vt = vt * np.where(vt[np.arange(n_components), np.abs(vt).argmax(axis=1)] < 0, -1.0, 1.0)[:, None]  # fixed signs
    return PcaBasis(tuple(int(n) for n in nodes), mapping, float(epsilon), mean, vt,
                    np.sqrt(variance[:n_components]), variance[:n_components] / variance.sum(),
                    (float(mapped.min()), float(mapped.max())), tuple(materials))


# --------------------------------------------------------------------------- the fit


def interpolation(nodes: tuple[int, ...], wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The flat node indices ``[N, 8]`` and weights ``[N, 8]`` a
    :class:`~neuralbrdf.models.baked_table.BakedTable` over ``nodes`` interpolates pairs
    ``wi, wo`` ``[N, 3]`` with (its coordinates and corners, in float64)."""
    coordinates = table_coordinates(torch.as_tensor(np.asarray(wi, dtype=np.float64)),
                                    torch.as_tensor(np.asarray(wo, dtype=np.float64)))
    strides = [int(np.prod(nodes[k + 1:])) for k in range(3)]
    base = np.zeros(len(wi), dtype=np.int64)
    fractions = []
    for u, n, stride in zip(coordinates, nodes, strides):
        x = np.clip(u.numpy(), 0.0, 1.0) * (n - 1)
        i = np.clip(np.floor(x), 0.0, n - 2)
        base += i.astype(np.int64) * stride
        fractions.append(x - i)
    index, weight = [], []
    for corner in itertools.product((0, 1), repeat=3):
        index.append(base + sum(b * s for b, s in zip(corner, strides)))
        weight.append(np.prod([f if b else 1.0 - f for b, f in zip(corner, fractions)], axis=0))
    return np.stack(index, axis=1), np.stack(weight, axis=1)


def design_matrix(basis: PcaBasis, wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(μ(x) [N], Φ [N, K])``: the mean and the components interpolated at the pairs."""
    index, weight = interpolation(basis.nodes, wi, wo)
    mean = np.sum(basis.mean[index] * weight, axis=1)
    design = np.einsum("nc,knc->nk", weight, basis.components[:, index])
    return mean, design


def ridge_coefficients(design: np.ndarray, targets: np.ndarray, scales: np.ndarray, ridge: float) -> np.ndarray:
    """``[C, K]``: per column ``j`` of ``targets`` ``[N, C]``, ``argmin ‖Φ c − t_j‖² + ridge Σ (c_k / s_k)²``
    (normal equations; ``ridge = 0``: the least-squares solution of least norm)."""
    if ridge == 0.0:
        return np.linalg.lstsq(design, targets, rcond=None)[0].T
    gram = design.T @ design + ridge * np.diag(1.0 / np.asarray(scales, dtype=np.float64) ** 2)
    return np.linalg.solve(gram, design.T @ targets).T


def fit_channels(basis: PcaBasis, wi: np.ndarray, wo: np.ndarray, values: np.ndarray, ridge: float,
                 source: str = "<memory>") -> np.ndarray:
    """The coefficients ``[C, K]`` of each channel of BRDF samples ``values`` ``[N, C]`` (sr⁻¹) at
    pairs ``wi, wo`` (module docstring).  Pairs at or below the horizon carry no information
    (``f = 0`` there by definition) and are left out.  :class:`InputError` naming ``source`` when no
    pair is above the horizon, a value is not finite or ``ridge`` is not a finite number ``≥ 0``;
    :class:`ValueError` when the solution is not finite."""
    if isinstance(ridge, bool) or not isinstance(ridge, (int, float)) or not np.isfinite(ridge) or ridge < 0:
        raise InputError(f"the ridge weight must be a finite number >= 0, got {ridge!r}", key="ridge")
    wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 2 or len(values) != len(wi):
        raise InputError(f"expected values [N, C] for {len(wi)} direction pairs, got shape {list(values.shape)}",
                         path=source)
    if not np.all(np.isfinite(values)):
        raise InputError(f"{int(np.sum(~np.isfinite(values)))} BRDF value(s) are not finite; a PCA fit needs finite "
                         "samples", path=source)
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0) if len(wi) else np.zeros(0, dtype=bool)
    if not np.any(above):
        raise InputError("no sample above the horizon to fit the PCA coefficients to", path=source)
    wi, wo, values = wi[above], wo[above], values[above]
    mean, design = design_matrix(basis, wi, wo)
    cosines = wi[:, 2] * wo[:, 2]
    targets = to_mapped(values, cosines, basis.mapping, basis.epsilon) - mean[:, None]
    coefficients = ridge_coefficients(design, targets, basis.scales, float(ridge))
    if not np.all(np.isfinite(coefficients)):
        raise ValueError(f"the ridge solution is not finite ({int(np.sum(~np.isfinite(coefficients)))} coefficients)")
    return coefficients


def mapped_nodes(basis: PcaBasis, coefficients: np.ndarray) -> np.ndarray:
    """``y`` ``[P, C]`` at the nodes of channels with ``coefficients`` ``[C, K]``, clipped to the
    training set's :attr:`~PcaBasis.value_range`."""
    y = basis.mean[:, None] + basis.components[: coefficients.shape[1]].T @ np.asarray(coefficients, dtype=np.float64).T
    return np.clip(y, *basis.value_range)


def node_values(basis: PcaBasis, coefficients: np.ndarray) -> np.ndarray:
    """BRDF values ``[n_h, n_d, n_p, C]`` (sr⁻¹, ``≥ 0``) at the nodes of channels with ``coefficients``."""
    f = from_mapped(mapped_nodes(basis, coefficients), node_cosines(basis.nodes), basis.mapping, basis.epsilon)
    return f.reshape(*basis.nodes, f.shape[1])


#: Floor of ``cos θi cos θo`` under the ``nielsen`` mapping's division (directions at the horizon).
_COSINE_FLOOR = 1e-6


class PcaTable(nn.Module):
    """``f(wi, wo[, λ])`` of a fitted material: its mapped values ``y`` read by a
    :class:`~neuralbrdf.models.baked_table.BakedTable`, then unmapped (module docstring).

    ``mapped``: ``[n_h, n_d, n_p, 3]`` (RGB) or ``[n_h, n_d, n_p, n_λ]`` (spectral, with
    ``wavelength_range_nm``), finite; stored less ``offset`` (their minimum when negative), since a
    table holds values ``≥ 0``.
    """

    def __init__(self, mapped, wavelength_range_nm: tuple[float, float] | None = None, mapping: str = "log1p",
                 epsilon: float = 1e-3) -> None:
        super().__init__()
        if mapping not in MAPPINGS:
            raise ValueError(f"unknown mapping {mapping!r}; expected one of {MAPPINGS}")
        mapped = torch.as_tensor(mapped, dtype=torch.float32)
        if not torch.isfinite(mapped).all():
            raise ValueError("the mapped table values must be finite")
        self.mapping, self.epsilon = mapping, float(epsilon)
        self.offset = min(0.0, float(mapped.min()))
        self.table = BakedTable(mapped - self.offset, wavelength_range_nm)
        self.nodes = self.table.nodes
        self.wavelength_range_nm = self.table.wavelength_range_nm

    @property
    def mapped(self) -> torch.Tensor:
        """The mapped values ``[n_h, n_d, n_p, C]`` the model holds."""
        return self.table.flat.reshape(*self.table.nodes[:3], -1) + self.offset

    def forward(self, wi: torch.Tensor, wo: torch.Tensor, wavelength: torch.Tensor | None = None) -> torch.Tensor:
        y = self.table(wi, wo, wavelength)
        if self.offset:
            y = y + self.offset
        if self.mapping == "log1p":
            f = torch.expm1(y)  # 0 below the horizon already: the table gives y = 0 there
        else:
            cosines = torch.clamp(wi[:, 2] * wo[:, 2], min=_COSINE_FLOOR)
            f = (torch.exp(y) - self.epsilon) / (cosines if self.wavelength_range_nm is not None else cosines[:, None])
        f = torch.clamp(f, min=0.0)
        if self.mapping == "log1p" and not self.offset:
            return f
        mask = above_horizon(wi, wo)
        return torch.where(mask if self.wavelength_range_nm is not None else mask.unsqueeze(-1), f, torch.zeros_like(f))


def pca_table(basis: PcaBasis, coefficients: np.ndarray,
              wavelength_range_nm: tuple[float, float] | None = None) -> PcaTable:
    """The fitted material as a :class:`PcaTable`: three channels (RGB) or, with
    ``wavelength_range_nm``, one column per wavelength node spread evenly over it."""
    coefficients = np.asarray(coefficients, dtype=np.float64)
    if wavelength_range_nm is None and coefficients.shape[0] != 3:
        raise ValueError(f"an RGB table needs 3 channels of coefficients, got {coefficients.shape[0]}")
    mapped = mapped_nodes(basis, coefficients).reshape(*basis.nodes, coefficients.shape[0])
    return PcaTable(mapped, wavelength_range_nm, basis.mapping, basis.epsilon)
