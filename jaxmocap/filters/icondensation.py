"""ICONDENSATION (Isard & Blake 1998; Fontmarty et al. IROS 2007, Table I and §III-A): importance sampling from a
mixture of the dynamics, a detector-driven proposal and the initial prior.

Per frame, from the weighted set ``{x_j, w_j}`` of the previous frame (``N`` particles, static counts
``N_dyn = round(α N)``, ``N_det = round(β N)``, ``N_prior = N - N_dyn - N_det``):

* ``N_dyn`` particles from the dynamics ``f(x) = Σ_j w_j N(x; x_j, Δ²)`` (resample, then random walk with std Δ);
* ``N_det`` particles from the detection-driven density ``g(x) = N(x; x^D, Δ_D²)`` around the configuration ``x^D``
  given for this frame (``proposal_centre(observation) -> (x^D (D,), valid)``); when ``valid`` is False these slots
  are drawn from the dynamics instead (``N_dyn`` becomes ``N_dyn + N_det`` in ``q``);
* ``N_prior`` particles from the prior ``p0(x) = N(x; x_init, Σ0)`` (diagonal, std ``prior_std``);
* all of them through the joint limits.

Weights (``weighting``):

* ``"mixture"`` (default): every particle is weighed against the whole mixture it was drawn from,
  ``π_i ∝ p(z | x_i) f(x_i) / q(x_i)`` with ``q = (N_dyn f + N_det g + N_prior p0) / N``. This is the deterministic-
  mixture importance weight of the ICONDENSATION target ``p(z | x) Σ_j w_j p(x | x_j)``: the weighted set
  approximates the same filtering posterior as SIR, only with a better proposal.
* ``"isard_blake"``: the original per-component rule of Isard & Blake (1998, §3): ``λ = 1`` for particles from the
  dynamics and from the prior, ``λ = f(x) / g(x)`` for those from the importance function, ``π ∝ λ p(z | x)``.

``f``, ``g`` and ``p0`` are the Gaussian densities without the folding/clipping of the joint limits (exact away from
the bounds). ``f`` costs one ``(N, N)`` product of whitened states
(:func:`jaxmocap.filters.base.gaussian_mixture_logpdf`).

The likelihood is batched: ``loglik_batch(X (N, D), observation, layer) -> (N,)`` (``layer``:
:func:`jaxmocap.filters.base.single_layer`). By default the observation must have the
attributes ``centre`` (``(D,)``) and ``valid`` (bool scalar), e.g. a NamedTuple that also carries the image data.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp

from jaxmocap.filters import base
from jaxmocap.filters.base import Info, State

__all__ = [
    "ICondensation",
    "ImportanceOptions",
    "Info",
    "State",
    "counts",
    "default_proposal_centre",
    "importance_sample",
    "propose",
]

WEIGHTINGS = ("mixture", "isard_blake")


def default_proposal_centre(observation):
    """``(observation.centre, observation.valid)``."""
    return observation.centre, observation.valid


def counts(num_particles: int, dynamics_fraction: float, detection_fraction: float) -> tuple[int, int, int]:
    """Static ``(N_dyn, N_det, N_prior)`` for fractions α (dynamics) and β (detection); the prior gets the rest."""
    if dynamics_fraction < 0 or detection_fraction < 0 or dynamics_fraction + detection_fraction > 1 + 1e-9:
        raise ValueError("fractions must be ≥ 0 and sum to at most 1")
    n_dyn = int(round(dynamics_fraction * num_particles))
    n_det = min(int(round(detection_fraction * num_particles)), num_particles - n_dyn)
    return n_dyn, n_det, num_particles - n_dyn - n_det


def importance_sample(
    key: jax.Array,
    particles: jnp.ndarray,
    log_weights: jnp.ndarray,
    num_particles: int,
    split: tuple[int, int, int],
    dynamics_std: jnp.ndarray,
    centre: jnp.ndarray,
    valid: jnp.ndarray,
    detection_std: jnp.ndarray,
    prior_mean: jnp.ndarray,
    prior_std: jnp.ndarray,
    *,
    scheme: str,
    lower=None,
    upper=None,
    limit_mode: str = "clip",
    weighting: str = "mixture",
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Draw ``num_particles`` from the ICONDENSATION mixture; returns ``(X (N, D), log_correction (N,))``.

    The dynamics slots take a random subset of one resampling of size ``N`` (each slot's ancestor is then
    distributed as ``w``, whatever the scheme). ``log_correction`` is what multiplies the likelihood: ``log f(x) - log q(x)`` (``"mixture"``) or ``log λ``
    (``"isard_blake"``); see the module docstring. The slots are ordered dynamics, detection, prior.
    """
    if weighting not in WEIGHTINGS:
        raise ValueError(f"unknown weighting {weighting!r}; choose one of {WEIGHTINGS}")
    n_dyn, n_det, n_prior = split
    n = num_particles
    k_sel, k_perm, k_dyn, k_det, k_prior = jax.random.split(key, 5)
    dtype = particles.dtype
    slot = jnp.arange(n)
    is_det = (slot >= n_dyn) & (slot < n_dyn + n_det) & valid
    is_prior = slot >= n_dyn + n_det

    # the schemes return ancestors in index order: shuffle them so that the first N_dyn slots are a draw from f
    selected = jax.random.permutation(k_perm, base.resample(scheme, k_sel, particles, log_weights, n)[0])
    from_dyn = selected + dynamics_std * jax.random.normal(k_dyn, (n, particles.shape[1]), dtype)
    from_det = centre + detection_std * jax.random.normal(k_det, (n, particles.shape[1]), dtype)
    from_prior = prior_mean + prior_std * jax.random.normal(k_prior, (n, particles.shape[1]), dtype)
    X = jnp.where(is_prior[:, None], from_prior, jnp.where(is_det[:, None], from_det, from_dyn))
    X = base.apply_limits(X, lower, upper, limit_mode)

    log_f = base.gaussian_mixture_logpdf(X, particles, base.normalise(log_weights)[0], dynamics_std)
    log_g = base.gaussian_logpdf(X, centre, detection_std)
    if weighting == "isard_blake":
        return X, jnp.where(is_det, log_f - log_g, 0.0)
    log_p0 = base.gaussian_logpdf(X, prior_mean, prior_std)
    frac_det = jnp.where(valid, n_det / n, 0.0)
    frac_dyn = n_dyn / n + (n_det / n - frac_det)
    frac_prior = n_prior / n
    terms = jnp.stack(
        [
            jnp.log(frac_dyn) + log_f if n_dyn + n_det > 0 else jnp.full_like(log_f, -jnp.inf),
            jnp.where(valid & (n_det > 0), jnp.log(jnp.maximum(frac_det, 1e-30)) + log_g, -jnp.inf),
            jnp.log(frac_prior) + log_p0 if n_prior > 0 else jnp.full_like(log_f, -jnp.inf),
        ]
    )
    log_q = jax.nn.logsumexp(terms, axis=0)
    return X, log_f - log_q


@dataclasses.dataclass(frozen=True, kw_only=True)
class ImportanceOptions:
    """The options of ICONDENSATION's importance function, keyword-only fields of :class:`ICondensation` and of
    the IAPF (:class:`jaxmocap.filters.apf.APF` with ``first_layer="icondensation"``).

    ``detection_std (D,)``: Δ_D of the detection-driven Gaussian (None → the std of the dynamics);
    ``dynamics_fraction`` (α) and ``detection_fraction`` (β): the mixture's fractions (:func:`counts`);
    ``proposal_centre``: ``observation -> (x^D, valid)`` (None → :func:`default_proposal_centre`); ``weighting``:
    one of :data:`WEIGHTINGS` (module docstring).
    """

    detection_std: jnp.ndarray | None = None
    dynamics_fraction: float = 0.5
    detection_fraction: float = 0.4
    proposal_centre: Callable | None = None
    weighting: str = "mixture"

    def _check_importance(self, num_particles: int) -> None:
        """Raise on fractions that do not split ``num_particles`` or an unknown weighting."""
        counts(num_particles, self.dynamics_fraction, self.detection_fraction)
        if self.weighting not in WEIGHTINGS:
            raise ValueError(f"unknown weighting {self.weighting!r}; choose one of {WEIGHTINGS}")


def propose(filt, key: jax.Array, state: State, observation, dynamics_std: jnp.ndarray):
    """:func:`importance_sample` for a filter with the :class:`ImportanceOptions`, ``num_particles``, the prior
    (``prior_mean``, ``prior_std``), resampling and limits, from the weighted set ``state``, the dynamics diffusing
    by ``dynamics_std``."""
    centre, valid = (filt.proposal_centre or default_proposal_centre)(observation)
    det_std = dynamics_std if filt.detection_std is None else filt.detection_std
    n = filt.num_particles
    return importance_sample(
        key,
        state.particles,
        state.log_weights,
        n,
        counts(n, filt.dynamics_fraction, filt.detection_fraction),
        dynamics_std,
        jnp.asarray(centre, state.particles.dtype),
        jnp.asarray(valid, bool),
        det_std,
        filt.prior_mean,
        filt.prior_std,
        scheme=filt.resampling,
        lower=filt.lower,
        upper=filt.upper,
        limit_mode=filt.limit_mode,
        weighting=filt.weighting,
    )


@dataclasses.dataclass(frozen=True)
class ICondensation(ImportanceOptions, base.FilterBase):
    """ICONDENSATION filter.

    Arrays (traced): ``diffusion_std (D,)`` (Δ, the dynamics), ``prior_mean (D,)`` (x_init), ``prior_std (D,)``
    (Σ0^{1/2}), ``detection_std (D,)`` (Δ_D; None → Δ), ``lower, upper`` (or None).
    Static: ``loglik_batch`` (data when it is a pytree), ``num_particles``, the other :class:`ImportanceOptions`
    (``dynamics_fraction``, ``detection_fraction``, ``proposal_centre``, ``weighting``), ``resampling``,
    ``limit_mode``, ``circular``, ``recovery``, ``recovery_widen`` (as in :class:`jaxmocap.filters.sir.SIR`).
    """

    prior_mean: jnp.ndarray
    prior_std: jnp.ndarray
    num_particles: int

    def __post_init__(self):
        self._check_importance(self.num_particles)

    def init(self, key: jax.Array, mean: jnp.ndarray | None = None, std: jnp.ndarray | None = None) -> State:
        """Particles from ``N(mean, std²)``, by default the prior ``p0``."""
        mean = self.prior_mean if mean is None else mean
        std = self.prior_std if std is None else std
        return base.init_state(key, self.num_particles, mean, std, self.lower, self.upper, self.limit_mode)

    def step(self, key: jax.Array, state: State, observation) -> tuple[State, Info]:
        """One frame: mixture proposal, weights ``p(z|x) f/q`` (or λ p(z|x)), estimate."""
        k_prop, k_rec = jax.random.split(key)
        X, log_corr = propose(self, k_prop, state, observation, self.diffusion_std)
        return self._weigh_once(k_rec, X, log_corr, observation, state.estimate)


base.register_filter(
    ICondensation, ("diffusion_std", "prior_mean", "prior_std", "detection_std", "lower", "upper")
)
