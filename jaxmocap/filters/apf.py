"""Annealed particle filter (APF; Deutscher, Blake & Reid 2000; Deutscher & Reid 2005) and the interleaved variant IAPF
(Fontmarty et al. IROS 2007, Table I): ICONDENSATION's importance function in the first layer only.

Per frame, ``L`` layers ``l = 0 … L-1`` (0 runs first: broadest diffusion, smallest β), each on ``N`` particles:

1. propose: layer 0 resamples the previous frame's final weighted set and diffuses with ``Δ · s_0`` (the motion
   model); in the IAPF it instead draws from the ICONDENSATION mixture (dynamics with ``Δ · s_0``, detector-driven
   Gaussian, prior) and keeps the importance correction ``f/q`` (see :mod:`jaxmocap.filters.icondensation`);
   layers ``l ≥ 1`` resample the previous layer's weighted set and diffuse with ``Δ · s_l``; then the joint limits;
2. weigh: ``ll = loglik_batch(X, observation, layer)``, β_l from the schedule (:class:`jaxmocap.filters.annealing.Schedule`:
   fixed, Deutscher's survival-rate rule, the thesis correction, or PARSEC's bisection; an adaptive β is chosen on
   ``ll`` alone), ``log w_i = β_l ll_i (+ log f/q in the IAPF's first layer)``, normalised;
3. after the last layer: estimate = weighted mean of the final weighted set (circular for flagged entries), best
   particle; the final weighted set is the state carried to the next frame.

``s_l`` are the schedule's diffusion scales (``Schedule.scales``). The likelihood receives a
:class:`jaxmocap.filters.base.Layer` — ``(index, beta, partition)`` — so that it can change its cue weights per layer
(feature-based annealing, López Méndez 2009 eq. 5.2: ``λ_c(β, l)``): signature
``loglik_batch(X (N, D), observation, layer) -> (N,)``; a likelihood that ignores ``layer`` gives the plain APF.

A schedule may carry its own β rule (``Schedule(kind="rule", beta_rule=...)``); the PARSEC wing builds its
bodytrack-mode filter this way (its schedule, multinomial resampling, plain weighted mean of the final set).

Recovery: a layer in which no log-likelihood is finite never yields NaN: its particles are replaced (``"reinit"``:
around the previous frame's estimate with std ``recovery_widen · Δ``; ``"uniform"``: the proposed particles kept)
with uniform weights, the later layers go on from there, and ``Info.recovered`` is set.

The whole step (all layers) is one function to ``jit``; the layers run in a ``lax.scan`` (the IAPF's first layer,
which differs, before it).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from jaxmocap.filters import annealing, base, icondensation
from jaxmocap.filters.annealing import Schedule
from jaxmocap.filters.base import Info, Layer, State

__all__ = ["APF", "Info", "Layer", "State"]

FIRST_LAYERS = ("dynamics", "icondensation")


@dataclasses.dataclass(frozen=True)
class APF(icondensation.ImportanceOptions, base.FilterBase):
    """Annealed particle filter; with ``first_layer="icondensation"`` the IAPF.

    Data (traced): ``diffusion_std (D,)`` (Δ), ``lower, upper``, the values of ``schedule``
    (:class:`jaxmocap.filters.annealing.Schedule`: β, diffusion scales, survival target); for the IAPF also
    ``prior_mean``, ``prior_std`` and ``detection_std`` (None → Δ · s_0); ``loglik_batch`` when it is a pytree
    (:func:`jaxmocap.filters.base.register_filter`).
    Static: a plain ``loglik_batch(X, observation, layer)``, ``num_particles`` (per layer), the schedule's kind,
    number of layers and bisection settings, ``first_layer`` (``"dynamics"`` or ``"icondensation"``), the other
    :class:`~jaxmocap.filters.icondensation.ImportanceOptions` (``dynamics_fraction``, ``detection_fraction``,
    ``proposal_centre``, ``weighting``),
    ``resampling``, ``limit_mode``, ``circular``, ``recovery``, ``recovery_widen``, ``keep_layers`` (return the
    weighted set after each layer in :attr:`Info.layer_sets`).
    """

    num_particles: int
    schedule: Schedule = Schedule()
    first_layer: str = "dynamics"
    prior_mean: jnp.ndarray | None = None
    prior_std: jnp.ndarray | None = None
    keep_layers: bool = False

    def __post_init__(self):
        if self.first_layer not in FIRST_LAYERS:
            raise ValueError(f"unknown first_layer {self.first_layer!r}; choose one of {FIRST_LAYERS}")
        if self.first_layer == "icondensation":
            self._check_importance(self.num_particles)
            if self.prior_mean is None or self.prior_std is None:
                raise ValueError("the IAPF needs prior_mean and prior_std (the prior p0 of ICONDENSATION)")

    @property
    def num_layers(self) -> int:
        return self.schedule.num_layers

    init = base.filter_init

    # -- one layer ---------------------------------------------------------------------------------------------

    def _beta_hint(self, layer, beta_prev):
        return base.beta_hint(self.schedule, layer, beta_prev)

    def _weigh(self, key, X, log_corr, observation, layer, beta_prev, surv_prev, previous_estimate):
        return weigh_layer(
            self, key, X, log_corr, observation, layer, beta_prev, surv_prev, previous_estimate
        )

    def step(self, key: jax.Array, state: State, observation) -> tuple[State, Info]:
        """One frame of ``L`` annealing layers. Returns the new state and :class:`Info` with ``(L,)`` layer stats."""
        dtype = state.particles.dtype
        scales = jnp.asarray(self.schedule.scales, dtype)
        n = self.num_particles

        def layer_fn(carry, inputs):
            """A resample-diffuse-weigh layer (every layer of the APF; layers 1 … L-1 of the IAPF)."""
            X, log_w, beta_prev, surv_prev, recovered, _ = carry
            k, layer = inputs
            k_sel, k_move, k_rec = jax.random.split(k, 3)
            X = base.resample(self.resampling, k_sel, X, log_w, n)[0]
            X = base.diffuse(
                k_move, X, self.diffusion_std * scales[layer], self.lower, self.upper, self.limit_mode
            )
            X, log_w, stats, rec = self._weigh(
                k_rec, X, jnp.zeros((n,), dtype), observation, layer, beta_prev, surv_prev, state.estimate
            )
            kept = (X, log_w) if self.keep_layers else None
            return (X, log_w, stats.beta, stats.survival_rate, recovered | rec, rec), (stats, kept)

        k_first, k_w0, k_layers = jax.random.split(key, 3)
        zero, one = jnp.zeros((), dtype), jnp.ones((), dtype)
        if self.first_layer == "icondensation":
            # layer 0 of the IAPF: ICONDENSATION's importance function, with the dynamics diffusing by Δ · s_0
            std0 = self.diffusion_std * scales[0]
            X, log_corr = icondensation.propose(self, k_first, state, observation, std0)
            X, log_w, stats0, rec0 = self._weigh(
                k_w0, X, log_corr, observation, jnp.int32(0), zero, one, state.estimate
            )
            carry = (X, log_w, stats0.beta, stats0.survival_rate, rec0, rec0)
            first = 1
        else:
            # layer 0 of the APF resamples the previous frame's set: the same layer as the others
            carry = (state.particles, state.log_weights, zero, one, jnp.zeros((), bool), jnp.zeros((), bool))
            first = 0
        layers = jnp.arange(first, self.num_layers, dtype=jnp.int32)
        keys = jax.random.split(k_layers, self.num_layers)[first:]
        (X, log_w, _, _, recovered, last_recovered), (all_stats, sets) = jax.lax.scan(
            layer_fn, carry, (keys, layers)
        )
        if first:
            all_stats = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), stats0, all_stats)
            if self.keep_layers:
                sets = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), carry[:2], sets)

        estimate = base.weighted_mean(X, log_w, self.circular)
        # a recovery in the last layer leaves a re-initialised cloud: report the previous estimate
        if self.recovery == "reinit":
            estimate = jnp.where(last_recovered, state.estimate, estimate)
        best = X[jnp.argmax(log_w)]
        return State(X, log_w, estimate), Info(estimate, best, all_stats, recovered, sets)


base.register_filter(
    APF, ("diffusion_std", "lower", "upper", "prior_mean", "prior_std", "detection_std", "schedule")
)


def weigh_layer(filt, key, X, log_corr, observation, layer, beta_prev, surv_prev, previous_estimate):
    """Weigh proposed particles ``X (N, D)`` at ``layer`` for an annealed filter ``filt`` (the APF, or any filter
    with its fields: ``loglik_batch``, ``schedule``, ``diffusion_std``, limits, recovery): ``ℓ = log p(z | x)``,
    β by the schedule, ``log w = β ℓ + log_corr`` normalised, and a re-initialised set where no weight is finite.
    Returns ``(X, log_w, stats, recovered)``."""
    ll = base.mask_loglik(filt.loglik_batch(X, observation, Layer(layer, filt._beta_hint(layer, beta_prev))))
    sol = annealing.choose_beta(filt.schedule, ll, layer, beta_prev, surv_prev)
    log_w, ok = base.normalise(
        sol.beta * jnp.where(jnp.isfinite(ll), ll, 0.0) + jnp.where(jnp.isfinite(ll), log_corr, -jnp.inf)
    )
    stats = base.layer_stats(ll, log_w, sol.beta, sol.status)
    return filt._recover(key, X, previous_estimate, ok), log_w, stats, ~ok
