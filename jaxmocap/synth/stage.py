"""The stage of a synthetic sequence: camera rigs placed around the clip, and the backgrounds behind the subject.

Rigs (:func:`preset_rig`), all placed relative to the clip: ``c`` is the centre of the horizontal range of the
root over the rendered frames, ``f̂`` the subject's mean facing direction (``(left hip − right hip) × ẑ``,
horizontal) and ``l̂ = ẑ × f̂`` its left:

* ``stereo``: the IROS 2007 robot head, two parallel cameras 0.30 m apart at 1.3 m height in front of the
  subject (``c + D f̂``), looking at ``c + 1.0 ẑ``; ``D`` is 3.0 m or more, so that every root position stays
  at least 2.5 m away and the whole body stays in both images;
* ``frontal-lateral``: the thesis set-up, one webcam in front (``c + D₁ f̂``) and one on the subject's left
  (``c + D₂ l̂``), at 1.5 m, looking at ``c + 1.0 ẑ`` (a slight down-tilt), ``D`` from 3.0 m (2.0 m minimum),
  mild radial distortion ``k₁ = −0.05``;
* ``ring4``: four cameras at azimuths 45°, 135°, 225°, 315° from ``f̂`` on a 3.5 m radius circle at 2.5 m
  height, looking at ``c + 0.9 ẑ`` (HumanEva / PARSEC-like);
* a calibration file (:func:`jaxmocap.io.calibration.load_calibration`): the cameras as calibrated; the clip is shifted
  horizontally so that ``c`` lies below the point nearest to all optical axes (:func:`place_motion`; the shift
  is in ``meta.json`` as ``world_offset``, and the ground truth is in the calibration's world).

Focal length ``0.8·w`` (64° horizontal field of view), principal point at the image centre. Preset distances
grow in 5 % steps until every joint and end site of every rendered frame projects at least 3 % of the width
inside the image.

Backgrounds (:func:`background_image`): the bundled photographs, a plain wall and floor, or an image file, with
optional procedural clutter drawn from ``numpy.random.default_rng([seed, view])``.
"""

from __future__ import annotations

import math
import os
import pathlib
from importlib import resources

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import body as body_mod
from jaxmocap.geometry import camera

#: The rig presets of :func:`preset_rig`.
PRESETS = ("stereo", "frontal-lateral", "ring4")


# ---------------------------------------------------------------------------------------------------------------
# Rigs


def subject_frame(joints: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(c, f̂, l̂)`` of evaluation joints ``(T, 15, 3)``: centre of the root's horizontal range (``z = 0``),
    mean facing direction ``(left hip − right hip) × ẑ`` (horizontal, unit) and left ``ẑ × f̂``."""
    ev = {n: i for i, n in enumerate(body_mod.EVAL_JOINTS)}
    root = joints[:, ev["root"], :2]
    c = np.array([*(0.5 * (root.min(0) + root.max(0))), 0.0])
    hips = joints[:, ev["left_hip"]] - joints[:, ev["right_hip"]]
    f = np.cross(hips, [0.0, 0.0, 1.0]).mean(0)
    f[2] = 0.0
    n = np.linalg.norm(f)
    f = np.array([1.0, 0.0, 0.0]) if n < 1e-9 else f / n
    return c, f, np.cross([0.0, 0.0, 1.0], f)


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """World → camera ``(R, t)`` of a camera at ``eye`` looking at ``target``: camera ``z`` forward, ``x`` right
    (``z × up``), ``y`` down, ``t = −R eye``."""
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    x = x / np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return R, -R @ eye


def _intrinsics(size: tuple[int, int], focal: float = 0.8) -> np.ndarray:
    w, h = size
    return np.array([[focal * w, 0.0, 0.5 * (w - 1)], [0.0, focal * w, 0.5 * (h - 1)], [0.0, 0.0, 1.0]])


_project = jax.jit(camera.project_with_depth)


def _visible(rig: camera.Rig, points: np.ndarray, margin: float) -> bool:
    """Whether every point projects in front of every camera (``z > 0.3`` m) and at least ``margin · w`` pixels
    inside its image. ``points (P, 3)`` with a fixed ``P`` (one compilation)."""
    uv, z = _project(rig.to_jax(jnp.float32), jnp.asarray(points, jnp.float32))
    uv, z = np.asarray(uv), np.asarray(z)
    for v, (w, h) in enumerate(rig.image_size):
        m = margin * w
        u, vv = uv[v, :, 0], uv[v, :, 1]
        if not (np.all(z[v] > 0.3) and np.all((u >= m) & (u <= w - 1 - m) & (vv >= m) & (vv <= h - 1 - m))):
            return False
    return True


def preset_rig(
    name: str,
    points: np.ndarray,
    joints: np.ndarray,
    size: tuple[int, int] = (640, 480),
    margin: float = 0.03,
) -> camera.Rig:
    """A rig preset (module docstring) placed around a clip.

    Args:
      name: ``"stereo"``, ``"frontal-lateral"`` or ``"ring4"``.
      points: ``(T, P, 3)`` every point that must stay in view (joints and end sites of the rendered frames).
      joints: ``(T, 15, 3)`` evaluation joints (for :func:`subject_frame` and the minimum distance).
      size: ``(w, h)`` of every image.
    """
    c, f, left = subject_frame(joints)
    up = np.array([0.0, 0.0, 1.0])
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    pts = pts[np.round(np.linspace(0, len(pts) - 1, 4096)).astype(np.int64)]
    root_xy = joints[:, 0, :2]
    K = _intrinsics(size)

    def fit(make, d0: float, d_min: float) -> camera.Rig:
        d = d0
        for _ in range(60):
            rig = make(d)
            centres = np.asarray(camera.camera_centres(rig.to_jax(jnp.float32)))
            near = min(float(np.min(np.linalg.norm(root_xy - cc[:2], axis=-1))) for cc in centres)
            if near >= d_min and _visible(rig, pts, margin):
                return rig
            d *= 1.05
        raise ValueError(f"the subject does not fit in the {name!r} rig even {d:.1f} m away")

    def rig_of(names, eyes_R_t) -> camera.Rig:
        Rs = [R for R, _ in eyes_R_t]
        ts = [t for _, t in eyes_R_t]
        V = len(names)
        return camera.from_opencv(
            np.stack([K] * V), np.zeros((V, 5)), np.stack(Rs), np.stack(ts), names, [size] * V
        )

    if name == "stereo":
        target = c + 1.0 * up

        def make(d):
            head = c + d * f + 1.3 * up
            R, _ = look_at(head, target)
            return rig_of(("left", "right"), [(R, -R @ (head + s * 0.15 * R[0])) for s in (-1.0, 1.0)])

        return fit(make, 3.0, 2.5)
    if name == "frontal-lateral":
        target = c + 1.0 * up
        rigs = []
        for cam, direction in (("frontal", f), ("lateral", left)):

            def make(d, direction=direction, cam=cam):
                return rig_of((cam,), [look_at(c + d * direction + 1.5 * up, target)])

            rigs.append(fit(make, 3.0, 2.0))
        dist = np.array([[-0.05, 0.0, 0.0, 0.0, 0.0]] * 2)
        return camera.from_opencv(
            np.stack([K, K]),
            dist,
            np.concatenate([r.R for r in rigs]),
            np.concatenate([r.t for r in rigs]),
            ("frontal", "lateral"),
            [size, size],
        )
    if name == "ring4":
        target = c + 0.9 * up
        azimuths = np.deg2rad([45.0, 135.0, 225.0, 315.0])

        def make(d):
            eyes = [c + d * (math.cos(a) * f + math.sin(a) * left) + 2.5 * up for a in azimuths]
            return rig_of(tuple(f"cam{i + 1}" for i in range(4)), [look_at(e, target) for e in eyes])

        return fit(make, 3.5, 1.5)
    raise ValueError(f"unknown rig preset {name!r}; choose one of {PRESETS} or a calibration file")


def place_motion(
    rig: camera.Rig, joints: np.ndarray, distance: float = 3.0, weight: float = 0.01
) -> np.ndarray:
    """Horizontal shift ``(3,)`` (``z = 0``) that puts the clip's centre (:func:`subject_frame`) below the point
    ``p`` nearest to every optical axis of ``rig``, in the least-squares sense with a weak pull (``weight``) to
    the points ``distance`` metres in front of each camera (which decides ``p`` when the axes are parallel):
    ``p = (Σ (I − a aᵀ) + w I)⁻¹ Σ ((I − a aᵀ) C + w (C + distance · a))`` with ``C`` the centres, ``a`` the
    axes."""
    R = np.asarray(rig.R, np.float64)
    centres = np.asarray(camera.camera_centres(rig.to_jax(jnp.float32)), np.float64)
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for v in range(R.shape[0]):
        a = R[v, 2]
        P = np.eye(3) - np.outer(a, a)
        A += P + weight * np.eye(3)
        b += P @ centres[v] + weight * (centres[v] + distance * a)
    p = np.linalg.solve(A, b)
    c, _, _ = subject_frame(joints)
    return np.array([p[0] - c[0], p[1] - c[1], 0.0])


# ---------------------------------------------------------------------------------------------------------------
# Backgrounds


def _photos() -> list[pathlib.Path]:
    base = resources.files("jaxmocap") / "data" / "backgrounds"
    return sorted(pathlib.Path(str(p)) for p in base.iterdir() if str(p).lower().endswith((".jpg", ".png")))


def _fill(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Centre-crop ``image`` to the aspect of ``size`` and resize it (area interpolation) to ``size``."""
    w, h = size
    ih, iw = image.shape[:2]
    if iw * h > ih * w:
        cw = max(1, round(ih * w / h))
        x0 = (iw - cw) // 2
        image = image[:, x0 : x0 + cw]
    else:
        ch = max(1, round(iw * h / w))
        y0 = (ih - ch) // 2
        image = image[y0 : y0 + ch]
    interp = cv2.INTER_AREA if image.shape[1] > w else cv2.INTER_LINEAR
    return cv2.resize(image, (w, h), interpolation=interp)


def draw_clutter(rng: np.random.Generator, image: np.ndarray, level: float) -> np.ndarray:
    """Draw ``round(40·level)`` random striped rectangles and ellipses, their colours half-way between a random
    colour and the image's mean colour (muted, like furniture and posters)."""
    h, w = image.shape[:2]
    out = image.copy()
    mean = image.reshape(-1, 3).mean(0)
    for _ in range(int(round(40 * level))):
        colour = [int(c) for c in np.clip(0.5 * rng.integers(0, 256, 3) + 0.5 * mean, 0, 255)]
        stripe = [int(np.clip(c + rng.integers(-50, 51), 0, 255)) for c in colour]
        cx, cy = int(rng.integers(0, w)), int(rng.integers(0, h))
        sx, sy = int(rng.integers(w // 40 + 1, w // 8 + 2)), int(rng.integers(h // 40 + 1, h // 6 + 2))
        shape = np.zeros((h, w), np.uint8)
        if rng.random() < 0.6:
            cv2.rectangle(shape, (cx - sx, cy - sy), (cx + sx, cy + sy), 255, -1)
        else:
            cv2.ellipse(shape, (cx, cy), (sx, sy), float(rng.uniform(0, 180)), 0, 360, 255, -1)
        layer = np.empty((h, w, 3), np.uint8)
        layer[:] = colour
        period = int(rng.integers(4, 24))
        vertical = rng.random() < 0.5
        for k in range(-max(h, w), max(h, w), period):
            if vertical:
                cv2.line(layer, (cx + k, 0), (cx + k, h), stripe, max(1, period // 3))
            else:
                cv2.line(layer, (0, cy + k), (w, cy + k), stripe, max(1, period // 3))
        out[shape > 0] = layer[shape > 0]
    return out


def background_image(
    kind: str, size: tuple[int, int], view: int, seed: int, clutter: float = 0.0
) -> np.ndarray:
    """``(h, w, 3)`` uint8 RGB background of view ``view``.

    ``kind``: ``"photo"`` (the bundled photographs in turn, centre-cropped and resized), ``"plain"`` (a grey
    wall above a darker floor) or an image file path; then procedural clutter of density ``clutter`` in [0, 1]
    drawn from ``default_rng([seed, view])``.
    """
    w, h = size
    if kind == "photo":
        photos = _photos()
        img = cv2.imread(os.fspath(photos[view % len(photos)]), cv2.IMREAD_COLOR)
        base = _fill(img[..., ::-1], size)
    elif kind == "plain":
        rows = np.linspace(0.0, 1.0, h)[:, None, None]
        wall = np.array([200.0, 196.0, 188.0])
        floor = np.array([120.0, 116.0, 110.0])
        base = np.where(rows < 0.55, wall - 30.0 * rows, floor + 20.0 * rows)
        base = np.broadcast_to(base, (h, w, 3)).round().astype(np.uint8)
    else:
        img = cv2.imread(os.fspath(kind), cv2.IMREAD_COLOR)
        if img is None:
            raise MocapInputError(kind, "cannot read background image")
        base = _fill(img[..., ::-1], size)
    base = np.ascontiguousarray(base)
    if clutter > 0:
        base = draw_clutter(np.random.default_rng([int(seed), int(view)]), base, float(clutter))
    return base
