"""Ctrl-C and SIGTERM handling: raised at once, held back inside a ``deferred`` block until it ends, never raised
where Python would swallow it (a garbage-collector callback, as JAX registers one) but kept for ``check``."""

import gc
import os
import signal

import pytest

from jaxmocap.tracking import interrupts


def _kill(sig):
    os.kill(os.getpid(), sig)
    sum(range(1000))  # a few bytecodes: the handler runs here


def test_signals_raise_at_once_outside_a_deferred_block():
    with interrupts.handling():
        with pytest.raises(interrupts.Terminated):
            _kill(signal.SIGTERM)
        assert interrupts.consume() == signal.SIGTERM
        with pytest.raises(KeyboardInterrupt):
            _kill(signal.SIGINT)
        assert interrupts.consume() == signal.SIGINT and interrupts.received() is None
    assert signal.getsignal(signal.SIGTERM) is not interrupts._handler  # restored


def test_a_deferred_block_ends_before_the_signal_is_raised():
    done = []
    with interrupts.handling():
        with pytest.raises(interrupts.Terminated):
            with interrupts.deferred():
                _kill(signal.SIGTERM)
                with interrupts.deferred():
                    done.append("inner")
                done.append("outer")
        interrupts.consume()
    assert done == ["inner", "outer"]


def test_a_signal_in_a_gc_callback_is_kept_for_check():
    fired = []

    def callback(phase, info):
        if phase == "start" and not fired:
            fired.append(phase)
            _kill(signal.SIGINT)

    gc.callbacks.append(callback)
    try:
        with interrupts.handling():
            gc.collect()  # an exception raised in the callback would be printed and lost (pytest: an error)
            assert fired and interrupts.received() == signal.SIGINT
            with pytest.raises(KeyboardInterrupt):
                interrupts.check()
            interrupts.consume()
            interrupts.check()  # handled: nothing left
    finally:
        gc.callbacks.remove(callback)
    assert interrupts.exit_status(KeyboardInterrupt()) == 130
    assert interrupts.exit_status(interrupts.Terminated()) == 143
