"""Speed of PARSEC bodytrack's likelihood: JAX (``jaxmocap.parsec.likelihood``) against a NumPy baseline.

Reports µs per particle per layer (one likelihood evaluation of every particle) for ``--particles`` states drawn
around sequenceB_2's initial pose with PoseParameters' standard deviations, 4 cameras, frame 0: the median and
minimum wall time of ``--repeats`` runs after compilation, the process CPU time, and the same for a NumPy
implementation of the same likelihood (vectorised over particles, float32 like the C++;
:func:`reference.numpy_baselines.np_loglik`) run in the same process.

Then bodytrack's own likelihood, built from source by this script (``benchmarks/bodytrack.py``: ``make -C
$BODYTRACK_SRC OUT=build/bodytrack``) and timed by its ``ll_bench`` (``TrackingModel::LogLikelihood`` on the same
number of states drawn the same way, frame 0), side by side with the JAX likelihood: ``--bodytrack-rounds``
interleaved A/B rounds, each as found and with one busy-loop process started by the script, the load average of
each round, the ratio per round and its median (``0`` skips it). ``benchmarks/perf/vs_bodytrack.py`` does the same
for the whole tracker.

    .venv/bin/python benchmarks/perf/bench_parsec.py [--particles 4000] [--repeats 9] [--devices 2] [--bodytrack-rounds 5]

``--devices 2`` splits the particles over two XLA host devices (one per core) with ``shard_map``.
``--pool-threads 1`` starts XLA's CPU backend with one intra-op thread instead of one per core (XLA sizes the pool
from the process's affinity mask: the mask is narrowed while the backend starts and restored after).

The likelihood is compiled as the PARSEC tracker compiles it (:func:`jaxmocap.parsec.likelihood.jit_loglik_batch`,
with :func:`jaxmocap.host.particle_options`; the header prints them). ``--xla-options NAME=VALUE ...`` compiles
the likelihood with XLA's defaults and once more per option (XLA debug options passed to
``compile(compiler_options=...)``, e.g. ``xla_cpu_prefer_vector_width=512``) and times each against the defaults
in the same process, ``--ab-rounds`` interleaved rounds (the order alternating), with the largest
difference of its log-likelihoods from the default's (0: bit-identical).

    .venv/bin/python benchmarks/perf/bench_parsec.py --bodytrack-rounds 0 --xla-options xla_cpu_prefer_vector_width=512

``--edge-chunks C[,C...] ...`` does the same for other edge samples per loop iteration
(:class:`jaxmocap.parsec.likelihood.Config`: ``8`` for every group, or one per group, ``12,12,8,8,6,6``):

    .venv/bin/python benchmarks/perf/bench_parsec.py --bodytrack-rounds 0 --edge-chunks 8 --ab-rounds 15

``--host-choices`` does the same for the four compilations of two choices (the pixel reads as gathers of their own
or fused into the sampling loop, which :func:`jaxmocap.host.gathers_apart` chooses by CPU; XLA's fusion emitters,
:func:`jaxmocap.host.particle_options`'s on every CPU, or its loop emitter, :data:`jaxmocap.host.LOOP_FUSION`), the
first row this CPU's compilation — to check the choices on a CPU they were not measured on; and, where
sequenceB_2's folder is there (``benchmarks/bodytrack.py``), the PARSEC tracker's step (:class:`bodytrack.Tracker`,
frames overlapped as ``jaxmocap track`` runs them) compiled with either emitter, at 4000 × 5 and 1000 × 3, as found
and beside one busy process, interleaved in this process (seconds per frame; its estimates differ only through
float rounding at pixel borders):

    .venv/bin/python benchmarks/perf/bench_parsec.py --bodytrack-rounds 0 --host-choices --ab-rounds 9

``--against REV`` does the same for the likelihood as it was at git revision ``REV``: the whole ``jaxmocap`` package
of ``REV`` (``git archive``, so its cylinders and cameras too) imported beside this checkout's; and, where
sequenceB_2's folder is there (``benchmarks/bodytrack.py``: ``$JAXMOCAP_DATA/parsec/sequenceB_2``), for the host side
of a frame, the observation of frame 0 as ``jaxmocap track`` reads it (``ParsecSource.observation``: four cameras'
BMPs decoded, binarised and filtered into bodytrack's edge maps), each revision's own, in ``--ab-rounds``
interleaved rounds of 20 calls (median per round; the maps compared bit for bit):

    .venv/bin/python benchmarks/perf/bench_parsec.py --bodytrack-rounds 0 --against main --ab-rounds 11
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import bodytrack
import common

DATA = common.ROOT / "tests" / "data" / "parsec"


def _args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--particles", type=int, default=4000)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--numpy-repeats", type=int, default=3)
    ap.add_argument("--devices", type=int, default=1, help="XLA host devices to split the particles over")
    ap.add_argument(
        "--pool-threads",
        type=int,
        default=0,
        help="start XLA's CPU backend with this many intra-op threads (its pool is sized from the affinity mask, "
        "narrowed for the backend's start only; 0: one per core, XLA's default)",
    )
    ap.add_argument(
        "--bodytrack-rounds",
        type=int,
        default=5,
        help="side-by-side rounds with bodytrack's ll_bench (0: none)",
    )
    ap.add_argument(
        "--xla-options", nargs="*", default=[], metavar="NAME=VALUE", help="A/B against the default"
    )
    ap.add_argument(
        "--edge-chunks", nargs="*", default=[], metavar="C[,C...]", help="A/B of Config(chunk=...)"
    )
    ap.add_argument(
        "--against", metavar="REV", help="A/B of the likelihood (its package) at git revision REV"
    )
    ap.add_argument(
        "--host-choices",
        action="store_true",
        help="A/B of the four compilations of the pixel reads apart or fused (jaxmocap.host's choice) and XLA's "
        "fusion or loop emitters",
    )
    ap.add_argument("--ab-rounds", type=int, default=7, help="interleaved rounds of the A/B options")
    return ap.parse_args(argv)


ARGS = _args() if __name__ == "__main__" else None
if ARGS is not None and ARGS.devices > 1:  # must precede the first import of jax
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={ARGS.devices}"
    )

import cv2  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from reference.numpy_baselines import np_loglik  # noqa: E402

from jaxmocap import host, parsec  # noqa: E402

if ARGS is not None and ARGS.pool_threads > 0:  # XLA sizes its intra-op pool from the affinity mask at start
    _allowed = os.sched_getaffinity(0)
    os.sched_setaffinity(0, set(sorted(_allowed)[: ARGS.pool_threads]))
    jax.devices()
    os.sched_setaffinity(0, _allowed)
from jaxmocap.parsec import likelihood as pl  # noqa: E402


def _png(p):
    return cv2.imread(str(p), cv2.IMREAD_UNCHANGED)


def _stats(t: common.Timings):
    """Median and minimum wall time, median CPU time."""
    return np.median(t.wall), np.min(t.wall), np.median(t.cpu)


def _option(text: str) -> dict:
    """``NAME=VALUE`` → ``{NAME: VALUE}`` with VALUE a bool, an int or a string."""
    name, _, value = text.partition("=")
    low = value.lower()
    v = low == "true" if low in ("true", "false") else int(value) if value.lstrip("-").isdigit() else value
    return {name: v}


def ab_table(progs: dict, X, obs, rounds: int, title: str, calls: int = 5) -> None:
    """Print ``progs`` (name → compiled likelihood; the first the baseline) timed interleaved in this process:
    median µs per particle (wall, process CPU) over ``rounds`` rounds of the median of ``calls`` calls, the
    per-round ratio baseline / this (above 1: this is faster), the median CPU ratio and the largest |Δ loglik|
    against the baseline."""
    base = next(iter(progs))
    ref = np.asarray(progs[base](X, obs))
    n = X.shape[0]
    wall = {k: [] for k in progs}
    cpu = {k: [] for k in progs}
    for r in range(rounds):
        for k in list(progs)[:: 1 if r % 2 == 0 else -1]:
            t = common.timed_calls(lambda k=k: progs[k](X, obs).block_until_ready(), calls, warmup=1)
            wall[k].append(np.median(t.wall) / n * 1e6)
            cpu[k].append(np.median(t.cpu) / n * 1e6)
    print(f"\n{title}, {rounds} interleaved rounds in this process (load {os.getloadavg()[0]:.1f}):\n")
    print(
        f"| compilation | µs/particle (median) | process CPU µs | {base} / this, per round | median | CPU ratio "
        "| max abs diff |"
    )
    print("|---|---|---|---|---|---|---|")
    for k, prog in progs.items():
        ratio = np.asarray(wall[base]) / np.asarray(wall[k])
        cratio = np.median(np.asarray(cpu[base]) / np.asarray(cpu[k]))
        diff = np.abs(np.asarray(prog(X, obs)) - ref).max()
        print(
            f"| {k} | {np.median(wall[k]):.2f} | {np.median(cpu[k]):.2f} | {', '.join(f'{x:.2f}' for x in ratio)} "
            f"| **{np.median(ratio):.2f}** | {cratio:.2f} | {diff:.1e} |"
        )


def host_choices(shape, cams) -> dict:
    """The likelihood compiled four ways (name → program), this CPU's own compilation first: gathers apart or fused
    (:func:`jaxmocap.host.gathers_apart`) × XLA's loop (:data:`jaxmocap.host.LOOP_FUSION`) or fusion emitters, each
    with :data:`jaxmocap.host.COPY_REGIONS`; "this CPU's choice" is what :func:`jaxmocap.host.gathers_apart` and
    :func:`jaxmocap.host.particle_options` give here."""
    chosen = (host.gathers_apart(), host.LOOP_FUSION.items() <= host.particle_options().items())
    ways = sorted(((a, loop) for a in (True, False) for loop in (True, False)), key=lambda w: w != chosen)
    progs = {}
    for apart, loop in ways:
        options = dict(host.COPY_REGIONS, **(host.LOOP_FUSION if loop else {}))
        name = f"{'apart' if apart else 'fused'}, {'loop' if loop else 'fusion'} emitters"
        name += " (this CPU's choice)" if (apart, loop) == chosen else ""
        fn = pl.make_loglik_batch(shape, cams, pl.Config(gathers_apart=apart))
        progs[name] = jax.jit(fn, compiler_options=options)
    return progs


def tracker_emitters_ab(rounds: int, sizes=((4000, 5), (1000, 3))) -> None:
    """Print the PARSEC tracker's seconds per frame with XLA's fusion emitters (:func:`jaxmocap.host.particle_options`)
    and with its loop emitter (:data:`jaxmocap.host.LOOP_FUSION` added), ``rounds`` interleaved rounds in this
    process, as found and beside one busy process (:func:`bodytrack.busy`): per round the median frame of two runs
    of the sequence (seeds 0, 1), the ratio loop / fusion per round (above 1: the fusion emitters are faster)."""
    seq = parsec.load_sequence(bodytrack.SEQ)
    ways = {"fusion": host.particle_options(), "loop": {**host.particle_options(), **host.LOOP_FUSION}}
    print(
        f"\nThe PARSEC tracker per frame with XLA's fusion or loop emitters, {rounds} interleaved rounds:\n"
    )
    print(
        "| particles × layers | condition | fusion s/frame | loop s/frame | loop / fusion, per round | median |"
    )
    print("|---|---|---|---|---|---|")
    for particles, layers in sizes:
        trackers = {k: bodytrack.Tracker(seq, particles, layers, options=o) for k, o in ways.items()}
        for t in trackers.values():
            t.run(0, overlap=True)  # compiles
        for condition in ("as found", "+1 busy process"):
            got = {k: [] for k in trackers}
            with bodytrack.busy(condition != "as found"):
                for r in range(rounds):
                    for k in list(trackers)[:: 1 if r % 2 == 0 else -1]:
                        runs = [trackers[k].run(seed, overlap=True).frame for seed in (0, 1)]
                        got[k].append(float(np.median(np.concatenate(runs))))
            ratio = np.asarray(got["loop"]) / np.asarray(got["fusion"])
            print(
                f"| {particles} × {layers} | {condition} | {np.median(got['fusion']):.4f} | "
                f"{np.median(got['loop']):.4f} | {', '.join(f'{q:.2f}' for q in ratio)} | **{np.median(ratio):.2f}** |"
            )


def likelihood_at(rev: str):
    """``jaxmocap.parsec.likelihood`` as of git revision ``rev``, with the rest of the package as of ``rev`` too (the
    cylinders, cameras and images it imports): :func:`common.package_at`."""
    return common.package_at(rev, "parsec.likelihood")


def observation_ab(rev: str, rounds: int, calls: int = 20) -> None:
    """Interleaved A/B of ``ParsecSource.observation(0)`` of sequenceB_2's folder: revision ``rev``'s package
    against this checkout's (module docstring); prints ms per call per round and the ratios."""
    from jaxmocap.parsec.inputs import ParsecSource

    at = common.package_at(rev, "parsec.inputs")
    sources = {rev: at.ParsecSource(bodytrack.SEQ), "this checkout": ParsecSource(bodytrack.SEQ)}
    maps = {k: s.observation(0) for k, s in sources.items()}
    same = all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(*maps.values(), strict=True))
    times: dict = {k: [] for k in sources}
    for r in range(rounds):
        for k in list(sources)[:: 1 if r % 2 == 0 else -1]:
            obs = sources[k].observation
            times[k].append(common.median_seconds(lambda o=obs: jax.block_until_ready(o(0)), calls, warmup=1))
    ratios = np.asarray(times[rev]) / np.asarray(times["this checkout"])
    print(
        f"\nA frame's observation (ParsecSource.observation, 4 cameras, 640x480) at {rev} and now, {rounds} "
        f"interleaved rounds of {calls} calls; the same maps: {same}"
    )
    for k, v in times.items():
        print(f"  {k:14s} ms per call, per round: " + ", ".join(f"{1e3 * t:.2f}" for t in v))
    print(f"  {rev} ÷ this checkout per round: " + ", ".join(f"{q:.2f}" for q in ratios))
    print(f"  median: {np.median(ratios):.2f}")


def main(args):
    seq = DATA / "sequenceB_2"
    shape = parsec.load_body_shape(seq / "BodyShapeParameters.txt")
    cams = parsec.load_cameras(seq)
    x0 = parsec.load_pose(seq / "InitialPose.txt")
    std = parsec.load_pose_parameters(seq / "PoseParameters.txt").std
    ims = np.stack([_png(DATA / "frames" / f"cam{k}_f0000.png") for k in range(1, 5)])
    fgs = np.stack([_png(DATA / "frames" / f"fg{k}_f0000.png") for k in range(1, 5)])
    edge = np.stack([parsec.edge_map(im) for im in ims])
    fg = (fgs != 0).astype(np.uint8)
    obs = pl.observation(edge, fg)
    N = args.particles
    X = (x0 + np.random.default_rng(0).normal(size=(N, 31)) * std).astype(np.float32)
    Xj = jnp.asarray(X)

    ll_fn = pl.make_loglik_batch(shape, cams)
    if args.devices > 1:
        from jax.sharding import Mesh, NamedSharding
        from jax.sharding import PartitionSpec as P

        mesh = Mesh(np.array(jax.devices()[: args.devices]), ("p",))
        f = jax.jit(
            jax.shard_map(ll_fn, mesh=mesh, in_specs=(P("p"), P()), out_specs=P("p"), check_vma=False),
            compiler_options=host.particle_options(),
        )
        Xj = jax.device_put(Xj, NamedSharding(mesh, P("p")))
        obs = jax.device_put(obs, NamedSharding(mesh, P()))
    else:
        f = pl.jit_loglik_batch(shape, cams)
    t0 = time.perf_counter()
    ll = np.asarray(f(Xj, obs))
    compile_s = time.perf_counter() - t0
    med, best, cpu = _stats(common.timed_calls(lambda: f(Xj, obs).block_until_ready(), args.repeats))

    ll_np = np_loglik(shape, cams, edge, fg, X)  # warm-up and agreement
    nmed, nbest, ncpu = _stats(
        common.timed_calls(lambda: np_loglik(shape, cams, edge, fg, X), args.numpy_repeats)
    )

    us = lambda s: s / N * 1e6
    print(f"PARSEC likelihood, {N} particles x 4 views (640x480), frame 0 of sequenceB_2")
    pool = sum(
        pathlib.Path(f"/proc/self/task/{t}/comm").read_text().strip() == "tf_XLAEigen"
        for t in (os.listdir("/proc/self/task") if os.path.isdir("/proc/self/task") else [])
    )
    print(
        f"  devices: {jax.devices()[: args.devices]}, cores visible: {os.cpu_count()}, XLA intra-op threads: {pool}, "
        f"load average: {os.getloadavg()}"
    )
    print(f"  CPU: {host.description()}; XLA options: {host.particle_options() or 'defaults'}")
    print(f"  JAX    compile+first run {compile_s:.1f} s")
    print(
        f"  JAX    µs/particle/layer: median {us(med):.2f}  min {us(best):.2f}  (process CPU {us(cpu):.2f})"
    )
    print(
        f"  NumPy  µs/particle/layer: median {us(nmed):.2f}  min {us(nbest):.2f}  (process CPU {us(ncpu):.2f})"
    )
    print(f"  speed-up JAX vs NumPy (median): {nmed / med:.1f}x")
    ok = (ll > -1e9) & (ll_np > -1e9)
    print(
        f"  agreement: valid flags equal {np.mean((ll > -1e9) == (ll_np > -1e9)):.4f}, "
        f"max |Δ loglik| {np.abs(ll[ok] - ll_np[ok]).max():.2e}, "
        f"exactly equal {np.mean(ll[ok] == ll_np[ok].astype(np.float32)):.3f}"
    )
    if args.xla_options:
        low = jax.jit(ll_fn).lower(Xj, obs)
        progs = {"default": low.compile()}
        progs.update({o: low.compile(compiler_options=_option(o)) for o in args.xla_options})
        ab_table(progs, Xj, obs, args.ab_rounds, "XLA compiler options")
    if args.edge_chunks:
        progs = {"default": f}
        for c in args.edge_chunks:
            chunk = tuple(int(v) for v in c.split(","))
            cfg = pl.Config(chunk=chunk[0] if len(chunk) == 1 else chunk)
            progs[f"chunk={c}"] = pl.jit_loglik_batch(shape, cams, cfg)
        ab_table(progs, Xj, obs, args.ab_rounds, "Edge samples per loop iteration (Config.chunk)")
    if args.host_choices:
        ab_table(
            host_choices(shape, cams),
            Xj,
            obs,
            args.ab_rounds,
            "The pixel reads apart or fused × XLA's fusion or loop emitters",
        )
        if bodytrack.SEQ.is_dir():
            tracker_emitters_ab(args.ab_rounds)
    if args.against:
        at = likelihood_at(args.against)
        options = common.particle_options_of(at)  # the options that revision compiles it with
        progs = {
            args.against: jax.jit(at.make_loglik_batch(shape, cams), compiler_options=options),
            "this checkout": f,
        }
        ab_table(progs, Xj, obs, args.ab_rounds, f"The likelihood at {args.against} and now")
        if bodytrack.SEQ.is_dir():
            observation_ab(args.against, args.ab_rounds)
    if args.bodytrack_rounds > 0:
        bodytrack.build()
        reps = 5
        jobs = {
            "likelihood µs/particle": (
                lambda: bodytrack.bodytrack_likelihood(N, reps)["us_median"],
                lambda: us(common.median_seconds(lambda: f(Xj, obs).block_until_ready(), reps, warmup=1)),
            )
        }
        rows = bodytrack.side_by_side(jobs, args.bodytrack_rounds, log=lambda s: None)
        print(
            f"\nbodytrack serial C++ (ll_bench, median of {reps}) vs JAX (median of {reps} after an untimed call), "
            "side by side:\n"
        )
        print(bodytrack.table(rows))


if __name__ == "__main__":
    sys.exit(main(ARGS))
