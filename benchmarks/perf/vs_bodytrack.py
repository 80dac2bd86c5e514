"""jaxmocap against PARSEC bodytrack built from source, side by side on the same machine, interleaved A/B.

bodytrack (PARSEC 3.0, unmodified C++, Apache-2.0) is built by this script from ``$BODYTRACK_SRC`` (default
``/work/shared/parsec/bodytrack``; its README and Makefile) into ``build/bodytrack/`` (git-ignored) with
``make -C $BODYTRACK_SRC OUT=$PWD/build/bodytrack``. Then, for ``--rounds`` rounds, each round in two conditions,

* **as found**: nothing added to whatever else runs on the machine;
* **+1 busy process**: a CPU-bound child process (``python -c "while True: pass"``) started by this script for the
  duration of the condition and killed after it,

it times, alternating which of the two goes first from round to round:

* **likelihood**: µs per particle of one evaluation of ``--particles`` states of frame 0 of sequenceB_2 around its
  initial pose: bodytrack's ``ll_bench`` (``TrackingModel::LogLikelihood`` particle by particle; median of its
  repeats) against :func:`jaxmocap.parsec.likelihood.jit_loglik_batch` (median of the same number of calls,
  compiled before the first round); also the process CPU time per particle of each side (all threads);
* **tracker**, per frame at 4000 × 5 and 1000 × 3: ``bodytrack-serial`` and ``bodytrack-pthreads`` (2 threads),
  each in its own A/B pair, on the two frames of sequenceB_2 (4 cameras, thread model 4 = serial or 2 =
  pthreads, no BMP output), its per-frame time the median interval between the "Processing
  frame i" lines it prints (flushed; the last frame ends when the process exits; each frame includes bodytrack's
  reading of the BMPs, its edge maps and the annealed filter step) against jaxmocap's PARSEC tracker
  (:func:`jaxmocap.parsec.annealing.parsec_apf` + the PARSEC likelihood, as ``benchmarks/experiments/parsec_track.py``
  runs it, seed 0): per frame the host edge/foreground maps plus the compiled filter step (all layers), median over
  the frames; compiled before the first round.

Each round records the 1-minute load average when it starts (``os.getloadavg``); a condition is labelled *idle*
only when that load is below 1.0, otherwise *loaded* with the load. The ratio is bodytrack's time over jaxmocap's
(above 1: jaxmocap faster); the report gives it per round and its median per condition.

    python benchmarks/perf/vs_bodytrack.py [--rounds 5] [--particles 4000] [--out benchmarks/results/vs_bodytrack.md]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import bodytrack as bt
import common

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxmocap import host, parsec  # noqa: E402
from jaxmocap.parsec import likelihood as pl  # noqa: E402

TRACKER_CONFIGS = ((4000, 5), (1000, 3))


class Jaxmocap:
    """The jaxmocap side, compiled once: the likelihood of ``particles`` states of frame 0 and the PARSEC tracker
    at each configuration of :data:`TRACKER_CONFIGS`."""

    def __init__(self, particles: int):
        self.seq = parsec.load_sequence(bt.SEQ)
        seq = self.seq
        self.obs0 = seq.observation(0)
        x0, std = seq.initial_pose, seq.pose_std
        X = (x0 + np.random.default_rng(0).normal(size=(particles, 31)) * std).astype(np.float32)
        self.X = jnp.asarray(X)
        self.ll = pl.jit_loglik_batch(seq.shape, seq.cameras)
        self.ll(self.X, self.obs0).block_until_ready()
        self.trackers = {c: bt.Tracker(seq, *c) for c in TRACKER_CONFIGS}
        for c in TRACKER_CONFIGS:  # compile
            self.frames(c)

    def likelihood_us(self, repeats: int) -> tuple[float, float]:
        """Median wall and process-CPU µs per particle over ``repeats`` calls."""
        t = common.timed_calls(lambda: self.ll(self.X, self.obs0).block_until_ready(), repeats)
        n = self.X.shape[0]
        return float(np.median(t.wall)) / n * 1e6, float(np.median(t.cpu)) / n * 1e6

    def frames(self, config: tuple[int, int], seed: int = 0) -> float:
        """Seconds per frame, median over the frames: host maps of frame ``t`` + the compiled filter step."""
        return self.trackers[config].run(seed).per_frame


def run(rounds: int, particles: int, repeats: int, log=print) -> list[dict]:
    """Every measurement (:func:`bodytrack.side_by_side` rows; µs per particle or seconds per frame)."""
    bt.build()
    t0 = time.perf_counter()
    jm = Jaxmocap(particles)
    log(f"jaxmocap compiled in {time.perf_counter() - t0:.0f} s")
    lw, lc = "likelihood µs/particle", "likelihood process-CPU µs/particle"

    def ll_bodytrack():
        r = bt.bodytrack_likelihood(particles, repeats)
        return {lw: r["us_median"], lc: r["cpu_us_median"]}

    def ll_jaxmocap():
        wall, cpu = jm.likelihood_us(repeats)
        return {lw: wall, lc: cpu}

    jobs = {lw: (ll_bodytrack, ll_jaxmocap)}
    for n, ly in TRACKER_CONFIGS:
        for model in bt.MODELS:
            jobs[f"tracker {n} × {ly} s/frame, bodytrack {model}"] = (
                lambda n=n, ly=ly, m=model: float(np.median(bt.bodytrack_frames(n, ly, model=m))),
                lambda c=(n, ly): jm.frames(c),
            )
    return bt.side_by_side(jobs, rounds, log)


def to_markdown(rows: list[dict], particles: int, repeats: int) -> str:
    """The setting, then :func:`bodytrack.table`."""
    head = (
        f"bodytrack built from `{bt.SRC}` (g++ -O2, serial); jaxmocap on JAX {jax.__version__} "
        f"({jax.devices()[0].platform}), XLA_FLAGS=`{os.environ.get('XLA_FLAGS', '')}`, compiler options "
        f"{host.loop_fusion_options() or 'XLA defaults'}; {os.cpu_count()} cores ({host.description()}); "
        f"{common.stamp()}. Likelihood: {particles} particles, median of {repeats} calls each side."
    )
    return head + "\n\n" + bt.table(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--particles", type=int, default=4000)
    ap.add_argument("--repeats", type=int, default=5, help="likelihood calls per round, each side")
    ap.add_argument("--out", type=pathlib.Path, default=None, help="write the Markdown report here")
    a = ap.parse_args(argv)
    rows = run(a.rounds, a.particles, a.repeats, log=lambda s: print(s, flush=True))
    md = to_markdown(rows, a.particles, a.repeats)
    print(md)
    if a.out is not None:
        cmd = f"python {common.script(__file__)} --rounds {a.rounds} --out {a.out}"
        common.write_result(a.out, "# jaxmocap vs PARSEC bodytrack, side by side\n\n" + md, cmd)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
