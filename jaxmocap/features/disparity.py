"""Dense stereo on a calibrated pair: which pixels of the first view lie where a person can be.

:class:`StereoGate` rectifies the two views (:func:`cv2.stereoRectify`, at ``scale`` of the full size), computes
a semi-global block-matching disparity ``d`` (:func:`jaxmocap.features.stereo.sgbm_matcher`) and turns it into world points with
the rectification's reprojection matrix ``Q``: ``[X Y Z W]ᵀ = Q [u v d 1]ᵀ`` in the rectified first camera,
rotated back to the first camera (``R₁ᵀ``) and to the world (``Rᵢᵀ (X_c − tᵢ)``). A pixel passes the gate when its
disparity is valid, its point is at most ``max_range`` metres from the first camera and its height ``z`` lies in
``height_range`` (world ``z`` up, floor at 0). Skin-coloured clutter on a wall behind a person fails the range
gate however its colour looks, and a face that touches such clutter in the image is cut from it by the gate.
No background model is used (the cameras may move).
"""

from __future__ import annotations

import cv2
import numpy as np

from jaxmocap.features.blobs import relative_pose
from jaxmocap.features.stereo import sgbm_disparity, sgbm_matcher

__all__ = ["StereoGate", "StereoFrame"]


class StereoFrame:
    """One frame of the gate, all in the rectified first view at the gate's size ``(h, w)``: ``image (h, w, 3)``
    the rectified first view (BGR ``uint8``), ``disparity (h, w)`` float32 pixels (NaN: none); ``points (h, w, 3)``
    world metres (NaN without a disparity) and ``ok (h, w)`` bool, the gate, computed from the disparity when
    first read (a frame whose matched blobs the disparity confirms never needs them: :meth:`StereoGate.agrees`
    reads the disparity alone)."""

    def __init__(self, gate: StereoGate, image: np.ndarray, disparity: np.ndarray):
        self._gate, self.image, self.disparity = gate, image, disparity
        self._points = self._ok = None

    @property
    def points(self) -> np.ndarray:
        if self._points is None:
            self._points = self._gate._points(self.disparity)
        return self._points

    @property
    def ok(self) -> np.ndarray:
        if self._ok is None:
            self._ok = self._gate._ok(self.disparity)
        return self._ok


class StereoGate:
    """The range and height gate of the module docstring for views ``views`` of ``rig`` (images at the rig's full
    size, BGR ``uint8``); ``scale``: the size of the rectified images against the full size (0.5: a quarter of
    the pixels); ``max_disparity``: the disparity search range at that size (a multiple of 16 is taken), which
    sets the nearest depth seen, ``f·B·scale / max_disparity``; ``block``: the matcher's block size
    (:func:`jaxmocap.features.stereo.sgbm_matcher`)."""

    def __init__(
        self,
        rig,
        views: tuple[int, int] = (0, 1),
        scale: float = 0.5,
        max_range: float = 6.0,
        height_range: tuple[float, float] = (0.3, 2.3),
        max_disparity: int = 64,
        block: int = 5,
    ):
        i, j = views
        K, d, R, t = (np.asarray(a, np.float64) for a in (rig.K, rig.dist, rig.R, rig.t))
        size = tuple(int(s) for s in rig.image_size[i])
        if tuple(int(s) for s in rig.image_size[j]) != size:
            raise ValueError(f"a stereo gate needs views of one size, got {size} and {rig.image_size[j]}")
        if not 0.0 < scale <= 1.0:
            raise ValueError(f"scale must lie in (0, 1], got {scale}")
        small = (max(1, round(size[0] * scale)), max(1, round(size[1] * scale)))
        Rrel, Trel = relative_pose(R[i], t[i], R[j], t[j])
        R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
            K[i], d[i], K[j], d[j], size, Rrel, Trel, alpha=0, newImageSize=small
        )
        if P2[0, 3] > 0:
            raise ValueError("the second view of a stereo gate must lie to the right of the first")
        self.maps = [
            cv2.initUndistortRectifyMap(K[v], d[v], Rv, Pv, small, cv2.CV_16SC2)
            for v, Rv, Pv in ((i, R1, P1), (j, R2, P2))
        ]
        self.Q, self.R1, self.P1, self.size = Q, R1, P1, small
        self.R0, self.t0 = R[i], t[i]
        # rectified (u, v, d, 1) → homogeneous world point in one 4 × 4 product: [R₀ᵀR₁ᵀ | −R₀ᵀt₀; 0 0 0 1] · Q
        A = np.eye(4)
        A[:3, :3], A[:3, 3] = R[i].T @ R1.T, -R[i].T @ t[i]
        M = A @ Q
        # contiguous: numpy multiplies by a transposed view element by element (≈ 8× slower on 77k pixels)
        self._Mt, self._m = np.ascontiguousarray(M[:, :3].T), M[:, 3].copy()
        self.max_range, self.height_range = float(max_range), tuple(height_range)
        self.matcher = sgbm_matcher(max_disparity, block, speckle_window=50)

    def to_world(self, uvd: np.ndarray) -> np.ndarray:
        """World points ``(..., 3)`` of rectified first-view pixels with disparities ``uvd (..., 3)``
        (``(u, v, d)``); ``d ≤ 0`` gives a point at infinity or behind the cameras."""
        uvd = np.asarray(uvd, np.float64)
        h = uvd @ self._Mt  # (..., 4): the world point times d / B
        h += self._m
        with np.errstate(divide="ignore", invalid="ignore"):
            return h[..., :3] * (1.0 / h[..., 3:4])

    def agrees(self, frame: StereoFrame, points: np.ndarray, tol: float = 2.0, half: int = 2) -> np.ndarray:
        """``(K,)`` bool: whether each world point ``points (K, 3)`` lies where ``frame``'s dense stereo puts the
        scene: its own disparity in the rectified pair, ``f B / Z_r``, within ``tol`` pixels (at the gate's size)
        of the median valid disparity in the ``(2·half + 1)²`` window around its rectified pixel (False where the
        window has none, or the point is outside the image or behind the cameras)."""
        X = np.asarray(points, np.float64).reshape(-1, 3)
        Xr = (X @ self.R0.T + self.t0) @ self.R1.T
        out = np.zeros(len(X), bool)
        w, h = self.size
        baseline_f = self.Q[2, 3] / self.Q[3, 2]  # f B: Q maps (u, v, d, 1) to (u - cx, v - cy, f, d / B)
        for k, (x, y, z) in enumerate(Xr):
            if z <= 0:
                continue
            u, v = self.P1[0, 0] * x / z + self.P1[0, 2], self.P1[1, 1] * y / z + self.P1[1, 2]
            iu, iv = int(round(u)), int(round(v))
            if not (0 <= iu < w and 0 <= iv < h):
                continue
            win = frame.disparity[max(iv - half, 0) : iv + half + 1, max(iu - half, 0) : iu + half + 1]
            win = win[np.nan_to_num(win) > 0]
            out[k] = win.size > 0 and abs(np.median(win) - baseline_f / z) <= tol
        return out

    def __call__(self, images, views: tuple[int, int] = (0, 1)) -> StereoFrame:
        """The gate of one frame (``images[views[0]]``, ``images[views[1]]``)."""
        rect = [
            cv2.remap(images[v], m[0], m[1], cv2.INTER_LINEAR) for v, m in zip(views, self.maps, strict=True)
        ]
        return StereoFrame(self, rect[0], sgbm_disparity(rect[0], rect[1], self.matcher))

    def _points(self, disp: np.ndarray) -> np.ndarray:
        """``(h, w, 3)`` world points of a disparity map (NaN without a disparity)."""
        w, h = self.size
        iv, iu = np.nonzero(np.nan_to_num(disp) > 0)
        pts = np.full((h, w, 3), np.nan)
        pts[iv, iu] = self.to_world(np.column_stack([iu, iv, disp[iv, iu]]))
        return pts

    def _ok(self, disp: np.ndarray) -> np.ndarray:
        """``(h, w)`` bool, the gate of a disparity map: a valid disparity whose world point lies within
        ``max_range`` of the first camera and in ``height_range``. The point's coordinates are ratios of affine
        functions of ``(u, v, d)`` (:meth:`to_world`), evaluated on the pixel grid without gathering the points."""
        w, h = self.size
        d = np.nan_to_num(disp).astype(np.float64)
        u, v = np.arange(w, dtype=np.float64)[None, :], np.arange(h, dtype=np.float64)[:, None]
        M, m = self._Mt.T, self._m  # h = M (u, v, d) + m: the world point times d / B, and d / B
        X = [M[k, 0] * u + M[k, 1] * v + M[k, 2] * d + m[k] for k in range(4)]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / X[3]
            c = -self.t0 @ self.R0
            r2 = sum((X[k] * inv - c[k]) ** 2 for k in range(3))
            z = X[2] * inv
            lo, hi = self.height_range
            return (d > 0) & (r2 <= self.max_range**2) & (z >= lo) & (z <= hi)
