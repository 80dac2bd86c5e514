"""Simulated 2D keypoint detections in OpenPose BODY_25B JSON, from the ground truth, with a seeded error model.

These detections are **simulated**: no detector ran. They stand in for OpenPose's output so that keypoint cues and
detection-based initialisation can be exercised on synthetic sequences, with an error model written here whose
parameters (:class:`DetectionModel`) are assumptions of the project, recorded in ``meta.json``; they are not
fitted to a real detector (the Pose2Sim demo's BODY_25B keypoints agree with triangulation to about 10 px at
1080 px, i.e. about 6 px at 640 px, the same order as the default noise here).

3D keypoints (:func:`keypoints_3d`) from the evaluation joints, the head spheroid and the toe tips, in the head
frame ``(f̂, l̂, â)`` (``â`` the head axis upwards, ``l̂`` the shoulder line made orthogonal to it, ``f̂ = l̂ × â``
forwards) with ``m`` the head centre, ``h`` half its length and ``r`` its equatorial radius:

* shoulders, elbows, wrists, hips, knees, ankles: the evaluation joints;
* ``Nose = m − 0.15 h â + r f̂``; ``L/REye = m + 0.1 h â + r (0.92 f̂ ± 0.35 l̂)``; ``L/REar = m ± r l̂``;
  ``HeadTop = m + h â``; ``UpperNeck`` halfway between the thorax and the head's lower pole ``m − h â``;
* per foot, with ``a`` the ankle, ``t`` the toe tip, ``v = t − a`` and ``ŝ`` the horizontal unit vector to the
  foot's outer side: ``BigToe = t − 0.025 ŝ``, ``SmallToe = a + 0.75 v + 0.03 ŝ``, ``Heel = a − 0.06 v̂ₕ −
  0.05 ẑ`` (``v̂ₕ`` the horizontal direction of ``v``).

Error model, per view and keypoint ``k`` with true pixel ``u_k``, camera depth ``z_k`` (m) and blur ``b_k`` (the
keypoint's image motion over the rendered exposure, pixels):

* visibility: a keypoint is **occluded** when no pixel within 2 px of ``u_k`` carries one of its own part labels
  (the rendered cones passing within their radius + 4 cm of it, the head for the head points), and a face point
  also when its surface normal faces away from the camera; outside the image or behind the camera it is not
  detected at all;
* missed with probability ``p_miss`` when visible, ``p_miss_occluded`` when occluded;
* a detected keypoint is ``u_k + ε``, ``ε ~ N(0, σ_k² I₂)`` with
  ``σ_k = c_k (σ₀ w / 640 + β b_k)(1 + γ max(0, z_k − z₀))`` times ``occluded_factor`` when occluded; ``c_k`` the
  COCO keypoint constant of the point relative to the elbow's (:data:`RELATIVE_SIGMA`), ``w`` the image width;
* with probability ``p_swap`` per view and frame the left and right keypoints of one limb pair (arms or legs with
  feet, equally likely) are exchanged after the noise;
* confidence ``clip(c₀ exp(−|ε|² / (2 (3 σ_k)²)) + N(0, 0.05²), 0.05, 0.99)`` with ``c₀ = conf_visible`` or
  ``conf_occluded``, times 0.8 for swapped keypoints; a missed keypoint is written ``0, 0, 0`` as OpenPose does.

Every random number of a view's frame comes from the generator the caller passes (the synthesiser's
``default_rng([seed, frame, view, 2])``).
"""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np

from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io.openpose import BODY_25B_KEYPOINTS

__all__ = [
    "BODY_25B",
    "RELATIVE_SIGMA",
    "DetectionModel",
    "keypoints_3d",
    "own_labels",
    "visibility",
    "simulate_view",
    "openpose_json",
    "write_openpose_json",
    "Detector",
]

#: OpenPose BODY_25B keypoints in output order.
BODY_25B = BODY_25B_KEYPOINTS
_K = {n: i for i, n in enumerate(BODY_25B)}

#: Per-keypoint noise relative to the elbow's: COCO's keypoint constants (nose .026, eyes .025, ears .035,
#: shoulders .079, elbows .072, wrists .062, hips .107, knees .087, ankles .089) divided by .072; the head top and
#: upper neck take the ears', the feet points the ankles'.
RELATIVE_SIGMA = (
    np.array(
        [0.026, 0.025, 0.025, 0.035, 0.035, 0.079, 0.079, 0.072, 0.072, 0.062, 0.062, 0.107, 0.107]
        + [0.087, 0.087, 0.089, 0.089, 0.035, 0.035, 0.089, 0.089, 0.089, 0.089, 0.089, 0.089]
    )
    / 0.072
)

_FACE = ("Nose", "LEye", "REye", "LEar", "REar")
_HEAD = (*_FACE, "HeadTop")
_SWAP_GROUPS = (
    (("LShoulder", "RShoulder"), ("LElbow", "RElbow"), ("LWrist", "RWrist")),
    (
        ("LHip", "RHip"),
        ("LKnee", "RKnee"),
        ("LAnkle", "RAnkle"),
        ("LBigToe", "RBigToe"),
        ("LSmallToe", "RSmallToe"),
        ("LHeel", "RHeel"),
    ),
)


@dataclasses.dataclass(frozen=True)
class DetectionModel:
    """Parameters of the error model of the module docstring (pixels, metres, probabilities)."""

    sigma0: float = 3.0
    blur_gain: float = 0.5
    distance_gain: float = 0.2
    distance0: float = 2.0
    occluded_factor: float = 3.0
    p_miss: float = 0.03
    p_miss_occluded: float = 0.7
    p_swap: float = 0.03
    conf_visible: float = 0.85
    conf_occluded: float = 0.35

    def sigma(self, width: int, depth: np.ndarray, blur: np.ndarray, occluded: np.ndarray) -> np.ndarray:
        """``σ_k (K,)`` of the module docstring for keypoints in BODY_25B order (or ``(..., 25)``)."""
        base = self.sigma0 * width / 640.0 + self.blur_gain * np.asarray(blur, np.float64)
        far = 1.0 + self.distance_gain * np.maximum(0.0, np.asarray(depth, np.float64) - self.distance0)
        return RELATIVE_SIGMA * base * far * np.where(occluded, self.occluded_factor, 1.0)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def keypoints_3d(
    joints: np.ndarray, head_poles: np.ndarray, head_radius: float, toes: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """BODY_25B keypoints of the module docstring and the outward normals of the face points.

    Args:
      joints: ``(T, 15, 3)`` evaluation joints; head_poles: ``(T, 2, 3)`` lower and upper pole of the head
        spheroid; head_radius: its equatorial radius; toes: ``(T, 2, 3)`` left and right toe tips.

    Returns ``(T, 25, 3)`` keypoints and ``(T, 5, 3)`` unit normals of Nose, LEye, REye, LEar, REar.
    """
    e = {n: joints[:, i] for i, n in enumerate(EVAL_JOINTS)}
    lo, hi = head_poles[:, 0], head_poles[:, 1]
    m, h = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo, axis=-1, keepdims=True)
    a = _unit(hi - lo)
    s = e["left_shoulder"] - e["right_shoulder"]
    left = _unit(s - np.sum(s * a, -1, keepdims=True) * a)
    fwd = np.cross(left, a)
    r = float(head_radius)
    eye_n = lambda sign: _unit(0.92 * fwd + sign * 0.35 * left)
    normals = np.stack([fwd, eye_n(1.0), eye_n(-1.0), left, -left], 1)
    T = joints.shape[0]
    out = np.zeros((T, 25, 3))
    out[:, _K["Nose"]] = m - 0.15 * h * a + r * fwd
    out[:, _K["LEye"]] = m + 0.1 * h * a + r * eye_n(1.0)
    out[:, _K["REye"]] = m + 0.1 * h * a + r * eye_n(-1.0)
    out[:, _K["LEar"]] = m + r * left
    out[:, _K["REar"]] = m - r * left
    out[:, _K["HeadTop"]] = hi
    out[:, _K["UpperNeck"]] = 0.5 * (e["thorax"] + lo)
    for side, s_ in (("left", "L"), ("right", "R")):
        for part in ("Shoulder", "Elbow", "Wrist", "Hip", "Knee", "Ankle"):
            out[:, _K[s_ + part]] = e[f"{side}_{part.lower()}"]
        ank = e[f"{side}_ankle"]
        tip = toes[:, 0 if side == "left" else 1]
        v = tip - ank
        vh = _unit(v * [1.0, 1.0, 0.0])
        outer = np.cross([0.0, 0.0, 1.0], vh) * (1.0 if side == "left" else -1.0)
        out[:, _K[s_ + "BigToe"]] = tip - 0.025 * outer
        out[:, _K[s_ + "SmallToe"]] = ank + 0.75 * v + 0.03 * outer
        out[:, _K[s_ + "Heel"]] = ank - 0.06 * vh - np.array([0.0, 0.0, 0.05])
    return out, normals


def own_labels(keypoints: np.ndarray, cone_a, cone_b, radius_a, radius_b, head_label: int) -> list[set[int]]:
    """Labels each keypoint ``(25, 3)`` may show as: the cones ``(C, 3)`` whose axis passes within their larger
    radius + 4 cm of it, and ``head_label`` for the head points."""
    a, b = np.asarray(cone_a), np.asarray(cone_b)
    d = b - a
    t = np.clip(
        np.einsum("kcx,cx->kc", keypoints[:, None] - a[None], d) / np.maximum((d * d).sum(-1), 1e-12), 0, 1
    )
    dist = np.linalg.norm(keypoints[:, None] - (a[None] + t[..., None] * d[None]), axis=-1)
    near = dist <= np.maximum(radius_a, radius_b)[None] + 0.04
    out = [set(np.flatnonzero(row).tolist()) for row in near]
    for n in _HEAD:
        out[_K[n]].add(head_label)
    out[_K["UpperNeck"]].add(head_label)
    return out


def visibility(
    uv: np.ndarray,
    depth: np.ndarray,
    labels: np.ndarray,
    own: list[set[int]],
    face_normals: np.ndarray,
    to_camera: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """``(in_view (25,), occluded (25,))`` of one view: ``uv (25, 2)`` true pixels, ``depth (25,)``, ``labels
    (H, W)`` rendered part labels, ``own`` from :func:`own_labels`, ``face_normals (5, 3)`` and ``to_camera
    (25, 3)`` unit vectors from each keypoint to the camera centre (module docstring)."""
    H, W = labels.shape
    px = np.rint(uv).astype(np.int64)
    in_view = (depth > 0) & (px[:, 0] >= 0) & (px[:, 0] < W) & (px[:, 1] >= 0) & (px[:, 1] < H)
    occluded = np.zeros(len(uv), bool)
    for k in np.flatnonzero(in_view):
        x0, x1 = max(0, px[k, 0] - 2), min(W, px[k, 0] + 3)
        y0, y1 = max(0, px[k, 1] - 2), min(H, px[k, 1] + 3)
        seen = set(np.unique(labels[y0:y1, x0:x1]).tolist())
        occluded[k] = not (seen & own[k])
    for i, n in enumerate(_FACE):
        occluded[_K[n]] |= float(face_normals[i] @ to_camera[_K[n]]) <= 0.0
    return in_view, occluded


def simulate_view(
    rng: np.random.Generator,
    uv: np.ndarray,
    depth: np.ndarray,
    blur: np.ndarray,
    in_view: np.ndarray,
    occluded: np.ndarray,
    width: int,
    model: DetectionModel = DetectionModel(),
) -> tuple[np.ndarray, dict]:
    """Detections ``(25, 3)`` = (x, y, confidence), zeros where missed, of one view and frame by the error model.

    Args: true pixels ``uv (25, 2)``, camera ``depth (25,)`` m, ``blur (25,)`` px, ``in_view``/``occluded``
    ``(25,)`` (:func:`visibility`), image ``width``. Draws, in this order: misses, noise, swap, confidence noise.

    Returns the detections and ``info``: ``detected (25,)`` per output slot, ``sigma (25,)`` and ``noise (25, 2)``
    per true keypoint (output slot ``k`` holds ``uv_k + noise_k`` unless swapped), and ``swapped`` (the exchanged
    slots, empty when none).
    """
    K = len(BODY_25B)
    p = np.where(occluded, model.p_miss_occluded, model.p_miss)
    detected = in_view & (rng.random(K) >= p)
    sigma = model.sigma(width, depth, blur, occluded)
    noise = rng.standard_normal((K, 2)) * sigma[:, None]
    xy = uv + noise
    base = np.where(occluded, model.conf_occluded, model.conf_visible)
    conf = base * np.exp(-np.sum(noise**2, -1) / (2 * (3 * sigma) ** 2))
    swapped: list[int] = []
    if rng.random() < model.p_swap:
        group = _SWAP_GROUPS[int(rng.integers(len(_SWAP_GROUPS)))]
        for ln, rn in group:
            i, j = _K[ln], _K[rn]
            xy[[i, j]] = xy[[j, i]]
            conf[[i, j]] = 0.8 * conf[[j, i]]
            detected[[i, j]] = detected[[j, i]]
            swapped += [i, j]
    conf = np.clip(conf + 0.05 * rng.standard_normal(K), 0.05, 0.99)
    out = np.zeros((K, 3))
    out[detected, :2] = xy[detected]
    out[detected, 2] = conf[detected]
    info = {"detected": detected, "sigma": sigma, "noise": noise, "swapped": np.asarray(swapped, np.int64)}
    return out, info


def openpose_json(detections: np.ndarray) -> str:
    """OpenPose's keypoint JSON (version 1.3 layout) of one person's ``(25, 3)`` detections."""
    person = {
        "person_id": [-1],
        "pose_keypoints_2d": [round(float(v), 3) for v in np.asarray(detections).reshape(-1)],
        "face_keypoints_2d": [],
        "hand_left_keypoints_2d": [],
        "hand_right_keypoints_2d": [],
        "pose_keypoints_3d": [],
        "face_keypoints_3d": [],
        "hand_left_keypoints_3d": [],
        "hand_right_keypoints_3d": [],
    }
    return json.dumps({"version": 1.3, "people": [person]}, sort_keys=True)


def write_openpose_json(path: str | os.PathLike, detections: np.ndarray) -> None:
    """Write :func:`openpose_json` to ``path``."""
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write(openpose_json(detections) + "\n")


class Detector:
    """Simulated detections of one sequence: every view's projections of the keypoints of every source frame,
    computed once (OpenCV's ``projectPoints``, the calibration's own model); :meth:`frame` draws one view's.

    Args:
      K, dist, R, t: the cameras (``(V, 3, 3)``, ``(V, 5)``, ``(V, 3, 3)``, ``(V, 3)``); sizes: ``(w, h)`` each.
      keypoints: ``(S, 25, 3)`` and normals ``(S, 5, 3)`` of every source frame (:func:`keypoints_3d`).
      blur: source frames per exposure (the synthesiser's ``blur``); model: the error model.
    """

    def __init__(self, K, dist, R, t, sizes, keypoints, normals, blur: int = 1, model=None):
        import cv2

        self.model = DetectionModel() if model is None else model
        self.sizes = [tuple(s) for s in sizes]
        self.keypoints = np.asarray(keypoints, np.float64)
        self.normals = np.asarray(normals, np.float64)
        self.blur = int(blur)
        S = self.keypoints.shape[0]
        flat = self.keypoints.reshape(-1, 3)
        self.uv, self.depth, self.centres = [], [], []
        for v in range(len(K)):
            rvec = cv2.Rodrigues(np.asarray(R[v], np.float64))[0]
            uv, _ = cv2.projectPoints(
                flat, rvec, np.asarray(t[v], np.float64), np.asarray(K[v]), np.asarray(dist[v])
            )
            self.uv.append(uv.reshape(S, 25, 2))
            self.depth.append((flat @ np.asarray(R[v]).T + t[v])[:, 2].reshape(S, 25))
            self.centres.append(-np.asarray(R[v]).T @ np.asarray(t[v]))

    def frame(self, rng: np.random.Generator, view: int, source: int, labels: np.ndarray, own) -> np.ndarray:
        """Detections ``(25, 3)`` of ``view`` at source frame ``source`` given its rendered ``labels (H, W)`` and
        :func:`own_labels` ``own``."""
        S = self.keypoints.shape[0]
        half = (self.blur - 1) // 2
        lo, hi = max(0, source - half), min(S - 1, source - half + self.blur - 1)
        uv, depth = self.uv[view][source], self.depth[view][source]
        blur = np.linalg.norm(self.uv[view][hi] - self.uv[view][lo], axis=-1)
        to_cam = _unit(self.centres[view] - self.keypoints[source])
        in_view, occluded = visibility(uv, depth, labels, own, self.normals[source], to_cam)
        out, _ = simulate_view(rng, uv, depth, blur, in_view, occluded, self.sizes[view][0], self.model)
        return out
