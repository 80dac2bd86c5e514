"""Any mocap skeleton: which of its joints are the 15 evaluation joints, its length unit and its up axis.

:func:`recognise` places :data:`jaxmocap.geometry.body.EVAL_JOINTS` on a :class:`~jaxmocap.io.mocap.Motion` in
three passes, each one filling only what the previous ones left: a mapping given by the user
(:func:`load_mapping`, TOML ``evaluation joint = "file joint"``), the joint names, then the tree's shape (both
in :mod:`jaxmocap.io.skeleton_match`). :func:`load_mocap` reads any ``.bvh`` or ``.amc``/``.asf`` clip that way.

:func:`normalise` re-roots the motion at the pelvis (nodes above it, such as Bandai's ``joint_Root``, are not
body), moves the rest pose to an upright frame when the file's is not one (Bandai's rest pose lays every bone
along its local x), gives a head without an end site of non-zero length one :data:`NOMINAL_HEAD_BONE` long along
the neck, and a bare wrist a hand :data:`NOMINAL_HAND` long along the forearm.

Units (:func:`detect_scale`): a BVH does not state its unit; the leg (thigh + shank, file units) is compared with
:data:`TYPICAL_LEG` m under each of :data:`UNIT_CANDIDATES` (mm, cm, inch, the CMU cgspeed unit, m) and the
nearest in log ratio wins. Neighbouring candidates differ by at least a factor 2.2, so any adult leg from 0.56 to
1.24 m is read in the right unit. Up axis (:func:`detect_up_axis`): the direction from the ankles to the head.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping

import numpy as np

from jaxmocap.errors import MocapInputError, load_toml
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io.mocap import (
    INCH,
    JointSpec,
    Motion,
    end_site_positions,
    forward_kinematics,
    rest_eval_joints,
    rest_positions,
    spec_joints,
)
from jaxmocap.io.skeleton_match import (
    FAMILIES,
    SYNONYMS,
    ancestors,
    chain_errors,
    is_ancestor,
    match_names,
    match_shape,
    shape_mapping,
    split_name,
    upright,
)

__all__ = [
    "FAMILIES",
    "SYNONYMS",
    "UNIT_CANDIDATES",
    "TYPICAL_LEG",
    "NOMINAL_HEAD_BONE",
    "NOMINAL_HAND",
    "Recognition",
    "split_name",
    "match_names",
    "match_shape",
    "load_mapping",
    "recognise",
    "detect_scale",
    "detect_up_axis",
    "normalise",
    "reroot",
    "rebase_rest",
    "with_end_site",
    "load_mocap",
]

#: Metres per file unit tried by :func:`detect_scale`: millimetre, centimetre, inch, CMU cgspeed unit, metre.
UNIT_CANDIDATES: dict[str, float] = {
    "mm": 0.001,
    "cm": 0.01,
    "inch": INCH,
    "cmu": INCH / 0.45,
    "m": 1.0,
}

#: Thigh + shank of an adult of 1.7 m (0.491 of the stature, Drillis & Contini), metres.
TYPICAL_LEG = 0.83

#: Length (m) given to a head bone the file leaves without one: skull base to crown of an adult.
NOMINAL_HEAD_BONE = 0.18

#: Length (m) given to a hand the file leaves without one (wrist to fingertips, 0.108 of a 1.7 m stature).
NOMINAL_HAND = 0.18


@dataclasses.dataclass(frozen=True)
class Recognition:
    """How a skeleton was read.

    Attributes:
      mapping: evaluation joint → :data:`~jaxmocap.io.mocap.JointSpec` for all 15 joints.
      family: the known family matched by names, ``"names"`` (the tokenised reading), ``"shape"``, ``"file"``
        (a user mapping) or a ``+``-joined mix (e.g. ``"names+shape"``).
      sources: evaluation joint → which pass placed it (``"file"``, ``"names"``, ``"shape"`` or a family).
      scale: metres per file unit (given or detected); scale_source: ``"given"``, ``"detected"`` or ``"file"``.
      up_axis: the file's up axis; up_source: ``"given"``, ``"detected"`` or ``"file"``.
    """

    mapping: dict
    family: str
    sources: dict
    scale: float = 1.0
    scale_source: str = "given"
    up_axis: str = "y"
    up_source: str = "given"

    def to_json(self) -> dict:
        return {
            "family": self.family,
            "mapping": {k: list(v) if isinstance(v, tuple) else v for k, v in self.mapping.items()},
            "scale": self.scale,
            "scale_source": self.scale_source,
            "up_axis": self.up_axis,
            "up_source": self.up_source,
        }


# ---------------------------------------------------------------------------------------------------------------
# Mapping files and recognition


def load_mapping(path: str | os.PathLike) -> dict[str, JointSpec]:
    """Read a TOML mapping: ``evaluation_joint = "file joint"``; ``head`` may also be ``["Head", "HeadTop"]``
    (middle of two joints) or ``["Head"]`` (middle of the joint and its end site). Unknown keys and values of
    another type raise :class:`MocapInputError`."""
    doc = load_toml(path, "mapping")
    doc = doc.get("joints", doc)
    out: dict[str, JointSpec] = {}
    for key, value in doc.items():
        if key not in EVAL_JOINTS:
            raise MocapInputError(
                path, f"unknown evaluation joint {key!r} (expected {', '.join(EVAL_JOINTS)})"
            )
        if isinstance(value, str) and value:
            out[key] = value
        elif isinstance(value, list) and len(value) in (1, 2) and all(isinstance(v, str) for v in value):
            out[key] = ("end_mid", value[0]) if len(value) == 1 else ("mid", value[0], value[1])
        else:
            raise MocapInputError(path, f"{key}: expected a joint name or a list of one or two names")
    return out


def recognise(
    motion: Motion, mapping: Mapping[str, JointSpec] | None = None, *, source: str | os.PathLike | None = None
) -> Recognition:
    """Place the 15 evaluation joints on ``motion`` (module docstring): ``mapping`` first, then names, then the
    tree's shape. Raises :class:`MocapInputError` naming the joints no pass could place (or a mapped joint the
    file lacks)."""
    where = source if source is not None else (motion.source or None)
    names = motion.joint_names
    given = dict(mapping or {})
    for key, spec in given.items():
        missing = [n for n in spec_joints(spec) if n not in names]
        if missing:
            raise MocapInputError(
                where, f"mapping {key} = {missing[0]!r}: no such joint (joints: {', '.join(names)})"
            )
    sources = dict.fromkeys(given, "file")
    result = dict(given)
    by_name, family = match_names(names, motion.parents)
    for k, v in by_name.items():
        if k not in result:
            result[k], sources[k] = v, family
    why = ""
    if len(result) < len(EVAL_JOINTS):
        by_shape, why = shape_mapping(motion)
        for k, v in by_shape.items():
            if k not in result:
                result[k], sources[k] = v, "shape"
    missing = [j for j in EVAL_JOINTS if j not in result]
    if missing:
        raise MocapInputError(
            where,
            f"cannot place the evaluation joints {', '.join(missing)} by name or by the skeleton's shape "
            f"(shape: {why}); "
            f'name them in a mapping file (--mapping, TOML: evaluation joint = "file joint")',
        )
    bad = sorted(chain_errors(names, motion.parents, result) - set(given))
    if bad:
        raise MocapInputError(where, f"the joints placed for {', '.join(bad)} do not form a body's chains")
    used = set(sources[j] for j in EVAL_JOINTS)
    kinds = [k for k in ("file", family, "shape") if k in used]
    return Recognition({j: result[j] for j in EVAL_JOINTS}, "+".join(kinds), sources)


def detect_scale(motion: Motion, mapping: Mapping[str, JointSpec]) -> tuple[float, str]:
    """``(metres per file unit, candidate name)`` of a motion read in file units (module docstring). Raises
    ``ValueError`` when no candidate gives an adult leg (0.5–1.4 m)."""
    e = dict(zip(EVAL_JOINTS, rest_eval_joints(motion, mapping), strict=True))
    leg = 0.5 * sum(
        np.linalg.norm(e[f"{s}_hip"] - e[f"{s}_knee"]) + np.linalg.norm(e[f"{s}_knee"] - e[f"{s}_ankle"])
        for s in ("left", "right")
    )
    name, s = min(
        UNIT_CANDIDATES.items(), key=lambda kv: abs(math.log(max(leg, 1e-12) * kv[1] / TYPICAL_LEG))
    )
    if not 0.5 <= leg * s <= 1.4:
        raise ValueError(f"cannot tell the length unit: the legs measure {leg:.4g} file units; pass a scale")
    return s, name


def detect_up_axis(motion: Motion, mapping: Mapping[str, JointSpec]) -> str:
    """The file's up axis (``"y"`` or ``"z"``) of a motion read as y up: the median over frames of the unit
    vector from the mean ankle to the head is along world z (file y) or world x (file z). Raises
    ``ValueError`` otherwise."""
    from jaxmocap.io.mocap import eval_joints

    ev = eval_joints(motion, mapping)
    i = {n: k for k, n in enumerate(EVAL_JOINTS)}
    d = ev[:, i["head"]] - 0.5 * (ev[:, i["left_ankle"]] + ev[:, i["right_ankle"]])
    d = np.median(d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12), axis=0)
    if d[2] > 0.7:
        return "y"
    if d[0] > 0.7:
        return "z"
    raise ValueError("cannot tell which axis is up (the ankle-to-head direction is along none of +y, +z)")


# ---------------------------------------------------------------------------------------------------------------
# Normalising a recognised motion


def _rebuild(motion: Motion, names, parents, offsets, L, tr, end_parents, end_offsets) -> Motion:
    W, X = forward_kinematics(parents, tr, L)
    rest = np.broadcast_to(offsets[1:], tr[:, 1:].shape)
    animated = tr.shape[0] > 0 and not np.allclose(tr[:, 1:], rest, rtol=0, atol=1e-12)
    return dataclasses.replace(
        motion,
        joint_names=tuple(names),
        parents=tuple(int(p) for p in parents),
        offsets=np.asarray(offsets, np.float64),
        local_rotations=L,
        root_positions=tr[:, 0].copy(),
        positions=X,
        end_parents=tuple(int(e) for e in end_parents),
        end_offsets=np.asarray(end_offsets, np.float64).reshape(-1, 3),
        end_positions=end_site_positions(W, X, end_parents, end_offsets),
        local_translations=tr if animated else None,
    )


def reroot(motion: Motion, joint: str) -> Motion:
    """The subtree of ``joint`` as a motion rooted there: the new root's rotation is its world rotation, its
    translation its world position, its rest offset its rest world position; positions are unchanged."""
    j = motion.joint_index(joint)
    if j == 0:
        return motion
    keep = [k for k in range(motion.num_joints) if j in ancestors(motion.parents, k)]
    new = {k: n for n, k in enumerate(keep)}
    tr = motion.translations()
    W, X = forward_kinematics(motion.parents, tr, motion.local_rotations)
    L = motion.local_rotations[:, keep].copy()
    tr = tr[:, keep].copy()
    L[:, 0], tr[:, 0] = W[:, j], X[:, j]
    Xr, _ = rest_positions(motion)
    offsets = motion.offsets[keep].copy()
    offsets[0] = Xr[j]
    parents = [-1] + [new[motion.parents[k]] for k in keep[1:]]
    ends = [e for e, p in enumerate(motion.end_parents) if p in new]
    return _rebuild(
        motion,
        [motion.joint_names[k] for k in keep],
        parents,
        offsets,
        L,
        tr,
        [new[motion.end_parents[e]] for e in ends],
        motion.end_offsets[ends],
    )


def rebase_rest(motion: Motion, frame: int) -> Motion:
    """The same motion with frame ``frame`` as its rest pose: with ``B_j = W_j(frame)``, local rotations
    ``L'_j = B_p L_j B_jᵀ``, translations ``t'_j = B_p t_j``, rest offsets ``B_p t_j(frame)``, end offsets
    ``B_j o``; world positions are unchanged and every ``W'_j(frame) = I``."""
    tr = motion.translations()
    W, _ = forward_kinematics(motion.parents, tr, motion.local_rotations)
    B = W[frame]  # (J, 3, 3)
    Bp = np.stack([np.eye(3) if p < 0 else B[p] for p in motion.parents])
    L = Bp[None] @ motion.local_rotations @ np.swapaxes(B, -1, -2)[None]
    tr = np.einsum("jab,tjb->tja", Bp, tr)
    offsets = tr[frame].copy()
    idx = np.asarray(motion.end_parents, np.int64)
    end_offsets = np.einsum("eab,eb->ea", B[idx], motion.end_offsets) if len(idx) else motion.end_offsets
    return _rebuild(
        motion, motion.joint_names, motion.parents, offsets, L, tr, motion.end_parents, end_offsets
    )


def with_end_site(motion: Motion, joint: str, offset: np.ndarray) -> Motion:
    """``motion`` with the first end site of ``joint`` set to ``offset (3,)`` (in the joint's frame; added when
    the joint has none)."""
    j = motion.joint_index(joint)
    end_parents = list(motion.end_parents)
    end_offsets = motion.end_offsets.copy()
    if j in end_parents:
        end_offsets[end_parents.index(j)] = offset
    else:
        end_parents.append(j)
        end_offsets = np.concatenate([end_offsets, np.asarray(offset, np.float64)[None]], 0)
    return _rebuild(
        motion,
        motion.joint_names,
        motion.parents,
        motion.offsets,
        motion.local_rotations,
        motion.translations(),
        end_parents,
        end_offsets,
    )


def normalise(motion: Motion, mapping: Mapping[str, JointSpec]) -> Motion:
    """A recognised motion (metres, z up) made ready for rendering and evaluation: re-rooted at the pelvis
    (:func:`reroot`), its rest pose moved to the most upright frame when the file's rest pose does not stand
    (:func:`rebase_rest`; the frame maximising head height above the lower ankle), a head end site of
    :data:`NOMINAL_HEAD_BONE` along the neck (the rest direction from the head's parent to the head) when the
    ``("end_mid", head)`` joint has none of non-zero length, and a hand end site of :data:`NOMINAL_HAND` along
    the forearm on a wrist with nothing past it (Bandai-Namco's hands are bare wrists)."""
    from jaxmocap.io.mocap import eval_joints

    m = reroot(motion, mapping["root"])
    if not upright(rest_eval_joints(m, _with_end(m, mapping))):
        ev = eval_joints(m, _with_end(m, mapping))
        i = {n: k for k, n in enumerate(EVAL_JOINTS)}
        height = ev[:, i["head"], 2] - np.minimum(ev[:, i["left_ankle"], 2], ev[:, i["right_ankle"], 2])
        m = rebase_rest(m, int(np.argmax(height)))
    head = mapping["head"]
    if isinstance(head, tuple) and head[0] == "end_mid":
        j = m.joint_index(head[1])
        e = m.end_parents.index(j) if j in m.end_parents else None
        if e is None or np.linalg.norm(m.end_offsets[e]) < 0.02:
            m = _extend(m, head[1], NOMINAL_HEAD_BONE)
    X, E = rest_positions(m)
    for side in ("left", "right"):
        w = m.joint_index(mapping[f"{side}_wrist"])
        beyond = [X[k] for k in range(m.num_joints) if is_ancestor(m.parents, w, k)]
        beyond += [E[e] for e, p in enumerate(m.end_parents) if p == w or is_ancestor(m.parents, w, p)]
        if not any(np.linalg.norm(x - X[w]) > 0.02 for x in beyond):
            m = _extend(m, m.joint_names[w], NOMINAL_HAND)
    return m


def _extend(m: Motion, joint: str, length: float) -> Motion:
    """``m`` with an end site ``length`` metres beyond ``joint`` along its rest bone (parent → joint)."""
    d = m.offsets[m.joint_index(joint)]
    n = float(np.linalg.norm(d))
    if n < 1e-9:
        raise ValueError(f"{m.source}: the joint {joint!r} has no bone to extend")
    return with_end_site(m, joint, length * d / n)


def _with_end(motion: Motion, mapping: Mapping[str, JointSpec]) -> dict[str, JointSpec]:
    """``mapping`` with an ``end_mid`` head on a joint without end site read as the joint itself."""
    head = mapping["head"]
    if (
        isinstance(head, tuple)
        and head[0] == "end_mid"
        and motion.joint_index(head[1]) not in motion.end_parents
    ):
        return {**mapping, "head": head[1]}
    return dict(mapping)


# ---------------------------------------------------------------------------------------------------------------
# Loading any clip


def load_mocap(
    path: str | os.PathLike,
    *,
    asf: str | os.PathLike | None = None,
    scale: float | None = None,
    up_axis: str | None = None,
    mapping: Mapping[str, JointSpec] | str | os.PathLike | None = None,
    fps: float = 120.0,
) -> tuple[Motion, Recognition]:
    """Load a ``.bvh`` or ``.amc`` (with its ``asf``) clip of any skeleton, recognised and normalised.

    Args:
      path: the clip. asf: the ASF skeleton of an ``.amc`` (required for one).
      scale: metres per file unit; ``None`` detects it for a BVH (:func:`detect_scale`) and reads it from the
        ASF units for ASF/AMC.
      up_axis: ``"y"``/``"z"``; ``None`` detects it for a BVH (:func:`detect_up_axis`), ``"y"`` for ASF/AMC.
      mapping: a mapping (or a TOML file, :func:`load_mapping`) placing some or all evaluation joints.
      fps: frame rate of an ``.amc`` (not recorded in the file).

    Returns ``(motion, recognition)``: the motion in metres, z up, after :func:`normalise`; ``recognition``
    says how every joint, the unit and the axis were found. Bad input raises :class:`MocapInputError`.
    """
    from jaxmocap.io import asfamc, bvh
    from jaxmocap.io.mocap import motion_in_units

    if scale is not None and not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number of metres per unit, got {scale!r}")
    if up_axis not in (None, "y", "z"):
        raise ValueError(f"up axis must be y or z, got {up_axis!r}")
    if mapping is not None and not isinstance(mapping, Mapping):
        mapping = load_mapping(mapping)
    ext = os.fspath(path).lower().rsplit(".", 1)[-1]
    if ext == "bvh":
        data = bvh.read_bvh(path)
        raw = bvh.motion_from_bvh(data, scale=1.0, up_axis="y", source=os.fspath(path))
    elif ext == "amc":
        if asf is None:
            raise MocapInputError(path, "an .amc motion needs its .asf skeleton")
        skel = asfamc.read_asf(asf)
        values, unit = asfamc.read_amc(path, skel)
        raw = asfamc.motion_from_asfamc(skel, values, unit, fps=fps, scale=1.0, source=os.fspath(path))
        scale = skel.scale if scale is None else scale
        up_axis = "y" if up_axis is None else up_axis
    else:
        raise MocapInputError(path, f"unknown motion format .{ext} (expected .bvh, or .amc with an .asf)")
    rec = recognise(raw, mapping, source=path)
    try:
        up_source = "given" if up_axis is not None or ext == "amc" else "detected"
        up = up_axis if up_axis is not None else detect_up_axis(raw, _with_end(raw, rec.mapping))
        upright = motion_in_units(raw, 1.0, up)
        if scale is None:
            scale, _ = detect_scale(upright, _with_end(upright, rec.mapping))
            scale_source = "detected"
        else:
            scale_source = "file" if ext == "amc" and asf is not None and scale == skel.scale else "given"
        m = normalise(motion_in_units(raw, scale, up), rec.mapping)
    except ValueError as e:
        raise MocapInputError(path, str(e)) from None
    rec = dataclasses.replace(
        rec, scale=float(scale), scale_source=scale_source, up_axis=up, up_source=up_source
    )
    return m, rec
