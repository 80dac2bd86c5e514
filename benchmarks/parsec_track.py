"""PARSEC bodytrack's sequenceB_2 tracked with the APF in PARSEC mode, ``parsec31`` and the PARSEC likelihood, with
bodytrack's two configurations (4000 particles × 5 layers, 1000 × 3), compared with bodytrack's own output poses.

bodytrack is stochastic, so its output is one draw: the comparison reports, per frame, the mean distance (mm) over
the 15 evaluation joints between our estimate and ``reference/poses_<N>p<L>l.txt`` for each seed, next to the
spread of our estimates (mean joint distance between the estimates of two seeds, over all seed pairs). Speed: the
median wall time of a filter step (all layers) per frame after compilation, plus the per-frame preprocessing (edge
maps), against bodytrack's serial 0.28 s/frame (4000 × 5) and 0.062 s/frame (1000 × 3) on a 2-core machine
(FORMAT.md). Initialisation as bodytrack's: particles ``InitialPose + N(0, σ_0)`` weighted against frame 0 with
its β. Usage::

    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/parsec_track.py [--seeds 3] [--report]
"""

from __future__ import annotations

import argparse
import itertools
import os
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap import body as body_mod
from jaxmocap import parsec
from jaxmocap import parsec_track as ptrack
from jaxmocap.filters import APF

DATA = pathlib.Path(os.environ.get("JAXMOCAP_DATA", "/work/shared/data")) / "parsec"
RESULTS = pathlib.Path(__file__).resolve().parent / "results"
CONFIGS = ((4000, 5), (1000, 3))
BODYTRACK_S = {(4000, 5): 0.284, (1000, 3): 0.062}


def make_runner(seq, num_particles: int, num_layers: int):
    """``run(obs, seed) -> (estimates (F, 31), per-frame step seconds)``, compiled once per configuration."""
    std = jnp.asarray(seq.pose_std, jnp.float32)
    loglik = ptrack.make_loglik(seq.shape, seq.cameras)  # bodytrack drops invalid poses (−1e10)
    filt = APF.parsec(loglik, std, num_particles, num_layers)

    @jax.jit
    def start(k, o):
        return ptrack.weighted_start(filt, loglik, k, jnp.asarray(seq.initial_pose, jnp.float32), std, o)

    step = jax.jit(filt.step)

    def run(obs, seed: int):
        key = jax.random.key(seed)
        state = start(jax.random.fold_in(key, 1000), obs[0])
        est, secs = [], []
        for t in range(len(obs)):
            t0 = time.perf_counter()
            state, info = step(jax.random.fold_in(key, t), state, obs[t])
            jax.block_until_ready(state.particles)
            secs.append(time.perf_counter() - t0)
            est.append(np.asarray(info.estimate, np.float64))
        return np.stack(est), secs

    return run


def joints_mm(model, X: np.ndarray) -> np.ndarray:
    f = jax.jit(jax.vmap(lambda x: body_mod.joint_positions(model, x)))
    return np.asarray(f(jnp.asarray(X, jnp.float32)), np.float64)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--report", action="store_true", help=f"write {RESULTS}/parsec_track.md")
    a = ap.parse_args(argv)
    seq = parsec.load_sequence(DATA / "sequenceB_2")
    t0 = time.perf_counter()
    obs = [seq.observation(t) for t in range(len(seq.frames))]
    prep = (time.perf_counter() - t0) / len(obs)
    model = parsec.parsec31(seq.shape)  # millimetres
    lines = []
    for N, L in CONFIGS:
        ref = parsec.load_poses(DATA / "reference" / f"poses_{N}p{L}l.txt")
        J_ref = joints_mm(model, ref)
        runs, times = [], []
        run = make_runner(seq, N, L)
        for s in range(a.seeds):
            est, secs = run(obs, s)
            runs.append(joints_mm(model, est))
            times += secs if s > 0 else secs[1:]  # the first call compiles
        J = np.stack(runs)  # (S, F, 15, 3)
        d_ref = np.linalg.norm(J - J_ref[None], axis=-1).mean(axis=-1)  # (S, F)
        pairs = list(itertools.combinations(range(len(J)), 2))
        spread = (
            np.mean([np.linalg.norm(J[i] - J[j], axis=-1).mean(axis=-1) for i, j in pairs], axis=0)
            if pairs
            else np.full(J.shape[1], np.nan)
        )
        step_s = float(np.median(times))
        for f in range(J.shape[1]):
            line = (
                f"| {N} × {L} | {f} | {np.mean(d_ref[:, f]):.1f} ({np.min(d_ref[:, f]):.1f}–{np.max(d_ref[:, f]):.1f}) | "
                f"{spread[f]:.1f} |"
            )
            lines.append(line)
            print(line, flush=True)
        tline = f"| {N} × {L} | {step_s:.3f} | {prep:.3f} | {step_s + prep:.3f} | {BODYTRACK_S[(N, L)]:.3f} |"
        print(tline, flush=True)
        lines.append(("time", tline))
    if a.report:
        acc = [x for x in lines if isinstance(x, str)]
        tim = [x[1] for x in lines if not isinstance(x, str)]
        dev = jax.devices()[0]
        text = (
            "# PARSEC sequenceB_2: APF (PARSEC mode) + parsec31 + PARSEC likelihood vs bodytrack\n\n"
            f"Reproduce: `JAX_PLATFORMS=cpu .venv/bin/python benchmarks/parsec_track.py --seeds {a.seeds} --report`\n\n"
            f"Seeds 0–{a.seeds - 1}; distances are the mean over the 15 evaluation joints (mm) of the parsec31 model "
            "(PARSEC's 10 cylinders).\n\n"
            "| config | frame | to bodytrack's pose: mean (min–max over seeds) | our spread (between seeds) |\n"
            "|---|---|---|---|\n" + "\n".join(acc) + "\n\n"
            f"## Time per frame ({dev.platform}, after compilation; median over seeds and frames 1+)\n\n"
            "| config | filter step s | edge/fg maps s | total s | bodytrack serial s |\n|---|---|---|---|---|\n"
            + "\n".join(tim)
            + "\n"
        )
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / "parsec_track.md").write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
