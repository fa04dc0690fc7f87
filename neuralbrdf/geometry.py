"""Direction conventions and BRDF parameterisations (docs/formats.md#conventions).

Local shading frame with ``z`` the surface normal; both directions point *away* from the
surface (``wi`` toward the light, ``wo`` toward the viewer).  Three ways to name a direction
pair are used throughout the project:

* **unit vectors** ``wi, wo`` of shape ``[..., 3]``;
* **spherical angles** ``theta`` in [0°, 90°] from the normal, ``phi`` in [0°, 360°);
* **signed in-plane angles** ``(theta_i, theta_r)`` in [-90°, 90°], the convention of the
  report (S. Chitnis, *Simplifying BRDF Acquisition*, §4.1.2): ``wi = (sin ti, 0, cos ti)``,
  ``wo = (-sin tr, 0, cos tr)``, so the mirror direction is ``theta_r = theta_i``.

The Rusinkiewicz (1998) half/difference parameterisation gives, for any pair, the angles
``theta_h, theta_d`` and an *in-plane equivalent* ``ti = theta_d + theta_h``,
``tr = theta_d - theta_h`` with the same ``theta_h, theta_d`` (the bivariate approximation of
isotropic BRDFs, Romeiro et al. 2008).  For an in-plane pair ``theta_h = |ti - tr| / 2`` and
``theta_d = |ti + tr| / 2``.

Every function is vectorised and works on NumPy arrays and PyTorch tensors alike (through the
array API, :mod:`array_api_compat`); torch inputs keep their autograd graph.  Angles are in
degrees at this module's boundary unless a name ends in ``_rad``.
"""

from __future__ import annotations

import math

from array_api_compat import array_namespace

DEG = math.pi / 180.0

#: ``sin theta_h`` below which a pair counts as the mirror configuration (about 2e-4°).
MIRROR_SIN_THETA_H = 3e-6


def array_namespace_of(*arrays):
    """The array-API namespace (NumPy or torch) of ``arrays``; Python scalars are ignored."""
    return array_namespace(*[a for a in arrays if not isinstance(a, (int, float))])



def _stack3(xp, x, y, z):
    return xp.stack([x, y, z], axis=-1)


def _clip_unit(xp, c):
    return xp.clip(c, -1.0, 1.0)


def normalize(v):
    """Scale vectors ``[..., 3]`` to unit length."""
    xp = array_namespace_of(v)
    return v / xp.linalg.vector_norm(v, axis=-1, keepdims=True)


def dot(a, b):
    """Row-wise dot product of ``[..., 3]`` arrays, shape ``[...]``."""
    return (a * b).sum(-1)


def spherical_to_vector(theta_deg, phi_deg):
    """Unit vector ``[..., 3]`` from polar ``theta`` and azimuth ``phi`` (degrees)."""
    xp = array_namespace_of(theta_deg, phi_deg)
    t = theta_deg * DEG
    p = phi_deg * DEG
    st = xp.sin(t)
    return _stack3(xp, st * xp.cos(p), st * xp.sin(p), xp.cos(t))


def vector_to_spherical(v):
    """``(theta, phi)`` in degrees of vectors ``[..., 3]``; ``phi`` in [0, 360), 0 at the pole.

    Vectors need not be normalised.
    """
    xp = array_namespace_of(v)
    v = normalize(v)
    theta = xp.acos(_clip_unit(xp, v[..., 2])) / DEG
    phi = xp.atan2(v[..., 1], v[..., 0]) / DEG
    phi = xp.where(phi < 0, phi + 360.0, phi)
    # atan2 can round -tiny to exactly 360 after the shift; keep the half-open range.
    phi = xp.where(phi >= 360.0, phi - 360.0, phi)
    return theta, phi


def inplane_to_vectors(theta_i_deg, theta_r_deg):
    """``(wi, wo)`` for signed in-plane angles (degrees): the report's convention, docs/formats.md#conventions."""
    xp = array_namespace_of(theta_i_deg, theta_r_deg)
    ti = theta_i_deg * DEG
    tr = theta_r_deg * DEG
    zero_i = xp.zeros_like(ti)
    zero_r = xp.zeros_like(tr)
    wi = _stack3(xp, xp.sin(ti), zero_i, xp.cos(ti))
    wo = _stack3(xp, -xp.sin(tr), zero_r, xp.cos(tr))
    return wi, wo


def inplane_to_spherical(theta_i_deg, theta_r_deg):
    """Spherical ``(theta_i, phi_i, theta_o, phi_o)`` (degrees) of a signed in-plane pair.

    These are the exact spherical angles of :func:`inplane_to_vectors`: ``phi_i = 0`` for
    ``theta_i >= 0`` and ``180°`` for ``theta_i < 0``; ``phi_o = 180°`` for ``theta_r > 0`` and
    ``0`` otherwise.  So ``phi_o - phi_i = 180°`` exactly when ``theta_r`` has the sign of
    ``theta_i``, as docs/formats.md#conventions states.  The report also rotates every pair to
    ``phi_i = 0`` (its §4.1.2), which is
    equivalent for isotropic BRDFs but loses the sign of ``theta_i``; we keep it, because the
    spectral MLP's train/test split (report Table 5.1) is asymmetric in ``theta_i``.
    :func:`spherical_to_inplane` reads both forms.
    """
    xp = array_namespace_of(theta_i_deg, theta_r_deg)
    theta_i = xp.abs(theta_i_deg)
    theta_o = xp.abs(theta_r_deg)
    phi_i = xp.where(theta_i_deg < 0, 180.0, 0.0) + xp.zeros_like(theta_i)
    phi_o = xp.where(theta_r_deg > 0, 180.0, 0.0) + xp.zeros_like(theta_o)
    return theta_i, phi_i, theta_o, phi_o


#: Largest ``|y|`` of a unit direction still taken as lying in the plane of incidence (x-z).
IN_PLANE_TOLERANCE = 1e-9


def in_plane_of_incidence(wi, wo):
    """True where ``wi``, ``wo`` and the normal are coplanar: ``|n · (wi × wo)| <= 1e-9``."""
    xp = array_namespace_of(wi, wo)
    return xp.abs(wi[..., 0] * wo[..., 1] - wi[..., 1] * wo[..., 0]) <= IN_PLANE_TOLERANCE


def spherical_to_inplane(theta_i, phi_i, theta_o, phi_o):
    """Signed in-plane ``(theta_i, theta_r)`` (degrees) of spherical direction pairs.

    Pairs in the x-z plane (the plane of :func:`inplane_to_vectors`) are decoded exactly, sign
    of ``theta_i`` included; any other pair gets its :func:`inplane_equivalent` (same
    Rusinkiewicz ``theta_h, theta_d``).  Inverse of :func:`inplane_to_spherical`.
    """
    xp = array_namespace_of(theta_i, phi_i, theta_o, phi_o)
    wi, wo = spherical_pair_to_vectors(theta_i, phi_i, theta_o, phi_o)
    in_plane = (xp.abs(wi[..., 1]) < IN_PLANE_TOLERANCE) & (xp.abs(wo[..., 1]) < IN_PLANE_TOLERANCE)
    # wi = (sin ti, 0, cos ti), wo = (-sin tr, 0, cos tr): the polar angles carry the magnitudes
    exact_i = xp.where(wi[..., 0] < 0, -theta_i, theta_i)
    exact_r = xp.where(wo[..., 0] > 0, -theta_o, theta_o)
    equiv_i, equiv_r = inplane_equivalent(wi, wo)
    return xp.where(in_plane, exact_i, equiv_i), xp.where(in_plane, exact_r, equiv_r)


def half_vector_above(wi, wo):
    """``(h, above)``: the half vector, and where both directions are strictly above the horizon.

    Below the horizon ``wi + wo`` may vanish; ``h`` is the normal there, so formulas can be
    evaluated everywhere without dividing by zero and masked with ``above`` afterwards.
    """
    xp = array_namespace_of(wi, wo)
    above = (wi[..., 2] > 0.0) & (wo[..., 2] > 0.0)
    zero = xp.zeros_like(wi[..., 2])
    pole = _stack3(xp, zero, zero, zero + 1.0)
    return normalize(xp.where(above[..., None], wi + wo, pole)), above


def _azimuth_cos_sin(xp, v):
    """``(cos phi, sin phi)`` of the azimuth of ``v`` ``[..., 3]`` as ratios, without ``atan2``
    (which ONNX lacks, so that models on directions export); ``(1, 0)`` on the pole, where
    ``atan2(0, 0) = 0``."""
    r = xp.sqrt(v[..., 0] ** 2 + v[..., 1] ** 2)
    on_pole = r <= 0.0
    safe_r = xp.where(on_pole, xp.ones_like(r), r)
    return xp.where(on_pole, xp.ones_like(r), v[..., 0] / safe_r), xp.where(on_pole, xp.zeros_like(r), v[..., 1] / safe_r)


def half_diff_vectors(wi, wo):
    """Rusinkiewicz half vector ``h`` and difference vector ``d`` (both unit, ``[..., 3]``).

    ``h = normalize(wi + wo)``; ``d`` is ``wi`` rotated by ``-phi_h`` about ``z`` and then by
    ``-theta_h`` about ``y``, i.e. ``wi`` expressed in the frame where ``h`` is the pole.

    At the mirror configuration (``theta_h = 0``, below :data:`MIRROR_SIN_THETA_H`) ``phi_h``
    is undefined and ``atan2`` of rounding noise would pick it, and with it ``phi_d``; there
    ``phi_h = phi_i`` (the limit along the plane of incidence), which keeps ``d`` invariant
    under rotations about the normal: ``d = (sin theta_i, 0, cos theta_i)``.
    """
    xp = array_namespace_of(wi, wo)
    h = normalize(wi + wo)
    cos_th = _clip_unit(xp, h[..., 2])
    sin_th = xp.sqrt(xp.clip(1.0 - cos_th * cos_th, 0.0, None))
    at_mirror = xp.sqrt(h[..., 0] ** 2 + h[..., 1] ** 2) < MIRROR_SIN_THETA_H
    cp, sp = _azimuth_cos_sin(xp, xp.where(at_mirror[..., None], wi, h))
    # rotate wi by -phi_h about z
    x1 = cp * wi[..., 0] + sp * wi[..., 1]
    y1 = -sp * wi[..., 0] + cp * wi[..., 1]
    z1 = wi[..., 2]
    # rotate by -theta_h about y
    dx = cos_th * x1 - sin_th * z1
    dz = sin_th * x1 + cos_th * z1
    return h, _stack3(xp, dx, y1, dz)


def half_diff_angles(wi, wo):
    """Rusinkiewicz angles ``(theta_h, phi_h, theta_d, phi_d)`` in degrees, phis in [0, 360)."""
    h, d = half_diff_vectors(wi, wo)
    theta_h, phi_h = vector_to_spherical(h)
    theta_d, phi_d = vector_to_spherical(d)
    return theta_h, phi_h, theta_d, phi_d


def inplane_half_diff_angles(theta_i_deg, theta_r_deg):
    """Closed form for in-plane pairs: ``theta_h = |ti - tr|/2``, ``theta_d = |ti + tr|/2``."""
    xp = array_namespace_of(theta_i_deg, theta_r_deg)
    return xp.abs(theta_i_deg - theta_r_deg) / 2.0, xp.abs(theta_i_deg + theta_r_deg) / 2.0


def inplane_equivalent(wi, wo):
    """Signed in-plane pair ``(theta_i, theta_r)`` (degrees) with the same ``theta_h, theta_d``.

    ``ti = theta_d + theta_h``, ``tr = theta_d - theta_h`` (docs/formats.md#conventions).  For an in-plane input this
    is the same pair up to the isotropy/reciprocity symmetries (it returns the representative
    with ``ti >= |tr|``).  Far out of plane ``ti`` can exceed 90°: the bivariate approximation
    then asks the in-plane model for a configuration beyond the horizon (models should clamp).
    """
    theta_h, _, theta_d, _ = half_diff_angles(wi, wo)
    return theta_d + theta_h, theta_d - theta_h


def spherical_pair_to_vectors(theta_i, phi_i, theta_o, phi_o):
    """``(wi, wo)`` from the four spherical angles of a BRDF sample table row (degrees)."""
    return spherical_to_vector(theta_i, phi_i), spherical_to_vector(theta_o, phi_o)


def reflect(w):
    """Mirror direction of ``w`` about the normal: ``(-x, -y, z)``."""
    xp = array_namespace_of(w)
    return _stack3(xp, -w[..., 0], -w[..., 1], w[..., 2])


def half_diff_to_vectors(theta_h_deg, theta_d_deg, phi_d_deg, phi_h_deg=0.0):
    """``(wi, wo)`` of Rusinkiewicz angles (degrees): the inverse of :func:`half_diff_angles`.

    ``d = (sin θd cos φd, sin θd sin φd, cos θd)`` is rotated by ``θh`` about ``y`` and then by
    ``φh`` about ``z`` to give ``wi``; ``wo`` is ``wi`` mirrored about ``h``.  With the default
    ``φh = 0`` this is the θh–θd image of MERL and the BRDF Explorer (at ``φd = 90°`` both
    directions stay above the horizon for every ``θh, θd < 90°``).
    """
    xp = array_namespace_of(theta_h_deg, theta_d_deg, phi_d_deg, phi_h_deg)
    phi_h_deg = phi_h_deg + 0.0 * theta_h_deg  # a number becomes an array of the angles' namespace
    d = spherical_to_vector(theta_d_deg, phi_d_deg)
    h = spherical_to_vector(theta_h_deg, phi_h_deg)
    ch, sh = xp.cos(theta_h_deg * DEG), xp.sin(theta_h_deg * DEG)
    x1 = ch * d[..., 0] + sh * d[..., 2]  # rotate by +θh about y
    z1 = -sh * d[..., 0] + ch * d[..., 2]
    cp, sp = xp.cos(phi_h_deg * DEG), xp.sin(phi_h_deg * DEG)  # then by +φh about z
    wi = _stack3(xp, cp * x1 - sp * d[..., 1], sp * x1 + cp * d[..., 1], z1)
    wo = 2.0 * dot(wi, h)[..., None] * h - wi
    return wi, wo
