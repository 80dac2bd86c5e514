"""Pixel lookups against NumPy indexing and OpenCV's bilinear remap."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
from jax.test_util import check_grads

from jaxmocap.likelihood import maps


def _maps(rng, V=2, H=37, W=53):
    return rng.uniform(0, 255, size=(V, H, W)).astype(np.float32)


def test_nearest_matches_numpy_and_counts_outside():
    rng = np.random.default_rng(0)
    M = _maps(rng)
    V, H, W = M.shape
    uv = rng.uniform([-5, -5], [W + 5, H + 5], size=(V, 400, 2)).astype(np.float32)
    vals, inside = maps.lookup_nearest(jnp.asarray(M), jnp.asarray(uv))
    # nearest pixel centre, ties rounding up: floor(u + 1/2)
    iu = np.clip(np.floor(uv[..., 0] + 0.5), 0, W - 1).astype(int)
    iv = np.clip(np.floor(uv[..., 1] + 0.5), 0, H - 1).astype(int)
    ref = np.stack([M[v][iv[v], iu[v]] for v in range(V)])
    np.testing.assert_array_equal(np.asarray(vals), ref)
    ref_inside = (np.floor(uv[..., 0] + 0.5) >= 0) & (np.floor(uv[..., 0] + 0.5) <= W - 1)
    ref_inside &= (np.floor(uv[..., 1] + 0.5) >= 0) & (np.floor(uv[..., 1] + 0.5) <= H - 1)
    np.testing.assert_array_equal(np.asarray(inside), ref_inside)


def test_shared_index_reads_every_dtype_and_channels():
    """One index serves several maps: bytes stay exact, float16 converts, (V, H, W, C) maps give channels, and
    batched queries (a leading particle axis) index the right view."""
    rng = np.random.default_rng(3)
    V, H, W = 2, 11, 13
    M8 = rng.integers(0, 256, size=(V, H, W)).astype(np.uint8)
    M3 = rng.uniform(size=(V, H, W, 3)).astype(np.float32)
    uv = rng.uniform([-0.4, -0.4], [W - 0.6, H - 0.6], size=(5, V, 17, 2)).astype(np.float32)
    idx, inside = maps.nearest_index(jnp.asarray(uv), (V, H, W))
    assert bool(jnp.all(inside))
    iu = np.floor(uv[..., 0] + 0.5).astype(int)
    iv = np.floor(uv[..., 1] + 0.5).astype(int)
    view = np.arange(V)[None, :, None]
    np.testing.assert_array_equal(np.asarray(maps.gather(jnp.asarray(M8), idx, raw=True)), M8[view, iv, iu])
    np.testing.assert_allclose(
        np.asarray(maps.gather(jnp.asarray(M8), idx, 1 / 255)), M8[view, iv, iu] / 255, rtol=1e-6
    )
    np.testing.assert_allclose(
        np.asarray(maps.gather(jnp.asarray(M8.astype(np.float16)), idx)), M8[view, iv, iu].astype(np.float32)
    )
    np.testing.assert_array_equal(np.asarray(maps.gather(jnp.asarray(M3), idx)), M3[view, iv, iu])


def test_visible_index_reads_the_sentinel():
    """A hidden sample's index points one past the flattened maps; read from a map with that entry appended it
    returns the fill value, a visible one its pixel."""
    rng = np.random.default_rng(5)
    V, H, W = 2, 9, 12
    M = rng.integers(0, 1 << 24, size=(V, H, W)).astype(np.int32)
    uv = rng.uniform([-3, -3], [W + 3, H + 3], size=(4, V, 30, 2)).astype(np.float32)
    seen = rng.uniform(size=(4, V, 30)) < 0.6
    idx, inside = maps.nearest_index(jnp.asarray(uv), (V, H, W))
    vis = maps.visible_index(idx, jnp.asarray(seen) & inside, (V, H, W))
    flat = maps.with_sentinel(jnp.asarray(M), -1)
    assert flat.shape == (V * H * W + 1,) and int(flat[-1]) == -1
    got = np.asarray(maps.gather(flat, vis, raw=True))
    iu = np.clip(np.floor(uv[..., 0] + 0.5), 0, W - 1).astype(int)
    iv = np.clip(np.floor(uv[..., 1] + 0.5), 0, H - 1).astype(int)
    ref = np.where(seen & np.asarray(inside), M[np.arange(V)[None, :, None], iv, iu], -1)
    np.testing.assert_array_equal(got, ref)
    assert 0 < np.mean(ref == -1) < 1


def test_bilinear_matches_cv2_remap():
    rng = np.random.default_rng(1)
    M = _maps(rng)
    V, H, W = M.shape
    uv = rng.uniform([0, 0], [W - 1, H - 1], size=(V, 300, 2)).astype(np.float32)
    vals, inside = maps.lookup_bilinear(jnp.asarray(M), jnp.asarray(uv))
    assert bool(jnp.all(inside))
    for v in range(V):
        ref = cv2.remap(M[v], uv[v, :, 0:1], uv[v, :, 1:2], cv2.INTER_LINEAR)[:, 0]
        # OpenCV quantises the fractional part to 1/32 pixel (INTER_BITS = 5)
        np.testing.assert_allclose(np.asarray(vals[v]), ref, atol=255 / 32)
        np.testing.assert_allclose(np.asarray(vals[v]).mean(), ref.mean(), rtol=1e-3)


def test_bilinear_exact_at_pixel_centres_and_differentiable():
    rng = np.random.default_rng(2)
    M = _maps(rng, V=1, H=9, W=11)
    iu, iv = np.meshgrid(np.arange(11), np.arange(9))
    uv = np.stack([iu.ravel(), iv.ravel()], -1)[None].astype(np.float32)
    vals, _ = maps.lookup_bilinear(jnp.asarray(M), jnp.asarray(uv))
    np.testing.assert_allclose(np.asarray(vals[0]), M[0].ravel(), rtol=1e-6)
    with jax.enable_x64(True):
        M64 = jnp.asarray(M, jnp.float64)
        check_grads(
            lambda p: maps.lookup_bilinear(M64, p)[0], (jnp.asarray([[[3.3, 4.6], [7.2, 1.9]]]),), order=1
        )


def test_non_finite_coordinates_are_outside_not_nan():
    M = jnp.ones((1, 4, 4))
    uv = jnp.asarray([[[jnp.nan, 1.0], [1.0, jnp.inf]]])
    for f in (maps.lookup_nearest, maps.lookup_bilinear):
        vals, inside = f(M, uv)
        assert not bool(jnp.any(inside)) and bool(jnp.all(jnp.isfinite(vals)))


def test_bilinear_gradient_is_the_slope_of_a_linear_map_and_checks_numerically():
    """On a map that is linear in the pixel coordinates, ``m = α u + β v + γ`` (per view), bilinear interpolation is
    exact and its gradient in ``uv`` is ``(α, β)`` everywhere inside (the finite differences of neighbouring
    texels are the slopes); the derivatives of the value, of multi-channel maps and in the map itself agree with
    numerical differences (``check_grads``, forward and reverse)."""
    V, H, W = 2, 6, 8
    slopes = np.array([[0.7, -1.3, 4.0], [-2.1, 0.4, 9.0]], np.float32)  # (α, β, γ) per view
    iv, iu = np.mgrid[0:H, 0:W].astype(np.float32)
    M = jnp.asarray(np.stack([a * iu + b * iv + c for a, b, c in slopes]))
    rng = np.random.default_rng(3)
    uv = jnp.asarray(rng.uniform([0.1, 0.1], [W - 1.1, H - 1.1], size=(V, 7, 2)), jnp.float32)
    f = lambda p: maps.lookup_bilinear(M, p)[0]  # noqa: E731
    np.testing.assert_allclose(
        jax.jit(f)(uv),
        slopes[:, None, 0] * uv[..., 0] + slopes[:, None, 1] * uv[..., 1] + slopes[:, None, 2],
        rtol=1e-5,
    )
    g = jax.jit(jax.grad(lambda p: jnp.sum(f(p))))(uv)
    np.testing.assert_allclose(g, np.broadcast_to(slopes[:, None, :2], g.shape), rtol=1e-5)
    jf = jax.jit(jax.jacfwd(lambda p: jnp.sum(f(p))))(uv)
    np.testing.assert_allclose(jf, g, rtol=1e-6)
    with jax.enable_x64(True):
        uv64 = jnp.asarray(uv, jnp.float64)
        M64 = jnp.asarray(rng.uniform(0, 1, size=(V, H, W, 3)))
        check_grads(
            jax.jit(lambda p: maps.lookup_bilinear(M64, p)[0]), (uv64,), order=1, modes=("fwd", "rev")
        )
        check_grads(jax.jit(lambda m: maps.lookup_bilinear(m, uv64)[0]), (M64[..., 0],), order=1)
        s = lambda p: maps.gather_bilinear(M64[..., 1], *maps.bilinear_index(p, (V, H, W))[:3], 0.25)  # noqa: E731
        check_grads(jax.jit(s), (uv64,), order=1, modes=("fwd", "rev"))
