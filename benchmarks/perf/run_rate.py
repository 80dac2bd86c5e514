"""Whole-run frames per second of a long ``jaxmocap track`` against its step rate: what writing the outputs costs.

A stereo sequence of the bundled CMU walk (30 fps, 86 frames at ``--size``) is played forwards and backwards
(:class:`scenes.PingPong`) into ``--frames`` frames and tracked (``full25``, APF ``--particles`` × ``--layers``,
default cues, ground-truth start, the sequence's masks), alternately with every output on and with the outputs
off (a tracker whose per-frame writes do nothing), ``--repeats`` times each, in one process (the compiled step
reloaded from the persistent cache). Rates over the same frames, the first frame (which compiles) left out:

* **step rate** — what the progress bar and the summary report: frames per second of the per-frame work alone
  (reading and the features of the next frame, the filter step, track-loss bookkeeping), from the ``seconds`` of
  every frame's diagnostics record, which stop before the frame's outputs are handed on;
* **whole-run rate** — frames per second of the wall clock from the first frame's outputs to the return of
  ``Tracker.run()``: every output included (per frame: the pose journal, the CSV line, the diagnostics line, the
  resume checkpoint; from time to time: the rewrites of ``poses.npz`` and ``diagnostics.json``; at the end:
  ``poses.npz``, ``track.bvh``, ``diagnostics.json``, ``run.json``);
* **whole-run rate without outputs** — the same, outputs off: the baseline that the cost of the outputs is
  measured against without trusting the step rate (which the output thread could slow down).

The target is a whole-run rate within 5 % of the step rate. Also reported: the median time of a frame's outputs
(in the output thread) and of the outputs at the end, and the sizes of the files written. The machine is shared:
the table gives each run, and the load average.

    python benchmarks/perf/run_rate.py [--frames 3000] [--size 160x120] [--particles 100] [--layers 3] [--repeats 2] [--out benchmarks/results/run_rate.md]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common
import numpy as np
import scenes

from jaxmocap import compilation_cache
from jaxmocap.io.sources import SequenceSource
from jaxmocap.synth import generate as synth
from jaxmocap.tracking import tracker
from jaxmocap.tracking.options import TrackOptions


class TimedTracker(tracker.Tracker):
    """A :class:`~jaxmocap.tracking.tracker.Tracker` that notes when each frame's outputs are written and how long
    that takes, and how long the outputs of the way out take; with ``write=False`` its per-frame writes do
    nothing (nor its outputs at the end: no frame to write)."""

    def __init__(self, *args, write: bool = True, **kwargs):
        super().__init__(*args, **kwargs)
        self.write = write
        self.written: list[float] = []
        self.seconds: list[float] = []
        self.frame_output_s: list[float] = []
        self.final_s = None

    def _write_frame(self, pose_writer, diag, t, x, joints, record):
        t0 = time.monotonic()
        self.seconds.append(record["seconds"])
        if self.write:
            super()._write_frame(pose_writer, diag, t, x, joints, record)
        self.written.append(time.monotonic())
        self.frame_output_s.append(self.written[-1] - t0)

    def _write_outputs(self, *args, **kwargs):
        t0 = time.monotonic()
        out = super()._write_outputs(*args, **kwargs)
        self.final_s = time.monotonic() - t0
        return out


def one_run(seq: pathlib.Path, out: pathlib.Path, frames: int, opts: TrackOptions, write: bool) -> dict:
    source = scenes.PingPong(SequenceSource(seq), frames)
    try:
        run = TimedTracker(source, out, opts, quiet=True, write=write)
        summary = run.run()
        end = time.monotonic()
    finally:
        source.close()
    n = len(run.written)
    return {
        "write": write,
        "frames": n,
        "step_fps": (n - 1) / sum(run.seconds[1:]),  # as DiagnosticsWriter.frames_per_s
        "whole_fps": (n - 1) / (end - run.written[0]),
        "frame_output_ms": 1e3 * float(np.median(run.frame_output_s[1:])),
        "final_s": run.final_s,
        "sizes": {p.name: p.stat().st_size for p in sorted(out.iterdir()) if p.is_file()},
        "error_mm": summary.get("mean_error_mm"),
    }


def measure(frames: int, size: str, particles: int, layers: int, repeats: int = 2, log=print) -> list[dict]:
    compilation_cache.enable()  # each run's step is compiled once, then reloaded
    opts = TrackOptions(
        model="full25",
        particles=particles,
        layers=layers,
        init="groundtruth",
        foreground="mask",
        overwrite=True,
    )
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        seq = tmp / "seq"
        synth.synthesize("demo", seq, rig="stereo", size=size, seed=0, overwrite=True)
        for k in range(repeats):
            for write in (False, True):
                r = one_run(seq, tmp / f"run{k}{'w' if write else 'n'}", frames, opts, write)
                log(
                    f"outputs {'on' if write else 'off'}: {r['frames']} frames, step {r['step_fps']:.2f} frames/s, "
                    f"whole run {r['whole_fps']:.2f} frames/s"
                )
                runs.append(r)
    return runs


def to_markdown(runs: list[dict], size: str, particles: int, layers: int) -> str:
    on = [r for r in runs if r["write"]]
    off = [r for r in runs if not r["write"]]
    step = float(np.median([r["step_fps"] for r in on]))
    whole = float(np.median([r["whole_fps"] for r in on]))
    base = float(np.median([r["whole_fps"] for r in off]))
    rows = [
        f"| {k // 2 + 1} | {'on' if r['write'] else 'off'} | {r['step_fps']:.2f} | {r['whole_fps']:.2f} | "
        f"{r['whole_fps'] / r['step_fps']:.3f} | {r['frame_output_ms']:.2f} | "
        f"{r['final_s']:.2f} |"
        for k, r in enumerate(runs)
    ]
    files = ", ".join(f"{k} {v / 1e6:.2f} MB" for k, v in on[-1]["sizes"].items())
    ratio = whole / step
    return "\n".join(
        [
            f"# Whole-run rate against the step rate over {on[0]['frames']} frames",
            "",
            f"The bundled CMU walk at {size} played forwards and backwards into {on[0]['frames']} frames, `full25`, "
            f"APF {particles} × {layers}, default cues (mean joint error {on[-1]['error_mm']:.1f} mm); runs with "
            "every output on and off, alternately.",
            "",
            "| pair | outputs | step rate (frames/s) | whole-run rate (frames/s) | whole / step | a frame's outputs "
            "(median ms, output thread) | outputs at the end (s) |",
            "|---|---|---|---|---|---|---|",
            *rows,
            "",
            f"Medians with the outputs on: step rate {step:.2f} frames/s, whole-run rate {whole:.2f} frames/s, "
            f"**{ratio:.3f}** of the step rate — target (within 5 %) **{'met' if ratio >= 0.95 else 'NOT met'}**; "
            f"against the whole-run rate with the outputs off ({base:.2f} frames/s): {whole / base:.3f}.",
            "",
            f"Files written: {files}.",
            "",
            f"Machine: {common.machine_line()}; {common.stamp()}.",
            "",
        ]
    )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--layers", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=2, help="pairs of runs (outputs off, on)")
    ap.add_argument("--out", default=str(common.RESULTS / "run_rate.md"))
    a = ap.parse_args(argv)
    runs = measure(a.frames, a.size, a.particles, a.layers, a.repeats)
    md = to_markdown(runs, a.size, a.particles, a.layers)
    print(md)
    command = (
        f"python {common.script(__file__)} --frames {a.frames} --size {a.size} --particles {a.particles} "
        f"--layers {a.layers} --repeats {a.repeats}"
    )
    common.write_result(pathlib.Path(a.out), md, command)


if __name__ == "__main__":
    main()
