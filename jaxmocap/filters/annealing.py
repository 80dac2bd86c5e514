"""Effective sample size, survival rate and annealing schedules (choice of the exponent β per layer).

An annealed particle filter weighs the particles of layer ``l`` with ``w_i ∝ p(z | x_i)^{β_l}``, i.e. log-weights
``β_l · ll_i``. The **survival rate** of a weighted set (Deutscher & Reid 2005) is

    α = (Σ_i w_i)² / (Σ_i w_i²) / N = ESS / N,

computed here in log space: ``log α = 2 logsumexp(lw) - logsumexp(2 lw) - log N``. For tempered weights,
``lw_i = β (ll_i - max_j ll_j)``; α(β) falls from ``n_finite / N`` at β = 0 towards ``k / N`` as β → ∞ (``k``: number
of particles tied at the maximum). Entries of ``ll`` that are NaN or ``-inf`` are dead particles: weight 0 at every β,
counted in ``N``.

Rules for β, all usable inside ``jit``:

* :func:`solve_beta` — Deutscher's rule: the β with α(β) = α_target (default 0.5), by bisection on ``[0, β_max]``
  (:mod:`jaxmocap.fit.solvers`). Without a sign change it falls back (``status``): α(β_max) > α_target → ``β_max`` (the
  sharpest exponent allowed: the log-likelihoods are too flat to reach the target); α(0) < α_target (more than
  ``1 - α_target`` of the particles are dead) → ``0`` (uniform weights over the live particles).
* :func:`corrected_beta` — the thesis' single correction (López Méndez 2009, eq. 6.4):
  ``β(l) = β(l-1) - ε_l (α_target - α(l-1))`` with ``ε_l = 1 / (1 + l)``, kept non-decreasing over the layers.
* fixed sequences (:meth:`Schedule.fixed`, :meth:`Schedule.iros2007`);
* a rule of the caller's (``Schedule(kind="rule", beta_rule=...)``): any jit-able function of the layer's
  log-likelihoods and the schedule, e.g. PARSEC bodytrack's bisection, which its wing supplies.

The bisection calls :func:`jaxmocap.fit.solvers.bisection_with_value` (no bracket check) through :func:`_bisection`.
β carries no gradient (``stop_gradient`` on the log-likelihoods it is computed from).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxmocap.fit import solvers

__all__ = [
    "IROS2007_DYNAMICS_EXPONENTS",
    "IROS2007_LIKELIHOOD_EXPONENTS",
    "STATUS_BETA_MAX",
    "STATUS_BETA_ZERO",
    "STATUS_MAXITER",
    "STATUS_OK",
    "BetaSolution",
    "Schedule",
    "choose_beta",
    "corrected_beta",
    "ess",
    "iros2007_exponents",
    "solve_beta",
    "survival_rate",
    "tempered_survival_rate",
]

STATUS_OK = 0
"""The bisection met its tolerance."""
STATUS_BETA_MAX = 1
"""No sign change: the survival rate stays above the target up to β_max (β = β_max; a rule may choose another
fallback)."""
STATUS_BETA_ZERO = 2
"""No sign change: the survival rate is below the target already at β = 0 (β = 0)."""
STATUS_MAXITER = 3
"""The bisection stopped at its iteration limit before meeting the tolerance (β = last midpoint)."""


def _masked(log_values: jnp.ndarray) -> jnp.ndarray:
    """NaN and ±inf → ``-inf`` (dead particles)."""
    return jnp.where(jnp.isfinite(log_values), log_values, -jnp.inf)


def _log_survival(log_w: jnp.ndarray) -> jnp.ndarray:
    """``log α = 2 logsumexp(lw) - logsumexp(2 lw) - log N``; ``-inf`` when no weight is finite."""
    lw = _masked(log_w)
    any_finite = jnp.any(jnp.isfinite(lw))
    top = jnp.where(any_finite, jnp.max(lw), 0.0)
    d = lw - top
    num = 2.0 * jax.nn.logsumexp(d)
    den = jax.nn.logsumexp(2.0 * d)
    out = num - den - math.log(lw.shape[-1])
    return jnp.where(any_finite, out, -jnp.inf)


def survival_rate(log_w: jnp.ndarray) -> jnp.ndarray:
    """Survival rate ``α = (Σw)² / (Σw²) / N`` of ``(N,)`` log-weights (normalised or not); 0 if none is finite."""
    return jnp.exp(_log_survival(log_w))


def ess(log_w: jnp.ndarray) -> jnp.ndarray:
    """Effective sample size ``(Σw)² / Σw²`` (Kong 1992) of ``(N,)`` log-weights; 0 if none is finite."""
    return log_w.shape[-1] * survival_rate(log_w)


def _tempered(beta: jnp.ndarray, loglik: jnp.ndarray) -> jnp.ndarray:
    """Log-weights ``β (ll - max ll)`` with dead particles at ``-inf`` for every β (also β = 0)."""
    finite = jnp.isfinite(loglik)
    top = jnp.max(jnp.where(finite, loglik, -jnp.inf))
    top = jnp.where(jnp.isfinite(top), top, 0.0)
    d = jnp.where(finite, loglik - top, 0.0)
    return jnp.where(finite, beta * d, -jnp.inf)


def tempered_survival_rate(beta: jnp.ndarray, loglik: jnp.ndarray) -> jnp.ndarray:
    """``α(β)`` of the weights ``exp(β ll_i)`` for ``(N,)`` log-likelihoods ``ll``."""
    return survival_rate(_tempered(beta, loglik))


class BetaSolution(NamedTuple):
    """Result of a β rule: ``beta`` (scalar), the survival rate it gives, and a ``status`` code (``STATUS_*``)."""

    beta: jnp.ndarray
    survival_rate: jnp.ndarray
    status: jnp.ndarray


def _bisection(fn, lower, upper, tol: float, maxiter: int, *args):
    """Root of ``fn(β, *args)`` on ``[lower, upper]`` by bisection, jit-compatible
    (:func:`jaxmocap.fit.solvers.bisection_with_value`).

    Returns ``(β, fn(β))`` at the last midpoint. The caller checks the bracket (no check is made here, so the
    function works under ``jit``).
    """
    return solvers.bisection_with_value(fn, lower, upper, *args, maxiter=maxiter, tol=tol)


def solve_beta(
    loglik: jnp.ndarray,
    target: float = 0.5,
    beta_max: float = 1e3,
    tol: float = 1e-5,
    maxiter: int = 100,
) -> BetaSolution:
    """Deutscher's rule: the β ∈ [0, β_max] whose survival rate α(β) equals ``target``.

    Args:
      loglik: ``(N,)`` log-likelihoods (NaN/``-inf`` allowed: dead particles).
      target: desired survival rate α_target ∈ (0, 1).
      beta_max: upper end of the bracket (static or traced).
      tol: stop when ``|α(β) - target| ≤ tol``.
      maxiter: bisection steps at most (each halves the bracket).

    Returns:
      :class:`BetaSolution`; the fallbacks without a sign change are β_max (``STATUS_BETA_MAX``) and 0
      (``STATUS_BETA_ZERO``), see the module docstring.
    """
    ll = jax.lax.stop_gradient(jnp.asarray(loglik))
    dtype = ll.dtype if jnp.issubdtype(ll.dtype, jnp.floating) else jnp.float32
    ll = ll.astype(dtype)

    def gap(beta, values):
        return tempered_survival_rate(beta, values) - target

    beta_max = jnp.asarray(beta_max, dtype)
    gap_lo = gap(jnp.zeros((), dtype), ll)
    gap_hi = gap(beta_max, ll)
    beta, value = _bisection(gap, jnp.zeros((), dtype), beta_max, tol, maxiter, ll)
    beta = beta.astype(dtype)
    converged = jnp.abs(value) <= tol
    too_flat = gap_hi > 0  # survival stays above the target over the whole bracket
    too_dead = gap_lo < 0  # survival below the target already at β = 0
    beta = jnp.where(too_dead, 0.0, jnp.where(too_flat, beta_max, beta)).astype(dtype)
    status = jnp.where(
        too_dead,
        STATUS_BETA_ZERO,
        jnp.where(too_flat, STATUS_BETA_MAX, jnp.where(converged, STATUS_OK, STATUS_MAXITER)),
    ).astype(jnp.int32)
    return BetaSolution(beta, tempered_survival_rate(beta, ll), status)


def corrected_beta(
    beta_prev: jnp.ndarray,
    survival_prev: jnp.ndarray,
    layer: jnp.ndarray,
    target: float = 0.5,
    monotone: bool = True,
) -> jnp.ndarray:
    """The thesis' single correction (López Méndez 2009, eq. 6.4).

    ``β(l) = β(l-1) - ε_l (α_target - α(l-1))`` with ``ε_l = 1 / (1 + l)``, where α(l-1) is the survival rate measured
    at layer ``l-1`` with β(l-1). With ``monotone`` the result is kept ≥ β(l-1) (β non-decreasing over the layers);
    it is always kept ≥ 0.
    """
    eps = 1.0 / (1.0 + jnp.asarray(layer, jnp.result_type(float)))
    beta = beta_prev - eps * (target - survival_prev)
    if monotone:
        beta = jnp.maximum(beta, beta_prev)
    return jnp.maximum(beta, 0.0)


_KINDS = ("fixed", "survival", "corrected", "rule")


@dataclasses.dataclass(frozen=True)
class Schedule:
    """An annealing schedule over ``num_layers`` layers: a pytree whose values are data and whose structure is static.

    Data (pytree leaves, traced when the schedule, or a filter holding it, is an argument of ``jit``): ``betas``,
    ``diffusion_scales`` (tuples of ``num_layers`` scalars, or None) and ``survival_target``; a new value of any of
    them reuses the compiled step. Static (part of the tree structure, a new value compiles anew): ``kind``,
    ``num_layers``, ``beta_max``, ``tol``, ``maxiter``, ``monotone``, ``beta_rule``. A schedule built from Python
    numbers is hashable and compares by value.

    Attributes:
      kind: ``"fixed"`` (``betas`` per layer), ``"survival"`` (Deutscher's rule every layer, :func:`solve_beta`),
        ``"corrected"`` (layer 0 from ``betas[0]`` if given, else Deutscher's rule; later layers by
        :func:`corrected_beta`), ``"rule"`` (``beta_rule`` every layer).
      num_layers: L.
      betas: per-layer likelihood exponents for ``"fixed"``; ``betas[0]`` is the starting β of ``"corrected"``.
      diffusion_scales: per-layer multipliers of the diffusion std, in run order (default all 1).
      survival_target: α_target.
      beta_max: bracket ``[0, β_max]`` of the bisection.
      tol, maxiter: bisection tolerance on ``|α - α_target|`` and step limit.
      monotone: keep β non-decreasing in ``"corrected"``.
      beta_rule: for ``"rule"``, ``beta_rule(ll, schedule) -> BetaSolution`` of the layer's ``(N,)`` log-likelihoods
        (``stop_gradient`` already applied); it reads its parameters (``survival_target``, traced, and the static
        ``beta_max``, ``tol``, ``maxiter``) from the schedule. A module-level function, so that the schedule's
        structure stays hashable.
    """

    kind: str = "survival"
    num_layers: int = 1
    betas: tuple[float, ...] | None = None
    diffusion_scales: tuple[float, ...] | None = None
    survival_target: float = 0.5
    beta_max: float = 1e3
    tol: float = 1e-5
    maxiter: int = 100
    monotone: bool = True
    beta_rule: Callable[[jnp.ndarray, Schedule], BetaSolution] | None = None

    def __post_init__(self):
        # the constructors validate; pytree unflattening (traced leaves) goes through _unflatten, not here
        if self.kind not in _KINDS:
            raise ValueError(f"unknown schedule kind {self.kind!r}; choose one of {_KINDS}")
        if self.num_layers < 1:
            raise ValueError("num_layers must be ≥ 1")
        if self.kind == "fixed" and (self.betas is None or len(self.betas) != self.num_layers):
            raise ValueError("a fixed schedule needs one beta per layer")
        if (self.kind == "rule") != (self.beta_rule is not None):
            raise ValueError('a beta_rule goes with kind="rule", and kind="rule" needs one')
        if self.diffusion_scales is not None and len(self.diffusion_scales) != self.num_layers:
            raise ValueError("diffusion_scales needs one entry per layer")
        if not 0.0 < self.survival_target < 1.0:
            raise ValueError("survival_target must lie in (0, 1)")
        # normalise sequences to tuples of floats so that the schedule stays hashable
        if self.betas is not None:
            object.__setattr__(self, "betas", tuple(float(b) for b in self.betas))
        if self.diffusion_scales is not None:
            object.__setattr__(self, "diffusion_scales", tuple(float(s) for s in self.diffusion_scales))

    @property
    def scales(self) -> tuple[float, ...]:
        """Per-layer diffusion std multipliers (all 1 unless set)."""
        return self.diffusion_scales if self.diffusion_scales is not None else (1.0,) * self.num_layers

    @classmethod
    def fixed(cls, betas, diffusion_scales=None) -> Schedule:
        """Given exponents ``β_l`` (and optionally std multipliers) per layer."""
        betas = tuple(float(b) for b in betas)
        return cls(kind="fixed", num_layers=len(betas), betas=betas, diffusion_scales=diffusion_scales)

    @classmethod
    def from_exponents(cls, likelihood_exponents, dynamics_exponents) -> Schedule:
        """Per-layer likelihood exponents ``β_l`` and dynamics exponents ``a_l``.

        Raising the Gaussian diffusion kernel ``N(x; x', Σ)`` to the power ``a_l`` gives ``N(x; x', Σ / a_l)`` up to
        a constant, so the diffusion std multiplier of layer ``l`` is ``a_l^{-1/2}``.
        """
        betas = tuple(float(b) for b in likelihood_exponents)
        dyn = tuple(float(a) for a in dynamics_exponents)
        if len(dyn) != len(betas):
            raise ValueError("one dynamics exponent per layer")
        return cls.fixed(betas, tuple(a**-0.5 for a in dyn))

    @classmethod
    def iros2007(cls) -> Schedule:
        """The fixed 3-layer schedule of Fontmarty et al. (IROS 2007, Table II), as exponents per layer.

        Likelihood exponents β = (0.1, 0.4, 1) and dynamics exponents a = (1, 4, 25) (diffusion std multipliers
        1, 1/2, 1/5). Both sequences are exposed as arrays by :func:`iros2007_exponents`.
        """
        return cls.from_exponents(IROS2007_LIKELIHOOD_EXPONENTS, IROS2007_DYNAMICS_EXPONENTS)

    @classmethod
    def deutscher(
        cls, num_layers: int, survival_target: float = 0.5, diffusion_scales=None, **kw
    ) -> Schedule:
        """Deutscher's rule (α(β_l) = α_target) at every layer."""
        return cls(
            kind="survival",
            num_layers=num_layers,
            survival_target=survival_target,
            diffusion_scales=diffusion_scales,
            **kw,
        )


_SCHEDULE_DATA = ("betas", "diffusion_scales", "survival_target")
_SCHEDULE_STATIC = tuple(f.name for f in dataclasses.fields(Schedule) if f.name not in _SCHEDULE_DATA)


def _flatten_schedule(s: Schedule):
    return tuple(getattr(s, n) for n in _SCHEDULE_DATA), tuple(getattr(s, n) for n in _SCHEDULE_STATIC)


def _unflatten_schedule(static, data) -> Schedule:
    s = object.__new__(Schedule)  # no __post_init__: leaves may be tracers (or any placeholder of tree_util)
    for n, v in zip(_SCHEDULE_STATIC, static, strict=True):
        object.__setattr__(s, n, v)
    for n, v in zip(_SCHEDULE_DATA, data, strict=True):
        object.__setattr__(s, n, v)
    return s


jax.tree_util.register_pytree_node(Schedule, _flatten_schedule, _unflatten_schedule)

IROS2007_LIKELIHOOD_EXPONENTS = (0.1, 0.4, 1.0)
IROS2007_DYNAMICS_EXPONENTS = (1.0, 4.0, 25.0)


def iros2007_exponents() -> tuple[jnp.ndarray, jnp.ndarray]:
    """``(likelihood exponents (3,), dynamics exponents (3,))`` of IROS 2007 Table II, first layer first."""
    return jnp.asarray(IROS2007_LIKELIHOOD_EXPONENTS), jnp.asarray(IROS2007_DYNAMICS_EXPONENTS)


def choose_beta(
    schedule: Schedule,
    loglik: jnp.ndarray,
    layer: jnp.ndarray,
    beta_prev: jnp.ndarray,
    survival_prev: jnp.ndarray,
) -> BetaSolution:
    """β of layer ``layer`` (traced int) for ``(N,)`` log-likelihoods under ``schedule``.

    ``beta_prev`` / ``survival_prev`` are the β and survival rate of the previous layer (used by ``"corrected"``).
    """
    ll = jax.lax.stop_gradient(jnp.asarray(loglik))
    dtype = ll.dtype
    if schedule.kind == "fixed":
        beta = jnp.asarray(schedule.betas, dtype)[layer]
        return BetaSolution(beta, tempered_survival_rate(beta, ll), jnp.asarray(STATUS_OK, jnp.int32))
    if schedule.kind == "rule":
        return schedule.beta_rule(ll, schedule)
    solve = lambda: solve_beta(
        ll, schedule.survival_target, schedule.beta_max, schedule.tol, schedule.maxiter
    )
    if schedule.kind == "survival":
        return solve()
    # "corrected"
    if schedule.betas is not None:
        first = jnp.asarray(schedule.betas[0], dtype)
        first = BetaSolution(first, tempered_survival_rate(first, ll), jnp.asarray(STATUS_OK, jnp.int32))
    else:
        first = solve()
    later = corrected_beta(
        beta_prev, survival_prev, layer, schedule.survival_target, schedule.monotone
    ).astype(dtype)
    is_first = jnp.asarray(layer) == 0
    beta = jnp.where(is_first, first.beta, later)
    status = jnp.where(is_first, first.status, STATUS_OK).astype(jnp.int32)
    return BetaSolution(beta, tempered_survival_rate(beta, ll), status)
