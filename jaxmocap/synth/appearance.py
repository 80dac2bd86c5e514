"""What makes the synthetic subject look like a person to the face, skin and wrist-band cues: a face painted on the
front of the head spheroid, optionally bare forearms (short sleeves) and coloured bands around the wrists
(Li & Kulić's markers).

Every rendered pixel of the body is the world point ``P = Rᵀ (z (x, y, 1) − t)`` of its ray (``z`` its depth,
``(x, y)`` its undistorted normalised coordinates, ``R``, ``t`` the camera's world → camera transform).

**Face.** On the head spheroid (centre ``m``, polar axis ``â``, half-length ``h``, equatorial radius ``r``) a
pixel's face coordinates are ``X = (P − m)·l̂ / r``, ``Y = (P − m)·â / h`` and its side ``Z = (P − m)·f̂``, in
the head's frame ``(l̂, â, f̂)`` (:func:`head_frames`): ``f̂`` the direction the face looks, carried by the head
joint's rotation, ``l̂ = â × f̂`` the subject's left. Where ``Z > 0`` the albedo inside each ellipse
``((X − X₀)/r_X)² + ((Y − Y₀)/r_Y)² ≤ 1`` of :data:`FACE_FEATURES` (eye sockets, brows, eyes, the shadow under the nose, the
mouth; mirrored left/right where ``X₀ ≠ 0``) is the feature's colour; hair covers ``Y > HAIRLINE − 0.25 X²``
on the front and ``Y > HAIRLINE_BACK`` behind (``Z < 0``). Elsewhere the head keeps its skin. The layout follows
a face's proportions: eyes 6–7 cm apart at the middle of the head's height, the mouth 5 cm below it, so that a
Viola–Jones frontal-face cascade sees the dark eye band above lighter cheeks and the darker mouth below.

**Wrist bands.** A pixel of a forearm or hand cone lies on the band of wrist ``w`` (elbow ``e``) when
``−BAND_WIDTH ≤ (P − w)·d̂ ≤ 0`` with ``d̂ = (w − e)/|w − e|`` (the last ``BAND_WIDTH`` metres of the forearm
before the wrist) and it is within ``BAND_REACH`` of the forearm's axis; its albedo is the band colour.

**Short sleeves.** The forearms take the skin colour (and the skin's faint texture with textured clothing):
:data:`SHORT_SLEEVES`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.geometry import render

__all__ = [
    "FACE_FEATURES",
    "HAIR",
    "HAIRLINE",
    "HAIRLINE_BACK",
    "BAND_COLOUR",
    "BAND_WIDTH",
    "BAND_REACH",
    "SHORT_SLEEVES",
    "SLEEVES",
    "head_frames",
    "decorate",
]

#: Face features ``(X₀, Y₀, r_X, r_Y, RGB)`` in head units (``X`` in equatorial radii to the subject's left,
#: ``Y`` in polar half-lengths up from the head's centre); later ones are drawn over earlier ones.
FACE_FEATURES: tuple[tuple[float, float, float, float, tuple[float, float, float]], ...] = (
    (0.34, 0.15, 0.27, 0.17, (0.70, 0.52, 0.42)),  # eye socket
    (0.36, 0.36, 0.22, 0.06, (0.22, 0.14, 0.10)),  # brow
    (0.34, 0.14, 0.17, 0.09, (0.10, 0.08, 0.08)),  # eye
    (0.0, -0.20, 0.11, 0.05, (0.50, 0.36, 0.30)),  # shadow under the nose
    (0.0, -0.44, 0.27, 0.07, (0.40, 0.14, 0.14)),  # mouth
)

#: Hair colour and where it starts on the front (``Y``, lowered by ``0.25 X²`` towards the sides) and behind.
HAIR = (0.16, 0.11, 0.08)
HAIRLINE = 0.62
HAIRLINE_BACK = 0.0

#: Wrist bands: colour (a saturated lime green, far from skin and from every clothing colour in chromaticity), width and the largest
#: distance from the forearm's axis (metres).
BAND_COLOUR = (0.55, 0.90, 0.05)
BAND_WIDTH = 0.04
BAND_REACH = 0.08

#: Sleeve lengths: long (the forearms wear the shirt) or short (bare forearms).
SLEEVES = ("long", "short")

#: Colour overrides of the body parts that short sleeves leave bare.
SHORT_SLEEVES: dict[str, tuple[float, float, float]] = {"forearm": render.SKIN}


def head_frames(head_rotations: np.ndarray, torso_forward: np.ndarray, head_axes: np.ndarray) -> np.ndarray:
    """``(T, 3, 3)`` head frames with rows ``(l̂, â, f̂)`` (world components) per frame.

    ``head_rotations (T, 3, 3)``: world rotation of the head joint; ``torso_forward (T, 3)``: the direction the
    torso faces (``(left hip − right hip) × ẑ``); ``head_axes (T, 3)``: the head spheroid's polar axis. The face
    direction in the head joint's own frame is the mean over the clip of ``W_tᵀ f_t`` (the head faces where the
    torso does on average), so the face turns with the head: ``f_t ∝ W_t f_local`` made orthogonal to ``â``."""
    W = np.asarray(head_rotations, np.float64)
    f = np.asarray(torso_forward, np.float64)
    a = np.asarray(head_axes, np.float64)
    a = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)
    local = np.einsum("tji,tj->ti", W, f / np.maximum(np.linalg.norm(f, axis=-1, keepdims=True), 1e-12))
    local = local.mean(0)
    local /= max(float(np.linalg.norm(local)), 1e-12)
    fwd = np.einsum("tij,j->ti", W, local)
    fwd = fwd - np.sum(fwd * a, -1, keepdims=True) * a
    fwd /= np.maximum(np.linalg.norm(fwd, axis=-1, keepdims=True), 1e-12)
    left = np.cross(a, fwd)
    return np.stack([left, a, fwd], axis=1)


def _ellipse(X, Y, x0, y0, rx, ry):
    return ((X - x0) / rx) ** 2 + ((Y - y0) / ry) ** 2 <= 1.0


def _face_colour(albedo, X, Y, Z):
    """Albedo ``(N, 3)`` with the face and hair of the module docstring drawn where ``(X, Y, Z)`` say."""
    out = albedo
    front = Z > 0
    for x0, y0, rx, ry, rgb in FACE_FEATURES:
        inside = _ellipse(X, Y, x0, y0, rx, ry)
        if x0 != 0:
            inside = inside | _ellipse(X, Y, -x0, y0, rx, ry)
        out = jnp.where((front & inside)[:, None], jnp.asarray(rgb, albedo.dtype), out)
    hair = jnp.where(front, Y > HAIRLINE - 0.25 * X * X, Y > HAIRLINE_BACK)
    return jnp.where(hair[:, None], jnp.asarray(HAIR, albedo.dtype), out)


@jax.jit
def decorate(
    albedo,
    depth,
    label,
    rays,
    R,
    t,
    head_label,
    head_centre,
    head_frame,
    head_half,
    banded,
    wrists,
    elbows,
    band_width,
):
    """``(H, W, 3)`` albedo with the face on the head and the wrist bands drawn (module docstring).

    Args: ``albedo (H, W, 3)`` the clothing's albedo, ``depth (H, W)`` camera z (0 background), ``label
    (H, W)`` (−1 background), ``rays (H, W, 2)``, camera ``R (3, 3)``, ``t (3,)``; ``head_label`` the head's
    label (−1: no face), ``head_centre (3,)``, ``head_frame (3, 3)`` rows ``(l̂, â, f̂)``, ``head_half (2,)``
    ``(r, h)``; ``banded (L,)`` bool: the labels that carry bands (forearms and hands); ``wrists``, ``elbows``
    ``(2, 3)`` world positions; ``band_width`` metres (0: no bands). Pure per pixel, so the cost is ``O(H W)``.
    """
    H, W = label.shape
    xy = rays.reshape(-1, 2)
    z = depth.reshape(-1)
    lab = label.reshape(-1)
    pc = jnp.concatenate([xy, jnp.ones_like(xy[:, :1])], -1) * z[:, None]
    P = (pc - t) @ R  # Rᵀ (p − t), row form
    col = albedo.reshape(-1, 3)
    q = (P - head_centre) @ head_frame.T
    face = _face_colour(col, q[:, 0] / head_half[0], q[:, 1] / head_half[1], q[:, 2])
    col = jnp.where(((lab == head_label) & (head_label >= 0))[:, None], face, col)
    d = wrists - elbows
    d = d / jnp.maximum(jnp.linalg.norm(d, axis=-1, keepdims=True), 1e-9)
    rel = P[:, None, :] - wrists[None]  # (N, 2, 3)
    along = jnp.einsum("nsk,sk->ns", rel, d)
    radial = jnp.linalg.norm(rel - along[..., None] * d[None], axis=-1)
    on_band = (along >= -band_width) & (along <= 0.0) & (radial <= BAND_REACH) & (band_width > 0)
    on_band = jnp.any(on_band, -1) & banded[jnp.maximum(lab, 0)] & (lab >= 0)
    col = jnp.where(on_band[:, None], jnp.asarray(BAND_COLOUR, col.dtype), col)
    return col.reshape(H, W, 3)
