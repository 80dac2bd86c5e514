"""Edges and the distance transform I_DT: closed-form distances of known edge patterns, Canny on a drawn
shape, foreground masking, dilation and smoothing."""

import cv2
import numpy as np
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.features.edges import (
    canny_edges,
    distance_transform,
    edge_map,
    mask_edges,
    masked_canny,
    smooth_edges,
)


def test_distance_of_a_vertical_line_is_the_column_offset():
    e = np.zeros((60, 80), np.uint8)
    e[:, 31] = 255
    xx = np.mgrid[0:60, 0:80][1]
    np.testing.assert_array_equal(distance_transform(e), np.abs(xx - 31).astype(np.float32))


def test_distance_of_points_is_euclidean():
    e = np.zeros((60, 80), np.uint8)
    pts = [(17, 23), (40, 70), (59, 0)]
    for y, x in pts:
        e[y, x] = 255
    yy, xx = np.mgrid[0:60, 0:80]
    ref = np.min([np.hypot(yy - y, xx - x) for y, x in pts], axis=0)
    np.testing.assert_allclose(distance_transform(e), ref, rtol=0, atol=1e-4)


def test_distance_of_a_circle_is_radial_offset():
    # Rasterised circle (1-px): the distance to the drawn pixels is |r − R| up to the rasterisation (≤ 1 px).
    e = np.zeros((201, 201), np.uint8)
    cv2.circle(e, (100, 100), 60, 255, 1)
    yy, xx = np.mgrid[0:201, 0:201]
    ref = np.abs(np.hypot(yy - 100, xx - 100) - 60)
    assert np.max(np.abs(distance_transform(e) - ref)) <= 1.0


def test_truncation_and_empty_edge_image():
    e = np.zeros((30, 40), np.uint8)
    e[0, 0] = 255
    dt = distance_transform(e, truncate=10.0)
    yy, xx = np.mgrid[0:30, 0:40]
    np.testing.assert_allclose(dt, np.minimum(np.hypot(yy, xx), 10.0), atol=1e-4)
    empty = np.zeros((30, 40), np.uint8)
    np.testing.assert_array_equal(distance_transform(empty, truncate=7.0), np.full((30, 40), 7.0, np.float32))
    np.testing.assert_allclose(distance_transform(empty), np.hypot(30, 40))
    with pytest.raises(MocapInputError):
        distance_transform(np.zeros((3, 4, 3), np.uint8))


def _circle_image(noise=4.0, seed=0):
    rng = np.random.default_rng(seed)
    img = np.full((200, 240, 3), (90, 110, 70), np.float64)
    cv2.circle(img, (120 * 16, 100 * 16), 50 * 16, (40, 160, 230), -1, lineType=cv2.LINE_AA, shift=4)
    return np.clip(img + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8)


def test_canny_finds_the_boundary_of_a_drawn_disc():
    img = _circle_image()
    E = canny_edges(img)
    ys, xs = np.nonzero(E)
    r = np.hypot(xs - 120, ys - 100)
    assert len(xs) > 250  # circumference ≈ 314 px
    assert np.max(np.abs(r - 50)) <= 1.5  # every edge pixel lies on the boundary (no noise edges)
    # coverage: every boundary point has an edge pixel within 1.5 px
    th = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    dt = distance_transform(E)
    bx = np.rint(120 + 50 * np.cos(th)).astype(int)
    by = np.rint(100 + 50 * np.sin(th)).astype(int)
    assert np.max(dt[by, bx]) <= 1.5


def test_masking_keeps_only_edges_near_the_foreground():
    img = np.full((120, 200, 3), 40, np.uint8)
    cv2.rectangle(img, (20, 30), (60, 90), (200, 200, 200), -1)
    cv2.rectangle(img, (120, 30), (170, 90), (200, 200, 200), -1)
    fg = np.zeros((120, 200), np.uint8)
    fg[30:91, 20:61] = 255  # only the left square is foreground
    E = canny_edges(img)
    kept = mask_edges(E, fg, dilate_size=5)
    assert np.any(E[:, 100:]) and not np.any(kept[:, 100:])
    np.testing.assert_array_equal(kept[:, :100], E[:, :100])
    # distance transform of the masked edges: the right square's outline is ≥ 59 px from any kept edge
    dt = distance_transform(kept)
    assert dt[60, 145] > 59
    # mask dilation: a foreground one pixel short of the outline still keeps it when dilated by 3
    fg_in = np.zeros_like(fg)
    fg_in[32:89, 22:59] = 255
    assert not np.any(mask_edges(E, fg_in, dilate_size=1)[:, 18:20])
    assert np.any(mask_edges(E, fg_in, dilate_size=7)[:, 18:21])


def test_smoothed_edges_are_bounded_peaked_and_local():
    e = np.zeros((41, 41), np.uint8)
    e[:, 20] = 255
    dilate, sigma = 3, 1.0
    s = smooth_edges(e, dilate, sigma)
    row = s[20]
    assert s.dtype == np.float32 and s.min() >= 0 and s.max() <= 1
    assert row[20] == row.max() and row[20] > 0.8
    # symmetric and non-increasing away from the line
    np.testing.assert_allclose(row[:20], row[21:][::-1], atol=1e-6)
    assert np.all(np.diff(row[:21]) >= -1e-7)
    # zero beyond the dilation half-width plus the 3σ kernel support
    reach = dilate // 2 + int(np.ceil(3 * sigma))
    assert np.all(row[: 20 - reach] == 0) and np.all(row[20 + reach + 1 :] == 0)
    # without smoothing, the dilated line is exactly `dilate` pixels wide
    np.testing.assert_array_equal(np.nonzero(smooth_edges(e, 5, 0.0)[20])[0], np.arange(18, 23))


def test_edge_map_pipeline_on_a_drawn_shape():
    img = _circle_image()
    fg = np.zeros(img.shape[:2], np.uint8)
    cv2.circle(fg, (120, 100), 50, 255, -1)
    e01, dt, raw = edge_map(img, fg, mask_dilate=7, truncate=20.0)
    assert e01.shape == dt.shape == raw.shape == img.shape[:2]
    assert dt.max() <= 20.0
    yy, xx = np.mgrid[0:200, 0:240]
    r = np.hypot(xx - 120, yy - 100)
    # I_DT ≈ distance to the circle, up to the 1.5 px edge localisation
    near = r < 70
    assert np.max(np.abs(dt[near] - np.minimum(np.abs(r[near] - 50), 20.0))) <= 1.6
    assert np.all(e01[np.abs(r - 50) > 8] == 0)


def test_cropped_canny_equals_masked_full_image_canny(data_dir):
    img = cv2.imread(str(data_dir / "features" / "background_cam03_ext_crop.png"))  # a real, busy image
    yy, xx = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
    fg = ((((xx - 150) / 40.0) ** 2 + ((yy - 170) / 90.0) ** 2) <= 1).astype(np.uint8) * 255
    full = mask_edges(canny_edges(img), fg, dilate_size=15)
    assert full.sum() > 0
    np.testing.assert_array_equal(masked_canny(img, fg, mask_dilate=15), full)
    assert not np.any(masked_canny(img, np.zeros_like(fg)))


def test_truncated_distance_transform_equals_the_full_one():
    rng = np.random.default_rng(0)
    e = np.zeros((200, 300), np.uint8)
    ys, xs = rng.integers(60, 120, 30), rng.integers(100, 180, 30)
    e[ys, xs] = 255
    full = cv2.distanceTransform(np.where(e > 0, 0, 255).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    for tau in (5.0, 17.5, 400.0):
        np.testing.assert_allclose(distance_transform(e, truncate=tau), np.minimum(full, tau), atol=1e-5)
    np.testing.assert_allclose(distance_transform(e), full)
