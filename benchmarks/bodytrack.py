"""PARSEC bodytrack (unmodified C++, Apache-2.0) built from source and run beside jaxmocap's benchmarks.

``build()`` runs ``make -C $BODYTRACK_SRC OUT=<repo>/build/bodytrack`` (``BODYTRACK_SRC`` default
``/work/shared/parsec/bodytrack``: its README and Makefile; ``build/`` is git-ignored); ``bodytrack_likelihood``
runs its ``ll_bench`` (``TrackingModel::LogLikelihood`` alone), ``bodytrack_run`` / ``bodytrack_frames`` a tracker
build with per-frame and whole-run times; :class:`Tracker` is jaxmocap's side of the tracker comparison; ``busy()``
starts a CPU-bound child process for the loaded rounds; ``label`` names a round idle only when the 1-minute load
average is below 1.0.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import pathlib
import subprocess
import sys
import time
from typing import NamedTuple

import common
import numpy as np

SRC = pathlib.Path(os.environ.get("BODYTRACK_SRC", "/work/shared/parsec/bodytrack"))
SEQ = pathlib.Path(os.environ.get("JAXMOCAP_DATA", "/work/shared/data")) / "parsec" / "sequenceB_2"
BUILD = common.ROOT / "build" / "bodytrack"
#: the two conditions of every round: nothing added to the machine, and one busy-loop process started by us
CONDITIONS = ("as found", "+1 busy process")


def build(out: pathlib.Path = BUILD) -> pathlib.Path:
    """Build bodytrack's serial tracker and ``ll_bench`` into ``out`` (make skips what exists); returns ``out``."""
    if not (SRC / "Makefile").is_file():
        raise SystemExit(f"error: no bodytrack sources at {SRC} (set BODYTRACK_SRC)")
    targets = [str(out / exe) for exe, _, _ in MODELS.values()] + [str(out / "ll_bench")]
    subprocess.run(["make", "-C", str(SRC), f"OUT={out}", *targets], check=True, stdout=subprocess.DEVNULL)
    return out


@contextlib.contextmanager
def busy(on: bool):
    """While active (if ``on``): one CPU-bound child process, killed on exit."""
    if not on:
        yield
        return
    p = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    _BUSY.append(p)
    try:
        time.sleep(0.5)  # let it reach the run queue
        yield
    finally:
        _BUSY.remove(p)
        p.kill()
        p.wait()


_BUSY: list = []  # the busy processes of the active :func:`busy` blocks


def busy_now() -> bool:
    """Whether a :func:`busy` process is running (a measurement function can tell its condition)."""
    return bool(_BUSY)


def bodytrack_likelihood(particles: int, repeats: int, out: pathlib.Path = BUILD) -> dict:
    """``ll_bench``'s report: ``us_median`` (wall µs per particle), ``cpu_us_median``, ``valid``, ``mean_ll``."""
    r = subprocess.run(
        [str(out / "ll_bench"), str(SEQ), str(particles), str(repeats)],
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(r.stdout.strip().splitlines()[-1])


#: bodytrack's builds: executable and thread-model arguments (4 = serial; 2 = pthreads, 2 threads)
MODELS = {"serial": ("bodytrack-serial", "4", "1"), "pthreads": ("bodytrack-pthreads", "2", "2")}


def bodytrack_run(
    particles: int, layers: int, frames: int = 2, model: str = "serial", out: pathlib.Path = BUILD
) -> tuple[list[float], float]:
    """``(seconds per frame, whole-run seconds)`` of bodytrack's ``model`` build (:data:`MODELS`) on ``frames``
    frames of sequenceB_2: per frame the intervals between its "Processing frame" lines (the last frame ends when
    the process exits); the whole run from the process's start to its exit."""
    exe, tm, nt = MODELS[model]
    argv = [str(out / exe), str(SEQ), "4", str(frames), str(particles), str(layers), tm, nt, "0"]
    t0 = time.perf_counter()
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=out)
    stamps = []
    for line in p.stdout:
        if line.startswith("Processing frame"):
            stamps.append(time.perf_counter())
    p.wait()
    end = time.perf_counter()
    if p.returncode != 0 or len(stamps) != frames:
        raise RuntimeError(f"{exe} failed (exit {p.returncode}, {len(stamps)} frames)")
    return list(np.diff([*stamps, end])), end - t0


def bodytrack_frames(
    particles: int, layers: int, frames: int = 2, model: str = "serial", out: pathlib.Path = BUILD
) -> list[float]:
    """Seconds per frame of :func:`bodytrack_run`."""
    return bodytrack_run(particles, layers, frames, model, out)[0]


def likelihood_problem(seq, particles: int):
    """``(likelihood, particles, observation)``: :func:`jaxmocap.parsec.likelihood.jit_loglik_batch` of ``seq``,
    ``particles`` states drawn around its initial pose with its standard deviations (seed 0), frame 0: the
    likelihood the scripts time and profile against ``ll_bench``'s."""
    import jax.numpy as jnp

    from jaxmocap.parsec import likelihood as pl

    x0, std = seq.initial_pose, seq.pose_std
    X = (x0 + np.random.default_rng(0).normal(size=(particles, 31)) * std).astype(np.float32)
    return pl.jit_loglik_batch(seq.shape, seq.cameras), jnp.asarray(X), seq.observation(0)


class TrackerRun(NamedTuple):
    """One run of :class:`Tracker` over F frames: ``estimates (F, 31)`` (float64, PARSEC units) and ``frame (F,)``
    the seconds of each frame; run one after the other (``overlap=False``) also the split ``maps (F,)`` (the frame's
    observation: images read, edge and foreground maps) and ``step (F,)`` (the compiled filter step, all layers),
    whose sum is ``frame``; None when overlapped."""

    estimates: np.ndarray
    frame: np.ndarray
    maps: np.ndarray | None = None
    step: np.ndarray | None = None

    @property
    def per_frame(self) -> float:
        """Median over the frames of the frame's seconds."""
        return float(np.median(self.frame))


class Tracker:
    """jaxmocap's PARSEC tracker at ``particles`` × ``layers``: :func:`jaxmocap.parsec.annealing.parsec_apf` with the
    PARSEC likelihood and bodytrack's initialisation (``InitialPose + N(0, σ_0)`` weighted against frame 0 with its
    β), the start and the step each jitted once (compiled by the first :meth:`run`). ``package``: the ``jaxmocap``
    package to build it from (default this checkout's; :func:`common.package_at` for another revision's);
    ``options``: XLA's compiler options of both (default: those the package's ``jaxmocap track`` uses). Each
    frame's observation is read from the sequence folder as ``jaxmocap track`` reads it (the package's
    ``ParsecSource``: the BMPs decoded, the edge and foreground maps computed), as bodytrack reads its frames."""

    def __init__(
        self,
        seq,
        particles: int,
        layers: int,
        package=None,
        folder: pathlib.Path = SEQ,
        options: dict | None = None,
    ):
        import jax
        import jax.numpy as jnp

        if package is None:  # this checkout's; or another revision's (``common.package_at``)
            import jaxmocap as package
        ptrack = importlib.import_module(f"{package.__name__}.parsec.track")
        parsec_apf = importlib.import_module(f"{package.__name__}.parsec.annealing").parsec_apf
        inputs = importlib.import_module(f"{package.__name__}.parsec.inputs")

        self.seq, self._jax = seq, jax
        self.source = inputs.ParsecSource(folder)
        std = jnp.asarray(seq.pose_std, jnp.float32)
        x0 = jnp.asarray(seq.initial_pose, jnp.float32)
        loglik = ptrack.make_loglik(seq.shape, seq.cameras)  # bodytrack drops invalid poses (−1e10)
        filt = parsec_apf(loglik, std, particles, layers)
        if options is None:  # the options the package's own ``jaxmocap track`` compiles the step with
            options = common.particle_options_of(ptrack)
        self._start = jax.jit(
            lambda k, o: ptrack.weighted_start(filt, loglik, k, x0, std, o), compiler_options=options
        )
        self._step = jax.jit(filt.step, compiler_options=options)

    def run(self, seed: int = 0, frames: int | None = None, overlap: bool = False) -> TrackerRun:
        """Track frames ``0 … frames − 1`` (all by default) with key ``seed``.

        ``overlap=False``: each frame timed as its observation (:attr:`source`) and then the filter step, which
        waits for its particles. ``overlap=True``: as ``jaxmocap track``'s frame loop runs them
        (:class:`jaxmocap.tracking.loop.TrackingLoop`): the step of frame ``t`` dispatched, the observation of the
        next frame made on the host while it runs, then the step waited for; frame ``t``'s time is that whole
        interval, so every frame pays one observation (the last frame makes frame 0's again; frame 0's first
        observation, made before the first step, is not timed)."""
        jax, source = self._jax, self.source
        key = jax.random.key(seed)
        F = source.num_frames if frames is None else frames
        obs = source.observation(0)
        state = self._start(jax.random.fold_in(key, 1000), obs)
        jax.block_until_ready(state.particles)
        est, frame, maps, step = [], [], [], []
        for t in range(F):
            t0 = time.perf_counter()
            if overlap:
                state, info = self._step(jax.random.fold_in(key, t), state, obs)
                obs = source.observation((t + 1) % F)
                jax.block_until_ready(state.particles)
            else:
                obs = source.observation(t)
                t1 = time.perf_counter()
                state, info = self._step(jax.random.fold_in(key, t), state, obs)
                jax.block_until_ready(state.particles)
                maps.append(t1 - t0)
                step.append(time.perf_counter() - t1)
            frame.append(time.perf_counter() - t0)
            est.append(np.asarray(info.estimate, np.float64))
        if overlap:
            return TrackerRun(np.stack(est), np.asarray(frame))
        return TrackerRun(np.stack(est), np.asarray(frame), np.asarray(maps), np.asarray(step))


def label(load: float) -> str:
    return "idle" if load < 1.0 else f"loaded ({load:.1f})"


def side_by_side(jobs: dict, rounds: int, log=print) -> list[dict]:
    """Interleaved A/B: ``jobs`` maps a measurement name to ``(bodytrack_fn, jaxmocap_fn)``, each ``() -> float``
    (or both ``() -> {measurement: float}`` with the same keys, several measurements of one call).
    Every round runs both conditions of :data:`CONDITIONS` (the second with :func:`busy`), in each every
    measurement's two functions, alternating which goes first. Returns dicts ``round, condition, load (1-min load
    average at the start of the condition), what, bodytrack, jaxmocap``."""
    rows = []
    for r in range(rounds):
        for ci, cond in enumerate(CONDITIONS):
            with busy(ci > 0):
                load = os.getloadavg()[0]
                order = (0, 1) if (r + ci) % 2 == 0 else (1, 0)
                for what, fns in jobs.items():
                    v = [{}, {}]
                    for i in order:
                        got = fns[i]()
                        v[i] = got if isinstance(got, dict) else {what: got}
                    for w in v[0]:
                        b, j = v[0][w], v[1][w]
                        rows.append(dict(round=r, condition=cond, load=load, what=w, bodytrack=b, jaxmocap=j))
                        log(
                            f"round {r} {cond:16s} load {load:5.2f} {w:34s} bodytrack {b:8.4f} "
                            f"jaxmocap {j:8.4f} ratio {b / j:5.2f}"
                        )
    return rows


def revisions_side_by_side(rounds: int, names: list[str], jobs: dict, extra=None, log=print) -> list[dict]:
    """Interleaved A/B of checkouts: every round runs both conditions of :data:`CONDITIONS` (the second with
    :func:`busy`), in each every job of ``jobs`` (job name → ``fn(checkout name) -> seconds``) for every checkout
    of ``names``, the order alternating by round and condition, then ``extra()`` (None, or ``() -> {name:
    seconds}``: e.g. bodytrack's own run) once per condition. Returns dicts ``round, condition, command (the job),
    load (1-min load average before the job), <checkout>: seconds …`` plus ``extra``'s entries."""
    rows = []
    for r in range(rounds):
        for ci, cond in enumerate(CONDITIONS):
            with busy(ci > 0):
                order = names if (r + ci) % 2 == 0 else names[::-1]
                for job, fn in jobs.items():
                    load = os.getloadavg()[0]
                    got = {n: fn(n) for n in order}
                    if extra is not None:
                        got.update(extra())
                    rows.append(dict(round=r, condition=cond, command=job, load=load, **got))
                    log(
                        f"round {r} {cond:16s} {job:6s} load {load:5.2f} "
                        + " ".join(f"{k} {v:.2f}" for k, v in got.items())
                    )
    return rows


def table(rows: list[dict]) -> str:
    """Markdown: the median ratio (bodytrack / jaxmocap, above 1 = jaxmocap faster) per measurement and
    condition with every round's ratio, then every round with its load and state (idle only below load 1.0)."""
    lines = [
        "Ratio = bodytrack / jaxmocap (above 1: jaxmocap faster), interleaved A/B per round. A round is *idle* "
        "only if the 1-min load average is below 1.0.",
        "",
        "| measurement | condition | rounds | load (min–max) | bodytrack (median) | jaxmocap (median) | "
        "ratio per round | median ratio |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for what in dict.fromkeys(r["what"] for r in rows):
        for cond in CONDITIONS:
            sel = [r for r in rows if r["what"] == what and r["condition"] == cond]
            if not sel:
                continue
            loads = [r["load"] for r in sel]
            ratios = [r["bodytrack"] / r["jaxmocap"] for r in sel]
            lines.append(
                f"| {what} | {cond} | {len(sel)} | {min(loads):.1f}–{max(loads):.1f} | "
                f"{np.median([r['bodytrack'] for r in sel]):.4g} | {np.median([r['jaxmocap'] for r in sel]):.4g} | "
                f"{', '.join(f'{x:.2f}' for x in ratios)} | **{np.median(ratios):.2f}** |"
            )
    lines += [
        "",
        "| round | condition | load (1 min) | state | measurement | bodytrack | jaxmocap | ratio |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['round']} | {r['condition']} | {r['load']:.2f} | {label(r['load'])} | {r['what']} | "
            f"{r['bodytrack']:.4g} | {r['jaxmocap']:.4g} | {r['bodytrack'] / r['jaxmocap']:.2f} |"
        )
    return "\n".join(lines) + "\n"
