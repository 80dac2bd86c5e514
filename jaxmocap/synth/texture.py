"""Textured clothing: a solid texture fixed to each bone, so that the surface of the body has detail that moves with
it (what stereo matching, colour templates and optical flow need) while every garment keeps its colour.

Each rendered pixel of label ``l`` (a cone of bone ``p → c``, or the head) is the world point
``P = Rᵀ (z (x, y, 1) − t)`` of its ray; its coordinates in the frame of the joint that carries the bone,
``q = W_pᵀ (P − X_p)`` (metres; ``W_p``, ``X_p`` that joint's world rotation and position at the frame), do not
change as the limb moves. The albedo is ``colour_l · (1 + Σ_i a_i sin(2π k_i·q + φ_i))``, clipped to [0, 1], with
the part's colour (:data:`TEXTURED_COLOURS`, skin for bare parts) and per-garment waves (:data:`GARMENTS`): eight random directions with wavelengths 1.5–4 cm (a weave), plus stripes
along the bone for the shirt and a coarser check for the trousers; skin gets a faint 3 % mottle only, so skin
colour stays skin colour. Waves are drawn from ``default_rng([seed, 1 << 22, garment])``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["GARMENTS", "TEXTURED_COLOURS", "garment_of", "texture_waves", "textured_albedo"]

#: Colours (RGB in [0, 1]) of the textured clothing by body part: a light-blue shirt with red upper and grey lower
#: sleeves, dark shorts over denim thighs and navy shins, black shoes; chosen away from skin hues (the bundled skin
#: model gives each of them a skin probability of at most 0.11 over the shading range), so that skin is only skin.
TEXTURED_COLOURS: dict[str, tuple[float, float, float]] = {
    "torso": (0.55, 0.70, 0.85),
    "clavicle": (0.55, 0.70, 0.85),
    "upper_arm": (0.70, 0.15, 0.15),
    "forearm": (0.50, 0.50, 0.52),
    "pelvis": (0.25, 0.25, 0.28),
    "thigh": (0.25, 0.35, 0.55),
    "shin": (0.12, 0.15, 0.40),
    "foot": (0.12, 0.12, 0.12),
    "toe": (0.12, 0.12, 0.12),
    "limb": (0.50, 0.50, 0.52),
}

#: Garment of each body part, and its texture: (weave amplitude, stripe amplitude, stripe wavelength m,
#: check amplitude, check wavelength m).
GARMENTS: dict[str, tuple[float, float, float, float, float]] = {
    "shirt": (0.20, 0.18, 0.05, 0.0, 0.1),
    "trousers": (0.22, 0.0, 0.05, 0.12, 0.08),
    "shoes": (0.15, 0.0, 0.05, 0.0, 0.1),
    "skin": (0.03, 0.0, 0.05, 0.0, 0.1),
    "other": (0.2, 0.0, 0.05, 0.0, 0.1),
}
_ROLE_GARMENT = {
    "torso": "shirt",
    "clavicle": "shirt",
    "upper_arm": "shirt",
    "forearm": "shirt",
    "pelvis": "trousers",
    "thigh": "trousers",
    "shin": "trousers",
    "foot": "shoes",
    "toe": "shoes",
    "neck": "skin",
    "head": "skin",
    "hand": "skin",
    "finger": "skin",
    "thumb": "skin",
}
_N_WEAVE = 8


def garment_of(role: str) -> str:
    """The garment of a body part (``"other"`` for parts not listed)."""
    return _ROLE_GARMENT.get(role, "other")


def texture_waves(
    roles, bone_axes: np.ndarray, seed: int, bare=()
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Wave vectors ``(L, N, 3)`` (cycles per metre), phases ``(L, N)`` and amplitudes ``(L, N)`` of every label.

    ``roles``: body part per label; ``bone_axes (L, 3)``: each bone's unit direction in its joint's frame (the
    stripes run across it); ``bare``: body parts left uncovered (skin's texture, e.g. forearms in short
    sleeves). Labels of one garment share its weave, so that a garment looks like one cloth."""
    garments = list(GARMENTS)
    L, N = len(roles), _N_WEAVE + 3
    waves, phases, amps = np.zeros((L, N, 3)), np.zeros((L, N)), np.zeros((L, N))
    weave = {}
    for g, name in enumerate(garments):
        rng = np.random.default_rng([int(seed), 1 << 22, g])
        d = rng.standard_normal((_N_WEAVE, 3))
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        k = d / rng.uniform(0.015, 0.04, (_N_WEAVE, 1))
        weave[name] = (k, rng.uniform(0, 2 * np.pi, _N_WEAVE), rng.uniform(0, 2 * np.pi, 3))
    for l, role in enumerate(roles):
        name = "skin" if role in bare else garment_of(role)
        a_weave, a_stripe, l_stripe, a_check, l_check = GARMENTS[name]
        k, ph, ph2 = weave[name]
        axis = np.asarray(bone_axes[l], np.float64)
        axis = axis / max(float(np.linalg.norm(axis)), 1e-12)
        side = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
        side /= np.linalg.norm(side)
        waves[l, :_N_WEAVE], phases[l, :_N_WEAVE] = k, ph
        amps[l, :_N_WEAVE] = a_weave / np.sqrt(_N_WEAVE / 2)
        waves[l, _N_WEAVE] = axis / l_stripe
        waves[l, _N_WEAVE + 1] = axis / l_check
        waves[l, _N_WEAVE + 2] = side / l_check
        phases[l, _N_WEAVE:] = ph2
        amps[l, _N_WEAVE:] = (a_stripe, a_check, a_check)
    return waves, phases, amps


@jax.jit
def textured_albedo(depth, label, rays, R, t, frames_R, frames_X, colours, waves, phases, amps):
    """``(H, W, 3)`` albedo of one render (module docstring).

    Args: ``depth (H, W)`` camera z (0 background), ``label (H, W)``, ``rays (H, W, 2)`` undistorted normalised
    pixel coordinates, camera ``R (3, 3)``, ``t (3,)``; per label the joint frame ``frames_R (L, 3, 3)``,
    ``frames_X (L, 3)``, ``colours (L, 3)`` and the waves of :func:`texture_waves`.

    The texture is evaluated on the body's pixels only, gathered into a fixed-size list of a quarter of the image
    (a body covering more keeps its plain colour beyond that count), so the cost follows the body, not the image.
    """
    H, W = label.shape
    cap = max(1, (H * W) // 4)
    flat = label.reshape(-1)
    (idx,) = jnp.nonzero(flat >= 0, size=cap, fill_value=0)
    lab = jnp.maximum(flat[idx], 0)
    xy = rays.reshape(-1, 2)[idx]
    z = depth.reshape(-1)[idx]
    pc = jnp.concatenate([xy, jnp.ones_like(xy[:, :1])], -1) * z[:, None]
    P = (pc - t) @ R  # Rᵀ (p − t), row form
    q = jnp.einsum("nij,ni->nj", frames_R[lab], P - frames_X[lab])  # W_pᵀ (P − X_p)
    phase = 2 * jnp.pi * jnp.einsum("nkj,nj->nk", waves[lab], q) + phases[lab]
    factor = 1.0 + jnp.sum(amps[lab] * jnp.sin(phase), -1)
    plain = colours[jnp.maximum(flat, 0)]
    textured = jnp.clip(colours[lab] * factor[:, None], 0.0, 1.0)
    valid = flat[idx] >= 0
    out = plain.at[idx].set(jnp.where(valid[:, None], textured, plain[idx]))
    return out.reshape(H, W, 3)
