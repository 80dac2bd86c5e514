"""Programs compiled by the frame loop's thread, counted frame by frame: after the first frame, no frame may compile
(every frame has the first one's shapes), and a run that does says so.

JAX reports every lowering of a program to XLA through :mod:`jax.monitoring`
(``/jax/core/compile/jaxpr_to_mlir_module_duration``): one per program that is not in the in-memory caches, whether
or not the persistent compilation cache then holds its executable. :class:`CompileWatch` counts the lowerings of
the thread that created it, so that the run's background threads (the outputs' writer, the compilation ahead of
the first frame) are not counted.
"""

from __future__ import annotations

import threading

import jax

__all__ = ["CompileWatch", "LOWERING_EVENT"]

#: the :mod:`jax.monitoring` event of one program's lowering (its duration in seconds)
LOWERING_EVENT = "/jax/core/compile/jaxpr_to_mlir_module_duration"

_local = threading.local()
_lock = threading.Lock()
_registered = False


def _listener(event: str, duration: float, **_kw) -> None:
    if event == LOWERING_EVENT and getattr(_local, "watching", False):
        _local.count += 1


class CompileWatch:
    """Counts the programs lowered by this thread since the last :meth:`take`."""

    def __init__(self):
        global _registered
        with _lock:
            if not _registered:
                jax.monitoring.register_event_duration_secs_listener(_listener)
                _registered = True
        _local.watching, _local.count = True, 0

    def take(self) -> int:
        """The programs lowered by this thread since the last call (or since the watch began)."""
        n, _local.count = _local.count, 0
        return n

    def close(self) -> None:
        _local.watching = False
