"""PARSEC bodytrack's sequenceB_2 tracked with the APF in PARSEC mode, ``parsec31`` and the PARSEC likelihood, with
bodytrack's two configurations (4000 particles × 5 layers, 1000 × 3), compared with bodytrack's own output poses.

bodytrack is stochastic, so its output is one draw: the comparison reports, per frame, the mean distance (mm) over
the 15 evaluation joints between our estimate and ``reference/poses_<N>p<L>l.txt`` for each seed, next to the
spread of our estimates (mean joint distance between the estimates of two seeds, over all seed pairs).

Speed, against bodytrack built from source by this script (``benchmarks/bodytrack.py``: ``build/bodytrack``),
interleaved A/B in ``--rounds`` rounds, each as found and with one busy-loop process started by the script
(:func:`bodytrack.side_by_side`, the rounds of ``benchmarks/perf/vs_bodytrack.py``): seconds per frame of
bodytrack's serial and pthreads builds (intervals between its "Processing frame" lines) against ours (the frame's
observation, read from the sequence folder as bodytrack reads it: BMPs decoded, edge and foreground maps made; then
the compiled filter step, all layers, seed 0; frames not overlapped, :meth:`bodytrack.Tracker.run`; median over
the frames), the ratio per
round, its median, and the 1-minute load average of each round. First-frame latency (unless ``--no-latency``): a
one-frame ``jaxmocap track`` of the sequence in a new process (process start to exit, outputs written) at
bodytrack's 4000 × 5, cold (an empty compilation cache directory, ``JAXMOCAP_CACHE_DIR``) and then warm (the same
directory, filled), each followed by bodytrack serial's whole runs of one frame and of both frames (process start
to exit). The report keeps the hand-written text of the results file from its ``## Notes`` heading on.

Initialisation as bodytrack's: particles ``InitialPose + N(0, σ_0)`` weighted against frame 0 with
its β. Usage::

    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/experiments/parsec_track.py [--seeds 3] [--rounds 5] [--report]
    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/experiments/parsec_track.py ... --no-latency
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
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import bodytrack
import common
import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap import host, parsec
from jaxmocap.eval import viz
from jaxmocap.geometry import body as body_mod

DATA = pathlib.Path(os.environ.get("JAXMOCAP_DATA", "/work/shared/data")) / "parsec"

CONFIGS = ((4000, 5), (1000, 3))
#: where the hand-written text of ``results/parsec_track.md`` begins (kept by ``--report``)
NOTES = "\n## Notes\n"


def joints_mm(model, X: np.ndarray) -> np.ndarray:
    f = jax.jit(jax.vmap(lambda x: body_mod.joint_positions(model, x)))
    return np.asarray(f(jnp.asarray(X, jnp.float32)), np.float64)


OVERLAY_SIZE = (320, 240)  # (width, height) of each view in the montage


def _scaled(uv: np.ndarray, s: float) -> np.ndarray:
    """Pixel coordinates of an image resized by ``s`` (pixel centres at integers: ``u' = s (u + ½) − ½``)."""
    return s * (np.asarray(uv, np.float64) + 0.5) - 0.5


def save_overlay(seq, path: pathlib.Path, frame: int = 1, seed: int = 0) -> float:
    """Track frames ``0 … frame`` (1000 × 3, ``seed``) and write the 2×2 montage of ``frame`` to ``path``.

    Everything is in PARSEC's millimetres: the estimate (pelvis translation in mm) on ``parsec31(seq.shape)`` (mm),
    projected through the ``.cal`` cameras loaded in mm (:func:`jaxmocap.parsec.files.load_parsec_calibration`), the
    same projection as bodytrack's ``ProjectPoints`` (:func:`jaxmocap.parsec.cameras.project`, checked here on the
    joints).
    Returns the mean distance (mm) over the 15 joints between the estimate and bodytrack's pose of ``frame``.
    """
    N, L = 1000, 3
    x = bodytrack.Tracker(seq, N, L).run(seed, frames=frame + 1).estimates[frame]
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


def first_frame_seconds(cache: pathlib.Path, out: pathlib.Path) -> float:
    """Wall seconds of a one-frame ``jaxmocap track`` of sequenceB_2 (bodytrack's 4000 × 5) in a new process with
    this checkout's package and the compilation cache in ``cache``, from the process's start to its exit."""
    env = dict(os.environ, JAXMOCAP_CACHE_DIR=str(cache), JAX_PLATFORMS="cpu")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env["PYTHONPATH"] = str(common.ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    cmd = [sys.executable, "-m", "jaxmocap.cli", "track", str(bodytrack.SEQ), "--out", str(out)]
    cmd += ["--frames", "0:1", "--quiet", "--overwrite"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"jaxmocap track failed: {(proc.stderr or proc.stdout).strip()[-300:]}")
    return wall


def latency_table(log=print) -> list[str]:
    """Cold then warm first frame of jaxmocap, each followed by bodytrack serial's one-frame and two-frame runs."""
    lines = [
        "| cache | load (1 min) | jaxmocap first frame s | bodytrack serial 1 frame s | bodytrack serial 2 frames s |",
        "|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        cache, out = pathlib.Path(tmp) / "cache", pathlib.Path(tmp) / "out"
        for state in ("cold (empty)", "warm (filled)"):
            load = os.getloadavg()[0]
            ours = first_frame_seconds(cache, out)
            one = bodytrack.bodytrack_run(4000, 5, frames=1)[1]
            two = bodytrack.bodytrack_run(4000, 5, frames=2)[1]
            lines.append(f"| {state} | {load:.1f} | {ours:.1f} | {one:.2f} | {two:.2f} |")
            log(lines[-1])
    return lines


def accuracy_lines(seq, trackers: dict, seeds: int, log=print) -> list[str]:
    """Per configuration and frame: the distance to bodytrack's pose over ``seeds`` seeds and our spread."""
    model = parsec.parsec31(seq.shape)  # millimetres
    lines = []
    for (N, L), tracker in trackers.items():
        J_ref = joints_mm(model, parsec.load_poses(DATA / "reference" / f"poses_{N}p{L}l.txt"))
        J = np.stack([joints_mm(model, tracker.run(s).estimates) for s in range(seeds)])  # (S, F, 15, 3)
        d_ref = np.linalg.norm(J - J_ref[None], axis=-1).mean(axis=-1)  # (S, F)
        pairs = list(itertools.combinations(range(len(J)), 2))
        spread = (
            np.mean([np.linalg.norm(J[i] - J[j], axis=-1).mean(axis=-1) for i, j in pairs], axis=0)
            if pairs
            else np.full(J.shape[1], np.nan)
        )
        for f in range(J.shape[1]):
            d = d_ref[:, f]
            lines.append(
                f"| {N} × {L} | {f} | {d.mean():.1f} ({d.min():.1f}–{d.max():.1f}) | {spread[f]:.1f} |"
            )
            log(lines[-1])
    return lines


def speed_rows(trackers: dict, rounds: int, log=print) -> tuple[list[dict], dict]:
    """:func:`bodytrack.side_by_side` of the trackers against bodytrack's builds, and per configuration and
    condition the runs of ours (:class:`bodytrack.TrackerRun`) for the maps / step split."""
    runs: dict = {}

    def ours(c):
        r = trackers[c].run(0)
        runs.setdefault((c, bodytrack.CONDITIONS[bodytrack.busy_now()]), []).append(r)
        return r.per_frame

    jobs = {}
    for n, ly in trackers:
        for m in bodytrack.MODELS:
            jobs[f"{n} × {ly} s/frame, bodytrack {m}"] = (
                lambda n=n, ly=ly, m=m: float(np.median(bodytrack.bodytrack_frames(n, ly, model=m))),
                lambda c=(n, ly): ours(c),
            )
    return bodytrack.side_by_side(jobs, rounds, log), runs


def split_lines(runs: dict) -> list[str]:
    """Table rows per configuration and condition: medians over the runs' frames of our filter step, our host
    maps, and of the runs' per-frame totals (seconds)."""
    lines = []
    for (c, cond), rs in runs.items():
        maps = np.median([r.maps for r in rs])
        step = np.median([r.step for r in rs])
        tot = np.median([r.per_frame for r in rs])
        lines.append(f"| {c[0]} × {c[1]} | {cond} | {len(rs)} | {step:.3f} | {maps:.3f} | {tot:.3f} |")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3, help="seeds of the accuracy table")
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds against bodytrack")
    ap.add_argument("--no-latency", action="store_true", help="skip the cold / warm first-frame runs")
    ap.add_argument("--report", action="store_true", help=f"write {common.RESULTS}/parsec_track.md")
    ap.add_argument(
        "--overlay",
        type=pathlib.Path,
        metavar="PATH",
        help="only write the overlay montage of frame 1 (1000 × 3, seed 0) to PATH (a PNG)",
    )
    a = ap.parse_args(argv)
    log = lambda s: print(s, flush=True)  # noqa: E731
    seq = parsec.load_sequence(DATA / "sequenceB_2")
    if a.overlay is not None:
        d = save_overlay(seq, a.overlay)
        print(f"wrote {a.overlay} (frame 1, 1000 × 3, seed 0: {d:.1f} mm from bodytrack's pose)")
        return 0
    bodytrack.build()
    t0 = time.perf_counter()
    trackers = {c: bodytrack.Tracker(seq, *c) for c in CONFIGS}
    acc = accuracy_lines(seq, trackers, a.seeds, log)  # compiles each configuration on its first seed
    log(f"accuracy runs (compilation included) {time.perf_counter() - t0:.0f} s")
    rows, runs = speed_rows(trackers, a.rounds, log)
    lat = [] if a.no_latency else latency_table(log)
    if not a.report:
        return 0
    dev = jax.devices()[0]
    cmd = f"JAX_PLATFORMS=cpu python {common.script(__file__)} --seeds {a.seeds} --rounds {a.rounds} --report"
    text = (
        "# PARSEC sequenceB_2: APF (PARSEC mode) + parsec31 + PARSEC likelihood vs bodytrack\n\n"
        f"Reproduce: `{cmd}`\n\n"
        f"Seeds 0–{a.seeds - 1}; distances are the mean over the 15 evaluation joints (mm) of the parsec31 model "
        "(PARSEC's 10 cylinders).\n\n"
        "| config | frame | to bodytrack's pose: mean (min–max over seeds) | our spread (between seeds) |\n"
        "|---|---|---|---|\n" + "\n".join(acc) + "\n\n"
        f"## Time per frame, side by side with bodytrack ({common.stamp()})\n\n"
        f"bodytrack built from `{bodytrack.SRC}` (g++ -O2) and run by this script; jaxmocap on JAX {jax.__version__} "
        f"({dev.platform}), XLA_FLAGS=`{os.environ.get('XLA_FLAGS', '')}`, compiler options "
        f"{host.particle_options() or 'XLA defaults'}; {os.cpu_count()} cores ({host.description()}). "
        f"{a.rounds} rounds; per frame: bodytrack's interval between its frame lines, ours the frame's "
        "observation (read from the folder: images, edge and foreground maps) + the compiled filter step (seed 0, "
        "after compilation, frames not overlapped), median over the 2 frames.\n\n"
        + bodytrack.table(rows)
        + "\nOurs split (median over the rounds' frames):\n\n"
        "| config | condition | runs | filter step s | observation s | total s |\n|---|---|---|---|---|---|\n"
        + "\n".join(split_lines(runs))
        + "\n"
    )
    if lat:
        text += (
            "\n## First-frame latency (4000 × 5, process start to exit)\n\n"
            "jaxmocap: `jaxmocap track sequenceB_2 --frames 0:1` in a new process with `JAXMOCAP_CACHE_DIR` an empty "
            "directory (cold: every program compiled), then the same directory (warm: the compiled programs "
            "reloaded); after each, bodytrack serial's whole run of one and of two frames.\n\n"
            + "\n".join(lat)
            + "\n"
        )
    path = common.RESULTS / "parsec_track.md"
    old = path.read_text() if path.is_file() else ""
    if NOTES in old:  # the hand-written part
        text += "\n" + old[old.index(NOTES) + 1 :]
    common.write_result(path, text, cmd)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
