"""Pixel lookups in image maps stacked by view, as the cues need them.

Maps are ``(V, H, W)`` arrays (one per view); query points are pixel coordinates ``uv (V, P, 2)`` with ``u`` the
column and ``v`` the row, pixel centres at integer coordinates (OpenCV convention). Every lookup clamps to the
image and returns an explicit ``inside (V, P)`` mask, so that a cue can count out-of-image samples the way its
definition requires. Written as one gather from the flattened maps: per particle under ``vmap`` this is the
cheapest form on CPU.
"""

from __future__ import annotations

import jax.numpy as jnp


def inside_image(uv: jnp.ndarray, height: int, width: int) -> jnp.ndarray:
    """``(..., 2) -> (...)`` bool: the nearest pixel centre of ``uv`` lies in the image."""
    u, v = uv[..., 0], uv[..., 1]
    return (
        (u > -0.5) & (u < width - 0.5) & (v > -0.5) & (v < height - 0.5) & jnp.isfinite(u) & jnp.isfinite(v)
    )


def _flat_index(maps_shape, iu, iv):
    V, H, W = maps_shape
    view = jnp.arange(V, dtype=jnp.int32).reshape((V,) + (1,) * (iu.ndim - 1))
    return (view * H + iv) * W + iu


def lookup_nearest(maps: jnp.ndarray, uv: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Nearest-pixel values of ``maps (V, H, W)`` at ``uv (V, P, 2)``: ``(values (V, P), inside (V, P))``.

    Out-of-image points read the clamped border pixel; use ``inside`` to mask them.
    """
    V, H, W = maps.shape
    inside = inside_image(uv, H, W)
    u = jnp.where(jnp.isfinite(uv[..., 0]), uv[..., 0], 0.0)
    v = jnp.where(jnp.isfinite(uv[..., 1]), uv[..., 1], 0.0)
    iu = jnp.clip(jnp.round(u), 0, W - 1).astype(jnp.int32)
    iv = jnp.clip(jnp.round(v), 0, H - 1).astype(jnp.int32)
    values = jnp.take(maps.reshape(-1), _flat_index(maps.shape, iu, iv), mode="clip")
    return values, inside


def lookup_bilinear(maps: jnp.ndarray, uv: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Bilinear interpolation of ``maps (V, H, W)`` at ``uv (V, P, 2)``; differentiable in ``uv``.

    Coordinates are clamped to ``[0, W−1] × [0, H−1]`` before interpolation; returns ``(values, inside)``.
    """
    V, H, W = maps.shape
    inside = inside_image(uv, H, W)
    u = jnp.clip(jnp.where(jnp.isfinite(uv[..., 0]), uv[..., 0], 0.0), 0.0, W - 1.0)
    v = jnp.clip(jnp.where(jnp.isfinite(uv[..., 1]), uv[..., 1], 0.0), 0.0, H - 1.0)
    u0 = jnp.clip(jnp.floor(u), 0, W - 2).astype(jnp.int32)
    v0 = jnp.clip(jnp.floor(v), 0, H - 2).astype(jnp.int32)
    fu = u - u0
    fv = v - v0
    flat = maps.reshape(-1).astype(jnp.result_type(maps.dtype, jnp.float32))
    i00 = _flat_index(maps.shape, u0, v0)
    a = jnp.take(flat, i00, mode="clip")
    b = jnp.take(flat, i00 + 1, mode="clip")
    c = jnp.take(flat, i00 + W, mode="clip")
    d = jnp.take(flat, i00 + W + 1, mode="clip")
    values = (a * (1 - fu) + b * fu) * (1 - fv) + (c * (1 - fu) + d * fu) * fv
    return values, inside
