"""Stereo depth: rectification (``cv2.stereoRectify``), semi-global block matching (``cv2.StereoSGBM``),
disparity → depth, and the depth map resampled into the original (unrectified) left camera.

For a rectified pair with focal length ``f`` (pixels) and baseline ``B`` (metres) the depth of a pixel with
disparity ``d = u_left − u_right > 0`` is ``Z = f B / d`` along the rectified optical axis.
"""

from __future__ import annotations

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.features.blobs import relative_pose
from jaxmocap.features.edges import luminance


def sgbm_matcher(
    num_disparities: int = 64,
    block_size: int = 5,
    min_disparity: int = 0,
    channels: int = 1,
    uniqueness_ratio: int = 10,
    speckle_window: int = 100,
    speckle_range: int = 2,
    disp12_max_diff: int = 1,
    mode: int = cv2.STEREO_SGBM_MODE_SGBM_3WAY,
):
    """``cv2.StereoSGBM`` with the usual smoothness penalties ``P1 = 8·c·b²``, ``P2 = 32·c·b²`` (``c`` channels,
    ``b`` block size). ``num_disparities`` is rounded up to a multiple of 16."""
    num_disparities = int(16 * int(np.ceil(num_disparities / 16)))
    return cv2.StereoSGBM_create(
        minDisparity=min_disparity,
        numDisparities=num_disparities,
        blockSize=block_size,
        P1=8 * channels * block_size**2,
        P2=32 * channels * block_size**2,
        disp12MaxDiff=disp12_max_diff,
        uniquenessRatio=uniqueness_ratio,
        speckleWindowSize=speckle_window,
        speckleRange=speckle_range,
        mode=mode,
    )


def sgbm_disparity(left: np.ndarray, right: np.ndarray, matcher=None, **kwargs) -> np.ndarray:
    """Disparity of a rectified pair (left view's pixels), ``(H, W)`` float32 in pixels; NaN where SGBM found
    none. ``left``/``right``: BGR or grey ``uint8``; they are matched on luminance. ``kwargs`` go to
    ``sgbm_matcher`` when no ``matcher`` is given."""
    if np.shape(left) != np.shape(right):
        raise MocapInputError(None, f"stereo images differ in shape: {np.shape(left)} vs {np.shape(right)}")
    matcher = sgbm_matcher(**kwargs) if matcher is None else matcher
    raw = matcher.compute(luminance(left), luminance(right))  # int16, 1/16 pixel
    disp = raw.astype(np.float32) * np.float32(1.0 / 16.0)
    disp[raw < (matcher.getMinDisparity() * 16)] = np.nan
    return disp


def disparity_to_depth(disparity: np.ndarray, focal_px: float, baseline_m: float) -> np.ndarray:
    """``Z = f B / d`` (metres) where ``d > 0``; 0 (no measurement) elsewhere and where ``d`` is NaN."""
    d = np.asarray(disparity, np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(d > 0, np.float32(focal_px * baseline_m) / d, np.float32(0.0))
    return np.nan_to_num(z, nan=0.0).astype(np.float32)


def bad_pixel_rate(
    disparity: np.ndarray, ground_truth: np.ndarray, threshold: float = 1.0
) -> tuple[float, float]:
    """Middlebury error measure: fraction of pixels with known ground truth (``gt > 0``) whose estimate is off by
    more than ``threshold`` pixels, counting pixels without an estimate (NaN) as bad; also returns the density
    (fraction of known pixels that have an estimate)."""
    gt = np.asarray(ground_truth, np.float64)
    d = np.asarray(disparity, np.float64)
    known = gt > 0
    valid = known & np.isfinite(d)
    bad = known & ~(valid & (np.abs(np.where(valid, d, 0.0) - gt) <= threshold))
    n = max(int(known.sum()), 1)
    return float(bad.sum()) / n, float(valid.sum()) / n


class StereoDepth:
    """Depth in the left camera of a calibrated pair of a ``Rig``.

    On construction: relative pose ``R = R_r R_lᵀ``, ``T = t_r − R t_l``; ``cv2.stereoRectify`` (zero disparity at
    infinity, ``alpha``) gives rectifying rotations ``R1, R2`` and projections ``P1, P2``; the rectification maps
    of both views; and, for every pixel of the original left image, its position in the rectified left image
    (``cv2.undistortPoints`` with ``R1, P1``) and the factor ``c = R1[:, 2] · ((u_r − cx)/f, (v_r − cy)/f, 1)``
    that converts a rectified depth ``Z_r`` to the depth ``z = c Z_r`` along the original left optical axis.

    ``depth(left, right)``: rectify, ``sgbm_disparity``, ``Z_r = f B / d``, sampled (nearest) at each original left
    pixel → ``(H, W)`` float32 metres, 0 = none. The pair must be side by side with ``left`` on the left.

    ``alpha = 1`` (default) keeps every source pixel inside the rectified image, so that every pixel of the
    original left image can receive a depth; ``alpha = 0`` zooms in on the valid region (finer disparities, but
    the image borders get no depth).
    """

    def __init__(self, rig, left: int = 0, right: int = 1, alpha: float = 1.0, **sgbm_kwargs):
        K = np.asarray(rig.K, np.float64)
        dist = np.asarray(rig.dist, np.float64)
        Rw = np.asarray(rig.R, np.float64)
        tw = np.asarray(rig.t, np.float64)
        sizes = [tuple(int(v) for v in s) for s in rig.image_size]
        if sizes[left] == (0, 0):
            raise MocapInputError(None, f"stereo view {left} has no image size in the calibration")
        if sizes[left] != sizes[right]:
            raise MocapInputError(
                None, f"stereo views {left} and {right} differ in size: {sizes[left]} vs {sizes[right]}"
            )
        self.size = sizes[left]  # (w, h)
        R, T = relative_pose(Rw[left], tw[left], Rw[right], tw[right])
        R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
            K[left],
            dist[left],
            K[right],
            dist[right],
            self.size,
            R,
            T,
            flags=cv2.CALIB_ZERO_DISPARITY,
            alpha=alpha,
        )
        if abs(P2[1, 3]) > abs(P2[0, 3]):
            raise MocapInputError(
                None, f"views {left} and {right} are one above the other; only side-by-side pairs"
            )
        if P2[0, 3] >= 0:
            raise MocapInputError(
                None, f"view {left} is to the right of view {right}: swap left and right for StereoDepth"
            )
        self.R1, self.P1, self.P2 = R1, P1, P2
        self.focal = float(P1[0, 0])
        self.baseline = float(-P2[0, 3] / P2[0, 0])
        w, h = self.size
        self.maps_left = cv2.initUndistortRectifyMap(K[left], dist[left], R1, P1, self.size, cv2.CV_16SC2)
        self.maps_right = cv2.initUndistortRectifyMap(K[right], dist[right], R2, P2, self.size, cv2.CV_16SC2)
        grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), -1)
        rect = cv2.undistortPoints(grid.reshape(-1, 1, 2), K[left], dist[left], R=R1, P=P1).reshape(h, w, 2)
        self.back_map = rect.astype(np.float32)
        f, cx, cy = P1[0, 0], P1[0, 2], P1[1, 2]
        ray = np.stack([(rect[..., 0] - cx) / f, (rect[..., 1] - cy) / f, np.ones((h, w))], -1)
        self.depth_factor = (ray @ R1[:, 2]).astype(np.float32)
        self.matcher = sgbm_matcher(**sgbm_kwargs)

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        for name, img in (("left", left), ("right", right)):
            if (img.shape[1], img.shape[0]) != self.size:
                raise MocapInputError(
                    None, f"{name} image is {img.shape[1]}x{img.shape[0]}, calibration {self.size}"
                )
        return (
            cv2.remap(left, *self.maps_left, cv2.INTER_LINEAR),
            cv2.remap(right, *self.maps_right, cv2.INTER_LINEAR),
        )

    def disparity(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """Disparity in the rectified left image (NaN = none)."""
        return sgbm_disparity(*self.rectify(left, right), matcher=self.matcher)

    def depth(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """Depth (metres, 0 = none) at each pixel of the original left image."""
        z_rect = disparity_to_depth(self.disparity(left, right), self.focal, self.baseline)
        z = cv2.remap(
            z_rect,
            self.back_map[..., 0],
            self.back_map[..., 1],
            cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        )
        return z * self.depth_factor
