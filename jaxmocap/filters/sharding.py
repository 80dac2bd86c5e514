"""Scaling a filter beyond one device with JAX's own machinery: sharded particles, batched runs, bounded memory.

Three independent pieces, none of which changes the filter code (:mod:`jaxmocap.filters`):

* **sharded particles** (:func:`sharded_step`, :func:`sharded_run`): the particle axis ``N`` of the state
  (``particles (N, D)``, ``log_weights (N,)``) is split over the devices of a one-axis
  :class:`jax.sharding.Mesh` (``NamedSharding(mesh, P("particles"))``); the filter, the key and the observation are
  replicated, and the step is compiled once by ``jax.jit`` with these ``in_shardings``/``out_shardings``. XLA's
  SPMD partitioner inserts the collectives: resampling stays **global** (the cumulative weights and the ancestor
  gather see all ``N`` particles), so a sharded run samples the same ancestors as an unsharded one, and the
  random numbers do not depend on the sharding (``jax_threefry_partitionable``, JAX's default). The likelihood,
  the expensive part, is additionally pinned to the particle sharding with ``with_sharding_constraint`` on its
  input and output, so that each device evaluates only its ``N / n_dev`` particles.
* **batched runs** (:func:`batched_run`): ``B`` independent runs (seeds, and/or sequences of equal shape) in one
  compiled call, ``jit(vmap(run))`` with :func:`jaxmocap.filters.base.run` (a ``lax.scan`` over frames) inside;
  with a mesh, the batch axis is sharded over the devices (``P("batch")``), i.e. the runs are spread over them.
* **chunked likelihood** (:func:`chunked`, :func:`with_chunks`): ``loglik(X (N, D), ...) -> (N,)`` evaluated as
  ``lax.map`` over ``⌈N / c⌉`` equal chunks of at most ``c`` particles, so that the likelihood's intermediates — e.g. the
  ``(N, V, P)`` projected flesh points of :class:`jaxmocap.likelihood.compose.Likelihood` — take ``O(c)`` memory
  instead of ``O(N)``; the result is the same function of each particle, computed in pieces.

Example (two devices, forced on a CPU with ``XLA_FLAGS=--xla_force_host_platform_device_count=2`` set before
``jax`` is imported)::

    mesh = scale.device_mesh()                       # all devices on the axis "particles"
    step = scale.sharded_step(filt, mesh)            # filt: any jaxmocap filter
    state = scale.shard_state(filt.init(key, x0), mesh)
    state, info = step(key_t, state, observation)    # info replicated on every device

Multi-host: after ``jax.distributed.initialize()`` in every process, ``jax.devices()`` lists the devices of all
hosts and the same code runs a global mesh over them (see ``benchmarks/results/scale.md``).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import AxisType, Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from jaxmocap.filters import base
from jaxmocap.filters.base import State

__all__ = [
    "BATCH_AXIS",
    "PARTICLE_AXIS",
    "batch_sharding",
    "batched_init",
    "batched_run",
    "chunked",
    "device_mesh",
    "gather",
    "shard_state",
    "sharded_run",
    "sharded_step",
    "state_sharding",
    "with_chunks",
]

PARTICLE_AXIS = "particles"
BATCH_AXIS = "batch"


def device_mesh(num_devices: int | None = None, axis_name: str = PARTICLE_AXIS, devices=None) -> Mesh:
    """A one-axis mesh over the first ``num_devices`` of ``devices`` (default: all of ``jax.devices()``, i.e.
    every device of every process after ``jax.distributed.initialize``)."""
    devices = list(jax.devices() if devices is None else devices)
    n = len(devices) if num_devices is None else int(num_devices)
    if not 1 <= n <= len(devices):
        raise ValueError(f"num_devices must be between 1 and {len(devices)} (the devices available), got {n}")
    return jax.make_mesh((n,), (axis_name,), axis_types=(AxisType.Auto,), devices=devices[:n])


def _replicated(mesh: Mesh) -> NamedSharding:
    return NamedSharding(mesh, P())


def state_sharding(mesh: Mesh, axis: str | None = None) -> State:
    """:class:`~jaxmocap.filters.base.State` of shardings: ``particles (N, D)`` and ``log_weights (N,)`` split
    along ``N`` over ``axis`` (default: the mesh's only axis), ``estimate (D,)`` replicated."""
    axis = mesh.axis_names[0] if axis is None else axis
    split = NamedSharding(mesh, P(axis))
    return State(split, split, _replicated(mesh))


def _check_divisible(n: int, mesh: Mesh, what: str) -> None:
    if n % mesh.size:
        raise ValueError(f"{what} ({n}) must be a multiple of the number of devices ({mesh.size})")


def shard_state(state: State, mesh: Mesh, axis: str | None = None) -> State:
    """Place a filter state on the mesh with :func:`state_sharding` (``N`` must divide evenly)."""
    _check_divisible(state.particles.shape[0], mesh, "the number of particles")
    shardings = state_sharding(mesh, axis)
    if jax.process_count() > 1:  # every process holds the same state: each builds its own devices' shards
        return State(*(_global(a, s) for a, s in zip(state, shardings, strict=True)))
    return jax.device_put(state, shardings)


def _constrained(loglik: Callable, sharding: NamedSharding) -> Callable:
    """``loglik`` with its particles ``X (N, D)`` and its result ``(N,)`` pinned to ``sharding`` (along ``N``)."""

    def wrapped(X, *args):
        X = jax.lax.with_sharding_constraint(X, sharding)
        return jax.lax.with_sharding_constraint(loglik(X, *args), sharding)

    return wrapped


def _shard_likelihood(filt, mesh: Mesh, axis: str):
    if not hasattr(filt, "loglik_batch"):
        return filt
    return dataclasses.replace(filt, loglik_batch=_constrained_cached(filt.loglik_batch, mesh, axis))


@functools.lru_cache(maxsize=64)
def _constrained_cached(loglik: Callable, mesh: Mesh, axis: str) -> Callable:
    # one wrapper per (likelihood, mesh, axis): the filter's static fields, hence jit's cache key, stay the same
    return _constrained(loglik, NamedSharding(mesh, P(axis)))


def sharded_step(filt, mesh: Mesh, axis: str | None = None) -> Callable:
    """``step(key, state, observation) -> (State, Info)`` of ``filt`` compiled with the particle axis sharded.

    ``state`` (from :func:`shard_state`, or any placement: ``jit`` moves it) has ``N`` split over ``axis``; the
    returned state keeps that sharding and ``Info`` is replicated. The filter's arithmetic is unchanged: the
    partitioner adds the cross-device reductions (normalisation, ESS, β search, weighted mean) and the global
    resampling gather, so estimates equal those of ``filt.step`` up to the summation order of those reductions.
    """
    axis = mesh.axis_names[0] if axis is None else axis
    rep = _replicated(mesh)
    st = state_sharding(mesh, axis)
    f = _shard_likelihood(filt, mesh, axis)
    step = jax.jit(type(f).step, in_shardings=(rep, rep, st, rep), out_shardings=(st, rep))

    def run_step(key, state, observation):
        _check_divisible(state.particles.shape[0], mesh, "the number of particles")
        return step(f, key, state, observation)

    return run_step


def sharded_run(filt, key: jax.Array, state: State, observations: Any, mesh: Mesh, axis: str | None = None):
    """A whole sequence (:func:`jaxmocap.filters.base.run`, one ``lax.scan`` over the ``T`` frames of
    ``observations``) with the particle axis sharded. Returns ``(final State, Info stacked over T)``."""
    axis = mesh.axis_names[0] if axis is None else axis
    _check_divisible(state.particles.shape[0], mesh, "the number of particles")
    return _sharded_runner(mesh, axis)(_shard_likelihood(filt, mesh, axis), key, state, observations)


@functools.lru_cache(maxsize=64)
def _sharded_runner(mesh: Mesh, axis: str) -> Callable:
    rep, st = _replicated(mesh), state_sharding(mesh, axis)
    return jax.jit(_run, in_shardings=(rep, rep, st, rep), out_shardings=(st, rep))


def _run(f, key, state, observations):
    return base.run(f.step, key, state, observations)


# ---------------------------------------------------------------------------------------------------------------
# Batched runs


def batch_sharding(mesh: Mesh, axis: str | None = None) -> NamedSharding:
    """Arrays with a leading batch axis ``(B, ...)`` split along ``B`` over ``axis`` (default: the mesh's axis)."""
    return NamedSharding(mesh, P(mesh.axis_names[0] if axis is None else axis))


def batched_init(filt, keys: jax.Array, mean, std=None) -> State:
    """``B`` initial states, ``filt.init(keys[b], mean, std)`` for each of the ``B`` keys (vmapped)."""
    return jax.vmap(lambda k: filt.init(k, mean, std))(keys)


def _pad(tree, b: int, total: int):
    """Pad the leading axis of every leaf from ``b`` to ``total`` entries with copies of the last entry."""
    if total == b:
        return tree
    return jax.tree_util.tree_map(lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], total - b, axis=0)]), tree)


def _global(tree, sharding: NamedSharding):
    """Host values (the same on every process) as global arrays of ``sharding``. One process: ``jit`` places
    them itself; several (``jax.distributed``): each process builds the shards of its own devices."""
    if jax.process_count() == 1:
        return tree

    def one(a):
        a = np.asarray(a)
        return jax.make_array_from_callback(a.shape, sharding, lambda idx: a[idx])

    return jax.tree_util.tree_map(one, tree)


def gather(tree):
    """The full value of (possibly multi-process) global arrays on every process, as NumPy arrays."""
    if jax.process_count() == 1:
        return jax.device_get(tree)
    from jax.experimental import multihost_utils

    return multihost_utils.process_allgather(tree, tiled=True)


@functools.lru_cache(maxsize=64)
def _batched_runner(impl, batched_observations: bool, mesh: Mesh | None) -> Callable:
    """The jitted ``vmap(run)``, cached so that repeated calls with the same filter configuration reuse it."""

    def one(f, kd, s, o):
        return base.run(f.step, jax.random.wrap_key_data(kd, impl=impl), s, o)

    fn = jax.vmap(one, in_axes=(None, 0, 0, 0 if batched_observations else None))
    if mesh is None:
        return jax.jit(fn)
    split, rep = batch_sharding(mesh), _replicated(mesh)
    obs = split if batched_observations else rep
    return jax.jit(fn, in_shardings=(rep, split, split, obs), out_shardings=split)


def batched_run(
    filt,
    keys: jax.Array,
    states: State,
    observations: Any,
    mesh: Mesh | None = None,
    *,
    batched_observations: bool = False,
):
    """``B`` independent runs of ``filt`` in one compiled call: ``jit(vmap(run))``.

    ``keys (B,)`` (typed keys, e.g. ``jax.vmap(jax.random.key)(seeds)``) and ``states`` (a :class:`State` with a
    leading ``B`` axis, e.g. :func:`batched_init`); ``observations``: one sequence (leaves ``(T, ...)``) shared by
    every run, or with ``batched_observations`` one per run (leaves ``(B, T, ...)``: sequences of equal shape).
    Run ``b`` equals ``base.run(filt.step, keys[b], states[b], observations[b])``.

    With ``mesh``, the batch axis is sharded over its devices: the runs are spread over them (``B`` is padded to
    a multiple of the device count with copies of the last run, whose results are dropped). A mesh over the
    devices of several processes (after ``jax.distributed.initialize``) works the same way when every process
    calls this with the same values; then the results are gathered (:func:`gather`) to every process as NumPy.
    Returns ``(final States (B, ...), Info (B, T, ...))``.
    """
    b = keys.shape[0]
    impl = jax.random.key_impl(keys)
    data = jax.random.key_data(keys)  # (B, ...) uint32: plain arrays cross process boundaries
    fn = _batched_runner(impl, bool(batched_observations), mesh)
    if mesh is None:
        return fn(filt, data, states, observations)
    total = -(-b // mesh.size) * mesh.size
    data, states = _pad(data, b, total), _pad(states, b, total)
    if batched_observations:
        observations = _pad(observations, b, total)
    split = batch_sharding(mesh)
    obs_sharding = split if batched_observations else _replicated(mesh)
    args = (_global(data, split), _global(states, split), _global(observations, obs_sharding))
    out = fn(filt, *args)
    if jax.process_count() > 1:
        out = gather(out)
    return jax.tree_util.tree_map(lambda a: a[:b], out)


# ---------------------------------------------------------------------------------------------------------------
# Memory-bounded likelihood


def chunked(loglik: Callable, chunk_size: int) -> Callable:
    """``loglik(X (N, D), *args) -> (N,)`` evaluated at most ``chunk_size`` particles at a time.

    ``X`` goes as ``n = ⌈N / c⌉`` equal chunks of ``⌈N / n⌉ ≤ c`` particles (4097 particles at ``c = 4096`` as two
    of 2049, not two of 4096), the last padded with copies of the first particle (their values are dropped),
    mapped with ``lax.map``, a sequential loop whose body holds the intermediates of one chunk: peak memory
    ``O(c)`` instead of ``O(N)`` (at ``c ≥ N`` or ``c ≤ 0``, one call as before). ``loglik`` may return any pytree
    of ``(N, ...)`` arrays. Every particle's value is the same function of that particle (the likelihoods are
    per-particle), so the result equals ``loglik(X, *args)``: bit for bit for element-wise computations;
    reductions inside a particle (sums over points and views) keep their order.
    """
    c = int(chunk_size)

    def wrapped(X, *args):
        N, D = X.shape
        if c <= 0 or N <= c:
            return loglik(X, *args)
        n = -(-N // c)
        size = -(-N // n)
        if n * size > N:
            X = jnp.concatenate([X, jnp.broadcast_to(X[:1], (n * size - N, D))])
        out = jax.lax.map(lambda Xc: loglik(Xc, *args), X.reshape(n, size, D))
        return jax.tree_util.tree_map(lambda a: a.reshape((n * size,) + a.shape[2:])[:N], out)

    return wrapped


def with_chunks(filt, chunk_size: int):
    """The same filter with its likelihood evaluated in chunks of ``chunk_size`` particles (:func:`chunked`)."""
    if not hasattr(filt, "loglik_batch"):
        raise TypeError(f"{type(filt).__name__} has no loglik_batch to evaluate in chunks")
    return dataclasses.replace(filt, loglik_batch=chunked(filt.loglik_batch, chunk_size))
