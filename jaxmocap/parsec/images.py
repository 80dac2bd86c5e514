"""PARSEC bodytrack's images and their preprocessing (``jaxmocap/parsec/FORMAT.md`` §6.1): grey images, binary
foreground maps and edge maps, bit for bit as bodytrack computes them (host side, numpy)."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numpy as np

from jaxmocap.errors import MocapInputError

__all__ = ["edge_map", "edge_maps", "foreground_map", "load_image", "per_camera"]

T = TypeVar("T")


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


def edge_map(gray: np.ndarray, threshold: float = 16.0, out: np.ndarray | None = None) -> np.ndarray:
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

    The intermediate images live in buffers kept per thread and image size (:func:`_workspace`: 7.0 MB for a
    640×480 image), not allocated per call: on a machine where touching fresh memory is slow (page faults of a
    virtual machine) the ten fresh 0.3–1.2 MB arrays of a 640×480 image cost more than the arithmetic (5–6 ms
    against 1.2–1.4 ms a camera, :func:`edge_maps`). ``out``: an ``(H, W) uint8`` array to write the map into
    (returned); a new one when None.
    """
    import cv2

    I = np.asarray(gray)
    if I.ndim != 2 or I.dtype != np.uint8:
        raise ValueError(f"edge_map expects a (H, W) uint8 image, got {I.shape} {I.dtype}")
    H, W = I.shape
    if out is None:
        out = np.empty((H, W), np.uint8)
    elif out.shape != (H, W) or out.dtype != np.uint8:
        raise ValueError(f"out must be a ({H}, {W}) uint8 array, got {out.shape} {out.dtype}")
    k = len(_BLUR)
    n = k // 2
    ws = _workspace(H, W)
    gx, gy = ws["gx"], ws["gy"]
    # (OpenCV writes into ``dst`` when its size and type fit, as here; the results are taken as returned)
    gx = cv2.Sobel(I, cv2.CV_32F, 1, 0, dst=gx, ksize=3)  # Gx = 8 gx, integers
    gy = cv2.Sobel(I, cv2.CV_32F, 0, 1, dst=gy, ksize=3)
    gx = cv2.multiply(gx, gx, dst=gx)
    gy = cv2.multiply(gy, gy, dst=gy)
    gx = cv2.add(gx, gy, dst=gx)  # 64 (gx² + gy²), exact
    bit = ws["bit"]  # B / 255
    np.greater_equal(gx, np.float32(threshold) * np.float32(64.0), out=bit.view(np.bool_))
    bit[0], bit[-1], bit[:, 0], bit[:, -1] = 0, 0, 0, 0
    code = ws["code"]  # Σ_i bit[x − n + i] · 2^i
    code = cv2.filter2D(bit, cv2.CV_8U, _TAPS, dst=code, anchor=(n, 0), borderType=cv2.BORDER_CONSTANT)
    tmp = cv2.LUT(code, _ROW_BLUR_256, dst=ws["tmp"])
    tmp[:, :n] = 0
    tmp[:, W - n :] = 0
    s, acc, prod = ws["s"], ws["acc"], ws["prod"]
    np.copyto(s, tmp)
    np.multiply(s[: H - 2 * n], _BLUR[0], out=acc)  # 0 + s·w is s·w exactly
    for i in range(1, k):
        np.multiply(s[i : i + H - 2 * n], _BLUR[i], out=prod)
        acc += prod
    out[:n] = 0
    out[H - n :] = 0
    np.copyto(out[n : H - n], acc, casting="unsafe")  # C cast: truncation (acc is in [0, 255])
    return out


#: the row pass's tap weights: code = Σ_i bit[x − n + i] · 2^i
_TAPS = (1 << np.arange(len(_BLUR))).astype(np.float32)[None, :]

_LOCAL = threading.local()


def _workspace(H: int, W: int) -> dict:
    """This thread's intermediate images of :func:`edge_map` for an ``H × W`` image (made on its first call with
    that size; one size kept per thread)."""
    ws = getattr(_LOCAL, "edge_map", None)
    if ws is None or ws["size"] != (H, W):
        m = H - 2 * (len(_BLUR) // 2)
        ws = {
            "size": (H, W),
            "gx": np.empty((H, W), np.float32),
            "gy": np.empty((H, W), np.float32),
            "bit": np.empty((H, W), np.uint8),
            "code": np.empty((H, W), np.uint8),
            "tmp": np.empty((H, W), np.uint8),
            "s": np.empty((H, W), np.float32),
            "acc": np.empty((m, W), np.float32),
            "prod": np.empty((m, W), np.float32),
        }
        _LOCAL.edge_map = ws
    return ws


_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def _forget_pool() -> None:
    """In a child made by ``fork``: the parent's threads do not exist there, so its pool is made anew."""
    global _POOL, _POOL_LOCK
    _POOL, _POOL_LOCK = None, threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)


def _pool() -> ThreadPoolExecutor:
    """The threads that compute one frame's edge maps side by side: one per CPU this process may use (at most 4),
    made once."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
            _POOL = ThreadPoolExecutor(max(1, min(cpus, 4)), thread_name_prefix="jaxmocap-edges")
        return _POOL


def per_camera(fn: Callable[[int], T], count: int) -> list[T]:
    """``[fn(0), …, fn(count − 1)]``, computed side by side in threads (:func:`_pool`; OpenCV's and NumPy's work
    on whole images runs without the interpreter's lock), as bodytrack's threaded builds read and filter their
    cameras' images in parallel. An exception of ``fn`` is raised here (the first camera's first)."""
    if count <= 1:
        return [fn(k) for k in range(count)]
    return list(_pool().map(fn, range(count)))


def edge_maps(grays, threshold: float = 16.0) -> np.ndarray:
    """:func:`edge_map` of every camera's grey image ``(V, H, W) uint8`` (or a sequence of ``(H, W)`` images of
    one size) → ``(V, H, W) uint8``, the cameras side by side (:func:`per_camera`); the same maps as one
    :func:`edge_map` per camera, bit for bit.

    SequenceB_2's four 640×480 images (2-core AMD EPYC without AVX-512, median of 100 calls, three runs): 16.4–19.9
    ms one camera after the other with a fresh array per intermediate image (before the buffers of
    :func:`_workspace`), 6.7–7.5 ms one after the other with them, 3.7–4.4 ms side by side."""
    ims = [np.asarray(g) for g in grays]
    if not ims:
        raise ValueError("edge_maps needs at least one image")
    shape = ims[0].shape
    if any(im.shape != shape for im in ims):
        raise ValueError(f"edge_maps needs images of one size, got {[im.shape for im in ims]}")
    out = np.empty((len(ims), *shape), np.uint8)
    per_camera(lambda k: edge_map(ims[k], threshold, out[k]), len(ims))
    return out
