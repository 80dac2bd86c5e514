"""Standard normal draws for the filters' moves: ``jax.random.normal``'s values, computed as one fused loop.

:func:`normal` returns exactly what ``jax.random.normal(key, shape, dtype)`` returns (the same bits: tested), so a
run's random stream does not depend on which of the two draws it. It exists for speed on a CPU: JAX lowers its
Threefry-2x32 hash there as a rolled loop over whole arrays (five passes, each writing two ``N·D`` word arrays;
it compiles faster), and applies the inverse error function on the ``(N, D)`` array, whose short minor axis
(``D`` = 14–31) vectorises poorly. Here the 20 rounds are written out, so that XLA fuses the hash, the conversion
to a uniform and ``erf⁻¹`` into one loop over the flat array: 1.7–1.9× for ``(4000, 31)`` draws on an AMD EPYC
(family 25, model 17), a layer's diffusion of the PARSEC tracker.

The construction is JAX's, for a typed or raw Threefry key with ``jax_threefry_partitionable`` (the default):
element ``i`` of the flattened shape hashes the counter ``(0, i)`` with the key's two words, Threefry-2x32 with 20
rounds (Salmon et al., "Parallel random numbers: as easy as 1, 2, 3", SC 2011: rotations (13, 15, 26, 6) and (17,
29, 16, 24), a key injection every 4 rounds, the parity constant 0x1BD11BDA), and takes the XOR of the two output
words; the top 23 bits make a float32 ``f`` in [0, 1), ``u = max(lo, 2 f + lo)`` with ``lo`` the float32 after −1,
and ``z = √2 erf⁻¹(u)``. Any other case (another key implementation or dtype, the non-partitionable stream, 2³²
elements or more) calls ``jax.random.normal`` itself.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["normal", "threefry2x32"]

_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))
_PARITY = np.uint32(0x1BD11BDA)


def _rotl(x, r: int):
    return (x << np.uint32(r)) | (x >> np.uint32(32 - r))


def threefry2x32(k0, k1, x0, x1):
    """Threefry-2x32 with 20 rounds of key ``(k0, k1)`` on counters ``(x0, x1)`` (uint32 arrays that broadcast),
    written out round by round → the two output words."""
    ks = (k0, k1, k0 ^ k1 ^ _PARITY)
    x0 = x0 + ks[0]
    x1 = x1 + ks[1]
    for i in range(5):
        for r in _ROTATIONS[i % 2]:
            x0 = x0 + x1
            x1 = _rotl(x1, r) ^ x0
        x0 = x0 + ks[(i + 1) % 3]
        x1 = x1 + ks[(i + 2) % 3] + np.uint32(i + 1)
    return x0, x1


def _threefry_words(key) -> jax.Array | None:
    """The key's two uint32 words ``(2,)`` when ``jax.random`` would hash with them as above, else None."""
    if not jax.config.jax_threefry_partitionable:
        return None
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        if key.shape != () or str(jax.random.key_impl(key)) != "threefry2x32":
            return None
        data = jax.random.key_data(key)
    elif key.dtype == jnp.uint32 and key.shape == (2,) and jax.config.jax_default_prng_impl == "threefry2x32":
        data = key
    else:
        return None
    return data


def normal(key: jax.Array, shape: tuple[int, ...], dtype=jnp.float32) -> jnp.ndarray:
    """``jax.random.normal(key, shape, dtype)``, the same values (module docstring). Called outside ``jit`` it
    runs as one compiled program (:func:`_normal_float32`), not operation by operation."""
    shape = tuple(int(s) for s in shape)
    words = _threefry_words(key)
    if words is None or jnp.dtype(dtype) != jnp.float32 or math.prod(shape) >= 2**32:
        return jax.random.normal(key, shape, dtype)
    return _normal_float32(words, shape)


@functools.partial(jax.jit, static_argnums=1)
def _normal_float32(words: jax.Array, shape: tuple[int, ...]) -> jnp.ndarray:
    """The float32 draws of :func:`normal` for the key words ``(2,)``."""
    size = math.prod(shape)
    counter = jax.lax.iota(jnp.uint32, size)
    a, b = threefry2x32(words[0], words[1], jnp.zeros_like(counter), counter)
    one = np.array(1.0, np.float32).view(np.uint32)
    f = jax.lax.bitcast_convert_type(((a ^ b) >> np.uint32(9)) | one, jnp.float32) - np.float32(1.0)
    lo = np.nextafter(np.float32(-1.0), np.float32(0.0))
    u = jax.lax.max(lo, f * (np.float32(1.0) - lo) + lo)
    return (np.float32(math.sqrt(2.0)) * jax.lax.erf_inv(u)).reshape(shape)
