"""Instructions per particle of PARSEC's likelihood, ours and bodytrack's, counted by valgrind (load-independent).

Times on a shared machine move with its load and with the CPU it is given; the number of instructions a program
executes does not move with the load (``valgrind --tool=callgrind`` counts them, whatever else runs). This script
counts, per particle and likelihood evaluation of frame 0 of sequenceB_2 (``--particles`` states around its initial
pose, as ``vs_bodytrack.py``):

* **bodytrack**: its ``ll_bench`` (``TrackingModel::LogLikelihood`` particle by particle), built from source by
  :mod:`bodytrack`, run twice under callgrind with 1 and ``1 + --calls`` repeats: the difference is the
  evaluations alone (image loading and setup cancel);
* **jaxmocap**, for each compilation in ``--variants`` (``default``: :func:`jaxmocap.parsec.likelihood.jit_loglik_batch`
  as the tracker compiles it on this CPU; ``emitters``: XLA's fusion emitters; ``loops``: its loop fusion emitter):
  a child process compiles the likelihood natively into a fresh compilation cache, then runs again under callgrind
  with instrumentation off until the program is loaded and has run once; ``callgrind_control`` turns it on while
  the child waits, the child makes ``--calls`` calls, and instrumentation is turned off while it waits again. The
  count is every thread's instructions in that window (XLA's two workers; the Python thread's polling for the
  signal files adds a few thousand).

valgrind reports a CPU without AVX-512 to the program it runs, so XLA compiles the AVX2 code under it on any host:
the counts are those of that code. Instructions are not time: they say how much work each program does, not how
fast a core retires it (``vs_bodytrack.py`` for time, side by side).

    python benchmarks/perf/instructions.py [--particles 400] [--calls 2] [--out benchmarks/results/instructions.md]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re
import shutil
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import bodytrack as bt
import common

from jaxmocap import host

VARIANTS = {
    "default": None,  # what jit_loglik_batch uses on this CPU
    "emitters": {"xla_cpu_use_fusion_emitters": True},
    "loops": {"xla_cpu_use_fusion_emitters": False},
}

CHILD = r"""
import json, os, sys, time
import numpy as np, jax, jax.numpy as jnp
jax.config.update("jax_compilation_cache_dir", sys.argv[1])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
from jaxmocap import parsec
from jaxmocap.parsec import likelihood as pl
seq = parsec.load_sequence(sys.argv[2])
obs = seq.observation(0)
n, calls, options = int(sys.argv[3]), int(sys.argv[4]), json.loads(sys.argv[5])
X = (seq.initial_pose + np.random.default_rng(0).normal(size=(n, 31)) * seq.pose_std).astype(np.float32)
X = jnp.asarray(X)
if options is None:
    f = pl.jit_loglik_batch(seq.shape, seq.cameras)
else:
    f = jax.jit(pl.make_loglik_batch(seq.shape, seq.cameras), compiler_options=options)
ll = np.asarray(f(X, obs))
print("READY", os.getpid(), flush=True)
go = sys.argv[6]
while go != "-" and not os.path.exists(go):
    time.sleep(0.2)
for _ in range(calls):
    f(X, obs).block_until_ready()
print("DONE", float(np.mean(ll[ll > -1e9])), flush=True)
while go != "-" and not os.path.exists(go + ".stop"):
    time.sleep(0.2)
"""

#: seconds for valgrind to apply a ``callgrind_control`` request (it is served between the child's waits)
SETTLE = 10.0


def _total(path: pathlib.Path) -> int:
    """The instruction total of a callgrind output file: its ``totals:`` line (under ``--instr-atstart=no`` the
    ``summary:`` line read 0 here while ``totals:`` held the count), else ``summary:``."""
    text = path.read_text()
    for key in ("totals", "summary"):
        m = re.search(rf"^{key}:\s+(\d+)", text, re.M)
        if m:
            return int(m.group(1))
    raise RuntimeError(f"no instruction total in {path}")


def bodytrack_count(particles: int, calls: int, work: pathlib.Path) -> int:
    """Instructions of ``calls`` evaluations of ``particles`` states by bodytrack's ``ll_bench``."""
    exe = bt.build() / "ll_bench"
    totals = []
    for repeats in (1, 1 + calls):
        out = work / f"bodytrack.{repeats}.out"
        subprocess.run(
            ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", str(exe), str(bt.SEQ)]
            + [str(particles), str(repeats)],
            check=True,
            capture_output=True,
        )
        totals.append(_total(out))
    return totals[1] - totals[0]


def jaxmocap_count(options, particles: int, calls: int, work: pathlib.Path, log=print) -> tuple[int, float]:
    """Instructions of ``calls`` evaluations of ``particles`` states by the compiled likelihood (``options``: XLA
    compiler options, None for :func:`jaxmocap.parsec.likelihood.jit_loglik_batch`), and its mean log-likelihood."""
    cache = pathlib.Path(tempfile.mkdtemp(dir=work))
    args = [cache, bt.SEQ, particles, calls, json.dumps(options)]
    # natively first: fills the compilation cache, so that the run under valgrind loads the program
    subprocess.run([sys.executable, "-c", CHILD, *map(str, args), "-"], check=True, capture_output=True)
    go, out = work / f"go.{cache.name}", work / f"callgrind.{cache.name}.out"
    cmd = ["valgrind", "--tool=callgrind", "--instr-atstart=no", f"--callgrind-out-file={out}"]
    proc = subprocess.Popen(
        cmd + [sys.executable, "-c", CHILD, *map(str, args), str(go)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    t0 = time.monotonic()
    line = proc.stdout.readline()
    if not line.startswith("READY"):
        proc.kill()
        raise RuntimeError(f"the child under valgrind did not start: {line!r}")
    pid = line.split()[1]
    log(f"  under valgrind, loaded in {time.monotonic() - t0:.0f} s")
    # instrumentation on while the child waits, then its calls, then off while it waits again: the requests are
    # served asynchronously, so each gets time to take effect before the child moves on
    subprocess.run(["callgrind_control", "-i", "on", pid], check=True, capture_output=True)
    time.sleep(SETTLE)
    go.touch()
    done = proc.stdout.readline()
    subprocess.run(["callgrind_control", "-i", "off", pid], check=True, capture_output=True)
    time.sleep(SETTLE)
    pathlib.Path(f"{go}.stop").touch()
    proc.wait(timeout=600)
    if not done.startswith("DONE"):
        raise RuntimeError(f"the child under valgrind did not finish: {done!r}")
    return _total(out), float(done.split()[1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--particles", type=int, default=400)
    ap.add_argument("--calls", type=int, default=2)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--out", type=pathlib.Path)
    a = ap.parse_args(argv)
    if shutil.which("valgrind") is None or shutil.which("callgrind_control") is None:
        sys.exit("valgrind (with callgrind_control) is needed: apt-get install valgrind")
    evals = a.particles * a.calls
    rows = []
    with tempfile.TemporaryDirectory() as d:
        work = pathlib.Path(d)
        print(f"bodytrack ll_bench, {a.particles} particles, {a.calls} + 1 against 1 repeats", flush=True)
        bt_count = bodytrack_count(a.particles, a.calls, work)
        rows.append(("bodytrack `ll_bench` (g++ -O2, serial)", bt_count / evals, None))
        for name in a.variants:
            options = VARIANTS[name]
            print(f"jaxmocap {name}", flush=True)
            count, mean_ll = jaxmocap_count(options, a.particles, a.calls, work)
            label = (host.particle_options() or "XLA defaults") if options is None else options
            rows.append((f"jaxmocap `{name}` ({label})", count / evals, mean_ll))
    if any(per <= 0 for _, per, _ in rows):
        sys.exit("a count is zero: valgrind did not apply the instrumentation request (raise SETTLE)")
    base = rows[0][1]
    lines = [
        f"# Instructions per particle: PARSEC's likelihood, jaxmocap and bodytrack\n\n"
        f"{common.stamp()}; {common.machine_line()}; counted by `valgrind --tool=callgrind` (which reports a CPU "
        f"without AVX-512 to the programs it runs: the AVX2 code on any host). {a.particles} states of frame 0 of "
        f"sequenceB_2 around its initial pose, {a.calls} evaluations each; per particle and evaluation.\n",
        "| program | instructions per particle | ÷ bodytrack | mean log-likelihood |",
        "|---|---|---|---|",
    ]
    for name, per, mean_ll in rows:
        ll = "" if mean_ll is None else f"{mean_ll:.4f}"
        lines.append(f"| {name} | {per:,.0f} | {per / base:.2f} | {ll} |")
    lines.append(
        "\nReading: the ratio is work, not time (a core retires the vectorisable code faster); the same counts on any "
        "load. XLA's code is compiled for the CPU valgrind reports, so on a CPU with AVX-512 the program that runs "
        "natively is another one (`jaxmocap.host`): compare these counts only with counts, and times only side by "
        "side (`vs_bodytrack.py`)."
    )
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        common.write_result(a.out, text, f"python benchmarks/perf/instructions.py --out {a.out}")


if __name__ == "__main__":
    main()
