"""Cue energies: one pure function per cue, of one particle's projected geometry and one frame's observation.

Every cue returns an energy ``E ≥ 0`` — per view ``(V,)`` for image cues, a scalar for view-free cues (3D
distances, priors) — and the likelihood composes them in Gibbs form ``p(z | x) ∝ exp(−Σ_c λ_c Σ_v w_v E_c,v)``
(:mod:`jaxmocap.likelihood`). Most energies are normalised to [0, 1] so that Li & Kulić's weighting
``w_c = A^(−d_c)`` (A = 100, their eq. 4) is the same form with ``λ_c = k_c ln A``.

The geometry a cue reads (:class:`Geometry`) is computed once per particle for all cues; ``V`` views, ``P`` flesh
surface points, ``C`` occluding-contour points, ``J`` evaluation joints.

Which cues are differentiable in the pose: ``edge_distance``, ``foreground`` and ``edges`` with ``bilinear=True``
(they read maps by bilinear interpolation; the nearest-pixel default is piecewise constant), ``keypoints``,
``blobs3d``, ``ground``, ``interpenetration``. Not differentiable (piecewise constant or set-valued):
``edge_fraction``, ``depth`` (its foreground/occlusion switch), ``silhouette_divergence`` (inside/outside tests).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxmocap import flesh, maps
from jaxmocap.observation import Observation, as_float

#: Li & Kulić's penalty for a sample point outside the foreground in the depth cue (eq. 1), metres.
DEPTH_PENALTY_M = 2.8


class Geometry(NamedTuple):
    """Projected geometry of one particle (fields a configuration does not need are ``None``).

    joints ``(J, 3)`` world evaluation joints; joints_uv ``(V, J, 2)``;
    surface ``(P, 3)`` world flesh points; surface_uv ``(V, P, 2)``; surface_depth ``(V, P)`` camera z;
    surface_facing ``(V, P)`` bool: outward normal faces the camera;
    contour_uv ``(V, C, 2)`` occluding-contour points of the cones seen from each camera;
    primitives: :class:`jaxmocap.flesh.Primitives` in the world frame.
    """

    joints: jnp.ndarray | None = None
    joints_uv: jnp.ndarray | None = None
    surface: jnp.ndarray | None = None
    surface_uv: jnp.ndarray | None = None
    surface_depth: jnp.ndarray | None = None
    surface_facing: jnp.ndarray | None = None
    contour_uv: jnp.ndarray | None = None
    primitives: flesh.Primitives | None = None


class CueContext(NamedTuple):
    """Static facts a cue may need besides geometry and observation."""

    joint_names: tuple[str, ...]
    params: dict
    rig: object


def _lookup(obs_map, uv, bilinear: bool):
    f = maps.lookup_bilinear if bilinear else maps.lookup_nearest
    return f(obs_map, uv)


# ---------------------------------------------------------------------------------------------------------------
# Image cues (per view)


def foreground(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Foreground matching (López Méndez eq. 4.3): fraction of the model's surface samples that fall on background.

    ``E_v = (1/P) Σ_p (1 − F_v(u_vp))``; a sample outside the image counts as background.
    """
    F, inside = _lookup(as_float(obs.foreground), g.surface_uv, ctx.params.get("bilinear", False))
    miss = jnp.where(inside, 1.0 - F, 1.0)
    return jnp.mean(miss, axis=-1)


def edges(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Edge matching (López Méndez eq. 4.5): ``E_v = (1/C) Σ_c (1 − Ẽ_v(u_vc))`` on the occluding-contour points, with
    ``Ẽ`` the dilated, smoothed edge map in [0, 1] (§4.2); out-of-image points count as 1."""
    E, inside = _lookup(as_float(obs.edges), g.contour_uv, ctx.params.get("bilinear", False))
    return jnp.mean(jnp.where(inside, 1.0 - E, 1.0), axis=-1)


def edge_distance(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Edge distance (Fontmarty et al. §III-B): ``p ∝ exp(−D²/2σ_e²)`` with ``D`` the distance-transform value
    ``I_DT`` at the contour points. Energy: ``E_v = (1/C) Σ_c min(I_DT(u_vc), d_max)² / (2 σ_e²)`` (σ_e and d_max in
    pixels; out-of-image points take ``d_max``). Bilinear lookups: differentiable."""
    sigma = ctx.params.get("sigma_px", 6.0)
    dmax = ctx.params.get("max_px", 30.0)
    D, inside = maps.lookup_bilinear(as_float(obs.edge_dt, unit=False), g.contour_uv)
    D = jnp.where(inside, jnp.minimum(D, dmax), dmax)
    return jnp.mean(D * D, axis=-1) / (2.0 * sigma * sigma)


def edge_fraction(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Li & Kulić edge cue (eq. 2): the fraction of projected contour pixels that are not on the edge map
    (edge value below ``threshold``, default 0.5); out-of-image points count as off."""
    E, inside = maps.lookup_nearest(as_float(obs.edges), g.contour_uv)
    on = inside & (E >= ctx.params.get("threshold", 0.5))
    return 1.0 - jnp.mean(on.astype(E.dtype), axis=-1)


def depth(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Li & Kulić depth cue (eq. 1), rescaled to [0, 1].

    For the camera-facing surface samples: ``d_p = |z_p − D(u_p)|`` where the observed pixel is foreground (and has
    a depth), else the fixed penalty 2.8 m; ``E_v = min(mean_p d_p, 2.8) / 2.8``.
    """
    Dm, inside = maps.lookup_nearest(as_float(obs.depth, unit=False), g.surface_uv)
    if obs.has("foreground"):
        F, _ = maps.lookup_nearest(as_float(obs.foreground), g.surface_uv)
        fg = F >= 0.5
    else:
        fg = Dm > 0
    ok = inside & fg & (Dm > 0)
    d = jnp.where(ok, jnp.abs(g.surface_depth - Dm), DEPTH_PENALTY_M)
    w = g.surface_facing.astype(d.dtype)
    mean = jnp.sum(d * w, axis=-1) / jnp.maximum(jnp.sum(w, axis=-1), 1.0)
    return jnp.minimum(mean, DEPTH_PENALTY_M) / DEPTH_PENALTY_M


def silhouette_divergence(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Foreground divergence (López Méndez eq. 4.6): the part of the observed silhouette the model does not occupy.

    A static grid of pixel samples (``grid`` = (columns, rows), default 40×30) is weighted by the foreground map;
    ``E_v = Σ_g F(g) (1 − inside_v(g)) / Σ_g F(g)`` with ``inside_v`` the projected-limb test of
    :func:`jaxmocap.flesh.inside_projected` (pinhole; distortion ignored for this coverage test).
    Together with :func:`foreground` (model on silhouette) it penalises both ways of disagreeing.
    """
    V, H, W = obs.foreground.shape
    gc, gr = ctx.params.get("grid", (40, 30))
    us = (np.arange(gc) + 0.5) * (W / gc) - 0.5
    vs = (np.arange(gr) + 0.5) * (H / gr) - 0.5
    grid = np.stack(np.meshgrid(us, vs), -1).reshape(-1, 2).astype(np.float32)
    uvg = jnp.broadcast_to(jnp.asarray(grid), (V,) + grid.shape)
    F, _ = maps.lookup_nearest(as_float(obs.foreground), uvg)
    rig = ctx.rig
    K = jnp.asarray(rig.K, F.dtype)
    R = jnp.asarray(rig.R, F.dtype)
    t = jnp.asarray(rig.t, F.dtype)
    out = []
    for v in range(V):
        ins = flesh.inside_projected(g.primitives, K[v], R[v], t[v], uvg[v])
        out.append(jnp.sum(F[v] * (1.0 - ins.astype(F.dtype))) / jnp.maximum(jnp.sum(F[v]), 1.0))
    return jnp.stack(out)


def keypoints(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """2D keypoint cue (beyond the three works): robust distance between projected model joints and detections.

    ``E_v = Σ_k c_vk ρ(‖u_vj(k) − z_vk‖ / σ) / Σ_k c_vk`` with the Geman–McClure ``ρ(r) = r² / (1 + r²)`` (bounded,
    so a wrong detection costs at most its confidence), σ in pixels (default 20), ``pairs`` = static tuple of
    (model joint name, keypoint index) and detections ``obs.keypoints2d (V, K, 3)`` = (u, v, confidence).
    """
    pairs = ctx.params["pairs"]
    sigma = ctx.params.get("sigma_px", 20.0)
    jidx = np.asarray([ctx.joint_names.index(j) for j, _ in pairs])
    kidx = np.asarray([k for _, k in pairs])
    det = obs.keypoints2d[:, kidx]  # (V, M, 3)
    proj = g.joints_uv[:, jidx]  # (V, M, 2)
    d = proj - det[..., :2]
    r2 = jnp.sum(d * d, axis=-1) / (sigma * sigma)
    c = det[..., 2]
    return jnp.sum(c * r2 / (1.0 + r2), axis=-1) / jnp.maximum(jnp.sum(c, axis=-1), 1e-6)


# ---------------------------------------------------------------------------------------------------------------
# 3D cues and priors (scalar)


def blobs3d(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """3D blob distance (Fontmarty et al. §III-B): each detected skin blob ``b_k`` (head, hands) is explained by the
    nearest of the model's head and wrists: ``E = Σ_k c_k min_j ‖X_j − b_k‖² / (2σ²) / max(Σ_k c_k, 1)``, σ in
    metres (default 0.1)."""
    names = ctx.params.get("joints", ("head", "left_wrist", "right_wrist"))
    sigma = ctx.params.get("sigma_m", 0.1)
    idx = np.asarray([ctx.joint_names.index(j) for j in names])
    X = g.joints[idx]  # (M, 3)
    d = obs.blobs3d[:, None, :] - X[None]  # (K, M, 3)
    d2 = jnp.min(jnp.sum(d * d, axis=-1), axis=-1)
    c = obs.blob_conf
    return jnp.sum(c * d2) / (2.0 * sigma * sigma) / jnp.maximum(jnp.sum(c), 1.0)


def ground(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Ground distance (Li & Kulić distance cue): the feet may not go below the floor ``z = floor`` (default 0).

    ``E = Σ_ankles max(0, floor + clearance − z) / scale``; clearance (default 0: the body presets end at the
    ankle, which stands on the floor) and scale (default 0.05 m) are parameters; zero for feet above the floor.
    """
    names = [j for j in ("left_ankle", "right_ankle") if j in ctx.joint_names]
    idx = np.asarray([ctx.joint_names.index(j) for j in names])
    z = g.joints[idx, 2]
    floor = ctx.params.get("floor", 0.0) + ctx.params.get("clearance", 0.0)
    return jnp.sum(jnp.maximum(floor - z, 0.0)) / ctx.params.get("scale", 0.05)


def interpenetration(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Inter-penetration prior (López Méndez eq. 6.2–6.3): limbs may not pass through each other.

    For the static cone pairs ``pairs`` (default: each forearm against the torso and the other forearm, the shins
    against each other), the closest distance ``d`` between the two cone axes is compared with the sum of the
    largest radii: ``E = Σ max(0, r_i + r_j − d)² / s²`` (s = 0.02 m).
    """
    prims = g.primitives
    pairs = ctx.params["pairs"]
    s = ctx.params.get("scale", 0.02)
    total = jnp.zeros((), prims.cone_a.dtype)
    for i, j in pairs:
        d = _segment_distance(prims.cone_a[i], prims.cone_b[i], prims.cone_a[j], prims.cone_b[j])
        r = jnp.maximum(prims.r_a[i], prims.r_b[i]) + jnp.maximum(prims.r_a[j], prims.r_b[j])
        total = total + jnp.maximum(r - d, 0.0) ** 2
    return total / (s * s)


def _segment_distance(p0, p1, q0, q1):
    """Closest distance between segments ``p0p1`` and ``q0q1`` (clamped parameters; smooth almost everywhere)."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, f = jnp.dot(d1, d1), jnp.dot(d2, d2), jnp.dot(d2, r)
    b, c = jnp.dot(d1, d2), jnp.dot(d1, r)
    den = jnp.maximum(a * e - b * b, 1e-12)
    s = jnp.clip((b * f - c * e) / den, 0.0, 1.0)
    t = jnp.clip((b * s + f) / jnp.maximum(e, 1e-12), 0.0, 1.0)
    s = jnp.clip((b * t - c) / jnp.maximum(a, 1e-12), 0.0, 1.0)
    diff = p0 + s * d1 - (q0 + t * d2)
    return jnp.sqrt(jnp.dot(diff, diff) + 1e-12)


# ---------------------------------------------------------------------------------------------------------------
# Registry

#: name → (function, per-view?, the geometry it needs)
CUES: dict[str, tuple[Callable, bool, frozenset]] = {
    "foreground": (foreground, True, frozenset({"surface"})),
    "edges": (edges, True, frozenset({"contour"})),
    "edge_distance": (edge_distance, True, frozenset({"contour"})),
    "edge_fraction": (edge_fraction, True, frozenset({"contour"})),
    "depth": (depth, True, frozenset({"surface"})),
    "silhouette_divergence": (silhouette_divergence, True, frozenset({"primitives"})),
    "keypoints": (keypoints, True, frozenset({"joints_uv"})),
    "blobs3d": (blobs3d, False, frozenset({"joints"})),
    "ground": (ground, False, frozenset({"joints"})),
    "interpenetration": (interpenetration, False, frozenset({"primitives"})),
}

#: Observation fields each cue reads (a clear error names the missing one).
REQUIRES: dict[str, tuple[str, ...]] = {
    "foreground": ("foreground",),
    "edges": ("edges",),
    "edge_distance": ("edge_dt",),
    "edge_fraction": ("edges",),
    "depth": ("depth",),
    "silhouette_divergence": ("foreground",),
    "keypoints": ("keypoints2d",),
    "blobs3d": (),
    "ground": (),
    "interpenetration": (),
}
