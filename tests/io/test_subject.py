"""The subject among the detections of every view and frame, and what the detections say about the calibration.

References: the real Pose2Sim demo (its calibration, OpenPose BODY_25B detections of frames 0-9 and 37 with a
bystander in cam01/cam02 and, in frame 37, the subject split into two detections in cam01, and Pose2Sim's own
triangulated .trc), and people projected with ``cv2.projectPoints``."""

import pathlib

import cv2
import numpy as np
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import camera
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io import keypoints as K
from jaxmocap.io import openpose
from jaxmocap.io import subject as S
from jaxmocap.io.calibration import load_calibration
from jaxmocap.io.pose2sim import reference_joints

P2S = pathlib.Path(__file__).parents[1] / "data" / "calib" / "pose2sim"
CALIB = P2S / "Calib_qualisys_converted_by_pose2sim_a948c20.toml"
FOLDERS = [P2S / "pose" / f"cam0{c}_json" for c in range(1, 5)]
FRAMES = [0, 1, 2, 37]


@pytest.fixture(scope="module")
def rig():
    return load_calibration(CALIB)


def _project(rig, X: np.ndarray) -> np.ndarray:
    """``(V, J, 2)`` pixels of world points ``X (J, 3)``, by OpenCV."""
    out = []
    for v in range(rig.num_views):
        rvec, _ = cv2.Rodrigues(np.asarray(rig.R[v], np.float64))
        uv, _ = cv2.projectPoints(
            X, rvec, np.asarray(rig.t[v], np.float64), np.asarray(rig.K[v]), np.asarray(rig.dist[v])
        )
        out.append(uv.reshape(-1, 2))
    return np.stack(out)


def _dets(folders, frames, order=None):
    """``dets[t][v]`` evaluation-joint detections; ``order(people)`` rearranges each file's people."""
    out = []
    for f in frames:
        row = []
        for folder in folders:
            people = openpose.read_people(openpose.frame_files(folder)[f])
            people = people if order is None else order(people)
            row.append(np.stack([K.eval_keypoints(p, "BODY_25B") for p in people]))
        out.append(row)
    return out


def test_subject_of_the_real_demo_whatever_the_order_of_people(rig):
    """cam01/cam02 hold a bystander (and in frame 37 cam01 splits the subject in two, the larger half first): the
    chosen detections lie on Pose2Sim's triangulation of the subject in every view (median ≤ 40 px on 1920 px
    images; the bystander is > 400 px away), the split halves are joined, and reversing the people of every
    file changes nothing."""
    ref, _, _ = reference_joints(P2S / "S00_P00_T01_BalancingTrial_0-100.trc")
    kp, report = S.select_subject(rig, _dets(FOLDERS, FRAMES), fps=60.0)
    assert report["subject_frames"] == len(FRAMES) and report["views_per_frame"] == [4] * len(FRAMES)
    for i, f in enumerate(FRAMES):
        uv = _project(rig, ref[f])
        for v in range(4):
            ok = (kp[i, v, :, 2] > 0.3) & np.isfinite(uv[v]).all(axis=1)
            ok[EVAL_JOINTS.index("head")] = False  # the reference's head is the head top and nose
            assert ok.sum() >= 8
            assert np.median(np.linalg.norm(kp[i, v, ok, :2] - uv[v, ok], axis=1)) < 40.0, (f, v)
    # frame 37, cam01: the upper body of the first detection and the legs of the second
    lower = [EVAL_JOINTS.index(j) for j in ("left_knee", "right_knee", "left_ankle", "right_ankle")]
    upper = [EVAL_JOINTS.index(j) for j in ("thorax", "left_shoulder", "right_elbow")]
    assert np.all(kp[3, 0, lower, 2] > 0.3) and np.all(kp[3, 0, upper, 2] > 0.3)
    reordered, _ = S.select_subject(rig, _dets(FOLDERS, FRAMES, order=lambda p: p[::-1]), fps=60.0)
    np.testing.assert_array_equal(reordered, kp)


def test_a_view_with_left_and_right_swapped(rig):
    """cam02's detections with left and right swapped (a back read as a front): left out of the subject, or, with
    ``mirrored``, taken back mirrored: cam02's original detections again, the other views as without it."""
    dets = _dets(FOLDERS, FRAMES)
    kp, _ = S.select_subject(rig, dets, fps=60.0)
    swapped = [[d[:, S.MIRROR] if v == 1 else d for v, d in enumerate(row)] for row in dets]
    left_out, report = S.select_subject(rig, swapped, fps=60.0)
    assert report["views_per_frame"] == [3] * len(FRAMES) and not np.any(left_out[:, 1, :, 2] > 0)
    back, report = S.select_subject(rig, swapped, fps=60.0, mirrored=True)
    assert report["views_per_frame"] == [4] * len(FRAMES)
    np.testing.assert_array_equal(back[:, 1], kp[:, 1])
    np.testing.assert_array_equal(back[:, [0, 2, 3]], left_out[:, [0, 2, 3]])
    assert sorted(S.MIRROR) == list(range(len(EVAL_JOINTS))) and S.MIRROR[EVAL_JOINTS.index("left_knee")] == (
        EVAL_JOINTS.index("right_knee")
    )


def test_the_subject_stays_tracked(rig):
    """Synthetic: the subject (Pose2Sim's frame-0 joints) in every view, a bystander 2 m away seen by cam01 and
    cam02 only; in frame 5 the subject is hidden from cam01/cam02, so that both people are seen by two cameras.
    The subject is the person seen most over the frames; in frame 5 cam01/cam02 give no detection (not the
    bystander's)."""
    ref, _, _ = reference_joints(P2S / "S00_P00_T01_BalancingTrial_0-100.trc")
    X = np.nan_to_num(ref[0])
    other = X + np.array([2.0, 0.5, 0.0])
    dets = []
    for t in range(10):
        moved = X + np.array([0.01 * t, 0.0, 0.0])
        uv_s, uv_b = _project(rig, moved), _project(rig, other)
        row = []
        for v in range(4):
            people = []
            if v >= 2 or t != 5:
                people.append(np.c_[uv_s[v], np.full(15, 0.9)])
            if v < 2:
                people.insert(0, np.c_[uv_b[v], np.full(15, 0.9)])  # the bystander listed first
            row.append(np.stack(people))
        dets.append(row)
    kp, report = S.select_subject(rig, dets, fps=60.0)
    for t in range(10):
        uv = _project(rig, X + np.array([0.01 * t, 0.0, 0.0]))
        for v in range(4):
            if t == 5 and v < 2:
                assert np.all(kp[t, v, :, 2] == 0)
            else:
                np.testing.assert_allclose(kp[t, v, :, :2], uv[v], atol=1e-6)
    assert report["views_per_frame"][5] == 2


def test_folders_in_another_order_are_refused(rig):
    dets = _dets(FOLDERS, range(10))
    assert S.check_rig(rig, dets, "keypoints") == []
    swapped = [[row[1], row[0], row[2], row[3]] for row in dets]
    with pytest.raises(MocapInputError, match=r"input 2 → camera 'cam_01', input 1 → camera 'cam_02'"):
        S.check_rig(rig, swapped, "keypoints")
    with pytest.raises(MocapInputError, match="another order"):
        S.load_subject([FOLDERS[i] for i in (0, 1, 3, 2)], rig, range(10), 60.0)


def test_millimetre_translations_seen_in_the_limbs(rig):
    """Reprojection cannot tell a rig scaled by 1000 from the true one, the triangulated limbs can."""
    import dataclasses

    mm = dataclasses.replace(rig, t=np.asarray(rig.t) * 1000.0)
    with pytest.raises(MocapInputError, match=r"limbs .* m long .*millimetres"):
        S.check_rig(mm, _dets(FOLDERS, range(10)), "calib.toml")
    cm = dataclasses.replace(
        rig, t=np.asarray(rig.t) * 100.0
    )  # centimetres: refused, with no millimetre hint
    with pytest.raises(MocapInputError, match=r"limbs .* m long .*metres$"):
        S.check_rig(cm, _dets(FOLDERS, range(10)), "calib.toml")


def test_load_subject_layout_and_missing_frames(rig, tmp_path):
    """The layout comes from the files; a frame without a file has no detections; a file numbered past the
    videos' last frame is refused."""
    sub = S.load_subject(FOLDERS, rig, range(12), 60.0, total=100)
    assert sub.layout == "BODY_25B" and sub.keypoints.shape == (12, 4, 15, 3)
    assert np.all(sub.keypoints[10:, :, :, 2] == 0) and np.all(sub.keypoints[:10].max(axis=(1, 2))[:, 2] > 0)
    assert any("no keypoint file for 2 of 12 frames (10, 11)" in n for n in sub.notes)
    with pytest.raises(MocapInputError, match=r"keypoints of frame 37, but the videos have 20 frames"):
        S.load_subject(FOLDERS, rig, range(12), 60.0, total=20)
    with pytest.raises(MocapInputError, match="the COCO_17 layout has 17"):
        S.load_subject(FOLDERS, rig, range(3), 60.0, layout="COCO_17")


def test_body_dimensions_of_the_real_subject(rig):
    sub = S.load_subject(FOLDERS, rig, range(10), 60.0)
    d = S.body_dimensions(sub.keypoints, rig)
    for k in ("upper_arm_length", "forearm_length", "thigh_length", "shin_length", "torso_length"):
        assert 0.2 < d[k] < 0.6, (k, d[k])
    assert d["shoulder_width"] > d["hip_width"] > 0.1 and d["hip_drop"] == 0.0


def test_the_subject_of_a_close_stereo_pair_in_every_frame():
    """Two cameras 0.3 m apart, 3.5 m from the subject (Pose2Sim's frame-0 joints walking sideways at 1.2 m/s),
    320×240, detections with 4 px of Gaussian noise (fixed seed): such a pair triangulates a joint's depth to about
    ±1 m, and some joints' rays meet behind the cameras. The subject is still one person seen by both cameras in
    every frame (the joints without a triangulation left out; the frames linked across the lines of sight); linking
    the frames by the 3D distance of the centres, with the person dropped where a ray met behind a camera, found
    the subject in 15 of the 30 frames. Detections that contradict each other are dropped, not the person."""
    from jaxmocap.synth.stage import look_at

    ref, _, _ = reference_joints(P2S / "S00_P00_T01_BalancingTrial_0-100.trc")
    X0 = np.nan_to_num(ref[0])
    c = X0.mean(axis=0)
    K = np.array([[256.0, 0.0, 159.5], [0.0, 256.0, 119.5], [0.0, 0.0, 1.0]])
    eye = c + np.array([3.5, 0.0, 0.0])
    R, _ = look_at(eye, c)
    ts = [-R @ (eye + s * 0.15 * R[0]) for s in (-1.0, 1.0)]
    rig = camera.from_opencv(
        np.stack([K, K]),
        np.zeros((2, 5)),
        np.stack([R, R]),
        np.stack(ts),
        ("left", "right"),
        [(320, 240)] * 2,
    )
    rng = np.random.default_rng(0)
    T, dets = 30, []
    for t in range(T):
        uv = _project(rig, X0 + np.array([0.0, 1.2 * t / 30.0, 0.0]))
        dets.append(
            [np.c_[uv[v] + rng.normal(0.0, 4.0, uv[v].shape), np.full(15, 0.9)][None] for v in range(2)]
        )
    kp, report = S.select_subject(rig, dets, fps=30.0)
    assert report["subject_frames"] == T
    assert report["views_per_frame"] == [2] * T
    # the wrists exchanged in the right view: the right wrist's rays meet behind the cameras (30 px of negative
    # disparity), and neither view's detection of it is kept; every other joint is
    uv = _project(rig, X0)
    lw, rw = EVAL_JOINTS.index("left_wrist"), EVAL_JOINTS.index("right_wrist")
    right = np.c_[uv[1], np.full(15, 0.9)]
    right[[lw, rw]] = right[[rw, lw]]
    kp, report = S.select_subject(rig, [[np.c_[uv[0], np.full(15, 0.9)][None], right[None]]], fps=30.0)
    assert report["subject_frames"] == 1
    np.testing.assert_array_equal(kp[0, :, rw, 2], 0.0)
    np.testing.assert_array_equal(np.delete(kp[0, :, :, 2], rw, axis=1), 0.9)


def _noisy_views(rig, sigma, seed=0):
    """``(T, V, 15, 3)``: the real subject's 100 frames of ``.trc`` joints projected by OpenCV into ``rig``, with
    Gaussian noise of ``sigma[v]`` px per coordinate in view ``v`` (confidence 0.9; 0 where the joint is missing)."""
    ref, _, _ = reference_joints(P2S / "S00_P00_T01_BalancingTrial_0-100.trc")
    rng = np.random.default_rng(seed)
    out = np.zeros((len(ref), rig.num_views, 15, 3))
    for t, X in enumerate(ref):
        ok = np.all(np.isfinite(X), axis=1)
        uv = _project(rig, np.nan_to_num(X))
        for v in range(rig.num_views):
            out[t, v, :, :2] = uv[v] + rng.normal(0.0, sigma[v], uv[v].shape)
            out[t, v, :, 2] = np.where(ok, 0.9, 0.0)
    return out


def test_view_noise_measures_each_cameras_noise(rig):
    """Four real cameras, the real subject's 100 frames of joints projected by OpenCV, Gaussian noise of a known
    standard deviation per view: the variance-component estimate recovers every view's, one view four times as
    noisy as the others included, within 10 % (≈ 1500 residuals of 2 coordinates a view: a relative standard error
    of about 2 % for σ). The plain triangulation's residuals would not: the noisy view's error spreads into the
    others (the first round, equal weights, measures the quiet views 1.3-1.9× too noisy). With three of the cameras the
    noisy one still stands out; a joint seen by two views only is not measured."""
    np.testing.assert_allclose(S.view_noise(_noisy_views(rig, [2.0] * 4), rig), 2.0, rtol=0.1)
    for noisy in range(4):
        sigma = np.full(4, 2.0)
        sigma[noisy] = 8.0
        kp = _noisy_views(rig, sigma, seed=noisy)
        np.testing.assert_allclose(S.view_noise(kp, rig), sigma, rtol=0.1)
        first = S.view_noise(kp, rig, rounds=1)
        assert np.all(np.delete(first, noisy) > 1.25 * 2.0), first
        three = [c for c in range(4) if c != (noisy + 1) % 4]
        s3 = S.view_noise(kp[:, three], camera.select(rig, three))
        assert np.argmax(s3) == three.index(noisy) and np.max(s3) > 2.0 * np.max(np.delete(s3, np.argmax(s3)))
    two = _noisy_views(rig, [2.0] * 4)
    two[:, 2:, :, 2] = 0.0
    assert np.all(np.isnan(S.view_noise(two, rig)))


def test_view_noise_of_the_real_recording_orders_the_cameras_as_pose2sims_markers(rig):
    """The real recording's detections (11 frames, 4 cameras): the cameras come out in the same order of noise as
    the distances between their detections and the projections of Pose2Sim's own triangulated markers (the .trc,
    made by another program from all four cameras): cam_01 and cam_03 far noisier than cam_02 and cam_04."""
    sub = S.load_subject(FOLDERS, rig, range(11), 60.0)
    sigma = S.view_noise(sub.keypoints, rig)
    ref, _, _ = reference_joints(P2S / "S00_P00_T01_BalancingTrial_0-100.trc")
    dist = [[] for _ in range(4)]
    for t in range(11):
        uv = _project(rig, np.nan_to_num(ref[t]))
        for v in range(4):
            ok = (sub.keypoints[t, v, :, 2] > 0.3) & np.all(np.isfinite(ref[t]), axis=1)
            dist[v].append(np.linalg.norm(uv[v][ok] - sub.keypoints[t, v, ok, :2], axis=1))
    markers = np.array([np.median(np.concatenate(d)) for d in dist])
    np.testing.assert_array_equal(np.argsort(sigma), np.argsort(markers))
    assert min(sigma[0], sigma[2]) > 1.5 * max(sigma[1], sigma[3]), sigma


def test_view_noise_notes_name_the_cameras_to_check():
    notes = S.view_noise_notes(["a", "b", "c", "d"], np.array([2.0, 2.5, np.nan, 6.0]))
    assert notes[0].endswith(": a 2.0, b 2.5, d 6.0"), notes
    assert len(notes) == 2 and notes[1].startswith("d: detections 2× or more") and "that camera" in notes[1]
    assert len(S.view_noise_notes(["a", "b", "c"], np.array([2.0, 3.0, 3.9]))) == 1
    assert "a, c: " in S.view_noise_notes(list("abcde"), np.array([9.0, 2.0, 8.0, 2.0, 2.1]))[1]
    assert S.view_noise_notes(["a", "b"], np.array([np.nan, np.nan])) == []
