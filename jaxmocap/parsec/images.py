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


def _binary_row_blur() -> np.ndarray:
    """The row pass of the blur on a binary image, tabulated: entry ``c`` (7 bits, bit ``i`` set where tap ``i``
    reads 255) is ``uint8(Σ_i 255·b_i·w_i)`` accumulated in float32 in kernel order, exactly what the direct pass
    computes for that neighbourhood."""
    lut = np.zeros(1 << len(_BLUR), np.uint8)
    for code in range(len(lut)):
        acc = np.float32(0.0)
        for i, w in enumerate(_BLUR):
            acc = np.float32(acc + np.float32(255.0 if code >> i & 1 else 0.0) * w)
        lut[code] = np.uint8(acc)
    return lut


_ROW_BLUR = _binary_row_blur()


_ROW_BLUR_256 = np.concatenate([_ROW_BLUR, np.zeros(256 - len(_ROW_BLUR), np.uint8)])  # cv2.LUT takes 256


def edge_map(gray: np.ndarray, threshold: float = 16.0) -> np.ndarray:
    """bodytrack's edge map (§6.1) of a grey image ``(H, W) uint8`` → ``(H, W) uint8``, bit for bit.

    1. ``gx``, ``gy``: Sobel / 8 in float32, summed in bodytrack's term order;
    2. ``B = 255`` where ``gx² + gy² ≥ threshold``, else 0, with a zero 1-pixel border;
    3. 7-tap blur along rows (x in [3, W−3)), truncated to uint8, then along columns (y in [3, H−3)), truncated
       again; the margins are zero. Float32 accumulation in kernel order, as the C++ does.

    Steps 1–2 are exact in any order: ``gx = Gx/8`` with ``Gx`` the integer Sobel response (``|Gx| ≤ 1020``), so
    every partial sum is a multiple of 1/8 and ``gx² + gy² = (Gx² + Gy²)/64`` with ``Gx² + Gy² < 2²⁴``, all exact
    in float32; they are computed as ``Gx² + Gy² ≥ 64·threshold`` with OpenCV's Sobel (float32 output, integer
    values). ``B`` is binary, so the row pass reads its result from a 128-entry table indexed by the 7 taps' bits
    (:func:`_binary_row_blur`, the same float32 sums; the 7-bit codes by an integer filter, exact). The column pass
    is order-dependent and accumulates directly, tap by tap in kernel order.
    """
    import cv2

    I = np.asarray(gray)
    if I.ndim != 2 or I.dtype != np.uint8:
        raise ValueError(f"edge_map expects a (H, W) uint8 image, got {I.shape} {I.dtype}")
    H, W = I.shape
    gx = cv2.Sobel(I, cv2.CV_32F, 1, 0, ksize=3)  # Gx = 8 gx, integers
    gy = cv2.Sobel(I, cv2.CV_32F, 0, 1, ksize=3)
    mag = cv2.add(cv2.multiply(gx, gx), cv2.multiply(gy, gy))  # 64 (gx² + gy²), exact
    bit = np.zeros((H, W), np.uint8)
    bit[1:-1, 1:-1] = mag[1:-1, 1:-1] >= np.float32(threshold) * np.float32(64.0)  # B / 255
    k = len(_BLUR)
    n = k // 2
    taps = (1 << np.arange(k)).astype(np.float32)[None, :]  # code = Σ_i bit[x − n + i] · 2^i
    code = cv2.filter2D(bit, cv2.CV_8U, taps, anchor=(n, 0), borderType=cv2.BORDER_CONSTANT)
    tmp = cv2.LUT(code, _ROW_BLUR_256)
    tmp[:, :n] = 0
    tmp[:, W - n :] = 0
    s = tmp.astype(np.float32)
    acc = s[: H - 2 * n] * _BLUR[0]  # 0 + s·w is s·w exactly
    prod = np.empty_like(acc)
    for i in range(1, k):
        np.multiply(s[i : i + H - 2 * n], _BLUR[i], out=prod)
        acc += prod
    out = np.zeros((H, W), np.uint8)
    out[n:-n] = acc.astype(np.uint8)  # C cast: truncation (acc is in [0, 255])
    return out
