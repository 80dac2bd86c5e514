"""OpenPose 2D keypoint JSON (one file per frame, ``people[i].pose_keypoints_2d = [x0, y0, c0, x1, …]``), the
format OpenPose, Pose2Sim and rtmlib (RTMPose) write for every layout of :mod:`jaxmocap.io.keypoints`.

Pixel coordinates are (column, row) of the image the detector ran on; a keypoint that was not detected is written
as ``0, 0, 0``. Files are matched to video frames by the frame number in their name (:func:`frame_files`), never by
their rank: a missing file is a frame without detections.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Sequence

import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.io.keypoints import LAYOUTS

__all__ = [
    "BODY_25B_KEYPOINTS",
    "BODY_25B_INDEX",
    "BODY_25B_OF_JOINT",
    "frame_files",
    "frame_number",
    "load_openpose_folder",
    "load_openpose_json",
    "read_people",
]

#: Keypoint names of OpenPose's BODY_25B model, in output order.
BODY_25B_KEYPOINTS: tuple[str, ...] = LAYOUTS["BODY_25B"]

#: Index of each BODY_25B keypoint name (the one table of BODY_25B indices).
BODY_25B_INDEX: dict[str, int] = {name: i for i, name in enumerate(BODY_25B_KEYPOINTS)}

#: BODY_25B keypoint of each evaluation joint (:data:`jaxmocap.geometry.body.EVAL_JOINTS`) it measures (``thorax``
#: ≈ the upper neck; the root and the head centre have none).
BODY_25B_OF_JOINT: dict[str, int] = {
    joint: BODY_25B_INDEX[name]
    for joint, name in (
        ("thorax", "UpperNeck"),
        ("left_shoulder", "LShoulder"),
        ("right_shoulder", "RShoulder"),
        ("left_elbow", "LElbow"),
        ("right_elbow", "RElbow"),
        ("left_wrist", "LWrist"),
        ("right_wrist", "RWrist"),
        ("left_hip", "LHip"),
        ("right_hip", "RHip"),
        ("left_knee", "LKnee"),
        ("right_knee", "RKnee"),
        ("left_ankle", "LAnkle"),
        ("right_ankle", "RAnkle"),
    )
}


def _person_array(path, person: dict, k: int) -> np.ndarray:
    if not isinstance(person, dict) or "pose_keypoints_2d" not in person:
        raise MocapInputError(path, f"person {k} has no pose_keypoints_2d")
    kp = person["pose_keypoints_2d"]
    if not isinstance(kp, list) or len(kp) % 3 != 0:
        raise MocapInputError(path, f"person {k}: pose_keypoints_2d is not a list of (x, y, c) triples")
    try:
        arr = np.asarray([float(v) for v in kp], dtype=np.float64).reshape((-1, 3))
    except (TypeError, ValueError, OverflowError):
        raise MocapInputError(path, f"person {k}: pose_keypoints_2d holds a non-number") from None
    if not np.all(np.isfinite(arr)):
        raise MocapInputError(path, f"person {k}: non-finite keypoint values")
    return arr


def read_people(path: str | os.PathLike) -> list[np.ndarray]:
    """Keypoints ``(K, 3)`` = (x, y, confidence) of every person in an OpenPose-format JSON file (as OpenPose,
    Pose2Sim and rtmlib write them), in file order; every person must have the same ``K``."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except OSError as e:
        raise MocapInputError(path, f"cannot read: {e.strerror or e}") from None
    except UnicodeDecodeError:
        raise MocapInputError(path, "not a UTF-8 text file") from None
    except json.JSONDecodeError as e:
        raise MocapInputError(path, f"invalid JSON: {e.msg}", e.lineno) from None
    except (RecursionError, ValueError) as e:
        raise MocapInputError(path, f"invalid JSON: {e}") from None
    if not isinstance(data, dict) or not isinstance(data.get("people"), list):
        raise MocapInputError(path, "no 'people' list: not an OpenPose keypoint file")
    people = [_person_array(path, p, k) for k, p in enumerate(data["people"])]
    for k, p in enumerate(people):
        if p.shape[0] != people[0].shape[0]:
            raise MocapInputError(
                path, f"person {k} has {p.shape[0]} keypoints, person 0 {people[0].shape[0]}"
            )
    return people


def load_openpose_json(
    path: str | os.PathLike, person: str | int = "first", num_keypoints: int = len(BODY_25B_KEYPOINTS)
) -> np.ndarray:
    """Keypoints ``(K, 3)`` = (x, y, confidence) of one person in an OpenPose JSON file.

    ``person``: ``"first"`` (``people[0]``), ``"most_confident"`` (largest summed confidence) or an index. A file
    with no (such) person gives zeros, OpenPose's own "not detected", of ``num_keypoints`` rows. (A tracking run
    chooses its subject across views and time instead: :mod:`jaxmocap.io.subject`.)
    """
    people = read_people(path)
    for k, p in enumerate(people):
        if p.shape[0] != num_keypoints:
            raise MocapInputError(path, f"person {k} has {p.shape[0]} keypoints, expected {num_keypoints}")
    if person == "first":
        idx = 0
    elif person == "most_confident":
        idx = int(np.argmax([p[:, 2].sum() for p in people])) if people else 0
    elif isinstance(person, int) and not isinstance(person, bool):
        idx = person
    else:
        raise ValueError(f"person must be 'first', 'most_confident' or an index, not {person!r}")
    if idx >= len(people) or idx < 0:
        return np.zeros((num_keypoints, 3))
    return people[idx]


def frame_number(name: str) -> int | None:
    """The frame number in a keypoint file's name: the last group of digits, an OpenPose ``_keypoints`` suffix and
    the extension left out (``cam01.0007.json`` → 7, ``video_000000000012_keypoints.json`` → 12); None without
    digits."""
    stem = re.sub(r"(_keypoints)?\.json$", "", name, flags=re.IGNORECASE)
    m = re.findall(r"\d+", stem)
    return int(m[-1]) if m else None


def frame_files(folder: str | os.PathLike) -> dict[int, str]:
    """``{frame number: path}`` of the ``*.json`` files of a folder (:func:`frame_number`); a file without a
    number, or two files of one frame, is an error."""
    folder = os.fspath(folder)
    if not os.path.isdir(folder):
        raise MocapInputError(folder, "no such keypoint folder")
    try:
        names = sorted(f for f in os.listdir(folder) if f.lower().endswith(".json"))
    except OSError as e:
        raise MocapInputError(folder, f"cannot list: {e.strerror or e}") from None
    if not names:
        raise MocapInputError(folder, "no .json keypoint files")
    out: dict[int, str] = {}
    for name in names:
        n = frame_number(name)
        if n is None:
            raise MocapInputError(os.path.join(folder, name), "no frame number in the file name")
        if n in out:
            raise MocapInputError(
                os.path.join(folder, name), f"frame {n} again (also {os.path.basename(out[n])})"
            )
        out[n] = os.path.join(folder, name)
    return out


def load_openpose_folder(
    folder: str | os.PathLike,
    person: str | int = "first",
    num_keypoints: int = len(BODY_25B_KEYPOINTS),
    frames: Sequence[int] | None = None,
) -> np.ndarray:
    """Keypoints ``(T, K, 3)`` of one person per frame (:func:`load_openpose_json`), files matched to frames by the
    number in their name (:func:`frame_files`): rows for ``frames`` (default: every file's frame, in order), zeros
    for a frame without a file."""
    files = frame_files(folder)
    frames = sorted(files) if frames is None else [int(f) for f in frames]
    zero = np.zeros((num_keypoints, 3))
    return np.stack(
        [load_openpose_json(files[f], person, num_keypoints) if f in files else zero for f in frames]
    )
