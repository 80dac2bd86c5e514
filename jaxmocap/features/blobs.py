"""Skin blobs: connected components in each view, stereo matching under the epipolar constraint, triangulation.

For the head and hands cue (Fontmarty et al., IROS 2007; Li & Kulić): the largest skin regions of each view
(``skin_blobs``), matched between two calibrated views (``match_blobs``) where the centroids satisfy
``x₂ᵀ F x₁ ≈ 0`` with the fundamental matrix of the rig (``fundamental_matrix``), then triangulated
(``triangulate_pair``) into 3D points with confidences (``stereo_blobs``).

Camera conventions follow ``jaxmocap.geometry.camera.Rig``: ``x_cam = R x_world + t``, pixel ``u`` = column, ``v`` = row,
OpenCV distortion ``[k1, k2, p1, p2, k3]``. Centroids are undistorted before the epipolar test and triangulation.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError


class Blobs(NamedTuple):
    """Blobs of one view, largest first: ``centroids (n, 2)`` (u, v) pixels, ``areas (n,)`` pixels,
    ``boxes (n, 4)`` ``(x, y, w, h)``, ``labels (H, W)`` int32 component image (0 = none, blob ``i`` → i + 1) or
    None when not asked for."""

    centroids: np.ndarray
    areas: np.ndarray
    boxes: np.ndarray
    labels: np.ndarray | None


def skin_blobs(
    skin: np.ndarray,
    threshold: float = 0.5,
    max_blobs: int = 3,
    min_area: int = 20,
    open_size: int = 3,
    close_size: int = 5,
    with_labels: bool = False,
) -> Blobs:
    """The ``max_blobs`` largest 8-connected components of ``skin > threshold`` with area ≥ ``min_area``.

    ``skin``: ``(H, W)`` probability (float in [0, 1], or ``uint8`` read as ``round(255·p)``) or a 0/255 mask.
    The binary mask is cleaned by an opening (``open_size``) and a closing (``close_size``) first.
    ``with_labels`` also returns the component image of the kept blobs.
    """
    skin = np.asarray(skin)
    if skin.ndim != 2:
        raise MocapInputError(None, f"skin map must be (H, W), got shape {skin.shape}")
    if skin.dtype == np.uint8:
        mask = np.where(skin > threshold * 255.0, np.uint8(255), np.uint8(0))
    else:
        mask = np.where(skin > threshold, np.uint8(255), np.uint8(0))
    if open_size > 1:
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((open_size, open_size), np.uint8))
    if close_size > 1:
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((close_size, close_size), np.uint8))
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8, ltype=cv2.CV_32S)
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.flatnonzero(areas >= min_area)
    keep = keep[np.argsort(-areas[keep], kind="stable")][:max_blobs]
    out_labels = None
    if with_labels:
        relabel = np.zeros(n, np.int32)
        relabel[keep + 1] = np.arange(1, len(keep) + 1, dtype=np.int32)
        out_labels = relabel[labels]
    return Blobs(
        centroids=centroids[keep + 1].astype(np.float64),
        areas=areas[keep].astype(np.float64),
        boxes=stats[keep + 1, :4].astype(np.int64),
        labels=out_labels,
    )


def _np(x) -> np.ndarray:
    return np.asarray(x, np.float64)


def skew(t: np.ndarray) -> np.ndarray:
    """``[t]×`` such that ``[t]× v = t × v``."""
    return np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])


def relative_pose(R1, t1, R2, t2) -> tuple[np.ndarray, np.ndarray]:
    """Pose of camera 2 relative to camera 1: ``x₂ = R x₁ + t`` with ``R = R₂ R₁ᵀ``, ``t = t₂ − R t₁``."""
    R1, t1, R2, t2 = _np(R1), _np(t1), _np(R2), _np(t2)
    R = R2 @ R1.T
    return R, t2 - R @ t1


def fundamental_matrix(K1, R1, t1, K2, R2, t2) -> np.ndarray:
    """``F = K₂⁻ᵀ [t]× R K₁⁻¹`` for the relative pose ``(R, t)`` of camera 2 w.r.t. camera 1, so that
    ``x₂ᵀ F x₁ = 0`` for homogeneous (undistorted) pixels of one world point; scaled to unit Frobenius norm."""
    R, t = relative_pose(R1, t1, R2, t2)
    F = np.linalg.inv(_np(K2)).T @ skew(t) @ R @ np.linalg.inv(_np(K1))
    return F / np.linalg.norm(F)


def fundamental_from_rig(rig, i: int, j: int) -> np.ndarray:
    """Fundamental matrix between views ``i`` (first) and ``j`` (second) of a ``Rig``."""
    K, R, t = _np(rig.K), _np(rig.R), _np(rig.t)
    return fundamental_matrix(K[i], R[i], t[i], K[j], R[j], t[j])


def undistort_pixels(uv: np.ndarray, K, dist) -> np.ndarray:
    """Distorted pixels ``(n, 2)`` → ideal pinhole pixels ``(n, 2)`` of the same camera (``cv2.undistortPoints``)."""
    uv = np.asarray(uv, np.float64).reshape(-1, 1, 2)
    if len(uv) == 0:
        return np.zeros((0, 2))
    K = _np(K)
    return cv2.undistortPoints(uv, K, _np(dist), P=K).reshape(-1, 2)


def epipolar_distance(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Symmetric epipolar distance ``(n1, n2)`` in pixels: the mean of the distance of ``x₂`` to the line
    ``F x₁`` and of ``x₁`` to the line ``Fᵀ x₂``."""
    x1 = np.asarray(x1, np.float64).reshape(-1, 2)
    x2 = np.asarray(x2, np.float64).reshape(-1, 2)
    h1 = np.column_stack([x1, np.ones(len(x1))])
    h2 = np.column_stack([x2, np.ones(len(x2))])
    l2 = h1 @ F.T  # (n1, 3): lines in image 2
    l1 = h2 @ F  # (n2, 3): lines in image 1
    alg = h2 @ F @ h1.T  # (n2, n1) = x2ᵀ F x1
    d2 = np.abs(alg.T) / np.maximum(np.hypot(l2[:, 0], l2[:, 1]), 1e-300)[:, None]
    d1 = np.abs(alg.T) / np.maximum(np.hypot(l1[:, 0], l1[:, 1]), 1e-300)[None, :]
    return 0.5 * (d1 + d2)


def projection_matrix(K, R, t) -> np.ndarray:
    """``P = K [R | t]`` (3, 4)."""
    return _np(K) @ np.column_stack([_np(R), _np(t)])


def triangulate_pair(rig, i: int, j: int, uv_i: np.ndarray, uv_j: np.ndarray) -> np.ndarray:
    """World points ``(n, 3)`` from distorted pixel correspondences ``(n, 2)`` in views ``i`` and ``j``:
    undistortion, then linear triangulation (``cv2.triangulatePoints``)."""
    K, d, R, t = _np(rig.K), _np(rig.dist), _np(rig.R), _np(rig.t)
    a = undistort_pixels(uv_i, K[i], d[i])
    b = undistort_pixels(uv_j, K[j], d[j])
    if len(a) == 0:
        return np.zeros((0, 3))
    X = cv2.triangulatePoints(
        projection_matrix(K[i], R[i], t[i]), projection_matrix(K[j], R[j], t[j]), a.T, b.T
    )
    return (X[:3] / X[3]).T


class BlobMatch(NamedTuple):
    """One matched pair: blob indices ``i`` (first view) and ``j`` (second view), symmetric epipolar distance in
    pixels, the area ratio ``min/max`` and the confidence."""

    i: int
    j: int
    epipolar: float
    area_ratio: float
    confidence: float


def match_blobs(
    blobs1: Blobs,
    blobs2: Blobs,
    F: np.ndarray,
    max_epipolar: float = 5.0,
    sigma_epipolar: float = 2.0,
    min_area_ratio: float = 0.25,
) -> list[BlobMatch]:
    """Greedy one-to-one matching of blob centroids (already undistorted if the cameras distort) under the
    epipolar constraint.

    Candidate pairs need a symmetric epipolar distance ``d ≤ max_epipolar`` and an area ratio
    ``min(a₁, a₂)/max(a₁, a₂) ≥ min_area_ratio``; their confidence is ``exp(−d²/(2σ²)) · ratio``. Pairs are
    taken by decreasing confidence, each blob at most once.
    """
    if len(blobs1.areas) == 0 or len(blobs2.areas) == 0:
        return []
    d = epipolar_distance(F, blobs1.centroids, blobs2.centroids)
    a1, a2 = blobs1.areas[:, None], blobs2.areas[None, :]
    ratio = np.minimum(a1, a2) / np.maximum(np.maximum(a1, a2), 1e-12)
    conf = np.exp(-0.5 * (d / sigma_epipolar) ** 2) * ratio
    ok = (d <= max_epipolar) & (ratio >= min_area_ratio)
    pairs = sorted(zip(*np.nonzero(ok), strict=True), key=lambda ij: -conf[ij])
    used1, used2, out = set(), set(), []
    for i, j in pairs:
        if i in used1 or j in used2:
            continue
        used1.add(i)
        used2.add(j)
        out.append(BlobMatch(int(i), int(j), float(d[i, j]), float(ratio[i, j]), float(conf[i, j])))
    return out


def stereo_blobs(
    rig,
    blobs: list[Blobs] | tuple[Blobs, Blobs],
    views: tuple[int, int] = (0, 1),
    max_blobs: int = 3,
    **match_kwargs,
) -> tuple[np.ndarray, np.ndarray, list[BlobMatch]]:
    """3D skin blobs from a calibrated pair: ``(points (K, 3), confidence (K,), matches)``, ``K = max_blobs``.

    ``blobs``: the ``Blobs`` of ``views[0]`` and ``views[1]``. Centroids are undistorted, matched with
    ``match_blobs``, triangulated with ``triangulate_pair``; matches that land behind either camera are dropped.
    Slots are filled by decreasing confidence; empty slots are zeros with confidence 0.
    """
    i, j = views
    K, d, R, t = _np(rig.K), _np(rig.dist), _np(rig.R), _np(rig.t)
    b1, b2 = blobs
    u1 = b1._replace(centroids=undistort_pixels(b1.centroids, K[i], d[i]))
    u2 = b2._replace(centroids=undistort_pixels(b2.centroids, K[j], d[j]))
    matches = match_blobs(u1, u2, fundamental_from_rig(rig, i, j), **match_kwargs)
    points = np.zeros((max_blobs, 3), np.float64)
    conf = np.zeros((max_blobs,), np.float64)
    kept = []
    if matches:
        X = triangulate_pair(
            rig,
            i,
            j,
            b1.centroids[[m.i for m in matches]],
            b2.centroids[[m.j for m in matches]],
        )
        z1 = X @ R[i][2] + t[i][2]
        z2 = X @ R[j][2] + t[j][2]
        for m, x, za, zb in zip(matches, X, z1, z2, strict=True):
            if za > 0 and zb > 0 and len(kept) < max_blobs:
                points[len(kept)] = x
                conf[len(kept)] = m.confidence
                kept.append(m)
    return points, conf, kept
