"""The filters' normal draws (:mod:`jaxmocap.filters.normal`) against ``jax.random.normal`` itself, bit for bit, and
Threefry-2x32 against the known-answer vectors published with Random123 (Salmon et al., SC 2011)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.filters.normal import normal, threefry2x32

# Random123's kat_vectors for threefry2x32_20: (key, counter) -> output
KAT = [
    ((0x00000000, 0x00000000), (0x00000000, 0x00000000), (0x6B200159, 0x99BA4EFE)),
    ((0xFFFFFFFF, 0xFFFFFFFF), (0xFFFFFFFF, 0xFFFFFFFF), (0x1CB996FC, 0xBB002BE7)),
    ((0x13198A2E, 0x03707344), (0x243F6A88, 0x85A308D3), (0xC4923A9C, 0x483DF7A0)),
]


@pytest.mark.parametrize("key, counter, expected", KAT)
def test_threefry_known_answers(key, counter, expected):
    out = threefry2x32(*(jnp.uint32(v) for v in key + counter))
    assert tuple(int(o) for o in out) == expected


@pytest.mark.parametrize("shape", [(4000, 31), (600, 14), (7,), (1, 25), (3, 5, 2)])
def test_same_values_as_jax_random_normal(shape):
    for seed in (0, 1, 12345):
        key = jax.random.key(seed)
        want = np.asarray(jax.random.normal(key, shape))
        np.testing.assert_array_equal(np.asarray(normal(key, shape)), want)
        np.testing.assert_array_equal(np.asarray(jax.jit(normal, static_argnums=1)(key, shape)), want)


def test_split_vmapped_and_raw_keys():
    keys = jax.random.split(jax.random.key(7), 5)
    got = jax.vmap(lambda k: normal(k, (300, 31)))(keys)
    want = jax.vmap(lambda k: jax.random.normal(k, (300, 31)))(keys)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    raw = jax.random.PRNGKey(3)  # a legacy uint32[2] key
    np.testing.assert_array_equal(
        np.asarray(normal(raw, (50, 3))), np.asarray(jax.random.normal(raw, (50, 3)))
    )


@pytest.mark.parametrize("dtype", [jnp.bfloat16, jnp.float16])
def test_other_dtypes_fall_back(dtype):
    key = jax.random.key(2)
    got = normal(key, (40, 3), dtype)
    assert got.dtype == dtype
    np.testing.assert_array_equal(np.asarray(got), np.asarray(jax.random.normal(key, (40, 3), dtype)))


def test_rbg_keys_fall_back():
    key = jax.random.key(4, impl="rbg")
    np.testing.assert_array_equal(
        np.asarray(normal(key, (20, 3))), np.asarray(jax.random.normal(key, (20, 3)))
    )


def test_eager_calls_run_one_compiled_program_per_shape():
    """Outside ``jit`` the written-out rounds are not dispatched operation by operation: one compiled program per
    shape, reused for every key."""
    from jaxmocap.filters import normal as module

    before = module._normal_float32._cache_size()
    for seed in range(3):
        normal(jax.random.key(seed), (11, 13))
    assert module._normal_float32._cache_size() == before + 1
