"""Speed of PARSEC bodytrack's likelihood: JAX (``jaxmocap.parsec.likelihood``) against a NumPy baseline.

Reports µs per particle per layer (one likelihood evaluation of every particle) for ``--particles`` states drawn
around sequenceB_2's initial pose with PoseParameters' standard deviations, 4 cameras, frame 0: the median and
minimum wall time of ``--repeats`` runs after compilation, the process CPU time, and the same for a NumPy
implementation of the same likelihood (vectorised over particles, float32 like the C++;
:func:`reference.numpy_baselines.np_loglik`) run in the same process.
bodytrack's serial C++ takes about 13 µs per particle and layer on a 2-core machine like the CI machine
(``jaxmocap/parsec/FORMAT.md``, including its noise and resampling).

    .venv/bin/python benchmarks/perf/bench_parsec.py [--particles 4000] [--repeats 9] [--devices 2]

``--devices 2`` splits the particles over two XLA host devices (one per core) with ``shard_map``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common

DATA = common.ROOT / "tests" / "data" / "parsec"
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
from reference.numpy_baselines import np_loglik  # noqa: E402

from jaxmocap import parsec  # noqa: E402
from jaxmocap.parsec import likelihood as pl  # noqa: E402


def _png(p):
    return cv2.imread(str(p), cv2.IMREAD_UNCHANGED)


def _stats(t: common.Timings):
    """Median and minimum wall time, median CPU time."""
    return np.median(t.wall), np.min(t.wall), np.median(t.cpu)


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
    med, best, cpu = _stats(common.timed_calls(lambda: f(Xj, obs).block_until_ready(), args.repeats))

    ll_np = np_loglik(shape, cams, edge, fg, X)  # warm-up and agreement
    nmed, nbest, ncpu = _stats(
        common.timed_calls(lambda: np_loglik(shape, cams, edge, fg, X), args.numpy_repeats)
    )

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
