"""Calibration files: readers and writer of camera rigs (:class:`jaxmocap.geometry.camera.Rig`), host side in numpy
float64.

Readers: OpenCV ``FileStorage`` YAML/XML (:func:`load_opencv_storage`), Pose2Sim TOML (:func:`load_pose2sim_toml`),
caliscope TOML (:func:`load_caliscope_toml`), Qualisys ``.qca.txt`` (:func:`load_qualisys_qca`) and EasyMocap's
``intri.yml``/``extri.yml`` (:func:`load_easymocap`);
:func:`load_calibration` detects the format, after asking the readers that wings register with
:func:`register_reader` (PARSEC / Bouguet ``.cal`` cameras come with the PARSEC wing). Every reader raises
:class:`jaxmocap.errors.MocapInputError` (file and line) for anything truncated or malformed; :func:`read_text`,
:func:`checked_camera` and :func:`rig_from_cameras` are the shared checks a registered reader uses too.

Units: :func:`check_units` converts a rig in millimetres to metres (or refuses one in unknown units).

Writer: :func:`save_calibration` writes the Pose2Sim-layout TOML that Pose2Sim and ``cv2.projectPoints`` users read
directly.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import tomllib
import xml.etree.ElementTree as ET
from collections.abc import Callable, Sequence
from typing import NamedTuple

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry.camera import Rig, _normalise_dist, rodrigues

__all__ = [
    "check_units",
    "checked_camera",
    "load_calibration",
    "load_caliscope_toml",
    "load_easymocap",
    "load_opencv_storage",
    "load_pose2sim_toml",
    "load_qualisys_qca",
    "read_text",
    "register_reader",
    "rig_from_cameras",
    "save_calibration",
]


# ---------------------------------------------------------------------------------------------------------------
# Shared helpers (also for the readers registered by wings)


_CV_EXCEPTIONS = (ValueError, TypeError, OverflowError, KeyError, IndexError, AttributeError, SystemError)


def read_text(path: str | os.PathLike) -> str:
    """The UTF-8 text of a calibration file; MocapInputError (with the line of a bad byte) otherwise."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as e:
        raise MocapInputError(path, f"cannot read calibration file: {e.strerror or e}") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data[: e.start].count(b"\n") + 1
        raise MocapInputError(path, "not a UTF-8 text file", line) from None


def _line_of(text: str, pattern: str, start_line: int = 1) -> int | None:
    """1-based line of the first match of the regular expression ``pattern`` at or after ``start_line``."""
    lines = text.splitlines()
    rx = re.compile(pattern)
    for i in range(max(start_line, 1) - 1, len(lines)):
        if rx.search(lines[i]):
            return i + 1
    return None


def _as_array(value, shape_ok, what: str, path, line) -> np.ndarray:
    """``value`` as a finite float64 array whose shape passes ``shape_ok``; MocapInputError otherwise."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (ValueError, TypeError, OverflowError):
        raise MocapInputError(path, f"{what} is not an array of numbers", line) from None
    if not shape_ok(arr.shape):
        raise MocapInputError(path, f"{what} has shape {arr.shape}", line)
    if not np.all(np.isfinite(arr)):
        raise MocapInputError(path, f"{what} has non-finite values", line)
    return arr


def checked_camera(path, line, name, K, dist, R, t, size) -> tuple:
    """Validate one camera's parameters; return them normalised (K, dist(5,), R, t, (w, h))."""
    K = _as_array(K, lambda s: s == (3, 3), f"camera {name!r}: camera matrix", path, line)
    off = np.abs([K[1, 0], K[2, 0], K[2, 1], K[2, 2] - 1.0])
    if K[0, 0] <= 0 or K[1, 1] <= 0 or np.any(off > 1e-9):
        msg = f"camera {name!r}: camera matrix is not [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0"
        raise MocapInputError(path, msg, line)
    K = np.array([[K[0, 0], K[0, 1], K[0, 2]], [0.0, K[1, 1], K[1, 2]], [0.0, 0.0, 1.0]])
    dist_ok = lambda s: len(s) == 1 and s[0] in (4, 5, 8, 12, 14)
    dist = _as_array(dist, dist_ok, f"camera {name!r}: distortion", path, line)
    try:
        dist = _normalise_dist(dist)
    except ValueError as e:
        raise MocapInputError(path, f"camera {name!r}: {e}", line) from None
    R = _as_array(R, lambda s: s == (3, 3), f"camera {name!r}: rotation", path, line)
    if np.max(np.abs(R @ R.T - np.eye(3))) > 1e-3 or np.linalg.det(R) < 0:
        raise MocapInputError(path, f"camera {name!r}: rotation matrix is not a rotation", line)
    t = _as_array(t, lambda s: s == (3,), f"camera {name!r}: translation", path, line)
    size = _as_array(size, lambda s: s == (2,), f"camera {name!r}: image size", path, line)
    if np.any(size < 0) or np.any(size > 1e6) or np.any(size != np.round(size)):
        raise MocapInputError(
            path, f"camera {name!r}: image size {size.tolist()} is not two whole pixels", line
        )
    return K, dist, R, t, (int(size[0]), int(size[1]))


def rig_from_cameras(cams: list[tuple], names: list[str], path=None) -> Rig:
    """A :class:`Rig` of cameras checked by :func:`checked_camera` (names must differ)."""
    if len(set(names)) != len(names):
        raise MocapInputError(path, f"camera names repeat: {names}")
    return Rig(
        K=np.stack([c[0] for c in cams]),
        dist=np.stack([c[1] for c in cams]),
        R=np.stack([c[2] for c in cams]),
        t=np.stack([c[3] for c in cams]),
        names=tuple(names),
        image_size=tuple(c[4] for c in cams),
    )


# ---------------------------------------------------------------------------------------------------------------
# OpenCV FileStorage (YAML / XML)


def _cv_message(e: BaseException) -> tuple[str, int | None]:
    """Message and line of a ``cv2.error`` (the bindings sometimes raise SystemError with it as the cause)."""
    while isinstance(e, SystemError) and e.__cause__ is not None:
        e = e.__cause__
    msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    m = re.search(r"in function '[^']*\((\d+)\):\s*([^']*)'", msg)
    if m:
        return m.group(2).strip() or msg, int(m.group(1))
    m = re.search(r"error: \([-\d]+:[^)]*\) (.*)$", msg)
    return (m.group(1) if m else msg), None


def load_opencv_storage(path: str | os.PathLike, translation_scale: float = 1.0) -> Rig:
    """OpenCV ``FileStorage`` calibration (YAML or XML), read with ``cv2.FileStorage``.

    Understood layouts:

    * single camera (``calibration.cpp`` sample): ``camera_matrix``, ``distortion_coefficients`` and optionally
      ``image_width``/``image_height``; the camera sits at the world origin (``R = I``, ``t = 0``);
    * stereo pair (``stereo_calib.cpp`` sample): ``M1 D1 M2 D2`` with ``R T`` from the same file or, if absent,
      from a sibling ``extrinsics.yml``/``.yaml``/``.xml``; camera 1 is the world frame, camera 2 has ``R, T``
      (``T`` is in calibration-pattern units: multiply by ``translation_scale`` to get metres). Without any
      ``R T`` both cameras sit at the origin.
    """
    text = read_text(path)
    fs = _open_storage(path, text)
    opened = [fs]
    try:
        try:
            root = fs.root()
            keys = set(root.keys()) if root.isMap() else set()
        except (cv2.error, *_CV_EXCEPTIONS) as e:
            raise MocapInputError(path, f"cannot read the top-level map: {_cv_message(e)[0]}") from None
        if "camera_matrix" in keys:
            K = _fs_mat(fs, path, text, "camera_matrix")
            D = _fs_mat(fs, path, text, "distortion_coefficients", optional=True)
            D = np.zeros(5) if D is None else D.reshape(-1)
            w = _fs_real(fs, path, text, "image_width")
            h = _fs_real(fs, path, text, "image_height")
            line = _line_of(text, r"camera_matrix")
            cam = checked_camera(path, line, "cam0", K, D, np.eye(3), np.zeros(3), (w or 0, h or 0))
            return rig_from_cameras([cam], ["cam0"], path)
        if {"M1", "M2"} <= keys:
            ext_fs, ext_path, ext_text = fs, path, text
            if "R" not in keys:
                sib = _sibling_extrinsics(path)
                if sib is not None:
                    ext_path, ext_text = sib, read_text(sib)
                    ext_fs = _open_storage(sib, ext_text)
                    opened.append(ext_fs)
            R = _fs_mat(ext_fs, ext_path, ext_text, "R", optional=True)
            T = _fs_mat(ext_fs, ext_path, ext_text, "T", optional=True)
            if (R is None) != (T is None):
                raise MocapInputError(ext_path, "extrinsics need both R and T")
            if R is None:
                R, T = np.eye(3), np.zeros(3)
            elif R.size == 3:
                R = rodrigues(
                    _as_array(R.reshape(3), lambda s: True, "R", ext_path, _line_of(ext_text, r"\bR\b"))
                )
            T = T.reshape(-1) * float(translation_scale)
            w = _fs_real(fs, path, text, "image_width") or 0
            h = _fs_real(fs, path, text, "image_height") or 0
            cams = []
            for i, (Rk, Tk) in enumerate([(np.eye(3), np.zeros(3)), (R, T)], start=1):
                Ki = _fs_mat(fs, path, text, f"M{i}")
                Di = _fs_mat(fs, path, text, f"D{i}", optional=True)
                Di = np.zeros(5) if Di is None else Di.reshape(-1)
                cams.append(
                    checked_camera(path, _line_of(text, rf"\bM{i}\b"), f"cam{i}", Ki, Di, Rk, Tk, (w, h))
                )
            return rig_from_cameras(cams, ["cam1", "cam2"], path)
        raise MocapInputError(path, "no camera_matrix or M1/M2 entries: not an OpenCV camera calibration")
    finally:
        for f in opened:
            f.release()


def _open_storage(path, text: str):
    if not text.lstrip().startswith(("%YAML", "<?xml", "<opencv_storage")):
        raise MocapInputError(path, "not an OpenCV FileStorage file (no %YAML or <?xml header)", 1)
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, *_CV_EXCEPTIONS) as e:
        msg, line = _cv_message(e)
        raise MocapInputError(path, f"OpenCV cannot parse it: {msg}", line) from None
    if not fs.isOpened():
        raise MocapInputError(path, "OpenCV cannot open it as FileStorage")
    return fs


def _fs_mat(fs, path, text, key: str, optional: bool = False) -> np.ndarray | None:
    line = _line_of(text, rf"(^|\s|<){re.escape(key)}(\s*:|[\s>])")
    try:
        node = fs.getNode(key)
        if node.empty() or node.isNone():
            if optional:
                return None
            raise MocapInputError(path, f"missing entry {key!r}")
        if node.isSeq():
            vals = [node.at(i).real() for i in range(node.size())]
            if not all(node.at(i).isReal() or node.at(i).isInt() for i in range(node.size())):
                raise MocapInputError(path, f"{key!r} is not a list of numbers", line)
            m = np.asarray(vals, dtype=np.float64)
        else:
            m = node.mat()
    except (cv2.error, *_CV_EXCEPTIONS) as e:
        if isinstance(e, MocapInputError):
            raise
        msg, _ = _cv_message(e)
        raise MocapInputError(path, f"cannot read {key!r}: {msg}", line) from None
    if m is None or not isinstance(m, np.ndarray):
        raise MocapInputError(path, f"{key!r} is not a matrix", line)
    m = np.asarray(m, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        raise MocapInputError(path, f"{key!r} has non-finite values", line)
    if key.startswith(("camera_matrix", "M")) or key == "R":
        if m.size not in ((3, 9) if key == "R" else (9,)):
            raise MocapInputError(path, f"{key!r} has {m.size} entries", line)
        m = m.reshape(3, 3) if m.size == 9 else m
    return m


def _fs_real(fs, path, text, key: str) -> float | None:
    try:
        node = fs.getNode(key)
        if node.empty() or node.isNone():
            return None
        if not (node.isInt() or node.isReal()):
            raise MocapInputError(path, f"{key!r} is not a number", _line_of(text, re.escape(key)))
        return float(node.real())
    except (cv2.error, *_CV_EXCEPTIONS) as e:
        if isinstance(e, MocapInputError):
            raise
        msg, _ = _cv_message(e)
        raise MocapInputError(path, f"cannot read {key!r}: {msg}", _line_of(text, re.escape(key))) from None


def _sibling_extrinsics(path) -> str | None:
    folder = os.path.dirname(os.fspath(path))
    for name in ("extrinsics.yml", "extrinsics.yaml", "extrinsics.xml"):
        p = os.path.join(folder, name)
        if os.path.isfile(p):
            return p
    return None


# ---------------------------------------------------------------------------------------------------------------
# EasyMocap intri.yml / extri.yml

EASYMOCAP_FILES = ("intri.yml", "extri.yml")


def _easymocap_pair(path) -> tuple[str, str] | None:
    """``(intri.yml, extri.yml)`` of a folder holding both, or of either file (the other one beside it)."""
    p = os.fspath(path)
    folder = p if os.path.isdir(p) else os.path.dirname(p)
    if not os.path.isdir(p) and os.path.basename(p).lower() not in EASYMOCAP_FILES:
        return None
    pair = tuple(os.path.join(folder, n) for n in EASYMOCAP_FILES)
    if os.path.isdir(p) and not all(os.path.isfile(f) for f in pair):
        return None
    return pair


def _fs_names(fs, path, text) -> list[str]:
    node = fs.getNode("names")
    if node.empty() or node.isNone() or not node.isSeq() or node.size() == 0:
        raise MocapInputError(path, "no 'names' list of cameras: not an EasyMocap camera file")
    out = []
    for i in range(node.size()):
        item = node.at(i)
        out.append(item.string() if item.isString() else str(int(item.real())))
    return out


def load_easymocap(path: str | os.PathLike) -> Rig:
    """EasyMocap's cameras: ``intri.yml`` and ``extri.yml`` (OpenCV FileStorage YAML), given as their folder or as
    either file (the other beside it).

    ``intri.yml``: ``names`` (the cameras), and per camera ``K_<name>`` (3×3), ``dist_<name>`` (1×5; ``D_<name>``
    in some versions) and optionally ``H_<name>``, ``W_<name>`` (image size). ``extri.yml``: ``Rot_<name>``
    (3×3 world→camera) or ``R_<name>`` (its Rodrigues vector) and ``T_<name>`` (3×1, metres: EasyMocap's unit),
    ``x_cam = R x_world + T``. The cameras are those of ``intri.yml``'s ``names``, in that order.
    """
    pair = _easymocap_pair(path)
    if pair is None:
        raise MocapInputError(path, "not an EasyMocap folder (intri.yml and extri.yml)")
    intri_path, extri_path = pair
    texts = [read_text(f) for f in pair]
    fss = [_open_storage(f, t) for f, t in zip(pair, texts, strict=True)]
    try:
        (fi, fe), (ti, te) = fss, texts
        try:
            names = _fs_names(fi, intri_path, ti)
        except (cv2.error, *_CV_EXCEPTIONS) as e:
            if isinstance(e, MocapInputError):
                raise
            raise MocapInputError(intri_path, f"cannot read 'names': {_cv_message(e)[0]}") from None
        cams = []
        for n in names:
            K = _fs_mat(fi, intri_path, ti, f"K_{n}")
            D = _fs_mat(fi, intri_path, ti, f"dist_{n}", optional=True)
            if D is None:
                D = _fs_mat(fi, intri_path, ti, f"D_{n}", optional=True)
            D = np.zeros(5) if D is None else D.reshape(-1)
            h = _fs_real(fi, intri_path, ti, f"H_{n}")
            w = _fs_real(fi, intri_path, ti, f"W_{n}")
            R = _fs_mat(fe, extri_path, te, f"Rot_{n}", optional=True)
            if R is None:
                rv = _fs_mat(fe, extri_path, te, f"R_{n}")
                R = rodrigues(
                    _as_array(
                        rv.reshape(-1), lambda s: s == (3,), f"R_{n}", extri_path, _line_of(te, f"R_{n}")
                    )
                )
            T = _fs_mat(fe, extri_path, te, f"T_{n}").reshape(-1)
            size = (0, 0) if h is None or w is None or h < 0 or w < 0 else (w, h)
            cams.append(checked_camera(intri_path, _line_of(ti, f"K_{re.escape(n)}"), n, K, D, R, T, size))
        return rig_from_cameras(cams, names, intri_path)
    finally:
        for f in fss:
            f.release()


# ---------------------------------------------------------------------------------------------------------------
# Units


#: the smallest a standing person (1.8 m) may appear in every view of a rig for tracking (px)
MIN_PERSON_PX = 100.0


def check_units(rig: Rig, units: str = "auto", path=None) -> tuple[Rig, str | None]:
    """``(rig in metres, note or None)``: translations converted or checked.

    ``units``: ``"m"`` (as stored), ``"mm"`` (divided by 1000) or ``"auto"``: two cameras ``d`` apart can both see a
    standing person (1.8 m) at least :data:`MIN_PERSON_PX` tall only when ``d ≤ 2 f · 1.8 / MIN_PERSON_PX`` (``f``
    the median focal length, px); a rig whose cameras are farther apart is taken as in millimetres when that
    holds after dividing by 1000 (a note says so), and refused otherwise. Rigs of one camera, or whose cameras
    share a centre, are kept as they are."""
    if units not in ("auto", "m", "mm"):
        raise ValueError(f"calibration units must be auto, m or mm, not {units!r}")
    if units == "mm":
        return dataclasses.replace(rig, t=np.asarray(rig.t, np.float64) / 1000.0), None
    if units == "m" or rig.num_views < 2:
        return rig, None
    R, t = np.asarray(rig.R, np.float64), np.asarray(rig.t, np.float64)
    centres = -np.einsum("vji,vj->vi", R, t)
    span = float(np.max(np.linalg.norm(centres[:, None] - centres[None], axis=-1)))
    f = float(np.median(0.5 * (np.asarray(rig.K)[:, 0, 0] + np.asarray(rig.K)[:, 1, 1])))
    limit = 2.0 * f * 1.8 / MIN_PERSON_PX
    if span <= limit:
        return rig, None
    if span / 1000.0 <= limit:
        note = (
            f"the cameras are {span:.0f} m apart, too far to film one person (at most {limit:.0f} m with focal "
            f"lengths of {f:.0f} px): translations taken as millimetres and divided by 1000 "
            "(--calibration-units m keeps them)"
        )
        return dataclasses.replace(rig, t=t / 1000.0), note
    raise MocapInputError(
        path,
        f"the cameras are {span:.3g} m apart, too far to film one person (at most {limit:.0f} m), even read as "
        "millimetres: the translations are in unknown units",
    )


# ---------------------------------------------------------------------------------------------------------------
# TOML: Pose2Sim / OpenCV layout and caliscope


def _parse_toml(path, text: str) -> dict:
    try:
        return tomllib.loads(text)
    except RecursionError:
        raise MocapInputError(path, "invalid TOML: nested too deeply") from None
    except tomllib.TOMLDecodeError as e:
        m = re.search(r"\(at line (\d+), column \d+\)", str(e))
        line = int(m.group(1)) if m else getattr(e, "lineno", None)
        msg = re.sub(r"\s*\(at line \d+, column \d+\)", "", str(e)) or "invalid TOML"
        raise MocapInputError(path, f"invalid TOML: {msg}", line) from None


def _table_line(text: str, dotted: str) -> int | None:
    parts = dotted.split(".")
    pat = r"^\s*\[\s*" + r"\s*\.\s*".join(r"[\"']?" + re.escape(p) + r"[\"']?" for p in parts) + r"\s*\]"
    return _line_of(text, pat)


def _key_line(text: str, table_line: int | None, key: str) -> int | None:
    if table_line is None:
        return None
    return _line_of(text, r"^\s*[\"']?" + re.escape(key) + r"[\"']?\s*=", table_line) or table_line


def _toml_camera(path, text: str, table: str, cam: dict, name: str) -> tuple:
    tl = _table_line(text, table)
    for key in ("matrix", "distortions", "rotation", "translation"):
        if key not in cam:
            raise MocapInputError(path, f"camera table [{table}] has no {key!r}", tl)
    if cam.get("fisheye", False) is True:
        raise MocapInputError(
            path, f"camera [{table}] is a fisheye camera: not supported", _key_line(text, tl, "fisheye")
        )
    rot_line = _key_line(text, tl, "rotation")
    rot = _as_array(
        cam["rotation"], lambda s: s in ((3,), (3, 3)), f"camera {name!r}: rotation", path, rot_line
    )
    R = rodrigues(rot) if rot.shape == (3,) else rot
    size = cam.get("size", (0, 0))
    return checked_camera(path, tl, name, cam["matrix"], cam["distortions"], R, cam["translation"], size)


def load_pose2sim_toml(path: str | os.PathLike) -> Rig:
    """Pose2Sim / OpenCV-layout TOML: one table per camera with ``name``, ``size = [w, h]``, ``matrix`` (K),
    ``distortions`` (4 or 5 OpenCV terms), ``rotation`` (Rodrigues vector world→camera, or a 3×3 matrix),
    ``translation`` (metres) and ``fisheye`` (must be false). A ``[metadata]`` table is skipped."""
    text = read_text(path)
    data = _parse_toml(path, text)
    cams, names = [], []
    for key, cam in data.items():
        if key == "metadata":
            continue
        if not isinstance(cam, dict):
            raise MocapInputError(
                path, f"top-level entry {key!r} is not a camera table", _key_line(text, 1, key)
            )
        name = cam.get("name", key)
        if not isinstance(name, str):
            raise MocapInputError(path, f"camera [{key}]: name is not a string", _table_line(text, key))
        cams.append(_toml_camera(path, text, key, cam, name))
        names.append(name)
    if not cams:
        raise MocapInputError(path, "no camera tables")
    return rig_from_cameras(cams, names, path)


def load_caliscope_toml(path: str | os.PathLike, include_ignored: bool = False) -> Rig:
    """caliscope ``camera_array.toml``: tables ``[cameras.N]`` with ``size = [w, h]``, ``matrix``, 5-term
    ``distortions``, ``rotation`` (3×3 world→camera matrix) and ``translation`` (metres).

    ``rotation_count`` (90° steps) only rotates caliscope's display of the frames; the intrinsics and the 2D
    detections refer to the unrotated sensor image, so it does not enter the model. Cameras marked
    ``ignore = true`` are left out unless ``include_ignored``. Cameras are named ``cam_<cam_id>``.
    """
    text = read_text(path)
    data = _parse_toml(path, text)
    cameras = data.get("cameras")
    if not isinstance(cameras, dict) or not cameras:
        raise MocapInputError(path, "no [cameras.N] tables: not a caliscope camera array")
    cams, names = [], []
    for key, cam in cameras.items():
        table = f"cameras.{key}"
        if not isinstance(cam, dict):
            raise MocapInputError(path, f"[{table}] is not a table", _table_line(text, table))
        if cam.get("ignore", False) is True and not include_ignored:
            continue
        cam_id = cam.get("cam_id", key)
        if not isinstance(cam_id, int | str) or isinstance(cam_id, bool):
            raise MocapInputError(path, f"[{table}]: cam_id is not an integer", _table_line(text, table))
        name = f"cam_{cam_id}"
        cams.append(_toml_camera(path, text, table, cam, name))
        names.append(name)
    if not cams:
        raise MocapInputError(path, "no usable cameras")
    return rig_from_cameras(cams, names, path)


# ---------------------------------------------------------------------------------------------------------------
# Qualisys QCA (XML)


def load_qualisys_qca(path: str | os.PathLike) -> Rig:
    """Qualisys QTM calibration export (``Calib.qca.txt``, XML).

    Per camera: intrinsics in 1/64 pixel, ``fx = focalLengthU/64``, ``cx = centerPointU/64 − fov_video.left``
    (and likewise for v, with ``top``); distortion ``[radialDistortion1, radialDistortion2, tangentalDistortion1,
    tangentalDistortion2, radialDistortion3]`` as given; ``<transform>`` is the camera pose in the world (mm) with
    ``Rq = [r11 … r33]`` row-major, and the OpenCV world→camera model is ``R = diag(1, −1, −1) Rq``,
    ``t = −R (x, y, z)/1000`` (z-up world, metres). Image size from ``fov_video``. Cameras with a non-zero
    ``viewrotation`` are not supported.
    """
    text = read_text(path)
    try:
        root = ET.fromstring(text.encode("utf-8"))
    except ET.ParseError as e:
        line = e.position[0] if getattr(e, "position", None) else None
        raise MocapInputError(path, f"invalid XML: {e}", line) from None
    except (LookupError, ValueError, RecursionError) as e:  # e.g. an unknown encoding in the declaration
        raise MocapInputError(path, f"invalid XML: {e}", 1) from None
    if root.tag != "calibration":
        raise MocapInputError(
            path, f"root element is <{root.tag[:40]}>, not <calibration>: not a Qualisys QCA file"
        )
    cam_nodes = root.findall("./cameras/camera")
    if not cam_nodes:
        raise MocapInputError(path, "no <camera> elements")
    cams, names = [], []
    for k, cam in enumerate(cam_nodes):
        name = cam.get("serial") or f"cam{k + 1}"
        line = (
            _line_of(text, r"<camera\b[^>]*serial=\"" + re.escape(name) + '"') if cam.get("serial") else None
        )

        def num(elem, attr, name=name, line=line):
            if elem is None:
                raise MocapInputError(path, f"camera {name!r}: missing element", line)
            s = elem.get(attr)
            try:
                v = float(s)
            except (TypeError, ValueError):
                raise MocapInputError(
                    path, f"camera {name!r}: attribute {attr!r} missing or not a number", line
                ) from None
            if not math.isfinite(v):
                raise MocapInputError(path, f"camera {name!r}: attribute {attr!r} is not finite", line)
            return v

        if cam.get("viewrotation", "0") not in ("0", "0.0"):
            raise MocapInputError(path, f"camera {name!r}: viewrotation is not supported", line)
        fov = cam.find("fov_video")
        intr = cam.find("intrinsic")
        tr = cam.find("transform")
        left, top, right, bottom = (num(fov, a) for a in ("left", "top", "right", "bottom"))
        fx, fy = num(intr, "focalLengthU") / 64.0, num(intr, "focalLengthV") / 64.0
        cx, cy = num(intr, "centerPointU") / 64.0 - left, num(intr, "centerPointV") / 64.0 - top
        skew = num(intr, "skew") if intr is not None and intr.get("skew") is not None else 0.0
        dist = [
            num(intr, "radialDistortion1"),
            num(intr, "radialDistortion2"),
            num(intr, "tangentalDistortion1"),
            num(intr, "tangentalDistortion2"),
            num(intr, "radialDistortion3") if intr.get("radialDistortion3") is not None else 0.0,
        ]
        Rq = np.asarray([num(tr, f"r{i}{j}") for i in (1, 2, 3) for j in (1, 2, 3)]).reshape(3, 3)
        pos = np.asarray([num(tr, a) for a in ("x", "y", "z")]) / 1000.0
        R = np.diag([1.0, -1.0, -1.0]) @ Rq
        t = -R @ pos
        K = [[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]
        size = (right - left + 1, bottom - top + 1)
        cams.append(checked_camera(path, line, name, K, dist, R, t, size))
        names.append(name)
    return rig_from_cameras(cams, names, path)


# ---------------------------------------------------------------------------------------------------------------
# Auto-detection and writing


class _Reader(NamedTuple):
    name: str
    accepts: Callable[[object], bool]
    load: Callable[[object], Rig]


_READERS: list[_Reader] = []


def register_reader(name: str, accepts: Callable[[object], bool], load: Callable[[object], Rig]) -> None:
    """Teach :func:`load_calibration` a format: ``accepts(path)`` says whether ``load(path)`` reads ``path`` (a path
    or a list of paths, as given to :func:`load_calibration`), before the formats of this module are tried.
    Registered readers are asked in the order they were registered; registering a name again replaces it."""
    _READERS[:] = [r for r in _READERS if r.name != name]
    _READERS.append(_Reader(name, accepts, load))


def load_calibration(path: str | os.PathLike | Sequence[str | os.PathLike]) -> Rig:
    """Load a calibration, detecting its format (metres, z-up world as stored).

    * a format registered with :func:`register_reader` that accepts ``path`` (the PARSEC wing registers its
      Bouguet ``.cal`` cameras: a folder, a ``.cal`` file or a list of ``.cal`` files, converted to metres);
    * EasyMocap's ``intri.yml`` + ``extri.yml`` (their folder, or either file): :func:`load_easymocap`;
    * ``.toml``: caliscope if it has ``[cameras.N]`` tables (:func:`load_caliscope_toml`), otherwise Pose2Sim
      (:func:`load_pose2sim_toml`);
    * XML whose root is ``<calibration>``: Qualisys QCA (:func:`load_qualisys_qca`);
    * other YAML/XML: OpenCV FileStorage (:func:`load_opencv_storage`).
    """
    if isinstance(path, str | os.PathLike) and _easymocap_pair(path) is not None:
        return load_easymocap(path)
    for reader in _READERS:
        if reader.accepts(path):
            return reader.load(path)
    wing = "PARSEC / Bouguet .cal cameras are read by jaxmocap's parsec wing: import it first"
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"no reader for a list of calibration files ({wing})")
    p = os.fspath(path)
    if os.path.isdir(p) or p.lower().endswith(".cal"):
        raise MocapInputError(p, f"no reader for a calibration folder or .cal file ({wing})")
    text = read_text(p)
    head = text.lstrip()[:4096]
    if p.lower().endswith(".toml"):
        data = _parse_toml(p, text)
        if isinstance(data.get("cameras"), dict):
            return load_caliscope_toml(p)
        return load_pose2sim_toml(p)
    if head.startswith("%YAML") or head.startswith("<opencv_storage") or "<opencv_storage" in head:
        return load_opencv_storage(p)
    if head.startswith("<") and re.search(r"<calibration[\s>]", head):
        return load_qualisys_qca(p)
    if re.match(r"^\s*\[", text):
        data = _parse_toml(p, text)
        if isinstance(data.get("cameras"), dict):
            return load_caliscope_toml(p)
        return load_pose2sim_toml(p)
    raise MocapInputError(p, "unknown calibration format (expected OpenCV YAML/XML, TOML, QCA or .cal)", 1)


def _rotation_vector(R: np.ndarray) -> np.ndarray:
    """Rodrigues vector of a rotation matrix (OpenCV's ``cv2.Rodrigues``, which handles angles near π)."""
    rvec, _ = cv2.Rodrigues(np.asarray(R, dtype=np.float64))
    return rvec.reshape(3)


def save_calibration(path: str | os.PathLike, rig: Rig) -> None:
    """Write ``rig`` as a Pose2Sim-layout TOML (readable by Pose2Sim, by :func:`load_calibration` and directly
    usable with ``cv2.projectPoints``): one table per camera with ``name``, ``size = [w, h]``, ``matrix`` (K; a
    non-zero skew is kept in ``matrix[0][1]``, which ``cv2.projectPoints`` ignores), ``distortions`` (5 OpenCV
    terms), ``rotation`` (Rodrigues vector world→camera), ``translation`` (metres) and ``fisheye = false``, then
    Pose2Sim's ``[metadata]`` table."""
    import tomli_w

    K, dist, R, t = (np.asarray(a, dtype=np.float64) for a in (rig.K, rig.dist, rig.R, rig.t))
    doc: dict = {}
    for v, name in enumerate(rig.names):
        if name in doc or name == "metadata":
            raise ValueError(f"camera name {name!r} is repeated or reserved")
        w, h = rig.image_size[v]
        doc[name] = {
            "name": name,
            "size": [float(w), float(h)],
            "matrix": K[v].tolist(),
            "distortions": dist[v].tolist(),
            "rotation": _rotation_vector(R[v]).tolist(),
            "translation": t[v].tolist(),
            "fisheye": False,
        }
    doc["metadata"] = {"adjusted": False, "error": 0.0}
    with open(path, "wb") as f:
        tomli_w.dump(doc, f)
