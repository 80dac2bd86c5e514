"""Does smoothing the exported track lower its error? Butterworth cut-offs against none, on synthetic sequences of
real CMU motion capture.

Scenario (all choices stated here):

* clips: the bundled CMU walk (subject 2, trial 1, source frames 150:390), the CMU Charleston dance (150:390) and
  the CMU hops (131_03, source frames 420:660; the two from ``../shared/data/mocap/cmu``): 240 source frames at
  120 fps → 60 frames at 30 fps, rendered by :func:`jaxmocap.synth.generate.synthesize` with the ``stereo`` preset
  at 320×240 (photo background, sensor noise 0.01, virtual depth with 2 cm noise);
* the tracker as ``jaxmocap track`` runs it by default (full25, APF 300 particles × 5 layers, the default cues
  with depth, and the 2D keypoints cue when the input has detections), seeds ``0..--seeds-1``, on the input a real
  setup records (``benchmarks/scenes.py``,
  :class:`PlateSource`: silhouettes subtracted against the plates, the first pose from the simulated 2D
  detections); with ``--oracle`` on the rendered masks, initialised from the ground truth of the first frame;
* every run's raw estimates are exported by :func:`jaxmocap.tracking.outputs.export_track` (the code a run ends
  with: gap filling, zero-phase Butterworth of order 4 on the states, float64 kinematics) with each ``--smooth``
  value, and the exported joints compared with the ground truth (mean over frames and the 15 evaluation joints of
  the Euclidean distance, mm, :func:`jaxmocap.eval.metrics.evaluate`).

The table gives the mean ± std over seeds per clip and the mean over the clips; the last column is the change
against ``none``. The default cut-off of ``--smooth butterworth`` (:data:`jaxmocap.tracking.smoothing
.DEFAULT_CUTOFF_HZ`) was chosen from it (README, "Smoothing").

    .venv/bin/python benchmarks/experiments/smoothing.py [--seeds 3] [--quick] [--oracle]

Writes ``benchmarks/results/smoothing.md`` (not with ``--quick``).
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import common
from scenes import SHARED_CMU, CachedTracker, open_source

from jaxmocap.eval import metrics
from jaxmocap.eval.plots import read_records
from jaxmocap.synth import generate as synth
from jaxmocap.tracking import outputs
from jaxmocap.tracking.options import TrackOptions

RESULTS = common.RESULTS / "smoothing.md"
CUTOFFS = (1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 6.0, 8.0, 10.0)
#: (name, motion, asf, source frames)
CLIPS = (
    ("walk 02_01", "demo", None, "150:390"),
    ("charleston", SHARED_CMU / "charleston1.amc", SHARED_CMU / "charleston.asf", "150:390"),
    ("hops 131_03", SHARED_CMU / "131_03.bvh", None, "420:660"),
)


def track_and_export(
    seq: pathlib.Path, seeds: int, work: pathlib.Path, specs, log, oracle: bool = False
) -> dict[str, list[float]]:
    """Per ``--smooth`` value, the exported track's error (mm) of every seed on one sequence (``oracle``: rendered
    masks, ground-truth initialisation and body)."""
    source = open_source(seq, oracle)
    gt_frames, gt = metrics.load_groundtruth(seq)
    errors: dict[str, list[float]] = {s: [] for s in specs}
    options = (
        TrackOptions(init="groundtruth", overwrite=True)
        if oracle
        else TrackOptions(init="ik", foreground="mask", overwrite=True)
    )
    try:
        run = CachedTracker(source, work / "track", options, quiet=True)
        for s in range(seeds):
            run.o.seed = s
            t0 = time.monotonic()
            run.run()
            poses = np.load(work / "track" / "poses.npz")
            diag = read_records(work / "track")
            for spec in specs:
                summary = outputs.export_track(
                    work / "track", run.model, run.frames, poses["frame_index"], poses["state"], diag,
                    source.fps, smooth=spec, plots=False, groundtruth=gt,
                )  # fmt: skip
                errors[spec].append(summary["mean_error_smoothed_mm"])
            lost = sum(bool(r.get("lost")) for r in diag)
            log(
                f"  seed {s}: {time.monotonic() - t0:.0f} s, {lost} lost frame(s), none {errors['none'][-1]:.1f} mm"
            )
    finally:
        source.close()
    return errors


def main(argv=None) -> str:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="one clip, 8 frames, one seed; writes nothing")
    ap.add_argument(
        "--oracle",
        action="store_true",
        help="rendered masks and ground-truth initialisation (default: plates)",
    )
    args = ap.parse_args(argv)
    specs = ["none"] + [f"butterworth:{c:g}" for c in CUTOFFS]
    clips = CLIPS[:1] if args.quick else CLIPS
    seeds = 1 if args.quick else args.seeds
    per_clip = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = pathlib.Path(tmp)
        for name, motion, asf, frames in clips:
            seq = work / name.replace(" ", "_")
            t0 = time.monotonic()
            synth.synthesize(
                motion, seq, rig="stereo", asf=asf, frames="150:182" if args.quick else frames,
                size="160x120" if args.quick else "320x240", seed=0, overwrite=True,
            )  # fmt: skip
            print(f"{name}: synthesised in {time.monotonic() - t0:.0f} s", flush=True)
            per_clip[name] = track_and_export(seq, seeds, work / f"{seq.name}_run", specs, print, args.oracle)
    lines = [
        f"Exported-track error (mm, mean ± std over {seeds} seed(s)) of full25 / APF 300 × 5 tracks of 60-frame "
        "synthetic stereo sequences (320×240, 30 fps) of real CMU motion capture, by `--smooth`; input: "
        + (
            "rendered masks, initialised from the ground truth (oracle)."
            if args.oracle
            else "silhouettes subtracted against the plates, initialised from the simulated detections."
        ),
        "",
        "| `--smooth` | " + " | ".join(per_clip) + " | mean | change |",
        "|---|" + "---|" * (len(per_clip) + 2),
    ]
    means = {s: float(np.mean([np.mean(e[s]) for e in per_clip.values()])) for s in specs}
    for s in specs:
        cells = [f"{np.mean(e[s]):.1f} ± {np.std(e[s]):.1f}" for e in per_clip.values()]
        change = means[s] - means["none"]
        lines.append(f"| `{s}` | " + " | ".join(cells) + f" | {means[s]:.1f} | {change:+.1f} |")
    best = min(specs, key=means.get)
    lines += ["", f"Lowest mean: `{best}` ({means[best] - means['none']:+.1f} mm against `none`)."]
    return common.report(
        RESULTS,
        "\n".join(lines),
        f"python {common.script(__file__)} --seeds {seeds}" + (" --oracle" if args.oracle else ""),
        write=not args.quick,
    )


if __name__ == "__main__":
    main()
