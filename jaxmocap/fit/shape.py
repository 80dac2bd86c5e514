"""Body-shape calibration: fit a subject's limb lengths and radii (and the poses) to a few frames by gradient descent.

A body preset is built from a dimension dict by ``jax.numpy`` code (:mod:`jaxmocap.geometry.body`), and the flesh points follow
the dimensions (:func:`jaxmocap.likelihood.gradients.with_body`), so the composed log-likelihood is differentiable in the
dimensions ``θ`` as well as in the poses. Calibration maximises, over ``T`` frames with observations ``z_t``,

    ``J(θ, x_1 … x_T) = (1/T) Σ_t ℓ(x_t, z_t; θ) − (ρ/2) Σ_d u_d²``

(optionally minus a silhouette-coverage term, :func:`coverage_energy`) with the parametrisation

* ``θ_d = θ⁰_d · exp(u_d)`` for lengths and radii (positive; ``u`` is the log-ratio to the start),
  ``θ_d = θ⁰_d + s_θ u_d`` for the signed offsets (``*_drop``, ``s_θ`` = 5 cm);
* ``x_t = x⁰_t + s_x ⊙ v_t`` with ``s_x`` = 5 cm for translations and 0.1 rad for angles, kept inside the joint limits
  after every step;

by Adam (optax) on ``(u, v)`` for a fixed number of steps (one ``lax.scan``, compiled once). ``ρ`` (default 0) is an
optional ridge pulling the dimensions towards the start. Only differentiable cues move the dimensions (see
:mod:`jaxmocap.likelihood.cues`); the silhouette cues alone favour thin, short limbs (a smaller body falls inside any silhouette),
so the contour (``edge_distance``) or detection (``keypoints``) cues must be part of the likelihood.

Dimension names are those of :data:`jaxmocap.geometry.body.DEFAULT_DIMENSIONS`; a name prefixed with ``left_``/``right_``
fits one side only, an unprefixed name is shared by both sides (:func:`symmetric_names` lists the usual set).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxmocap.filters.base import apply_limits
from jaxmocap.geometry import body, camera, flesh
from jaxmocap.likelihood.compose import Likelihood
from jaxmocap.likelihood.gradients import likelihood_with_dimensions

__all__ = [
    "LENGTHS",
    "RADII",
    "Coverage",
    "ShapeFit",
    "calibrate",
    "coverage_energy",
    "foreground_samples",
    "limb_lengths",
    "symmetric_names",
]

#: Length dimensions of the ``full25`` preset that a calibration usually fits.
LENGTHS = (
    "torso_length",
    "shoulder_width",
    "shoulder_drop",
    "hip_width",
    "hip_drop",
    "neck_length",
    "upper_arm_length",
    "forearm_length",
    "thigh_length",
    "shin_length",
)
#: Radius dimensions of the ``full25`` preset.
RADII = (
    "torso_radius_bottom",
    "torso_radius_top",
    "upper_arm_radius_top",
    "upper_arm_radius_bottom",
    "forearm_radius_top",
    "forearm_radius_bottom",
    "thigh_radius_top",
    "thigh_radius_bottom",
    "shin_radius_top",
    "shin_radius_bottom",
)

_SIGNED_SCALE = 0.05  # metres per unit of u for signed offsets


def symmetric_names(lengths: bool = True, radii: bool = True) -> tuple[str, ...]:
    """The shared (both sides) dimension names to fit: :data:`LENGTHS` and/or :data:`RADII`."""
    return (LENGTHS if lengths else ()) + (RADII if radii else ())


class ShapeFit(NamedTuple):
    """Result of :func:`calibrate`: the full dimension dict (fitted names replaced), the fitted states ``(T, D)`` and
    the objective ``J`` before each step ``(steps,)`` (and after the last, as its final entry)."""

    dims: dict
    states: np.ndarray
    objective: np.ndarray


def _signed(name: str) -> bool:
    return name.endswith(body.SIGNED_DIMENSION_SUFFIX)


def _dims_of(u: jnp.ndarray, names: Sequence[str], start: Mapping[str, jnp.ndarray], base: Mapping) -> dict:
    d = dict(base)
    for i, n in enumerate(names):
        d[n] = start[n] + _SIGNED_SCALE * u[i] if _signed(n) else start[n] * jnp.exp(u[i])
    return d


class Coverage(NamedTuple):
    """Silhouette coverage term of a calibration: observed foreground pixels ``pixels (T, V, M, 2)`` (u, v) with
    weights ``(T, V, M)`` (0 for padding), the robust scale ``sigma_px`` and the term's weight ``κ``."""

    pixels: jnp.ndarray
    weights: jnp.ndarray
    sigma_px: float = 5.0
    weight: float = 1.0


def foreground_samples(
    foreground: np.ndarray, num: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``num`` pixels drawn without replacement from each view's foreground (value ≥ 0.5) of
    ``foreground (V, H, W)``: ``(pixels (V, num, 2) as (u, v), weights (V, num))``, padded with weight 0."""
    fg = np.asarray(foreground, np.float32)
    V = fg.shape[0]
    pix = np.zeros((V, num, 2), np.float32)
    w = np.zeros((V, num), np.float32)
    for v in range(V):
        rows, cols = np.nonzero(fg[v] >= 0.5)
        if rows.size == 0:
            continue
        pick = rng.choice(rows.size, size=min(num, rows.size), replace=False)
        pix[v, : pick.size] = np.stack([cols[pick], rows[pick]], -1)
        w[v, : pick.size] = 1.0
    return pix, w


def coverage_energy(
    model: body.BodyModel,
    surface: flesh.FleshPoints,
    rig: camera.Rig,
    x: jnp.ndarray,
    pixels: jnp.ndarray,
    weights: jnp.ndarray,
    sigma_px: float = 5.0,
) -> jnp.ndarray:
    """How much of the observed silhouette the model leaves uncovered (the direction the ``foreground`` cue does not
    see): for each observed pixel ``q`` the distance ``d_q`` to the nearest projected flesh point,

        ``E = Σ_v Σ_q w_vq ρ(d_vq / σ) / Σ_q w_vq``,  ``ρ(r) = r² / (1 + r²)`` (Geman–McClure, bounded),

    so that a too-thin or too-short limb is pulled out to its silhouette. ``pixels (V, M, 2)``, ``weights (V, M)``.
    Differentiable in ``x`` and in the model's dimensions (through ``surface``).
    """
    R, t = body.segment_poses(model, x)
    X, _ = surface.world(R, t)
    uv = camera.project(rig, X)  # (V, P, 2)
    d2 = jnp.sum((pixels[:, :, None, :] - uv[:, None, :, :]) ** 2, axis=-1)  # (V, M, P)
    r2 = jnp.min(d2, axis=-1) / (sigma_px * sigma_px)
    rho = r2 / (1.0 + r2)
    return jnp.sum(jnp.sum(weights * rho, axis=-1) / jnp.maximum(jnp.sum(weights, axis=-1), 1.0))


def calibrate(
    lik: Likelihood,
    observations,
    states: jnp.ndarray,
    *,
    names: Sequence[str] | None = None,
    init: Mapping[str, float] | None = None,
    steps: int = 150,
    learning_rate: float = 0.02,
    fit_pose: bool = True,
    ridge: float = 0.0,
    coverage: Coverage | None = None,
    layer=0,
    builder: Callable | None = None,
    penalty: tuple[Callable, object] | None = None,
) -> ShapeFit:
    """Fit body dimensions (and poses) to ``T`` frames by gradient ascent on the log-likelihood.

    Args:
      lik: the likelihood (its model fixes the preset; its dimensions are replaced by ``init``).
      observations: the ``T`` frames' observations stacked along a leading axis (a pytree of arrays).
      states: ``(T, D)`` starting poses (e.g. from a tracker run with default dimensions).
      names: dimensions to fit (default :func:`symmetric_names`); the others keep their ``init`` value.
      init: the starting dimensions (default :data:`jaxmocap.geometry.body.DEFAULT_DIMENSIONS`); must contain every name.
      steps, learning_rate: Adam steps and step size (in ``u``/``v`` units: ``0.02`` ≈ 2 % of a length per step).
      fit_pose: optimise the poses too (otherwise they stay at ``states``).
      ridge: ``ρ`` of the module docstring.
      coverage: an optional :class:`Coverage` term, subtracted as ``κ · mean_t coverage_energy`` (see
        :func:`coverage_energy`); it counters the shrinking that the ``foreground`` cue alone favours.
      layer: annealing layer of the likelihood to use.
      builder: ``dims -> BodyModel`` (default: the preset of ``lik.model``).
      penalty: an optional ``(fn, data)``: ``fn(L, X, data)`` (a scalar, ``L`` the likelihood with the current
        dimensions, ``X (T, D)`` the current poses, ``data`` a pytree of arrays passed to the compiled loop as an
        argument) is subtracted from the objective (e.g. :func:`jaxmocap.fit.shape_start.silhouette_distance`).

    Returns:
      :class:`ShapeFit` (host arrays and floats).
    """
    names = tuple(symmetric_names() if names is None else names)
    base = dict(body.DEFAULT_DIMENSIONS if init is None else init)
    missing = [n for n in names if n not in base and n.split("_", 1)[-1] not in base]
    if missing:
        raise ValueError(f"no starting value for dimensions {missing}")
    dtype = lik.model.offset.dtype
    start = {}
    for n in names:
        key = n if n in base else n.split("_", 1)[-1]  # "left_forearm_length" starts from "forearm_length"
        start[n] = jnp.asarray(base[key], dtype)
    base = {k: jnp.asarray(v, dtype) for k, v in base.items()}
    X0 = jnp.asarray(states, dtype)
    if X0.ndim != 2:
        raise ValueError("states must be (T, D)")
    scale_x = jnp.where(jnp.asarray(lik.model.angular), 0.1, 0.05).astype(dtype)
    layout = flesh.surface_layout(lik.model, total=int(lik.surface.local.shape[0]))
    lower, upper = lik.model.lower, lik.model.upper

    pen_fn, pen_data = penalty if penalty is not None else (None, None)

    def objective(params, observations, pen_data):
        u, v = params
        X = X0 + scale_x * v if fit_pose else X0
        L = likelihood_with_dimensions(lik, _dims_of(u, names, start, base), builder, layout)
        ll = jax.vmap(lambda x, o: L.log_likelihood(x, o, layer))(X, observations)
        out = jnp.mean(ll) - 0.5 * ridge * jnp.sum(u * u)
        if coverage is not None:
            e = jax.vmap(
                lambda x, p, w: coverage_energy(L.model, L.surface, L.rig, x, p, w, coverage.sigma_px)
            )(X, jnp.asarray(coverage.pixels, dtype), jnp.asarray(coverage.weights, dtype))
            out = out - coverage.weight * jnp.mean(e)
        if pen_fn is not None:
            out = out - pen_fn(L, X, pen_data)
        return out

    opt = optax.adam(learning_rate)
    params = (jnp.zeros(len(names), dtype), jnp.zeros_like(X0))

    @jax.jit
    def run(params, observations, pen_data):
        def body_fn(carry, _):
            params, state = carry
            value, grads = jax.value_and_grad(objective)(params, observations, pen_data)
            grads = jax.tree_util.tree_map(lambda g: jnp.where(jnp.isfinite(g), -g, 0.0), grads)
            updates, state = opt.update(grads, state, params)
            u, v = optax.apply_updates(params, updates)
            if fit_pose:  # keep the poses inside the joint limits
                v = (apply_limits(X0 + scale_x * v, lower, upper) - X0) / scale_x
            return ((u, v), state), value

        (params, _), values = jax.lax.scan(body_fn, (params, opt.init(params)), None, length=steps)
        return params, jnp.append(values, objective(params, observations, pen_data))

    (u, v), values = run(params, observations, pen_data)
    dims = {k: float(x) for k, x in _dims_of(u, names, start, base).items()}
    X = X0 + scale_x * v if fit_pose else X0
    return ShapeFit(dims, np.asarray(X), np.asarray(values))


def limb_lengths(model: body.BodyModel) -> dict[str, float]:
    """Distances between adjacent evaluation joints of ``model`` at its rest pose (metres), e.g.
    ``"left_forearm" = ‖left_wrist − left_elbow‖``: the lengths a calibration can be checked against."""
    J = np.asarray(body.joint_positions(model, model.rest_pose), np.float64)
    idx = {n: i for i, n in enumerate(model.joint_names)}
    pairs = {
        "upper_arm": ("shoulder", "elbow"),
        "forearm": ("elbow", "wrist"),
        "thigh": ("hip", "knee"),
        "shin": ("knee", "ankle"),
    }
    out = {}
    for side in ("left", "right"):
        for limb, (a, b) in pairs.items():
            ja, jb = f"{side}_{a}", f"{side}_{b}"
            if ja in idx and jb in idx:
                out[f"{side}_{limb}"] = float(np.linalg.norm(J[idx[ja]] - J[idx[jb]]))
    if "root" in idx and "thorax" in idx:
        out["torso"] = float(np.linalg.norm(J[idx["thorax"]] - J[idx["root"]]))
    return out
