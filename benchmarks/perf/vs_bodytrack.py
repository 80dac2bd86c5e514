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
  repeats after an untimed first pass) against :func:`jaxmocap.parsec.likelihood.jit_loglik_batch` (median of
  the same number of calls after an untimed one, compiled before the first round); also the process CPU time
  per particle of each side (all threads);
* **tracker**, per frame at 4000 × 5 and 1000 × 3: ``bodytrack-serial`` and ``bodytrack-pthreads`` (2 threads),
  each in its own A/B pair, on the two frames of sequenceB_2 (4 cameras, thread model 4 = serial or 2 =
  pthreads, no BMP output), its per-frame time the median interval between the "Processing
  frame i" lines it prints (flushed; the last frame ends when the process exits; each frame includes bodytrack's
  reading of the BMPs, its edge maps and the annealed filter step) against jaxmocap's PARSEC tracker
  (:class:`bodytrack.Tracker`: :func:`jaxmocap.parsec.annealing.parsec_apf` + the PARSEC likelihood, as
  ``benchmarks/experiments/parsec_track.py`` runs it, seed 0, compiled before the first round), median over the
  frames, each frame's observation read from the sequence folder (the BMPs decoded, the edge and foreground maps
  made) as bodytrack reads it, timed two ways after the same bodytrack run: **overlapped** (the rows "tracker N ×
  L s/frame"), as ``jaxmocap track``'s frame loop runs: the step of a frame dispatched and the next frame's
  observation made on the host while it runs, each frame paying one observation; and **not overlapped** (the rows
  "tracker, frames not overlapped"): the frame's observation, then its step.

* **likelihood, a new process** (``--auto-rounds``): the same likelihood timed by a child process started in the
  condition, which chooses XLA's CPU threads as ``jaxmocap`` does by default (``--cpu-threads auto``,
  :func:`jaxmocap.host.choose_cpu_threads`: one per core the other processes leave free, measured over 0.25 s
  when the child starts) and reads its compiled program from a persistent compilation cache shared by the
  children; the threads chosen are reported per round. A process's threads are fixed when it starts, so the
  in-process likelihood above keeps the threads of the condition the script started in.
* **tracker, a new process** (``--auto-rounds``, the rows "tracker s/frame, new process, auto threads"): each
  configuration's tracker likewise in a child process started in the condition with the threads ``jaxmocap track``
  would choose there, its programs read from the same cache, run once untimed and twice timed (frames
  overlapped; median over the four frames), against one run of each bodytrack build: what a command started on a
  busy machine gets.

Each round records the 1-minute load average when it starts (``os.getloadavg``); a condition is labelled *idle*
only when that load is below 1.0, otherwise *loaded* with the load. The ratio is bodytrack's time over jaxmocap's
(above 1: jaxmocap faster); the report gives it per round and its median per condition.

With ``--against REV`` the trackers are also built from the package of git revision ``REV``
(:func:`common.package_at`) and timed against this checkout's, interleaved in both conditions
(:func:`against_table`).

    python benchmarks/perf/vs_bodytrack.py [--rounds 5] [--particles 4000] [--auto-rounds] [--against REV] [--out benchmarks/results/vs_bodytrack.md]
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
import numpy as np  # noqa: E402

from jaxmocap import host, parsec  # noqa: E402

TRACKER_CONFIGS = ((4000, 5), (1000, 3))


def likelihood_us(ll, X, obs, repeats: int) -> tuple[float, float]:
    """Median wall and process-CPU µs per particle of ``ll(X, obs)`` over ``repeats`` calls after one untimed call
    (as ``ll_bench`` discards its first pass)."""
    t = common.timed_calls(lambda: ll(X, obs).block_until_ready(), repeats, warmup=1)
    n = X.shape[0]
    return float(np.median(t.wall)) / n * 1e6, float(np.median(t.cpu)) / n * 1e6


class Jaxmocap:
    """The jaxmocap side, compiled once: the likelihood of ``particles`` states of frame 0 and the PARSEC tracker
    at each configuration of :data:`TRACKER_CONFIGS`."""

    def __init__(self, particles: int, against: str | None = None):
        self.seq = parsec.load_sequence(bt.SEQ)
        seq = self.seq
        self.ll, self.X, self.obs0 = bt.likelihood_problem(seq, particles)
        self.ll(self.X, self.obs0).block_until_ready()
        self.trackers = {c: bt.Tracker(seq, *c) for c in TRACKER_CONFIGS}
        for c in TRACKER_CONFIGS:  # compile
            self.frames(c, overlap=False)
        self.against = {}
        if against is not None:  # the same trackers built from the package of revision ``against``
            package = sys.modules[common.package_at(against, "parsec.track").__name__.split(".")[0]]
            self.against = {c: bt.Tracker(seq, *c, package=package) for c in TRACKER_CONFIGS}
            for c in TRACKER_CONFIGS:
                self.against[c].run(0, overlap=False)

    def likelihood_us(self, repeats: int) -> tuple[float, float]:
        """:func:`likelihood_us` of the likelihood compiled here."""
        return likelihood_us(self.ll, self.X, self.obs0, repeats)

    def frames(self, config: tuple[int, int], seed: int = 0, overlap: bool = True) -> float:
        """Seconds per frame, median over the frames (:meth:`bodytrack.Tracker.run`): with ``overlap`` as
        ``jaxmocap track`` runs its frames (the next frame's observation made while the step runs), else the
        frame's observation and then its step."""
        return self.frames_at(THIS, config, seed, overlap)

    def frames_at(self, name: str, config: tuple[int, int], seed: int = 0, overlap: bool = True) -> float:
        """:meth:`frames` of this checkout (``name`` :data:`THIS`) or of the ``against`` revision."""
        trackers = self.trackers if name == THIS else self.against
        return trackers[config].run(seed, overlap=overlap).per_frame


THIS = "this checkout"
#: the start of the measurement names of the tracker timed with its frames one after the other (not overlapped)
SERIAL = "tracker, frames not overlapped,"
#: the start of the measurement names of the tracker timed in a new process per round (``--auto-rounds``)
AUTO_TRACKER = "tracker s/frame, new process, auto threads,"
#: the measurement name of the likelihood timed in a new process per call (``--auto-rounds``)
AUTO = "likelihood µs/particle, new process, auto threads"


def likelihood_child(particles: int, repeats: int) -> dict:
    """In a new process: XLA's CPU threads chosen as ``jaxmocap`` chooses them (``--cpu-threads auto``), then
    :func:`likelihood_us` of :func:`bodytrack.likelihood_problem` (its program from the persistent compilation cache of
    ``JAXMOCAP_CACHE_DIR``). Returns ``{us, cpu_us, threads, other_busy_cpus}``."""
    host.limit_cpu_threads(host.choose_cpu_threads(host.cpu_sample()))
    from jaxmocap import compilation_cache

    compilation_cache.enable()
    us, cpu_us = likelihood_us(*bt.likelihood_problem(parsec.load_sequence(bt.SEQ), particles), repeats)
    auto = host.thread_summary()
    return dict(us=us, cpu_us=cpu_us, threads=auto["xla_cpu_threads"],
                other_busy_cpus=auto.get("cpu_threads_auto", {}).get("other_busy_cpus", 0.0))  # fmt: skip


def tracker_child(particles: int, layers: int) -> dict:
    """In a new process: XLA's CPU threads chosen as ``jaxmocap`` chooses them (``--cpu-threads auto``), then the
    :class:`bodytrack.Tracker` at ``particles`` × ``layers`` (its programs from the persistent compilation cache of
    ``JAXMOCAP_CACHE_DIR``), run once untimed and twice timed, frames overlapped as ``jaxmocap track`` runs them.
    Returns ``{s, threads, other_busy_cpus}``: ``s`` the median seconds per frame over the timed runs' frames."""
    host.limit_cpu_threads(host.choose_cpu_threads(host.cpu_sample()))
    from jaxmocap import compilation_cache

    compilation_cache.enable()
    tracker = bt.Tracker(parsec.load_sequence(bt.SEQ), particles, layers)
    tracker.run(0, overlap=True)
    frames = np.concatenate([tracker.run(seed, overlap=True).frame for seed in (0, 1)])
    auto = host.thread_summary()
    return dict(s=float(np.median(frames)), threads=auto["xla_cpu_threads"],
                other_busy_cpus=auto.get("cpu_threads_auto", {}).get("other_busy_cpus", 0.0))  # fmt: skip


def in_new_process(flags: list[str], cache: pathlib.Path) -> dict:
    """``python vs_bodytrack.py FLAGS`` (a child mode) run now, in the condition the caller set up, its programs
    cached in ``cache``; the JSON of its last line."""
    import json
    import subprocess

    env = dict(os.environ, JAXMOCAP_CACHE_DIR=str(cache))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    proc = subprocess.run(
        [sys.executable, __file__, *flags], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(proc.stdout.strip().splitlines()[-1])


def tracker_in_new_process(particles: int, layers: int, cache: pathlib.Path) -> dict:
    """:func:`tracker_child` run by ``python vs_bodytrack.py --tracker-child`` now."""
    return in_new_process(["--tracker-child", str(particles), str(layers)], cache)


def likelihood_in_new_process(particles: int, repeats: int, cache: pathlib.Path) -> dict:
    """:func:`likelihood_child` run by ``python vs_bodytrack.py --likelihood-child`` now (in the condition the
    caller set up)."""
    return in_new_process(
        ["--likelihood-child", "--particles", str(particles), "--repeats", str(repeats)], cache
    )


def against_table(jm: Jaxmocap, rev: str, rounds: int, log=print) -> str:
    """The tracker per frame, this checkout against revision ``rev``, interleaved
    (:func:`bodytrack.revisions_side_by_side`): per configuration and condition the ratio ``rev ÷ this`` per
    round (above 1: this checkout faster) and its median."""
    names = [THIS, rev]
    jobs = {f"{n} × {ly}": (lambda name, c=(n, ly): jm.frames_at(name, c)) for n, ly in TRACKER_CONFIGS}
    rows = bt.revisions_side_by_side(rounds, names, jobs, log=log)
    lines = [
        f"Tracker s/frame (frames overlapped), this checkout against `{rev}` (its `jaxmocap/` package), interleaved in "
        "one process; "
        f"ratio = {rev} ÷ this checkout (above 1: this checkout faster).",
        "",
        f"| tracker | condition | load (min–max) | this checkout (median) | {rev} (median) | ratio per round | "
        "median ratio |",
        "|---|---|---|---|---|---|---|",
    ]
    for job in jobs:
        for cond in bt.CONDITIONS:
            sel = [r for r in rows if r["command"] == job and r["condition"] == cond]
            ratios = [r[rev] / r[THIS] for r in sel]
            loads = [r["load"] for r in sel]
            lines.append(
                f"| {job} | {cond} | {min(loads):.1f}–{max(loads):.1f} | "
                f"{np.median([r[THIS] for r in sel]):.4g} | {np.median([r[rev] for r in sel]):.4g} | "
                + ", ".join(f"{q:.2f}" for q in ratios)
                + f" | **{np.median(ratios):.2f}** |"
            )
    return "\n".join(lines)


def run(rounds: int, particles: int, repeats: int, log=print, against: str | None = None, auto: bool = False):
    """Every measurement (:func:`bodytrack.side_by_side` rows; µs per particle or seconds per frame), and the
    :func:`against_table` of revision ``against`` (None without one); with ``auto`` also :data:`AUTO`, whose rows
    carry the child's ``threads``."""
    import tempfile

    bt.build()
    t0 = time.perf_counter()
    jm = Jaxmocap(particles, against)
    log(f"jaxmocap compiled in {time.perf_counter() - t0:.0f} s")
    lw, lc = "likelihood µs/particle", "likelihood process-CPU µs/particle"

    def ll_bodytrack():
        r = bt.bodytrack_likelihood(particles, repeats)
        return {lw: r["us_median"], lc: r["cpu_us_median"]}

    def ll_jaxmocap():
        wall, cpu = jm.likelihood_us(repeats)
        return {lw: wall, lc: cpu}

    jobs = {lw: (ll_bodytrack, ll_jaxmocap)}
    children, tracker_children = [], []
    # the children's compilation cache, removed after the rounds
    cache_dir = tempfile.TemporaryDirectory(prefix="vs_bodytrack_cache_")
    cache = pathlib.Path(cache_dir.name)
    if auto:
        likelihood_in_new_process(particles, 1, cache)  # compiles into the cache

        def ll_child():
            r = likelihood_in_new_process(particles, repeats, cache)
            children.append(r)
            log(f"  new process: {r['threads']} thread(s), others kept {r['other_busy_cpus']:.2f} CPUs busy")
            return r["us"]

        jobs[AUTO] = (lambda: ll_bodytrack()[lw], ll_child)
        for n, ly in TRACKER_CONFIGS:
            tracker_in_new_process(n, ly, cache)  # compiles into the cache
            names = tuple(f"{AUTO_TRACKER} {n} × {ly}, bodytrack {m}" for m in bt.MODELS)

            def theirs(n=n, ly=ly, names=names):
                return {
                    w: float(np.median(bt.bodytrack_frames(n, ly, model=m)))
                    for w, m in zip(names, bt.MODELS, strict=True)
                }

            def ours(n=n, ly=ly, names=names):
                r = tracker_in_new_process(n, ly, cache)
                tracker_children.append(dict(r, config=f"{n} × {ly}"))
                log(
                    f"  new process, {n} × {ly}: {r['threads']} thread(s), others kept {r['other_busy_cpus']:.2f} busy"
                )
                return dict.fromkeys(names, r["s"])

            jobs[names[0]] = (theirs, ours)
    for n, ly in TRACKER_CONFIGS:
        for model in bt.MODELS:
            # one bodytrack run against ours both ways: overlapped (as ``jaxmocap track`` runs) and one after the
            # other (the observation, then the step), the two orders alternating with bodytrack's
            names = (
                f"tracker {n} × {ly} s/frame, bodytrack {model}",
                f"{SERIAL} {n} × {ly}, bodytrack {model}",
            )

            def theirs(n=n, ly=ly, m=model, names=names):
                v = float(np.median(bt.bodytrack_frames(n, ly, model=m)))
                return dict.fromkeys(names, v)

            def ours(c=(n, ly), names=names):
                return {names[0]: jm.frames(c, overlap=True), names[1]: jm.frames(c, overlap=False)}

            jobs[names[0]] = (theirs, ours)
    try:
        rows = bt.side_by_side(jobs, rounds, log)
    finally:
        cache_dir.cleanup()
    for row, child in zip([r for r in rows if r["what"] == AUTO], children, strict=True):
        row["threads"] = child["threads"]
    # each tracker child gave two rows (against bodytrack serial, then pthreads), in the order the children ran
    pairs = [r for r in rows if r["what"].startswith(AUTO_TRACKER)]
    for i, child in enumerate(tracker_children):
        for row in pairs[2 * i : 2 * i + 2]:
            row["threads"] = child["threads"]
    return rows, (against_table(jm, against, rounds, log) if against is not None else None)


def auto_note(rows: list[dict]) -> str:
    """The threads the new processes chose, per condition (the likelihood's, then each tracker's)."""
    groups = {"the likelihood's": [r for r in rows if r["what"] == AUTO]}
    for r in rows:
        if r["what"].startswith(AUTO_TRACKER) and r["what"].endswith("serial"):
            config = r["what"][len(AUTO_TRACKER) :].split(",")[0].strip()
            groups.setdefault(f"the {config} tracker's", []).append(r)
    if not groups["the likelihood's"]:
        return ""
    parts = []
    for what, sel in groups.items():
        per = {c: [r["threads"] for r in sel if r["condition"] == c] for c in bt.CONDITIONS}
        parts.append(what + " " + "; ".join(f"{c}: {', '.join(map(str, t))}" for c, t in per.items()))
    return (
        "XLA CPU threads chosen by the new processes (`--cpu-threads auto`), per round: "
        + "; ".join(parts)
        + "."
    )


def to_markdown(rows: list[dict], particles: int, repeats: int) -> str:
    """The setting, then :func:`bodytrack.table`."""
    head = (
        f"bodytrack built from `{bt.SRC}` (g++ -O2, serial); jaxmocap on JAX {jax.__version__} "
        f"({jax.devices()[0].platform}), XLA_FLAGS=`{os.environ.get('XLA_FLAGS', '')}`, compiler options "
        f"{host.particle_options() or 'XLA defaults'}; {os.cpu_count()} cores ({host.description()}); "
        f"{common.stamp()}. Likelihood: {particles} particles, median of {repeats} calls each side."
    )
    return head + "\n\n" + bt.table(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--particles", type=int, default=4000)
    ap.add_argument("--repeats", type=int, default=5, help="likelihood calls per round, each side")
    ap.add_argument("--out", type=pathlib.Path, default=None, help="write the Markdown report here")
    ap.add_argument(
        "--against", metavar="REV", help="also time the tracker built from the package of git revision REV"
    )
    ap.add_argument(
        "--auto-rounds",
        action="store_true",
        help="also the likelihood and the trackers in a new process per round, threads chosen as --cpu-threads auto",
    )
    ap.add_argument("--likelihood-child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--tracker-child", nargs=2, type=int, metavar=("N", "L"), help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.tracker_child:
        import json

        print(json.dumps(tracker_child(*a.tracker_child)))
        return 0
    if a.likelihood_child:
        import json

        print(json.dumps(likelihood_child(a.particles, a.repeats)))
        return 0
    rows, versus = run(
        a.rounds,
        a.particles,
        a.repeats,
        log=lambda s: print(s, flush=True),
        against=a.against,
        auto=a.auto_rounds,
    )
    md = to_markdown(rows, a.particles, a.repeats)
    if a.auto_rounds:
        md += "\n\n" + auto_note(rows)
    if versus is not None:
        md += "\n\n" + versus
    print(md)
    if a.out is not None:
        cmd = f"python {common.script(__file__)} --rounds {a.rounds}"
        cmd += " --auto-rounds" if a.auto_rounds else ""
        cmd += f" --against {a.against}" if a.against else ""
        cmd += f" --out {a.out}"
        common.write_result(a.out, "# jaxmocap vs PARSEC bodytrack, side by side\n\n" + md, cmd)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
