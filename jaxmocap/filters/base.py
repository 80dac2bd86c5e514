"""Building blocks shared by the particle filters: weights, diffusion, joint limits, estimates, recovery, frame loop.

Conventions:

* every filter calls its likelihood as ``loglik_batch(X (N, D), observation, layer) -> (N,)`` with ``layer`` a
  :class:`Layer` (single-layer filters pass :func:`single_layer`: index 0, β = 1, their partition); a likelihood
  that ignores ``layer`` serves every filter;

* particles ``X (N, D)``, log-weights ``(N,)`` normalised so that ``logsumexp = 0``; a NaN or ``±inf`` log-likelihood
  marks a dead particle (log-weight ``-inf``) and is counted in the diagnostics;
* joint limits ``lower, upper (D,)`` (e.g. ``BodyModel.lower/upper``) are applied after every diffusion, by clipping
  (``"clip"``: probability mass piles up on the bound) or by reflection (``"reflect"``: the Gaussian is folded back
  into the box, a kernel that stays symmetric, k(x → y) = k(y → x), and puts no atom on the bound); infinite bounds
  mean no limit;
* a filter is a frozen dataclass registered as a pytree (:func:`register_filter`): its arrays (diffusion std,
  limits, prior), its annealing schedule's values (β, diffusion scales, survival target) and a pytree likelihood's
  leaves are data, traced when the filter is an argument of ``jit``; its configuration (counts, number of layers,
  schemes, modes, a plain likelihood function) is static. ``jax.jit(lambda f, k, s, o: f.step(k, s, o))`` compiles
  once for every filter that differs from the first only in data.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from jaxmocap.filters import annealing, resampling
from jaxmocap.stored_programs import stored_jit

__all__ = [
    "LIMIT_MODES",
    "RECOVERY_MODES",
    "FilterBase",
    "Info",
    "Layer",
    "LayerStats",
    "State",
    "apply_limits",
    "beta_hint",
    "chunked_loglik",
    "filter_init",
    "diffuse",
    "finish",
    "gaussian_logpdf",
    "gaussian_mixture_logpdf",
    "ignore_layer",
    "init_state",
    "layer_stats",
    "mask_loglik",
    "normalise",
    "recover",
    "register_filter",
    "resample",
    "run",
    "single_layer",
    "weighted_mean",
]

LIMIT_MODES = ("clip", "reflect")
# full float32 products: GPUs would otherwise use reduced-precision (TF32) matmuls, and |a|² + |b|² - 2 a·b cancels
_EXACT = jax.lax.Precision.HIGHEST


class Layer(NamedTuple):
    """What an annealed filter tells the likelihood about the current stage (feature-based annealing hook).

    ``index``: the layer ``l`` (int32 scalar, 0 = first layer run in a frame); ``beta``: the exponent of this layer
    when the schedule fixes it in advance, otherwise the previous layer's β (0 in the first layer), since an adaptive
    β is chosen from the returned values; ``partition``: the partition/level (a Python int, 0 when not partitioned;
    a traced int32 in a :class:`~jaxmocap.filters.partitioned.Partitioned` filter with ``scan_partitions``).
    """

    index: jnp.ndarray
    beta: jnp.ndarray
    partition: int | jnp.ndarray = 0


def single_layer(dtype=jnp.float32, partition: int | jnp.ndarray = 0) -> Layer:
    """The :class:`Layer` of a filter without annealing: index 0, β = 1, partition ``partition``."""
    return Layer(jnp.zeros((), jnp.int32), jnp.ones((), dtype), partition)


def ignore_layer(loglik_batch: Callable) -> Callable:
    """Adapt a likelihood ``loglik_batch(X, observation)`` to the filters' ``(X, observation, layer)``."""

    def wrapped(X, observation, layer):
        del layer
        return loglik_batch(X, observation)

    return wrapped


class LayerStats(NamedTuple):
    """Per-layer diagnostics of one weighting (each a scalar; stacked over layers in an ``Info``)."""

    beta: jnp.ndarray
    survival_rate: jnp.ndarray
    ess: jnp.ndarray
    loglik_min: jnp.ndarray
    loglik_max: jnp.ndarray
    loglik_range: jnp.ndarray
    num_nonfinite: jnp.ndarray
    beta_status: jnp.ndarray


@dataclasses.dataclass(frozen=True)
class FilterBase:
    """What every filter holds: its likelihood ``loglik_batch(X, observation, layer) -> (N,)`` and random-walk
    std ``diffusion_std (D,)`` (Δ), then, keyword-only, the joint limits ``lower, upper (D,)`` (or None), the
    ``resampling`` scheme (:mod:`jaxmocap.filters.resampling`), ``limit_mode`` (:data:`LIMIT_MODES`), ``circular``
    (per DOF: averaged as an angle; or None), ``recovery`` (:data:`RECOVERY_MODES`) and ``recovery_widen`` (std
    multiplier of a re-initialised cloud)."""

    loglik_batch: Callable
    diffusion_std: jnp.ndarray
    _: dataclasses.KW_ONLY
    lower: jnp.ndarray | None = None
    upper: jnp.ndarray | None = None
    resampling: str = "systematic"
    limit_mode: str = "clip"
    circular: tuple[bool, ...] | None = None
    recovery: str = "reinit"
    recovery_widen: float = 3.0

    def _recover(
        self, key: jax.Array, X: jnp.ndarray, previous_estimate: jnp.ndarray, ok, mask=None
    ) -> jnp.ndarray:
        """:func:`recover` with this filter's spread, limits and mode: ``X`` where ``ok``, else the fresh set."""
        return recover(
            key, X, previous_estimate, self.diffusion_std, self.recovery_widen, self.lower, self.upper,
            self.limit_mode, self.recovery, ok=ok, mask=mask,
        )  # fmt: skip

    def _weigh_once(self, key, X, log_prior, observation, previous_estimate) -> tuple[State, Info]:
        """A frame of a filter without layers after its proposal: weights ``log_prior + ll(X)`` normalised, then
        :meth:`_finish` (recovery, estimate) — ``(State, Info)`` with one layer of statistics."""
        ll = mask_loglik(self.loglik_batch(X, observation, single_layer(X.dtype)))
        log_w, ok = normalise(log_prior + ll)
        stats = layer_stats(ll, log_w, 1.0)
        X, log_w, estimate, best = self._finish(key, X, log_w, ok, previous_estimate)
        info = Info(estimate, best, jax.tree_util.tree_map(lambda a: a[None], stats), ~ok)
        return State(X, log_w, estimate), info

    def _finish(self, key, X, log_w, ok, previous_estimate):
        """:func:`finish` with this filter's configuration: ``(particles, log_weights, estimate, best)``."""
        return finish(
            key, X, log_w, ok, previous_estimate, self.diffusion_std, widen=self.recovery_widen,
            lower=self.lower, upper=self.upper, limit_mode=self.limit_mode, recovery=self.recovery,
            circular=self.circular,
        )  # fmt: skip


def _is_pytree_callable(fn) -> bool:
    """True when ``fn`` is a registered pytree (a :class:`jax.tree_util.Partial`, a likelihood object), even one
    without leaves (its structure then compares by its own rule instead of by identity), False for a plain function
    (a single leaf)."""
    if fn is None:
        return False
    tree = jax.tree_util.tree_structure(fn)
    return not (jax.tree_util.treedef_is_leaf(tree) and tree.num_leaves == 1)


def register_filter(cls, data_fields: tuple[str, ...]):
    """Register a frozen dataclass as a pytree: ``data_fields`` (arrays, a :class:`~annealing.Schedule`) are data,
    every other field is static (part of the tree structure, hashed into ``jit``'s cache).

    ``loglik_batch`` is data when it is itself a pytree with children (e.g. a :class:`jax.tree_util.Partial` over a
    :class:`jaxmocap.likelihood.compose.Likelihood`, whose cue weights and λ schedule are leaves), static when it is
    a plain function (hashed by identity). So filters that differ only in data share one compiled step.
    """
    names = tuple(f.name for f in dataclasses.fields(cls))
    data = tuple(n for n in names if n in data_fields)
    meta = tuple(n for n in names if n not in data_fields and n != "loglik_batch")

    def flatten(f):
        fn = f.loglik_batch
        traced = _is_pytree_callable(fn)
        children = (fn if traced else None, *(getattr(f, n) for n in data))
        aux = (traced, None if traced else fn, *(getattr(f, n) for n in meta))
        return children, aux

    def unflatten(aux, children):
        f = object.__new__(cls)  # no __post_init__: the leaves may be tracers
        traced, static_fn, *meta_values = aux
        object.__setattr__(f, "loglik_batch", children[0] if traced else static_fn)
        for n, v in zip(data, children[1:], strict=True):
            object.__setattr__(f, n, v)
        for n, v in zip(meta, meta_values, strict=True):
            object.__setattr__(f, n, v)
        return f

    jax.tree_util.register_pytree_node(cls, flatten, unflatten)
    return cls


def mask_loglik(loglik: jnp.ndarray) -> jnp.ndarray:
    """Map NaN and ``±inf`` log-likelihoods to ``-inf`` (dead particles)."""
    return jnp.where(jnp.isfinite(loglik), loglik, -jnp.inf)


def chunked_loglik(loglik_batch: Callable, X: jnp.ndarray, observation, layer, n, chunk: int) -> jnp.ndarray:
    """``(B,)`` log-likelihoods of the first ``n`` rows of a buffer ``X (B, D)`` (``B`` a multiple of ``chunk``;
    ``n`` may be traced): ``loglik_batch`` on chunks of ``chunk`` rows, ``⌈n / chunk⌉`` of them (a loop whose trip
    count is data, so one compiled program serves every ``n``); the rows of the chunks not run are ``-inf``."""
    B = X.shape[0]
    if B % chunk:
        raise ValueError(f"the buffer's {B} rows are not a multiple of the chunk ({chunk})")

    def body(i, ll):
        rows = jax.lax.dynamic_slice_in_dim(X, i * chunk, chunk)
        out = loglik_batch(rows, observation, layer).astype(ll.dtype)
        return jax.lax.dynamic_update_slice_in_dim(ll, out, i * chunk, 0)

    return jax.lax.fori_loop(0, (n + chunk - 1) // chunk, body, jnp.full((B,), -jnp.inf, X.dtype))


def normalise(log_w: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """``(log_w - logsumexp(log_w), ok)`` with non-finite entries at ``-inf``; ``ok`` is False when none is finite.

    When nothing is finite the returned weights are uniform (``-log N``), never NaN.
    """
    lw = mask_loglik(log_w)
    ok = jnp.any(jnp.isfinite(lw))
    norm = lw - jax.nn.logsumexp(jnp.where(ok, lw, 0.0))
    uniform = jnp.full_like(lw, -jnp.log(lw.shape[0]))
    return jnp.where(ok, norm, uniform), ok


def layer_stats(
    loglik: jnp.ndarray, log_w: jnp.ndarray, beta: jnp.ndarray, beta_status: jnp.ndarray | int = 0
) -> LayerStats:
    """Diagnostics of ``(N,)`` log-likelihoods and the normalised log-weights built from them."""
    finite = jnp.isfinite(loglik)
    any_finite = jnp.any(finite)
    lo = jnp.where(any_finite, jnp.min(jnp.where(finite, loglik, jnp.inf)), jnp.nan)
    hi = jnp.where(any_finite, jnp.max(jnp.where(finite, loglik, -jnp.inf)), jnp.nan)
    return LayerStats(
        beta=jnp.asarray(beta, log_w.dtype),
        survival_rate=annealing.survival_rate(log_w),
        ess=annealing.ess(log_w),
        loglik_min=lo,
        loglik_max=hi,
        loglik_range=hi - lo,
        num_nonfinite=jnp.sum(~finite).astype(jnp.int32),
        beta_status=jnp.asarray(beta_status, jnp.int32),
    )


def apply_limits(X: jnp.ndarray, lower, upper, mode: str = "clip") -> jnp.ndarray:
    """Bring ``(..., D)`` states into ``[lower, upper]`` (``(D,)`` each, or None for no limits).

    ``"clip"``: ``min(max(x, lower), upper)``. ``"reflect"``: fold ``x`` back at the bounds as often as needed,
    ``t = (x - lower) mod 2w`` with ``w = upper - lower``, ``x' = lower + (t if t ≤ w else 2w - t)``; entries with an
    infinite bound are clipped (a no-op for the infinite side).
    """
    if lower is None and upper is None:
        return X
    if mode not in LIMIT_MODES:
        raise ValueError(f"unknown limit mode {mode!r}; choose one of {LIMIT_MODES}")
    lower = jnp.full(X.shape[-1], -jnp.inf, X.dtype) if lower is None else jnp.asarray(lower, X.dtype)
    upper = jnp.full(X.shape[-1], jnp.inf, X.dtype) if upper is None else jnp.asarray(upper, X.dtype)
    clipped = jnp.clip(X, lower, upper)
    if mode == "clip":
        return clipped
    width = upper - lower
    finite = jnp.isfinite(width) & (width > 0)
    safe_w = jnp.where(finite, width, 1.0)
    safe_lo = jnp.where(finite, lower, 0.0)
    t = jnp.mod(X - safe_lo, 2.0 * safe_w)
    folded = safe_lo + jnp.where(t > safe_w, 2.0 * safe_w - t, t)
    return jnp.where(finite, folded, clipped)


def diffuse(key: jax.Array, X: jnp.ndarray, std: jnp.ndarray, lower=None, upper=None, mode: str = "clip"):
    """Random-walk move ``X + std ⊙ ε``, ``ε ~ N(0, I)``, then the limits. ``std``: ``(D,)`` or ``(N, D)``."""
    noise = jax.random.normal(key, X.shape, X.dtype)
    return apply_limits(X + std * noise, lower, upper, mode)


def weighted_mean(X: jnp.ndarray, log_w: jnp.ndarray, circular=None) -> jnp.ndarray:
    """Weighted mean ``Σ_i w_i x_i`` of ``(N, D)`` particles with normalised log-weights ``(N,)``.

    Entries flagged in ``circular`` (``(D,)`` bool, or None) use the circular mean
    ``atan2(Σ w_i sin x_i, Σ w_i cos x_i)`` instead, so that angles wrapping at ±π average correctly.
    """
    w = jnp.exp(log_w)
    w = w / jnp.sum(w)
    mean = jnp.matmul(w, X, precision=_EXACT)
    if circular is None:
        return mean
    circ = jnp.asarray(circular, bool)
    ang = jnp.arctan2(
        jnp.matmul(w, jnp.sin(X), precision=_EXACT), jnp.matmul(w, jnp.cos(X), precision=_EXACT)
    )
    return jnp.where(circ, ang, mean)


def gaussian_mixture_logpdf(X: jnp.ndarray, centres: jnp.ndarray, log_w: jnp.ndarray, std: jnp.ndarray):
    """``log Σ_j w_j N(x_i; c_j, diag(std²))`` for every row of ``X (N, D)``; ``centres (M, D)``, ``log_w (M,)``.

    Uses ``|a - b|² = |a|² + |b|² - 2 a·b`` on whitened, centred coordinates (one ``(N, M)`` matrix product instead of
    an ``(N, M, D)`` difference tensor).
    """
    inv = 1.0 / std
    shift = jnp.mean(centres, axis=0)
    a = (X - shift) * inv
    b = (centres - shift) * inv
    sq = (
        jnp.sum(a * a, axis=1)[:, None]
        + jnp.sum(b * b, axis=1)[None, :]
        - 2.0 * jnp.matmul(a, b.T, precision=_EXACT)
    )
    sq = jnp.maximum(sq, 0.0)
    d = X.shape[-1]
    log_norm = -0.5 * d * jnp.log(2.0 * jnp.pi) - jnp.sum(jnp.log(std))
    return jax.nn.logsumexp(log_w[None, :] - 0.5 * sq, axis=1) + log_norm


def gaussian_logpdf(X: jnp.ndarray, mean: jnp.ndarray, std: jnp.ndarray) -> jnp.ndarray:
    """``log N(x_i; mean, diag(std²))`` for every row of ``X (N, D)``."""
    z = (X - mean) / std
    d = X.shape[-1]
    return -0.5 * jnp.sum(z * z, axis=1) - 0.5 * d * jnp.log(2.0 * jnp.pi) - jnp.sum(jnp.log(std))


def resample(scheme: str, key: jax.Array, X: jnp.ndarray, log_w: jnp.ndarray, num_samples: int):
    """``(X[ancestors], ancestors)`` with ``num_samples`` ancestors drawn by the named scheme."""
    anc = resampling.get(scheme)(key, log_w, num_samples)
    return X[anc], anc


def run(step: Callable, key: jax.Array, state: Any, observations: Any) -> tuple[Any, Any]:
    """Filter a sequence: ``lax.scan`` of ``step(key_t, state, observation_t)`` over the leading axis of
    ``observations`` (a pytree of arrays with ``T`` frames). Returns ``(final state, Info stacked over T)``."""
    num_frames = jax.tree_util.tree_leaves(observations)[0].shape[0]
    keys = jax.random.split(key, num_frames)

    def body(carry, inputs):
        k, obs = inputs
        return step(k, carry, obs)

    return jax.lax.scan(body, state, (keys, observations))


RECOVERY_MODES = ("reinit", "uniform")


def recover(
    key: jax.Array,
    X: jnp.ndarray,
    previous_estimate: jnp.ndarray,
    std: jnp.ndarray,
    widen: float,
    lower=None,
    upper=None,
    limit_mode: str = "clip",
    mode: str = "reinit",
    ok=None,
    mask=None,
) -> jnp.ndarray:
    """Particles to use after a weighting where every log-weight was ``-inf``/NaN (their weights become uniform).

    ``"reinit"``: a fresh cloud ``previous_estimate + widen · std ⊙ ε`` inside the limits; ``"uniform"``: keep the
    proposed particles ``X`` (uniform weights over the prior/proposal sample). ``mask`` (``(D,)`` bool): re-draw
    only these coordinates, keep the others of ``X``.

    ``ok`` (scalar bool): the weighting succeeded, so ``X`` is returned as it is; the fresh cloud is drawn only when
    ``ok`` is False (a ``lax.cond``: its ``N × D`` normal draws cost as much as a layer's diffusion, and on a CPU
    the branch not taken does not run; under ``vmap`` with a batched ``ok`` both run and one is selected).
    """
    if mode not in RECOVERY_MODES:
        raise ValueError(f"unknown recovery mode {mode!r}; choose one of {RECOVERY_MODES}")
    if mode == "uniform":
        return X

    def fresh():
        noise = jax.random.normal(key, X.shape, X.dtype)
        out = apply_limits(previous_estimate + widen * std * noise, lower, upper, limit_mode)
        return out if mask is None else jnp.where(mask, out, X)

    if ok is None:
        return fresh()
    return jax.lax.cond(ok, lambda: X, fresh)


class State(NamedTuple):
    """Filter state after a frame: ``particles (N, D)``, normalised ``log_weights (N,)``, ``estimate (D,)``."""

    particles: jnp.ndarray
    log_weights: jnp.ndarray
    estimate: jnp.ndarray


class Info(NamedTuple):
    """Diagnostics of one frame.

    ``estimate (D,)``: the filter's output (weighted mean); ``best (D,)``: the particle of largest final weight;
    ``layers``: :class:`LayerStats` with a leading layer axis ``(L,)`` (``(1,)`` for single-layer filters, ``(K, L)``
    for partitioned ones); ``recovered``: True when some weighting had no finite log-weight and the filter fell back
    (see :func:`recover`); ``layer_sets``: None, or (an annealed filter built with ``keep_layers``) the weighted
    set after each layer, ``(particles (L, N, D), log_weights (L, N))`` (:func:`jaxmocap.eval.mixtures.
    count_layer_modes`).
    """

    estimate: jnp.ndarray
    best: jnp.ndarray
    layers: LayerStats
    recovered: jnp.ndarray
    layer_sets: tuple | None = None


@stored_jit(static_argnames=("num_particles", "limit_mode"))
def init_state(
    key: jax.Array, num_particles: int, mean, std, lower=None, upper=None, limit_mode="clip"
) -> State:
    """A Gaussian cloud ``mean + std ⊙ ε`` of ``num_particles`` particles inside the limits, uniform weights.

    One compiled program (kept on disk by a run of the command line, :func:`jaxmocap.stored_programs.stored_jit`):
    run eagerly its seven operations were seven small programs, each traced, lowered and looked up in the
    compilation cache at every start (0.14 s of a warm stereo ``jaxmocap track`` under cProfile)."""
    mean = jnp.asarray(mean)
    std = jnp.broadcast_to(jnp.asarray(std, mean.dtype), mean.shape)
    X = mean + std * jax.random.normal(key, (num_particles, mean.shape[-1]), mean.dtype)
    X = apply_limits(X, lower, upper, limit_mode)
    log_w = jnp.full((num_particles,), -jnp.log(num_particles), mean.dtype)
    return State(X, log_w, mean)


def filter_init(filt, key: jax.Array, mean: jnp.ndarray, std: jnp.ndarray | None = None) -> State:
    """``init`` of a filter with ``num_particles``, ``diffusion_std`` (Δ), limits and ``limit_mode``:
    ``num_particles`` particles ``mean + std ⊙ ε`` (``std`` defaults to Δ), uniform weights."""
    std = filt.diffusion_std if std is None else std
    return init_state(key, filt.num_particles, mean, std, filt.lower, filt.upper, filt.limit_mode)


def beta_hint(schedule, layer, beta_prev):
    """The β a likelihood is told at ``layer`` (:class:`Layer`): the schedule's when it is fixed, else the previous
    layer's."""
    if schedule.kind == "fixed":
        return jnp.asarray(schedule.betas, beta_prev.dtype)[layer]
    return beta_prev


def finish(
    key: jax.Array,
    X: jnp.ndarray,
    log_w: jnp.ndarray,
    ok: jnp.ndarray,
    previous_estimate: jnp.ndarray,
    std: jnp.ndarray,
    *,
    widen: float,
    lower,
    upper,
    limit_mode: str,
    recovery: str,
    circular,
) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """Apply the recovery when ``ok`` is False; returns ``(particles, log_weights, estimate, best)``."""
    X = recover(key, X, previous_estimate, std, widen, lower, upper, limit_mode, recovery, ok=ok)
    estimate = weighted_mean(X, log_w, circular)
    if recovery == "reinit":
        estimate = jnp.where(ok, estimate, previous_estimate)
    best = X[jnp.argmax(log_w)]
    return X, log_w, estimate, best
