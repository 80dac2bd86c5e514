"""Pixel lookups in image maps stacked by view, as the cues need them.

Maps are ``(V, H, W)`` arrays (one per view), or ``(V, H, W, C)`` for multi-channel maps; query points are pixel
coordinates ``uv (..., V, P, 2)`` with ``u`` the column and ``v`` the row, pixel centres at integer coordinates
(OpenCV convention). Every lookup clamps to the image and returns an explicit ``inside`` mask, so that a cue can
count out-of-image samples the way its definition requires.

The lookups are split in two so that several maps read at the same points share one index computation:

* :func:`nearest_index` / :func:`bilinear_index` turn coordinates into flat indices into the flattened maps
  (and the bilinear fractions); the result passes through ``lax.optimization_barrier``, meant to make XLA compute
  it once instead of fusing (and recomputing) the rounding into every gather that reads it (see below for the
  CPU compiler);
* :func:`gather` / :func:`gather_bilinear` read a map at those indices, in the map's own dtype (``uint8`` maps
  stay bytes until after the gather: fewer cache misses), as ``float32``.

XLA's CPU compiler drops ``optimization_barrier`` before fusion and copies cheap element-wise producers (here the
projection, lens distortion, rounding and the camera-facing test) into every fusion that reads them; a gather, in
contrast, is never duplicated. Cues that read many values per sample therefore read them through one gather whose
result already carries the sample's visibility: :func:`visible_index` sends a hidden or out-of-image sample to a
sentinel entry one past the end of the flattened maps, and :func:`with_sentinel` appends that entry to a map
(measured on ``upper14`` with the IROS 2007 cues: the per-limb colour sums had recomputed the projection in each of
their ≈ 40 fusions).

Nearest pixel: ``iu = ⌊u + ½⌋`` (ties round up), inside iff ``−½ < u < W − ½`` (and likewise for ``v``).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax.custom_derivatives import SymbolicZero


def inside_image(uv: jnp.ndarray, height: int, width: int) -> jnp.ndarray:
    """``(..., 2) -> (...)`` bool: the nearest pixel centre of ``uv`` lies in the image (False for NaN/inf)."""
    u, v = uv[..., 0], uv[..., 1]
    return (u > -0.5) & (u < width - 0.5) & (v > -0.5) & (v < height - 0.5)


def _view_offset(num_views: int, plane: int) -> jnp.ndarray:
    """``(V, 1)`` start of each view's plane in the flattened maps (indices are ``(..., V, P)``)."""
    return (jnp.arange(num_views, dtype=jnp.int32) * plane)[:, None]


def _float_type(dtype):
    """float32 for byte and half maps, else the map's own float type (float64 maps stay float64)."""
    return dtype if dtype in (jnp.float32, jnp.float64) else jnp.float32


def _finite(a: jnp.ndarray) -> jnp.ndarray:
    return jnp.where(jnp.isfinite(a), a, 0.0)


def nearest_index(uv: jnp.ndarray, shape: tuple[int, int, int]) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Flat nearest-pixel indices of ``uv (..., V, P, 2)`` into maps of shape ``(V, H, W)``.

    Returns ``(index (..., V, P) int32, inside (..., V, P) bool)``; out-of-image points index the clamped border
    pixel (non-finite coordinates the pixel ``(0, 0)``).
    """
    V, H, W = shape[:3]
    inside = inside_image(uv, H, W)
    iu = jnp.clip(_finite(uv[..., 0]) + 0.5, 0.0, W - 0.5).astype(jnp.int32)
    iv = jnp.clip(_finite(uv[..., 1]) + 0.5, 0.0, H - 0.5).astype(jnp.int32)
    index = _view_offset(V, H * W) + iv * W + iu
    return jax.lax.optimization_barrier((index, inside))


def visible_index(index: jnp.ndarray, visible: jnp.ndarray, shape: tuple[int, int, int]) -> jnp.ndarray:
    """``index (..., V, P)`` where ``visible``, else the sentinel ``V·H·W`` (the entry :func:`with_sentinel`
    appends to maps of shape ``(V, H, W)``)."""
    V, H, W = shape[:3]
    return jnp.where(visible, index, V * H * W)


def with_sentinel(maps: jnp.ndarray, fill) -> jnp.ndarray:
    """``maps (V, H, W)`` flattened to ``(V·H·W + 1,)`` with ``fill`` appended: read at a :func:`visible_index`,
    a hidden sample returns ``fill``."""
    return jnp.concatenate([maps.reshape(-1), jnp.full((1,), fill, maps.dtype)])


def gather(maps: jnp.ndarray, index: jnp.ndarray, scale: float = 1.0, raw: bool = False) -> jnp.ndarray:
    """``maps (V, H, W)`` at flat ``index`` → float values times ``scale`` (float32; float64 maps stay float64);
    ``(V, H, W, C)`` maps give ``(..., C)``; a flat map (:func:`with_sentinel`) gives ``(...)``; ``raw=True``
    returns the stored values unconverted. Indices must be in range (as :func:`nearest_index` makes them)."""
    if maps.ndim in (1, 3):
        vals = maps.reshape(-1).at[index].get(mode="promise_in_bounds")
    else:
        vals = maps.reshape(-1, maps.shape[-1]).at[index].get(mode="promise_in_bounds")
    if raw:
        return vals
    vals = vals.astype(_float_type(maps.dtype))
    return vals * scale if scale != 1.0 else vals


def lookup_nearest(maps: jnp.ndarray, uv: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Nearest-pixel values of ``maps (V, H, W)`` at ``uv (V, P, 2)``: ``(values (V, P), inside (V, P))``.

    Out-of-image points read the clamped border pixel; use ``inside`` to mask them. Values keep the map's dtype
    class: float maps give float32.
    """
    index, inside = nearest_index(uv, maps.shape)
    return gather(maps, index), inside


def bilinear_index(
    uv: jnp.ndarray, shape: tuple[int, int, int]
) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """Top-left flat index and fractions for bilinear interpolation at ``uv (..., V, P, 2)`` in ``(V, H, W)`` maps.

    Coordinates are clamped to ``[0, W−1] × [0, H−1]``; returns ``(i00, fu, fv, inside)`` with the four
    neighbours at ``i00, i00 + 1, i00 + W, i00 + W + 1``. ``fu``, ``fv`` carry the gradient in ``uv``.
    """
    V, H, W = shape[:3]
    inside = inside_image(uv, H, W)
    u = jnp.clip(_finite(uv[..., 0]), 0.0, W - 1.0)
    v = jnp.clip(_finite(uv[..., 1]), 0.0, H - 1.0)
    u0 = jnp.clip(jax.lax.stop_gradient(jnp.floor(u)), 0, max(W - 2, 0))
    v0 = jnp.clip(jax.lax.stop_gradient(jnp.floor(v)), 0, max(H - 2, 0))
    i00 = _view_offset(V, H * W) + v0.astype(jnp.int32) * W + u0.astype(jnp.int32)
    i00, inside = jax.lax.optimization_barrier((i00, inside))
    return i00, u - u0, v - v0, inside


def gather_bilinear(
    maps: jnp.ndarray, i00: jnp.ndarray, fu: jnp.ndarray, fv: jnp.ndarray, scale: float = 1.0
) -> jnp.ndarray:
    """Bilinear interpolation of ``maps (V, H, W)`` (or ``(V, H, W, C)``) at indices from :func:`bilinear_index`:
    ``((1−fu)(1−fv) m₀₀ + fu(1−fv) m₀₁ + (1−fu) fv m₁₀ + fu fv m₁₁) · scale`` in float32.

    Differentiable in ``fu``, ``fv`` (and linear in ``maps``) through its own JVP: the derivatives are the finite
    differences of the four texels already read, ``∂/∂fu = (m₀₁ − m₀₀)(1 − fv) + (m₁₁ − m₁₀) fv`` and
    ``∂/∂fv = (m₁₀ + (m₁₁ − m₁₀) fu) − (m₀₀ + (m₀₁ − m₀₀) fu)`` (times ``scale``), computed next to the value in
    the forward pass; the reverse pass multiplies them by the cotangent and reads no texel again. The value is
    the same expression as without derivatives.
    """
    return _bilinear(maps, i00, fu, fv, float(scale))


def _texels(maps, i00):
    W = maps.shape[2]
    return gather(maps, i00), gather(maps, i00 + 1), gather(maps, i00 + W), gather(maps, i00 + W + 1)


def _interpolate(a, b, c, d, fu, fv, scale):
    if a.ndim > fu.ndim:
        fu, fv = fu[..., None], fv[..., None]
    out = (a + (b - a) * fu) * (1 - fv) + (c + (d - c) * fu) * fv
    return out * scale if scale != 1.0 else out


@functools.partial(jax.custom_jvp, nondiff_argnums=(4,))
def _bilinear(maps, i00, fu, fv, scale):
    return _interpolate(*_texels(maps, i00), fu, fv, scale)


def _quads(maps: jnp.ndarray) -> jnp.ndarray:
    """``(V·H·W, 4)``: each pixel's value with those of its right, lower and lower-right neighbours (the four
    texels a bilinear read at that top-left index interpolates; past the last row of the last view, zeros)."""
    n = maps.size
    W = maps.shape[2]
    flat = jnp.concatenate([maps.reshape(-1), jnp.zeros((W + 1,), maps.dtype)])
    return jnp.stack([flat[:n], flat[1 : n + 1], flat[W : n + W], flat[W + 1 : n + W + 1]], -1)


@functools.partial(_bilinear.defjvp, symbolic_zeros=True)
def _bilinear_jvp(scale, primals, tangents):
    maps, i00, fu, fv = primals
    t_maps, _, t_fu, t_fv = tangents
    if maps.ndim == 3:  # one gather of the four texels of each sample, read from the map of pixel quads
        q = gather(_quads(maps), i00)
        a, b, c, d = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    else:
        a, b, c, d = _texels(maps, i00)
    out = _interpolate(a, b, c, d, fu, fv, scale)
    gu, gv = (fu[..., None], fv[..., None]) if a.ndim > fu.ndim else (fu, fv)
    top = a + (b - a) * gu
    du = (b - a) * (1 - gv) + (d - c) * gv
    dv = c + (d - c) * gu - top
    tangent = jnp.zeros_like(out)
    for t, coef in ((t_fu, du), (t_fv, dv)):
        if not isinstance(t, SymbolicZero):
            tangent = tangent + coef * (t[..., None] if a.ndim > t.ndim else t)
    if scale != 1.0:
        tangent = tangent * scale
    if not isinstance(t_maps, SymbolicZero):
        tangent = tangent + _interpolate(*_texels(jnp.asarray(t_maps), i00), fu, fv, scale)
    return out, tangent


def texel_quads(maps: jnp.ndarray) -> jnp.ndarray:
    """``(V·H·W, 4)`` texel quads of ``maps (V, H, W)`` (:func:`_quads`): :func:`gather` at a :func:`bilinear_index`
    reads the four texels ``m₀₀, m₀₁, m₁₀, m₁₁`` of each sample in one gather, for a cue that combines them
    otherwise than by :func:`gather_bilinear` (with :func:`bilinear_weights`)."""
    return _quads(maps)


def bilinear_weights(fu: jnp.ndarray, fv: jnp.ndarray) -> jnp.ndarray:
    """``(..., 4)`` bilinear weights ``((1−fu)(1−fv), fu(1−fv), (1−fu) fv, fu fv)`` of the texels of
    :func:`texel_quads`, differentiable in ``fu``, ``fv``."""
    return jnp.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], -1)


def lookup_bilinear(maps: jnp.ndarray, uv: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Bilinear interpolation of ``maps (V, H, W)`` at ``uv (V, P, 2)``; differentiable in ``uv``.

    Coordinates are clamped to ``[0, W−1] × [0, H−1]`` before interpolation; returns ``(values, inside)``.
    """
    i00, fu, fv, inside = bilinear_index(uv, maps.shape)
    return gather_bilinear(maps, i00, fu, fv), inside
