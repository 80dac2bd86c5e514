"""How accurate is ``jaxmocap track`` with its defaults on realistic input, against triangulating the same detections?

Scenario (every choice stated here):

* clips (:data:`CLIPS`; the walk is bundled, the others from ``../shared/data/mocap``): five stretches of four
  real CMU recordings (a walk, the Charleston dance, a turn, a crouch, two-footed hops) and one Bandai-Namco clip
  (raising the left hand: the only arm-only motion in the shared data; CC BY-NC 4.0), each rendered by
  :func:`jaxmocap.synth.generate.synthesize` at 30 fps (the CMU clips' 120 fps subsampled every 4th frame: 240
  source frames → 60 frames, 2 s; the Bandai clip is 30 fps, all of its 55 frames) with the synthesiser's defaults (photo background, sensor noise 0.01, simulated
  OpenPose BODY_25B detections), seed 0, at ``--size`` (default 320×240), for each rig of ``--rigs`` (default
  ``stereo``: two cameras 0.3 m apart; ``ring4``: four cameras around the subject);
* the input a recording gives (:class:`jaxmocap.io.sources.SequenceSource` with ``recording=True``): the images,
  the calibration, the empty-scene plates, the depth maps and the simulated detections; no rendered mask and no
  ground truth reaches the run;
* the tracker (:class:`jaxmocap.tracking.tracker.Tracker`, the code ``jaxmocap track`` runs) with the default
  :class:`~jaxmocap.tracking.options.TrackOptions` but ``seed`` (``0 … --seeds − 1``) and ``overwrite``: a fresh
  tracker per run, so every run compiles (the persistent compilation cache is on, as for ``jaxmocap track``);
* the baseline: each frame's detections triangulated joint by joint (:func:`jaxmocap.geometry.camera.triangulate`:
  DLT over the views whose confidence is positive, each view's rows weighted by its confidence; a joint seen by
  fewer than two views is not triangulated and is counted); the root as the middle of the two triangulated hips
  (as the tracker's IK start takes it); the head has no detection in the evaluation layout, so the baseline has
  none;
* errors (:func:`jaxmocap.eval.metrics.joint_errors` against the sequence's ``groundtruth.npz``): the 3D distance
  of each evaluation joint in each frame (mm) of the tracked ``poses.npz`` (the filter's per-frame estimate) and of
  the exported, Butterworth-smoothed ``poses_smoothed.npz`` (the default export); the tables give the mean, median
  and 95th percentile of these per-joint errors pooled over frames, seeds and clips. Side by side, tracker and
  triangulation are both scored over the 14 joints the baseline can estimate (all but the head), the baseline
  over the cells it triangulated;
* speed: the run's frames/s after the first frame (the summary's ``frames_per_s``: features, filter and outputs
  per frame; compilation left out), with the machine's load average at the start of each run. These are absolute
  speeds on a shared machine, not ratios against a baseline run side by side.

The goals checked: ``ring4`` mean error ≤ 30 mm and ``stereo`` ≤ 60 mm (the tracked poses, all 15 joints), each
at ≥ 10 frames/s, and the tracker's mean error below the triangulation's.

Every (rig, clip, seed) run and every baseline is saved under ``--work`` as soon as it ends, and the results file
is rewritten after each: a rerun with the same ``--work`` resumes where the last one stopped.

    python benchmarks/experiments/accuracy_default.py [--seeds 5] [--size 320x240] [--work DIR] [--quick]
        [--rigs RIG …] [--clips WORD …] [--set FIELD=VALUE …]

Experiments: ``--clips`` (clips whose names start with the words) and ``--set`` (a :class:`TrackOptions` field
set otherwise; the runs are kept apart under ``--work``, one folder per set of options) print their tables and
leave the results file alone.

Writes ``benchmarks/results/accuracy_default.md`` (not with ``--quick``: one clip, one seed, 8 frames at 160×120,
the stereo rig, printed only).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import shutil
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import common
from scenes import MOCAP

from jaxmocap import compilation_cache
from jaxmocap.eval import metrics
from jaxmocap.geometry import camera
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io.sources import SequenceSource
from jaxmocap.synth import generate as synth
from jaxmocap.tracking.options import TrackOptions
from jaxmocap.tracking.tracker import Tracker

RESULTS = common.RESULTS / "accuracy_default.md"
CMU, BANDAI = MOCAP / "cmu", MOCAP / "bandai"
#: (name, what happens, motion, asf, source frames)
CLIPS = (
    ("walk 02_01", "walk", "demo", None, "0:240"),
    ("charleston", "dance: kicks, arms swinging", CMU / "charleston1.amc", CMU / "charleston.asf",
     "150:390"),
    ("turn 131_03", "a turn of about 300° while stepping", CMU / "131_03.bvh", None, "780:1020"),
    ("crouch 131_01", "turns about 100° and crouches (root down to 0.5 m)", CMU / "131_01.bvh", None,
     "300:540"),
    ("hops 131_03", "two-footed hops", CMU / "131_03.bvh", None, "420:660"),
    ("raise hand (Bandai)", "raises the left hand above the head and lowers it",
     BANDAI / "dataset-2_raise-up-left-hand_normal_001.bvh", None, "0:55"),
)  # fmt: skip
RIGS = ("stereo", "ring4")
#: the 14 joints the baseline estimates (every evaluation joint but the head)
COMMON = [j for j, n in enumerate(EVAL_JOINTS) if n != "head"]
GOALS = {"ring4": 30.0, "stereo": 60.0}
GOAL_FPS = 10.0
#: what the tables show (written for the measured tables: ``python benchmarks/experiments/accuracy_default.py
#: --seeds 5``, 2026-11-30: four cameras 06:57 UTC, stereo 09:41 UTC)
READING = (
    "Reading (written for the runs of 2026-11-30, 5 seeds, on an AMD EPYC family 25 model 17 (AVX-512): four "
    "cameras at 06:57-07:01 UTC, the stereo pair at 09:41-09:43 UTC; the defaults: the filter's estimate refined "
    "on each frame's detections and the particles moved with it, `jaxmocap.tracking.refine`, prior weight 1 with "
    "four cameras and 30 with the stereo pair, whose refinement also reads the depth maps at the trunk's and the "
    "limbs' joints (sigma_d 5 cm) where the estimate does not put the joint more than 0.25 m behind the surface "
    "its pixel sees (`refine.DEPTH_OCCLUDED_M`, since 09:40 UTC: the experiments section 'the depth of an "
    "occluded joint'); the keypoints cue at weight 32, the root's angles in the velocity prediction; 64 silhouette "
    "samples per view for the coverage cue, `jaxmocap.tracking.features.COVERAGE_SAMPLES`; APF 300 particles per "
    "layer with the stereo pair and 50 with four cameras, `jaxmocap.tracking.options.default_particles`): both "
    "goals hold with both rigs. Stereo: 49.2 mm over the 15 joints (46.6 mm mean, 30.7 mm median over the 14; "
    "52.0 mm before the occlusion test, 05:41 UTC; 54.0 mm with 3 seeds on 2026-11-29 on the AVX2 EPYC, model 1) "
    "against 858.9 mm (250.6 mm) for the triangulation (at f = 256 px a 0.30 m baseline about 4 m from the "
    "subject turns one pixel of disparity into about 0.2 m of depth: the detections leave a joint's distance "
    "along the rays nearly free, the depth maps fix it); every clip 23.4-65.6 mm, the turn above 60; the wrists "
    "and ankles still have long tails (a limb put on the wrong side of the body along the rays for a few "
    "frames), at 30.9 frames/s. Four cameras: 28.8 mm over the 15 joints (28.4 mm mean, 25.3 mm median over the "
    "14) against 43.2 mm (35.0 mm) for the triangulation of the same detections, below it on every clip and "
    "every joint, at 32.3 frames/s (23.1-37.4); with 300 particles, the default until then, 28.7 mm (28.4 / "
    "25.4) at 18.6 frames/s (05:41-05:48 UTC, same seeds), and 8.8 frames/s on the model 1 on 2026-11-29, whose "
    "XLA programs run 1.5-1.8x slower (3 seeds; the 50-particle default not measured there: about 19.4 frames/s "
    "expected, from XLA's AVX2 code on the model 17, in the experiments below). The runs had the machine to "
    "themselves (load 0.9-2.1 at their starts and ends: the tracker's own threads): absolute rates, which move "
    "with the CPU the machine is given; side by side in one process against the revision before: "
    "`benchmarks/results/track_rate.md`. No run started more than 0.5 m off: the first pose is the model fitted "
    "to the detections' reprojection, with the depth maps deciding along the rays "
    "(`jaxmocap.tracking.init.keypoint_pose`)."
)
#: a run whose first frame is off by more than this (mean over the joints, mm) did not start on the subject
BAD_START_MM = 500.0


def with_experiments(md: str) -> str:
    """``md`` followed by the ``## Experiments`` sections of the results file as it stands: the notes of earlier
    runs (option sweeps, the reasons for the defaults), which a regeneration keeps."""
    old = RESULTS.read_text() if RESULTS.exists() else ""
    i = old.find("\n## Experiments")
    return md if i < 0 else md.rstrip("\n") + "\n" + old[i:]


def key(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name).strip("_")


def save_atomic(path: pathlib.Path, **arrays) -> None:
    """``np.savez`` into ``path`` through a temporary file and a rename (a crash leaves the old file or none)."""
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def sequence(work: pathlib.Path, rig: str, clip, size: str, frames: str | None = None) -> pathlib.Path:
    """The synthetic sequence of ``clip`` for ``rig`` under ``work`` (rendered once: a marker file says it is
    complete)."""
    name, _, motion, asf, source_frames = clip
    d = work / "sequences" / rig / key(name)
    done = d / ".complete"
    if not done.exists():
        synth.synthesize(motion, d, rig=rig, asf=asf, frames=frames or source_frames, size=size, seed=0,
                         overwrite=True)  # fmt: skip
        done.write_text("")
    return d


def triangulate_detections(source: SequenceSource) -> tuple[np.ndarray, np.ndarray]:
    """The baseline: ``(joints (T, 15, 3) metres, NaN where not estimated; views (T, 15) the number of views that
    detect each joint)`` from the source's keypoints ``(T, V, 15, 3)`` (u, v, confidence): confidence-weighted DLT
    of every joint seen by at least two views, the root as the middle of the two hips, no head."""
    import jax.numpy as jnp

    kp = np.asarray(source.keypoints, np.float64)  # (T, V, 15, 3)
    uv = np.moveaxis(kp[..., :2], 1, 2)  # (T, 15, V, 2)
    conf = np.moveaxis(np.where(kp[..., 2] > 0, kp[..., 2], 0.0), 1, 2)  # (T, 15, V)
    X = np.asarray(
        camera.triangulate(
            source.rig.to_jax(jnp.float32), jnp.asarray(uv, jnp.float32), jnp.asarray(conf, jnp.float32)
        ),
        np.float64,
    )
    head, root = EVAL_JOINTS.index("head"), EVAL_JOINTS.index("root")
    hips = [EVAL_JOINTS.index("left_hip"), EVAL_JOINTS.index("right_hip")]
    X[:, root] = X[:, hips].mean(axis=1)  # NaN when either hip is missing
    X[:, head] = np.nan
    views = (conf > 0).sum(-1)
    views[:, root] = np.minimum(views[:, hips[0]], views[:, hips[1]])
    return X, views


def baseline(seq: pathlib.Path, path: pathlib.Path) -> None:
    """Triangulate the detections of ``seq`` and save the per-joint errors (mm) to ``path``."""
    source = SequenceSource(seq, recording=True)
    try:
        X, views = triangulate_detections(source)
    finally:
        source.close()
    gt_frames, gt = metrics.load_groundtruth(seq)
    err = metrics.joint_errors(X[gt_frames], gt)
    save_atomic(path, errors=err, views=views[gt_frames])


def track(
    seq: pathlib.Path, out: pathlib.Path, seed: int, path: pathlib.Path, options: dict | None = None
) -> None:
    """Track ``seq`` with the default options (``seed``; ``options``: fields of :class:`TrackOptions` set otherwise,
    ``--set``), score it, save errors (mm) and speed to ``path``."""
    source = SequenceSource(seq, recording=True)
    load = os.getloadavg()[0]
    try:
        t0 = time.monotonic()
        opts = TrackOptions(**{**(options or {}), "seed": seed, "overwrite": True})
        summary = Tracker(source, out, opts, quiet=True).run()
        wall = time.monotonic() - t0
    finally:
        source.close()
    gt_frames, gt = metrics.load_groundtruth(seq)
    row = {int(f): i for i, f in enumerate(gt_frames)}

    tracked = np.full(gt.shape, np.nan)  # (T, 15, 3) the tracked joints, kept for analyses of the runs

    def errors(name):
        frames, joints = metrics.load_prediction(out / name)
        e = np.full(gt.shape[:2], np.nan)
        for f, j in zip(frames, joints, strict=True):
            e[row[int(f)]] = metrics.joint_errors(j, gt[row[int(f)]])
            if name == "poses.npz":
                tracked[row[int(f)]] = j
        return e

    smoothed = (
        errors("poses_smoothed.npz")
        if (out / "poses_smoothed.npz").exists()
        else np.full(gt.shape[:2], np.nan)
    )
    save_atomic(
        path, errors=errors("poses.npz"), smoothed=smoothed, joints=tracked,
        states=np.load(out / "poses.npz")["state"], lost=int(summary.get("lost_frames") or 0),
        reinit=int(summary.get("reinitialisations") or 0), fps=float(summary.get("frames_per_s") or np.nan),
        first_frame_s=float(summary.get("first_frame_s") or np.nan), wall_s=wall, load=load,
        load_end=os.getloadavg()[0], summary=json.dumps(summary, default=str),
    )  # fmt: skip


# ---------------------------------------------------------------------------------------------------------------
# Report


def stats(e: np.ndarray) -> tuple[float, float, float]:
    """``(mean, median, 95th percentile)`` of the finite values of ``e`` (NaN when none)."""
    v = np.asarray(e, np.float64).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return (np.nan, np.nan, np.nan)
    return (float(v.mean()), float(np.median(v)), float(np.percentile(v, 95)))


def fmt(s) -> str:
    return " / ".join("—" if not np.isfinite(x) else f"{x:.1f}" for x in s)


def load_units(work: pathlib.Path, rig: str, clips, seeds: int, variant: str | None = None):
    """``{clip name: (baseline npz or None, [run npz, …])}`` of what is saved for ``rig`` (the runs of the
    default options, or of ``variant``: :func:`variant_name`)."""
    out = {}
    for clip in clips:
        d = work / "units" / rig / key(clip[0])
        b = d / "triangulation.npz"
        r = d if variant is None else d / "variants" / variant
        runs = [np.load(r / f"seed{s}.npz") for s in range(seeds) if (r / f"seed{s}.npz").exists()]
        out[clip[0]] = (np.load(b) if b.exists() else None, runs)
    return out


def rig_report(rig: str, units: dict) -> tuple[str, dict]:
    """The markdown of one rig and its headline numbers."""
    lines = [
        f"### {rig}",
        "",
        "Per-joint error (mm), mean / median / 95th percentile over frames × joints (× seeds); tracker and "
        "triangulation over the 14 joints but the head; the tracker's all 15 joints (tracked and exported); "
        "untriangulated: cells (frame × joint, of the 14) seen by fewer than two views; start: the tracker's mean "
        "error in the first frame (the pose found by inverse kinematics on the first frame's triangulated "
        "detections, after one filter step).",
        "",
        "| clip | seeds | tracker, 14 joints | triangulation, 14 joints | untriangulated | tracker, 15 joints | "
        "exported (smoothed), 15 joints | start | frames/s (median, range) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    all_t, all_b, all_s, fps, loads, first = [], [], [], [], [], []
    good, bad = [], []  # the runs that started on the subject (their errors), the clips of those that did not
    missing = total = 0
    for name, (b, runs) in units.items():
        if b is None and not runs:
            continue
        et = np.stack([r["errors"] for r in runs]) if runs else np.full((1, 1, 15), np.nan)
        es = np.stack([r["smoothed"] for r in runs]) if runs else et
        eb = b["errors"] if b is not None else np.full((1, 15), np.nan)
        miss = int(np.sum(b["views"][:, COMMON] < 2)) if b is not None else 0
        cells = eb[:, COMMON].size if b is not None else 0
        f = [float(r["fps"]) for r in runs]
        fps += f
        loads += [float(r["load"]) for r in runs] + [float(r["load_end"]) for r in runs]
        first += [float(r["first_frame_s"]) for r in runs]
        for r in runs:
            if np.nanmean(r["errors"][0]) > BAD_START_MM:
                bad.append(name)
            else:
                good.append(r["errors"])
        if runs:
            all_t.append(et.reshape(-1, 15))
            all_s.append(es.reshape(-1, 15))
        if b is not None:
            all_b.append(eb)
            missing, total = missing + miss, total + cells
        fs = f"{np.median(f):.1f} ({min(f):.1f}–{max(f):.1f})" if f else "—"
        lines.append(
            f"| {name} | {len(runs)} | {fmt(stats(et[..., COMMON]))} | {fmt(stats(eb[:, COMMON]))} | "
            f"{miss} of {cells} | {fmt(stats(et))} | {fmt(stats(es))} | {fmt(stats(et[:, 0])[:1])} | {fs} |"
        )
    T = np.concatenate(all_t) if all_t else np.full((1, 15), np.nan)
    S = np.concatenate(all_s) if all_s else T
    B = np.concatenate(all_b) if all_b else np.full((1, 15), np.nan)
    fs = f"{np.median(fps):.1f} ({min(fps):.1f}–{max(fps):.1f})" if fps else "—"
    lines.append(
        f"| **all clips** | | **{fmt(stats(T[:, COMMON]))}** | **{fmt(stats(B[:, COMMON]))}** | "
        f"{missing} of {total} | **{fmt(stats(T))}** | {fmt(stats(S))} | | {fs} |"
    )
    G = np.concatenate(good) if good else np.full((1, 15), np.nan)
    bad_text = ", ".join(f"{n} × {bad.count(n)}" for n in dict.fromkeys(bad)) or "none"
    lines += [
        "",
        f"Runs that started more than {BAD_START_MM / 1000:.1f} m off (first frame's mean error): {len(bad)} of "
        f"{len(bad) + len(good)} ({bad_text}). The tracker over the other runs (14 joints, mean / median / 95th "
        f"percentile): {fmt(stats(G[:, COMMON]))} mm; the triangulation over all frames: {fmt(stats(B[:, COMMON]))} mm.",
        "",
        "Per joint over all clips (mean / median / 95th percentile, mm):",
        "",
        "| joint | tracker | triangulation | exported (smoothed) |",
        "|---|---|---|---|",
    ]
    for j, n in enumerate(EVAL_JOINTS):
        lines.append(f"| {n} | {fmt(stats(T[:, j]))} | {fmt(stats(B[:, j]))} | {fmt(stats(S[:, j]))} |")
    head = dict(
        tracker=stats(T)[0], tracker14=stats(T[:, COMMON]), triangulation=stats(B[:, COMMON]),
        fps=float(np.median(fps)) if fps else np.nan, runs=len(fps),
        load=(min(loads), max(loads)) if loads else (np.nan, np.nan),
        first=float(np.median(first)) if first else np.nan,
    )  # fmt: skip
    return "\n".join(lines), head


def report(
    work: pathlib.Path, rigs, clips, seeds: int, size: str, command: str, reading: str = "", variant=None
) -> str:
    """The results file's text from what is saved under ``work`` (``reading``: a paragraph after the goals;
    ``variant``: the runs of options set otherwise, :func:`variant_name`)."""
    parts, heads = [], {}
    for rig in rigs:
        md, heads[rig] = rig_report(rig, load_units(work, rig, clips, seeds, variant))
        parts.append(md)
    seed_counts = sorted(
        {len(r) for rig in rigs for _, r in load_units(work, rig, clips, seeds, variant).values()}
    )
    goal = [
        "| rig | goal | tracker mean, 15 joints | frames/s (median) | error goal | speed goal | "
        "tracker vs triangulation, 14 joints: mean; median |",
        "|---|---|---|---|---|---|---|",
    ]
    for rig in rigs:
        h, g = heads[rig], GOALS.get(rig, np.nan)

        def yes(ok):
            return "holds" if ok else "**fails**"

        goal.append(
            f"| {rig} | ≤ {g:.0f} mm at ≥ {GOAL_FPS:.0f} frames/s | {h['tracker']:.1f} mm | {h['fps']:.1f} | "
            f"{yes(h['tracker'] <= g)} | {yes(h['fps'] >= GOAL_FPS)} | "
            + "; ".join(
                f"{h['tracker14'][i]:.1f} vs {h['triangulation'][i]:.1f} mm: "
                f"{yes(h['tracker14'][i] < h['triangulation'][i])}"
                for i in (0, 1)
            )
            + " |"
        )
    speed = "; ".join(
        f"{rig}: {heads[rig]['runs']} runs, median first frame (compilation) {heads[rig]['first']:.0f} s, "
        f"load average (1 min) {heads[rig]['load'][0]:.1f}–{heads[rig]['load'][1]:.1f} at the runs' starts and ends"
        for rig in rigs
    )
    clip_lines = [f"- **{c[0]}**: {c[1]} (source frames {c[4]})" for c in clips]
    return "\n".join(
        [
            f"<!-- Regenerate: {command} -->",
            "# `jaxmocap track` with its defaults against triangulating the detections",
            "",
            f"Synthetic sequences of real motion capture at {size}, 30 fps, rigs {', '.join(rigs)}; input as a "
            "recording gives it (images, calibration, plates, simulated BODY_25B detections; no masks, no ground "
            "truth); the tracker with the default options but the seed, seeds per clip: "
            f"{', '.join(map(str, seed_counts))} (of {seeds} asked); the baseline triangulates each frame's "
            f"detections (scenario: the docstring of `{common.script(__file__)}`). {common.stamp()}.",
            "",
            "Clips:",
            "",
            *clip_lines,
            "",
            "## Goals",
            "",
            *goal,
            "",
            *([reading, ""] if reading else []),
            f"Speed: frames/s after the first frame, end to end (features, filter, outputs), on a shared 2-core "
            f"machine: {speed}. These are absolute speeds under that load, not ratios against a baseline run "
            "side by side.",
            "",
            "## Per rig",
            "",
            *[p + "\n" for p in parts],
        ]
    )


# ---------------------------------------------------------------------------------------------------------------


def variant_name(options: dict) -> str | None:
    """The folder name of the runs of ``options`` (None: the defaults): ``velocity=0.8,filter=iapf`` made safe."""
    if not options:
        return None
    return "".join(
        c if c.isalnum() or c in "=.-" else "_" for c in ",".join(f"{k}={v}" for k, v in options.items())
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="seeds per clip and rig (default 5)")
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--rigs", nargs="+", default=list(RIGS), choices=RIGS)
    ap.add_argument(
        "--work",
        default=None,
        help="where sequences and per-run results are kept, a rerun resumes there (default "
        "$TMPDIR/jaxmocap_accuracy_default; with --quick a new temporary folder)",
    )
    ap.add_argument(
        "--quick", action="store_true", help="one clip, one seed, 8 frames at 160x120, stereo; prints"
    )
    ap.add_argument(
        "--clips", nargs="+", default=None,
        help="only the clips whose names start with these words (e.g. turn crouch); prints, writes no results file",
    )  # fmt: skip
    ap.add_argument(
        "--set", action="append", default=[], metavar="FIELD=VALUE",
        help="a TrackOptions field set otherwise (repeatable; e.g. --set velocity=0.8 --set 'cues=foreground,"
        "keypoints:8'): runs kept apart under --work; prints, writes no results file",
    )  # fmt: skip
    a = ap.parse_args(argv)
    if a.seeds < 1:
        ap.error("--seeds must be at least 1")
    try:
        options = common.track_options(a.set)
    except ValueError as e:
        ap.error(str(e))
    variant = variant_name(options)
    compilation_cache.enable()
    clips = [c for c in CLIPS if c[2] == "demo" or pathlib.Path(c[2]).is_file()]
    if a.clips:
        clips = [c for c in clips if any(c[0].startswith(w) for w in a.clips)]
        if not clips:
            ap.error(f"no clip starts with {' or '.join(a.clips)}")
    partial = bool(a.clips or options)  # a partial run prints its table and leaves the results file alone
    if a.quick:
        clips, a.seeds, a.size, a.rigs = clips[:1], 1, "160x120", ["stereo"]
    if a.work:
        work = pathlib.Path(a.work)
    elif a.quick:  # a smoke test tracks every time: a fresh folder
        work = pathlib.Path(tempfile.mkdtemp(prefix="jaxmocap_accuracy_default_quick_"))
    else:
        work = pathlib.Path(tempfile.gettempdir()) / "jaxmocap_accuracy_default"
    command = f"python {common.script(__file__)} --seeds {a.seeds}" + (
        f" --size {a.size}" if a.size != "320x240" else ""
    )
    if partial:
        command += f" --rigs {' '.join(a.rigs)}" + "".join(f" --set '{s}'" for s in a.set)
        command += f" --clips {' '.join(a.clips)}" if a.clips else ""
    log = lambda s: print(s, file=sys.stderr, flush=True)  # noqa: E731
    for rig in a.rigs:  # sequences and baselines first: cheap, and the tracker runs then only track
        for clip in clips:
            seq = sequence(work, rig, clip, a.size, "150:182" if a.quick else None)
            d = work / "units" / rig / key(clip[0])
            d.mkdir(parents=True, exist_ok=True)
            if not (d / "triangulation.npz").exists():
                baseline(seq, d / "triangulation.npz")
            log(f"{rig} {clip[0]}: sequence and triangulation ready")
    for s in range(a.seeds):  # seed-major: an interrupted run has every clip at the same count of seeds
        for rig in a.rigs:
            for clip in clips:
                d = work / "units" / rig / key(clip[0])
                if variant is not None:
                    d = d / "variants" / variant
                    d.mkdir(parents=True, exist_ok=True)
                if (d / f"seed{s}.npz").exists():
                    continue
                t0 = time.monotonic()
                track(work / "sequences" / rig / key(clip[0]), work / "track", s, d / f"seed{s}.npz", options)
                r = np.load(d / f"seed{s}.npz")
                log(f"{rig} {clip[0]} seed {s}: {np.nanmean(r['errors']):.1f} mm, {float(r['fps']):.1f} frames/s, "
                    f"{time.monotonic() - t0:.0f} s")  # fmt: skip
                if not a.quick and not partial:
                    RESULTS.write_text(
                        with_experiments(report(work, a.rigs, clips, a.seeds, a.size, command, READING))
                    )
    md = report(work, a.rigs, clips, a.seeds, a.size, command, "" if a.quick or partial else READING, variant)
    if not a.quick and not partial:
        RESULTS.write_text(with_experiments(md))
    elif not a.work:
        shutil.rmtree(work, ignore_errors=True)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
