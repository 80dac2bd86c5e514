"""Calibrated camera rigs: pinhole projection with OpenCV distortion, triangulation, calibration files.

Camera model (the OpenCV / Bouguet model, Hartley & Zisserman ch. 6–7): a world point ``X`` maps to the camera frame
by ``X_c = R X + t`` (``R`` world→camera, ``t`` in metres), to normalised coordinates ``a = x_c/z_c``,
``b = y_c/z_c``, through the lens distortion with ``r² = a² + b²``

    a_d = a (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 a b + p2 (r² + 2 a²)
    b_d = b (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2 b²) + 2 p2 a b

and to pixels by ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]``: ``u = fx a_d + s b_d + cx``, ``v = fy b_d + cy``
(``u`` = column, ``v`` = row from the top; integer coordinates are pixel centres, the OpenCV convention). The skew
``s`` is Bouguet's ``alpha_c · fx``; OpenCV's own ``projectPoints`` ignores ``K[0, 1]``, so the two agree whenever
``s = 0`` (every calibration shipped with the project).

The JAX functions are pure, jit-able and differentiable, and are written per coordinate: each of ``x_c, y_c, z_c``
is one ``(..., V, P)`` array built from scalar rig coefficients, with no 3×3 product per point (XLA on CPU
vectorises these long flat arrays about ten times faster than many small 3×3 products).

Loaders (host side, numpy float64) read OpenCV ``FileStorage`` YAML/XML, Pose2Sim TOML, caliscope TOML, PARSEC /
Bouguet ``.cal`` and Qualisys ``.qca.txt`` files and raise :class:`jaxmocap.errors.MocapInputError` (file and
line) for anything truncated or malformed. :func:`save_calibration` writes the Pose2Sim-layout TOML that Pose2Sim
and ``cv2.projectPoints`` users read directly.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import tomllib
import xml.etree.ElementTree as ET
from collections.abc import Sequence

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError

__all__ = [
    "Rig",
    "from_opencv",
    "select",
    "scale_images",
    "world_to_camera",
    "project",
    "project_with_depth",
    "project_per_view",
    "in_view",
    "camera_centres",
    "projection_matrices",
    "undistort_points",
    "triangulate",
    "load_calibration",
    "load_opencv_storage",
    "load_pose2sim_toml",
    "load_caliscope_toml",
    "load_parsec_calibration",
    "load_qualisys_qca",
    "save_calibration",
    "rodrigues",
]

# ---------------------------------------------------------------------------------------------------------------
# The rig


@dataclasses.dataclass(frozen=True)
class Rig:
    """``V`` calibrated cameras; a JAX pytree whose leaves are the four arrays.

    Array fields:
      K ``(V, 3, 3)``: intrinsics ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels;
      dist ``(V, 5)``: OpenCV distortion ``[k1, k2, p1, p2, k3]``;
      R ``(V, 3, 3)``: world→camera rotation; t ``(V, 3)``: translation in metres, ``x_cam = R x_world + t``.

    Static fields (hashable, static under ``jit``): ``names`` (one per camera) and ``image_size`` (``(width,
    height)`` in pixels per camera; ``(0, 0)`` where the file does not say).

    Loaders return numpy float64 arrays (the file's full precision); the JAX functions cast them to the dtype of
    the points they project (float32 by default). :meth:`to_jax` makes device arrays explicitly.
    """

    K: jnp.ndarray
    dist: jnp.ndarray
    R: jnp.ndarray
    t: jnp.ndarray
    names: tuple[str, ...] = ()
    image_size: tuple[tuple[int, int], ...] = ()

    @property
    def num_views(self) -> int:
        """Number of cameras ``V`` (static)."""
        return len(self.names)

    def to_jax(self, dtype=None) -> Rig:
        """The same rig with ``jax.Array`` leaves of ``dtype`` (default: JAX's default float)."""
        dtype = jnp.result_type(float) if dtype is None else dtype
        return dataclasses.replace(
            self,
            K=jnp.asarray(self.K, dtype),
            dist=jnp.asarray(self.dist, dtype),
            R=jnp.asarray(self.R, dtype),
            t=jnp.asarray(self.t, dtype),
        )


jax.tree_util.register_dataclass(
    Rig, data_fields=["K", "dist", "R", "t"], meta_fields=["names", "image_size"]
)


def rodrigues(rvec) -> np.ndarray:
    """Rotation matrix of a Rodrigues (axis·angle) vector, host side in float64. ``(..., 3) -> (..., 3, 3)``.

    ``R = I + sin θ/θ ŵ + (1 − cos θ)/θ² ŵ²`` with ``θ = |w|`` (series near θ = 0).
    """
    w = np.asarray(rvec, dtype=np.float64)
    th2 = np.sum(w * w, axis=-1)[..., None, None]
    th = np.sqrt(th2)
    small = th2 < 1e-16
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ths)) / (ths * ths))
    z = np.zeros_like(w[..., 0])
    W = np.stack(
        [
            np.stack([z, -w[..., 2], w[..., 1]], -1),
            np.stack([w[..., 2], z, -w[..., 0]], -1),
            np.stack([-w[..., 1], w[..., 0], z], -1),
        ],
        -2,
    )
    return np.eye(3) + a * W + b * (W @ W)


def _rotation_vector(R: np.ndarray) -> np.ndarray:
    """Rodrigues vector of a rotation matrix (OpenCV's ``cv2.Rodrigues``, which handles angles near π)."""
    rvec, _ = cv2.Rodrigues(np.asarray(R, dtype=np.float64))
    return rvec.reshape(3)


def _normalise_dist(dist: np.ndarray) -> np.ndarray:
    """``(V, n)`` OpenCV coefficients with n in {4, 5, 8, 12, 14} → ``(V, 5)``; the rational/prism/tilt terms
    beyond the fifth must be zero (this model does not implement them)."""
    dist = np.asarray(dist, dtype=np.float64)
    n = dist.shape[-1]
    if n == 4:
        return np.concatenate([dist, np.zeros(dist.shape[:-1] + (1,))], -1)
    if n == 5:
        return dist
    if n in (8, 12, 14):
        if np.any(dist[..., 5:] != 0):
            raise ValueError(
                "distortion terms beyond k1,k2,p1,p2,k3 (rational, thin-prism, tilt) are not supported"
            )
        return dist[..., :5]
    raise ValueError(f"expected 4, 5, 8, 12 or 14 distortion coefficients, got {n}")


def from_opencv(
    K,
    dist,
    rotation,
    tvec,
    names: Sequence[str] | None = None,
    image_size: Sequence[tuple[int, int]] | None = None,
) -> Rig:
    """Rig from OpenCV-style parameters (one camera or ``V`` stacked), host side in float64.

    Args:
      K: ``(3, 3)`` or ``(V, 3, 3)`` camera matrices.
      dist: ``(n,)`` or ``(V, n)`` OpenCV distortion coefficients (n = 4 or 5; 8/12/14 with zero extra terms).
      rotation: world→camera rotation, either Rodrigues vectors ``(3,)``/``(V, 3)`` (as ``cv2.projectPoints``'
        ``rvec``) or matrices ``(3, 3)``/``(V, 3, 3)``.
      tvec: ``(3,)`` or ``(V, 3)`` translations (metres).
      names: camera names (default ``cam0, cam1, …``).
      image_size: ``(width, height)`` per camera (default ``(0, 0)``: unknown).
    """
    K = np.asarray(K, dtype=np.float64)
    K = K.reshape((-1, 3, 3))
    V = K.shape[0]
    dist = _normalise_dist(np.asarray(dist, dtype=np.float64).reshape((V, -1)))
    rot = np.asarray(rotation, dtype=np.float64)
    if rot.shape[-2:] == (3, 3):
        R = rot.reshape((V, 3, 3))
    else:
        R = rodrigues(rot.reshape((V, 3)))
    t = np.asarray(tvec, dtype=np.float64).reshape((V, 3))
    names = tuple(f"cam{i}" for i in range(V)) if names is None else tuple(str(n) for n in names)
    sizes = ((0, 0),) * V if image_size is None else tuple((int(w), int(h)) for w, h in image_size)
    if len(names) != V or len(sizes) != V:
        raise ValueError(f"{V} cameras but {len(names)} names and {len(sizes)} image sizes")
    return Rig(K=K, dist=dist, R=R, t=t, names=names, image_size=sizes)


def select(rig: Rig, indices: Sequence[int | str]) -> Rig:
    """Sub-rig of the cameras ``indices`` (positions or names), in that order."""
    idx = [rig.names.index(i) if isinstance(i, str) else int(i) for i in indices]
    sel = np.asarray(idx, dtype=np.int64)
    return Rig(
        K=rig.K[sel],
        dist=rig.dist[sel],
        R=rig.R[sel],
        t=rig.t[sel],
        names=tuple(rig.names[i] for i in idx),
        image_size=tuple(rig.image_size[i] for i in idx),
    )


def scale_images(rig: Rig, factor: float | tuple[float, float]) -> Rig:
    """Rig for images resized by ``factor`` (``0.5`` = half size), per axis if a pair ``(fx, fy)``.

    Pixel-centre convention (OpenCV's: integer coordinates are pixel centres, ``cv2.resize`` maps
    ``x_new = (x_old + 0.5)·f − 0.5``), so ``fx' = f fx``, ``s' = f s``, ``cx' = f (cx + 0.5) − 0.5`` and likewise
    for ``y``. The image size becomes ``round(w f) × round(h f)``, the size ``cv2.resize(img, None, fx=f, fy=f)``
    gives (OpenCV then uses ``f`` itself as the scale, as here).
    """
    fx, fy = (float(factor), float(factor)) if np.isscalar(factor) else (float(factor[0]), float(factor[1]))
    xp = np if isinstance(rig.K, np.ndarray) else jnp
    S = xp.asarray([[fx, 0.0, 0.5 * fx - 0.5], [0.0, fy, 0.5 * fy - 0.5], [0.0, 0.0, 1.0]], dtype=rig.K.dtype)
    # [u', v', 1] = S [u, v, 1] for every pixel, so K' = S K.
    K = xp.einsum("ij,vjk->vik", S, rig.K)
    sizes = tuple((int(round(w * fx)), int(round(h * fy))) for w, h in rig.image_size)
    return dataclasses.replace(rig, K=K, image_size=sizes)


# ---------------------------------------------------------------------------------------------------------------
# Projection (pure JAX, per coordinate)


def _float_points(X) -> jnp.ndarray:
    X = jnp.asarray(X)
    if not jnp.issubdtype(X.dtype, jnp.floating):
        X = X.astype(jnp.result_type(float))
    return X


def _col(a: jnp.ndarray) -> jnp.ndarray:
    """``(V,)`` coefficient → ``(V, 1)`` so that it broadcasts against ``(..., V, P)``."""
    return a[:, None]


def _camera_coords(rig: Rig, X: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """``x_c = R X + t`` per coordinate: three ``(..., V, P)`` arrays for ``X (..., P, 3)``."""
    dt = X.dtype
    R = jnp.asarray(rig.R, dt)
    t = jnp.asarray(rig.t, dt)
    x = X[..., None, :, 0]
    y = X[..., None, :, 1]
    z = X[..., None, :, 2]
    xc = _col(R[:, 0, 0]) * x + _col(R[:, 0, 1]) * y + _col(R[:, 0, 2]) * z + _col(t[:, 0])
    yc = _col(R[:, 1, 0]) * x + _col(R[:, 1, 1]) * y + _col(R[:, 1, 2]) * z + _col(t[:, 1])
    zc = _col(R[:, 2, 0]) * x + _col(R[:, 2, 1]) * y + _col(R[:, 2, 2]) * z + _col(t[:, 2])
    return xc, yc, zc


def _distort(dist: jnp.ndarray, a: jnp.ndarray, b: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """OpenCV distortion of normalised coordinates ``(a, b)`` (``(..., V, P)``, coefficients ``(V, 5)``)."""
    k1, k2, p1, p2, k3 = (_col(dist[:, i]) for i in range(5))
    a2 = a * a
    b2 = b * b
    ab = a * b
    r2 = a2 + b2
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    ad = a * radial + 2.0 * p1 * ab + p2 * (r2 + 2.0 * a2)
    bd = b * radial + p1 * (r2 + 2.0 * b2) + 2.0 * p2 * ab
    return ad, bd


def world_to_camera(rig: Rig, X) -> jnp.ndarray:
    """Camera-frame coordinates ``R_v X + t_v``. ``X (..., P, 3) -> (..., V, P, 3)``."""
    X = _float_points(X)
    return jnp.stack(_camera_coords(rig, X), -1)


def project_with_depth(rig: Rig, X) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Pixel coordinates and camera depth of world points in every view.

    ``X (..., P, 3)`` → ``uv (..., V, P, 2)`` (column, row; with distortion, see the module docstring) and
    ``depth (..., V, P)`` = ``z_c``. ``uv`` is meaningless where ``depth <= 0`` (behind the camera): mask with the
    depth, or use :func:`in_view`. The rig is cast to the dtype of ``X``.
    """
    X = _float_points(X)
    return pixels_from_camera(rig, *_camera_coords(rig, X))


def pixels_from_camera(rig: Rig, xc, yc, zc) -> tuple[jnp.ndarray, jnp.ndarray]:
    """:func:`project_with_depth` from camera-frame coordinates: ``xc, yc, zc (..., V, P)`` → ``uv (..., V, P, 2)``
    and ``depth = zc`` (for callers that compose the camera with another transform first)."""
    dt = zc.dtype
    K = jnp.asarray(rig.K, dt)
    dist = jnp.asarray(rig.dist, dt)
    inv_z = 1.0 / zc
    ad, bd = _distort(dist, xc * inv_z, yc * inv_z)
    u = _col(K[:, 0, 0]) * ad + _col(K[:, 0, 1]) * bd + _col(K[:, 0, 2])
    v = _col(K[:, 1, 1]) * bd + _col(K[:, 1, 2])
    return jnp.stack([u, v], -1), zc


def project(rig: Rig, X) -> jnp.ndarray:
    """Pixel coordinates of world points in every view. ``X (..., P, 3) -> (..., V, P, 2)``.

    See :func:`project_with_depth` for points behind a camera.
    """
    return project_with_depth(rig, X)[0]


def project_per_view(rig: Rig, X) -> jnp.ndarray:
    """Pixel coordinates of each view's own points through that view's camera only.

    ``X (..., V, P, 3)`` (``X[..., v, :, :]`` seen by camera ``v``, e.g. occluding contours, which depend on the
    viewpoint) → ``(..., V, P, 2)``; the same model as :func:`project_with_depth`, per coordinate.
    """
    X = _float_points(X)
    dt = X.dtype
    R = jnp.asarray(rig.R, dt)
    t = jnp.asarray(rig.t, dt)
    K = jnp.asarray(rig.K, dt)
    dist = jnp.asarray(rig.dist, dt)
    x, y, z = X[..., 0], X[..., 1], X[..., 2]
    xc = _col(R[:, 0, 0]) * x + _col(R[:, 0, 1]) * y + _col(R[:, 0, 2]) * z + _col(t[:, 0])
    yc = _col(R[:, 1, 0]) * x + _col(R[:, 1, 1]) * y + _col(R[:, 1, 2]) * z + _col(t[:, 1])
    zc = _col(R[:, 2, 0]) * x + _col(R[:, 2, 1]) * y + _col(R[:, 2, 2]) * z + _col(t[:, 2])
    inv_z = 1.0 / zc
    ad, bd = _distort(dist, xc * inv_z, yc * inv_z)
    u = _col(K[:, 0, 0]) * ad + _col(K[:, 0, 1]) * bd + _col(K[:, 0, 2])
    v = _col(K[:, 1, 1]) * bd + _col(K[:, 1, 2])
    return jnp.stack([u, v], -1)


def in_view(rig: Rig, X, near: float = 1e-3) -> jnp.ndarray:
    """Whether each point projects validly into each image. ``X (..., P, 3) -> bool (..., V, P)``.

    True where the depth exceeds ``near`` (metres), the radial distortion is still increasing at the point's
    radius (``d(r·L(r²))/dr = 1 + 3k1 r² + 5k2 r⁴ + 7k3 r⁶ > 0``; beyond the first fold the polynomial model
    maps far-off points back into the picture) and, for cameras whose image size is known, the pixel lies in
    ``[-0.5, w - 0.5] × [-0.5, h - 0.5]``.
    """
    X = _float_points(X)
    dt = X.dtype
    uv, depth = project_with_depth(rig, X)
    xc, yc, zc = _camera_coords(rig, X)
    safe_z = jnp.where(zc > near, zc, 1.0)
    a = xc / safe_z
    b = yc / safe_z
    r2 = a * a + b * b
    dist = jnp.asarray(rig.dist, dt)
    k1, k3, k2 = _col(dist[:, 0]), _col(dist[:, 4]), _col(dist[:, 1])
    slope = 1.0 + r2 * (3.0 * k1 + r2 * (5.0 * k2 + r2 * 7.0 * k3))
    ok = (depth > near) & (slope > 0)
    size = np.asarray(rig.image_size, dtype=np.float64).reshape((-1, 2))
    known = size[:, 0] > 0
    w = jnp.asarray(np.where(known, size[:, 0], np.inf), dt)[:, None]
    h = jnp.asarray(np.where(known, size[:, 1], np.inf), dt)[:, None]
    u, v = uv[..., 0], uv[..., 1]
    inside = (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5)
    return ok & inside


def camera_centres(rig: Rig) -> jnp.ndarray:
    """Optical centres in the world frame, ``C = −Rᵀ t``. ``(V, 3)``."""
    R = jnp.asarray(rig.R)
    t = jnp.asarray(rig.t)
    return -jnp.einsum("vji,vj->vi", R, t)


def projection_matrices(rig: Rig, normalized: bool = False) -> jnp.ndarray:
    """``(V, 3, 4)`` matrices ``K [R | t]`` (or ``[R | t]`` if ``normalized``), without distortion."""
    Rt = jnp.concatenate([jnp.asarray(rig.R), jnp.asarray(rig.t)[:, :, None]], -1)
    if normalized:
        return Rt
    return jnp.einsum("vij,vjk->vik", jnp.asarray(rig.K), Rt)


# ---------------------------------------------------------------------------------------------------------------
# Undistortion and triangulation


def undistort_points(
    rig: Rig, uv, fixed_point_iterations: int = 5, newton_iterations: int = 3, normalized: bool = True
) -> jnp.ndarray:
    """Remove lens distortion from pixel observations. ``uv (..., V, 2) -> (..., V, 2)``.

    Returns normalised coordinates ``(x_c/z_c, y_c/z_c)`` (or, with ``normalized=False``, the ideal pinhole pixels
    ``K [a, b, 1]``). The distorted normalised point ``(a_d, b_d) = K⁻¹ [u, v, 1]`` is inverted through the
    distortion model by ``fixed_point_iterations`` of OpenCV's iteration (``cv::undistortPoints``: ``a ← (a_d −
    Δa(a, b)) / L(r²)``, 5 by default as OpenCV's default criteria), then ``newton_iterations`` Newton steps on
    the 2×2 system ``distort(a, b) = (a_d, b_d)`` with the analytic Jacobian, which converge quadratically from
    there (to ~1e-12 in float64 inside the monotone part of the model). Fixed counts keep it jit-able and
    differentiable.
    """
    uv = _float_points(uv)
    dt = uv.dtype
    K = jnp.asarray(rig.K, dt)
    dist = jnp.asarray(rig.dist, dt)
    k1, k2, p1, p2, k3 = (dist[:, i] for i in range(5))
    fx, s, cx, fy, cy = K[:, 0, 0], K[:, 0, 1], K[:, 0, 2], K[:, 1, 1], K[:, 1, 2]
    bd = (uv[..., 1] - cy) / fy
    ad = (uv[..., 0] - cx - s * bd) / fx
    a, b = ad, bd
    for _ in range(fixed_point_iterations):
        r2 = a * a + b * b
        icdist = 1.0 / (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
        da = 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a)
        db = p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b
        a = (ad - da) * icdist
        b = (bd - db) * icdist
    for _ in range(newton_iterations):
        a2, b2, ab = a * a, b * b, a * b
        r2 = a2 + b2
        L = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dL = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3)
        fa = a * L + 2.0 * p1 * ab + p2 * (r2 + 2.0 * a2) - ad
        fb = b * L + p1 * (r2 + 2.0 * b2) + 2.0 * p2 * ab - bd
        j11 = L + 2.0 * a2 * dL + 2.0 * p1 * b + 6.0 * p2 * a
        j12 = 2.0 * ab * dL + 2.0 * p1 * a + 2.0 * p2 * b
        j21 = 2.0 * ab * dL + 2.0 * p1 * a + 2.0 * p2 * b
        j22 = L + 2.0 * b2 * dL + 6.0 * p1 * b + 2.0 * p2 * a
        det = j11 * j22 - j12 * j21
        a = a - (j22 * fa - j12 * fb) / det
        b = b - (j11 * fb - j21 * fa) / det
    if normalized:
        return jnp.stack([a, b], -1)
    return jnp.stack([fx * a + s * b + cx, fy * b + cy], -1)


def triangulate(rig: Rig, uv, weights=None) -> jnp.ndarray:
    """Linear (DLT) triangulation of one point per ``...`` from its views. ``uv (..., V, 2) -> (..., 3)``.

    The observations are undistorted first (:func:`undistort_points`) to normalised coordinates ``(a_v, b_v)``;
    each view contributes the rows ``w_v (a_v P_v³ − P_v¹)`` and ``w_v (b_v P_v³ − P_v²)`` with ``P_v = [R_v|t_v]``
    (Hartley & Zisserman §12.2), and the point is the right singular vector of the smallest singular value,
    de-homogenised. ``weights (..., V)`` scale the rows (0 drops a view; default all 1). Where fewer than two views
    have a positive weight the result is NaN.
    """
    uv = _float_points(uv)
    dt = uv.dtype
    ab = undistort_points(rig, uv)
    P = projection_matrices(rig, normalized=True).astype(dt)  # (V, 3, 4)
    if weights is None:
        w = jnp.ones(uv.shape[:-1], dt)
    else:
        w = jnp.broadcast_to(jnp.asarray(weights, dt), uv.shape[:-1])
    a = ab[..., 0:1]  # (..., V, 1)
    b = ab[..., 1:2]
    rows_a = w[..., None] * (a * P[:, 2, :] - P[:, 0, :])  # (..., V, 4)
    rows_b = w[..., None] * (b * P[:, 2, :] - P[:, 1, :])
    A = jnp.concatenate([rows_a, rows_b], -2)  # (..., 2V, 4)
    _, _, vh = jnp.linalg.svd(A, full_matrices=False)
    h = vh[..., -1, :]
    X = h[..., :3] / h[..., 3:4]
    enough = jnp.sum(w > 0, axis=-1) >= 2
    return jnp.where(enough[..., None], X, jnp.nan)


# ---------------------------------------------------------------------------------------------------------------
# Calibration files: shared helpers


_CV_EXCEPTIONS = (ValueError, TypeError, OverflowError, KeyError, IndexError, AttributeError, SystemError)


def _read_text(path: str | os.PathLike) -> str:
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as e:
        raise MocapInputError(path, f"cannot read calibration file: {e.strerror or e}") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data[: e.start].count(b"\n") + 1
        raise MocapInputError(path, "not a UTF-8 text file", line) from None


def _line_of(text: str, pattern: str, start_line: int = 1) -> int | None:
    """1-based line of the first match of the regular expression ``pattern`` at or after ``start_line``."""
    lines = text.splitlines()
    rx = re.compile(pattern)
    for i in range(max(start_line, 1) - 1, len(lines)):
        if rx.search(lines[i]):
            return i + 1
    return None


def _as_array(value, shape_ok, what: str, path, line) -> np.ndarray:
    """``value`` as a finite float64 array whose shape passes ``shape_ok``; MocapInputError otherwise."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (ValueError, TypeError, OverflowError):
        raise MocapInputError(path, f"{what} is not an array of numbers", line) from None
    if not shape_ok(arr.shape):
        raise MocapInputError(path, f"{what} has shape {arr.shape}", line)
    if not np.all(np.isfinite(arr)):
        raise MocapInputError(path, f"{what} has non-finite values", line)
    return arr


def _checked_camera(path, line, name, K, dist, R, t, size) -> tuple:
    """Validate one camera's parameters; return them normalised (K, dist(5,), R, t, (w, h))."""
    K = _as_array(K, lambda s: s == (3, 3), f"camera {name!r}: camera matrix", path, line)
    off = np.abs([K[1, 0], K[2, 0], K[2, 1], K[2, 2] - 1.0])
    if K[0, 0] <= 0 or K[1, 1] <= 0 or np.any(off > 1e-9):
        msg = f"camera {name!r}: camera matrix is not [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0"
        raise MocapInputError(path, msg, line)
    K = np.array([[K[0, 0], K[0, 1], K[0, 2]], [0.0, K[1, 1], K[1, 2]], [0.0, 0.0, 1.0]])
    dist_ok = lambda s: len(s) == 1 and s[0] in (4, 5, 8, 12, 14)
    dist = _as_array(dist, dist_ok, f"camera {name!r}: distortion", path, line)
    try:
        dist = _normalise_dist(dist)
    except ValueError as e:
        raise MocapInputError(path, f"camera {name!r}: {e}", line) from None
    R = _as_array(R, lambda s: s == (3, 3), f"camera {name!r}: rotation", path, line)
    if np.max(np.abs(R @ R.T - np.eye(3))) > 1e-3 or np.linalg.det(R) < 0:
        raise MocapInputError(path, f"camera {name!r}: rotation matrix is not a rotation", line)
    t = _as_array(t, lambda s: s == (3,), f"camera {name!r}: translation", path, line)
    size = _as_array(size, lambda s: s == (2,), f"camera {name!r}: image size", path, line)
    if np.any(size < 0) or np.any(size > 1e6) or np.any(size != np.round(size)):
        raise MocapInputError(
            path, f"camera {name!r}: image size {size.tolist()} is not two whole pixels", line
        )
    return K, dist, R, t, (int(size[0]), int(size[1]))


def _rig_from(cams: list[tuple], names: list[str], path=None) -> Rig:
    if len(set(names)) != len(names):
        raise MocapInputError(path, f"camera names repeat: {names}")
    return Rig(
        K=np.stack([c[0] for c in cams]),
        dist=np.stack([c[1] for c in cams]),
        R=np.stack([c[2] for c in cams]),
        t=np.stack([c[3] for c in cams]),
        names=tuple(names),
        image_size=tuple(c[4] for c in cams),
    )


# ---------------------------------------------------------------------------------------------------------------
# OpenCV FileStorage (YAML / XML)


def _cv_message(e: BaseException) -> tuple[str, int | None]:
    """Message and line of a ``cv2.error`` (the bindings sometimes raise SystemError with it as the cause)."""
    while isinstance(e, SystemError) and e.__cause__ is not None:
        e = e.__cause__
    msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    m = re.search(r"in function '[^']*\((\d+)\):\s*([^']*)'", msg)
    if m:
        return m.group(2).strip() or msg, int(m.group(1))
    m = re.search(r"error: \([-\d]+:[^)]*\) (.*)$", msg)
    return (m.group(1) if m else msg), None


def load_opencv_storage(path: str | os.PathLike, translation_scale: float = 1.0) -> Rig:
    """OpenCV ``FileStorage`` calibration (YAML or XML), read with ``cv2.FileStorage``.

    Understood layouts:

    * single camera (``calibration.cpp`` sample): ``camera_matrix``, ``distortion_coefficients`` and optionally
      ``image_width``/``image_height``; the camera sits at the world origin (``R = I``, ``t = 0``);
    * stereo pair (``stereo_calib.cpp`` sample): ``M1 D1 M2 D2`` with ``R T`` from the same file or, if absent,
      from a sibling ``extrinsics.yml``/``.yaml``/``.xml``; camera 1 is the world frame, camera 2 has ``R, T``
      (``T`` is in calibration-pattern units: multiply by ``translation_scale`` to get metres). Without any
      ``R T`` both cameras sit at the origin.
    """
    text = _read_text(path)
    fs = _open_storage(path, text)
    opened = [fs]
    try:
        try:
            root = fs.root()
            keys = set(root.keys()) if root.isMap() else set()
        except (cv2.error, *_CV_EXCEPTIONS) as e:
            raise MocapInputError(path, f"cannot read the top-level map: {_cv_message(e)[0]}") from None
        if "camera_matrix" in keys:
            K = _fs_mat(fs, path, text, "camera_matrix")
            D = _fs_mat(fs, path, text, "distortion_coefficients", optional=True)
            D = np.zeros(5) if D is None else D.reshape(-1)
            w = _fs_real(fs, path, text, "image_width")
            h = _fs_real(fs, path, text, "image_height")
            line = _line_of(text, r"camera_matrix")
            cam = _checked_camera(path, line, "cam0", K, D, np.eye(3), np.zeros(3), (w or 0, h or 0))
            return _rig_from([cam], ["cam0"], path)
        if {"M1", "M2"} <= keys:
            ext_fs, ext_path, ext_text = fs, path, text
            if "R" not in keys:
                sib = _sibling_extrinsics(path)
                if sib is not None:
                    ext_path, ext_text = sib, _read_text(sib)
                    ext_fs = _open_storage(sib, ext_text)
                    opened.append(ext_fs)
            R = _fs_mat(ext_fs, ext_path, ext_text, "R", optional=True)
            T = _fs_mat(ext_fs, ext_path, ext_text, "T", optional=True)
            if (R is None) != (T is None):
                raise MocapInputError(ext_path, "extrinsics need both R and T")
            if R is None:
                R, T = np.eye(3), np.zeros(3)
            elif R.size == 3:
                R = rodrigues(
                    _as_array(R.reshape(3), lambda s: True, "R", ext_path, _line_of(ext_text, r"\bR\b"))
                )
            T = T.reshape(-1) * float(translation_scale)
            w = _fs_real(fs, path, text, "image_width") or 0
            h = _fs_real(fs, path, text, "image_height") or 0
            cams = []
            for i, (Rk, Tk) in enumerate([(np.eye(3), np.zeros(3)), (R, T)], start=1):
                Ki = _fs_mat(fs, path, text, f"M{i}")
                Di = _fs_mat(fs, path, text, f"D{i}", optional=True)
                Di = np.zeros(5) if Di is None else Di.reshape(-1)
                cams.append(
                    _checked_camera(path, _line_of(text, rf"\bM{i}\b"), f"cam{i}", Ki, Di, Rk, Tk, (w, h))
                )
            return _rig_from(cams, ["cam1", "cam2"], path)
        raise MocapInputError(path, "no camera_matrix or M1/M2 entries: not an OpenCV camera calibration")
    finally:
        for f in opened:
            f.release()


def _open_storage(path, text: str):
    if not text.lstrip().startswith(("%YAML", "<?xml", "<opencv_storage")):
        raise MocapInputError(path, "not an OpenCV FileStorage file (no %YAML or <?xml header)", 1)
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, *_CV_EXCEPTIONS) as e:
        msg, line = _cv_message(e)
        raise MocapInputError(path, f"OpenCV cannot parse it: {msg}", line) from None
    if not fs.isOpened():
        raise MocapInputError(path, "OpenCV cannot open it as FileStorage")
    return fs


def _fs_mat(fs, path, text, key: str, optional: bool = False) -> np.ndarray | None:
    line = _line_of(text, rf"(^|\s|<){re.escape(key)}(\s*:|[\s>])")
    try:
        node = fs.getNode(key)
        if node.empty() or node.isNone():
            if optional:
                return None
            raise MocapInputError(path, f"missing entry {key!r}")
        if node.isSeq():
            vals = [node.at(i).real() for i in range(node.size())]
            if not all(node.at(i).isReal() or node.at(i).isInt() for i in range(node.size())):
                raise MocapInputError(path, f"{key!r} is not a list of numbers", line)
            m = np.asarray(vals, dtype=np.float64)
        else:
            m = node.mat()
    except (cv2.error, *_CV_EXCEPTIONS) as e:
        if isinstance(e, MocapInputError):
            raise
        msg, _ = _cv_message(e)
        raise MocapInputError(path, f"cannot read {key!r}: {msg}", line) from None
    if m is None or not isinstance(m, np.ndarray):
        raise MocapInputError(path, f"{key!r} is not a matrix", line)
    m = np.asarray(m, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        raise MocapInputError(path, f"{key!r} has non-finite values", line)
    if key.startswith(("camera_matrix", "M")) or key == "R":
        if m.size not in ((3, 9) if key == "R" else (9,)):
            raise MocapInputError(path, f"{key!r} has {m.size} entries", line)
        m = m.reshape(3, 3) if m.size == 9 else m
    return m


def _fs_real(fs, path, text, key: str) -> float | None:
    try:
        node = fs.getNode(key)
        if node.empty() or node.isNone():
            return None
        if not (node.isInt() or node.isReal()):
            raise MocapInputError(path, f"{key!r} is not a number", _line_of(text, re.escape(key)))
        return float(node.real())
    except (cv2.error, *_CV_EXCEPTIONS) as e:
        if isinstance(e, MocapInputError):
            raise
        msg, _ = _cv_message(e)
        raise MocapInputError(path, f"cannot read {key!r}: {msg}", _line_of(text, re.escape(key))) from None


def _sibling_extrinsics(path) -> str | None:
    folder = os.path.dirname(os.fspath(path))
    for name in ("extrinsics.yml", "extrinsics.yaml", "extrinsics.xml"):
        p = os.path.join(folder, name)
        if os.path.isfile(p):
            return p
    return None


# ---------------------------------------------------------------------------------------------------------------
# TOML: Pose2Sim / OpenCV layout and caliscope


def _parse_toml(path, text: str) -> dict:
    try:
        return tomllib.loads(text)
    except RecursionError:
        raise MocapInputError(path, "invalid TOML: nested too deeply") from None
    except tomllib.TOMLDecodeError as e:
        m = re.search(r"\(at line (\d+), column \d+\)", str(e))
        line = int(m.group(1)) if m else getattr(e, "lineno", None)
        msg = re.sub(r"\s*\(at line \d+, column \d+\)", "", str(e)) or "invalid TOML"
        raise MocapInputError(path, f"invalid TOML: {msg}", line) from None


def _table_line(text: str, dotted: str) -> int | None:
    parts = dotted.split(".")
    pat = r"^\s*\[\s*" + r"\s*\.\s*".join(r"[\"']?" + re.escape(p) + r"[\"']?" for p in parts) + r"\s*\]"
    return _line_of(text, pat)


def _key_line(text: str, table_line: int | None, key: str) -> int | None:
    if table_line is None:
        return None
    return _line_of(text, r"^\s*[\"']?" + re.escape(key) + r"[\"']?\s*=", table_line) or table_line


def _toml_camera(path, text: str, table: str, cam: dict, name: str) -> tuple:
    tl = _table_line(text, table)
    for key in ("matrix", "distortions", "rotation", "translation"):
        if key not in cam:
            raise MocapInputError(path, f"camera table [{table}] has no {key!r}", tl)
    if cam.get("fisheye", False) is True:
        raise MocapInputError(
            path, f"camera [{table}] is a fisheye camera: not supported", _key_line(text, tl, "fisheye")
        )
    rot_line = _key_line(text, tl, "rotation")
    rot = _as_array(
        cam["rotation"], lambda s: s in ((3,), (3, 3)), f"camera {name!r}: rotation", path, rot_line
    )
    R = rodrigues(rot) if rot.shape == (3,) else rot
    size = cam.get("size", (0, 0))
    return _checked_camera(path, tl, name, cam["matrix"], cam["distortions"], R, cam["translation"], size)


def load_pose2sim_toml(path: str | os.PathLike) -> Rig:
    """Pose2Sim / OpenCV-layout TOML: one table per camera with ``name``, ``size = [w, h]``, ``matrix`` (K),
    ``distortions`` (4 or 5 OpenCV terms), ``rotation`` (Rodrigues vector world→camera, or a 3×3 matrix),
    ``translation`` (metres) and ``fisheye`` (must be false). A ``[metadata]`` table is skipped."""
    text = _read_text(path)
    data = _parse_toml(path, text)
    cams, names = [], []
    for key, cam in data.items():
        if key == "metadata":
            continue
        if not isinstance(cam, dict):
            raise MocapInputError(
                path, f"top-level entry {key!r} is not a camera table", _key_line(text, 1, key)
            )
        name = cam.get("name", key)
        if not isinstance(name, str):
            raise MocapInputError(path, f"camera [{key}]: name is not a string", _table_line(text, key))
        cams.append(_toml_camera(path, text, key, cam, name))
        names.append(name)
    if not cams:
        raise MocapInputError(path, "no camera tables")
    return _rig_from(cams, names, path)


def load_caliscope_toml(path: str | os.PathLike, include_ignored: bool = False) -> Rig:
    """caliscope ``camera_array.toml``: tables ``[cameras.N]`` with ``size = [w, h]``, ``matrix``, 5-term
    ``distortions``, ``rotation`` (3×3 world→camera matrix) and ``translation`` (metres).

    ``rotation_count`` (90° steps) only rotates caliscope's display of the frames; the intrinsics and the 2D
    detections refer to the unrotated sensor image, so it does not enter the model. Cameras marked
    ``ignore = true`` are left out unless ``include_ignored``. Cameras are named ``cam_<cam_id>``.
    """
    text = _read_text(path)
    data = _parse_toml(path, text)
    cameras = data.get("cameras")
    if not isinstance(cameras, dict) or not cameras:
        raise MocapInputError(path, "no [cameras.N] tables: not a caliscope camera array")
    cams, names = [], []
    for key, cam in cameras.items():
        table = f"cameras.{key}"
        if not isinstance(cam, dict):
            raise MocapInputError(path, f"[{table}] is not a table", _table_line(text, table))
        if cam.get("ignore", False) is True and not include_ignored:
            continue
        cam_id = cam.get("cam_id", key)
        if not isinstance(cam_id, int | str) or isinstance(cam_id, bool):
            raise MocapInputError(path, f"[{table}]: cam_id is not an integer", _table_line(text, table))
        name = f"cam_{cam_id}"
        cams.append(_toml_camera(path, text, table, cam, name))
        names.append(name)
    if not cams:
        raise MocapInputError(path, "no usable cameras")
    return _rig_from(cams, names, path)


# ---------------------------------------------------------------------------------------------------------------
# PARSEC / Bouguet .cal


_PARSEC_IMAGE_SIZE = (640, 480)


def _load_bouguet_cal(path, scale: float, image_size: tuple[int, int]) -> tuple:
    """One Bouguet-toolbox ``.cal`` file: fc(2) cc(2) alpha_c kc(5) Rc_ext(9, row-major) Tc_ext(3) omc_ext(3)."""
    text = _read_text(path)
    vals, lines = [], []
    for i, raw in enumerate(text.splitlines(), start=1):
        for tok in raw.split():
            try:
                v = float(tok)
            except ValueError:
                raise MocapInputError(path, f"{tok[:40]!r} is not a number", i) from None
            if not math.isfinite(v):
                raise MocapInputError(path, f"non-finite value {tok[:40]!r}", i)
            vals.append(v)
            lines.append(i)
    if len(vals) < 25:
        raise MocapInputError(
            path, f"truncated: expected 25 numbers, found {len(vals)}", len(text.splitlines()) or 1
        )
    if len(vals) > 25:
        raise MocapInputError(path, f"expected 25 numbers, found {len(vals)}", lines[25])
    fc, cc, alpha, kc = vals[0:2], vals[2:4], vals[4], vals[5:10]
    R = np.asarray(vals[10:19]).reshape(3, 3)
    T = np.asarray(vals[19:22]) * scale
    K = [[fc[0], alpha * fc[0], cc[0]], [0.0, fc[1], cc[1]], [0.0, 0.0, 1.0]]
    name = os.path.splitext(os.path.basename(os.fspath(path)))[0]
    return _checked_camera(path, lines[10], name, K, kc, R, T, image_size), name


def load_parsec_calibration(
    dir_or_files: str | os.PathLike | Sequence[str | os.PathLike],
    units: str = "m",
    image_size: tuple[int, int] = _PARSEC_IMAGE_SIZE,
) -> Rig:
    """PARSEC bodytrack / Bouguet ``.cal`` cameras.

    ``dir_or_files``: a sequence folder (with ``CALIB/``), a ``CALIB/`` folder (``Camera1.cal …`` in numeric
    order), one ``.cal`` file or a list of them. Each file holds 25 numbers in the Bouguet toolbox order
    ``fc(2) cc(2) alpha_c kc(5) Rc_ext(9, row-major) Tc_ext(3) omc_ext(3)`` (bodytrack's ``CameraModel.cpp``):
    ``K = [[fc_x, alpha_c fc_x, cc_x], [0, fc_y, cc_y], [0, 0, 1]]`` (skew kept), ``dist = kc`` (Bouguet's
    order is OpenCV's), ``R = Rc_ext``, ``t = Tc_ext``. The PARSEC world is z-up in millimetres: ``units="m"``
    converts ``t`` to metres, ``units="mm"`` keeps millimetres (for parity with the C++ reference). The unused
    ``omc_ext`` is read but ignored. Images are 640×480 with rows from the top.
    """
    if units not in ("m", "mm"):
        raise ValueError(f"units must be 'm' or 'mm', not {units!r}")
    scale = 1e-3 if units == "m" else 1.0
    if isinstance(dir_or_files, str | os.PathLike):
        p = os.fspath(dir_or_files)
        if os.path.isdir(p):
            if os.path.isdir(os.path.join(p, "CALIB")):
                p = os.path.join(p, "CALIB")
            files = [os.path.join(p, f) for f in os.listdir(p) if f.lower().endswith(".cal")]
            if not files:
                raise MocapInputError(p, "no .cal files in this folder")

            def order(f):
                m = re.search(r"(\d+)\D*$", os.path.basename(f))
                return (int(m.group(1)) if m else -1, os.path.basename(f))

            files.sort(key=order)
        else:
            files = [p]
    else:
        files = [os.fspath(f) for f in dir_or_files]
        if not files:
            raise ValueError("no .cal files given")
    cams, names = [], []
    for f in files:
        cam, name = _load_bouguet_cal(f, scale, image_size)
        cams.append(cam)
        names.append(name)
    return _rig_from(cams, names, files[0] if len(files) == 1 else os.path.dirname(files[0]))


# ---------------------------------------------------------------------------------------------------------------
# Qualisys QCA (XML)


def load_qualisys_qca(path: str | os.PathLike) -> Rig:
    """Qualisys QTM calibration export (``Calib.qca.txt``, XML).

    Per camera: intrinsics in 1/64 pixel, ``fx = focalLengthU/64``, ``cx = centerPointU/64 − fov_video.left``
    (and likewise for v, with ``top``); distortion ``[radialDistortion1, radialDistortion2, tangentalDistortion1,
    tangentalDistortion2, radialDistortion3]`` as given; ``<transform>`` is the camera pose in the world (mm) with
    ``Rq = [r11 … r33]`` row-major, and the OpenCV world→camera model is ``R = diag(1, −1, −1) Rq``,
    ``t = −R (x, y, z)/1000`` (z-up world, metres). Image size from ``fov_video``. Cameras with a non-zero
    ``viewrotation`` are not supported.
    """
    text = _read_text(path)
    try:
        root = ET.fromstring(text.encode("utf-8"))
    except ET.ParseError as e:
        line = e.position[0] if getattr(e, "position", None) else None
        raise MocapInputError(path, f"invalid XML: {e}", line) from None
    except (LookupError, ValueError, RecursionError) as e:  # e.g. an unknown encoding in the declaration
        raise MocapInputError(path, f"invalid XML: {e}", 1) from None
    if root.tag != "calibration":
        raise MocapInputError(
            path, f"root element is <{root.tag[:40]}>, not <calibration>: not a Qualisys QCA file"
        )
    cam_nodes = root.findall("./cameras/camera")
    if not cam_nodes:
        raise MocapInputError(path, "no <camera> elements")
    cams, names = [], []
    for k, cam in enumerate(cam_nodes):
        name = cam.get("serial") or f"cam{k + 1}"
        line = (
            _line_of(text, r"<camera\b[^>]*serial=\"" + re.escape(name) + '"') if cam.get("serial") else None
        )

        def num(elem, attr, name=name, line=line):
            if elem is None:
                raise MocapInputError(path, f"camera {name!r}: missing element", line)
            s = elem.get(attr)
            try:
                v = float(s)
            except (TypeError, ValueError):
                raise MocapInputError(
                    path, f"camera {name!r}: attribute {attr!r} missing or not a number", line
                ) from None
            if not math.isfinite(v):
                raise MocapInputError(path, f"camera {name!r}: attribute {attr!r} is not finite", line)
            return v

        if cam.get("viewrotation", "0") not in ("0", "0.0"):
            raise MocapInputError(path, f"camera {name!r}: viewrotation is not supported", line)
        fov = cam.find("fov_video")
        intr = cam.find("intrinsic")
        tr = cam.find("transform")
        left, top, right, bottom = (num(fov, a) for a in ("left", "top", "right", "bottom"))
        fx, fy = num(intr, "focalLengthU") / 64.0, num(intr, "focalLengthV") / 64.0
        cx, cy = num(intr, "centerPointU") / 64.0 - left, num(intr, "centerPointV") / 64.0 - top
        skew = num(intr, "skew") if intr is not None and intr.get("skew") is not None else 0.0
        dist = [
            num(intr, "radialDistortion1"),
            num(intr, "radialDistortion2"),
            num(intr, "tangentalDistortion1"),
            num(intr, "tangentalDistortion2"),
            num(intr, "radialDistortion3") if intr.get("radialDistortion3") is not None else 0.0,
        ]
        Rq = np.asarray([num(tr, f"r{i}{j}") for i in (1, 2, 3) for j in (1, 2, 3)]).reshape(3, 3)
        pos = np.asarray([num(tr, a) for a in ("x", "y", "z")]) / 1000.0
        R = np.diag([1.0, -1.0, -1.0]) @ Rq
        t = -R @ pos
        K = [[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]
        size = (right - left + 1, bottom - top + 1)
        cams.append(_checked_camera(path, line, name, K, dist, R, t, size))
        names.append(name)
    return _rig_from(cams, names, path)


# ---------------------------------------------------------------------------------------------------------------
# Auto-detection and writing


def load_calibration(path: str | os.PathLike | Sequence[str | os.PathLike]) -> Rig:
    """Load a calibration, detecting its format (metres, z-up world as stored).

    * a folder, a ``.cal`` file or a list of ``.cal`` files: PARSEC / Bouguet (:func:`load_parsec_calibration`,
      converted to metres);
    * ``.toml``: caliscope if it has ``[cameras.N]`` tables (:func:`load_caliscope_toml`), otherwise Pose2Sim
      (:func:`load_pose2sim_toml`);
    * XML whose root is ``<calibration>``: Qualisys QCA (:func:`load_qualisys_qca`);
    * other YAML/XML: OpenCV FileStorage (:func:`load_opencv_storage`).
    """
    if not isinstance(path, str | os.PathLike):
        return load_parsec_calibration(path)
    p = os.fspath(path)
    if os.path.isdir(p) or p.lower().endswith(".cal"):
        return load_parsec_calibration(p)
    text = _read_text(p)
    head = text.lstrip()[:4096]
    if p.lower().endswith(".toml"):
        data = _parse_toml(p, text)
        if isinstance(data.get("cameras"), dict):
            return load_caliscope_toml(p)
        return load_pose2sim_toml(p)
    if head.startswith("%YAML") or head.startswith("<opencv_storage") or "<opencv_storage" in head:
        return load_opencv_storage(p)
    if head.startswith("<") and re.search(r"<calibration[\s>]", head):
        return load_qualisys_qca(p)
    if re.match(r"^\s*\[", text):
        data = _parse_toml(p, text)
        if isinstance(data.get("cameras"), dict):
            return load_caliscope_toml(p)
        return load_pose2sim_toml(p)
    raise MocapInputError(p, "unknown calibration format (expected OpenCV YAML/XML, TOML, QCA or .cal)", 1)


def save_calibration(path: str | os.PathLike, rig: Rig) -> None:
    """Write ``rig`` as a Pose2Sim-layout TOML (readable by Pose2Sim, by :func:`load_calibration` and directly
    usable with ``cv2.projectPoints``): one table per camera with ``name``, ``size = [w, h]``, ``matrix`` (K; a
    non-zero skew is kept in ``matrix[0][1]``, which ``cv2.projectPoints`` ignores), ``distortions`` (5 OpenCV
    terms), ``rotation`` (Rodrigues vector world→camera), ``translation`` (metres) and ``fisheye = false``, then
    Pose2Sim's ``[metadata]`` table."""
    import tomli_w

    K, dist, R, t = (np.asarray(a, dtype=np.float64) for a in (rig.K, rig.dist, rig.R, rig.t))
    doc: dict = {}
    for v, name in enumerate(rig.names):
        if name in doc or name == "metadata":
            raise ValueError(f"camera name {name!r} is repeated or reserved")
        w, h = rig.image_size[v]
        doc[name] = {
            "name": name,
            "size": [float(w), float(h)],
            "matrix": K[v].tolist(),
            "distortions": dist[v].tolist(),
            "rotation": _rotation_vector(R[v]).tolist(),
            "translation": t[v].tolist(),
            "fisheye": False,
        }
    doc["metadata"] = {"adjusted": False, "error": 0.0}
    with open(path, "wb") as f:
        tomli_w.dump(doc, f)
