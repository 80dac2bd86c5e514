"""Frame sources of a tracking run: per frame the BGR images of every view, optional foreground masks, depth maps
(metres) and 2D keypoints.

A source has ``rig``, ``fps``, ``num_frames``, ``view_names``, ``has_masks``, ``has_depth``, ``has_keypoints``,
``body_path``, ``groundtruth`` (``(T, 15, 3)`` joints or None), ``plate_files`` (one empty-scene image per view,
or None), ``description`` (a dict for ``run.json``), ``read(t, masks=True, depth=True) -> FrameData``,
``plates()`` and ``close()``. A frame that cannot be read raises
:class:`BadFrame`; everything else that is wrong with the input raises :class:`~jaxmocap.errors.MocapInputError`.

* :class:`SequenceSource` — a sequence folder (:mod:`jaxmocap.io.sequence`);
* :class:`VideoSource` — synchronised videos + a calibration, optional OpenPose keypoint folders and depth-map
  folders (``.npy`` metres, 16-bit PNG millimetres or float TIFF metres).
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib
from collections.abc import Sequence
from typing import NamedTuple

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.io.calibration import check_units, load_calibration

__all__ = [
    "DETECTIONS",
    "BadFrame",
    "FrameData",
    "SequenceSource",
    "VideoSource",
    "codec_cropped",
    "fit_image_sizes",
    "read_plates",
]


#: the folder of a sequence view's 2D detections (``views/<camera>/openpose/``)
DETECTIONS = "openpose"


class BadFrame(Exception):
    """A frame that cannot be read (a corrupt image, a video frame that does not decode)."""


class FrameData(NamedTuple):
    """One frame of every view: ``images`` BGR uint8 ``(H, W, 3)``; ``masks`` bool ``(H, W)`` or None; ``depth``
    float32 metres (0 = none) or None; ``keypoints`` ``(V, K, 3)`` (u, v, confidence) or None."""

    images: list
    masks: list | None
    depth: list | None
    keypoints: np.ndarray | None


def _check_depth(path, d: np.ndarray) -> np.ndarray:
    d = np.asarray(d, np.float32)
    if d.ndim != 2:
        raise MocapInputError(path, f"a depth map must be 2-D, got shape {d.shape}")
    if not np.all(np.isfinite(d)):
        bad = int(np.sum(~np.isfinite(d)))
        raise MocapInputError(path, f"depth map has {bad} NaN/inf values (use 0 for 'no depth')")
    if np.any(d < 0):
        raise MocapInputError(path, "depth map has negative values")
    return d


def _check_depth_units(path, d: np.ndarray, from_mm: bool) -> None:
    """Refuse a depth map whose median depth (of the positive values, every 4th pixel) is not 0.1–30 m."""
    sample = d[::4, ::4]
    pos = sample[sample > 0]
    if pos.size < 16:
        return
    med = float(np.median(pos))
    if 0.1 <= med <= 30.0:
        return
    if from_mm:
        why = "16-bit depth images are millimetres"
    else:
        why = "depth maps in .npy / float TIFF files are metres" + (" (millimetres?)" if med > 30 else "")
    raise MocapInputError(path, f"median depth {med:.4g} m, not 0.1-30 m: {why}")


def _read_depth_file(path: pathlib.Path, size) -> np.ndarray:
    """A depth map file: ``.npy`` float metres, or a 16-bit PNG / float TIFF (millimetres / metres)."""
    if not path.is_file():
        raise MocapInputError(path, "missing depth map")
    from_mm = False
    if path.suffix.lower() == ".npy":
        try:
            d = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise MocapInputError(path, f"cannot read depth map: {e}") from None
    else:
        img = cv2.imread(os.fspath(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise MocapInputError(path, "cannot read depth map (corrupt or unknown format)")
        from_mm = img.dtype == np.uint16
        d = img.astype(np.float32) / 1000.0 if from_mm else img
    d = _check_depth(path, d)
    _check_depth_units(path, d, from_mm)
    if size is not None and (d.shape[1], d.shape[0]) != tuple(size):
        raise MocapInputError(
            path, f"depth map is {d.shape[1]}x{d.shape[0]}, the calibration says {size[0]}x{size[1]}"
        )
    return d


def read_plates(paths: Sequence[pathlib.Path], rig) -> list[np.ndarray]:
    """The empty-scene plates ``paths`` (one image file per camera of ``rig``, in its order) as BGR uint8 images
    of the calibration's image sizes. :class:`MocapInputError` naming the file when one is missing, unreadable
    or of another size."""
    if len(paths) != len(rig.image_size):
        raise MocapInputError(
            paths[0] if paths else None, f"{len(paths)} plates for {len(rig.image_size)} cameras"
        )
    out = []
    for path, size in zip(paths, rig.image_size, strict=True):
        path = pathlib.Path(path)
        if not path.is_file():
            raise MocapInputError(path, "no such plate (an image of the camera's empty scene)")
        img = cv2.imread(os.fspath(path), cv2.IMREAD_COLOR)
        if img is None:
            raise MocapInputError(path, "cannot read the plate image")
        want = tuple(int(x) for x in size)
        if (img.shape[1], img.shape[0]) != want:
            raise MocapInputError(
                path,
                f"the plate is {img.shape[1]}x{img.shape[0]} but the camera's images are {want[0]}x{want[1]}",
            )
        out.append(img)
    return out


class SequenceSource:
    """Frames of a sequence folder (:func:`jaxmocap.io.sequence.load_sequence`).

    Detections: when every view has a ``views/<camera>/openpose/`` folder (OpenPose-format JSON of any layout of
    :mod:`jaxmocap.io.keypoints`, e.g. the simulated BODY_25B detections that ``jaxmocap synth`` writes), they are
    read as a video's keypoint folders are (:func:`jaxmocap.io.subject.load_subject`: layout, subject selection,
    the calibration checked against them) and every frame carries its keypoints; ``detections=False`` ignores them.

    ``recording=True`` reads the folder as a real recording gives it: the images, calibration, plates, depth maps
    and detections, but not the rendered masks (``has_masks`` False: the tracker's own ``--foreground`` segments
    the images) and not the ground truth (``groundtruth`` None: nothing to initialise from or score against inside
    the run; evaluate afterwards with ``jaxmocap eval``).
    """

    def __init__(
        self,
        root: str | os.PathLike,
        detections: bool = True,
        recording: bool = False,
        keypoint_layout: str = "auto",
    ):
        from jaxmocap.io import sequence as seqio

        self.seq = seqio.load_sequence(root)
        self.root = pathlib.Path(root)
        self.rig = self.seq.rig
        self.fps = self.seq.fps
        self.num_frames = self.seq.num_frames
        self.view_names = self.seq.view_names
        self.has_masks = "mask" in self.seq.channels and not recording
        self.has_depth = "depth" in self.seq.channels
        self.body_path = self.seq.body_path
        gt = self.seq.groundtruth
        self.groundtruth = None if (gt is None or recording) else gt.joints
        plates = [self.root / seqio.VIEWS / name / seqio.PLATE for name in self.view_names]
        self.plate_files = plates if all(p.is_file() for p in plates) else None
        self.description = {"sequence": os.fspath(self.root)}
        if recording:
            self.description["read as"] = "recording (no masks, no ground truth)"
        self.notes: list[str] = []
        self.keypoints, self.keypoint_layout = None, None
        folders = [self.root / seqio.VIEWS / name / DETECTIONS for name in self.view_names]
        if detections and all(f.is_dir() and any(f.glob("*.json")) for f in folders):
            from jaxmocap.io.subject import load_subject

            T = self.num_frames
            sub = load_subject(
                [os.fspath(f) for f in folders], self.rig, range(T), self.fps, keypoint_layout, total=T
            )
            self.keypoints, self.keypoint_layout = sub.keypoints, sub.layout  # (T, V, 15, 3)
            self.notes += sub.notes
            self.description["keypoints"] = f"views/<camera>/{DETECTIONS}/ ({sub.layout})"
        self.has_keypoints = self.keypoints is not None

    def plates(self) -> list[np.ndarray]:
        """The views' empty-scene plates (:func:`read_plates`)."""
        return read_plates(self.plate_files or [], self.rig)

    def read(self, t: int, masks: bool = True, depth: bool = True) -> FrameData:
        """Frame ``t``: BGR images, and the masks / depth maps the sequence has unless ``masks`` / ``depth`` is
        False (each is a PNG to decode: a tracker that does not use them skips them)."""
        try:
            images = [v.bgr(t) for v in self.seq.views]
            m = [v.mask(t) for v in self.seq.views] if (masks and self.has_masks) else None
            d = (
                [_check_depth(v.path("depth", t), v.depth(t)) for v in self.seq.views]
                if (depth and self.has_depth)
                else None
            )
        except MocapInputError as e:
            if "cannot read image" in str(e) or "missing image" in str(e):
                raise BadFrame(str(e)) from None
            raise
        return FrameData(images, m, d, None if self.keypoints is None else self.keypoints[t])

    def close(self) -> None:
        pass


def codec_cropped(calibrated: tuple[int, int], video: tuple[int, int]) -> bool:
    """Whether a ``video (w, h)`` frame is the ``calibrated (w, h)`` image cropped at the right / bottom by a codec's
    padding: each side equal, or the calibrated one the video's rounded up to the codec's block (a multiple of 8
    that is less than 16 pixels larger: 1080 → 1088)."""
    return all(c == v or (v < c < v + 16 and c % 8 == 0) for c, v in zip(calibrated, video, strict=True))


def fit_image_sizes(rig, sizes, files, calibration) -> tuple[tuple, list[str]]:
    """The image size of each camera for frames of ``sizes`` (w, h) from ``files``: the calibrated size, the
    video's when the calibration has none or when the video is the calibrated image cropped by codec padding
    (:func:`codec_cropped`: pixel coordinates are kept, a note says so); any other difference is refused."""
    fixed, notes = [], []
    for k, (f, s) in enumerate(zip(files, sizes, strict=True)):
        want = tuple(rig.image_size[k])
        if want == (0, 0) or want == tuple(s):
            fixed.append(tuple(s))
        elif codec_cropped(want, s):
            fixed.append(tuple(s))
            notes.append(
                f"camera {rig.names[k]!r} is calibrated for {want[0]}x{want[1]} images and {pathlib.Path(f).name} "
                f"is {s[0]}x{s[1]}: taken as the calibrated image cropped by the codec's padding (same pixel "
                "coordinates)"
            )
        else:
            raise MocapInputError(
                calibration,
                f"camera {rig.names[k]!r} is calibrated for {want[0]}x{want[1]} images but {pathlib.Path(f).name} "
                f"is {s[0]}x{s[1]} (not the calibrated image cropped by codec padding)",
            )
    return tuple(fixed), notes


def _numbered(paths) -> list[pathlib.Path]:
    """Paths in order of the last number in their names (then by name)."""
    from jaxmocap.io.openpose import frame_number

    return sorted(paths, key=lambda p: (frame_number(p.name + ".json") or 0, p.name))


class VideoSource:
    """Synchronised videos (frame ``t`` of every video is the same instant) with their calibration, optional
    keypoint folders (one per camera, OpenPose-format JSON of any layout of :mod:`jaxmocap.io.keypoints`, matched
    to frames by the number in their names; the subject chosen across views and time, :mod:`jaxmocap.io.subject`)
    and depth-map folders (one per camera: ``.npy`` metres, 16-bit PNG millimetres, or float TIFF metres, one file
    per frame in the order of the numbers in their names).

    Checks: the calibration's units (:func:`jaxmocap.io.calibration.check_units`, ``calibration_units``), its image
    sizes against the videos' (:func:`fit_image_sizes`), and, with keypoints, its cameras against the detections
    (:func:`jaxmocap.io.subject.check_rig`: camera order, units); depth maps must be in metres (median depth
    0.1–30 m). ``notes``: what was assumed or converted, for the user. ``keypoint_layout``: ``"auto"`` or a layout
    name; ``layout_hint``: the layout the recording's configuration names (used when the files leave it open).
    ``plates``: one image of the empty scene per camera (for ``--foreground plate``), checked when read.
    ``detector``: without ``keypoints``, the 2D pose detector that makes them (:mod:`jaxmocap.io.detect`:
    ``auto``, ``none`` or a detector's name; its detections cached per video) for the frames ``"A:B"`` (the
    run's; default all, the others without detections); ``progress``: called with a line before and after each
    video's detection.
    """

    def __init__(
        self,
        videos: Sequence[str | os.PathLike],
        calibration: str | os.PathLike,
        keypoints: Sequence[str | os.PathLike] | None = None,
        depth: Sequence[str | os.PathLike] | None = None,
        keypoint_layout: str = "auto",
        calibration_units: str = "auto",
        layout_hint: str | None = None,
        fps: float | None = None,
        plates: Sequence[str | os.PathLike] | None = None,
        detector: str | None = "none",
        progress=None,
        frames: str | None = None,
    ):
        self.videos = [pathlib.Path(v) for v in videos]
        if not self.videos:
            raise MocapInputError(None, "no video given")
        for v in self.videos:
            if not v.is_file():
                raise MocapInputError(v, "no such video file")
            if not os.access(v, os.R_OK):
                raise MocapInputError(v, "video file is not readable")
        calibration = pathlib.Path(calibration)
        if not calibration.exists():
            raise MocapInputError(calibration, "no such calibration file")
        rig = load_calibration(calibration)
        rig, unit_note = check_units(rig, calibration_units, calibration)
        self.notes = [] if unit_note is None else [f"{calibration}: {unit_note}"]
        if rig.num_views != len(self.videos):
            raise MocapInputError(
                calibration,
                f"the calibration has {rig.num_views} cameras but {len(self.videos)} videos were given",
            )
        self.caps, counts, sizes, fpss = [], [], [], []
        for v in self.videos:
            cap = cv2.VideoCapture(os.fspath(v))
            if not cap.isOpened():
                raise MocapInputError(v, "cannot open the video (unknown format or corrupt)")
            self.caps.append(cap)
            counts.append(int(round(cap.get(cv2.CAP_PROP_FRAME_COUNT))))
            sizes.append((int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))))
            fpss.append(float(cap.get(cv2.CAP_PROP_FPS)))
        for v, n in zip(self.videos, counts, strict=True):
            if n != counts[0]:
                raise MocapInputError(
                    v,
                    f"has {n} frames but {self.videos[0]} has {counts[0]}: the videos must be synchronised frame by frame",
                )
        if counts[0] <= 0:
            raise MocapInputError(self.videos[0], "the video has no frame")
        fixed, size_notes = fit_image_sizes(rig, sizes, self.videos, calibration)
        self.notes += size_notes
        self.rig = dataclasses.replace(rig, image_size=fixed)
        self.num_frames = counts[0]
        if fps is not None:
            self.fps = float(fps)
        else:
            self.fps = fpss[0] if fpss[0] > 0 and math.isfinite(fpss[0]) else 30.0
        self.view_names = self.rig.names
        self.positions = [0] * len(self.caps)
        self.has_masks = False
        self.body_path = None
        self.groundtruth = None
        self.scene_images = None
        self.keypoints = None
        self.keypoint_layout = None
        self.detector = None
        if not keypoints and detector not in (None, "none"):
            keypoints, keypoint_layout = self._detect(detector, progress, frames), "MEDIAPIPE_33"
        if keypoints:
            from jaxmocap.io.subject import load_subject

            if len(keypoints) != len(self.videos):
                raise MocapInputError(
                    keypoints[0], f"{len(keypoints)} keypoint folders for {len(self.videos)} videos"
                )
            a, b = self.detected if self.detector is not None else (0, self.num_frames)
            sub = load_subject(
                [os.fspath(k) for k in keypoints],
                self.rig,
                range(a, b),
                self.fps,
                keypoint_layout,
                layout_hint,
                total=self.num_frames,
                mirrored=self.detector is not None,  # the detector may read a back as a front
            )
            shape = (
                self.num_frames,
                *sub.keypoints.shape[1:],
            )  # (T, V, 15, 3); zeros outside the frames read
            self.keypoints = np.zeros(shape, np.float32)
            self.keypoints[a:b], self.keypoint_layout = sub.keypoints, sub.layout
            if self.detector is not None and not np.any(self.keypoints[..., 2] > 0):
                self.notes.append(
                    f"the {self.detector} detector found no subject: tracking from the images alone"
                )
                self.keypoints, self.keypoint_layout, self.detector = None, None, None
            else:
                self.notes += sub.notes
        self.has_keypoints = self.keypoints is not None
        #: no detections checked the calibration against the videos: the tracker's setup checks the camera order
        #: with the silhouettes (:meth:`jaxmocap.tracking.setup.TrackSetup._check_camera_order`)
        self.check_silhouettes = not self.has_keypoints
        self.depth_files = None
        if depth:
            if len(depth) != len(self.videos):
                raise MocapInputError(depth[0], f"{len(depth)} depth folders for {len(self.videos)} videos")
            self.depth_files = []
            for folder in depth:
                folder = pathlib.Path(folder)
                if not folder.is_dir():
                    raise MocapInputError(folder, "no such depth folder")
                files = _numbered(
                    p for p in folder.iterdir() if p.suffix.lower() in (".npy", ".png", ".tif", ".tiff")
                )
                if len(files) != self.num_frames:
                    raise MocapInputError(
                        folder, f"has {len(files)} depth maps for {self.num_frames} video frames"
                    )
                self.depth_files.append(files)
        self.has_depth = self.depth_files is not None
        self.plate_files = [pathlib.Path(p) for p in plates] if plates else None
        if self.plate_files is not None and len(self.plate_files) != len(self.videos):
            raise MocapInputError(
                self.plate_files[0], f"{len(self.plate_files)} plates for {len(self.videos)} videos"
            )
        self.description = {
            "videos": [os.fspath(v) for v in self.videos],
            "calibration": os.fspath(calibration),
            "keypoints": [os.fspath(k) for k in keypoints or []],
            "keypoint_layout": self.keypoint_layout,
            "depth": [os.fspath(d) for d in depth or []],
        }
        if self.detector is not None:
            self.description["detector"] = self.detector
        if plates:
            self.description["plates"] = [os.fspath(p) for p in plates]

    def _detect(self, detector: str, progress, frames: str | None) -> list[pathlib.Path] | None:
        """The keypoint folders of the videos made by ``detector`` (``auto`` or a name of
        :data:`jaxmocap.io.detect.DETECTORS`; :func:`jaxmocap.io.detect.detect_video`: read from the cache when
        there) for the frames ``"A:B"`` (default all; ``detected``: the range), or None with a note when ``auto``
        finds no detector installed."""
        from jaxmocap.choices import parse_frames
        from jaxmocap.io import detect

        name, note = detect.resolve_detector(detector)
        if note is not None:
            self.notes.append(note)
        if name is None:
            return None
        self.detected = parse_frames(frames, self.num_frames)
        model = detect.BlazePose()
        folders = []
        for v in self.videos:
            folder, count = detect.detect_video(v, model, progress=progress, frames=self.detected)
            how = "read from" if count == 0 else f"of {count} frames written to"
            self.notes.append(f"{v.name}: {name} detections {how} {folder}")
            folders.append(folder)
        self.detector = name
        return folders

    def plates(self) -> list[np.ndarray]:
        """The cameras' empty-scene plates (:func:`read_plates`)."""
        return read_plates(self.plate_files or [], self.rig)

    def read(self, t: int, masks: bool = True, depth: bool = True) -> FrameData:
        """Frame ``t`` of every video (BGR), with the depth maps unless ``depth`` is False (videos have no
        masks: ``masks`` is accepted for the common interface)."""
        images = []
        for k, cap in enumerate(self.caps):
            if self.positions[k] != t:
                cap.set(cv2.CAP_PROP_POS_FRAMES, t)
            ok, frame = cap.read()
            self.positions[k] = t + 1
            if not ok or frame is None:
                self.positions[k] = -1
                raise BadFrame(f"{self.videos[k]}: frame {t} could not be decoded")
            images.append(frame)
        d = None
        if self.depth_files is not None and depth:
            d = [
                _read_depth_file(files[t], self.rig.image_size[k]) for k, files in enumerate(self.depth_files)
            ]
        kp = None if self.keypoints is None else self.keypoints[t]
        return FrameData(images, None, d, kp)

    def close(self) -> None:
        for cap in self.caps:
            cap.release()
