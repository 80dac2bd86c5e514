"""A sequence folder as the tracker reads it: its detections (``views/<camera>/openpose/``), and read as a
recording (no rendered masks, no ground truth).

References: the OpenPose JSON files themselves, read with :mod:`json`, and the ground-truth joints projected with
``cv2.projectPoints``."""

import json
import pathlib
import shutil
import sys

import numpy as np
import pytest

from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io.keypoints import LAYOUTS
from jaxmocap.io.sources import DETECTIONS, SequenceSource
from jaxmocap.synth import generate as synth

sys.path.insert(0, str(pathlib.Path(__file__).parents[1] / "fit"))
from test_ik import _opencv_pixels  # noqa: E402  (the joints projected by cv2.projectPoints)

#: BODY_25B keypoint of a few evaluation joints
B25B = {"left_wrist": "LWrist", "right_knee": "RKnee", "left_ankle": "LAnkle", "right_shoulder": "RShoulder"}


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    out = tmp_path_factory.mktemp("seq") / "walk"
    synth.synthesize("demo", out, rig="stereo", frames="150:162", size=(160, 120), seed=0)
    return out


def test_detections_are_read_from_the_views_folders(seq):
    src = SequenceSource(seq)
    assert src.has_keypoints and src.keypoint_layout == "BODY_25B"
    T, V = src.num_frames, len(src.view_names)
    assert src.keypoints.shape == (T, V, len(EVAL_JOINTS), 3)
    names = LAYOUTS["BODY_25B"]
    rig = src.rig
    for t in range(T):
        fd = src.read(t)
        assert fd.masks is not None and fd.keypoints.shape == (V, len(EVAL_JOINTS), 3)
        for v, view in enumerate(src.view_names):
            # the file as OpenPose writes it: one person, 25 × (u, v, c) flat
            f = seq / "views" / view / DETECTIONS / f"{view}_{t:012d}_keypoints.json"
            people = json.loads(f.read_text())["people"]
            flat = np.asarray(people[0]["pose_keypoints_2d"], float).reshape(-1, 3)
            for joint, kp in B25B.items():
                got = fd.keypoints[v, EVAL_JOINTS.index(joint)]
                want = flat[names.index(kp)]
                if want[2] > 0:
                    np.testing.assert_allclose(got, want, atol=1e-3, err_msg=(t, view, joint))
            # and where the confident ones lie: near the true joints as OpenCV projects them
            uv = _opencv_pixels(rig, src.groundtruth[t])[v]
            kp = fd.keypoints[v]
            seen = kp[:, 2] > 0
            assert seen.sum() >= 10
            assert np.linalg.norm(kp[seen, :2] - uv[seen], axis=-1).max() < 10


def test_recording_hides_masks_and_ground_truth(seq):
    src = SequenceSource(seq, recording=True)
    assert not src.has_masks and src.groundtruth is None and src.has_keypoints
    assert src.plate_files is not None  # the empty-scene plates are part of a recording
    fd = src.read(0)
    assert fd.masks is None and fd.keypoints is not None and len(fd.images) == 2
    assert not SequenceSource(seq, detections=False).has_keypoints
    assert SequenceSource(seq, detections=False).read(0).keypoints is None


def test_detections_of_only_some_views_are_not_used(seq, tmp_path):
    copy = tmp_path / "walk"
    shutil.copytree(seq, copy)
    shutil.rmtree(copy / "views" / SequenceSource(seq).view_names[1] / DETECTIONS)
    src = SequenceSource(copy)
    assert not src.has_keypoints and src.read(0).keypoints is None
