"""The BRDF sample table, the project's one interchange format (SPEC §2.1).

CSV with a header: ``theta_i, phi_i, theta_o, phi_o`` (degrees, spherical, SPEC §1), then
either ``R, G, B`` (linear sRGB, sr⁻¹) or one column per wavelength named by its value in nm,
and an optional ``weight`` column.  One row per direction pair.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

RGB_CHANNELS = ("R", "G", "B")
ANGLE_COLUMNS = ("theta_i", "phi_i", "theta_o", "phi_o")


@dataclass
class BrdfTable:
    """BRDF samples at direction pairs.

    Attributes
    ----------
    theta_i, phi_i, theta_o, phi_o:
        Spherical angles in degrees, shape ``[N]`` (float64).
    values:
        BRDF in sr⁻¹, shape ``[N, C]`` (float64), never multiplied by a cosine.
    wavelengths:
        ``None`` for RGB tables (``C == 3``, channels R, G, B), else the wavelengths in nm of
        the ``C`` spectral columns (float64, ``[C]``).
    weight:
        Optional per-row weight ``[N]``.
    source:
        Where the table came from (a path or a description), for error messages.
    """

    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    values: np.ndarray
    wavelengths: np.ndarray | None = None
    weight: np.ndarray | None = None
    source: str = field(default="<memory>")
