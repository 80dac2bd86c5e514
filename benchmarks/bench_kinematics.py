"""Throughput of forward kinematics + projection of flesh points (full25, ~600 points, 2 views).

Compares, in one process, the compiled JAX hot path (structure-of-arrays FK, vmapped over particles) with a NumPy
implementation of the same arithmetic, vectorised over particles. Prints medians and the ratio.

    python benchmarks/bench_kinematics.py [--particles 4000] [--repeats 7] [--quick]
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
from bench_likelihood import np_segment_poses

from jaxmocap.geometry import body, camera, flesh, kinematics


def _stereo_rig():
    K = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])
    R = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])  # looking along −x, z up
    ts = [-R @ np.array([3.0, y, 1.0]) for y in (-0.15, 0.15)]
    return camera.from_opencv(np.stack([K, K]), np.zeros((2, 5)), np.stack([R, R]), np.stack(ts))


def _numpy_pipeline(model, pts_local, seg, rig, X):
    """The same arithmetic in NumPy (float64): FK over the tree (batched over particles, the NumPy FK of
    ``bench_likelihood.py``), point transform, projection."""
    R, t = np_segment_poses(model, X, np.float64)
    R, t = R[:, seg], t[:, seg]
    Xw = np.einsum("npij,pj->npi", R, pts_local) + t
    Xc = np.einsum("vij,npj->nvpi", np.asarray(rig.R), Xw) + np.asarray(rig.t)[None, :, None, :]
    K = np.asarray(rig.K)
    u = K[None, :, 0, 0, None] * Xc[..., 0] / Xc[..., 2] + K[None, :, 0, 2, None]
    v = K[None, :, 1, 1, None] * Xc[..., 1] / Xc[..., 2] + K[None, :, 1, 2, None]
    return np.stack([u, v], -1)


def _median_time(f, repeats):
    f()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def run(particles: int = 4000, repeats: int = 7, points: int = 600) -> dict:
    model = body.full25()
    rig = _stereo_rig()
    layout = flesh.surface_layout(model, total=points)
    surf = flesh.surface_points(model, layout)
    rigj = rig.to_jax(jnp.float32)

    def one(x):
        R, t = body.segment_poses(model, x)
        Xw = kinematics.transform_points(R, t, surf.local, surf.segment)
        return camera.project(rigj, Xw)

    f = jax.jit(jax.vmap(one))
    X = model.rest_pose + 0.3 * jax.random.normal(jax.random.key(0), (particles, model.num_dofs))
    t_jax = _median_time(lambda: f(X).block_until_ready(), repeats)
    Xn = np.asarray(X, np.float64)
    pts = np.asarray(surf.local, np.float64)
    seg = np.asarray(surf.segment)
    ref = _numpy_pipeline(model, pts, seg, rig, Xn)
    np.testing.assert_allclose(np.asarray(f(X)), ref, atol=0.05)  # same arithmetic, float32 vs float64
    n_np = max(particles // 4, 100)
    t_np = _median_time(lambda: _numpy_pipeline(model, pts, seg, rig, Xn[:n_np]), max(3, repeats // 2))
    return {
        "particles": particles,
        "points": int(pts.shape[0]),
        "views": rig.num_views,
        "jax_particles_per_s": particles / t_jax,
        "numpy_particles_per_s": n_np / t_np,
        "ratio": (particles / t_jax) / (n_np / t_np),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=4000)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--quick", action="store_true", help="tiny sizes (smoke test)")
    a = ap.parse_args(argv)
    r = run(200, 2) if a.quick else run(a.particles, a.repeats)
    print(f"FK + projection, full25, {r['points']} points, {r['views']} views, {r['particles']} particles")
    print(f"  JAX   : {r['jax_particles_per_s']:12,.0f} particles/s")
    print(f"  NumPy : {r['numpy_particles_per_s']:12,.0f} particles/s")
    print(f"  ratio : {r['ratio']:.1f}x")


if __name__ == "__main__":
    main()
