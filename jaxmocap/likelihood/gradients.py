"""Gradients of the log-likelihood with respect to the pose, the camera parameters and the body dimensions.

The composed log-likelihood of :mod:`jaxmocap.likelihood.compose`,

    ``ℓ(x; θ_cam, θ_body) = log p_l(z | x) = −Σ_c λ_c(l) k_c Σ_v w_v E_c,v(x, z)``,

is a pure JAX function of the state ``x (D,)``, of the cameras (the ``rig`` leaves of the
:class:`~jaxmocap.likelihood.compose.Likelihood`) and of the body dimensions (the ``model`` and flesh-point leaves, which
:func:`jaxmocap.geometry.body.full25` and the other presets build from a dimension dict with ``jax.numpy``). Its gradient
exists wherever the cues are differentiable: every cue in its differentiable configuration
(:data:`jaxmocap.likelihood.cues.DIFFERENTIABLE`: the map cues with ``params={"bilinear": True}``, the colour
histogram, ``edge_fraction``, ``depth`` and ``silhouette_divergence`` with ``soft=True`` as well; ``keypoints``,
``blobs3d``, ``ground``, ``interpenetration`` and ``coverage`` always); in their default configurations the map and
threshold cues are piecewise constant and contribute a zero gradient almost everywhere.

Three groups of parameters:

* **pose** — :func:`value_and_grad_pose` (one state), :func:`batch_value_and_grad` (``(N, D)`` particles, from any
  batched log-likelihood ``loglik_batch(X, observation, layer)``: one ``vjp`` gives every particle's value and
  gradient, since the particles do not interact);
* **cameras** — :class:`CameraParams`: per view the focal lengths ``(f_x, f_y)``, the principal point
  ``(c_x, c_y)``, the skew, OpenCV's distortion ``(k₁, k₂, p₁, p₂, k₃)``, the Rodrigues vector ``r`` of
  ``R = exp([r]×)`` (world → camera) and ``t`` (metres); :func:`camera_params` / :func:`rig_from_params` convert,
  :func:`camera_value_and_grad` differentiates (the layout of OpenCV's ``projectPoints`` Jacobian, which the tests
  use as the reference);
* **body dimensions** — a dict ``{name: value}`` of the preset's dimensions (``torso_length``, ``left_forearm_length``,
  ``thigh_radius_top`` …; :data:`jaxmocap.geometry.body.DEFAULT_DIMENSIONS`); :func:`with_body` rebuilds a likelihood around a
  (traced) model, :func:`body_value_and_grad` differentiates.

Non-finite log-likelihoods (a particle far outside the images, a dead particle) give value ``−inf`` and a zero
gradient, never NaN. Everything here is pure and jit-able; compile it once per configuration.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import NamedTuple

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.geometry import body, camera, flesh, kinematics
from jaxmocap.likelihood.compose import Likelihood, finite_value_and_grad

__all__ = [
    "CameraParams",
    "batch_value_and_grad",
    "own_value_and_grad",
    "vjp_value_and_grad",
    "body_value_and_grad",
    "camera_params",
    "camera_value_and_grad",
    "grad_pose",
    "likelihood_with_dimensions",
    "rig_from_params",
    "total_log_likelihood",
    "value_and_grad_pose",
    "with_body",
]


_finite = finite_value_and_grad


# ---------------------------------------------------------------------------------------------------------------
# Pose


def value_and_grad_pose(lik: Likelihood, x: jnp.ndarray, observation, layer=0):
    """``(ℓ, ∂ℓ/∂x)`` of one state ``x (D,)``: a scalar and ``(D,)``. ``layer``: as in ``Likelihood.log_likelihood``."""
    value, grad = jax.value_and_grad(lambda s: lik.log_likelihood(s, observation, layer))(x)
    return _finite(value, grad)


def grad_pose(lik: Likelihood, x: jnp.ndarray, observation, layer=0) -> jnp.ndarray:
    """``∂ℓ/∂x (D,)`` of one state (zero where ℓ is not finite)."""
    return value_and_grad_pose(lik, x, observation, layer)[1]


def batch_value_and_grad(loglik_batch: Callable, X: jnp.ndarray, observation, layer=0):
    """Values ``(N,)`` and gradients ``(N, D)`` of a batched log-likelihood at particles ``X (N, D)``.

    A likelihood that knows its own batched gradient takes it: one that carries a ``batch_value_and_grad(X,
    observation, layer)`` attribute (the tracker's likelihood), or a bound ``Likelihood.batch``
    (:meth:`Likelihood.batch_value_and_grad`: the per-particle log-likelihood differentiated in one ``vmap``, in
    chunks past ``2 · chunk_size`` particles).
    Any other ``loglik_batch(X, observation, layer) -> (N,)`` must treat the particles independently, so that
    ``∂/∂x_i Σ_j ℓ(x_j) = ∂ℓ(x_i)/∂x_i``: one reverse pass (``jax.vjp`` with a cotangent of ones) gives all
    gradients.
    """
    fast = own_value_and_grad(loglik_batch)
    if fast is not None:
        return fast(X, observation, layer)
    return vjp_value_and_grad(loglik_batch, X, observation, layer)


def vjp_value_and_grad(loglik_batch: Callable, X: jnp.ndarray, observation, layer=0):
    """The general path of :func:`batch_value_and_grad`: one ``jax.vjp`` of the batched likelihood with a
    cotangent of ones (of zeros at non-finite values)."""
    values, pullback = jax.vjp(lambda S: loglik_batch(S, observation, layer), X)
    ok = jnp.isfinite(values)
    (grads,) = pullback(jnp.where(ok, 1.0, 0.0).astype(values.dtype))
    return _finite(values, grads)


def own_value_and_grad(loglik_batch: Callable) -> Callable | None:
    """The batched value-and-gradient a likelihood provides itself (see :func:`batch_value_and_grad`), or None."""
    fast = getattr(loglik_batch, "batch_value_and_grad", None)
    if fast is not None:
        return fast
    owner = getattr(loglik_batch, "__self__", None)
    if isinstance(owner, Likelihood) and getattr(loglik_batch, "__name__", None) == "batch":
        return owner.batch_value_and_grad
    return None


# ---------------------------------------------------------------------------------------------------------------
# Cameras


class CameraParams(NamedTuple):
    """Differentiable camera parameters of ``V`` views (a pytree).

    focal ``(V, 2)`` = ``(f_x, f_y)`` pixels; centre ``(V, 2)`` = ``(c_x, c_y)`` pixels; skew ``(V,)`` = ``K[0, 1]``;
    dist ``(V, 5)`` = ``(k₁, k₂, p₁, p₂, k₃)``; rvec ``(V, 3)``: Rodrigues vector of the world→camera rotation
    (``R = exp([rvec]×)``, OpenCV's ``rvec``); t ``(V, 3)`` metres (``x_cam = R x + t``).
    """

    focal: jnp.ndarray
    centre: jnp.ndarray
    skew: jnp.ndarray
    dist: jnp.ndarray
    rvec: jnp.ndarray
    t: jnp.ndarray


def camera_params(rig: camera.Rig, dtype=jnp.float32) -> CameraParams:
    """The :class:`CameraParams` of a rig (host side: the rotation vector comes from ``cv2.Rodrigues``)."""
    K = np.asarray(rig.K, np.float64)
    R = np.asarray(rig.R, np.float64)
    rvec = np.stack([cv2.Rodrigues(np.ascontiguousarray(r))[0].reshape(3) for r in R])
    f = lambda a: jnp.asarray(a, dtype)
    return CameraParams(
        focal=f(np.stack([K[:, 0, 0], K[:, 1, 1]], -1)),
        centre=f(np.stack([K[:, 0, 2], K[:, 1, 2]], -1)),
        skew=f(K[:, 0, 1]),
        dist=f(np.asarray(rig.dist, np.float64)),
        rvec=f(rvec),
        t=f(np.asarray(rig.t, np.float64)),
    )


def rig_from_params(params: CameraParams, like: camera.Rig) -> camera.Rig:
    """A :class:`~jaxmocap.geometry.camera.Rig` with the arrays of ``params`` (differentiable) and the static fields
    (names, image sizes) of ``like``."""
    fx, fy = params.focal[:, 0], params.focal[:, 1]
    cx, cy = params.centre[:, 0], params.centre[:, 1]
    zero, one = jnp.zeros_like(fx), jnp.ones_like(fx)
    K = jnp.stack(
        [
            jnp.stack([fx, params.skew, cx], -1),
            jnp.stack([zero, fy, cy], -1),
            jnp.stack([zero, zero, one], -1),
        ],
        -2,
    )
    R = kinematics.so3_exp(params.rvec)
    return dataclasses.replace(like, K=K, dist=params.dist, R=R, t=params.t)


def total_log_likelihood(lik: Likelihood, X: jnp.ndarray, observations, layer=0) -> jnp.ndarray:
    """``Σ_t ℓ(x_t, z_t)`` over frames: ``X (D,)`` with one observation, or ``X (T, D)`` with observations stacked
    along a leading ``T`` axis (a pytree of arrays)."""
    if X.ndim == 1:
        return lik.log_likelihood(X, observations, layer)
    return jnp.sum(jax.vmap(lambda x, o: lik.log_likelihood(x, o, layer))(X, observations))


def camera_value_and_grad(lik: Likelihood, params: CameraParams, X: jnp.ndarray, observations, layer=0):
    """``(ℓ, ∂ℓ/∂params)`` for the cameras ``params`` (:class:`CameraParams`) at fixed poses.

    ``X``: one state ``(D,)`` with its observation, or ``(T, D)`` states with observations stacked over ``T``
    (the log-likelihoods are summed). The rig of ``lik`` only supplies names and image sizes.
    """

    def f(p):
        return total_log_likelihood(
            dataclasses.replace(lik, rig=rig_from_params(p, lik.rig)), X, observations, layer
        )

    return _finite(*jax.value_and_grad(f)(params))


# ---------------------------------------------------------------------------------------------------------------
# Body dimensions


def with_body(
    lik: Likelihood, model: body.BodyModel, layout: flesh.SurfaceLayout | None = None
) -> Likelihood:
    """The likelihood ``lik`` around another body ``model`` of the same preset (e.g. one built from traced
    dimensions): the model leaf is replaced and the flesh points are recomputed on it.

    ``layout`` is the static :class:`~jaxmocap.geometry.flesh.SurfaceLayout` of the flesh points; by default the one
    ``Likelihood.create`` chose for ``lik.model`` (areas of the concrete model, the same total), so that the points
    keep their number and segments and only move with the dimensions.
    """
    if model.topology != lik.model.topology or model.shape_kind != lik.model.shape_kind:
        raise ValueError(
            "with_body needs a model of the same preset (topology and flesh kinds) as the likelihood"
        )
    if layout is None:
        layout = flesh.surface_layout(lik.model, total=int(lik.surface.local.shape[0]))
    surface = flesh.surface_points(model, layout)
    if tuple(surface.segment) != tuple(lik.surface.segment):
        raise ValueError("the surface layout does not match the likelihood's flesh points")
    return dataclasses.replace(lik, model=model, surface=surface)


def likelihood_with_dimensions(
    lik: Likelihood,
    dims: Mapping[str, jnp.ndarray],
    builder: Callable | None = None,
    layout: flesh.SurfaceLayout | None = None,
) -> Likelihood:
    """``with_body(lik, builder(dims))``: the likelihood of a subject with dimensions ``dims`` (values may be traced).

    ``builder`` defaults to the preset of ``lik.model`` (``body.build(lik.model.name, ·)``), in the model's dtype.
    """
    dtype = lik.model.offset.dtype
    if builder is None:
        builder = lambda d: body.build(lik.model.name, d, dtype=dtype)
    return with_body(lik, builder(dict(dims)), layout)


def body_value_and_grad(
    lik: Likelihood,
    dims: Mapping[str, jnp.ndarray],
    X: jnp.ndarray,
    observations,
    layer=0,
    builder: Callable | None = None,
):
    """``(ℓ, {name: ∂ℓ/∂dims[name]})`` for body dimensions ``dims`` at fixed poses ``X`` (``(D,)`` or ``(T, D)``
    with stacked observations, as in :func:`camera_value_and_grad`). Dimensions absent from ``dims`` keep the
    preset's defaults (:data:`jaxmocap.geometry.body.DEFAULT_DIMENSIONS`); to differentiate the subject of ``lik`` pass all
    its dimensions."""
    layout = flesh.surface_layout(lik.model, total=int(lik.surface.local.shape[0]))
    dims = {k: jnp.asarray(v, lik.model.offset.dtype) for k, v in dims.items()}

    def f(d):
        return total_log_likelihood(
            likelihood_with_dimensions(lik, d, builder, layout), X, observations, layer
        )

    return _finite(*jax.value_and_grad(f)(dims))
