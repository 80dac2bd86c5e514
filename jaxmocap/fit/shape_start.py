"""Body-shape calibration from the first frames of a recording, poses unknown.

:func:`calibrate_from_start` takes what a recording gives for ``T`` frames (the foreground of plate subtraction,
the edge distance maps, the 2D detections) and fits a body preset's limb lengths, radii and the ``T`` poses:

1. lengths: the limbs and widths measured from the triangulated detections
   (:func:`jaxmocap.io.subject.body_dimensions`, medians over the frames; :data:`MEASURED`, each only within
   :data:`MEASURED_RANGE` of the preset's), the preset's values for the rest (radii, torso, drops, head);
2. poses: each frame's model fitted to its detections (:func:`jaxmocap.tracking.init.keypoint_pose`: IK on the
   triangulated joints, then the reprojection fit), frames where that fails left out;
3. a joint fit of the dimensions and poses (:func:`jaxmocap.fit.shape.calibrate`, Adam on the log-ratios of the
   dimensions and the scaled poses) maximising

   ``J = −(1/T) Σ_t Σ_v [ w_k E_kp,tv + w_e E_edge,tv ] − κ (1/T) Σ_t (1/V) Σ_v (E_out,tv + E_cov,tv)``

   with ``E_kp`` the ``keypoints`` cue (Geman–McClure of the joint–detection distances, σ = ``sigma_px``; the
   thorax left out: a detector's neck keypoint is not the model's thorax), ``E_edge`` the bilinear
   ``edge_distance`` cue (weight 0 by default), and the silhouette outline distances of
   :func:`silhouette_distance` (pixels):

   * ``E_cov``: over ``M`` pixels of the observed silhouette's outline, the distance to the outline of the
     projected flesh primitives, two-sided: an outline pixel outside the model (too thin, too short) and one inside
     it (too fat) both cost their distance;
     The outline past the wrists and ankles (a person's hands and feet, which the preset has not) is left out
     (:func:`end_weights`);
   * ``E_out``: over the model's projected occluding contours, the distance beyond one pixel to the observed
     foreground (a limb that sticks out of the silhouette).

   Both are linear in pixels and zero-mean at the truth, so no side of the silhouette is preferred. The plain
   ``foreground`` cue (the fraction of model points on background) is not used: any model inside the silhouette
   is optimal for it, which is why a fit with it shrinks the radii.

Weights (``κ`` = :data:`SILHOUETTE_WEIGHT`, ``w_k`` = :data:`KEYPOINT_WEIGHT`, ``w_e`` = :data:`EDGE_WEIGHT`) were
chosen by measurement (``benchmarks/experiments/shape_calibration.py``, results in
``benchmarks/results/shape_calibration.md``): a larger keypoint weight lets the poses and lengths fit the detection
noise at the silhouettes' expense (at ``w_k = 8`` the objective of the fit beat that of the true dimensions and
poses), and the image edges (texture, background) pulled the arm radii off.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.fit import shape
from jaxmocap.geometry import body, camera, flesh
from jaxmocap.likelihood import compose, maps
from jaxmocap.likelihood import coverage as coverage_mod

__all__ = [
    "MIN_FRAMES",
    "SILHOUETTE_WEIGHT",
    "StartFit",
    "calibrate_from_start",
    "end_weights",
    "silhouette_data",
    "outline_distance",
    "silhouette_distance",
]

#: the fewest frames with a pose from the detections that a calibration accepts
MIN_FRAMES = 3
#: ``κ``, ``w_k``, ``w_e`` of the module docstring (per pixel of silhouette distance; per unit of the cues' energies)
SILHOUETTE_WEIGHT = 1.0
KEYPOINT_WEIGHT = 0.5
EDGE_WEIGHT = 0.0
#: the dimensions taken from the triangulated detections: the limbs and the widths. Not the torso length and the
#: shoulder drop, which the detector's neck keypoint (BODY_25B ``UpperNeck``, halfway up the neck) would set a few
#: centimetres long, nor the hip drop (the detections have no pelvis centre)
MEASURED = (
    "upper_arm_length",
    "forearm_length",
    "thigh_length",
    "shin_length",
    "shoulder_width",
    "hip_width",
)
#: a measured dimension is taken only within these factors of the preset's: detections triangulated from a close
#: stereo pair can put a joint tens of centimetres off along the rays (hip widths of 0.56 m measured on a synthetic
#: stereo sequence whose subject's is 0.20 m), and a start that far off does not come back; an adult's segments
#: lie well within ±20 % of the preset's
MEASURED_RANGE = (0.8, 1.25)
#: the cap of the inner side of the outline distance (pixels): an outline pixel deep inside the model (a hole in the
#: foreground) costs at most this
INNER_DMAX = 2.0
#: the cap ``d_max`` of both silhouette distances (pixels): a stray foreground blob or a lost limb costs at most this
SILHOUETTE_DMAX = 20.0


class StartFit(NamedTuple):
    """Result of :func:`calibrate_from_start`: the fitted dimensions (every one of the preset), the starting
    dimensions, the fitted and starting poses ``(T', D)`` of the frames used, their indices ``(T',)`` into the
    input, and the objective before each Adam step and after the last ``(steps + 1,)``."""

    dims: dict
    start_dims: dict
    states: np.ndarray
    start_states: np.ndarray
    frames: np.ndarray
    objective: np.ndarray


def silhouette_data(foreground: np.ndarray, samples: int = 256) -> dict:
    """The host-side data of :func:`silhouette_distance` for ``foreground (T, V, H, W)`` (float in [0, 1] or uint8;
    foreground where ≥ ½ of full scale): ``dt (T, V, H, W)`` the distance (pixels) of every pixel centre to the
    nearest foreground pixel centre (OpenCV's exact L2 transform; :data:`SILHOUETTE_DMAX` where a view has no
    foreground), ``uv (T, V, M, 2)`` and ``w (T, V, M)``: ``M = samples`` pixels of the silhouette's outline
    (foreground pixels with a background 4-neighbour) evenly spaced in raster order
    (:func:`jaxmocap.likelihood.coverage.silhouette_samples`), weight 0 for padding."""
    fg = np.asarray(foreground)
    fg = fg >= (128 if fg.dtype == np.uint8 else 0.5)
    T, V, H, W = fg.shape
    dt = np.full((T, V, H, W), SILHOUETTE_DMAX, np.float32)
    uv = np.zeros((T, V, samples, 2), np.float32)
    w = np.zeros((T, V, samples), np.float32)
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    for t in range(T):
        for v in range(V):
            m = fg[t, v].astype(np.uint8)
            if not m.any():
                continue
            dt[t, v] = cv2.distanceTransform(1 - m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
            outline = (m > 0) & (cv2.erode(m, cross, borderType=cv2.BORDER_REPLICATE) == 0)
            uv[t, v], w[t, v] = coverage_mod.silhouette_samples(outline, samples)
    return {"dt": dt, "uv": uv, "w": w}


#: the distal joints beyond which a person has what the preset does not model (hands past the wrists, feet past the
#: ankles), each with its limb's proximal joint, and how far the unmodelled part reaches (m): outline pixels within
#: this distance of the joint and beyond ``END_MARGIN`` before it along the limb are left out of ``E_cov``
ENDS = (("left_elbow", "left_wrist"), ("right_elbow", "right_wrist"), ("left_knee", "left_ankle"),
        ("right_knee", "right_ankle"))  # fmt: skip
END_REACH = 0.25
END_MARGIN = 0.05


def end_weights(model, rig: camera.Rig, X: np.ndarray, uv: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``w (T, V, M)`` with the outline samples ``uv (T, V, M, 2)`` past the hands and feet set to 0: for each pair
    ``(p, d)`` of :data:`ENDS` with joints of the poses ``X (T, D)`` projected to ``p', d'`` at camera depth ``z``,
    a sample ``q`` with ``‖q − d'‖ < f · END_REACH / z`` and ``(q − p')·(d' − p') / ‖d' − p'‖ > ‖d' − p'‖ −
    f · END_MARGIN / z`` (past a point ``END_MARGIN`` before the joint along the limb)."""
    names = model.joint_names
    pairs = [(names.index(a), names.index(b)) for a, b in ENDS if a in names and b in names]
    w = np.array(w, np.float32, copy=True)
    if not pairs:
        return w
    J = np.asarray(jax.vmap(lambda x: body.joint_positions(model, x))(jnp.asarray(X, model.offset.dtype)))
    f = np.asarray(rig.K)[:, 0, 0]
    for t in range(len(X)):
        puv, z = (np.asarray(a, np.float64) for a in camera.project_with_depth(rig, jnp.asarray(J[t])))
        for v in range(puv.shape[0]):
            q = uv[t, v].astype(np.float64)
            for a, b in pairs:
                axis = puv[v, b] - puv[v, a]
                length = max(float(np.linalg.norm(axis)), 1e-6)
                along = (q - puv[v, a]) @ axis / length
                zb = max(float(z[v, b]), 1e-3)
                near = np.linalg.norm(q - puv[v, b], axis=-1) < f[v] * END_REACH / zb
                past = along > length - f[v] * END_MARGIN / zb
                w[t, v][near & past] = 0.0
    return w


def _outlines(lik: compose.Likelihood, R: jnp.ndarray, t: jnp.ndarray, k: int) -> jnp.ndarray:
    """``(V, Q, 2)`` the model's occluding contours seen from each camera (``k`` points on each cone generator,
    ``2k`` on each ellipsoid's outline; :func:`jaxmocap.geometry.flesh.contour_points`), projected."""
    centres = camera.camera_centres(lik.rig)
    cones = jax.vmap(lambda c: flesh.contour_points(lik.model, R, t, c, k))(centres)  # (V, C, 2, k, 3)
    pts = [cones.reshape(centres.shape[0], -1, 3)]
    if flesh.ellipsoid_segments(lik.model):
        ell = jax.vmap(lambda c: flesh.ellipse_contour_points(lik.model, R, t, c, 2 * k))(centres)
        pts.append(ell.reshape(centres.shape[0], -1, 3))
    return camera.project_per_view(lik.rig, jnp.concatenate(pts, axis=1))


def outline_distance(ua, ub, pa, pb, uv, rounded) -> jnp.ndarray:
    """``(V, M)`` signed distance (pixels, negative inside) from samples ``uv (V, M, 2)`` to the union of projected
    primitives: axes ``ua → ub (V, S, 2)``, radii ``pa, pb (V, S)`` at their ends, ``rounded (S,)`` static bools.

    With ``s`` the sample's coordinate along the axis (length ``L``), ``p`` its distance from the axis line and
    ``ρ = pa + clip(s / L, 0, 1) (pb − pa)``: a flat-capped cone seen from the side is the trapezoid
    ``−max(s − L, −s) ≥ 0, p ≤ ρ``, whose signed distance is ``√(max(a, 0)² + max(l, 0)²)`` outside and
    ``max(a, l)`` inside, ``a = max(s − L, −s)``, ``l = p − ρ``; a rounded primitive (the head's spheroid) is the
    capsule ``‖q − nearest axis point‖ − ρ``. The union's distance is the minimum over primitives."""
    d = ub - ua
    L = jnp.sqrt(jnp.sum(d * d, axis=-1) + 1e-12)  # (V, S)
    n = d / L[..., None]
    q = uv[:, None, :, :] - ua[:, :, None, :]  # (V, S, M, 2)
    s = jnp.sum(q * n[:, :, None, :], axis=-1)
    p = jnp.abs(q[..., 0] * n[:, :, None, 1] - q[..., 1] * n[:, :, None, 0])
    tau = jnp.clip(s / L[..., None], 0.0, 1.0)
    rho = pa[..., None] + tau * (pb - pa)[..., None]
    ax = jnp.maximum(s - L[..., None], -s)
    lat = p - rho
    box = jnp.where(
        jnp.maximum(ax, lat) > 0,
        jnp.sqrt(jnp.maximum(ax, 0.0) ** 2 + jnp.maximum(lat, 0.0) ** 2 + 1e-12),
        jnp.maximum(ax, lat),
    )
    axial = jnp.clip(s, 0.0, L[..., None]) - s
    capsule = jnp.sqrt(axial**2 + p**2 + 1e-12) - rho
    return jnp.min(jnp.where(jnp.asarray(rounded)[None, :, None], capsule, box), axis=1)


def silhouette_distance(
    lik: compose.Likelihood, X: jnp.ndarray, data: dict, weight: float = SILHOUETTE_WEIGHT, k: int = 8
) -> jnp.ndarray:
    """``κ · (1/T) Σ_t (1/V) Σ_v (E_out + E_cov)`` of the module docstring for poses ``X (T, D)`` of ``lik``'s model
    in ``lik.rig``; ``data`` from :func:`silhouette_data`; both terms in pixels, capped at ``d_max`` =
    :data:`SILHOUETTE_DMAX`:

    * ``E_cov = Σ_m w_m |clip(d_m + ½, −d_in, d_max)| / Σ_m w_m`` over the observed outline pixels, ``d_m`` the
      signed distance (negative inside) of pixel ``m`` to the union of the projected flesh primitives
      (:func:`outline_distance`; radii ``f r / z``); ``+½``: an outline pixel's centre lies on average half a pixel inside the true outline;
      ``d_in`` = :data:`INNER_DMAX` caps the cost of holes in the foreground;
    * ``E_out = mean_q min(max(DT(c_q) − 1, 0), d_max)`` over the model's projected occluding-contour points
      ``c_q`` (:func:`_outlines`), ``DT`` the distance transform of the background: zero within a pixel of the
      observed foreground, so it adds no bias at the truth and only stops a limb sticking out of the silhouette.

    A model too fat or too thin by ``δ`` pixels costs about ``δ`` on each outline pixel of the limb.
    Differentiable in the poses and, through ``lik``, in the dimensions."""
    dmax = SILHOUETTE_DMAX
    rounded = np.asarray(
        [False] * len(flesh.cone_segments(lik.model)) + [True] * len(flesh.ellipsoid_segments(lik.model))
    )

    def one(x, dt, uv, w):
        R, t = body.segment_poses(lik.model, x)
        d_out, inside = maps.lookup_bilinear(dt, _outlines(lik, R, t, k))
        e_out = jnp.mean(jnp.where(inside, jnp.clip(d_out - 1.0, 0.0, dmax), dmax), axis=-1)  # (V,)
        a, b, ra, rb = coverage_mod._capsules(flesh.world_primitives(lik.model, R, t))
        ua, za = camera.project_with_depth(lik.rig, a)
        ub, zb = camera.project_with_depth(lik.rig, b)
        f = lik.rig.K[:, 0, 0][:, None]
        pa = f * ra[None] / jnp.maximum(za, 1e-3)
        pb = f * rb[None] / jnp.maximum(zb, 1e-3)
        d = outline_distance(ua, ub, pa, pb, uv, rounded)  # (V, M)
        d = jnp.clip(d + 0.5, -INNER_DMAX, dmax)
        d = jnp.abs(d)
        e_cov = jnp.sum(w * d, axis=-1) / jnp.maximum(jnp.sum(w, axis=-1), 1.0)
        return jnp.mean(e_out + e_cov)

    return weight * jnp.mean(jax.vmap(one)(X, data["dt"], data["uv"], data["w"]))


def _stack_frames(observations, keep: np.ndarray):
    return jax.tree_util.tree_map(lambda a: a[keep] if hasattr(a, "shape") and a.ndim else a, observations)


def calibrate_from_start(
    observations,
    rig: camera.Rig,
    keypoints: np.ndarray,
    *,
    keypoint_rig: camera.Rig | None = None,
    preset: str = "full25",
    init: dict | None = None,
    names: Sequence[str] | None = None,
    measure: bool = True,
    steps: int = 300,
    learning_rate: float = 0.02,
    silhouette_weight: float = SILHOUETTE_WEIGHT,
    keypoint_weight: float = KEYPOINT_WEIGHT,
    edge_weight: float = EDGE_WEIGHT,
    sigma_px: float = 3.0,
    surface_points: int = 300,
    samples: int = 256,
) -> StartFit:
    """Calibrate a subject's dimensions from ``T`` frames with unknown poses (module docstring).

    Args:
      observations: the frames' :class:`~jaxmocap.features.observation.Observation` stacked along a leading axis
        ``T`` (one pytree), in the pixels of ``rig``: ``foreground (T, V, H, W)`` (``jaxmocap track``'s features:
        plate or background subtraction), ``keypoints2d (T, V, 15, 3)`` (the detections as evaluation joints in
        these pixels) and, with ``edge_weight > 0``, ``edge_dt (T, V, H, W)`` (the edge distance transform).
      rig: the cameras of the feature maps.
      keypoints: ``(T, V, 15, 3)`` the detections as evaluation joints (u, v, confidence) in the pixels of
        ``keypoint_rig`` (default ``rig``): triangulated for the starting lengths and fitted for the poses.
      preset: the body preset (a model with the evaluation joints, e.g. ``full25``); init: starting dimensions
        (default the preset's), overridden by the measured lengths when ``measure``.
      names: the dimensions to fit (default :data:`jaxmocap.fit.shape.LENGTHS` + :data:`~jaxmocap.fit.shape.RADII`;
        names the preset's dimensions lack are dropped).
      steps, learning_rate: Adam on the log-ratios of the dimensions and the scaled poses
        (:func:`jaxmocap.fit.shape.calibrate`).
      silhouette_weight, keypoint_weight, edge_weight: ``κ``, ``w_k``, ``w_e``; sigma_px: the keypoint cue's σ.
      surface_points: flesh samples of the model; samples: ``M`` observed foreground pixels per view and frame.

    Returns:
      :class:`StartFit`.

    Raises:
      ValueError: fewer than :data:`MIN_FRAMES` frames, shapes that disagree, no foreground (or edge) maps or
        detections in them, no detection at all, or fewer than :data:`MIN_FRAMES` frames whose detections give a
        pose.
    """
    from jaxmocap.io.subject import body_dimensions
    from jaxmocap.tracking.init import KEYPOINT_OF, keypoint_pose

    kp = np.asarray(keypoints, np.float64)
    krig = rig if keypoint_rig is None else keypoint_rig
    if kp.ndim != 4 or kp.shape[2:] != (len(body.EVAL_JOINTS), 3) or kp.shape[1] != rig.num_views:
        raise ValueError(
            f"keypoints must be (T, {rig.num_views}, {len(body.EVAL_JOINTS)}, 3) evaluation joints, got {kp.shape}"
        )
    T = kp.shape[0]
    if T < MIN_FRAMES:
        raise ValueError(f"body-shape calibration needs at least {MIN_FRAMES} frames, got {T}")
    for field in ("foreground", "edge_dt") if edge_weight > 0 else ("foreground",):
        a = getattr(observations, field, None)
        if a is None or np.ndim(a) != 4 or a.shape[:2] != (T, rig.num_views):
            got = None if a is None else tuple(a.shape)
            raise ValueError(f"observations.{field} must be (T={T}, V={rig.num_views}, H, W), got {got}")
    k2 = getattr(observations, "keypoints2d", None)
    if k2 is None or np.ndim(k2) != 4 or k2.shape[:3] != (T, rig.num_views, len(body.EVAL_JOINTS)):
        got = None if k2 is None else tuple(k2.shape)
        raise ValueError(f"observations.keypoints2d must be (T={T}, V={rig.num_views}, 15, 3), got {got}")
    if not np.any(kp[..., 2] > 0):
        raise ValueError("no detections in the calibration frames: the poses cannot be initialised")
    dims0 = dict(body.DEFAULT_DIMENSIONS if init is None else {**body.DEFAULT_DIMENSIONS, **init})
    if measure:
        measured = body_dimensions(kp, krig)
        if len(measured) >= 6:
            lo, hi = MEASURED_RANGE
            dims0.update({n: v for n, v in measured.items() if n in MEASURED and lo <= v / dims0[n] <= hi})
    model0 = body.build(preset, dims0)
    states, keep = [], []
    for t in range(T):
        x = keypoint_pose(model0, krig, kp[t])
        if x is not None:
            states.append(x)
            keep.append(t)
    if len(keep) < MIN_FRAMES:
        raise ValueError(
            f"the detections give a pose in {len(keep)} of {T} frames; body-shape calibration needs {MIN_FRAMES}"
        )
    keep = np.asarray(keep)
    obs = _stack_frames(observations, keep)
    X0 = np.stack(states)
    pairs = tuple((j, k) for j, k in KEYPOINT_OF.items() if j in model0.joint_names and j != "thorax")
    cues = [compose.Cue("keypoints", keypoint_weight, {"pairs": pairs, "sigma_px": float(sigma_px)})]
    if edge_weight > 0:
        cues.append(compose.Cue("edge_distance", edge_weight, {"bilinear": True}))
    lik = compose.Likelihood.create(model0, rig, cues, surface_points=surface_points, chunk_size=0)
    data = silhouette_data(np.asarray(obs.foreground), samples)
    data["w"] = end_weights(model0, rig, X0, data["uv"], data["w"])
    data = {k: jnp.asarray(v) for k, v in data.items()}
    names = tuple(shape.LENGTHS + shape.RADII if names is None else names)
    names = tuple(n for n in names if n in dims0)
    fit = shape.calibrate(
        lik,
        obs,
        jnp.asarray(X0, model0.offset.dtype),
        names=names,
        init=dims0,
        steps=steps,
        learning_rate=learning_rate,
        penalty=(lambda L, X, d: silhouette_distance(L, X, d, silhouette_weight), data),
    )
    return StartFit(fit.dims, {k: float(v) for k, v in dims0.items()}, fit.states, X0, keep, fit.objective)
