"""A 3D room around the subject, seen consistently by every camera, and the body's shadow in it.

Room (:func:`make_room`): an axis-aligned box ``[cx ± hx] × [cy ± hy] × [0, height]`` around the clip's centre
``c``, at least :data:`MIN_HALF` m and 1.5 m beyond the farthest camera in each direction. Its four walls carry
the bundled photographs of a real laboratory (each scaled to the wall's height and tiled with mirroring along
it, then optional procedural clutter); the floor is a seeded tiled texture (0.6 m tiles of varying colour, 6 mm
grout, two octaves of smoothed noise: texture for stereo matching, without a licence; cool greys, away from
skin hues); the ceiling is plain.

Every pixel of a view is the first wall, floor or ceiling point along its ray (the calibration's own ray,
:func:`jaxmocap.geometry.render.pixel_rays`), textured by bilinear lookup at 2×2 sub-pixels averaged (against
aliasing far away), and shaded ``albedo · (ROOM_AMBIENT + (1 − ROOM_AMBIENT) max(0, n·l̂))`` under the
synthesiser's light ``l̂``. In shadow the direct term vanishes: ``albedo · ROOM_AMBIENT``.

Shadow (:class:`ShadowCaster`): a camera 20 m away towards the light, looking at the clip's centre (nearly
parallel rays), renders the body's depth each frame (256×256, the exact ray caster); a room point is in shadow
where that depth map, read bilinearly at the point's projection as a coverage fraction, has a body hit nearer
the light than the point (by 5 cm). The empty-scene plate is the room without the body and its shadow.
"""

from __future__ import annotations

import dataclasses
import os
from importlib import resources

import cv2
import numpy as np

from jaxmocap.geometry import render
from jaxmocap.synth.stage import draw_clutter, look_at

__all__ = ["MIN_HALF", "ROOM_AMBIENT", "Room", "RoomView", "ShadowCaster", "make_room", "room_view"]

#: Smallest half-size of the room (m) and its height.
MIN_HALF = 4.0
HEIGHT = 3.0

#: Ambient fraction of the room's shading.
ROOM_AMBIENT = 0.6

_FLOOR_PPM = 200.0  # floor texels per metre
_WALL_PPM = 120.0


@dataclasses.dataclass(frozen=True)
class Room:
    """``lo (3,)`` and ``hi (3,)`` corners of the box; ``walls``: textures ``(h, w, 3)`` float32 in [0, 1] of the
    walls at ``x = lo``, ``x = hi``, ``y = lo``, ``y = hi``; ``floor``, ``ceiling`` textures."""

    lo: np.ndarray
    hi: np.ndarray
    walls: tuple
    floor: np.ndarray
    ceiling: np.ndarray


def _photos() -> list[np.ndarray]:
    base = resources.files("jaxmocap") / "data" / "backgrounds"
    paths = sorted(str(p) for p in base.iterdir() if str(p).lower().endswith((".jpg", ".png")))
    return [cv2.imread(os.fspath(p), cv2.IMREAD_COLOR)[..., ::-1] for p in paths]


def _wall_texture(photo: np.ndarray, length: float, mirror: bool) -> np.ndarray:
    """The photo scaled to the room's height and tiled (alternately mirrored) over ``length`` metres."""
    h = int(round(HEIGHT * _WALL_PPM))
    w_photo = max(1, int(round(photo.shape[1] * h / photo.shape[0])))
    tile = cv2.resize(photo, (w_photo, h), interpolation=cv2.INTER_AREA)
    if mirror:
        tile = tile[:, ::-1]
    n = int(np.ceil(length * _WALL_PPM / w_photo)) + 1
    strip = np.concatenate([tile if k % 2 == 0 else tile[:, ::-1] for k in range(n)], 1)
    return strip[:, : int(round(length * _WALL_PPM)) + 2]


def _floor_texture(rng: np.random.Generator, size_x: float, size_y: float) -> np.ndarray:
    """Tiles of 0.6 m in cool grey shades with dark grout, modulated by two octaves of smoothed noise."""
    w, h = int(round(size_x * _FLOOR_PPM)) + 2, int(round(size_y * _FLOOR_PPM)) + 2
    tile = int(round(0.6 * _FLOOR_PPM))
    nx, ny = w // tile + 1, h // tile + 1
    shades = (
        np.array([0.50, 0.54, 0.58])
        + rng.uniform(-0.08, 0.08, (ny, nx, 1))
        + rng.uniform(-0.015, 0.015, (ny, nx, 3))
    )
    img = np.repeat(np.repeat(shades, tile, 0), tile, 1)[:h, :w].astype(np.float32)
    unit = lambda a: a / max(float(a.std()), 1e-6)
    fine = unit(cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 1.5))
    coarse = unit(cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 12.0))
    img *= (1.0 + 0.09 * fine + 0.08 * coarse)[..., None]
    grout = np.zeros((h, w), bool)
    g = max(1, int(round(0.006 * _FLOOR_PPM)))
    for k in range(0, max(w, h), tile):
        grout[:, k : k + g] = True
        grout[k : k + g, :] = True
    img[grout] = (0.27, 0.28, 0.30)
    return np.clip(img, 0.0, 1.0)


def make_room(centre: np.ndarray, camera_centres: np.ndarray, seed: int, clutter: float = 0.0) -> Room:
    """The room of the module docstring around ``centre (3,)`` enclosing ``camera_centres (V, 3)``."""
    c = np.asarray(centre, np.float64)
    cams = np.asarray(camera_centres, np.float64).reshape(-1, 3)
    half = np.maximum(MIN_HALF, np.abs(cams[:, :2] - c[:2]).max(0) + 1.5)
    lo = np.array([c[0] - half[0], c[1] - half[1], 0.0])
    hi = np.array([c[0] + half[0], c[1] + half[1], max(HEIGHT, float(cams[:, 2].max()) + 0.5)])
    photos = _photos()
    walls = []
    for k, length in enumerate((2 * half[1], 2 * half[1], 2 * half[0], 2 * half[0])):
        tex = _wall_texture(photos[k % len(photos)], length, mirror=k >= len(photos))
        if clutter > 0:
            tex = draw_clutter(np.random.default_rng([int(seed), 1 << 21, k]), tex, float(clutter))
        walls.append(tex.astype(np.float32) / 255.0)
    rng = np.random.default_rng([int(seed), 1 << 21])
    floor = _floor_texture(rng, 2 * half[0], 2 * half[1])
    ceiling = np.full((8, 8, 3), 0.85, np.float32)
    return Room(lo, hi, tuple(walls), floor, ceiling)


@dataclasses.dataclass(frozen=True)
class RoomView:
    """One camera's view of the room: ``lit`` and ``dark`` ``(H, W, 3)`` float32 images (with and without the
    direct light), and ``points (H, W, 3)`` the world point of each pixel centre."""

    lit: np.ndarray
    dark: np.ndarray
    points: np.ndarray

    def image(self, shadow: np.ndarray | None = None) -> np.ndarray:
        """``lit`` where ``shadow (H, W)`` (in [0, 1]) is 0, ``dark`` where it is 1."""
        if shadow is None:
            return self.lit
        s = shadow[..., None].astype(np.float32)
        return self.lit * (1 - s) + self.dark * s


def _hits(room: Room, origin: np.ndarray, d: np.ndarray):
    """Nearest room surface along rays ``origin + τ d`` (``d (N, 3)``): ``(τ (N,), plane (N,))``, planes 0–3 the
    walls (x lo, x hi, y lo, y hi), 4 the floor, 5 the ceiling."""
    taus = []
    for axis, value in (
        (0, room.lo[0]),
        (0, room.hi[0]),
        (1, room.lo[1]),
        (1, room.hi[1]),
        (2, room.lo[2]),
        (2, room.hi[2]),
    ):
        with np.errstate(divide="ignore", invalid="ignore"):
            tau = (value - origin[axis]) / d[:, axis]
        taus.append(np.where(tau > 1e-9, tau, np.inf))
    taus = np.stack(taus, 1)
    plane = np.argmin(taus, 1)
    return taus[np.arange(len(d)), plane], plane


def _lookup(tex: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear texture values ``(N, 3)`` at texel coordinates ``u, v (N,)`` (mirrored past the edges)."""
    n = len(u)
    rows = -(-n // 1024)
    pad = rows * 1024 - n
    shape = lambda a: np.pad(a.astype(np.float32), (0, pad)).reshape(rows, 1024)
    out = cv2.remap(tex, shape(u), shape(v), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return out.reshape(-1, 3)[:n]


def _shade(room: Room, origin: np.ndarray, d: np.ndarray, light: np.ndarray):
    """Albedo ``(N, 3)``, Lambert factor ``(N,)`` and points ``(N, 3)`` of rays ``d (N, 3)`` from ``origin``."""
    tau, plane = _hits(room, origin, d)
    P = origin + tau[:, None] * d
    normals = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)
    albedo = np.zeros((len(d), 3), np.float32)
    for k in range(6):
        sel = plane == k
        if not sel.any():
            continue
        p = P[sel]
        if k < 4:
            along = p[:, 1] - room.lo[1] if k < 2 else p[:, 0] - room.lo[0]
            tex = room.walls[k]
            u, v = along * _WALL_PPM, (room.hi[2] - p[:, 2]) * tex.shape[0] / (room.hi[2] - room.lo[2])
        elif k == 4:
            tex = room.floor
            u, v = (p[:, 0] - room.lo[0]) * _FLOOR_PPM, (p[:, 1] - room.lo[1]) * _FLOOR_PPM
        else:
            tex = room.ceiling
            u, v = np.zeros(len(p)), np.zeros(len(p))
        albedo[sel] = _lookup(tex, u, v)
    lam = np.maximum(0.0, normals[plane] @ light)
    return albedo, lam.astype(np.float32), P


def room_view(room: Room, K, dist, R, t, size: tuple[int, int], light: np.ndarray) -> RoomView:
    """The room seen by one camera (module docstring); ``light (3,)`` unit, towards the light."""
    w, h = int(size[0]), int(size[1])
    K = np.asarray(K, np.float64)
    R = np.asarray(R, np.float64)
    origin = -R.T @ np.asarray(t, np.float64)
    K2 = K.copy()
    K2[:2] *= 2.0
    K2[0, 2] += 0.5
    K2[1, 2] += 0.5
    xy = render.pixel_rays(K2, dist, (2 * w, 2 * h)).reshape(-1, 2).astype(np.float64)
    d = np.concatenate([xy, np.ones((len(xy), 1))], 1) @ R  # Rᵀ (x, y, 1), row form
    albedo, lam, _ = _shade(room, origin, d, light)
    down = lambda a: a.reshape(h, 2, w, 2, -1).mean((1, 3))
    lit = down(albedo * (ROOM_AMBIENT + (1 - ROOM_AMBIENT) * lam)[:, None])
    dark = down(albedo * ROOM_AMBIENT)
    xy1 = render.pixel_rays(K, dist, (w, h)).reshape(-1, 2).astype(np.float64)
    d1 = np.concatenate([xy1, np.ones((len(xy1), 1))], 1) @ R
    tau, _ = _hits(room, origin, d1)
    points = (origin + tau[:, None] * d1).reshape(h, w, 3)
    return RoomView(lit.astype(np.float32), dark.astype(np.float32), points)


class ShadowCaster:
    """The light's camera of the module docstring and each view's lookup into it.

    Args:
      centre: ``(3,)`` point the light camera looks at; radius: metres around it that must stay in its image;
      light: ``(3,)`` unit vector towards the light; views: the :class:`RoomView` of every camera.
    """

    SIZE = 256
    DISTANCE = 20.0

    def __init__(self, centre: np.ndarray, radius: float, light: np.ndarray, views):
        c = np.asarray(centre, np.float64)
        eye = c + self.DISTANCE * np.asarray(light, np.float64)
        self.R, self.t = look_at(eye, c)
        f = 0.5 * (self.SIZE - 2) * self.DISTANCE / max(radius, 0.1)
        self.K = np.array([[f, 0, 0.5 * (self.SIZE - 1)], [0, f, 0.5 * (self.SIZE - 1)], [0, 0, 1.0]])
        self.maps = []
        for view in views:
            P = view.points.reshape(-1, 3) @ self.R.T + self.t
            uv = P[:, :2] / P[:, 2:3] * [f, f] + self.K[:2, 2]
            h, w = view.points.shape[:2]
            self.maps.append(
                (
                    uv[:, 0].reshape(h, w).astype(np.float32),
                    uv[:, 1].reshape(h, w).astype(np.float32),
                    P[:, 2].reshape(h, w),
                )
            )

    def depth(self, prims, caps: str) -> np.ndarray:
        """The body's depth from the light, ``(SIZE, SIZE)``, 0 where it is not."""
        r = render.render_view(
            self.K, None, self.R, self.t, (self.SIZE, self.SIZE), prims, caps=caps, normals=False
        )
        return np.asarray(r.depth, np.float32)

    def shadow(self, depth: np.ndarray, view: int) -> np.ndarray:
        """``(H, W)`` shadow fraction in [0, 1] of view ``view``'s room pixels given the light's ``depth``."""
        u, v, z = self.maps[view]
        cover = cv2.remap((depth > 0).astype(np.float32), u, v, cv2.INTER_LINEAR, borderValue=0.0)
        near = cv2.remap(depth, u, v, cv2.INTER_NEAREST, borderValue=0.0)
        return np.where((near > 0) & (near < z - 0.05), cover, 0.0).astype(np.float32)
