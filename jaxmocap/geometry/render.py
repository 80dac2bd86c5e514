"""Exact per-pixel ray casting of the flesh primitives, shading and virtual depth (synthetic sequences).

Scene: :class:`jaxmocap.geometry.flesh.Primitives` in world coordinates — ``C`` truncated cones (``cone_a``, ``cone_b``,
``r_a``, ``r_b``) and ``E`` ellipsoids (``ell_centre``, ``ell_axes``). Cones are closed either with **flat caps**
(``caps="flat"``: the same solid as :mod:`jaxmocap.geometry.flesh` samples and tests, the default) or with **spheres** of
radius ``r_a`` at ``a`` and ``r_b`` at ``b`` (``caps="sphere"``: a rounded limb, "capsule"-like, that hides the
gaps at bent joints of a mocap skeleton). Labels: cones ``0 … C−1`` then ellipsoids ``C … C+E−1``, ``−1`` for
background. Nearest surface wins. The camera must be outside every primitive (only hits in front of it count).

Camera: ``x_cam = R x + t`` with intrinsics ``K`` and OpenCV distortion. Rays are cast in the camera frame from
the origin through ``d = (x, y, 1)`` where ``(x, y)`` are the *undistorted* normalised coordinates of each pixel
centre (pixel ``(u, v)`` = column, row; integer coordinates are pixel centres as in OpenCV). With distortion,
:func:`pixel_rays` inverts it per pixel with ``cv2.undistortPointsIter``, so the image is the distorted image of
the scene directly (no resampling). Because ``d_z = 1``, the ray parameter of a hit *is* its camera depth ``z``.

Intersections, all along ``p(τ) = τ d`` (``τ > 0``); ``w = −a`` is the camera centre relative to ``a``,
``z₀ = w·â``, ``w⊥ = w − z₀ â``, ``k = Δ/L``, ``ρ₀ = r_a + k z₀``, ``d_z = d·â``:

* cone lateral surface ``|w⊥ + τ d⊥| = ρ₀ + k τ d_z``: ``A τ² + 2 B τ + C = 0`` with
  ``A = |d|² − (1 + k²) d_z²``, ``B = w⊥·d − k ρ₀ d_z``, ``C = |w⊥|² − ρ₀²``; roots in the numerically stable
  form ``q = −(B + sgn(B)√(B² − AC))``, ``τ = q/A, C/q``; kept when ``0 ≤ z₀ + τ d_z ≤ L`` and on the right nappe;
* flat caps: ``τ = −z₀/d_z`` and ``(L − z₀)/d_z`` with ``|w⊥ + τ d⊥|² ≤ r²``;
* spheres ``|w + τ d| = r`` and ellipsoids (unit sphere after ``y = M⁻¹ x``): the near root of the quadratic.

Per-primitive constants are computed once per frame; per ray each primitive costs two dot products, one square
root and two or three divisions. The image is cast in square tiles (default 16×16): a tile's rays meet all
primitives at once as ``(C, tile²)`` arrays (vectorised over primitives, so the compiled program does not grow
with ``C``), and the nearest hit is a minimum over the primitive axis. Tiles that no primitive can cover (their
range of normalised coordinates misses every primitive's conservative image range) are skipped: a ``fori_loop``
with a data-dependent trip count runs over the others, so a new frame never recompiles. One ``jit`` compilation
per ``(H, W, C, E)`` and static options. Measured in ``benchmarks/bench_render.py``: culling is what makes a
640×480 view of a whole body fast (the body covers a few percent of a capture view).

Host side (NumPy/OpenCV): Lambert shading with per-label colours, background compositing, illumination change,
Gaussian sensor noise, motion blur as the average of sub-frame renders, and Li & Kulić's virtual depth maps
(front-surface depth, Gaussian-smoothed inside the silhouette, Gaussian noise ≈ 2 cm, 16-bit millimetre PNG).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from typing import NamedTuple

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import body as body_mod
from jaxmocap.geometry.flesh import Primitives, axis_length, orthonormal_basis, world_primitives

CAPS = ("flat", "sphere")
PART_LATERAL, PART_CAP_A, PART_CAP_B, PART_ELLIPSOID = 0, 1, 2, 3

__all__ = [
    "Primitives",
    "Render",
    "pixel_rays",
    "render",
    "render_view",
    "label_colours",
    "primitives_from_model",
    "primitives_from_skeleton",
    "shade",
    "composite",
    "add_sensor_noise",
    "average_frames",
    "virtual_depth",
    "write_depth_png",
    "read_depth_png",
]


class Render(NamedTuple):
    """One rendered view. ``depth (H, W)``: camera ``z`` in metres, 0 for background; ``label (H, W)`` int32,
    −1 for background; ``normal (H, W, 3)``: outward unit normal in the *camera* frame (world: ``Rᵀ n``), 0 for
    background."""

    depth: jnp.ndarray
    label: jnp.ndarray
    normal: jnp.ndarray

    @property
    def mask(self):
        return self.label >= 0


# ---------------------------------------------------------------------------------------------------------------
# Scenes


def primitives_from_model(model: body_mod.BodyModel, x: jnp.ndarray) -> Primitives:
    """World primitives of a :class:`jaxmocap.geometry.body.BodyModel` in state ``x (D,)`` (flat-capped cones + head)."""
    R, t = body_mod.segment_poses(model, x)
    return world_primitives(model, R, t)


def primitives_from_skeleton(
    positions: jnp.ndarray,
    parents: Sequence[int],
    radius_start: jnp.ndarray,
    radius_end: jnp.ndarray | None = None,
    *,
    bones: Sequence[int] | None = None,
    head: tuple[int, int] | None = None,
    head_radius: float | jnp.ndarray = 0.09,
    head_length: float | jnp.ndarray | None = None,
) -> Primitives:
    """Dress a skeleton in cones and an ellipsoid head.

    Args:
      positions: ``(J, 3)`` world joint positions of one frame (metres, z up).
      parents: ``J`` parent indices (``−1`` for a root); static.
      radius_start, radius_end: ``(B,)`` radius of each bone at its parent end and at its child end (``radius_end``
        defaults to ``radius_start``).
      bones: static child-joint indices of the bones to dress, in label order; default every joint with a parent.
        Bone ``j`` is the cone from ``positions[parents[j]]`` to ``positions[j]``. Leave out zero-length bones.
      head: ``(base, tip)`` joint indices: a spheroid with its polar axis along ``base → tip``, starting at
        ``base``, polar length ``head_length`` (default ``|tip − base|``) and equatorial radius ``head_radius``.

    Returns:
      :class:`Primitives` with ``C = len(bones)`` cones (labels in ``bones`` order) and ``E = 1`` ellipsoid when
      ``head`` is given (label ``C``), else ``E = 0``.
    """
    positions = jnp.asarray(positions)
    parents = tuple(int(p) for p in parents)
    if bones is None:
        bones = tuple(j for j, p in enumerate(parents) if p >= 0)
    bones = np.asarray(bones, dtype=np.int32)
    if np.any(np.asarray(parents)[bones] < 0):
        raise ValueError("every bone must name a joint that has a parent")
    ra = jnp.broadcast_to(jnp.asarray(radius_start, positions.dtype), bones.shape)
    rb = ra if radius_end is None else jnp.broadcast_to(jnp.asarray(radius_end, positions.dtype), bones.shape)
    a = positions[np.asarray(parents)[bones]]
    b = positions[bones]
    if head is None:
        centre = jnp.zeros((0, 3), positions.dtype)
        axes = jnp.zeros((0, 3, 3), positions.dtype)
    else:
        base, tip = positions[head[0]], positions[head[1]]
        ahat, L = axis_length(base[None], tip[None])
        hl = L if head_length is None else jnp.asarray(head_length, positions.dtype)[None]
        e1, e2 = orthonormal_basis(ahat)
        r = jnp.asarray(head_radius, positions.dtype)
        centre = base[None] + 0.5 * hl[:, None] * ahat
        axes = jnp.stack([r * e1, r * e2, 0.5 * hl[:, None] * ahat], -1)
    return Primitives(a, b, ra, rb, centre, axes)


# ---------------------------------------------------------------------------------------------------------------
# Rays


def pixel_rays(K: np.ndarray, dist: np.ndarray | None, size: tuple[int, int]) -> np.ndarray:
    """Undistorted normalised coordinates ``(H, W, 2)`` float32 of every pixel centre: ray ``d = (x, y, 1)``.

    ``size = (w, h)``. With ``dist`` (OpenCV ``[k1, k2, p1, p2, k3]``) not all zero, the distortion is inverted by
    ``cv2.undistortPointsIter`` (iterated to 1e-10), so that projecting ``(x, y, 1)`` with the lens model gives
    back the pixel.
    """
    w, h = int(size[0]), int(size[1])
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    K = np.asarray(K, dtype=np.float64)
    if dist is None or not np.any(np.asarray(dist)):
        Kinv = np.linalg.inv(K)
        pts = np.stack([u, v, np.ones_like(u)], -1) @ Kinv.T
        xy = pts[..., :2] / pts[..., 2:3]
    else:
        pts = np.stack([u.ravel(), v.ravel()], -1)[:, None, :]
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
        xy = cv2.undistortPointsIter(pts, K, np.asarray(dist, np.float64).ravel(), None, None, crit)
        xy = xy.reshape(h, w, 2)
    return xy.astype(np.float32)


# ---------------------------------------------------------------------------------------------------------------
# Ray casting


def _prepare(p: Primitives) -> dict:
    """Per-primitive constants of a camera-frame scene (camera at the origin), computed once per frame."""
    out = {}
    if p.num_cones:
        ahat, L = axis_length(p.cone_a, p.cone_b)
        w = -p.cone_a
        z0 = jnp.sum(w * ahat, -1)
        wp = w - z0[:, None] * ahat
        k = jnp.where(L > 0, (p.r_b - p.r_a) / jnp.where(L > 0, L, 1.0), 0.0)
        rho0 = p.r_a + k * z0
        wp2 = jnp.sum(wp * wp, -1)
        out.update(
            ahat=ahat,
            wp=wp,
            z0=z0,
            L=L,
            g=1.0 + k * k,
            k=k,
            kr=k * rho0,
            rho0=rho0,
            C=wp2 - rho0 * rho0,
            wp2=wp2,
            ra2=p.r_a * p.r_a,
            rb2=p.r_b * p.r_b,
            sa=wp2 + z0 * z0 - p.r_a * p.r_a,  # |camera − a|² − r_a²
            sb=wp2 + (z0 - L) ** 2 - p.r_b * p.r_b,  # |camera − b|² − r_b²
            a=p.cone_a,
            b=p.cone_b,
        )
    if p.num_ellipsoids:
        Minv = jnp.linalg.inv(p.ell_axes)
        o = -jnp.einsum("eij,ej->ei", Minv, p.ell_centre)
        out.update(Minv=Minv, o=o, oo=jnp.sum(o * o, -1) - 1.0, centre=p.ell_centre)
    # per-label table for the normal pass: cones [a, â, b, k], ellipsoids [centre, M⁻¹ (row-major)]
    rows = []
    if p.num_cones:
        rows.append(jnp.concatenate([p.cone_a, out["ahat"], p.cone_b, out["k"][:, None]], -1))
        rows[-1] = jnp.pad(rows[-1], ((0, 0), (0, 2)))
    if p.num_ellipsoids:
        rows.append(jnp.concatenate([p.ell_centre, out["Minv"].reshape(-1, 9)], -1))
    out["table"] = jnp.concatenate(rows, 0)
    return out


def _cast(x: jnp.ndarray, y: jnp.ndarray, c: dict, C: int, E: int, caps: str):
    """Nearest hit along ``d = (x, y, 1)`` for flat pixel arrays ``(P,)``: ``(τ, label, part)`` (inf, −1, 0 for
    none). All primitives at once: per-primitive constants ``(C, 1)`` broadcast against pixels ``(1, P)``, then a
    minimum over the primitive axis (ties go to the lower label)."""
    inf = jnp.asarray(jnp.inf, x.dtype)
    x, y = x[None, :], y[None, :]
    dd = x * x + y * y + 1.0
    taus, parts = [], []
    if C:
        col = lambda name, j=None: (c[name] if j is None else c[name][:, j])[:, None]
        z0, L, Cq, k, rho0 = col("z0"), col("L"), col("C"), col("k"), col("rho0")
        dz = col("ahat", 0) * x + col("ahat", 1) * y + col("ahat", 2)
        wpd = col("wp", 0) * x + col("wp", 1) * y + col("wp", 2)
        A = dd - col("g") * dz * dz
        B = wpd - col("kr") * dz
        disc = B * B - A * Cq
        sq = jnp.sqrt(jnp.maximum(disc, 0.0))
        q = -(B + jnp.where(B >= 0, sq, -sq))
        ok = disc >= 0
        tau = jnp.full(dz.shape, inf)
        for root in (q / A, Cq / q):
            z = z0 + root * dz
            good = ok & (root > 0) & (z >= 0) & (z <= L) & (rho0 + k * (z - z0) >= 0)
            tau = jnp.minimum(tau, jnp.where(good, root, inf))
        prt = jnp.zeros(dz.shape, jnp.int32)
        if caps == "flat":
            inv = 1.0 / dz
            dperp2 = dd - dz * dz
            for end, (t_end, r2) in enumerate(((-z0 * inv, col("ra2")), ((L - z0) * inv, col("rb2")))):
                rad2 = col("wp2") + t_end * (2.0 * wpd + t_end * dperp2)
                t_cap = jnp.where((t_end > 0) & (rad2 <= r2), t_end, inf)
                upd = t_cap < tau
                tau, prt = jnp.where(upd, t_cap, tau), jnp.where(upd, end + 1, prt)
        else:
            inv_dd = 1.0 / dd
            for end, (wd, s0) in enumerate(((wpd + z0 * dz, col("sa")), (wpd + (z0 - L) * dz, col("sb")))):
                disc_s = wd * wd - dd * s0
                t_s = (-wd - jnp.sqrt(jnp.maximum(disc_s, 0.0))) * inv_dd
                t_s = jnp.where((disc_s >= 0) & (t_s > 0), t_s, inf)
                upd = t_s < tau
                tau, prt = jnp.where(upd, t_s, tau), jnp.where(upd, end + 1, prt)
        taus.append(tau)
        parts.append(prt)
    if E:
        M, o = c["Minv"], c["o"]
        d = [M[:, r, 0:1] * x + M[:, r, 1:2] * y + M[:, r, 2:3] for r in range(3)]
        A = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        B = o[:, 0:1] * d[0] + o[:, 1:2] * d[1] + o[:, 2:3] * d[2]
        disc = B * B - A * c["oo"][:, None]
        tau = (-B - jnp.sqrt(jnp.maximum(disc, 0.0))) / A
        taus.append(jnp.where((disc >= 0) & (tau > 0), tau, inf))
        parts.append(jnp.full(tau.shape, PART_ELLIPSOID, jnp.int32))
    tau = jnp.concatenate(taus, 0)
    part = jnp.concatenate(parts, 0)
    label = jnp.argmin(tau, axis=0).astype(jnp.int32)
    best = jnp.take_along_axis(tau, label[None], 0)[0]
    part = jnp.take_along_axis(part, label[None], 0)[0]
    hit = best < inf
    return best, jnp.where(hit, label, -1), jnp.where(hit, part, 0)


def _normals(x, y, depth, label, part, c: dict, C: int, E: int, caps: str):
    """Outward unit normals ``(n_x, n_y, n_z)`` (camera frame, 0 for background) at the hits, per coordinate,
    from the per-label table gathered per pixel."""
    g = c["table"][jnp.maximum(label, 0)]
    col = [g[:, j] for j in range(12)]
    P = (x * depth, y * depth, depth)
    if C:
        a, ah, b, k = col[0:3], col[3:6], col[6:9], col[9]
        w = [P[i] - a[i] for i in range(3)]
        z = w[0] * ah[0] + w[1] * ah[1] + w[2] * ah[2]
        rad = [w[i] - z * ah[i] for i in range(3)]
        rn = jax.lax.rsqrt(jnp.maximum(rad[0] ** 2 + rad[1] ** 2 + rad[2] ** 2, 1e-30))
        n = [rad[i] * rn - k * ah[i] for i in range(3)]
        if caps == "flat":
            cap_a, cap_b = [-v for v in ah], list(ah)
        else:
            cap_a, cap_b = w, [P[i] - b[i] for i in range(3)]
        n = [
            jnp.where(part == PART_CAP_A, cap_a[i], jnp.where(part == PART_CAP_B, cap_b[i], n[i]))
            for i in range(3)
        ]
    else:
        n = [jnp.zeros_like(x)] * 3
    if E:
        m, Mi = col[0:3], col[3:12]
        v = [P[i] - m[i] for i in range(3)]
        yv = [Mi[3 * r] * v[0] + Mi[3 * r + 1] * v[1] + Mi[3 * r + 2] * v[2] for r in range(3)]
        ne = [Mi[j] * yv[0] + Mi[3 + j] * yv[1] + Mi[6 + j] * yv[2] for j in range(3)]
        n = [jnp.where(part == PART_ELLIPSOID, ne[i], n[i]) for i in range(3)]
    inv = jax.lax.rsqrt(jnp.maximum(n[0] ** 2 + n[1] ** 2 + n[2] ** 2, 1e-30))
    hit = label >= 0
    return [jnp.where(hit, v * inv, 0.0) for v in n]


def _pixels(x, y, c, C, E, caps, normals):
    best, label, part = _cast(x, y, c, C, E, caps)
    depth = jnp.where(label >= 0, best, 0.0)
    if normals:
        n = _normals(x, y, depth, label, part, c, C, E, caps)
    else:
        n = [jnp.zeros_like(x)] * 3
    return depth, label, n


def _sphere_range(cx, cz, r):
    """Range of ``x/z`` over spheres with centre ``(cx, ·, cz)`` and radius ``r`` (the tangent planes through the
    camera's other image axis): ``s = (cx cz ± r √(cx² + cz² − r²)) / (cz² − r²)``; ``±∞`` unless the sphere lies
    in front of the camera plane (``cz > r``)."""
    front = cz > r * 1.0001 + 1e-6
    den = jnp.where(front, cz * cz - r * r, 1.0)
    rt = r * jnp.sqrt(jnp.maximum(cx * cx + cz * cz - r * r, 0.0))
    lo = jnp.where(front, (cx * cz - rt) / den, -jnp.inf)
    hi = jnp.where(front, (cx * cz + rt) / den, jnp.inf)
    return lo, hi


def _bounds(p: Primitives) -> jnp.ndarray:
    """``(C + E, 4)`` conservative ranges ``[x_lo, x_hi, y_lo, y_hi]`` of the normalised image coordinates each
    camera-frame primitive covers. A flat- or sphere-capped cone lies in the convex hull of the spheres
    ``(a, r_a)`` and ``(b, r_b)`` and, in front of the camera, the range of ``x/z`` over a convex hull is the union
    of the ranges of its parts; an ellipsoid lies in its sphere of radius the longest semi-axis."""
    centres = [p.cone_a, p.cone_b, p.ell_centre]
    radii = [p.r_a, p.r_b, jnp.sqrt(jnp.max(jnp.sum(p.ell_axes**2, axis=-2), axis=-1))]
    out = []
    for axis in (0, 1):
        r = [_sphere_range(cc[:, axis], cc[:, 2], rr) for cc, rr in zip(centres, radii, strict=True)]
        lo = jnp.concatenate([jnp.minimum(r[0][0], r[1][0]), r[2][0]])
        hi = jnp.concatenate([jnp.maximum(r[0][1], r[1][1]), r[2][1]])
        out += [lo, hi]
    return jnp.stack(out, -1)


@functools.partial(jax.jit, static_argnames=("caps", "normals", "tile", "cull"))
def render(
    rays: jnp.ndarray,
    R: jnp.ndarray,
    t: jnp.ndarray,
    prims: Primitives,
    caps: str = "flat",
    normals: bool = True,
    tile: int = 16,
    cull: bool = True,
) -> Render:
    """Ray-cast one view.

    Args:
      rays: ``(H, W, 2)`` undistorted normalised pixel coordinates from :func:`pixel_rays`.
      R, t: world → camera rotation ``(3, 3)`` and translation ``(3,)``.
      prims: world :class:`Primitives`.
      caps: ``"flat"`` or ``"sphere"`` (static).
      normals: compute the normal map (static; zeros otherwise).
      tile: static tile side in pixels: the image is cast tile by tile (``tile²`` rays against all primitives at
        once, so intermediates stay in cache), in a ``fori_loop`` with a data-dependent trip count.
      cull: static; skip the tiles no primitive can cover: each tile's range of normalised coordinates is
        compared with every primitive's conservative image range (:func:`_bounds`); skipped tiles are
        background. Culling changes no pixel (tested).

    Returns:
      :class:`Render` with ``(H, W)`` maps. One compilation per ``(H, W, C, E)`` and static options.
    """
    if caps not in CAPS:
        raise ValueError(f"caps must be one of {CAPS}")
    H, W = rays.shape[0], rays.shape[1]
    pc = prims.transformed(R, t)
    C, E = pc.num_cones, pc.num_ellipsoids
    if C + E == 0:
        z = jnp.zeros((H, W), rays.dtype)
        return Render(z, jnp.full((H, W), -1, jnp.int32), jnp.zeros((H, W, 3), rays.dtype))
    c = _prepare(pc)
    th, tw = -(-H // tile), -(-W // tile)
    padded = jnp.pad(rays, ((0, th * tile - H), (0, tw * tile - W), (0, 0)), mode="edge")
    tiles = padded.reshape(th, tile, tw, tile, 2).transpose(0, 2, 1, 3, 4).reshape(th * tw, tile * tile, 2)
    tx, ty = tiles[..., 0], tiles[..., 1]
    box = _bounds(pc)  # (C+E, 4)
    overlap = (
        (jnp.min(tx, 1)[:, None] <= box[None, :, 1])
        & (jnp.max(tx, 1)[:, None] >= box[None, :, 0])
        & (jnp.min(ty, 1)[:, None] <= box[None, :, 3])
        & (jnp.max(ty, 1)[:, None] >= box[None, :, 2])
    )
    active = jnp.any(overlap, axis=1) if cull else jnp.ones(overlap.shape[0], bool)
    order = jnp.argsort(~active, stable=True).astype(jnp.int32)
    n_active = jnp.sum(active).astype(jnp.int32)
    T, Pt = th * tw, tile * tile
    zero = jnp.zeros((T, Pt), rays.dtype)
    init = (zero, jnp.full((T, Pt), -1, jnp.int32)) + ((zero, zero, zero) if normals else ())

    def body(i, bufs):
        ti = order[i]
        depth, label, n = _pixels(tx[ti], ty[ti], c, C, E, caps, normals)
        new = (depth, label) + (tuple(n) if normals else ())
        return tuple(b.at[ti].set(v) for b, v in zip(bufs, new, strict=True))

    bufs = jax.lax.fori_loop(0, n_active, body, init)

    def untile(a):
        a = a.reshape((th, tw, tile, tile) + a.shape[2:])
        a = jnp.swapaxes(a, 1, 2).reshape((th * tile, tw * tile) + a.shape[4:])
        return a[:H, :W]

    nor = jnp.stack([untile(b) for b in bufs[2:]], -1) if normals else jnp.zeros((H, W, 3), rays.dtype)
    return Render(untile(bufs[0]), untile(bufs[1]), nor)


@functools.lru_cache(maxsize=16)
def _cached_rays(K_bytes: bytes, dist_bytes: bytes, size: tuple[int, int]) -> jnp.ndarray:
    K = np.frombuffer(K_bytes, dtype=np.float64).reshape(3, 3)
    dist = np.frombuffer(dist_bytes, dtype=np.float64)
    return jnp.asarray(pixel_rays(K, dist, size))


def render_view(
    K, dist, R, t, size: tuple[int, int], prims: Primitives, caps: str = "flat", normals: bool = True
):
    """:func:`render` for a camera given by ``K (3,3)``, ``dist (5,)`` or None, ``R``, ``t``, ``size = (w, h)``;
    the per-pixel rays are computed once per camera and cached."""
    K = np.ascontiguousarray(K, dtype=np.float64)
    d = np.zeros(5) if dist is None else np.ascontiguousarray(dist, dtype=np.float64).ravel()
    rays = _cached_rays(K.tobytes(), d.tobytes(), (int(size[0]), int(size[1])))
    return render(
        rays, jnp.asarray(R, rays.dtype), jnp.asarray(t, rays.dtype), prims, caps=caps, normals=normals
    )


# ---------------------------------------------------------------------------------------------------------------
# Host-side image formation (NumPy / OpenCV)

#: Default colours (RGB, 0–1): a clothing colour per limb and skin for head and hands.
SKIN = (0.87, 0.67, 0.55)
CLOTHING = (
    (0.20, 0.30, 0.65),
    (0.70, 0.15, 0.15),
    (0.15, 0.55, 0.25),
    (0.85, 0.65, 0.10),
    (0.45, 0.20, 0.55),
    (0.10, 0.55, 0.60),
    (0.35, 0.35, 0.35),
    (0.80, 0.40, 0.10),
)
_SKIN_WORDS = ("head", "neck", "hand", "finger", "thumb", "wrist", "face")


def label_colours(names: Sequence[str]) -> np.ndarray:
    """``(n, 3)`` RGB colours for labels named ``names``: skin for head/neck/hands, else a clothing colour per
    limb, the same for the left and right limb of a pair (names differing only by a left/right prefix)."""
    out, groups = [], {}
    for name in names:
        low = name.lower()
        if any(wd in low for wd in _SKIN_WORDS):
            out.append(SKIN)
            continue
        key = low
        for pre in ("left_", "right_", "left", "right", "l_", "r_"):
            if key.startswith(pre):
                key = key[len(pre) :]
                break
        if key not in groups:
            groups[key] = CLOTHING[len(groups) % len(CLOTHING)]
        out.append(groups[key])
    return np.asarray(out, dtype=np.float64)


def shade(
    rendered: Render,
    colours: np.ndarray,
    light: Sequence[float] = (0.3, -0.6, -1.0),
    ambient: float = 0.35,
    illumination: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Lambert shading: ``I = illumination · colour[label] · (ambient + (1 − ambient) max(0, n·l̂))``.

    ``light`` points from the surface towards the light, in the camera frame (``x`` right, ``y`` down, ``z``
    forward; the default is above the camera, slightly to the right). Returns ``(rgb (H, W, 3) float in [0, 1],
    mask (H, W) bool)``; ``illumination`` scales the light (a global illumination change).
    """
    label = np.asarray(rendered.label)
    n = np.asarray(rendered.normal, dtype=np.float64)
    l_hat = np.asarray(light, dtype=np.float64)
    l_hat = l_hat / np.linalg.norm(l_hat)
    mask = label >= 0
    lam = np.clip(n @ l_hat, 0.0, None)
    col = np.asarray(colours, dtype=np.float64)[np.maximum(label, 0)]
    rgb = illumination * col * (ambient + (1.0 - ambient) * lam)[..., None]
    rgb[~mask] = 0.0
    return np.clip(rgb, 0.0, 1.0), mask


def composite(rgb: np.ndarray, mask: np.ndarray, background: np.ndarray | None = None) -> np.ndarray:
    """Foreground over background: ``(H, W, 3)`` float in [0, 1]. ``background`` is uint8 (0–255) or float
    (0–1) of the same size, or None for black."""
    if background is None:
        bg = np.zeros_like(rgb)
    else:
        bg = np.asarray(background)
        bg = bg.astype(np.float64) / 255.0 if bg.dtype == np.uint8 else bg.astype(np.float64)
        if bg.shape != rgb.shape:
            raise ValueError(f"background {bg.shape} does not match the image {rgb.shape}")
    return np.where(mask[..., None], rgb, bg)


def average_frames(frames: Sequence[np.ndarray]) -> np.ndarray:
    """Motion blur: the mean of sub-frame images rendered at poses spread over the exposure (each composited
    over the background), which blurs the foreground along its real motion and mixes it with the background."""
    return np.mean(np.stack([np.asarray(f, dtype=np.float64) for f in frames]), axis=0)


def add_sensor_noise(rng: np.random.Generator, image: np.ndarray, sigma: float = 0.01) -> np.ndarray:
    """Gaussian sensor noise of standard deviation ``sigma`` (image units) then quantisation to uint8."""
    noisy = np.asarray(image, dtype=np.float64) + rng.normal(0.0, sigma, np.shape(image))
    return np.clip(np.rint(noisy * 255.0), 0, 255).astype(np.uint8)


def virtual_depth(
    rng: np.random.Generator, depth: np.ndarray, smooth_px: float = 1.5, noise_m: float = 0.02
) -> np.ndarray:
    """Li & Kulić's virtual depth sensor: front-surface depth, Gaussian-smoothed, plus Gaussian noise.

    Smoothing is a normalised convolution inside the silhouette, ``G∗(z·m) / G∗m`` (``G`` a Gaussian of
    ``smooth_px`` pixels, ``m`` the mask), so background zeros do not bleed into the body. Then
    ``z + N(0, noise_m²)``. Returns ``(H, W)`` uint16 millimetres, 0 where there is no depth.
    """
    z = np.asarray(depth, dtype=np.float64)
    m = (z > 0).astype(np.float64)
    if smooth_px > 0:
        num = cv2.GaussianBlur(z * m, (0, 0), smooth_px)
        den = cv2.GaussianBlur(m, (0, 0), smooth_px)
        z = np.where(m > 0, num / np.maximum(den, 1e-12), 0.0)
    z = z + (m > 0) * rng.normal(0.0, noise_m, z.shape)
    mm = np.where(m > 0, np.clip(np.rint(z * 1000.0), 1, 65535), 0)
    return mm.astype(np.uint16)


def write_depth_png(path: str | os.PathLike, depth_mm: np.ndarray) -> None:
    """Write a uint16 millimetre depth map as a 16-bit PNG."""
    arr = np.asarray(depth_mm)
    if arr.dtype != np.uint16 or arr.ndim != 2:
        raise ValueError("depth must be a 2-D uint16 array of millimetres")
    if not cv2.imwrite(os.fspath(path), arr):
        raise OSError(f"could not write {path}")


def read_depth_png(path: str | os.PathLike) -> np.ndarray:
    """Read a 16-bit millimetre depth PNG as float32 metres (0 = no depth)."""
    arr = cv2.imread(os.fspath(path), cv2.IMREAD_UNCHANGED)
    if arr is None:
        raise MocapInputError(path, "cannot read depth image")
    if arr.dtype != np.uint16 or arr.ndim != 2:
        raise MocapInputError(path, f"depth image must be single-channel 16-bit, got {arr.dtype} {arr.shape}")
    return arr.astype(np.float32) / 1000.0
