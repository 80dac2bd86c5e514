"""Hybrid annealed particle filters: the APF with gradient steps on the particles, and an APF whose estimate is
refined by gradient ascent.

The APF (:mod:`jaxmocap.filters.apf`) explores by diffusion alone; a differentiable likelihood
(:mod:`jaxmocap.likelihood.gradients`) also tells each particle which way is uphill. :class:`HybridAPF` runs the APF's layers
``l = 0 … L-1`` (layer 0 resamples the previous frame's weighted set) with one more stage:

1. resample the weighted set ``{x_i, w_i}`` of the previous layer (or frame);
2. **gradient move** (:class:`GradientMove`): ``S`` steps of an optax optimiser that maximise this layer's
   log-likelihood ``ℓ_l`` — on every resampled particle, or on the ``k`` distinct particles of largest weight
   (``best_k``; their copies follow them, so a particle drawn ``m`` times is moved once);
3. diffuse with ``Δ · s_l`` and apply the joint limits;
4. weigh with ``β_l ℓ_l`` (β by the schedule, :func:`jaxmocap.filters.annealing.choose_beta`) and normalise.

The moves work in whitened coordinates ``u = (x − x₀) / (Δ · s_l)``: the state mixes metres and radians, and a step
of one unit is one standard deviation of the layer's diffusion in every entry. With ``g = ∂ℓ_l/∂x`` the optimiser
receives the gradient of the loss ``−ℓ_l`` in ``u``, ``−(Δ · s_l) ⊙ g``, and its update ``δu`` moves the particle to
``limits(x + (Δ · s_l) ⊙ δu)``. The optimiser is vmapped over particles, so its state and any normalisation are per
particle. Built-in choices (``optimizer``): ``"adam"`` (``optax.adam``), ``"sgd"`` (``optax.sgd``) and
``"normalised"`` (steps of fixed length ``learning_rate`` along ``−∇_u``, i.e. normalised gradient ascent); any
``optax.GradientTransformation`` is accepted.

A deterministic move followed by the usual weights ``∝ p^β`` is, like the annealing layers themselves, a search
heuristic and not an importance-sampling correction: the moved set no longer carries exact posterior weights.

:class:`HybridAPF` with ``refine`` set also (or, with ``move=None``, only) refines the output: after the last layer,
``refine.steps`` optimiser steps from the weighted mean (``refine_from="mean"``) or the best particle (``"best"``) on
the last layer's likelihood; the output is the best point visited (start, iterates, final point) by ``ℓ``. ``Info.estimate`` (and ``State.estimate``) is the refined
pose; the particles are not changed. :meth:`HybridAPF.refined` builds that variant.

Cost per frame (:meth:`HybridAPF.evaluations`): ``N · L`` likelihood evaluations by the layers plus
``S · (N or k)`` gradient evaluations per moved layer, plus ``refine.steps + 1`` for the refinement (each gradient
evaluation is one forward and one reverse pass).

Same API as :class:`~jaxmocap.filters.apf.APF`: ``loglik_batch(X (N, D), observation, layer) -> (N,)``,
``init(key, mean, std)``, ``step(key, state, observation) -> (State, Info)``; a frozen dataclass registered as a
pytree (arrays traced, configuration static), one compilation for every frame.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from jaxmocap.filters import base
from jaxmocap.filters.annealing import Schedule
from jaxmocap.filters.apf import weigh_layer
from jaxmocap.filters.base import Info, Layer, State
from jaxmocap.likelihood.gradients import batch_value_and_grad

if TYPE_CHECKING:
    import optax

__all__ = ["DEFAULT_REFINE", "OPTIMIZERS", "GradientMove", "HybridAPF", "gradient_ascent", "make_optimizer"]

OPTIMIZERS = ("adam", "sgd", "normalised")


def _normalised_steps(learning_rate: float) -> optax.GradientTransformation:
    """Updates ``−lr · g / ‖g‖`` (zero for a zero gradient): a fixed step length along the descent direction."""
    import optax

    def init(params):
        del params
        return optax.EmptyState()

    def update(updates, state, params=None):
        del params
        sq = sum(jnp.sum(g * g) for g in jax.tree_util.tree_leaves(updates))
        norm = jnp.sqrt(sq)
        scale = jnp.where(norm > 0, -learning_rate / jnp.where(norm > 0, norm, 1.0), 0.0)
        return jax.tree_util.tree_map(lambda g: scale * g, updates), state

    return optax.GradientTransformation(init, update)


def _is_transformation(x) -> bool:
    import optax

    return isinstance(x, optax.GradientTransformation)


def make_optimizer(
    name: str | optax.GradientTransformation, learning_rate: float
) -> optax.GradientTransformation:
    """An optax transformation by name (:data:`OPTIMIZERS`), or ``name`` itself when it already is one.

    (optax is imported by the functions that use it, not with this module: a run without gradient moves does not
    load it, about 0.1 s of every command's start.)"""
    import optax

    if isinstance(name, optax.GradientTransformation):
        return name
    if name == "adam":
        return optax.adam(learning_rate)
    if name == "sgd":
        return optax.sgd(learning_rate)
    if name == "normalised":
        return _normalised_steps(learning_rate)
    raise ValueError(
        f"unknown optimizer {name!r}; choose one of {OPTIMIZERS} or pass an optax transformation"
    )


@dataclasses.dataclass(frozen=True)
class GradientMove:
    """Gradient steps on particles (static configuration, hashable).

    Attributes:
      steps: optimiser steps ``S`` (each costs one gradient evaluation per moved particle).
      learning_rate: in whitened units (one unit = one standard deviation of the layer's diffusion).
      optimizer: ``"adam"``, ``"sgd"``, ``"normalised"`` or an ``optax.GradientTransformation``.
      best_k: move only the ``k`` distinct particles of largest weight (None: every resampled particle).
      layers: the layer indices that move (None: all).
    """

    steps: int = 2
    learning_rate: float = 0.5
    optimizer: str | optax.GradientTransformation = "normalised"
    best_k: int | None = None
    layers: tuple[int, ...] | None = None

    def __post_init__(self):
        if self.steps < 0:
            raise ValueError("steps must be ≥ 0")
        if self.best_k is not None and self.best_k < 1:
            raise ValueError("best_k must be ≥ 1 (or None for every particle)")
        if self.optimizer not in OPTIMIZERS and not _is_transformation(self.optimizer):
            raise ValueError(f"unknown optimizer {self.optimizer!r}; choose one of {OPTIMIZERS}")
        if self.layers is not None:
            object.__setattr__(self, "layers", tuple(int(i) for i in self.layers))

    def active(self, layer: int) -> bool:
        return self.steps > 0 and (self.layers is None or layer in self.layers)


def gradient_ascent(
    loglik_batch: Callable,
    X: jnp.ndarray,
    observation,
    layer,
    scale: jnp.ndarray,
    move: GradientMove,
    lower=None,
    upper=None,
    limit_mode: str = "clip",
    return_path: bool = False,
):
    """``move.steps`` optimiser steps that raise ``loglik_batch(·, observation, layer)`` from ``X (M, D)``.

    ``scale (D,)``: the whitening ``Δ · s_l`` (see the module docstring). Returns ``(X_moved (M, D), ll (S, M))``
    with ``ll[s]`` the log-likelihoods of the iterate at which step ``s`` was taken (``ll[0]``: at ``X``); with
    ``return_path`` also those iterates ``(S, M, D)``. The final point is not evaluated. Dead particles (non-finite
    ℓ) have a zero gradient and stay where they are.
    """
    opt = make_optimizer(move.optimizer, move.learning_rate)
    U = jnp.zeros_like(X)
    opt_state = jax.vmap(opt.init)(U)

    def body(carry, _):
        X, opt_state = carry
        ll, G = batch_value_and_grad(loglik_batch, X, observation, layer)
        updates, opt_state = jax.vmap(opt.update)(-G * scale, opt_state, jnp.zeros_like(X))
        X_new = base.apply_limits(X + scale * updates, lower, upper, limit_mode)
        return (X_new, opt_state), (ll, X if return_path else None)

    (X, _), (lls, path) = jax.lax.scan(body, (X, opt_state), None, length=move.steps)
    return (X, lls, path) if return_path else (X, lls)


#: The refinement of :meth:`HybridAPF.refined` by default: 10 Adam steps of 0.3 diffusion std.
DEFAULT_REFINE = GradientMove(steps=10, learning_rate=0.3, optimizer="adam")


@dataclasses.dataclass(frozen=True)
class HybridAPF(base.FilterBase):
    """Annealed particle filter with gradient moves between resampling and diffusion, and/or a refined estimate.

    Data (traced): ``diffusion_std (D,)`` (Δ), ``lower``, ``upper``, the values of ``schedule``; ``loglik_batch``
    when it is a pytree.
    Static: a plain ``loglik_batch(X, observation, layer)`` (differentiable in ``X``), ``num_particles`` (per
    layer), the schedule's structure, ``move`` (:class:`GradientMove` or None), ``refine`` (:class:`GradientMove` or None; its
    ``best_k``/``layers`` are ignored), ``refine_from`` (``"mean"`` or ``"best"``), ``resampling``, ``limit_mode``,
    ``circular``, ``recovery``, ``recovery_widen`` (as in :class:`~jaxmocap.filters.apf.APF`).
    """

    num_particles: int
    schedule: Schedule = Schedule()
    move: GradientMove | None = GradientMove()
    refine: GradientMove | None = None
    refine_from: str = "mean"

    def __post_init__(self):
        if self.refine_from not in ("mean", "best"):
            raise ValueError(f"refine_from must be 'mean' or 'best', got {self.refine_from!r}")
        if self.move is not None and self.move.best_k is not None and self.move.best_k > self.num_particles:
            raise ValueError(f"best_k = {self.move.best_k} exceeds num_particles = {self.num_particles}")

    @property
    def num_layers(self) -> int:
        return self.schedule.num_layers

    @classmethod
    def refined(
        cls,
        loglik_batch: Callable,
        diffusion_std: jnp.ndarray,
        num_particles: int,
        schedule: Schedule | None = None,
        refine: GradientMove = DEFAULT_REFINE,
        **kw,
    ) -> HybridAPF:
        """The plain APF whose estimate is refined by ``refine.steps`` gradient steps (no moves in the layers)."""
        schedule = Schedule() if schedule is None else schedule
        return cls(loglik_batch, diffusion_std, num_particles, schedule, move=None, refine=refine, **kw)

    def evaluations(self) -> dict[str, int]:
        """Per frame: ``{"likelihood": …, "gradient": …}`` evaluations (one per particle and call)."""
        n, L = self.num_particles, self.num_layers
        grads = 0
        if self.move is not None:
            k = n if self.move.best_k is None else self.move.best_k
            grads += sum(self.move.steps * k for l in range(L) if self.move.active(l))
        if self.refine is not None and self.refine.steps > 0:
            grads += self.refine.steps
        lik = n * L + (1 if self.refine is not None and self.refine.steps > 0 else 0)
        return {"likelihood": lik, "gradient": grads}

    init = base.filter_init

    # -- pieces ------------------------------------------------------------------------------------------------

    def _beta_hint(self, layer, beta_prev):
        return base.beta_hint(self.schedule, layer, beta_prev)

    def _move_flags(self) -> tuple[bool, ...]:
        return tuple(self.move is not None and self.move.active(l) for l in range(self.num_layers))

    def step(self, key: jax.Array, state: State, observation) -> tuple[State, Info]:
        """One frame of ``L`` layers (a ``lax.scan``; a layer without a move skips it by ``lax.cond``). Returns the
        new state and :class:`~jaxmocap.filters.base.Info` with ``(L,)`` layer statistics."""
        dtype = state.particles.dtype
        scales = jnp.asarray(self.schedule.scales, dtype)
        flags = jnp.asarray(self._move_flags())
        n = self.num_particles
        move = self.move
        any_move = any(self._move_flags())

        def ascend(X, lay, scale):
            return gradient_ascent(
                self.loglik_batch, X, observation, lay, scale, move, self.lower, self.upper, self.limit_mode
            )[0]

        def layer_fn(carry, inputs):
            X, log_w, beta_prev, surv_prev, recovered, _ = carry
            k, layer = inputs
            k_sel, k_move, k_rec = jax.random.split(k, 3)
            scale = self.diffusion_std * scales[layer]
            lay = Layer(layer, self._beta_hint(layer, beta_prev))
            if any_move and move.best_k is not None:
                # move the k distinct particles of largest weight; their copies follow them through the resampling
                def move_best(X):
                    _, top = jax.lax.top_k(log_w, move.best_k)
                    return X.at[top].set(ascend(X[top], lay, scale))

                X = jax.lax.cond(flags[layer], move_best, lambda X: X, X)
            X = base.resample(self.resampling, k_sel, X, log_w, n)[0]
            if any_move and move.best_k is None:
                X = jax.lax.cond(flags[layer], lambda X: ascend(X, lay, scale), lambda X: X, X)
            X = base.diffuse(k_move, X, scale, self.lower, self.upper, self.limit_mode)
            X, log_w, stats, rec = weigh_layer(
                self,
                k_rec,
                X,
                jnp.zeros((n,), dtype),
                observation,
                layer,
                beta_prev,
                surv_prev,
                state.estimate,
            )
            return (X, log_w, stats.beta, stats.survival_rate, recovered | rec, rec), stats

        zero, one = jnp.zeros((), dtype), jnp.ones((), dtype)
        no = jnp.zeros((), bool)
        carry = (state.particles, state.log_weights, zero, one, no, no)
        layers = jnp.arange(self.num_layers, dtype=jnp.int32)
        # the APF's key stream (apf.APF with first_layer="dynamics"): without moves the two filters agree exactly
        keys = jax.random.split(jax.random.split(key, 3)[2], self.num_layers)
        (X, log_w, beta_last, _, recovered, last_rec), all_stats = jax.lax.scan(
            layer_fn, carry, (keys, layers)
        )

        estimate = base.weighted_mean(X, log_w, self.circular)
        best = X[jnp.argmax(log_w)]
        if self.refine is not None and self.refine.steps > 0:
            estimate = self._refine(estimate, best, observation, beta_last)
        if self.recovery == "reinit":
            estimate = jnp.where(last_rec, state.estimate, estimate)
        return State(X, log_w, estimate), Info(estimate, best, all_stats, recovered)

    def _refine(self, estimate, best, observation, beta_prev):
        """Gradient refinement of the output on the last layer's likelihood: the best point visited (the start,
        every iterate, the final point) by ℓ."""
        last = self.num_layers - 1
        lay = Layer(jnp.int32(last), self._beta_hint(last, beta_prev))
        start = (estimate if self.refine_from == "mean" else best)[None]
        scale = self.diffusion_std * jnp.asarray(self.schedule.scales[last], start.dtype)
        moved, lls, path = gradient_ascent(
            self.loglik_batch, start, observation, lay, scale, self.refine, self.lower, self.upper,
            self.limit_mode, return_path=True,
        )  # fmt: skip
        ll_final = base.mask_loglik(self.loglik_batch(moved, observation, lay))
        values = jnp.concatenate([lls[:, 0], ll_final])
        points = jnp.concatenate([path[:, 0], moved])
        return points[jnp.argmax(values)]


base.register_filter(HybridAPF, ("diffusion_std", "lower", "upper", "schedule"))
