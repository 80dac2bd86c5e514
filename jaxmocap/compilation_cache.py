"""Persistent XLA compilation cache of the command line.

Compiling a tracker step takes 5–30 s on a CPU (``benchmarks/perf/compile_time.py``). JAX can store
compiled programs on disk and reload them when the same program — same shapes, options, JAX/XLA version and XLA
flags — is compiled again, so the second ``jaxmocap track`` / ``demo`` / ``sweep`` of a configuration skips most of
its compilation.

Directory: ``$JAXMOCAP_CACHE_DIR``, else ``$XDG_CACHE_HOME/jaxmocap/xla`` (``~/.cache/jaxmocap/xla``);
``JAXMOCAP_CACHE_DIR=off`` disables it. A cache directory already configured for JAX itself
(``JAX_COMPILATION_CACHE_DIR``, ``jax.config``) is used as it is. Programs that took at least
``min_compile_seconds`` to compile are stored: by default every program, the one-operation programs of eager
``jax.numpy`` code included, because reading such a program back is cheaper than compiling it again (a warm
two-frame stereo ``jaxmocap track --init ik`` compiles about 160 of them: 18.4–20.3 s with every program stored
against 23.5–24.9 s with only those over 1 s, ratio per round 0.73–0.91 as found and beside a busy process, 1.8
against 1.1 MB of cache). The command line and :func:`jaxmocap.track` also keep the runs' filter steps (and
PARSEC's weighted start) *traced*, with their compiled executables, in the ``jaxmocap-exported/`` folder beside
them, so that a warm run neither traces nor lowers them (:mod:`jaxmocap.stored_programs`). Deleting the directory
is always safe. Scripts and notebooks get the same cache by calling :func:`enable` before their first compilation
(and the traced steps with ``with stored_programs.use(enable()):`` around their run).
"""

from __future__ import annotations

import os
import pathlib
from collections.abc import Mapping

import jax

#: values of ``JAXMOCAP_CACHE_DIR`` that turn the cache off
OFF = ("off", "0", "none", "")


def cache_dir(env: Mapping[str, str] = os.environ) -> pathlib.Path | None:
    """The directory the command line caches compiled programs in (None: disabled); see the module docstring."""
    if "JAXMOCAP_CACHE_DIR" in env:
        value = env["JAXMOCAP_CACHE_DIR"].strip()
        return None if value.lower() in OFF else pathlib.Path(value).expanduser()
    base = env.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "jaxmocap" / "xla"


def enable(env: Mapping[str, str] = os.environ, min_compile_seconds: float = 0.0) -> pathlib.Path | None:
    """Turn JAX's persistent compilation cache on in :func:`cache_dir` (created if needed) unless JAX already has
    one; returns the directory in use, or None when disabled or when the directory cannot be created."""
    current = jax.config.jax_compilation_cache_dir
    if current:
        return pathlib.Path(current)
    d = cache_dir(env)
    if d is None:
        return None
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None  # a read-only home must not stop tracking: compile as usual
    jax.config.update("jax_compilation_cache_dir", str(d))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_seconds))
    return d
