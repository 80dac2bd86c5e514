"""Frames read ahead in a thread (:mod:`jaxmocap.io.read_ahead`): the values and errors of a plain read, in frame
order; one read at a time; frames read on the reader's thread, not the caller's."""

from __future__ import annotations

import threading
import time

import pytest

from jaxmocap.io.read_ahead import ReadAhead


class _Source:
    """``read(t)``: ``("frame", t)`` after a short sleep, ``ValueError`` for the frames in ``bad``; records which
    thread read each frame and the most reads that ever ran at once."""

    def __init__(self, bad=()):
        self.bad, self.threads, self.order = set(bad), {}, []
        self.running = self.most = 0
        self.lock = threading.Lock()

    def __call__(self, t):
        with self.lock:
            self.running += 1
            self.most = max(self.most, self.running)
        try:
            time.sleep(0.01)
            self.threads[t] = threading.current_thread().name
            self.order.append(t)
            if t in self.bad:
                raise ValueError(f"frame {t} is unreadable")
            return ("frame", t)
        finally:
            with self.lock:
                self.running -= 1


def test_frames_read_ahead_are_those_a_plain_read_gives_read_in_the_readers_thread():
    src = _Source()
    reader = ReadAhead(src, name="test-read")
    frames = list(range(6))
    got = [reader(t, ahead=frames[k + 1 : k + 3]) for k, t in enumerate(frames)]
    assert got == [("frame", t) for t in frames]
    assert src.order == frames  # each frame read once, in order
    assert src.threads[0] == threading.current_thread().name  # nothing was in flight for the first
    assert all(src.threads[t].startswith("test-read") for t in frames[1:])
    assert src.most == 1 and reader.in_flight == ()
    reader.close()


def test_an_unreadable_frame_raises_at_the_call_that_asks_for_it():
    src = _Source(bad={2})
    reader = ReadAhead(src)
    assert reader(0, ahead=(1, 2)) == ("frame", 0)
    assert reader(1, ahead=(2, 3)) == ("frame", 1)  # frame 2 failed in the thread already: not raised here
    with pytest.raises(ValueError, match="frame 2"):
        reader(2, ahead=(3, 4))
    assert reader(3) == ("frame", 3)  # read ahead before the error: still served
    reader.close()


def test_a_frame_out_of_order_waits_for_the_frames_in_flight_and_is_read_now():
    src = _Source()
    reader = ReadAhead(src)
    reader(0, ahead=(1, 2))
    assert reader.in_flight == (1, 2)
    assert reader(7) == ("frame", 7)
    assert src.threads[7] == threading.current_thread().name
    assert src.order == [0, 1, 2, 7] and src.most == 1 and reader.in_flight == ()
    reader(8, ahead=(9,))
    reader.wait()
    assert reader.in_flight == () and src.order[-1] == 9
    reader.close()
