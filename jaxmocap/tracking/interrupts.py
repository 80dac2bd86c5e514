"""Ctrl-C and SIGTERM during a tracking run: the run stops at once, except while it writes a frame's outputs.

:func:`handling` installs handlers for SIGINT and SIGTERM (in the main thread; elsewhere it does nothing): SIGINT
raises :class:`KeyboardInterrupt` and SIGTERM raises :class:`Terminated` where the program is, unless it is inside
a :func:`deferred` block (the writes of one frame's outputs, the flush of a run's outputs on its way out), where the
signal is recorded and raised when the outermost block ends. A frame is therefore written whole or not at all, and
the exit path that flushes the outputs is not cut short by a second Ctrl-C.

The first signal is also remembered (:func:`received`) until its exception is handled (:func:`consume`). Python
swallows an exception raised in a garbage-collector callback or a finaliser (printing "Exception ignored in …": JAX
runs a callback at every collection), so there the handler raises nothing; the frame loop calls :func:`check` at
every frame and before it writes anything, and the command line reports a signal even when no exception reached
it.
"""

from __future__ import annotations

import contextlib
import gc
import signal
import threading

__all__ = ["Terminated", "check", "consume", "deferred", "exit_status", "handling", "received"]


class Terminated(BaseException):
    """SIGTERM: the process was asked to end (by ``kill``, a job scheduler, a container runtime)."""


_state = {"depth": 0, "pending": None, "received": None}


def _exception(signum: int) -> BaseException:
    return KeyboardInterrupt() if signum == signal.SIGINT else Terminated()


def _swallowing(frame) -> bool:
    """Whether an exception raised in ``frame`` would be swallowed: inside a garbage-collector callback or a
    finaliser (``__del__``)."""
    callbacks = {getattr(cb, "__code__", None) for cb in gc.callbacks}
    while frame is not None:
        if frame.f_code in callbacks or frame.f_code.co_name == "__del__":
            return True
        frame = frame.f_back
    return False


def _handler(signum, frame):
    if _state["received"] is None:
        _state["received"] = signum
    if _state["depth"] > 0:
        if _state["pending"] is None:
            _state["pending"] = signum
        return
    if _swallowing(frame):
        return  # check() raises it where it is not lost
    raise _exception(signum)


@contextlib.contextmanager
def handling():
    """Install the handlers of SIGINT and SIGTERM for the block (restoring the previous ones after it); nested or
    outside the main thread it leaves the handlers as they are."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    if all(h is _handler for h in before.values()):
        yield
        return
    for s in before:
        signal.signal(s, _handler)
    try:
        yield
    finally:
        for s, h in before.items():
            signal.signal(s, h)


@contextlib.contextmanager
def deferred():
    """A block that a signal does not interrupt: it is raised when the outermost block ends (unless that block
    already ends with an exception, which then carries on)."""
    _state["depth"] += 1
    ok = False
    try:
        yield
        ok = True
    finally:
        _state["depth"] -= 1
        if _state["depth"] == 0 and _state["pending"] is not None:
            signum, _state["pending"] = _state["pending"], None
            if ok:
                raise _exception(signum)


def received() -> int | None:
    """The first signal received and not yet handled (``signal.SIGINT`` / ``signal.SIGTERM``), or None."""
    return _state["received"]


def check() -> None:
    """Raise the exception of a signal received earlier and not yet handled (its own exception was not raised,
    or was swallowed on its way)."""
    if _state["received"] is not None and _state["depth"] == 0:
        raise _exception(_state["received"])


def consume() -> int | None:
    """Mark the signal received as handled (its exception has reached the code that ends the run); returns it.

    CPython's mark of an unhandled Ctrl-C is cleared too (:func:`_clear_unhandled_mark`): without that, a process
    whose KeyboardInterrupt passed through an extension's embedded Python code on its way here ends by SIGINT after
    its one line, not with the status the command returns."""
    signum = _state["received"]
    _state.update(pending=None, received=None)
    _clear_unhandled_mark()
    return signum


def _clear_unhandled_mark() -> None:
    """CPython ends the process with SIGINT, once the program has returned, when a KeyboardInterrupt escaped code
    run through its ``PyRun_*`` entry points (an extension module that runs Python source while it loads: measured,
    2 in 60 Ctrl-Cs 0.5–1.1 s into ``jaxmocap track``), even when the exception was caught further up; each run
    through those entry points starts by clearing the mark, so running an empty string clears it. Nothing happens
    where there is no CPython API (another interpreter)."""
    try:
        import ctypes

        ctypes.pythonapi.PyRun_SimpleString(b"")
    except (ImportError, AttributeError, OSError):
        pass


def exit_status(exc: BaseException) -> int:
    """The exit status of a process ended by ``exc``: 130 for Ctrl-C, 143 for SIGTERM (128 + the signal)."""
    return 128 + (signal.SIGTERM if isinstance(exc, Terminated) else signal.SIGINT)
