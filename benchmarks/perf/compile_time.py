"""Compile time: the hot programs per body model, and the first-frame latency of ``jaxmocap track`` per filter family.

Two tables, both with the persistent compilation cache off (``JAXMOCAP_CACHE_DIR=off``):

1. **Programs** (``--programs``): for each body model, the three programs the tracker compiles, built by the
   tracker's own setup (:class:`jaxmocap.tracking.setup.TrackSetup`) on a synthetic stereo sequence of the bundled
   CMU walk (320×240, foreground, edge distance, coverage and, for ``full25``, depth):

   * ``fk``: the forward kinematics vmapped over 8192 particles;
   * ``likelihood``: the tracker's log-likelihood over 8192 particles;
   * ``apf``: one frame of the annealed particle filter with the default particles and layers.

   With ``--pieces`` also (or instead) the programs of ``--filter hybrid`` (its cues: :data:`HYBRID_CUES`):

   * ``hybrid``: one frame of the hybrid filter (layers with gradient moves);
   * ``hybrid-nomove``: the same filter without its moves (what the moves add is the difference);
   * ``gradient``: the value and gradient of the tracker's likelihood at the ``best_k`` particles one optimiser
     step of a move evaluates.

   For each: the time to trace and lower (``jit(...).lower``), to compile (``.compile()``, XLA), the process's CPU
   time during the compilation (XLA compiles its kernels on a thread pool) and the size of the lowered module in
   lines of StableHLO text (the CPU compiler's time grows with it). ``--isolate`` runs each row in a fresh
   interpreter, as ``jaxmocap track`` sees it. With ``--codegen`` each program is compiled three times more: with
   XLA's default code generation, with the defaults but XLA's classic loop emitters instead of its MLIR fusion
   emitters (:data:`CLASSIC_CODEGEN`), and with the test suite's (:data:`SUITE_CODEGEN`: the classic emitters at
   the lowest backend optimisation level, ``tests/conftest.py``); the table gives each compilation's CPU time and
   each program's run time (interleaved rounds, the median of each, and the medians of the per-round ratios).

2. **First frame** (default): the wall time from process start to the end of a one-frame ``jaxmocap track`` run
   (import, features, initialisation, compilation of the filter step, one step, outputs) for every model × filter
   family: ``apf``, ``iapf``, ``partitioned`` with equal counts and with unequal counts (Li & Kulić's
   1000,200,350,… on ``full25``), ``hierarchical``, ``hybrid`` (with the default cues less ``depth``, which has no
   gradient), and the process's CPU time (user + system, every thread: the work, whatever the load). With
   ``--before DIR`` (another checkout of the project, e.g. a ``git worktree`` of an older commit) each
   configuration is run with that checkout and with this one in alternation, so that both see the same machine
   load; ``--rounds N`` repeats that N times (the order alternating) and the table gives the medians and the
   median and range of the per-round ratios.

3. **Step time** (``--steps``): the compiled filter step's run time per model × family, as the tracker runs it
   (initialised by the tracker's own pose fit on the first frame), the median over the 16 frames of the sequence
   per round. With ``--before DIR`` one worker process per checkout compiles the step once, and each round times
   the sequence in each worker in turn; the ratio is the median of the per-round ratios (the run-time guard of
   the compile-time changes: a shorter compilation may not cost step time).

4. **Tracks** (``--tracks``): the whole sequence tracked by ``jaxmocap track`` for the seeds of ``--seeds`` (the
   persistent cache on, one per checkout), the mean joint error against the ground truth; with ``--before DIR``
   with each checkout, whether the poses are the same bit for bit and the largest difference (the guard of the
   results: a change that only reorganises the compiled program must leave the tracks as they were, one that
   changes rounding must leave the accuracy).

With ``--out FILE`` the table is written with the command that regenerates it less ``--before DIR`` (the note
under the table names that checkout and its commit).

    python benchmarks/perf/compile_time.py [--models upper9 upper14 full25] [--filters apf iapf ...]
                                           [--before DIR] [--rounds N] [--programs [--isolate] [--codegen]] [--steps]
                                           [--tracks --seeds 0 1 2] [--quick]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pathlib
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

import common  # noqa: E402

MODELS = ("upper9", "upper14", "full25")
PIECES = ("fk", "likelihood", "apf")
#: the programs of ``--filter hybrid`` (``--pieces``)
HYBRID_PIECES = ("hybrid", "hybrid-nomove", "gradient")
#: the test suite's code generation (tests/conftest.py), against XLA's defaults (``--codegen``)
SUITE_CODEGEN = {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}
DEFAULT_CODEGEN = {"xla_backend_optimization_level": 3, "xla_cpu_use_fusion_emitters": True}
#: XLA's defaults but the classic loop emitters (the suite's second flag alone)
CLASSIC_CODEGEN = {"xla_backend_optimization_level": 3, "xla_cpu_use_fusion_emitters": False}
#: filter family -> (filter name, particle-count rule: None = the default, "unequal" = one count per partition)
FAMILIES = {
    "apf": ("apf", None),
    "iapf": ("iapf", None),
    "partitioned": ("partitioned", None),
    "partitioned-unequal": ("partitioned", "unequal"),
    "hierarchical": ("hierarchical", None),
    "hybrid": ("hybrid", None),
}
ROOT = pathlib.Path(__file__).resolve().parents[2]
#: the cues of the gradient filters (the default set less ``depth``, which has no gradient)
HYBRID_CUES = "foreground,edge_distance,coverage:4"


def make_sequence(folder: pathlib.Path) -> pathlib.Path:
    """A short synthetic stereo sequence (depth included) of the bundled CMU walk, rendered once per run."""
    from jaxmocap.synth import generate as synth

    out = folder / "seq"
    synth.synthesize(
        "demo", out, rig="stereo", frames="0:16", fps=30.0, size="320x240", seed=0, overwrite=True
    )
    return out


def unequal_counts(model_name: str) -> str:
    """Li & Kulić's counts for ``full25`` (torso 1000, head 200, arms and legs 350); for the upper bodies the same
    rule (1000 for the torso, 200 for the head, 350 for every other partition)."""
    from jaxmocap.filters.factory import partition_groups
    from jaxmocap.geometry import body

    groups = partition_groups(body.build(model_name))
    return ",".join(["1000", "200"] + ["350"] * (len(groups) - 2))


# ---------------------------------------------------------------------------------------------------------------
# Programs


def program(model_name: str, piece: str, seq: pathlib.Path, particles: int = 8192):
    """``(jitted function, arguments, particles)`` of one piece, built by the tracker's setup."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxmocap.geometry import body
    from jaxmocap.io.sources import SequenceSource
    from jaxmocap.tracking.options import TrackOptions
    from jaxmocap.tracking.setup import TrackSetup

    hybrid = piece in HYBRID_PIECES
    options = TrackOptions(model=model_name, filter="hybrid", cues=HYBRID_CUES) if hybrid else None
    setup = TrackSetup(SequenceSource(seq), options or TrackOptions(model=model_name, filter="apf"))
    model = setup.model
    x0 = np.asarray(model.rest_pose, np.float32)
    n = particles if piece in ("fk", "likelihood") else int(setup.num_particles)
    X = jnp.asarray(x0 + 0.05 * np.random.default_rng(1).normal(size=(n, model.num_dofs)), jnp.float32)
    if piece == "fk":
        return jax.jit(jax.vmap(lambda x: body.segment_poses(model, x))), (X,), n
    tobs = setup.observe(setup.frames[0])[0]
    if piece == "likelihood":
        return jax.jit(setup.loglik), (X, tobs, 0), n
    filt = setup.make_filter(x0)
    if piece == "gradient":
        from jaxmocap.filters.base import Layer
        from jaxmocap.likelihood.gradients import batch_value_and_grad

        k = filt.move.best_k
        layer = Layer(jnp.int32(0), jnp.float32(0.1))
        return jax.jit(lambda X, o: batch_value_and_grad(filt.loglik_batch, X, o, layer)), (X[:k], tobs), k
    if piece == "hybrid-nomove":
        filt = dataclasses.replace(filt, move=None)
    state = filt.init(jax.random.key(0), jnp.asarray(x0))
    return jax.jit(filt.step), (jax.random.key(1), state, tobs), n


def measure(model_name: str, piece: str, seq: pathlib.Path, codegen: bool = False) -> dict:
    f, args, n = program(model_name, piece, seq)
    t0 = time.perf_counter()
    lowered = f.lower(*args)
    t1 = time.perf_counter()
    c1 = _cpu_seconds(resource.RUSAGE_SELF)
    lowered.compile()
    t2 = time.perf_counter()
    out = dict(
        compile_cpu_s=_cpu_seconds(resource.RUSAGE_SELF) - c1,
        model=model_name,
        piece=piece,
        particles=n,
        lower_s=t1 - t0,
        compile_s=t2 - t1,
        hlo_lines=len(lowered.as_text().splitlines()),
    )
    if codegen:
        out.update(codegen_rows(lowered, args))
    return out


def codegen_rows(lowered, args, rounds: int = 9) -> dict:
    """``--codegen``: compile CPU seconds and run seconds of ``lowered`` with XLA's defaults, the classic emitters
    and the suite's code generation (interleaved rounds, each the mean of 3 calls after one untimed call)."""
    import jax
    import numpy as np

    compiled, out = {}, {}
    variants = (("default", DEFAULT_CODEGEN), ("classic", CLASSIC_CODEGEN), ("suite", SUITE_CODEGEN))
    for name, options in variants:
        c0 = _cpu_seconds(resource.RUSAGE_SELF)
        compiled[name] = lowered.compile(compiler_options=options)
        out[f"{name}_compile_cpu_s"] = _cpu_seconds(resource.RUSAGE_SELF) - c0
    runs = {name: [] for name in compiled}
    for r in range(rounds):
        for name in sorted(compiled, reverse=r % 2 == 1):  # the order alternating
            call = lambda f=compiled[name]: jax.block_until_ready(f(*args))  # noqa: E731
            runs[name].append(float(common.timed_calls(call, 3, warmup=1).wall.mean()))
    for name, t in runs.items():
        out[f"{name}_run_s"] = float(np.median(t))
    for name in ("classic", "suite"):
        out[f"{name}_run_ratio"] = float(np.median(np.asarray(runs[name]) / np.asarray(runs["default"])))
    return out


def _cpu_seconds(who) -> float:
    """User + system CPU seconds of this process (every thread) or of its finished children."""
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def _isolated(model_name: str, piece: str, seq: pathlib.Path, codegen: bool = False) -> dict:
    """:func:`measure` in a fresh interpreter (no compiled program or trace shared with earlier rows)."""
    cmd = [
        sys.executable,
        __file__,
        "--row",
        model_name,
        piece,
        str(seq),
        *(["--codegen"] if codegen else []),
    ]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=_env(ROOT))
    return json.loads(out.stdout.strip().splitlines()[-1])


def programs_table(
    models, seq: pathlib.Path, isolate: bool, pieces=PIECES, codegen: bool = False
) -> list[str]:
    head = "| model | piece | particles | lower s | compile s | compile CPU s | HLO lines |"
    if codegen:
        head += (
            " compile CPU s: defaults / classic / suite | run ms: defaults / classic / suite |"
            " run time / defaults: classic, suite |"
        )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for m in models:
        for p in pieces:
            r = (_isolated if isolate else measure)(m, p, seq, codegen)
            line = (
                f"| {r['model']} | {r['piece']} | {r['particles']} | {r['lower_s']:.2f} | {r['compile_s']:.2f} "
                f"| {r['compile_cpu_s']:.2f} | {r['hlo_lines']} |"
            )
            if codegen:
                line += (
                    " "
                    + " / ".join(f"{r[k + '_compile_cpu_s']:.2f}" for k in ("default", "classic", "suite"))
                    + " | "
                    + " / ".join(f"{r[k + '_run_s'] * 1e3:.1f}" for k in ("default", "classic", "suite"))
                    + f" | {r['classic_run_ratio']:.2f}, {r['suite_run_ratio']:.2f} |"
                )
            lines.append(line)
            print(lines[-1], flush=True)
    return lines


# ---------------------------------------------------------------------------------------------------------------
# First frame


def _env(checkout: pathlib.Path) -> dict:
    env = dict(os.environ, JAXMOCAP_CACHE_DIR="off", JAX_PLATFORMS="cpu")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env["PYTHONPATH"] = str(checkout) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def track_command(seq: pathlib.Path, model: str, family: str, out: pathlib.Path, *extra: str) -> list[str]:
    """``jaxmocap track`` of one model × family (the unequal counts, the gradient filters' cues) into ``out``."""
    name, rule = FAMILIES[family]
    cmd = [sys.executable, "-m", "jaxmocap.cli", "track", str(seq), "--out", str(out), "--model", model]
    cmd += ["--filter", name, "--quiet", "--overwrite", *extra]
    if rule == "unequal":
        cmd += ["--particles", unequal_counts(model)]
    if name == "hybrid":  # the gradient filters need differentiable cues: the default set without depth
        cmd += ["--cues", HYBRID_CUES]
    return cmd


def first_frame_seconds(
    checkout: pathlib.Path, seq: pathlib.Path, model: str, family: str, out: pathlib.Path
) -> tuple[float | None, float | None, str | None]:
    """``(wall s, CPU s, None)`` of a one-frame ``jaxmocap track`` in a new process with ``checkout``'s package
    (CPU: user + system time of the process, every thread), or ``(None, None, why)`` when it failed."""
    cmd = track_command(seq, model, family, out, "--frames", "0:1")
    c0 = _cpu_seconds(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=_env(checkout), cwd=str(out.parent))
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["?"]
        return None, None, tail[0]
    return seconds, _cpu_seconds(resource.RUSAGE_CHILDREN) - c0, None


def _table_start(before: pathlib.Path | None, alone: str, paired: str) -> tuple[dict, list[str]]:
    """The checkouts a table compares (``after`` = this one, and ``before`` when given) and its two header lines:
    ``alone`` without a ``before`` checkout, ``paired`` with one."""
    trees = {"after": ROOT} if before is None else {"before": before, "after": ROOT}
    head = alone if before is None else paired
    return trees, [head, "|" + "---|" * (head.count("|") - 1)]


def first_frame_table(
    models, families, seq, before: pathlib.Path | None, work: pathlib.Path, rounds: int
) -> list[str]:
    trees, lines = _table_start(
        before,
        "| model | filter | first frame s | CPU s |",
        "| model | filter | before s | after s | after / before (median of rounds) | range of rounds "
        "| before CPU s | after CPU s |",
    )
    for m in models:
        for fam in families:
            out = work / f"run_{m}_{fam}"
            wall: dict = {k: [] for k in trees}
            cpu: dict = {k: [] for k in trees}
            why = None
            for r in range(rounds):  # the order of the checkouts alternates between rounds
                for k in sorted(trees, reverse=r % 2 == 0):
                    w, c, fail = first_frame_seconds(trees[k], seq, m, fam, out)
                    why = why or (fail and f"{k}: {fail}")
                    if w is not None:
                        wall[k].append(w)
                        cpu[k].append(c)
            if why is not None:
                lines.append(f"| {m} | {fam} | failed: {why} |")
            elif before is None:
                lines.append(
                    f"| {m} | {fam} | {np.median(wall['after']):.1f} | {np.median(cpu['after']):.1f} |"
                )
            else:
                ratio = np.asarray(wall["after"]) / np.asarray(wall["before"])
                b, a = (np.median(wall[k]) for k in ("before", "after"))
                cb, ca = (np.median(cpu[k]) for k in ("before", "after"))
                lines.append(
                    f"| {m} | {fam} | {b:.1f} | {a:.1f} | {np.median(ratio):.2f} | {ratio.min():.2f}–{ratio.max():.2f} "
                    f"| {cb:.1f} | {ca:.1f} |"
                )
            print(lines[-1], flush=True)
    return lines


# ---------------------------------------------------------------------------------------------------------------
# Step time


def step_worker(model: str, family: str, seq: pathlib.Path) -> None:
    """A worker (``--worker``): builds the configuration as ``jaxmocap track`` does, compiles the step, prints
    ``ready``; then for each ``go`` on stdin runs the step over every frame from the same initial state and prints
    the milliseconds of each call (JSON)."""
    import jax
    import numpy as np

    from jaxmocap.io.sources import SequenceSource
    from jaxmocap.tracking.options import TrackOptions
    from jaxmocap.tracking.setup import TrackSetup

    name, rule = FAMILIES[family]
    particles = [int(c) for c in unequal_counts(model).split(",")] if rule == "unequal" else None
    cues = HYBRID_CUES if name == "hybrid" else None
    options = TrackOptions(model=model, filter=name, particles=particles, cues=cues)
    setup = TrackSetup(SequenceSource(seq), options)
    frames = [setup.observe(t)[:3] for t in setup.frames]
    tobs0, masks0, fd0 = frames[0]
    x0, spread, _ = setup.initial_state(setup.frames[0], masks0, fd0)
    x0 = np.asarray(x0, np.float64)
    setup.set_references(x0, tobs0)
    filt = setup.make_filter(x0)
    observations = []
    for tobs, masks, fd in frames:
        centre = setup.detection(fd, masks, x0)
        if centre is not None:
            tobs = tobs._replace(centre=jax.numpy.asarray(centre, np.float32), valid=jax.numpy.asarray(True))
        observations.append(tobs)
    state0 = setup.start(filt, jax.random.key(1), x0, spread, tobs0)
    step = jax.jit(lambda f, k, s, o: f.step(k, s, o))
    jax.block_until_ready(step(filt, jax.random.key(0), state0, observations[0]))
    print("ready", flush=True)
    for line in sys.stdin:
        if line.strip() != "go":
            break
        state, ms = state0, []
        for i, tobs in enumerate(observations):
            t0 = time.perf_counter()
            state, info = step(filt, jax.random.key(i), state, tobs)
            jax.block_until_ready((state, info))
            ms.append(1e3 * (time.perf_counter() - t0))
        print(json.dumps(ms), flush=True)


def step_table(models, families, seq, before: pathlib.Path | None, rounds: int) -> list[str]:
    trees, lines = _table_start(
        before,
        "| model | filter | step ms |",
        "| model | filter | before ms | after ms | after / before (median of rounds) | range of rounds |",
    )
    for m in models:
        for fam in families:
            cmd = [sys.executable, __file__, "--worker", m, fam, str(seq)]
            workers = {
                k: subprocess.Popen(
                    cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=_env(tree)
                )
                for k, tree in trees.items()
            }
            for w in workers.values():  # both compile at once
                while w.stdout.readline().strip() != "ready":
                    if w.poll() is not None:
                        raise RuntimeError(f"step worker failed: {m} {fam}")
            med: dict = {k: [] for k in workers}
            for _ in range(rounds):
                for k, w in workers.items():
                    w.stdin.write("go\n")
                    w.stdin.flush()
                    med[k].append(float(np.median(json.loads(w.stdout.readline()))))
            for w in workers.values():
                w.stdin.close()
                w.wait()
            a = np.asarray(med["after"])
            if before is None:
                lines.append(f"| {m} | {fam} | {np.median(a):.1f} |")
            else:
                b = np.asarray(med["before"])
                r = a / b
                lines.append(
                    f"| {m} | {fam} | {np.median(b):.1f} | {np.median(a):.1f} | {np.median(r):.2f} "
                    f"| {r.min():.2f}–{r.max():.2f} |"
                )
            print(lines[-1], flush=True)
    return lines


# ---------------------------------------------------------------------------------------------------------------
# Tracks


def tracks_table(models, families, seq, before: pathlib.Path | None, seeds, work: pathlib.Path) -> list[str]:
    trees, lines = _table_start(
        before,
        "| model | filter | seeds | mean joint error mm |",
        "| model | filter | seeds | identical poses | largest difference | before mm | after mm |",
    )
    for m in models:
        for fam in families:
            poses: dict = {k: [] for k in trees}
            err: dict = {k: [] for k in trees}
            for seed in seeds:
                for k, tree in trees.items():
                    out = work / f"track_{k}"
                    env = dict(_env(tree), JAXMOCAP_CACHE_DIR=str(work / f"cache_{k}"))
                    cmd = track_command(seq, m, fam, out, "--seed", str(seed))
                    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
                    if proc.returncode != 0:
                        raise RuntimeError(f"{k} {m} {fam}: {(proc.stderr or proc.stdout).strip()[-300:]}")
                    poses[k].append(np.load(out / "poses.npz")["state"])
                    err[k].append(
                        json.loads((out / "diagnostics.json").read_text())["summary"]["mean_error_mm"]
                    )
            if before is None:
                lines.append(f"| {m} | {fam} | {len(seeds)} | {np.mean(err['after']):.1f} |")
            else:
                pairs = list(zip(poses["before"], poses["after"], strict=True))
                same = sum(bool(np.array_equal(p, q)) for p, q in pairs)
                diff = max(float(np.max(np.abs(p - q))) for p, q in pairs)
                b, a = (f"{np.mean(err[k]):.1f}" for k in ("before", "after"))
                lines.append(
                    f"| {m} | {fam} | {len(seeds)} | {same} of {len(seeds)} | {diff:.2g} | {b} | {a} |"
                )
            print(lines[-1], flush=True)
    return lines


def _before_note(before: pathlib.Path) -> str:
    """Where the before column comes from: the checkout and its commit."""
    proc = subprocess.run(
        ["git", "-C", str(before), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    )
    commit = proc.stdout.strip() or "unknown"
    return f"Before: the checkout `{before}` at commit {commit} (`--before {before}`), run in alternation with this one."


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", nargs="*", default=list(MODELS), choices=MODELS)
    ap.add_argument("--filters", nargs="*", default=list(FAMILIES), choices=list(FAMILIES))
    ap.add_argument("--before", type=pathlib.Path, help="another checkout to run side by side (first frame)")
    ap.add_argument("--programs", action="store_true", help="the programs table instead of the first frame")
    ap.add_argument("--isolate", action="store_true", help="programs: each row in a fresh interpreter")
    ap.add_argument(
        "--codegen", action="store_true", help="programs: XLA's default code generation against the suite's"
    )
    ap.add_argument(
        "--pieces", nargs="*", default=list(PIECES), choices=[*PIECES, *HYBRID_PIECES], help="programs: which"
    )
    ap.add_argument("--steps", action="store_true", help="the step-time table instead of the first frame")
    ap.add_argument("--rounds", type=int, help="rounds per configuration (first frame: 1, steps: 7)")
    ap.add_argument("--tracks", action="store_true", help="whole tracks of the sequence (of both checkouts)")
    ap.add_argument("--seeds", nargs="*", type=int, default=[0], help="tracks: the seeds")
    ap.add_argument("--quick", action="store_true", help="upper9 with the APF only (a smoke test)")
    ap.add_argument("--out", type=pathlib.Path, help="write the table (markdown) here as well")
    ap.add_argument("--row", nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--worker", nargs=3, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    os.environ["JAXMOCAP_CACHE_DIR"] = "off"
    os.environ.pop("JAX_COMPILATION_CACHE_DIR", None)
    if a.row:
        print(json.dumps(measure(a.row[0], a.row[1], pathlib.Path(a.row[2]), a.codegen)))
        return
    if a.worker:
        step_worker(a.worker[0], a.worker[1], pathlib.Path(a.worker[2]))
        return
    if a.quick:
        a.models, a.filters = ["upper9"], ["apf"]
    with tempfile.TemporaryDirectory(prefix="jaxmocap-compile-") as tmp:
        work = pathlib.Path(tmp)
        seq = make_sequence(work)
        load0 = os.getloadavg()[0]
        if a.programs:
            title = "Compile time of the tracker's programs (cache off)"
            lines = programs_table(a.models, seq, a.isolate, a.pieces, a.codegen)
        elif a.tracks:
            title = "Whole tracks of the sequence (16 frames; mean joint error against the ground truth)"
            lines = tracks_table(a.models, a.filters, seq, a.before, a.seeds, work)
        elif a.steps:
            title = "Run time of the compiled filter step (median over the frames of a round)"
            lines = step_table(a.models, a.filters, seq, a.before, a.rounds or 7)
        else:
            title = "First-frame latency of `jaxmocap track` (process start to one tracked frame, cache off)"
            lines = first_frame_table(a.models, a.filters, seq, a.before, work, a.rounds or 1)
        note = f"load average {load0:.2f} at the start, {os.getloadavg()[0]:.2f} at the end; {common.stamp()}"
        if a.before is not None:
            note += "\n\n" + _before_note(a.before)
        text = "\n".join([f"### {title}", "", *lines, "", note, ""])
        print(note)
        if a.out:  # the command without the other checkout (named in the note), as the register gives it
            args = sys.argv[1:] if argv is None else list(argv)
            if "--before" in args:
                i = args.index("--before")
                args = args[:i] + args[i + 2 :]
            common.write_result(a.out, text, " ".join(["python", common.script(__file__), *map(str, args)]))


if __name__ == "__main__":
    main()
