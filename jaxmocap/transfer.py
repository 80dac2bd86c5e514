"""Host values onto the device without a program.

``jnp.asarray`` of a NumPy array or a Python number stages a small program the first time a process sees each
shape and dtype (JAX 0.10: ``jit(stage)``, or ``jit(convert_element_type)`` when the dtype changes), and so do
``jnp.zeros`` and the other constructors: each is a lowering plus a compilation, or a read of the persistent
compilation cache, for what is a copy of a few bytes. A warm ``jaxmocap track`` spent about a second of its set-up
on a hundred of them. ``jax.device_put`` of a NumPy array copies the bytes with no program. Set-up code that turns
host constants into device arrays therefore works in NumPy and crosses with :func:`to_device`; code that may run
under a trace (a tracer among its inputs) keeps ``jax.numpy``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["is_traced", "to_device"]


def is_traced(x) -> bool:
    """True when ``x`` is a JAX tracer (inside ``jit``, ``grad``, ``vmap``…), whose value the host cannot read."""
    return isinstance(x, jax.core.Tracer)


def to_device(x, dtype=None) -> jax.Array:
    """``x`` as a ``jax.Array`` of ``dtype`` (default: ``x``'s own), the dtype canonicalised as JAX does (64-bit
    types become 32-bit ones unless ``jax_enable_x64``).

    Host values (NumPy arrays, Python numbers and nested sequences of them) are converted on the host and copied
    with ``jax.device_put``: no program is staged. ``jax.Array`` values and tracers go through ``jnp.asarray``, so
    the function may be called under a trace. Unlike ``jnp.asarray(python_float)`` the result is never weakly
    typed.
    """
    if isinstance(x, jax.Array):
        return jnp.asarray(x, dtype)
    a = np.asarray(x, dtype=None if dtype is None else np.dtype(dtype))
    canonical = jax.dtypes.canonicalize_dtype(a.dtype)
    return jax.device_put(a if a.dtype == canonical else a.astype(canonical))
