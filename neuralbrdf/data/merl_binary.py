"""MERL ``.binary`` measured BRDF files (Matusik, Pfister, Brand, McMillan 2003, *A data-driven
reflectance model*), the format most measured-BRDF users hold.

Layout (MERL's reference reader ``BRDFRead.cpp``): three little-endian ``int32`` dimensions
``(n_theta_h, n_theta_d, n_phi_d) = (90, 90, 180)``, then ``3 · n`` little-endian doubles, channel
by channel (R, G, B), each channel in ``theta_h``-major, ``theta_d``, ``phi_d``-minor order.
Stored values are scaled per channel: multiply by :data:`CHANNEL_SCALES` (1/1500, 1.15/1500,
1.66/1500) to get the BRDF in sr⁻¹.  Negative cells are MERL's marker for directions the
gonioreflectometer did not measure.

Lookup (:meth:`MerlBrdf.evaluate`) is MERL's own nearest-cell rule on the Rusinkiewicz angles
(:func:`neuralbrdf.geometry.half_diff_angles`, degrees): ``i_h = ⌊sqrt(90 θh)⌋`` (finer cells near
the specular peak), ``i_d = ⌊θd / 90° · 90⌋``, ``i_φ = ⌊(φd mod 180°) / 180° · 180⌋``
(reciprocity: ``φd`` and ``φd + 180°`` are the same cell), each clamped to its range.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from neuralbrdf.atomic import note_input
from neuralbrdf.data.plans import plan_label, plan_spherical
from neuralbrdf.data.table import BrdfTable
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import half_diff_angles, spherical_pair_to_vectors
from neuralbrdf.limits import file_problem

#: MERL's grid ``(theta_h, theta_d, phi_d)`` resolution.
MERL_SHAPE = (90, 90, 180)
#: Stored value × scale = BRDF in sr⁻¹, per channel (R, G, B).
CHANNEL_SCALES = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
HEADER_BYTES = 12


@dataclass(frozen=True, eq=False)
class MerlBrdf:
    """A MERL measurement: ``values`` ``[3, 90, 90, 180]`` in sr⁻¹ (negative: not measured)."""

    name: str
    values: np.ndarray
    source: str = "<memory>"

    @classmethod
    def load(cls, path: str | PathLike[str]) -> MerlBrdf:
        """Read a ``.binary`` file, checking its header against its size before reading the data."""
        path = Path(path)
        if not path.is_file():
            raise InputError(file_problem(path) or "no such MERL .binary file", path=path)
        note_input(path)
        size = path.stat().st_size
        expected_size = HEADER_BYTES + 3 * int(np.prod(MERL_SHAPE)) * 8
        with open(path, "rb") as handle:
            header = np.frombuffer(handle.read(HEADER_BYTES), dtype="<i4")
            if header.size != 3 or tuple(int(v) for v in header) != MERL_SHAPE:
                found = "a truncated header" if header.size != 3 else f"dimensions {header.tolist()}"
                raise InputError(f"not a MERL .binary file: {found}, expected dimensions {list(MERL_SHAPE)}",
                                 path=path)
            if size != expected_size:
                raise InputError(f"MERL .binary file of {size} bytes; its header needs exactly {expected_size}",
                                 path=path)
            data = np.frombuffer(handle.read(), dtype="<f8")
        if not np.all(np.isfinite(data)):
            bad = int(np.argmax(~np.isfinite(data)))
            raise InputError(f"non-finite value at double {bad} of the data", path=path)
        values = data.reshape(3, *MERL_SHAPE) * CHANNEL_SCALES[:, None, None, None]
        return cls(name=path.stem, values=values, source=str(path))

    def cell_indices(self, wi, wo) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """MERL's nearest cell ``(i_h, i_d, i_phi)`` of unit direction pairs ``[N, 3]``."""
        theta_h, _, theta_d, phi_d = half_diff_angles(np.asarray(wi, float), np.asarray(wo, float))
        n_h, n_d, n_phi = MERL_SHAPE
        i_h = np.floor(np.sqrt(np.clip(theta_h, 0.0, None) / 90.0 * n_h * n_h))
        i_d = np.floor(theta_d / 90.0 * n_d)
        i_phi = np.floor(np.mod(phi_d, 180.0) / 180.0 * n_phi)
        return (np.clip(i_h, 0, n_h - 1).astype(int), np.clip(i_d, 0, n_d - 1).astype(int),
                np.clip(i_phi, 0, n_phi - 1).astype(int))

    def evaluate(self, wi, wo) -> np.ndarray:
        """RGB BRDF ``[N, 3]`` in sr⁻¹ (module docstring); 0 below the horizon.

        Cells MERL did not measure (negative) are returned as 0 with one warning giving their count.
        """
        wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
        i_h, i_d, i_phi = self.cell_indices(wi, wo)
        f = self.values[:, i_h, i_d, i_phi].T
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        missing = above[:, None] & (f < 0)
        if missing.any():
            warnings.warn(
                f"{self.source}: {int(missing.any(axis=1).sum())} of {len(f)} direction pairs fall in cells MERL "
                "did not measure (negative values); written as 0",
                stacklevel=2,
            )
        return np.where(above[:, None] & ~missing, f, 0.0)


def sample_merl(brdf: MerlBrdf, plan_name: str) -> BrdfTable:
    """RGB :class:`BrdfTable` of a MERL measurement on a sampling plan of docs/measure.md#sampling-plans."""
    angles = plan_spherical(plan_name)
    values = brdf.evaluate(*spherical_pair_to_vectors(*angles))
    return BrdfTable(*angles, values=values, source=f"merl:{brdf.name}:{plan_label(plan_name)}")


def write_merl(values_sr: np.ndarray, path: str | PathLike[str]) -> None:
    """Write ``values_sr`` ``[3, 90, 90, 180]`` (sr⁻¹; negative = not measured) as a ``.binary`` file."""
    from neuralbrdf.atomic import atomic_path

    values_sr = np.asarray(values_sr, dtype=np.float64)
    if values_sr.shape != (3, *MERL_SHAPE):
        raise ValueError(f"MERL values must have shape {(3, *MERL_SHAPE)}, got {values_sr.shape}")
    stored = np.where(values_sr < 0, values_sr, values_sr / CHANNEL_SCALES[:, None, None, None])
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        handle.write(np.asarray(MERL_SHAPE, dtype="<i4").tobytes())
        handle.write(stored.astype("<f8").tobytes())
