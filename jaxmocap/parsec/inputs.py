"""PARSEC bodytrack sequence folders as a tracking input (``jaxmocap track SEQUENCE_B``).

A bodytrack input folder (``../shared/data/parsec/FORMAT.md`` §3) holds ``CALIB/Camera<k>.cal`` (Bouguet
cameras, mm), ``CAM<k>/imageNNNN.bmp`` (8-bit grey images), ``FG<k>/imageNNNN.bmp`` (foreground maps),
``BodyShapeParameters.txt`` (the 10-cylinder body), ``InitialPose.txt`` (the 31-value start state: radians, and
the pelvis translation in **mm**) and ``PoseParameters.txt`` (per-DOF σ_0, min, max). :func:`find_parsec_folder`
recognises such a folder (or a folder holding exactly one), :class:`ParsecSource` reads it frame by frame: per
frame the likelihood's observation (bodytrack's edge maps and binary foreground maps, :mod:`jaxmocap.parsec.model`).

Everything here stays in PARSEC's millimetres; :mod:`jaxmocap.parsec.track` converts its outputs to metres.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import camera
from jaxmocap.parsec import model as parsec

__all__ = ["NOMINAL_FPS", "ParsecSource", "find_parsec_folder", "is_parsec_folder"]

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

    Attributes: ``root`` (the sequence folder), ``cameras`` (:class:`jaxmocap.parsec.model.Cameras`, mm), ``rig``
    (:class:`jaxmocap.geometry.camera.Rig`, metres), ``shape`` (:class:`jaxmocap.parsec.model.BodyShape`, mm),
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
        self.cameras = parsec.cameras_from_rig(camera.load_parsec_calibration(cal_files, units="mm"), "mm")
        self.rig = camera.load_parsec_calibration(cal_files, units="m")
        self.shape = parsec.load_body_shape(root / "BodyShapeParameters.txt")
        self.initial_pose = parsec.load_pose(root / "InitialPose.txt")
        self.pose_parameters = parsec.load_pose_parameters(root / "PoseParameters.txt")
        available = None
        for k in range(n):
            for kind in ("CAM", "FG"):
                d = root / f"{kind}{k + 1}"
                if not d.is_dir():
                    raise MocapInputError(d, f"image folder missing (the sequence has {n} cameras)")
                nums = set(parsec._frame_numbers(os.fspath(d)))
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

    def images(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``t``: grey images and binary foreground maps, ``(V, H, W) uint8`` each (rows from the top)."""
        ims, fgs = [], []
        for k in range(self.num_views):
            name = f"image{t:04d}.bmp"
            pairs = []
            for kind in ("CAM", "FG"):
                p = self.root / f"{kind}{k + 1}" / name
                a = parsec.load_image(p)
                w, h = (
                    self.rig.image_size[k] if self.rig.image_size[k] != (0, 0) else (a.shape[1], a.shape[0])
                )
                if a.shape != (h, w):
                    raise MocapInputError(p, f"image is {a.shape[1]}x{a.shape[0]}, expected {w}x{h}")
                pairs.append(a)
            ims.append(pairs[0])
            fgs.append(parsec.foreground_map(pairs[1]))
        return np.stack(ims), np.stack(fgs)

    def observation(self, t: int):
        """The PARSEC likelihood's observation of frame ``t`` (:func:`jaxmocap.parsec.likelihood.observation`:
        bodytrack's edge maps, §6.1, and its binary foreground maps)."""
        from jaxmocap.parsec import likelihood as parsec_likelihood

        ims, fgs = self.images(t)
        return parsec_likelihood.observation(np.stack([parsec.edge_map(im) for im in ims]), fgs)

    def close(self) -> None:
        pass
