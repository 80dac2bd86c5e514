"""Frames read ahead, in a thread of their own: the next frames are decoded (and given their host work) while the
current one is tracked.

``reader = ReadAhead(read)`` wraps ``read(t) -> value`` (a source's decoding of frame ``t``, and the start of
whatever image work needs no pose). ``reader(t, ahead=(u, …))`` returns ``read(t)`` — the value read ahead when
the frames in flight begin with ``t``, else read now on the caller's thread — and makes sure that frames ``u, …``
are being read, in that order, in the reader's thread. An exception of ``read`` (an unreadable frame) is raised by
the call that asks for that frame, in frame order, as a call without read-ahead raises it.

The reads run one after the other in one thread (a call for a frame that is not next first waits for the frames
in flight and drops them), so sources that decode sequentially (a video's ``cv2.VideoCapture``) see one reader at
a time. :meth:`ReadAhead.wait` waits for the frames in flight: call it before anything else reads the source or
closes it. OpenCV's decoders and image functions release the GIL, so the reads overlap the caller's work on
another core.
"""

from __future__ import annotations

import collections
import concurrent.futures
from collections.abc import Callable, Iterable
from typing import Any

__all__ = ["ReadAhead"]


class ReadAhead:
    """``reader(t, ahead=()) -> read(t)``, reading the frames ``ahead`` in a thread meanwhile (module docstring)."""

    def __init__(self, read: Callable[[int], Any], name: str = "jaxmocap-read"):
        self._read, self._name = read, name
        self._pool: concurrent.futures.ThreadPoolExecutor | None = None
        self._queue: collections.deque[tuple[int, concurrent.futures.Future]] = collections.deque()

    def __call__(self, t: int, ahead: Iterable[int] = ()):
        if self._queue and self._queue[0][0] == t:
            value = self._queue.popleft()[1].result()  # the read's exception, if any, raised here
        else:
            self.wait()  # other frames were read ahead: let them finish, unused
            value = self._read(t)
        queued = [u for u, _ in self._queue]
        for u in ahead:
            if u in queued:
                continue
            if self._pool is None:
                self._pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix=self._name)
            self._queue.append((u, self._pool.submit(self._read, u)))
        return value

    @property
    def in_flight(self) -> tuple[int, ...]:
        """The frames being read ahead, in order."""
        return tuple(u for u, _ in self._queue)

    def wait(self) -> None:
        """Wait for the frames in flight (their values and exceptions dropped)."""
        pending = [f for _, f in self._queue]
        self._queue.clear()
        concurrent.futures.wait(pending)

    def close(self) -> None:
        """:meth:`wait`, then end the reader's thread."""
        self.wait()
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
