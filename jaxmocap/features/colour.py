"""Colour features: float RGB maps (colour templates, Li & Kulić) and per-ROI normalised colour histograms with
the Bhattacharyya distance (Fontmarty et al., IROS 2007). NumPy reference helpers; the colour cue itself runs in
JAX on the ``rgb`` map of an ``Observation``."""

from __future__ import annotations

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError


def rgb_float(image: np.ndarray) -> np.ndarray:
    """BGR ``uint8`` ``(H, W, 3)`` → RGB float32 in [0, 1] ``(H, W, 3)`` (for colour templates)."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise MocapInputError(None, f"expected a BGR uint8 image (H, W, 3), got {image.dtype} {image.shape}")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB).astype(np.float32) * np.float32(1.0 / 255.0)


def _roi_mask(roi, shape: tuple[int, int]) -> np.ndarray:
    roi_arr = np.asarray(roi)
    if roi_arr.shape == shape:
        return roi_arr > 0
    if roi_arr.shape == (4,):
        x, y, w, h = (int(v) for v in roi_arr)
        m = np.zeros(shape, bool)
        m[max(y, 0) : max(y + h, 0), max(x, 0) : max(x + w, 0)] = True
        return m
    raise MocapInputError(
        None, f"ROI must be a box (x, y, w, h) or an (H, W) mask, got shape {roi_arr.shape}"
    )


def roi_histograms(image: np.ndarray, rois, bins: int = 8, space: str = "rgb") -> np.ndarray:
    """Colour histograms ``(R, n)`` normalised to sum 1 of the pixels of each ROI.

    ``rois``: boxes ``(x, y, w, h)`` or ``(H, W)`` masks. ``space``: ``"rgb"`` (joint ``bins³`` histogram of the
    B, G, R values), ``"hs"`` (joint ``bins²`` hue–saturation histogram, OpenCV HSV) or ``"rg"`` (joint ``bins²``
    histogram of the chromaticities ``r = R/(R+G+B)``, ``g = G/(R+G+B)``, insensitive to brightness). An empty
    ROI gives a zero row.
    """
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise MocapInputError(None, f"expected a BGR uint8 image (H, W, 3), got {image.dtype} {image.shape}")
    if space == "rgb":
        q = (image.astype(np.int64) * bins) // 256
        index = (q[..., 2] * bins + q[..., 1]) * bins + q[..., 0]
        n = bins**3
    elif space == "hs":
        hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV).astype(np.int64)
        index = np.minimum(hsv[..., 0] * bins // 180, bins - 1) * bins + hsv[..., 1] * bins // 256
        n = bins**2
    elif space == "rg":
        f = image.astype(np.float64)
        s = f.sum(axis=2)
        s = np.where(s > 0, s, 1.0)
        r = np.minimum((f[..., 2] / s * bins).astype(np.int64), bins - 1)
        g = np.minimum((f[..., 1] / s * bins).astype(np.int64), bins - 1)
        index = r * bins + g
        n = bins**2
    else:
        raise ValueError(f"space must be 'rgb', 'hs' or 'rg', got {space!r}")
    out = np.zeros((len(rois), n), np.float64)
    for k, roi in enumerate(rois):
        counts = np.bincount(index[_roi_mask(roi, image.shape[:2])], minlength=n).astype(np.float64)
        total = counts.sum()
        if total > 0:
            out[k] = counts / total
    return out


def bhattacharyya_distance(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``d(p, q) = sqrt(1 − Σ_i sqrt(p_i q_i))`` for histograms normalised to sum 1, over the last axis."""
    bc = np.sum(np.sqrt(np.asarray(p, np.float64) * np.asarray(q, np.float64)), axis=-1)
    return np.sqrt(np.maximum(1.0 - bc, 0.0))
