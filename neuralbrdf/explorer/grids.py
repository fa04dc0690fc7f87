"""The direction pairs each view of the BRDF explorer evaluates (conventions of :mod:`neuralbrdf.geometry`).

Every grid returns unit vectors ``wi, wo`` ``[N, 3]`` in the local frame (``z`` the normal, both
pointing away from the surface) and the coordinates a chart draws them at.  Angles in degrees.

* :func:`plane_slice` — the incident direction at ``θi`` in the plane of incidence (``φi = 0``)
  and outgoing directions along a plane through the normal at azimuth ``φ`` from it: signed
  ``θr`` in the report's in-plane convention (mirror direction at ``θr = θi`` when ``φ = 0``);
* :func:`hemisphere_disk` — the same ``wi`` and every outgoing direction of the hemisphere on a
  square image in the azimuthal equidistant projection: ``(x, y) = θo (cos φo, sin φo)``, so the
  distance from the centre is ``θo``;
* :func:`lobe_grid` — the same ``wi`` and a ``θo × φo`` grid, for the 3-D lobe;
* :func:`half_diff_image` — the Rusinkiewicz ``θh × θd`` image at one ``φd`` (``φh = 0``), the
  MERL / BRDF Explorer view (Burley 2012);
* :func:`lit_sphere` — a unit sphere seen orthographically along ``−z`` by a camera on the ``z``
  axis and lit by a directional light: per pixel the light and view directions in the local frame
  of the sphere's normal there (the tangent the image's ``x`` axis projected onto the surface).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from neuralbrdf.geometry import half_diff_to_vectors, spherical_to_vector

#: Outgoing directions of a plane slice: signed θr every this many degrees in (−90°, 90°).
SLICE_STEP_DEG = 0.5
#: Pixels per side of the hemisphere map and of the lit sphere.
HEMISPHERE_SIZE = 64
SPHERE_SIZE = 64
#: θo × φo nodes of the 3-D lobe.
LOBE_SHAPE = (24, 49)
#: Cells per side of the θh–θd image (1° cells, as MERL's θd axis).
HALF_DIFF_SIZE = 90
#: Sphere pixels this close to the silhouette (in radius) are left out: the normal there grazes the view.
SPHERE_RIM = 0.995


def incident(theta_i: float) -> np.ndarray:
    """``wi`` ``[3]`` at polar angle ``theta_i`` in the plane of incidence (``φi = 0``)."""
    return spherical_to_vector(np.asarray(float(theta_i)), np.asarray(0.0))


def plane_slice(theta_i: float, plane_phi: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(theta_r, wi, wo)``: signed ``θr`` (degrees) and the pairs of the slice (module docstring)."""
    theta_r = np.arange(-90.0 + SLICE_STEP_DEG, 90.0, SLICE_STEP_DEG)
    phi = np.radians(plane_phi)
    s, c = np.sin(np.radians(theta_r)), np.cos(np.radians(theta_r))
    wo = np.stack([-s * np.cos(phi), -s * np.sin(phi), c], axis=1)
    return theta_r, np.broadcast_to(incident(theta_i), wo.shape).copy(), wo


def disk_coordinates(size: int) -> np.ndarray:
    """Pixel centres of a ``size × size`` image over ``[−90°, 90°]²`` (degrees), row-major from ``−90``."""
    return -90.0 + (np.arange(size) + 0.5) * (180.0 / size)


@dataclass(frozen=True)
class Image:
    """Pairs at the pixels of a square image: ``wi, wo`` ``[M, 3]`` at the ``M`` pixels where
    ``inside`` (``[size, size]``, row = y, column = x) is set."""

    wi: np.ndarray
    wo: np.ndarray
    inside: np.ndarray

    def scatter(self, values: np.ndarray, fill=np.nan) -> np.ndarray:
        """``values`` ``[M, ...]`` placed on the image ``[size, size, ...]``, ``fill`` outside."""
        image = np.full(self.inside.shape + values.shape[1:], fill, dtype=np.float64)
        image[self.inside] = values
        return image


def hemisphere_disk(theta_i: float, size: int = HEMISPHERE_SIZE) -> Image:
    """The hemisphere map (module docstring): pixels with ``θo < 90°``."""
    axis = disk_coordinates(size)
    x, y = np.meshgrid(axis, axis)
    theta_o = np.hypot(x, y)
    inside = theta_o < 90.0
    wo = spherical_to_vector(theta_o[inside], np.degrees(np.arctan2(y[inside], x[inside])))
    return Image(np.broadcast_to(incident(theta_i), wo.shape).copy(), wo, inside)


def lobe_grid(theta_i: float, shape: tuple[int, int] = LOBE_SHAPE):
    """``(theta_o, phi_o, wi, wo)``: node angles (degrees) and the pairs ``[n_θ·n_φ, 3]`` (C order)."""
    theta_o = np.linspace(0.0, 89.0, shape[0])
    phi_o = np.linspace(0.0, 360.0, shape[1])
    t, p = np.meshgrid(theta_o, phi_o, indexing="ij")
    wo = spherical_to_vector(t.ravel(), p.ravel())
    return theta_o, phi_o, np.broadcast_to(incident(theta_i), wo.shape).copy(), wo


def half_diff_image(phi_d: float, size: int = HALF_DIFF_SIZE) -> tuple[np.ndarray, Image]:
    """``(axis, image)``: cell centres in degrees (both axes) and the pairs of the ``θh × θd`` image
    (row = θd, column = θh), pairs below the horizon (possible when ``φd ≠ 90°``) left out."""
    axis = (np.arange(size) + 0.5) * (90.0 / size)
    theta_h, theta_d = np.meshgrid(axis, axis)
    wi, wo = half_diff_to_vectors(theta_h.ravel(), theta_d.ravel(), np.full(theta_h.size, float(phi_d)))
    above = ((wi[:, 2] > 0) & (wo[:, 2] > 0)).reshape(theta_h.shape)
    return axis, Image(wi[above.ravel()], wo[above.ravel()], above)


def lit_sphere(light_theta: float, light_phi: float, size: int = SPHERE_SIZE) -> tuple[np.ndarray, Image]:
    """``(axis, image)``: pixel centres on ``[−1, 1]`` and the local light (``wi``) and view (``wo``)
    directions at the sphere's pixels (module docstring).  The light is at polar angle
    ``light_theta`` from the view direction and azimuth ``light_phi`` about it (0° = image right,
    90° = up).  Pixels facing away from the light keep their pairs: ``wi`` is then below the
    horizon and every model gives 0 there."""
    axis = -1.0 + (np.arange(size) + 0.5) * (2.0 / size)
    x, y = np.meshgrid(axis, axis)
    inside = np.hypot(x, y) < SPHERE_RIM
    normal = np.stack([x[inside], y[inside], np.sqrt(1.0 - x[inside] ** 2 - y[inside] ** 2)], axis=1)
    tangent = np.array([1.0, 0.0, 0.0]) - normal[:, :1] * normal
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    bitangent = np.cross(normal, tangent)
    frame = np.stack([tangent, bitangent, normal], axis=1)  # rows: the local axes in world coordinates
    light = spherical_to_vector(np.asarray(float(light_theta)), np.asarray(float(light_phi)))
    view = np.array([0.0, 0.0, 1.0])
    return axis, Image(frame @ light, frame @ view, inside)
