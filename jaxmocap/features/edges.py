"""Edge maps and their distance transform.

* ``canny_edges`` — Canny on the luminance ``Y = 0.299 R + 0.587 G + 0.114 B`` (OpenCV's BGR→grey).
* ``edge_map`` — López Méndez (2009) §4.2: Canny edges kept only inside the dilated foreground, dilated with a
  square structuring element and Gaussian-smoothed, giving a map in [0, 1] that the edge cue samples.
* ``distance_transform`` — Fontmarty et al. (IROS 2007): ``I_DT(p) = min_{e ∈ edges} ‖p − e‖₂`` in pixels, the
  exact Euclidean distance (``cv2.distanceTransform`` with ``DIST_L2`` and ``DIST_MASK_PRECISE``, then rounded to
  ``√k`` of the nearest integer ``k``: see below), optionally truncated at ``τ``: ``min(I_DT, τ)``.

**Determinism of I_DT.** OpenCV's precise transform runs Intel IPP's ``ippiTrueDistanceTransform`` when the image
has fewer than 2¹⁴ pixels or OpenCV runs on one thread, its own Felzenszwalb transform otherwise. IPP's result
depends on the address of the output buffer modulo 32 bytes (values differ by up to 2 ulp between addresses), and an output array allocated by the Python binding lands wherever ``malloc`` puts
it — which depends on what the process allocated before (JAX's buffers, for one). The same image could thus give
maps differing by 1 ulp in a hundred pixels, and a long track then diverges. :func:`distance_transform` therefore
writes into a 64-byte aligned buffer (one code path of IPP) and replaces every distance ``d`` by
``√(round(d²))`` (computed in float64, rounded once to float32): the correctly rounded distance to the nearest
edge pixel, whichever implementation ran and however many threads OpenCV has. OpenCV's own transform is exact;
IPP's is within 2 ulp below 512 px (``|d² − k| ≤ 0.05``: the rounding recovers ``k``), while farther away it can
be off by one in ``k`` (measured on 1500² images) — distances the pipeline's truncation at 50 px never keeps.

Edge images are ``uint8`` with 255 on edge pixels; masks ``uint8`` with non-zero = foreground.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError


def luminance(image: np.ndarray) -> np.ndarray:
    """``(H, W, 3)`` BGR or ``(H, W)`` grey → ``(H, W)`` ``uint8`` luminance."""
    image = np.asarray(image)
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    raise MocapInputError(None, f"expected an (H, W) or (H, W, 3) image, got shape {image.shape}")


def canny_edges(
    image: np.ndarray,
    low: float = 50.0,
    high: float = 150.0,
    aperture: int = 3,
    l2_gradient: bool = True,
    presmooth: float = 0.0,
) -> np.ndarray:
    """Canny edges of the luminance of ``image``: ``(H, W)`` ``uint8`` with 255 on edges.

    ``presmooth`` > 0 applies a Gaussian blur of that σ (pixels) first.
    """
    grey = luminance(image)
    if presmooth > 0:
        grey = cv2.GaussianBlur(grey, (0, 0), presmooth)
    return cv2.Canny(grey, low, high, apertureSize=aperture, L2gradient=l2_gradient)


def _dilated_foreground(foreground: np.ndarray, shape: tuple[int, int], dilate_size: int) -> np.ndarray:
    fg = np.asarray(foreground)
    if fg.shape != shape:
        raise MocapInputError(None, f"foreground {fg.shape} and image {shape} differ in shape")
    if fg.dtype != np.uint8:
        fg = (fg > 0).astype(np.uint8) * np.uint8(255)
    if dilate_size > 1:
        fg = cv2.dilate(fg, np.ones((dilate_size, dilate_size), np.uint8))
    return fg


def mask_edges(edges: np.ndarray, foreground: np.ndarray | None, dilate_size: int = 15) -> np.ndarray:
    """Keep the edges inside the foreground dilated by a ``dilate_size²`` square (None: keep all)."""
    if foreground is None:
        return edges
    fg = _dilated_foreground(foreground, edges.shape, dilate_size)
    return cv2.bitwise_and(edges, edges, mask=fg)


def masked_canny(
    image: np.ndarray,
    foreground: np.ndarray | None,
    low: float = 50.0,
    high: float = 150.0,
    mask_dilate: int = 15,
    presmooth: float = 0.0,
    margin: int = 16,
) -> np.ndarray:
    """``mask_edges(canny_edges(image), foreground, mask_dilate)``, computed on the bounding box of the dilated
    foreground grown by ``margin`` pixels only (the Sobel support and the hysteresis of the Canny detector see
    the same neighbourhood as on the full image unless an edge chain leaves and re-enters that box)."""
    if foreground is None:
        return canny_edges(image, low, high, presmooth=presmooth)
    grey = luminance(image)
    fg = _dilated_foreground(foreground, grey.shape, mask_dilate)
    out = np.zeros(grey.shape, np.uint8)
    box = _bbox(fg, margin)
    if box is None:
        return out
    e = canny_edges(grey[box], low, high, presmooth=presmooth)
    out[box] = cv2.bitwise_and(e, e, mask=fg[box])
    return out


def smooth_edges(edges: np.ndarray, dilate_size: int = 3, sigma: float = 1.0) -> np.ndarray:
    """Edge pixels → ``(H, W)`` float32 map in [0, 1]: dilation with a ``dilate_size²`` square, then a Gaussian
    blur of standard deviation ``sigma`` pixels (kernel ±3σ), divided by 255."""
    e = edges if dilate_size <= 1 else cv2.dilate(edges, np.ones((dilate_size, dilate_size), np.uint8))
    e = e.astype(np.float32) * np.float32(1.0 / 255.0)
    if sigma > 0:
        ksize = 2 * int(math.ceil(3.0 * sigma)) + 1
        e = cv2.GaussianBlur(e, (ksize, ksize), sigma)
    return e


def _bbox(mask: np.ndarray, pad: int) -> tuple[slice, slice] | None:
    """Rows/columns slice of the bounding box of the non-zero pixels, grown by ``pad`` and clipped; None if empty."""
    x, y, w, h = cv2.boundingRect(mask)
    if w == 0 or h == 0:
        return None
    H, W = mask.shape
    return slice(max(y - pad, 0), min(y + h + pad, H)), slice(max(x - pad, 0), min(x + w + pad, W))


def _aligned_empty(shape: tuple[int, int], dtype=np.float32, align: int = 64) -> np.ndarray:
    """An uninitialised C-contiguous array whose data starts at a multiple of ``align`` bytes."""
    dtype = np.dtype(dtype)
    n = int(np.prod(shape)) * dtype.itemsize
    raw = np.empty(n + align, np.uint8)
    start = (-raw.ctypes.data) % align
    return raw[start : start + n].view(dtype).reshape(shape)


def _exact_distances(d: np.ndarray) -> np.ndarray:
    """``√(round(d²))`` in float32 (correctly rounded: the square root of the integer ``k`` in float64, rounded
    once; ``k`` is recovered when ``|d² − k| < ½``, e.g. ``d`` within 2 ulp of ``√k`` below 512 px)."""
    d2 = d.astype(np.float64)
    np.multiply(d2, d2, out=d2)
    np.rint(d2, out=d2)
    np.sqrt(d2, out=d2)
    return d2.astype(np.float32)


def distance_transform(edges: np.ndarray, truncate: float | None = None) -> np.ndarray:
    """Euclidean distance (pixels) from every pixel to the nearest non-zero pixel of ``edges``.

    ``(H, W)`` float32, exact (``DIST_MASK_PRECISE``; every value the correctly rounded ``√k`` of the integer
    squared distance ``k``, the same bytes whatever the process did before: module docstring),
    ``min(d, truncate)`` when ``truncate`` is set. An image
    without any edge pixel gives ``truncate`` everywhere, or the image diagonal ``sqrt(H² + W²)`` without it.
    With ``truncate``, only the bounding box of the edges grown by ``truncate`` is transformed (pixels outside
    it are farther than ``truncate`` from every edge), which gives the same result faster.
    """
    edges = np.asarray(edges)
    if edges.ndim != 2:
        raise MocapInputError(None, f"edges must be (H, W), got shape {edges.shape}")
    H, W = edges.shape
    edges = edges if edges.dtype == np.uint8 else (edges != 0).astype(np.uint8)
    box = _bbox(edges, 0 if truncate is None else int(math.ceil(truncate)) + 1)
    if box is None:
        fill = math.hypot(H, W) if truncate is None else truncate
        return np.full((H, W), fill, np.float32)
    if truncate is None:
        box = (slice(0, H), slice(0, W))
    # cv2.distanceTransform measures the distance to the nearest zero pixel: edges → 0, the rest → 255.
    not_edge = cv2.compare(edges[box], 0, cv2.CMP_EQ)
    dt_box = _aligned_empty(not_edge.shape)
    cv2.distanceTransform(not_edge, cv2.DIST_L2, cv2.DIST_MASK_PRECISE, dst=dt_box)
    dt_box = _exact_distances(dt_box)
    if truncate is None:
        return dt_box
    np.minimum(dt_box, np.float32(truncate), out=dt_box)
    dt = np.full((H, W), truncate, np.float32)
    dt[box] = dt_box
    return dt


def edge_map(
    image: np.ndarray,
    foreground: np.ndarray | None = None,
    *,
    low: float = 50.0,
    high: float = 150.0,
    mask_dilate: int = 15,
    dilate_size: int = 3,
    sigma: float = 1.0,
    truncate: float | None = None,
    presmooth: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The edge features of one view: ``(edges01, edge_dt, raw_edges)``.

    ``raw_edges``: Canny edges (``uint8`` 0/255) masked by the foreground dilated by ``mask_dilate``;
    ``edges01``: ``smooth_edges(raw_edges, dilate_size, sigma)`` in [0, 1]; ``edge_dt``:
    ``distance_transform(raw_edges, truncate)`` in pixels. The distance transform uses the thin edges, not the
    dilated ones, so that distances are measured to the edge centre lines.
    """
    raw = masked_canny(image, foreground, low, high, mask_dilate, presmooth)
    return smooth_edges(raw, dilate_size, sigma), distance_transform(raw, truncate), raw
