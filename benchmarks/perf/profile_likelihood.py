"""Where the compiled likelihood spends its time: XLA's own per-kernel trace of ``jax.jit(Likelihood.batch)``.

Runs a configuration of ``bench_likelihood.py`` (:data:`scenes.CONFIGS`) under ``jax.profiler.trace`` and sums the trace's kernel events
(XLA CPU "thunks": one fused loop, a scatter, a library reduction or dot, ...) by name over the profiled calls, then
lists the heaviest with what each fusion contains (counts of its HLO operations, from the compiled program's text),
so that a kernel that recomputes the projection (dozens of multiplies), gathers per point or transposes stands
out. Times are CPU time summed over both worker threads, per call; the tracer adds some overhead.

``--config parsec`` profiles PARSEC bodytrack's likelihood instead (:func:`jaxmocap.parsec.likelihood.jit_loglik_batch`,
``--particles`` states around sequenceB_2's initial pose, frame 0, as ``vs_bodytrack.py``); ``--by-kind`` adds the
times summed over the kernels of one kind (the name without its number: the sample-index kernels of every loop
together, say); ``--pool-threads 1`` starts XLA's CPU backend with one thread (each kernel's CPU time then is its
whole cost, without the other thread's waiting).

    .venv/bin/python benchmarks/perf/profile_likelihood.py                      # upper14 with the IROS 2007 cues
    .venv/bin/python benchmarks/perf/profile_likelihood.py --config full25-lk --top 15
    .venv/bin/python benchmarks/perf/profile_likelihood.py --config parsec --particles 4000 --by-kind --pool-threads 1
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import re
import sys
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import scenes


def fusion_contents(hlo: str) -> dict[str, collections.Counter]:
    """Kernel name → counts of the HLO operations in the computation it calls (compiled program text)."""
    comps = {
        m.group(1): m.group(2)
        for m in re.finditer(r"^(?:ENTRY )?%(\S+) (?:\(.*?\) -> .*? )?\{\n(.*?)^\}", hlo, re.S | re.M)
    }
    out = {}
    for name, comp in re.findall(r"%(\S+) = \S+ fusion\(.*?\), kind=\w+, calls=%(\S+?)[,\s]", hlo):
        out[name] = collections.Counter(re.findall(r"= \S+ ([a-z][\w-]*)\(", comps.get(comp, "")))
    return out


def kernel_times(trace_dir: str, calls: int) -> collections.Counter:
    """Kernel name → microseconds per call, from the Perfetto trace JAX wrote into ``trace_dir``."""
    path = sorted(glob.glob(f"{trace_dir}/**/perfetto_trace.json.gz", recursive=True))[-1]
    with gzip.open(path) as f:
        events = json.load(f)["traceEvents"]
    tot: collections.Counter = collections.Counter()
    for e in events:
        name = e.get("name", "")
        if e.get("ph") == "X" and "Execute" not in name and not name.startswith(("$", "Pjit")):
            tot[name] += e["dur"] / calls
    return tot


def problem(config: str, particles: int):
    """``(f, args)``: the jitted likelihood of ``config`` and its arguments (``f(*args)`` evaluates the batch)."""
    rng = np.random.default_rng(0)
    if config == "parsec":
        import bodytrack

        from jaxmocap import parsec

        f, X, obs = bodytrack.likelihood_problem(parsec.load_sequence(bodytrack.SEQ), particles)
        return f, (X, obs)
    model, rig, obs, lik, _ = scenes.build(config, rng)
    X = jnp.asarray(scenes.particles(model, particles, rng))
    return jax.jit(lambda X, obs: lik.batch(X, obs, 0)), (X, obs)


def by_kind(times: collections.Counter) -> collections.Counter:
    """Kernel times summed by kind: the kernel's name without its trailing number (``while`` spans include the
    kernels they run)."""
    out: collections.Counter = collections.Counter()
    for name, us in times.items():
        out[re.sub(r"\.\d+$", "", name)] += us
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--config",
        default="upper14-iros",
        choices=sorted({**scenes.CONFIGS, **scenes.SAMPLE_SWEEP}) + ["parsec"],
    )
    ap.add_argument("--particles", type=int, default=8192)
    ap.add_argument("--calls", type=int, default=3)
    ap.add_argument("--top", type=int, default=12)
    ap.add_argument(
        "--by-kind", action="store_true", help="also the times summed over the kernels of one kind"
    )
    ap.add_argument("--pool-threads", type=int, default=0, help="XLA CPU threads (0: one per core)")
    a = ap.parse_args(argv)
    from jaxmocap import host

    host.limit_cpu_threads(a.pool_threads)
    f, args = problem(a.config, a.particles)
    f(*args).block_until_ready()
    contents = fusion_contents(f.lower(*args).compile().as_text())
    with tempfile.TemporaryDirectory() as d:
        with jax.profiler.trace(d, create_perfetto_trace=True):
            for _ in range(a.calls):
                f(*args).block_until_ready()
        times = kernel_times(d, a.calls)
    total = sum(times.values())
    print(f"{a.config}, {a.particles} particles: {total / 1e3:.1f} ms of kernel time per call")
    if a.by_kind:
        print("| kernels of a kind | ms per call |\n|---|---|")
        for kind, us in by_kind(times).most_common(a.top):
            print(f"| {kind} | {us / 1e3:.2f} |")
    print("| kernel | ms per call | share | operations (heaviest first) |")
    print("|---|---|---|---|")
    for name, us in times.most_common(a.top):
        ops = contents.get(name, collections.Counter())
        heavy = {
            k: v for k, v in ops.most_common() if k not in ("parameter", "constant", "bitcast", "broadcast")
        }
        text = ", ".join(f"{k} {v}" for k, v in list(heavy.items())[:8])
        print(f"| {name} | {us / 1e3:.2f} | {us / total:.0%} | {text} |")


if __name__ == "__main__":
    main()
