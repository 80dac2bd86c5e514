"""2D keypoint files of every layout (BODY_25, BODY_25B, HALPE_26, COCO_17, COCO_133, MediaPipe-33) written the
way OpenPose / Pose2Sim / rtmlib write them, read into the evaluation joints; the layout told from the files;
files matched to frames by the number in their names.

Reference: a real BODY_25B detection of the Pose2Sim demo (tests/data/calib/pose2sim), rewritten into each layout's
published keypoint order (OpenPose's output documentation for BODY_25, Halpe-FullBody's for HALPE_26, COCO's and
COCO-WholeBody's, MediaPipe's pose landmark list), with BODY_25's neck and mid-hip made as OpenPose makes them (the
middles of the shoulders and of the hips)."""

import json
import pathlib

import numpy as np
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io import keypoints as K
from jaxmocap.io import openpose

P2S = pathlib.Path(__file__).parents[1] / "data" / "calib" / "pose2sim" / "pose"

COCO = "nose leye reye lear rear lsho rsho lelb relb lwri rwri lhip rhip lkne rkne lank rank".split()
FEET_B25B = "lbig lsmall lheel rbig rsmall rheel".split()
# published orders, in the short names above (+ the layout's own points)
PUBLISHED = {
    "BODY_25B": COCO + ["upperneck", "headtop"] + FEET_B25B,
    "BODY_25": "nose neck rsho relb rwri lsho lelb lwri midhip rhip rkne rank lhip lkne lank reye leye rear lear".split()
    + FEET_B25B,
    "HALPE_26": COCO + "head neck hip lbig rbig lsmall rsmall lheel rheel".split(),
    "COCO_17": COCO,
    "COCO_133": COCO + FEET_B25B + ["face"] * 68 + ["hand"] * 42,
    "MEDIAPIPE_33": "nose leye_in leye leye_out reye_in reye reye_out lear rear mouth_l mouth_r lsho rsho lelb "
    "relb lwri rwri lpinky rpinky lindex rindex lthumb rthumb lhip rhip lkne rkne lank rank lheel rheel lfoot "
    "rfoot".split(),
}


def _real_people() -> list[np.ndarray]:
    """Every BODY_25B detection of the ten stored frames of the four cameras."""
    out = []
    for f in sorted(P2S.glob("cam0*_json/*.json")):
        out += openpose.read_people(f)
    return out


def _named(b25b: np.ndarray) -> dict[str, np.ndarray]:
    """The BODY_25B keypoints by short name, plus the points other layouts have (BODY_25's neck and mid-hip as
    OpenPose makes them, HALPE's head/neck/hip, MediaPipe's extra face and hand points near the face and wrists)."""
    d = dict(zip(PUBLISHED["BODY_25B"], b25b, strict=True))

    def mid(a, b):
        c = min(d[a][2], d[b][2])
        return np.r_[(d[a][:2] + d[b][:2]) / 2, c] if c > 0 else np.zeros(3)

    d.update(neck=mid("lsho", "rsho"), midhip=mid("lhip", "rhip"), hip=mid("lhip", "rhip"), head=d["headtop"])
    for k in ("leye_in", "leye_out", "reye_in", "reye_out", "mouth_l", "mouth_r", "face"):
        d[k] = d["nose"]
    for k in ("lpinky", "lindex", "lthumb", "hand"):
        d[k] = d["lwri"]
    for k in ("rpinky", "rindex", "rthumb"):
        d[k] = d["rwri"]
    d.update(lfoot=d["lbig"], rfoot=d["rbig"])
    return d


def _write(path: pathlib.Path, people: list[np.ndarray]) -> None:
    """One frame as OpenPose writes it (``version``, ``people`` with ``person_id`` and empty face / hand lists)."""
    doc = {
        "version": 1.3,
        "people": [
            {
                "person_id": [-1],
                "pose_keypoints_2d": [round(float(v), 3) for v in p.reshape(-1)],
                "face_keypoints_2d": [],
                "hand_left_keypoints_2d": [],
                "hand_right_keypoints_2d": [],
                "pose_keypoints_3d": [],
            }
            for p in people
        ],
    }
    path.write_text(json.dumps(doc))


def _expected(b25b: np.ndarray, neck: str) -> np.ndarray:
    """The evaluation joints of a BODY_25B detection, by the module's definitions."""
    d = _named(b25b)
    names = {"root": ("lhip", "rhip"), "thorax": neck, "head": ("lear", "rear")}
    short = {"shoulder": "sho", "elbow": "elb", "wrist": "wri", "hip": "hip", "knee": "kne", "ankle": "ank"}
    for s in ("left", "right"):
        for p, q in short.items():
            names[f"{s}_{p}"] = (f"{s[0]}{q}",)
    out = np.zeros((15, 3))
    for j, joint in enumerate(EVAL_JOINTS):
        parts = [d[n] for n in names[joint]]
        c = min(p[2] for p in parts)
        if c > 0:
            out[j] = [*np.mean([p[:2] for p in parts], axis=0), c]
    return out


@pytest.mark.parametrize("layout", list(PUBLISHED))
def test_each_layout_read_into_the_evaluation_joints(layout, tmp_path):
    people = _real_people()[:6]
    rows = [np.stack([_named(p)[n] for n in PUBLISHED[layout]]) for p in people]
    for t in range(3):
        _write(tmp_path / f"cam01_{t:012d}_keypoints.json", rows[2 * t : 2 * t + 2])
    files = openpose.frame_files(tmp_path)
    assert sorted(files) == [0, 1, 2]
    got = [openpose.read_people(files[t]) for t in range(3)]
    assert [len(g) for g in got] == [2, 2, 2] and got[0][0].shape == (K.COUNTS[layout], 3)
    neck = {"BODY_25": ("neck",), "BODY_25B": ("upperneck",), "HALPE_26": ("neck",)}.get(
        layout, ("lsho", "rsho")
    )
    for t in range(3):
        for i in range(2):
            ev = K.eval_keypoints(got[t][i], layout)
            np.testing.assert_allclose(ev, _expected(people[2 * t + i], neck), atol=2e-3)
    assert K.layout_of_count(K.COUNTS[layout])[0] == layout or K.COUNTS[layout] == 25


def test_body25_told_from_body25b():
    """Both have 25 keypoints; the real detections say which by where their neck and mid-hip lie."""
    b25b = _real_people()
    assert K.detect_layout(25, b25b) == "BODY_25B"
    b25 = [np.stack([_named(p)[n] for n in PUBLISHED["BODY_25"]]) for p in b25b]
    assert K.detect_layout(25, b25) == "BODY_25"
    assert K.detect_layout(25, b25[:1]) is None  # too few people to tell
    assert K.detect_layout(17, []) == "COCO_17" and K.detect_layout(33, []) == "MEDIAPIPE_33"
    with pytest.raises(ValueError, match="no known layout"):
        K.detect_layout(18, [])


def test_missing_confidence_and_negative_scores():
    kp = np.zeros((17, 3))
    kp[[11, 12], :] = [[10, 20, 0.9], [30, 40, 0.0]]  # right hip missing: no root
    kp[5] = [1, 2, -0.5]  # a negative score counts as missing
    ev = K.eval_keypoints(kp, "COCO_17")
    assert ev[EVAL_JOINTS.index("root")].tolist() == [0, 0, 0]
    assert ev[EVAL_JOINTS.index("left_hip")].tolist() == [10, 20, 0.9]
    assert ev[EVAL_JOINTS.index("left_shoulder"), 2] == 0
    with pytest.raises(ValueError, match="COCO_17 keypoints are"):
        K.eval_keypoints(np.zeros((18, 3)), "COCO_17")


def test_files_matched_by_frame_number(tmp_path):
    """A missing file is a frame without detections, never a shift of the later frames."""
    people = _real_people()
    for t in (0, 1, 3, 4):  # frame 2 has no file
        _write(tmp_path / f"cam02.{t:04d}.json", [people[t]])
    rows = openpose.load_openpose_folder(tmp_path, frames=range(5))
    assert rows.shape == (5, 25, 3)
    np.testing.assert_allclose(rows[2], 0)
    for t in (0, 1, 3, 4):
        np.testing.assert_allclose(rows[t], people[t], atol=1e-3)
    _write(tmp_path / "cam02.4.json", [people[0]])
    with pytest.raises(MocapInputError, match="frame 4 again"):
        openpose.frame_files(tmp_path)
    (tmp_path / "cam02.4.json").unlink()
    (tmp_path / "notes.json").write_text("{}")
    with pytest.raises(MocapInputError, match="no frame number"):
        openpose.frame_files(tmp_path)
    assert openpose.frame_number("video_000000000012_keypoints.json") == 12
    assert openpose.frame_number("cam01.0007.json") == 7
