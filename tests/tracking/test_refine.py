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

from jaxmocap.filters.base import State
from jaxmocap.fit import ik
from jaxmocap.geometry import body, camera
from jaxmocap.tracking import init as init_mod
from jaxmocap.tracking.refine import REFINE_ROBUST_PX, KeypointRefiner, refine_pairs


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
    new, info = jax.jit(refiner)(state, _Info(jnp.asarray(est)), kp)
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
    new, info = refiner(state, _Info(jnp.asarray(est)), kp.at[..., 2].set(0.0))
    np.testing.assert_array_equal(np.asarray(info.estimate), est)
    np.testing.assert_array_equal(np.asarray(new.particles), est[None])


def test_a_stronger_prior_stays_nearer_the_filters_estimate(scene):
    model, rig, x, X, kp, pairs = scene
    est = _wrong(model, x)
    state = State(jnp.asarray(est[None]), jnp.zeros(1), jnp.asarray(est))
    moves = []
    for prior in (1.0, 1e4):
        _, info = KeypointRefiner(model, rig, pairs, 3.0, prior, "estimate")(
            state, _Info(jnp.asarray(est)), kp
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
        _, info = refiner(state, _Info(jnp.asarray(est)), wrong)
        errs[robust] = _joints_error(model, info.estimate, X)
    assert errs[REFINE_ROBUST_PX][seen].max() < 0.015, errs[REFINE_ROBUST_PX]
    assert errs[None][wrist] > 3.0 * errs[REFINE_ROBUST_PX][wrist], (
        errs[None][wrist],
        errs[REFINE_ROBUST_PX][wrist],
    )
