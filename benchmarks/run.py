"""Run the benchmarks and regenerate ``benchmarks/RESULTS.md``.

    python benchmarks/run.py                     # every benchmark except the slow experiments; updates RESULTS.md
    python benchmarks/run.py --all               # also the slow experiments (accuracy tables, hybrid filters)
    python benchmarks/run.py --only end_to_end scaling
    python benchmarks/run.py --quick             # tiny sizes, every benchmark (smoke test); writes nothing
    python benchmarks/run.py --quick --results /tmp/R.md   # … into another file
    python benchmarks/run.py --list

Each benchmark is a function ``(quick) -> markdown`` (a table, or the benchmark's printed report in a code block);
the numbers inside are medians over repeated runs after compilation, with ratios against baselines run in the same
process (see each module's docstring). ``RESULTS.md`` keeps its hand-written text: the runner only replaces what
lies between the markers ``<!-- generated:NAME begin -->`` and ``<!-- generated:NAME end -->`` (and appends a new
section when a benchmark has no markers yet). The ``machine`` block records the CPU model, cores, load average at
the start, versions and date of the last run.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import importlib
import io
import os
import pathlib
import platform
import re
import sys
import time
from collections.abc import Callable

os.environ.setdefault("JAX_PLATFORMS", "cpu")

HERE = pathlib.Path(__file__).resolve().parent
RESULTS = HERE / "RESULTS.md"


def _module(name: str):
    if str(HERE) not in sys.path:
        sys.path.insert(0, str(HERE))
    return importlib.import_module(name)


def _captured(fn: Callable, *args) -> str:
    """Run ``fn(*args)`` and return what it printed, in a code block (or its markdown return value)."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        ret = fn(*args)
    text = buf.getvalue().rstrip()
    if isinstance(ret, str) and ret.strip() and ret.strip() in text:
        return text
    return "```\n" + text + "\n```"


# ---------------------------------------------------------------------------------------------------------------
# The benchmarks


def _kinematics(quick: bool) -> str:
    m = _module("bench_kinematics")
    r = m.run(200, 2) if quick else m.run(4000, 7)
    return (
        f"`full25`, {r['points']} flesh points, {r['views']} views, {r['particles']} particles.\n\n"
        "| implementation | particles/s |\n|---|---|\n"
        f"| JAX (SoA FK, vmapped, one jit) | {r['jax_particles_per_s']:,.0f} |\n"
        f"| NumPy, same arithmetic vectorised over particles | {r['numpy_particles_per_s']:,.0f} |\n"
        f"| ratio | {r['ratio']:.1f}× |"
    )


def _parsec(quick: bool) -> str:
    m = _module("bench_parsec")
    argv = ["--particles", "100", "--repeats", "2", "--numpy-repeats", "1"] if quick else ["--repeats", "21"]
    return _captured(m.main, m._args(argv))


def _features(quick: bool) -> str:
    m = _module("bench_features")
    return _captured(m.main, ["--repeats", "3" if quick else "60"])


def _render(quick: bool) -> str:
    m = _module("bench_render")
    return _captured(m.main, ["--quick", "--repeats", "2"] if quick else [])


def _synth(quick: bool) -> str:
    m = _module("bench_synth")
    return _captured(m.main, ["--frames", "120:128", "--size", "160x120"] if quick else [])


def _likelihood(quick: bool) -> str:
    return _captured(_module("bench_likelihood").main, ["--quick"] if quick else ["--per-cue", "--sweep"])


def _iros(quick: bool) -> str:
    m = _module("iros_synthetic")
    return _captured(m.main, ["--quick"] if quick else [])


def _foreground(quick: bool) -> str:
    m = _module("foreground_iou")
    frames, size = ("120:126", "160x120") if quick else ("120:180", "640x480")
    return m.to_markdown(m.evaluate(frames, size), frames, size)


def _hybrid(quick: bool) -> str:
    m = _module("hybrid_vs_apf")
    return _captured(m.main, ["--quick"] if quick else [])


def _end_to_end(quick: bool) -> str:
    m = _module("end_to_end")
    return m.to_markdown(m.run(quick))


def _scaling(quick: bool) -> str:
    m = _module("scaling")
    md = m.main(["--quick"] if quick else [])
    return md if quick else md + "\n\n![likelihood scaling](results/scaling.png)"


def _accuracy(quick: bool) -> str:
    m = _module("accuracy")
    log = lambda s: print(s, file=sys.stderr, flush=True)  # noqa: E731
    if quick:
        return m.run(quick=True, out=None, log=log)
    md = m.run(log=log)
    return "Full tables: [results/accuracy.md](results/accuracy.md).\n\n" + md.split("\n", 2)[2]


@dataclasses.dataclass(frozen=True)
class Bench:
    title: str
    fn: Callable[[bool], str]
    command: str
    slow: bool = False


BENCHMARKS: dict[str, Bench] = {
    "kinematics": Bench("Forward kinematics + projection", _kinematics, "benchmarks/bench_kinematics.py"),
    "likelihood": Bench("Likelihood throughput vs NumPy", _likelihood, "benchmarks/bench_likelihood.py"),
    "parsec": Bench("PARSEC bodytrack likelihood", _parsec, "benchmarks/bench_parsec.py --repeats 21"),
    "features": Bench("Image features", _features, "benchmarks/bench_features.py --repeats 60"),
    "render": Bench("Rendering", _render, "benchmarks/bench_render.py"),
    "synth": Bench("Synthetic sequences", _synth, "benchmarks/bench_synth.py"),
    "end_to_end": Bench("Frames per second end to end", _end_to_end, "benchmarks/end_to_end.py"),
    "scaling": Bench("Likelihood scaling", _scaling, "benchmarks/scaling.py"),
    "iros": Bench("IROS 2007 synthetic experiment", _iros, "benchmarks/iros_synthetic.py"),
    "foreground": Bench("Foreground IoU", _foreground, "benchmarks/foreground_iou.py"),
    "accuracy": Bench("Tracking accuracy", _accuracy, "benchmarks/accuracy.py", slow=True),
    "hybrid": Bench("Hybrid vs APF", _hybrid, "benchmarks/hybrid_vs_apf.py", slow=True),
}


# ---------------------------------------------------------------------------------------------------------------
# Machine, versions, RESULTS.md


def cpu_model() -> str:
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_block(load: tuple[float, float, float]) -> str:
    import cv2
    import jax
    import jaxlib
    import numpy as np

    devices = ", ".join(sorted({f"{d.platform}" for d in jax.devices()}))
    return (
        f"Machine: {cpu_model()}, {os.cpu_count()} cores, load average at start {load[0]:.1f} / {load[1]:.1f} / "
        f"{load[2]:.1f} (1 / 5 / 15 min); JAX devices: {devices}.  \n"
        f"Versions: Python {platform.python_version()}, JAX {jax.__version__}, jaxlib {jaxlib.__version__}, "
        f"NumPy {np.__version__}, OpenCV {cv2.__version__}.  \n"
        f"Date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}."
    )


def _markers(name: str) -> tuple[str, str]:
    return f"<!-- generated:{name} begin -->", f"<!-- generated:{name} end -->"


def update_block(text: str, name: str, body: str, title: str | None = None) -> str:
    """``text`` with the block ``name`` replaced by ``body`` (appended as a new ``## title`` section if absent)."""
    begin, end = _markers(name)
    block = f"{begin}\n{body.strip()}\n{end}"
    pat = re.compile(re.escape(begin) + r".*?" + re.escape(end), re.S)
    if pat.search(text):
        return pat.sub(lambda _m: block, text, count=1)
    sep = "" if text.endswith("\n\n") or not text else ("\n" if text.endswith("\n") else "\n\n")
    head = f"## {title}\n\n" if title else ""
    return f"{text}{sep}{head}{block}\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick", action="store_true", help="tiny sizes (smoke test); writes only with --results"
    )
    ap.add_argument("--only", nargs="+", metavar="NAME", help="run only these benchmarks (see --list)")
    ap.add_argument("--all", action="store_true", help="include the slow experiments")
    ap.add_argument(
        "--results", default=None, help=f"file to update (default {RESULTS.name}, not with --quick)"
    )
    ap.add_argument("--list", action="store_true")
    a = ap.parse_args(argv)
    if a.list:
        for k, b in BENCHMARKS.items():
            print(f"{k:12s} {b.title}{'  (slow)' if b.slow else ''}")
        return 0
    unknown = [n for n in a.only or [] if n not in BENCHMARKS]
    if unknown:
        ap.error(f"unknown benchmark(s) {', '.join(unknown)}; choose from {', '.join(BENCHMARKS)}")
    names = a.only or [k for k, b in BENCHMARKS.items() if a.all or a.quick or not b.slow]
    out = pathlib.Path(a.results) if a.results else (None if a.quick else RESULTS)
    load = os.getloadavg()

    def write_block(name: str, body: str, title: str | None = None) -> None:
        # re-read before every write: another run (--only …) may have updated other blocks meanwhile
        if out is not None:
            text = out.read_text() if out.exists() else "# Benchmark results\n"
            out.write_text(update_block(text, name, body, title))

    write_block("machine", machine_block(load))
    failed = []
    for name in names:
        b = BENCHMARKS[name]
        print(f"== {name}: {b.title}", file=sys.stderr, flush=True)
        t0, la = time.monotonic(), os.getloadavg()[0]
        try:
            md = b.fn(a.quick)
        except Exception as e:  # keep going: one broken benchmark must not lose the others' results
            failed.append(name)
            md = f"**failed**: `{type(e).__name__}: {e}`"
            print(f"   {name} failed: {type(e).__name__}: {e}", file=sys.stderr, flush=True)
        dt = time.monotonic() - t0
        stamp = (
            f"_Generated {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} by `python benchmarks/run.py --only "
            f"{name}{' --quick' if a.quick else ''}` (same as `python {b.command}`), load average {la:.1f} at "
            f"start, {dt:.0f} s._"
        )
        print(md, flush=True)
        write_block(name, stamp + "\n\n" + md, b.title)  # after every benchmark: an interrupted run keeps it
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
