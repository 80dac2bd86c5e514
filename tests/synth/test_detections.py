"""Simulated OpenPose detections: their error statistics against the documented model (closed forms, bounds from
the sample size), visibility from part labels and face normals, the keypoint geometry, and the JSON that the
project's OpenPose reader loads."""

import numpy as np
import pytest

from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io import openpose
from jaxmocap.synth import detections as dets

K = 25
W, H = 640, 480
N = 6000  # simulated views


@pytest.fixture(scope="module")
def draws():
    """``N`` views with random truth: pixels anywhere, depth 1.5–8 m, blur 0–12 px, 30 % occluded, 5 % outside."""
    rng = np.random.default_rng(7)
    model = dets.DetectionModel()
    out = []
    for n in range(N):
        uv = rng.uniform([0, 0], [W, H], (K, 2))
        depth = rng.uniform(1.5, 8.0, K)
        blur = rng.uniform(0.0, 12.0, K)
        occluded = rng.random(K) < 0.3
        in_view = rng.random(K) >= 0.05
        det, info = dets.simulate_view(
            np.random.default_rng([1, n]), uv, depth, blur, in_view, occluded, W, model
        )
        out.append((uv, depth, blur, occluded, in_view, det, info))
    return model, out


def _sigma(depth, blur, occluded, k):
    """The documented σ_k, written out again: c_k (σ₀ w/640 + β b)(1 + γ max(0, z − z₀)) × 3 when occluded."""
    coco = {"Nose": 0.026, "Eye": 0.025, "Ear": 0.035, "Shoulder": 0.079, "Elbow": 0.072, "Wrist": 0.062}
    coco |= {"Hip": 0.107, "Knee": 0.087, "Ankle": 0.089, "UpperNeck": 0.035, "HeadTop": 0.035}
    coco |= {"BigToe": 0.089, "SmallToe": 0.089, "Heel": 0.089}
    name = openpose.BODY_25B_KEYPOINTS[k]
    c = coco[name if name in coco else name[1:]] / 0.072
    return c * (3.0 * W / 640 + 0.5 * blur) * (1 + 0.2 * max(0.0, depth - 2.0)) * (3.0 if occluded else 1.0)


def _bound(p, n):
    """Four standard deviations of a binomial proportion."""
    return 4 * np.sqrt(p * (1 - p) / n)


def test_noise_is_gaussian_with_the_model_sigma(draws):
    _, rows = draws
    z = []
    for uv, depth, blur, occ, _, det, info in rows:
        swapped = set(info["swapped"].tolist())
        for k in np.flatnonzero(det[:, 2] > 0):
            if k not in swapped:
                z.append((det[k, :2] - uv[k]) / _sigma(depth[k], blur[k], occ[k], k))
    z = np.concatenate(z)
    n = z.size
    assert n > 150_000
    assert abs(z.mean()) < 4 / np.sqrt(n)
    assert abs(z.var() - 1) < 4 * np.sqrt(2 / n)
    inside = np.mean(np.abs(z) < 1)
    assert abs(inside - 0.682689) < _bound(0.682689, n)
    assert abs(np.mean(np.abs(z) > 3) - 0.0026998) < _bound(0.0026998, n)


def test_miss_and_swap_rates(draws):
    model, rows = draws
    vis_miss, occ_miss, outside_found, swaps = [], [], 0, 0
    for _, _, _, occ, in_view, det, info in rows:
        found = det[:, 2] > 0
        sw = np.zeros(K, bool)
        sw[info["swapped"]] = True
        keep = ~sw  # a swap moves each slot's fate to the other side
        vis_miss += list(~found[in_view & ~occ & keep])
        occ_miss += list(~found[in_view & occ & keep])
        outside_found += int(found[~in_view & keep].sum())
        swaps += bool(len(info["swapped"]))
    for rate, p in ((vis_miss, model.p_miss), (occ_miss, model.p_miss_occluded)):
        assert abs(np.mean(rate) - p) < _bound(p, len(rate))
    assert outside_found == 0
    assert abs(swaps / N - model.p_swap) < _bound(model.p_swap, N)


def test_swapped_slots_hold_the_other_side(draws):
    """A swapped slot holds the opposite keypoint's noisy detection: normalised by that keypoint's σ, its offset
    from the opposite truth is standard normal (bounded), and far from its own truth for most."""
    _, rows = draws
    z = []
    for uv, depth, blur, occ, _, det, info in rows:
        s = info["swapped"]
        for i, j in zip(s[0::2], s[1::2], strict=True):
            for a, b in ((i, j), (j, i)):
                if det[a, 2] > 0:
                    z.append((det[a, :2] - uv[b]) / _sigma(depth[b], blur[b], occ[b], b))
    z = np.concatenate(z)
    assert z.size > 500 and abs(z.var() - 1) < 4 * np.sqrt(2 / z.size)


def test_confidence_means(draws):
    """E[c₀ exp(−|ε|²/(2(3σ)²))] = c₀ / (1 + 1/9) for ε ~ N(0, σ² I₂) (the χ²₂ moment generating function); the
    clipping and the 0.05 noise move the mean by less than 0.005."""
    model, rows = draws
    for occluded, c0 in ((False, model.conf_visible), (True, model.conf_occluded)):
        c = np.concatenate(
            [
                det[(det[:, 2] > 0) & (occ == occluded) & ~np.isin(np.arange(K), info["swapped"]), 2]
                for _, _, _, occ, _, det, info in rows
            ]
        )
        expected = c0 * 0.9
        assert abs(c.mean() - expected) < 0.005 + 4 * c.std() / np.sqrt(c.size)
        assert c.min() >= 0.05 and c.max() <= 0.99


def test_visibility_from_labels_and_normals():
    labels = np.full((40, 60), -1, np.int32)
    labels[:, :30] = 3  # part 3 covers the left half
    uv = np.zeros((K, 2)) + [45.0, 20.0]  # every keypoint on the background half
    uv[7] = [10.0, 20.0]  # the left elbow on part 3
    uv[8] = [10.0, 20.0]  # the right elbow on part 3, not its own
    uv[9] = [100.0, 20.0]  # the left wrist outside the image
    own = [{5} for _ in range(K)]
    own[7] = {3}
    normals = np.tile([0.0, 0.0, -1.0], (5, 1))
    to_cam = np.tile([0.0, 0.0, -1.0], (K, 1))
    to_cam[1] = [0.0, 0.0, 1.0]  # the left eye faces away
    in_view, occluded = dets.visibility(uv, np.ones(K), labels, own, normals, to_cam)
    assert in_view[7] and not occluded[7]
    assert in_view[8] and occluded[8]
    assert not in_view[9]
    assert occluded[1] and occluded[0]  # away-facing eye; nose on the background (no head label near)


def test_keypoint_geometry():
    """A subject standing at the origin facing +x (left +y): face points in front, left ones on +y, feet points
    around the toes and behind the ankles."""
    e = {n: np.zeros(3) for n in EVAL_JOINTS}
    e |= {"thorax": [0, 0, 1.45], "left_shoulder": [0, 0.2, 1.42], "right_shoulder": [0, -0.2, 1.42]}
    e |= {"left_ankle": [0, 0.1, 0.08], "right_ankle": [0, -0.1, 0.08]}
    joints = np.array([[e[n] for n in EVAL_JOINTS]], float)
    poles = np.array([[[0, 0, 1.5], [0, 0, 1.72]]])
    toes = np.array([[[0.2, 0.1, 0.02], [0.2, -0.1, 0.02]]])
    kp, normals = dets.keypoints_3d(joints, poles, 0.09, toes)
    p = dict(zip(openpose.BODY_25B_KEYPOINTS, kp[0], strict=True))
    assert p["Nose"][0] == pytest.approx(0.09) and p["LEye"][1] > 0 > p["REye"][1]
    assert p["LEar"][1] == pytest.approx(0.09) and p["HeadTop"][2] == pytest.approx(1.72)
    assert p["LHeel"][0] < 0 < p["LBigToe"][0] and p["LBigToe"][1] < 0.1 < p["LSmallToe"][1]
    assert p["RSmallToe"][1] < -0.1 < p["RBigToe"][1]
    np.testing.assert_allclose(normals[0, 0], [1, 0, 0], atol=1e-12)


def test_json_reads_back(tmp_path):
    det = np.zeros((K, 3))
    det[5] = [100.25, 50.5, 0.8]
    dets.write_openpose_json(tmp_path / "cam_000000000003_keypoints.json", det)
    back = openpose.load_openpose_folder(tmp_path)
    np.testing.assert_allclose(back[0], det)
