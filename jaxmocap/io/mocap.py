"""The common result of the motion-capture loaders, its forward kinematics, and the map to the evaluation joints.

Every loader (:mod:`jaxmocap.io.bvh`, :mod:`jaxmocap.io.asfamc`) returns a :class:`Motion`: a kinematic tree
whose joints carry one rotation per frame, in metres, with the world **z up** (right-handed).

Forward kinematics (the BVH convention, which ASF/AMC also reduces to once its bone frames are folded in):

.. math::

    W_j = W_{p(j)} L_j, \\qquad X_j = X_{p(j)} + W_{p(j)}\\, t_j, \\qquad W_{root} = L_{root}, \\; X_{root} = r

with ``L_j`` the local rotation of joint ``j`` (``local_rotations``), ``t_j`` its translation in the parent's
frame (the rest ``offsets`` unless the file animates it: ``local_translations``) and ``r`` the root position.
An end site ``e`` hanging from joint ``j`` sits at ``X_j + W_j o_e``.

Up-axis conversion: a y-up right-handed frame (BVH, CMU ASF) maps to the z-up right-handed world by the cyclic
permutation ``(x, y, z)_yup -> (z, x, y)_zup``, i.e. ``p_zup = A p_yup`` with
``A = [[0, 0, 1], [1, 0, 0], [0, 1, 0]]`` (det +1, so no mirror). Rotations become ``A L Aᵀ``. The CMU subjects
face +z with their left side towards +x in the files, so after the conversion they face +x with their left
towards +y: the rest orientation of the body presets in :mod:`jaxmocap.geometry.body`.

Evaluation joints (:data:`jaxmocap.geometry.body.EVAL_JOINTS`) of a CMU skeleton, each defined on the bones, with its
joint in the CMU ASF / the 3ds Max-friendly cgspeed BVH / the MotionBuilder-friendly cgspeed BVH:

* root — the pelvis, the root: ``root`` / ``Hips`` / ``Hips``;
* thorax — the base of the neck, start of the lower neck: ``lowerneck`` / ``lowerneck`` / ``Neck``;
* head — the middle of the head bone, between the head joint and the end site of the head bone (the top of
  the head): ``head`` / ``Head`` / ``Head``;
* left/right shoulder — start of the humerus: ``l/rhumerus`` / ``Left/RightShoulder`` / ``Left/RightArm``;
* left/right elbow — start of the radius: ``l/rradius`` / ``Left/RightElbow`` / ``Left/RightForeArm``;
* left/right wrist — start of the hand bone, where the hand bends: ``l/rhand`` / ``Left/RightWrist`` /
  ``Left/RightHand``. In the ASF the ``l/rwrist`` bone (``dof ry``) carries the forearm's twist and continues the
  radius to the wrist; ``l/rhand`` carries the wrist's flexion and deviation (``dof rx rz``), so the wrist is the
  end of ``l/rwrist``. The cgspeed conversions agree: their ``Left/RightWrist`` sits one radius plus one ASF
  wrist bone past the elbow, at the ``lhand`` joint;
* left/right hip — start of the femur: ``l/rfemur`` / ``Left/RightHip`` / ``Left/RightUpLeg``;
* left/right knee — start of the tibia: ``l/rtibia`` / ``Left/RightKnee`` / ``Left/RightLeg``;
* left/right ankle — start of the foot: ``l/rfoot`` / ``Left/RightAnkle`` / ``Left/RightFoot``.

"Start of bone b" is the position of the joint that rotates b (BVH joints and ASF bones are named after the
bone they move). Each ASF joint above is the start of the bone carrying that articulation's bending degrees of
freedom (shoulder and hip: ``rx ry rz``; elbow and knee: ``rx``; wrist: ``rx rz``; ankle: ``rx rz``), a twist-only
bone (``l/rwrist``) being part of the segment before it (``tests/io/test_asfamc.py`` reads this from the ASF). The ASF and 3ds Max-friendly names are checked on the shipped CMU clips; the
MotionBuilder-friendly ones follow the same conversion with the other naming and are accepted by name.
Note that the cgspeed BVH skeleton drops the ASF ``thorax`` bone: its ``lowerneck`` joint coincides with
``Chest2``, the start of the ASF ``thorax`` bone.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry.body import EVAL_JOINTS

#: ``p_zup = Y_UP_TO_Z_UP @ p_yup``: the cyclic permutation (x, y, z)_yup -> (z, x, y)_zup.
Y_UP_TO_Z_UP = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

#: One inch in metres.
INCH = 0.0254


def read_lines(path) -> list[str]:
    """The lines of the text file at ``path`` (UTF-8, undecodable bytes replaced, any line ending); raises
    :class:`MocapInputError` when it cannot be read."""
    try:
        with open(path, encoding="utf-8", errors="replace", newline=None) as f:
            return f.read().splitlines()
    except OSError as e:
        raise MocapInputError(path, f"cannot read file: {e.strerror or e}") from None


def up_axis_matrix(up_axis: str) -> np.ndarray:
    """The rotation taking a file's frame with the given up axis (``"y"`` or ``"z"``) to the z-up world."""
    if up_axis == "y":
        return Y_UP_TO_Z_UP.copy()
    if up_axis == "z":
        return np.eye(3)
    raise ValueError(f"up_axis must be 'y' or 'z', got {up_axis!r}")


@dataclasses.dataclass(frozen=True, eq=False)
class Motion:
    """A motion clip: a kinematic tree animated over ``T`` frames (metres, world z up).

    Attributes:
      joint_names: ``J`` names, parents before children.
      parents: ``J`` parent indices, ``-1`` for the root (index 0).
      offsets: ``(J, 3)`` rest translation of each joint in its parent's frame (the root's is its rest position).
      local_rotations: ``(T, J, 3, 3)`` rotation ``L_j`` of each joint relative to its parent's frame.
      root_positions: ``(T, 3)`` world position of the root.
      positions: ``(T, J, 3)`` world joint positions.
      fps: frames per second.
      source: the file it came from.
      end_parents: ``E`` joint indices that carry an end site (bone ends without a child joint: head top,
        finger and toe tips).
      end_offsets: ``(E, 3)`` end-site offsets in their joint's frame.
      end_positions: ``(T, E, 3)`` world end-site positions.
      local_translations: ``(T, J, 3)`` per-frame translation of every joint in its parent's frame when some
        non-root joint is animated in translation (BVH position channels); ``None`` otherwise, meaning
        ``offsets`` for every joint but the root, whose translation is ``root_positions``.
    """

    joint_names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    local_rotations: np.ndarray
    root_positions: np.ndarray
    positions: np.ndarray
    fps: float
    source: str = ""
    end_parents: tuple[int, ...] = ()
    end_offsets: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    end_positions: np.ndarray | None = None
    local_translations: np.ndarray | None = None

    @property
    def num_frames(self) -> int:
        return int(self.local_rotations.shape[0])

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    def joint_index(self, name: str) -> int:
        return self.joint_names.index(name)

    def translations(self) -> np.ndarray:
        """``(T, J, 3)`` translation of every joint in its parent's frame for every frame."""
        if self.local_translations is not None:
            return self.local_translations
        T = self.num_frames
        tr = np.broadcast_to(self.offsets, (T, self.num_joints, 3)).copy()
        tr[:, 0] = self.root_positions
        return tr

    def end_site_of(self, joint: str) -> int:
        """Index (into ``end_parents``) of the first end site hanging from ``joint``."""
        j = self.joint_index(joint)
        if j not in self.end_parents:
            raise KeyError(f"joint {joint!r} has no end site")
        return self.end_parents.index(j)


def forward_kinematics(
    parents: Sequence[int], translations: np.ndarray, rotations: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World rotations and positions of a tree (float64 NumPy, vectorised over frames).

    Args:
      parents: ``J`` parent indices (parents first, ``-1`` for roots).
      translations: ``(T, J, 3)`` joint translations in the parent frame (world for roots).
      rotations: ``(T, J, 3, 3)`` local rotations.

    Returns:
      ``W (T, J, 3, 3)`` and ``X (T, J, 3)`` with ``W_j = W_p L_j`` and ``X_j = X_p + W_p t_j``.
    """
    translations = np.asarray(translations, dtype=np.float64)
    rotations = np.asarray(rotations, dtype=np.float64)
    W = np.empty_like(rotations)
    X = np.empty_like(translations)
    for j, p in enumerate(parents):
        if p < 0:
            W[:, j] = rotations[:, j]
            X[:, j] = translations[:, j]
        else:
            W[:, j] = W[:, p] @ rotations[:, j]
            X[:, j] = X[:, p] + np.einsum("tab,tb->ta", W[:, p], translations[:, j])
    return W, X


def end_site_positions(W: np.ndarray, X: np.ndarray, end_parents: Sequence[int], end_offsets) -> np.ndarray:
    """``(T, E, 3)`` world end sites ``X_j + W_j o_e`` from the output of :func:`forward_kinematics`."""
    idx = np.asarray(end_parents, dtype=np.int64)
    if idx.size == 0:
        return np.zeros((X.shape[0], 0, 3))
    return X[:, idx] + np.einsum("teab,eb->tea", W[:, idx], np.asarray(end_offsets, dtype=np.float64))


def build_motion(
    joint_names: Sequence[str],
    parents: Sequence[int],
    offsets: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
    fps: float,
    source: str,
    end_parents: Sequence[int] = (),
    end_offsets: np.ndarray | None = None,
    scale: float = 1.0,
    up_axis: str = "z",
) -> Motion:
    """Assemble a :class:`Motion` from file-frame data: scale lengths to metres, turn the frame to z up, run FK.

    ``offsets (J, 3)``, ``translations (T, J, 3)`` and ``end_offsets (E, 3)`` are in file units and axes,
    ``rotations (T, J, 3, 3)`` in the file's axes; the result has ``A t · scale`` and ``A L Aᵀ``
    (:func:`up_axis_matrix`).
    """
    A = up_axis_matrix(up_axis)
    offsets = scale * np.asarray(offsets, dtype=np.float64) @ A.T
    translations = scale * np.asarray(translations, dtype=np.float64) @ A.T
    rotations = A @ np.asarray(rotations, dtype=np.float64) @ A.T
    end_offsets = np.zeros((0, 3)) if end_offsets is None else np.asarray(end_offsets, dtype=np.float64)
    end_offsets = scale * end_offsets.reshape(-1, 3) @ A.T
    W, X = forward_kinematics(parents, translations, rotations)
    rest = np.broadcast_to(offsets[1:], translations[:, 1:].shape)
    animated = translations.shape[0] > 0 and not np.array_equal(translations[:, 1:], rest)
    return Motion(
        joint_names=tuple(joint_names),
        parents=tuple(int(p) for p in parents),
        offsets=offsets,
        local_rotations=rotations,
        root_positions=translations[:, 0].copy(),
        positions=X,
        fps=float(fps),
        source=str(source),
        end_parents=tuple(int(e) for e in end_parents),
        end_offsets=end_offsets,
        end_positions=end_site_positions(W, X, end_parents, end_offsets),
        local_translations=translations if animated else None,
    )


def motion_in_units(motion: Motion, scale: float, up_axis: str, from_up_axis: str = "y") -> Motion:
    """A motion built in file units (``scale=1``) read with ``from_up_axis``, rebuilt with ``scale`` metres per
    unit and the file's ``up_axis`` (:func:`build_motion` on the file-frame data recovered with ``A⁻¹``)."""
    A = up_axis_matrix(from_up_axis)
    back = lambda v: np.asarray(v, np.float64) @ A  # A⁻¹ v = Aᵀ v, row form v A
    return build_motion(
        motion.joint_names,
        motion.parents,
        back(motion.offsets),
        A.T @ motion.local_rotations @ A,
        back(motion.translations()),
        motion.fps,
        motion.source,
        motion.end_parents,
        back(motion.end_offsets),
        scale=scale,
        up_axis=up_axis,
    )


def rest_positions(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """World joint ``(J, 3)`` and end-site ``(E, 3)`` positions of the rest pose (all rotations identity, root at
    its rest offset)."""
    J = motion.num_joints
    R = np.broadcast_to(np.eye(3), (1, J, 3, 3))
    W, X = forward_kinematics(motion.parents, motion.offsets[None], R)
    return X[0], end_site_positions(W, X, motion.end_parents, motion.end_offsets)[0]


# ---------------------------------------------------------------------------------------------------------------
# Elementary rotations and Euler angles (NumPy or jax.numpy through ``xp``)

_AXIS = {"x": 0, "y": 1, "z": 2, "X": 0, "Y": 1, "Z": 2}


def axis_rotation(axis: int, angle, xp=np):
    """``(..., 3, 3)`` right-handed rotation by ``angle (...)`` radians about coordinate axis 0, 1 or 2."""
    angle = xp.asarray(angle)
    c, s = xp.cos(angle), xp.sin(angle)
    one, zero = xp.ones_like(angle), xp.zeros_like(angle)
    if axis == 0:
        rows = ((one, zero, zero), (zero, c, -s), (zero, s, c))
    elif axis == 1:
        rows = ((c, zero, s), (zero, one, zero), (-s, zero, c))
    else:
        rows = ((c, -s, zero), (s, c, zero), (zero, zero, one))
    return xp.stack([xp.stack(r, -1) for r in rows], -2)


def euler_to_matrix(angles, order: str, xp=np):
    """``R = R_{order[0]}(a_0) R_{order[1]}(a_1) ⋯`` for ``angles (..., k)`` in radians, ``order`` like ``"ZYX"``.

    This is the BVH channel convention (channels listed outermost first) and, read as "apply the last listed
    rotation first", the composition of any sequence of axis rotations.
    """
    angles = xp.asarray(angles)
    R = None
    for k, a in enumerate(order):
        Rk = axis_rotation(_AXIS[a], angles[..., k], xp)
        R = Rk if R is None else R @ Rk
    if R is None:
        return xp.broadcast_to(xp.eye(3), angles.shape[:-1] + (3, 3))
    return R


def matrix_to_euler(R, order: str, xp=np):
    """Inverse of :func:`euler_to_matrix` for a Tait–Bryan ``order`` (three distinct axes). ``(...,3,3)->(...,3)``.

    With ``R = R_a(θ1) R_b(θ2) R_c(θ3)`` and ``s = +1`` for cyclic ``(a, b, c)`` (xyz, yzx, zxy), ``-1``
    otherwise: ``θ2 = asin(s R_ac)``, ``θ1 = atan2(-s R_bc, R_cc)``, ``θ3 = atan2(-s R_ab, R_aa)``. At gimbal lock
    (``|R_ac| ≈ 1``) θ3 is set to 0 and θ1 absorbs the whole rotation about the common axis.
    """
    a, b, c = (_AXIS[o] for o in order)
    if len({a, b, c}) != 3 or len(order) != 3:
        raise ValueError(f"order must name three distinct axes, got {order!r}")
    s = 1.0 if (a, b, c) in ((0, 1, 2), (1, 2, 0), (2, 0, 1)) else -1.0
    R = xp.asarray(R)
    sin2 = xp.clip(s * R[..., a, c], -1.0, 1.0)
    t2 = xp.arcsin(sin2)
    locked = xp.abs(sin2) > 1.0 - 1e-9
    t1 = xp.arctan2(-s * R[..., b, c], R[..., c, c])
    t3 = xp.arctan2(-s * R[..., a, b], R[..., a, a])
    # gimbal lock: R_a(θ1) R_b(±90°) = ... ; recover θ1 from the block that does not involve axis c.
    t1_locked = xp.arctan2(s * R[..., c, b], R[..., b, b])
    t1 = xp.where(locked, t1_locked, t1)
    t3 = xp.where(locked, xp.zeros_like(t3), t3)
    return xp.stack([t1, t2, t3], -1)


# ---------------------------------------------------------------------------------------------------------------
# Evaluation joints

#: A joint spec is a joint name (its position), ``("end_mid", name)`` (midpoint of the joint and its first end
#: site) or ``("mid", a, b)`` (midpoint of joints ``a`` and ``b``).
JointSpec = str | tuple[str, str] | tuple[str, str, str]


def eval_naming(
    axial: tuple[JointSpec, JointSpec, JointSpec], limbs: Mapping[str, str], sided: str
) -> dict[str, JointSpec]:
    """The evaluation-joint mapping of a skeleton that names its sides by a pattern: ``axial`` the specs of
    ``root``, ``thorax`` and ``head``; ``limbs`` the file's name of each limb joint (``shoulder``, ``elbow``,
    ``wrist``, ``hip``, ``knee``, ``ankle``) without its side; ``sided`` how a side and a name make a joint name,
    with ``{l}`` (``l``/``r``), ``{L}`` (``L``/``R``) or ``{Side}`` (``Left``/``Right``) and ``{name}``."""
    out: dict[str, JointSpec] = dict(zip(("root", "thorax", "head"), axial, strict=True))
    for joint in EVAL_JOINTS[3:]:
        side, limb = joint.split("_", 1)
        out[joint] = sided.format(l=side[0], L=side[0].upper(), Side=side.capitalize(), name=limbs[limb])
    return out


#: The CMU ASF (the wrists are the ``lhand``/``rhand`` joints: the ends of the ``lwrist``/``rwrist`` bones).
CMU_ASF_EVAL = eval_naming(
    ("root", "lowerneck", ("end_mid", "head")),
    dict(shoulder="humerus", elbow="radius", wrist="hand", hip="femur", knee="tibia", ankle="foot"),
    "{l}{name}",
)
#: The 3ds Max-friendly cgspeed BVH conversion of the CMU database.
CMU_BVH_3DSMAX_EVAL = eval_naming(
    ("Hips", "lowerneck", ("end_mid", "Head")),
    dict(shoulder="Shoulder", elbow="Elbow", wrist="Wrist", hip="Hip", knee="Knee", ankle="Ankle"),
    "{Side}{name}",
)
#: The MotionBuilder-friendly cgspeed BVH conversion.
CMU_BVH_MOTIONBUILDER_EVAL = eval_naming(
    ("Hips", "Neck", ("end_mid", "Head")),
    dict(shoulder="Arm", elbow="ForeArm", wrist="Hand", hip="UpLeg", knee="Leg", ankle="Foot"),
    "{Side}{name}",
)

#: Known skeletons, tried in this order by :func:`eval_mapping`.
KNOWN_MAPPINGS: dict[str, dict[str, JointSpec]] = {
    "cmu_asf": CMU_ASF_EVAL,
    "cmu_bvh_3dsmax": CMU_BVH_3DSMAX_EVAL,
    "cmu_bvh_motionbuilder": CMU_BVH_MOTIONBUILDER_EVAL,
}


def _spec_ok(motion: Motion, spec: JointSpec) -> bool:
    if isinstance(spec, str):
        return spec in motion.joint_names
    if spec[0] == "mid" and len(spec) == 3:
        return all(n in motion.joint_names for n in spec[1:])
    if spec[0] != "end_mid" or len(spec) != 2:
        return False
    name = spec[1]
    return name in motion.joint_names and motion.joint_index(name) in motion.end_parents


def spec_joints(spec: JointSpec) -> tuple[str, ...]:
    """The joint names a :data:`JointSpec` refers to."""
    return (spec,) if isinstance(spec, str) else tuple(spec[1:])


def eval_mapping(motion: Motion) -> dict[str, JointSpec]:
    """The first of :data:`KNOWN_MAPPINGS` whose joints all exist in ``motion`` (raises ``KeyError`` if none)."""
    for mapping in KNOWN_MAPPINGS.values():
        if all(_spec_ok(motion, s) for s in mapping.values()):
            return mapping
    raise KeyError(
        f"{motion.source or 'motion'}: skeleton matches none of the known CMU namings "
        f"({', '.join(KNOWN_MAPPINGS)}); recognise it with jaxmocap.io.skeletons.recognise or pass mapping="
    )


def _spec_points(motion: Motion, spec: JointSpec, joints: np.ndarray, ends: np.ndarray) -> np.ndarray:
    if isinstance(spec, str):
        return joints[..., motion.joint_index(spec), :]
    if spec[0] == "mid":
        return 0.5 * (
            joints[..., motion.joint_index(spec[1]), :] + joints[..., motion.joint_index(spec[2]), :]
        )
    _, name = spec
    e = motion.end_site_of(name)
    return 0.5 * (joints[..., motion.joint_index(name), :] + ends[..., e, :])


def eval_joints(motion: Motion, mapping: Mapping[str, JointSpec] | None = None) -> np.ndarray:
    """``(T, 15, 3)`` world positions of :data:`jaxmocap.geometry.body.EVAL_JOINTS` (in that order), metres, z up.

    ``mapping`` gives each evaluation joint as a joint name or ``("end_mid", name)``; by default it is found
    among the CMU skeletons of the module docstring (:func:`eval_mapping`).
    """
    mapping = eval_mapping(motion) if mapping is None else mapping
    ends = motion.end_positions if motion.end_positions is not None else np.zeros((motion.num_frames, 0, 3))
    return np.stack([_spec_points(motion, mapping[n], motion.positions, ends) for n in EVAL_JOINTS], axis=1)


def rest_eval_joints(motion: Motion, mapping: Mapping[str, JointSpec] | None = None) -> np.ndarray:
    """``(15, 3)`` evaluation joints of the rest pose (see :func:`rest_positions`)."""
    mapping = eval_mapping(motion) if mapping is None else mapping
    X, E = rest_positions(motion)
    return np.stack([_spec_points(motion, mapping[n], X, E) for n in EVAL_JOINTS], axis=0)


# ---------------------------------------------------------------------------------------------------------------
# Body dimensions of a mocap subject


def body_dimensions_from_motion(motion: Motion, mapping: Mapping[str, JointSpec] | None = None) -> dict:
    """Dimensions of :func:`jaxmocap.geometry.body.full25` (keys of ``body.DEFAULT_DIMENSIONS``) measured on the skeleton.

    Measured on the rest pose (bone lengths do not change over a clip), with ``u`` the unit vector from the root
    to the thorax (the torso axis) and ``E`` the evaluation joints of :func:`rest_eval_joints`:

    * ``torso_length = |thorax − root|``;
    * ``left_/right_upper_arm_length = |shoulder − elbow|``, ``…forearm_length = |elbow − wrist|``,
      ``…thigh_length = |hip − knee|``, ``…shin_length = |knee − ankle|``;
    * ``shoulder_width = |l_shoulder − r_shoulder|``, ``hip_width = |l_hip − r_hip|``;
    * ``shoulder_drop = −(mean shoulder − thorax)·u`` (negative when the shoulders sit above the base of the
      neck, as on CMU skeletons), ``hip_drop = −(mean hip − root)·u``;
    * ``head_length`` = length of the head bone (joint to end site), ``neck_length`` = distance along ``u``
      from the thorax to the head bone's start, so that the model's head centre, ``neck_length +
      head_length / 2`` above the thorax, is the middle of the head bone;
    * the unprefixed limb keys hold the mean of both sides.

    Radii are not measured (the skeleton has none) and keep their defaults.
    """
    mapping = eval_mapping(motion) if mapping is None else mapping
    E = dict(zip(EVAL_JOINTS, rest_eval_joints(motion, mapping), strict=True))
    X, ends = rest_positions(motion)
    dist = lambda a, b: float(np.linalg.norm(E[a] - E[b]))
    u = E["thorax"] - E["root"]
    torso = float(np.linalg.norm(u))
    u = u / torso
    head_spec = mapping["head"]
    if isinstance(head_spec, str):
        head_start = head_end = E["head"]
    elif head_spec[0] == "mid":
        head_start, head_end = X[motion.joint_index(head_spec[1])], X[motion.joint_index(head_spec[2])]
    else:
        j = motion.joint_index(head_spec[1])
        head_start, head_end = X[j], ends[motion.end_site_of(head_spec[1])]
    dims = {
        "torso_length": torso,
        "shoulder_width": dist("left_shoulder", "right_shoulder"),
        "shoulder_drop": float(-(0.5 * (E["left_shoulder"] + E["right_shoulder"]) - E["thorax"]) @ u),
        "hip_width": dist("left_hip", "right_hip"),
        "hip_drop": float(-(0.5 * (E["left_hip"] + E["right_hip"]) - E["root"]) @ u),
        "neck_length": float((head_start - E["thorax"]) @ u),
        "head_length": float(np.linalg.norm(head_end - head_start)),
    }
    for side in ("left", "right"):
        dims[f"{side}_upper_arm_length"] = dist(f"{side}_shoulder", f"{side}_elbow")
        dims[f"{side}_forearm_length"] = dist(f"{side}_elbow", f"{side}_wrist")
        dims[f"{side}_thigh_length"] = dist(f"{side}_hip", f"{side}_knee")
        dims[f"{side}_shin_length"] = dist(f"{side}_knee", f"{side}_ankle")
    for key in ("upper_arm_length", "forearm_length", "thigh_length", "shin_length"):
        dims[key] = 0.5 * (dims[f"left_{key}"] + dims[f"right_{key}"])
    for k, v in dims.items():
        if not math.isfinite(v):
            raise ValueError(f"{motion.source}: dimension {k} is not finite")
    return dims
