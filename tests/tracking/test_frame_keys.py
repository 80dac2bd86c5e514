"""The tracker's per-frame keys derived on the host (:mod:`jaxmocap.tracking.frame_keys`) are JAX's own."""

import jax
import numpy as np
import pytest

from jaxmocap.tracking.frame_keys import frame_key, threefry2x32


def _jax_keys(seed, t):
    k = jax.random.fold_in(jax.random.key(np.uint32(seed)), np.int32(t))
    return k, jax.random.fold_in(k, 1), jax.random.fold_in(k, 2)


@pytest.mark.parametrize("seed", [0, 1, 7, 12345, 2**31 - 1, 2**31, 2**32 - 1])
def test_frame_keys_are_jax_fold_in_of_jax_key(seed):
    for t in (0, 1, 2, 99, 1000, 2**31 - 1):
        for purpose, b in enumerate(_jax_keys(seed, t)):
            a = frame_key(seed, t, purpose)
            assert a.dtype == b.dtype
            np.testing.assert_array_equal(
                np.asarray(jax.random.key_data(a)), np.asarray(jax.random.key_data(b))
            )


def test_threefry_known_answer():
    """Random123's published known-answer vectors for Threefry-2x32 with 20 rounds (kat_vectors: counter and key
    all zeros, all ones, and the digits of pi)."""
    assert threefry2x32((0, 0), (0, 0)) == (0x6B200159, 0x99BA4EFE)
    assert threefry2x32((0xFFFFFFFF, 0xFFFFFFFF), (0xFFFFFFFF, 0xFFFFFFFF)) == (0x1CB996FC, 0xBB002BE7)
    assert threefry2x32((0x13198A2E, 0x03707344), (0x243F6A88, 0x85A308D3)) == (0xC4923A9C, 0x483DF7A0)


def test_frames_draw_different_noise():
    data = lambda t, p: tuple(np.asarray(jax.random.key_data(frame_key(0, t, p))))  # noqa: E731
    assert data(0, 0) != data(1, 0)
    assert len({data(0, p) for p in (0, 1, 2)}) == 3
    with pytest.raises(ValueError, match="purpose"):
        frame_key(0, 0, 3)
