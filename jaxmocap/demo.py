"""``jaxmocap demo``: the main job of the README on the bundled real motion — a synthetic stereo sequence of the CMU
walk 02_01, tracked, evaluated against its ground truth, with an overlay frame and the table the README shows."""

from __future__ import annotations

import pathlib

from jaxmocap.errors import silence_opencv

DEMO_FRAMES = "0:240"
DEMO_SIZE = "320x240"


def run(args) -> int:
    """``jaxmocap demo``: synthesise the stereo walk, track it, evaluate it, draw one overlay frame (README)."""
    import shutil
    import time

    import cv2
    import numpy as np

    from jaxmocap.eval import metrics, viz
    from jaxmocap.filters.factory import particles_text
    from jaxmocap.io.sources import SequenceSource
    from jaxmocap.synth import generate as synth
    from jaxmocap.tracking import tracker
    from jaxmocap.tracking.options import TrackOptions, cues_text

    silence_opencv()
    t0 = time.monotonic()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    seq_dir, track_dir = out / "sequence", out / "track"
    print(f"motion: {synth.demo_clip()[0].name} (CMU subject 2, trial 1: a walk). {synth.CMU_LICENCE}")
    print(f"1/4 synthesising a stereo sequence ({args.size}) of source frames {args.frames} ...", flush=True)
    seq = synth.synthesize(
        "demo", seq_dir, rig="stereo", frames=args.frames, size=args.size, seed=args.seed, overwrite=True
    )
    t1 = time.monotonic()
    print(f"    {seq.num_frames} frames x {len(seq.views)} views in {t1 - t0:.1f} s", flush=True)
    print(f"2/4 tracking with {args.filter} ...", flush=True)
    options = TrackOptions(
        filter=args.filter,
        particles=args.particles,
        layers=args.layers,
        seed=args.seed,
        init="ik",
        overlay=True,
        overwrite=True,
    )
    # read as a recording: images, calibration, plates and the simulated detections; the rendered masks and the
    # ground truth stay out of the run (they score it afterwards)
    source = SequenceSource(seq_dir, recording=True)
    if track_dir.exists():
        shutil.rmtree(track_dir)
    run = tracker.Tracker(source, track_dir, options, quiet=args.quiet)
    summary = run.run()
    t2 = time.monotonic()
    print("3/4 evaluating ...", flush=True)
    report = metrics.evaluate_folders([track_dir], seq_dir, out / "eval.json")
    print("4/4 overlay frame ...", flush=True)
    mid = len(run.frames) // 2
    poses = metrics.load_prediction(track_dir)
    state = dict(zip(poses[0].tolist(), np.load(track_dir / "poses.npz")["state"], strict=True))[
        run.frames[mid]
    ]
    fd = source.read(run.frames[mid], masks=False)
    truth = seq.groundtruth.joints[run.frames[mid]]
    views = viz.overlay_image(fd.images, run.model, source.rig.to_jax(), state, truth)
    crops = viz.person_crops(views, source.rig.to_jax(), truth)  # the subject, enlarged, in both views
    cv2.imwrite(
        str(out / "demo_overlay.png"), np.concatenate(crops, axis=1), [cv2.IMWRITE_PNG_COMPRESSION, 9]
    )
    total = time.monotonic() - t0
    cues = cues_text(summary["cues"])
    head = [
        "jaxmocap demo: CMU 02_01 (walk), synthetic stereo, " + f"{seq.num_frames} frames at {args.size}",
        f"model {summary['model']}, filter {summary['filter']}, {particles_text(summary['particles'])} particles x "
        f"{summary['layers']} layers, cues {cues}",
        "input as recorded: images, plates, depth maps, simulated detections (no masks, no ground truth); start by "
        "IK; "
        + (
            f"estimate refined on the detections ({summary['refine']}, prior {summary['refine_prior']:g}"
            + (f", depth maps at σ_d {summary['refine_depth']:g} m)" if summary.get("refine_depth") else ")")
            if summary.get("refine", "none") != "none"
            else "estimate not refined"
        ),
        f"tracking {t2 - t1:.1f} s ({summary['frames_per_s']:.2f} frames/s after the first frame), total {total:.1f} s",
        "",
    ]
    table = "\n".join(head) + metrics.format_table(report)
    (out / "demo_table.txt").write_text(table + "\n")
    print()
    print(table)
    print()
    print(
        f"wrote {out / 'demo_table.txt'}, {out / 'demo_overlay.png'}, {out / 'eval.json'} (+ plots), {track_dir}/ (poses, BVH, overlay videos)"
    )
    return 0
