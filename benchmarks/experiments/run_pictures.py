"""The pictures a tracking run leaves, for the README: ``plots/`` (trajectories, 3D skeleton, per-frame quality) and
the overlay montage.

Scenario: ``jaxmocap track`` with its defaults (full25, APF 300 × 5, default cues, ``--smooth butterworth``) and
``--overlay`` on the bundled CMU walk (subject 2, trial 1, source frames 0:240 → 60 frames at 30 fps) synthesised
for the ``stereo`` preset at 320×240, initialised from the ground truth; the run's ``plots/*.png`` and
``overlay_montage.png`` are copied to ``benchmarks/results/run_*.png``.

    .venv/bin/python benchmarks/experiments/run_pictures.py [--quick]

``--quick``: 8 frames at 160×120, 30 particles × 2 layers, nothing copied.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import shutil
import sys
import tempfile

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import common

from jaxmocap import cli

PICTURES = {
    "plots/trajectories.png": "run_trajectories.png",
    "plots/skeleton.png": "run_skeleton.png",
    "plots/quality.png": "run_quality.png",
    "overlay_montage.png": "run_overlay_montage.png",
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        seq, run = pathlib.Path(tmp) / "seq", pathlib.Path(tmp) / "run"
        frames, size = ("0:32", "160x120") if args.quick else ("0:240", "320x240")
        cli.main(["synth", "--motion", "demo", "--rig", "stereo", "--frames", frames, "--size", size, "--out",
                  str(seq), "--quiet"])  # fmt: skip
        extra = ["--particles", "30", "--layers", "2"] if args.quick else []
        code = cli.main(["track", str(seq), "--out", str(run), "--overlay", "--init", "groundtruth", *extra])
        if code != 0:
            return code
        for src, dst in PICTURES.items():
            if not (run / src).is_file():
                raise RuntimeError(f"the run left no {src}")
            if not args.quick:
                shutil.copyfile(run / src, common.RESULTS / dst)
                print(f"wrote {common.RESULTS / dst}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
