"""bodytrack's cylinders, fast: the kinematic chain of :func:`jaxmocap.parsec.model.parsec31` written with the
structure of PARSEC's joints, the scaled cylinder poses and their projected outlines (``jaxmocap/parsec/FORMAT.md``
§6.2–6.3).

PARSEC's joints only rotate about coordinate axes, so a joint mixes two rotation columns instead of multiplying
matrices, and the float32 sine and cosine are computed by a short polynomial that XLA vectorises. Batch axes are
trailing (``x (31, *B)``) so that every intermediate is a long flat array.
"""

from __future__ import annotations

from collections.abc import Mapping

import jax.numpy as jnp
import numpy as np

from jaxmocap.parsec.cameras import Cameras, _project_xyz, _trail
from jaxmocap.parsec.files import BodyShape
from jaxmocap.parsec.model import (
    _SEGMENTS,
    CYLINDER_SEGMENT,
    SEGMENT_NAMES,
    cylinder_lengths,
    shape_from_dims,
)

__all__ = ["cylinder_corners", "cylinder_poses"]


def _materialise(*arrays: jnp.ndarray) -> list[jnp.ndarray]:
    """The same arrays (one shape), computed once: read back through one gather of their stack.

    XLA's CPU compiler drops ``lax.optimization_barrier`` before fusion and copies cheap element-wise producers
    into every fusion that reads them (:mod:`jaxmocap.likelihood.maps`), so a value read by many outputs is
    recomputed for each; a gather is never copied. Used where the recomputation was measured to cost: the
    sines and cosines read by every joint of the chain, and the outline offsets read by the eight corner
    coordinates (``benchmarks/perf/bench_parsec.py --against``).
    """
    stack = jnp.stack(arrays)
    out = jnp.take(stack, jnp.arange(len(arrays)), axis=0, mode="clip")
    return [out[i] for i in range(len(arrays))]


def _sincos(x: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """``(sin x, cos x)``; float32 by Cody–Waite reduction to [−π/4, π/4] and Cephes' polynomials (≤ 1 ulp for
    the angles of a body, about 10× faster than XLA's CPU sin/cos), float64 by ``jnp.sin``/``jnp.cos``."""
    x = jnp.asarray(x)
    if x.dtype != jnp.float32:
        return jnp.sin(x), jnp.cos(x)
    f = np.float32
    k = jnp.floor(x * f(2.0 / np.pi) + f(0.5))
    r = ((x - k * f(1.5703125)) - k * f(4.837512969970703125e-4)) - k * f(7.54978995489188216e-8)
    z = r * r
    s = ((f(-1.9515295891e-4) * z + f(8.3321608736e-3)) * z - f(1.6666654611e-1)) * z * r + r
    c = ((f(2.443315711809948e-5) * z - f(1.388731625493765e-3)) * z + f(4.166664568298827e-2)) * z * z
    c = c - f(0.5) * z + f(1.0)
    q = k - f(4.0) * jnp.floor(k * f(0.25))  # quadrant 0..3
    swap = (q == 1.0) | (q == 3.0)
    sn = jnp.where(swap, c, s)
    cs = jnp.where(swap, s, c)
    sn = jnp.where(q >= 2.0, -sn, sn)
    cs = jnp.where((q == 1.0) | (q == 2.0), -cs, cs)
    return sn, cs


# A frame is (cols, t): cols[j] the j-th rotation column and t the translation, each a (3, *B) array.


def _times_constant(cols, M: np.ndarray):
    """``R · M`` for a constant signed permutation ``M``: columns picked and negated, no arithmetic."""
    out = []
    for j in range(3):
        i = int(np.flatnonzero(M[:, j])[0])
        out.append(cols[i] if M[i, j] > 0 else -cols[i])
    return tuple(out)


def _times_axis_rotation(cols, axis: tuple, s, c):
    """``R · R_a(θ)`` for a rotation about ±x, ±y or ±z (``s, c`` = sin, cos of θ): two columns mix."""
    k = int(np.flatnonzero(axis)[0])
    s = s if axis[k] > 0 else -s
    i, j = {0: (1, 2), 1: (2, 0), 2: (0, 1)}[k]  # R_a maps e_i → c e_i + s e_j, e_j → −s e_i + c e_j
    out = list(cols)
    out[i] = c * cols[i] + s * cols[j]
    out[j] = c * cols[j] - s * cols[i]
    return tuple(out)


def _segment_frames(lengths: jnp.ndarray, x: jnp.ndarray) -> list:
    """The 14 segment frames of :data:`~jaxmocap.parsec.model.SEGMENT_NAMES` for states ``x (31, *B)`` (batch
    axes trailing, ``B = ()`` for one state): per segment ``(cols, t)`` with ``(3, *B)`` arrays (the hot path).

    Same chain as :func:`~jaxmocap.parsec.model.parsec31`'s ``segment_poses`` (tested), written with the structure
    of PARSEC's joints: constant rotations permute columns and a rotation about a coordinate axis mixes two
    columns.
    """
    dt = x.dtype
    batch = x.shape[1:]
    sin, cos = _materialise(*_sincos(x))
    sin, cos = sin[:, None], cos[:, None]  # (31, 1, *B) against (3, *B) columns
    eye = jnp.broadcast_to(_trail(jnp.eye(3, dtype=dt), len(batch)), (3, 3) + batch)
    frames: list = []
    for name, parent, rot, off, dofs in _SEGMENTS:
        if parent is None:
            cols = (eye[:, 0], eye[:, 1], eye[:, 2])
            t = x[3:6]
        else:
            pcols, t = frames[SEGMENT_NAMES.index(parent)]
            if off is not None:
                k, sign, axis = off
                t = t + pcols[axis] * (sign * lengths[k])
            cols = _times_constant(pcols, rot)
        for d, axis in dofs:
            if not (name == "pelvis" and d in (3, 4, 5)):  # the pelvis translation is set above
                cols = _times_axis_rotation(cols, axis, sin[d], cos[d])
        frames.append((cols, t))
    return frames


def _cylinder_frames(shape: BodyShape, x: jnp.ndarray):
    """Scaled cylinder frames of states ``x (31, *B)``: ``(A, t)`` with ``A[i][j]`` and ``t[i]`` ``(10, *B)``
    arrays (row i, column j of the scaled rotation ``R·diag(sx, sy, 1)``)."""
    dt = x.dtype
    nb = x.ndim - 1
    limbs = jnp.asarray(shape.limbs, dt)
    frames = _segment_frames(jnp.asarray(shape.lengths, dt), x)
    sel = [frames[s] for s in CYLINDER_SEGMENT]
    scale = (_trail(limbs[:, 2], nb + 1), _trail(limbs[:, 3], nb + 1), None)
    A_cols = []
    for j in range(3):
        v = jnp.stack([f[0][j] for f in sel])  # (10, 3, *B)
        A_cols.append(v if scale[j] is None else v * scale[j])
    T = jnp.stack([f[1] for f in sel])
    A = [[A_cols[j][:, i] for j in range(3)] for i in range(3)]
    return A, [T[:, i] for i in range(3)]


def cylinder_poses(dims: BodyShape | Mapping[str, object] | None, x: jnp.ndarray) -> jnp.ndarray:
    """bodytrack's cylinder poses ``(10, 3, 4)`` ``[R·diag(sx, sy, 1) | t]`` (mm) for one state ``x (31,)``.

    ``dims``: the body shape as for :func:`~jaxmocap.parsec.model.parsec31`. Use ``jax.vmap`` for particles.
    """
    shape = shape_from_dims(dims)
    x = jnp.asarray(x)
    A, t = _cylinder_frames(shape, x)
    rows = [jnp.stack([A[i][0], A[i][1], A[i][2], t[i]], -1) for i in range(3)]
    return jnp.stack(rows, 1)


def _scaled_poses(shape: BodyShape, R: jnp.ndarray, t: jnp.ndarray) -> jnp.ndarray:
    """Cylinder poses from :func:`jaxmocap.geometry.body.segment_poses` of :func:`~jaxmocap.parsec.model.parsec31`
    (``R (14, 3, 3)``, ``t``)."""
    seg = np.asarray(CYLINDER_SEGMENT)
    limbs = jnp.asarray(shape.limbs, R.dtype)
    scale = jnp.stack([limbs[:, 2], limbs[:, 3], jnp.ones_like(limbs[:, 2])], -1)  # (10, 3)
    Rc = R[seg] * scale[:, None, :]
    return jnp.concatenate([Rc, t[seg][:, :, None]], -1)


def cylinder_corners(shape: BodyShape, cams: Cameras, poses: jnp.ndarray) -> jnp.ndarray:
    """Projected outline corners of every cylinder in every camera (§6.3): ``poses (10, 3, 4)`` → ``(V, 10, 4,
    2)`` pixels, corners in bodytrack's order P0..P3.

    In the cylinder's scaled local frame, ``r = (0, 0, len/2) − inv(pose)·eye`` and ``r2 = (−r.y, r.x, 0)/|r.xy|``;
    the corners ``P0 = −b r2``, ``P1 = −t r2 + (0, 0, len)``, ``P2 = t r2 + (0, 0, len)``, ``P3 = b r2`` (b, t the
    bottom and top radii) go through the pose and the camera. Written per coordinate over ``(V, 10)`` arrays.
    """
    A = [[poses[:, i, j] for j in range(3)] for i in range(3)]
    t = [poses[:, i, 3] for i in range(3)]
    return _corners(shape, cams, A, t)


def _corners(shape: BodyShape, cams: Cameras, A, t) -> jnp.ndarray:
    """:func:`cylinder_corners` from scaled frames ``A[i][j]``, ``t[i]`` of shape ``(10, *B)`` → ``(V, 10, 4, 2,
    *B)``. Every intermediate is a ``(V, 10, *B)`` array (batch axes last, so XLA vectorises over them)."""
    dt = t[0].dtype
    nb = t[0].ndim - 1
    c = cams.astype(dt)
    limbs = jnp.asarray(shape.limbs, dt)
    length = _trail(cylinder_lengths(shape).astype(dt), nb)
    bottom, top = _trail(limbs[:, 0], nb), _trail(limbs[:, 1], nb)
    sx, sy = _trail(limbs[:, 2], nb), _trail(limbs[:, 3], nb)
    cam = lambda a: _trail(a, nb + 1)  # (V,) → (V, 1, *1)
    # eye in the scaled local frame, inv([A | t])·eye = diag(1/sx, 1/sy, 1) Rᵀ (eye − t), Rᵀ's rows = A's
    # columns over the scales; only its x and y are needed
    e = [cam(c.eye[:, i]) - t[i][None] for i in range(3)]  # (V, 10, *B)
    ex = (A[0][0] * e[0] + A[1][0] * e[1] + A[2][0] * e[2]) / (sx * sx)
    ey = (A[0][1] * e[0] + A[1][1] * e[1] + A[2][1] * e[2]) / (sy * sy)
    inv = 1.0 / jnp.sqrt(ex * ex + ey * ey)
    r2x = ey * inv  # r2 = (−r.y, r.x)/|r| with r = (0, 0, len/2) − eye_local
    r2y = -ex * inv
    u = [A[i][0] * r2x + A[i][1] * r2y for i in range(3)]  # world offset of the local (r2x, r2y, 0)
    # computed once, not once per corner coordinate (the eight outputs would each recompute them)
    *u, tx, ty, tz = _materialise(*u, *(jnp.broadcast_to(t[i], u[0].shape) for i in range(3)))
    t = [tx, ty, tz]
    w = [A[i][2] * length for i in range(3)]  # world offset of the local (0, 0, len), (10, *B)
    corners = []
    for k, rad in enumerate((-bottom, -top, top, bottom)):
        P = [t[i] + rad * u[i] + (w[i] if k in (1, 2) else 0.0) for i in range(3)]
        corners.append(_project_xyz(c, *P, nb=nb + 1))
    return jnp.stack([jnp.stack(p, 2) for p in corners], 2)
