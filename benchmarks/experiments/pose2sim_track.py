"""Track the Pose2Sim 4-camera demo recording (a real person balancing on one leg) from its project folder
through :func:`jaxmocap.track`, and compare with Pose2Sim's triangulated ``.trc`` reference.

The input is a Pose2Sim project folder made under ``--out`` of links to the recording: ``Config.toml``,
``calibration/`` (the calibration as Pose2Sim converted it, and ``extrinsics/`` scene images), ``videos/`` and
``pose/`` (the shipped OpenPose BODY_25B detections of every person in view). Everything else is what the library
does with such a folder (:func:`jaxmocap.io.pose2sim.open_project`): cam01/cam02 videos (1080 px wide) taken as the
calibrated 1088 px images cropped by codec padding, the keypoint layout read from the files (Config.toml names
another), the subject chosen across views and time, its body dimensions measured from the triangulated detections,
an IK initialisation on them, a median background without the subject's box filled from the scene images; then the
APF on images down-sampled by ``--downsample`` with the cues ``foreground``, ``edge_distance``, ``coverage`` and
``keypoints``. The 2-camera run is a project of the pair whose viewing directions towards the subject are closest
in angle (its calibration written for those two cameras).

Reported, over the tracked frames: per-joint and mean 3D distance (mm) to the ``.trc`` reference for every camera
set; the 2D distance (px, full-size images) of the tracked joints and of the reference's own markers to the
subject's detections (confidence > 0.3) of each camera.

``--leave-one-out``: for each camera in turn, track from the other three and project the tracked joints into the
held-out camera; the baseline triangulates the same three cameras' detections of the subject (linear DLT, each
view weighed by its detection confidence, views under 0.3 left out: Pose2Sim's weighting without its
reprojection-error view rejection) and projects them the same way; a second baseline is Pose2Sim's whole
triangulation step with its default settings (:func:`pose2sim_triangulated`: the view rejection at 15 px and the
interpolation of short gaps). Both are compared with the held-out camera's
own detections (confidence > 0.3), per joint, in full-size pixels; so is the run's body model fitted on each frame
to the three cameras' detections alone (:func:`skeleton_fit`: what the skeleton can do with them at best); written to
``results/pose2sim_loo.md``. Usage::

    .venv/bin/python benchmarks/experiments/pose2sim_track.py --out /tmp/p2s --report   # 4 cameras and the pair
    .venv/bin/python benchmarks/experiments/pose2sim_track.py --out /tmp/p2s_loo --leave-one-out
    .venv/bin/python benchmarks/experiments/pose2sim_track.py --make-test-data tests/data/pose2sim_small
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import shutil
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common
import cv2
import jax.numpy as jnp
import numpy as np
from scenes import P2S_CALIB as CALIB
from scenes import P2S_DATA as DATA
from scenes import P2S_DERIVED as DERIVED
from scenes import P2S_TRC as TRC
from scenes import pose2sim_project as make_project

import jaxmocap
from jaxmocap.choices import MODELS
from jaxmocap.fit.ik import fit_pose_2d
from jaxmocap.geometry import body, camera
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io import calibration
from jaxmocap.io.keypoints import KEYPOINT_INDEX
from jaxmocap.io.pose2sim import JOINT_OF_TRC, Pose2SimSource, open_project, reference_joints
from jaxmocap.tracking.init import KEYPOINT_SIGMA_PX
from jaxmocap.tracking.smoothing import butterworth, fill_gaps, parse_smooth

#: the tracker's default cues for such a folder (the keypoints cue at its default weight, 32)
CUES = "foreground,edge_distance,coverage:4,keypoints:32"


def paths(root: pathlib.Path, images: bool = False) -> dict:
    cams = [f"cam0{c}" for c in range(1, 5)]
    kp = root / DERIVED / "pose" if (root / DERIVED).is_dir() else root / "pose"
    out = {
        "calibration": root / CALIB if (root / CALIB).is_file() else root / "calibration.toml",
        "keypoints": [kp / f"{c}_json" for c in cams],
        "extrinsics": [root / "calibration" / "extrinsics" / f"{c}_ext.png" for c in cams],
        "trc": root / TRC if (root / TRC).is_file() else root / "reference.trc",
    }
    if images:
        out["images"] = [root / "images" / c for c in cams]
        out["backgrounds"] = [root / "background" / f"{c}.jpg" for c in cams]
    else:
        out["videos"] = [root / "videos" / f"{c}.mp4" for c in cams]
    return out


def neighbouring_pair(rig: camera.Rig, centre: np.ndarray) -> tuple[int, int]:
    """The two cameras whose viewing directions towards ``centre`` are closest in angle."""
    c = np.asarray(camera.camera_centres(rig.to_jax(jnp.float32)), np.float64)
    d = centre[None] - c
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    best, pair = -2.0, (0, 1)
    for i in range(len(c)):
        for j in range(i + 1, len(c)):
            if d[i] @ d[j] > best:
                best, pair = float(d[i] @ d[j]), (i, j)
    return pair


def reprojection(rig_full: camera.Rig, points: np.ndarray, kp_full: np.ndarray, pairs) -> np.ndarray:
    """Per-camera mean distance (px) between projected ``points (T, P, 3)`` and detections ``kp_full (T, V, 15, 3)``
    (evaluation joints) of ``pairs`` (index into P, index into the detections), confidence > 0.3."""
    rj = rig_full.to_jax(jnp.float32)
    V = kp_full.shape[1]
    errs = [[] for _ in range(V)]
    for t in range(points.shape[0]):
        P = np.nan_to_num(points[t])
        uv = np.asarray(camera.project(rj, jnp.asarray(P, jnp.float32)), np.float64)  # (V, P, 2)
        for v in range(V):
            for p, k in pairs:
                if kp_full[t, v, k, 2] > 0.3 and np.all(np.isfinite(points[t, p])):
                    errs[v].append(np.linalg.norm(uv[v, p] - kp_full[t, v, k, :2]))
    return np.asarray([np.mean(e) if e else np.nan for e in errs])


def track(out: pathlib.Path, cams, a) -> dict:
    """One run on the project of cameras ``cams``; returns the numbers (the run is kept in ``out / "run"``)."""
    project = make_project(out / "project", cams, pose=not a.detector)
    t0 = time.monotonic()
    res = jaxmocap.track(
        input=project,
        out=out / "run",
        overwrite=True,
        downsample=a.downsample,
        particles=a.particles,
        layers=a.layers,
        cues=a.cues,
        seed=a.seed,
        frames=a.frames,
        model=a.model,
        **({} if a.refine is None else {"refine": a.refine}),
        **({} if a.refine_prior is None else {"refine_prior": a.refine_prior}),
    )
    wall = time.monotonic() - t0
    src = open_project(project, detector="blazepose" if a.detector else "none", frames=a.frames)
    try:
        idx = [int(f) for f in res.frames]
        ref, markers, _ = reference_joints(DATA / TRC)
        err = np.linalg.norm(res.joints - ref[idx], axis=-1) * 1000.0  # (T, 15) mm
        kp = src.keypoints[idx]
        pairs = [(j, j) for j in KEYPOINT_INDEX.values()]
        track_px = reprojection(src.rig, res.joints, kp, pairs)
        names = list(JOINT_OF_TRC)
        mk = np.stack([markers[n] for n in names], axis=1)[idx]
        ref_px = reprojection(src.rig, mk, kp, [(i, JOINT_OF_TRC[n]) for i, n in enumerate(names)])
        mid = len(idx) // 2
        shown = (src.read(idx[mid]).images, src.rig, kp[mid], res.states[mid])
        dims = json.loads((out / "run" / "run.json").read_text())["body_dimensions"]
        exported = np.load(out / "run" / "poses_smoothed.npz")  # the exported track (smoothed by default)
        row = {int(f): k for k, f in enumerate(exported["frame_index"])}
        joints_exported = np.stack([exported["joints"][row[f]] for f in idx])
        fps, smooth = float(exported["fps"]), str(exported["smooth"])
    finally:
        src.close()
    return {
        "cameras": [src.view_names[v] for v in range(src.rig.num_views)],
        "frames": idx,
        "mean_mm": float(np.nanmean(err)),
        "mean_mm_no_head": float(np.nanmean(np.delete(err, EVAL_JOINTS.index("head"), axis=1))),
        "median_mm": float(np.nanmedian(err)),
        "per_joint_mm": {j: float(np.nanmean(err[:, i])) for i, j in enumerate(EVAL_JOINTS)},
        "per_frame_mm": [float(v) for v in np.nanmean(err, axis=1)],
        "track_reprojection_px": [float(v) for v in track_px],
        "reference_reprojection_px": [float(v) for v in ref_px],
        "body": dims,
        "notes": res.notes,
        "lost_frames": int(np.sum(res.diagnostics["lost"])),
        "seconds": wall,
        "seconds_per_frame": wall / max(len(idx), 1),
        "_shown": shown,
        "_dims": dims,
        "_joints": res.joints,
        "_joints_exported": joints_exported,
        "fps": fps,
        "smooth": smooth,
    }


def held_out_errors(rig_full: camera.Rig, points: np.ndarray, kp_full: np.ndarray, held: int) -> np.ndarray:
    """``(T, 15)`` px: distance in camera ``held`` between the projected ``points (T, 15, 3)`` (evaluation joints)
    and that camera's detections ``kp_full (T, V, 15, 3)``; NaN where the detection's confidence is ≤ 0.3 or the
    point is missing."""
    rj = camera.select(rig_full, [held]).to_jax(jnp.float32)
    P = np.nan_to_num(np.asarray(points, np.float64))
    uv = np.asarray(camera.project(rj, jnp.asarray(P, jnp.float32)), np.float64)[:, 0]  # (T, 15, 2)
    det = kp_full[:, held]
    err = np.linalg.norm(uv - det[..., :2], axis=-1)
    ok = (det[..., 2] > 0.3) & np.all(np.isfinite(points), axis=-1)
    return np.where(ok, err, np.nan)


def triangulated(rig_full: camera.Rig, kp_full: np.ndarray, cams) -> np.ndarray:
    """``(T, 15, 3)``: the subject's detections of cameras ``cams`` triangulated per joint and frame (module
    docstring: confidence-weighted DLT, views under 0.3 dropped, NaN with fewer than two views)."""
    sub = camera.select(rig_full, list(cams)).to_jax(jnp.float32)  # (JAX's default precision)
    kp = np.moveaxis(kp_full[:, list(cams)], 1, 2)  # (T, 15, V', 3)
    w = np.where(kp[..., 2] > 0.3, kp[..., 2], 0.0)
    X = camera.triangulate(sub, jnp.asarray(kp[..., :2], jnp.float32), jnp.asarray(w, jnp.float32))
    return np.asarray(X, np.float64)


#: Pose2Sim's triangulation settings, the defaults its ``Config.toml`` (``[triangulation]``) ships with: the mean
#: reprojection error (px) above which cameras are left out, the detection likelihood below which a camera is
#: not used, the fewest cameras a point is triangulated from, and the longest gap (frames) it interpolates
P2S_REPROJ_PX = 15.0
P2S_LIKELIHOOD = 0.3
P2S_MIN_CAMERAS = 2
P2S_INTERP_GAP = 10
#: Pose2Sim's default filtering of the triangulated points (``[filtering]``: Butterworth, order 4, 6 Hz)
P2S_FILTER = "butterworth:6"


def pose2sim_triangulated(rig_full: camera.Rig, kp_full: np.ndarray, cams) -> tuple[np.ndarray, float]:
    """``(T, 15, 3)`` and the fraction of (frame, joint) points left out: the subject's detections of cameras
    ``cams`` triangulated as Pose2Sim's triangulation step does it with its defaults (:data:`P2S_REPROJ_PX` …):
    per point, the cameras whose detection has a likelihood of at least 0.3, linear DLT with each camera's rows
    weighed by that likelihood (in pixels: times the focal length); when the mean reprojection error over the
    cameras used exceeds 15 px, every subset with one camera fewer is triangulated and the best kept, and so on
    down to two cameras; a point still above 15 px is left out (NaN). Then, per joint, gaps shorter than 10
    frames between triangulated frames are filled by cubic interpolation. Undistorted points (its
    ``undistort_points = true``); without its optional left/right swap (``handle_LR_swap``, off by default)."""
    import itertools

    from scipy.interpolate import CubicSpline

    from jaxmocap.io.subject import ViewGeometry

    geo = ViewGeometry(camera.select(rig_full, list(cams)))
    T, n = kp_full.shape[0], len(cams)
    out = np.full((T, len(EVAL_JOINTS), 3), np.nan)
    tried = rejected = 0
    for t in range(T):
        ab = np.stack([geo.normalise(v, kp_full[t, c]) for v, c in enumerate(cams)])  # (n, 15, 3)
        for j in range(len(EVAL_JOINTS)):
            use = [v for v in range(n) if ab[v, j, 2] >= P2S_LIKELIHOOD]
            if len(use) < P2S_MIN_CAMERAS:
                continue
            tried += 1
            for k in range(len(use), P2S_MIN_CAMERAS - 1, -1):
                best = None
                for sub in itertools.combinations(use, k):
                    pts = ab[list(sub), j : j + 1]
                    w = (pts[:, :, 2] * geo.f[list(sub), None]) / geo.f.mean()
                    X = geo.triangulate(
                        list(sub), np.concatenate([pts[..., :2], np.ones_like(pts[..., 2:])], -1), w
                    )
                    err = np.mean([geo.joint_residuals(v, X, ab[v, j : j + 1])[0] for v in sub])
                    if np.isfinite(err) and (best is None or err < best[0]):
                        best = (err, X[0])
                if best is not None and best[0] <= P2S_REPROJ_PX:
                    out[t, j] = best[1]
                    break
            else:
                rejected += 1
    frames = np.arange(T)
    for j in range(len(EVAL_JOINTS)):
        ok = np.all(np.isfinite(out[:, j]), axis=1)
        if ok.sum() < 4:
            continue
        spline = CubicSpline(frames[ok], out[ok, j], axis=0)
        edges = np.flatnonzero(np.diff(np.r_[0, (~ok).astype(int), 0]))  # each gap's first frame and its end
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            if a > 0 and b < T and b - a < P2S_INTERP_GAP:  # between triangulated frames, and short
                out[a:b, j] = spline(frames[a:b])
    return out, rejected / max(tried, 1)


def skeleton_fit(
    rig_full: camera.Rig,
    kp_full: np.ndarray,
    cams,
    states: np.ndarray,
    dims: dict,
    model_name: str = "full25",
) -> np.ndarray:
    """``(T, 15, 3)``: the run's body model (preset ``model_name`` with the run's dimensions ``dims``) fitted on each
    frame to the detections of cameras ``cams`` alone (:func:`jaxmocap.fit.ik.fit_pose_2d` from the tracked state ``states[t]``,
    prior weight 1, each detection of confidence > 0.3 weighed by its confidence over
    :data:`~jaxmocap.tracking.init.KEYPOINT_SIGMA_PX`² in full-size pixels): what the skeleton itself can do with
    the three cameras' detections, without images, filter or smoothing."""
    import jax

    model = body.build(model_name, dims)
    names = list(model.joint_names)
    pairs = [(names.index(j), k) for j, k in KEYPOINT_INDEX.items()]
    jidx, kidx = np.array([p for p, _ in pairs]), np.array([k for _, k in pairs])
    sub = camera.select(rig_full, list(cams)).to_jax(jnp.float32)
    fit = jax.jit(lambda uv, w, x0: fit_pose_2d(model, sub, uv, w, x0, prior_weight=1.0))
    fitted = []
    for t in range(states.shape[0]):
        det = kp_full[t][list(cams)][:, kidx]  # (V', M, 3)
        uv = np.zeros((len(cams), len(names), 2), np.float32)
        w = np.zeros((len(cams), len(names)), np.float32)
        uv[:, jidx] = det[..., :2]
        w[:, jidx] = np.where(det[..., 2] > 0.3, det[..., 2], 0.0) / KEYPOINT_SIGMA_PX**2
        fitted.append(fit(jnp.asarray(uv), jnp.asarray(w), jnp.asarray(states[t], jnp.float32)))
    X = jax.vmap(lambda x: body.joint_positions(model, x))(jnp.stack(fitted))
    return np.asarray(X, np.float64)


def smoothed(points: np.ndarray, fps: float, smooth: str) -> np.ndarray:
    """``points (T, 15, 3)`` through the exported track's filter (``smooth``, the ``--smooth`` spelling: the same
    zero-phase Butterworth low-pass, :func:`jaxmocap.tracking.smoothing.butterworth`) coordinate by coordinate,
    each joint's missing frames interpolated for the filter (:func:`jaxmocap.tracking.smoothing.fill_gaps`) and left missing after it."""
    cutoff = parse_smooth(smooth, fps)
    out = np.full_like(points, np.nan)
    t = np.arange(points.shape[0])
    for j in range(points.shape[1]):
        ok = np.all(np.isfinite(points[:, j]), axis=-1)
        if ok.sum() < 2:
            continue
        filled, _ = fill_gaps(t, t, points[:, j], ok)
        out[:, j] = filled if cutoff is None else butterworth(filled, fps, cutoff)
        out[~ok, j] = np.nan
    return out


def leave_one_out(out: pathlib.Path, a) -> list[dict]:
    """For each camera: track from the other three (:func:`track`) and triangulate their detections; the
    reprojection errors of both in the held-out camera (module docstring)."""
    full = open_project(make_project(out / "project_all", (0, 1, 2, 3)))
    try:
        rig, kp_all = full.rig, np.asarray(full.keypoints)
        names = list(full.view_names)
    finally:
        full.close()
    kp_base = kp_all  # what the three cameras give the baseline: the shipped detections, or the detector's
    if a.detector:
        det = open_project(
            make_project(out / "project_all_detector", (0, 1, 2, 3), pose=False),
            detector="blazepose",
            frames=a.frames,
        )
        try:
            kp_base = np.asarray(det.keypoints)
        finally:
            det.close()
    rows = []
    for held in range(4):
        cams = tuple(c for c in range(4) if c != held)
        r = track(out / f"without{held + 1}", cams, a)
        idx = r["frames"]
        kp = kp_all[idx]
        joints = np.asarray(r.pop("_joints"))
        e_track = held_out_errors(rig, joints, kp, held)
        tri = triangulated(rig, kp_base[idx], cams)
        e_tri = held_out_errors(rig, tri, kp, held)
        p2s, p2s_rejected = pose2sim_triangulated(rig, kp_base[idx], cams)
        e_p2s = held_out_errors(rig, p2s, kp, held)
        states = np.load(out / f"without{held + 1}" / "run" / "poses.npz")["state"]
        e_fit = held_out_errors(
            rig, skeleton_fit(rig, kp_base[idx], cams, states, r["_dims"], a.model), kp, held
        )
        # the exported track against the triangulation through the same filter (Pose2Sim filters its own)
        e_track_s = held_out_errors(rig, np.asarray(r.pop("_joints_exported")), kp, held)
        e_tri_s = held_out_errors(rig, smoothed(tri, r["fps"], r["smooth"]), kp, held)
        e_p2s_s = held_out_errors(rig, smoothed(p2s, r["fps"], r["smooth"]), kp, held)
        e_p2s_out = held_out_errors(rig, smoothed(p2s, r["fps"], P2S_FILTER), kp, held)  # its own output
        both = np.isfinite(e_track) & np.isfinite(e_tri)  # the same detections for both
        both &= np.isfinite(e_track_s) & np.isfinite(e_tri_s) & np.isfinite(e_fit)
        # Pose2Sim's procedure leaves some points out: compared with the tracker on the detections it has
        with_p2s = np.isfinite(e_track) & np.isfinite(e_track_s) & np.isfinite(e_p2s) & np.isfinite(e_p2s_s)
        with_p2s &= np.isfinite(e_p2s_out)
        rows.append(
            {
                "held_out": names[held],
                "frames": len(idx),
                "track_px": {j: float(np.mean(e_track[:, i][both[:, i]])) for i, j in enumerate(EVAL_JOINTS)},
                "triangulation_px": {
                    j: float(np.mean(e_tri[:, i][both[:, i]])) for i, j in enumerate(EVAL_JOINTS)
                },
                "track_mean_px": float(np.mean(e_track[both])),
                "triangulation_mean_px": float(np.mean(e_tri[both])),
                "track_median_px": float(np.median(e_track[both])),
                "exported_mean_px": float(np.mean(e_track_s[both])),
                "triangulation_smoothed_mean_px": float(np.mean(e_tri_s[both])),
                "skeleton_fit_mean_px": float(np.mean(e_fit[both])),
                "skeleton_fit_px": {
                    j: float(np.mean(e_fit[:, i][both[:, i]])) for i, j in enumerate(EVAL_JOINTS)
                },
                "exported_px": {
                    j: float(np.mean(e_track_s[:, i][both[:, i]])) for i, j in enumerate(EVAL_JOINTS)
                },
                "triangulation_smoothed_px": {
                    j: float(np.mean(e_tri_s[:, i][both[:, i]])) for i, j in enumerate(EVAL_JOINTS)
                },
                "smooth": r["smooth"],
                "triangulation_median_px": float(np.median(e_tri[both])),
                "pairs": int(both.sum()),
                "pose2sim_pairs": int(with_p2s.sum()),
                "pose2sim_px": {
                    j: float(np.mean(e_p2s[:, i][both[:, i] & with_p2s[:, i]]))
                    for i, j in enumerate(EVAL_JOINTS)
                },
                "pose2sim_rejected": float(p2s_rejected),
                "track_vs_pose2sim_px": float(np.mean(e_track[with_p2s])),
                "pose2sim_mean_px": float(np.mean(e_p2s[with_p2s])),
                "exported_vs_pose2sim_px": float(np.mean(e_track_s[with_p2s])),
                "pose2sim_smoothed_mean_px": float(np.mean(e_p2s_s[with_p2s])),
                "pose2sim_output_mean_px": float(np.mean(e_p2s_out[with_p2s])),
                "mean_mm_to_trc": r["mean_mm"],
                "seconds_per_frame": r["seconds_per_frame"],
            }
        )
        print(
            f"held out {names[held]}: tracked {rows[-1]['track_mean_px']:.1f} px, triangulated "
            f"{rows[-1]['triangulation_mean_px']:.1f} px; exported {rows[-1]['exported_mean_px']:.1f} px, "
            f"triangulated and smoothed {rows[-1]['triangulation_smoothed_mean_px']:.1f} px over "
            f"{rows[-1]['pairs']} detections; Pose2Sim's procedure {rows[-1]['pose2sim_mean_px']:.1f} px against "
            f"{rows[-1]['track_vs_pose2sim_px']:.1f} tracked, {rows[-1]['pose2sim_smoothed_mean_px']:.1f} filtered "
            f"against {rows[-1]['exported_vs_pose2sim_px']:.1f} exported over {rows[-1]['pose2sim_pairs']} "
            f"({100 * rows[-1]['pose2sim_rejected']:.0f} % of its points rejected)",
            flush=True,
        )
    return rows


def loo_report(rows: list[dict], a, argv) -> str:
    cmd = f"JAX_PLATFORMS=cpu python {common.script(__file__)} " + " ".join(
        x for x in (sys.argv[1:] if argv is None else argv)
    )
    wins = sum(r["track_mean_px"] < r["triangulation_mean_px"] for r in rows)
    lines = [
        "# Pose2Sim demo recording: leave one camera out\n",
        f"Reproduce: `{cmd}` ({common.stamp()}, {common.machine_line()})\n",
        "For each camera in turn, the recording is tracked from the other three (`jaxmocap.track` on a Pose2Sim "
        f"project of three cameras: the `{a.model}` body, APF {a.particles} × {a.layers}, images down-sampled by "
        f"{a.downsample}, cues "
        f"`{a.cues}`, seed {a.seed}, frames {a.frames}), and the tracked joints are projected into the held-out "
        "camera. Baseline: the same three cameras' detections of the subject triangulated (linear DLT weighed by "
        "confidence, detections under 0.3 dropped: Pose2Sim's weighting, without its view rejection) and projected "
        "the same way. Both are compared with the held-out camera's own detections (confidence > 0.3; the same "
        "detections for both), in full-size pixels. The held-out detections are not seen by either.\n",
        *(
            [
                "**Keypoints from the built-in detector** (`--detector`): the three cameras' projects have no "
                "`pose/` folder, so `jaxmocap.track` detects the keypoints itself (BlazePose, `jaxmocap.io.detect`), "
                "and the baseline triangulates the same detector's keypoints of those cameras; the held-out camera "
                "is scored against its shipped OpenPose detections, as above.\n"
            ]
            if a.detector
            else []
        ),
        "## Mean (median) reprojection error in the held-out camera, px\n",
        "| held out | tracked | triangulated | tracker lower | detections | tracked 3D distance to the .trc (mm) | s/frame |",
        "|---|---|---|---|---|---|---|",
    ]
    wins_s = sum(r["exported_mean_px"] < r["triangulation_smoothed_mean_px"] for r in rows)
    wins_p = sum(r["track_vs_pose2sim_px"] < r["pose2sim_mean_px"] for r in rows)
    wins_ps = sum(r["exported_vs_pose2sim_px"] < r["pose2sim_smoothed_mean_px"] for r in rows)
    wins_po = sum(r["exported_vs_pose2sim_px"] < r["pose2sim_output_mean_px"] for r in rows)
    for r in rows:
        lines.append(
            f"| {r['held_out']} | {r['track_mean_px']:.1f} ({r['track_median_px']:.1f}) | "
            f"{r['triangulation_mean_px']:.1f} ({r['triangulation_median_px']:.1f}) | "
            f"{'yes' if r['track_mean_px'] < r['triangulation_mean_px'] else 'no'} | {r['pairs']} | "
            f"{r['mean_mm_to_trc']:.1f} | {r['seconds_per_frame']:.2f} |"
        )
    lines += [
        "",
        f"The tracker's reprojection error is lower than this triangulation's for {wins} of {len(rows)} held-out "
        f"cameras{' (every one)' if wins == len(rows) else ''}; against Pose2Sim's whole triangulation step, "
        "below.\n",
        "## The exported track against the triangulation filtered alike, px\n",
        f"What a user takes away is the exported track (`poses_smoothed.npz`, BVH, TRC: `--smooth {rows[0]['smooth']}`, "
        "a zero-phase Butterworth low-pass of the states), and Pose2Sim filters its triangulated points too (a "
        "Butterworth low-pass by default): here the triangulated joints go through the same filter as the exported "
        "track, each joint's untriangulated frames interpolated for it. The same held-out detections as above.\n",
        "| held out | exported track | triangulated, filtered | exported lower |",
        "|---|---|---|---|",
        *(
            f"| {r['held_out']} | {r['exported_mean_px']:.1f} | {r['triangulation_smoothed_mean_px']:.1f} | "
            f"{'yes' if r['exported_mean_px'] < r['triangulation_smoothed_mean_px'] else 'no'} |"
            for r in rows
        ),
        "",
        f"Lower for {wins_s} of {len(rows)} held-out cameras.\n",
        "## Against Pose2Sim's own triangulation procedure, px\n",
        "The baseline above is Pose2Sim's weighting alone. Its triangulation step does more with its default "
        f"settings (`pose2sim_triangulated`): a point whose mean reprojection error exceeds {P2S_REPROJ_PX:g} px is "
        "triangulated again from every subset of one camera fewer, the best kept, down to two cameras, and left "
        f"out if still above; gaps under {P2S_INTERP_GAP} frames are then filled by cubic interpolation. Compared "
        "on the held-out detections where it gives a point (the tracker on the same ones), raw and through the "
        "exported track's filter; and Pose2Sim's output as it writes it, its triangulation through its own default "
        f"filter (`{P2S_FILTER}`: order 4, zero phase), against the exported track.\n",
        "| held out | tracked | Pose2Sim's procedure | tracker lower | exported | Pose2Sim's, filtered alike | "
        "exported lower | Pose2Sim's output | exported lower | detections | points rejected |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
        *(
            f"| {r['held_out']} | {r['track_vs_pose2sim_px']:.1f} | {r['pose2sim_mean_px']:.1f} | "
            f"{'yes' if r['track_vs_pose2sim_px'] < r['pose2sim_mean_px'] else 'no'} | "
            f"{r['exported_vs_pose2sim_px']:.1f} | {r['pose2sim_smoothed_mean_px']:.1f} | "
            f"{'yes' if r['exported_vs_pose2sim_px'] < r['pose2sim_smoothed_mean_px'] else 'no'} | "
            f"{r['pose2sim_output_mean_px']:.1f} | "
            f"{'yes' if r['exported_vs_pose2sim_px'] < r['pose2sim_output_mean_px'] else 'no'} | "
            f"{r['pose2sim_pairs']} | {100 * r['pose2sim_rejected']:.0f} % |"
            for r in rows
        ),
        "",
        f"The tracker's reprojection error is lower than Pose2Sim's triangulation step's for {wins_p} of "
        f"{len(rows)} held-out cameras: the goal (lower for every choice) "
        f"**{'is met' if wins_p == len(rows) else 'is not met'}** against Pose2Sim's triangulation step, raw "
        f"against raw. Against the weighted DLT alone (above): {wins} of {len(rows)}; filtered alike: {wins_ps} of "
        f"{len(rows)}; the exported track against Pose2Sim's filtered output: {wins_po} of {len(rows)}.\n",
        "## The skeleton alone on the three cameras' detections, px\n",
        "What the body model can do at best with the detections: on each frame the run's model (its own body "
        "dimensions) fitted to the three cameras' detections alone by their reprojection error, from the tracked "
        "pose (`skeleton_fit`: no images, no filter, no smoothing), projected into the held-out camera like the "
        "others. Where this is above the triangulation, the detections alone cannot bring the model's joints below "
        "it (the model's torso and shoulders, fixed limb lengths, joint centres where the detector has surface "
        "landmarks); only what the images add can.\n",
        "| held out | skeleton fitted | tracked | triangulated | skeleton lower than triangulation |",
        "|---|---|---|---|---|",
        *(
            f"| {r['held_out']} | {r['skeleton_fit_mean_px']:.1f} | {r['track_mean_px']:.1f} | "
            f"{r['triangulation_mean_px']:.1f} | "
            f"{'yes' if r['skeleton_fit_mean_px'] < r['triangulation_mean_px'] else 'no'} |"
            for r in rows
        ),
        "",
        "## Per joint, px (tracked / triangulated / Pose2Sim's triangulation step / skeleton fitted)\n",
        "| joint | " + " | ".join(r["held_out"] for r in rows) + " |",
        "|---" * (len(rows) + 1) + "|",
    ]
    for j in EVAL_JOINTS:
        if all(not np.isfinite(r["track_px"][j]) for r in rows):
            lines.append(f"| {j} | " + " | ".join("— (no detected keypoint)" for _ in rows) + " |")
            continue
        lines.append(
            f"| {j} | "
            + " | ".join(
                f"{r['track_px'][j]:.1f} / {r['triangulation_px'][j]:.1f} / {r['pose2sim_px'][j]:.1f} / "
                f"{r['skeleton_fit_px'][j]:.1f}"
                for r in rows
            )
            + " |"
        )
    text = "\n".join(lines) + "\n"
    common.write_result(
        common.RESULTS / ("pose2sim_loo_detector.md" if a.detector else "pose2sim_loo.md"), text, cmd
    )
    return text


def save_overlay(res: dict, path: pathlib.Path, scale: float = 0.25) -> None:
    """The tracked model (and the detections, white dots) on the middle tracked frame of every camera, drawn at
    full size and shown at ``scale``."""
    from jaxmocap.eval import viz
    from jaxmocap.tracking.options import build_model

    images, rig, kps, x = res["_shown"]
    model = build_model("full25", None, None, res["_dims"])
    ims = viz.overlay_image(images, model, rig.to_jax(jnp.float32), x)
    small = []
    for im, kp in zip(ims, kps, strict=True):
        for u, w, c in kp:
            if c > 0.3:
                cv2.circle(im, (int(round(u)), int(round(w))), 8, (255, 255, 255), -1)
        h = int(round(1920 * scale))
        small.append(
            cv2.resize(im, (int(round(im.shape[1] * h / im.shape[0])), h), interpolation=cv2.INTER_AREA)
        )
    cv2.imwrite(os.fspath(path), np.hstack(small), [cv2.IMWRITE_PNG_COMPRESSION, 9])


def table(results: list[dict]) -> str:
    head = "| joint | " + " | ".join("+".join(r["cameras"]) for r in results) + " |"
    lines = [head, "|---" * (len(results) + 1) + "|"]
    for j in EVAL_JOINTS:
        lines.append(f"| {j} | " + " | ".join(f"{r['per_joint_mm'][j]:.0f}" for r in results) + " |")
    lines.append("| **mean** | " + " | ".join(f"**{r['mean_mm']:.1f}**" for r in results) + " |")
    lines.append("| mean without head | " + " | ".join(f"{r['mean_mm_no_head']:.1f}" for r in results) + " |")
    lines.append("| median | " + " | ".join(f"{r['median_mm']:.1f}" for r in results) + " |")
    return "\n".join(lines)


def make_test_data(dest: pathlib.Path, frames: list[int], scale: float) -> None:
    """Copy a few frames of the recording at ``scale`` (JPEG), the backgrounds, the calibration, the detections
    of those frames, the reference and the licence into ``dest``."""
    p = paths(DATA)
    src = Pose2SimSource(p["calibration"], p["keypoints"], videos=p["videos"], scale=scale)
    bgs = src.background(p["extrinsics"])
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "calibration").mkdir(exist_ok=True)
    shutil.copy(p["calibration"], dest / "calibration.toml")
    (dest / "background").mkdir(exist_ok=True)
    for v in range(len(src.view_names)):
        cam = f"cam0{v + 1}"
        cv2.imwrite(os.fspath(dest / "background" / f"{cam}.jpg"), bgs[v], [cv2.IMWRITE_JPEG_QUALITY, 90])
        (dest / "images" / cam).mkdir(parents=True, exist_ok=True)
        (dest / "pose" / f"{cam}_json").mkdir(parents=True, exist_ok=True)
        for f in frames:
            fd = src.read(f)
            cv2.imwrite(
                os.fspath(dest / "images" / cam / f"{f:04d}.jpg"),
                fd.images[v],
                [cv2.IMWRITE_JPEG_QUALITY, 90],
            )
            name_json = f"{cam}.{f:04d}.json"
            shutil.copy(p["keypoints"][v] / name_json, dest / "pose" / f"{cam}_json" / name_json)
    src.close()
    # the reference: header and the rows of the chosen frames (frame numbers kept)
    lines = p["trc"].read_text().splitlines()
    head, rows = lines[:5], [r for r in lines[5:] if r.strip()]
    keep = [rows[f] for f in frames]
    head[2] = head[2].split("\t")
    head[2][2] = str(len(keep))
    head[2] = "\t".join(head[2])
    (dest / "reference.trc").write_text("\n".join(head + keep) + "\n")
    shutil.copy(DATA / "LICENSE.pose2sim", dest / "LICENSE.pose2sim")
    (dest / "PROVENANCE.md").write_text(
        "# Provenance\n\n"
        "A few frames of the Pose2Sim demo trial (perfanalytics/pose2sim, BSD-3-Clause, see LICENSE.pose2sim):\n"
        "videos `Pose2Sim/Demo_SinglePerson/videos/camNN.mp4` at HEAD f7b39c747b361ce2cef2304bd7d42dddd15b3d36;\n"
        "OpenPose BODY_25B detections (`pose/camNN_json`), the triangulated reference (`pose-3d/"
        "S00_P00_T01_BalancingTrial_0-100.trc`) and the calibration (`S00_Calibration/Calib_qualisys.toml`) at\n"
        "commit a948c205cfe4ea5c22d6941929e8efaba591a59d (S00_P00_T01_BalancingTrial).\n\n"
        f"Made by `benchmarks/experiments/pose2sim_track.py --make-test-data`: frames {frames} of every camera resized by {scale}\n"
        "(cam01/cam02 padded on the right from 1080 to the calibrated 1088 px first), JPEG quality 90;\n"
        "`background/` (JPEG quality 90) = per-pixel median of 15 frames without the subject's box, filled from\n"
        "`calibration/extrinsics/camNN_ext.png`; the detection JSONs and calibration copied unmodified;\n"
        "`reference.trc` = the header and the rows of these frames (NumFrames changed accordingly).\n"
    )
    shutil.rmtree(dest / "calibration")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="/tmp/pose2sim_track", help="working folder of the runs")
    ap.add_argument(
        "--downsample", type=int, default=4, choices=(1, 2, 4), help="image down-sampling (default 4)"
    )
    ap.add_argument("--frames", default="0:100", help="frames A:B (default 0:100)")
    ap.add_argument("--particles", type=int, default=300)
    ap.add_argument("--layers", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--model", default="full25", choices=MODELS, help="body model (default full25)")
    ap.add_argument("--cues", default=CUES, help=f"cues and weights (default {CUES})")
    ap.add_argument("--refine", help="the tracker's refinement on the detections (default: the library's)")
    ap.add_argument("--refine-prior", type=float, help="its prior weight (default: the library's)")
    ap.add_argument("--pair-only", action="store_true", help="only the 2-camera run")
    ap.add_argument("--no-pair", action="store_true", help="only the 4-camera run")
    ap.add_argument(
        "--report", action="store_true", help=f"write {common.RESULTS}/pose2sim.md and the overlay"
    )
    ap.add_argument("--make-test-data", metavar="DIR", help="write the small test copy and exit")
    ap.add_argument(
        "--leave-one-out",
        action="store_true",
        help=f"track from three cameras, compare in the fourth with triangulation ({common.RESULTS}/pose2sim_loo.md)",
    )
    ap.add_argument(
        "--detector",
        action="store_true",
        help="the three cameras' keypoints from the built-in detector, not the shipped detections (tracked and "
        f"triangulated alike; scored against the held-out camera's shipped ones; {common.RESULTS}/pose2sim_loo_detector.md)",
    )
    a = ap.parse_args(argv)
    if a.make_test_data:
        make_test_data(pathlib.Path(a.make_test_data), [0, 1, 2, 3], 0.125)
        return 0
    out = pathlib.Path(a.out)
    if a.leave_one_out:
        print(loo_report(leave_one_out(out, a), a, argv))
        return 0
    ref, _, _ = reference_joints(DATA / TRC)
    pair = neighbouring_pair(calibration.load_calibration(DATA / CALIB), np.nanmean(ref[:, 0], axis=0))
    sets = []
    if not a.pair_only:
        sets.append((0, 1, 2, 3))
    if not a.no_pair:
        sets.append(pair)
    results = []
    for cams in sets:
        r = track(out / ("cams" + "".join(str(c + 1) for c in cams)), cams, a)
        results.append(r)
        print(
            f"cameras {'+'.join(r['cameras'])}: mean {r['mean_mm']:.1f} mm (without head {r['mean_mm_no_head']:.1f}), "
            f"reprojection tracked {np.round(r['track_reprojection_px'], 1)} px vs reference "
            f"{np.round(r['reference_reprojection_px'], 1)} px, {r['seconds_per_frame']:.2f} s/frame",
            flush=True,
        )
        for note in r["notes"]:
            print(f"  note: {note}", flush=True)
    keep = [{k: v for k, v in r.items() if not k.startswith("_")} for r in results]
    out.mkdir(parents=True, exist_ok=True)
    (out / "pose2sim.json").write_text(json.dumps(keep, indent=1))
    print(table(results))
    if a.report:
        write_report(results, a, argv)
    return 0


def write_report(results: list[dict], a, argv) -> None:
    common.RESULTS.mkdir(exist_ok=True)
    save_overlay(results[0], common.RESULTS / "pose2sim_overlay.png")
    cmd = f"JAX_PLATFORMS=cpu python {common.script(__file__)} " + " ".join(
        x for x in (sys.argv[1:] if argv is None else argv)
    )
    rows = []
    for r in results:
        rows.append(
            f"| {'+'.join(r['cameras'])} | "
            + " | ".join(
                f"{t:.1f} / {q:.1f}"
                for t, q in zip(r["track_reprojection_px"], r["reference_reprojection_px"], strict=True)
            )
            + " |"
        )
    frames = results[0]["frames"]
    notes = "\n".join(f"- {n}" for n in results[0]["notes"])
    dims = ", ".join(f"{k} {v:.3f}" for k, v in sorted(results[0]["body"].items()))
    text = (
        "# Pose2Sim demo recording: tracked from its project folder, compared with Pose2Sim's triangulation\n\n"
        f"Reproduce: `{cmd}`\n\n"
        f"Input: the recording as a Pose2Sim project folder (videos, calibration, shipped BODY_25B detections) "
        f"given to `jaxmocap.track(input=FOLDER, …)` (the same as `jaxmocap track FOLDER`). Frames "
        f"{frames[0]}–{frames[-1]} (60 fps), images down-sampled by {a.downsample}, APF {a.particles} particles × "
        f"{a.layers} layers, seed {a.seed}, cues `{a.cues}`; everything else the library's defaults for the "
        "folder.\n\n"
        f"What the library said about the input (4-camera run):\n\n{notes}\n\n"
        f"Body dimensions measured from the triangulated detections (m): {dims}.\n\n"
        "## 3D distance to the `.trc` reference (mm, mean over frames)\n\n"
        + table(results)
        + "\n\n## 2D distance to the subject's detections (px, full 1080/1088×1920 images, confidence > 0.3)\n\n"
        "tracked model / the reference's own markers, per camera\n\n"
        + "| cameras | "
        + " | ".join(f"cam {i + 1}" for i in range(len(results[0]["cameras"])))
        + " |\n"
        + "|---" * (len(results[0]["cameras"]) + 1)
        + "|\n"
        + "\n".join(rows)
        + "\n\n"
        + "\n".join(
            f"- {'+'.join(r['cameras'])}: {r['seconds_per_frame']:.2f} s/frame (CPU, whole run: decoding, "
            f"features, compilation), track lost in {r['lost_frames']} frame(s)"
            for r in results
        )
        + "\n"
    )
    common.write_result(common.RESULTS / "pose2sim.md", text, cmd)


if __name__ == "__main__":
    raise SystemExit(main())
