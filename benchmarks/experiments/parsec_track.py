"""PARSEC bodytrack's sequenceB_2 tracked with the APF in PARSEC mode, ``parsec31`` and the PARSEC likelihood, with
bodytrack's two configurations (4000 particles × 5 layers, 1000 × 3), compared with bodytrack's own output poses.

bodytrack is stochastic, so its output is one draw: the comparison reports, per frame, the mean distance (mm) over
the 15 evaluation joints between our estimate and ``reference/poses_<N>p<L>l.txt`` for each seed, next to the
spread of our estimates (mean joint distance between the estimates of two seeds, over all seed pairs). Speed: the
median wall time of a filter step (all layers) per frame after compilation, plus the per-frame preprocessing (edge
maps), against bodytrack's serial build run in the same script after each seed (``benchmarks/bodytrack.py``: built
from source into ``build/bodytrack``; its per-frame time from its "Processing frame" lines, median over seeds and
frames; the 1-minute load average recorded). ``benchmarks/perf/vs_bodytrack.py`` is the interleaved A/B
comparison, idle and loaded. Initialisation as bodytrack's: particles ``InitialPose + N(0, σ_0)`` weighted against frame 0 with
its β. Usage::

    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/experiments/parsec_track.py [--seeds 3] [--report]
    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/experiments/parsec_track.py --overlay benchmarks/results/parsec_overlay.png

``--overlay PATH`` skips the comparison: it tracks frames 0–1 with 1000 particles × 3 layers (seed 0) and writes a
2×2 montage of the four cameras of frame 1 (each 320×240): the projected cones of ``parsec31`` (green), its bones
(yellow) and joints (red), and bodytrack's joints of ``reference/poses_1000p3l.txt`` (white crosses).
"""

from __future__ import annotations

import argparse
import itertools
import os
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import bodytrack
import common
import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap import parsec
from jaxmocap.eval import viz
from jaxmocap.geometry import body as body_mod
from jaxmocap.parsec import track as ptrack
from jaxmocap.parsec.annealing import parsec_apf

DATA = pathlib.Path(os.environ.get("JAXMOCAP_DATA", "/work/shared/data")) / "parsec"

CONFIGS = ((4000, 5), (1000, 3))


def make_runner(seq, num_particles: int, num_layers: int):
    """``run(obs, seed) -> (estimates (F, 31), per-frame step seconds)``, compiled once per configuration."""
    std = jnp.asarray(seq.pose_std, jnp.float32)
    loglik = ptrack.make_loglik(seq.shape, seq.cameras)  # bodytrack drops invalid poses (−1e10)
    filt = parsec_apf(loglik, std, num_particles, num_layers)

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


OVERLAY_SIZE = (320, 240)  # (width, height) of each view in the montage


def _scaled(uv: np.ndarray, s: float) -> np.ndarray:
    """Pixel coordinates of an image resized by ``s`` (pixel centres at integers: ``u' = s (u + ½) − ½``)."""
    return s * (np.asarray(uv, np.float64) + 0.5) - 0.5


def save_overlay(seq, obs, path: pathlib.Path, frame: int = 1, seed: int = 0) -> float:
    """Track frames ``0 … frame`` (1000 × 3, ``seed``) and write the 2×2 montage of ``frame`` to ``path``.

    Everything is in PARSEC's millimetres: the estimate (pelvis translation in mm) on ``parsec31(seq.shape)`` (mm),
    projected through the ``.cal`` cameras loaded in mm (:func:`jaxmocap.parsec.files.load_parsec_calibration`), the
    same projection as bodytrack's ``ProjectPoints`` (:func:`jaxmocap.parsec.cameras.project`, checked here on the joints).
    Returns the mean distance (mm) over the 15 joints between the estimate and bodytrack's pose of ``frame``.
    """
    N, L = 1000, 3
    est, _ = make_runner(seq, N, L)(obs[: frame + 1], seed)
    x = est[frame]
    model = parsec.parsec31(seq.shape)  # millimetres
    cal = [DATA / "sequenceB_2" / "CALIB" / f"Camera{k + 1}.cal" for k in range(seq.cameras.num_views)]
    rig = parsec.load_parsec_calibration(cal, units="mm")
    ref = parsec.load_poses(DATA / "reference" / f"poses_{N}p{L}l.txt")[frame]
    J, J_ref = joints_mm(model, np.stack([x, ref]))
    g = {
        k: np.asarray(v, np.float64)
        for k, v in viz.overlay_geometry(model, rig, jnp.asarray(x, jnp.float32)).items()
    }
    ref_uv = np.asarray(parsec.project(seq.cameras, jnp.asarray(J_ref)), np.float64)  # (V, 15, 2)
    ours_uv = np.asarray(parsec.project(seq.cameras, jnp.asarray(J)), np.float64)
    gap = float(np.abs(ours_uv - g["joints"]).max())
    if gap > 0.05:
        raise AssertionError(f"viz's projection differs from bodytrack's by {gap:.3f} px")
    W, H = OVERLAY_SIZE
    tiles = []
    for v, im in enumerate(seq.images[frame]):
        s = W / im.shape[1]
        small = cv2.resize(cv2.cvtColor(im, cv2.COLOR_GRAY2BGR), (W, H), interpolation=cv2.INTER_AREA)
        gv = {k: (_scaled(a, s) if k in ("cones", "ellipses", "joints") else a) for k, a in g.items()}
        tile = viz.draw_overlay(small, gv, v, model.joint_names, truth=_scaled(ref_uv[v], s))
        cv2.putText(
            tile, f"Camera{v + 1}", (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA
        )
        tiles.append(tile)
    while len(tiles) % 2:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.hstack(tiles[i : i + 2]) for i in range(0, len(tiles), 2)]
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(os.fspath(path), np.vstack(rows), [cv2.IMWRITE_PNG_COMPRESSION, 9]):
        raise OSError(f"cannot write {path}")
    return float(np.linalg.norm(J - J_ref, axis=-1).mean())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--report", action="store_true", help=f"write {common.RESULTS}/parsec_track.md")
    ap.add_argument(
        "--overlay",
        type=pathlib.Path,
        metavar="PATH",
        help="only write the overlay montage of frame 1 (1000 × 3, seed 0) to PATH (a PNG)",
    )
    a = ap.parse_args(argv)
    seq = parsec.load_sequence(DATA / "sequenceB_2")
    t0 = time.perf_counter()
    obs = [seq.observation(t) for t in range(len(seq.frames))]
    if a.overlay is not None:
        d = save_overlay(seq, obs, a.overlay)
        print(f"wrote {a.overlay} (frame 1, 1000 × 3, seed 0: {d:.1f} mm from bodytrack's pose)")
        return 0
    prep = (time.perf_counter() - t0) / len(obs)
    model = parsec.parsec31(seq.shape)  # millimetres
    lines = []
    bodytrack.build()
    for N, L in CONFIGS:
        ref = parsec.load_poses(DATA / "reference" / f"poses_{N}p{L}l.txt")
        J_ref = joints_mm(model, ref)
        runs, times, bt_times, loads = [], [], [], []
        run = make_runner(seq, N, L)
        for s in range(a.seeds):
            loads.append(os.getloadavg()[0])
            est, secs = run(obs, s)
            runs.append(joints_mm(model, est))
            times += secs if s > 0 else secs[1:]  # the first call compiles
            bt_times += bodytrack.bodytrack_frames(N, L)
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
        tline = (
            f"| {N} × {L} | {step_s:.3f} | {prep:.3f} | {step_s + prep:.3f} | {np.median(bt_times):.3f} | "
            f"{min(loads):.1f}–{max(loads):.1f} |"
        )
        print(tline, flush=True)
        lines.append(("time", tline))
    if a.report:
        acc = [x for x in lines if isinstance(x, str)]
        tim = [x[1] for x in lines if not isinstance(x, str)]
        dev = jax.devices()[0]
        cmd = f"JAX_PLATFORMS=cpu .venv/bin/python {common.script(__file__)} --seeds {a.seeds} --report"
        text = (
            "# PARSEC sequenceB_2: APF (PARSEC mode) + parsec31 + PARSEC likelihood vs bodytrack\n\n"
            f"Reproduce: `{cmd}`\n\n"
            f"Seeds 0–{a.seeds - 1}; distances are the mean over the 15 evaluation joints (mm) of the parsec31 model "
            "(PARSEC's 10 cylinders).\n\n"
            "| config | frame | to bodytrack's pose: mean (min–max over seeds) | our spread (between seeds) |\n"
            "|---|---|---|---|\n" + "\n".join(acc) + "\n\n"
            f"## Time per frame ({dev.platform}, after compilation; median over seeds and frames 1+)\n\n"
            "| config | filter step s | edge/fg maps s | total s | bodytrack serial s (same script) | load |\n"
            "|---|---|---|---|---|---|\n" + "\n".join(tim) + "\n"
        )
        common.write_result(common.RESULTS / "parsec_track.md", text, cmd)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
