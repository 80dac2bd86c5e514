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
  tracker step): copy insertion with region analysis, and XLA's loop fusion emitter instead of its default fusion
  emitters on a CPU without AVX-512.
* :func:`limit_cpu_threads` — start XLA's CPU backend with fewer intra-op threads than cores, and
  :func:`cpu_threads`, how many it has.

:func:`vector_isa` and :func:`description` read ``/proc/cpuinfo`` once (Linux); elsewhere they fall back to :mod:`platform`.
"""

from __future__ import annotations

import functools
import os
import pathlib
import platform

__all__ = [
    "COPY_REGIONS",
    "LOOP_FUSION",
    "cpu_threads",
    "description",
    "limit_cpu_threads",
    "particle_options",
    "vector_isa",
]

#: XLA's CPU compiler option that selects its loop fusion emitter instead of the fusion emitters (its default).
LOOP_FUSION = {"xla_cpu_use_fusion_emitters": False}

#: XLA's CPU compiler option that runs copy insertion with region analysis (fewer copies of loop-carried arrays).
COPY_REGIONS = {"xla_cpu_copy_insertion_use_region_analysis": True}


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
    likelihood and tracker step) compiled for XLA's CPU backend: :data:`COPY_REGIONS` on every CPU, with
    :data:`LOOP_FUSION` on an x86 CPU without AVX-512; ``{}`` for an accelerator. An option that ``XLA_FLAGS``
    names is left out (the user's choice wins).

    Why :data:`COPY_REGIONS`: the annealing layers and the likelihood's sampling loops are ``while`` loops whose
    carried arrays XLA's copy insertion copies every iteration when it cannot prove a copy unneeded; with its
    region analysis it proves more. Bit-identical results; on an AMD EPYC with AVX-512 (family 25, model 17) the
    PARSEC likelihood ran 1.05× faster on one thread (``bench_parsec.py --xla-options
    xla_cpu_copy_insertion_use_region_analysis=true --pool-threads 1``, seven interleaved rounds, 2026-11-30) and
    the PARSEC tracker's step at 4000 × 5 1.24× faster (1.16× beside a busy process; five interleaved rounds in
    one process).

    Why :data:`LOOP_FUSION`: on an AVX2 CPU (AMD EPYC, family 25, model 1), XLA's fusion emitters turn PARSEC's
    per-sample edge loops (a pixel index, an unsigned bounds test and a one-byte gather per sample,
    :mod:`jaxmocap.parsec.likelihood`) into scalar code of ≈ 190 k instructions per particle and layer
    (``valgrind --tool=callgrind``, ``benchmarks/perf/instructions.py``; 210 k before the in-bounds pixel reads,
    about 1.6 instructions per cycle at the CPU's nominal 2.45 GHz); the loop fusion emitter's code, 171 k
    instructions, ran the likelihood 1.69× faster in one process (``bench_parsec.py --xla-options
    xla_cpu_use_fusion_emitters=false``, five interleaved rounds, 2026-11-29) and the whole PARSEC tracker at 4000
    × 5 1.7× faster (``vs_bodytrack.py``). The same switch made the default tracker's step (other cues, other
    loops) slower on that CPU (stereo 11.5–13.3 against 14.2 frames/s, four cameras 6.4–7.6 against 9.6,
    ``track_rate.py`` in separate processes), so it is a choice per program, not per process. Elsewhere XLA's
    emitters are kept: on an AMD EPYC with AVX-512 (family 25, model 17) the loop emitter ran the PARSEC
    likelihood at 0.37× the default (the same command, seven interleaved rounds, 2026-11-29 21:56 UTC: 6.97
    against 2.57 µs per particle), as the fast runs of 2026-11-22/25 had found for an earlier version (0.24×)."""
    import jax

    if jax.default_backend() != "cpu":
        return {}  # programs compiled for an accelerator
    options = dict(COPY_REGIONS)
    if vector_isa() in ("AVX2", "AVX", "SSE"):
        options.update(LOOP_FUSION)
    flags = os.environ.get("XLA_FLAGS", "")
    return {name: value for name, value in options.items() if name not in flags}


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
