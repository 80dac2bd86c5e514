"""PARSEC bodytrack's input files: the body shape, poses, pose parameters and Bouguet ``.cal`` cameras.

The layouts are documented in ``jaxmocap/parsec/FORMAT.md`` (§3). Everything is read in PARSEC's units
(millimetres and radians) into float64 numpy arrays; every defect raises :class:`jaxmocap.errors.MocapInputError`
naming the file and line.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry.camera import Rig
from jaxmocap.io.calibration import checked_camera, read_text, rig_from_cameras

__all__ = [
    "BodyShape",
    "DOF_NAMES",
    "LENGTH_NAMES",
    "LIMB_FIELDS",
    "MM_PER_M",
    "PART_NAMES",
    "PoseParameters",
    "accepts_cal",
    "load_body_shape",
    "load_parsec_calibration",
    "load_pose",
    "load_pose_parameters",
    "load_poses",
]

MM_PER_M = 1000.0

#: The 10 body parts (cylinders) in bodytrack's order.
PART_NAMES: tuple[str, ...] = (
    "torso",
    "left_thigh",
    "left_shin",
    "right_thigh",
    "right_shin",
    "left_upper_arm",
    "left_forearm",
    "right_upper_arm",
    "right_forearm",
    "head",
)

#: The 4 values per part in ``BodyShapeParameters.txt``.
LIMB_FIELDS: tuple[str, ...] = ("radius_bottom", "radius_top", "scale_x", "scale_y")

#: The 18 lengths of ``BodyShapeParameters.txt`` (mm). ``length_4/8/12/16`` are read but unused by bodytrack.
LENGTH_NAMES: tuple[str, ...] = (
    "torso_length",
    "left_hip_offset",
    "left_thigh_length",
    "left_shin_length",
    "length_4",
    "right_hip_offset",
    "right_thigh_length",
    "right_shin_length",
    "length_8",
    "left_clavicle_length",
    "left_upper_arm_length",
    "left_forearm_length",
    "length_12",
    "right_clavicle_length",
    "right_upper_arm_length",
    "right_forearm_length",
    "length_16",
    "head_length",
)

#: The 31 state entries in PARSEC's order.
DOF_NAMES: tuple[str, ...] = (
    "pelvis_rx",
    "pelvis_ry",
    "pelvis_rz",
    "pelvis_tx",
    "pelvis_ty",
    "pelvis_tz",
    "left_hip_rx",
    "left_hip_ry",
    "left_hip_rz",
    "left_knee",
    "right_hip_rx",
    "right_hip_ry",
    "right_hip_rz",
    "right_knee",
    "left_clavicle_rx",
    "left_clavicle_ry",
    "left_shoulder_rx",
    "left_shoulder_ry",
    "left_shoulder_rz",
    "left_elbow",
    "right_clavicle_rx",
    "right_clavicle_ry",
    "right_shoulder_rx",
    "right_shoulder_ry",
    "right_shoulder_rz",
    "right_elbow",
    "thorax_ry",
    "thorax_rz",
    "head_rx",
    "head_ry",
    "head_rz",
)

NUM_PARTS = 10
NUM_LENGTHS = 18
NUM_DOFS = 31


class BodyShape(NamedTuple):
    """``BodyShapeParameters.txt``: ``limbs (10, 4)`` = [bottom radius, top radius, x-scale, y-scale] per part
    (mm, mm, 1, 1) and ``lengths (18,)`` (mm, :data:`LENGTH_NAMES`). A pytree; arrays may be traced."""

    limbs: jnp.ndarray
    lengths: jnp.ndarray


# ---------------------------------------------------------------------------------------------------------------
# Text files


def _numbers(path, text: str, prefix: str = "") -> tuple[list[float], list[int]]:
    """All whitespace-separated numbers of ``text`` with their 1-based line numbers; ``prefix`` starts the
    message of a bad token."""
    vals, lines = [], []
    for i, raw in enumerate(text.splitlines(), start=1):
        for tok in raw.split():
            try:
                v = float(tok)
            except ValueError:
                raise MocapInputError(path, f"{prefix}{tok[:40]!r} is not a number", i) from None
            if not math.isfinite(v):
                raise MocapInputError(path, f"{prefix}non-finite value {tok[:40]!r}", i)
            vals.append(v)
            lines.append(i)
    return vals, lines


def _read_numbers(path: str | os.PathLike, what: str) -> tuple[list[float], list[int]]:
    """All whitespace-separated numbers of a text file with their 1-based line numbers."""
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            text = f.read()
    except OSError as e:
        raise MocapInputError(path, f"cannot read {what}: {e.strerror or e}") from None
    return _numbers(path, text, f"{what}: ")


def _expect_count(path, what, vals, lines, n):
    if len(vals) < n:
        last = lines[-1] if lines else 1
        raise MocapInputError(path, f"{what}: expected {n} numbers, found {len(vals)}", last)
    if len(vals) > n:
        raise MocapInputError(path, f"{what}: expected {n} numbers, found more", lines[n])


def load_body_shape(path: str | os.PathLike) -> BodyShape:
    """``BodyShapeParameters.txt``: 10×4 limb values then 18 lengths (float64 numpy arrays)."""
    what = "BodyShapeParameters"
    vals, lines = _read_numbers(path, what)
    _expect_count(path, what, vals, lines, NUM_PARTS * 4 + NUM_LENGTHS)
    limbs = np.asarray(vals[: NUM_PARTS * 4]).reshape(NUM_PARTS, 4)
    lengths = np.asarray(vals[NUM_PARTS * 4 :])
    for i in range(NUM_PARTS):
        line = lines[4 * i]
        if np.any(limbs[i, :2] < 0):
            raise MocapInputError(path, f"{what}: negative radius for part {i} ({PART_NAMES[i]})", line)
        if np.any(limbs[i, 2:] <= 0):
            raise MocapInputError(path, f"{what}: scale of part {i} ({PART_NAMES[i]}) must be positive", line)
    if np.any(lengths < 0):
        k = int(np.argmax(lengths < 0))
        raise MocapInputError(path, f"{what}: negative length [{k}] ({LENGTH_NAMES[k]})", lines[40 + k])
    return BodyShape(limbs, lengths)


def load_pose(path: str | os.PathLike) -> np.ndarray:
    """``InitialPose.txt``: the 31-value state (float64; radians and mm)."""
    vals, lines = _read_numbers(path, "pose")
    _expect_count(path, "pose", vals, lines, NUM_DOFS)
    return np.asarray(vals)


class PoseParameters(NamedTuple):
    """``PoseParameters.txt``: per-DOF standard deviation, minimum and maximum, ``(31,)`` each."""

    std: np.ndarray
    min: np.ndarray
    max: np.ndarray


def load_pose_parameters(path: str | os.PathLike) -> PoseParameters:
    """``PoseParameters.txt``: 31 standard deviations, 31 minima, 31 maxima."""
    what = "PoseParameters"
    vals, lines = _read_numbers(path, what)
    _expect_count(path, what, vals, lines, 3 * NUM_DOFS)
    a = np.asarray(vals).reshape(3, NUM_DOFS)
    if np.any(a[0] < 0):
        k = int(np.argmax(a[0] < 0))
        raise MocapInputError(path, f"{what}: negative standard deviation for {DOF_NAMES[k]}", lines[k])
    return PoseParameters(a[0], a[1], a[2])


def load_poses(path: str | os.PathLike) -> np.ndarray:
    """bodytrack's output ``poses.txt``: one 31-value state a line → ``(F, 31)``."""
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            text = f.read()
    except OSError as e:
        raise MocapInputError(path, f"cannot read poses: {e.strerror or e}") from None
    rows = []
    for i, raw in enumerate(text.splitlines(), start=1):
        toks = raw.split()
        if not toks:
            continue
        if len(toks) != NUM_DOFS:
            raise MocapInputError(path, f"poses: expected {NUM_DOFS} values a line, found {len(toks)}", i)
        try:
            row = [float(t) for t in toks]
        except ValueError:
            raise MocapInputError(path, "poses: a value is not a number", i) from None
        if not all(math.isfinite(v) for v in row):
            raise MocapInputError(path, "poses: non-finite value", i)
        rows.append(row)
    return np.asarray(rows, dtype=np.float64).reshape(-1, NUM_DOFS)


# ---------------------------------------------------------------------------------------------------------------
# Cameras: Bouguet .cal files


_PARSEC_IMAGE_SIZE = (640, 480)


def _load_bouguet_cal(path, scale: float, image_size: tuple[int, int]) -> tuple:
    """One Bouguet-toolbox ``.cal`` file: fc(2) cc(2) alpha_c kc(5) Rc_ext(9, row-major) Tc_ext(3) omc_ext(3)."""
    text = read_text(path)
    vals, lines = _numbers(path, text)
    if len(vals) < 25:
        raise MocapInputError(
            path, f"truncated: expected 25 numbers, found {len(vals)}", len(text.splitlines()) or 1
        )
    if len(vals) > 25:
        raise MocapInputError(path, f"expected 25 numbers, found {len(vals)}", lines[25])
    fc, cc, alpha, kc = vals[0:2], vals[2:4], vals[4], vals[5:10]
    R = np.asarray(vals[10:19]).reshape(3, 3)
    T = np.asarray(vals[19:22]) * scale
    K = [[fc[0], alpha * fc[0], cc[0]], [0.0, fc[1], cc[1]], [0.0, 0.0, 1.0]]
    name = os.path.splitext(os.path.basename(os.fspath(path)))[0]
    return checked_camera(path, lines[10], name, K, kc, R, T, image_size), name


def load_parsec_calibration(
    dir_or_files: str | os.PathLike | Sequence[str | os.PathLike],
    units: str = "m",
    image_size: tuple[int, int] = _PARSEC_IMAGE_SIZE,
) -> Rig:
    """PARSEC bodytrack / Bouguet ``.cal`` cameras.

    ``dir_or_files``: a sequence folder (with ``CALIB/``), a ``CALIB/`` folder (``Camera1.cal …`` in numeric
    order), one ``.cal`` file or a list of them. Each file holds 25 numbers in the Bouguet toolbox order
    ``fc(2) cc(2) alpha_c kc(5) Rc_ext(9, row-major) Tc_ext(3) omc_ext(3)`` (bodytrack's ``CameraModel.cpp``):
    ``K = [[fc_x, alpha_c fc_x, cc_x], [0, fc_y, cc_y], [0, 0, 1]]`` (skew kept), ``dist = kc`` (Bouguet's
    order is OpenCV's), ``R = Rc_ext``, ``t = Tc_ext``. The PARSEC world is z-up in millimetres: ``units="m"``
    converts ``t`` to metres, ``units="mm"`` keeps millimetres (for parity with the C++ reference). The unused
    ``omc_ext`` is read but ignored. Images are 640×480 with rows from the top.
    """
    if units not in ("m", "mm"):
        raise ValueError(f"units must be 'm' or 'mm', not {units!r}")
    scale = 1e-3 if units == "m" else 1.0
    if isinstance(dir_or_files, str | os.PathLike):
        p = os.fspath(dir_or_files)
        if os.path.isdir(p):
            if os.path.isdir(os.path.join(p, "CALIB")):
                p = os.path.join(p, "CALIB")
            files = [os.path.join(p, f) for f in os.listdir(p) if f.lower().endswith(".cal")]
            if not files:
                raise MocapInputError(p, "no .cal files in this folder")

            def order(f):
                m = re.search(r"(\d+)\D*$", os.path.basename(f))
                return (int(m.group(1)) if m else -1, os.path.basename(f))

            files.sort(key=order)
        else:
            files = [p]
    else:
        files = [os.fspath(f) for f in dir_or_files]
        if not files:
            raise ValueError("no .cal files given")
    cams, names = [], []
    for f in files:
        cam, name = _load_bouguet_cal(f, scale, image_size)
        cams.append(cam)
        names.append(name)
    return rig_from_cameras(cams, names, files[0] if len(files) == 1 else os.path.dirname(files[0]))


def accepts_cal(path) -> bool:
    """Whether :func:`jaxmocap.io.calibration.load_calibration` should read ``path`` with
    :func:`load_parsec_calibration`: a list of files, a folder or a ``.cal`` file."""
    if not isinstance(path, str | os.PathLike):
        return True
    p = os.fspath(path)
    return os.path.isdir(p) or p.lower().endswith(".cal")
