"""SIR / CONDENSATION (Isard & Blake 1998; Gordon et al. 1993): the bootstrap particle filter.

Per frame, from the weighted set ``{x_j, w_j}`` of the previous frame:

1. select: ancestors ``a_i`` by the chosen resampling scheme (every frame, or only when the survival rate
   ``ESS / N`` falls below ``resample_threshold``);
2. predict: random walk ``x_i ~ N(x_{a_i}, diag(Δ²))`` (``Δ = diffusion_std``, one std per DOF), then the joint
   limits (clip or reflect, see :func:`jaxmocap.filters.base.apply_limits`);
3. measure: ``log w_i = log w_{a_i}^{prior} + ll_i`` with ``ll = loglik_batch(X, observation, layer)``, normalised in log space
   (``w^{prior}`` is uniform after a resampling);
4. estimate: the weighted mean ``Σ w_i x_i`` of this weighted set (circular mean for entries flagged in ``circular``)
   and the best particle ``argmax w_i``.

The likelihood is batched: ``loglik_batch(X (N, D), observation, layer) -> (N,)`` (vmap a per-particle function
yourself); ``layer`` is :func:`jaxmocap.filters.base.single_layer` (index 0, β = 1).
If no particle has a finite log-likelihood the frame is recovered (``Info.recovered``): see ``recovery``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from jaxmocap.filters import annealing, base
from jaxmocap.filters.base import Info, State

__all__ = ["SIR", "Info", "State"]


@dataclasses.dataclass(frozen=True)
class SIR(base.FilterBase):
    """Bootstrap particle filter with random-walk dynamics.

    Arrays (traced): ``diffusion_std (D,)`` (Δ), ``lower, upper (D,)`` joint limits or None.
    Static: ``loglik_batch`` (data when it is a pytree), ``num_particles``, ``resampling`` (a :mod:`jaxmocap.filters.resampling` scheme name),
    ``limit_mode``, ``circular`` (tuple of bools per DOF, or None), ``resample_threshold`` (None: resample every frame;
    else resample when the survival rate is below it), ``recovery`` (``"reinit"`` or ``"uniform"``) and
    ``recovery_widen`` (std multiplier of the re-initialised cloud).
    """

    num_particles: int
    resample_threshold: float | None = None

    init = base.filter_init

    def step(self, key: jax.Array, state: State, observation) -> tuple[State, Info]:
        """One frame: select, predict, measure, estimate. Returns the new state and :class:`Info`."""
        k_sel, k_move, k_rec = jax.random.split(key, 3)
        n = self.num_particles
        X, _ = base.resample(self.resampling, k_sel, state.particles, state.log_weights, n)
        prior_lw = jnp.full((n,), -jnp.log(n), X.dtype)
        if self.resample_threshold is not None:
            keep = annealing.survival_rate(state.log_weights) >= self.resample_threshold
            X = jnp.where(keep, state.particles, X)
            prior_lw = jnp.where(keep, state.log_weights, prior_lw)
        X = base.diffuse(k_move, X, self.diffusion_std, self.lower, self.upper, self.limit_mode)
        return self._weigh_once(k_rec, X, prior_lw, observation, state.estimate)


base.register_filter(SIR, ("diffusion_std", "lower", "upper"))
