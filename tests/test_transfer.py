"""Host values onto the device without a staged program (``jaxmocap.transfer``)."""

import logging

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.transfer import is_traced, to_device


def compilations(caplog, fn):
    """``fn()`` and the number of programs JAX compiled (or read from its cache) while it ran."""
    caplog.clear()
    with caplog.at_level(logging.WARNING), jax.log_compiles(True):
        out = fn()
    return out, sum(r.getMessage().startswith("Compiling ") for r in caplog.records)


def test_host_arrays_cross_without_a_program_where_jnp_asarray_stages_one(caplog):
    # shapes no other test of this process uses, so neither call can find a program compiled before
    host = np.arange(7 * 13, dtype=np.float64).reshape(7, 13) / 7.0
    x, n = compilations(caplog, lambda: to_device(host, np.float32))
    assert n == 0
    assert isinstance(x, jax.Array) and x.dtype == np.float32 and x.shape == (7, 13) and not x.weak_type
    np.testing.assert_array_equal(np.asarray(x), host.astype(np.float32))  # the host's rounding, bit for bit
    # the measurement can fail: jnp.asarray of a new shape stages (and compiles) a program
    _, n_asarray = compilations(caplog, lambda: jnp.asarray(np.ones((11, 5), np.float32)))
    assert n_asarray >= 1


@pytest.mark.parametrize(
    ("value", "dtype", "expected"),
    [
        (np.zeros(3), None, np.float32),  # float64 canonicalised as JAX does without x64
        ([1, 2, 3], None, np.int32),
        (np.False_, None, np.bool_),
        (0.5, np.float32, np.float32),
        (np.arange(4, dtype=np.uint8), None, np.uint8),
        ([0.0, 1.5], jnp.float32, np.float32),
    ],
)
def test_dtypes_follow_jax_canonicalisation(value, dtype, expected):
    x = to_device(value, dtype)
    assert x.dtype == expected
    assert x.dtype == jnp.asarray(value, dtype).dtype
    np.testing.assert_array_equal(np.asarray(x), np.asarray(jnp.asarray(value, dtype)))


def test_jax_arrays_and_tracers_go_through_jax_numpy():
    y = jnp.arange(3.0)
    assert to_device(y, jnp.int32).dtype == jnp.int32

    def f(t):
        assert is_traced(t)
        return to_device(t, jnp.float32) * 2.0

    np.testing.assert_array_equal(jax.jit(f)(jnp.arange(3)), [0.0, 2.0, 4.0])
    assert jax.grad(lambda t: to_device(t, jnp.float32) ** 2)(3.0) == 6.0
    assert not is_traced(y) and not is_traced(np.ones(2)) and not is_traced(1.0)
