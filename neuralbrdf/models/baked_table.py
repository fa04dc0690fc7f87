"""A model baked into a table over Rusinkiewicz angles, evaluated by multilinear interpolation.

The cheap rung of a model's cost ladder (docs/select.md): any isotropic BRDF tabulated over the
half/difference parametrisation of Rusinkiewicz (1998, *A New Change of Variables for Efficient
BRDF Representation*) — the parametrisation MERL's measured tables use (Matusik et al. 2003) —
and, for spectral models, over wavelength.  A query costs a few dozen arithmetic operations and
``2^D`` table reads (16 for spectral, 8 three-channel reads for RGB), whatever the parent cost.

Table axes, each node grid uniform in its coordinate on ``[0, 1]``:

* ``a_h = (1 − cos θh)^(1/4)`` — ``≈ sqrt(θh / √2)`` near the mirror direction, MERL's
  square-root spacing of ``θh`` that puts nodes where specular lobes change fast;
* ``a_d = cos θd``;
* ``a_p = |cos φd|`` — an isotropic, reciprocal BRDF depends on ``φd`` only through it
  (``f(φd) = f(−φd)`` by isotropy and ``= f(φd + π)`` by reciprocity);
* ``a_λ = (λ − λ_min) / (λ_max − λ_min)``, clamped (spectral tables only).

Measured data (``axes="measured"``: the resampled truth of an RGL measurement,
:mod:`neuralbrdf.evaluation.truth`) is isotropic but not reciprocal — exchanging ``wi`` and ``wo``
changes the value — and its values near retro-reflection (small ``θd``) change as fast as
anywhere, so two axes change: ``a_d = θd / 90°`` (uniform in ``θd``, where ``cos θd`` puts its
first node past 12° at 45 nodes) and ``a_p = (1 + cos φd) / 2`` (``φd`` over ``[0°, 180°]``;
exchanging ``wi`` and ``wo`` maps ``a_p`` to ``1 − a_p``).

All three angles come from ``s = wi + wo`` and ``t = wi − wo`` without ``atan2`` or ``acos``
(unit vectors: ``|s| = 2 cos θd``, ``|t| = 2 sin θd``, so ``θd = atan(|t| / |s|)``): ``cos θh = s_z / |s|``,
``1 − cos θh = sin²θh / (1 + cos θh)`` with ``sin²θh = |s_xy|² / |s|²`` (no cancellation near the
mirror direction), and ``cos φd = (cos θd cos θh − wi_z) / (sin θd sin θh) = −t_z |s| / (|t| |s_xy|)``
(``d``, ``wi`` in the frame of ``h``, has ``φd = 0`` when ``wi`` leans further from the normal than
``h``).

Indices are computed in float32 (exact below 2^24 entries) and cast to integers only to read the
table (ONNX ``Floor``, ``Cast``, ``Gather``; all interpreted by
:mod:`neuralbrdf.render.drjit_onnx`).  ``f = 0`` at or below the horizon, as for every model
(:mod:`neuralbrdf.models.directional`).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import torch
from torch import nn

from neuralbrdf.models.nlb import above_horizon

#: Floor on the denominators of the coordinate formulas (reached only at degenerate pairs: the
#: mirror direction for ``φd``, grazing opposite directions for ``θh``).
_TINY = 1e-20
#: ``|cos φd|`` within this of 1 is taken as 1 (:func:`table_coordinates`).
_PLANE_SNAP = 1e-6
#: Entries a table may hold: float32 indices stay exact below 2^24.
MAX_ENTRIES = 2**24


#: The table parametrisations (module docstring).
AXES = ("reciprocal", "measured")


def _check_axes(axes: str) -> None:
    if axes not in AXES:
        raise ValueError(f"unknown table axes {axes!r}; expected one of {AXES}")


def table_coordinates(wi: torch.Tensor, wo: torch.Tensor,
                      axes: str = "reciprocal") -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(a_h, a_d, a_p)`` in ``[0, 1]`` of unit direction pairs ``[N, 3]`` (module docstring)."""
    _check_axes(axes)
    s, t = wi + wo, wi - wo
    s_xy2 = s[:, 0] * s[:, 0] + s[:, 1] * s[:, 1]
    s2 = torch.clamp(s_xy2 + s[:, 2] * s[:, 2], min=_TINY)
    s_norm = torch.sqrt(s2)
    cos_h = torch.clamp(s[:, 2] / s_norm, 0.0, 1.0)
    one_minus_cos_h = torch.clamp(s_xy2 / s2 / (1.0 + cos_h), 0.0, 1.0)
    a_h = torch.sqrt(torch.sqrt(one_minus_cos_h))
    t_norm = torch.sqrt(t[:, 0] * t[:, 0] + t[:, 1] * t[:, 1] + t[:, 2] * t[:, 2])
    ratio = t[:, 2] * s_norm / torch.clamp(t_norm * torch.sqrt(s_xy2), min=_TINY)  # −cos φd
    # in-plane pairs (cos φd = ±1: every in-plane measurement) sit exactly on the last φd node:
    # onnxruntime rounds this expression ~3e-7 away from PyTorch, which leaks the next node's value in
    ratio = torch.where(ratio > 1.0 - _PLANE_SNAP, 1.0, torch.where(ratio < _PLANE_SNAP - 1.0, -1.0, ratio))
    if axes == "measured":
        a_d = torch.clamp(torch.atan(t_norm / torch.clamp(s_norm, min=_TINY)) * (2.0 / math.pi), 0.0, 1.0)
        return a_h, a_d, torch.clamp(0.5 - 0.5 * ratio, 0.0, 1.0)
    return a_h, torch.clamp(0.5 * s_norm, 0.0, 1.0), torch.clamp(torch.abs(ratio), 0.0, 1.0)


def node_directions(nodes: tuple[int, int, int], axes: str = "reciprocal") -> tuple[np.ndarray, np.ndarray]:
    """``wi, wo`` ``[n_h·n_d·n_p, 3]`` (float64, C order over the three axes) at the table's
    angular nodes: the inverse of :func:`table_coordinates` with ``φh = 0``.  Pairs that reach
    below the horizon are returned as they are (:func:`lifted` moves them up for baking)."""
    _check_axes(axes)
    n_h, n_d, n_p = nodes
    a_h, a_d, a_p = np.meshgrid(*(np.linspace(0.0, 1.0, n) for n in nodes), indexing="ij")
    cos_h = 1.0 - a_h.ravel() ** 4
    sin_h = np.sqrt(np.clip(1.0 - cos_h**2, 0.0, None))
    cos_d = np.cos(a_d.ravel() * np.pi / 2) if axes == "measured" else a_d.ravel()
    sin_d = np.sqrt(np.clip(1.0 - cos_d**2, 0.0, None))
    cos_p = 2.0 * a_p.ravel() - 1.0 if axes == "measured" else a_p.ravel()
    sin_p = np.sqrt(np.clip(1.0 - cos_p**2, 0.0, None))
    d = np.stack([sin_d * cos_p, sin_d * sin_p, cos_d], axis=1)
    # rotate the difference vector by θh about y: the half vector (sin θh, 0, cos θh) becomes its pole
    wi = np.stack([cos_h * d[:, 0] + sin_h * d[:, 2], d[:, 1], -sin_h * d[:, 0] + cos_h * d[:, 2]], axis=1)
    h = np.stack([sin_h, np.zeros_like(sin_h), cos_h], axis=1)
    wo = 2.0 * np.sum(wi * h, axis=1, keepdims=True) * h - wi
    return wi, wo


def lifted(w: np.ndarray, min_z: float = 1e-3) -> np.ndarray:
    """Unit directions with ``z`` raised to at least ``min_z``: nodes below the horizon are baked
    with the value at the horizon, so that interpolation next to it does not blend in zeros."""
    w = np.array(w, dtype=np.float64)
    w[:, 2] = np.maximum(w[:, 2], min_z)
    return w / np.linalg.norm(w, axis=1, keepdims=True)


#: Node pairs evaluated per call of the baked model (bounds the memory of a spectral bake).
CHUNK_PAIRS = 1 << 16


def _values_in_chunks(evaluator, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float | None) -> np.ndarray:
    """``evaluator`` at every pair (at one wavelength for a spectral one), :data:`CHUNK_PAIRS` per call."""
    chunks = []
    for start in range(0, len(wi), CHUNK_PAIRS):
        a, b = wi[start:start + CHUNK_PAIRS], wo[start:start + CHUNK_PAIRS]
        chunks.append(evaluator.values(a, b, None if wavelength_nm is None else np.full(len(a), wavelength_nm)))
    return np.concatenate(chunks)


def bake_values(evaluator, nodes: tuple[int, ...], wavelength_range_nm=None, axes: str = "reciprocal") -> np.ndarray:
    """The values ``[n_h, n_d, n_p, n_λ or 3]`` of ``evaluator`` (anything with ``values(wi, wo,
    wavelength)`` and ``is_spectral``, such as :class:`~neuralbrdf.evaluation.scores.OnnxEvaluator`)
    at the nodes of a table (:func:`node_directions`, :func:`lifted`; ``n_λ`` wavelengths spread
    evenly over ``wavelength_range_nm``)."""
    wi, wo = node_directions(tuple(nodes[:3]), axes)
    wi, wo = lifted(wi), lifted(wo)
    if wavelength_range_nm is None:
        return _values_in_chunks(evaluator, wi, wo, None).reshape(*nodes[:3], 3)
    columns = [_values_in_chunks(evaluator, wi, wo, wavelength)
               for wavelength in np.linspace(*wavelength_range_nm, nodes[3])]
    return np.stack(columns, axis=-1).reshape(*nodes[:3], nodes[3])


class BakedTable(nn.Module):
    """``f(wi, wo[, λ])`` by multilinear interpolation in ``values`` (module docstring).

    ``values``: ``[n_h, n_d, n_p, n_λ]`` (spectral, ``wavelength_range_nm`` given) or
    ``[n_h, n_d, n_p, 3]`` (linear sRGB), BRDF in sr⁻¹ at the nodes; every axis but the channel
    axis of an RGB table needs at least 2 nodes.  ``axes``: ``"reciprocal"`` or ``"measured"``
    (module docstring).
    """

    def __init__(self, values: torch.Tensor, wavelength_range_nm: tuple[float, float] | None = None,
                 axes: str = "reciprocal") -> None:
        super().__init__()
        values = torch.as_tensor(values, dtype=torch.float32)
        spectral = wavelength_range_nm is not None
        if values.ndim != 4 or (not spectral and values.shape[3] != 3):
            raise ValueError(f"table values must be [n_h, n_d, n_p, n_λ or 3], got {list(values.shape)}")
        interpolated = values.shape if spectral else values.shape[:3]
        if min(interpolated) < 2 or values.numel() > MAX_ENTRIES:
            raise ValueError(f"every interpolated axis needs >= 2 nodes and the table <= {MAX_ENTRIES} "
                             f"entries, got {list(values.shape)}")
        if not torch.isfinite(values).all() or (values < 0).any():
            raise ValueError("table values must be finite and >= 0")
        self.nodes = tuple(int(n) for n in interpolated)
        _check_axes(axes)
        self.axes = axes
        self.wavelength_range_nm = None if not spectral else tuple(float(x) for x in wavelength_range_nm)
        self.register_buffer("flat", values.reshape(-1) if spectral else values.reshape(-1, 3))
        # strides of the interpolated axes in the flat table (RGB: rows of 3 channels)
        self.strides = tuple(int(math.prod(self.nodes[k + 1:])) for k in range(len(self.nodes)))

    def forward(self, wi: torch.Tensor, wo: torch.Tensor, wavelength: torch.Tensor | None = None) -> torch.Tensor:
        coordinates = list(table_coordinates(wi, wo, self.axes))
        if self.wavelength_range_nm is not None:
            low, high = self.wavelength_range_nm
            coordinates.append((wavelength - low) / (high - low))
        base, fractions = torch.zeros_like(coordinates[0]), []
        for u, n, stride in zip(coordinates, self.nodes, self.strides):
            x = torch.clamp(u, 0.0, 1.0) * (n - 1)
            i = torch.clamp(torch.floor(x), 0.0, n - 2)
            base = base + i * stride
            fractions.append(x - i)
        f = None
        for corner in itertools.product((0, 1), repeat=len(self.nodes)):
            offset = sum(b * stride for b, stride in zip(corner, self.strides))
            weight = None
            for b, fraction in zip(corner, fractions):
                w = fraction if b else 1.0 - fraction
                weight = w if weight is None else weight * w
            value = self.flat[(base + offset).long()]
            term = value * (weight if self.wavelength_range_nm is not None else weight.unsqueeze(-1))
            f = term if f is None else f + term
        mask = above_horizon(wi, wo)
        return torch.where(mask if self.wavelength_range_nm is not None else mask.unsqueeze(-1), f, torch.zeros_like(f))
