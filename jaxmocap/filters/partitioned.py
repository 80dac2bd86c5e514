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

Compilation: without ``scan_partitions`` each partition is its own stage of the step, so a step with ``K``
partitions inlines the likelihood ``K`` times (hierarchical: ``2K``, since the first layer of a level runs outside
its scan over layers). With ``scan_partitions=True`` — for a likelihood that does not need the partition as a
Python int (it receives it traced) — all partitions run as one ``lax.scan`` over the partition index, DOF mask and
key, their layers inside a scan over layers, and the likelihood is inlined once (:meth:`Partitioned._scanned`).
With unequal counts the set lives in a buffer of :attr:`Partitioned.buffer_size` rows (the largest count rounded
up to whole chunks of ``chunk`` rows): resampling, diffusion and weighing run on the first ``N_k`` rows (a
``lax.switch`` over the distinct counts, each branch the unrolled step's operations on arrays of the true size, so
the random draws are the same) and the likelihood on the ``⌈N_k / chunk⌉`` chunks that hold them (a loop whose trip
count is data: the same evaluations as a batch of ``N_k``). Keys, masks and the order of operations are those of
the unrolled step: equal counts give it bit for bit; unequal counts give the same particles, and log-likelihoods
that can differ in the last bit where the likelihood's arithmetic depends on the batch width (``chunk`` rows
instead of ``N_k``; the tracker's ``coverage`` term does). Measured on ``full25`` with Li & Kulić's counts
(``benchmarks/results/compile_time.md``): compilation in a third of the CPU time, the step no slower.

Recovery: a partition (or layer) without any finite log-likelihood re-draws its group's DOFs around the previous
frame's estimate with std ``recovery_widen · Δ`` (or keeps them, ``recovery="uniform"``) with uniform weights, and
sets ``Info.recovered``; with ``"reinit"`` the frame's estimate of those DOFs is the previous frame's. ``Info.layers`` has shape ``(K, L)`` (``L = 1`` without a schedule).
"""

from __future__ import annotations

import dataclasses
import functools
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
    ``recovery_widen``, ``scan_partitions`` (run all partitions in one ``lax.scan``; the likelihood then
    receives the partition index traced — see the module docstring), ``chunk`` (rows per likelihood call of a
    scanned step with unequal counts; the tracker's likelihood works in chunks of 128 itself).
    """

    groups: tuple[tuple[int, ...], ...]
    counts: tuple[int, ...]
    schedule: Schedule | None = None
    scan_partitions: bool = False
    chunk: int = 128

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
        if self.chunk < 1:
            raise ValueError("chunk must be ≥ 1")
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
        """``[(start, stop), …]``: the stages of a step, each running partitions ``start … stop − 1`` and inlining
        the likelihood once: every partition alone, or with ``scan_partitions`` all of them in one stage."""
        K = len(self.groups)
        return [(0, K)] if self.scan_partitions else [(k, k + 1) for k in range(K)]

    @property
    def buffer_size(self) -> int:
        """Rows of the particle buffer of a scanned step: the count when all are equal, else the largest count
        rounded up to a multiple of ``chunk``."""
        if len(set(self.counts)) == 1:
            return self.counts[0]
        return -(-max(self.counts) // self.chunk) * self.chunk

    # -- one layer: propose (resample, diffuse), evaluate, accept (β, weights, recovery) ----------------------

    def _propose(self, k_sel, k_move, X, log_w, n, std):
        X = base.resample(self.resampling, k_sel, X, log_w, n)[0]
        return base.diffuse(k_move, X, std, self.lower, self.upper, self.limit_mode)

    def _accept(self, k_rec, X, ll, layer, beta_prev, surv_prev, mask, previous_estimate):
        """β (1 without a schedule), normalised weights and the recovery: ``(X, log_w, stats, recovered)``."""
        if self.schedule is None:
            beta, status = jnp.ones((), X.dtype), annealing.STATUS_OK
        else:
            sol = annealing.choose_beta(self.schedule, ll, layer, beta_prev, surv_prev)
            beta, status = sol.beta, sol.status
        log_w, ok = base.normalise(beta * jnp.where(jnp.isfinite(ll), ll, -jnp.inf))
        stats = base.layer_stats(ll, log_w, beta, status)
        return self._recover(k_rec, X, previous_estimate, ok, mask), log_w, stats, ~ok

    def _layer(self, carry, inputs, k, mask, propose, evaluate, accept):
        """One layer of partition ``k``: ``propose(k_sel, k_move, X, log_w, std, layer)``, ``evaluate(X, layer)``
        (log-likelihoods), ``accept(k_rec, X, ll, layer, beta_prev, surv_prev)``. ``carry``: ``(X, log_w, β,
        survival rate, recovered)`` of the previous layer; ``inputs``: ``(key, layer index)``."""
        X, log_w, beta_prev, surv_prev, recovered = carry
        kk, layer = inputs
        k_sel, k_move, k_rec = jax.random.split(kk, 3)
        std = jnp.where(mask, self.diffusion_std, 0.0)
        if self.schedule is None:
            lay = base.single_layer(X.dtype, k)
        else:
            std = std * jnp.asarray(self.schedule.scales, X.dtype)[layer]
            lay = Layer(layer, base.beta_hint(self.schedule, layer, beta_prev), k)
        X = propose(k_sel, k_move, X, log_w, std, layer)
        ll = base.mask_loglik(evaluate(X, lay))
        X, log_w, stats, rec = accept(k_rec, X, ll, layer, beta_prev, surv_prev)
        return (X, log_w, stats.beta, stats.survival_rate, recovered | rec), stats

    def _partition(self, key, X, log_w, k, mask, layer_fn, first_apart):
        """The layers of partition ``k`` from the set ``(X, log_w)``: ``layer_fn(carry, (key, layer))``; the first
        layer outside the scan over layers when ``first_apart`` (it changes the set's size). Returns ``(X, log_w,
        stats with a leading (L,) axis, recovered)``."""
        dtype = X.dtype
        carry = (X, log_w, jnp.zeros((), dtype), jnp.ones((), dtype), jnp.zeros((), bool))
        if self.schedule is None:
            carry, stats = layer_fn(carry, (key, jnp.zeros((), jnp.int32)))
            stats = jax.tree_util.tree_map(lambda a: a[None], stats)
        else:
            L = self.schedule.num_layers
            keys = jax.random.split(key, L)
            layers = jnp.arange(L, dtype=jnp.int32)
            if first_apart:
                carry, first = layer_fn(carry, (keys[0], layers[0]))
                carry, rest = jax.lax.scan(layer_fn, carry, (keys[1:], layers[1:]))
                stats = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), first, rest)
            else:
                carry, stats = jax.lax.scan(layer_fn, carry, (keys, layers))
        X, log_w, _, _, rec = carry
        return X, log_w, stats, rec

    # -- the frame ---------------------------------------------------------------------------------------------

    def step(self, key: jax.Array, state: State, observation) -> tuple[State, Info]:
        """One frame over all partitions. ``Info.layers`` has shape ``(K, L)``."""
        keys = jax.random.split(key, len(self.groups))
        if self.scan_partitions:
            X, log_w, recovered, stale, stats = self._scanned(keys, state, observation)
        else:
            X, log_w, recovered, stale, stats = self._unrolled(keys, state, observation)
        estimate = base.weighted_mean(X, log_w, self.circular)
        if self.recovery == "reinit":
            estimate = jnp.where(stale, state.estimate, estimate)
        best = X[jnp.argmax(log_w)]
        return State(X, log_w, estimate), Info(estimate, best, stats, recovered)

    def _unrolled(self, keys, state, observation):
        """Every partition its own stage (``k`` a Python int); ``(X, log_w, recovered, stale DOFs, stats)``."""
        X, log_w = state.particles, state.log_weights
        masks = self._masks(X.shape[1])
        recovered = jnp.zeros((), bool)
        stale = jnp.zeros(X.shape[1], bool)  # DOFs re-initialised by a recovery in this frame
        all_stats = []
        for k, n in enumerate(self.counts):
            mask = jnp.asarray(masks[k])
            propose = lambda ks, km, X, lw, std, layer, n=n: self._propose(ks, km, X, lw, n, std)
            evaluate = lambda X, lay: self.loglik_batch(X, observation, lay)
            accept = lambda kr, X, ll, layer, b, s, mask=mask: self._accept(
                kr, X, ll, layer, b, s, mask, state.estimate
            )
            layer_fn = functools.partial(
                self._layer, k=k, mask=mask, propose=propose, evaluate=evaluate, accept=accept
            )
            X, log_w, stats, rec = self._partition(keys[k], X, log_w, k, mask, layer_fn, True)
            recovered, stale = recovered | rec, stale | (rec & mask)
            all_stats.append(jax.tree_util.tree_map(lambda a: a[None], stats))
        return X, log_w, recovered, stale, jax.tree_util.tree_map(lambda *a: jnp.concatenate(a), *all_stats)

    def _scanned(self, keys, state, observation):
        """All partitions in one ``lax.scan`` (``k`` traced); ``(X, log_w, recovered, stale DOFs, stats)``.

        Equal counts: the set keeps its size. Unequal counts: the set lives in a buffer of :attr:`buffer_size`
        rows whose first ``N_k`` rows are partition ``k``'s particles (the others are copies of the first).
        Resampling, diffusion and weighing run on those rows (``lax.switch`` over the distinct ``(N_in, N_k)``
        pairs and counts ``N_k``: each a small program, the same operations as the unrolled step), and the
        likelihood on ``⌈N_k / chunk⌉`` chunks of ``chunk`` rows (a loop with a trip count of data), so that it is
        traced and compiled once for all partitions and evaluates the same rows as a batch of ``N_k`` padded to
        whole chunks."""
        X, log_w = state.particles, state.log_weights
        K, counts = len(self.groups), self.counts
        B = self.buffer_size
        masks = jnp.asarray(self._masks(X.shape[1]))
        L = 1 if self.schedule is None else self.schedule.num_layers
        pairs = sorted({(counts[k - 1], counts[k]) for k in range(K)} | {(n, n) for n in counts if L > 1})
        sizes = sorted(set(counts))
        table = np.asarray(
            [
                [pairs.index((counts[k - 1], counts[k])) for k in range(K)],
                [pairs.index((counts[k], counts[k])) if L > 1 else 0 for k in range(K)],
                [sizes.index(n) for n in counts],
                list(counts),
            ],
            np.int32,
        ).T  # (K, 4): resampling pair of the first layer, of the others, count index, count

        def stage(carry, inputs):
            X, log_w, recovered, stale = carry
            kk, k, mask, row = inputs

            def propose(ks, km, X, lw, std, layer):
                if len(pairs) == 1:
                    return self._propose(ks, km, X, lw, B, std)
                branches = [functools.partial(self._propose_rows, n_in=a, n=b, rows=B) for a, b in pairs]
                pair = jnp.where(layer == 0, row[0], row[1])
                return jax.lax.switch(pair, branches, ks, km, X, lw, std)

            def evaluate(X, lay):
                if len(sizes) == 1:
                    return self.loglik_batch(X, observation, lay)
                return base.chunked_loglik(self.loglik_batch, X, observation, lay, row[3], self.chunk)

            def accept(kr, X, ll, layer, b, s):
                if len(sizes) == 1:
                    return self._accept(kr, X, ll, layer, b, s, mask, state.estimate)
                branches = [
                    functools.partial(self._accept_rows, n=n, rows=B, previous_estimate=state.estimate)
                    for n in sizes
                ]
                return jax.lax.switch(row[2], branches, kr, X, ll, layer, b, s, mask)

            layer_fn = functools.partial(
                self._layer, k=k, mask=mask, propose=propose, evaluate=evaluate, accept=accept
            )
            X, log_w, stats, rec = self._partition(kk, X, log_w, k, mask, layer_fn, False)
            return (X, log_w, recovered | rec, stale | (rec & mask)), stats

        carry = (
            _pad_rows(X, B),
            _pad_rows(log_w, B, -jnp.inf),
            jnp.zeros((), bool),
            jnp.zeros(X.shape[1], bool),
        )
        ks = jnp.arange(K, dtype=jnp.int32)
        (X, log_w, recovered, stale), stats = jax.lax.scan(
            stage, carry, (keys, ks, masks, jnp.asarray(table))
        )
        n = counts[-1]
        return X[:n], log_w[:n], recovered, stale, stats

    def _propose_rows(self, k_sel, k_move, X, log_w, std, *, n_in, n, rows):
        """:meth:`_propose` from the first ``n_in`` rows of a buffer to ``n`` particles, padded to ``rows``."""
        return _pad_rows(self._propose(k_sel, k_move, X[:n_in], log_w[:n_in], n, std), rows)

    def _accept_rows(self, k_rec, X, ll, layer, beta_prev, surv_prev, mask, *, n, rows, previous_estimate):
        """:meth:`_accept` of the first ``n`` rows of a buffer, padded back to ``rows`` (log-weights −inf)."""
        X, log_w, stats, rec = self._accept(
            k_rec, X[:n], ll[:n], layer, beta_prev, surv_prev, mask, previous_estimate
        )
        return _pad_rows(X, rows), _pad_rows(log_w, rows, -jnp.inf), stats, rec


def _pad_rows(A: jnp.ndarray, rows: int, fill=None) -> jnp.ndarray:
    """``A (n, …)`` extended to ``rows`` rows with copies of its first row (or ``fill``)."""
    n = A.shape[0]
    if n == rows:
        return A
    shape = (rows - n,) + A.shape[1:]
    tail = jnp.broadcast_to(A[:1], shape) if fill is None else jnp.full(shape, fill, A.dtype)
    return jnp.concatenate([A, tail])


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
