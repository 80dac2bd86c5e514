"""The synthetic subject: the mocap skeleton dressed as cones and a head spheroid, with a body part per cone.

Every bone of non-zero length becomes a truncated cone with spherical caps from its parent joint to its child
joint (end sites included, so the head, fingers, thumbs and toes have their bones), with radii by body part
(:data:`ROLE_RADII`), and the head becomes a spheroid centred on the middle of the head bone (polar length
:data:`HEAD_LENGTH`, equatorial radius :data:`HEAD_RADIUS`). Clothing colours are per limb (:data:`ROLE_COLOURS`,
the same on both sides); head, neck and hands are skin-coloured.

Body parts come from the evaluation joints the skeleton was recognised with
(:func:`jaxmocap.io.skeletons.recognise`), so they hold for any naming: a bone belongs to the segment between the
evaluation joints it lies between (root → thorax: torso; root → hip: pelvis; spine → shoulder: clavicle;
shoulder → elbow: upper arm; elbow → wrist: forearm; past the wrist: hand, or finger/thumb by name; hip → knee:
thigh; knee → ankle: shin; the first bone past the ankle: foot, later ones: toe; thorax → head: neck).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.geometry import render
from jaxmocap.io.mocap import JointSpec, Motion, body_dimensions_from_motion, rest_positions
from jaxmocap.io.skeleton_match import ancestors
from jaxmocap.io.skeletons import recognise

#: Cone radii (metres) at the parent and child end of a bone, by body part.
ROLE_RADII: dict[str, tuple[float, float]] = {
    "torso": (0.135, 0.135),
    "pelvis": (0.10, 0.09),
    "clavicle": (0.06, 0.055),
    "upper_arm": (0.05, 0.04),
    "forearm": (0.04, 0.03),
    "hand": (0.03, 0.025),
    "finger": (0.022, 0.018),
    "thumb": (0.015, 0.012),
    "thigh": (0.08, 0.06),
    "shin": (0.055, 0.04),
    "foot": (0.04, 0.035),
    "toe": (0.035, 0.03),
    "neck": (0.05, 0.05),
    "limb": (0.04, 0.04),
}

#: Clothing colours (RGB in [0, 1]) by body part, the same for the left and right limb; skin for bare parts.
ROLE_COLOURS: dict[str, tuple[float, float, float]] = {
    "torso": (0.20, 0.30, 0.65),
    "clavicle": (0.20, 0.30, 0.65),
    "upper_arm": (0.70, 0.15, 0.15),
    "forearm": (0.85, 0.60, 0.10),
    "pelvis": (0.25, 0.25, 0.28),
    "thigh": (0.15, 0.55, 0.25),
    "shin": (0.45, 0.20, 0.55),
    "foot": (0.12, 0.12, 0.12),
    "toe": (0.12, 0.12, 0.12),
    "limb": (0.10, 0.55, 0.60),
    "neck": render.SKIN,
    "hand": render.SKIN,
    "finger": render.SKIN,
    "thumb": render.SKIN,
    "head": render.SKIN,
}

#: Head spheroid: polar length (chin to crown) and equatorial radius, metres.
HEAD_LENGTH = 0.22
HEAD_RADIUS = 0.09


def _roles(motion: Motion, mapping: Mapping[str, JointSpec], bones: Sequence[tuple[int, int]]) -> list[str]:
    """Body part of each bone ``(parent joint, child point)`` (points past ``J`` are end sites) from the
    evaluation joints of ``mapping`` (module docstring). Joints at the wrist's rest position count as the wrist
    (an ASF thumb hangs from the bone before the hand)."""
    par = list(motion.parents) + list(motion.end_parents)
    X, _ = rest_positions(motion)
    at = lambda k: motion.joint_index(mapping[k] if isinstance(mapping[k], str) else mapping[k][1])
    up = lambda c: set(ancestors(par, c))  # c and its ancestors
    names = list(motion.joint_names) + [motion.joint_names[p] + "_end" for p in motion.end_parents]
    thorax = at("thorax")
    spine = up(thorax)
    out = []
    for p, c in bones:
        role, above = None, up(p)
        for side in ("left", "right"):
            sh, el, wr = (at(f"{side}_{k}") for k in ("shoulder", "elbow", "wrist"))
            hp, kn, an = (at(f"{side}_{k}") for k in ("hip", "knee", "ankle"))
            at_wrist = {j for j in range(len(X)) if np.linalg.norm(X[j] - X[wr]) <= 1e-9}
            if at_wrist & above:
                thumb = "thumb" in (names[p] + names[c]).lower()
                role = "thumb" if thumb else "hand" if p in at_wrist else "finger"
            elif el in above:
                role = "forearm"
            elif sh in above:
                role = "upper_arm"
            elif c in up(sh) and c not in spine:
                role = "clavicle"
            elif an in above:
                role = "foot" if p == an else "toe"
            elif kn in above:
                role = "shin"
            elif hp in above:
                role = "thigh"
            elif c in up(hp) and c not in spine:
                role = "pelvis"
            if role is not None:
                break
        if role is None:
            role = "torso" if c in spine else "neck" if thorax in above else "limb"
        out.append(role)
    return out


@dataclasses.dataclass(frozen=True)
class Dressing:
    """How a skeleton is dressed; static (hashable) except for the radii.

    Points are the ``J`` joints, then the ``E`` end sites, then two head points (the ends of the head
    spheroid's polar axis); ``parents`` has one entry per point (``−1`` for the root and the head points).
    ``bones``: child point of each cone (label order), ``part_names`` / ``part_roles`` per label (cones, then
    ``"head"``), ``radius_start``/``radius_end`` ``(C,)``, ``head_bone``: ``(head joint, its end site point)``.
    """

    parents: tuple[int, ...]
    bones: tuple[int, ...]
    part_names: tuple[str, ...]
    part_roles: tuple[str, ...]
    radius_start: tuple[float, ...]
    radius_end: tuple[float, ...]
    head_bone: tuple[int, int]
    head_length: float = HEAD_LENGTH
    head_radius: float = HEAD_RADIUS

    @property
    def num_cones(self) -> int:
        return len(self.bones)

    @property
    def head_points(self) -> tuple[int, int]:
        n = len(self.parents)
        return (n - 2, n - 1)

    def colours(self, palette: Mapping[str, tuple[float, float, float]] | None = None) -> np.ndarray:
        """``(C + 1, 3)`` RGB in [0, 1] per label: :data:`ROLE_COLOURS`, with ``palette`` overriding parts."""
        table = {**ROLE_COLOURS, **(palette or {})}
        return np.asarray([table.get(r, table["limb"]) for r in self.part_roles], np.float64)


def dress(
    motion: Motion,
    mapping: Mapping[str, JointSpec] | None = None,
    head_length: float = HEAD_LENGTH,
    head_radius: float = HEAD_RADIUS,
) -> Dressing:
    """Cones for every bone of ``motion`` (parent → child, end sites included) of non-zero rest length, bones
    repeating another one's end points left out; the head bone (of ``mapping["head"]``) becomes the spheroid.

    ``mapping``: the evaluation joints (default :func:`jaxmocap.io.skeletons.recognise`). A bone is named after
    its parent joint (BVH and ASF name a bone after the joint that moves it), with ``>child`` appended when the
    parent starts several bones; its body part follows the module docstring.
    """
    mapping = recognise(motion).mapping if mapping is None else mapping
    X, E = rest_positions(motion)
    names = list(motion.joint_names)
    J = len(names)
    child_names = names + [names[p] + "_end" for p in motion.end_parents]
    parents = list(motion.parents) + list(motion.end_parents)
    pts = np.concatenate([X, E], 0) if len(E) else X
    head_spec = mapping["head"]
    if isinstance(head_spec, str):
        raise ValueError(f"{motion.source}: the head joint needs an end site or a head-top joint")
    head_joint = motion.joint_index(head_spec[1])
    if head_spec[0] == "mid":
        head_end = motion.joint_index(head_spec[2])
    else:
        head_end = J + motion.end_parents.index(head_joint)
    kept, seen = [], []
    for c in range(len(parents)):
        p = parents[c]
        if p < 0 or c == head_end or np.linalg.norm(pts[c] - pts[p]) <= 1e-6:
            continue
        ends = (pts[p], pts[c])
        if any(np.allclose(ends, s, atol=1e-6) for s in seen):
            continue
        seen.append(ends)
        kept.append(c)
    n_children = {p: sum(parents[c] == p for c in kept) for p in range(J)}
    roles = _roles(motion, mapping, [(parents[c], c) for c in kept])
    part_names = [
        names[parents[c]] if n_children[parents[c]] <= 1 else f"{names[parents[c]]}>{child_names[c]}"
        for c in kept
    ]
    radii = [ROLE_RADII.get(r, ROLE_RADII["limb"]) for r in roles]
    return Dressing(
        parents=tuple(parents + [-1, -1]),
        bones=tuple(kept),
        part_names=tuple(part_names) + ("head",),
        part_roles=tuple(roles) + ("head",),
        radius_start=tuple(r[0] for r in radii),
        radius_end=tuple(r[1] for r in radii),
        head_bone=(head_joint, head_end),
        head_length=float(head_length),
        head_radius=float(head_radius),
    )


def toe_points(motion: Motion, mapping: Mapping[str, JointSpec]) -> tuple[int, int]:
    """Indices into :func:`dressing_points` (joints, then end sites) of the left and right toe tips: the
    descendant of each ankle farthest from it at rest (the ankle itself when its foot has no bone)."""
    X, E = rest_positions(motion)
    pts = np.concatenate([X, E], 0) if len(E) else X
    par = list(motion.parents) + list(motion.end_parents)
    out = []
    for side in ("left", "right"):
        a = motion.joint_index(mapping[f"{side}_ankle"])
        below = [p for p in range(len(par)) if p != a and a in ancestors(par, p)]
        out.append(max(below, key=lambda p: np.linalg.norm(pts[p] - pts[a])) if below else a)
    return out[0], out[1]


def dressing_points(motion: Motion, dressing: Dressing, frames: Sequence[int] | np.ndarray) -> np.ndarray:
    """``(T, P, 3)`` points of :class:`Dressing` at the source frames ``frames``: joints, end sites, and the head
    spheroid's axis ends ``m ± (head_length/2) â`` with ``m`` the middle of the head bone and ``â`` its
    direction."""
    idx = np.asarray(frames, dtype=np.int64)
    ends = motion.end_positions if motion.end_positions is not None else np.zeros((motion.num_frames, 0, 3))
    pts = np.concatenate([motion.positions[idx], ends[idx]], axis=1)
    hj, he = dressing.head_bone
    a, b = pts[:, hj], pts[:, he]
    axis = b - a
    axis = axis / np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), 1e-12)
    mid = 0.5 * (a + b)
    half = 0.5 * dressing.head_length
    return np.concatenate([pts, (mid - half * axis)[:, None], (mid + half * axis)[:, None]], axis=1)


@functools.partial(jax.jit, static_argnames=("dressing",))
def _scene(points: jnp.ndarray, dressing: Dressing) -> render.Primitives:
    return render.primitives_from_skeleton(
        points,
        dressing.parents,
        jnp.asarray(dressing.radius_start, points.dtype),
        jnp.asarray(dressing.radius_end, points.dtype),
        bones=dressing.bones,
        head=dressing.head_points,
        head_radius=dressing.head_radius,
    )


def scene_primitives(points: np.ndarray, dressing: Dressing) -> render.Primitives:
    """World :class:`jaxmocap.geometry.render.Primitives` of one frame's points ``(P, 3)`` (float32): ``C`` cones in
    :attr:`Dressing.bones` order, then the head spheroid (label ``C``)."""
    return _scene(jnp.asarray(points, jnp.float32), dressing)


def body_dimensions(
    motion: Motion, dressing: Dressing, mapping: Mapping[str, JointSpec] | None = None
) -> dict[str, float]:
    """``full25`` dimensions of the dressed subject: lengths measured on the skeleton
    (:func:`jaxmocap.io.mocap.body_dimensions_from_motion`), the radii of the dressing, and the head of the
    dressing (``head_length``; ``neck_length`` lowered so that the model's head centre stays the middle of the
    head bone, the ground-truth ``head`` joint)."""
    dims = body_dimensions_from_motion(motion, recognise(motion).mapping if mapping is None else mapping)
    bone_len = dims["head_length"]
    dims["head_length"] = dressing.head_length
    dims["head_radius"] = dressing.head_radius
    dims["neck_length"] = max(0.0, dims["neck_length"] - 0.5 * (dressing.head_length - bone_len))
    r = ROLE_RADII
    dims.update(
        torso_radius_bottom=r["torso"][0],
        torso_radius_top=r["torso"][1],
        upper_arm_radius_top=r["upper_arm"][0],
        upper_arm_radius_bottom=r["upper_arm"][1],
        forearm_radius_top=r["forearm"][0],
        forearm_radius_bottom=r["forearm"][1],
        thigh_radius_top=r["thigh"][0],
        thigh_radius_bottom=r["thigh"][1],
        shin_radius_top=r["shin"][0],
        shin_radius_bottom=r["shin"][1],
    )
    return dims
