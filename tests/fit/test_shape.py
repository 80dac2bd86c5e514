"""Body-shape calibration (:mod:`jaxmocap.fit.shape`): a synthetic subject with known, modified limb lengths is
rendered into three views (:mod:`jaxmocap.geometry.render`, the body model's own flesh) in three poses; calibration from the
default dimensions recovers the lengths."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.features.observation import make_observation
from jaxmocap.fit import shape
from jaxmocap.geometry import body, camera, render
from jaxmocap.likelihood import compose as L
from jaxmocap.synth.stage import look_at

W, H = 120, 90
#: The subject: default dimensions times these factors (5–10 % changes, 2–4 cm on each limb).
FACTORS = {
    "torso_length": 1.06,
    "upper_arm_length": 1.10,
    "forearm_length": 0.90,
    "thigh_length": 1.08,
    "shin_length": 0.92,
}
PAIRS = tuple((n, i) for i, n in enumerate(body.EVAL_JOINTS))


def _rig():
    cams = ([3.2, 0.3, 1.3], [0.4, 3.3, 1.2], [-2.4, -2.2, 1.5])
    Rs, ts = zip(*[look_at(np.asarray(c), [0.0, 0.0, 0.95]) for c in cams], strict=True)
    K = np.array([[0.75 * W, 0.0, (W - 1) / 2], [0.0, 0.75 * W, (H - 1) / 2], [0.0, 0.0, 1.0]])
    return camera.from_opencv(
        np.stack([K] * 3), np.zeros((3, 5)), np.stack(Rs), np.stack(ts), image_size=[(W, H)] * 3
    )


def _poses(model):
    out = []
    for sets in (
        [("left_shoulder_rx", 0.6), ("left_elbow", 0.9), ("right_hip_rx", -0.4), ("right_knee", 0.7)],
        [
            ("right_shoulder_rx", -0.7),
            ("right_elbow", 1.1),
            ("left_hip_rx", 0.5),
            ("left_knee", 0.9),
            ("root_rz", 0.5),
        ],
        [("left_shoulder_ry", -0.5), ("right_shoulder_ry", 0.5), ("left_elbow", 0.6), ("right_elbow", 0.6)],
    ):
        x = model.rest_pose
        for n, v in sets:
            x = x.at[model.dof_index(n)].set(v)
        out.append(x)
    return jnp.stack(out)


@pytest.fixture(scope="module")
def subject():
    """The true dimensions, poses (T, D) and stacked observations: blurred silhouettes, the distance transform of
    their Canny edges, and the projected evaluation joints (exact) as 2D keypoints."""
    true = dict(body.DEFAULT_DIMENSIONS)
    true.update({k: body.DEFAULT_DIMENSIONS[k] * f for k, f in FACTORS.items()})
    model = body.full25(true)
    rig = _rig()
    X = _poses(model)
    idx = [model.joint_names.index(n) for n in body.EVAL_JOINTS]
    obs = []
    for x in X:
        prims = render.primitives_from_model(model, x)
        fgs, dts = [], []
        for v in range(rig.num_views):
            depth = np.asarray(
                render.render_view(rig.K[v], rig.dist[v], rig.R[v], rig.t[v], (W, H), prims).depth
            )
            mask = (depth > 0).astype(np.uint8)
            assert 0 < mask.mean() < 0.5  # the subject is in view
            e = cv2.Canny(mask * 255, 50, 150)
            fgs.append(cv2.GaussianBlur(mask.astype(np.float32), (5, 5), 1.5))
            dts.append(cv2.distanceTransform((e == 0).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE))
        uv = np.asarray(camera.project(rig, np.asarray(body.joint_positions(model, x))[idx]))
        kp = np.concatenate([uv, np.ones(uv.shape[:2] + (1,))], -1)
        obs.append(make_observation(rig, foreground=fgs, edge_dt=dts, keypoints2d=kp))
    stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *obs)
    return true, model, rig, X, stacked


def test_calibration_recovers_limb_lengths(subject):
    """Start: the default dimensions, 2–4 cm off on every fitted length (they are the true ones divided by the
    factors); poses known. Likelihood: bilinear silhouette and edge-distance cues plus the keypoints cue, whose 2D
    joints constrain the lengths directly. 80 Adam steps of 3 %.

    Measured: every limb length (joint to joint, :func:`jaxmocap.fit.shape.limb_lengths`) within 6 mm of the truth
    (mean 3–4 mm) from a mean start error of 29 mm. Bound: 10 mm per limb, under one pixel at the subject
    (3.2 m away, f = 90 px: one pixel ≈ 36 mm) and a third of the smallest start error; the mean error must also
    fall below a quarter of the start's. The fitted lengths' flesh points follow the dimensions, so a fit that ignored
    the gradient would stay at the start errors."""
    true, model, rig, X, obs = subject
    m0 = body.full25()
    cues = [
        L.Cue("edge_distance", params={"bilinear": True}),
        L.Cue("foreground", params={"bilinear": True}),
        L.Cue("keypoints", params={"pairs": PAIRS, "sigma_px": 3.0}),
    ]
    lik = L.Likelihood.create(m0, rig, cues, surface_points=100)
    fit = shape.calibrate(lik, obs, X, names=tuple(FACTORS), steps=80, learning_rate=0.03, fit_pose=False)
    assert np.all(np.isfinite(fit.objective)) and fit.objective[-1] > fit.objective[0]
    truth = shape.limb_lengths(model)
    start = shape.limb_lengths(m0)
    got = shape.limb_lengths(body.full25(fit.dims))
    err = {k: abs(got[k] - truth[k]) for k in truth}
    err0 = {k: abs(start[k] - truth[k]) for k in truth}
    print("limb length errors (mm), start → fitted:")
    for k in truth:
        print(f"  {k:>16}: {1000 * err0[k]:5.1f} → {1000 * err[k]:4.1f}")
    print(f"  mean: {1000 * np.mean(list(err0.values())):.1f} → {1000 * np.mean(list(err.values())):.1f}")
    assert min(err0.values()) > 0.02
    assert max(err.values()) < 0.010, err
    assert np.mean(list(err.values())) < 0.25 * np.mean(list(err0.values()))
    # the dimensions themselves (each fitted name) within 3 % of the truth
    for k in FACTORS:
        assert fit.dims[k] == pytest.approx(true[k], rel=0.03), (k, fit.dims[k], true[k])
