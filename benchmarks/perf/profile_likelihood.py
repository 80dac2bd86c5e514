"""Where the compiled likelihood spends its time: XLA's own per-kernel trace of ``jax.jit(Likelihood.batch)``.

Runs a configuration of ``bench_likelihood.py`` (:data:`scenes.CONFIGS`) under ``jax.profiler.trace`` and sums the trace's kernel events
(XLA CPU "thunks": one fused loop, a scatter, a library reduction or dot, ...) by name over the profiled calls, then
lists the heaviest with what each fusion contains (counts of its HLO operations, from the compiled program's text),
so that a kernel that recomputes the projection (dozens of multiplies), gathers per point or transposes stands
out. Times are CPU time summed over both worker threads, per call; the tracer adds some overhead.

    .venv/bin/python benchmarks/perf/profile_likelihood.py                      # upper14 with the IROS 2007 cues
    .venv/bin/python benchmarks/perf/profile_likelihood.py --config full25-lk --top 15
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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--config", default="upper14-iros", choices=sorted({**scenes.CONFIGS, **scenes.SAMPLE_SWEEP})
    )
    ap.add_argument("--particles", type=int, default=8192)
    ap.add_argument("--calls", type=int, default=3)
    ap.add_argument("--top", type=int, default=12)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    model, rig, obs, lik, _ = scenes.build(a.config, rng)
    X = jnp.asarray(scenes.particles(model, a.particles, rng))
    f = jax.jit(lik.batch)
    f(X, obs, 0).block_until_ready()
    contents = fusion_contents(f.lower(X, obs, 0).compile().as_text())
    with tempfile.TemporaryDirectory() as d:
        with jax.profiler.trace(d, create_perfetto_trace=True):
            for _ in range(a.calls):
                f(X, obs, 0).block_until_ready()
        times = kernel_times(d, a.calls)
    total = sum(times.values())
    print(f"{a.config}, {a.particles} particles: {total / 1e3:.1f} ms of kernel time per call")
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
