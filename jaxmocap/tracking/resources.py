"""Does a tracking run's filter step fit in memory? Checked before anything is written to the output folder.

Two checks, both raising ``ValueError`` with one line (the command line exits with status 2):

* :func:`check_particle_set`, before the initial set is drawn and before compiling: the particle set alone,
  ``N·(D + 1)`` float32 values (states and log-weights; ``N`` summed over partitions), must fit in the memory
  available, and ``N`` must index with int32 (``N < 2³¹``). Instant, and a lower bound of what the step needs.
* :func:`check_program`, once XLA has compiled the step and before it runs: XLA's own buffer assignment
  (``Compiled.memory_analysis()``) gives the bytes of the program's temporaries and outputs; their sum must fit
  in the memory available. This is the figure that an allocation would fail on (e.g. 548 GB for 10⁷ particles of
  the default full-body APF, where the particle set is 1 GB).

The memory available is the accelerator's free memory (``Device.memory_stats``: ``bytes_limit − bytes_in_use``)
or, on the CPU, the system's ``MemAvailable`` (``/proc/meminfo``; the physical memory elsewhere).
"""

from __future__ import annotations

import os

import jax

__all__ = ["available_bytes", "check_particle_set", "check_program", "gigabytes"]

MAX_PARTICLES = 2**31 - 1


def gigabytes(n: float) -> str:
    return f"{n / 1e9:.1f} GB" if n >= 1e8 else f"{n / 1e6:.1f} MB"


def available_bytes(device=None) -> int | None:
    """Free memory of ``device`` (default: JAX's first device) in bytes, or None when unknown."""
    device = jax.devices()[0] if device is None else device
    if device.platform != "cpu":
        try:
            stats = device.memory_stats() or {}
        except Exception:  # a backend without memory statistics
            stats = {}
        if "bytes_limit" in stats:
            return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
        return None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_particle_set(total: int, num_dofs: int, what: str, available: int | None = None) -> None:
    """Refuse ``total`` particles of ``num_dofs`` DOFs whose set alone would not fit (module docstring)."""
    if total > MAX_PARTICLES:
        raise ValueError(f"{what}: at most {MAX_PARTICLES:,} particles in all, got {total:,}")
    available = available_bytes() if available is None else available
    need = 4 * total * (num_dofs + 1)
    if available is not None and need > available:
        fit = max(available // (4 * (num_dofs + 1)), 0)
        raise ValueError(
            f"{what}: the particle set alone needs {gigabytes(need)}, more than the {gigabytes(available)} of memory "
            f"available (fewer than {fit:,} particles could fit)"
        )


def program_bytes(compiled) -> int | None:
    """The bytes a compiled program allocates when it runs (temporaries and outputs not aliasing an argument),
    from XLA's buffer assignment; None when the backend does not say."""
    try:
        ma = compiled.memory_analysis()
    except Exception:  # not every backend implements it
        return None
    if ma is None:
        return None
    return int(ma.temp_size_in_bytes) + int(ma.output_size_in_bytes) - int(ma.alias_size_in_bytes)


def check_program(compiled, what: str, particles: int, available: int | None = None) -> None:
    """Refuse a compiled step whose temporaries and outputs would not fit (module docstring); ``particles``: its
    total particle count, for the advice (memory grows linearly with it)."""
    need = program_bytes(compiled)
    available = available_bytes() if available is None else available
    if need is None or available is None or need <= available:
        return
    fit = int(particles * available / need)
    raise ValueError(
        f"{what} needs {gigabytes(need)} of memory (XLA's estimate of the compiled program), more than the "
        f"{gigabytes(available)} available: use fewer particles (about {fit:,} would fit)"
    )
