"""The markers of a body model written to ``poses.trc`` and ``poses.c3d``: its evaluation joints, then the centres
of its other joints.

Names: the evaluation joints the model has, in :data:`jaxmocap.geometry.body.EVAL_JOINTS` order (``root``,
``thorax``, ``head``, ``left_shoulder``, …), then the origin of every segment that lies on none of them in the rest
state (the joint the segment turns about, e.g. parsec31's ``spine`` and clavicles), named after the segment (with
``_origin`` appended where an evaluation joint has that name). Positions come from the float64 kinematics of
:func:`jaxmocap.io.body_bvh.segment_poses_np`: an evaluation joint ``k`` on segment ``s`` is ``t_s + R_s p_k``.
"""

from __future__ import annotations

import numpy as np

from jaxmocap.geometry import body as body_mod
from jaxmocap.io.body_bvh import segment_poses_np

__all__ = ["marker_names", "marker_positions"]


def _plan(model: body_mod.BodyModel) -> tuple[tuple[str, ...], list[tuple[int, int]]]:
    """Names and ``(segment, joint index or -1 for the origin)`` of every marker."""
    order = [model.joint_names.index(n) for n in body_mod.EVAL_JOINTS if n in model.joint_names]
    names = [model.joint_names[k] for k in order]
    plan = [(int(model.joint_segment[k]), k) for k in order]
    R0, t0 = segment_poses_np(model, np.asarray(model.rest_pose, np.float64)[None])
    J0 = _points(model, R0, t0, plan)[0]
    for s, seg in enumerate(model.segment_names):
        if np.min(np.linalg.norm(J0 - t0[0, s], axis=1)) > 1e-6:
            names.append(f"{seg}_origin" if seg in names else seg)
            plan.append((s, -1))
    return tuple(names), plan


def _points(model, R: np.ndarray, t: np.ndarray, plan) -> np.ndarray:
    jp = np.asarray(model.joint_point, np.float64)
    cols = [t[:, s] if k < 0 else t[:, s] + np.einsum("tab,b->ta", R[:, s], jp[k]) for s, k in plan]
    return np.stack(cols, axis=1) if cols else np.zeros((t.shape[0], 0, 3))


def marker_names(model: body_mod.BodyModel) -> tuple[str, ...]:
    """The ``M`` marker names of ``model`` (module docstring)."""
    return _plan(model)[0]


def marker_positions(model: body_mod.BodyModel, states: np.ndarray) -> tuple[tuple[str, ...], np.ndarray]:
    """``(names, positions (T, M, 3))`` in metres, z-up world, for ``states (T, D)``."""
    names, plan = _plan(model)
    R, t = segment_poses_np(model, states)
    return names, _points(model, R, t, plan)
