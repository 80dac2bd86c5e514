"""Body-shape calibration from the first frames of a recording, poses unknown
(:func:`jaxmocap.fit.shape_start.calibrate_from_start`).

Synthetic part (every choice stated here):

* the subject: a ``full25`` body whose fitted lengths and radii are the defaults times :data:`FACTORS` (±10 %,
  mixed signs; the head keeps its default size); its poses are the model fitted by IK
  (:func:`jaxmocap.fit.ik.fit_pose`) to the evaluation joints of a real CMU recording (:data:`CLIP`: the walk
  02_01, source frames 0–40 at 30 fps) — so the rendered body is exactly a ``full25`` model and the truth is
  known;
* the scene: the synthesiser's ``ring4`` (or ``stereo``) rig placed around the motion
  (:func:`jaxmocap.synth.stage.preset_rig`), ``--size`` (default 320×240), ray-cast flat-capped cones and head
  spheroid (:func:`jaxmocap.geometry.render.render_view`) shaded by the synthesiser (:func:`jaxmocap.synth.generate.
  view_images`: Lambert light, one clothing colour per limb, the bundled photographs behind, sensor noise 0.01),
  one empty-scene plate per view (:mod:`jaxmocap.synth.plates`) and simulated BODY_25B detections
  (:class:`jaxmocap.synth.detections.Detector`, the synthesiser's error model; toe tips 15 cm in front of the
  ankles), written as a sequence folder;
* the input (what a recording gives): :class:`jaxmocap.io.sources.SequenceSource` with ``recording=True`` and the
  tracker's features (:class:`jaxmocap.tracking.features.FeatureBuilder`: foreground by subtraction of the plates,
  the edge distance transform, the detections) of the first ``--frames`` (10) frames; no rendered mask, pose or
  dimension reaches the fit; the truth only scores;
* the fit: :func:`~jaxmocap.fit.shape_start.calibrate_from_start` with its defaults (``--steps``).

Reported per fitted dimension: true, start (the measured lengths, else the default), fitted, relative error; the
goal is every length and radius within 5 %. The signed offsets (``*_drop``, a few cm) are judged in mm.

Real part: the Pose2Sim demo (4 cameras, 1080×1920 downsampled by 4, shipped BODY_25B detections, median
background; loaded as ``pose2sim_track.py`` loads it: a project folder of links, :func:`scenes.pose2sim_project`, opened by
:func:`jaxmocap.io.pose2sim.open_project`), first 10 frames;
the fitted limb lengths (joint to joint, :func:`jaxmocap.fit.shape.limb_lengths`) against the median over the same
frames of the distances between Pose2Sim's triangulated ``.trc`` markers of the same joints.

    python benchmarks/experiments/shape_calibration.py [--work DIR] [--rigs ring4 stereo] [--steps 200]
        [--no-pose2sim] [--quick]

Writes ``benchmarks/results/shape_calibration.md`` (not with ``--quick``: 160×120, 4 frames, 40 steps, printed).
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import common
import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.fit import ik, shape
from jaxmocap.fit.shape_start import calibrate_from_start
from jaxmocap.geometry import body, flesh, render
from jaxmocap.io import sequence as seqio
from jaxmocap.io.mocap import eval_joints
from jaxmocap.io.sources import SequenceSource
from jaxmocap.synth import detections as dets
from jaxmocap.synth import generate as synth
from jaxmocap.synth import plates
from jaxmocap.synth.dressing import ROLE_COLOURS
from jaxmocap.tracking.features import FeatureBuilder

RESULTS = common.RESULTS / "shape_calibration.md"
#: the subject: default dimension × factor (fitted lengths and radii, ±10 %, mixed signs)
FACTORS = {
    "torso_length": 1.10,
    "shoulder_width": 0.90,
    "shoulder_drop": 1.10,
    "hip_width": 1.10,
    "hip_drop": 0.90,
    "neck_length": 0.90,
    "upper_arm_length": 0.90,
    "forearm_length": 1.10,
    "thigh_length": 1.10,
    "shin_length": 0.90,
    "torso_radius_bottom": 0.90,
    "torso_radius_top": 1.10,
    "upper_arm_radius_top": 1.10,
    "upper_arm_radius_bottom": 0.90,
    "forearm_radius_top": 0.90,
    "forearm_radius_bottom": 1.10,
    "thigh_radius_top": 1.10,
    "thigh_radius_bottom": 0.90,
    "shin_radius_top": 0.90,
    "shin_radius_bottom": 1.10,
}
#: the motion (the bundled CMU walk 02_01) and its source frames
CLIP = ("demo", None, "0:60")
FEATURE_CUES = ("foreground", "edge_distance", "keypoints")


def true_dimensions() -> dict:
    return {**body.DEFAULT_DIMENSIONS, **{k: body.DEFAULT_DIMENSIONS[k] * f for k, f in FACTORS.items()}}


def _colours(model) -> np.ndarray:
    """``(C + E, 3)`` label colours: a clothing colour per limb (the synthesiser's), skin for the head."""
    out = []
    for s in flesh.cone_segments(model) + flesh.ellipsoid_segments(model):
        name = model.segment_names[s]
        role = next(
            (r for r in ("upper_arm", "forearm", "thigh", "shin", "torso") if name.endswith(r)), "head"
        )
        out.append(ROLE_COLOURS[role])
    return np.asarray(out, np.float32)


def render_subject(out: pathlib.Path, rig_name: str, size: tuple[int, int], frames: int, seed: int = 0):
    """Render the subject of :data:`FACTORS` moving as the CMU clip into the sequence folder ``out`` (module
    docstring); returns the true joints ``(T, 15, 3)``."""
    motion, asf, span = CLIP
    m, rec = synth.load_clip(motion, asf)
    a, b = synth.parse_frames(span, m.num_frames)
    src = np.arange(a, b, max(1, round(m.fps / 30.0)))[:frames]
    ej = eval_joints(m, rec.mapping)[src]
    model = body.full25(true_dimensions())
    dt = model.offset.dtype
    X, x = [], None
    for t in range(len(src)):
        target = jnp.asarray(ik.select_joints(model, ej[t]), dt)
        x = ik.fit_pose(model, target, init=x).state
        X.append(x)
    X = jnp.stack(X)
    joints = np.asarray(jax.vmap(lambda s: body.joint_positions(model, s))(X), np.float64)
    prims = [render.primitives_from_model(model, s) for s in X]
    points = np.stack(
        [
            np.concatenate([np.asarray(p.cone_a), np.asarray(p.cone_b), np.asarray(p.ell_centre)])
            for p in prims
        ]
    )
    cams = synth.preset_rig(rig_name, np.concatenate([points, joints], 1), joints, size)
    K, dist, Rv, tv = (np.asarray(v, np.float64) for v in (cams.K, cams.dist, cams.R, cams.t))
    V, T = cams.num_views, len(src)
    colours = jnp.asarray(_colours(model))
    C = prims[0].num_cones
    # detections: head poles, toe tips 15 cm in front of the ankles (the body faces its root's +x)
    poles = np.stack(
        [
            np.stack(
                [
                    np.asarray(p.ell_centre[0] - p.ell_axes[0, :, 2]),
                    np.asarray(p.ell_centre[0] + p.ell_axes[0, :, 2]),
                ]
            )
            for p in prims
        ]
    )
    fwd = np.asarray(jax.vmap(lambda s: body.segment_poses(model, s)[0][0, :, 0])(X), np.float64)
    fwd[:, 2] = 0.0
    fwd /= np.linalg.norm(fwd, axis=-1, keepdims=True)
    ank = [body.EVAL_JOINTS.index(n) for n in ("left_ankle", "right_ankle")]
    toes = joints[:, ank] + 0.15 * fwd[:, None]
    head_r = float(true_dimensions()["head_radius"])
    kp3, normals = dets.keypoints_3d(joints, poles, head_r, toes)
    detector = dets.Detector(K, dist, Rv, tv, cams.image_size, kp3, normals, 1)
    out.mkdir(parents=True, exist_ok=True)
    names = cams.names
    backgrounds = []
    for v in range(V):
        bg = jnp.asarray(synth.background_image("photo", cams.image_size[v], v, seed), jnp.float32) / 255.0
        backgrounds.append(bg)
        plate = plates.plate_image(np.random.default_rng([seed, 1 << 20, v, 3]), bg, 0.01)
        p = plates.plate_path(out, names[v])
        p.parent.mkdir(parents=True, exist_ok=True)
        seqio.write_rgb(p, plate)
    for k in range(T):
        p = prims[k]
        own = dets.own_labels(kp3[k], np.asarray(p.cone_a), np.asarray(p.cone_b), np.asarray(p.r_a),
                              np.asarray(p.r_b), C)  # fmt: skip
        for v in range(V):
            r = render.render_view(K[v], dist[v], Rv[v], tv[v], cams.image_size[v], p)
            light = jnp.asarray(
                Rv[v] @ np.array([0.4, 0.3, 1.0]) / np.linalg.norm([0.4, 0.3, 1.0]), jnp.float32
            )
            rgb, _, labels = synth.view_images(np.random.default_rng([seed, k, v]), [r], colours, light,
                                               backgrounds[v])  # fmt: skip
            path = seqio.frame_path(out, names[v], "rgb", k)
            path.parent.mkdir(parents=True, exist_ok=True)
            seqio.write_rgb(path, rgb)
            found = detector.frame(np.random.default_rng([seed, k, v, 2]), v, k, labels, own)
            dpath = synth.detections_path(out, names[v], k)
            dpath.parent.mkdir(parents=True, exist_ok=True)
            dets.write_openpose_json(dpath, found)
    seqio.write_calibration(out, cams)
    seqio.write_meta(out, {"frames": T, "fps": 30.0, "generator": "shape_calibration.py"})
    seqio.write_groundtruth(out, joints)
    return joints


def observations(source, frames: int, samples: int = 256):
    """The stacked image observations of the first ``frames`` frames as ``jaxmocap track`` computes them, their
    rig and the detections ``(T, V, 15, 3)`` (full-size pixels)."""
    fb = FeatureBuilder(source, FEATURE_CUES, "auto", 1, samples, list(range(frames)))
    D = body.full25().num_dofs
    obs = []
    for t in range(frames):
        tobs, _ = fb(source.read(t, masks=False, depth=False), D)
        obs.append(tobs.image)
    stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *obs)
    return stacked, fb.rig, np.asarray(source.keypoints[:frames]), fb.foreground


def score(fit, truth: dict) -> list[tuple]:
    rows = []
    for n in shape.LENGTHS + shape.RADII:
        t, s, f = truth[n], fit.start_dims[n], fit.dims[n]
        rows.append((n, t, s, f, (s - t) / t, (f - t) / t))
    return rows


def synthetic(
    work: pathlib.Path, rig: str, size, frames: int, steps: int, log=print, **fit_options
) -> tuple[list, dict]:
    seq = work / f"subject_{rig}_{size[0]}x{size[1]}_{frames}"
    if not (seq / ".complete").exists():
        render_subject(seq, rig, size, frames)
        (seq / ".complete").write_text("")
    source = SequenceSource(seq, recording=True)
    try:
        obs, frig, kp, fg = observations(source, frames)
        t0 = time.monotonic()
        fit = calibrate_from_start(obs, frig, kp, keypoint_rig=source.rig, steps=steps, **fit_options)
        wall = time.monotonic() - t0
    finally:
        source.close()
    rows = score(fit, true_dimensions())
    info = {"wall_s": wall, "frames_used": len(fit.frames), "foreground": fg,
            "objective": (float(fit.objective[0]), float(fit.objective[-1]))}  # fmt: skip
    log(f"{rig}: {wall:.1f} s, objective {info['objective'][0]:.3f} -> {info['objective'][1]:.3f}")
    for r in rows:
        log(
            f"  {r[0]:>24}: true {r[1]:.4f} start {r[2]:.4f} fitted {r[3]:.4f}  {100 * r[4]:+6.1f}% -> {100 * r[5]:+6.1f}%"
        )
    return rows, info


#: the limbs compared on the Pose2Sim recording: name -> (joint, joint) of the evaluation joints / .trc markers
P2S_LIMBS = {
    f"{side}_{limb}": (f"{side}_{a}", f"{side}_{b}")
    for side in ("left", "right")
    for limb, (a, b) in {
        "upper_arm": ("shoulder", "elbow"),
        "forearm": ("elbow", "wrist"),
        "thigh": ("hip", "knee"),
        "shin": ("knee", "ankle"),
    }.items()
}


def pose2sim(
    work: pathlib.Path, frames: int, steps: int, downsample: int = 4, log=print
) -> tuple[list, dict]:
    """Calibrate from the first ``frames`` frames of the Pose2Sim demo (module docstring); rows
    ``(limb, reference median (m), start, fitted)``."""
    from scenes import P2S_DATA, P2S_TRC, pose2sim_project

    from jaxmocap.io.pose2sim import open_project, reference_joints

    project = pose2sim_project(work / "pose2sim_project", (0, 1, 2, 3))
    source = open_project(project)
    try:
        T = source.num_frames
        fb = FeatureBuilder(source, FEATURE_CUES, "auto", downsample, 256, list(range(T)))
        D = body.full25().num_dofs
        obs = [fb(source.read(t, masks=False, depth=False), D)[0].image for t in range(frames)]
        stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *obs)
        kp = np.asarray(source.keypoints[:frames])
        t0 = time.monotonic()
        fit = calibrate_from_start(stacked, fb.rig, kp, keypoint_rig=source.rig, steps=steps)
        wall = time.monotonic() - t0
        idx = [int(f) for f in list(getattr(source, "frame_numbers", range(T)))[:frames]]
    finally:
        source.close()
    ref, _, _ = reference_joints(P2S_DATA / P2S_TRC)
    ref = ref[idx]
    j = {n: i for i, n in enumerate(body.EVAL_JOINTS)}
    got = shape.limb_lengths(body.full25(fit.dims))
    start = shape.limb_lengths(body.full25(fit.start_dims))
    rows = []
    for name, (a, b) in P2S_LIMBS.items():
        r = float(np.median(np.linalg.norm(ref[:, j[a]] - ref[:, j[b]], axis=-1)))
        rows.append((name, r, start[name], got[name]))
    info = {"wall_s": wall, "frames_used": len(fit.frames), "foreground": fb.foreground,
            "downsample": downsample, "dims": fit.dims, "start_dims": fit.start_dims}  # fmt: skip
    log(f"pose2sim: {wall:.1f} s, frames used {len(fit.frames)}")
    for r in rows:
        log(f"  {r[0]:>16}: reference {1000 * r[1]:.1f} mm start {1000 * r[2]:.1f} fitted {1000 * r[3]:.1f}")
    return rows, info


#: what regenerates the results file (its first line: the runner's entry, ``benchmarks/run.py``)
COMMAND = (
    "JAX_PLATFORMS=cpu python benchmarks/experiments/shape_calibration.py --rigs ring4 stereo "
    "--work /tmp/shape_calibration"
)


def report(synth_results: dict, p2s, args, load: float) -> str:
    """The results file's markdown."""
    lines = [
        f"<!-- Regenerate: {COMMAND} -->",
        "# Body-shape calibration from the first frames, poses unknown",
        "",
        f"`jaxmocap.fit.shape_start.calibrate_from_start` (its defaults, {args.steps} Adam steps) on the first "
        f"{args.frames} frames; scene and input: the docstring of `benchmarks/experiments/shape_calibration.py`. "
        f"Run {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, load average {load:.1f} at the start.",
        "",
    ]
    for rig, (rows, info) in synth_results.items():
        ok = [r for r in rows if abs(r[5]) <= 0.05]
        lines += [
            f"## Synthetic subject, {rig}, {args.size}",
            "",
            f"Foreground: `{info['foreground']}`; frames with a pose from the detections: {info['frames_used']}; "
            f"fit {info['wall_s']:.0f} s; objective {info['objective'][0]:.3f} → {info['objective'][1]:.3f}. "
            f"Within 5 %: {len(ok)} of {len(rows)}.",
            "",
            "| dimension | true (m) | start (m) | fitted (m) | start error | fitted error | within 5 % |",
            "|---|---|---|---|---|---|---|",
        ]
        for n, t, s0, f, e0, e in rows:
            mm = f" ({1000 * (f - t):+.1f} mm)" if n.endswith("_drop") else ""
            lines.append(
                f"| {n} | {t:.4f} | {s0:.4f} | {f:.4f} | {100 * e0:+.1f} % | {100 * e:+.1f} %{mm} | "
                f"{'yes' if abs(e) <= 0.05 else 'no'} |"
            )
        lines.append("")
    if p2s is not None:
        rows, info = p2s
        lines += [
            "## Pose2Sim demo (real), first frames",
            "",
            f"4 cameras, images down-sampled by {info['downsample']}, foreground `{info['foreground']}`, the shipped "
            f"BODY_25B detections; frames with a pose: {info['frames_used']}; fit {info['wall_s']:.0f} s. Reference: "
            "the median over the same frames of the distance between Pose2Sim's triangulated `.trc` markers.",
            "",
            "| limb | reference (mm) | start (mm) | fitted (mm) | fitted − reference (mm) |",
            "|---|---|---|---|---|",
        ]
        for n, r, s0, f in rows:
            lines.append(
                f"| {n} | {1000 * r:.1f} | {1000 * s0:.1f} | {1000 * f:.1f} | {1000 * (f - r):+.1f} |"
            )
        lines.append("")
    lines += ["## Tracking with it (`jaxmocap track --body calibrate`)", "", TRACKING, ""]
    lines += ["## How the objective was chosen", "", DESIGN, "", "## Reading", "", READING, ""]
    return "\n".join(lines)


#: how the objective and its weights were chosen: the ring4 subject above, 300 steps (200 for the first row), each
#: row one run of ``--no-pose2sim --set NAME=VALUE …`` on the code of that step (2026-11-25)
DESIGN = """| silhouette term | w_k | w_e | radii: fitted errors | limbs: fitted errors |
|---|---|---|---|---|
| area coverage (distance to flesh points) + flesh points' distance to the foreground; thorax keypoint and measured torso used (200 steps) | 8 | 1 | −32 … +1 % (9 of 10 thinner) | −5.5 … +6.0 % |
| one-sided outline distances (½ px dead zone on both sides; 200 steps) | 8 | 1 | −28 … +22 % | −5.8 … +6.6 % |
| the same | 2 | 1 | −16 … +11 % | −6.1 … +5.6 % |
| the same | 0.5 | 1 | −16 … +4 % | −5.8 … +3.9 % |
| the same | 0.5 | 0 | −7.5 … +6.2 % | −5.1 … +2.7 % |
| two-sided outline distance to capsules (rounded ends) | 0.5 | 0 | −13.7 … +2.6 % | −5.8 … +0.9 % |
| two-sided outline distance to flat-ended cones | 0.5 | 0 | −4.6 … +2.8 % | −2.2 … +3.5 % |
| the same | 0.25 | 0 | −2.9 … +3.0 % | −0.3 … +3.5 % |

The last two rows are without leaving out the outline past the wrists and ankles (the default now, for real
people's hands and feet: on the Pose2Sim recording the fit without it stretched the forearms to 456 mm and the
shins to 534 mm, against 242–258 and 364–390 mm from the reference). At `w_k = 8` the objective of the fit (−11.9) beat that of the true dimensions and poses (−14.2): the poses and
lengths fitted the detection noise at the silhouettes' expense. The image edges (`w_e`) pulled the arm radii off.
The rounded capsule ends let a limb end short of its flat-capped silhouette (forearm −6 %).
Leaving the shoulder drop, hip drop and neck length at the preset's (`names` without them, all else the default; one run,
2026-11-25 18:03 UTC): torso length −0.5 % (from +5.6 %), the three left 9-11 % (3-8 mm) off, but the upper arm's
length +7.5 % and its top radius −9.5 %: 13 of 20 within 5 % against 14; the default fits all 20."""

#: what the tables show (written for the run of 2026-11-25 17:54 UTC; the fit is deterministic, a rerun gives the
#: same numbers)
#: ``jaxmocap track --body calibrate`` against the other sources of the dimensions (measured separately, with
#: ``accuracy_default.py``; the text is kept in the results file)
TRACKING = """`python benchmarks/experiments/accuracy_default.py --rigs ring4 --clips walk --seeds 1 --work /tmp/shape_acc
--set body=…` (the CMU walk dressed as the synthesiser dresses it, 60 frames, plates and simulated detections; one
seed, one clip, load average 8-9; 2026-11-25 18:05-18:09 UTC): mean error over the 15 joints 53.4 mm with the
dimensions measured from the detections (`body=detections`), 49.2 mm with `body=calibrate` (the detections'
torso column, the limbs, widths and radii fitted to the first 10 frames), 41.9 mm with the sequence's own body file
(the dressed skeleton's measured dimensions, the default when the folder has one). One seed and one clip: not
enough to change the default, which stays as it was."""

READING = (
    "Four cameras: every radius holds (within 4.6 %, from 9-11 % at the start; the worst the upper arm's top, "
    "inside the torso's silhouette in a walk), and so do the shoulder width and the upper-arm, thigh and shin "
    "lengths (within 3.4 %): 14 of the 20 dimensions. Not holding: the forearm (-5.3 %: its start, the "
    "triangulated detections, was -4.6 %, and the outline past the wrists is left out, so the detections decide "
    "it), the hip width (-6.5 %), and the torso column: torso length +5.6 %, shoulder drop +24 mm, hip drop "
    "-14 mm, neck -23 mm. These four trade against each other: where the torso's flat ends lie (between the "
    "thighs, under the head and shoulders) the silhouette does not show, and the detector's neck keypoint is not "
    "the model's thorax; the joints they place (shoulders, head centre) come within about a centimetre. Two "
    "cameras 0.3 m apart: the triangulated lengths were 10-180 % off and were replaced by the preset's where "
    "outside 0.8-1.25x of it; 6 of the 20 dimensions hold (radii up to -80 %: the shin's bottom collapsed), so a stereo "
    "pair does not calibrate the body this way. Pose2Sim (real): the fitted limbs are within 1-26 mm of the "
    "reference (mean 13.9 mm over the eight limbs) against 0.5-40 mm (mean 12.6 mm) for the lengths measured from "
    "the detections alone: the fit does not improve the lengths of this real subject; its dimensions are the same "
    "on both sides, while the reference's sides differ by 7-27 mm."
)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", type=pathlib.Path, default=None)
    ap.add_argument("--rigs", nargs="+", default=["ring4"])
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--no-pose2sim", action="store_true")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument(
        "--set", nargs="*", default=[], help="NAME=VALUE options of calibrate_from_start (experiments)"
    )
    args = ap.parse_args(argv)
    if args.quick:
        args.size, args.frames, args.steps, args.no_pose2sim = "160x120", 4, 40, True
    size = synth.parse_size(args.size)
    work = args.work or pathlib.Path(tempfile.mkdtemp(prefix="shape_calibration_"))
    load = os.getloadavg()[0]
    opts = {k: float(v) for k, v in (a.split("=", 1) for a in args.set)}
    results = {rig: synthetic(work, rig, size, args.frames, args.steps, **opts) for rig in args.rigs}
    p2s = None if args.no_pose2sim else pose2sim(work, args.frames, args.steps)
    if not (args.quick or opts):
        RESULTS.write_text(report(results, p2s, args, load))
        print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
