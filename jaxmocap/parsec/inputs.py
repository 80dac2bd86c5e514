"""PARSEC bodytrack sequence folders as a tracking input (``jaxmocap track SEQUENCE_B``).

A bodytrack input folder (``jaxmocap/parsec/FORMAT.md`` §3) holds ``CALIB/Camera<k>.cal`` (Bouguet
cameras, mm), ``CAM<k>/imageNNNN.bmp`` (8-bit grey images), ``FG<k>/imageNNNN.bmp`` (foreground maps),
``BodyShapeParameters.txt`` (the 10-cylinder body), ``InitialPose.txt`` (the 31-value start state: radians, and
the pelvis translation in **mm**) and ``PoseParameters.txt`` (per-DOF σ_0, min, max). :func:`find_parsec_folder`
recognises such a folder (or a folder holding exactly one), :class:`ParsecSource` reads it frame by frame: per
frame the likelihood's observation (bodytrack's edge maps and binary foreground maps, :mod:`jaxmocap.parsec.images`);
:func:`load_sequence` reads a whole folder at once (:class:`ParsecSequence`).

Everything here stays in PARSEC's millimetres; :mod:`jaxmocap.parsec.track` converts its outputs to metres.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import re

import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.parsec import cameras, files, images

__all__ = [
    "NOMINAL_FPS",
    "ParsecSequence",
    "ParsecSource",
    "find_parsec_folder",
    "is_parsec_folder",
    "load_sequence",
]

#: bodytrack's input sets do not state a frame rate; the outputs' time stamps use this one.
NOMINAL_FPS = 30.0

_TEXT_FILES = ("BodyShapeParameters.txt", "InitialPose.txt", "PoseParameters.txt")


def _looks_like_parsec(p: pathlib.Path) -> bool:
    """A folder with bodytrack's ``CALIB`` folder or one of its three parameter files."""
    return (p / "CALIB").is_dir() or any((p / f).is_file() for f in _TEXT_FILES)


def find_parsec_folder(path: str | os.PathLike) -> pathlib.Path | None:
    """The bodytrack sequence folder ``path`` is, or the only one directly inside it (e.g. PARSEC's unpacked
    ``inputs`` folder holding ``sequenceB_1``); None when neither (a synthesis-format sequence folder has a
    ``meta.json`` and is never taken for one)."""
    p = pathlib.Path(path)
    if not p.is_dir() or (p / "meta.json").exists():
        return None
    if _looks_like_parsec(p):
        return p
    try:
        subs = sorted(q for q in p.iterdir() if q.is_dir() and _looks_like_parsec(q))
    except OSError:
        return None
    return subs[0] if len(subs) == 1 else None


def is_parsec_folder(path: str | os.PathLike | None) -> bool:
    """True when :func:`find_parsec_folder` finds a bodytrack sequence folder at ``path``."""
    return path is not None and find_parsec_folder(path) is not None


class ParsecSource:
    """A bodytrack sequence folder read frame by frame.

    Attributes: ``root`` (the sequence folder), ``cameras`` (:class:`jaxmocap.parsec.cameras.Cameras`, mm), ``rig``
    (:class:`jaxmocap.geometry.camera.Rig`, metres), ``shape`` (:class:`jaxmocap.parsec.files.BodyShape`, mm),
    ``initial_pose (31,)`` (radians, mm), ``pose_parameters`` (σ_0, min, max), ``num_frames`` (frames
    ``0 … num_frames−1`` present in every ``CAM<k>`` and ``FG<k>``), ``fps`` (:data:`NOMINAL_FPS`),
    ``view_names``, ``description``. Every defect of the folder raises :class:`~jaxmocap.errors.MocapInputError`
    naming the file.
    """

    def __init__(self, path: str | os.PathLike):
        root = find_parsec_folder(path)
        if root is None:
            raise MocapInputError(
                path,
                "not a PARSEC bodytrack sequence folder (expected CALIB/Camera<k>.cal, CAM<k>/, FG<k>/, "
                + ", ".join(_TEXT_FILES)
                + ")",
            )
        self.root = root
        calib = root / "CALIB"
        if not calib.is_dir():
            raise MocapInputError(calib, "missing: a bodytrack sequence needs CALIB/Camera<k>.cal")
        n = 0
        while (calib / f"Camera{n + 1}.cal").is_file():
            n += 1
        if n == 0:
            raise MocapInputError(calib / "Camera1.cal", "missing camera calibration")
        cal_files = [calib / f"Camera{k + 1}.cal" for k in range(n)]
        for f in _TEXT_FILES:
            if not (root / f).is_file():
                raise MocapInputError(root / f, "missing (every bodytrack sequence has it)")
        self.cameras = cameras.cameras_from_rig(files.load_parsec_calibration(cal_files, units="mm"), "mm")
        self.rig = files.load_parsec_calibration(cal_files, units="m")
        self.shape = files.load_body_shape(root / "BodyShapeParameters.txt")
        self.initial_pose = files.load_pose(root / "InitialPose.txt")
        self.pose_parameters = files.load_pose_parameters(root / "PoseParameters.txt")
        available = None
        for k in range(n):
            for kind in ("CAM", "FG"):
                d = root / f"{kind}{k + 1}"
                if not d.is_dir():
                    raise MocapInputError(d, f"image folder missing (the sequence has {n} cameras)")
                nums = set(_frame_numbers(os.fspath(d)))
                if 0 not in nums:
                    raise MocapInputError(d / "image0000.bmp", "missing: frames are numbered from 0")
                available = nums if available is None else available & nums
        count = 0
        while count in available:
            count += 1
        self.num_frames = count
        self.num_views = n
        self.fps = NOMINAL_FPS
        self.view_names = tuple(f"Camera{k + 1}" for k in range(n))
        self.description = {"parsec_sequence": os.fspath(root)}

    def _camera(self, t: int, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Camera ``k``'s grey image and binary foreground map of frame ``t``, ``(H, W) uint8`` each, checked
        against the calibration's image size."""
        name = f"image{t:04d}.bmp"
        pair = []
        for kind in ("CAM", "FG"):
            p = self.root / f"{kind}{k + 1}" / name
            a = images.load_image(p)
            w, h = self.rig.image_size[k] if self.rig.image_size[k] != (0, 0) else (a.shape[1], a.shape[0])
            if a.shape != (h, w):
                raise MocapInputError(p, f"image is {a.shape[1]}x{a.shape[0]}, expected {w}x{h}")
            pair.append(a)
        return pair[0], images.foreground_map(pair[1])

    def images(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``t``: grey images and binary foreground maps, ``(V, H, W) uint8`` each (rows from the top); the
        cameras read side by side (:func:`jaxmocap.parsec.images.per_camera`)."""
        pairs = images.per_camera(lambda k: self._camera(t, k), self.num_views)
        return np.stack([a for a, _ in pairs]), np.stack([f for _, f in pairs])

    def observation(self, t: int):
        """The PARSEC likelihood's observation of frame ``t`` (:func:`jaxmocap.parsec.likelihood.observation`:
        bodytrack's edge maps, §6.1, and its binary foreground maps): each camera's images read and its edge map
        computed in one task, the cameras side by side (:func:`jaxmocap.parsec.images.per_camera`)."""
        from jaxmocap.parsec import likelihood as parsec_likelihood

        def camera(k):
            im, fg = self._camera(t, k)
            return images.edge_map(im), fg

        pairs = images.per_camera(camera, self.num_views)
        return parsec_likelihood.observation(np.stack([e for e, _ in pairs]), np.stack([f for _, f in pairs]))

    def close(self) -> None:
        pass


# ---------------------------------------------------------------------------------------------------------------
# Whole sequences in memory


@dataclasses.dataclass
class ParsecSequence:
    """A bodytrack input folder (``load_sequence``).

    ``images``, ``foreground`` ``(F, V, H, W) uint8`` (camera images; foreground maps binarised to {0, 1});
    ``cameras`` (:class:`jaxmocap.parsec.cameras.Cameras`, mm) and ``rig`` (:class:`jaxmocap.geometry.camera.Rig`,
    metres); ``shape``; ``initial_pose (31,)``; ``pose_parameters`` (std, min, max); ``frames``: the frame numbers
    read.
    """

    images: np.ndarray
    foreground: np.ndarray
    cameras: cameras.Cameras
    rig: object
    shape: files.BodyShape
    initial_pose: np.ndarray
    pose_parameters: files.PoseParameters
    frames: tuple[int, ...]

    @property
    def pose_std(self) -> np.ndarray:
        return self.pose_parameters.std

    def edge_maps(self, frame: int) -> np.ndarray:
        """bodytrack's edge maps ``(V, H, W) uint8`` of frame index ``frame`` (0-based into ``frames``)."""
        return images.edge_maps(self.images[frame])

    def observation(self, frame: int):
        """The likelihood's :class:`jaxmocap.parsec.likelihood.Observation` of frame index ``frame``."""
        from jaxmocap.parsec import likelihood as parsec_likelihood

        return parsec_likelihood.observation(self.edge_maps(frame), self.foreground[frame])


def _frame_numbers(folder: str) -> list[int]:
    out = []
    for f in os.listdir(folder):
        m = re.fullmatch(r"image(\d{4,})\.bmp", f, flags=re.IGNORECASE)
        if m:
            out.append(int(m.group(1)))
    return sorted(out)


def load_sequence(
    path: str | os.PathLike, frames: int | None = None, num_cameras: int | None = None
) -> ParsecSequence:
    """Read a bodytrack sequence folder (``CALIB/Camera<k>.cal``, ``CAM<k>/imageNNNN.bmp``, ``FG<k>/…``,
    ``BodyShapeParameters.txt``, ``InitialPose.txt``, ``PoseParameters.txt``).

    ``num_cameras``: default all ``Camera<k>.cal`` from 1 up; ``frames``: read the first ``frames`` frames
    (default: every frame present in all cameras, which must be consecutive from 0).
    """
    root = os.fspath(path)
    if not os.path.isdir(root):
        raise MocapInputError(root, "not a sequence folder")
    calib = os.path.join(root, "CALIB")
    if num_cameras is None:
        num_cameras = 0
        while os.path.isfile(os.path.join(calib, f"Camera{num_cameras + 1}.cal")):
            num_cameras += 1
        if num_cameras == 0:
            raise MocapInputError(calib, "no CALIB/Camera1.cal")
    cal_files = [os.path.join(calib, f"Camera{k + 1}.cal") for k in range(num_cameras)]
    for f in cal_files:
        if not os.path.isfile(f):
            raise MocapInputError(f, "camera calibration file missing")
    rig_mm = files.load_parsec_calibration(cal_files, units="mm")
    rig = files.load_parsec_calibration(cal_files, units="m")
    cams = cameras.cameras_from_rig(rig_mm, units="mm")
    available = None
    for k in range(num_cameras):
        for kind in ("CAM", "FG"):
            d = os.path.join(root, f"{kind}{k + 1}")
            if not os.path.isdir(d):
                raise MocapInputError(d, "image folder missing")
            nums = set(_frame_numbers(d))
            available = nums if available is None else available & nums
    if frames is None:
        n = 0
        while n in available:
            n += 1
        if n == 0:
            raise MocapInputError(os.path.join(root, "CAM1"), "no image0000.bmp in every camera folder")
        frames = n
    grey, fgs = [], []
    for fr in range(frames):
        ims, fs = [], []
        for k in range(num_cameras):
            name = f"image{fr:04d}.bmp"
            im = images.load_image(os.path.join(root, f"CAM{k + 1}", name))
            fg = images.load_image(os.path.join(root, f"FG{k + 1}", name))
            w, h = (
                rig.image_size[k]
                if rig.image_size and rig.image_size[k] != (0, 0)
                else (im.shape[1], im.shape[0])
            )
            for p, a in (
                (os.path.join(root, f"CAM{k + 1}", name), im),
                (os.path.join(root, f"FG{k + 1}", name), fg),
            ):
                if a.shape != (h, w):
                    raise MocapInputError(p, f"image is {a.shape[1]}x{a.shape[0]}, expected {w}x{h}")
            ims.append(im)
            fs.append(images.foreground_map(fg))
        grey.append(ims)
        fgs.append(fs)
    return ParsecSequence(
        images=np.asarray(grey, dtype=np.uint8),
        foreground=np.asarray(fgs, dtype=np.uint8),
        cameras=cams,
        rig=rig,
        shape=files.load_body_shape(os.path.join(root, "BodyShapeParameters.txt")),
        initial_pose=files.load_pose(os.path.join(root, "InitialPose.txt")),
        pose_parameters=files.load_pose_parameters(os.path.join(root, "PoseParameters.txt")),
        frames=tuple(range(frames)),
    )
