"""Scaling benchmarks of :mod:`jaxmocap.filters.sharding`: throughput vs device count, peak memory vs particles.

Scene: the bundled CMU walk synthesised for a stereo rig at 96×72 (``--frames``), the ``upper9`` model and the
tracker's likelihood (``foreground`` + ``coverage``, :mod:`jaxmocap.tracking.tracker`). Every measurement runs in its own
subprocess, since ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` must be set before ``jax`` is imported:

1. **sharded particles**: the APF step (``--layers`` layers) with ``--particles`` particles split over ``N``
   forced host devices (:func:`jaxmocap.filters.sharding.sharded_step`), median seconds per frame after compilation;
2. **batched seeds**: ``--seeds`` seeds of the same APF over all frames in one call
   (:func:`jaxmocap.filters.sharding.batched_run`), the seeds spread over the ``N`` devices; run-frames per second;
3. **memory vs particles**: the likelihood on ``N`` particles whole and in chunks of ``--chunk``
   (:func:`jaxmocap.filters.sharding.chunked`): XLA's buffer assignment of the compiled call (``memory_analysis``:
   temporaries + arguments + outputs, exact and without running it), and, for the sizes in ``--run-sizes``, the
   peak resident memory (``ru_maxrss``) of a process that evaluates it once, against the same process before the
   evaluation.

Forced host devices are partitions of the same CPU: on a machine with few cores they share them, so their
throughput shows the overhead of the SPMD program, not a speed-up; the same script measures real devices (GPUs)
unchanged.

    .venv/bin/python benchmarks/perf/bench_scale.py [--devices 1,2] [--particles 2048] [--out benchmarks/results/scale.md]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common

ROOT = str(common.ROOT)


def _child(args) -> dict:
    import resource

    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxmocap.filters import sharding as scale
    from jaxmocap.filters.factory import make_filter
    from jaxmocap.tracking import sweep

    spec = sweep.make_spec(
        sequences=[args.seq], filters=["apf"], model="upper9", cues="foreground,coverage", layers=args.layers
    )
    prep = sweep._Prepared(args.seq, spec)
    tr = prep.setup_for("apf", args.layers)
    dt = tr.model.offset.dtype
    x0 = jnp.asarray(prep.x0, dt)
    out = {"devices": jax.device_count(), "frames": len(prep.frames)}

    def make(n):
        return make_filter(
            "apf", tr.loglik, tr.model, tr.std, n, tr.layers, prep.x0, 3.0 * tr.std, tr.o.survival_target
        )

    if args.task == "throughput":
        mesh = scale.device_mesh()
        f = make(args.particles)
        step = scale.sharded_step(f, mesh)
        state = scale.shard_state(f.init(jax.random.key(0), x0), mesh)
        obs = [
            jax.tree_util.tree_map(lambda a, t=t: a[t], prep.observations) for t in range(len(prep.frames))
        ]
        times = []
        for t, o in enumerate(obs):
            t0 = time.perf_counter()
            state, info = step(jax.random.key(t), state, o)
            jax.block_until_ready(info)
            times.append(time.perf_counter() - t0)
        out["compile_and_first_s"] = times[0]
        out["step_s"] = float(np.median(times[1:]))
        # batched seeds over all frames, spread over the devices
        bmesh = scale.device_mesh(None, scale.BATCH_AXIS)
        g = make(args.batch_particles)
        keys = jax.vmap(jax.random.key)(jnp.arange(args.seeds, dtype=jnp.uint32))
        states = scale.batched_init(g, keys, x0)
        res = []
        for _ in range(2):  # the first call compiles
            t0 = time.perf_counter()
            jax.block_until_ready(scale.batched_run(g, keys, states, prep.observations, bmesh))
            res.append(time.perf_counter() - t0)
        out["batched_s"] = res[1]
        out["run_frames_per_s"] = args.seeds * len(prep.frames) / res[1]
    else:
        obs0 = jax.tree_util.tree_map(lambda a: a[0], prep.observations)
        loglik = tr.loglik if args.chunk <= 0 else scale.chunked(tr.loglik, args.chunk)
        fn = jax.jit(lambda X, o: loglik(X, o, 0))
        X = jax.ShapeDtypeStruct((args.n, tr.model.num_dofs), dt)
        m = fn.lower(X, obs0).compile().memory_analysis()
        out["compiled_bytes"] = int(m.temp_size_in_bytes + m.argument_size_in_bytes + m.output_size_in_bytes)
        out["temp_bytes"] = int(m.temp_size_in_bytes)
        if args.execute:
            Xv = x0 + 0.05 * jax.random.normal(jax.random.key(0), (args.n, tr.model.num_dofs), dt)
            jax.block_until_ready(fn(Xv[:8], obs0))  # warm the runtime: the baseline includes it
            before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
            t0 = time.perf_counter()
            ll = jax.block_until_ready(fn(Xv, obs0))
            out["eval_s"] = time.perf_counter() - t0  # includes this size's compilation
            out["maxrss_increase_bytes"] = 1024 * (
                resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
            )
            out["finite"] = int(np.isfinite(np.asarray(ll)).sum())
    return out


def _spawn(devices: int, extra: list[str], timeout: float) -> dict:
    env = dict(os.environ, JAX_PLATFORMS="cpu", XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}")
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    cmd = [sys.executable, os.path.abspath(__file__), "--child", *extra]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
    if p.returncode != 0:
        return {"error": p.stderr.strip().splitlines()[-1] if p.stderr.strip() else f"exit {p.returncode}"}
    return json.loads(p.stdout.strip().splitlines()[-1])


def _mb(b) -> str:
    return "—" if b is None else f"{b / 2**20:,.0f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--task", default="throughput", help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--execute", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument(
        "--seq", help="a synthetic sequence folder (default: synthesised into a temporary folder)"
    )
    ap.add_argument("--frames", default="0:24", help="source frames of the 120 fps clip (at 60 fps)")
    ap.add_argument("--devices", default="1,2", help="forced host device counts")
    ap.add_argument("--particles", type=int, default=2048, help="particles of the sharded step")
    ap.add_argument("--batch-particles", type=int, default=256, help="particles of each batched run")
    ap.add_argument("--seeds", type=int, default=4, help="seeds of the batched runs")
    ap.add_argument("--layers", type=int, default=2)
    ap.add_argument("--sizes", default="10000,100000,1000000", help="particle counts of the memory table")
    ap.add_argument("--run-sizes", default="100000", help="sizes also executed for the resident memory")
    ap.add_argument("--chunk", type=int, default=16384, help="likelihood chunk (particles)")
    ap.add_argument("--out", help="write the Markdown tables here")
    args = ap.parse_args()
    if args.child:
        print(json.dumps(_child(args)))
        return

    with tempfile.TemporaryDirectory() as tmp:
        seq = args.seq
        if seq is None:
            from jaxmocap.synth import generate as synth

            seq = os.path.join(tmp, "seq")
            synth.synthesize("demo", seq, rig="stereo", frames=args.frames, fps=60.0, size="96x72", seed=0)
        seq_args = ["--seq", seq, "--layers", str(args.layers)]
        lines = [
            f"load average at start: {os.getloadavg()[0]:.1f} on {os.cpu_count()} logical CPUs",
            "",
            f"### Throughput vs forced host devices (APF, {args.layers} layers, upper9, foreground + coverage)",
            "",
            f"| devices | sharded step, {args.particles} particles (s/frame) | first frame incl. compile (s) | "
            f"{args.seeds} seeds × {args.batch_particles} particles batched (run-frames/s) |",
            "|---|---|---|---|",
        ]
        for d in [int(x) for x in args.devices.split(",") if x]:
            extra = seq_args + ["--task", "throughput", "--particles", str(args.particles)]
            extra += ["--batch-particles", str(args.batch_particles), "--seeds", str(args.seeds)]
            r = _spawn(d, extra, 1200)
            print(d, r, flush=True)
            if "error" in r:
                lines.append(f"| {d} | error: {r['error']} | | |")
                continue
            lines.append(
                f"| {r['devices']} | {r['step_s']:.3f} | {r['compile_and_first_s']:.1f} | {r['run_frames_per_s']:.1f} |"
            )
        lines += [
            "",
            f"### Likelihood memory vs particles (one device; chunk = {args.chunk} particles)",
            "",
            "| particles | compiled buffers, whole (MiB) | compiled buffers, chunked (MiB) | "
            "peak RSS increase, whole (MiB) | peak RSS increase, chunked (MiB) |",
            "|---|---|---|---|---|",
        ]
        run_sizes = {int(x) for x in args.run_sizes.split(",") if x}
        for n in [int(x) for x in args.sizes.split(",") if x]:
            row = {}
            for label, chunk in (("whole", 0), ("chunked", args.chunk)):
                extra = seq_args + ["--task", "memory", "--n", str(n), "--chunk", str(chunk)]
                if n in run_sizes:
                    extra.append("--execute")
                row[label] = r = _spawn(1, extra, 1200)
                print(n, label, r, flush=True)
            w, c = row["whole"], row["chunked"]
            lines.append(
                f"| {n:,} | {_mb(w.get('compiled_bytes'))} | {_mb(c.get('compiled_bytes'))} | "
                f"{_mb(w.get('maxrss_increase_bytes'))} | {_mb(c.get('maxrss_increase_bytes'))} |"
            )
        text = "\n".join(lines) + "\n"
        print(text)
        if args.out:
            with open(args.out, "w") as f:
                f.write(text)


if __name__ == "__main__":
    t0 = time.time()
    main()
