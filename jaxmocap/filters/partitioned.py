"""Partitioned sampling (MacCormick & Isard 2000; Li & Kulić, §II) and hierarchical sampling (López Méndez 2009,
§3.1.2: the torso first, annealing layers at every level).

The state's DOFs are split into ordered, disjoint index groups ``G_0 … G_{K-1}`` with static particle counts
``N_0 … N_{K-1}`` (Li & Kulić: torso 6 DOFs → 1000, head 3 → 200, upper arms 3 → 500, forearms 1 → 200, thighs 3 → 500,
calves 1 → 200; body models give their own groups). Per frame, for ``k = 0 … K-1``:

1. resample the current weighted set to ``N_k`` particles (from the previous frame's final set for ``k = 0``);
2. diffuse only the DOFs of ``G_k`` (random walk with std ``Δ[G_k]``; the others are copied unchanged), limits;
3. weigh with the partition's likelihood ``ll = loglik_batch(X, observation, layer)``, ``layer`` =
   ``Layer(0, 1, partition=k)`` (``k`` a Python int, traced with ``scan_partitions``), normalise.

After the last partition the estimate is the weighted mean of the final set (every particle carries all DOFs).
When the likelihood factorises, ``p(z | x) = Π_k p_k(z | x_{G_k})``, and the dynamics act independently on the groups,
the final weighted set targets the exact filtering posterior (weighted resampling, MacCormick & Isard).
DOFs in no group are never diffused.

Hierarchical sampling: with a ``schedule`` (:class:`jaxmocap.filters.annealing.Schedule`) every level runs that schedule's
annealing layers on its group (as in :class:`jaxmocap.filters.apf.APF`, diffusion ``Δ[G_k] · s_l``), and the
likelihood receives ``Layer(index=l, beta, partition=k)``: ``loglik_batch(X, observation, layer)``.

Compilation: each partition is its own stage of the step, so a step with ``K`` partitions inlines the likelihood
``K`` times (hierarchical: ``2K``, since the first layer of a level runs outside its scan over layers). With
``scan_partitions=True`` — for a likelihood that does not need the partition as a Python int (it receives it
traced) — consecutive partitions whose input sets have their own size (equal counts) run as one ``lax.scan`` over
the partition index, DOF mask and key, their layers all inside the scan over layers (:meth:`Partitioned.runs`):
``full25`` with one count for all six partitions inlines the likelihood once. Keys, masks and the order of
operations are those of the unrolled step. The trade, measured on ``full25`` (``benchmarks/compile_partitions.py``):
with one stage left, compilation 2.6–5.3× faster and each step 9–15 % slower (XLA overlaps less work inside a
loop); with unequal counts (four stages) compilation only 2–16 % faster.

Recovery: a partition (or layer) without any finite log-likelihood re-draws its group's DOFs around the previous
frame's estimate with std ``recovery_widen · Δ`` (or keeps them, ``recovery="uniform"``) with uniform weights, and
sets ``Info.recovered``; with ``"reinit"`` the frame's estimate of those DOFs is the previous frame's. ``Info.layers`` has shape ``(K, L)`` (``L = 1`` without a schedule).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.filters import annealing, base
from jaxmocap.filters.annealing import Schedule
from jaxmocap.filters.base import Info, Layer, State

__all__ = ["Info", "Partitioned", "State", "hierarchical"]


@dataclasses.dataclass(frozen=True)
class Partitioned(base.FilterBase):
    """Partitioned (or, with ``schedule``, hierarchical) sampling.

    Data (traced): ``diffusion_std (D,)``, ``lower, upper``, the values of ``schedule`` (None: partitioned
    sampling); ``loglik_batch`` when it is a pytree.
    Static: a plain ``loglik_batch``, ``groups`` (tuple of tuples of DOF indices), ``counts`` (particles per group),
    the schedule's structure, ``resampling``, ``limit_mode``, ``circular``, ``recovery``,
    ``recovery_widen``, ``scan_partitions`` (run equal-count partitions in one ``lax.scan``; the likelihood then
    receives the partition index traced — see the module docstring).
    """

    groups: tuple[tuple[int, ...], ...]
    counts: tuple[int, ...]
    schedule: Schedule | None = None
    scan_partitions: bool = False

    def __post_init__(self):
        groups = tuple(tuple(int(i) for i in g) for g in self.groups)
        counts = tuple(int(c) for c in self.counts)
        if len(groups) != len(counts) or not groups:
            raise ValueError("one particle count per partition, at least one partition")
        flat = [i for g in groups for i in g]
        if len(flat) != len(set(flat)) or any(i < 0 for i in flat) or any(not g for g in groups):
            raise ValueError("partitions must be non-empty, disjoint groups of non-negative DOF indices")
        if any(c < 1 for c in counts):
            raise ValueError("particle counts must be ≥ 1")
        object.__setattr__(self, "groups", groups)
        object.__setattr__(self, "counts", counts)

    @property
    def num_particles(self) -> int:
        """Size of the set carried between frames (the last partition's count)."""
        return self.counts[-1]

    def init(self, key: jax.Array, mean: jnp.ndarray, std: jnp.ndarray | None = None) -> State:
        """``counts[-1]`` particles ``mean + std ⊙ ε`` (``std`` defaults to Δ), uniform weights."""
        std = self.diffusion_std if std is None else std
        return base.init_state(key, self.num_particles, mean, std, self.lower, self.upper, self.limit_mode)

    def _masks(self, dim: int) -> np.ndarray:
        """``(K, D)`` bool: the DOFs of each group."""
        m = np.zeros((len(self.groups), dim), bool)
        for k, g in enumerate(self.groups):
            m[k, list(g)] = True
        return m

    def runs(self) -> list[tuple[int, int]]:
        """``[(start, stop), …]``: the stages of a step, each running partitions ``start … stop − 1``. Without
        ``scan_partitions`` every partition is its own stage. With it, a partition whose input set has its own size
        (``counts[k − 1] == counts[k]``; the first partition's input is the previous frame's set of ``counts[-1]``)
        joins the stage before it when that stage is of such partitions too: maximal runs of equal counts, each
        scanned, minus a first partition that resamples from a set of another size."""
        out: list[list] = []
        for k in range(len(self.groups)):
            same_size = self.scan_partitions and self.counts[k - 1] == self.counts[k]
            if same_size and out and out[-1][2]:
                out[-1][1] = k + 1
            else:
                out.append([k, k + 1, same_size])
        return [(a, b) for a, b, _ in out]

    def _weigh(self, key, X, ll, beta, status, mask, previous_estimate):
        log_w, ok = base.normalise(beta * jnp.where(jnp.isfinite(ll), ll, -jnp.inf))
        stats = base.layer_stats(ll, log_w, beta, status)
        X_rec = self._recover(key, X, previous_estimate)
        X_rec = jnp.where(mask, X_rec, X)
        return jnp.where(ok, X, X_rec), log_w, stats, ~ok

    def _partition(self, key, X, log_w, k, mask, n, observation, previous_estimate):
        """Run partition ``k`` (a Python int, or traced with ``scan_partitions``) of ``n`` particles on the DOFs
        ``mask (D,)``; returns ``(X, log_w, stats with a leading (L,) axis, recovered)``."""
        dtype = X.dtype
        std_k = jnp.where(mask, self.diffusion_std, 0.0)
        if self.schedule is None:
            k_sel, k_move, k_rec = jax.random.split(key, 3)
            X = base.resample(self.resampling, k_sel, X, log_w, n)[0]
            X = base.diffuse(k_move, X, std_k, self.lower, self.upper, self.limit_mode)
            ll = base.mask_loglik(self.loglik_batch(X, observation, base.single_layer(dtype, k)))
            X, log_w, stats, rec = self._weigh(
                k_rec, X, ll, jnp.ones((), dtype), annealing.STATUS_OK, mask, previous_estimate
            )
            return X, log_w, jax.tree_util.tree_map(lambda a: a[None], stats), rec

        schedule = self.schedule
        scales = jnp.asarray(schedule.scales, dtype)

        def layer_fn(carry, inputs):
            X, log_w, beta_prev, surv_prev, recovered = carry
            kk, layer = inputs
            k_sel, k_move, k_rec = jax.random.split(kk, 3)
            X = base.resample(self.resampling, k_sel, X, log_w, n)[0]
            X = base.diffuse(k_move, X, std_k * scales[layer], self.lower, self.upper, self.limit_mode)
            hint = base.beta_hint(schedule, layer, beta_prev)
            ll = base.mask_loglik(self.loglik_batch(X, observation, Layer(layer, hint, k)))
            sol = annealing.choose_beta(schedule, ll, layer, beta_prev, surv_prev)
            X, log_w, stats, rec = self._weigh(k_rec, X, ll, sol.beta, sol.status, mask, previous_estimate)
            return (X, log_w, stats.beta, stats.survival_rate, recovered | rec), stats

        L = schedule.num_layers
        keys = jax.random.split(key, L)
        layers = jnp.arange(L, dtype=jnp.int32)
        carry = (X, log_w, jnp.zeros((), dtype), jnp.ones((), dtype), jnp.zeros((), bool))
        if self.scan_partitions and X.shape[0] == n:
            carry, stats = jax.lax.scan(layer_fn, carry, (keys, layers))
        else:  # the first layer (resampling from a set of another size in general) runs outside the scan
            carry, first = layer_fn(carry, (keys[0], layers[0]))
            carry, rest = jax.lax.scan(layer_fn, carry, (keys[1:], layers[1:]))
            stats = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), first, rest)
        X, log_w, _, _, rec = carry
        return X, log_w, stats, rec

    def step(self, key: jax.Array, state: State, observation) -> tuple[State, Info]:
        """One frame over all partitions. ``Info.layers`` has shape ``(K, L)``."""
        keys = jax.random.split(key, len(self.groups))
        X, log_w = state.particles, state.log_weights
        masks = self._masks(X.shape[1])
        recovered = jnp.zeros((), bool)
        stale = jnp.zeros(X.shape[1], bool)  # DOFs re-initialised by a recovery in this frame
        all_stats = []
        for start, stop in self.runs():
            n = self.counts[start]

            def stage(carry, inputs, n=n):
                X, log_w, recovered, stale = carry
                kk, k, mask = inputs
                X, log_w, stats, rec = self._partition(kk, X, log_w, k, mask, n, observation, state.estimate)
                return (X, log_w, recovered | rec, stale | (rec & mask)), stats

            carry = (X, log_w, recovered, stale)
            if stop - start == 1:
                carry, stats = stage(carry, (keys[start], start, jnp.asarray(masks[start])))
                stats = jax.tree_util.tree_map(lambda a: a[None], stats)
            else:
                ks = jnp.arange(start, stop, dtype=jnp.int32)
                carry, stats = jax.lax.scan(
                    stage, carry, (keys[start:stop], ks, jnp.asarray(masks[start:stop]))
                )
            X, log_w, recovered, stale = carry
            all_stats.append(stats)
        stats = jax.tree_util.tree_map(lambda *a: jnp.concatenate(a), *all_stats)
        estimate = base.weighted_mean(X, log_w, self.circular)
        if self.recovery == "reinit":
            estimate = jnp.where(stale, state.estimate, estimate)
        best = X[jnp.argmax(log_w)]
        return State(X, log_w, estimate), Info(estimate, best, stats, recovered)


def hierarchical(
    loglik_batch: Callable,
    diffusion_std: jnp.ndarray,
    groups,
    counts,
    schedule: Schedule,
    **kw,
) -> Partitioned:
    """Hierarchical sampling: annealing layers (``schedule``) at every level, ``loglik_batch(X, observation, layer)``
    with ``layer = Layer(index, beta, partition)``; groups ordered torso first."""
    return Partitioned(loglik_batch, diffusion_std, groups, counts, schedule=schedule, **kw)


base.register_filter(Partitioned, ("diffusion_std", "lower", "upper", "schedule"))
