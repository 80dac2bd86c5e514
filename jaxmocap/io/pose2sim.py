"""Pose2Sim recordings: a Pose2Sim project folder as the input of a tracking run, the ``.trc`` reference, and the
scaled image-folder source of the tests and benchmarks.

**Project folder** (:func:`open_project`, what ``jaxmocap track FOLDER`` reads when ``FOLDER`` holds a
``Config.toml``), as Pose2Sim lays out a trial:

* ``Config.toml`` — ``[project] frame_rate`` (a number, or ``'auto'``: the videos'), ``frame_range`` (``[a, b]``:
  the frames tracked unless ``--frames`` says otherwise), ``[pose] pose_model`` (the keypoint layout, used when the
  files leave it open: :func:`jaxmocap.io.subject.load_subject`);
* ``calibration/`` — one calibration: a ``.toml`` (Pose2Sim's ``Calib_*.toml``), else EasyMocap's
  ``intri.yml``/``extri.yml``, else a Qualisys ``.qca.txt``; ``calibration/extrinsics/<video>_ext.*`` scene images,
  when there is one per camera, fill the background where the subject never leaves a pixel;
* ``videos/`` — one video per camera, in name order (the calibration's camera order);
* ``pose/`` — optional: ``<video>_json/`` keypoint folders (any layout of :mod:`jaxmocap.io.keypoints`).

It becomes a :class:`jaxmocap.io.sources.VideoSource` (codec padding, units, camera-order checks, subject selection).

**The demo's layout** (``Demo_SinglePerson``): ``videos/camNN.mp4``, a Pose2Sim calibration TOML (OpenCV convention,
:func:`jaxmocap.io.calibration.load_pose2sim_toml`), ``camNN_json/camNN.NNNN.json`` OpenPose BODY_25B detections
of every person in view and a ``.trc`` of the 3D keypoints Pose2Sim triangulated from them (y-up,
:mod:`jaxmocap.io.trc`); cam01/cam02 videos are 1080 px wide where the calibration says 1088 (codec padding).

**Image-folder source** (:class:`Pose2SimSource`): images resized by ``scale`` (``cv2.INTER_AREA``) with the rig and
the keypoints mapped to the resized pixels (:func:`jaxmocap.geometry.camera.scale_images`: ``u' = (u + 0.5)·s −
0.5``), frames narrower than the calibration by codec padding padded on the right (edge pixels repeated).
"""

from __future__ import annotations

import os
import pathlib
from collections.abc import Sequence

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import body as body_mod
from jaxmocap.geometry import camera
from jaxmocap.io.calibration import load_calibration
from jaxmocap.io.sources import BadFrame, FrameData, VideoSource, codec_cropped
from jaxmocap.io.subject import load_subject, subject_box
from jaxmocap.io.trc import load_trc

__all__ = [
    "JOINT_OF_TRC",
    "Pose2SimSource",
    "REFERENCE_OF",
    "is_project",
    "open_project",
    "project_settings",
    "reference_joints",
]

#: Index of each ``.trc`` marker that is an evaluation joint in the keypoints of a source
#: (:func:`jaxmocap.io.keypoints.eval_keypoints`; Pose2Sim's ``Neck`` is the thorax).
JOINT_OF_TRC = {
    name: body_mod.EVAL_JOINTS.index(joint)
    for name, joint in [("Neck", "thorax")]
    + [
        (f"{side[0].upper()}{part.capitalize()}", f"{side}_{part}")
        for side in ("left", "right")
        for part in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")
    ]
}

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
        sub = load_subject([keypoint_dirs[c] for c in cams], self.full_rig, self.frame_numbers, fps)
        self.notes = sub.notes
        kp = sub.keypoints.astype(np.float64)  # (T, V, 15, 3) full-size pixels
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
        if not codec_cropped((W, H), (img.shape[1], img.shape[0])):
            raise MocapInputError(
                None, f"camera {self.view_names[v]}: frame {img.shape[1]}x{img.shape[0]}, not {W}x{H}"
            )
        if img.shape[1] < W or img.shape[0] < H:
            img = cv2.copyMakeBorder(img, 0, H - img.shape[0], 0, W - img.shape[1], cv2.BORDER_REPLICATE)
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
                stacks[v].append(img.astype(np.float32))
                keep[v].append(subject_box(self.keypoints[t, v], img.shape[:2]))
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


# ---------------------------------------------------------------------------------------------------------------
# A Pose2Sim project folder

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v")


def is_project(folder: str | os.PathLike) -> bool:
    """Whether ``folder`` is a Pose2Sim project (a folder with ``Config.toml`` and ``videos/``)."""
    p = pathlib.Path(folder)
    return p.is_dir() and (p / "Config.toml").is_file() and (p / "videos").is_dir()


def project_settings(folder: str | os.PathLike) -> dict:
    """What ``Config.toml`` says that a tracking run uses: ``fps`` (None: the videos'), ``frames`` (``"a:b"`` or
    None), ``layout`` (the keypoint layout of ``[pose] pose_model``, or None) and ``multi_person``."""
    import tomllib

    from jaxmocap.io.keypoints import POSE2SIM_MODELS

    path = pathlib.Path(folder) / "Config.toml"
    try:
        cfg = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as e:
        raise MocapInputError(path, f"cannot read: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise MocapInputError(path, f"invalid TOML: {e}") from None
    project = cfg.get("project", {}) if isinstance(cfg.get("project"), dict) else {}
    pose = cfg.get("pose", {}) if isinstance(cfg.get("pose"), dict) else {}
    rate = project.get("frame_rate", "auto")
    fps = float(rate) if isinstance(rate, int | float) and not isinstance(rate, bool) and rate > 0 else None
    rng = project.get("frame_range", "auto")
    frames = None
    if isinstance(rng, list) and len(rng) == 2 and all(isinstance(v, int) for v in rng):
        frames = f"{rng[0]}:{rng[1]}"
    model = pose.get("pose_model")
    layout = POSE2SIM_MODELS.get(str(model).upper()) if isinstance(model, str) else None
    return {
        "fps": fps,
        "frames": frames,
        "layout": layout,
        "multi_person": project.get("multi_person") is True,
    }


def _project_calibration(folder: pathlib.Path) -> pathlib.Path:
    cal = folder / "calibration"
    if not cal.is_dir():
        raise MocapInputError(folder, "a Pose2Sim project needs a calibration/ folder")
    tomls = sorted(cal.glob("*.toml"))
    if len(tomls) > 1:
        calib = [p for p in tomls if p.name.lower().startswith("calib")]
        if len(calib) != 1:
            names = ", ".join(p.name for p in tomls)
            raise MocapInputError(cal, f"several calibration files ({names}): keep one")
        tomls = calib
    if tomls:
        return tomls[0]
    if (cal / "intri.yml").is_file() and (cal / "extri.yml").is_file():
        return cal
    qca = sorted(cal.glob("*.qca.txt"))
    if len(qca) == 1:
        return qca[0]
    raise MocapInputError(cal, "no calibration file (a .toml, intri.yml + extri.yml or a .qca.txt)")


def _project_keypoints(folder: pathlib.Path, videos: list[pathlib.Path]) -> list[pathlib.Path] | None:
    pose = folder / "pose"
    if not pose.is_dir():
        return None
    dirs = sorted(p for p in pose.iterdir() if p.is_dir() and p.name.lower().endswith("_json"))
    if not dirs:
        return None
    by_name = {p.name[: -len("_json")]: p for p in dirs}
    if all(v.stem in by_name for v in videos):
        return [by_name[v.stem] for v in videos]
    if len(dirs) != len(videos):
        raise MocapInputError(pose, f"{len(dirs)} keypoint folders (*_json) for {len(videos)} videos")
    return dirs


def open_project(
    folder: str | os.PathLike,
    keypoint_layout: str = "auto",
    calibration_units: str = "auto",
    detector: str | None = "none",
    progress=None,
    frames: str | None = None,
) -> VideoSource:
    """The frame source of a Pose2Sim project folder (module docstring); its ``project`` attribute holds
    :func:`project_settings` and its ``notes`` what was assumed. ``detector`` / ``progress`` / ``frames`` (default
    ``Config.toml``'s): for a project without keypoint folders (:class:`VideoSource`)."""
    folder = pathlib.Path(folder)
    if not is_project(folder):
        raise MocapInputError(folder, "not a Pose2Sim project (Config.toml and videos/)")
    settings = project_settings(folder)
    videos = sorted(p for p in (folder / "videos").iterdir() if p.suffix.lower() in VIDEO_SUFFIXES)
    if not videos:
        raise MocapInputError(folder / "videos", "no video files")
    calib = _project_calibration(folder)
    keypoints = _project_keypoints(folder, videos)
    src = VideoSource(
        videos,
        calib,
        keypoints,
        keypoint_layout=keypoint_layout,
        calibration_units=calibration_units,
        layout_hint=settings["layout"],
        fps=settings["fps"],
        detector=detector,
        progress=progress,
        frames=frames if frames is not None else settings["frames"],
    )
    if keypoints is None and src.detector is None:
        src.notes.append(f"{folder / 'pose'}: no keypoint folders: tracking from the images alone")
    if settings["multi_person"]:
        src.notes.append("Config.toml says multi_person = true: one person, the subject, is tracked")
    ext = folder / "calibration" / "extrinsics"
    scenes = [sorted(ext.glob(f"{v.stem}_ext.*")) if ext.is_dir() else [] for v in videos]
    if all(scenes):
        src.scene_images = [s[0] for s in scenes]
    src.project = settings
    src.description = {"pose2sim_project": os.fspath(folder), **src.description}
    return src
