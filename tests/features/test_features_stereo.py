"""Stereo: fundamental matrix, skin-blob matching and triangulation on a synthetic calibrated pair, SGBM on the
Middlebury Aloe pair against its ground truth, rectified depth of a rendered textured plane and the half-size range and height gate on it, down-sampling."""

import pathlib

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.features.blobs import (
    epipolar_distance,
    fundamental_from_rig,
    skin_blobs,
    stereo_blobs,
    triangulate_pair,
)
from jaxmocap.features.disparity import StereoGate
from jaxmocap.features.pipeline import FeatureConfig, FeatureExtractor
from jaxmocap.features.resample import downsample, scale_rig
from jaxmocap.features.skin import default_skin_model
from jaxmocap.features.stereo import StereoDepth, bad_pixel_rate, disparity_to_depth, sgbm_disparity
from jaxmocap.geometry.camera import Rig

DATA = pathlib.Path(__file__).parents[1] / "data" / "features"
W, H = 640, 480


def look_rotation(forward, up=(0.0, 0.0, 1.0)):
    """World→camera rotation of a camera looking along ``forward`` (camera x right, y down, z forward)."""
    z = np.asarray(forward, float) / np.linalg.norm(forward)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def make_rig(centres, targets, dist=None, f=600.0):
    R = np.stack([look_rotation(np.subtract(tg, c)) for c, tg in zip(centres, targets, strict=True)])
    C = np.asarray(centres, float)
    t = -np.einsum("vij,vj->vi", R, C)
    V = len(C)
    K = np.tile(np.array([[f, 0.0, 319.5], [0.0, f, 239.5], [0.0, 0.0, 1.0]]), (V, 1, 1))
    K[1, 0, 2] += 3.0  # slightly different principal points
    dist = np.zeros((V, 5)) if dist is None else np.asarray(dist, float)
    return Rig(K=K, dist=dist, R=R, t=t, names=tuple(f"c{v}" for v in range(V)), image_size=((W, H),) * V)


def project(rig, v, X):
    rvec, _ = cv2.Rodrigues(np.asarray(rig.R[v]))
    uv, _ = cv2.projectPoints(np.asarray(X, float), rvec, np.asarray(rig.t[v], float), rig.K[v], rig.dist[v])
    return uv.reshape(-1, 2)


@pytest.fixture(scope="module")
def pair_rig():
    # two cameras 0.3 m apart, 3 m from the person, converging slightly; mild barrel distortion
    dist = [[-0.08, 0.02, 0.0005, -0.0003, 0.0], [-0.05, 0.01, 0.0, 0.0004, 0.0]]
    return make_rig([(-0.15, -3.0, 1.3), (0.15, -3.0, 1.35)], [(0.0, 0.0, 1.3), (0.05, 0.0, 1.3)], dist)


def test_fundamental_matrix_satisfies_the_epipolar_constraint(pair_rig):
    nodist = Rig(pair_rig.K, np.zeros((2, 5)), pair_rig.R, pair_rig.t, pair_rig.names, pair_rig.image_size)
    rng = np.random.default_rng(0)
    X = rng.uniform((-1, -0.5, 0.3), (1, 1, 2.2), (50, 3))
    x1, x2 = project(nodist, 0, X), project(nodist, 1, X)
    F = fundamental_from_rig(nodist, 0, 1)
    d = epipolar_distance(F, x1, x2)
    assert np.max(np.diag(d)) < 1e-6
    off = d[~np.eye(50, dtype=bool)]
    assert np.median(off) > 5.0  # the distance discriminates non-corresponding points
    # same matrix (up to scale and sign) as OpenCV's 8-point estimate from the exact correspondences
    F_cv, _ = cv2.findFundamentalMat(x1, x2, cv2.FM_8POINT)
    F_cv /= np.linalg.norm(F_cv)
    assert min(np.linalg.norm(F - F_cv), np.linalg.norm(F + F_cv)) < 1e-4


def _skin_colour(model):
    """Centre of the RGB bin with the most skin samples, as BGR (a colour the model calls skin)."""
    r, g, b = np.unravel_index(np.argmax(model.rgb_skin), model.rgb_skin.shape)
    return (int(b) * 32 + 16, int(g) * 32 + 16, int(r) * 32 + 16)


TRUTH = np.array([[0.0, 0.1, 1.75], [-0.45, -0.2, 1.1], [0.4, 0.15, 1.25]])  # head, hands (metres)


def blob_images(rig, model, seed=1):
    """Skin-coloured discs at the projections of ``TRUTH`` (radii 10 / 5 / 5 cm) on a dark blue background with
    noise, plus a distractor disc seen by camera 0 only."""
    colour = _skin_colour(model)
    radius_m = np.array([0.1, 0.05, 0.05])
    rng = np.random.default_rng(seed)
    images = []
    for v in range(2):
        img = np.full((H, W, 3), (120, 70, 40), np.float64)  # dark blue (BGR)
        uv = project(rig, v, TRUTH)
        depth = (TRUTH @ rig.R[v].T + rig.t[v])[:, 2]
        for (u, w), r in zip(uv, 600.0 * radius_m / depth, strict=True):
            cv2.circle(
                img, (int(round(u * 16)), int(round(w * 16))), int(round(r * 16)), colour, -1, cv2.LINE_AA, 4
            )
        if v == 0:  # off every epipolar line of the true blobs
            cv2.circle(img, (560, 60), 12, colour, -1)
        images.append(np.clip(img + rng.normal(0.0, 3.0, img.shape), 0, 255).astype(np.uint8))
    return images


def test_blob_matching_and_triangulation(pair_rig):
    model = default_skin_model()
    images = blob_images(pair_rig, model)
    blobs = [skin_blobs(model.probability(img), max_blobs=4) for img in images]
    assert [len(b.areas) for b in blobs] == [4, 3]
    points, conf, matches = stereo_blobs(pair_rig, blobs, max_blobs=4)
    assert len(matches) == 3 and conf[3] == 0.0 and np.all(points[3] == 0.0)
    assert np.all(conf[:3] > 0.5)
    err = np.linalg.norm(points[:3, None] - TRUTH[None], axis=-1).min(axis=1)
    assert np.max(err) < 0.01, err  # metres, at 3 m with a 0.3 m baseline


def test_pipeline_with_blobs_and_stereo_depth(pair_rig):
    model = default_skin_model()
    config = FeatureConfig(foreground="none", blobs=True, stereo_depth=True, max_blobs=4)
    obs = FeatureExtractor(pair_rig, config, skin_model=model)(blob_images(pair_rig, model))
    assert obs.blobs3d.shape == (4, 3) and obs.depth.shape == (2, H, W) and obs.has("depth")
    assert float(jnp.max(jnp.abs(obs.depth[1]))) == 0.0  # depth lives in the left view only
    conf = np.asarray(obs.blob_conf)
    assert np.sum(conf > 0) == 3
    err = np.linalg.norm(np.asarray(obs.blobs3d)[conf > 0][:, None] - TRUTH[None], axis=-1).min(axis=1)
    assert np.max(err) < 0.01


def test_skin_blobs_are_the_largest_components():
    skin = np.zeros((200, 300), np.float32)
    discs = [((50, 60), 20), ((200, 50), 12), ((150, 150), 30), ((260, 170), 3)]  # (centre (u, v), radius)
    for (u, v), r in discs:
        cv2.circle(skin, (u, v), r, 0.9, -1)
    b = skin_blobs(skin, threshold=0.5, max_blobs=3, min_area=20, with_labels=True)
    np.testing.assert_allclose(b.centroids, [[150, 150], [50, 60], [200, 50]], atol=1e-9)  # largest first
    np.testing.assert_allclose(b.areas, np.pi * np.array([30, 20, 12]) ** 2, rtol=0.05)
    assert set(np.unique(b.labels)) == {0, 1, 2, 3} and b.labels[150, 150] == 1 and b.labels[170, 260] == 0
    assert len(skin_blobs(skin, threshold=0.95).areas) == 0
    u8 = skin_blobs((skin * 255).astype(np.uint8), threshold=0.5, max_blobs=5, min_area=1, open_size=1)
    assert len(u8.areas) == 4 and u8.labels is None


def test_triangulate_pair_recovers_projected_points(pair_rig):
    rng = np.random.default_rng(2)
    X = rng.uniform((-1, -0.5, 0.3), (1, 1, 2.2), (20, 3))
    Y = triangulate_pair(pair_rig, 0, 1, project(pair_rig, 0, X), project(pair_rig, 1, X))
    np.testing.assert_allclose(Y, X, atol=1e-6)


def _half(img):
    return cv2.resize(img, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)


def test_sgbm_on_middlebury_aloe():
    """Half-size Aloe; GT 8-bit = full-size disparity (0 = unknown), so half-size GT = value / 2 at even pixels."""
    L = _half(cv2.imread(str(DATA / "aloeL.jpg")))
    R = _half(cv2.imread(str(DATA / "aloeR.jpg")))
    gt = cv2.imread(str(DATA / "aloeGT.png"), cv2.IMREAD_UNCHANGED)[::2, ::2].astype(np.float32) / 2.0
    assert L.shape[:2] == gt.shape == (555, 641)
    d = sgbm_disparity(L, R, min_disparity=16, num_disparities=96, block_size=5)
    known = gt > 0
    est = known & np.isfinite(d)
    err = np.abs(d[est] - gt[est])
    # among estimated pixels (Middlebury bad-pixel rates, thresholds 1 and 2 px); measured 5.0 % and 3.8 %
    assert np.mean(err > 1.0) < 0.08
    assert np.mean(err > 2.0) < 0.06
    # counting missing estimates as bad: SGBM leaves the left min+num disparity columns empty (≈ 17 %)
    bad2, density = bad_pixel_rate(d, gt, 2.0)
    assert density > 0.7 and bad2 < 0.32
    inner = known.copy()
    inner[:, : 16 + 96] = False
    assert np.mean(np.isfinite(d[inner])) > 0.85


def _render_plane(rig, v, texture, origin, e1, e2, metres_per_px):
    """Image of a textured plane through the homography K [R e1 s, R e2 s, R o + t] (texture px → image px)."""
    R, t, K = rig.R[v], rig.t[v], rig.K[v]
    Hm = K @ np.column_stack([R @ e1 * metres_per_px, R @ e2 * metres_per_px, R @ origin + t])
    return cv2.warpPerspective(texture, Hm, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def _slanted_plane_scene():
    """``(rig, images, n, p0)``: a pair 2.5 m from a randomly textured plane through ``p0`` with normal ``n``."""
    rig = make_rig([(-0.1, -2.5, 1.3), (0.1, -2.5, 1.32)], [(0.0, 0.0, 1.3), (0.03, 0.0, 1.29)])
    rng = np.random.default_rng(3)
    coarse = rng.integers(0, 256, (96, 96, 3)).astype(np.uint8)
    texture = cv2.resize(coarse, (1024, 1024), interpolation=cv2.INTER_CUBIC)
    texture = cv2.add(texture, rng.integers(0, 40, texture.shape).astype(np.uint8))
    n = np.array([0.3, -1.0, 0.15])
    n /= np.linalg.norm(n)
    p0 = np.array([0.0, 0.4, 1.3])
    e1 = np.cross(n, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    s = 5.0 / 1024  # the texture covers 5 m × 5 m
    origin = p0 - 512 * s * (e1 + e2)
    return rig, [_render_plane(rig, v, texture, origin, e1, e2, s) for v in range(2)], n, p0


def test_stereo_depth_of_a_slanted_plane():
    rig, imgs, n, p0 = _slanted_plane_scene()
    sd = StereoDepth(rig, 0, 1, num_disparities=64, block_size=5)
    z = sd.depth(*imgs)
    # ground truth: ray through each left pixel meets the plane
    C = -rig.R[0].T @ rig.t[0]
    uu, vv = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    rays = np.stack([(uu - rig.K[0, 0, 2]) / 600.0, (vv - rig.K[0, 1, 2]) / 600.0, np.ones_like(uu)], -1)
    d_world = rays @ rig.R[0]  # R^T ray, per pixel
    lam = (n @ (p0 - C)) / (d_world @ n)
    z_true = lam  # rays have unit camera-z, so the camera depth equals λ
    ok = z > 0
    rel = np.abs(z[ok] - z_true[ok]) / z_true[ok]
    # measured: density 0.957, median relative error 0.0029, p90 0.0067
    assert ok.mean() > 0.85
    assert np.median(rel) < 0.01 and np.percentile(rel, 90) < 0.03
    assert np.isclose(
        sd.baseline, np.linalg.norm(np.diff([-rig.R[v].T @ rig.t[v] for v in range(2)], axis=0))
    )


def test_stereo_gate_puts_points_on_the_plane_and_keeps_those_in_range_and_height():
    """:class:`StereoGate` at half size on the slanted plane: its world points lie on the plane (distance to it
    against the depth resolution of one half-size pixel of disparity, ``Z² / (f B / 2)`` ≈ 0.1 m at 2.5 m), and
    its gate keeps the share of the first view's pixels whose true plane point (the pixel's ray met with the
    plane) lies within ``max_range`` of the camera and in ``height_range``."""
    rig, imgs, n, p0 = _slanted_plane_scene()
    C = -rig.R[0].T @ rig.t[0]
    max_range, heights = 3.1, (0.8, 1.9)
    gate = StereoGate(rig, (0, 1), 0.5, max_range, heights)
    fr = gate(imgs)
    assert fr.image.shape == (H // 2, W // 2, 3) and fr.points.shape == (H // 2, W // 2, 3)
    valid = np.isfinite(fr.disparity) & (np.nan_to_num(fr.disparity) > 0)
    assert valid.mean() > 0.7  # SGBM leaves the first 64 of 320 columns empty
    off = np.abs((fr.points[valid] - p0) @ n)
    # measured: median 0.012 m, p90 0.026 m
    assert np.median(off) < 0.02 and np.percentile(off, 90) < 0.1
    # each rectified pixel's ray (its rectified camera: P1, R1) met with the plane
    f, cx, cy = gate.P1[0, 0], gate.P1[0, 2], gate.P1[1, 2]
    uu, vv = np.meshgrid(np.arange(W // 2, dtype=float), np.arange(H // 2, dtype=float))
    rays = np.stack([(uu - cx) / f, (vv - cy) / f, np.ones_like(uu)], -1) @ gate.R1 @ rig.R[0]
    X = C + ((n @ (p0 - C)) / (rays @ n))[..., None] * rays
    inside = (
        (np.linalg.norm(X - C, axis=-1) <= max_range) & (X[..., 2] >= heights[0]) & (X[..., 2] <= heights[1])
    )
    assert 0.2 < inside[valid].mean() < 0.8  # the gate cuts the plane (measured: 0.36 inside)
    # measured: the gate agrees with the true points on 0.99 of the valid pixels
    assert np.mean(fr.ok[valid] == inside[valid]) > 0.95
    # a point on the plane agrees with the dense disparity; the same point 0.5 m nearer the camera does not
    Xp = X[120, 200]
    towards = Xp + 0.5 * (C - Xp) / np.linalg.norm(C - Xp)
    assert gate.agrees(fr, np.stack([Xp, towards])).tolist() == [True, False]
    with pytest.raises(ValueError, match="right of the first"):
        StereoGate(rig, (1, 0))


def test_stereo_depth_rejects_swapped_or_mismatched_views(pair_rig):
    with pytest.raises(MocapInputError, match="swap"):
        StereoDepth(pair_rig, 1, 0)
    sd = StereoDepth(pair_rig, 0, 1)
    with pytest.raises(MocapInputError):
        sd.depth(np.zeros((240, 320, 3), np.uint8), np.zeros((240, 320, 3), np.uint8))


def test_disparity_to_depth():
    d = np.array([[8.0, 0.0, np.nan, -1.0]], np.float32)
    np.testing.assert_allclose(disparity_to_depth(d, 500.0, 0.1), [[6.25, 0.0, 0.0, 0.0]])


@pytest.mark.parametrize("factor", [2, 4])
def test_downsampled_frame_matches_the_scaled_rig(pair_rig, factor):
    """A small bright disc drawn at a projected point stays at the projection through the scaled rig."""
    X = np.array([[0.2, 0.3, 1.6]])
    uv = project(pair_rig, 0, X)[0]
    img = np.zeros((H, W), np.float32)
    cv2.circle(img, (int(round(uv[0] * 256)), int(round(uv[1] * 256))), 6 * 256, 1.0, -1, cv2.LINE_AA, 8)
    small = downsample(img, factor)
    small_rig = scale_rig(pair_rig, factor)
    assert small.shape[::-1] == small_rig.image_size[0]
    m = cv2.moments(small)
    centroid = np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])
    np.testing.assert_allclose(centroid, project(small_rig, 0, X)[0], atol=0.05)
    with pytest.raises(ValueError):
        downsample(img, 3)
