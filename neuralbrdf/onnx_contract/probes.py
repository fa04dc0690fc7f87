"""The direction pairs on which a model file is tried at load (:mod:`neuralbrdf.onnx_contract`): a few
pairs on both sides of the horizon (:func:`probe_directions`) and the dense stratified probe of sign
and finiteness, near-mirror and grazing pairs included (:func:`dense_probe`)."""

from __future__ import annotations

import numpy as np


def probe_directions(n_above: int = 64, n_below: int = 16, seed: int = 0):
    """Deterministic probe pairs ``(wi, wo, below)``: ``n_above`` pairs with both directions
    above the horizon, then ``n_below`` pairs with one of them below (``below`` marks those)."""
    rng = np.random.default_rng(seed)
    n = n_above + n_below
    wi = rng.normal(size=(n, 3))
    wo = rng.normal(size=(n, 3))
    wi[:, 2] = np.abs(wi[:, 2]) + 0.05
    wo[:, 2] = np.abs(wo[:, 2]) + 0.05
    below = np.arange(n) >= n_above
    flip_wi = below & (np.arange(n) % 2 == 0)
    wi[flip_wi, 2] *= -1.0
    wo[below & ~flip_wi, 2] *= -1.0
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    return wi.astype(np.float32), wo.astype(np.float32), below


#: Dense load-time probe (:func:`dense_probe`): strata of the incident polar angle ...
PROBE_THETA_I_STRATA = 18
#: ... and, per incident stratum, of the outgoing polar angle × azimuth.
PROBE_OUT_STRATA = (18, 36)
#: Incident angles (one per degree, 0°–89°) probed at and around their mirror direction ...
PROBE_MIRROR_THETA_I = 90
#: ... at these angular offsets from the mirror (degrees) ...
PROBE_MIRROR_OFFSETS_DEG = (0.0, 0.01, 0.1, 0.3, 1.0, 3.0)
#: ... in this many azimuths around it.
PROBE_MIRROR_AZIMUTHS = 8
#: Grazing probe: both polar angles in [85°, 89.99°], strata per angle and of the azimuth.
PROBE_GRAZING_STRATA = (8, 8, 16)
#: Wavelengths (spread over a spectral model's range, both ends included) of the dense probe.
PROBE_WAVELENGTHS = 8


def _stratified(rng, low: float, high: float, count: int) -> np.ndarray:
    """One jittered sample in each of ``count`` equal strata of [low, high]."""
    edges = np.linspace(low, high, count + 1)
    return edges[:-1] + rng.uniform(0.0, 1.0, count) * np.diff(edges)


def _rotated(theta_deg, phi_deg, azimuth_deg) -> np.ndarray:
    from neuralbrdf.geometry import spherical_to_vector

    return spherical_to_vector(np.asarray(theta_deg, dtype=np.float64), np.asarray(phi_deg) + azimuth_deg)


def dense_probe(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Direction pairs ``(wi, wo, near_mirror)`` (float32 ``[M, 3]``, bool ``[M]``) of the load-time
    sign and finiteness check, all above the horizon (about 16 000 pairs):

    * a stratified hemisphere: :data:`PROBE_THETA_I_STRATA` strata of ``θi`` in [0°, 89.9°], each
      with :data:`PROBE_OUT_STRATA` strata of ``θo`` × ``φo``, jittered, the whole pair rotated
      by a random azimuth (isotropy is not assumed);
    * near-mirror pairs, where glossy models peak and fits overshoot: ``θi`` = 0.5°, 1.5°, …,
      89.5° with ``wo`` the mirror direction tilted by each of :data:`PROBE_MIRROR_OFFSETS_DEG`
      in :data:`PROBE_MIRROR_AZIMUTHS` directions (kept when above the horizon);
    * grazing pairs: both polar angles in [85°, 89.99°] (:data:`PROBE_GRAZING_STRATA`).
    """
    rng = np.random.default_rng(seed)
    wi, wo = [], []
    n_theta, n_phi = PROBE_OUT_STRATA
    for theta_i in _stratified(rng, 0.0, 89.9, PROBE_THETA_I_STRATA):
        theta_o = np.repeat(_stratified(rng, 0.0, 89.9, n_theta), n_phi)
        phi_o = np.tile(_stratified(rng, 0.0, 360.0, n_phi), n_theta)
        azimuth = rng.uniform(0.0, 360.0)
        wo.append(_rotated(theta_o, phi_o, azimuth))
        wi.append(np.repeat(_rotated(theta_i, 0.0, azimuth)[None], len(theta_o), axis=0))
    n_hemisphere = sum(len(w) for w in wi)
    theta_i = np.arange(PROBE_MIRROR_THETA_I) + 0.5
    offsets = np.asarray(PROBE_MIRROR_OFFSETS_DEG)
    around = np.arange(PROBE_MIRROR_AZIMUTHS) * 360.0 / PROBE_MIRROR_AZIMUTHS
    ti, offset, turn = (a.ravel() for a in np.meshgrid(theta_i, offsets, around, indexing="ij"))
    keep = (offset > 0) | (turn == 0)  # the exact mirror once per angle
    ti, offset, turn = ti[keep], offset[keep], turn[keep]
    # The mirror of (θi, 0°) is (θi, 180°); tilt it by ``offset`` towards azimuth ``turn`` about itself.
    mirror = _rotated(ti, 180.0, 0.0)
    tangent_a = np.stack([-np.cos(np.radians(ti)), np.zeros_like(ti), -np.sin(np.radians(ti))], axis=1)
    tangent_b = np.stack([np.zeros_like(ti), np.ones_like(ti), np.zeros_like(ti)], axis=1)
    tilt, spin = np.radians(offset)[:, None], np.radians(turn)[:, None]
    out = np.cos(tilt) * mirror + np.sin(tilt) * (np.cos(spin) * tangent_a + np.sin(spin) * tangent_b)
    above = out[:, 2] > 1e-6
    wi.append(_rotated(ti[above], 0.0, 0.0))
    wo.append(out[above])
    n_mirror = int(above.sum())
    n_t, _, n_p = PROBE_GRAZING_STRATA
    grazing_i = _stratified(rng, 85.0, 89.99, n_t)
    grazing_o = _stratified(rng, 85.0, 89.99, n_t)
    gi, go, gp = (a.ravel() for a in np.meshgrid(grazing_i, grazing_o, _stratified(rng, 0.0, 360.0, n_p), indexing="ij"))
    wi.append(_rotated(gi, 0.0, 0.0))
    wo.append(_rotated(go, gp, 0.0))
    wi, wo = np.concatenate(wi), np.concatenate(wo)
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    near_mirror = np.zeros(len(wi), dtype=bool)
    near_mirror[n_hemisphere : n_hemisphere + n_mirror] = True
    return wi.astype(np.float32), wo.astype(np.float32), near_mirror
