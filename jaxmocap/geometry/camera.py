"""Calibrated camera rigs: pinhole projection with OpenCV distortion, image scaling, triangulation.

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

The calibration files that give a rig are read and written by :mod:`jaxmocap.io.calibration`.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from jaxmocap.stored_programs import stored_jit
from jaxmocap.transfer import to_device

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
    "camera_centres_host",
    "projection_matrices",
    "undistort_points",
    "triangulate",
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
            K=to_device(self.K, dtype),
            dist=to_device(self.dist, dtype),
            R=to_device(self.R, dtype),
            t=to_device(self.t, dtype),
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
    and ``depth = zc`` (for callers that compose the camera with another transform first).

    Differentiated through its own JVP (:func:`_pixels`): the 2×3 Jacobian of each point's pixel in its camera
    coordinates is written out, so a reverse pass costs six products per point instead of the reversed chain of
    the distortion polynomial.
    """
    dt = zc.dtype
    u, v = _pixels(jnp.asarray(rig.K, dt), jnp.asarray(rig.dist, dt), xc, yc, zc)
    return jnp.stack([u, v], -1), zc


def _pixels_plain(K, dist, xc, yc, zc):
    inv_z = 1.0 / zc
    ad, bd = _distort(dist, xc * inv_z, yc * inv_z)
    u = _col(K[:, 0, 0]) * ad + _col(K[:, 0, 1]) * bd + _col(K[:, 0, 2])
    v = _col(K[:, 1, 1]) * bd + _col(K[:, 1, 2])
    return u, v


@jax.custom_jvp
def _pixels(K, dist, xc, yc, zc):
    """``(u, v)``, each ``(..., V, P)``, of camera-frame points (module docstring's model; ``K (V, 3, 3)``,
    ``dist (V, 5)``)."""
    return _pixels_plain(K, dist, xc, yc, zc)


@functools.partial(_pixels.defjvp, symbolic_zeros=True)
def _pixels_jvp(primals, tangents):
    """With ``a = x_c/z_c``, ``b = y_c/z_c``, ``ρ = 1 + k1 r² + k2 r⁴ + k3 r⁶`` and ``ρ' = dρ/d(r²)``:

        ∂a_d/∂a = ρ + 2a²ρ' + 2p1 b + 6p2 a        ∂a_d/∂b = 2abρ' + 2p1 a + 2p2 b
        ∂b_d/∂a = 2abρ' + 2p1 a + 2p2 b            ∂b_d/∂b = ρ + 2b²ρ' + 6p1 b + 2p2 a

    ``da = (dx_c − a dz_c)/z_c``, ``db = (dy_c − b dz_c)/z_c``, ``du = fx da_d + s db_d``, ``dv = fy db_d``.
    Tangents of the intrinsics or the distortion (camera calibration) take the automatic derivative instead.
    """
    K, dist, xc, yc, zc = primals
    tK, tdist, tx, ty, tz = tangents
    if not (isinstance(tK, SymbolicZero) and isinstance(tdist, SymbolicZero)):
        dense = tuple(
            jnp.zeros_like(p) if isinstance(t, SymbolicZero) else t
            for p, t in zip(primals, tangents, strict=True)
        )
        return jax.jvp(_pixels_plain, primals, dense)
    k1, k2, p1, p2, k3 = (_col(dist[:, i]) for i in range(5))
    inv_z = 1.0 / zc
    a = xc * inv_z
    b = yc * inv_z
    a2, b2, ab = a * a, b * b, a * b
    r2 = a2 + b2
    rho = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    drho = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    fx, s, fy = _col(K[:, 0, 0]), _col(K[:, 0, 1]), _col(K[:, 1, 1])
    off = 2.0 * ab * drho + 2.0 * p1 * a + 2.0 * p2 * b  # ∂a_d/∂b = ∂b_d/∂a
    daa = rho + 2.0 * a2 * drho + 2.0 * p1 * b + 6.0 * p2 * a
    dbb = rho + 2.0 * b2 * drho + 6.0 * p1 * b + 2.0 * p2 * a
    dz = 0.0 if isinstance(tz, SymbolicZero) else tz
    da = ((0.0 if isinstance(tx, SymbolicZero) else tx) - a * dz) * inv_z
    db = ((0.0 if isinstance(ty, SymbolicZero) else ty) - b * dz) * inv_z
    dad = daa * da + off * db
    dbd = off * da + dbb * db
    return _pixels_plain(K, dist, xc, yc, zc), (fx * dad + s * dbd, fy * dbd)


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
    return jnp.stack(_pixels(K, dist, xc, yc, zc), -1)


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


def camera_centres_host(rig: Rig) -> np.ndarray:
    """:func:`camera_centres` in NumPy, float64 ``(V, 3)``: for host code, where the two small programs of the
    JAX form (traced, lowered and looked up in the compilation cache on every start) would cost more than the
    arithmetic."""
    R = np.asarray(rig.R, np.float64)
    t = np.asarray(rig.t, np.float64)
    return -np.einsum("vji,vj->vi", R, t)


def projection_matrices(rig: Rig, normalised: bool = False) -> jnp.ndarray:
    """``(V, 3, 4)`` matrices ``K [R | t]`` (or ``[R | t]`` if ``normalised``), without distortion."""
    Rt = jnp.concatenate([jnp.asarray(rig.R), jnp.asarray(rig.t)[:, :, None]], -1)
    if normalised:
        return Rt
    return jnp.einsum("vij,vjk->vik", jnp.asarray(rig.K), Rt)


# ---------------------------------------------------------------------------------------------------------------
# Undistortion and triangulation


@functools.partial(jax.jit, static_argnames=("fixed_point_iterations", "newton_iterations", "normalised"))
def undistort_points(
    rig: Rig, uv, fixed_point_iterations: int = 5, newton_iterations: int = 3, normalised: bool = True
) -> jnp.ndarray:
    """Remove lens distortion from pixel observations. ``uv (..., V, 2) -> (..., V, 2)``.

    Returns normalised coordinates ``(x_c/z_c, y_c/z_c)`` (or, with ``normalised=False``, the ideal pinhole pixels
    ``K [a, b, 1]``). The distorted normalised point ``(a_d, b_d) = K⁻¹ [u, v, 1]`` is inverted through the
    distortion model by ``fixed_point_iterations`` of OpenCV's iteration (``cv::undistortPoints``: ``a ← (a_d −
    Δa(a, b)) / L(r²)``, 5 by default as OpenCV's default criteria), then ``newton_iterations`` Newton steps on
    the 2×2 system ``distort(a, b) = (a_d, b_d)`` with the analytic Jacobian, which converge quadratically from
    there (to ~1e-12 in float64 inside the monotone part of the model). Fixed counts keep it jit-able and
    differentiable. Compiled as one program per shape (the iterations are ~130 elementwise operations: called
    eagerly they would be dispatched one by one).
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
    if normalised:
        return jnp.stack([a, b], -1)
    return jnp.stack([fx * a + s * b + cx, fy * b + cy], -1)


@stored_jit
def triangulate(rig: Rig, uv, weights=None) -> jnp.ndarray:
    """Linear (DLT) triangulation of one point per ``...`` from its views. ``uv (..., V, 2) -> (..., 3)``.

    The observations are undistorted first (:func:`undistort_points`) to normalised coordinates ``(a_v, b_v)``;
    each view contributes the rows ``w_v (a_v P_v³ − P_v¹)`` and ``w_v (b_v P_v³ − P_v²)`` with ``P_v = [R_v|t_v]``
    (Hartley & Zisserman §12.2), and the point is the right singular vector of the smallest singular value,
    de-homogenised. ``weights (..., V)`` scale the rows (0 drops a view; default all 1). Where fewer than two views
    have a positive weight the result is NaN. Compiled as one program per shape, like :func:`undistort_points`
    (and its trace kept on disk by a run of the command line, :func:`jaxmocap.stored_programs.stored_jit`):
    triangulate many points in one call (the leading axes), not one call per point.
    """
    uv = _float_points(uv)
    dt = uv.dtype
    ab = undistort_points(rig, uv)
    P = projection_matrices(rig, normalised=True).astype(dt)  # (V, 3, 4)
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
