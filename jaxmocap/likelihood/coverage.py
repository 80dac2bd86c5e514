"""The silhouette **coverage** cue: every part of the observed silhouette should be covered by some projected limb.

The model-on-silhouette cues (``foreground``, Li & Kulić's ``depth``) do not penalise a limb hidden in front of the
torso, so ``M`` samples of the observed silhouette per view must each be covered by some projected limb. The samples
are the observation's ``silhouette`` / ``silhouette_w`` fields when it has them (:func:`silhouette_samples`, host
side: the tracker's features), else ``M`` (parameter ``samples``, default 128) foreground pixels evenly spaced in
raster order, taken on the device from the foreground map (:func:`prepare`, once per call). Its energy is
``E_v = (1/M) Σ_m min(d_m / d_max, 1)`` with ``d_m`` the distance from sample ``m`` to the nearest projected flesh
capsule (axis segment minus the projected radius ``f r / z``, clipped at 0), a cheap stand-in for López Méndez's
foreground divergence (eq. 4.6); it is differentiable in the pose.

``d_max`` is :data:`COVERAGE_DMAX` of the image width (at least one pixel; parameter ``d_max`` of the cue).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.features.observation import Observation, as_float
from jaxmocap.geometry import body as body_mod
from jaxmocap.geometry import camera, flesh

__all__ = [
    "COVERAGE_DMAX",
    "coverage",
    "coverage_energy",
    "d_max_of",
    "prepare",
    "primitives_energy",
    "silhouette_samples",
]

#: ``d_max`` of the coverage term as a fraction of the image width (at least one pixel): about one pixel, so that
#: a silhouette sample counts as uncovered as soon as it lies outside every projected limb, the mirror image of the
#: ``foreground`` cue (a model sample counts as soon as it lies outside the silhouette).
COVERAGE_DMAX = 0.004


def _capsules(p: flesh.Primitives):
    """World capsules of the flesh primitives ``p``: cones as they are, each ellipsoid as its polar axis with its
    equatorial radius. Returns ``a, b (S, 3)``, ``r_a, r_b (S,)``."""
    a, b, ra, rb = p.cone_a, p.cone_b, p.r_a, p.r_b
    if p.num_ellipsoids:
        polar = p.ell_axes[:, :, 2]
        r = jnp.sqrt(jnp.sum(p.ell_axes[:, :, 0] ** 2, axis=-1))
        a = jnp.concatenate([a, p.ell_centre - polar])
        b = jnp.concatenate([b, p.ell_centre + polar])
        ra = jnp.concatenate([ra, r])
        rb = jnp.concatenate([rb, r])
    return a, b, ra, rb


def primitives_energy(prims: flesh.Primitives, rig: camera.Rig, uv, w, d_max) -> jnp.ndarray:
    """Coverage energy per view ``(V,)`` of world primitives ``prims`` (see :func:`coverage_energy`)."""
    a, b, ra, rb = _capsules(prims)
    ua, za = camera.project_with_depth(rig, a)  # (V, S, 2), (V, S)
    ub, zb = camera.project_with_depth(rig, b)
    f = rig.K[:, 0, 0][:, None]
    pa = (f * ra[None] / jnp.maximum(za, 1e-3))[..., None]  # (V, S, 1)
    pb = (f * rb[None] / jnp.maximum(zb, 1e-3))[..., None]
    dmin = jnp.maximum(nearest_capsule_distance(ua, ub, pa, pb, uv), 0.0)  # (V, M)
    e = jnp.minimum(dmin / d_max[:, None], 1.0)
    return jnp.sum(w * e, axis=-1) / jnp.maximum(jnp.sum(w, axis=-1), 1.0)


def _capsule_distances(ua, ub, pa, pb, uv):
    """``(V, S, M)`` signed distances from the samples ``uv (V, M, 2)`` to the projected capsules (axes ``ua → ub
    (V, S, 2)``, radii ``pa, pb (V, S, 1)``): the distance to the foot of the perpendicular ``τ`` (clamped to the
    axis) less the radius there."""
    # (V, S, M) arrays, one coordinate at a time: the samples on the minor axis and the minimum over capsules
    # across rows vectorise on a CPU (with (V, M, S, 2) and reductions over the short minor axes: 2× slower)
    ax, ay = ua[..., 0:1], ua[..., 1:2]
    dx, dy = ub[..., 0:1] - ax, ub[..., 1:2] - ay
    len2 = jnp.maximum(dx * dx + dy * dy, 1e-9)
    qx = uv[:, None, :, 0] - ax
    qy = uv[:, None, :, 1] - ay
    tau = jnp.clip((qx * dx + qy * dy) / len2, 0.0, 1.0)
    cx, cy = qx - tau * dx, qy - tau * dy
    return jnp.sqrt(cx * cx + cy * cy + 1e-12) - (pa + tau * (pb - pa))


@jax.custom_jvp
def nearest_capsule_distance(ua, ub, pa, pb, uv) -> jnp.ndarray:
    """``(V, M)``: ``min_s`` of :func:`_capsule_distances` (shapes there).

    Its derivative is that of the nearest capsule's distance alone (``s* = argmin_s``; at ties the first), through
    its own JVP: the reverse pass runs over ``(V, M)`` samples instead of the ``(V, S, M)`` sample-capsule pairs
    (whose every intermediate the automatic derivative of the minimum keeps). The value is the same expression as
    without derivatives."""
    return jnp.min(_capsule_distances(ua, ub, pa, pb, uv), axis=1)


@nearest_capsule_distance.defjvp
def _nearest_capsule_distance_jvp(primals, tangents):
    ua, ub, pa, pb, uv = primals
    dist = _capsule_distances(ua, ub, pa, pb, uv)
    out = jnp.min(dist, axis=1)
    # the first nearest capsule (V, M), by a plain minimum (XLA's CPU backend runs argmin's two-operand reduction
    # several times slower)
    S = dist.shape[1]
    rank = jnp.arange(S, dtype=jnp.int32)[None, :, None]
    near = jnp.minimum(jnp.min(jnp.where(dist <= out[:, None, :], rank, S), axis=1), S - 1)

    def pick(a):  # (V, S, k) capsule values -> (V, M, k) of each sample's nearest capsule
        return jnp.take_along_axis(a, near[..., None], axis=1)

    V, M = near.shape

    def one(ua, ub, pa, pb, uv):  # each sample's distance to its own capsule: (V, M, ·) values -> (V, M)
        flat = lambda a: a.reshape(V * M, 1, a.shape[-1])
        return _capsule_distances(flat(ua), flat(ub), flat(pa), flat(pb), flat(uv)).reshape(V, M)

    args = (pick(ua), pick(ub), pick(pa), pick(pb), uv)
    t_args = tuple(pick(jnp.asarray(t)) for t in tangents[:4]) + (jnp.asarray(tangents[4]),)
    return out, jax.jvp(one, args, t_args)[1]


def coverage_energy(
    model: body_mod.BodyModel,
    rig: camera.Rig,
    x: jnp.ndarray,
    uv: jnp.ndarray,
    w: jnp.ndarray,
    d_max: jnp.ndarray,
) -> jnp.ndarray:
    """Silhouette coverage energy per view ``(V,)`` of one state ``x (D,)`` (module docstring).

    ``uv (V, M, 2)`` silhouette samples (pixels), ``w (V, M)`` their weights, ``d_max (V,)`` the distance (pixels)
    at which a sample counts as fully uncovered. For capsule ``s`` with projected axis ``a_s b_s`` and projected
    radii ``ρ = f_x r / z`` at its ends: ``d_m = max(0, min_s (‖u_m − (a_s + τ (b_s − a_s))‖ − ρ_s(τ)))`` with ``τ``
    the clamped foot of the perpendicular; ``E_v = Σ_m w_m min(d_m / d_max, 1) / max(Σ_m w_m, 1)``.
    """
    R, t = body_mod.segment_poses(model, x)
    return primitives_energy(flesh.world_primitives(model, R, t), rig, uv, w, d_max)


def d_max_of(rig: camera.Rig, fraction: float = COVERAGE_DMAX) -> jnp.ndarray:
    """``(V,)`` distances (pixels) at which a sample counts as uncovered: ``max(1, fraction · image width)``."""
    return jnp.asarray([max(1.0, fraction * w) for w, _ in rig.image_size], jnp.float32)


def prepare(obs: Observation, ctx, cache: dict):
    """The silhouette samples ``(uv (V, M, 2), w (V, M))`` of one call: the observation's own, else ``M`` pixels of
    ``foreground ≥ 0.5`` per view at ranks ``round(j (n − 1) / (min(M, n) − 1))``, ``j < min(M, n)``, in raster
    order (``n`` foreground pixels in the view; the other slots weigh 0)."""
    del cache
    if obs.silhouette is not None:
        return obs.silhouette, obs.silhouette_w
    M = int(ctx.params.get("samples", 128))
    fg = (as_float(obs.foreground) >= 0.5).reshape(obs.foreground.shape[0], -1)  # (V, H·W)
    W = obs.foreground.shape[2]
    count = jnp.cumsum(fg.astype(jnp.int32), axis=-1)
    total = count[:, -1:]  # (V, 1)
    k = jnp.minimum(total, M)
    j = jnp.arange(M)[None, :]
    rank = jnp.round(j * (total - 1).astype(jnp.float32) / jnp.maximum(k - 1, 1)).astype(jnp.int32)
    pick = jnp.stack([jnp.searchsorted(c, r + 1, side="left") for c, r in zip(count, rank, strict=True)])
    pick = jnp.clip(pick, 0, fg.shape[1] - 1)
    uv = jnp.stack([pick % W, pick // W], -1).astype(jnp.float32)
    return uv, (j < k).astype(jnp.float32)


def coverage(g, obs: Observation, ctx) -> jnp.ndarray:
    """The cue (:data:`jaxmocap.likelihood.cues.CUES`): :func:`coverage_energy` of the particle's primitives
    against the silhouette samples of :func:`prepare`, ``(V,)``."""
    uv, w = ctx.aux
    d_max = d_max_of(ctx.rig, float(ctx.params.get("d_max", COVERAGE_DMAX)))
    return primitives_energy(g.primitives, ctx.rig, uv, w, d_max)


def silhouette_samples(mask: np.ndarray, M: int) -> tuple[np.ndarray, np.ndarray]:
    """``M`` foreground pixels of a boolean mask, evenly spaced in raster order: ``(uv (M, 2), w (M,))``; slots
    beyond the number of foreground pixels have weight 0."""
    ys, xs = np.nonzero(mask)
    uv = np.zeros((M, 2), np.float32)
    w = np.zeros(M, np.float32)
    if xs.size:
        idx = np.round(np.linspace(0, xs.size - 1, min(M, xs.size))).astype(np.int64)
        uv[: idx.size, 0] = xs[idx]
        uv[: idx.size, 1] = ys[idx]
        w[: idx.size] = 1.0
    return uv, w
