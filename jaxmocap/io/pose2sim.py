"""Pose2Sim recordings: synchronised videos (or image folders), their calibration, OpenPose detections and the
triangulated ``.trc`` reference, as a tracking source.

Layout of a Pose2Sim trial (the ``Demo_SinglePerson`` demo):

* ``videos/camNN.mp4`` (or, for small copies, ``images/camNN/NNNN.jpg``), one per camera, frame ``t`` of every
  camera the same instant;
* a Pose2Sim calibration TOML (OpenCV convention, :func:`jaxmocap.io.calibration.load_pose2sim_toml`);
* ``camNN_json/camNN.NNNN.json``: OpenPose BODY_25B detections of every person in view;
* a ``.trc`` file of the 3D keypoints Pose2Sim triangulated from them (y-up, see :mod:`jaxmocap.io.trc`).

**Image size.** Some videos are narrower than the calibration says (1080 vs 1088 px): the detections were made on
the narrow frames in the calibration's pixel coordinates, so the frames are padded on the right (edge pixels
repeated) to the calibrated width.

**Scale.** The source delivers images resized by ``scale`` (``cv2.INTER_AREA``) with the rig and the keypoints
mapped to the resized pixels (:func:`jaxmocap.geometry.camera.scale_images`: ``u' = (u + 0.5)·s − 0.5``), so a tracker can
work on small images without resizing every frame twice.

**Subject.** A file can hold bystanders; the subject is the person whose confident keypoints (c > 0.1) span the
largest bounding-box diagonal (the person nearest to the camera), which picks the balancing subject in every frame
of the demo.
"""

from __future__ import annotations

import json
import os
import pathlib
from collections.abc import Sequence

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import body as body_mod
from jaxmocap.geometry import camera
from jaxmocap.io.calibration import load_calibration
from jaxmocap.io.openpose import BODY_25B_INDEX, BODY_25B_KEYPOINTS
from jaxmocap.io.sources import BadFrame, FrameData
from jaxmocap.io.trc import load_trc

__all__ = [
    "KEYPOINT_OF_TRC",
    "Pose2SimSource",
    "REFERENCE_OF",
    "body_dimensions",
    "reference_joints",
    "subject_keypoints",
]

#: BODY_25B keypoint index of each ``.trc`` marker (Pose2Sim's BODY_25B skeleton names the upper neck ``Neck``
#: and the head top ``Head``; the others as OpenPose does).
_TRC_NAME = {"UpperNeck": "Neck", "HeadTop": "Head"}
KEYPOINT_OF_TRC = {
    _TRC_NAME.get(name, name): BODY_25B_INDEX[name] for name in ("Nose", *BODY_25B_KEYPOINTS[5:19])
}  # the nose, then the shoulders to the head top

#: ``.trc`` markers averaged for each evaluation joint (:data:`jaxmocap.geometry.body.EVAL_JOINTS`). ``root`` is the middle
#: of the hips; ``head`` (the model's head centre) is approximated by the middle of the head top and the nose.
REFERENCE_OF = {
    "root": ("LHip", "RHip"),
    "thorax": ("Neck",),
    "head": ("Head", "Nose"),
    "left_shoulder": ("LShoulder",),
    "left_elbow": ("LElbow",),
    "left_wrist": ("LWrist",),
    "right_shoulder": ("RShoulder",),
    "right_elbow": ("RElbow",),
    "right_wrist": ("RWrist",),
    "left_hip": ("LHip",),
    "left_knee": ("LKnee",),
    "left_ankle": ("LAnkle",),
    "right_hip": ("RHip",),
    "right_knee": ("RKnee",),
    "right_ankle": ("RAnkle",),
}


def reference_joints(trc_path: str | os.PathLike) -> tuple[np.ndarray, dict[str, np.ndarray], float]:
    """The ``.trc`` reference in the z-up world: ``(eval joints (T, 15, 3), markers {name: (T, 3)}, fps)``."""
    names, X, fps = load_trc(trc_path, y_up=True)
    markers = {n: X[:, i] for i, n in enumerate(names)}
    missing = sorted({m for ms in REFERENCE_OF.values() for m in ms} - set(markers))
    if missing:
        raise MocapInputError(trc_path, f"lacks the markers {', '.join(missing)}")
    J = np.stack(
        [np.mean([markers[m] for m in REFERENCE_OF[j]], axis=0) for j in body_mod.EVAL_JOINTS], axis=1
    )
    return J, markers, fps


def _people(path: pathlib.Path) -> list[np.ndarray]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise MocapInputError(path, f"cannot read OpenPose JSON: {e}") from None
    people = data.get("people") if isinstance(data, dict) else None
    if not isinstance(people, list):
        raise MocapInputError(path, "no 'people' list: not an OpenPose keypoint file")
    out = []
    for p in people:
        kp = np.asarray(p.get("pose_keypoints_2d", []), np.float64)
        if kp.size % 3 or kp.size == 0:
            raise MocapInputError(path, "pose_keypoints_2d is not a list of (x, y, c) triples")
        out.append(kp.reshape(-1, 3))
    return out


def subject_keypoints(path: str | os.PathLike, num_keypoints: int = 25) -> np.ndarray:
    """Keypoints ``(K, 3)`` of the subject in one OpenPose file: the person whose keypoints with confidence > 0.1
    span the largest bounding-box diagonal (zeros when nobody is detected)."""
    best, size = np.zeros((num_keypoints, 3)), -1.0
    for kp in _people(pathlib.Path(path)):
        ok = kp[:, 2] > 0.1
        if ok.sum() < 2:
            continue
        d = float(np.linalg.norm(kp[ok, :2].max(axis=0) - kp[ok, :2].min(axis=0)))
        if d > size:
            best, size = kp[:num_keypoints], d
    return best


def body_dimensions(keypoints: np.ndarray, rig: camera.Rig) -> dict[str, float]:
    """Subject dimensions (metres) for :func:`jaxmocap.geometry.body.build` from detections ``(T, V, 25, 3)`` (BODY_25B,
    pixels of ``rig``): every keypoint triangulated per frame (confidence > 0.3 in at least two views), then the
    median over frames of each limb length (both sides pooled), shoulder and hip widths, the torso length
    ``|neck − mid-hip|`` and the shoulder drop ``|neck − mid-shoulder|``, with ``hip_drop = 0``: the detector's hips
    define the pelvis centre (their middle), so the model's root and thorax coincide with the middle of the
    detected hips and the detected neck."""
    import jax.numpy as jnp

    kp = np.asarray(keypoints, np.float64)
    rj = rig.to_jax(jnp.float32)
    T = kp.shape[0]
    X = np.full((T, kp.shape[2], 3), np.nan)
    for t in range(T):
        for k in range(kp.shape[2]):
            c = np.where(kp[t, :, k, 2] > 0.3, kp[t, :, k, 2], 0.0)
            if np.sum(c > 0) >= 2:
                X[t, k] = np.asarray(
                    camera.triangulate(
                        rj, jnp.asarray(kp[t, :, k, :2], jnp.float32), jnp.asarray(c, jnp.float32)
                    )
                )

    def dist(a, b):
        return np.linalg.norm(X[:, a] - X[:, b], axis=-1)

    def med(*ds):
        v = np.concatenate(ds)
        v = v[np.isfinite(v)]
        return float(np.median(v)) if v.size else float("nan")

    k = dict(KEYPOINT_OF_TRC)
    mid_hip = 0.5 * (X[:, k["LHip"]] + X[:, k["RHip"]])
    mid_shoulder = 0.5 * (X[:, k["LShoulder"]] + X[:, k["RShoulder"]])
    dims = {
        "upper_arm_length": med(dist(k["LShoulder"], k["LElbow"]), dist(k["RShoulder"], k["RElbow"])),
        "forearm_length": med(dist(k["LElbow"], k["LWrist"]), dist(k["RElbow"], k["RWrist"])),
        "thigh_length": med(dist(k["LHip"], k["LKnee"]), dist(k["RHip"], k["RKnee"])),
        "shin_length": med(dist(k["LKnee"], k["LAnkle"]), dist(k["RKnee"], k["RAnkle"])),
        "shoulder_width": med(dist(k["LShoulder"], k["RShoulder"])),
        "hip_width": med(dist(k["LHip"], k["RHip"])),
        "torso_length": med(np.linalg.norm(X[:, k["Neck"]] - mid_hip, axis=-1)),
        "shoulder_drop": med(np.linalg.norm(X[:, k["Neck"]] - mid_shoulder, axis=-1)),
        "hip_drop": 0.0,
    }
    return {n: v for n, v in dims.items() if np.isfinite(v) and (v > 0 or n == "hip_drop")}


class Pose2SimSource:
    """A Pose2Sim trial as a tracking source (the interface of :class:`jaxmocap.io.sources.VideoSource`).

    ``calibration``: Pose2Sim TOML; ``videos``: one file per camera, or ``image_dirs``: one folder of
    ``NNNN.jpg``/``.png`` per camera whose frame numbers are ``frames``; ``keypoint_dirs``: one OpenPose JSON folder
    per camera (``*.NNNN.json``); ``cameras``: indices of the calibration's cameras to use (default all);
    ``scale``: image scale of the delivered frames (``1.0`` = full size; see the module docstring); ``frames``: the
    recording's frame numbers (default ``range(number of video frames)``), frame ``i`` of the source is frame
    ``frames[i]`` of the recording. Stored images already at the target scale are used as they are.
    """

    def __init__(
        self,
        calibration: str | os.PathLike,
        keypoint_dirs: Sequence[str | os.PathLike],
        videos: Sequence[str | os.PathLike] | None = None,
        image_dirs: Sequence[str | os.PathLike] | None = None,
        cameras: Sequence[int] | None = None,
        scale: float = 1.0,
        frames: Sequence[int] | None = None,
        fps: float = 60.0,
    ):
        if (videos is None) == (image_dirs is None):
            raise MocapInputError(None, "give either videos or image folders")
        full = load_calibration(calibration)
        cams = list(range(full.num_views)) if cameras is None else [int(c) for c in cameras]
        inputs = list(videos if videos is not None else image_dirs)
        if len(inputs) != full.num_views:
            raise MocapInputError(calibration, f"{full.num_views} cameras but {len(inputs)} inputs")
        if len(keypoint_dirs) != full.num_views:
            raise MocapInputError(
                calibration, f"{full.num_views} cameras but {len(keypoint_dirs)} keypoint folders"
            )
        self.cameras = cams
        self.full_rig = camera.select(full, cams)
        self.scale = float(scale)
        self.rig = camera.scale_images(self.full_rig, self.scale) if self.scale != 1.0 else self.full_rig
        self.caps = None
        self.image_files = None
        if videos is not None:
            self.caps = []
            for c in cams:
                cap = cv2.VideoCapture(os.fspath(inputs[c]))
                if not cap.isOpened():
                    raise MocapInputError(inputs[c], "cannot open the video")
                self.caps.append(cap)
            n = min(int(round(cap.get(cv2.CAP_PROP_FRAME_COUNT))) for cap in self.caps)
            self.frame_numbers = list(range(n)) if frames is None else [int(f) for f in frames]
            self.positions = [0] * len(cams)
        else:
            if frames is None:
                raise MocapInputError(None, "image folders need the frame numbers")
            self.frame_numbers = [int(f) for f in frames]
            self.image_files = []
            for c in cams:
                folder = pathlib.Path(inputs[c])
                files = []
                for f in self.frame_numbers:
                    hits = [folder / f"{f:04d}{ext}" for ext in (".jpg", ".png")]
                    hits = [h for h in hits if h.is_file()]
                    if not hits:
                        raise MocapInputError(folder, f"no image {f:04d}.jpg/.png")
                    files.append(hits[0])
                self.image_files.append(files)
        self.num_frames = len(self.frame_numbers)
        kps = []
        for c in cams:
            folder = pathlib.Path(keypoint_dirs[c])
            per = []
            for f in self.frame_numbers:
                hits = sorted(folder.glob(f"*.{f:04d}.json")) or sorted(
                    folder.glob(f"*{f:012d}_keypoints.json")
                )
                if not hits:
                    raise MocapInputError(folder, f"no keypoint file for frame {f}")
                per.append(subject_keypoints(hits[0]))
            kps.append(np.stack(per))
        kp = np.stack(kps, axis=1)  # (T, V, K, 3) full-size pixels
        self.keypoints_full = kp.astype(np.float32)
        kp = kp.copy()
        kp[..., :2] = np.where(kp[..., 2:3] > 0, (kp[..., :2] + 0.5) * self.scale - 0.5, 0.0)
        self.keypoints = kp.astype(np.float32)
        self.fps = float(fps)
        self.view_names = self.rig.names
        self.has_masks = False
        self.has_depth = False
        self.has_keypoints = True
        self.body_path = None
        self.groundtruth = None
        self.description = {
            "pose2sim": os.fspath(calibration),
            "cameras": cams,
            "scale": self.scale,
            "frames": [self.frame_numbers[0], self.frame_numbers[-1] + 1],
        }

    def _fit(self, img: np.ndarray, v: int) -> np.ndarray:
        """Pad a narrow frame to the calibrated width, then resize to the source scale."""
        w, h = self.rig.image_size[v]
        if img.shape[1] == w and img.shape[0] == h:
            return img
        W, H = self.full_rig.image_size[v]
        if img.shape[0] != H or img.shape[1] > W:
            raise MocapInputError(
                None, f"camera {self.view_names[v]}: frame {img.shape[1]}x{img.shape[0]}, not {W}x{H}"
            )
        if img.shape[1] < W:
            img = cv2.copyMakeBorder(img, 0, 0, 0, W - img.shape[1], cv2.BORDER_REPLICATE)
        return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)

    def read(self, t: int, masks: bool = True, depth: bool = True):
        f = self.frame_numbers[t]
        images = []
        for v in range(len(self.cameras)):
            if self.caps is not None:
                cap = self.caps[v]
                if self.positions[v] != f:
                    cap.set(cv2.CAP_PROP_POS_FRAMES, f)
                ok, img = cap.read()
                self.positions[v] = f + 1 if ok else -1
                if not ok or img is None:
                    raise BadFrame(f"camera {self.view_names[v]}: frame {f} could not be decoded")
            else:
                img = cv2.imread(os.fspath(self.image_files[v][t]), cv2.IMREAD_COLOR)
                if img is None:
                    raise BadFrame(f"{self.image_files[v][t]}: cannot read image")
            images.append(self._fit(img, v))
        return FrameData(images, None, None, self.keypoints[t])

    def background(
        self, extrinsics: Sequence[str | os.PathLike] | None = None, num: int = 15
    ) -> list[np.ndarray]:
        """Background image per view (BGR, source scale): the per-pixel median of ``num`` frames spread over the
        source with the subject's region of each frame left out (the bounding box of its keypoints, widened by 25 %
        of its height), and, where the subject covers a pixel in all of them, the camera's scene image of
        ``extrinsics`` (one per calibration camera) when given, else the plain median."""
        pick = sorted(
            {int(i) for i in np.round(np.linspace(0, self.num_frames - 1, min(num, self.num_frames)))}
        )
        stacks = [[] for _ in self.cameras]
        keep = [[] for _ in self.cameras]
        for t in pick:
            fd = self.read(t)
            for v, img in enumerate(fd.images):
                m = np.ones(img.shape[:2], bool)
                kp = self.keypoints[t, v]
                ok = kp[:, 2] > 0.1
                if ok.sum() >= 2:
                    lo, hi = kp[ok, :2].min(axis=0), kp[ok, :2].max(axis=0)
                    pad = 0.25 * (hi[1] - lo[1])
                    x0, y0 = np.floor(lo - pad).astype(int)
                    x1, y1 = np.ceil(hi + pad).astype(int)
                    m[max(y0, 0) : max(y1 + 1, 0), max(x0, 0) : max(x1 + 1, 0)] = False
                stacks[v].append(img.astype(np.float32))
                keep[v].append(m)
        out = []
        for v in range(len(self.cameras)):
            S = np.stack(stacks[v])
            K = np.stack(keep[v])
            plain = np.median(S, axis=0)
            masked = np.where(K[..., None], S, np.nan)
            with np.errstate(all="ignore"):
                import warnings

                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    med = np.nanmedian(masked, axis=0)
            hole = ~np.any(K, axis=0)
            fill = plain
            if extrinsics is not None:
                ext = cv2.imread(os.fspath(extrinsics[self.cameras[v]]), cv2.IMREAD_COLOR)
                if ext is None:
                    raise MocapInputError(extrinsics[self.cameras[v]], "cannot read image")
                fill = self._fit(ext, v).astype(np.float32)
            med = np.where(hole[..., None], fill, med)
            out.append(np.clip(np.round(med), 0, 255).astype(np.uint8))
        return out

    def close(self) -> None:
        for cap in self.caps or []:
            cap.release()
