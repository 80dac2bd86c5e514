"""Articulated body models: kinematic tree, named degrees of freedom, joint limits, flesh primitives.

Conventions (DESIGN.md): metres and radians, world right-handed with **z up**. At the zero state every preset
stands upright facing **+x** with its left side towards **+y**, arms hanging along the body. The state vector is
root translation, root orientation, then joint angles, in the order of ``model.dof_names``.

Body dimensions (limb lengths, radii) come from a small TOML body file so a subject can be fitted:

.. code-block:: toml

    model = "full25"
    [dimensions]          # metres; a key may be prefixed with left_ / right_ to break symmetry
    torso_length = 0.50
    upper_arm_length = 0.29

A model is built from its dimensions on the host (NumPy, then one copy of each array to the device) or, when a
dimension is a tracer, with ``jax.numpy``, so gradients flow to limb lengths and radii
(``jax.grad(lambda d: loss(full25(d)))``).

Presets:

* ``upper9``  — López Méndez (2009) Table 6.1: base-of-neck position (3), body orientation θ0 (1), neck y,
  shoulders x/y/z, elbows y: the 13-D state of eq. 6.1.
* ``upper14`` — Fontmarty et al. (IROS 2007): 6 global DOF, 3 per shoulder, 1 per elbow; head rigid with the torso.
* ``full25``  — Li & Kulić: root translation 3, root rotation 3, neck 3, shoulders 3+3, elbows 1+1, hips 3+3,
  knees 1+1; every angle limited.
* ``full32``  — ``full25`` with a 3-DOF spine joint halfway up the torso and a 2-DOF shoulder girdle per side
  (:func:`full32`).
* ``parsec31`` — PARSEC bodytrack's 10-cylinder body, in millimetres; the PARSEC wing (subpackage ``parsec``)
  registers it with :func:`register_preset` when it is imported.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Mapping
from importlib import resources
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError, load_toml
from jaxmocap.geometry import kinematics
from jaxmocap.transfer import is_traced, to_device

#: The 15 evaluation joints of Li & Kulić, in the order every output of the project uses.
EVAL_JOINTS: tuple[str, ...] = (
    "root",
    "thorax",
    "head",
    "left_shoulder",
    "left_elbow",
    "left_wrist",
    "right_shoulder",
    "right_elbow",
    "right_wrist",
    "left_hip",
    "left_knee",
    "left_ankle",
    "right_hip",
    "right_knee",
    "right_ankle",
)

SHAPE_NONE, SHAPE_CONE, SHAPE_ELLIPSOID = "none", "cone", "ellipsoid"


@dataclasses.dataclass(frozen=True)
class BodyModel:
    """A body model: a pytree whose leaves are arrays and whose topology is static.

    Array fields (``S`` segments, ``D`` DOFs, ``J`` evaluation joints):
      rest_rotation ``(S, 3, 3)``, offset ``(S, 3)``: joint frame of each segment in its parent's frame at zero state;
      dof_axis ``(D, 3)``: unit axes in the joint frames;
      lower, upper, rest_pose ``(D,)``: joint limits and the rest (initial / IK prior) state;
      joint_point ``(J, 3)``: evaluation joints in their segment frames;
      shape_start, shape_end ``(S, 3)``, radius_start, radius_end ``(S,)``: the flesh primitive of each segment in its
      frame — a truncated cone between the two points, or an ellipsoid whose axis runs between them with equatorial
      radius ``radius_start``.

    Static fields: name, topology (:class:`jaxmocap.geometry.kinematics.Topology`), joint_names (subset of
    :data:`EVAL_JOINTS`, in that order), joint_segment, shape_kind (per segment).
    """

    rest_rotation: jnp.ndarray
    offset: jnp.ndarray
    dof_axis: jnp.ndarray
    lower: jnp.ndarray
    upper: jnp.ndarray
    rest_pose: jnp.ndarray
    joint_point: jnp.ndarray
    shape_start: jnp.ndarray
    shape_end: jnp.ndarray
    radius_start: jnp.ndarray
    radius_end: jnp.ndarray
    name: str = dataclasses.field(metadata=dict(static=True), default="")
    topology: kinematics.Topology | None = dataclasses.field(metadata=dict(static=True), default=None)
    joint_names: tuple[str, ...] = dataclasses.field(metadata=dict(static=True), default=())
    joint_segment: tuple[int, ...] = dataclasses.field(metadata=dict(static=True), default=())
    shape_kind: tuple[str, ...] = dataclasses.field(metadata=dict(static=True), default=())

    @property
    def dof_names(self) -> tuple[str, ...]:
        return self.topology.dof_names

    @property
    def num_dofs(self) -> int:
        return self.topology.num_dofs

    @property
    def segment_names(self) -> tuple[str, ...]:
        return self.topology.segment_names

    @property
    def angular(self) -> np.ndarray:
        """``(D,)`` bool: which state entries are angles (revolute)."""
        return np.asarray([k == "R" for k in self.topology.dof_kinds])

    def dof_index(self, name: str) -> int:
        return self.topology.dof_names.index(name)


jax.tree_util.register_dataclass(
    BodyModel,
    data_fields=[
        "rest_rotation",
        "offset",
        "dof_axis",
        "lower",
        "upper",
        "rest_pose",
        "joint_point",
        "shape_start",
        "shape_end",
        "radius_start",
        "radius_end",
    ],
    meta_fields=["name", "topology", "joint_names", "joint_segment", "shape_kind"],
)


# ---------------------------------------------------------------------------------------------------------------
# Evaluation of a model


def segment_poses(model: BodyModel, x: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """World transforms of all segments for one state ``x (D,)``: ``R (S, 3, 3)``, ``t (S, 3)``. vmap for particles."""
    return kinematics.segment_poses(model.topology, model.rest_rotation, model.offset, model.dof_axis, x)


def joint_positions(model: BodyModel, x: jnp.ndarray) -> jnp.ndarray:
    """World positions ``(J, 3)`` of the model's evaluation joints (``model.joint_names``) for one state."""
    R, t = segment_poses(model, x)
    return kinematics.transform_points(R, t, model.joint_point, model.joint_segment)


def clip_to_limits(model: BodyModel, x: jnp.ndarray) -> jnp.ndarray:
    """Clamp a state (any leading shape) to the joint limits."""
    return jnp.clip(x, model.lower, model.upper)


def within_limits(model: BodyModel, x: jnp.ndarray) -> jnp.ndarray:
    """``(...)`` bool: all entries inside the limits."""
    return jnp.all((x >= model.lower) & (x <= model.upper), axis=-1)


def trunk_segments(model: BodyModel) -> tuple[int, ...]:
    """The segments of the trunk: the root and every segment on the way from the root to a branching segment (one
    with two or more children), in segment order. ``full25``: the torso alone; ``full32``: torso and chest (the
    chest carries the head and both girdles); ``parsec31``: pelvis, spine and thorax. What hangs from the trunk —
    head, arms with their girdles, legs — are the body's branches (:func:`jaxmocap.filters.factory.partition_groups`)."""
    parents = model.topology.parents
    children = [0] * len(parents)
    for p in parents:
        if p >= 0:
            children[p] += 1
    trunk = set()
    for s, n in enumerate(children):
        if n >= 2 or parents[s] < 0:
            while s >= 0 and s not in trunk:
                trunk.add(s)
                s = parents[s]
    return tuple(sorted(trunk))


# ---------------------------------------------------------------------------------------------------------------
# Building presets from dimensions

_DEG = math.pi / 180.0
_BIG = 100.0  # metres / radians treated as "unlimited" for root translation
_NECK_HEIGHT = 1.45  # rest height of the base of the neck for the upper-body presets (standing adult)

#: Dimensions that are signed offsets (e.g. CMU shoulders sit above the base of the neck: a negative drop).
SIGNED_DIMENSION_SUFFIX = "_drop"

DEFAULT_DIMENSIONS: dict[str, float] = {
    "torso_length": 0.50,  # pelvis centre to base of neck
    "torso_radius_bottom": 0.13,
    "torso_radius_top": 0.15,
    "shoulder_width": 0.36,  # between the shoulder joints
    "shoulder_drop": 0.03,  # shoulder joints below the base of the neck
    "neck_length": 0.08,
    "head_length": 0.23,
    "head_radius": 0.09,
    "hip_width": 0.18,  # between the hip joints
    "hip_drop": 0.06,  # hip joints below the pelvis centre
    "upper_arm_length": 0.29,
    "upper_arm_radius_top": 0.05,
    "upper_arm_radius_bottom": 0.04,
    "forearm_length": 0.26,  # elbow to wrist
    "forearm_radius_top": 0.04,
    "forearm_radius_bottom": 0.03,
    "thigh_length": 0.43,
    "thigh_radius_top": 0.08,
    "thigh_radius_bottom": 0.06,
    "shin_length": 0.43,
    "shin_radius_top": 0.055,
    "shin_radius_bottom": 0.04,
}


def _dim(dims: Mapping[str, object], key: str, side: str = ""):
    """Look up ``side_key`` (``left_``/``right_``) then ``key`` in ``dims``, then the defaults: a tracer as it is,
    any other value as a NumPy scalar of JAX's default float (float32 unless ``jax_enable_x64``), so that a model
    built from concrete dimensions is computed on the host with the arithmetic ``jax.numpy`` would do."""
    if side and f"{side}_{key}" in dims:
        v = dims[f"{side}_{key}"]
    elif key in dims:
        v = dims[key]
    else:
        v = DEFAULT_DIMENSIONS[key]
    return v if is_traced(v) else np.asarray(v, jax.dtypes.canonicalize_dtype(np.float64))


def _stack(values, dtype):
    """``values`` stacked along a new first axis as ``dtype``: with ``jax.numpy`` when one of them is traced,
    else with NumPy (host arithmetic, no program staged; :mod:`jaxmocap.transfer`)."""
    if any(is_traced(v) for v in values):
        return jnp.stack([jnp.asarray(v, dtype) for v in values])
    return np.stack([np.asarray(v, dtype) for v in values])


class _Dof(NamedTuple):
    """One state entry of a model being built: name, kind (``"R"``/``"P"``), axis, limits, rest value."""

    name: str
    kind: str
    axis: np.ndarray
    lower: object
    upper: object
    rest: object


class _Segment(NamedTuple):
    """One segment of a model being built: name, parent index (−1: root), its DOF indices, offset, flesh shape
    ``(kind, start, end, radius_start, radius_end)``."""

    name: str
    parent: int
    dofs: tuple[int, ...]
    offset: jnp.ndarray
    shape: tuple


@dataclasses.dataclass
class _Builder:
    """Accumulates segments and DOFs. Values stay NumPy unless a dimension is traced (then ``jax.numpy``, so that
    gradients flow to the dimensions); :meth:`build` puts the model's arrays on the device."""

    dtype: object = jnp.float32
    segments: list[_Segment] = dataclasses.field(default_factory=list)
    dofs: list[_Dof] = dataclasses.field(default_factory=list)
    joints: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        self.dtype = jax.dtypes.canonicalize_dtype(self.dtype)

    def vec(self, *xs):
        return _stack(xs, self.dtype)

    def _index(self, segment: str) -> int:
        return [g.name for g in self.segments].index(segment)

    def segment(self, name, parent, offset, dofs=(), shape=(SHAPE_NONE, None, None, 0.0, 0.0)):
        """dofs: sequence of (dof name, kind, axis, lower, upper[, rest])."""
        first = len(self.dofs)
        for d in dofs:
            name_d, kind, axis, lo, hi = d[:5]
            rest = d[5] if len(d) > 5 else 0.0
            self.dofs.append(_Dof(name_d, kind, np.asarray(axis, dtype=np.float64), lo, hi, rest))
        parent_index = -1 if parent is None else self._index(parent)
        self.segments.append(_Segment(name, parent_index, tuple(range(first, len(self.dofs))), offset, shape))
        return len(self.segments) - 1

    def joint(self, name, segment, point):
        self.joints[name] = (self._index(segment), point)

    def build(self, model_name: str) -> BodyModel:
        segs, dofs = self.segments, self.dofs
        S = len(segs)
        topology = kinematics.Topology(
            segment_names=tuple(g.name for g in segs),
            parents=tuple(g.parent for g in segs),
            segment_dofs=tuple(g.dofs for g in segs),
            dof_names=tuple(d.name for d in dofs),
            dof_kinds=tuple(d.kind for d in dofs),
            rest_rotated=(False,) * S,
        )
        zero = self.vec(0.0, 0.0, 0.0)
        names = tuple(j for j in EVAL_JOINTS if j in self.joints)
        kinds, starts, ends, r0, r1 = [], [], [], [], []
        for kind, a, b, ra, rb in (g.shape for g in segs):
            kinds.append(kind)
            starts.append(zero if a is None else a)
            ends.append(zero if b is None else b)
            r0.append(ra)
            r1.append(rb)
        dt = self.dtype
        arrays = {
            "rest_rotation": np.broadcast_to(np.eye(3, dtype=dt), (S, 3, 3)),
            "offset": _stack([g.offset for g in segs], dt),
            "dof_axis": np.stack([d.axis for d in dofs]).astype(dt),
            "lower": _stack([d.lower for d in dofs], dt),
            "upper": _stack([d.upper for d in dofs], dt),
            "rest_pose": _stack([d.rest for d in dofs], dt),
            "joint_point": _stack([self.joints[n][1] for n in names], dt),
            "shape_start": _stack(starts, dt),
            "shape_end": _stack(ends, dt),
            "radius_start": _stack(r0, dt),
            "radius_end": _stack(r1, dt),
        }
        return BodyModel(
            **{k: to_device(v, dt) for k, v in arrays.items()},
            name=model_name,
            topology=topology,
            joint_names=names,
            joint_segment=tuple(self.joints[n][0] for n in names),
            shape_kind=tuple(kinds),
        )


X, Y, Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
NEG_Y = (0.0, -1.0, 0.0)


def _translation_dofs(prefix: str, height=0.0):
    """Prismatic x, y, z DOFs; the rest value of z is ``height`` (the root's height when standing)."""
    rest = (0.0, 0.0, height)
    return [
        (f"{prefix}_t{a}", "P", ax, -_BIG, _BIG, r) for a, ax, r in zip("xyz", (X, Y, Z), rest, strict=True)
    ]


def _ball_dofs(prefix: str, rx, ry, rz) -> list:
    """Three revolute DOFs ``{prefix}_rx, _ry, _rz`` about x, y, z with limits ``(lower, upper)`` each."""
    return [
        (f"{prefix}_r{a}", "R", axis, *lim)
        for a, axis, lim in zip("xyz", (X, Y, Z), (rx, ry, rz), strict=True)
    ]


def _limb(b: _Builder, dims, side: str, parent: str, attach, parts, dofs, joint_names):
    """Two cones hanging along −z: ``{side}_{parts[0]}`` at ``attach`` in ``parent`` with ``dofs[0]`` and
    ``{side}_{parts[1]}`` at its far end with ``dofs[1]``; their lengths and radii are the ``{part}_length``,
    ``{part}_radius_top`` and ``{part}_radius_bottom`` dimensions. Joints ``{side}_{joint_names[k]}`` at the
    origins of the two segments and at the far end of the second."""
    upper, lower = parts
    L1 = _dim(dims, f"{upper}_length", side)
    L2 = _dim(dims, f"{lower}_length", side)
    segments = ((upper, parent, attach, L1), (lower, f"{side}_{upper}", b.vec(0.0, 0.0, -L1), L2))
    for (part, par, at, L), seg_dofs in zip(segments, dofs, strict=True):
        cone = (
            SHAPE_CONE,
            b.vec(0.0, 0.0, 0.0),
            b.vec(0.0, 0.0, -L),
            _dim(dims, f"{part}_radius_top", side),
            _dim(dims, f"{part}_radius_bottom", side),
        )
        b.segment(f"{side}_{part}", par, at, seg_dofs, cone)
    ends = ((upper, 0.0), (lower, 0.0), (lower, -L2))
    for name, (part, z) in zip(joint_names, ends, strict=True):
        b.joint(f"{side}_{name}", f"{side}_{part}", b.vec(0.0, 0.0, z))


def _arm(b: _Builder, dims, side: str, parent: str, shoulder_point, shoulder_dofs: bool = True):
    """Upper arm (shoulder x, y, z) and forearm (elbow about −y: positive flexion brings the hand forward)."""
    s = 1.0 if side == "left" else -1.0
    # abduction about +x lifts the left arm towards +y; the right arm mirrors it.
    abd = (-30 * _DEG, 170 * _DEG) if s > 0 else (-170 * _DEG, 30 * _DEG)
    dofs = _ball_dofs(f"{side}_shoulder", abd, (-170 * _DEG, 60 * _DEG), (-90 * _DEG, 90 * _DEG))
    elbow = [(f"{side}_elbow", "R", NEG_Y, 0.0, 150 * _DEG)]
    parts, joints = ("upper_arm", "forearm"), ("shoulder", "elbow", "wrist")
    _limb(b, dims, side, parent, shoulder_point, parts, (dofs if shoulder_dofs else (), elbow), joints)


def _leg(b: _Builder, dims, side: str, parent: str, hip_point):
    """Thigh (hip x, y, z) and shin (knee about +y: positive flexion moves the foot backwards)."""
    s = 1.0 if side == "left" else -1.0
    abd = (-30 * _DEG, 70 * _DEG) if s > 0 else (-70 * _DEG, 30 * _DEG)
    hip = _ball_dofs(f"{side}_hip", abd, (-120 * _DEG, 30 * _DEG), (-60 * _DEG, 60 * _DEG))
    knee = [(f"{side}_knee", "R", Y, 0.0, 150 * _DEG)]
    _limb(b, dims, side, parent, hip_point, ("thigh", "shin"), (hip, knee), ("hip", "knee", "ankle"))


def _torso(b: _Builder, dims, root_dofs, bottom, top):
    """The root segment ``torso`` at the origin: a cone along z from height ``bottom`` to ``top``."""
    cone = (
        SHAPE_CONE,
        b.vec(0.0, 0.0, bottom),
        b.vec(0.0, 0.0, top),
        _dim(dims, "torso_radius_bottom"),
        _dim(dims, "torso_radius_top"),
    )
    b.segment("torso", None, b.vec(0.0, 0.0, 0.0), root_dofs, cone)


def _head_shape(b: _Builder, dims):
    n, h, r = _dim(dims, "neck_length"), _dim(dims, "head_length"), _dim(dims, "head_radius")
    return (SHAPE_ELLIPSOID, b.vec(0.0, 0.0, n), b.vec(0.0, 0.0, n + h), r, r), b.vec(0.0, 0.0, n + 0.5 * h)


def _full_root_dofs(dims) -> list:
    """Root translation (its rest height: the pelvis centre of a person standing) and rotation ``Rz·Ry·Rx``."""
    standing = _dim(dims, "hip_drop") + _dim(dims, "thigh_length") + _dim(dims, "shin_length")
    return _translation_dofs("root", standing) + [
        ("root_rz", "R", Z, -2 * math.pi, 2 * math.pi),
        ("root_ry", "R", Y, -90 * _DEG, 90 * _DEG),
        ("root_rx", "R", X, -90 * _DEG, 90 * _DEG),
    ]


def _neck_dofs() -> list:
    return [
        ("neck_rx", "R", X, -40 * _DEG, 40 * _DEG),
        ("neck_ry", "R", Y, -50 * _DEG, 60 * _DEG),
        ("neck_rz", "R", Z, -70 * _DEG, 70 * _DEG),
    ]


def _legs(b: _Builder, dims) -> None:
    hw, hd = 0.5 * _dim(dims, "hip_width"), _dim(dims, "hip_drop")
    for side, s in (("left", 1.0), ("right", -1.0)):
        _leg(b, dims, side, "torso", b.vec(0.0, s * hw, -hd))


def full25(dims: Mapping[str, object] | None = None, dtype=jnp.float32) -> BodyModel:
    """Li & Kulić's 25-DOF full body. Root at the pelvis centre; rotation ``Rz·Ry·Rx`` (yaw, pitch, roll)."""
    dims = dims or {}
    b = _Builder(dtype=dtype)
    T = _dim(dims, "torso_length")
    _torso(b, dims, _full_root_dofs(dims), 0.0, T)
    head_shape, head_centre = _head_shape(b, dims)
    b.segment("head", "torso", b.vec(0.0, 0.0, T), _neck_dofs(), head_shape)
    b.joint("root", "torso", b.vec(0.0, 0.0, 0.0))
    b.joint("thorax", "torso", b.vec(0.0, 0.0, T))
    b.joint("head", "head", head_centre)
    sw, sd = 0.5 * _dim(dims, "shoulder_width"), _dim(dims, "shoulder_drop")
    for side, s in (("left", 1.0), ("right", -1.0)):
        _arm(b, dims, side, "torso", b.vec(0.0, s * sw, T - sd))
    _legs(b, dims)
    return b.build("full25")


#: Height of ``full32``'s spine joint above the pelvis centre, as a fraction of the torso length.
SPINE_HEIGHT = 0.5


def full32(dims: Mapping[str, object] | None = None, dtype=jnp.float32) -> BodyModel:
    """``full25`` with a torso that bends and shoulders that shrug: 32 DOFs.

    The torso of ``full25`` split at :data:`SPINE_HEIGHT` of its length into the pelvis part (``torso``, the root)
    and ``chest``, joined by a spine joint of 3 DOFs (``spine_rx`` lateral bend ±30°, ``spine_ry`` flexion −30°…45°,
    ``spine_rz`` twist ±30°), and a shoulder girdle per side: a ``{side}_clavicle`` segment at the base of the neck
    (no flesh) with elevation ``{side}_clavicle_rx`` and protraction ``{side}_clavicle_rz`` (±20° each) that
    carries the arm. The same dimensions and joints as ``full25``; at zero spine and girdle angles the joints and
    the flesh are ``full25``'s (the torso cone cut in two at the same radii). State order: root 6, spine 3, neck 3,
    left girdle 2, left arm 4, right girdle 2, right arm 4, left leg 4, right leg 4.

    What it is for: a real person's neck keypoint and shoulders move with the shoulder girdle and the thoracic spine,
    which ``full25``'s rigid torso cannot follow (``benchmarks/results/pose2sim_loo.md``).
    """
    dims = dims or {}
    b = _Builder(dtype=dtype)
    T = _dim(dims, "torso_length")
    L = SPINE_HEIGHT * T
    r0, r1 = _dim(dims, "torso_radius_bottom"), _dim(dims, "torso_radius_top")
    r_mid = r0 + SPINE_HEIGHT * (r1 - r0)
    b.segment(
        "torso",
        None,
        b.vec(0.0, 0.0, 0.0),
        _full_root_dofs(dims),
        (SHAPE_CONE, b.vec(0.0, 0.0, 0.0), b.vec(0.0, 0.0, L), r0, r_mid),
    )
    spine = [
        ("spine_rx", "R", X, -30 * _DEG, 30 * _DEG),
        ("spine_ry", "R", Y, -30 * _DEG, 45 * _DEG),
        ("spine_rz", "R", Z, -30 * _DEG, 30 * _DEG),
    ]
    b.segment(
        "chest",
        "torso",
        b.vec(0.0, 0.0, L),
        spine,
        (SHAPE_CONE, b.vec(0.0, 0.0, 0.0), b.vec(0.0, 0.0, T - L), r_mid, r1),
    )
    head_shape, head_centre = _head_shape(b, dims)
    b.segment("head", "chest", b.vec(0.0, 0.0, T - L), _neck_dofs(), head_shape)
    b.joint("root", "torso", b.vec(0.0, 0.0, 0.0))
    b.joint("thorax", "chest", b.vec(0.0, 0.0, T - L))
    b.joint("head", "head", head_centre)
    sw, sd = 0.5 * _dim(dims, "shoulder_width"), _dim(dims, "shoulder_drop")
    for side, s in (("left", 1.0), ("right", -1.0)):
        girdle = [
            (f"{side}_clavicle_rx", "R", X, -20 * _DEG, 20 * _DEG),
            (f"{side}_clavicle_rz", "R", Z, -20 * _DEG, 20 * _DEG),
        ]
        b.segment(f"{side}_clavicle", "chest", b.vec(0.0, 0.0, T - L), girdle)
        _arm(b, dims, side, f"{side}_clavicle", b.vec(0.0, s * sw, -sd))
    _legs(b, dims)
    return b.build("full32")


def _upper(dims, dtype, model_name: str, root_dofs, neck_dofs) -> BodyModel:
    """Upper body with its root at the base of the neck and the torso hanging below it."""
    dims = dims or {}
    b = _Builder(dtype=dtype)
    T = _dim(dims, "torso_length")
    _torso(b, dims, root_dofs, -T, 0.0)
    head_shape, head_centre = _head_shape(b, dims)
    b.segment("head", "torso", b.vec(0.0, 0.0, 0.0), neck_dofs, head_shape)
    b.joint("root", "torso", b.vec(0.0, 0.0, -T))
    b.joint("thorax", "torso", b.vec(0.0, 0.0, 0.0))
    b.joint("head", "head", head_centre)
    sw, sd = 0.5 * _dim(dims, "shoulder_width"), _dim(dims, "shoulder_drop")
    for side, s in (("left", 1.0), ("right", -1.0)):
        _arm(b, dims, side, "torso", b.vec(0.0, s * sw, -sd))
    return b.build(model_name)


def upper9(dims: Mapping[str, object] | None = None, dtype=jnp.float32) -> BodyModel:
    """The thesis' upper body (Table 6.1, eq. 6.1): 13-D state ``(x0, y0, z0, θ0, neck_y, shoulders, elbows)``."""
    root = _translation_dofs("neck_base", _NECK_HEIGHT) + [("body_rz", "R", Z, -2 * math.pi, 2 * math.pi)]
    neck = [("neck_ry", "R", Y, -50 * _DEG, 60 * _DEG)]
    return _upper(dims, dtype, "upper9", root, neck)


def upper14(dims: Mapping[str, object] | None = None, dtype=jnp.float32) -> BodyModel:
    """Fontmarty et al.'s 14 DOF: 6 global (translation, ``Rz·Ry·Rx``), 3 per shoulder, 1 per elbow; rigid head."""
    root = _translation_dofs("root", _NECK_HEIGHT) + [
        ("root_rz", "R", Z, -2 * math.pi, 2 * math.pi),
        ("root_ry", "R", Y, -90 * _DEG, 90 * _DEG),
        ("root_rx", "R", X, -90 * _DEG, 90 * _DEG),
    ]
    return _upper(dims, dtype, "upper14", root, ())


#: The built-in presets (metres): name → ``builder(dims, dtype=...)``.
PRESETS = {"upper9": upper9, "upper14": upper14, "full25": full25, "full32": full32}

#: Presets that a wing of the package registers when it is imported: name → the wing's subpackage.
WING_PRESETS = {"parsec31": "parsec"}


class _Registered(NamedTuple):
    builder: Callable[..., BodyModel]
    metric_builder: Callable[..., BodyModel] | None


_REGISTERED: dict[str, _Registered] = {}


def register_preset(
    name: str, builder: Callable[..., BodyModel], metric_builder: Callable[..., BodyModel] | None = None
) -> None:
    """Make ``name`` buildable by :func:`build`.

    ``builder(dims, dtype=...)`` builds the model in the preset's native units; ``metric_builder(dims)`` builds it
    in metres (what the tracker works in); without one the native units are metres. Registering a name again
    replaces it; a built-in preset cannot be replaced.
    """
    if name in PRESETS:
        raise ValueError(f"{name!r} is a built-in body model")
    _REGISTERED[name] = _Registered(builder, metric_builder)


def preset_names() -> tuple[str, ...]:
    """The names :func:`build` accepts now: the built-in presets, then the registered ones."""
    return (*PRESETS, *_REGISTERED)


def build(
    name: str, dims: Mapping[str, object] | None = None, dtype=jnp.float32, in_metres: bool = False
) -> BodyModel:
    """Build a preset by name: a built-in one (``upper9``, ``upper14``, ``full25``, ``full32``; metres) or one registered with
    :func:`register_preset` (``parsec31`` once the PARSEC wing is imported; millimetres unless ``in_metres``).

    ``in_metres``: the model in metres (the registered metric builder, which takes no ``dtype``); the built-in
    presets are in metres already.
    """
    if name in PRESETS:
        return PRESETS[name](dims, dtype=dtype)
    if name in _REGISTERED:
        entry = _REGISTERED[name]
        if in_metres and entry.metric_builder is not None:
            return entry.metric_builder(dims)
        return entry.builder(dims, dtype=dtype)
    msg = f"unknown body model {name!r}; choose one of {sorted(preset_names())}"
    if name in WING_PRESETS:
        wing = WING_PRESETS[name]
        msg += f" ({name!r} comes with the {wing} wing: import jaxmocap.{wing} first)"
    raise ValueError(msg)


# ---------------------------------------------------------------------------------------------------------------
# Body files


def load_body_file(path: str | os.PathLike) -> tuple[str, dict[str, float]]:
    """Read a body file: returns ``(model name, dimensions)``. Raises :class:`MocapInputError` on bad content."""
    data = load_toml(path, "body file")
    name = data.get("model")
    if not isinstance(name, str):
        raise MocapInputError(path, "body file needs a string 'model = \"...\"'")
    dims = data.get("dimensions", {})
    if not isinstance(dims, dict):
        raise MocapInputError(path, "[dimensions] must be a table")
    out = {}
    for k, v in dims.items():
        if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
            raise MocapInputError(path, f"dimension {k!r} must be a finite number, got {v!r}")
        if v < 0 and not k.endswith(SIGNED_DIMENSION_SUFFIX):
            raise MocapInputError(path, f"dimension {k!r} must be non-negative, got {v!r}")
        out[k] = float(v)
    return name, out


def load_body(path: str | os.PathLike, dtype=jnp.float32) -> BodyModel:
    """Build the model a body file names with its dimensions."""
    name, dims = load_body_file(path)
    try:
        return build(name, dims, dtype=dtype)
    except (ValueError, KeyError) as e:
        raise MocapInputError(path, str(e)) from None


def save_body(path: str | os.PathLike, model_name: str, dims: Mapping[str, float]) -> None:
    """Write a body file (see the module docstring for its layout)."""
    import tomli_w

    with open(path, "wb") as f:
        tomli_w.dump({"model": model_name, "dimensions": {k: float(v) for k, v in dims.items()}}, f)


def default_body_path(name: str) -> str:
    """Path of the body file shipped with the package for a preset (default dimensions)."""
    return str(resources.files("jaxmocap") / "data" / "bodies" / f"{name}.toml")
