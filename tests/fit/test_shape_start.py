"""Body-shape calibration from unknown poses (:func:`jaxmocap.fit.shape_start.calibrate_from_start`): a ``full25``
subject whose lengths and radii differ from the preset's by ±10 % is rendered (the project's ray caster, its own
flesh) into three small views in four poses; the fit sees only the silhouettes, their edge distance maps and noisy
2D detections (the projected joints plus seeded Gaussian noise), never the poses or the dimensions."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.features.observation import make_observation
from jaxmocap.fit import shape, shape_start
from jaxmocap.geometry import body, camera, render
from jaxmocap.synth.stage import look_at

W, H = 240, 180
#: the subject: preset dimension × factor (mixed signs)
FACTORS = dict(
    zip(
        ("upper_arm_length", "forearm_length", "thigh_length", "shin_length", "upper_arm_radius_bottom"),
        (0.90, 1.10, 1.10, 0.90, 1.10),
        strict=True,
    ),
    forearm_radius_bottom=0.90,
    thigh_radius_top=1.10,
    thigh_radius_bottom=0.90,
    shin_radius_top=0.90,
    torso_radius_top=1.10,
)
NOISE_PX = 1.0


def _rig():
    """Three cameras on a 3.1 m circle around the subject (azimuths 10°, 100°, 220°), 1.2–1.4 m high."""
    K = np.array([[0.9 * W, 0.0, (W - 1) / 2], [0.0, 0.9 * W, (H - 1) / 2], [0.0, 0.0, 1.0]])
    poses = [
        look_at(np.array([3.1 * np.cos(np.radians(a)), 3.1 * np.sin(np.radians(a)), z]), [0.0, 0.0, 0.95])
        for a, z in ((10, 1.3), (100, 1.2), (220, 1.4))
    ]
    R, t = (np.stack(v) for v in zip(*poses, strict=True))
    return camera.from_opencv(np.stack([K] * 3), np.zeros((3, 5)), R, t, image_size=[(W, H)] * 3)


#: the four poses: DOF name -> value per pose (0 where not given, the rest pose otherwise)
POSES = {
    "left_shoulder_rx": (0.5, 0.0, 0.0, 0.3),
    "left_shoulder_ry": (0.0, 0.0, -0.6, 0.0),
    "left_elbow": (0.9, 0.0, 0.6, 0.0),
    "right_shoulder_rx": (0.0, -0.6, 0.0, -0.3),
    "right_shoulder_ry": (0.0, 0.0, 0.5, 0.0),
    "right_elbow": (0.0, 1.1, 0.0, 0.0),
    "left_hip_ry": (0.0, -0.5, 0.0, 0.0),
    "right_hip_ry": (-0.4, 0.0, 0.0, 0.0),
    "left_knee": (0.0, 0.9, 0.0, 0.4),
    "right_knee": (0.7, 0.0, 0.0, 0.0),
    "root_rz": (0.0, 0.0, 0.6, -0.5),
}


def _poses(model):
    X = np.tile(np.asarray(model.rest_pose), (4, 1))
    for name, values in POSES.items():
        X[:, model.dof_index(name)] = values
    return jnp.asarray(X, model.offset.dtype)


@pytest.fixture(scope="module")
def scene():
    true = {**body.DEFAULT_DIMENSIONS, **{k: body.DEFAULT_DIMENSIONS[k] * f for k, f in FACTORS.items()}}
    model = body.full25(true)
    rig = _rig()
    X = _poses(model)
    rng = np.random.default_rng(7)
    obs, kps = [], []
    for x in X:
        prims = render.primitives_from_model(model, x)
        fgs, dts = [], []
        for v in range(rig.num_views):
            depth = render.render_view(rig.K[v], rig.dist[v], rig.R[v], rig.t[v], (W, H), prims).depth
            mask = (np.asarray(depth) > 0).astype(np.uint8)
            edges = cv2.Canny(mask * 255, 50, 150)
            fgs.append(mask.astype(np.float32))
            dts.append(
                cv2.distanceTransform((edges == 0).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
            )
        J = np.asarray(body.joint_positions(model, x))
        uv = np.asarray(camera.project(rig, J)) + rng.normal(0.0, NOISE_PX, (rig.num_views, len(J), 2))
        kp = np.concatenate([uv, np.ones(uv.shape[:2] + (1,))], -1)
        kps.append(kp)
        obs.append(make_observation(rig, foreground=fgs, edge_dt=dts, keypoints2d=kp))
    stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *obs)
    return true, model, rig, stacked, np.stack(kps)


@pytest.fixture(scope="module")
def fitted(scene):
    true, model, rig, obs, kp = scene
    return shape_start.calibrate_from_start(obs, rig, kp, steps=150)


def test_recovers_lengths_and_radii_from_unknown_poses(scene, fitted):
    """Measured (4 poses, 3 views at 240×180, 1 px detection noise, 150 steps): every radius within 4.1 % of the
    truth, from 9–11 % at the start; every length within 1.1 % (their start, the triangulated noisy detections,
    within 1.1 % as well). A pixel is about 1.4 cm at the subject, so 6 % of a 3–5 cm radius is 0.1–0.2 px.
    Bounds: every radius within 6 % and nearer the truth than its start, the radii's mean error at most a third of
    the start's (a fit that ignored the silhouettes keeps the start's 10 %), every length within 3 %. Radii hidden
    inside a neighbour's silhouette at a joint (the upper arm's top in the torso's, the forearm's top in the upper
    arm's) are not in :data:`FACTORS`: these few poses do not show them."""
    true, *_ = scene
    fit = fitted
    assert np.all(np.isfinite(fit.objective)) and fit.objective[-1] > fit.objective[0]
    errs, errs0 = {}, {}
    for n in FACTORS:
        errs[n] = (fit.dims[n] - true[n]) / true[n]
        errs0[n] = (fit.start_dims[n] - true[n]) / true[n]
        print(f"{n:>24}: start {100 * errs0[n]:+5.1f} %  fitted {100 * errs[n]:+5.1f} %")
    radii = [n for n in FACTORS if "radius" in n]
    assert np.mean([abs(errs[n]) for n in radii]) <= np.mean([abs(errs0[n]) for n in radii]) / 3
    bad = {n: round(errs[n], 3) for n in radii if abs(errs[n]) > 0.06 or abs(errs[n]) >= abs(errs0[n])}
    bad.update({n: round(e, 3) for n, e in errs.items() if n not in radii and abs(e) > 0.03})
    assert not bad, bad


def test_limb_lengths_joint_to_joint(scene, fitted):
    """The fitted model's limbs (joint to joint, :func:`jaxmocap.fit.shape.limb_lengths`) within 2 cm of the
    truth's, under a pixel and a half at the subject (measured: at most about 0.5 cm, the thighs)."""
    true, model, *_ = scene
    got = shape.limb_lengths(body.full25(fitted.dims))
    ref = shape.limb_lengths(model)
    worst = max(abs(got[k] - ref[k]) for k in ref)
    assert worst < 0.02, {k: round(got[k] - ref[k], 4) for k in ref}


def test_bad_input(scene):
    true, model, rig, obs, kp = scene
    with pytest.raises(ValueError, match="at least 3 frames"):
        shape_start.calibrate_from_start(jax.tree_util.tree_map(lambda a: a[:2], obs), rig, kp[:2])
    with pytest.raises(ValueError, match="no detections"):
        shape_start.calibrate_from_start(obs, rig, np.zeros_like(kp))
    with pytest.raises(ValueError, match="keypoints must be"):
        shape_start.calibrate_from_start(obs, rig, kp[:, :2])
    with pytest.raises(ValueError, match="observations.foreground"):
        shape_start.calibrate_from_start(obs._replace(foreground=None), rig, kp)
    with pytest.raises(ValueError, match="observations.keypoints2d"):
        shape_start.calibrate_from_start(obs._replace(keypoints2d=None), rig, kp)
    with pytest.raises(ValueError, match="observations.edge_dt"):
        shape_start.calibrate_from_start(obs._replace(edge_dt=None), rig, kp, edge_weight=1.0)
    few = kp.copy()
    few[1:, :, :, 2] = 0.0  # one frame with detections: no pose in the others
    with pytest.raises(ValueError, match="give a pose in 1 of 4"):
        shape_start.calibrate_from_start(obs, rig, few)
