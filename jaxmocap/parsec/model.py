"""PARSEC bodytrack's body model, value for value.

PARSEC's ``bodytrack`` (Intel, Apache-2.0) tracks a walking person in 4 calibrated cameras with an annealed
particle filter over a 10-cylinder body driven by a 31-value state. This module reproduces its body exactly so
that likelihoods and filters written here can be compared with it and timed against it. Its neighbours: the input
files (:mod:`jaxmocap.parsec.files`), images and maps (:mod:`jaxmocap.parsec.images`), cameras
(:mod:`jaxmocap.parsec.cameras`), the fast cylinder chain (:mod:`jaxmocap.parsec.cylinders`) and the likelihood
(:mod:`jaxmocap.parsec.likelihood`). The documentation of the C++ code is ``jaxmocap/parsec/FORMAT.md``
(sections cited as §).

**Units.** PARSEC works in millimetres and so does everything here: the translation entries (3, 4, 5) of the
state, body lengths, camera translations and cylinder poses are in **mm**; angles are radians. The rest of the
project uses metres: :func:`to_metres` converts a state and :func:`joint_positions_metres` gives the evaluation
joints in metres; :func:`parsec31_in_metres` builds the whole body in metres.

**State** (31 values, PARSEC's order, §3 ``InitialPose.txt``): 0–2 pelvis Euler angles about x, y, z; 3–5 pelvis
translation; 6–8 left hip; 9 left knee; 10–12 right hip; 13 right knee; 14–15 left clavicle; 16–18 left shoulder;
19 left elbow; 20–21 right clavicle; 22–24 right shoulder; 25 right elbow; 26–27 thorax (y, z); 28–30 head.

**Kinematics** (§6.2). With ``E(θ, φ, τ) = Rz(τ) Rx(θ) Ry(φ)`` the pelvis is ``[E(a0, a1, a2) | (a3, a4, a5)]``
and every other joint multiplies its parent by a constant rotation, a translation and ``inv(E(...)) = Ry(−φ)
Rx(−θ) Rz(−τ)``: three revolute degrees of freedom about −y, −x, −z, in that order. :func:`parsec31` writes this
chain as a :class:`jaxmocap.geometry.body.BodyModel` (14 segments: the 10 cylinders plus the intermediate frames ``spine``,
``thorax`` and the two clavicles), so the generic filters and :func:`jaxmocap.geometry.body.segment_poses` run it
unchanged. The likelihood uses a specialised version of the same chain
(:func:`jaxmocap.parsec.cylinders.cylinder_poses`, tested equal).

**Cylinders.** Cylinder ``i`` (0 torso, 1 left thigh, 2 left shin, 3 right thigh, 4 right shin, 5 left upper arm,
6 left forearm, 7 right upper arm, 8 right forearm, 9 head) is the frame of its segment with the rotation columns
scaled by ``(limbs[i][2], limbs[i][3], 1)``; its axis is local +z from 0 to a signed length (negative for the
arms), with radius ``limbs[i][0]`` at 0 and ``limbs[i][1]`` at the far end
(:func:`jaxmocap.parsec.cylinders.cylinder_poses`).

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
from collections.abc import Mapping
from importlib import resources

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.geometry import body, kinematics
from jaxmocap.parsec.cameras import Cameras  # noqa: F401  (the tracking run reads it through this module)
from jaxmocap.parsec.files import (
    DOF_NAMES,
    LENGTH_NAMES,
    LIMB_FIELDS,
    MM_PER_M,
    NUM_DOFS,
    NUM_PARTS,
    PART_NAMES,
    BodyShape,
    load_body_shape,
    load_pose,  # noqa: F401  (the tracking run reads it through this module)
)

__all__ = [
    "CYLINDER_SEGMENT",
    "SEGMENT_NAMES",
    "cylinder_lengths",
    "default_shape",
    "from_metres",
    "joint_positions_metres",
    "parsec31",
    "parsec31_in_metres",
    "shape_from_dims",
    "shape_to_dims",
    "to_metres",
    "with_limits",
]

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
    SEGMENT_NAMES.index("pelvis" if p == "torso" else p) for p in PART_NAMES
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
    """A :class:`~jaxmocap.parsec.files.BodyShape` from a shape (returned as is), a mapping of named dimensions
    (missing names take the sequenceB values; unknown names raise ``ValueError``) or ``None`` (sequenceB)."""
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
    xp = _array_module(limbs, lengths)
    return BodyShape(
        xp.stack([xp.stack([xp.asarray(v) for v in row]) for row in limbs]),
        xp.stack([xp.asarray(v) for v in lengths]),
    )


def _array_module(*values):
    """``jax.numpy`` when any leaf of ``values`` is traced (gradients must flow), else ``numpy``: a concrete body
    is built on the host, not as one compiled one-operation program per ``jax.numpy`` call (about 30 of them,
    0.5–1 s of a run's start)."""
    return jnp if any(isinstance(v, jax.core.Tracer) for v in jax.tree.leaves(values)) else np


def cylinder_lengths(shape: BodyShape) -> jnp.ndarray:
    """Signed length (mm) of each cylinder along its local z: ``(10,)`` (negative for the four arm parts)."""
    L = jnp.asarray(shape.lengths)
    return jnp.stack([s * L[k] for k, s in _CYLINDER_LENGTH])


# ---------------------------------------------------------------------------------------------------------------
# The body model


def parsec31(dims: BodyShape | Mapping[str, object] | None = None, dtype=jnp.float32) -> body.BodyModel:
    """PARSEC bodytrack's body as a :class:`jaxmocap.geometry.body.BodyModel` (**millimetres**, 31 DOFs in PARSEC's order).

    ``dims``: a :class:`~jaxmocap.parsec.files.BodyShape` (from :func:`~jaxmocap.parsec.files.load_body_shape`), a
    mapping of named dimensions (see :func:`shape_from_dims`) or ``None`` for sequenceB's body. Gradients flow to
    the dimensions.

    The kinematic chain reproduces §6.2 exactly (see the module docstring): ``segment_poses(model, x)`` returns
    the unscaled chain matrices of bodytrack for the 14 segments. The flesh primitives are the 10 cylinders as
    circular truncated cones; the elliptic cross-section of the torso and the head (x/y scales) is kept only by
    :func:`~jaxmocap.parsec.cylinders.cylinder_poses`, the cone radius being the area-preserving ``r·sqrt(sx·sy)``.
    Joint limits are wide (±2π for angles, ±1e5 mm for the translation) because bodytrack applies none
    (``BodyPose::Valid`` returns true before its checks); :func:`with_limits` sets PoseParameters' bounds. The rest
    pose is every angle zero with the pelvis raised so that the longer leg's ankle is at z = 0: the body stands
    upright, left side towards +y, arms stretched horizontally towards −x (PARSEC's zero pose).
    """
    shape = shape_from_dims(dims)
    xp = _array_module(shape)  # numpy for a concrete body (one device transfer per field at the end)
    dtype = np.dtype(dtype)
    limbs = xp.asarray(shape.limbs, dtype)
    L = xp.asarray(shape.lengths, dtype)
    zero = xp.zeros((), dtype)

    def vec(*xs):
        return xp.stack([xp.asarray(v, dtype) for v in xs])

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
    cyl_len = [s * L[k] for k, s in _CYLINDER_LENGTH]  # cylinder_lengths
    kind = [body.SHAPE_NONE] * S
    starts = [vec(zero, zero, zero)] * S
    ends = [vec(zero, zero, zero)] * S
    r0 = [zero] * S
    r1 = [zero] * S
    for i, s in enumerate(CYLINDER_SEGMENT):
        k = xp.sqrt(limbs[i, 2] * limbs[i, 3])
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
    standing = xp.maximum(L[2] + L[3], L[6] + L[7])
    rest = xp.concatenate([xp.zeros(5, dtype), xp.reshape(standing, (1,)), xp.zeros(NUM_DOFS - 6, dtype)])
    # numpy fields go to the device by a transfer (jnp.asarray of a numpy array compiles a program per shape)
    put = jax.device_put if xp is np else jnp.asarray
    return body.BodyModel(
        rest_rotation=put(np.stack([s[2] for s in _SEGMENTS]).astype(dtype)),
        offset=put(xp.stack(offsets)),
        dof_axis=put(np.asarray(dof_axis, dtype=np.float64).astype(dtype)),
        lower=put(lower.astype(dtype)),
        upper=put(upper.astype(dtype)),
        rest_pose=put(rest),
        joint_point=put(xp.stack([joints[n][1] for n in names])),
        shape_start=put(xp.stack(starts)),
        shape_end=put(xp.stack(ends)),
        radius_start=put(xp.stack(r0)),
        radius_end=put(xp.stack(r1)),
        name="parsec31",
        topology=topology,
        joint_names=names,
        joint_segment=tuple(joints[n][0] for n in names),
        shape_kind=tuple(kind),
    )


def with_limits(model: body.BodyModel, lower, upper) -> body.BodyModel:
    """The model with joint limits ``lower, upper (31,)`` (e.g. PoseParameters' min and max, which bodytrack
    itself never applies)."""
    dt = model.lower.dtype
    return dataclasses.replace(model, lower=jnp.asarray(lower, dt), upper=jnp.asarray(upper, dt))


def parsec31_in_metres(dims: BodyShape | Mapping[str, object] | None = None) -> body.BodyModel:
    """:func:`parsec31` in **metres** (float32): PARSEC's shape (``dims`` as for :func:`shape_from_dims`) with
    radii and lengths divided by :data:`MM_PER_M`, the x/y scales kept, so that the body shares the calibration and
    cues of the other models. The state's pelvis translation is then in metres too (:func:`to_metres`)."""
    shape = shape_from_dims(dims or None)  # no dimensions given: sequenceB's, as for None
    limbs = np.asarray(shape.limbs, np.float64).copy()
    limbs[:, :2] /= MM_PER_M
    shape = BodyShape(limbs.astype(np.float32), (np.asarray(shape.lengths) / MM_PER_M).astype(np.float32))
    return parsec31(shape)


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
