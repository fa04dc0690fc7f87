"""GCMS raw measurements (SPEC §2.2; report §2.1.1 and §3.2).

What a Murakami GCMS-3B style goniospectrophotometer exports: CSV with signed in-plane
``theta_i, theta_r`` (degrees, SPEC §1) and one column per wavelength 390–730 nm at 10 nm
(35 bands) holding the radiance factor beta (unitless).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

GCMS_WAVELENGTHS_NM = np.arange(390.0, 731.0, 10.0)


@dataclass
class GcmsMeasurement:
    """One GCMS raw file.

    Attributes
    ----------
    theta_i, theta_r:
        Signed in-plane angles in degrees, shape ``[N]``.
    beta:
        Radiance factor (unitless) ``[N, 35]`` at :data:`GCMS_WAVELENGTHS_NM`.
    source:
        Path or description for error messages.
    """

    theta_i: np.ndarray
    theta_r: np.ndarray
    beta: np.ndarray
    source: str = field(default="<memory>")

    @property
    def wavelengths(self) -> np.ndarray:
        return GCMS_WAVELENGTHS_NM
