"""What the benchmark scripts share: where things are, timing, and writing a results file.

Every script under ``benchmarks/perf/`` and ``benchmarks/experiments/`` starts with the one line

    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules

so that ``common`` (this module), ``scenes`` and ``reference`` import the same way whether the script runs as
``python benchmarks/perf/bench_likelihood.py`` from the repository root, is loaded by ``benchmarks/run.py`` or by a
test. Scripts import these modules only, never each other.

Timing: :func:`timed_calls` times one function ``repeats`` times (wall clock and process CPU time of each call);
:func:`interleaved_rounds` times several functions round-robin, so that a load that changes over time on a shared
machine hits all of them alike. Both return the raw samples; the scripts report medians (and minima) of them.
"""

from __future__ import annotations

import pathlib
import time
from collections.abc import Callable, Hashable
from typing import NamedTuple

import numpy as np

from jaxmocap import host

# every benchmark runs as an application of its own: the garbage collector's thresholds of the command line
# (tracing JAX programs under CPython's own thresholds spent 8-10 % of the time in collections)
host.relax_gc()

BENCH = pathlib.Path(__file__).resolve().parent
ROOT = BENCH.parent
RESULTS = BENCH / "results"


def script(file: str) -> str:
    """The path of a script (its ``__file__``) relative to the repository root, as a command names it:
    ``benchmarks/perf/bench_likelihood.py``."""
    return pathlib.Path(file).resolve().relative_to(ROOT).as_posix()


class Timings(NamedTuple):
    """Per-call samples in seconds: ``wall (R,)`` (``time.perf_counter``) and ``cpu (R,)`` (process CPU time of
    every thread, ``time.process_time``)."""

    wall: np.ndarray
    cpu: np.ndarray


def timed_calls(fn: Callable[[], object], repeats: int, warmup: int = 0) -> Timings:
    """Call ``fn()`` ``warmup`` times untimed, then ``repeats`` times, each timed alone. ``fn`` must wait for its
    result (``block_until_ready``) for the wall time to mean anything. The wall interval spans the call only (the
    CPU clock is read outside it)."""
    for _ in range(warmup):
        fn()
    wall, cpu = [], []
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return Timings(np.asarray(wall), np.asarray(cpu))


def median_seconds(fn: Callable[[], object], repeats: int, warmup: int = 0) -> float:
    """The median wall time of :func:`timed_calls` (seconds)."""
    return float(np.median(timed_calls(fn, repeats, warmup).wall))


def interleaved_rounds(
    fns: dict[Hashable, Callable], rounds: int, args: Callable[[int], tuple] = lambda r: ()
) -> dict[Hashable, np.ndarray]:
    """Wall seconds of every function of ``fns`` over ``rounds`` rounds, each round calling every function once
    (in the dict's order) with the arguments ``args(round)``. Returns name → ``(rounds,)`` samples."""
    times: dict[Hashable, list[float]] = {k: [] for k in fns}
    for r in range(rounds):
        a = args(r)
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn(*a)
            times[k].append(time.perf_counter() - t0)
    return {k: np.asarray(v) for k, v in times.items()}


def stamp() -> str:
    """The current time as results files give it: ``2026-11-22 05:36 UTC``."""
    return time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())


def machine_line() -> str:
    """``"<CPU> (family, model; vector ISA), <n> cores, load average <1 min>"`` (:func:`jaxmocap.host.description`:
    XLA compiles for the CPU it finds, so figures compare only on the same one; the machine is shared: the load
    says how much)."""
    import os

    from jaxmocap import host

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return f"{host.description()}, {os.cpu_count()} cores, load average {load:.1f}"


def regenerate_line(command: str) -> str:
    """The first line of a Markdown results file: the command that regenerates it, as an HTML comment."""
    return f"<!-- Regenerate: {command} -->\n"


def write_result(path: pathlib.Path, text: str, command: str) -> pathlib.Path:
    """Write the Markdown ``text`` to ``path`` (``results/…`` by default in the scripts), its first line naming
    ``command``; creates the folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(regenerate_line(command) + text)
    return path


def report(path: pathlib.Path, text: str, command: str, write: bool = True) -> str:
    """Print a script's Markdown ``text`` and, with ``write``, save it with :func:`write_result`; returns it."""
    print(text)
    if write:
        write_result(path, text + "\n", command)
    return text


def package_at(rev: str, module: str):
    """``jaxmocap.<module>`` as of git revision ``rev``, with the rest of the package as of ``rev`` too: ``jaxmocap/``
    of ``rev`` extracted with ``git archive`` into a temporary folder as the package ``jaxmocap_at_rev``, its imports
    renamed, imported beside this checkout's (for same-process A/B timings, ``--against REV``)."""
    import importlib
    import re
    import subprocess
    import sys
    import tempfile

    root = pathlib.Path(tempfile.mkdtemp())
    tar = subprocess.run(
        ["git", "-C", str(ROOT), "archive", rev, "jaxmocap"], check=True, capture_output=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(root)], input=tar, check=True)
    pkg = root / "jaxmocap_at_rev"
    (root / "jaxmocap").rename(pkg)
    for f in pkg.rglob("*.py"):
        text = f.read_text()
        text = re.sub(r"\bfrom jaxmocap(?=[. ])", "from jaxmocap_at_rev", text)
        text = re.sub(r"\bimport jaxmocap\.", "import jaxmocap_at_rev.", text)
        text = re.sub(r"(?<![\w.])jaxmocap\.(?=[a-z_]+\.)", "jaxmocap_at_rev.", text)
        f.write_text(text)
    sys.path.insert(0, str(root))
    try:
        return importlib.import_module(f"jaxmocap_at_rev.{module}")
    finally:
        sys.path.remove(str(root))


def particle_options_of(module) -> dict:
    """The XLA options that the package holding ``module`` (this checkout's or :func:`package_at`'s) compiles
    PARSEC's programs with: its ``host.particle_options()``, or ``host.loop_fusion_options()`` before 2026-11-30."""
    import importlib

    host = importlib.import_module(module.__name__.split(".")[0] + ".host")
    return (getattr(host, "particle_options", None) or host.loop_fusion_options)()


def checkout_at(rev: str, into: pathlib.Path) -> pathlib.Path:
    """``jaxmocap/`` of git revision ``rev`` extracted into ``into``; returns ``into``."""
    import subprocess

    tar = subprocess.run(
        ["git", "-C", str(ROOT), "archive", rev, "jaxmocap"], check=True, capture_output=True
    ).stdout
    into.mkdir(parents=True)
    subprocess.run(["tar", "-x", "-C", str(into)], input=tar, check=True)
    return into


def run_python(
    root: pathlib.Path, args: list[str], cache: pathlib.Path, pythonpath: str | None = None, what: str = ""
) -> float:
    """Wall seconds, process start to exit, of ``python ARGS`` run in ``root`` (whose ``jaxmocap`` package it
    imports) with the compilation cache in ``cache`` and ``PYTHONPATH`` set to ``pythonpath`` (unset by default);
    a failure is raised naming ``what`` (default: the command)."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, JAXMOCAP_CACHE_DIR=str(cache), JAX_PLATFORMS="cpu")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env.pop("PYTHONPATH", None)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    # Python's bytecode cache as an installation has it (a shell with PYTHONDONTWRITEBYTECODE set compiles every
    # module of the package from source in every process: 0.2 s of a warm start)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env, cwd=root)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        what = what or f"python {' '.join(args)}"
        raise RuntimeError(f"{what} ({root}) failed: {(proc.stderr or proc.stdout).strip()[-400:]}")
    return wall


def run_cli(root: pathlib.Path, cache: pathlib.Path, args: list[str]) -> float:
    """Wall seconds, process start to exit, of ``python -m jaxmocap.cli ARGS`` run in ``root`` (whose ``jaxmocap``
    package it imports) with the compilation cache in ``cache`` (:func:`run_python`)."""
    return run_python(root, ["-m", "jaxmocap.cli", *args], cache, what=f"jaxmocap {args[0]}")


def track_options(items) -> dict:
    """``["velocity=0.8", "cues=foreground,keypoints:8"]`` → ``{"velocity": 0.8, "cues": "foreground,…"}``: fields
    of :class:`jaxmocap.tracking.options.TrackOptions` with their values converted to the field's type
    (:func:`~jaxmocap.tracking.options.option_types`); ``seed`` and ``overwrite`` are the scripts' own."""
    from jaxmocap.tracking.options import option_types

    types, out = option_types(), {}
    for item in items or ():
        name, eq, value = item.partition("=")
        if not eq or name not in types or name in ("seed", "overwrite"):
            raise ValueError(
                f"{item!r}: expected FIELD=VALUE with a field of TrackOptions but seed/overwrite"
            )
        kind = types[name]
        if kind is bool:
            out[name] = value.lower() in ("1", "true", "yes")
        elif kind in (int, float):
            out[name] = kind(value)
        elif kind == "particles":
            out[name] = int(value)
        else:
            out[name] = value
    return out
