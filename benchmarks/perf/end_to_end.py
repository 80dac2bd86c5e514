"""Frames per second end to end (image features + filtering) in the configurations of the three works.

A 640×480 two-view sequence of the bundled CMU walk (subject 2, trial 1, source frames ``150:…`` at 30 fps, the
``stereo`` preset, photo background, noise 0.01, virtual depth) is rendered by :func:`jaxmocap.synth.generate.synthesize`
and tracked by :class:`jaxmocap.tracking.tracker.Tracker` exactly as ``jaxmocap track`` does (foreground by static
background subtraction against the median of the sequence, edges / distance transform, silhouette samples; one
compiled filter step per frame; poses and diagnostics written), initialised from the ground truth:

* **IROS 2007** (Fontmarty et al.): ``upper14``, IAPF, 3 layers, 200 particles per layer (600 likelihood evaluations
  per frame, the budget of their Fig. 3–4 comparison); cues foreground, edge distance, coverage;
* **Li & Kulić**: ``full25``, partitioned sampling, their 1000 + 200 + 500 + 200 + 500 + 200 = 2600 likelihood
  evaluations per frame (torso, head, upper arms, forearms, thighs, calves) mapped onto this tracker's six
  partitions of ``full25`` (torso, head, each whole arm, each whole leg) as 1000 / 200 / 350 / 350 / 350 / 350;
  cues foreground, coverage, ``edge_fraction`` (their eq. 2), ``depth`` (eq. 1);
* **the thesis** (López Méndez): ``upper9``, FBAPF, 200 particles × 3 layers, 2 views; default cues;
* a variant of the IROS 2007 configuration whose image features are computed at 320×240 (the tracker's
  ``--downsample 2``: the frames are still read and tracked at 640×480 calibration, the foreground / edge maps and
  the silhouette samples are half-size).

Reported: frames/s after the first frame of the plain tracker (its own ``frames_per_s``: wall time per frame,
including reading the PNGs, features, the step, writing poses; the tracker prepares frame ``t + 1`` on the host
while the compiled step of frame ``t`` runs), the same for a profiled run that waits for each step (features and
step serialised: a lower bound), and that run's profile split per frame: feature preprocessing (reading +
:class:`~jaxmocap.tracking.FeatureBuilder`), the compiled filter step, and within the step the likelihood (the
compiled likelihood timed alone on batches of the step's sizes) vs the rest (resampling, diffusion, β search,
estimates).
CPU ms/frame: process CPU time (all threads) of features + step, median over frames: on a shared machine the
wall-clock rate is depressed by other jobs, and ``1000 / CPU ms`` is what one otherwise idle core would sustain.
The quick mode (smoke test) reads the rendered masks as the foreground instead of subtracting a background.

    .venv/bin/python benchmarks/perf/end_to_end.py [--frames 20] [--quick]
"""

from __future__ import annotations

import argparse
import collections
import os
import pathlib
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from jaxmocap.filters.factory import particles_text  # noqa: E402
from jaxmocap.io.sources import SequenceSource  # noqa: E402
from jaxmocap.synth import generate as synth
from jaxmocap.tracking import tracker  # noqa: E402
from jaxmocap.tracking.options import TrackOptions  # noqa: E402

#: (label, model, filter, particles per layer / partition, layers, cues, likelihood evaluations per frame, target)
CONFIGS = (
    ("IROS 2007", "upper14", "iapf", 200, 3, "foreground,edge_distance,coverage:4", 600, 30.0),
    (
        "Li & Kulić",
        "full25",
        "partitioned",
        (1000, 200, 350, 350, 350, 350),
        1,
        "foreground,coverage:4,edge_fraction,depth",
        2600,
        10.0,
    ),
    ("thesis", "upper9", "fbapf", 200, 3, "foreground,edge_distance,coverage:4", 600, None),
)
#: (label, down-sampling factor of the image features) of the variants run besides the configurations above
VARIANTS = (("IROS 2007, features at 320×240", 2),)


class ProfiledTracker(tracker.Tracker):
    """A :class:`~jaxmocap.tracking.tracker.Tracker` that times its feature preprocessing and its compiled step."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.feature_s: list[float] = []
        self.step_s: list[float] = []
        self.feature_cpu: list[float] = []
        self.step_cpu: list[float] = []
        self.last_obs = None

    def _observe(self, t):
        t0, c0 = time.perf_counter(), time.process_time()
        out = super()._observe(t)
        self.feature_s.append(time.perf_counter() - t0)
        self.feature_cpu.append(time.process_time() - c0)
        if out[0] is not None:
            self.last_obs = out[0]
        return out

    def _make_filter(self, x0):
        super()._make_filter(x0)
        inner = self._step

        def timed(filt, key, state, tobs):
            t0, c0 = time.perf_counter(), time.process_time()
            out = inner(filt, key, state, tobs)
            out[0].particles.block_until_ready()
            self.step_s.append(time.perf_counter() - t0)
            self.step_cpu.append(time.process_time() - c0)
            return out

        self._step = timed


def likelihood_seconds(run: ProfiledTracker, batches, repeats: int = 5) -> float:
    """Time of the compiled likelihood on the step's batches (``batches``: particles per layer or partition, one
    entry per likelihood call of a frame): the sum over batches of the median time of each size."""
    x0 = np.asarray(run.model.rest_pose, np.float32)
    f = jax.jit(lambda X, o: run.loglik(X, o, 0))
    obs = run.last_obs
    total = 0.0
    for n, calls in sorted(collections.Counter(batches).items()):
        X = jnp.asarray(x0 + np.random.default_rng(0).normal(0, 0.02, (n, x0.size)).astype(np.float32))
        total += common.median_seconds(lambda X=X: f(X, obs).block_until_ready(), repeats, warmup=1) * calls
    return total


def run(quick: bool = False, frames: int = 20, log=print) -> list[dict]:
    rows = []
    n_frames = 3 if quick else frames
    size = "160x120" if quick else "640x480"
    with tempfile.TemporaryDirectory() as tmp:
        seq_dir = pathlib.Path(tmp) / "seq"
        a = 150
        synth.synthesize("demo", seq_dir, rig="stereo", frames=f"{a}:{a + 4 * n_frames}", size=size, seed=0)
        runs = [(*c, 1) for c in CONFIGS]
        runs += [(v, *CONFIGS[0][1:], ds) for v, ds in VARIANTS]
        # the quick smoke test runs the first configuration only: the others take the same code path
        for label, model, flt, n, L, cues, evals, target, ds in runs[:1] if quick else runs:
            if quick:
                n = tuple(max(c // 20, 4) for c in n) if isinstance(n, tuple) else max(n // 20, 4)
                evals = sum(n) if isinstance(n, tuple) else max(evals // 20, 4)
            source = SequenceSource(seq_dir)
            try:
                fg = "mask" if quick else "median"
                opts = TrackOptions(
                    model=model,
                    filter=flt,
                    particles=n,
                    layers=L,
                    cues=cues,
                    init="groundtruth",
                    foreground=fg,
                    downsample=ds,
                    overwrite=True,
                )
                # the plain tracker's rate (left out of the quick smoke test: one compilation fewer)
                plain = (
                    None
                    if quick
                    else tracker.Tracker(source, pathlib.Path(tmp) / "plain", opts, quiet=True).run()
                )
                tr = ProfiledTracker(source, pathlib.Path(tmp) / "track", opts, quiet=True)
                t0 = time.perf_counter()
                summary = tr.run()
                wall = time.perf_counter() - t0
                batches = list(n) if isinstance(n, tuple) else [n] * L
                lik_s = likelihood_seconds(tr, batches, repeats=1 if quick else 5)
            finally:
                source.close()
            feat = float(np.median(tr.feature_s[1:])) if len(tr.feature_s) > 1 else float(tr.feature_s[0])
            step = float(np.median(tr.step_s[1:])) if len(tr.step_s) > 1 else float(tr.step_s[0])
            fps = (plain or summary)["frames_per_s"] or float("nan")
            fps_serial = summary["frames_per_s"] or float("nan")
            cpu = float(np.median(tr.feature_cpu[1:] or tr.feature_cpu)) + float(
                np.median(tr.step_cpu[1:] or tr.step_cpu)
            )
            rows.append(
                dict(
                    label=label,
                    model=model,
                    filter=flt,
                    particles=n,
                    layers=L,
                    evaluations=evals,
                    cues=cues,
                    fps=fps,
                    fps_serial=fps_serial,
                    cpu_ms=cpu * 1e3,
                    target=target,
                    feature_ms=feat * 1e3,
                    step_ms=step * 1e3,
                    likelihood_ms=lik_s * 1e3,
                    rest_ms=max(step - lik_s, 0.0) * 1e3,
                    wall_s=wall,
                    first_frame_s=summary["first_frame_s"],
                    frames=summary["frames_tracked"],
                    foreground=fg,
                )
            )
            log(
                f"{label}: {fps:.2f} frames/s, {fps_serial:.2f} serialised (features {feat * 1e3:.0f} ms, step {step * 1e3:.0f} ms, "
                f"likelihood {lik_s * 1e3:.0f} ms)"
            )
    return rows


def to_markdown(rows: list[dict], quick: bool = False) -> str:
    lines = [
        "| configuration | model | filter | particles × layers | likelihood evals/frame | frames/s | target | "
        "serialised frames/s | CPU ms/frame | foreground | features ms | step ms | of which likelihood ms | "
        "resampling + rest ms | bound by |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        tgt = f"≥ {r['target']:.0f}" if r["target"] else "–"
        met = "" if not r["target"] else (" ✓" if r["fps"] >= r["target"] else " ✗")
        parts = {
            "features": r["feature_ms"],
            "likelihood": r["likelihood_ms"],
            "resampling + rest": r["rest_ms"],
        }
        bound = max(parts, key=parts.get)
        share = parts[bound] / max(sum(parts.values()), 1e-9)
        lines.append(
            f"| {r['label']} | {r['model']} | {r['filter']} | {particles_text(r['particles'])} × {r['layers']} | {r['evaluations']} | "
            f"**{r['fps']:.2f}**{met} | {tgt} | {r['fps_serial']:.2f} | {r['cpu_ms']:.0f} | {r['foreground']} | "
            f"{r['feature_ms']:.1f} | {r['step_ms']:.1f} | {r['likelihood_ms']:.1f} | {r['rest_ms']:.1f} | "
            f"{bound} ({100 * share:.0f} %) |"
        )
    return "\n".join(lines)


def main(argv=None) -> str:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--quick", action="store_true", help="3 frames at 160×120, 1/20 of the particles")
    a = ap.parse_args(argv)
    md = to_markdown(run(a.quick, a.frames))
    print(md)
    return md


if __name__ == "__main__":
    main()
