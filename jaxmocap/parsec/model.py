"""PARSEC bodytrack's body model, inputs and image preprocessing, value for value.

PARSEC's ``bodytrack`` (Intel, Apache-2.0) tracks a walking person in 4 calibrated cameras with an annealed
particle filter over a 10-cylinder body driven by a 31-value state. This module reproduces its geometry exactly so
that likelihoods and filters written here can be compared with it and timed against it; the likelihood itself is
in :mod:`jaxmocap.parsec.likelihood`. The documentation of the C++ code is ``../shared/data/parsec/FORMAT.md``
(sections cited as §).

**Units.** PARSEC works in millimetres and so does everything here: the translation entries (3, 4, 5) of the
state, body lengths, camera translations and cylinder poses are in **mm**; angles are radians. The rest of the
project uses metres: :func:`to_metres` converts a state and :func:`joint_positions_metres` gives the evaluation
joints in metres.

**State** (31 values, PARSEC's order, §3 ``InitialPose.txt``): 0–2 pelvis Euler angles about x, y, z; 3–5 pelvis
translation; 6–8 left hip; 9 left knee; 10–12 right hip; 13 right knee; 14–15 left clavicle; 16–18 left shoulder;
19 left elbow; 20–21 right clavicle; 22–24 right shoulder; 25 right elbow; 26–27 thorax (y, z); 28–30 head.

**Kinematics** (§6.2). With ``E(θ, φ, τ) = Rz(τ) Rx(θ) Ry(φ)`` the pelvis is ``[E(a0, a1, a2) | (a3, a4, a5)]``
and every other joint multiplies its parent by a constant rotation, a translation and ``inv(E(...)) = Ry(−φ)
Rx(−θ) Rz(−τ)``: three revolute degrees of freedom about −y, −x, −z, in that order. :func:`parsec31` writes this
chain as a :class:`jaxmocap.geometry.body.BodyModel` (14 segments: the 10 cylinders plus the intermediate frames ``spine``,
``thorax`` and the two clavicles), so the generic filters and :func:`jaxmocap.geometry.body.segment_poses` run it
unchanged. The likelihood uses a specialised version of the same chain (:func:`cylinder_poses`, tested equal):
PARSEC's joints only rotate about coordinate axes, so a joint mixes two rotation columns instead of multiplying
matrices, and the float32 sine and cosine are computed by a short polynomial that XLA vectorises.

**Cylinders.** Cylinder ``i`` (0 torso, 1 left thigh, 2 left shin, 3 right thigh, 4 right shin, 5 left upper arm,
6 left forearm, 7 right upper arm, 8 right forearm, 9 head) is the frame of its segment with the rotation columns
scaled by ``(limbs[i][2], limbs[i][3], 1)``; its axis is local +z from 0 to a signed length (negative for the
arms), with radius ``limbs[i][0]`` at 0 and ``limbs[i][1]`` at the far end (:func:`cylinder_poses`).

**Evaluation joints** (a subset of :data:`jaxmocap.geometry.body.EVAL_JOINTS`, all 15): ``root`` = pelvis origin (torso
cylinder bottom centre); ``thorax`` = torso cylinder top centre (where the clavicles and the head start); ``head``
= centre of the head cylinder's axis; shoulders, elbows = origins of the upper-arm and forearm cylinders; wrists =
far ends of the forearm cylinders; hips, knees = origins of the thigh and shin cylinders; ankles = far ends of the
shin cylinders.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import re
from collections.abc import Mapping
from importlib import resources
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import body, kinematics

__all__ = [
    "BodyShape",
    "Cameras",
    "PART_NAMES",
    "DOF_NAMES",
    "LENGTH_NAMES",
    "CYLINDER_SEGMENT",
    "PoseParameters",
    "ParsecSequence",
    "default_shape",
    "shape_from_dims",
    "shape_to_dims",
    "parsec31",
    "with_limits",
    "cylinder_lengths",
    "cylinder_poses",
    "cylinder_corners",
    "project",
    "load_body_shape",
    "load_pose",
    "load_pose_parameters",
    "load_poses",
    "load_image",
    "load_cameras",
    "cameras_from_rig",
    "load_sequence",
    "edge_map",
    "foreground_map",
    "to_metres",
    "from_metres",
    "joint_positions_metres",
    "MM_PER_M",
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

# Constant rotations of BodyGeometry.h (row-major).
_I3 = np.eye(3)
_XROT90 = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
_XROT180 = np.diag([1.0, -1.0, -1.0])
_XROT270 = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
_YROT90 = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
_YROT180 = np.diag([-1.0, 1.0, -1.0])
_ZROT180 = np.diag([-1.0, -1.0, 1.0])
_SHOULDER = _XROT90 @ _ZROT180 @ _YROT90  # r = XRot90 · ZRot180 · YRot90

_X, _Y, _Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
_NX, _NY, _NZ = (-1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0)


def _inv_euler(theta: int | None, phi: int | None, tau: int | None) -> list[tuple[int, tuple]]:
    """``inv(E(a_θ, a_φ, a_τ)) = Ry(−a_φ) Rx(−a_θ) Rz(−a_τ)`` as revolute DOFs; ``None`` marks a constant 0."""
    out = []
    for idx, axis in ((phi, _NY), (theta, _NX), (tau, _NZ)):
        if idx is not None:
            out.append((idx, axis))
    return out


# (segment name, parent, rest rotation, offset as (length index, sign, axis) or None, DOFs [(state index, axis)])
_SEGMENTS: tuple = (
    ("pelvis", None, _I3, None, [(3, _X), (4, _Y), (5, _Z), (2, _Z), (0, _X), (1, _Y)]),
    ("left_thigh", "pelvis", _YROT180, (1, 1.0, 1), _inv_euler(6, 7, 8)),
    ("left_shin", "left_thigh", _I3, (2, 1.0, 2), _inv_euler(None, 9, None)),
    ("right_thigh", "pelvis", _YROT180, (5, -1.0, 1), _inv_euler(10, 11, 12)),
    ("right_shin", "right_thigh", _I3, (6, 1.0, 2), _inv_euler(None, 13, None)),
    ("spine", "pelvis", _XROT180, None, _inv_euler(None, 26, 27)),
    ("thorax", "spine", _I3, (0, -1.0, 2), []),
    ("left_clavicle", "thorax", _XROT90, None, _inv_euler(14, 15, None)),
    ("left_upper_arm", "left_clavicle", _SHOULDER, (9, -1.0, 2), _inv_euler(16, 17, 18)),
    ("left_forearm", "left_upper_arm", _I3, (10, -1.0, 2), _inv_euler(None, 19, None)),
    ("right_clavicle", "thorax", _XROT270, None, _inv_euler(20, 21, None)),
    ("right_upper_arm", "right_clavicle", _SHOULDER, (13, -1.0, 2), _inv_euler(22, 23, 24)),
    ("right_forearm", "right_upper_arm", _I3, (14, -1.0, 2), _inv_euler(None, 25, None)),
    ("head", "thorax", _XROT180, None, _inv_euler(28, 29, 30)),
)
SEGMENT_NAMES: tuple[str, ...] = tuple(s[0] for s in _SEGMENTS)

#: Segment index of each cylinder (part).
CYLINDER_SEGMENT: tuple[int, ...] = tuple(
    SEGMENT_NAMES.index(n)
    for n in (
        "pelvis",
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
)
# signed cylinder length of each part: (length index, sign)
_CYLINDER_LENGTH = (
    (0, 1.0),
    (2, 1.0),
    (3, 1.0),
    (6, 1.0),
    (7, 1.0),
    (10, -1.0),
    (11, -1.0),
    (14, -1.0),
    (15, -1.0),
    (17, 1.0),
)

_BIG_MM = 1.0e5  # PoseParameters.txt's bound for the translation (mm)


# ---------------------------------------------------------------------------------------------------------------
# Body shape


class BodyShape(NamedTuple):
    """``BodyShapeParameters.txt``: ``limbs (10, 4)`` = [bottom radius, top radius, x-scale, y-scale] per part
    (mm, mm, 1, 1) and ``lengths (18,)`` (mm, :data:`LENGTH_NAMES`). A pytree; arrays may be traced."""

    limbs: jnp.ndarray
    lengths: jnp.ndarray


def _default_shape_path() -> str:
    return str(resources.files("jaxmocap") / "data" / "parsec" / "BodyShapeParameters.txt")


@functools.cache
def _default_shape_values() -> tuple[tuple[float, ...], tuple[float, ...]]:
    shape = load_body_shape(_default_shape_path())
    return tuple(shape.limbs.reshape(-1).tolist()), tuple(shape.lengths.tolist())


def default_shape() -> BodyShape:
    """The body of PARSEC's sequenceB (shipped in ``jaxmocap/data/parsec``), float64 numpy arrays."""
    limbs, lengths = _default_shape_values()
    return BodyShape(np.asarray(limbs).reshape(NUM_PARTS, 4), np.asarray(lengths))


def shape_to_dims(shape: BodyShape) -> dict[str, float]:
    """Named dimensions (``{part}_{field}`` for :data:`LIMB_FIELDS`, and :data:`LENGTH_NAMES`), e.g. for a body
    file with ``model = "parsec31"``."""
    limbs = np.asarray(shape.limbs, dtype=np.float64)
    lengths = np.asarray(shape.lengths, dtype=np.float64)
    out = {
        f"{p}_{f}": float(limbs[i, j]) for i, p in enumerate(PART_NAMES) for j, f in enumerate(LIMB_FIELDS)
    }
    out.update({n: float(lengths[k]) for k, n in enumerate(LENGTH_NAMES)})
    return out


def shape_from_dims(dims: BodyShape | Mapping[str, object] | None) -> BodyShape:
    """A :class:`BodyShape` from a shape (returned as is), a mapping of named dimensions (missing names take the
    sequenceB values; unknown names raise ``ValueError``) or ``None`` (sequenceB)."""
    if isinstance(dims, BodyShape):
        return dims
    base = default_shape()
    if dims is None:
        return base
    if not isinstance(dims, Mapping):
        raise TypeError(f"dims must be a BodyShape, a mapping or None, not {type(dims).__name__}")
    limb_keys = {f"{p}_{f}": (i, j) for i, p in enumerate(PART_NAMES) for j, f in enumerate(LIMB_FIELDS)}
    unknown = [k for k in dims if k not in limb_keys and k not in LENGTH_NAMES]
    if unknown:
        raise ValueError(
            f"unknown parsec31 dimension(s) {sorted(unknown)}; known: {sorted([*limb_keys, *LENGTH_NAMES])}"
        )
    limbs = [
        [dims.get(f"{p}_{f}", base.limbs[i, j]) for j, f in enumerate(LIMB_FIELDS)]
        for i, p in enumerate(PART_NAMES)
    ]
    lengths = [dims.get(n, base.lengths[k]) for k, n in enumerate(LENGTH_NAMES)]
    return BodyShape(
        jnp.stack([jnp.stack([jnp.asarray(v) for v in row]) for row in limbs]),
        jnp.stack([jnp.asarray(v) for v in lengths]),
    )


def cylinder_lengths(shape: BodyShape) -> jnp.ndarray:
    """Signed length (mm) of each cylinder along its local z: ``(10,)`` (negative for the four arm parts)."""
    L = jnp.asarray(shape.lengths)
    return jnp.stack([s * L[k] for k, s in _CYLINDER_LENGTH])


# ---------------------------------------------------------------------------------------------------------------
# The body model


def parsec31(dims: BodyShape | Mapping[str, object] | None = None, dtype=jnp.float32) -> body.BodyModel:
    """PARSEC bodytrack's body as a :class:`jaxmocap.geometry.body.BodyModel` (**millimetres**, 31 DOFs in PARSEC's order).

    ``dims``: a :class:`BodyShape` (from :func:`load_body_shape`), a mapping of named dimensions (see
    :func:`shape_from_dims`) or ``None`` for sequenceB's body. Gradients flow to the dimensions.

    The kinematic chain reproduces §6.2 exactly (see the module docstring): ``segment_poses(model, x)`` returns
    the unscaled chain matrices of bodytrack for the 14 segments. The flesh primitives are the 10 cylinders as
    circular truncated cones; the elliptic cross-section of the torso and the head (x/y scales) is kept only by
    :func:`cylinder_poses`, the cone radius being the area-preserving ``r·sqrt(sx·sy)``. Joint limits are wide
    (±2π for angles, ±1e5 mm for the translation) because bodytrack applies none (``BodyPose::Valid`` returns
    true before its checks); :func:`with_limits` sets PoseParameters' bounds. The rest pose is every angle zero
    with the pelvis raised so that the longer leg's ankle is at z = 0: the body stands upright, left side towards
    +y, arms stretched horizontally towards −x (PARSEC's zero pose).
    """
    shape = shape_from_dims(dims)
    limbs = jnp.asarray(shape.limbs, dtype)
    L = jnp.asarray(shape.lengths, dtype)
    zero = jnp.zeros((), dtype)

    def vec(*xs):
        return jnp.stack([jnp.asarray(v, dtype) for v in xs])

    offsets, dof_axis, seg_dofs, parents, kinds = [], [None] * NUM_DOFS, [], [], [None] * NUM_DOFS
    for name, parent, _rot, off, dofs in _SEGMENTS:
        parents.append(-1 if parent is None else SEGMENT_NAMES.index(parent))
        if off is None:
            offsets.append(vec(zero, zero, zero))
        else:
            k, sign, axis = off
            o = [zero, zero, zero]
            o[axis] = sign * L[k]
            offsets.append(vec(*o))
        idx = []
        for d, axis in dofs:
            idx.append(d)
            dof_axis[d] = axis
            kinds[d] = "P" if d in (3, 4, 5) and name == "pelvis" else "R"
        seg_dofs.append(tuple(idx))
    topology = kinematics.Topology(
        segment_names=SEGMENT_NAMES,
        parents=tuple(parents),
        segment_dofs=tuple(seg_dofs),
        dof_names=DOF_NAMES,
        dof_kinds=tuple(kinds),
        rest_rotated=tuple(not np.array_equal(s[2], _I3) for s in _SEGMENTS),
    )
    ang = np.asarray([k == "R" for k in kinds])
    lower = np.where(ang, -2.0 * math.pi, -_BIG_MM)
    upper = -lower

    # flesh: one cone per cylinder segment
    S = len(SEGMENT_NAMES)
    cyl_len = cylinder_lengths(BodyShape(limbs, L))
    kind = [body.SHAPE_NONE] * S
    starts = [vec(zero, zero, zero)] * S
    ends = [vec(zero, zero, zero)] * S
    r0 = [zero] * S
    r1 = [zero] * S
    for i, s in enumerate(CYLINDER_SEGMENT):
        k = jnp.sqrt(limbs[i, 2] * limbs[i, 3])
        kind[s] = body.SHAPE_CONE
        ends[s] = vec(zero, zero, cyl_len[i])
        r0[s] = limbs[i, 0] * k
        r1[s] = limbs[i, 1] * k

    seg = SEGMENT_NAMES.index
    joints = {
        "root": (seg("pelvis"), vec(zero, zero, zero)),
        "thorax": (seg("thorax"), vec(zero, zero, zero)),
        "head": (seg("head"), vec(zero, zero, 0.5 * L[17])),
        "left_shoulder": (seg("left_upper_arm"), vec(zero, zero, zero)),
        "left_elbow": (seg("left_forearm"), vec(zero, zero, zero)),
        "left_wrist": (seg("left_forearm"), vec(zero, zero, -L[11])),
        "right_shoulder": (seg("right_upper_arm"), vec(zero, zero, zero)),
        "right_elbow": (seg("right_forearm"), vec(zero, zero, zero)),
        "right_wrist": (seg("right_forearm"), vec(zero, zero, -L[15])),
        "left_hip": (seg("left_thigh"), vec(zero, zero, zero)),
        "left_knee": (seg("left_shin"), vec(zero, zero, zero)),
        "left_ankle": (seg("left_shin"), vec(zero, zero, L[3])),
        "right_hip": (seg("right_thigh"), vec(zero, zero, zero)),
        "right_knee": (seg("right_shin"), vec(zero, zero, zero)),
        "right_ankle": (seg("right_shin"), vec(zero, zero, L[7])),
    }
    names = tuple(j for j in body.EVAL_JOINTS if j in joints)
    # standing: the lower of the two ankles at z = 0 (legs hang straight down at zero angles)
    standing = jnp.maximum(L[2] + L[3], L[6] + L[7])
    rest = jnp.zeros(NUM_DOFS, dtype).at[5].set(standing)
    return body.BodyModel(
        rest_rotation=jnp.asarray(np.stack([s[2] for s in _SEGMENTS]), dtype),
        offset=jnp.stack(offsets),
        dof_axis=jnp.asarray(np.asarray(dof_axis, dtype=np.float64), dtype),
        lower=jnp.asarray(lower, dtype),
        upper=jnp.asarray(upper, dtype),
        rest_pose=rest,
        joint_point=jnp.stack([joints[n][1] for n in names]),
        shape_start=jnp.stack(starts),
        shape_end=jnp.stack(ends),
        radius_start=jnp.stack(r0),
        radius_end=jnp.stack(r1),
        name="parsec31",
        topology=topology,
        joint_names=names,
        joint_segment=tuple(joints[n][0] for n in names),
        shape_kind=tuple(kind),
    )


def parsec31_in_metres(
    dims: BodyShape | Mapping[str, object] | None = None, dtype=jnp.float32
) -> body.BodyModel:
    """:func:`parsec31` of the body ``dims`` in **metres** (radii and lengths / 1000), so that it shares the
    calibration and cues of the other models; the state's pelvis translation is then in metres too."""
    shape = shape_from_dims(dims)
    limbs = np.asarray(shape.limbs, np.float64).copy()
    limbs[:, :2] /= MM_PER_M
    shape = BodyShape(jnp.asarray(limbs), jnp.asarray(np.asarray(shape.lengths) / MM_PER_M))
    return parsec31(shape, dtype=dtype)


def with_limits(model: body.BodyModel, lower, upper) -> body.BodyModel:
    """The model with joint limits ``lower, upper (31,)`` (e.g. PoseParameters' min and max, which bodytrack
    itself never applies)."""
    dt = model.lower.dtype
    return dataclasses.replace(model, lower=jnp.asarray(lower, dt), upper=jnp.asarray(upper, dt))


def _sincos(x: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """``(sin x, cos x)``; float32 by Cody–Waite reduction to [−π/4, π/4] and Cephes' polynomials (≤ 1 ulp for
    the angles of a body, about 10× faster than XLA's CPU sin/cos), float64 by ``jnp.sin``/``jnp.cos``."""
    x = jnp.asarray(x)
    if x.dtype != jnp.float32:
        return jnp.sin(x), jnp.cos(x)
    f = np.float32
    k = jnp.floor(x * f(2.0 / np.pi) + f(0.5))
    r = ((x - k * f(1.5703125)) - k * f(4.837512969970703125e-4)) - k * f(7.54978995489188216e-8)
    z = r * r
    s = ((f(-1.9515295891e-4) * z + f(8.3321608736e-3)) * z - f(1.6666654611e-1)) * z * r + r
    c = ((f(2.443315711809948e-5) * z - f(1.388731625493765e-3)) * z + f(4.166664568298827e-2)) * z * z
    c = c - f(0.5) * z + f(1.0)
    q = k - f(4.0) * jnp.floor(k * f(0.25))  # quadrant 0..3
    swap = (q == 1.0) | (q == 3.0)
    sn = jnp.where(swap, c, s)
    cs = jnp.where(swap, s, c)
    sn = jnp.where(q >= 2.0, -sn, sn)
    cs = jnp.where((q == 1.0) | (q == 2.0), -cs, cs)
    return sn, cs


# A frame is (cols, t): cols[j] the j-th rotation column and t the translation, each a (3, *B) array.


def _times_constant(cols, M: np.ndarray):
    """``R · M`` for a constant signed permutation ``M``: columns picked and negated, no arithmetic."""
    out = []
    for j in range(3):
        i = int(np.flatnonzero(M[:, j])[0])
        out.append(cols[i] if M[i, j] > 0 else -cols[i])
    return tuple(out)


def _times_axis_rotation(cols, axis: tuple, s, c):
    """``R · R_a(θ)`` for a rotation about ±x, ±y or ±z (``s, c`` = sin, cos of θ): two columns mix."""
    k = int(np.flatnonzero(axis)[0])
    s = s if axis[k] > 0 else -s
    i, j = {0: (1, 2), 1: (2, 0), 2: (0, 1)}[k]  # R_a maps e_i → c e_i + s e_j, e_j → −s e_i + c e_j
    out = list(cols)
    out[i] = c * cols[i] + s * cols[j]
    out[j] = c * cols[j] - s * cols[i]
    return tuple(out)


def _segment_frames(lengths: jnp.ndarray, x: jnp.ndarray) -> list:
    """The 14 segment frames of :data:`SEGMENT_NAMES` for states ``x (31, *B)`` (batch axes trailing, ``B = ()``
    for one state): per segment ``(cols, t)`` with ``(3, *B)`` arrays (the hot path).

    Same chain as :func:`parsec31`'s ``segment_poses`` (tested), written with the structure of PARSEC's joints:
    constant rotations permute columns and a rotation about a coordinate axis mixes two columns.
    """
    dt = x.dtype
    batch = x.shape[1:]
    sin, cos = _sincos(x)
    sin, cos = sin[:, None], cos[:, None]  # (31, 1, *B) against (3, *B) columns
    eye = jnp.broadcast_to(_trail(jnp.eye(3, dtype=dt), len(batch)), (3, 3) + batch)
    frames: list = []
    for name, parent, rot, off, dofs in _SEGMENTS:
        if parent is None:
            cols = (eye[:, 0], eye[:, 1], eye[:, 2])
            t = x[3:6]
        else:
            pcols, t = frames[SEGMENT_NAMES.index(parent)]
            if off is not None:
                k, sign, axis = off
                t = t + pcols[axis] * (sign * lengths[k])
            cols = _times_constant(pcols, rot)
        for d, axis in dofs:
            if not (name == "pelvis" and d in (3, 4, 5)):  # the pelvis translation is set above
                cols = _times_axis_rotation(cols, axis, sin[d], cos[d])
        frames.append((cols, t))
    return frames


def _trail(a: jnp.ndarray, nb: int) -> jnp.ndarray:
    """``a`` with ``nb`` trailing singleton axes (to broadcast against trailing batch axes)."""
    return jnp.reshape(a, jnp.shape(a) + (1,) * nb)


def _cylinder_frames(shape: BodyShape, x: jnp.ndarray):
    """Scaled cylinder frames of states ``x (31, *B)``: ``(A, t)`` with ``A[i][j]`` and ``t[i]`` ``(10, *B)``
    arrays (row i, column j of the scaled rotation ``R·diag(sx, sy, 1)``)."""
    dt = x.dtype
    nb = x.ndim - 1
    limbs = jnp.asarray(shape.limbs, dt)
    frames = _segment_frames(jnp.asarray(shape.lengths, dt), x)
    sel = [frames[s] for s in CYLINDER_SEGMENT]
    scale = (_trail(limbs[:, 2], nb + 1), _trail(limbs[:, 3], nb + 1), None)
    A_cols = []
    for j in range(3):
        v = jnp.stack([f[0][j] for f in sel])  # (10, 3, *B)
        A_cols.append(v if scale[j] is None else v * scale[j])
    T = jnp.stack([f[1] for f in sel])
    A = [[A_cols[j][:, i] for j in range(3)] for i in range(3)]
    return A, [T[:, i] for i in range(3)]


def cylinder_poses(dims: BodyShape | Mapping[str, object] | None, x: jnp.ndarray) -> jnp.ndarray:
    """bodytrack's cylinder poses ``(10, 3, 4)`` ``[R·diag(sx, sy, 1) | t]`` (mm) for one state ``x (31,)``.

    ``dims``: the body shape as for :func:`parsec31`. Use ``jax.vmap`` for particles.
    """
    shape = shape_from_dims(dims)
    x = jnp.asarray(x)
    A, t = _cylinder_frames(shape, x)
    rows = [jnp.stack([A[i][0], A[i][1], A[i][2], t[i]], -1) for i in range(3)]
    return jnp.stack(rows, 1)


def _scaled_poses(shape: BodyShape, R: jnp.ndarray, t: jnp.ndarray) -> jnp.ndarray:
    """Cylinder poses from :func:`jaxmocap.geometry.body.segment_poses` of :func:`parsec31` (``R (14, 3, 3)``, ``t``)."""
    seg = np.asarray(CYLINDER_SEGMENT)
    limbs = jnp.asarray(shape.limbs, R.dtype)
    scale = jnp.stack([limbs[:, 2], limbs[:, 3], jnp.ones_like(limbs[:, 2])], -1)  # (10, 3)
    Rc = R[seg] * scale[:, None, :]
    return jnp.concatenate([Rc, t[seg][:, :, None]], -1)


# ---------------------------------------------------------------------------------------------------------------
# Cameras and projection (§6.3)


class Cameras(NamedTuple):
    """PARSEC / Bouguet cameras, ``V`` of them, millimetres (a pytree).

    ``fc (V, 2)``, ``cc (V, 2)`` pixels; ``alpha (V,)`` skew; ``kc (V, 5)`` distortion; ``R (V, 3, 3)``
    world→camera and ``T (V, 3)`` mm with ``X_c = R X + T``; ``eye (V, 3)`` the camera centre ``−Rᵀ T`` in mm.
    """

    fc: jnp.ndarray
    cc: jnp.ndarray
    alpha: jnp.ndarray
    kc: jnp.ndarray
    R: jnp.ndarray
    T: jnp.ndarray
    eye: jnp.ndarray

    @property
    def num_views(self) -> int:
        return int(np.shape(self.fc)[0])

    def astype(self, dtype) -> Cameras:
        return Cameras(*(jnp.asarray(a, dtype) for a in self))


def cameras_from_rig(rig, units: str = "m") -> Cameras:
    """:class:`Cameras` (mm) from a :class:`jaxmocap.geometry.camera.Rig` whose translations are in ``units`` ("m" or
    "mm"). The rig's OpenCV ``[k1, k2, p1, p2, k3]`` is Bouguet's ``kc`` in the same order."""
    if units not in ("m", "mm"):
        raise ValueError(f"units must be 'm' or 'mm', not {units!r}")
    K = np.asarray(rig.K, dtype=np.float64)
    R = np.asarray(rig.R, dtype=np.float64)
    T = np.asarray(rig.t, dtype=np.float64) * (MM_PER_M if units == "m" else 1.0)
    fc = np.stack([K[:, 0, 0], K[:, 1, 1]], -1)
    cc = np.stack([K[:, 0, 2], K[:, 1, 2]], -1)
    alpha = K[:, 0, 1] / K[:, 0, 0]
    eye = -np.einsum("vji,vj->vi", R, T)
    return Cameras(fc, cc, alpha, np.asarray(rig.dist, dtype=np.float64), R, T, eye)


def load_cameras(path: str | os.PathLike) -> Cameras:
    """The ``.cal`` cameras of a sequence folder, a ``CALIB`` folder or one ``.cal`` file, in mm (float64)."""
    from jaxmocap.geometry import camera

    return cameras_from_rig(camera.load_parsec_calibration(path, units="mm"), units="mm")


def project(cams: Cameras, X: jnp.ndarray) -> jnp.ndarray:
    """bodytrack's ``ProjectPoints`` (§6.3) of world points ``X (..., P, 3)`` mm → ``(..., V, P, 2)`` pixels.

    ``x = X_c.x / X_c.z``, ``y = X_c.y / X_c.z``, ``d = 1 + kc0 r² + kc1 r⁴ + kc4 r⁶``,
    ``xd = d x + kc2 (2xy) + kc2 (r² + 2x²)``, ``yd = d y + kc2 (r² + 2y²) + kc2 (2xy)`` (bodytrack uses ``kc[2]``
    for both tangential terms; PARSEC's cameras have ``kc2 = kc3 = 0``), ``u = fc.x (xd + α yd) + cc.x``,
    ``v = fc.y yd + cc.y``. Equals OpenCV's model with ``[k1, k2, p1, p2, k3]`` and skew where ``kc2 = kc3 = 0``.
    """
    X = jnp.asarray(X)
    dt = X.dtype
    c = cams.astype(dt)
    x, y, z = X[..., None, :, 0], X[..., None, :, 1], X[..., None, :, 2]
    u, v = _project_xyz(c, x, y, z)
    return jnp.stack([u, v], -1)


def _project_xyz(c: Cameras, x, y, z, nb: int = 1):
    """Per-coordinate projection; ``x, y, z`` broadcast against ``(V, *1)`` camera columns (``nb`` ones)."""
    _col = lambda a: _trail(a, nb)
    R, T = c.R, c.T
    xc = _col(R[:, 0, 0]) * x + _col(R[:, 0, 1]) * y + _col(R[:, 0, 2]) * z + _col(T[:, 0])
    yc = _col(R[:, 1, 0]) * x + _col(R[:, 1, 1]) * y + _col(R[:, 1, 2]) * z + _col(T[:, 1])
    zc = _col(R[:, 2, 0]) * x + _col(R[:, 2, 1]) * y + _col(R[:, 2, 2]) * z + _col(T[:, 2])
    inv_z = 1.0 / zc
    px = inv_z * xc
    py = inv_z * yc
    r2 = px * px + py * py
    r4 = r2 * r2
    k0, k1, k2, k4 = _col(c.kc[:, 0]), _col(c.kc[:, 1]), _col(c.kc[:, 2]), _col(c.kc[:, 4])
    d = 1.0 + k0 * r2 + k1 * r4 + k4 * (r4 * r2)
    a1 = 2.0 * px * py
    xd = d * px + k2 * a1 + k2 * (r2 + 2.0 * (px * px))
    yd = d * py + k2 * (r2 + 2.0 * (py * py)) + k2 * a1
    xd = xd + _col(c.alpha) * yd
    return _col(c.fc[:, 0]) * xd + _col(c.cc[:, 0]), _col(c.fc[:, 1]) * yd + _col(c.cc[:, 1])


def cylinder_corners(shape: BodyShape, cams: Cameras, poses: jnp.ndarray) -> jnp.ndarray:
    """Projected outline corners of every cylinder in every camera (§6.3): ``poses (10, 3, 4)`` → ``(V, 10, 4,
    2)`` pixels, corners in bodytrack's order P0..P3.

    In the cylinder's scaled local frame, ``r = (0, 0, len/2) − inv(pose)·eye`` and ``r2 = (−r.y, r.x, 0)/|r.xy|``;
    the corners ``P0 = −b r2``, ``P1 = −t r2 + (0, 0, len)``, ``P2 = t r2 + (0, 0, len)``, ``P3 = b r2`` (b, t the
    bottom and top radii) go through the pose and the camera. Written per coordinate over ``(V, 10)`` arrays.
    """
    A = [[poses[:, i, j] for j in range(3)] for i in range(3)]
    t = [poses[:, i, 3] for i in range(3)]
    return _corners(shape, cams, A, t)


def _corners(shape: BodyShape, cams: Cameras, A, t) -> jnp.ndarray:
    """:func:`cylinder_corners` from scaled frames ``A[i][j]``, ``t[i]`` of shape ``(10, *B)`` → ``(V, 10, 4, 2,
    *B)``. Every intermediate is a ``(V, 10, *B)`` array (batch axes last, so XLA vectorises over them)."""
    dt = t[0].dtype
    nb = t[0].ndim - 1
    c = cams.astype(dt)
    limbs = jnp.asarray(shape.limbs, dt)
    length = _trail(cylinder_lengths(shape).astype(dt), nb)
    bottom, top = _trail(limbs[:, 0], nb), _trail(limbs[:, 1], nb)
    sx, sy = _trail(limbs[:, 2], nb), _trail(limbs[:, 3], nb)
    cam = lambda a: _trail(a, nb + 1)  # (V,) → (V, 1, *1)
    # eye in the scaled local frame, inv([A | t])·eye = diag(1/sx, 1/sy, 1) Rᵀ (eye − t), Rᵀ's rows = A's
    # columns over the scales; only its x and y are needed
    e = [cam(c.eye[:, i]) - t[i][None] for i in range(3)]  # (V, 10, *B)
    ex = (A[0][0] * e[0] + A[1][0] * e[1] + A[2][0] * e[2]) / (sx * sx)
    ey = (A[0][1] * e[0] + A[1][1] * e[1] + A[2][1] * e[2]) / (sy * sy)
    inv = 1.0 / jnp.sqrt(ex * ex + ey * ey)
    r2x = ey * inv  # r2 = (−r.y, r.x)/|r| with r = (0, 0, len/2) − eye_local
    r2y = -ex * inv
    u = [A[i][0] * r2x + A[i][1] * r2y for i in range(3)]  # world offset of the local (r2x, r2y, 0)
    w = [A[i][2] * length for i in range(3)]  # world offset of the local (0, 0, len), (10, *B)
    corners = []
    for k, rad in enumerate((-bottom, -top, top, bottom)):
        P = [t[i] + rad * u[i] + (w[i] if k in (1, 2) else 0.0) for i in range(3)]
        corners.append(_project_xyz(c, *P, nb=nb + 1))
    return jnp.stack([jnp.stack(p, 2) for p in corners], 2)


# ---------------------------------------------------------------------------------------------------------------
# Text inputs


def _read_numbers(path: str | os.PathLike, what: str) -> tuple[list[float], list[int]]:
    """All whitespace-separated numbers of a text file with their 1-based line numbers."""
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            text = f.read()
    except OSError as e:
        raise MocapInputError(path, f"cannot read {what}: {e.strerror or e}") from None
    vals, lines = [], []
    for i, raw in enumerate(text.splitlines(), start=1):
        for tok in raw.split():
            try:
                v = float(tok)
            except ValueError:
                raise MocapInputError(path, f"{what}: {tok[:40]!r} is not a number", i) from None
            if not math.isfinite(v):
                raise MocapInputError(path, f"{what}: non-finite value {tok[:40]!r}", i)
            vals.append(v)
            lines.append(i)
    return vals, lines


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
# Images and preprocessing (§6.1)


def load_image(path: str | os.PathLike) -> np.ndarray:
    """An 8-bit grey image ``(H, W) uint8``, row 0 at the top (bodytrack flips bottom-up BMP rows the same way)."""
    import cv2

    p = os.fspath(path)
    if not os.path.isfile(p):
        raise MocapInputError(p, "image not found")
    im = cv2.imread(p, cv2.IMREAD_GRAYSCALE)
    if im is None:
        raise MocapInputError(p, "not a readable image")
    return im


def foreground_map(fg: np.ndarray) -> np.ndarray:
    """bodytrack's binary foreground map: pixel ≠ 0 → 1, else 0 (uint8; ``BinaryImage::ConvertToBinary``)."""
    return (np.asarray(fg) != 0).astype(np.uint8)


_BLUR = np.asarray(
    [
        0.12149085090552,
        0.14203719483447,
        0.15599734045770,
        0.16094922760463,
        0.15599734045770,
        0.14203719483447,
        0.12149085090552,
    ],
    dtype=np.float32,
)


def edge_map(gray: np.ndarray, threshold: float = 16.0) -> np.ndarray:
    """bodytrack's edge map (§6.1) of a grey image ``(H, W) uint8`` → ``(H, W) uint8``, bit for bit.

    1. ``gx``, ``gy``: Sobel / 8 in float32, summed in bodytrack's term order;
    2. ``B = 255`` where ``gx² + gy² ≥ threshold``, else 0, with a zero 1-pixel border;
    3. 7-tap blur along rows (x in [3, W−3)), truncated to uint8, then along columns (y in [3, H−3)), truncated
       again; the margins are zero. Float32 accumulation in kernel order, as the C++ does.
    """
    I = np.asarray(gray)
    if I.ndim != 2 or I.dtype != np.uint8:
        raise ValueError(f"edge_map expects a (H, W) uint8 image, got {I.shape} {I.dtype}")
    H, W = I.shape
    f = I.astype(np.float32)
    c8, c4 = np.float32(0.125), np.float32(0.25)
    up, mid, dn = f[:-2], f[1:-1], f[2:]
    ul, ur = up[:, :-2], up[:, 2:]
    ml, mr = mid[:, :-2], mid[:, 2:]
    dl, dr = dn[:, :-2], dn[:, 2:]
    gx = -c8 * ul + c8 * ur - c4 * ml + c4 * mr - c8 * dl + c8 * dr
    gy = -c8 * ul - c4 * up[:, 1:-1] - c8 * ur + c8 * dl + c4 * dn[:, 1:-1] + c8 * dr
    mag = gx * gx + gy * gy
    B = np.zeros((H, W), np.uint8)
    B[1:-1, 1:-1] = np.where(mag < np.float32(threshold), 0, 255).astype(np.uint8)
    n = len(_BLUR) // 2

    def row_pass(src):
        s = src.astype(np.float32)
        acc = np.zeros((src.shape[0], src.shape[1] - 2 * n), np.float32)
        for i in range(2 * n + 1):
            acc = acc + s[:, i : i + src.shape[1] - 2 * n] * _BLUR[i]
        out = np.zeros_like(src)
        out[:, n:-n] = acc.astype(np.uint8)  # C cast: truncation (acc is in [0, 255])
        return out

    tmp = row_pass(B)
    return np.ascontiguousarray(row_pass(tmp.T).T)


# ---------------------------------------------------------------------------------------------------------------
# Sequences


@dataclasses.dataclass
class ParsecSequence:
    """A bodytrack input folder (``load_sequence``).

    ``images``, ``foreground`` ``(F, V, H, W) uint8`` (camera images; foreground maps binarised to {0, 1});
    ``cameras`` (:class:`Cameras`, mm) and ``rig`` (:class:`jaxmocap.geometry.camera.Rig`, metres); ``shape``;
    ``initial_pose (31,)``; ``pose_parameters`` (std, min, max); ``frames``: the frame numbers read.
    """

    images: np.ndarray
    foreground: np.ndarray
    cameras: Cameras
    rig: object
    shape: BodyShape
    initial_pose: np.ndarray
    pose_parameters: PoseParameters
    frames: tuple[int, ...]

    @property
    def pose_std(self) -> np.ndarray:
        return self.pose_parameters.std

    def edge_maps(self, frame: int) -> np.ndarray:
        """bodytrack's edge maps ``(V, H, W) uint8`` of frame index ``frame`` (0-based into ``frames``)."""
        return np.stack([edge_map(im) for im in self.images[frame]])

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
    from jaxmocap.geometry import camera

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
    rig_mm = camera.load_parsec_calibration(cal_files, units="mm")
    rig = camera.load_parsec_calibration(cal_files, units="m")
    cams = cameras_from_rig(rig_mm, units="mm")
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
    images, fgs = [], []
    for fr in range(frames):
        ims, fs = [], []
        for k in range(num_cameras):
            name = f"image{fr:04d}.bmp"
            im = load_image(os.path.join(root, f"CAM{k + 1}", name))
            fg = load_image(os.path.join(root, f"FG{k + 1}", name))
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
            fs.append(foreground_map(fg))
        images.append(ims)
        fgs.append(fs)
    return ParsecSequence(
        images=np.asarray(images, dtype=np.uint8),
        foreground=np.asarray(fgs, dtype=np.uint8),
        cameras=cams,
        rig=rig,
        shape=load_body_shape(os.path.join(root, "BodyShapeParameters.txt")),
        initial_pose=load_pose(os.path.join(root, "InitialPose.txt")),
        pose_parameters=load_pose_parameters(os.path.join(root, "PoseParameters.txt")),
        frames=tuple(range(frames)),
    )


# ---------------------------------------------------------------------------------------------------------------
# Units


def to_metres(x: jnp.ndarray) -> jnp.ndarray:
    """A state (any leading shape, last axis 31) with the pelvis translation converted from mm to metres."""
    x = jnp.asarray(x)
    return x.at[..., 3:6].divide(MM_PER_M)


def from_metres(x: jnp.ndarray) -> jnp.ndarray:
    """Inverse of :func:`to_metres`."""
    x = jnp.asarray(x)
    return x.at[..., 3:6].multiply(MM_PER_M)


def joint_positions_metres(model: body.BodyModel, x: jnp.ndarray) -> jnp.ndarray:
    """Evaluation joints ``(J, 3)`` in metres for one state ``x (31,)`` (mm translation, as the model)."""
    return body.joint_positions(model, x) / MM_PER_M
