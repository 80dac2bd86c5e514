"""2D keypoint layouts of the detectors people use, and their mapping to the evaluation joints.

Layouts, keypoints in the order the tools write them (``people[i].pose_keypoints_2d = [x0, y0, c0, x1, …]``):

* ``BODY_25`` — OpenPose's default body model (25: nose, neck, right arm, left arm, mid-hip, right leg, left leg,
  eyes, ears, feet);
* ``BODY_25B`` — OpenPose's experimental model (25: COCO's 17, upper neck, head top, feet), the detections shipped
  with Pose2Sim's demo;
* ``HALPE_26`` — AlphaPose's Halpe body (26: COCO's 17, head, neck, hip, feet), Pose2Sim's ``Body_with_feet``
  (RTMPose through rtmlib);
* ``COCO_17`` — the COCO keypoints (17), Pose2Sim's ``Body``;
* ``COCO_133`` — COCO-WholeBody (133: COCO's 17, 6 foot, 68 face, 42 hand keypoints), Pose2Sim's ``Whole_body``;
  only the body keypoints are used;
* ``MEDIAPIPE_33`` — MediaPipe / BlazePose landmarks (33), written in pixels (Pose2Sim's ``BLAZEPOSE``).

**Evaluation joints.** :func:`eval_keypoints` maps ``(…, K, 3)`` keypoints of a layout to ``(…, 15, 3)`` in the
order of :data:`jaxmocap.geometry.body.EVAL_JOINTS`: each joint is the keypoint of the same name, or the middle of
two (:data:`EVAL_SOURCES`): ``root`` = the middle of the hips, ``head`` = the middle of the ears (the head centre),
``thorax`` = the layout's neck (BODY_25 ``Neck``, BODY_25B ``UpperNeck``, HALPE_26 ``Neck``; these differ by a few
centimetres along the neck), else the middle of the shoulders (COCO, MediaPipe). A joint made of two keypoints has
the smaller of their confidences, and confidence 0 (and ``u = v = 0``, OpenPose's "not detected") where either is
missing. Negative confidences count as 0.

**Which layout.** :func:`detect_layout`: the number of keypoints tells 17, 26, 33 and 133 apart; 25 is BODY_25 or
BODY_25B, told apart by where the keypoints lie: BODY_25's keypoint 8 (mid-hip) is the middle of keypoints 9 and 12
(the hips) and its keypoint 1 (neck) the middle of keypoints 2 and 5 (the shoulders), which BODY_25B's keypoints
8 (right elbow), 9 (left wrist), 12 (right hip), 1, 2 (the eyes) and 5 (left shoulder) are not.
"""

from __future__ import annotations

import numpy as np

from jaxmocap.geometry.body import EVAL_JOINTS

__all__ = [
    "EVAL_SOURCES",
    "KEYPOINT_INDEX",
    "LAYOUTS",
    "POSE2SIM_MODELS",
    "detect_layout",
    "eval_keypoints",
    "layout_of_count",
]

_FEET = ("LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel")
_ARMS = ("LShoulder", "RShoulder", "LElbow", "RElbow", "LWrist", "RWrist")
_LEGS = ("LHip", "RHip", "LKnee", "RKnee", "LAnkle", "RAnkle")
_COCO = ("Nose", "LEye", "REye", "LEar", "REar", *_ARMS, *_LEGS)
_MEDIAPIPE = (
    "Nose",
    "LEyeInner",
    "LEye",
    "LEyeOuter",
    "REyeInner",
    "REye",
    "REyeOuter",
    "LEar",
    "REar",
    "MouthLeft",
    "MouthRight",
    *_ARMS,
    "LPinky",
    "RPinky",
    "LIndex",
    "RIndex",
    "LThumb",
    "RThumb",
    *_LEGS,
    "LHeel",
    "RHeel",
    "LFootIndex",
    "RFootIndex",
)
_BODY_25 = (
    "Nose",
    "Neck",
    "RShoulder",
    "RElbow",
    "RWrist",
    "LShoulder",
    "LElbow",
    "LWrist",
    "MidHip",
    "RHip",
    "RKnee",
    "RAnkle",
    "LHip",
    "LKnee",
    "LAnkle",
    "REye",
    "LEye",
    "REar",
    "LEar",
    *_FEET,
)

#: Keypoint names of each layout, in output order (``COCO_133``: its 23 body and foot keypoints; the face and hand
#: keypoints that follow are not named).
LAYOUTS: dict[str, tuple[str, ...]] = {
    "BODY_25": _BODY_25,
    "BODY_25B": (*_COCO, "UpperNeck", "HeadTop", *_FEET),
    "HALPE_26": (
        *_COCO,
        "Head",
        "Neck",
        "Hip",
        "LBigToe",
        "RBigToe",
        "LSmallToe",
        "RSmallToe",
        "LHeel",
        "RHeel",
    ),
    "COCO_17": _COCO,
    "COCO_133": (*_COCO, "LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel"),
    "MEDIAPIPE_33": _MEDIAPIPE,
}

#: Number of keypoints a file of each layout holds per person.
COUNTS: dict[str, int] = {**{n: len(k) for n, k in LAYOUTS.items()}, "COCO_133": 133}

#: Pose2Sim's names of its pose models (``[pose] pose_model`` of ``Config.toml``), old and new, and their layouts.
POSE2SIM_MODELS: dict[str, str] = {
    "BODY_25": "BODY_25",
    "BODY_25B": "BODY_25B",
    "HALPE_26": "HALPE_26",
    "BODY_WITH_FEET": "HALPE_26",
    "COCO_17": "COCO_17",
    "BODY": "COCO_17",
    "COCO_133": "COCO_133",
    "WHOLE_BODY": "COCO_133",
    "COCO_133_WRIST": "COCO_133",
    "WHOLE_BODY_WRIST": "COCO_133",
    "BLAZEPOSE": "MEDIAPIPE_33",
    "MEDIAPIPE_33": "MEDIAPIPE_33",
}

_NECK = {"BODY_25": ("Neck",), "BODY_25B": ("UpperNeck",), "HALPE_26": ("Neck",)}

#: Keypoint names whose middle (or which, alone) each evaluation joint is, per layout (module docstring).
EVAL_SOURCES: dict[str, dict[str, tuple[str, ...]]] = {
    layout: {
        "root": ("LHip", "RHip"),
        "thorax": _NECK.get(layout, ("LShoulder", "RShoulder")),
        "head": ("LEar", "REar"),
        **{
            f"{side}_{part}": (f"{side[0].upper()}{part.capitalize()}",)
            for side in ("left", "right")
            for part in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")
        },
    }
    for layout in LAYOUTS
}

#: Index into :func:`eval_keypoints`'s array of each joint that the tracker compares with detections: every
#: evaluation joint but the root and the head, which no detector measures directly (they are middles of pairs);
#: thorax, then left before right for each part (the order of the keypoint cue's sum).
KEYPOINT_INDEX: dict[str, int] = {
    j: EVAL_JOINTS.index(j)
    for j in ["thorax"]
    + [f"{s}_{p}" for p in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle") for s in ("left", "right")]
}


def layout_of_count(count: int) -> list[str]:
    """The layouts whose files hold ``count`` keypoints per person."""
    return [n for n, c in COUNTS.items() if c == count]


def eval_keypoints(keypoints: np.ndarray, layout: str) -> np.ndarray:
    """``(…, K, 3)`` keypoints of ``layout`` → ``(…, 15, 3)`` evaluation joints (module docstring)."""
    if layout not in LAYOUTS:
        raise ValueError(f"unknown keypoint layout {layout!r}; choose one of {', '.join(LAYOUTS)}")
    kp = np.asarray(keypoints, np.float64)
    if kp.shape[-2] != COUNTS[layout] or kp.shape[-1] != 3:
        raise ValueError(f"{layout} keypoints are (..., {COUNTS[layout]}, 3), got {kp.shape}")
    index = {n: i for i, n in enumerate(LAYOUTS[layout])}
    out = np.zeros((*kp.shape[:-2], len(EVAL_JOINTS), 3))
    for j, joint in enumerate(EVAL_JOINTS):
        parts = kp[..., [index[n] for n in EVAL_SOURCES[layout][joint]], :]  # (…, n, 3)
        c = np.min(np.maximum(parts[..., 2], 0.0), axis=-1)
        ok = c > 0
        out[..., j, :2] = np.where(ok[..., None], np.mean(parts[..., :2], axis=-2), 0.0)
        out[..., j, 2] = c
    return out


def _middle_residual(people: list[np.ndarray], mid: int, a: int, b: int) -> list[float]:
    """``|k_mid − (k_a + k_b)/2| / |k_a − k_b|`` of each person detecting all three keypoints."""
    out = []
    for p in people:
        if min(p[mid, 2], p[a, 2], p[b, 2]) <= 0.1:
            continue
        span = float(np.linalg.norm(p[a, :2] - p[b, :2]))
        if span > 1e-6:
            out.append(float(np.linalg.norm(p[mid, :2] - 0.5 * (p[a, :2] + p[b, :2]))) / span)
    return out


def detect_layout(count: int, people: list[np.ndarray], min_people: int = 3) -> str | None:
    """The layout of detections with ``count`` keypoints (module docstring); ``people``: ``(count, 3)`` arrays of
    detected persons (for 25 keypoints). None when 25 keypoints and fewer than ``min_people`` persons detect the
    keypoints that tell BODY_25 from BODY_25B; ``ValueError`` for a count no layout has."""
    names = layout_of_count(count)
    if not names:
        known = ", ".join(f"{n} ({c})" for n, c in COUNTS.items())
        raise ValueError(f"{count} keypoints per person: no known layout ({known})")
    if len(names) == 1:
        return names[0]
    # 25 keypoints: BODY_25's mid-hip and neck are the middles of the hips and of the shoulders
    r = _middle_residual(people, 8, 9, 12) + _middle_residual(people, 1, 2, 5)
    if len(r) < min_people:
        return None
    return "BODY_25" if float(np.median(r)) < 0.15 else "BODY_25B"
