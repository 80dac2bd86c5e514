"""Resampling schemes for particle filters: multinomial, stratified, systematic, residual.

Every scheme has the signature ``scheme(key, log_weights (N,), num_samples) -> ancestors (M,) int32``:

* ``log_weights`` are log-weights, normalised or not; NaN and ``-inf`` entries get zero probability. If *no* entry is
  finite the weights are taken as uniform (a filter flags that case and recovers; resampling itself never fails).
* ``num_samples`` ``M`` is static (Python int) under ``jit``; ``M`` may differ from ``N`` (partitioned sampling).
* ``ancestors[m]`` is the index of the particle copied into slot ``m``; every scheme is unbiased:
  ``E[#{m: ancestors[m] = i}] = M w_i`` with ``w = softmax(log_weights)``.

All schemes draw by inverting the cumulative distribution ``c_i = w_0 + … + w_i`` at ``M`` points ``u_m ∈ [0, 1)``
(particle ``i`` is chosen when ``c_{i-1} ≤ u_m < c_i``); they differ only in how the points are drawn
(Douc, Cappé & Moulines 2005; Li & Kulić use systematic resampling):

* multinomial: ``u_m`` i.i.d. uniform — offspring counts are Multinomial(M, w), ``Var n_i = M w_i (1 - w_i)``;
* stratified: ``u_m = (m + U_m) / M`` with independent ``U_m ~ U[0, 1)`` — one point per stratum;
* systematic: ``u_m = (m + U) / M`` with a single ``U ~ U[0, 1)`` — every count is ``⌊M w_i⌋`` or ``⌈M w_i⌉``;
* residual: ``⌊M w_i⌋`` deterministic copies, then ``R = M - Σ⌊M w_i⌋`` multinomial draws from the residual weights
  ``(M w_i - ⌊M w_i⌋) / R`` (Liu & Chen 1998).

The inversion is a binary search (``O(M log N)`` time, ``O(N + M)`` memory), never an ``(M, N)`` table.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

__all__ = [
    "SCHEMES",
    "get",
    "multinomial",
    "normalised_weights",
    "residual",
    "stratified",
    "systematic",
]


def normalised_weights(log_weights: jnp.ndarray) -> jnp.ndarray:
    """``(N,)`` probabilities ``softmax(log_weights)``; non-finite entries get 0; uniform if none is finite."""
    log_weights = jnp.asarray(log_weights)
    finite = jnp.isfinite(log_weights)
    lw = jnp.where(finite, log_weights, -jnp.inf)
    any_finite = jnp.any(finite)
    top = jnp.where(any_finite, jnp.max(jnp.where(finite, lw, -jnp.inf)), 0.0)
    w = jnp.where(finite, jnp.exp(lw - top), 0.0)
    w = w / jnp.where(any_finite, jnp.sum(w), 1.0)
    uniform = jnp.full_like(w, 1.0 / w.shape[0])
    return jnp.where(any_finite, w, uniform)


def _invert_cdf(weights: jnp.ndarray, points: jnp.ndarray) -> jnp.ndarray:
    """Indices ``i`` with ``c_{i-1} ≤ u < c_i`` for each point ``u`` in ``[0, 1)``."""
    cdf = jnp.cumsum(weights)
    cdf = cdf / cdf[-1]  # guard against the last sum falling short of 1 in floating point
    idx = jnp.searchsorted(cdf, points, side="right")
    return jnp.clip(idx, 0, weights.shape[0] - 1).astype(jnp.int32)


def multinomial(key: jax.Array, log_weights: jnp.ndarray, num_samples: int) -> jnp.ndarray:
    """Multinomial resampling: ``M`` i.i.d. draws from ``w``. Returns ``(M,)`` int32 ancestors."""
    w = normalised_weights(log_weights)
    u = jax.random.uniform(key, (num_samples,), dtype=w.dtype)
    return _invert_cdf(w, u)


def stratified(key: jax.Array, log_weights: jnp.ndarray, num_samples: int) -> jnp.ndarray:
    """Stratified resampling: one uniform point in each of the ``M`` strata ``[m/M, (m+1)/M)``."""
    w = normalised_weights(log_weights)
    u = (
        jnp.arange(num_samples, dtype=w.dtype) + jax.random.uniform(key, (num_samples,), dtype=w.dtype)
    ) / num_samples
    return _invert_cdf(w, u)


def systematic(key: jax.Array, log_weights: jnp.ndarray, num_samples: int) -> jnp.ndarray:
    """Systematic resampling: the ``M`` points ``(m + U)/M`` share one uniform ``U``."""
    w = normalised_weights(log_weights)
    u = (jnp.arange(num_samples, dtype=w.dtype) + jax.random.uniform(key, (), dtype=w.dtype)) / num_samples
    return _invert_cdf(w, u)


def residual(key: jax.Array, log_weights: jnp.ndarray, num_samples: int) -> jnp.ndarray:
    """Residual resampling: ``⌊M w_i⌋`` copies of each particle, the remainder drawn multinomially.

    The deterministic copies fill slots ``0 … S-1`` (``S = Σ⌊M w_i⌋``, in particle order); slots ``S … M-1`` hold
    the multinomial draws from the residual weights.
    """
    w = normalised_weights(log_weights)
    scaled = num_samples * w
    copies = jnp.floor(scaled)
    # floor can exceed M by rounding when the weights are all on a few particles; clip the running total.
    ends = jnp.minimum(jnp.cumsum(copies), num_samples)
    slots = jnp.arange(num_samples)
    deterministic = jnp.clip(jnp.searchsorted(ends, slots, side="right"), 0, w.shape[0] - 1).astype(jnp.int32)
    remainder = jnp.maximum(scaled - copies, 0.0)
    total = jnp.sum(remainder)
    remainder_w = jnp.where(total > 0, remainder / jnp.where(total > 0, total, 1.0), w)
    u = jax.random.uniform(key, (num_samples,), dtype=w.dtype)
    drawn = _invert_cdf(remainder_w, u)
    return jnp.where(slots < ends[-1], deterministic, drawn)


SCHEMES: dict[str, Callable[[jax.Array, jnp.ndarray, int], jnp.ndarray]] = {
    "multinomial": multinomial,
    "stratified": stratified,
    "systematic": systematic,
    "residual": residual,
}


def get(name: str) -> Callable[[jax.Array, jnp.ndarray, int], jnp.ndarray]:
    """The scheme called ``name`` (one of :data:`SCHEMES`)."""
    try:
        return SCHEMES[name]
    except KeyError:
        raise ValueError(f"unknown resampling scheme {name!r}; choose one of {sorted(SCHEMES)}") from None
