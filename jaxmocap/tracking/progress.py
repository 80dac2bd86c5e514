"""The progress line of a tracking run, the lines around its compilation, and its warnings."""

from __future__ import annotations

import math
import sys
import time

import jax

__all__ = ["CompileNotice", "Progress", "warn"]


class Progress:
    """A one-line progress bar with frames per second on a terminal (a line every 10 % otherwise)."""

    def __init__(self, total: int, stream=None, enabled: bool = True, label: str = "track"):
        self.total, self.label = total, label
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.tty = enabled and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.t0 = time.monotonic()
        self.first_done = None
        self.last_pct = -1

    def end_line(self) -> None:
        """Finish a partly drawn terminal line (before an error message)."""
        if self.tty and self.first_done is not None:
            self.stream.write("\n")
            self.stream.flush()

    def update(self, done: int, note: str = "") -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if self.first_done is None and done > 0:
            self.first_done = (now, done)
        fps = 0.0
        if self.first_done is not None and done > self.first_done[1]:
            fps = (done - self.first_done[1]) / max(now - self.first_done[0], 1e-9)
        frac = done / max(self.total, 1)
        eta = (self.total - done) / fps if fps > 0 else float("nan")
        bar = "#" * int(round(24 * frac))
        text = f"{self.label} {done:>5}/{self.total} [{bar:<24}] {fps:5.2f} frames/s"
        if math.isfinite(eta):
            text += f"  ETA {eta:4.0f} s"
        if note:
            text += f"  {note}"
        if self.tty:
            self.stream.write("\r" + text + "\x1b[K")
            if done >= self.total:
                self.stream.write("\n")
            self.stream.flush()
        else:
            pct = int(10 * frac)
            if pct != self.last_pct or done >= self.total:
                self.last_pct = pct
                self.stream.write(text + "\n")
                self.stream.flush()


class CompileNotice:
    """``with CompileNotice(what):`` around the first call of a jitted function: a line saying what is being
    compiled before it, and one with the time it took after it (the call returns once XLA has compiled the program
    and dispatched it), saying whether the program is now in the persistent compilation cache
    (:mod:`jaxmocap.compilation_cache`)."""

    def __init__(self, what: str, enabled: bool = True, stream=None):
        self.what, self.enabled = what, enabled
        self.stream = sys.stderr if stream is None else stream
        self.seconds = None

    def __enter__(self):
        if self.enabled:
            self.stream.write(f"jaxmocap: compiling {self.what} ...\n")
            self.stream.flush()
        self.t0 = time.monotonic()
        return self

    def __exit__(self, kind, value, tb):
        self.seconds = time.monotonic() - self.t0
        if self.enabled and kind is None:
            cache = jax.config.jax_compilation_cache_dir
            where = f"cached for next time in {cache}" if cache else "compilation cache off"
            self.stream.write(f"jaxmocap: compiled in {self.seconds:.1f} s, {where}\n")
            self.stream.flush()
        return False


def warn(msg: str) -> None:
    sys.stderr.write(f"jaxmocap: warning: {msg}\n")
    sys.stderr.flush()
