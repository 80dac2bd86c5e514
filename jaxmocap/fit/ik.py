"""Inverse kinematics: fit a :class:`~jaxmocap.geometry.body.BodyModel` state to 3D joint positions.

Pose fitting (:func:`fit_pose`) solves, for one frame,

.. math::

    x^\\star = \\arg\\min_x \\; \\sum_j w_j \\,\\| f_j(x) - y_j \\|^2 \\; + \\; \\lambda \\sum_{d \\in P} (x_d - \\bar x_d)^2

with ``f_j`` the model's evaluation joints (:func:`jaxmocap.geometry.body.joint_positions`, in ``model.joint_names``
order), ``y_j`` the targets (NaN = missing, weight 0), ``x̄ = model.rest_pose`` and ``P`` the bounded joint
angles (the prior leaves the root translation and the unbounded heading alone). It runs Levenberg–Marquardt
(:func:`jaxmocap.fit.solvers.least_squares`).

Joint limits are respected by a smooth reparametrisation: every bounded angle is
``x_d = c_d + h_d sin u_d`` with ``c = (lower + upper)/2``, ``h = (upper − lower)/2``, and the solver works on
the unconstrained ``u`` (root translation and angles whose range spans a full turn use ``x_d = u_d``). The
result is therefore inside the limits by construction; the start point is pulled 2 % of the range inside so
that no angle starts where ``cos u = 0``.

The root is initialised by a weighted Procrustes (Kabsch) fit of the trunk's joints (those no DOF outside the
trunk moves: root, thorax, shoulders and hips for ``full25``) at the rest pose to their targets; the
rotation is then split into the model's root angles (``root_rz, root_ry, root_rx`` as ``Rz·Ry·Rx``, or a
single heading ``*_rz``, recognised by name).

The kinematics inside the solver (:func:`joints_and_jacobian`) is the body model's product of exponentials
evaluated with 4×4 transforms batched over segments and tree levels, with the geometric Jacobian: it equals
:func:`jaxmocap.geometry.body.joint_positions` (tested; its Jacobian against central differences) and compiles several
times faster inside the solver's loops than the per-coordinate hot-path kinematics.

:func:`fit_pose_2d` fits the same state to the 2D detections of every view instead (reprojection error in pixels),
which the body's known limb lengths make better posed than the triangulated targets when the views are close
together (see its docstring).

:func:`from_head_hands` is the importance-sampling IK of Fontmarty et al. (IROS 2007, §IV-A): from 3D head and
hand positions, the configuration nearest to the rest pose that puts the head and wrists there — the same
least squares with only those three targets and a stronger prior.

Everything is pure, jit-able and vmap-able: vmap :func:`fit_pose` over frames, or use :func:`fit_sequence`,
which warm-starts each frame from the previous one with ``lax.scan``. The solver core is jitted once per model
structure and array shapes, so eager calls (and eager vmaps) of :func:`fit_pose` and :func:`from_head_hands`
share one compilation; a new frame never recompiles.
"""

from __future__ import annotations

import functools
import math
import re
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.fit import solvers
from jaxmocap.geometry import camera, kinematics
from jaxmocap.geometry.body import EVAL_JOINTS, BodyModel
from jaxmocap.geometry.body import trunk_segments as body_trunk
from jaxmocap.io.mocap import matrix_to_euler
from jaxmocap.stored_programs import stored_jit
from jaxmocap.transfer import to_device

_MARGIN = 0.98  # start points are pulled inside this fraction of each bounded range
_FULL_TURN = 2.0 * math.pi - 1e-3


class PoseFit(NamedTuple):
    """Result of a fit (add a leading ``T`` axis for sequences).

    Attributes:
      state: ``(D,)`` fitted state (``model.dof_names`` order), inside the joint limits.
      errors: ``(J,)`` distance from each fitted joint to its target, metres (NaN where the target is missing).
      value: final objective ``½ Σ r²``; iterations: Levenberg–Marquardt iterations used.
    """

    state: jnp.ndarray
    errors: jnp.ndarray
    value: jnp.ndarray
    iterations: jnp.ndarray


# ---------------------------------------------------------------------------------------------------------------
# Limits as a reparametrisation


def _bounds(model: BodyModel):
    angular = jnp.asarray(model.angular)
    span = model.upper - model.lower
    bounded = angular & (span < _FULL_TURN)
    c = 0.5 * (model.upper + model.lower)
    h = jnp.where(bounded, 0.5 * span, 1.0)
    return bounded, c, h


def to_state(model: BodyModel, u: jnp.ndarray) -> jnp.ndarray:
    """State ``x`` of the unconstrained parameters ``u``: ``c + h sin u`` on bounded angles, ``u`` elsewhere."""
    bounded, c, h = _bounds(model)
    return jnp.where(bounded, c + h * jnp.sin(u), u)


def from_state(model: BodyModel, x: jnp.ndarray) -> jnp.ndarray:
    """Unconstrained parameters of a state (clamped to the limits, bounded angles pulled 2 % inside)."""
    bounded, c, h = _bounds(model)
    x = jnp.clip(x, model.lower, model.upper)
    s = jnp.clip((x - c) / h, -_MARGIN, _MARGIN)
    return jnp.where(bounded, jnp.arcsin(s), x)


def prior_mask(model: BodyModel) -> jnp.ndarray:
    """``(D,)`` bool: the state entries pulled towards ``model.rest_pose`` (bounded angles)."""
    return _bounds(model)[0]


# ---------------------------------------------------------------------------------------------------------------
# Root initialisation


def _root_dofs(model: BodyModel) -> tuple[list[int], list[int], str]:
    """Root translation DOF indices, root rotation DOF indices and their axis letters (from the names)."""
    topo = model.topology
    dofs = topo.segment_dofs[0]
    trans = [k for k in dofs if topo.dof_kinds[k] == "P"]
    rots = [k for k in dofs if topo.dof_kinds[k] == "R"]
    letters = ""
    for k in rots:
        m = re.search(r"_r([xyz])$", topo.dof_names[k])
        letters += m.group(1) if m else "?"
    return trans, rots, letters


def kabsch(P: jnp.ndarray, Q: jnp.ndarray, w: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Weighted rigid fit ``Q ≈ R P + t`` (Kabsch): ``P, Q (N, 3)``, ``w (N,) ≥ 0``. Returns ``R (3,3)``, ``t (3,)``.

    ``H = Σ w (p − p̄)(q − q̄)ᵀ = U S Vᵀ``, ``R = V diag(1, 1, det(V Uᵀ)) Uᵀ``, ``t = q̄ − R p̄`` (weighted means).
    Fewer than three weighted points give the identity rotation.
    """
    W = jnp.sum(w)
    Ws = jnp.where(W > 0, W, 1.0)
    pm = jnp.sum(w[:, None] * P, 0) / Ws
    qm = jnp.sum(w[:, None] * Q, 0) / Ws
    H = (w[:, None] * (P - pm)).T @ (Q - qm)
    U, _, Vt = jnp.linalg.svd(H)
    d = jnp.sign(jnp.linalg.det(Vt.T @ U.T))
    d = jnp.where(d == 0, 1.0, d)
    R = Vt.T @ jnp.diag(jnp.stack([jnp.ones_like(d), jnp.ones_like(d), d])) @ U.T
    R = jnp.where(jnp.sum(w > 0) >= 3, R, jnp.eye(3, dtype=P.dtype))
    return R, qm - R @ pm


def _clean(targets, weights):
    targets = jnp.asarray(targets)
    finite = jnp.all(jnp.isfinite(targets), axis=-1)
    w = jnp.where(finite, weights, 0.0)
    return jnp.where(finite[:, None], targets, 0.0), w


def _set_root(model: BodyModel, x: jnp.ndarray, R: jnp.ndarray, t: jnp.ndarray) -> jnp.ndarray:
    """Write root rotation ``R`` (split into the root angles) and translation ``t`` (root origin) into ``x``."""
    trans, rots, letters = _root_dofs(model)
    if len(rots) == 3 and sorted(letters) == ["x", "y", "z"]:
        x = x.at[jnp.asarray(rots)].set(matrix_to_euler(R, letters.upper(), xp=jnp).astype(x.dtype))
    elif len(rots) == 1 and letters in ("x", "y", "z"):
        a = "xyz".index(letters)
        b, c = (a + 1) % 3, (a + 2) % 3
        ang = jnp.arctan2(R[c, b] - R[b, c], R[b, b] + R[c, c])
        x = x.at[rots[0]].set(ang.astype(x.dtype))
    if trans:
        A = model.dof_axis[jnp.asarray(trans)].T  # (3, nP)
        o = model.offset[0]
        x = x.at[jnp.asarray(trans)].set((jnp.linalg.pinv(A) @ (t - o)).astype(x.dtype))
    return x


@stored_jit
def root_init(model: BodyModel, targets: jnp.ndarray, weights: jnp.ndarray | None = None) -> jnp.ndarray:
    """A start state: the rest pose with the root placed by Procrustes on the joints of the trunk.

    Args:
      targets: ``(J, 3)`` in ``model.joint_names`` order, NaN = missing; weights: ``(J,)`` (default ones).

    Uses the joints that no DOF outside the trunk (:func:`jaxmocap.geometry.body.trunk_segments`) moves, the trunk
    at its rest pose (``full25``: root, thorax, shoulders, hips; ``full32``, whose girdles move the shoulders:
    root, thorax, hips) when at least three of them have targets, else every joint with a target.
    """
    J = len(model.joint_names)
    weights = jnp.ones(J, model.lower.dtype) if weights is None else jnp.asarray(weights)
    Q, w = _clean(targets, weights)
    trans, rots, _ = _root_dofs(model)
    root_dofs = jnp.asarray(trans + rots, dtype=jnp.int32)
    x_ref = model.rest_pose.at[root_dofs].set(0.0)
    P, jac = joints_and_jacobian(model, x_ref)  # P in the root frame (plus the root offset)
    # joints of the trunk: no DOF outside it moves them (shoulder and hip centres included)
    others = np.ones(model.num_dofs, dtype=bool)
    others[[d for s in body_trunk(model) for d in model.topology.segment_dofs[s]]] = False
    rigid = ~jnp.any(jnp.abs(jac[:, :, others]) > 1e-6, axis=(1, 2))
    w_root = jnp.where(rigid, w, 0.0)
    w_use = jnp.where(jnp.sum(w_root > 0) >= 3, w_root, w)
    o = model.offset[0]
    R, t = kabsch(P - o, Q, w_use)
    # model: X = o + t_dofs + R p_local with p_local = P - o; fitted: X = R (P - o) + t  =>  origin o + t_dofs = t
    return clip_into(model, _set_root(model, model.rest_pose, R, t))


def clip_into(model: BodyModel, x: jnp.ndarray) -> jnp.ndarray:
    """Clamp to the joint limits."""
    return jnp.clip(x, model.lower, model.upper)


# ---------------------------------------------------------------------------------------------------------------
# Compact forward kinematics with the geometric Jacobian


def _ancestry(model: BodyModel) -> np.ndarray:
    """``(J, D)`` static bool: DOF ``k`` moves joint ``j`` (it acts on j's segment or an ancestor)."""
    topo = model.topology
    out = np.zeros((len(model.joint_names), topo.num_dofs), dtype=bool)
    for j, s in enumerate(model.joint_segment):
        while s >= 0:
            out[j, list(topo.segment_dofs[s])] = True
            s = topo.parents[s]
    return out


@functools.lru_cache(maxsize=32)
def _layout(topo) -> dict:
    """Static index arrays of a topology for the level-batched kinematics (cached per topology)."""
    S, D = topo.num_segments, topo.num_dofs
    m = max(1, max(len(d) for d in topo.segment_dofs))
    slot_dof = np.full((S, m), D, dtype=np.int32)  # D = padding (identity transform)
    dof_seg = np.zeros(D, dtype=np.int32)
    dof_slot = np.zeros(D, dtype=np.int32)
    for s, dofs in enumerate(topo.segment_dofs):
        for i, k in enumerate(dofs):
            slot_dof[s, i], dof_seg[k], dof_slot[k] = k, s, i
    depth = np.zeros(S, dtype=np.int32)
    for s, p in enumerate(topo.parents):
        depth[s] = 0 if p < 0 else depth[p] + 1
    levels = [np.flatnonzero(depth == d).astype(np.int32) for d in range(int(depth.max()) + 1)]
    parents = np.asarray(topo.parents, dtype=np.int32)
    return dict(m=m, slot_dof=slot_dof, dof_seg=dof_seg, dof_slot=dof_slot, levels=levels, parents=parents)


def _homogeneous(R, t):
    """``(..., 4, 4)`` from ``R (..., 3, 3)`` and ``t (..., 3)``."""
    top = jnp.concatenate([R, t[..., None]], -1)
    bottom = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 0.0, 1.0], R.dtype), top.shape[:-2] + (1, 4))
    return jnp.concatenate([top, bottom], -2)


def joints_and_jacobian(model: BodyModel, x: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Joint positions ``(J, 3)`` and their Jacobian ``∂X/∂x (J, 3, D)`` for one state.

    The same product of exponentials as :func:`jaxmocap.geometry.body.joint_positions`, evaluated with 4×4 transforms
    batched over segments (each segment's DOFs slot by slot, then the tree level by level) and products written
    as broadcast multiply-adds: a few large fused operations, quick to compile inside the solver's loops and
    about 0.015 ms a frame for ``full25`` on a CPU core when vmapped. The Jacobian is the geometric one: a revolute DOF
    ``k`` with world axis ``ω_k`` through the point ``q_k`` moves a descendant joint by ``ω_k × (X_j − q_k)``,
    a prismatic one by its world axis.
    """
    topo = model.topology
    lay = _layout(topo)
    dtype = x.dtype
    S = topo.num_segments
    axes = model.dof_axis.astype(dtype)
    revolute = np.asarray([k == "R" for k in topo.dof_kinds])
    eye = jnp.eye(3, dtype=dtype)
    rot = jnp.where(revolute[:, None, None], _rodrigues(axes, x), eye)
    shift = jnp.where(revolute[:, None], 0.0, axes * x[:, None])
    G = _homogeneous(jnp.concatenate([rot, eye[None]]), jnp.concatenate([shift, jnp.zeros((1, 3), dtype)]))
    # prefixes[i]: rest transform times the segment's first i DOF transforms, (S, 4, 4)
    prefixes = [_homogeneous(model.rest_rotation.astype(dtype), model.offset.astype(dtype))]
    for i in range(lay["m"]):
        prefixes.append(_mm(prefixes[-1], G[lay["slot_dof"][:, i]]))
    local = prefixes[-1]
    world = jnp.zeros((S, 4, 4), dtype)
    eye4 = jnp.eye(4, dtype=dtype)
    for level in lay["levels"]:
        par = lay["parents"][level]
        base = jnp.where((par >= 0)[:, None, None], world[np.maximum(par, 0)], eye4)
        world = world.at[level].set(_mm(base, local[level]))
    par = lay["parents"]
    parent_world = jnp.where((par >= 0)[:, None, None], world[np.maximum(par, 0)], eye4)  # (S, 4, 4)
    before = _mm(parent_world[lay["dof_seg"]], jnp.stack(prefixes[:-1], 1)[lay["dof_seg"], lay["dof_slot"]])
    A = jnp.sum(before[:, :3, :3] * axes[:, None, :], -1)  # world axis of each DOF, (D, 3)
    Q = before[:, :3, 3]  # the point it acts through, (D, 3)
    seg = np.asarray(model.joint_segment)
    X = jnp.sum(world[seg, :3, :3] * model.joint_point.astype(dtype)[:, None, :], -1) + world[seg, :3, 3]
    lever = X[:, None, :] - Q[None, :, :]  # (J, D, 3)
    moves = jnp.where(revolute[None, :, None], jnp.cross(A[None], lever), A[None])
    jac = jnp.where(_ancestry(model)[:, :, None], moves, 0.0)
    return X, jnp.swapaxes(jac, 1, 2)


def model_joints(model: BodyModel, x: jnp.ndarray) -> jnp.ndarray:
    """``(J, 3)`` joint positions (equal to :func:`jaxmocap.geometry.body.joint_positions`; see
    :func:`joints_and_jacobian`)."""
    return joints_and_jacobian(model, x)[0]


def _mm(A, B):
    """``A @ B`` over the last two axes as one broadcast multiply and sum: XLA on CPU runs this fused about 6×
    faster than many tiny batched matrix products (and compiles it faster)."""
    return jnp.sum(A[..., :, :, None] * B[..., None, :, :], axis=-2)


def _rodrigues(axis, theta):
    """``(D, 3, 3)`` rotations ``cos θ I + sin θ ŵ + (1 − cos θ) w wᵀ`` (eq. 2.6) of unit axes ``(D, 3)``."""
    c, s = jnp.cos(theta)[:, None, None], jnp.sin(theta)[:, None, None]
    eye = jnp.eye(3, dtype=axis.dtype)
    return c * eye + s * kinematics.hat(axis) + (1.0 - c) * axis[:, :, None] * axis[:, None, :]


# ---------------------------------------------------------------------------------------------------------------
# Fitting


def _residual(u, model, targets, w_sqrt, rest, prior_sqrt, u0, free):
    x = to_state(model, jnp.where(free, u, u0))
    X, _ = joints_and_jacobian(model, x)
    r_joints = (w_sqrt[:, None] * (X - targets)).ravel()
    return jnp.concatenate([r_joints, prior_sqrt * (x - rest)])


def _residual_jac(u, model, targets, w_sqrt, rest, prior_sqrt, u0, free):
    bounded, c, h = _bounds(model)
    u = jnp.where(free, u, u0)
    x = to_state(model, u)
    dx_du = jnp.where(free, jnp.where(bounded, h * jnp.cos(u), 1.0), 0.0)
    _, J = joints_and_jacobian(model, x)
    Jj = (w_sqrt[:, None, None] * J * dx_du).reshape(-1, u.shape[0])
    return jnp.concatenate([Jj, jnp.diag(prior_sqrt * dx_du)])


def fit_pose(
    model: BodyModel,
    targets: jnp.ndarray,
    weights: jnp.ndarray | None = None,
    init: jnp.ndarray | None = None,
    prior_weight: float = 1e-4,
    mask: jnp.ndarray | None = None,
    free: jnp.ndarray | None = None,
    prior_mean: jnp.ndarray | None = None,
    maxiter: int = 30,
    tol: float = 1e-6,
) -> PoseFit:
    """Fit the model's state to 3D joint positions by least squares (see the module docstring).

    Args:
      model: the body model.
      targets: ``(J, 3)`` metres, ``model.joint_names`` order; NaN rows are missing.
      weights: ``(J,)`` per-joint weights ``w_j`` (default 1, in 1/m²).
      init: ``(D,)`` start state; default :func:`root_init` (rest pose placed by Procrustes).
      prior_weight: ``λ`` in 1/rad² (``1e-4``: one radian away from the prior mean costs as much as a 1 cm
        joint error).
      mask: ``(J,)`` bool, joints to use (default all).
      free: ``(D,)`` bool, state entries the fit may change (default all); the others keep their ``init``
        value (clamped to the limits, bounded angles at most 98 % of the way to a limit).
      prior_mean: ``(D,)`` the ``x̄`` of the prior (default ``model.rest_pose``).
      maxiter, tol: Levenberg–Marquardt iteration cap and gradient-norm tolerance.

    Returns:
      :class:`PoseFit`. Pure: jit and vmap it over frames.
    """
    J = len(model.joint_names)
    dtype = model.lower.dtype
    weights = to_device(np.ones(J, dtype)) if weights is None else to_device(weights, dtype)
    if mask is not None:
        weights = jnp.where(jnp.asarray(mask), weights, 0.0)
    targets = to_device(targets, dtype)
    x0 = root_init(model, targets, weights) if init is None else to_device(init, dtype)
    free = to_device(np.ones(model.num_dofs, bool)) if free is None else to_device(free, bool)
    rest = model.rest_pose if prior_mean is None else to_device(prior_mean, dtype)
    return _solve(
        model,
        targets,
        weights,
        x0,
        to_device(prior_weight, dtype),
        free,
        rest,
        to_device(tol, dtype),
        maxiter,
    )


@stored_jit(static_argnames=("maxiter",))
def _solve(model, targets, weights, x0, prior_weight, free, rest, tol, maxiter) -> PoseFit:
    """The Levenberg–Marquardt core of :func:`fit_pose`, compiled once per model structure and array shapes.

    Called from the un-jitted wrappers, the compiled solver is shared by :func:`fit_pose` and
    :func:`from_head_hands` (and by their vmapped forms); inside a caller's ``jit`` it is simply inlined. A run of
    the command line keeps its trace on disk (:func:`jaxmocap.stored_programs.stored_jit`): the first pose of a
    warm run does not trace it again.
    """
    Q, w = _clean(targets, weights)
    u0 = from_state(model, x0)
    prior_sqrt = jnp.where(prior_mask(model), jnp.sqrt(prior_weight), 0.0)
    u, info = solvers.least_squares(
        _residual,
        u0,
        model,
        Q,
        jnp.sqrt(w),
        rest,
        prior_sqrt,
        u0,
        free,
        jac_fn=_residual_jac,
        maxiter=maxiter,
        tol=tol,
    )
    x = clip_into(model, to_state(model, jnp.where(free, u, u0)))
    err = jnp.linalg.norm(model_joints(model, x) - targets, axis=-1)
    return PoseFit(x, err, info.value, info.iterations)


def _residual_2d(u, model, rig, uv, w_sqrt, prior_sqrt, u0):
    X, _ = joints_and_jacobian(model, to_state(model, u))
    return _reprojection_residual(X, u, rig, uv, w_sqrt, prior_sqrt, u0)


def _reprojection_residual(X, u, rig, uv, w_sqrt, prior_sqrt, u0):
    """:func:`_residual_2d` at the joints ``X (J, 3)`` of ``u``: the weighted pixel misfits, then the prior's."""
    r = w_sqrt[..., None] * (camera.project(rig, X) - uv)  # (V, J, 2) pixels
    return jnp.concatenate([r.ravel(), prior_sqrt * (u - u0)])


def _joints_and_jacobian_u(model, u):
    """The joints ``X (J, 3)`` of the solver's coordinates ``u`` and their Jacobian ``∂X/∂u (J, 3, D)``."""
    bounded, c, h = _bounds(model)
    X, J = joints_and_jacobian(model, to_state(model, u))  # (J, 3), (J, 3, D)
    return X, J * jnp.where(bounded, h * jnp.cos(u), 1.0)


def _residual_2d_jac(u, model, rig, uv, w_sqrt, prior_sqrt, u0):
    X, Ju = _joints_and_jacobian_u(model, u)
    return _reprojection_jac(X, Ju, rig, w_sqrt, prior_sqrt)


def _reprojection_jac(X, Ju, rig, w_sqrt, prior_sqrt):
    """Rows of :func:`_residual_2d_jac` at the joints ``X (J, 3)`` with ``Ju = ∂X/∂u (J, 3, D)``."""
    dpi = jax.vmap(jax.jacfwd(lambda p: camera.project(rig, p[None])[:, 0]))(X)  # (J, V, 2, 3)
    Jr = jnp.einsum("jvab,jbd->vjad", dpi, Ju) * w_sqrt[..., None, None]  # (V, J, 2, D)
    return jnp.concatenate([Jr.reshape(-1, Ju.shape[-1]), jnp.diag(prior_sqrt)])


def fit_pose_2d(
    model: BodyModel,
    rig,
    keypoints: jnp.ndarray,
    weights: jnp.ndarray,
    init: jnp.ndarray,
    prior_weight: float = 1.0,
    maxiter: int = 30,
    tol: float = 1e-2,
    depth: jnp.ndarray | None = None,
    depth_weights: jnp.ndarray | None = None,
) -> jnp.ndarray:
    """Fit the state to 2D detections by their reprojection error (and to measured depths of the joints):

    ``x* = argmin_x Σ_v Σ_j w_vj ‖π_v(f_j(x)) − y_vj‖² [+ Σ_v Σ_j ω_vj (z_v(f_j(x)) − d_vj)²] + λ Σ_d (u_d − u0_d)²``

    with ``π_v`` camera ``v``'s projection (:func:`jaxmocap.geometry.camera.project`, distortion included),
    ``f_j`` the model's joints, ``y_vj`` the detected pixel of joint ``j`` in view ``v`` and ``w_vj`` its weight
    (the detection's confidence over its variance in px²; 0 where not detected), and a weak prior ``λ``
    (px²) that keeps the solver's coordinates ``u`` (module docstring) near the start ``init`` — the triangulated
    fit of :func:`fit_pose`, which also sets the joints no view detects. Triangulating each joint on its own puts
    detection noise into its depth in proportion to distance / baseline (a stereo pair 0.3 m apart at 3.4 m:
    each pixel of disparity error moves a joint ≈ 0.13 m along the ray, and the triangulated fit of the demo
    walk's first frames was 0.4–0.8 m off on average); here the limb lengths of the model tie the joints together,
    so the depth comes from the skeleton's projected size as well as from the disparities. With ``depth`` given,
    ``z_v`` is a joint's camera-frame depth (``z_c`` of :func:`jaxmocap.geometry.camera.project_with_depth`),
    ``d_vj`` its measured depth in view ``v`` (m, e.g. read from a depth map) and ``ω_vj`` that measurement's
    weight (1/m²; 0 where none): the depths fix what the disparities of close views fix poorly.

    Args:
      model: the body model; rig: the cameras (:class:`jaxmocap.geometry.camera.Rig`, pixels of ``keypoints``).
      keypoints: ``(V, J, 2)`` pixels in ``model.joint_names`` order; weights: ``(V, J)``.
      init: ``(D,)`` start state. prior_weight: ``λ``; maxiter, tol: Levenberg–Marquardt's.
      depth, depth_weights: ``(V, J)`` measured camera depths ``d`` and their weights ``ω`` (None: no depth term).

    Returns: ``(D,)`` the fitted state, inside the joint limits. Pure and jit-able; compiled once per model
    structure and shapes.
    """
    dtype = model.lower.dtype
    if (depth is None) != (depth_weights is None):
        raise ValueError("depth and depth_weights go together")
    measured = None if depth is None else (jnp.asarray(depth, dtype), jnp.asarray(depth_weights, dtype))
    return _solve_2d(
        model,
        rig,
        jnp.asarray(keypoints, dtype),
        jnp.asarray(weights, dtype),
        jnp.asarray(init, dtype),
        jnp.asarray(prior_weight, dtype),
        jnp.asarray(tol, dtype),
        maxiter,
        measured,
    )


@functools.partial(jax.jit, static_argnames=("maxiter",))
def _solve_2d(model, rig, uv, weights, x0, prior_weight, tol, maxiter, measured=None):
    """:func:`fit_pose_2d`; ``measured``: ``(depth, depth_weights)`` or None."""
    w = jnp.where(jnp.isfinite(uv).all(-1), jnp.maximum(weights, 0.0), 0.0)
    uv = jnp.where(jnp.isfinite(uv), uv, 0.0)
    u0 = from_state(model, clip_into(model, x0))
    prior_sqrt = jnp.full(u0.shape, jnp.sqrt(prior_weight))
    args = (model, rig, uv, jnp.sqrt(w), prior_sqrt, u0)
    residual, jac = _residual_2d, _residual_2d_jac
    if measured is not None:
        z, wz = measured
        wz = jnp.where(jnp.isfinite(z), jnp.maximum(wz, 0.0), 0.0)
        args += (jnp.where(jnp.isfinite(z), z, 0.0), jnp.sqrt(wz))
        residual, jac = _residual_2d_depth, _residual_2d_depth_jac
    u, _ = solvers.least_squares(residual, u0, *args, jac_fn=jac, maxiter=maxiter, tol=tol)
    return clip_into(model, to_state(model, u))


def _residual_2d_depth(u, model, rig, uv, w_sqrt, prior_sqrt, u0, z, wz_sqrt):
    """:func:`_residual_2d` and the weighted camera depths' misfits ``√ω_vj (z_v(f_j(x)) − d_vj)`` (m), from one
    forward kinematics."""
    X, _ = joints_and_jacobian(model, to_state(model, u))
    _, zc = camera.project_with_depth(rig, X)  # (V, J)
    rz = wz_sqrt * (zc - z)
    return jnp.concatenate([_reprojection_residual(X, u, rig, uv, w_sqrt, prior_sqrt, u0), rz.ravel()])


def _residual_2d_depth_jac(u, model, rig, uv, w_sqrt, prior_sqrt, u0, z, wz_sqrt):
    """Rows of :func:`_residual_2d_jac`, then the depths': ``∂z_v/∂X`` is camera ``v``'s third rotation row (one
    kinematic Jacobian for both)."""
    X, Ju = _joints_and_jacobian_u(model, u)
    Jz = jnp.einsum("vb,jbd->vjd", rig.R[:, 2, :].astype(Ju.dtype), Ju) * wz_sqrt[..., None]  # (V, J, D)
    top = _reprojection_jac(X, Ju, rig, w_sqrt, prior_sqrt)
    return jnp.concatenate([top, Jz.reshape(-1, u.shape[0])])


@functools.partial(jax.jit, static_argnames=("maxiter",))
def fit_sequence(
    model: BodyModel,
    targets: jnp.ndarray,
    weights: jnp.ndarray | None = None,
    init: jnp.ndarray | None = None,
    **options,
) -> PoseFit:
    """Fit every frame of ``targets (T, J, 3)``, each starting from the previous frame's solution (``lax.scan``).

    ``weights`` may be ``(J,)`` or ``(T, J)``; the first frame starts from ``init`` or :func:`root_init`;
    ``options`` are the other keywords of :func:`fit_pose` (``prior_weight``, ``mask``, ``free``, ``prior_mean``,
    ``maxiter``, ``tol``), the same for every frame. Returns a :class:`PoseFit` with a leading ``T`` axis.
    Compiled once per model structure, shapes and ``maxiter``.
    """
    targets = jnp.asarray(targets, model.lower.dtype)
    T, J = targets.shape[0], targets.shape[1]
    weights = (
        jnp.ones((J,), model.lower.dtype) if weights is None else jnp.asarray(weights, model.lower.dtype)
    )
    weights = jnp.broadcast_to(weights, (T, J))
    x0 = root_init(model, targets[0], weights[0]) if init is None else jnp.asarray(init, model.lower.dtype)

    def step(x_prev, frame):
        y, w = frame
        fit = fit_pose(model, y, w, x_prev, **options)
        return fit.state, fit

    _, fits = jax.lax.scan(step, x0, (targets, weights))
    return fits


def _heading_dof(model: BodyModel) -> int | None:
    trans, rots, letters = _root_dofs(model)
    return rots[letters.index("z")] if "z" in letters else None


def from_head_hands(
    model: BodyModel,
    head: jnp.ndarray,
    left_hand: jnp.ndarray,
    right_hand: jnp.ndarray,
    weights: jnp.ndarray | None = None,
    init: jnp.ndarray | None = None,
    free: jnp.ndarray | None = None,
    prior_weight: float = 1e-3,
    prior_mean: jnp.ndarray | None = None,
    maxiter: int = 30,
    tol: float = 1e-6,
) -> PoseFit:
    """IK from 3D head and hands to the configuration nearest a rest pose (Fontmarty et al. 2007, §IV-A).

    The targets are the model's ``head``, ``left_wrist`` and ``right_wrist`` joints; every other joint is free
    and the prior ``λ Σ (x_d − x̄_d)²`` over the bounded angles picks, among the poses that reach the targets,
    the one nearest ``x̄`` (``prior_mean``, default ``model.rest_pose``). In a tracker, pass the current torso
    estimate as ``init`` and free only the arm (and neck) angles: three points do not fix the torso's heading
    when the arms swing.

    The default start (``init=None``) is :func:`head_hands_init`: the rest pose turned so that its left side
    points along ``left_hand − right_hand`` and shifted so that its head is at ``head``.

    Args:
      head, left_hand, right_hand: ``(3,)`` metres.
      weights: ``(3,)`` for head, left, right (default ones, 1/m²).
      init: ``(D,)`` start state; free: ``(D,)`` bool, the entries the IK may change (default all).
      prior_weight: ``λ`` in 1/rad²; prior_mean: ``(D,)``.

    Returns:
      :class:`PoseFit` whose ``errors`` are over all the model's joints (NaN except the three targets).
    """
    names = model.joint_names
    dtype = model.lower.dtype
    J = len(names)
    idx = jnp.asarray([names.index("head"), names.index("left_wrist"), names.index("right_wrist")])
    pts = jnp.stack([jnp.asarray(head, dtype), jnp.asarray(left_hand, dtype), jnp.asarray(right_hand, dtype)])
    targets = jnp.full((J, 3), jnp.nan, dtype).at[idx].set(pts)
    w3 = jnp.ones(3, dtype) if weights is None else jnp.asarray(weights, dtype)
    w = jnp.zeros(J, dtype).at[idx].set(w3)
    if init is None:
        init = head_hands_init(model, pts[0], pts[1], pts[2], prior_mean)
    return fit_pose(model, targets, w, init, prior_weight, None, free, prior_mean, maxiter, tol)


@jax.jit
def head_hands_init(
    model: BodyModel,
    head: jnp.ndarray,
    left_hand: jnp.ndarray,
    right_hand: jnp.ndarray,
    pose: jnp.ndarray | None = None,
) -> jnp.ndarray:
    """Start state of :func:`from_head_hands`: ``pose`` (default the rest pose) turned to the heading
    ``ψ = atan2(−l_x, l_y)`` of ``l = left_hand − right_hand`` (its left side along ``l``) and shifted so that
    its head joint is at ``head``."""
    dtype = model.lower.dtype
    x0 = model.rest_pose if pose is None else jnp.asarray(pose, dtype)
    lvec = jnp.asarray(left_hand, dtype) - jnp.asarray(right_hand, dtype)
    k = _heading_dof(model)
    if k is not None:
        x0 = x0.at[k].set(jnp.arctan2(-lvec[0], lvec[1]))
    trans, _, _ = _root_dofs(model)
    if trans:
        shift = jnp.asarray(head, dtype) - model_joints(model, x0)[model.joint_names.index("head")]
        A = model.dof_axis[jnp.asarray(trans)].T
        x0 = x0.at[jnp.asarray(trans)].add(jnp.linalg.pinv(A) @ shift)
    return x0


def dof_mask(model: BodyModel, *prefixes: str) -> np.ndarray:
    """``(D,)`` bool: the state entries whose names start with any of ``prefixes`` (e.g. ``"left_shoulder"``)."""
    return np.asarray([any(n.startswith(p) for p in prefixes) for n in model.dof_names])


def select_joints(model: BodyModel, eval15: np.ndarray) -> np.ndarray:
    """Pick the model's joints (``model.joint_names``) out of ``(..., 15, 3)`` evaluation-joint arrays."""
    return np.asarray(eval15)[..., [EVAL_JOINTS.index(n) for n in model.joint_names], :]
