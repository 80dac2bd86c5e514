"""Placing the 15 evaluation joints on any skeleton by its joint names and by the shape of its tree.

Names (:func:`match_names`): first the exact tables of known families (:data:`FAMILIES`: the CMU ASF, the 3ds
Max-friendly cgspeed BVH, Mixamo, the MotionBuilder/HumanIK naming of the other cgspeed conversion and of Rokoko,
Bandai-Namco's research set), then a tokenised reading of any name (namespace ``mixamorig:`` and prefixes such as
``Bip01``/``m_avg``/``Skeleton_001`` dropped, the side read from ``Left``/``Right``/``L``/``R`` words, prefixes or
suffixes, CamelCase split) against synonym lists in priority order (:data:`SYNONYMS`), which covers the
"LeftUpLeg/LeftLeg/LeftFoot" family (MotionBuilder, Rokoko), Xsens MVN (``RightUpperLeg``), SMPL exports
(``L_Hip``, ``L_Knee``, ``L_Wrist``), OptiTrack Motive (``LThigh``, ``LShin``, ``LUArm``, ``LFArm``), 3ds Max Biped
(``Bip01 L Thigh``) and Unreal (``thigh_l``, ``calf_l``); the named joints must form the chains root → hip → knee
→ ankle, root → shoulder → elbow → wrist and root → thorax → head.

Shape (:func:`match_shape`), on an upright pose (the rest pose, else one of a few frames; read as y up, then z up):
the feet are the two lowest leaves whose branches part well above the floor, their branch point the pelvis; of
the other leaves the head is the highest and the hands the two farthest from the body's vertical axis on either
side, their branch point the chest; along each leg the hip is the first point past the pelvis, the knee the joint
nearest 0.52 of the pelvis height and the ankle the joint past it whose shank best matches the thigh; along each
arm, shoulder, elbow and wrist minimise ``log²(c / 0.12 H) + log²(u / 0.186 H) + log²(f / 0.146 H)`` for the
chest-to-shoulder path ``c``, upper arm ``u`` and forearm ``f`` (Drillis & Contini's segment fractions of the
stature ``H``, which the legs estimate as ``(thigh + shank) / 0.491``), the wrist at the hand's fork (where the
fingers and thumb part) when there is one; the thorax is the head branch's first joint; the head bone ends at the
highest leaf (a head-top joint when its bone is at least 0.045 H long and does not start at the neck); left is
``ẑ × forward`` with forward the toes' direction.

Head specs: ``("end_mid", head)`` (middle of the head joint and its end site) or ``("mid", head, top)`` when the
file has a head-top joint (Mixamo ``HeadTop_End``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence

import numpy as np

from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io.mocap import (
    CMU_ASF_EVAL,
    CMU_BVH_3DSMAX_EVAL,
    CMU_BVH_MOTIONBUILDER_EVAL,
    Y_UP_TO_Z_UP,
    JointSpec,
    Motion,
    eval_naming,
    rest_positions,
    spec_joints,
)

__all__ = [
    "FAMILIES",
    "SYNONYMS",
    "split_name",
    "match_names",
    "match_shape",
    "shape_mapping",
    "upright",
    "ancestors",
    "is_ancestor",
    "chain_errors",
]

BANDAI_EVAL = eval_naming(
    ("Hips", "Neck", ("end_mid", "Head")),
    dict(shoulder="UpperArm", elbow="LowerArm", wrist="Hand", hip="UpperLeg", knee="LowerLeg", ankle="Foot"),
    "{name}_{L}",
)

#: Mixamo (names after the ``mixamorig:`` namespace); the head is the middle of ``Head`` and ``HeadTop_End``.
MIXAMO_EVAL: dict[str, JointSpec] = {
    **CMU_BVH_MOTIONBUILDER_EVAL,
    "head": ("mid", "Head", "HeadTop_End"),
}

#: Known skeleton families by exact joint names (after any ``namespace:``), tried in this order.
FAMILIES: dict[str, dict[str, JointSpec]] = {
    "cmu_asf": CMU_ASF_EVAL,
    "cmu_bvh_3dsmax": CMU_BVH_3DSMAX_EVAL,
    "mixamo": MIXAMO_EVAL,
    "motionbuilder": CMU_BVH_MOTIONBUILDER_EVAL,
    "bandai_namco": BANDAI_EVAL,
}

_SIDED = ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")

#: Name stems (lower case, side and separators removed) of each evaluation joint, in priority order: the first
#: stem present on a side wins (``shoulder`` is a clavicle where an upper-arm joint also exists; ``hand`` is the
#: knuckles where a ``wrist`` joint also exists, as in SMPL; ``foot`` the toe base where an ``ankle`` exists).
SYNONYMS: dict[str, tuple[str, ...]] = {
    "root": ("hips", "pelvis", "hip", "root"),
    "thorax": ("lowerneck", "neck", "neck1", "neck01", "neckbase"),
    "head": ("head",),
    "shoulder": ("upperarm", "arm", "humerus", "uarm", "shoulder"),
    "elbow": ("forearm", "lowerarm", "elbow", "radius", "farm", "larm"),
    "wrist": ("wrist", "hand"),
    "hip": ("upleg", "upperleg", "thigh", "femur", "hip", "uleg"),
    "knee": ("leg", "lowerleg", "knee", "shin", "calf", "tibia", "lleg"),
    "ankle": ("ankle", "foot"),
}
_STEMS = {s for v in SYNONYMS.values() for s in v}
_PREFIX_WORDS = {"bip", "biped", "mixamorig", "m", "f", "avg", "skeleton", "def", "jnt", "mvn", "char"}
_SIDE_WORDS = {"l": "left", "left": "left", "r": "right", "right": "right"}
_WORD_RE = re.compile(r"[A-Z]+(?=[A-Z][a-z])|[A-Z]?[a-z]+|[A-Z]+|[0-9]+")


# ---------------------------------------------------------------------------------------------------------------
# Names


def split_name(name: str) -> tuple[str | None, str]:
    """``(side, stem)`` of a joint name: side ``"left"``, ``"right"`` or ``None``; the stem is the lower-case
    concatenation of the other words. Examples: ``mixamorig:LeftUpLeg`` → ``("left", "upleg")``, ``Hand_L`` →
    ``("left", "hand")``, ``Bip01 L Thigh`` → ``("left", "thigh")``, ``lfemur`` → ``("left", "femur")``,
    ``LFArm`` → ``("left", "farm")``, ``Neck1`` → ``(None, "neck1")``."""
    words = [w.lower() for w in _WORD_RE.findall(name.rsplit(":", 1)[-1])]
    while len(words) > 1 and (words[0] in _PREFIX_WORDS or words[0].isdigit()):
        words.pop(0)
    side = None
    for k, w in enumerate(words):
        if w in _SIDE_WORDS and len(words) > 1:
            side = _SIDE_WORDS[w]
            del words[k]
            break
    stem = "".join(words)
    if side is None:
        for word, s in (("left", "left"), ("right", "right")):
            if stem.startswith(word) and len(stem) > len(word):
                return s, stem[len(word) :]
            if stem.endswith(word) and len(stem) > len(word):
                return s, stem[: -len(word)]
        if stem[:1] in ("l", "r") and stem[1:] in _STEMS:
            return _SIDE_WORDS[stem[0]], stem[1:]
        if stem[-1:] in ("l", "r") and stem[:-1] in _STEMS:
            return _SIDE_WORDS[stem[-1]], stem[:-1]
    return side, stem


def ancestors(parents: Sequence[int], j: int) -> list[int]:
    out = []
    while j >= 0:
        out.append(j)
        j = parents[j]
    return out


def is_ancestor(parents: Sequence[int], a: int, b: int) -> bool:
    """Whether joint ``a`` is a strict ancestor of joint ``b``."""
    return a != b and a in ancestors(parents, b)


def chain_errors(names: Sequence[str], parents: Sequence[int], mapping: Mapping[str, JointSpec]) -> set[str]:
    """The evaluation joints of ``mapping`` that break the chains of the module docstring (both ends reported)."""
    index = {n: i for i, n in enumerate(names)}
    first = {k: index.get(spec_joints(v)[0], -1) for k, v in mapping.items()}
    bad: set[str] = set()
    chains = [("root", "thorax"), ("thorax", "head")]
    for side in ("left", "right"):
        chains += [
            ("root", f"{side}_hip"),
            (f"{side}_hip", f"{side}_knee"),
            (f"{side}_knee", f"{side}_ankle"),
        ]
        chains += [("root", f"{side}_shoulder")]
        chains += [(f"{side}_shoulder", f"{side}_elbow"), (f"{side}_elbow", f"{side}_wrist")]
    for a, b in chains:
        if a in first and b in first and not is_ancestor(parents, first[a], first[b]):
            bad |= {b} if a == "root" and b != "thorax" else {a, b}
    for side in _SIDED:
        la, ra = first.get(f"left_{side}"), first.get(f"right_{side}")
        if la is not None and la == ra:
            bad |= {f"left_{side}", f"right_{side}"}
    return bad


def _head_spec(names: Sequence[str], parents: Sequence[int], head: int) -> JointSpec:
    """``("mid", head, top)`` when a child joint of ``head`` is a head-top/end joint, else ``("end_mid", head)``."""
    for c, p in enumerate(parents):
        if p == head:
            _, stem = split_name(names[c])
            if "top" in stem or stem.endswith("end"):
                return ("mid", names[head], names[c])
    return ("end_mid", names[head])


def match_names(names: Sequence[str], parents: Sequence[int]) -> tuple[dict[str, JointSpec], str]:
    """Evaluation joints placed by the joint names: ``(mapping, family)``, the mapping possibly partial.

    A known family (:data:`FAMILIES`) must match all 15 joints by exact name (after a ``namespace:``); otherwise
    every name is read by :func:`split_name` and each evaluation joint takes the first stem of its
    :data:`SYNONYMS` found (on its side), keeping only joints that form the chains of the module docstring.
    """
    bare = [n.rsplit(":", 1)[-1] for n in names]
    for family, table in FAMILIES.items():
        if all(all(j in bare for j in spec_joints(s)) for s in table.values()):
            mapping = {k: _rename(v, bare, names) for k, v in table.items()}
            if not chain_errors(names, parents, mapping):
                return mapping, family
    parsed = [split_name(n) for n in names]
    found: dict[str, JointSpec] = {}
    for joint in EVAL_JOINTS:
        side, kind = joint.split("_", 1) if joint.split("_", 1)[0] in ("left", "right") else (None, joint)
        for stem in SYNONYMS[kind]:
            hits = [j for j, (s, st) in enumerate(parsed) if st == stem and s == side]
            if hits:
                j = min(hits, key=lambda j: len(ancestors(parents, j)))
                found[joint] = _head_spec(names, parents, j) if kind == "head" else names[j]
                break
    for joint in chain_errors(names, parents, found):
        found.pop(joint, None)
    return found, "names"


def _rename(spec: JointSpec, bare: Sequence[str], names: Sequence[str]) -> JointSpec:
    full = lambda n: names[bare.index(n)]
    return full(spec) if isinstance(spec, str) else (spec[0], *(full(n) for n in spec[1:]))


# ---------------------------------------------------------------------------------------------------------------
# Shape


class _Tree:
    """Joints and end sites of one pose as one tree of points: ``pos (P, 3)``, ``parent (P,)``, names."""

    def __init__(self, names, parents, X, end_parents, E, eps):
        J = len(names)
        keep = [e for e, p in enumerate(end_parents) if np.linalg.norm(E[e] - X[p]) > eps]
        self.J = J
        self.names = list(names) + [f"{names[end_parents[e]]}/end" for e in keep]
        self.parent = list(parents) + [end_parents[e] for e in keep]
        self.pos = np.concatenate([X, E[keep]], 0) if keep else np.asarray(X)
        self.children: list[list[int]] = [[] for _ in self.parent]
        for c, p in enumerate(self.parent):
            if p >= 0:
                self.children[p].append(c)
        self.leaves = [p for p in range(len(self.parent)) if not self.children[p]]
        self.eps = eps

    def fork(self, b: int) -> np.ndarray:
        """Where the branches of joint ``b`` part: its position, or that of its children when they all start at
        one other point (an ASF bone whose children both hang from its end)."""
        kids = self.pos[self.children[b]]
        if len(kids) > 1 and np.all(np.linalg.norm(kids - kids[0], axis=-1) <= self.eps):
            return kids[0]
        return self.pos[b]

    def path(self, a: int, b: int) -> list[int]:
        """Points from ``a`` (excluded) down to its descendant ``b`` (included)."""
        out = []
        while b != a:
            out.append(b)
            b = self.parent[b]
            if b < 0:
                raise ValueError("not a descendant")
        return out[::-1]

    def lca(self, a: int, b: int) -> int:
        up = set(ancestors(self.parent, a))
        while b not in up:
            b = self.parent[b]
        return b

    def under(self, a: int, b: int) -> bool:
        return a in ancestors(self.parent, b)

    def distinct(self, start: int, chain: list[int]) -> list[int]:
        """The points of ``chain`` that do not coincide with the one before them (the first of a group kept)."""
        out, last = [], self.pos[start]
        for p in chain:
            if np.linalg.norm(self.pos[p] - last) > self.eps:
                out.append(p)
                last = self.pos[p]
        return out

    def length(self, start: int, chain: list[int], i: int, j: int) -> float:
        """Path length along ``[start] + chain`` from index ``i`` to ``j`` (``-1`` = ``start``)."""
        pts = [self.pos[start]] + [self.pos[p] for p in chain]
        return float(sum(np.linalg.norm(pts[k + 1] - pts[k]) for k in range(i + 1, j + 1)))


def _leg(tree: _Tree, pelvis: int, leaf: int) -> tuple[int, int, int] | None:
    """(hip, knee, ankle) of the leg ending at ``leaf`` (module docstring): the hip is the first point past the
    pelvis, the knee the joint nearest 0.52 of the pelvis height, the ankle the joint past it whose shank best
    matches the thigh."""
    chain = [p for p in tree.distinct(pelvis, tree.path(pelvis, leaf)) if p < tree.J]
    z0 = min(tree.pos[:, 2])
    hp = tree.pos[pelvis, 2] - z0
    if len(chain) < 3 or hp <= 0:
        return None
    hip = chain[0]
    knee = min(chain[1:-1], key=lambda p: abs((tree.pos[p, 2] - z0) / hp - 0.52))
    k = chain.index(knee)
    thigh = tree.length(pelvis, chain, 0, k)
    ankle = min(
        chain[k + 1 :],
        key=lambda p: abs(math.log(max(tree.length(pelvis, chain, k, chain.index(p)), 1e-12) / thigh)),
    )
    return hip, knee, ankle


def _arm(tree: _Tree, chest: int, leaf: int, stature: float) -> tuple[int, int, int] | None:
    """(shoulder, elbow, wrist) of the arm ending at ``leaf`` by the proportions of the module docstring, the
    wrist at the hand's branching point (a joint with several children, as where fingers and thumb part) when
    the arm has one past its third point."""
    full = tree.path(chest, leaf)
    chain = [p for p in tree.distinct(chest, full) if p < tree.J]
    if len(chain) < 3:
        return None
    forks = [tree.fork(b) for b in full if len(tree.children[b]) > 1]
    branching = {k for k, q in enumerate(chain) for f in forks if np.linalg.norm(f - tree.pos[q]) <= tree.eps}
    wrists = sorted(k for k in branching if k >= 2) or list(range(2, len(chain)))
    best, arg = math.inf, None
    lg = lambda x, f: math.log(max(x, 1e-9) / (f * stature)) ** 2
    for i in range(len(chain)):
        for j in range(i + 1, len(chain)):
            for k in wrists:
                if k <= j:
                    continue
                cost = lg(tree.length(chest, chain, -1, i), 0.12)
                cost += lg(tree.length(chest, chain, i, j), 0.186) + lg(
                    tree.length(chest, chain, j, k), 0.146
                )
                if cost < best:
                    best, arg = cost, (chain[i], chain[j], chain[k])
    return arg


class _NotABody(Exception):
    """The shape pass's reason for giving up on a pose."""


def _why(reason: str) -> dict:
    raise _NotABody(reason)


def match_shape(
    names: Sequence[str],
    parents: Sequence[int],
    X: np.ndarray,
    end_parents: Sequence[int] = (),
    E: np.ndarray | None = None,
) -> dict[str, JointSpec]:
    """Evaluation joints placed by the tree's shape in one upright pose (module docstring), z up.

    Args:
      names, parents: the joints; X: ``(J, 3)`` their positions; end_parents, E: ``(E, 3)`` end sites.

    Returns the mapping, empty when the pose does not show a standing body with two legs, two arms and a head
    (feet lowest, head highest, arms to the sides) or when left cannot be told from right.
    """
    try:
        return _shape(names, parents, X, end_parents, E)
    except _NotABody:
        return {}


def _shape(names, parents, X, end_parents, E) -> dict[str, JointSpec]:
    """:func:`match_shape`, raising :class:`_NotABody` with the reason it gives up."""
    E = np.zeros((0, 3)) if E is None else np.asarray(E, np.float64)
    X = np.asarray(X, np.float64)
    allp = np.concatenate([X, E], 0)
    size = float(np.ptp(allp, axis=0).max()) if len(allp) else 0.0
    if size <= 0:
        return _why("no extent")
    tree = _Tree(names, parents, X, end_parents, E, 1e-4 * size)
    z = tree.pos[:, 2]
    H = float(np.ptp(z))
    if len(tree.leaves) < 5 or H <= 0.2 * size:
        return _why("fewer than 5 leaves or not upright")
    leaves = sorted(tree.leaves, key=lambda p: z[p])
    foot1 = leaves[0]
    foot2 = next((p for p in leaves[1:] if z[tree.lca(foot1, p)] - z[foot1] > 0.3 * H), None)
    if foot2 is None:
        return _why("no second foot")
    pelvis = tree.lca(foot1, foot2)
    if pelvis >= tree.J:
        return _why("pelvis is an end site")
    legs_top = [tree.path(pelvis, f)[0] for f in (foot1, foot2)]
    upper = [
        p
        for p in tree.leaves
        if tree.under(pelvis, p) and p != pelvis and not any(tree.under(t, p) for t in legs_top)
    ]
    if len(upper) < 3:
        return _why("fewer than 3 upper leaves")
    head_leaf = max(upper, key=lambda p: z[p])
    lateral = lambda p: tree.pos[p, :2] - tree.pos[pelvis, :2]
    hand1 = max(upper, key=lambda p: np.linalg.norm(lateral(p)))
    other = [p for p in upper if lateral(p) @ lateral(hand1) < 0]
    if not other:
        return _why("no second hand")
    hand2 = max(other, key=lambda p: np.linalg.norm(lateral(p)))
    chest = tree.lca(hand1, hand2)
    if head_leaf in (hand1, hand2) or tree.lca(head_leaf, hand1) != chest or chest >= tree.J:
        return _why("head not between the arms")
    thorax = tree.path(chest, head_leaf)[0]
    if thorax >= tree.J:
        return _why("no thorax")
    leg1, leg2 = _leg(tree, pelvis, foot1), _leg(tree, pelvis, foot2)
    if leg1 is None or leg2 is None:
        return _why("short leg")
    seg = lambda a, b: float(np.linalg.norm(tree.pos[a] - tree.pos[b]))
    stature = 0.5 * sum(seg(h, k) + seg(k, a) for h, k, a in (leg1, leg2)) / 0.491
    top_parent = tree.parent[head_leaf]
    if head_leaf >= tree.J:  # an end site: the head bone ends there
        head: JointSpec = ("end_mid", names[top_parent])
    elif top_parent not in (chest, thorax) and seg(top_parent, head_leaf) >= 0.045 * stature:
        head = ("mid", names[top_parent], names[head_leaf])  # a head-top joint
    else:
        head = ("end_mid", names[head_leaf])
    if names.index(head[1]) == chest:
        return _why("head is the chest")
    arm1, arm2 = _arm(tree, chest, hand1, stature), _arm(tree, chest, hand2, stature)
    if arm1 is None or arm2 is None:
        return _why("short arm")
    forward = np.zeros(2)
    for foot, (_, _, ankle) in ((foot1, leg1), (foot2, leg2)):
        forward += tree.pos[foot, :2] - tree.pos[ankle, :2]
    if np.linalg.norm(forward) < 0.02 * H:
        return _why("no feet direction")
    left = np.array([-forward[1], forward[0]])  # ẑ × forward
    side = lambda p, centre: float((tree.pos[p, :2] - tree.pos[centre, :2]) @ left)
    if side(leg1[0], pelvis) < 0:
        leg1, leg2 = leg2, leg1
    if side(arm1[0], chest) < 0:
        arm1, arm2 = arm2, arm1
    if side(leg1[0], pelvis) <= 0 or side(leg2[0], pelvis) >= 0:
        return _why("legs same side")
    if side(arm1[0], chest) <= 0 or side(arm2[0], chest) >= 0:
        return _why("arms same side")
    if max(leg1 + leg2 + arm1 + arm2) >= tree.J:
        return _why("limb joint is an end site")
    out: dict[str, JointSpec] = {"root": names[pelvis], "thorax": names[thorax], "head": head}
    for s, (h, k, a), (sh, el, wr) in (("left", leg1, arm1), ("right", leg2, arm2)):
        out.update(
            {
                f"{s}_hip": names[h],
                f"{s}_knee": names[k],
                f"{s}_ankle": names[a],
                f"{s}_shoulder": names[sh],
                f"{s}_elbow": names[el],
                f"{s}_wrist": names[wr],
            }
        )
    return out


def upright(joints: np.ndarray) -> bool:
    """Whether evaluation joints ``(15, 3)`` stand: head over thorax over root over knees over ankles (z), the
    torso within 45° of vertical."""
    e = dict(zip(EVAL_JOINTS, joints, strict=True))
    torso = e["thorax"] - e["root"]
    if np.linalg.norm(torso) <= 0 or torso[2] < math.cos(math.radians(45)) * np.linalg.norm(torso):
        return False
    ok = e["head"][2] > e["thorax"][2] > e["root"][2]
    for s in ("left", "right"):
        ok &= e["root"][2] > e[f"{s}_knee"][2] > e[f"{s}_ankle"][2]
    return bool(ok)


def _shape_candidates(motion: Motion):
    """Poses tried by the shape pass: the rest pose, then frames at 0, ¼, ½, ¾ of the clip; each as read and
    with the file's z axis as up."""
    X, E = rest_positions(motion)
    poses = [(X, E)]
    T = motion.num_frames
    ends = motion.end_positions if motion.end_positions is not None else np.zeros((T, 0, 3))
    for t in sorted({0, T // 4, T // 2, (3 * T) // 4}):
        if t < T:
            poses.append((motion.positions[t], ends[t]))
    for A in (np.eye(3), Y_UP_TO_Z_UP):  # p @ A takes the y-up reading back to the file's axes (z up)
        for X, E in poses:
            yield X @ A, E @ A


def shape_mapping(motion: Motion) -> tuple[dict[str, JointSpec], str]:
    """The first complete shape mapping over :func:`_shape_candidates`, else ``({}, reason)`` (the reason the
    rest pose was refused)."""
    reasons = []
    for X, E in _shape_candidates(motion):
        try:
            found = _shape(motion.joint_names, motion.parents, X, motion.end_parents, E)
        except _NotABody as e:
            reasons.append(str(e))
            continue
        if not chain_errors(motion.joint_names, motion.parents, found):
            return found, ""
        reasons.append("its limbs do not form a body's chains")
    return {}, reasons[0] if reasons else "no pose"
