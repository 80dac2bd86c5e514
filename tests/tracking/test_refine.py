"""The refinement of the filter's estimate on the frame's detections (:mod:`jaxmocap.tracking.refine`).

Reference: a pose of the ``full25`` model seen by four cameras around it, its joints projected by OpenCV
(``cv2.projectPoints``) as exact detections; the refinement of a wrong estimate must come back to that pose."""

from __future__ import annotations

from typing import NamedTuple

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.features.observation import make_observation
from jaxmocap.filters.base import State
from jaxmocap.fit import ik
from jaxmocap.geometry import body, camera
from jaxmocap.tracking import init as init_mod
from jaxmocap.tracking.refine import (
    DEPTH_JOINTS_DEFAULT,
    DEPTH_OCCLUDED_M,
    DEPTH_TRUNK,
    REFINE_ROBUST_PX,
    KeypointRefiner,
    refine_pairs,
)


def _ring(target, distance=4.0, f=256.0, size=(320, 240)):
    """Four cameras ``distance`` from ``target`` at 0°, 90°, 180°, 270° about the vertical z, looking at it."""
    Ks, Rs, ts = [], [], []
    for a in np.deg2rad([0.0, 90.0, 180.0, 270.0]):
        c = np.asarray(target) + distance * np.array([np.cos(a), np.sin(a), 0.0])
        z = (np.asarray(target) - c) / np.linalg.norm(np.asarray(target) - c)  # optical axis
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)  # image rows point down (world −z)
        R = np.stack([x, y, z])
        Ks.append(np.array([[f, 0, size[0] / 2], [0, f, size[1] / 2], [0, 0, 1.0]]))
        Rs.append(R)
        ts.append(-R @ c)
    return camera.from_opencv(Ks, np.zeros((4, 5)), Rs, ts, image_size=[size] * 4)


class _Info(NamedTuple):
    """The part of the filter's ``Info`` the refinement reads and replaces."""

    estimate: jnp.ndarray


def _Obs(keypoints2d, depth=None):
    """The frame's observation with detections ``(V, 15, 3)`` (and depth maps ``(V, H, W)``) only."""
    return make_observation(num_views=keypoints2d.shape[0], keypoints2d=np.asarray(keypoints2d), depth=depth)


@pytest.fixture(scope="module")
def scene():
    model = body.full25()
    rng = np.random.default_rng(0)
    x = np.asarray(model.rest_pose, np.float64).copy()
    limbs = np.ones(model.num_dofs, bool)
    limbs[list(model.topology.segment_dofs[0])] = False
    x[limbs] += rng.uniform(-0.4, 0.4, int(limbs.sum()))
    x = np.asarray(ik.clip_into(model, jnp.asarray(x, jnp.float32)), np.float64)
    X = np.asarray(ik.model_joints(model, jnp.asarray(x, jnp.float32)), np.float64)
    rig = _ring(X[0])
    pairs = refine_pairs(model)
    kp = np.zeros((4, len(body.EVAL_JOINTS), 3), np.float32)
    for v in range(4):
        uv, _ = cv2.projectPoints(
            X, cv2.Rodrigues(np.asarray(rig.R[v], np.float64))[0], np.asarray(rig.t[v], np.float64),
            np.asarray(rig.K[v], np.float64), np.zeros(5),
        )  # fmt: skip
        for j, k in pairs:
            kp[v, k, :2] = uv.reshape(-1, 2)[model.joint_names.index(j)]
            kp[v, k, 2] = 1.0
    return model, rig.to_jax(jnp.float32), x, X, jnp.asarray(kp), pairs


def _wrong(model, x):
    """The estimate 0.15 rad off in every limb angle (alternating signs) and 5 cm off at the root."""
    w = x + 0.15 * np.where(np.arange(len(x)) % 2 == 0, 1.0, -1.0)
    w[:3] = x[:3] + 0.05
    return np.asarray(ik.clip_into(model, jnp.asarray(w, jnp.float32)), np.float32)


def _joints_error(model, x, X):
    return np.linalg.norm(np.asarray(ik.model_joints(model, jnp.asarray(x, jnp.float32))) - X, axis=-1)


@pytest.mark.parametrize("mode", ["estimate", "track"])
def test_refinement_brings_a_wrong_estimate_to_the_detected_pose(scene, mode):
    """From 0.15 rad off in every angle (joints ≈ 10 cm off), the refined estimate puts every detected joint within
    1 cm of the pose OpenCV projected (the head included: its detection is the middle of the ears); ``track`` moves every particle by the estimate's correction, ``estimate`` leaves
    them."""
    model, rig, x, X, kp, pairs = scene
    est = _wrong(model, x)
    particles = est[None] + 0.02 * np.random.default_rng(1).standard_normal((16, model.num_dofs)).astype(
        np.float32
    )
    state = State(jnp.asarray(particles), jnp.full(16, -np.log(16.0)), jnp.asarray(est))
    refiner = KeypointRefiner(model, rig, pairs, init_mod.KEYPOINT_SIGMA_PX, 1.0, mode)
    new, info = jax.jit(refiner)(state, _Info(jnp.asarray(est)), _Obs(kp))
    start, err = _joints_error(model, est, X), _joints_error(model, info.estimate, X)
    seen = [model.joint_names.index(j) for j, _ in pairs]
    assert start[seen].mean() > 0.05
    assert err[seen].max() < 0.01, err
    np.testing.assert_allclose(np.asarray(new.estimate), np.asarray(info.estimate))
    moved = np.asarray(new.particles) - particles
    if mode == "track":
        delta = np.asarray(info.estimate) - est
        inside = (particles + delta >= np.asarray(model.lower)) & (
            particles + delta <= np.asarray(model.upper)
        )
        np.testing.assert_allclose(moved[inside], np.broadcast_to(delta, moved.shape)[inside], atol=1e-5)
        assert np.abs(delta).max() > 0.05
    else:
        assert np.all(moved == 0.0)


def test_a_frame_without_detections_keeps_the_filters_estimate(scene):
    model, rig, x, X, kp, pairs = scene
    est = _wrong(model, x)
    state = State(jnp.asarray(est[None]), jnp.zeros(1), jnp.asarray(est))
    refiner = KeypointRefiner(model, rig, pairs, init_mod.KEYPOINT_SIGMA_PX, 1.0, "track")
    new, info = refiner(state, _Info(jnp.asarray(est)), _Obs(kp.at[..., 2].set(0.0)))
    np.testing.assert_array_equal(np.asarray(info.estimate), est)
    np.testing.assert_array_equal(np.asarray(new.particles), est[None])


def test_a_stronger_prior_stays_nearer_the_filters_estimate(scene):
    model, rig, x, X, kp, pairs = scene
    est = _wrong(model, x)
    state = State(jnp.asarray(est[None]), jnp.zeros(1), jnp.asarray(est))
    moves = []
    for prior in (1.0, 1e4):
        _, info = KeypointRefiner(model, rig, pairs, 3.0, prior, "estimate")(
            state, _Info(jnp.asarray(est)), _Obs(kp)
        )
        moves.append(np.abs(np.asarray(info.estimate) - est).sum())
    assert moves[1] < 0.5 * moves[0], moves


def test_bad_refinement_options_are_refused(scene):
    model, rig, x, X, kp, pairs = scene
    with pytest.raises(ValueError, match="unknown refinement"):
        KeypointRefiner(model, rig, pairs, 3.0, 1.0, "smooth")
    with pytest.raises(ValueError, match="refine_prior"):
        KeypointRefiner(model, rig, pairs, 3.0, -1.0, "track")
    with pytest.raises(ValueError, match="needs detections"):
        KeypointRefiner(model, rig, (), 3.0, 1.0, "track")


def test_the_reweighting_discounts_a_wrong_detection(scene):
    """One view's left-wrist detection 70 px off at full confidence (a bystander's wrist, a detector's
    mistake): the plain least-squares fit bends the arm towards them; after the Geman–McClure reweighting every
    detected joint is back within 1.5 cm of the true pose, and the left wrist at least three times nearer than
    without it."""
    model, rig, x, X, kp, pairs = scene
    li = body.EVAL_JOINTS.index("left_wrist")
    wrong = kp.at[0, li, :2].add(jnp.asarray([42.0, -56.0]))
    est = _wrong(model, x)
    state = State(jnp.asarray(est[None]), jnp.zeros(1), jnp.asarray(est))
    seen = [model.joint_names.index(j) for j, _ in pairs]
    wrist = model.joint_names.index("left_wrist")
    errs = {}
    for robust in (None, REFINE_ROBUST_PX):
        refiner = KeypointRefiner(model, rig, pairs, init_mod.KEYPOINT_SIGMA_PX, 1.0, "estimate", robust)
        _, info = refiner(state, _Info(jnp.asarray(est)), _Obs(wrong))
        errs[robust] = _joints_error(model, info.estimate, X)
    assert errs[REFINE_ROBUST_PX][seen].max() < 0.015, errs[REFINE_ROBUST_PX]
    assert errs[None][wrist] > 3.0 * errs[REFINE_ROBUST_PX][wrist], (
        errs[None][wrist],
        errs[REFINE_ROBUST_PX][wrist],
    )


def _pair(target, distance=4.0, baseline=0.3, f=256.0, size=(320, 240)):
    """A stereo pair ``baseline`` apart, ``distance`` in front of ``target`` along −x, both looking along +x."""
    Ks, Rs, ts = [], [], []
    R = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # camera x = −world y, y = −z, z = +x
    for s in (-0.5, 0.5):
        c = np.asarray(target) + np.array([-distance, s * baseline, 0.0])
        Ks.append(np.array([[f, 0, size[0] / 2], [0, f, size[1] / 2], [0, 0, 1.0]]))
        Rs.append(R)
        ts.append(-R @ c)
    return camera.from_opencv(Ks, np.zeros((2, 5)), Rs, ts, image_size=[size] * 2)


def _opencv_depth_maps(rig, X, joints, half=4, size=(320, 240), behind=None):
    """Depth maps ``(V, H, W)`` (m, 0 = none) as a depth sensor would read the body's front surface near the
    ``joints``: a ``(2 half + 1)²`` patch around each joint's projection (``cv2.projectPoints``) at its camera
    depth (``R X + t``, third row) less its distance ``behind`` the surface (default
    :data:`~jaxmocap.tracking.init.DEPTH_BEHIND_SURFACE` for each)."""
    behind = np.full(len(joints), init_mod.DEPTH_BEHIND_SURFACE) if behind is None else np.asarray(behind)
    W, H = size
    maps = np.zeros((rig.num_views, H, W), np.float32)
    for v in range(rig.num_views):
        R, t = np.asarray(rig.R[v], np.float64), np.asarray(rig.t[v], np.float64)
        uv, _ = cv2.projectPoints(
            X[joints], cv2.Rodrigues(R)[0], t, np.asarray(rig.K[v], np.float64), np.zeros(5)
        )
        z = (X[joints] @ R.T + t)[:, 2]
        for (u, w), zj, s in zip(uv.reshape(-1, 2), z, behind, strict=True):
            c, r = int(round(u)), int(round(w))
            maps[v, r - half : r + half + 1, c - half : c + half + 1] = zj - s
    return maps


@pytest.mark.parametrize("plane", [4.2, 3.7])
def test_depth_targets_read_a_plane_at_the_joints_projections(scene, plane):
    """A fronto-parallel plane at camera depth ``plane`` in every view, with a hole around the thorax's projection
    in view 0: each joint of the depth term (:data:`DEPTH_JOINTS_DEFAULT`: trunk and limbs) gets the plane's depth
    plus its distance behind the surface as its target, at weight ``1/σ_d²``, unless the estimate puts it more than
    :data:`DEPTH_OCCLUDED_M` behind that target (occluded by the plane: its camera depth from OpenCV's ``R X + t``);
    the thorax in view 0 and the other joints (the root, the head) have weight 0. The nearer plane occludes some
    joints in some views, the farther none."""
    model, rig, x, X, kp, pairs = scene
    sigma = 0.05
    refiner = KeypointRefiner(model, rig, pairs, 3.0, 1.0, "estimate", depth_sigma=sigma)
    depth = np.full((4, 240, 320), plane, np.float32)
    uv = np.asarray(camera.project(rig, jnp.asarray(X, jnp.float32)))
    thorax = model.joint_names.index("thorax")
    c, r = (int(round(a)) for a in uv[0, thorax])
    depth[0, r - 3 : r + 4, c - 3 : c + 4] = 0.0
    z, wz = (np.asarray(a) for a in refiner.depth_targets(jnp.asarray(x, jnp.float32), jnp.asarray(depth)))
    expected_w, expected_z = np.zeros_like(wz), np.zeros_like(z)
    for v in range(rig.num_views):
        # camera depths, OpenCV's convention
        zc = X @ np.asarray(rig.R[v], np.float64)[2] + float(rig.t[v][2])
        for j, behind in DEPTH_JOINTS_DEFAULT:
            k = model.joint_names.index(j)
            if zc[k] - (plane + behind) <= DEPTH_OCCLUDED_M:
                expected_w[v, k], expected_z[v, k] = 1.0 / sigma**2, plane + behind
    expected_w[0, thorax] = expected_z[0, thorax] = 0.0
    # besides the root and the head of every view and the hole
    occluded = int(np.sum(expected_w == 0)) - 2 * rig.num_views - 1
    assert occluded == 0 if plane == 4.2 else occluded > 0
    assert {j for j, _ in DEPTH_JOINTS_DEFAULT} == set(model.joint_names) - {"root", "head"}
    np.testing.assert_allclose(wz, expected_w, rtol=1e-6)
    np.testing.assert_allclose(z, expected_z, rtol=1e-6)


def test_the_depth_term_holds_a_stereo_fit_at_the_measured_depth(scene):
    """A stereo pair 0.3 m apart 4 m from the subject (f = 256 px) and a model 10 % larger than the body (its
    dimensions measured badly): a 10 % larger body 0.4 m further away projects the same, and a pixel of disparity
    is about 0.2 m there, so the keypoint fit (2 px noise, the pair's prior weight 30, from the true pose) moves
    the trunk away from the cameras, by more than 8 cm (measured 11 cm, the prior holding it back); with the depth
    term (σ_d = 5 cm, depth maps read at the true trunk joints' surface as :func:`_opencv_depth_maps` builds them)
    the trunk's mean depth is within 3 cm of the truth (measured 1.1 cm)."""
    model, _, x, X, _, pairs = scene
    big = body.full25({k: 1.1 * np.asarray(v) for k, v in body.DEFAULT_DIMENSIONS.items()})
    rig = _pair(X[0]).to_jax(jnp.float32)
    rng = np.random.default_rng(3)
    kp = np.zeros((2, len(body.EVAL_JOINTS), 3), np.float32)
    uv = np.asarray(camera.project(rig, jnp.asarray(X, jnp.float32)))
    for j, k in pairs:
        kp[:, k, :2] = uv[:, model.joint_names.index(j)] + 2.0 * rng.standard_normal((2, 2))
        kp[:, k, 2] = 1.0
    trunk = [model.joint_names.index(j) for j in init_mod.DEPTH_JOINTS]
    depth = _opencv_depth_maps(rig, X, trunk)
    est = x.astype(np.float32)
    state = State(jnp.asarray(est[None]), jnp.zeros(1), jnp.asarray(est))
    off = {}
    for sigma in (None, 0.05):
        refiner = KeypointRefiner(
            big, rig, pairs, init_mod.KEYPOINT_SIGMA_PX, 30.0, "estimate", depth_sigma=sigma,
            depth_joints=DEPTH_TRUNK,
        )  # fmt: skip
        _, info = jax.jit(refiner)(state, _Info(jnp.asarray(est)), _Obs(kp, depth))
        fitted = np.asarray(ik.model_joints(big, info.estimate))
        off[sigma] = float(np.mean(fitted[trunk, 0]) - np.mean(X[trunk, 0]))  # world x: away from the pair
    assert off[None] > 0.08, off
    assert abs(off[0.05]) < 0.03, off


def test_without_depth_maps_the_depth_term_is_left_out(scene):
    """A refiner with a depth term given an observation without depth maps fits the detections alone: the same
    estimate as a refiner without it."""
    model, rig, x, X, kp, pairs = scene
    est = _wrong(model, x)
    state = State(jnp.asarray(est[None]), jnp.zeros(1), jnp.asarray(est))
    out = [
        KeypointRefiner(model, rig, pairs, 3.0, 1.0, "estimate", depth_sigma=s)(
            state, _Info(jnp.asarray(est)), _Obs(kp)
        )[1]
        for s in (None, 0.05)
    ]
    np.testing.assert_array_equal(np.asarray(out[0].estimate), np.asarray(out[1].estimate))


@pytest.mark.parametrize("wrong", [1.0, -0.5])
def test_the_depth_reweighting_discounts_a_wrong_reading(scene, wrong):
    """Exact detections in the stereo pair of :func:`test_the_depth_term_holds_a_stereo_fit_at_the_measured_depth`,
    depth maps read at the true surface of every joint of the depth term, but view 0 reads the left wrist
    ``wrong`` metres off. 1 m behind it (the wall through a gap): from the true pose, the fit without the reweighting
    pulls the wrist towards that reading (by more than 3× the reweighted fit's error); with it (``robust_px`` set:
    the depth term's Geman–McClure weights at :data:`REFINE_ROBUST_DEPTH`) the wrist stays within 5 cm. 0.5 m in
    front of it (a bystander's arm, the other hand): the wrist lies more than :data:`DEPTH_OCCLUDED_M` behind the
    reading, is taken as occluded in that view and stays within 5 cm with and without the reweighting. (The maps'
    patches overlap where joints project close together, as a sensor's readings of one surface would.)"""
    model, _, x, X, _, pairs = scene
    rig = _pair(X[0]).to_jax(jnp.float32)
    uv = np.asarray(camera.project(rig, jnp.asarray(X, jnp.float32)))
    kp = np.zeros((2, len(body.EVAL_JOINTS), 3), np.float32)
    for j, k in pairs:
        kp[:, k, :2], kp[:, k, 2] = uv[:, model.joint_names.index(j)], 1.0
    joints = [model.joint_names.index(j) for j, _ in DEPTH_JOINTS_DEFAULT]
    depth = _opencv_depth_maps(rig, X, joints, half=2, behind=[b for _, b in DEPTH_JOINTS_DEFAULT])
    wrist = model.joint_names.index("left_wrist")
    c, r = (int(round(a)) for a in uv[0, wrist])
    depth[0, r - 2 : r + 3, c - 2 : c + 3] += wrong
    est = x.astype(np.float32)
    state = State(jnp.asarray(est[None]), jnp.zeros(1), jnp.asarray(est))
    errs = {}
    for robust in (None, REFINE_ROBUST_PX):
        refiner = KeypointRefiner(
            model, rig, pairs, init_mod.KEYPOINT_SIGMA_PX, 1.0, "estimate", robust, 0.05
        )
        _, info = refiner(state, _Info(jnp.asarray(est)), _Obs(jnp.asarray(kp), depth))
        errs[robust] = _joints_error(model, info.estimate, X)[wrist]
    assert errs[REFINE_ROBUST_PX] < 0.05, errs
    if wrong > 0:
        assert errs[None] > 3.0 * errs[REFINE_ROBUST_PX], errs
    else:
        assert errs[None] < 0.05, errs
