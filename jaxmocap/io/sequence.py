"""Sequence folders: calibrated multi-view image sequences with optional ground truth, written and read here.

Layout of a sequence folder (``T`` frames, ``V`` cameras; every image is a PNG named ``NNNNNN.png`` with the
0-based output frame number, six digits):

.. code-block:: text

    calibration.toml            canonical Pose2Sim-layout TOML (jaxmocap.io.calibration.save_calibration), metres, z up
    meta.json                   {"frames": T, "fps": F, ...}: the frame count is the one authority
    views/<camera name>/rgb/    8-bit colour images (required)
    views/<camera name>/mask/   8-bit foreground masks, 255 = person, 0 = background (optional)
    views/<camera name>/depth/  16-bit depth along the camera z axis in millimetres, 0 = no depth (optional)
    views/<camera name>/labels/ 8-bit part labels: 0 = background, k + 1 = part k of meta["parts"] (optional)
    views/<camera name>/background.png   the camera's empty scene, recorded before the subject walks in (optional)
    groundtruth.npz             joints (T, 15, 3) metres, z up, in the order of joint_names
                                (= jaxmocap.geometry.body.EVAL_JOINTS); all_joints (T, J, 3) / all_joint_names (optional)
    body.toml                   body file of the subject (jaxmocap.geometry.body.load_body) (optional; meta["body"])

A channel folder, when present, holds exactly one image per frame for every camera; image sizes agree with the
calibration. :func:`load_sequence` checks the structure up front and reads images lazily, one at a time, raising
:class:`~jaxmocap.errors.MocapInputError` (with the offending file) for anything missing or corrupt.

Writers produce byte-identical files for identical inputs: PNG through OpenCV, JSON with sorted keys, and
``.npz`` archives with a fixed member timestamp (``numpy.savez`` stamps the current time).
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import os
import pathlib
import zipfile
from collections.abc import Iterator, Mapping

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import camera
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io import calibration

CALIBRATION = "calibration.toml"
META = "meta.json"
GROUNDTRUTH = "groundtruth.npz"
BODY = "body.toml"
VIEWS = "views"
#: File name of a view's empty-scene plate inside ``views/<camera>/``.
PLATE = "background.png"
CHANNELS = ("rgb", "mask", "depth", "labels")

__all__ = [
    "CALIBRATION",
    "META",
    "GROUNDTRUTH",
    "BODY",
    "VIEWS",
    "PLATE",
    "CHANNELS",
    "GroundTruth",
    "Sequence",
    "ViewFrames",
    "frame_path",
    "write_calibration",
    "write_meta",
    "write_groundtruth",
    "write_npz",
    "write_rgb",
    "write_mask",
    "write_depth",
    "write_labels",
    "read_rgb",
    "read_mask",
    "read_depth",
    "read_labels",
    "load_sequence",
]


# ---------------------------------------------------------------------------------------------------------------
# Paths and writers


def frame_path(root: str | os.PathLike, view: str, channel: str, frame: int) -> pathlib.Path:
    """``root/views/<view>/<channel>/NNNNNN.png``."""
    if channel not in CHANNELS:
        raise ValueError(f"channel must be one of {CHANNELS}, got {channel!r}")
    return pathlib.Path(root) / VIEWS / view / channel / f"{int(frame):06d}.png"


def _imwrite(path: str | os.PathLike, image: np.ndarray) -> None:
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(os.fspath(path), image):
        raise OSError(f"could not write {path}")


def write_rgb(path: str | os.PathLike, rgb: np.ndarray) -> None:
    """Write an ``(H, W, 3)`` uint8 RGB image (stored as an ordinary colour PNG)."""
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError("rgb must be an (H, W, 3) uint8 array")
    _imwrite(path, np.ascontiguousarray(rgb[..., ::-1]))


def write_mask(path: str | os.PathLike, mask: np.ndarray) -> None:
    """Write an ``(H, W)`` boolean foreground mask as 8-bit 0/255."""
    m = np.asarray(mask)
    if m.ndim != 2:
        raise ValueError("mask must be 2-D")
    _imwrite(path, np.where(m, 255, 0).astype(np.uint8))


def write_depth(path: str | os.PathLike, depth_mm: np.ndarray) -> None:
    """Write an ``(H, W)`` uint16 millimetre depth map as a 16-bit PNG (0 = no depth)."""
    arr = np.asarray(depth_mm)
    if arr.dtype != np.uint16 or arr.ndim != 2:
        raise ValueError("depth must be a 2-D uint16 array of millimetres")
    _imwrite(path, arr)


def write_labels(path: str | os.PathLike, labels: np.ndarray) -> None:
    """Write an ``(H, W)`` int part-label map (−1 = background, 0 … 254 = parts) as 8-bit ``label + 1``."""
    lab = np.asarray(labels)
    if lab.ndim != 2:
        raise ValueError("labels must be 2-D")
    if lab.size and (lab.min() < -1 or lab.max() > 254):
        raise ValueError("labels must lie in [-1, 254]")
    _imwrite(path, (lab + 1).astype(np.uint8))


def write_calibration(root: str | os.PathLike, rig: camera.Rig) -> pathlib.Path:
    """``root/calibration.toml`` in the canonical Pose2Sim layout."""
    path = pathlib.Path(root) / CALIBRATION
    path.parent.mkdir(parents=True, exist_ok=True)
    calibration.save_calibration(path, rig)
    return path


def _jsonable(x):
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, pathlib.PurePath):
        return os.fspath(x)
    return x


def write_meta(root: str | os.PathLike, meta: Mapping) -> pathlib.Path:
    """``root/meta.json`` (sorted keys, 2-space indent); ``meta`` needs ``frames`` (int) and ``fps``."""
    if "frames" not in meta or "fps" not in meta:
        raise ValueError("meta needs 'frames' and 'fps'")
    path = pathlib.Path(root) / META
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_jsonable(meta), indent=2, sort_keys=True, allow_nan=False) + "\n")
    return path


def write_npz(path: str | os.PathLike, arrays: Mapping[str, np.ndarray]) -> None:
    """An uncompressed ``.npz`` readable by :func:`numpy.load`, byte-identical for identical arrays (members
    in the given order, each stamped 1980-01-01 00:00:00)."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED) as zf:
        for name, value in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asarray(value), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue())


def write_groundtruth(
    root: str | os.PathLike,
    joints: np.ndarray,
    all_joints: np.ndarray | None = None,
    all_joint_names: tuple[str, ...] | None = None,
    **extra: np.ndarray,
) -> pathlib.Path:
    """``root/groundtruth.npz``: ``joints (T, 15, 3)`` (metres, z up) with ``joint_names`` =
    :data:`jaxmocap.geometry.body.EVAL_JOINTS`, optionally ``all_joints (T, J, 3)`` / ``all_joint_names (J,)`` and any
    further named arrays (e.g. ``frame_index``, the scene primitives)."""
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (len(EVAL_JOINTS), 3):
        raise ValueError(f"joints must be (T, {len(EVAL_JOINTS)}, 3), got {joints.shape}")
    arrays = {"joints": joints, "joint_names": np.asarray(EVAL_JOINTS)}
    if all_joints is not None:
        all_joints = np.asarray(all_joints, dtype=np.float64)
        if all_joint_names is None or all_joints.shape != (joints.shape[0], len(all_joint_names), 3):
            raise ValueError("all_joints must be (T, J, 3) with J = len(all_joint_names)")
        arrays["all_joints"] = all_joints
        arrays["all_joint_names"] = np.asarray(all_joint_names)
    arrays.update({k: np.asarray(v) for k, v in extra.items()})
    path = pathlib.Path(root) / GROUNDTRUTH
    path.parent.mkdir(parents=True, exist_ok=True)
    write_npz(path, arrays)
    return path


# ---------------------------------------------------------------------------------------------------------------
# Image readers (each raises MocapInputError naming the file)


def _imread(path: pathlib.Path, flags: int) -> np.ndarray:
    if not path.is_file():
        raise MocapInputError(path, "missing image")
    img = cv2.imread(os.fspath(path), flags)
    if img is None:
        raise MocapInputError(path, "cannot read image (corrupt or not a PNG)")
    return img


def _check_size(path, img: np.ndarray, size: tuple[int, int] | None) -> None:
    if size is not None and size != (0, 0) and (img.shape[1], img.shape[0]) != tuple(size):
        raise MocapInputError(
            path, f"image is {img.shape[1]}x{img.shape[0]} but the calibration says {size[0]}x{size[1]}"
        )


def read_bgr(path: str | os.PathLike, size: tuple[int, int] | None = None) -> np.ndarray:
    """``(H, W, 3)`` uint8 in OpenCV's BGR order, as decoded (no channel flip: what OpenCV-based preprocessing
    takes; a grey image is replicated to three channels)."""
    path = pathlib.Path(path)
    img = _imread(path, cv2.IMREAD_COLOR)
    _check_size(path, img, size)
    return img


def read_rgb(path: str | os.PathLike, size: tuple[int, int] | None = None) -> np.ndarray:
    """``(H, W, 3)`` uint8 RGB (a grey image is replicated to three channels)."""
    return np.ascontiguousarray(read_bgr(path, size)[..., ::-1])


def _read_8bit(path: pathlib.Path, size, what: str) -> np.ndarray:
    img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.dtype != np.uint8 or img.ndim != 2:
        raise MocapInputError(
            path, f"{what} must be a single-channel 8-bit image, got {img.dtype} {img.shape}"
        )
    _check_size(path, img, size)
    return img


def read_mask(path: str | os.PathLike, size: tuple[int, int] | None = None) -> np.ndarray:
    """``(H, W)`` bool foreground mask (pixels > 127)."""
    return _read_8bit(pathlib.Path(path), size, "mask") > 127


def read_labels(path: str | os.PathLike, size: tuple[int, int] | None = None) -> np.ndarray:
    """``(H, W)`` int32 part labels, −1 for background."""
    return _read_8bit(pathlib.Path(path), size, "label map").astype(np.int32) - 1


def read_depth(path: str | os.PathLike, size: tuple[int, int] | None = None) -> np.ndarray:
    """``(H, W)`` float32 depth in metres (0 = no depth) from a 16-bit millimetre PNG."""
    path = pathlib.Path(path)
    img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.dtype != np.uint16 or img.ndim != 2:
        raise MocapInputError(
            path, f"depth must be a single-channel 16-bit image, got {img.dtype} {img.shape}"
        )
    _check_size(path, img, size)
    return img.astype(np.float32) / 1000.0


_READERS = {"rgb": read_rgb, "mask": read_mask, "depth": read_depth, "labels": read_labels}


# ---------------------------------------------------------------------------------------------------------------
# The reader


@dataclasses.dataclass(frozen=True)
class GroundTruth:
    """Ground truth of a sequence: ``joints (T, 15, 3)`` metres z up named ``joint_names`` (EVAL_JOINTS order),
    ``all_joints (T, J, 3)`` / ``all_joint_names`` (None when absent) and every other array of the file in
    ``extra``."""

    joints: np.ndarray
    joint_names: tuple[str, ...]
    all_joints: np.ndarray | None = None
    all_joint_names: tuple[str, ...] | None = None
    extra: Mapping[str, np.ndarray] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class ViewFrames:
    """The frames of one camera, read lazily: ``rgb(t)``, ``mask(t)``, ``depth(t)``, ``labels(t)``."""

    root: pathlib.Path
    name: str
    size: tuple[int, int]
    num_frames: int
    channels: tuple[str, ...]

    def __len__(self) -> int:
        return self.num_frames

    def path(self, channel: str, t: int) -> pathlib.Path:
        return frame_path(self.root, self.name, channel, t)

    def read(self, channel: str, t: int) -> np.ndarray:
        """One image of ``channel`` at frame ``t`` (see the ``read_*`` functions for dtypes)."""
        return _READERS[channel](self._checked_path(channel, t), self.size)

    def _checked_path(self, channel: str, t: int) -> pathlib.Path:
        if channel not in self.channels:
            raise MocapInputError(
                self.root / VIEWS / self.name / channel, "this sequence has no such channel"
            )
        t = int(t)
        if not 0 <= t < self.num_frames:
            raise IndexError(f"frame {t} out of range [0, {self.num_frames})")
        return self.path(channel, t)

    def bgr(self, t: int) -> np.ndarray:
        """The colour image of frame ``t`` in OpenCV's BGR order (:func:`read_bgr`)."""
        return read_bgr(self._checked_path("rgb", t), self.size)

    def rgb(self, t: int) -> np.ndarray:
        return self.read("rgb", t)

    def mask(self, t: int) -> np.ndarray:
        return self.read("mask", t)

    def depth(self, t: int) -> np.ndarray:
        return self.read("depth", t)

    def labels(self, t: int) -> np.ndarray:
        return self.read("labels", t)

    def frames(self, channel: str = "rgb") -> Iterator[np.ndarray]:
        for t in range(self.num_frames):
            yield self.read(channel, t)


@dataclasses.dataclass(frozen=True)
class Sequence:
    """A sequence folder opened by :func:`load_sequence`.

    Attributes:
      root: the folder; rig: its calibration (:class:`jaxmocap.geometry.camera.Rig`, NumPy float64);
      num_frames: ``T``; fps: frames per second; views: one :class:`ViewFrames` per camera, in calibration
      order; channels: the channels every view has; groundtruth: :class:`GroundTruth` or None;
      body_path: the subject's body file or None; meta: the parsed ``meta.json``.
    """

    root: pathlib.Path
    rig: camera.Rig
    num_frames: int
    fps: float
    views: tuple[ViewFrames, ...]
    channels: tuple[str, ...]
    groundtruth: GroundTruth | None
    body_path: pathlib.Path | None
    meta: Mapping

    def __len__(self) -> int:
        return self.num_frames

    @property
    def view_names(self) -> tuple[str, ...]:
        return self.rig.names

    def view(self, key: int | str) -> ViewFrames:
        """The :class:`ViewFrames` of a camera by index or name."""
        if isinstance(key, str):
            if key not in self.rig.names:
                raise KeyError(f"no camera {key!r} in {self.root}; cameras: {', '.join(self.rig.names)}")
            key = self.rig.names.index(key)
        return self.views[key]

    def frame(self, t: int, channel: str = "rgb") -> list[np.ndarray]:
        """The images of every view at frame ``t`` (a list: views may differ in size)."""
        return [v.read(channel, t) for v in self.views]


def _load_meta(root: pathlib.Path) -> dict:
    path = root / META
    if not path.is_file():
        raise MocapInputError(
            path, "missing meta.json (every sequence folder needs one with 'frames' and 'fps')"
        )
    try:
        meta = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as e:
        raise MocapInputError(path, f"cannot read: {e}") from None
    except json.JSONDecodeError as e:
        raise MocapInputError(path, f"not valid JSON: {e.msg}", e.lineno) from None
    if not isinstance(meta, dict):
        raise MocapInputError(path, "must hold a JSON object")
    frames = meta.get("frames")
    if not isinstance(frames, int) or isinstance(frames, bool) or frames < 0:
        raise MocapInputError(path, f"'frames' must be a non-negative integer, got {frames!r}")
    fps = meta.get("fps")
    if not isinstance(fps, int | float) or isinstance(fps, bool) or not math.isfinite(fps) or fps <= 0:
        raise MocapInputError(path, f"'fps' must be a positive number, got {fps!r}")
    return meta


def _check_channel(root: pathlib.Path, view: str, channel: str, T: int) -> None:
    folder = root / VIEWS / view / channel
    present = {p.name for p in folder.iterdir() if p.suffix.lower() == ".png"}
    for t in range(T):
        name = f"{t:06d}.png"
        if name not in present:
            raise MocapInputError(folder / name, f"missing frame {t} of {T}")
    extra = sorted(present - {f"{t:06d}.png" for t in range(T)})
    if extra:
        raise MocapInputError(folder / extra[0], f"unexpected image: the sequence has {T} frames (meta.json)")


def _load_groundtruth(path: pathlib.Path, T: int) -> GroundTruth:
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise MocapInputError(path, f"cannot read ground truth: {e}") from None
    if "joints" not in data or "joint_names" not in data:
        raise MocapInputError(path, "ground truth needs 'joints' and 'joint_names'")
    joints, names = data.pop("joints"), tuple(str(n) for n in data.pop("joint_names"))
    if joints.shape != (T, len(names), 3):
        raise MocapInputError(path, f"'joints' is {joints.shape}, expected ({T}, {len(names)}, 3)")
    if names != EVAL_JOINTS:
        raise MocapInputError(path, f"'joint_names' must be jaxmocap.geometry.body.EVAL_JOINTS, got {names}")
    if not np.all(np.isfinite(joints)):
        raise MocapInputError(path, "'joints' has non-finite values")
    all_joints = data.pop("all_joints", None)
    all_names = data.pop("all_joint_names", None)
    if (all_joints is None) != (all_names is None):
        raise MocapInputError(path, "'all_joints' and 'all_joint_names' come together")
    if all_joints is not None:
        all_names = tuple(str(n) for n in all_names)
        if all_joints.shape != (T, len(all_names), 3):
            raise MocapInputError(
                path, f"'all_joints' is {all_joints.shape}, expected ({T}, {len(all_names)}, 3)"
            )
    return GroundTruth(joints.astype(np.float64), names, all_joints, all_names, data)


def load_sequence(root: str | os.PathLike) -> Sequence:
    """Open a sequence folder (see the module docstring): checks calibration, ``meta.json``, that every view has
    one image per frame in each of its channels, and the ground truth when present; images are read lazily.

    Raises:
      MocapInputError: naming the missing or corrupt file.
    """
    root = pathlib.Path(root)
    if not root.is_dir():
        raise MocapInputError(root, "not a sequence folder (no such directory)")
    calib = root / CALIBRATION
    if not calib.is_file():
        raise MocapInputError(calib, "missing calibration")
    rig = calibration.load_calibration(calib)
    meta = _load_meta(root)
    T = meta["frames"]
    views, common = [], None
    for name in rig.names:
        folder = root / VIEWS / name
        if not folder.is_dir():
            raise MocapInputError(folder, f"missing the folder of camera {name!r}")
        chans = tuple(c for c in CHANNELS if (folder / c).is_dir())
        if "rgb" not in chans:
            raise MocapInputError(folder / "rgb", "missing the rgb images")
        for c in chans:
            _check_channel(root, name, c, T)
        common = chans if common is None else tuple(c for c in common if c in chans)
        views.append(ViewFrames(root, name, tuple(rig.image_size[rig.names.index(name)]), T, chans))
    gt_path = root / GROUNDTRUTH
    gt = _load_groundtruth(gt_path, T) if gt_path.exists() else None
    body_name = meta.get("body", BODY)
    body_path = root / str(body_name)
    if not body_path.is_file():
        if "body" in meta:
            raise MocapInputError(body_path, "missing body file named in meta.json")
        body_path = None
    return Sequence(
        root=root,
        rig=rig,
        num_frames=T,
        fps=float(meta["fps"]),
        views=tuple(views),
        channels=common or (),
        groundtruth=gt,
        body_path=body_path,
        meta=meta,
    )
