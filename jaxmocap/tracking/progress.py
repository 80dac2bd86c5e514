"""The progress line of a tracking run, and its warnings."""

from __future__ import annotations

import math
import sys
import time

__all__ = ["Progress", "warn"]


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


def warn(msg: str) -> None:
    sys.stderr.write(f"jaxmocap: warning: {msg}\n")
    sys.stderr.flush()
