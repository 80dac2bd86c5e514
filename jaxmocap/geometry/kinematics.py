"""Rigid-body kinematics: twist exponentials and product-of-exponentials forward kinematics.

Notation after López Méndez (2009), ch. 2, and Murray, Li & Sastry:

* a twist ξ = (v, ω) ∈ R⁶ with ξ̂ = [[ω̂, v], [0, 0]] ∈ se(3) (eq. 2.7);
* the rotation exponential (Rodrigues, eq. 2.6) for a unit axis ω and angle θ:
  ``exp(ω̂θ) = I + ω̂ sin θ + ω̂² (1 − cos θ)``;
* the rigid-motion exponential (eq. 2.8–2.9) for ω ≠ 0:
  ``exp(ξ̂θ) = [[exp(ω̂θ), (I − exp(ω̂θ))(ω × v) + ω ωᵀ v θ], [0, 1]]`` and for ω = 0 (prismatic)
  ``[[I, v θ], [0, 1]]``;
* the product-of-exponentials map of a chain (eq. 2.5, 2.10):
  ``g_st(θ) = exp(ξ̂₁θ₁) exp(ξ̂₂θ₂) ⋯ exp(ξ̂ₙθₙ) g_st(0)``.

Two layers live here:

1. General, batched functions on ``(..., 3)`` / ``(..., 6)`` arrays (:func:`so3_exp`, :func:`se3_exp`,
   :func:`poe`), written for clarity and used as references.
2. The hot path (:func:`segment_poses`, :func:`transform_points`): forward kinematics of a kinematic tree with
   static topology, written per particle on scalars held as 9-tuples of rotation entries ("structure of
   arrays"). Under ``vmap`` every entry becomes one long ``(N,)`` vector, which XLA on CPU vectorises an order of
   magnitude better than many 3×3 products (see ``benchmarks/bench_kinematics.py``). The tree uses twists
   expressed in each joint's frame, which is the same product of exponentials as eq. 2.10 written with
   body-frame twists: ``g_s(θ) = g_parent(θ) · g_s,rest · Π_k exp(ξ̂_k θ_k)``. :func:`poe` with spatial twists
   gives the same transforms (tested). On the CPU the tree is walked by two nested loops (segments, then each
   segment's DOFs), which XLA compiles several times faster than the product written out (see
   ``benchmarks/perf/compile_time.py``); the arithmetic, and the results, are the same.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

# ---------------------------------------------------------------------------------------------------------------
# General batched maps


def hat(w: jnp.ndarray) -> jnp.ndarray:
    """Skew-symmetric matrix ``ŵ`` of ``w`` with ``ŵ p = w × p``. ``(..., 3) -> (..., 3, 3)``."""
    w = jnp.asarray(w)
    z = jnp.zeros_like(w[..., 0])
    return jnp.stack(
        [
            jnp.stack([z, -w[..., 2], w[..., 1]], -1),
            jnp.stack([w[..., 2], z, -w[..., 0]], -1),
            jnp.stack([-w[..., 1], w[..., 0], z], -1),
        ],
        -2,
    )


def _safe_norm(w: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """Return ``(θ, small, θ_safe)`` with gradients that stay finite at θ = 0 (the double-``where`` trick)."""
    sq = jnp.sum(w * w, axis=-1)
    small = sq < 1e-12
    sq_safe = jnp.where(small, 1.0, sq)
    theta_safe = jnp.sqrt(sq_safe)
    theta = jnp.where(small, 0.0, theta_safe)
    return theta, small, theta_safe


def so3_exp(omega: jnp.ndarray) -> jnp.ndarray:
    """Rotation matrix of the rotation vector ``omega = ω θ`` (eq. 2.6, Rodrigues). ``(..., 3) -> (..., 3, 3)``.

    Uses the Taylor series ``sin θ/θ ≈ 1 − θ²/6`` and ``(1 − cos θ)/θ² ≈ 1/2 − θ²/24`` near θ = 0 so that value and
    gradient are exact there.
    """
    omega = jnp.asarray(omega)
    theta, small, ts = _safe_norm(omega)
    sq = theta * theta
    a = jnp.where(small, 1.0 - sq / 6.0, jnp.sin(ts) / ts)
    b = jnp.where(small, 0.5 - sq / 24.0, (1.0 - jnp.cos(ts)) / (ts * ts))
    W = hat(omega)
    eye = jnp.eye(3, dtype=W.dtype)
    return eye + a[..., None, None] * W + b[..., None, None] * (W @ W)


def so3_log(R: jnp.ndarray) -> jnp.ndarray:
    """Rotation vector of a rotation matrix (inverse of :func:`so3_exp` for angles in [0, π)). ``(...,3,3)->(...,3)``."""
    R = jnp.asarray(R)
    cos = jnp.clip((jnp.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = jnp.arccos(cos)
    v = jnp.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    small = theta < 1e-6
    s = jnp.where(small, 1.0, jnp.sin(theta))
    scale = jnp.where(small, 0.5, theta / (2.0 * s))
    return scale[..., None] * v


def se3_exp(xi: jnp.ndarray) -> jnp.ndarray:
    """Homogeneous matrix ``exp(ξ̂)`` of a twist ``xi = (v, ω)`` scaled by θ (eq. 2.8–2.9). ``(...,6)->(...,4,4)``.

    With ``ξ θ = (v θ, ω θ)`` this is the closed form ``[[R, V v θ], [0, 1]]`` with
    ``V = I + (1 − cos θ)/θ² ω̂θ + (θ − sin θ)/θ³ (ω̂θ)²`` (equivalent to eq. 2.9), and ``[[I, v θ], [0, 1]]`` for
    ω = 0.
    """
    xi = jnp.asarray(xi)
    v, w = xi[..., :3], xi[..., 3:]
    theta, small, ts = _safe_norm(w)
    sq = theta * theta
    b = jnp.where(small, 0.5 - sq / 24.0, (1.0 - jnp.cos(ts)) / (ts * ts))
    c = jnp.where(small, 1.0 / 6.0 - sq / 120.0, (ts - jnp.sin(ts)) / (ts * ts * ts))
    W = hat(w)
    W2 = W @ W
    eye = jnp.eye(3, dtype=W.dtype)
    R = so3_exp(w)
    V = eye + b[..., None, None] * W + c[..., None, None] * W2
    t = jnp.einsum("...ij,...j->...i", V, v)
    top = jnp.concatenate([R, t[..., None]], -1)
    bottom = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 0.0, 1.0], W.dtype), top.shape[:-2] + (1, 4))
    return jnp.concatenate([top, bottom], -2)


def revolute_twist(axis: jnp.ndarray, point: jnp.ndarray) -> jnp.ndarray:
    """Twist of a revolute joint about unit ``axis`` through ``point``: ``ξ = (−ω × q, ω)``. ``(...,3)->(...,6)``."""
    axis = jnp.asarray(axis)
    return jnp.concatenate([-jnp.cross(axis, jnp.asarray(point)), axis], -1)


def prismatic_twist(axis: jnp.ndarray) -> jnp.ndarray:
    """Twist of a prismatic joint along unit ``axis``: ``ξ = (v, 0)``. ``(..., 3) -> (..., 6)``."""
    axis = jnp.asarray(axis)
    return jnp.concatenate([axis, jnp.zeros_like(axis)], -1)


def poe(twists: jnp.ndarray, theta: jnp.ndarray, g0: jnp.ndarray) -> jnp.ndarray:
    """Product of exponentials of one serial chain with spatial twists (eq. 2.5).

    Args:
      twists: ``(K, 6)`` spatial twists ``(v, ω)`` of the chain's joints in the reference configuration.
      theta: ``(..., K)`` joint values.
      g0: ``(4, 4)`` reference transform ``g_st(0)`` of the tool frame.

    Returns:
      ``(..., 4, 4)``: ``exp(ξ̂₁θ₁) ⋯ exp(ξ̂_Kθ_K) g0``.
    """
    theta = jnp.asarray(theta)
    g = jnp.broadcast_to(jnp.eye(4, dtype=theta.dtype), theta.shape[:-1] + (4, 4))
    for k in range(twists.shape[0]):
        g = g @ se3_exp(twists[k] * theta[..., k, None])
    return g @ g0


# ---------------------------------------------------------------------------------------------------------------
# Structure-of-arrays hot path: a rotation is a 9-tuple (row-major) of same-shaped arrays, a vector a 3-tuple.

Rot9 = tuple
Vec3 = tuple


def axis_angle9(axis, theta) -> Rot9:
    """Rodrigues' formula (eq. 2.6) for a unit ``axis`` (3-sequence of scalars) and angle ``theta``, as a 9-tuple."""
    x, y, z = axis[0], axis[1], axis[2]
    c = jnp.cos(theta)
    s = jnp.sin(theta)
    C = 1.0 - c
    return (
        c + x * x * C, x * y * C - z * s, x * z * C + y * s,
        y * x * C + z * s, c + y * y * C, y * z * C - x * s,
        z * x * C - y * s, z * y * C + x * s, c + z * z * C,
    )  # fmt: skip


def matmul9(A: Rot9, B: Rot9) -> Rot9:
    """Product of two 9-tuple rotations, written as explicit multiply-adds."""
    return tuple(
        A[3 * i] * B[j] + A[3 * i + 1] * B[3 + j] + A[3 * i + 2] * B[6 + j]
        for i in range(3)
        for j in range(3)
    )


def matvec9(A: Rot9, v: Vec3) -> Vec3:
    """``A v`` for a 9-tuple rotation and a 3-tuple vector."""
    return tuple(A[3 * i] * v[0] + A[3 * i + 1] * v[1] + A[3 * i + 2] * v[2] for i in range(3))


def to9(R: jnp.ndarray) -> Rot9:
    """``(3, 3)`` array → 9-tuple."""
    return tuple(R[i, j] for i in range(3) for j in range(3))


@dataclasses.dataclass(frozen=True)
class Topology:
    """Static (hashable) description of a kinematic tree.

    Attributes:
      segment_names: ``S`` names, parents before children.
      parents: ``S`` parent indices, ``-1`` for the root.
      segment_dofs: for each segment, the state indices acting at its joint, applied in this order.
      dof_names: ``D`` names of the state vector entries.
      dof_kinds: ``D`` entries, ``"P"`` (prismatic, translation along the axis) or ``"R"`` (revolute).
      rest_rotated: for each segment, whether its rest transform has a non-identity rotation (lets the common
        identity case skip a product).
    """

    segment_names: tuple[str, ...]
    parents: tuple[int, ...]
    segment_dofs: tuple[tuple[int, ...], ...]
    dof_names: tuple[str, ...]
    dof_kinds: tuple[str, ...]
    rest_rotated: tuple[bool, ...]

    def __post_init__(self):
        S = len(self.segment_names)
        if not (len(self.parents) == len(self.segment_dofs) == len(self.rest_rotated) == S):
            raise ValueError(
                "segment_names, parents, segment_dofs and rest_rotated must have one entry a segment"
            )
        for s, p in enumerate(self.parents):
            if p >= s:
                raise ValueError(f"segment {self.segment_names[s]!r}: parent {p} must come before it")
        used = sorted(i for dofs in self.segment_dofs for i in dofs)
        if used != list(range(len(self.dof_names))) or len(self.dof_kinds) != len(self.dof_names):
            raise ValueError("every state index must act at exactly one segment")
        if any(k not in ("P", "R") for k in self.dof_kinds):
            raise ValueError("dof_kinds must be 'P' or 'R'")

    @property
    def num_segments(self) -> int:
        return len(self.segment_names)

    @property
    def num_dofs(self) -> int:
        return len(self.dof_names)


def _slot_table(topology: Topology) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(dof, revolute, prismatic)``, each ``(S, M)``: the state index acting in slot ``j`` of segment ``s`` (its
    DOFs in order, padded to the largest count ``M`` with index 0) and the slot's kind (both False when padded)."""
    M = max(1, max(len(d) for d in topology.segment_dofs))
    dof = np.zeros((topology.num_segments, M), np.int32)
    kind = np.full((topology.num_segments, M), "-")
    for s, dofs in enumerate(topology.segment_dofs):
        for j, k in enumerate(dofs):
            dof[s, j], kind[s, j] = k, topology.dof_kinds[k]
    return dof, kind == "R", kind == "P"


#: backends on which :func:`segment_poses` runs as loops (:func:`_segment_poses_loop`); elsewhere written out
#: (:func:`_segment_poses_unrolled`: one fused kernel on a GPU, where each loop iteration is a kernel launch)
LOOP_BACKENDS = ("cpu",)


def segment_poses(
    topology: Topology,
    rest_rotation: jnp.ndarray,
    offset: jnp.ndarray,
    dof_axis: jnp.ndarray,
    x: jnp.ndarray,
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """World transform of every segment for one state (eq. 2.10 with joint-frame twists).

    ``g_s = g_parent(s) · (R_rest,s, o_s) · Π_{k ∈ dofs(s)} exp(ξ̂_k x_k)`` where a revolute ``k`` has
    ``ξ_k = (0, a_k)`` and a prismatic one ``ξ_k = (a_k, 0)`` in the joint frame.

    Args:
      topology: static tree.
      rest_rotation: ``(S, 3, 3)`` joint-frame rotation relative to the parent frame at zero state.
      offset: ``(S, 3)`` joint origin in the parent frame (world frame for the root).
      dof_axis: ``(D, 3)`` unit axes in the joint frame.
      x: ``(D,)`` state. Use ``jax.vmap`` for particles.

    Returns:
      ``R (S, 3, 3)`` and ``t (S, 3)``: segment frame → world.

    Two forms with the same arithmetic (identical results): on the backends of :data:`LOOP_BACKENDS` (the CPU)
    nested loops over the segments and their DOFs (:func:`_segment_poses_loop`: a program several times smaller,
    compiled in a fraction of the time), elsewhere the product written out segment by segment
    (:func:`_segment_poses_unrolled`), chosen by ``jax.default_backend()`` when traced.
    """
    if jax.default_backend() in LOOP_BACKENDS:
        return _segment_poses_cpu(topology, rest_rotation, offset, dof_axis, x)
    return _segment_poses_unrolled(topology, rest_rotation, offset, dof_axis, x)


def _segment_poses_unrolled(
    topology: Topology, rest_rotation, offset, dof_axis, x
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """:func:`segment_poses` written out per segment on scalars (9-tuples): one long expression per output entry.
    XLA's GPU compiler fuses it into one kernel; its CPU compiler copies each segment's chain from the root into
    every fusion that reads it (≈ 27 copies of each sine for ``full25``), whence :func:`_segment_poses_loop`."""
    x = jnp.asarray(x)
    Rs: list[Rot9] = []
    ts: list[Vec3] = []
    for s in range(topology.num_segments):
        R: Rot9 | None = None
        t: Vec3 = (offset[s, 0], offset[s, 1], offset[s, 2])
        if topology.rest_rotated[s]:
            R = to9(rest_rotation[s])
        for k in topology.segment_dofs[s]:
            a = (dof_axis[k, 0], dof_axis[k, 1], dof_axis[k, 2])
            if topology.dof_kinds[k] == "P":
                d = a if R is None else matvec9(R, a)
                t = tuple(t[i] + d[i] * x[k] for i in range(3))
            else:
                Rk = axis_angle9(a, x[k])
                R = Rk if R is None else matmul9(R, Rk)
        if R is None:
            R = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
            R = tuple(jnp.asarray(e, dtype=x.dtype) for e in R)
        p = topology.parents[s]
        if p >= 0:
            dt = matvec9(Rs[p], t)
            t = tuple(ts[p][i] + dt[i] for i in range(3))
            R = matmul9(Rs[p], R)
        Rs.append(R)
        ts.append(t)
    R_out = jnp.stack([jnp.stack(r) for r in Rs]).reshape(topology.num_segments, 3, 3)
    t_out = jnp.stack([jnp.stack(v) for v in ts])
    return R_out, t_out


def _segment_poses_loop(
    topology: Topology, rest_rotation, offset, dof_axis, x, joints: bool = False
) -> tuple[jnp.ndarray, ...]:
    """:func:`segment_poses` as loops (the CPU form).

    Two nested ``lax.scan``: over the segments in order (parents first; the carry holds every pose as a row
    ``(R, t)`` of 12 scalars, and an identity row that the roots take as their parent), and within a segment over
    its DOF slots, padded to the largest count ``M`` (carry: the segment's ``(R, t)``, starting from
    ``(R_rest, o_s)``). Each slot applies ``t ← t + (R a_k) x_k`` if prismatic and ``R ← R exp(â_k x_k)``
    (:func:`axis_angle9`) if revolute; the other operation gets value 0, which leaves ``R`` and ``t`` exactly as
    they are (``exp`` of angle 0 is the identity, products with it exact), so the results equal the product
    written out segment by segment (:func:`_segment_poses_unrolled`). The loop bodies are compiled once and each
    value is computed once (``full25``: 472 lines of StableHLO instead of 2828; after XLA's fusion 1677 instead
    of 20004), and the loops run at least as fast on a CPU.

    ``joints=True`` also returns each slot's axis and origin in its segment's parent frame, ``(S, M, 3)`` twice:
    ``R_loc a_k`` and ``t_loc`` as the slot finds them (``R_loc``, ``t_loc``: the segment's pose relative to its
    parent so far), for :func:`_segment_poses_cpu`'s derivative; ``R`` and ``t`` are the same arithmetic.
    """
    x = jnp.asarray(x)
    dt = x.dtype
    S = topology.num_segments
    dof, revolute, prismatic = _slot_table(topology)
    rest = jnp.eye(3, dtype=dt).reshape(1, 9)
    if any(topology.rest_rotated):
        rotated = np.asarray(topology.rest_rotated)[:, None]
        rest = jnp.where(rotated, jnp.asarray(rest_rotation, dt).reshape(S, 9), rest)
    rows = {
        "start": jnp.concatenate([jnp.broadcast_to(rest, (S, 9)), jnp.asarray(offset, dt)], axis=1),
        "parent": np.asarray([p if p >= 0 else S for p in topology.parents], np.int32),
        "axis": jnp.asarray(dof_axis, dt)[dof],
        "dof": dof,
        "revolute": revolute,
        "prismatic": prismatic,
    }
    any_prismatic = bool(prismatic.any())

    def slot(g, z):
        R, t = tuple(g[i] for i in range(9)), tuple(g[9 + i] for i in range(3))
        a = (z["axis"][0], z["axis"][1], z["axis"][2])
        xk = x[z["dof"]]
        zero = jnp.zeros_like(xk)
        joint = jnp.stack([*matvec9(R, a), *t]) if joints else None
        if any_prismatic:
            d = matvec9(R, a)
            xp = jnp.where(z["prismatic"], xk, zero)
            t = tuple(t[i] + d[i] * xp for i in range(3))
        R = matmul9(R, axis_angle9(a, jnp.where(z["revolute"], xk, zero)))
        return jnp.stack([*R, *t]), joint

    def segment(pose, row):
        slots = {k: row[k] for k in ("axis", "dof", "revolute", "prismatic")}
        g, joint = jax.lax.scan(slot, row["start"], slots)
        gp = pose[row["parent"]]
        Rp, tp = tuple(gp[i] for i in range(9)), tuple(gp[9 + i] for i in range(3))
        R, t = tuple(g[i] for i in range(9)), tuple(g[9 + i] for i in range(3))
        dv = matvec9(Rp, t)
        g = jnp.stack([*matmul9(Rp, R), *(tp[i] + dv[i] for i in range(3))])
        return pose.at[row["index"]].set(g), joint

    identity = jnp.asarray([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0], dt)
    pose = jnp.zeros((S + 1, 12), dt).at[S].set(identity)
    pose, joint = jax.lax.scan(segment, pose, {**rows, "index": np.arange(S, dtype=np.int32)})
    out = (pose[:S, :9].reshape(S, 3, 3), pose[:S, 9:])
    return out + (joint[..., :3], joint[..., 3:]) if joints else out


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _segment_poses_cpu(topology: Topology, rest_rotation, offset, dof_axis, x):
    """:func:`_segment_poses_loop`, with a derivative in ``x`` written from the joints' world twists.

    A revolute ``k`` (world axis ``w_k``, through the world point ``p_k``) turns every segment below it about that
    line and a prismatic one (world direction ``d_k``) shifts them: with ``A (S, D)`` the static table of the
    DOFs at or above each segment, ``Ω_s = Σ_k A_sk w_k ẋ_k`` (revolute ``k``) and ``ν_s = Σ_k A_sk (p_k × w_k)
    ẋ_k`` (revolute) ``+ d_k ẋ_k`` (prismatic), and ``Ṙ_s = Ω_s × R_s`` (column by column), ``ṫ_s = Ω_s × t_s +
    ν_s``. Reverse mode transposes this linear map (two products with ``Aᵀ`` and a dot per DOF) instead of
    reversing the two loops. Tangents of the other arguments (body dimensions) go through
    :func:`jax.jvp` of the loops and are added.
    """
    return _segment_poses_loop(topology, rest_rotation, offset, dof_axis, x)


def _ancestry(topology: Topology) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A (S, D), segment (D,), slot (D,))``: ``A_sk = 1`` where DOF ``k`` acts at segment ``s`` or above it; the
    segment and slot (:func:`_slot_table`) of each DOF."""
    S, D = topology.num_segments, topology.num_dofs
    seg, slot = np.zeros(D, np.int32), np.zeros(D, np.int32)
    for s, dofs in enumerate(topology.segment_dofs):
        for j, k in enumerate(dofs):
            seg[k], slot[k] = s, j
    above = np.zeros((S, S), bool)  # above[s, r]: r is s or one of its ancestors
    for s, p in enumerate(topology.parents):
        above[s, s] = True
        if p >= 0:
            above[s] |= above[p]
    return above[:, seg].astype(np.float32), seg, slot


def _cross(a, b):
    """``a × b`` over the last axis ``(..., 3)``, written out."""
    return jnp.stack(
        [
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ],
        -1,
    )


@functools.partial(_segment_poses_cpu.defjvp, symbolic_zeros=True)
def _segment_poses_cpu_jvp(topology, primals, tangents):
    rest_rotation, offset, dof_axis, x = primals
    R, t, axis_loc, origin_loc = _segment_poses_loop(topology, *primals, joints=True)
    A, seg, slot = _ancestry(topology)
    parent = np.asarray(topology.parents, np.int32)[seg]  # -1: the root (its parent pose is the identity)
    Rp = jnp.where((parent >= 0)[:, None, None], R[parent], jnp.eye(3, dtype=R.dtype))  # (D, 3, 3)
    tp = jnp.where((parent >= 0)[:, None], t[parent], 0.0)  # (D, 3)
    a, o = axis_loc[seg, slot], origin_loc[seg, slot]  # (D, 3) in the parent's frame
    w = sum(Rp[:, :, j] * a[:, j, None] for j in range(3))  # world axes / directions
    p = sum(Rp[:, :, j] * o[:, j, None] for j in range(3)) + tp  # world joint points
    revolute = np.asarray([k == "R" for k in topology.dof_kinds])[:, None]
    xt = tangents[3]
    dR = dt = None
    if not isinstance(xt, SymbolicZero):
        xt = xt[:, None]
        A = jnp.asarray(A, R.dtype)
        omega = A @ jnp.where(revolute, w * xt, 0.0)  # (S, 3)
        nu = A @ (jnp.where(revolute, _cross(p, w), w) * xt)
        dR = jnp.stack([_cross(omega, R[:, :, c]) for c in range(3)], -1)
        dt = _cross(omega, t) + nu
    others = tangents[:3]
    if not all(isinstance(z, SymbolicZero) for z in others):
        zeros = [
            jnp.zeros_like(v) if isinstance(z, SymbolicZero) else z
            for v, z in zip(primals, tangents, strict=True)
        ]
        zeros[3] = jnp.zeros_like(x)
        _, (eR, et) = jax.jvp(lambda *a: _segment_poses_loop(topology, *a), tuple(primals), tuple(zeros))
        dR, dt = (eR, et) if dR is None else (dR + eR, dt + et)
    if dR is None:
        dR, dt = jnp.zeros_like(R), jnp.zeros_like(t)
    return (R, t), (dR, dt)


#: At most this many runs of equal segment index: :func:`transform_points` uses static slices, beyond it a gather.
MAX_RUNS = 64
#: :func:`transform_points` slices runs only when they hold at least this many points on average; shorter ones (a
#: point a segment: joints, primitive end points) are gathered, the slices costing more program than they save.
MIN_RUN_LENGTH = 2


def segment_runs(segment_of_point: Sequence[int] | np.ndarray) -> list[tuple[int, int, int]]:
    """``(start, stop, segment)`` of each maximal run of consecutive points on the same segment (static)."""
    seg = np.asarray(segment_of_point, dtype=np.int64).reshape(-1)
    if seg.size == 0:
        return []
    cuts = np.flatnonzero(np.diff(seg)) + 1
    starts = np.concatenate([[0], cuts])
    stops = np.concatenate([cuts, [seg.size]])
    return [(int(a), int(b), int(seg[a])) for a, b in zip(starts, stops, strict=True)]


def apply_by_runs(
    A: jnp.ndarray, b: jnp.ndarray, points: jnp.ndarray, runs, adjoint: bool = False
) -> list[jnp.ndarray]:
    """Affine maps of the frames applied to the points of each run: the three coordinates ``(..., P)`` of
    ``A_{s(p)} p + b_{s(p)}`` for ``A (..., S, 3, 3)``, ``b (..., S, 3)``, ``points (P, 3)`` and the runs of
    :func:`segment_runs` (one broadcast per run and coordinate, concatenated; no per-point gather).
    ``adjoint``: :func:`affine_by_runs`.
    """
    pieces = affine_by_runs(A, b, points, runs, adjoint)
    return [
        pieces[0][i] if len(pieces) == 1 else jnp.concatenate([q[i] for q in pieces], -1) for i in range(3)
    ]


def affine_by_runs(A: jnp.ndarray, b: jnp.ndarray, points: jnp.ndarray, runs, adjoint: bool = False) -> tuple:
    """:func:`apply_by_runs` before the concatenation: per run ``(start, stop, s)``, the three coordinates
    ``(..., stop − start)`` of ``A_s p + b_s`` for the run's points.

    ``adjoint=True`` differentiates it by its written-out reverse pass (reverse mode only: ``jax.jvp`` and
    ``jacfwd`` are not defined through it): with ``ḡ_p`` the cotangent of point ``p``,
    ``Ā_s = Σ_{p∈s} ḡ_p p_pᵀ``, ``b̄_s = Σ_{p∈s} ḡ_p`` (one sum over each run's points, the segments stacked once)
    and ``p̄_p = A_{s(p)}ᵀ ḡ_p`` (summed over the leading axes of ``A``). The automatic transpose of the per-run
    slices pads every slice of ``A`` back to its whole shape and adds the pads up, nine a run and coordinate.
    """
    runs = tuple((int(a), int(z), int(s)) for a, z, s in runs)
    return _affine_runs_adjoint(A, b, points, runs) if adjoint else _affine_runs(A, b, points, runs)


def _affine_runs(A, b, points, runs) -> tuple[tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray], ...]:
    out = []
    for start, stop, s in runs:
        p = points[start:stop]
        out.append(
            tuple(
                A[..., s, i, 0, None] * p[:, 0]
                + A[..., s, i, 1, None] * p[:, 1]
                + A[..., s, i, 2, None] * p[:, 2]
                + b[..., s, i, None]
                for i in range(3)
            )
        )
    return tuple(out)


@functools.partial(jax.custom_vjp, nondiff_argnums=(3,))
def _affine_runs_adjoint(A, b, points, runs):
    return _affine_runs(A, b, points, runs)


def _affine_runs_fwd(A, b, points, runs):
    return _affine_runs(A, b, points, runs), (A, points)


def _affine_runs_bwd(runs, res, cot):
    A, points = res
    lead, S = A.shape[:-3], A.shape[-3]
    gA: dict[int, jnp.ndarray] = {}
    gb: dict[int, jnp.ndarray] = {}
    gp = jnp.zeros_like(points)
    for (start, stop, s), g in zip(runs, cot, strict=True):
        p1 = jnp.concatenate([points[start:stop], jnp.ones((stop - start, 1), points.dtype)], 1).T  # (4, L)
        ab = jnp.sum(jnp.stack(g, -2)[..., :, None, :] * p1, -1)  # (..., 3, 4): [Ā_s | b̄_s]
        a_s, b_s = ab[..., :3], ab[..., 3]
        gA[s] = gA[s] + a_s if s in gA else a_s
        gb[s] = gb[s] + b_s if s in gb else b_s
        q = jnp.stack(
            [sum(A[..., s, i, j, None] * g[i] for i in range(3)) for j in range(3)], -1
        )  # (..., L, 3)
        gp = gp.at[start:stop].add(q.reshape((-1,) + q.shape[-2:]).sum(0))
    zA, zb = jnp.zeros(lead + (3, 3), A.dtype), jnp.zeros(lead + (3,), A.dtype)
    GA = jnp.stack([gA.get(s, zA) for s in range(S)], -3)
    Gb = jnp.stack([gb.get(s, zb) for s in range(S)], -2)
    return GA, Gb, gp


_affine_runs_adjoint.defvjp(_affine_runs_fwd, _affine_runs_bwd)


def transform_points(
    R: jnp.ndarray,
    t: jnp.ndarray,
    points: jnp.ndarray,
    segment_of_point: Sequence[int] | np.ndarray,
    by_runs: bool = True,
    adjoint: bool = False,
) -> jnp.ndarray:
    """Move segment-local points to the world: ``X_p = R_{s(p)} p + t_{s(p)}``.

    Args:
      R: ``(..., S, 3, 3)`` segment rotations; t: ``(..., S, 3)`` translations.
      points: ``(P, 3)`` local coordinates (may be traced: body dimensions are differentiable).
      segment_of_point: ``P`` static segment indices.
      by_runs: False takes each point's transform whatever the layout.
      adjoint: the runs differentiated by their written-out reverse pass (:func:`affine_by_runs`; reverse mode only).

    Returns:
      ``(..., P, 3)``, computed per coordinate over ``(..., P)`` arrays.

    Points stored segment by segment (at most :data:`MAX_RUNS` runs of :data:`MIN_RUN_LENGTH` points or more on
    average, as flesh samples are) are moved one run at a time with static slices (:func:`apply_by_runs`); other
    layouts gather each point's transform (the same products in the same order). The result passes
    through ``lax.optimization_barrier`` (which XLA's CPU compiler drops, see :mod:`jaxmocap.likelihood.maps`).
    """
    runs = segment_runs(segment_of_point)
    if by_runs and 0 < len(runs) <= MAX_RUNS and runs[-1][1] >= MIN_RUN_LENGTH * len(runs):
        return jax.lax.optimization_barrier(jnp.stack(apply_by_runs(R, t, points, runs, adjoint), -1))
    seg = np.asarray(segment_of_point, dtype=np.int32)
    Rp = R[..., seg, :, :]
    tp = t[..., seg, :]
    px, py, pz = points[:, 0], points[:, 1], points[:, 2]
    out = [Rp[..., i, 0] * px + Rp[..., i, 1] * py + Rp[..., i, 2] * pz + tp[..., i] for i in range(3)]
    return jax.lax.optimization_barrier(jnp.stack(out, -1))


def euler_zyx(angles: jnp.ndarray) -> jnp.ndarray:
    """``Rz(a0) Ry(a1) Rx(a2)`` for ``angles (..., 3)``; the root orientation convention of the body presets."""
    angles = jnp.asarray(angles)
    ez = jnp.asarray([0.0, 0.0, 1.0], angles.dtype)
    ey = jnp.asarray([0.0, 1.0, 0.0], angles.dtype)
    ex = jnp.asarray([1.0, 0.0, 0.0], angles.dtype)
    return so3_exp(ez * angles[..., 0:1]) @ so3_exp(ey * angles[..., 1:2]) @ so3_exp(ex * angles[..., 2:3])
