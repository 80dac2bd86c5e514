"""Throughput of forward kinematics + projection of flesh points (full25, ~600 points, 2 views).

Compares, in one process, the compiled JAX hot path (structure-of-arrays FK, vmapped over particles) with a NumPy
implementation of the same arithmetic, vectorised over particles (:func:`reference.numpy_baselines.fk_projection`).
Prints medians and the ratio.

    python benchmarks/perf/bench_kinematics.py [--particles 4000] [--repeats 7] [--quick]
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common
from reference.numpy_baselines import fk_projection

from jaxmocap.geometry import body, camera, flesh, kinematics


def _stereo_rig():
    K = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])
    R = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])  # looking along −x, z up
    ts = [-R @ np.array([3.0, y, 1.0]) for y in (-0.15, 0.15)]
    return camera.from_opencv(np.stack([K, K]), np.zeros((2, 5)), np.stack([R, R]), np.stack(ts))


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
    t_jax = common.median_seconds(lambda: f(X).block_until_ready(), repeats, warmup=1)
    Xn = np.asarray(X, np.float64)
    pts = np.asarray(surf.local, np.float64)
    seg = np.asarray(surf.segment)
    ref = fk_projection(model, pts, seg, rig, Xn)
    np.testing.assert_allclose(np.asarray(f(X)), ref, atol=0.05)  # same arithmetic, float32 vs float64
    n_np = max(particles // 4, 100)
    t_np = common.median_seconds(
        lambda: fk_projection(model, pts, seg, rig, Xn[:n_np]), max(3, repeats // 2), warmup=1
    )
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
