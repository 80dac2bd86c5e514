"""Speed of PARSEC bodytrack's likelihood: JAX (``jaxmocap.parsec.likelihood``) against a NumPy baseline.

Reports µs per particle per layer (one likelihood evaluation of every particle) for ``--particles`` states drawn
around sequenceB_2's initial pose with PoseParameters' standard deviations, 4 cameras, frame 0: the median and
minimum wall time of ``--repeats`` runs after compilation, the process CPU time, and the same for a NumPy
implementation of the same likelihood (vectorised over particles, float32 like the C++) run in the same process.
bodytrack's serial C++ takes about 13 µs per particle and layer on a 2-core machine like the CI machine
(``jaxmocap/parsec/FORMAT.md``, including its noise and resampling).

    .venv/bin/python benchmarks/bench_parsec.py [--particles 4000] [--repeats 9] [--devices 2]

``--devices 2`` splits the particles over two XLA host devices (one per core) with ``shard_map``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "parsec"
BODYTRACK_US = 13.0


def _args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--particles", type=int, default=4000)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--numpy-repeats", type=int, default=3)
    ap.add_argument("--devices", type=int, default=1, help="XLA host devices to split the particles over")
    return ap.parse_args(argv)


ARGS = _args() if __name__ == "__main__" else None
if ARGS is not None and ARGS.devices > 1:  # must precede the first import of jax
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={ARGS.devices}"
    )

import cv2  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxmocap import parsec  # noqa: E402
from jaxmocap.parsec import likelihood as pl  # noqa: E402

# ---------------------------------------------------------------------------------------------------------------
# NumPy baseline: bodytrack's likelihood written with batched 3×3 matrices, vectorised over particles

F = np.float32
_XR90 = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], F)
_XR180 = np.diag([1, -1, -1]).astype(F)
_XR270 = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], F)
_YR90 = np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]], F)
_YR180 = np.diag([-1, 1, -1]).astype(F)
_ZR180 = np.diag([-1, -1, 1]).astype(F)


def _rot(axis, a):
    c, s = np.cos(a).astype(F), np.sin(a).astype(F)
    o, z = np.ones_like(c), np.zeros_like(c)
    if axis == 0:
        m = [[o, z, z], [z, c, -s], [z, s, c]]
    elif axis == 1:
        m = [[c, z, s], [z, o, z], [-s, z, c]]
    else:
        m = [[c, -s, z], [s, c, z], [z, z, o]]
    return np.stack([np.stack(r, -1) for r in m], -2)


def _euler_inv(th, ph, ta):
    """``inv(Rz(ta) Rx(th) Ry(ph))`` for ``(N,)`` angles."""
    E = _rot(2, ta) @ _rot(0, th) @ _rot(1, ph)
    return np.swapaxes(E, -1, -2)


def np_cylinder_poses(limbs, L, X):
    """``(N, 10, 3, 4)`` poses following BodyGeometry.cpp step by step."""
    N = len(X)
    a = X.T
    z = np.zeros(N, F)
    Rp = _rot(2, a[2]) @ _rot(0, a[0]) @ _rot(1, a[1])
    tp = np.stack([a[3], a[4], a[5]], -1)

    def pre(R, t, v):
        return t + R @ np.asarray(v, F)

    out = [None] * 10
    out[0] = (Rp, tp)
    for side, (hip, knee, off, l1) in enumerate(((6, 9, L[1], 2), (10, 13, -L[5], 6))):
        R = Rp @ _YR180
        t = pre(R, tp, [0, off, 0])
        R = R @ _euler_inv(a[hip], a[hip + 1], a[hip + 2])
        out[1 + 2 * side] = (R, t)
        t = pre(R, t, [0, 0, L[l1]])
        R = R @ _euler_inv(z, a[knee], z)
        out[2 + 2 * side] = (R, t)
    Rt = Rp @ _XR180 @ _euler_inv(z, a[26], a[27])
    tt = pre(Rt, tp, [0, 0, -L[0]])
    r = _XR90 @ _ZR180 @ _YR90
    for side, (cl, sh, el, rot, lc, lu) in enumerate(
        ((14, 16, 19, _XR90, 9, 10), (20, 22, 25, _XR270, 13, 14))
    ):
        R = Rt @ rot @ _euler_inv(a[cl], a[cl + 1], z)
        t = pre(R, tt, [0, 0, -L[lc]])
        R = R @ r @ _euler_inv(a[sh], a[sh + 1], a[sh + 2])
        out[5 + 2 * side] = (R, t)
        t = pre(R, t, [0, 0, -L[lu]])
        R = R @ _euler_inv(z, a[el], z)
        out[6 + 2 * side] = (R, t)
    out[9] = (Rt @ _XR180 @ _euler_inv(a[28], a[29], a[30]), tt)
    R = (
        np.stack([o[0] for o in out], 1)
        * np.concatenate([limbs[:, 2:4], np.ones((10, 1), F)], 1)[None, :, None, :]
    )
    t = np.stack([o[1] for o in out], 1)
    return np.concatenate([R, t[..., None]], -1)


def np_corners(limbs, length, cams, P):
    """``(N, V, 10, 4, 2)`` projected corners."""
    A, t = P[..., :3], P[..., 3]
    Ainv = np.linalg.inv(A)
    out = []
    for v in range(len(cams.fc)):
        e = np.einsum("npij,npj->npi", Ainv, cams.eye[v].astype(F) - t)
        r = np.stack([-e[..., 0], -e[..., 1]], -1)
        r2 = np.stack([-r[..., 1], r[..., 0]], -1) / np.linalg.norm(r, axis=-1, keepdims=True)
        pts = []
        for rad, zz in (
            (-limbs[:, 0], 0.0),
            (-limbs[:, 1], length),
            (limbs[:, 1], length),
            (limbs[:, 0], 0.0),
        ):
            loc = np.concatenate(
                [
                    rad[:, None] * r2,
                    np.broadcast_to(np.asarray(zz, F), rad.shape)[None, :, None] + 0 * r2[..., :1],
                ],
                -1,
            )
            pts.append(np.einsum("npij,npj->npi", A, loc) + t)
        X = np.stack(pts, 2)  # (N, 10, 4, 3)
        Xc = X @ cams.R[v].T.astype(F) + cams.T[v].astype(F)
        x, y = Xc[..., 0] / Xc[..., 2], Xc[..., 1] / Xc[..., 2]
        r2_ = x * x + y * y
        kc = cams.kc[v].astype(F)
        d = 1 + kc[0] * r2_ + kc[1] * r2_ * r2_ + kc[4] * r2_**3
        xd = d * x + kc[2] * 2 * x * y + kc[2] * (r2_ + 2 * x * x)
        yd = d * y + kc[2] * (r2_ + 2 * y * y) + kc[2] * 2 * x * y
        u = cams.fc[v, 0] * (xd + cams.alpha[v] * yd) + cams.cc[v, 0]
        w = cams.fc[v, 1] * yd + cams.cc[v, 1]
        out.append(np.stack([u, w], -1).astype(F))
    return np.stack(out, 1)


def _steps(d, n_max):
    """Float32 running sums 0, d, 2d, … (sequential, as the C++ loop) → ``(N, n_max + 1)``."""
    inc = np.broadcast_to(d[:, None], (len(d), n_max)).astype(F)
    return np.concatenate([np.zeros((len(d), 1), F), np.cumsum(inc, axis=1, dtype=F)], 1)


def _take(flat, offset, x, y, mask, W, H):
    xs, ys = (x + F(0.5)).astype(F), (y + F(0.5)).astype(F)
    m = mask & (xs > -1) & (xs < W) & (ys > -1) & (ys < H)
    idx = (
        offset
        + np.floor(np.maximum(ys, 0)).astype(np.int64) * W
        + np.floor(np.maximum(xs, 0)).astype(np.int64)
    )
    return np.take(flat, np.where(m, idx, 0)), m


def np_loglik(shape, cams, edge, fg, X):
    """bodytrack's log-likelihood of particles ``X (N, 31)`` with NumPy."""
    limbs, L = shape.limbs.astype(F), shape.lengths.astype(F)
    length = np.asarray(parsec.cylinder_lengths(shape), F)
    P = np_cylinder_poses(limbs, L, X.astype(F))
    uv = np_corners(limbs, length, cams, P)
    V, H, W = edge.shape
    fe, ff = edge.reshape(-1), fg.reshape(-1)
    N = len(X)
    ssd, ne, bg, ni = (np.zeros(N) for _ in range(4))
    for v in range(V):
        off = v * H * W
        for p in range(10):
            c = uv[:, v, p]
            for a, b in ((0, 1), (2, 3)):
                s = c[:, b] - c[:, a]
                n = np.maximum(np.floor(np.hypot(s[:, 0], s[:, 1]) / 5 + 0.5), 4).astype(np.int64)
                t = _steps((1 / n).astype(F), n.max())
                mask = np.arange(n.max() + 1)[None] <= n[:, None]
                val, m = _take(fe, off, c[:, a, :1] + t * s[:, :1], c[:, a, 1:] + t * s[:, 1:], mask, W, H)
                e = 255 - val.astype(np.int64)
                ssd += np.where(m, e * e, 0).sum(1)
                ne += m.sum(1)
            s1, s2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 3]
            mm = c[:, 0] + s1 / F(2) - (c[:, 3] + s2 / F(2))
            n1 = np.maximum(np.floor(np.hypot(s1[:, 0], s1[:, 1]) / 10 + 0.5), 4).astype(np.int64)
            n2 = np.maximum(np.floor(np.hypot(mm[:, 0], mm[:, 1]) / 10 + 0.5), 4).astype(np.int64)
            t1 = _steps((1 / n1).astype(F), n1.max())  # (N, R)
            t2 = _steps((1 / n2).astype(F), n2.max())[:, :-1]  # (N, C)
            e1 = c[:, None, 0] + t1[..., None] * s1[:, None]
            e2 = c[:, None, 3] + t1[..., None] * s2[:, None]
            md = e2 - e1
            x = e1[:, :, None, 0] + t2[:, None, :] * md[:, :, None, 0]
            y = e1[:, :, None, 1] + t2[:, None, :] * md[:, :, None, 1]
            mask = (np.arange(n1.max() + 1)[None, :, None] <= n1[:, None, None]) & (
                np.arange(n2.max())[None, None, :] < n2[:, None, None]
            )
            val, m = _take(ff, off, x, y, mask, W, H)
            bg += (m & (val == 0)).sum((1, 2))
            ni += m.sum((1, 2))
    ll = -(ssd / 255.0**2 / ne + bg / ni)
    valid = np.asarray(jax.vmap(lambda q: pl.geometry_valid(shape, q))(jnp.asarray(P)))
    return np.where(valid, ll, pl.INVALID)


# ---------------------------------------------------------------------------------------------------------------


def _png(p):
    return cv2.imread(str(p), cv2.IMREAD_UNCHANGED)


def _time(fn, repeats):
    walls, cpus = [], []
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return np.median(walls), np.min(walls), np.median(cpus)


def main(args):
    seq = DATA / "sequenceB_2"
    shape = parsec.load_body_shape(seq / "BodyShapeParameters.txt")
    cams = parsec.load_cameras(seq)
    x0 = parsec.load_pose(seq / "InitialPose.txt")
    std = parsec.load_pose_parameters(seq / "PoseParameters.txt").std
    ims = np.stack([_png(DATA / "frames" / f"cam{k}_f0000.png") for k in range(1, 5)])
    fgs = np.stack([_png(DATA / "frames" / f"fg{k}_f0000.png") for k in range(1, 5)])
    edge = np.stack([parsec.edge_map(im) for im in ims])
    fg = (fgs != 0).astype(np.uint8)
    obs = pl.observation(edge, fg)
    N = args.particles
    X = (x0 + np.random.default_rng(0).normal(size=(N, 31)) * std).astype(np.float32)
    Xj = jnp.asarray(X)

    ll_fn = pl.make_loglik_batch(shape, cams)
    if args.devices > 1:
        from jax.sharding import Mesh, NamedSharding
        from jax.sharding import PartitionSpec as P

        mesh = Mesh(np.array(jax.devices()[: args.devices]), ("p",))
        f = jax.jit(
            jax.shard_map(ll_fn, mesh=mesh, in_specs=(P("p"), P()), out_specs=P("p"), check_vma=False)
        )
        Xj = jax.device_put(Xj, NamedSharding(mesh, P("p")))
        obs = jax.device_put(obs, NamedSharding(mesh, P()))
    else:
        f = jax.jit(ll_fn)
    t0 = time.perf_counter()
    ll = np.asarray(f(Xj, obs))
    compile_s = time.perf_counter() - t0
    med, best, cpu = _time(lambda: f(Xj, obs).block_until_ready(), args.repeats)

    ll_np = np_loglik(shape, cams, edge, fg, X)  # warm-up and agreement
    nmed, nbest, ncpu = _time(lambda: np_loglik(shape, cams, edge, fg, X), args.numpy_repeats)

    us = lambda s: s / N * 1e6
    print(f"PARSEC likelihood, {N} particles x 4 views (640x480), frame 0 of sequenceB_2")
    print(
        f"  devices: {jax.devices()[: args.devices]}, cores visible: {os.cpu_count()}, load average: {os.getloadavg()}"
    )
    print(f"  JAX    compile+first run {compile_s:.1f} s")
    print(
        f"  JAX    µs/particle/layer: median {us(med):.2f}  min {us(best):.2f}  (process CPU {us(cpu):.2f})"
    )
    print(
        f"  NumPy  µs/particle/layer: median {us(nmed):.2f}  min {us(nbest):.2f}  (process CPU {us(ncpu):.2f})"
    )
    print(f"  speed-up JAX vs NumPy (median): {nmed / med:.1f}x")
    print(
        f"  vs bodytrack serial C++ ≈ {BODYTRACK_US:.0f} µs: {BODYTRACK_US / us(med):.2f}x (median), {BODYTRACK_US / us(best):.2f}x (min)"
    )
    ok = (ll > -1e9) & (ll_np > -1e9)
    print(
        f"  agreement: valid flags equal {np.mean((ll > -1e9) == (ll_np > -1e9)):.4f}, "
        f"max |Δ loglik| {np.abs(ll[ok] - ll_np[ok]).max():.2e}, "
        f"exactly equal {np.mean(ll[ok] == ll_np[ok].astype(np.float32)):.3f}"
    )


if __name__ == "__main__":
    sys.exit(main(ARGS))
