"""Colour and skin cues: one energy ``E ≥ 0`` per view ``(V,)`` of one particle's projected geometry and one
frame's observation (the conventions of :mod:`jaxmocap.likelihood.cues`, where they are registered).

* Fontmarty et al., IROS 2007 §III-B: ``colour_histogram`` (ROI colour histograms, Bhattacharyya distance),
  ``skin`` (skin colour at the projected head and hands), ``homogeneous_colour`` (per-limb colour spread).
* Li & Kulić §III-C: ``colour_template`` (eq. 3).
* López Méndez 2009 §4.3: ``head_skin`` (eq. 4.4).

The colour cues share one ``prepare`` step (:func:`_prepare_colour`): the colour map packed to one int32 per pixel
with a sentinel entry, so that one gather at a surface sample reads its colour and whether it is seen.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.features.observation import Observation
from jaxmocap.geometry import camera
from jaxmocap.likelihood import maps
from jaxmocap.likelihood.cue_context import (
    CueContext,
    Geometry,
    _joint_index,
    _segment_ids,
    _segment_points,
    _surface_values,
    _unit_scale,
    _weighted_mean,
)


def _rgb_bytes(obs: Observation) -> jnp.ndarray:
    """``(V, H, W, 3)`` int32 bytes ``round(255 c)`` of the colour map."""
    c = obs.rgb
    if c.dtype == jnp.uint8:
        return c.astype(jnp.int32)
    return jnp.round(jnp.clip(c.astype(jnp.float32), 0.0, 1.0) * 255.0).astype(jnp.int32)


def _packed_rgb(obs: Observation, cache: dict) -> jnp.ndarray:
    """``(V·H·W + 1,)`` int32 ``R + 256 G + 65536 B`` of the bytes ``round(255 c)``, flattened, with the sentinel
    −1 appended (:func:`jaxmocap.likelihood.maps.with_sentinel`): one gather reads a colour, and read at
    :attr:`Geometry.surface_visible_index` also whether the sample is seen."""
    if "rgb_packed" not in cache:
        c8 = _rgb_bytes(obs)
        cache["rgb_packed"] = maps.with_sentinel(c8[..., 0] | (c8[..., 1] << 8) | (c8[..., 2] << 16), -1)
    return cache["rgb_packed"]


def _unpack_bytes(p: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """Packed colours ``(...)`` int32 → the three int32 bytes R, G, B."""
    return p & 255, (p >> 8) & 255, (p >> 16) & 255


def _unpack_rgb(p: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """Packed colours ``(...)`` int32 → three float32 arrays R, G, B in [0, 1] (kept apart: per-channel arithmetic
    over long arrays, no reduction over a minor axis of 3)."""
    s = 1.0 / 255.0
    return tuple(c.astype(jnp.float32) * s for c in _unpack_bytes(p))


def _surface_rgb(obs: Observation, g: Geometry, ctx: CueContext):
    """``((R, G, B) each (V, P) in [0, 1], inside (V, P))`` at the surface points: nearest pixel from the packed
    colour map of ``aux``, or bilinear from the colour planes of ``aux`` with ``bilinear=True``."""
    if ctx.params.get("bilinear", False):
        i00, fu, fv, inside = maps.bilinear_index(g.surface_uv, obs.rgb.shape[:3])
        planes = ctx.aux["rgb_planes"]
        s = _unit_scale(obs.rgb)
        return tuple(maps.gather_bilinear(planes[c], i00, fu, fv, s) for c in range(3)), inside
    return _unpack_rgb(maps.gather(ctx.aux["rgb_packed"], g.surface_index, raw=True)), g.surface_inside


def _visible_rgb(g: Geometry, ctx: CueContext) -> jnp.ndarray:
    """``(V, P)`` int32 packed colours at the surface samples that face the camera and lie in the image, −1 at
    the others: one gather at :attr:`Geometry.surface_visible_index` (nearest pixel)."""
    return maps.gather(ctx.aux["rgb_packed"], g.surface_visible_index, raw=True)


# ---------------------------------------------------------------------------------------------------------------
# Skin cues


def head_skin(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Head with skin (López Méndez eq. 4.4): the fraction of the head's camera-facing surface samples that are not
    skin, ``E_v = Σ_p f_vp (1 − S_v(u_vp)) / Σ_p f_vp`` (``f`` = facing; out-of-image samples count as not skin;
    1 when no head sample faces the camera)."""
    sl = _segment_points(ctx, ctx.model.segment_names.index(ctx.params.get("segment", "head")))
    S, inside = _surface_values(obs.skin, g, ctx, points=sl)
    S = jnp.where(inside, S, 0.0)
    f = g.surface_facing[:, sl].astype(S.dtype)
    return _weighted_mean(1.0 - S, f, empty=1.0)


def _hand_samples(g: Geometry, ctx: CueContext) -> jnp.ndarray:
    """``(V, 2, K, 2)`` pixel samples on the two projected hands: the hand centre ``wrist + h (wrist − elbow)/|·|``
    (``hand_offset`` h, default 0.08 m) and a ring of 6 points at 0.6 of the projected hand radius
    ``f_x r / z`` (``hand_radius`` r, default 0.05 m)."""
    h = ctx.params.get("hand_offset", 0.08)
    r = ctx.params.get("hand_radius", 0.05)
    jw = _joint_index(ctx, ("left_wrist", "right_wrist"))
    je = _joint_index(ctx, ("left_elbow", "right_elbow"))
    w, e = g.joints[jw], g.joints[je]
    d = w - e
    c = w + h * d / jnp.sqrt(jnp.sum(d * d, axis=-1, keepdims=True) + 1e-12)
    uv, z = camera.project_with_depth(ctx.rig, c)  # (V, 2, 2), (V, 2)
    K = jnp.asarray(ctx.rig.K, uv.dtype)
    rad = 0.6 * K[:, 0, 0, None] * r / jnp.maximum(z, 1e-3)  # (V, 2)
    ang = np.linspace(0.0, 2 * np.pi, 6, endpoint=False)
    off = np.concatenate([np.zeros((1, 2)), np.stack([np.cos(ang), np.sin(ang)], -1)]).astype(
        np.float32
    )  # (7, 2)
    return uv[:, :, None, :] + rad[:, :, None, None] * jnp.asarray(off, uv.dtype)


def skin(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Skin colour at the projected head and hands (Fontmarty et al. §III-B): ``p ∝ exp(−Σ_k D_k² / 2σ_s²)`` with
    ``D_k = 1 − S̄_k`` one minus the mean skin probability over the samples of part ``k`` (head: its camera-facing
    surface samples; each hand: a disc of 7 samples around the projected hand centre, see
    :func:`_hand_samples`); out-of-image samples count as not skin. ``E_v = Σ_k D_k² / (2σ_s²)``, σ_s =
    ``sigma`` (default 0.5)."""
    sigma = ctx.params.get("sigma", 0.5)
    bil = ctx.params.get("bilinear", False)
    sl = _segment_points(ctx, ctx.model.segment_names.index("head"))
    S, inside = _surface_values(obs.skin, g, ctx, points=sl)
    S = jnp.where(inside, S, 0.0)
    head = _weighted_mean(S, g.surface_facing[:, sl].astype(S.dtype), empty=0.0)  # (V,)
    uvh = _hand_samples(g, ctx)
    V = uvh.shape[0]
    uvh = uvh.reshape(V, -1, 2)
    if bil:
        Sh, ins = maps.lookup_bilinear(obs.skin, uvh)
        Sh = Sh * _unit_scale(obs.skin)
    else:
        idx, ins = maps.nearest_index(uvh, obs.skin.shape)
        Sh = maps.gather(obs.skin, idx, _unit_scale(obs.skin))
    hands = jnp.mean(jnp.where(ins, Sh, 0.0).reshape(V, 2, -1), axis=-1)  # (V, 2)
    D = 1.0 - jnp.concatenate([head[:, None], hands], axis=-1)
    return jnp.sum(D * D, axis=-1) / (2.0 * sigma * sigma)


# ---------------------------------------------------------------------------------------------------------------
# Colour cues


def _colour_bins(c8: jnp.ndarray, bins: int, space: str) -> jnp.ndarray:
    """Bin index of colour bytes ``c8 (..., 3)`` (RGB, ``round(255 c)``) exactly as
    :func:`jaxmocap.features.colour.roi_histograms` bins them: ``"rgb"``: ``(q_r b + q_g) b + q_b`` with
    ``q = ⌊c8 b / 256⌋``; ``"rg"``: chromaticity ``r = R/(R+G+B)``, ``g = G/(R+G+B)`` binned to ``min(⌊r b⌋, b−1)``."""
    return _channel_bins(c8[..., 0], c8[..., 1], c8[..., 2], bins, space)


def _channel_bins(r8, g8, b8, bins: int, space: str) -> jnp.ndarray:
    """:func:`_colour_bins` of the three int32 byte arrays ``r8, g8, b8`` (as :func:`_unpack_bytes` gives them)."""
    if space == "rgb":  # bytes are non-negative: ⌊c b / 256⌋ is a shift
        return (((r8 * bins) >> 8) * bins + ((g8 * bins) >> 8)) * bins + ((b8 * bins) >> 8)
    if space == "rg":
        r, gg, b = (c.astype(jnp.float32) for c in (r8, g8, b8))
        s = r + gg + b
        s = jnp.where(s > 0, s, 1.0)
        qr = jnp.minimum(jnp.floor(r / s * bins), bins - 1).astype(jnp.int32)
        qg = jnp.minimum(jnp.floor(gg / s * bins), bins - 1).astype(jnp.int32)
        return qr * bins + qg
    raise ValueError(f"colour space must be 'rgb' or 'rg', got {space!r}")


def _num_bins(params: dict) -> int:
    b = int(params.get("bins", 4))
    return b**3 if params.get("space", "rgb") == "rgb" else b**2


def _prepare_colour(obs: Observation, ctx: CueContext, cache: dict):
    """The packed colour map (shared by the colour cues of a likelihood); with ``bilinear=True`` also the three
    colour planes ``(V, H, W)``."""
    out = {"rgb_packed": _packed_rgb(obs, cache)}
    if ctx.params.get("bilinear", False):
        if "rgb_planes" not in cache:
            cache["rgb_planes"] = tuple(obs.rgb[..., c] for c in range(3))
        out["rgb_planes"] = cache["rgb_planes"]
    return out


def _soft_bin_weights(rgb, bins: int) -> jnp.ndarray:
    """Triangular-kernel bin weights ``(..., bins³)`` of colours ``(R, G, B)`` (each ``(...)`` in [0, 1]): per channel
    ``k_j(c) = max(0, 1 − |c b − (j + ½)|)`` (clamped at the outer bin centres, so the weights sum to 1), joint
    weight the product over channels, in the bin order of :func:`_colour_bins`."""
    centre = jnp.arange(bins, dtype=rgb[0].dtype) + 0.5
    k = [
        jnp.maximum(1.0 - jnp.abs(jnp.clip(c * bins, 0.5, bins - 0.5)[..., None] - centre), 0.0) for c in rgb
    ]
    return (k[0][..., :, None, None] * k[1][..., None, :, None] * k[2][..., None, None, :]).reshape(
        rgb[0].shape + (bins**3,)
    )


@functools.cache
def _counter(size: int):
    """``counts(slot) -> (size,)`` float32: how many entries of the int32 array ``slot`` (values in ``[0, size)``)
    fall in each slot, by one scatter-add of ones. Its batching rule offsets each batch member's slots into one
    flat array and counts them with one 1-D scatter (the default rule scatters with a batch index per update, whose
    index array costs as much as the scatter itself)."""

    @jax.custom_batching.custom_vmap
    def counts(slot):
        return jnp.zeros((size,), jnp.float32).at[slot.reshape(-1)].add(1.0)

    @counts.def_vmap
    def _rule(axis_size, in_batched, slot):
        if not in_batched[0]:
            out = counts(slot)
            return jnp.broadcast_to(out, (axis_size, size)), True
        flat = slot.reshape(axis_size, -1) + (jnp.arange(axis_size, dtype=slot.dtype) * size)[:, None]
        out = jnp.zeros((axis_size * size,), jnp.float32).at[flat.reshape(-1)].add(1.0)
        return out.reshape(axis_size, size), True

    return counts


def colour_histogram(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """ROI colour histograms (Fontmarty et al. §III-B): ``p ∝ exp(−Σ_r D_r² / 2σ_c²)`` with the Bhattacharyya
    distance ``D_r = √(1 − Σ_b √(h_r,b(x) q_r,b))`` between the colour histogram ``h_r(x)`` of ROI ``r`` — the pixels
    under the camera-facing surface samples of segment ``r`` (``rois``, default every fleshed segment) — and the
    reference ``q_r`` of the first frame (:func:`jaxmocap.features.colour.roi_histograms` over the rendered ROI
    masks; :meth:`~jaxmocap.likelihood.compose.Likelihood.with_references`). ``E_v = Σ_r D_r² / (2σ_c²)``, σ_c = ``sigma``
    (default 0.2). Binning: ``bins`` per channel (default 4) in ``space`` ``"rgb"`` (joint bins³) or ``"rg"``
    (chromaticity, bins²). An ROI without any visible sample has ``D = 1``.

    ``soft=True`` (``"rgb"`` only; with ``bilinear=True`` for a gradient): triangular-kernel binning
    (:func:`_soft_bin_weights`) of bilinearly interpolated colours, the reference binned the same way, and
    ``√(h q + ε) − √ε`` (ε = 1e-6) per bin, so that the energy is differentiable.
    """
    sigma = ctx.params.get("sigma", 0.2)
    bins = int(ctx.params.get("bins", 4))
    soft = ctx.params.get("soft", False)
    B = _num_bins(ctx.params)
    segs = _segment_ids(ctx, ctx.params.get("rois"), "fleshed")
    if soft and ctx.params.get("space", "rgb") != "rgb":
        raise ValueError("soft colour histograms need space='rgb'")
    sqrt_ref = jnp.sqrt(ctx.ref)  # (V, R, B)
    if not soft:
        # one gather reads the colour and the visibility of every sample (-1: hidden or outside the image), and
        # one scatter-add counts every ROI (cost independent of the number of bins and ROIs): a visible point
        # adds 1 to slot roi(p)·B + b_p; hidden points and points outside the ROIs go to a spare last slot
        packed = _visible_rgb(g, ctx)  # (V, P)
        V = packed.shape[0]
        b = _channel_bins(*_unpack_bytes(packed), bins, ctx.params.get("space", "rgb"))
        roi = np.full(len(ctx.surface_segment), len(segs), np.int32)
        for r, s in enumerate(segs):
            sl = _segment_points(ctx, s)
            roi[sl] = r
        spare = len(segs) * B
        slot = jnp.where(packed >= 0, jnp.asarray(roi * B)[None, :] + b, spare)  # (V, P)
        slot = jnp.minimum(slot, spare) + jnp.arange(V, dtype=jnp.int32)[:, None] * (spare + 1)
        h = _counter(V * (spare + 1))(slot).reshape(V, spare + 1)
        h = h[:, :spare].reshape(V, len(segs), B)
        n = jnp.sum(h, axis=-1)  # (V, R)
        h = h / jnp.maximum(n, 1e-12)[..., None]
        bc = jnp.sum(jnp.sqrt(h) * sqrt_ref, axis=-1)
        return jnp.sum(jnp.where(n > 0, jnp.clip(1.0 - bc, 0.0, 1.0), 1.0), axis=-1) / (2.0 * sigma * sigma)
    rgb, inside = _surface_rgb(obs, g, ctx)
    w = (g.surface_facing & inside).astype(rgb[0].dtype)
    onehot = _soft_bin_weights(rgb, bins)  # (V, P, B)
    total = 0.0
    for r, s in enumerate(segs):
        sl = _segment_points(ctx, s)
        ws = w[:, sl]
        n = jnp.sum(ws, axis=-1)  # (V,)
        h = jnp.sum(onehot[:, sl] * ws[..., None], axis=1)
        h = h / jnp.maximum(n, 1e-12)[:, None]  # (V, B)
        bc = jnp.sum(jnp.sqrt(h * ctx.ref[:, r] + 1e-6), axis=-1) - B * 1e-3
        d2 = jnp.where(n > 0, jnp.clip(1.0 - bc, 0.0, 1.0), 1.0)
        total = total + d2
    return total / (2.0 * sigma * sigma)


def homogeneous_colour(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Homogeneous colour (Fontmarty et al. §III-B): limbs are uniformly coloured, so ``p ∝ exp(−D²/2σ_h²)`` with
    ``D = (1/L) Σ_l σ_l`` the mean over the limbs (``segments``, default every fleshed segment but the head) of
    the colour standard deviation ``σ_l = √((1/3) Σ_c Var_p c_p)`` of the RGB values (in [0, 1]) at the limb's
    camera-facing in-image surface samples. ``E_v = D² / (2σ_h²)``, σ_h = ``sigma`` (default 0.1). A limb with
    fewer than two visible samples is left out of the mean. Differentiable with ``bilinear=True``."""
    sigma = ctx.params.get("sigma", 0.1)
    if ctx.params.get("bilinear", False):
        rgb, inside = _surface_rgb(obs, g, ctx)
        w = (g.surface_facing & inside).astype(rgb[0].dtype)
    else:  # one gather: colour and visibility (-1) together
        packed = _visible_rgb(g, ctx)
        rgb = _unpack_rgb(packed)
        w = (packed >= 0).astype(jnp.float32)
    runs = [_segment_points(ctx, s) for s in _segment_ids(ctx, ctx.params.get("segments"), "limbs")]

    def limb_sums(a):  # (V, P) -> (V, L): sums over each limb's contiguous run of points (static slices)
        return jnp.stack([jnp.sum(a[:, sl], axis=-1) for sl in runs], -1)

    # one reduction per moment (stacking the seven moments first measured 20 % slower on the whole cue)
    n = limb_sums(w)
    ns = jnp.maximum(n, 1e-12)
    var = sum(limb_sums(w * c * c) / ns - (limb_sums(w * c) / ns) ** 2 for c in rgb)  # (V, L)
    sd = jnp.sqrt(jnp.maximum(var, 0.0) / 3.0 + 1e-8)
    D = _weighted_mean(sd, (n >= 2).astype(w.dtype), empty=0.0)
    return D * D / (2.0 * sigma * sigma)


def colour_template(g: Geometry, obs: Observation, ctx: CueContext) -> jnp.ndarray:
    """Li & Kulić colour cue (eq. 3): the RGB distance between each sample point's colour and its template, the
    colour the same sample point had in the first frame (:meth:`~jaxmocap.likelihood.compose.Likelihood.with_references`),
    rescaled to [0, 1]: ``E_v = Σ_p m_vp ‖c_vp(x) − T_vp‖ / √3 / Σ_p m_vp`` over the samples that face camera
    ``v`` now and had a template there (``m``); 1 when there are none. Colours are read as the 8-bit values
    ``round(255 c) / 255`` of the nearest pixel (``bilinear=True``: the stored colour planes interpolated
    bilinearly, which makes the cue differentiable); the template is read the same way, so the first frame has
    ``E = 0``."""
    T, valid = ctx.ref  # (3, V, P), (V, P)
    rgb, inside = _surface_rgb(obs, g, ctx)
    m = (valid & g.surface_facing & inside).astype(rgb[0].dtype)
    if ctx.part is not None:  # a partition's own body parts (jaxmocap.likelihood.partition)
        m = m * ctx.part.surface.astype(m.dtype)
    d2 = sum((rgb[c] - T[c]) ** 2 for c in range(3))
    d = jnp.sqrt(d2 + 1e-12) * (1.0 / math.sqrt(3.0))
    return _weighted_mean(d, m, empty=1.0)
