"""PARSEC bodytrack's images and their preprocessing (``jaxmocap/parsec/FORMAT.md`` §6.1): grey images, binary
foreground maps and edge maps, bit for bit as bodytrack computes them (host side, numpy)."""

from __future__ import annotations

import os

import numpy as np

from jaxmocap.errors import MocapInputError

__all__ = ["edge_map", "foreground_map", "load_image"]


def load_image(path: str | os.PathLike) -> np.ndarray:
    """An 8-bit grey image ``(H, W) uint8``, row 0 at the top (bodytrack flips bottom-up BMP rows the same way)."""
    import cv2

    p = os.fspath(path)
    if not os.path.isfile(p):
        raise MocapInputError(p, "image not found")
    im = cv2.imread(p, cv2.IMREAD_GRAYSCALE)
    if im is None:
        raise MocapInputError(p, "not a readable image")
    return im


def foreground_map(fg: np.ndarray) -> np.ndarray:
    """bodytrack's binary foreground map: pixel ≠ 0 → 1, else 0 (uint8; ``BinaryImage::ConvertToBinary``)."""
    return (np.asarray(fg) != 0).astype(np.uint8)


_BLUR = np.asarray(
    [
        0.12149085090552,
        0.14203719483447,
        0.15599734045770,
        0.16094922760463,
        0.15599734045770,
        0.14203719483447,
        0.12149085090552,
    ],
    dtype=np.float32,
)


def edge_map(gray: np.ndarray, threshold: float = 16.0) -> np.ndarray:
    """bodytrack's edge map (§6.1) of a grey image ``(H, W) uint8`` → ``(H, W) uint8``, bit for bit.

    1. ``gx``, ``gy``: Sobel / 8 in float32, summed in bodytrack's term order;
    2. ``B = 255`` where ``gx² + gy² ≥ threshold``, else 0, with a zero 1-pixel border;
    3. 7-tap blur along rows (x in [3, W−3)), truncated to uint8, then along columns (y in [3, H−3)), truncated
       again; the margins are zero. Float32 accumulation in kernel order, as the C++ does.
    """
    I = np.asarray(gray)
    if I.ndim != 2 or I.dtype != np.uint8:
        raise ValueError(f"edge_map expects a (H, W) uint8 image, got {I.shape} {I.dtype}")
    H, W = I.shape
    f = I.astype(np.float32)
    c8, c4 = np.float32(0.125), np.float32(0.25)
    up, mid, dn = f[:-2], f[1:-1], f[2:]
    ul, ur = up[:, :-2], up[:, 2:]
    ml, mr = mid[:, :-2], mid[:, 2:]
    dl, dr = dn[:, :-2], dn[:, 2:]
    gx = -c8 * ul + c8 * ur - c4 * ml + c4 * mr - c8 * dl + c8 * dr
    gy = -c8 * ul - c4 * up[:, 1:-1] - c8 * ur + c8 * dl + c4 * dn[:, 1:-1] + c8 * dr
    mag = gx * gx + gy * gy
    B = np.zeros((H, W), np.uint8)
    B[1:-1, 1:-1] = np.where(mag < np.float32(threshold), 0, 255).astype(np.uint8)
    n = len(_BLUR) // 2

    def row_pass(src):
        s = src.astype(np.float32)
        acc = np.zeros((src.shape[0], src.shape[1] - 2 * n), np.float32)
        for i in range(2 * n + 1):
            acc = acc + s[:, i : i + src.shape[1] - 2 * n] * _BLUR[i]
        out = np.zeros_like(src)
        out[:, n:-n] = acc.astype(np.uint8)  # C cast: truncation (acc is in [0, 255])
        return out

    tmp = row_pass(B)
    return np.ascontiguousarray(row_pass(tmp.T).T)
