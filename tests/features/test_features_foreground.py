"""Foreground segmentation on a constructed sequence: a real photo background (Pose2Sim lab, see
tests/data/features/PROVENANCE.md) with a pasted moving textured ellipse, sensor noise, a cast shadow and a global
illumination change; closed forms of the adaptive Gaussian (López Méndez eq. 4.1–4.2)."""

import pathlib

import cv2
import numpy as np
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.features.foreground import (
    DepthBackground,
    GaussianBackground,
    Mog2Background,
    ShadowParams,
    StaticBackground,
    brightness_chromaticity_distortion,
    depth_foreground,
    shadow_mask,
    without_shadows,
)

NOISE = 3.0
DATA = pathlib.Path(__file__).parents[1] / "data" / "features"


@pytest.fixture(scope="module")
def scene():
    bg = cv2.imread(str(DATA / "background_cam03_ext_crop.png"))
    assert bg is not None and bg.shape == (320, 320, 3)
    return Scene(bg)


class Scene:
    def __init__(self, bg):
        self.bg = bg
        H, W = bg.shape[:2]
        self.yy, self.xx = np.mgrid[0:H, 0:W]
        xx, yy = self.xx, self.yy
        self.texture = np.stack(
            [60 + 20 * np.sin(xx / 3.0), 80 + 20 * np.cos(yy / 4.0), 200 + 30 * np.sin((xx + yy) / 5.0)], -1
        )

    def shape_mask(self, t):
        cx, cy = 70 + 10 * t, 160 + 2 * t
        return ((self.xx - cx) / 32.0) ** 2 + ((self.yy - cy) / 48.0) ** 2 <= 1

    def shadow_region(self, t):
        cx, cy = 80 + 10 * t, 220 + 2 * t
        return (((self.xx - cx) / 50.0) ** 2 + ((self.yy - cy) / 25.0) ** 2 <= 1) & ~self.shape_mask(t)

    def frame(self, rng, t=None, gain=1.0, shadow=None):
        f = self.bg.astype(np.float64)
        if shadow is not None:
            f[shadow] *= 0.6
        m = np.zeros(self.bg.shape[:2], bool) if t is None else self.shape_mask(t)
        f[m] = self.texture[m]
        f = f * gain + rng.normal(0.0, NOISE, f.shape)
        return np.clip(np.rint(f), 0, 255).astype(np.uint8), m


def iou(mask, truth):
    a, b = mask > 0, truth > 0
    return (a & b).sum() / (a | b).sum()


def test_static_background_iou(scene):
    rng = np.random.default_rng(0)
    model = StaticBackground.from_frames(np.array([scene.frame(rng)[0] for _ in range(5)]))
    for t in range(0, 20, 4):
        f, m = scene.frame(rng, t)
        assert iou(model.update(f), m) >= 0.9
    # the raw per-channel test is exactly |I_c − B_c| > T_c in any channel
    f, _ = scene.frame(rng, 3)
    ref = np.any(np.abs(f.astype(int) - model.background.astype(int)) > 30, axis=2)
    np.testing.assert_array_equal(model.raw_mask(f) > 0, ref)


def test_shadow_removal_lowers_false_positives(scene):
    rng = np.random.default_rng(1)
    empties = np.array([scene.frame(rng)[0] for _ in range(5)])
    plain = StaticBackground.from_frames(empties)
    with_shadow = StaticBackground.from_frames(empties, shadow=ShadowParams())
    t = 8
    sh = scene.shadow_region(t)
    f, m = scene.frame(rng, t, shadow=sh)
    near = cv2.dilate(m.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    fp_plain = int(((plain.update(f) > 0) & ~near).sum())
    mask = with_shadow.update(f)
    fp_shadow = int(((mask > 0) & ~near).sum())
    # the darkened region is mostly flagged without shadow removal, and almost none of it with it
    assert fp_plain > 0.5 * sh.sum()
    assert fp_shadow <= 0.02 * fp_plain
    assert iou(mask, m) >= 0.9


def test_global_darkening_is_shadow_like(scene):
    rng = np.random.default_rng(2)
    empties = np.array([scene.frame(rng)[0] for _ in range(5)])
    plain = StaticBackground.from_frames(empties)
    with_shadow = StaticBackground.from_frames(empties, shadow=ShadowParams())
    f, m = scene.frame(rng, 6, gain=0.8)
    assert iou(plain.update(f), m) < 0.5  # a static threshold alone breaks under the illumination change
    assert iou(with_shadow.update(f), m) >= 0.9


def test_shadows_removed_at_the_masked_pixels_only_are_the_whole_frame_test(scene):
    """:func:`without_shadows` (the distortions at the masked pixels only) equals the mask and the complement of
    the whole frame's :func:`shadow_mask`, bit for bit: a scalar noise (the plate background's) and a per-pixel
    σ (the Gaussian background's), a cast shadow and a global darkening; an empty mask stays empty."""
    rng = np.random.default_rng(4)
    empties = np.array([scene.frame(rng)[0] for _ in range(5)])
    static = StaticBackground.from_frames(empties, shadow=ShadowParams())
    params = ShadowParams()
    std = rng.uniform(1.0, 6.0, scene.bg.shape).astype(np.float32)
    frames = [
        scene.frame(rng, 8, shadow=scene.shadow_region(8))[0],
        scene.frame(rng, 3, gain=0.8)[0],
        scene.frame(rng)[0],
    ]
    removed = 0
    for f in frames:
        raw = static.raw_mask(f)
        for mean, sigma, frame in (
            (static.background, static.noise_std, f),
            (static.background.astype(np.float32), std, f.astype(np.float32)),
        ):
            want = cv2.bitwise_and(raw, cv2.bitwise_not(shadow_mask(frame, mean, sigma, params)))
            got = without_shadows(raw, frame, mean, sigma, params)
            np.testing.assert_array_equal(got, want)
            removed += int(np.count_nonzero(raw) - np.count_nonzero(got))
    assert removed > 1000  # the shadows were there to remove
    empty = np.zeros(scene.bg.shape[:2], np.uint8)
    assert not without_shadows(empty, frames[0], static.background, 4.0, params).any()


def test_brightness_and_chromaticity_distortion_closed_form():
    rng = np.random.default_rng(3)
    mu = rng.uniform(20, 230, (8, 9, 3))
    std = rng.uniform(1, 5, (8, 9, 3))
    alpha, cd = brightness_chromaticity_distortion(0.7 * mu, mu, std)
    np.testing.assert_allclose(alpha, 0.7, rtol=1e-5)
    np.testing.assert_allclose(cd, 0.0, atol=1e-3)
    # a pure chromatic offset orthogonal (in σ-scaled space) to μ keeps α = 1 and has CD = its σ-norm
    m = mu / std
    v = rng.normal(size=mu.shape)
    v -= (np.sum(v * m, -1, keepdims=True) / np.sum(m * m, -1, keepdims=True)) * m
    alpha, cd = brightness_chromaticity_distortion(mu + v * std, mu, std)
    np.testing.assert_allclose(alpha, 1.0, atol=1e-4)
    np.testing.assert_allclose(cd, np.linalg.norm(v, axis=-1), rtol=1e-4)


def test_gaussian_mean_and_variance_follow_the_closed_form():
    # Constant frames B1 after a model initialised on B0: μ_n = B1 + (1−ρ)^n (B0 − B1) and, with Δ = B1 − B0,
    # σ²_n = (1−ρ)^n [σ²_0 + Δ² (1−ρ) (1 − (1−ρ)^n)]  (eq. 4.1–4.2 unrolled).
    rho, s0 = 0.1, 10.0
    b0 = np.full((4, 5, 3), 100.0, np.float32)
    b1 = b0 + np.array([30.0, -20.0, 5.0], np.float32)
    model = GaussianBackground(rho=rho, init_std=s0)
    model.initialise(b0)
    for n in range(1, 41):
        model.update(b1)
        a = (1 - rho) ** n
        np.testing.assert_allclose(model.mean, b1 + a * (b0 - b1), rtol=1e-5)
        var = a * (s0**2 + (b1 - b0) ** 2 * (1 - rho) * (1 - a))
        np.testing.assert_allclose(model.var, var, rtol=1e-4)
        np.testing.assert_allclose(model.std, np.maximum(np.sqrt(var), model.min_std), rtol=1e-4)


def test_gaussian_variance_converges_to_the_noise_level():
    # Stationary noise of variance s²: E[σ²_∞] = s² · 2(1−ρ)²/(2−ρ) (μ_t in eq. 4.2 already includes I_t).
    rho, s = 0.05, 5.0
    rng = np.random.default_rng(4)
    B = rng.uniform(50, 200, (60, 60, 3)).astype(np.float32)
    model = GaussianBackground(rho=rho, init_std=20.0)
    model.initialise(B)
    for _ in range(400):  # (1−ρ)^400 ≈ 1e-9: the initial state is forgotten
        model.learn(B + rng.normal(0.0, s, B.shape).astype(np.float32))
    expected = s**2 * 2 * (1 - rho) ** 2 / (2 - rho)
    v = model.var.ravel()
    tol = 5 * v.std() / np.sqrt(v.size)  # pixels are independent: 5 standard errors
    assert abs(v.mean() - expected) < tol
    assert abs(np.mean(model.mean - B)) < 5 * s * np.sqrt(rho / (2 - rho)) / np.sqrt(v.size)


def test_gaussian_background_tracks_a_moving_shape_and_adapts_to_illumination(scene):
    rng = np.random.default_rng(5)
    model = GaussianBackground()
    for _ in range(5):
        model.update(scene.frame(rng)[0])
    for t in range(20):
        f, m = scene.frame(rng, t)
        mask = model.update(f)
        assert iou(mask, m) >= 0.9
    fp = [float((model.update(scene.frame(rng, gain=0.8)[0]) > 0).mean()) for _ in range(40)]
    assert fp[0] > 0.3  # the lights went down: most of the image differs at first
    assert max(fp[-10:]) < 0.01  # and the model has converged to the new background


def test_mog2_segments_the_moving_shape(scene):
    rng = np.random.default_rng(6)
    model = Mog2Background()
    for _ in range(30):
        model.update(scene.frame(rng)[0])
    for t in range(0, 20, 4):
        f, m = scene.frame(rng, t)
        assert iou(model.update(f), m) >= 0.9


def test_depth_foreground_closed_form():
    bg = np.full((40, 50), 3.0, np.float32)
    bg[:, :5] = 0.0  # unknown background depth
    d = bg.copy()
    d[10:20, 10:30] = 2.0  # a person 1 m in front of the wall
    d[25:30, 10:30] = 2.95  # within the margin: background
    d[:, 40:] = 0.0  # no measurement
    d[:, :5] = 4.0  # measured where the background is unknown: foreground
    ref = np.zeros((40, 50), bool)
    ref[10:20, 10:30] = True
    ref[:, :5] = True
    np.testing.assert_array_equal(depth_foreground(d, bg, margin=0.1) > 0, ref)
    np.testing.assert_array_equal(depth_foreground(d, bg, margin=0.1, max_depth=3.5) > 0, ref & (d < 3.5))
    model = DepthBackground.from_frames([bg, bg, np.zeros_like(bg)], margin=0.1, dilate_size=1)
    np.testing.assert_array_equal(model.background_depth, bg)
    np.testing.assert_array_equal(model.update(d) > 0, ref)
    with pytest.raises(MocapInputError):
        depth_foreground(d[:10], bg)


def test_bad_frames_raise():
    model = StaticBackground(np.zeros((10, 12, 3), np.uint8))
    with pytest.raises(MocapInputError, match="differs from the background"):
        model.update(np.zeros((10, 13, 3), np.uint8))
    with pytest.raises(MocapInputError, match="colour image"):
        model.update(np.zeros((10, 12), np.uint8))
