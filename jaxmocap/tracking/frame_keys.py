"""The tracker's per-frame random keys, derived on the host.

Frame ``t`` of a run with seed ``s`` uses ``k = fold_in(key(s), t)`` for the filter step, ``fold_in(k, 1)`` for the
weighted start and ``fold_in(k, 2)`` for a re-initialisation (JAX's default threefry keys). A key is two uint32
words; ``key(s)`` is ``(0, s)`` and ``fold_in(k, d)`` is the Threefry-2x32 block cipher (Salmon et al., *Parallel
random numbers: as easy as 1, 2, 3*, SC 2011; 20 rounds, rotation constants 13 15 26 6 / 17 29 16 24, key schedule
with the parity constant ``0x1BD11BDA``) of the counter pair ``(0, d)`` under key ``k``.

Computed here in NumPy (a few microseconds), they need no compiled program: JAX's own ``fold_in`` is one, whose
first call in a process — trace, lowering and a compilation-cache look-up — took 95–140 ms of every warm run's
start (timed alone in a warm process, three runs, AVX2-only EPYC, 2026-12-01; the warm one-frame PARSEC run
``benchmarks/perf/parsec_latency.py`` times went from 1.48 to 1.42 s with ``--no-plots``, two runs of it
before and after, not side by side). The values are JAX's,
bit for bit
(``tests/tracking/test_frame_keys.py``); with another default key implementation (``jax_default_prng_impl``) the
keys are JAX's own, derived by JAX.
"""

from __future__ import annotations

import jax
import numpy as np

__all__ = ["frame_key", "threefry2x32"]

_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))
_PARITY = 0x1BD11BDA


def _rotl(x: int, d: int) -> int:
    return ((x << d) | (x >> (32 - d))) & 0xFFFFFFFF


def threefry2x32(key: tuple[int, int], counter: tuple[int, int]) -> tuple[int, int]:
    """Threefry-2x32 with 20 rounds: the two words of ``counter`` enciphered under the two words of ``key``
    (Python integers below 2**32)."""
    ks = (key[0], key[1], key[0] ^ key[1] ^ _PARITY)
    x0 = (counter[0] + ks[0]) & 0xFFFFFFFF
    x1 = (counter[1] + ks[1]) & 0xFFFFFFFF
    for block in range(5):
        for d in _ROTATIONS[block % 2]:
            x0 = (x0 + x1) & 0xFFFFFFFF
            x1 = _rotl(x1, d) ^ x0
        x0 = (x0 + ks[(block + 1) % 3]) & 0xFFFFFFFF
        x1 = (x1 + ks[(block + 2) % 3] + block + 1) & 0xFFFFFFFF
    return x0, x1


def _fold_in(key: tuple[int, int], data: int) -> tuple[int, int]:
    return threefry2x32(key, (0, data & 0xFFFFFFFF))


@jax.jit
def _frame_keys_jax(seed, t):
    k = jax.random.fold_in(jax.random.key(seed), t)
    return k, jax.random.fold_in(k, 1), jax.random.fold_in(k, 2)


def frame_key(seed: int, t: int, purpose: int = 0) -> jax.Array:
    """Frame ``t``'s key of a run with ``seed`` for ``purpose`` 0 (the filter step), 1 (the weighted start) or 2
    (a re-initialisation) (module docstring): a JAX key array."""
    if purpose not in (0, 1, 2):
        raise ValueError(f"purpose must be 0, 1 or 2, got {purpose}")
    if jax.config.jax_default_prng_impl != "threefry2x32":
        return _frame_keys_jax(np.uint32(seed), np.int32(t))[purpose]
    k = _fold_in((0, int(seed) & 0xFFFFFFFF), int(t))
    if purpose:
        k = _fold_in(k, purpose)
    return jax.random.wrap_key_data(np.asarray(k, np.uint32), impl="threefry2x32")
