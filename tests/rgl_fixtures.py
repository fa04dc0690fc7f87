"""Small RGL ``.bsdf`` measurements written by the tests, with a closed form to check them against.

A file with uniform ``vndf`` and ``luminance`` warps and ``jacobian = 0`` makes Mitsuba's
``measured`` plugin return the stored table itself, looked up at the half vector ``m`` of the
pair in the frame of ``wi``: ``eval(wi, wo) = f cos θo = T(θi, λ, u_θ(θm), u_φ(φm − φi))`` with
``u_θ = sqrt(2 θm / π)`` and ``u_φ = (φm − φi + π) / 2π`` (``measured.cpp``), interpolated
linearly in every coordinate.  The tables here are products ``c(θi) · s(λ or channel) · h(u_θ)``,
whose multilinear interpolation is the product of the three 1-D interpolations: a closed form
independent of the plugin (:func:`closed_form`).  ``c`` grows with ``θi``, so the data is
deliberately not reciprocal: exchanging ``wi`` and ``wo`` changes the value.
"""

from __future__ import annotations

import numpy as np

from neuralbrdf.data.rgl_bsdf import write_rgl_bsdf

THETA_I_DEG = np.array([0.0, 20.0, 40.0, 55.0, 70.0, 80.0, 90.0])
#: Incident-angle factor: the value grows fivefold from normal to grazing incidence (not reciprocal).
C_THETA = 1.0 + 4.0 * (THETA_I_DEG / 90.0) ** 2
WAVELENGTHS_NM = np.array([380.0, 420.0, 480.0, 550.0, 620.0, 700.0, 760.0])
#: Per band (spectral) or per channel (RGB) factor.
S_SPECTRAL = np.array([0.05, 0.08, 0.20, 0.45, 0.30, 0.25, 0.24])
S_RGB = np.array([0.30, 0.45, 0.12])
#: Nodes of the stored table over ``u_θ`` (last axis) and ``u_φ``.
GRID = 24
#: Width of the glossy lobe in ``θm`` (degrees) and its height over the diffuse floor.
LOBE_DEG = 12.0
LOBE_HEIGHT = 6.0


def lobe(u_theta: np.ndarray) -> np.ndarray:
    theta_m = np.degrees(u_theta**2 * np.pi / 2)
    return 1.0 + LOBE_HEIGHT * np.exp(-((theta_m / LOBE_DEG) ** 2))


def write_closed_form(path, spectral: bool, negative_red: float = 0.0) -> None:
    """The file of the module docstring; ``negative_red`` is subtracted from the red channel of an
    RGB file (colours outside sRGB, as in real RGB files)."""
    u = np.linspace(0.0, 1.0, GRID)
    s = S_SPECTRAL if spectral else S_RGB - np.array([negative_red, 0.0, 0.0])
    table = C_THETA[:, None, None, None] * s[None, :, None, None] * lobe(u)[None, None, None, :]
    table = np.broadcast_to(table, (len(THETA_I_DEG), len(s), GRID, GRID))
    ones = np.ones((2, 16))
    write_rgl_bsdf(path, theta_i_deg=THETA_I_DEG, ndf=ones, sigma=ones, vndf=np.ones((len(THETA_I_DEG), 16, 16)),
                   luminance=np.ones((len(THETA_I_DEG), GRID, GRID)), values=table,
                   wavelengths_nm=WAVELENGTHS_NM if spectral else None,
                   description="closed-form test material", jacobian=False)


def closed_form(wi: np.ndarray, wo: np.ndarray, spectral: bool, wavelengths_nm=None,
                negative_red: float = 0.0) -> np.ndarray:
    """``f(wi, wo)`` in sr⁻¹ of :func:`write_closed_form`'s file, ``wi`` the light: ``[N, W]`` at
    ``wavelengths_nm`` or ``[N, 3]``; not clipped, not masked below the horizon."""
    theta_i = np.degrees(np.arccos(np.clip(wi[:, 2], -1, 1)))
    m = wi + wo
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    u_theta = np.sqrt(np.arccos(np.clip(m[:, 2], -1, 1)) * 2 / np.pi)
    nodes = np.linspace(0.0, 1.0, GRID)
    value = np.interp(theta_i, THETA_I_DEG, C_THETA) * np.interp(u_theta, nodes, lobe(nodes)) / wo[:, 2]
    if spectral:
        return value[:, None] * np.interp(wavelengths_nm, WAVELENGTHS_NM, S_SPECTRAL)[None, :]
    return value[:, None] * (S_RGB - np.array([negative_red, 0.0, 0.0]))[None, :]
