"""Observation assembly (shapes, empty-field convention, dtypes, validation against the rig, one compilation for
every frame), the feature pipeline end to end, and the colour helpers."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.features.colour import bhattacharyya_distance, rgb_float, roi_histograms
from jaxmocap.features.observation import Observation, as_float, make_observation
from jaxmocap.features.pipeline import FeatureConfig, FeatureExtractor
from jaxmocap.geometry.camera import Rig

W, H = 160, 120


def simple_rig(V=2, sizes=None):
    K = np.tile(np.array([[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]]), (V, 1, 1))
    R = np.tile(np.eye(3), (V, 1, 1))
    t = np.zeros((V, 3))
    t[:, 0] = -0.2 * np.arange(V)  # cameras side by side along +x
    sizes = ((W, H),) * V if sizes is None else sizes
    return Rig(K=K, dist=np.zeros((V, 5)), R=R, t=t, names=tuple(f"c{v}" for v in range(V)), image_size=sizes)


def test_make_observation_shapes_and_empty_fields():
    rig = simple_rig()
    fg = [np.ones((H, W), np.float32), np.zeros((H, W), np.float32)]
    obs = make_observation(rig, foreground=fg, edge_dt=[np.full((H, W), 3.0)] * 2)
    assert isinstance(obs, Observation)
    assert obs.foreground.shape == (2, H, W) and obs.edge_dt.shape == (2, H, W)
    assert obs.edges.shape == obs.skin.shape == obs.depth.shape == (2, 1, 1)
    assert obs.rgb.shape == (2, 1, 1, 3)
    assert obs.blobs3d.shape == (3, 3) and obs.blob_conf.shape == (3,) and not np.any(obs.blob_conf)
    assert obs.keypoints2d.shape == (2, 1, 3)
    assert obs.has("foreground") and obs.has("edge_dt") and not obs.has("edges") and not obs.has("depth")
    assert not obs.has("keypoints2d") and obs.image_shape == (H, W) and obs.num_views == 2
    for leaf in jax.tree_util.tree_leaves(obs):
        assert isinstance(leaf, jax.Array) and leaf.dtype == jnp.float32
    obs = make_observation(rig, blobs3d=np.ones((2, 3)), blob_conf=[0.5, 0.25], max_blobs=4)
    np.testing.assert_array_equal(obs.blob_conf, [0.5, 0.25, 0.0, 0.0])
    np.testing.assert_array_equal(obs.blobs3d[2:], 0.0)


def test_make_observation_validates_against_the_rig():
    rig = simple_rig()
    with pytest.raises(MocapInputError, match="3 views given but the calibration has 2"):
        make_observation(rig, foreground=[np.zeros((H, W))] * 3)
    with pytest.raises(MocapInputError, match="calibration says 160x120"):
        make_observation(rig, foreground=[np.zeros((H, W)), np.zeros((H, W + 2))])
    with pytest.raises(MocapInputError, match="disagree in size"):
        make_observation(None, foreground=[np.zeros((H, W))], skin=[np.zeros((H + 1, W))])
    with pytest.raises(MocapInputError, match="keypoints2d"):
        make_observation(rig, keypoints2d=np.zeros((3, 5, 3)))
    with pytest.raises(MocapInputError, match="max_blobs"):
        make_observation(rig, blobs3d=np.zeros((4, 3)))
    with pytest.raises(ValueError):
        make_observation(rig, dtype="int32")


def test_views_of_different_sizes_are_padded():
    rig = simple_rig(sizes=((W, H), (W - 10, H - 4)))
    dt = [np.full((H, W), 2.0, np.float32), np.full((H - 4, W - 10), 5.0, np.float32)]
    fg = [np.ones((H, W)), np.ones((H - 4, W - 10))]
    obs = make_observation(rig, foreground=fg, edge_dt=dt)
    assert obs.foreground.shape == (2, H, W)
    assert (
        float(obs.foreground[1, H - 4 :].max()) == 0.0
        and float(obs.foreground[1, : H - 4, : W - 10].min()) == 1.0
    )
    assert float(obs.edge_dt[1, H - 1, W - 1]) == 5.0  # padded with the largest distance: no edge there


def test_map_dtypes_roundtrip():
    rig = simple_rig(V=1)
    rng = np.random.default_rng(0)
    p = rng.random((1, H, W)).astype(np.float32)
    dt = rng.uniform(0, 300, (1, H, W)).astype(np.float32)
    depth = rng.uniform(0, 5, (1, H, W)).astype(np.float32)
    o8 = make_observation(rig, skin=p, edge_dt=dt, depth=depth, dtype="uint8")
    assert o8.skin.dtype == jnp.uint8 and o8.edge_dt.dtype == jnp.uint8 and o8.depth.dtype == jnp.float32
    np.testing.assert_allclose(as_float(o8.skin), p, atol=0.5 / 255 + 1e-7)
    np.testing.assert_allclose(as_float(o8.edge_dt, unit=False), np.minimum(np.rint(dt), 255))
    o16 = make_observation(rig, skin=p, dtype="float16")
    assert o16.skin.dtype == jnp.float16
    np.testing.assert_allclose(as_float(o16.skin), p, atol=1e-3)
    # uint8 inputs of unit maps are read as round(255 p)
    of = make_observation(rig, foreground=(p * 255).astype(np.uint8))
    np.testing.assert_allclose(of.foreground, np.floor(p * 255) / 255, atol=1e-6)


def test_one_compilation_serves_every_frame():
    rig = simple_rig()
    traces = []

    @jax.jit
    def score(obs):
        traces.append(1)
        return jnp.sum(as_float(obs.foreground)) + jnp.sum(obs.edge_dt) + jnp.sum(obs.blob_conf)

    rng = np.random.default_rng(1)
    for _ in range(3):
        obs = make_observation(
            rig,
            foreground=rng.integers(0, 256, (2, H, W)).astype(np.uint8),
            edge_dt=rng.random((2, H, W)),
            blobs3d=rng.random((int(rng.integers(0, 4)), 3)),
            dtype="uint8",
        )
        score(obs).block_until_ready()
    assert len(traces) == 1


def _scene(rng, t, bg):
    img = bg.astype(np.float64).copy()
    cv2.rectangle(img, (30 + 5 * t, 40), (70 + 5 * t, 100), (40, 200, 240), -1)
    return np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("dtype,factor", [("float32", 1), ("uint8", 2), ("float16", 4)])
def test_feature_extractor_end_to_end(dtype, factor):
    rig = simple_rig()
    rng = np.random.default_rng(2)
    yy, xx = np.mgrid[0:H, 0:W]
    bg = np.stack([100 + 40 * np.sin(xx / 7.0), 120 + 30 * np.cos(yy / 5.0), 90 + 0 * xx], -1)
    config = FeatureConfig(dtype=dtype, downsample=factor, rgb=True, dt_truncate=40.0)
    fx = FeatureExtractor(rig, config)
    fx.set_background([np.clip(bg, 0, 255).astype(np.uint8)] * 2)
    obs = fx([_scene(rng, 0, bg), _scene(rng, 1, bg)])
    h, w = fx.rig.image_size[0][::-1]
    assert (h, w) == (round(H / factor), round(W / factor))
    assert obs.foreground.shape == obs.edges.shape == obs.edge_dt.shape == obs.skin.shape == (2, h, w)
    assert obs.rgb.shape == (2, h, w, 3) and not obs.has("depth")
    assert obs.foreground.dtype == jnp.dtype(dtype) and obs.edges.dtype == jnp.dtype(dtype)
    # the foreground covers the rectangle (scaled to the map), and edges lie only near it
    fg = np.asarray(as_float(obs.foreground[0])) > 0.5
    r = (slice(40 // factor + 1, 100 // factor), slice(30 // factor + 1, 70 // factor))
    assert fg[r].mean() > 0.95 and fg.mean() < 0.3
    assert float(as_float(obs.edge_dt, unit=False).max()) <= 40.0
    assert float(as_float(obs.edges).max()) > 0.5
    with pytest.raises(MocapInputError, match="calibration says"):
        fx([np.zeros((H, W + 1, 3), np.uint8)] * 2)
    with pytest.raises(MocapInputError, match="1 views given"):
        fx([np.zeros((H, W, 3), np.uint8)])


def test_feature_extractor_needs_a_background():
    fx = FeatureExtractor(simple_rig(), FeatureConfig(foreground="static"))
    with pytest.raises(MocapInputError, match="set_background"):
        fx([np.zeros((H, W, 3), np.uint8)] * 2)
    fx = FeatureExtractor(simple_rig(), FeatureConfig(foreground="none", skin=None, edge_dt=False))
    obs = fx([np.zeros((H, W, 3), np.uint8)] * 2)
    assert not obs.has("foreground") and not obs.has("skin") and not obs.has("edge_dt") and obs.has("edges")


def test_feature_extractor_with_depth_foreground():
    rig = simple_rig()
    bg = np.full((H, W), 3.0, np.float32)
    d = bg.copy()
    d[30:90, 50:100] = 1.8  # a person in front of the wall
    fx = FeatureExtractor(rig, FeatureConfig(foreground="depth", skin=None, downsample=2))
    fx.set_background_depth([bg, bg])
    frames = [np.full((H, W, 3), 90, np.uint8)] * 2
    obs = fx(frames, depth=[d, bg])
    fg = np.asarray(obs.foreground)
    assert obs.depth.shape == fg.shape == (2, H // 2, W // 2)
    # the 30×25 block, dilated by the 3×3 square of fg_dilate
    assert fg[0, 15:45, 25:50].min() == 1.0 and fg[0].sum() == 32 * 27 and fg[1].sum() == 0
    np.testing.assert_allclose(obs.depth[0, 20, 30], 1.8)
    with pytest.raises(MocapInputError, match="needs depth maps"):
        fx(frames)


def test_rgb_float_and_roi_histograms():
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (40, 50, 3)).astype(np.uint8)
    np.testing.assert_allclose(rgb_float(img), img[..., ::-1] / 255.0, atol=1e-7)
    rois = [(0, 0, 25, 40), (25, 0, 25, 40), np.ones((40, 50), bool)]
    for space, n in (("rgb", 512), ("hs", 64), ("rg", 64)):
        h = roi_histograms(img, rois, bins=8, space=space)
        assert h.shape == (3, n)
        np.testing.assert_allclose(h.sum(axis=1), 1.0)
    # the RGB histogram of a box equals OpenCV's calcHist of that box, normalised
    h = roi_histograms(img, rois[:1], bins=8)[0]
    ref = cv2.calcHist([img[:40, :25]], [2], None, [8], [0, 256]).ravel()  # marginal over R
    np.testing.assert_allclose(h.reshape(8, 8, 8).sum(axis=(1, 2)), ref / ref.sum())
    # chromaticity histograms ignore a brightness change (exact halving), RGB histograms do not
    bright = (img // 2) * 2
    dark = img // 2
    for space, same in (("rg", True), ("rgb", False)):
        d = bhattacharyya_distance(
            roi_histograms(bright, rois, space=space), roi_histograms(dark, rois, space=space)
        )
        assert np.all(d == 0.0) if same else np.all(d > 0.5)
    assert roi_histograms(img, [(0, 0, 0, 0)])[0].sum() == 0.0


def test_bhattacharyya_distance_matches_opencv():
    rng = np.random.default_rng(4)
    for _ in range(5):
        p = rng.random(64)
        q = rng.random(64)
        p /= p.sum()
        q /= q.sum()
        ref = cv2.compareHist(p.astype(np.float32), q.astype(np.float32), cv2.HISTCMP_BHATTACHARYYA)
        assert bhattacharyya_distance(p, q) == pytest.approx(ref, abs=1e-5)
    e = np.eye(4)
    assert bhattacharyya_distance(e[0], e[0]) == 0.0 and bhattacharyya_distance(e[0], e[1]) == 1.0


@pytest.mark.parametrize("kind", ["bool", "unit", "uint8"])
@pytest.mark.parametrize("dtype", ["uint8", "float32", "float16"])
def test_host_masks_are_the_observation_map_thresholded(kind, dtype):
    """The tracker's host masks (:func:`jaxmocap.tracking.features.host_masks`, computed without reading the map
    back from the device) equal the observation's stacked, encoded foreground map read back and thresholded at
    one half: views of different sizes padded with background; bool, [0, 1] and uint8 ``round(255 p)`` maps
    (values kept 0.01 away from one half, where a float16 or uint8 encoding may round across it)."""
    from jaxmocap.tracking.features import host_masks

    sizes = ((W, H), (W - 10, H - 4), (W, H - 2))
    rig = simple_rig(V=3, sizes=sizes)
    rng = np.random.default_rng(7)
    views = []
    for w, h in sizes:
        p = rng.random((h, w))
        p = np.where(np.abs(p - 0.5) < 0.01, 0.2, p)
        views.append(
            {"bool": p > 0.5, "unit": p.astype(np.float32), "uint8": np.rint(p * 255).astype(np.uint8)}[kind]
        )
    obs = make_observation(rig, foreground=views, dtype=dtype)
    fg = np.asarray(obs.foreground)
    read_back = fg >= (128 if fg.dtype == np.uint8 else 0.5)
    masks = host_masks(views, obs.foreground.shape)
    assert masks.dtype == bool and masks.shape == (3, H, W)
    np.testing.assert_array_equal(masks, read_back)
    assert masks[1, H - 4 :].sum() == 0 and masks[1, :, W - 10 :].sum() == 0  # the padding is background
    assert 0.4 < masks[0].mean() < 0.6
