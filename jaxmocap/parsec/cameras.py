"""PARSEC / Bouguet cameras in millimetres and bodytrack's projection (``jaxmocap/parsec/FORMAT.md`` §6.3)."""

from __future__ import annotations

import os
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxmocap.parsec.files import MM_PER_M, load_parsec_calibration

__all__ = ["Cameras", "cameras_from_rig", "load_cameras", "project"]


def _trail(a: jnp.ndarray, nb: int) -> jnp.ndarray:
    """``a`` with ``nb`` trailing singleton axes (to broadcast against trailing batch axes)."""
    return jnp.reshape(a, jnp.shape(a) + (1,) * nb)


class Cameras(NamedTuple):
    """PARSEC / Bouguet cameras, ``V`` of them, millimetres (a pytree).

    ``fc (V, 2)``, ``cc (V, 2)`` pixels; ``alpha (V,)`` skew; ``kc (V, 5)`` distortion; ``R (V, 3, 3)``
    world→camera and ``T (V, 3)`` mm with ``X_c = R X + T``; ``eye (V, 3)`` the camera centre ``−Rᵀ T`` in mm.
    """

    fc: jnp.ndarray
    cc: jnp.ndarray
    alpha: jnp.ndarray
    kc: jnp.ndarray
    R: jnp.ndarray
    T: jnp.ndarray
    eye: jnp.ndarray

    @property
    def num_views(self) -> int:
        return int(np.shape(self.fc)[0])

    def astype(self, dtype) -> Cameras:
        return Cameras(*(jnp.asarray(a, dtype) for a in self))


def cameras_from_rig(rig, units: str = "m") -> Cameras:
    """:class:`Cameras` (mm) from a :class:`jaxmocap.geometry.camera.Rig` whose translations are in ``units`` ("m" or
    "mm"). The rig's OpenCV ``[k1, k2, p1, p2, k3]`` is Bouguet's ``kc`` in the same order."""
    if units not in ("m", "mm"):
        raise ValueError(f"units must be 'm' or 'mm', not {units!r}")
    K = np.asarray(rig.K, dtype=np.float64)
    R = np.asarray(rig.R, dtype=np.float64)
    T = np.asarray(rig.t, dtype=np.float64) * (MM_PER_M if units == "m" else 1.0)
    fc = np.stack([K[:, 0, 0], K[:, 1, 1]], -1)
    cc = np.stack([K[:, 0, 2], K[:, 1, 2]], -1)
    alpha = K[:, 0, 1] / K[:, 0, 0]
    eye = -np.einsum("vji,vj->vi", R, T)
    return Cameras(fc, cc, alpha, np.asarray(rig.dist, dtype=np.float64), R, T, eye)


def load_cameras(path: str | os.PathLike) -> Cameras:
    """The ``.cal`` cameras of a sequence folder, a ``CALIB`` folder or one ``.cal`` file, in mm (float64)."""
    return cameras_from_rig(load_parsec_calibration(path, units="mm"), units="mm")


def project(cams: Cameras, X: jnp.ndarray) -> jnp.ndarray:
    """bodytrack's ``ProjectPoints`` (§6.3) of world points ``X (..., P, 3)`` mm → ``(..., V, P, 2)`` pixels.

    ``x = X_c.x / X_c.z``, ``y = X_c.y / X_c.z``, ``d = 1 + kc0 r² + kc1 r⁴ + kc4 r⁶``,
    ``xd = d x + kc2 (2xy) + kc2 (r² + 2x²)``, ``yd = d y + kc2 (r² + 2y²) + kc2 (2xy)`` (bodytrack uses ``kc[2]``
    for both tangential terms; PARSEC's cameras have ``kc2 = kc3 = 0``), ``u = fc.x (xd + α yd) + cc.x``,
    ``v = fc.y yd + cc.y``. Equals OpenCV's model with ``[k1, k2, p1, p2, k3]`` and skew where ``kc2 = kc3 = 0``.
    """
    X = jnp.asarray(X)
    dt = X.dtype
    c = cams.astype(dt)
    x, y, z = X[..., None, :, 0], X[..., None, :, 1], X[..., None, :, 2]
    u, v = _project_xyz(c, x, y, z)
    return jnp.stack([u, v], -1)


def _project_xyz(c: Cameras, x, y, z, nb: int = 1):
    """Per-coordinate projection; ``x, y, z`` broadcast against ``(V, *1)`` camera columns (``nb`` ones)."""
    _col = lambda a: _trail(a, nb)
    R, T = c.R, c.T
    xc = _col(R[:, 0, 0]) * x + _col(R[:, 0, 1]) * y + _col(R[:, 0, 2]) * z + _col(T[:, 0])
    yc = _col(R[:, 1, 0]) * x + _col(R[:, 1, 1]) * y + _col(R[:, 1, 2]) * z + _col(T[:, 1])
    zc = _col(R[:, 2, 0]) * x + _col(R[:, 2, 1]) * y + _col(R[:, 2, 2]) * z + _col(T[:, 2])
    inv_z = 1.0 / zc
    px = inv_z * xc
    py = inv_z * yc
    r2 = px * px + py * py
    r4 = r2 * r2
    k0, k1, k2, k4 = _col(c.kc[:, 0]), _col(c.kc[:, 1]), _col(c.kc[:, 2]), _col(c.kc[:, 4])
    d = 1.0 + k0 * r2 + k1 * r4 + k4 * (r4 * r2)
    a1 = 2.0 * px * py
    xd = d * px + k2 * a1 + k2 * (r2 + 2.0 * (px * px))
    yd = d * py + k2 * (r2 + 2.0 * (py * py)) + k2 * a1
    xd = xd + _col(c.alpha) * yd
    return _col(c.fc[:, 0]) * xd + _col(c.cc[:, 0]), _col(c.fc[:, 1]) * yd + _col(c.cc[:, 1])
