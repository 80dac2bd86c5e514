"""BVH of a body model's motion, laid out the way Blender, MotionBuilder and the common NumPy BVH loaders read it.

**Hierarchy.** One BVH joint per segment, named after it (``torso``, ``left_upper_arm``, …), plus one joint per
evaluation joint that is not a segment origin (wrists, ankles, the head centre, full25's thorax, …), a child of
its segment named after the evaluation joint (``<name>_centre`` where a segment already has that name, e.g.
``head_centre``), so that every evaluation joint is the head of a bone in Blender. Only leaves carry an ``End
Site``: the far end of the segment's flesh, or a 5 cm stub along the bone where that end is not beyond the joint.

**Channels.** The root has ``Xposition Yposition Zposition`` followed by three rotations; every other joint has
exactly three rotation channels, all in one order for the whole file (:data:`ROTATION_ORDER`, ``Zrotation
Xrotation Yrotation``: ``L = Rz·Rx·Ry``), zeros about the axes where the model has no freedom. A segment whose
rotational DOFs turn about distinct ± file axes in an order that is a subsequence of :data:`ROTATION_ORDER` (and
whose rest frame is the world's) gets its DOFs themselves (``±θ`` in degrees) as channel values — full25's
shoulders, hips, neck (``rx ry rz`` in the z-up world are ``Z X Y`` in the y-up file), elbows and knees; any
other segment the Euler angles of its local rotation (:func:`jaxmocap.io.mocap.matrix_to_euler`), unwrapped over
time.

**Rest pose.** The file's rest pose (all channels zero) is the model at its rest state ``model.rest_pose``
(standing, arms down, facing +Z with its left towards +X as in the CMU files): each BVH joint frame is the
segment's frame ``R_s`` times the constant ``Q_s = (R_s⁰)ᵀ`` of its rest-state rotation ``R_s⁰``, so that every
frame is parallel to the file's axes at rest. An ``OFFSET`` is then the rest-state displacement from the parent,
``R_p⁰ o_s``, and a local rotation ``L_s = (R_p Q_p)ᵀ (R_s Q_s)``. The root's ``OFFSET`` is its rest position
(full25's feet touch the floor in Blender's rest pose) and its position channels the absolute position, which
replace the ``OFFSET`` (as Blender's importer, bvhio, pybvh and :func:`jaxmocap.io.bvh.load_bvh` read them).

**Units and axes.** ``scale`` metres per file unit: :data:`UNITS` ``cm`` (0.01, the default; import into Blender
with Scale 0.01 for metres) or ``m`` (1.0). The file is y up, mapped from the z-up world by
``(x, y, z)_file = (y, z, x)_world``. Kinematics here is NumPy float64 (the same product of exponentials as
:mod:`jaxmocap.geometry.kinematics`: ``g_s = g_parent · (rest_rotation_s, offset_s) · Π_k exp(ξ̂_k θ_k)``).
"""

from __future__ import annotations

import contextlib
import os
import pathlib
import tempfile
from typing import NamedTuple

import numpy as np

from jaxmocap.geometry import body as body_mod
from jaxmocap.io import bvh
from jaxmocap.io.mocap import Motion, matrix_to_euler, up_axis_matrix

__all__ = [
    "ROTATION_ORDER",
    "UNITS",
    "bvh_eval_joints",
    "bvh_joint_names",
    "model_bvh",
    "save_model_bvh",
    "segment_poses_np",
]

#: Rotation channel order of every joint (outermost first): ``Zrotation Xrotation Yrotation``.
ROTATION_ORDER = "ZXY"
#: Metres per file unit of ``--bvh-units``.
UNITS = {"cm": 0.01, "m": 1.0}
#: Length (metres) of the end site of a joint whose segment has no flesh beyond it.
STUB = 0.05

_AXES = "XYZ"
_POS = ("Xposition", "Yposition", "Zposition")


def _rodrigues(axis: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """``exp(ω̂θ)`` for a unit axis ``(3,)`` and angles ``(T,)`` → ``(T, 3, 3)``."""
    w = np.asarray(axis, np.float64)
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3) + s * W + (1.0 - c) * (W @ W)


def segment_poses_np(model: body_mod.BodyModel, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World rotations ``(T, S, 3, 3)`` and origins ``(T, S, 3)`` of every segment for ``states (T, D)``, in
    float64 (:func:`jaxmocap.geometry.body.segment_poses` in NumPy)."""
    topo = model.topology
    X = np.asarray(states, np.float64).reshape(-1, model.num_dofs)
    T, S = X.shape[0], len(topo.segment_names)
    rest_R = np.asarray(model.rest_rotation, np.float64)
    offset = np.asarray(model.offset, np.float64)
    axes = np.asarray(model.dof_axis, np.float64)
    R, t = np.empty((T, S, 3, 3)), np.empty((T, S, 3))
    for s in range(S):
        Rl = np.broadcast_to(rest_R[s], (T, 3, 3)).copy()
        tl = np.broadcast_to(offset[s], (T, 3)).copy()
        for d in topo.segment_dofs[s]:
            if topo.dof_kinds[d] == "P":
                tl = tl + np.einsum("tab,b->ta", Rl, axes[d]) * X[:, d, None]
            else:
                Rl = Rl @ _rodrigues(axes[d], X[:, d])
        p = topo.parents[s]
        if p < 0:
            R[:, s], t[:, s] = Rl, tl
        else:
            R[:, s] = R[:, p] @ Rl
            t[:, s] = t[:, p] + np.einsum("tab,tb->ta", R[:, p], tl)
    return R, t


class _Layout(NamedTuple):
    """The BVH joints of a model: segments ``0..S-1`` then the extra evaluation joints."""

    names: tuple[str, ...]
    parents: tuple[int, ...]
    extra: tuple[int, ...]  # model.joint_names index of each extra joint
    eval_joint: tuple[int, ...]  # BVH joint of each of model.joint_names


def _layout(model: body_mod.BodyModel) -> _Layout:
    topo = model.topology
    names, parents = list(topo.segment_names), list(topo.parents)
    extra, eval_joint = [], []
    jp = np.asarray(model.joint_point, np.float64)
    for k, (name, s) in enumerate(zip(model.joint_names, model.joint_segment, strict=True)):
        if np.linalg.norm(jp[k]) <= 1e-9:
            eval_joint.append(int(s))
            continue
        eval_joint.append(len(names))
        names.append(f"{name}_centre" if name in names else name)
        parents.append(int(s))
        extra.append(k)
    return _Layout(tuple(names), tuple(parents), tuple(extra), tuple(eval_joint))


def bvh_joint_names(model: body_mod.BodyModel) -> tuple[str, ...]:
    """The BVH joint at each of ``model.joint_names`` (the segment for an evaluation joint at a segment origin)."""
    lay = _layout(model)
    return tuple(lay.names[j] for j in lay.eval_joint)


def _direct_plan(model, s: int, A: np.ndarray, Q: np.ndarray) -> list[tuple[int, int, float]] | None:
    """``[(dof, channel slot in ROTATION_ORDER, sign), …]`` when segment ``s``'s DOFs can be its channels (module
    docstring), else None."""
    topo = model.topology
    p = topo.parents[s]
    frames_aligned = np.allclose(Q[s], np.eye(3), atol=1e-9) and (
        p < 0 or np.allclose(Q[p], np.eye(3), atol=1e-9)
    )
    if not frames_aligned or not np.allclose(np.asarray(model.rest_rotation)[s], np.eye(3), atol=1e-9):
        return None
    plan, last = [], -1
    for d in topo.segment_dofs[s]:
        if topo.dof_kinds[d] == "P":
            if p >= 0:
                return None
            continue
        v = A.T @ np.asarray(model.dof_axis, np.float64)[d]  # the DOF axis in the file's frame
        k = int(np.argmax(np.abs(v)))
        if not np.isclose(abs(v[k]), 1.0, atol=1e-9) or float(np.asarray(model.rest_pose)[d]) != 0.0:
            return None
        slot = ROTATION_ORDER.index(_AXES[k])
        if slot <= last:
            return None
        plan.append((d, slot, float(np.sign(v[k]))))
        last = slot
    return plan


def model_bvh(
    model: body_mod.BodyModel, states: np.ndarray, fps: float, *, scale: float = 0.01, up_axis: str = "y"
) -> bvh.BvhData:
    """The BVH content of a state sequence ``states (T, D)`` of ``model`` (metres, radians, z up).

    Args:
      fps: frames per second; scale: metres per written unit (:data:`UNITS`); up_axis: the file's up axis.

    Returns:
      :class:`jaxmocap.io.bvh.BvhData` laid out as the module docstring says (write it with
      :func:`jaxmocap.io.bvh.save_bvh`).
    """
    states = np.asarray(states, np.float64)
    if states.ndim != 2 or states.shape[1] != model.num_dofs:
        raise ValueError(f"states must be (T, {model.num_dofs}), got {states.shape}")
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number of metres per unit, got {scale!r}")
    A = up_axis_matrix(up_axis)
    topo = model.topology
    S, T = len(topo.segment_names), states.shape[0]
    lay = _layout(model)
    R0, t0 = segment_poses_np(model, np.asarray(model.rest_pose, np.float64)[None])
    R0, t0 = R0[0], t0[0]
    Q = np.swapaxes(R0, -1, -2)  # Q_s = (R_s⁰)ᵀ
    to_file = lambda v: (A.T @ v) / scale  # a world vector in file units
    offset = np.asarray(model.offset, np.float64)  # one transfer (indexing the device array runs programs)
    offsets = [to_file(t0[0])] + [to_file(R0[p] @ offset[s]) for s, p in enumerate(topo.parents) if p >= 0]
    jp = np.asarray(model.joint_point, np.float64)
    shape_end = np.asarray(model.shape_end, np.float64)
    offsets += [to_file(R0[model.joint_segment[k]] @ jp[k]) for k in lay.extra]

    R, t = segment_poses_np(model, states)
    B = R @ Q  # BVH joint frames
    rot_names = tuple(f"{a}rotation" for a in ROTATION_ORDER)
    channels: list[tuple[str, ...]] = []
    cols: list[np.ndarray] = []
    for s in range(S):
        p = topo.parents[s]
        moves = p < 0 or any(topo.dof_kinds[d] == "P" for d in topo.segment_dofs[s])
        if moves:
            local_t = t[:, s] if p < 0 else np.einsum("tba,tb->ta", B[:, p], t[:, s] - t[:, p])
            cols.append(local_t @ A / scale)  # Aᵀ t, row form
        plan = _direct_plan(model, s, A, Q)
        if plan is not None:
            eul = np.zeros((T, 3))
            for d, slot, sign in plan:
                eul[:, slot] = sign * np.rad2deg(states[:, d])
        else:
            L = B[:, s] if p < 0 else np.swapaxes(B[:, p], -1, -2) @ B[:, s]
            eul = np.rad2deg(matrix_to_euler(A.T @ L @ A, ROTATION_ORDER)) if T else np.zeros((0, 3))
        cols.append(np.unwrap(eul, period=360.0, axis=0) if T else eul)
        channels.append((_POS if moves else ()) + rot_names)
    for _ in lay.extra:
        cols.append(np.zeros((T, 3)))
        channels.append(rot_names)
    frames = np.concatenate(cols, axis=1) if cols else np.zeros((T, 0))

    # end sites on the leaves: the flesh end beyond the joint, else a stub along the bone
    has_child = np.zeros(len(lay.names), bool)
    has_child[[p for p in lay.parents if p >= 0]] = True
    seg_has_child = np.zeros(S, bool)
    seg_has_child[[p for p in topo.parents if p >= 0]] = True
    end_parents, end_offsets = [], []
    for j in np.flatnonzero(~has_child):
        if j < S:  # a leaf segment: its flesh end
            s, base, along = j, np.zeros(3), offset[j]
        else:  # an evaluation joint: the flesh end beyond it on a leaf segment
            k = lay.extra[j - S]
            s, base = model.joint_segment[k], jp[k]
            along = base
        tip = shape_end[s] - base
        flesh = model.shape_kind[s] != body_mod.SHAPE_NONE and np.linalg.norm(tip) > 0.01
        if flesh and (j < S or (not seg_has_child[s] and float(tip @ base) > 0)):
            end = tip
        else:
            n = np.linalg.norm(along)
            end = STUB * (along / n if n > 1e-9 else np.array([0.0, 0.0, 1.0]))
        end_parents.append(int(j))
        end_offsets.append(to_file(R0[s] @ end))
    return bvh.BvhData(
        names=lay.names,
        parents=lay.parents,
        offsets=np.stack(offsets),
        channels=tuple(channels),
        frames=frames,
        frame_time=1.0 / float(fps),
        end_parents=tuple(end_parents),
        end_offsets=np.asarray(end_offsets, np.float64).reshape(-1, 3),
    )


def save_model_bvh(
    path: str | os.PathLike,
    model: body_mod.BodyModel,
    states: np.ndarray,
    fps: float,
    *,
    scale: float = 0.01,
    up_axis: str = "y",
    precision: int = 6,
) -> None:
    """Write :func:`model_bvh` to ``path`` atomically (a temporary file in the same folder, then ``os.replace``)."""
    data = model_bvh(model, states, fps, scale=scale, up_axis=up_axis)
    path = pathlib.Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o666 & ~mask)
        bvh.save_bvh(tmp, data, precision=precision)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def bvh_eval_joints(motion: Motion, model: body_mod.BodyModel) -> np.ndarray:
    """Evaluation joints ``(T, J_model, 3)`` (``model.joint_names`` order, metres) of a BVH written by
    :func:`save_model_bvh` and read back by :func:`jaxmocap.io.bvh.load_bvh` (joints named by
    :func:`bvh_joint_names`)."""
    idx = [motion.joint_index(n) for n in bvh_joint_names(model)]
    return motion.positions[:, idx]
