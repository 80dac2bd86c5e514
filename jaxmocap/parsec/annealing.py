"""PARSEC bodytrack's annealing: its choice of β per layer, its diffusion schedule and its annealed filter.

The core's :class:`jaxmocap.filters.Schedule` takes a β rule of the caller's (``kind="rule"``); this module
supplies bodytrack's (``AnnealingFactor.cpp``, ``jaxmocap/parsec/FORMAT.md`` §6.5):

* :func:`parsec_beta` — weights ``e_i = exp(β (ll_i - min ll))`` over the valid particles, bisection on
  ``[0, 1000]`` to ``|α - α_target| ≤ 1e-5`` in at most 100 steps, α taken as ``-α_target`` (i.e. "β too large")
  as soon as some ``β (ll_i - min ll) > 40``, and β = 1 when there is no sign change;
* :func:`parsec_diffusion_scales` — the per-layer diffusion std multipliers;
* :func:`parsec_schedule` — both as a :class:`~jaxmocap.filters.Schedule`;
* :func:`parsec_apf` — the annealed particle filter in PARSEC mode: that schedule, multinomial resampling, plain
  weighted mean of the final set, no motion model beyond the annealing diffusion.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import jax.numpy as jnp

from jaxmocap.filters.annealing import (
    STATUS_BETA_MAX,
    STATUS_MAXITER,
    STATUS_OK,
    BetaSolution,
    Schedule,
    _bisection,
    tempered_survival_rate,
)
from jaxmocap.filters.apf import APF

__all__ = ["parsec_apf", "parsec_beta", "parsec_diffusion_scales", "parsec_rule", "parsec_schedule"]


def parsec_beta(
    loglik: jnp.ndarray,
    target: float = 0.5,
    beta_max: float = 1000.0,
    precision: float = 1e-5,
    maxiter: int = 100,
    overflow: float = 40.0,
) -> BetaSolution:
    """β as PARSEC bodytrack chooses it (``AnnealingFactor.cpp``; ``jaxmocap/parsec/FORMAT.md`` §6.5).

    ``w_i = ll_i - min ll`` over the valid (finite) particles, ``N`` = number of valid particles,
    ``α(β) = (Σ e_i)² / Σ e_i² / N`` with ``e_i = exp(β w_i)`` in float32, except that α − α_target is taken as
    ``-α_target`` as soon as some ``β w_i > overflow`` (the reference's guard against float overflow, which makes the
    bisection treat such β as too large), and α = +∞ (β too small) when ``(Σ e_i)²`` overflows float32, as the
    reference's float arithmetic gives. Bisection on ``[0, beta_max]`` until ``|α - α_target| ≤ precision`` or
    ``maxiter`` steps; without a sign change over the bracket β = 1 (``STATUS_BETA_MAX``).
    """
    ll = jax.lax.stop_gradient(jnp.asarray(loglik, jnp.float32))
    valid = jnp.isfinite(ll)
    n_valid = jnp.maximum(jnp.sum(valid), 1).astype(jnp.float32)
    low = jnp.min(jnp.where(valid, ll, jnp.inf))
    w = jnp.where(valid, ll - low, 0.0)

    big = math.sqrt(float(jnp.finfo(jnp.float32).max))

    def gap(beta, values):
        v = beta * values
        e = jnp.where(valid, jnp.exp(jnp.minimum(v, overflow)), 0.0)
        b, f = jnp.sum(e), jnp.sum(e * e)
        # the reference's float B*B/F/N: +inf once B*B overflows; written as (B/F)(B/N) so that no intermediate
        # overflows to inf/inf = NaN whatever order the compiler divides in
        alpha = jnp.where(b >= big, jnp.inf, (b / f) * (b / n_valid))
        return jnp.where(jnp.any(valid & (v > overflow)), -target, alpha - target)

    zero = jnp.zeros((), jnp.float32)
    top = jnp.asarray(beta_max, jnp.float32)
    gap_lo, gap_hi = gap(zero, w), gap(top, w)
    beta, value = _bisection(gap, zero, top, precision, maxiter, w)
    same_sign = ((gap_lo > 0) & (gap_hi > 0)) | ((gap_lo < 0) & (gap_hi < 0))
    beta = jnp.where(same_sign, 1.0, beta).astype(jnp.float32)
    status = jnp.where(
        same_sign, STATUS_BETA_MAX, jnp.where(jnp.abs(value) <= precision, STATUS_OK, STATUS_MAXITER)
    )
    return BetaSolution(
        beta, tempered_survival_rate(beta, jnp.where(valid, ll, -jnp.inf)), status.astype(jnp.int32)
    )


def parsec_diffusion_scales(num_layers: int, ratio: float = 0.5) -> tuple[float, ...]:
    """PARSEC's per-layer diffusion std multipliers, in the order the layers run (``jaxmocap/parsec/FORMAT.md`` §6.5).

    ``σ_{L-1} = √ratio σ_0``, ``σ_j = √ratio σ_{j+1}``, and the layers run ``k = L-1 … 0``, so the scales are
    ``(√r, r, r^{3/2}, …, r^{(L-1)/2}, 1)``: for L = 5, ``(0.707, 0.5, 0.354, 0.25, 1.0)``. The last layer uses the
    full σ.
    """
    if num_layers < 1:
        raise ValueError("num_layers must be ≥ 1")
    s = math.sqrt(ratio)
    return tuple(s**j for j in range(1, num_layers)) + (1.0,)


def parsec_rule(ll: jnp.ndarray, schedule: Schedule) -> BetaSolution:
    """:func:`parsec_beta` with the schedule's target, bracket, precision and step limit (a ``beta_rule``)."""
    return parsec_beta(ll, schedule.survival_target, schedule.beta_max, schedule.tol, schedule.maxiter)


def parsec_schedule(num_layers: int) -> Schedule:
    """PARSEC bodytrack: its diffusion schedule and β bisection on [0, 1000] with the overflow quirk."""
    return Schedule(
        kind="rule",
        num_layers=num_layers,
        diffusion_scales=parsec_diffusion_scales(num_layers),
        beta_max=1000.0,
        tol=1e-5,
        maxiter=100,
        beta_rule=parsec_rule,
    )


def parsec_apf(
    loglik_batch: Callable, pose_std: jnp.ndarray, num_particles: int, num_layers: int, **kw
) -> APF:
    """PARSEC bodytrack's annealed filter (``jaxmocap/parsec/FORMAT.md`` §6.5) with ``pose_std`` = its ``PoseStd``
    σ_0: :func:`parsec_schedule` and multinomial resampling (other :class:`~jaxmocap.filters.apf.APF` options in
    ``kw``)."""
    kw.setdefault("resampling", "multinomial")
    return APF(loglik_batch, pose_std, num_particles, parsec_schedule(num_layers), **kw)
