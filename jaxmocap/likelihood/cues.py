"""Cue energies: one pure function per cue, of one particle's projected geometry and one frame's observation.

Every cue returns an energy ``E ≥ 0`` — per view ``(V,)`` for image cues, a scalar for view-free cues (3D
distances, priors) — and the likelihood composes them in Gibbs form ``p(z | x) ∝ exp(−Σ_c Σ_v λ_c,v k_c w_v E_c,v)``
(:mod:`jaxmocap.likelihood.compose`). The Gaussian cues of Fontmarty et al. (``p ∝ exp(−D²/2σ²)``) have ``E = D²/2σ²``;
Li & Kulić's distances are rescaled to [0, 1] so that their weighting ``w_c = A^(−d_c)`` (A = 100, eq. 4) is the
same form with ``λ_c = k_c ln A``.

The geometry a cue reads (:class:`~jaxmocap.likelihood.cue_context.Geometry`) is computed once per particle for all cues; ``V`` views, ``P`` flesh
surface points, ``Q`` occluding-contour points, ``J`` evaluation joints. Work that depends on the observation only
(masked depth, packed colours, the foreground samples of the divergence cue) is done once per call by the cue's
``prepare`` step, not once per particle.

This module holds the silhouette, edge, depth, keypoint and 3D cues and the registry :data:`CUES` of every cue;
the colour and skin cues are in :mod:`jaxmocap.likelihood.colour_cues`, and :class:`Geometry`, :class:`CueContext`
and the sample lookups they share in :mod:`jaxmocap.likelihood.cue_context`.

Cues by source (name — definition):

* Fontmarty et al., IROS 2007 §III-B: ``edge_distance`` (distance transform at the contour points),
  ``colour_histogram`` (ROI colour histograms, Bhattacharyya distance), ``blobs3d`` (3D head/hand blobs),
  ``skin`` (skin colour at the projected head and hands), ``homogeneous_colour`` (per-limb colour spread).
* Li & Kulić §III-C: ``depth`` (eq. 1), ``edge_fraction`` (eq. 2), ``colour_template`` (eq. 3),
  ``wristband`` and ``ground`` (distance cue); their product of weights (eq. 4) is the ``li-kulic`` schedule.
* López Méndez 2009 §4.3, §6.4: ``foreground`` (eq. 4.3), ``head_skin`` (eq. 4.4), ``edges`` (eq. 4.5),
  ``silhouette_divergence`` (eq. 4.6), ``interpenetration`` (eq. 6.2–6.3).
* 2D detections: ``keypoints`` (OpenPose BODY_25 / BODY_25B with confidences).

Image maps are read at the nearest pixel by default (one shared index per sample set: fast, piecewise constant in
the pose). ``bilinear=True`` reads them by bilinear interpolation instead, which makes a cue differentiable; the
cues whose default is a threshold or an inside test have a smooth variant with ``soft=True`` as well (and
``bilinear=True`` for their map reads): ``colour_histogram`` (triangular-kernel binning), ``edge_fraction`` (a C¹
ramp instead of the hit threshold), ``depth`` (the foreground/occlusion switch blended by the share of valid texels
of the bilinear read, the Charbonnier penalty ``√(r² + δ²) − δ`` for ``|r|``) and ``silhouette_divergence`` (a soft
silhouette: each primitive piece's coverage the logistic of its signed distance to its outline over a scale of
about a pixel). Each smooth variant tends to its default as its scale goes to 0; the defaults are unchanged.
:data:`DIFFERENTIABLE` lists, per cue, ``"yes"`` (always), ``"bilinear"`` (with ``bilinear=True``), ``"soft"``
(with ``soft=True`` and ``bilinear=True``) or ``"no"`` (none: no cue is that now); the gradient filters
(``jaxmocap track --filter hybrid`` / ``apf-refine``) set those parameters and refuse a ``"no"`` cue. In the
differentiable configurations a few switches remain on sets of measure zero in the pose (camera-facing tests,
clamps, minima): the energies are differentiable almost everywhere.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.features.observation import Observation
from jaxmocap.geometry import camera, flesh
from jaxmocap.io.openpose import BODY_25B_OF_JOINT
from jaxmocap.likelihood import coverage, maps
from jaxmocap.likelihood.colour_cues import (
    _prepare_colour,
    colour_histogram,
    colour_template,
    head_skin,
    homogeneous_colour,
    skin,
)

# re-exported (``x as x``): the reference builders of jaxmocap.likelihood.compose read them through this module
from jaxmocap.likelihood.colour_cues import _soft_bin_weights as _soft_bin_weights
from jaxmocap.likelihood.colour_cues import _surface_rgb as _surface_rgb
from jaxmocap.likelihood.cue_context import (
    CueContext,
    Geometry,
    _contour_values,
    _joint_index,
    _part_mean,
    _surface_values,
    _unit_scale,
)
from jaxmocap.likelihood.cue_context import _segment_ids as _segment_ids

#: Li & Kulić's penalty for a sample point outside the foreground in the depth cue (eq. 1), metres.
DEPTH_PENALTY_M = 2.8


# ---------------------------------------------------------------------------------------------------------------
# Silhouette and edge cues (López Méndez; Fontmarty et al.; Li & Kulić)


def foreground(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Foreground matching (López Méndez eq. 4.3): fraction of the model's surface samples that fall on background.

    ``E_v = (1/P) Σ_p (1 − F_v(u_vp))``; a sample outside the image counts as background.
    """
    F, inside = _surface_values(obs.foreground, g, ctx)
    return _part_mean(jnp.where(inside, 1.0 - F, 1.0), ctx, "surface")


def edges(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Edge matching (López Méndez eq. 4.5): ``E_v = (1/Q) Σ_q (1 − Ẽ_v(u_vq))`` on the occluding-contour points,
    with ``Ẽ`` the dilated, smoothed edge map in [0, 1] (§4.2); out-of-image points count as 1."""
    E, inside = _contour_values(obs.edges, g, ctx)
    return _part_mean(jnp.where(inside, 1.0 - E, 1.0), ctx, "contour")


def edge_distance(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Edge distance (Fontmarty et al. §III-B): ``p ∝ exp(−D²/2σ_e²)`` with ``D = (1/Q) Σ_q I_DT(u_q)`` the mean
    distance-transform value at the model's contour points, so ``E_v = D_v² / (2 σ_e²)``.

    Each distance is capped at ``max_px`` (default 30; out-of-image points take it), so that one stray point
    does not dominate; σ_e = ``sigma_px`` (default 6). Parameters in pixels.
    """
    sigma = ctx.params.get("sigma_px", 6.0)
    dmax = ctx.params.get("max_px", 30.0)
    D, inside = _contour_values(obs.edge_dt, g, ctx, unit=False)
    D = _part_mean(jnp.where(inside, jnp.minimum(D, dmax), dmax), ctx, "contour")
    return D * D / (2.0 * sigma * sigma)


def edge_fraction(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Li & Kulić edge cue (eq. 2): the fraction of projected contour pixels that are not on the edge map
    (edge value below ``threshold`` t, default 0.5); out-of-image points count as off.

    ``E_v = 1 − (1/Q) Σ_q [Ẽ_v(u_vq) ≥ t]`` with ``Ẽ`` the smoothed edge map in [0, 1] (§4.2, read at the nearest
    pixel). ``soft=True`` replaces the hit count by a soft one, ``E_v = 1 − (1/Q) Σ_q s((Ẽ_v(u_vq) − t) / h)``
    with the C¹ step :func:`_soft_step` (0 below ``t − h``, 1 above ``t + h``; ``softness`` h, default 0.25 of
    the map's range); with ``bilinear=True`` as well, ``Ẽ`` is read by bilinear interpolation (a blurred map,
    so ``Ẽ(u)`` is smooth between pixel centres) and the energy is differentiable in the pose. Where the map lies
    off the ramp (``|Ẽ − t| ≥ h``) the soft count is the hard one.
    """
    t = ctx.params.get("threshold", 0.5)
    if ctx.params.get("soft", False):
        E, inside = _contour_values(obs.edges, g, ctx)
        on = jnp.where(inside, _soft_step((E - t) / ctx.params.get("softness", 0.25)), 0.0)
        return 1.0 - _part_mean(on, ctx, "contour")
    E = maps.gather(obs.edges, g.contour_index, _unit_scale(obs.edges))
    on = g.contour_inside & (E >= t)
    return 1.0 - _part_mean(on.astype(E.dtype), ctx, "contour")


def _soft_step(z: jnp.ndarray) -> jnp.ndarray:
    """The C¹ step ``s(z) = ½ + ¾ z − ¼ z³`` on ``[−1, 1]``, 0 below and 1 above (slopes 0 at ±1)."""
    z = jnp.clip(z, -1.0, 1.0)
    return 0.5 + z * (0.75 - 0.25 * z * z)


def _prepare_depth(obs: Observation, ctx: CueContext, cache: dict):
    """Observed depth where the pixel is foreground (``F ≥ ½``; any measured pixel without a foreground map),
    else 0: one map, so the cue reads one value per sample. With ``bilinear=True`` its texel quads
    (:func:`jaxmocap.likelihood.maps.texel_quads`): one gather reads a sample's four texels."""
    D = obs.depth.astype(jnp.float32)
    if obs.has("foreground"):
        fg = obs.foreground.astype(jnp.float32) * _unit_scale(obs.foreground) >= 0.5
        D = jnp.where(fg, D, 0.0)
    if ctx.params.get("bilinear", False):
        return {"depth_quads": maps.texel_quads(D)}
    return {"depth": D}


def depth(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Li & Kulić depth cue (eq. 1), rescaled to [0, 1].

    For the camera-facing surface samples: ``d_p = ρ(z_p − D(u_p))`` where the observed pixel is foreground and
    has a depth, else the fixed penalty ``c`` = 2.8 m; ``E_v = min(mean_p d_p, c) / c``, with ``ρ(r) = |r|``.

    ``bilinear=True`` reads the masked depth ``D`` and its validity ``m = [D > 0]`` (:func:`_prepare_depth`) by
    bilinear interpolation, ``m̄(u)``, ``D̄(u)``, and blends the two cases by the share of valid texels:
    ``d_p = m̄ ρ(z_p − D̄/m̄) + (1 − m̄) c`` (``D̄/m̄``: the interpolated depth of the valid neighbours; ``m̄ = 0``
    out of the image), continuous where a sample crosses the silhouette's outline. ``soft=True`` takes the
    Charbonnier penalty ``ρ(r) = √(r² + δ²) − δ`` (``delta_m`` δ, default 0.02 m, the virtual sensor's noise;
    within δ of ``|r|``) instead of ``|r|``, smooth at ``r = 0``. With both the energy is differentiable in the
    pose (the facing test and the cap at ``c`` switch on sets of measure zero). Where all four texels are valid and
    the map is linear in the pixel coordinates, ``D̄`` is that plane exactly, and the nearest pixel's value is
    within ``(|∂D/∂u| + |∂D/∂v|) / 2`` of it.
    """
    soft = ctx.params.get("soft", False)
    if ctx.params.get("bilinear", False):
        i00, fu, fv, inside = maps.bilinear_index(g.surface_uv, obs.depth.shape)
        q = maps.gather(ctx.aux["depth_quads"], i00)  # (V, P, 4) texels
        w = maps.bilinear_weights(fu, fv)
        share = jnp.sum(w * (q > 0), axis=-1)  # m̄
        valid = jnp.where(inside, share, 0.0)
        r = g.surface_depth - jnp.sum(w * q, axis=-1) / jnp.maximum(share, 1e-6)
        d = valid * _depth_penalty(r, ctx, soft) + (1.0 - valid) * DEPTH_PENALTY_M
    else:
        Dm = maps.gather(ctx.aux["depth"], g.surface_index)
        ok = g.surface_inside & (Dm > 0)
        d = jnp.where(ok, _depth_penalty(g.surface_depth - Dm, ctx, soft), DEPTH_PENALTY_M)
    w = g.surface_facing.astype(d.dtype)
    if ctx.part is not None:
        w = w * ctx.part.surface.astype(d.dtype)
    mean = jnp.sum(d * w, axis=-1) / jnp.maximum(jnp.sum(w, axis=-1), 1.0)
    return jnp.minimum(mean, DEPTH_PENALTY_M) / DEPTH_PENALTY_M


def _depth_penalty(r: jnp.ndarray, ctx: CueContext, soft: bool) -> jnp.ndarray:
    """``ρ(r)`` of :func:`depth`: ``|r|``, or with ``soft`` the Charbonnier ``√(r² + δ²) − δ``."""
    if not soft:
        return jnp.abs(r)
    delta = ctx.params.get("delta_m", 0.02)
    return jnp.sqrt(r * r + delta * delta) - delta


#: Undistorted grids of the divergence cue (:func:`_grid_rays`), by calibration and grid: a few rigs at a time.
_GRID_RAYS: dict = {}


def _grid_rays(rig, grid: np.ndarray) -> np.ndarray | None:
    """``(V, G, 2)`` undistorted normalised camera coordinates of the pixel ``grid (G, 2)`` in every view of
    ``rig``, computed on the host once per calibration (:func:`jaxmocap.geometry.camera.undistort_points`, as
    the traced path computes them), or None when the calibration is traced (a rig passed into ``jit`` as data)."""
    try:
        key = (np.asarray(rig.K).tobytes(), np.asarray(rig.dist).tobytes(), grid.tobytes())
    except jax.errors.TracerArrayConversionError:
        return None
    if key not in _GRID_RAYS:
        if len(_GRID_RAYS) >= 8:
            _GRID_RAYS.pop(next(iter(_GRID_RAYS)))
        V = np.asarray(rig.K).shape[0]
        with jax.ensure_compile_time_eval():
            ab = camera.undistort_points(
                rig, jnp.broadcast_to(jnp.asarray(grid)[:, None], (grid.shape[0], V, 2))
            )
        _GRID_RAYS[key] = np.ascontiguousarray(np.moveaxis(np.asarray(ab, np.float32), 1, 0))
    return _GRID_RAYS[key]


def _prepare_divergence(obs: Observation, ctx: CueContext, cache: dict):
    """Foreground samples of the divergence cue, once per frame: the foreground value at a ``grid`` (columns,
    rows; default 80×60) of pixels, compacted to ``samples`` (default 256) slots per view — every foreground grid
    pixel once when there are at most that many (unused slots weigh 0), otherwise every (count/samples)-th in
    raster order (an evenly spread subsample) — with their weights and undistorted normalised camera coordinates.

    The grid is fixed, so its undistorted coordinates depend on the calibration only: they are computed once on
    the host (:func:`_grid_rays`) and the frame's samples gather theirs from that table — the same numbers as
    undistorting the picked pixels in the compiled program (which cost more than the rest of the cue: the
    iteration of the distortion model compiles into a slow fused loop on a CPU), done there only when the rig is
    traced. The grid values are read by indexing the map at the grid's rows and columns (nearest pixel: the
    grid points are pixel centres inside the image)."""
    V, H, W = obs.foreground.shape
    gc, gr = ctx.params.get("grid", (80, 60))
    M = int(ctx.params.get("samples", 256))
    us = np.floor((np.arange(gc) + 0.5) * (W / gc)).astype(np.int32)  # pixel centres, evenly spread
    vs = np.floor((np.arange(gr) + 0.5) * (H / gr)).astype(np.int32)
    grid = np.stack(np.meshgrid(us, vs), -1).reshape(-1, 2).astype(np.float32)
    G = grid.shape[0]
    F = obs.foreground[:, vs[:, None], us[None, :]].reshape(V, G).astype(jnp.float32)
    F = F * _unit_scale(obs.foreground)
    fg = F > 0
    count = jnp.cumsum(fg.astype(jnp.int32), axis=-1)  # (V, G)
    total = count[:, -1]
    j = jnp.arange(M)[None, :]
    spread = jnp.floor((j + 0.5) * total[:, None].astype(jnp.float32) / M).astype(jnp.int32)
    rank = jnp.where(total[:, None] <= M, j, spread)  # all of them, or an evenly spread subset
    pick = jax.vmap(lambda c, r: jnp.searchsorted(c, r + 1, side="left"))(count, rank)  # the (rank+1)-th
    pick = jnp.clip(pick, 0, G - 1)
    w = jnp.take_along_axis(F, pick, axis=-1) * (rank < total[:, None])
    rays = _grid_rays(ctx.rig, grid)
    if rays is not None:
        ab = jnp.take_along_axis(jnp.asarray(rays), pick[..., None], axis=1)  # (V, M, 2)
    else:
        uv = jnp.asarray(grid)[pick]  # (V, M, 2)
        ab = jnp.moveaxis(camera.undistort_points(ctx.rig, jnp.moveaxis(uv, 0, 1)), 1, 0)
    return {"x": ab[..., 0], "y": ab[..., 1], "w": w}


def _silhouette_pieces(prims: flesh.Primitives, R, t, x, y, pixel=None):
    """The pieces of the projected silhouette of the primitives at normalised image points ``(x, y)`` (``(M,)``,
    camera ``R, t``): for each, ``(value (M,), ok)`` with the point inside the piece iff ``value ≥ 0`` and ``ok``
    (exact for the flat-capped cones and the spheroids of :mod:`jaxmocap.geometry.flesh`).

    A cone's image is the convex quadrilateral spanned by its two contour generators (their four end points, in
    order, lie in one plane: the generators meet at the apex) united with the images of its two cap discs. A
    pixel ray ``d = (x, y, 1)`` meets the cap disc (centre ``c``, unit normal ``â``, radius ``r``, camera frame)
    iff ``s g > 0`` and ``f = s² |d|² − 2 s g (c·d) + g² (|c|² − r²) ≤ 0`` with ``s = â·c``, ``g = â·d`` (the ray
    hits the cap plane at ``t = s/g``; ``|t d − c| ≤ r``). A spheroid ``m + M y, |y| ≤ 1`` is hit iff, with
    ``e = M⁻¹ d`` and ``o = −M⁻¹ m``, ``q = (o·e)² − |e|² (|o|² − 1) ≥ 0`` and the far root is positive. Each test
    is a handful of multiply-adds per pixel and primitive, all fused into one loop over the pixels.

    ``pixel`` None: the values are the level functions themselves (the quadrilateral's ``min_k`` of its edge
    lines ``A_k x + B_k y + C_k``, ``−f``, ``q``) and ``ok`` the tests above. Otherwise (``pixel``: one pixel in
    normalised units, 1 / focal length) signed distances to the piece's outline (normalised units, positive
    inside) and ``ok`` weights in [0, 1]: the edge lines normalised to unit gradient, and for the conics ``h = −f``
    and ``q`` (quadratic in ``x, y``: constant Hessian ``∇²h``) the first-order distance
    ``h / √(|∇h|² + (10⁻³ ‖∇²h‖_F · pixel)²)`` (``h / |∇h|``, kept finite at a conic's centre). A first-order
    distance is meaningless near a nearly degenerate conic — a cap seen within a few degrees of edge-on, whose
    image is a sliver: along the sliver's line ``h`` and ``∇h`` both nearly vanish, and their ratio swings by
    pixels when the pose moves by micrometres — so a cap's weight is ``s((|s|/z_c − 0.04) / 0.02) · s(4u − 1)``
    (:func:`_soft_step`; ``z_c`` the centre's depth): 0 for a cap within ``|s| < 0.02 z_c`` of edge-on, whose
    sliver sticks out of the quadrilateral by at most 0.02 of its projected radius, and 1 from ``0.06 z_c`` on; and
    with ``u = g z_c / s`` (≈ ``z_c / z`` for a ray that meets the cap plane at depth ``z``: ≈ 1 on the disc's
    image) 0 from the plane's vanishing line ``g = 0`` on, where the test ``s g > 0`` switches, so that the
    coverage is continuous in the pose.
    """
    ca = prims.cone_a @ R.T + t
    cb = prims.cone_b @ R.T + t
    dd = x * x + y * y + 1.0

    def level(h, hx, hy, hess):  # hess: the three distinct entries of ∇²h
        if pixel is None:
            return h
        floor = (hess[0] ** 2 + hess[1] ** 2 + 2.0 * hess[2] ** 2) * (1e-3 * pixel) ** 2
        return h * jax.lax.rsqrt(hx * hx + hy * hy + floor)

    if prims.num_cones:
        g = flesh.cone_contours(ca, cb, prims.r_a, prims.r_b, jnp.zeros(3, ca.dtype), 2)  # (C, 2, 2, 3)
        quad = jnp.stack([g[:, 0, 0], g[:, 0, 1], g[:, 1, 1], g[:, 1, 0]], 1)  # (C, 4, 3): a+, b+, b−, a−
        front = jnp.all(quad[..., 2] > 1e-6, axis=-1)
        z = jnp.where(quad[..., 2] > 1e-6, quad[..., 2], 1.0)
        qx, qy = quad[..., 0] / z, quad[..., 1] / z  # (C, 4)
        nx, ny = jnp.roll(qx, -1, axis=1), jnp.roll(qy, -1, axis=1)
        A = -(ny - qy)
        B = nx - qx
        Cc = (ny - qy) * qx - (nx - qx) * qy
        orient = jnp.sign(jnp.sum(qx * ny - nx * qy, axis=1))  # (C,)
        A, B, Cc = A * orient[:, None], B * orient[:, None], Cc * orient[:, None]
        if pixel is not None:
            n = jax.lax.rsqrt(A * A + B * B + 1e-12)
            A, B, Cc = A * n, B * n, Cc * n
        ahat, _ = flesh.axis_length(ca, cb)
        for c in range(prims.num_cones):
            e = A[c, 0] * x + B[c, 0] * y + Cc[c, 0]
            for k in range(1, 4):
                e = jnp.minimum(e, A[c, k] * x + B[c, k] * y + Cc[c, k])
            yield e, front[c]
            gd = ahat[c, 0] * x + ahat[c, 1] * y + ahat[c, 2]
            for centre, r in ((ca[c], prims.r_a[c]), (cb[c], prims.r_b[c])):
                s = jnp.dot(ahat[c], centre)
                cd = centre[0] * x + centre[1] * y + centre[2]
                kappa = jnp.dot(centre, centre) - r * r
                f = s * s * dd - 2.0 * s * gd * cd + gd * gd * kappa
                fx, fy = (
                    2.0 * (s * s * xy - s * (ahat[c, i] * cd + gd * centre[i]) + gd * ahat[c, i] * kappa)
                    for i, xy in ((0, x), (1, y))
                )
                hess = [
                    2.0 * (s * s - 2.0 * s * ahat[c, i] * centre[i] + kappa * ahat[c, i] ** 2) for i in (0, 1)
                ] + [
                    2.0
                    * (
                        kappa * ahat[c, 0] * ahat[c, 1]
                        - s * (ahat[c, 0] * centre[1] + ahat[c, 1] * centre[0])
                    )
                ]
                if pixel is None:
                    yield -f, s * gd > 0
                else:  # weights: how open the cap is; the ray's hit at depth z = s / g (u = z_c / z, 0 at g = 0)
                    tilt = jnp.abs(s) / centre[2]
                    u = gd * centre[2] / jnp.where(tilt > 0.01, s, 0.01 * centre[2])
                    ok = _soft_step((tilt - 0.04) / 0.02) * _soft_step(4.0 * u - 1.0)
                    yield level(-f, -fx, -fy, hess), ok
    if prims.num_ellipsoids:
        m = prims.ell_centre @ R.T + t
        Mx = jnp.einsum("ij,ejk->eik", R, prims.ell_axes)  # columns: semi-axis vectors (orthogonal)
        Minv = jnp.swapaxes(Mx, -1, -2) / jnp.sum(Mx * Mx, axis=-2)[..., :, None]
        o = -jnp.einsum("eij,ej->ei", Minv, m)
        for k in range(prims.num_ellipsoids):
            e = [Minv[k, i, 0] * x + Minv[k, i, 1] * y + Minv[k, i, 2] for i in range(3)]
            oe = o[k, 0] * e[0] + o[k, 1] * e[1] + o[k, 2] * e[2]
            ee = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
            oo = jnp.dot(o[k], o[k])
            disc = oe * oe - ee * (oo - 1.0)
            po = [jnp.dot(o[k], Minv[k, :, j]) for j in (0, 1)]  # ∂(o·e)/∂x, ∂(o·e)/∂y
            qx, qy = (
                2.0 * (oe * po[j] - (oo - 1.0) * sum(e[i] * Minv[k, i, j] for i in range(3))) for j in (0, 1)
            )
            hess = [
                2.0 * (po[i] * po[j] - (oo - 1.0) * jnp.dot(Minv[k, :, i], Minv[k, :, j]))
                for i, j in ((0, 0), (1, 1), (0, 1))
            ]
            yield level(disc, qx, qy, hess), (oe < 0) | (oo <= 1.0)


def _silhouette_cover(prims: flesh.Primitives, R, t, x, y) -> jnp.ndarray:
    """``(M,)`` bool: whether normalised image points ``(x, y)`` (``(M,)``, camera ``R, t``) lie in the projected
    silhouette of any primitive: the union of the pieces of :func:`_silhouette_pieces`."""
    cover = jnp.zeros(x.shape, bool)
    for value, ok in _silhouette_pieces(prims, R, t, x, y):
        cover = cover | ((value >= 0) & ok)
    return cover


def _soft_silhouette_cover(prims: flesh.Primitives, R, t, x, y, scale, pixel) -> jnp.ndarray:
    """``(M,)`` in [0, 1]: the soft silhouette of the primitives at normalised image points ``(x, y)``.

    Each piece ``k`` of :func:`_silhouette_pieces` covers a point by ``c_k = σ(d_k / τ)``, the logistic of its
    signed distance to the piece's outline in pixels (``d_k = scale · τ ·`` the normalised distance, ``scale`` =
    focal length / τ), and the pieces are united as independent events, ``1 − Π_k (1 − c_k)`` =
    ``1 − exp(−Σ_k ok_k softplus(d_k / τ))`` (``ok_k`` the piece's weight). As τ → 0 this is the hard union
    :func:`_silhouette_cover` at every point off an outline (the distances have the sign of the level functions);
    a point at distance ``d`` from every outline is within ``K σ(−d/τ)`` of it (``K`` pieces). ``pixel``: one
    pixel in normalised units (:func:`_silhouette_pieces`).
    """
    total = jnp.zeros_like(x)
    for value, ok in _silhouette_pieces(prims, R, t, x, y, pixel=pixel):
        total = total + jnp.asarray(ok, value.dtype) * jax.nn.softplus(value * scale)
    return -jnp.expm1(-total)


def silhouette_divergence(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Foreground divergence (López Méndez eq. 4.6): the part of the observed silhouette the model does not occupy.

    ``E_v = Σ_s F(s) (1 − inside_v(s)) / Σ_s F(s)`` over the foreground samples ``s`` of the prepare step (a
    pixel grid, compacted), with ``inside_v`` the exact projected-silhouette test of the primitives (the samples are
    undistorted first, so lens distortion is taken into account). 0 when the view has no foreground. Together with
    :func:`foreground` (model on silhouette) it penalises both ways of disagreeing.

    ``soft=True``: ``inside_v`` is the soft silhouette :func:`_soft_silhouette_cover`, each primitive piece's
    coverage the logistic of its signed distance to its outline over ``scale_px`` τ (default 1 pixel, measured
    with the view's focal length ``K₀₀``): differentiable in the pose, and the hard cue as τ → 0. The samples
    are fixed by the observation, so ``bilinear`` has no effect here. The soft energy is larger than the hard one
    where limbs are a few τ wide (a sample inside a limb 2 px from its outline is covered by ≈ σ(2) = 0.88 only),
    and a conic's first-order distance a few pixels off a thin outline can be a fraction of the true one, so the
    soft silhouette reaches farther than τ past the caps: a likelihood built on it is its own, not the hard one's
    (at the true pose of a ``full25`` scene at 160×120, limbs 3–6 px wide: 0.14 per view, the hard cue 0).
    """
    a = ctx.aux
    R = jnp.asarray(ctx.rig.R, a["x"].dtype)
    t = jnp.asarray(ctx.rig.t, a["x"].dtype)
    soft = ctx.params.get("soft", False)
    out = []
    for v in range(R.shape[0]):
        w = a["w"][v]
        if soft:
            focal = jnp.asarray(ctx.rig.K[v, 0, 0], a["x"].dtype)
            scale = focal / ctx.params.get("scale_px", 1.0)
            cov = _soft_silhouette_cover(g.primitives, R[v], t[v], a["x"][v], a["y"][v], scale, 1.0 / focal)
            out.append(jnp.sum(w * (1.0 - cov)) / jnp.maximum(jnp.sum(w), 1e-12))
        else:
            cov = _silhouette_cover(g.primitives, R[v], t[v], a["x"][v], a["y"][v])
            out.append(jnp.sum(jnp.where(cov, 0.0, w)) / jnp.maximum(jnp.sum(w), 1e-12))
    return jnp.stack(out)


# ---------------------------------------------------------------------------------------------------------------
# 2D keypoints

#: OpenPose BODY_25 keypoint index of each model joint it has (joint centres only; the face points, neck,
#: mid-hip and feet are left out: they do not coincide with a model joint).
BODY_25_PAIRS: tuple[tuple[str, int], ...] = (
    ("right_shoulder", 2),
    ("right_elbow", 3),
    ("right_wrist", 4),
    ("left_shoulder", 5),
    ("left_elbow", 6),
    ("left_wrist", 7),
    ("right_hip", 9),
    ("right_knee", 10),
    ("right_ankle", 11),
    ("left_hip", 12),
    ("left_knee", 13),
    ("left_ankle", 14),
)
#: The same for OpenPose BODY_25B (:data:`jaxmocap.io.openpose.BODY_25B_OF_JOINT` but the neck).
BODY_25B_PAIRS: tuple[tuple[str, int], ...] = tuple(p for p in BODY_25B_OF_JOINT.items() if p[0] != "thorax")
KEYPOINT_LAYOUTS = {"body25": BODY_25_PAIRS, "body25b": BODY_25B_PAIRS}


def keypoints(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """2D keypoint cue: robust distance between projected model joints and detections with confidences.

    ``E_v = Σ_k c_vk ρ(‖u_vj(k) − z_vk‖ / σ) / Σ_k c_vk`` with the Geman–McClure ``ρ(r) = r² / (1 + r²)`` (bounded,
    so a wrong detection costs at most its confidence), σ in pixels (default 20); detections
    ``obs.keypoints2d (V, K, 3)`` = (u, v, confidence), e.g. from :func:`jaxmocap.io.openpose.load_openpose_json`.
    ``pairs``: static tuple of (model joint name, keypoint index), or ``layout`` = ``"body25"`` / ``"body25b"``
    (:data:`KEYPOINT_LAYOUTS`; default ``"body25b"``), restricted to the model's joints.
    """
    pairs = ctx.params.get("pairs")
    if pairs is None:
        pairs = tuple(
            p for p in KEYPOINT_LAYOUTS[ctx.params.get("layout", "body25b")] if p[0] in ctx.joint_names
        )
    sigma = ctx.params.get("sigma_px", 20.0)
    jidx = _joint_index(ctx, [j for j, _ in pairs])
    kidx = np.asarray([k for _, k in pairs])
    if kidx.max() >= obs.keypoints2d.shape[1]:
        raise ValueError(
            f"keypoint index {int(kidx.max())} but the detections have {obs.keypoints2d.shape[1]}"
        )
    det = obs.keypoints2d[:, kidx]  # (V, M, 3)
    d = g.joints_uv[:, jidx] - det[..., :2]
    r2 = jnp.sum(d * d, axis=-1) / (sigma * sigma)
    c = det[..., 2]
    if ctx.part is not None:
        c = c * ctx.part.joints[jidx].astype(c.dtype)
    return jnp.sum(c * r2 / (1.0 + r2), axis=-1) / jnp.maximum(jnp.sum(c, axis=-1), 1e-6)


# ---------------------------------------------------------------------------------------------------------------
# 3D cues and priors (scalar)


def blobs3d(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """3D blob distance (Fontmarty et al. §III-B): each detected skin blob ``b_k`` (head, hands) is explained by the
    nearest of the model's head and wrists: ``E = Σ_k c_k min_j ‖X_j − b_k‖² / (2σ²) / max(Σ_k c_k, 1)``, σ in
    metres (default 0.1)."""
    names = ctx.params.get("joints", ("head", "left_wrist", "right_wrist"))
    sigma = ctx.params.get("sigma_m", 0.1)
    X = g.joints[_joint_index(ctx, names)]  # (M, 3)
    d = obs.blobs3d[:, None, :] - X[None]  # (K, M, 3)
    d2 = jnp.min(jnp.sum(d * d, axis=-1), axis=-1)
    c = obs.blob_conf
    return jnp.sum(c * d2) / (2.0 * sigma * sigma) / jnp.maximum(jnp.sum(c), 1.0)


def wristband(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Wrist-band blob distance (Li & Kulić distance cue), rescaled to [0, 1].

    Each model wrist ``w`` is compared with the 3D band blobs ``obs.blobs3d`` (confidence ``c_k``): with ``slots``
    (static ((joint, blob slot), …): labelled bands) its own slot, otherwise the nearest confident blob;
    ``d_w = min(‖X_w − b‖, d_max) / d_max`` (``max_m`` d_max, default 0.5 m) and ``E = Σ_w c_w d_w / Σ_w c_w`` with
    ``c_w`` the matched blob's confidence; 0 when no band is seen."""
    dmax = ctx.params.get("max_m", 0.5)
    slots = ctx.params.get("slots")
    if slots is not None:
        wrists = _joint_index(ctx, [j for j, _ in slots])
        X = g.joints[wrists]
        k = np.asarray([s for _, s in slots])
        b, c = obs.blobs3d[k], obs.blob_conf[k]
        dist = jnp.sqrt(jnp.sum((X - b) ** 2, axis=-1) + 1e-12)
    else:
        wrists = _joint_index(ctx, ("left_wrist", "right_wrist"))
        X = g.joints[wrists]
        dist_all = jnp.sqrt(jnp.sum((X[:, None] - obs.blobs3d[None]) ** 2, axis=-1) + 1e-12)  # (2, K)
        dist_all = jnp.where(obs.blob_conf[None] > 0, dist_all, jnp.inf)
        j = jnp.argmin(dist_all, axis=-1)
        dist = jnp.take_along_axis(dist_all, j[:, None], axis=-1)[:, 0]
        c = jnp.where(jnp.isfinite(dist), obs.blob_conf[j], 0.0)
        dist = jnp.where(jnp.isfinite(dist), dist, dmax)
    d = jnp.minimum(dist, dmax) / dmax
    if ctx.part is not None:
        c = c * ctx.part.joints[wrists].astype(c.dtype)
    return jnp.sum(c * d) / jnp.maximum(jnp.sum(c), 1e-12)


def ground(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Ground distance (Li & Kulić distance cue): the feet may not go below the floor ``z = floor`` (default 0).

    ``E = Σ_ankles max(0, floor + clearance − z) / scale``; clearance (default 0: the body presets end at the
    ankle, which stands on the floor) and scale (default 0.05 m) are parameters; zero for feet above the floor.
    """
    names = [j for j in ("left_ankle", "right_ankle") if j in ctx.joint_names]
    if not names:
        return jnp.zeros((), g.joints.dtype)
    ankles = _joint_index(ctx, names)
    z = g.joints[ankles, 2]
    floor = ctx.params.get("floor", 0.0) + ctx.params.get("clearance", 0.0)
    below = jnp.maximum(floor - z, 0.0)
    if ctx.part is not None:
        below = below * ctx.part.joints[ankles].astype(below.dtype)
    return jnp.sum(below) / ctx.params.get("scale", 0.05)


#: Default inter-penetration pairs (segment names); pairs whose segments the model lacks are skipped.
INTERPENETRATION_PAIRS = (
    ("left_forearm", "torso"),
    ("right_forearm", "torso"),
    ("left_forearm", "chest"),
    ("right_forearm", "chest"),
    ("left_forearm", "right_forearm"),
    ("left_shin", "right_shin"),
)


def interpenetration(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Inter-penetration prior (López Méndez eq. 6.2–6.3): limbs may not pass through each other.

    For the static cone pairs ``pairs`` (segment names, or cone indices in :func:`jaxmocap.geometry.flesh.cone_segments`
    order; default :data:`INTERPENETRATION_PAIRS`), the closest points ``p_i(s*)``, ``p_j(t*)`` of the two cone axes
    (distance ``d``) are compared with the sum of the cones' radii there, ``r_i(s*) = r_a,i + s* (r_b,i − r_a,i)``
    (likewise ``r_j(t*)``): ``E = Σ max(0, r_i(s*) + r_j(t*) − d)² / s²`` (``scale`` s, 0.02 m). Comparing the
    radii at the closest points rather than the largest radii keeps tapered limbs that hang beside the torso
    (the rest pose) penetration-free.
    """
    prims = g.primitives
    cones = flesh.cone_segments(ctx.model)
    names = ctx.model.segment_names
    pairs = []
    for i, j in ctx.params.get("pairs", INTERPENETRATION_PAIRS):
        if isinstance(i, str):
            if i not in names or j not in names:
                continue
            si, sj = names.index(i), names.index(j)
            if si not in cones or sj not in cones:
                continue
            i, j = cones.index(si), cones.index(sj)
        pairs.append((int(i), int(j)))
    s = ctx.params.get("scale", 0.02)
    total = jnp.zeros((), prims.cone_a.dtype)
    for i, j in pairs:
        d, si, tj = _segment_distance(prims.cone_a[i], prims.cone_b[i], prims.cone_a[j], prims.cone_b[j])
        r = (
            prims.r_a[i]
            + si * (prims.r_b[i] - prims.r_a[i])
            + prims.r_a[j]
            + tj * (prims.r_b[j] - prims.r_a[j])
        )
        total = total + jnp.maximum(r - d, 0.0) ** 2
    return total / (s * s)


def _segment_distance(p0, p1, q0, q1):
    """Closest distance between segments ``p0p1`` and ``q0q1`` and the parameters ``s, t ∈ [0, 1]`` of the closest
    points ``p0 + s (p1 − p0)``, ``q0 + t (q1 − q0)`` (clamped; smooth almost everywhere): ``(d, s, t)``."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, f = jnp.dot(d1, d1), jnp.dot(d2, d2), jnp.dot(d2, r)
    b, c = jnp.dot(d1, d2), jnp.dot(d1, r)
    den = jnp.maximum(a * e - b * b, 1e-12)
    s = jnp.clip((b * f - c * e) / den, 0.0, 1.0)
    t = jnp.clip((b * s + f) / jnp.maximum(e, 1e-12), 0.0, 1.0)
    s = jnp.clip((b * t - c) / jnp.maximum(a, 1e-12), 0.0, 1.0)
    diff = p0 + s * d1 - (q0 + t * d2)
    return jnp.sqrt(jnp.dot(diff, diff) + 1e-12), s, t


# ---------------------------------------------------------------------------------------------------------------
# Registry


class CueSpec(NamedTuple):
    """A registered cue: ``energy(g, obs, ctx)``, whether it is per view, the geometry it needs (a function of its
    parameters), the observation fields it reads, whether it is differentiable (``"yes"``, ``"bilinear"``,
    ``"soft"`` = with ``soft=True`` and ``bilinear=True``, ``"no"``), an optional per-call
    ``prepare(obs, ctx, cache)``, an optional reference builder (see
    :meth:`jaxmocap.likelihood.compose.Likelihood.with_references`) and ``separate``: whether the likelihood
    composes the cue as a term of its own, after the sum of the λ table (the ``coverage`` cue; see
    :class:`jaxmocap.likelihood.compose.Likelihood`); ``partial``: whether the energy honours the sample weights of
    a partition (``CueContext.part``, :mod:`jaxmocap.likelihood.partition`), else it is the whole body's in every
    partition."""

    energy: Callable
    per_view: bool
    needs: Callable[[dict], frozenset]
    requires: tuple[str, ...]
    differentiable: str
    prepare: Callable | None = None
    reference: str | None = None
    separate: bool = False
    partial: bool = False


def _surface_needs(p):
    return frozenset({"surface"} if p.get("bilinear", False) else {"surface", "surface_index"})


def _contour_needs(p):
    return frozenset({"contour"} if p.get("bilinear", False) else {"contour", "contour_index"})


def _fixed(*parts):
    s = frozenset(parts)
    return lambda p: s


CUES: dict[str, CueSpec] = {
    "foreground": CueSpec(foreground, True, _surface_needs, ("foreground",), "bilinear"),
    "edges": CueSpec(edges, True, _contour_needs, ("edges",), "bilinear"),
    "edge_distance": CueSpec(edge_distance, True, _contour_needs, ("edge_dt",), "bilinear"),
    "edge_fraction": CueSpec(edge_fraction, True, _contour_needs, ("edges",), "soft"),
    "depth": CueSpec(
        depth, True, lambda p: _surface_needs(p) | {"facing"}, ("depth",), "soft", _prepare_depth
    ),
    "silhouette_divergence": CueSpec(
        silhouette_divergence, True, _fixed("primitives"), ("foreground",), "soft", _prepare_divergence
    ),
    "head_skin": CueSpec(head_skin, True, lambda p: _surface_needs(p) | {"facing"}, ("skin",), "bilinear"),
    "skin": CueSpec(skin, True, lambda p: _surface_needs(p) | {"joints", "facing"}, ("skin",), "bilinear"),
    "colour_histogram": CueSpec(
        colour_histogram,
        True,
        _fixed("surface", "surface_index", "facing"),
        ("rgb",),
        "soft",
        _prepare_colour,
        "histogram",
    ),
    "homogeneous_colour": CueSpec(
        homogeneous_colour,
        True,
        _fixed("surface", "surface_index", "facing"),
        ("rgb",),
        "bilinear",
        _prepare_colour,
    ),
    "colour_template": CueSpec(
        colour_template,
        True,
        _fixed("surface", "surface_index", "facing"),
        ("rgb",),
        "bilinear",
        _prepare_colour,
        "template",
    ),
    "keypoints": CueSpec(keypoints, True, _fixed("joints", "joints_uv"), ("keypoints2d",), "yes"),
    "blobs3d": CueSpec(blobs3d, False, _fixed("joints"), (), "yes"),
    "wristband": CueSpec(wristband, False, _fixed("joints"), (), "yes"),
    "ground": CueSpec(ground, False, _fixed("joints"), (), "yes"),
    "interpenetration": CueSpec(interpenetration, False, _fixed("primitives"), (), "yes"),
    "coverage": CueSpec(
        coverage.coverage, True, _fixed("primitives"), ("foreground",), "yes", coverage.prepare, separate=True
    ),
}

#: Cues whose energy a partition restricts to its own body parts (:mod:`jaxmocap.likelihood.partition`).
PARTIAL_CUES = (
    "foreground",
    "edges",
    "edge_distance",
    "edge_fraction",
    "depth",
    "colour_template",
    "keypoints",
    "wristband",
    "ground",
)
CUES = {n: s._replace(partial=n in PARTIAL_CUES) for n, s in CUES.items()}

#: Observation fields each cue reads (a clear error names the missing one).
REQUIRES: dict[str, tuple[str, ...]] = {n: s.requires for n, s in CUES.items()}
#: Differentiability of each cue in the pose (see the module docstring).
DIFFERENTIABLE: dict[str, str] = {n: s.differentiable for n, s in CUES.items()}
