"""The CPU this process runs on, as XLA's CPU backend sees it.

XLA compiles every program for the CPU it finds when the process starts (its instruction-set extensions, through
LLVM's host detection), so the same source and the same JAX can run very different machine code on two machines of
the same name: a cloud "AMD EPYC" may be a Zen 3 without AVX-512 on one day and a newer core with it on another.
Speed figures are only comparable between runs on the same :func:`description`.

* :func:`vector_isa` — the widest x86 vector extension the CPU reports (``"AVX-512"``, ``"AVX2"``, ``"AVX"``,
  ``"SSE"``), or the architecture's name elsewhere (``"aarch64"``).
* :func:`description` — ``"AMD EPYC (family 25, model 1; AVX2, no AVX-512)"``: the model name, the x86 family and
  model numbers (they tell two CPUs of one marketing name apart) and :func:`vector_isa`.
* :func:`particle_options` — the XLA compiler options of a gather-bound particle program (PARSEC's likelihood and
  tracker step): copy insertion with region analysis; :func:`gathers_apart`, where its pixel reads run apart
  from its sampling loops (x86 without AVX-512).
* :func:`limit_cpu_threads` — start XLA's CPU backend with fewer intra-op threads than cores, and
  :func:`cpu_threads`, how many it has; :class:`CpuSample`, :func:`other_busy_cpus` and :func:`auto_cpu_threads`
  — how many of this process's CPUs other processes keep busy (``/proc/stat``), and the threads that leaves
  (``jaxmocap --cpu-threads auto``).
* :func:`relax_gc` — the garbage collector's thresholds of a command-line run and of the test suite
  (:data:`GC_THRESHOLDS`).

:func:`vector_isa` and :func:`description` read ``/proc/cpuinfo`` once (Linux); elsewhere they fall back to :mod:`platform`.
"""

from __future__ import annotations

import functools
import os
import pathlib
import platform
import time
from typing import NamedTuple

__all__ = [
    "COPY_REGIONS",
    "GC_THRESHOLDS",
    "LOOP_FUSION",
    "MIN_INTERVAL_S",
    "CpuSample",
    "auto_cpu_threads",
    "cpu_sample",
    "cpu_threads",
    "description",
    "limit_cpu_threads",
    "choose_cpu_threads",
    "other_busy_cpus",
    "parse_proc_stat",
    "thread_summary",
    "particle_options",
    "relax_gc",
    "vector_isa",
]

#: XLA's CPU compiler option that selects its loop fusion emitter instead of the fusion emitters (its default). No
#: longer one of :func:`particle_options` (see there); kept for the benchmarks that compare the two
#: (``benchmarks/perf/bench_parsec.py --host-choices``).
LOOP_FUSION = {"xla_cpu_use_fusion_emitters": False}

#: XLA's CPU compiler option that runs copy insertion with region analysis (fewer copies of loop-carried arrays).
COPY_REGIONS = {"xla_cpu_copy_insertion_use_region_analysis": True}

#: CPython's cyclic garbage collector thresholds for a process that traces JAX programs: the youngest generation
#: collected after 50 000 net allocations of container objects instead of 700, the middle one after 20 of those.
GC_THRESHOLDS = (50_000, 20, 10)


def relax_gc() -> None:
    """Set :data:`GC_THRESHOLDS` (``gc.set_threshold``).

    Tracing and lowering a JAX program allocates hundreds of thousands of short-lived objects, and with CPython's
    thresholds (700, 10, 10) the collector ran about 400 young and 35 middle collections in a warm one-frame PARSEC
    run, and a few full ones, each walking the hundreds of thousands of objects that JAX's and the package's modules
    hold: 0.2–0.27 s of a 2.2 s run, 9–12 s of the 110–129 s of ``tests/tracking/test_tracker.py`` (0.06–0.09 s
    and 3.5 s with these). Most objects of a trace are freed by reference counting when it ends; the collector only
    frees reference cycles, and with these thresholds it frees them a little later. Full collections keep their own
    rule (when a quarter of the long-lived objects is new). For applications (the command line, the test suite):
    importing the package never changes the collector.
    """
    import gc

    gc.set_threshold(*GC_THRESHOLDS)


@functools.lru_cache(maxsize=1)
def _cpuinfo() -> dict[str, str]:
    """The first processor's ``key: value`` lines of ``/proc/cpuinfo`` (empty where there is none)."""
    fields: dict[str, str] = {}
    try:
        text = pathlib.Path("/proc/cpuinfo").read_text()
    except OSError:
        return fields
    for line in text.splitlines():
        if not line.strip():
            if fields:
                break  # the first processor is enough: they are alike
            continue
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    return fields


def vector_isa() -> str:
    """The widest vector extension of an x86 CPU (``"AVX-512"`` needs ``avx512f``), else the architecture."""
    arch = platform.machine()
    flags = set(_cpuinfo().get("flags", "").split())
    if arch not in ("x86_64", "AMD64", "i686", "i386") or not flags:
        return arch or "unknown"
    for flag, name in (("avx512f", "AVX-512"), ("avx2", "AVX2"), ("avx", "AVX")):
        if flag in flags:
            return name
    return "SSE"


def description() -> str:
    """``"<model name> (family F, model M; <ISA>[, no AVX-512])"``: enough to tell apart two CPUs that XLA compiles
    different code for."""
    info = _cpuinfo()
    name = info.get("model name") or platform.processor() or platform.machine() or "CPU"
    isa = vector_isa()
    if isa in ("AVX2", "AVX", "SSE"):
        isa += ", no AVX-512"
    parts = (
        [f"family {info['cpu family']}, model {info['model']}"]
        if "cpu family" in info and "model" in info
        else []
    )
    return f"{name} ({'; '.join(parts + [isa])})"


def particle_options() -> dict[str, bool]:
    """Compiler options (``jax.jit(..., compiler_options=...)``) for a gather-bound particle program (PARSEC's
    likelihood and tracker step) compiled for XLA's CPU backend: :data:`COPY_REGIONS`; ``{}`` for an
    accelerator. An option that ``XLA_FLAGS`` names is left out (the user's choice wins).

    Why :data:`COPY_REGIONS`: the annealing layers and the likelihood's sampling loops are ``while`` loops whose
    carried arrays XLA's copy insertion copies every iteration when it cannot prove a copy unneeded; with its
    region analysis it proves more. Bit-identical results; on an AMD EPYC with AVX-512 (family 25, model 17) the
    PARSEC likelihood ran 1.05× faster on one thread (``bench_parsec.py --xla-options
    xla_cpu_copy_insertion_use_region_analysis=true --pool-threads 1``, seven interleaved rounds, 2026-11-30) and
    the PARSEC tracker's step at 4000 × 5 1.24× faster (1.16× beside a busy process; five interleaved rounds in
    one process).

    Not :data:`LOOP_FUSION` (XLA's loop fusion emitter), since 2026-12-01. On an AVX2 CPU (AMD EPYC, family 25,
    model 1) it had run the PARSEC likelihood 1.69× faster than XLA's fusion emitters and the whole tracker 1.7×
    (2026-11-29), when each loop iteration's pixel reads were fused with the sample positions and XLA's fusion
    emitters made the whole iteration scalar code (≈ 190 k instructions per particle and layer against the loop
    emitter's 171 k, ``valgrind --tool=callgrind``). Since the reads run apart there (:func:`gathers_apart`) the
    fusion emitters are as fast or faster on that CPU: the PARSEC tracker's step at 4000 × 5 1.06–1.14× / 1.16–1.17×
    faster (medians of two runs, as found / beside a busy process, two XLA threads; 1.17× / 1.09× on one), at 1000 ×
    3 1.01–1.20× / 1.04–1.22×, five or seven interleaved rounds in one process (2026-12-01 23:05–23:25 UTC,
    ``bench_parsec.py --host-choices``, which times the tracker too); the likelihood alone 1.09–1.19×. On an AMD
    EPYC with AVX-512 (model 17) the loop emitter had run the likelihood at 0.37× and on an Intel Xeon with
    AVX-512 (family 6, model 167) at 0.38× (2026-12-01, ``--host-choices``)."""
    import jax

    if jax.default_backend() != "cpu":
        return {}  # programs compiled for an accelerator
    flags = os.environ.get("XLA_FLAGS", "")
    return {name: value for name, value in COPY_REGIONS.items() if name not in flags}


def gathers_apart() -> bool:
    """Whether PARSEC's likelihood reads its pixels with gathers of their own
    (:attr:`jaxmocap.parsec.likelihood.Config.gathers_apart`): on XLA's CPU backend of an x86 CPU without AVX-512,
    where XLA's fused sampling loop compiles to scalar code (1.49× faster apart, measured there); elsewhere the
    fused loop is kept (on an AMD EPYC with AVX-512 it is vector code with scalar reads, 2.6–3.0 µs of CPU per
    particle, not measured apart)."""
    import jax

    return jax.default_backend() == "cpu" and _x86_without_avx512()


def _x86_without_avx512() -> bool:
    """An x86 CPU whose widest vector extension is below AVX-512 (:func:`vector_isa`), where XLA's loops with
    per-sample gathers compile to scalar code: :func:`gathers_apart` chooses for it."""
    return vector_isa() in ("AVX2", "AVX", "SSE")


#: the name the operating system shows for a thread of XLA's CPU intra-op pool (Eigen's)
_POOL_THREAD = "tf_XLAEigen"


def cpu_threads() -> int | None:
    """The threads of XLA's CPU intra-op pool in this process (Linux, from ``/proc/self/task``; ``None``
    elsewhere). XLA starts them with its CPU backend, one per CPU of the process's affinity mask."""
    tasks = pathlib.Path("/proc/self/task")
    if not tasks.is_dir():
        return None
    count = 0
    for t in tasks.iterdir():
        try:
            count += (t / "comm").read_text().strip() == _POOL_THREAD
        except OSError:  # a thread that ended meanwhile
            continue
    return count


def limit_cpu_threads(n: int | None) -> None:
    """Start JAX's CPU backend with ``n`` intra-op threads (``None`` or 0: XLA's own choice, one per core).

    XLA sizes its pool from the CPUs the process may run on when the backend starts, so the affinity mask is
    narrowed to ``n`` CPUs while it starts and restored right after: the threads then run on any core. Why fewer:
    on a machine whose other cores are busy, XLA's threads wait for each other at the end of every parallel
    kernel; on the shared 2-core machine of ``benchmarks/RESULTS.md`` (item 1) one thread ran the PARSEC step
    in 65–69 ms in every condition, two threads in 46–109 ms idle and 57–89 ms beside a busy process.
    Must run before anything starts JAX's backends (the first array or ``jax.devices()``); Linux only."""
    if not n:
        return
    if n < 0:
        raise ValueError(f"the number of CPU threads must be positive, got {n}")
    import jax
    from jax._src import xla_bridge

    if xla_bridge.backends_are_initialized():
        raise RuntimeError("JAX's backends have started: XLA's CPU thread count can no longer be chosen")
    if not hasattr(os, "sched_setaffinity"):
        raise OSError("choosing XLA's CPU thread count needs sched_setaffinity (Linux)")
    allowed = os.sched_getaffinity(0)
    if n >= len(allowed):
        return  # XLA's default already
    os.sched_setaffinity(0, set(sorted(allowed)[:n]))
    try:
        jax.devices("cpu")
    finally:
        os.sched_setaffinity(0, allowed)


class CpuSample(NamedTuple):
    """One reading of the CPUs' time counters: ``busy`` and ``total`` jiffies per CPU number (``/proc/stat``:
    busy = user + nice + system + irq + softirq + steal, total = busy + idle + iowait), this process's own CPU
    seconds (every thread, :func:`os.times`) and the monotonic wall clock (s)."""

    busy: dict[int, int]
    total: dict[int, int]
    own_s: float
    wall_s: float


def parse_proc_stat(text: str) -> tuple[dict[int, int], dict[int, int]]:
    """``(busy, total)`` jiffies per CPU from the text of ``/proc/stat`` (its ``cpuN`` lines; see :class:`CpuSample`)."""
    busy, total = {}, {}
    for line in text.splitlines():
        head, _, rest = line.partition(" ")
        if not (head.startswith("cpu") and head[3:].isdigit()):
            continue
        v = [int(x) for x in rest.split()] + [0] * 8
        user, nice, system, idle, iowait, irq, softirq, steal = v[:8]
        b = user + nice + system + irq + softirq + steal
        busy[int(head[3:])], total[int(head[3:])] = b, b + idle + iowait
    return busy, total


def cpu_sample() -> CpuSample | None:
    """The counters now (``None`` where ``/proc/stat`` cannot be read: not Linux)."""
    try:
        text = pathlib.Path("/proc/stat").read_text()
    except OSError:
        return None
    busy, total = parse_proc_stat(text)
    t = os.times()
    return CpuSample(busy, total, t.user + t.system, time.monotonic())


def other_busy_cpus(a: CpuSample, b: CpuSample, cpus) -> float:
    """How many of ``cpus`` (CPU numbers, e.g. this process's affinity mask) other processes kept busy between the
    samples ``a`` and ``b``: ``Σ_c Δbusy_c / Δtotal_c − Δown / Δwall`` (each CPU's busy fraction, less the CPUs this
    process used itself), at least 0."""
    used = 0.0
    for c in cpus:
        dt = b.total.get(c, 0) - a.total.get(c, 0)
        if dt > 0:
            used += (b.busy.get(c, 0) - a.busy.get(c, 0)) / dt
    own = (b.own_s - a.own_s) / max(b.wall_s - a.wall_s, 1e-9)
    return max(used - own, 0.0)


def auto_cpu_threads(other: float, cpus: int) -> int:
    """XLA's intra-op threads for ``cpus`` CPUs of which other processes keep ``other`` busy: one per CPU left,
    ``cpus − round(other)``, at least 1. On a machine whose other cores are busy XLA's threads wait for a
    descheduled peer at the end of every parallel kernel. On the 2-core machine of ``benchmarks/RESULTS.md``
    (item 1), beside one busy process, the PARSEC likelihood ran at 3.20× bodytrack's speed in processes started
    there (which chose one thread) against 2.85× on the two threads of a process started idle, and idle at 3.39×
    (two threads chosen; ``vs_bodytrack.md``, 2026-11-30 15:49 UTC); the default tracker 1.00–1.19× faster busy
    on one thread (README.md, where it describes ``xla_cpu_threads``)."""
    return int(min(max(cpus - int(other + 0.5), 1), max(cpus, 1)))


#: the shortest interval :func:`choose_cpu_threads` measures over (s)
MIN_INTERVAL_S = 0.25
#: the last automatic choice of this process (:func:`thread_summary`)
_auto_choice: dict | None = None


def choose_cpu_threads(since: CpuSample | None) -> int | None:
    """``jaxmocap --cpu-threads auto``: :func:`auto_cpu_threads` for this process's affinity mask, from the other
    processes' load between ``since`` (taken when the program started, so that its imports are the interval) and
    now, over at least :data:`MIN_INTERVAL_S` (the rest slept); ``None`` (XLA's default: one per CPU) when every
    CPU is left free or the counters cannot be read, and without measuring when JAX's backends have started
    already (the command line called from a process that has computed: its threads are fixed). The choice is
    kept for :func:`thread_summary`."""
    global _auto_choice
    from jax._src import xla_bridge

    if since is None or not hasattr(os, "sched_getaffinity") or xla_bridge.backends_are_initialized():
        return None
    rest = MIN_INTERVAL_S - (time.monotonic() - since.wall_s)
    if rest > 0:
        time.sleep(rest)
    now = cpu_sample()
    if now is None:
        return None
    cpus = sorted(os.sched_getaffinity(0))
    other = other_busy_cpus(since, now, cpus)
    n = auto_cpu_threads(other, len(cpus))
    _auto_choice = {"cpus": len(cpus), "other_busy_cpus": round(other, 2), "threads": n,
                    "interval_s": round(now.wall_s - since.wall_s, 3)}  # fmt: skip
    return None if n >= len(cpus) else n


def thread_summary() -> dict:
    """What a run records of its CPU threads: ``xla_cpu_threads`` (:func:`cpu_threads`) and, after
    ``--cpu-threads auto``, ``cpu_threads_auto`` (the CPUs, the other processes' busy CPUs measured, the threads
    chosen and the interval of the measurement)."""
    out = {"xla_cpu_threads": cpu_threads()}
    if _auto_choice is not None:
        out["cpu_threads_auto"] = dict(_auto_choice)
    return out
