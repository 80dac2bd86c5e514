"""Foreground segmentation on the host: static background, adaptive Gaussian, MOG2, depth.

Frames are OpenCV images: ``(H, W, 3)`` BGR ``uint8`` (float frames are accepted by the Gaussian model). Every
model returns a mask ``(H, W)`` ``uint8`` with 255 = foreground, 0 = background (OpenCV's mask convention), from
``update(frame)``; models that learn keep their state on the host.

Methods:

* ``StaticBackground`` — Li & Kulić: per-channel thresholds ``|I_c − B_c| > T_c`` against a background image,
  combined over channels (any channel), cleaned by a small opening and dilated. ``plate_background`` builds one
  against a recorded empty-scene plate with its threshold from the plate's own sensor noise (``noise_sigma``).
* ``GaussianBackground`` — López Méndez (2009) eq. 4.1–4.2: one Gaussian per pixel and channel,
  ``μ_t = ρ I_t + (1 − ρ) μ_{t−1}``, ``σ²_t = ρ (I_t − μ_t)² + (1 − ρ) σ²_{t−1}``; foreground where
  ``|I − μ| > k σ`` in any channel (tested against the model of the previous frame, then updated).
* shadow removal for both (Horprasert et al. 1999): brightness distortion ``α`` and chromaticity distortion
  ``CD`` against the background colour; a darker pixel (``α_min ≤ α < α_max``) with small ``CD`` is a shadow.
* ``Mog2Background`` — OpenCV's mixture-of-Gaussians (``cv2.createBackgroundSubtractorMOG2``); its shadow label
  (127) counts as background.
* ``depth_foreground`` / ``DepthBackground`` — pixels whose depth is closer than a background depth by a margin.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError

FOREGROUND = 255


def _check_frame(frame: np.ndarray, shape: tuple[int, ...] | None = None, what: str = "frame") -> np.ndarray:
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] != 3:
        raise MocapInputError(None, f"{what}: expected an (H, W, 3) colour image, got shape {frame.shape}")
    if shape is not None and frame.shape != tuple(shape):
        raise MocapInputError(
            None, f"{what}: shape {frame.shape} differs from the background's {tuple(shape)}"
        )
    return frame


def _square(size: int) -> np.ndarray:
    return np.ones((size, size), np.uint8)


def clean_mask(mask: np.ndarray, open_size: int = 3, dilate_size: int = 3) -> np.ndarray:
    """Morphological opening with a ``open_size²`` square (removes isolated noise pixels), then dilation with a
    ``dilate_size²`` square. Sizes ≤ 1 skip the step. ``mask`` is ``uint8`` 0/255."""
    if open_size > 1:
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, _square(open_size))
    if dilate_size > 1:
        mask = cv2.dilate(mask, _square(dilate_size))
    return mask


def brightness_chromaticity_distortion(
    frame: np.ndarray, mean: np.ndarray, std: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """Horprasert et al. (1999) distortions of a colour ``I`` from the expected colour ``μ`` with spread ``σ``.

    Brightness distortion ``α = Σ_c I_c μ_c / σ_c² / Σ_c (μ_c / σ_c)²`` (the scale of ``μ`` closest to ``I``),
    chromaticity distortion ``CD = sqrt(Σ_c ((I_c − α μ_c) / σ_c)²)`` (distance from the line through ``μ``, in
    units of ``σ``). ``frame``, ``mean`` ``(H, W, 3)``; ``std`` ``(H, W, 3)`` or a scalar. Returns float32
    ``(α, CD)`` of shape ``(H, W)``; where ``μ = 0`` the brightness distortion is 1.
    """
    I = np.asarray(frame, np.float32)
    mu = np.asarray(mean, np.float32)
    inv_var = 1.0 / np.square(np.asarray(std, np.float32))
    if inv_var.ndim == 0:
        num = np.einsum("hwc,hwc->hw", I, mu)
        den = np.einsum("hwc,hwc->hw", mu, mu)
    else:
        num = np.einsum("hwc,hwc->hw", I * inv_var, mu)
        den = np.einsum("hwc,hwc->hw", mu * inv_var, mu)
    alpha = np.where(den > 0, num / np.maximum(den, 1e-12), 1.0).astype(np.float32)
    resid = (I - alpha[..., None] * mu) * np.sqrt(inv_var)
    cd = np.sqrt(np.einsum("hwc,hwc->hw", resid, resid)).astype(np.float32)
    return alpha, cd


@dataclass(frozen=True)
class ShadowParams:
    """Shadow test on ``(α, CD)``: shadow where ``alpha_min ≤ α < alpha_max`` and ``CD ≤ cd_max``.

    ``alpha_max > 1`` also accepts brighter pixels ("highlighted background", e.g. a light switched on).
    ``cd_max`` is in units of the per-pixel σ.
    """

    alpha_min: float = 0.4
    alpha_max: float = 0.98
    cd_max: float = 6.0


#: Shadow test of :func:`plate_background`: a cast shadow darkens the background to between half and nine tenths
#: of its brightness without changing its chromaticity by more than 4 noise standard deviations of the difference
#: of two exposures.
PLATE_SHADOW = ShadowParams(alpha_min=0.5, alpha_max=0.9, cd_max=4.0)


def shadow_mask(
    frame: np.ndarray, mean: np.ndarray, std: np.ndarray | float, params: ShadowParams = ShadowParams()
) -> np.ndarray:
    """``uint8`` mask (255 = shadow) of pixels that are a darker copy of the background colour (see
    ``brightness_chromaticity_distortion``)."""
    alpha, cd = brightness_chromaticity_distortion(frame, mean, std)
    shadow = (alpha >= params.alpha_min) & (alpha < params.alpha_max) & (cd <= params.cd_max)
    return shadow.astype(np.uint8) * np.uint8(255)


def without_shadows(
    mask: np.ndarray, frame: np.ndarray, mean: np.ndarray, std: np.ndarray | float, params: ShadowParams
) -> np.ndarray:
    """``mask`` (``(H, W) uint8`` 0/255) with its shadow pixels (:func:`shadow_mask` of ``frame`` against ``mean``,
    ``std``) set to 0, the same as ``mask & ~shadow_mask(...)``; the distortions are computed at the pixels that
    ``mask`` marks only, the others being 0 either way (a person covers a small part of a frame: on the bundled walk's
    320×240 stereo frames, 2 % of the pixels, :meth:`StaticBackground.update` of a plate background took 0.41
    instead of 4.6 ms a view). Returns a new array."""
    out = np.array(mask, np.uint8, copy=True)
    idx = np.flatnonzero(out)
    if idx.size == 0:
        return out
    sel = lambda a: np.asarray(a).reshape(-1, 3)[idx][None]  # noqa: E731 ((1, n, 3), the masked pixels)
    alpha, cd = brightness_chromaticity_distortion(
        sel(frame), sel(mean), std if np.ndim(std) == 0 else sel(np.broadcast_to(std, np.shape(frame)))
    )
    shadow = (alpha[0] >= params.alpha_min) & (alpha[0] < params.alpha_max) & (cd[0] <= params.cd_max)
    out.reshape(-1)[idx[shadow]] = 0
    return out


def noise_sigma(image: np.ndarray) -> float:
    """Standard deviation of additive white sensor noise in ``image`` ``(H, W)`` or ``(H, W, C)`` (units of the
    image), estimated from the image alone.

    The residual of Immerkær's (1996) mask ``N = [[1, −2, 1], [−2, 4, −2], [1, −2, 1]]`` is zero on any locally
    linear intensity and, for white noise of variance ``σ²``, has variance ``σ² Σ N² = 36 σ²``; ``σ`` is the
    median absolute residual over the interior pixels divided by ``6 Φ⁻¹(3/4)`` (the median absolute deviation
    of a normal variable), so that the edges and texture of a scene, a minority of pixels, do not inflate it as
    they inflate Immerkær's mean. Per channel; the median over channels. Integer images quantise the median to
    steps of ``1 / (6 · 0.6745)``.
    """
    img = np.asarray(image, np.float32)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[0] < 3 or img.shape[1] < 3:
        raise MocapInputError(
            None, f"expected an image (H, W) or (H, W, C) of at least 3x3, got {np.shape(image)}"
        )
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    out = []
    for c in range(img.shape[2]):
        r = cv2.filter2D(img[..., c], cv2.CV_32F, kernel)[1:-1, 1:-1]
        out.append(float(np.median(np.abs(r))) / (6.0 * 0.6744897501960817))
    return float(np.median(out))


class StaticBackground:
    """Static background image with per-channel thresholds (Li & Kulić), optional shadow removal.

    ``update(frame)``: ``raw = OR_c (|I_c − B_c| > T_c)``; with ``shadow`` set, shadow pixels of ``raw``
    (tested with a constant noise ``noise_std`` per channel) are removed; then opening and dilation
    (``clean_mask``). ``thresholds`` are given in B, G, R order like the frames (a scalar applies to all).
    """

    def __init__(
        self,
        background: np.ndarray,
        thresholds: float | tuple[float, float, float] = 30.0,
        open_size: int = 3,
        dilate_size: int = 3,
        shadow: ShadowParams | None = None,
        noise_std: float = 4.0,
    ):
        self.background = _check_frame(background, what="background").copy()
        t = np.broadcast_to(np.asarray(thresholds, np.float64), (3,))
        if np.any(t < 0):
            raise ValueError(f"thresholds must be non-negative, got {thresholds}")
        # cv2.inRange keeps |I − B| ≤ T as background; foreground is the complement (|I − B| > T).
        self._upper = tuple(float(np.floor(x)) for x in t)
        self.open_size = open_size
        self.dilate_size = dilate_size
        self.shadow = shadow
        self.noise_std = float(noise_std)

    @classmethod
    def from_frames(cls, frames, **kwargs) -> StaticBackground:
        """Background = per-pixel median of a stack of frames ``(T, H, W, 3)`` (robust to passing people)."""
        frames = np.asarray(frames)
        if frames.ndim != 4:
            raise MocapInputError(None, f"expected frames (T, H, W, 3), got shape {frames.shape}")
        return cls(np.median(frames, axis=0).astype(frames.dtype), **kwargs)

    def raw_mask(self, frame: np.ndarray) -> np.ndarray:
        """Thresholded difference before shadow removal and morphology: ``uint8`` 0/255."""
        frame = _check_frame(frame, self.background.shape)
        diff = cv2.absdiff(frame, self.background)
        return cv2.bitwise_not(cv2.inRange(diff, (0, 0, 0), self._upper))

    def update(self, frame: np.ndarray) -> np.ndarray:
        mask = self.raw_mask(frame)
        if self.shadow is not None:
            mask = without_shadows(mask, frame, self.background, self.noise_std, self.shadow)
        return clean_mask(mask, self.open_size, self.dilate_size)


def plate_background(
    plate: np.ndarray,
    sigma: float | None = None,
    shadow: ShadowParams | None = PLATE_SHADOW,
    open_size: int = 1,
    dilate_size: int = 1,
    threshold: float | None = None,
) -> StaticBackground:
    """A :class:`StaticBackground` against a recorded empty-scene ``plate`` ``(H, W, 3)`` BGR uint8.

    ``sigma``: the sensor noise (8-bit units); None estimates it from the plate (:func:`noise_sigma`). A frame
    and the plate each carry that noise, so their difference has ``√2 σ``: the threshold is four of those,
    ``T = max(8, 4 √2 σ)`` per channel (``threshold`` given: that instead), and the shadow test (``shadow``;
    None: no shadow removal) uses ``√2 σ`` (at least 1) as its noise scale. ``open_size`` / ``dilate_size``:
    :func:`clean_mask` (default none).
    """
    plate = _check_frame(plate, what="plate")
    sigma = noise_sigma(plate) if sigma is None else float(sigma)
    if not np.isfinite(sigma) or sigma < 0:
        raise ValueError(f"sensor noise must be finite and non-negative, got {sigma}")
    return StaticBackground(
        plate,
        max(8.0, 4.0 * np.sqrt(2.0) * sigma) if threshold is None else threshold,
        open_size=open_size,
        dilate_size=dilate_size,
        shadow=shadow,
        noise_std=max(1.0, np.sqrt(2.0) * sigma),
    )


class GaussianBackground:
    """Adaptive single Gaussian per pixel and channel with learning rate ``rho`` (López Méndez eq. 4.1–4.2).

    ``update(frame)`` classifies ``frame`` against the current model, foreground where ``|I_c − μ_c| > k σ_c``
    for any channel (``σ_c`` floored at ``min_std``), removes shadows if ``shadow`` is set, cleans the mask
    (``clean_mask``), then updates the model:

        μ_t  = ρ I_t + (1 − ρ) μ_{t−1}                 (4.1)
        σ²_t = ρ (I_t − μ_t)² + (1 − ρ) σ²_{t−1}       (4.2)

    With ``selective=True`` only pixels classified as background are updated (the classic variant; it does not
    recover from lasting global changes). The first frame (or ``initialise``) sets ``μ`` and ``σ² = init_std²``.

    The default ``ρ = 0.01`` keeps a person who passes over a pixel for a few frames from inflating its ``σ``
    (each foreground frame adds ``ρ (I − μ)²`` to ``σ²``), yet adapts to a global change within ~1/(ρk) frames
    because ``σ`` grows with the persistent difference.
    """

    def __init__(
        self,
        rho: float = 0.01,
        k: float = 3.0,
        init_std: float = 10.0,
        min_std: float = 3.0,
        shadow: ShadowParams | None = None,
        open_size: int = 3,
        dilate_size: int = 3,
        selective: bool = False,
    ):
        if not 0.0 < rho <= 1.0:
            raise ValueError(f"rho must lie in (0, 1], got {rho}")
        self.rho = float(rho)
        self.k = float(k)
        self.init_std = float(init_std)
        self.min_std = float(min_std)
        self.shadow = shadow
        self.open_size = open_size
        self.dilate_size = dilate_size
        self.selective = selective
        self.mean: np.ndarray | None = None
        self.var: np.ndarray | None = None

    def initialise(self, frame: np.ndarray) -> None:
        frame = _check_frame(frame)
        self.mean = np.ascontiguousarray(frame, dtype=np.float32).copy()
        self.var = np.full(frame.shape, self.init_std**2, np.float32)
        # work buffers (the per-frame arithmetic writes into them instead of allocating)
        self._I = np.empty_like(self.mean)
        self._d = np.empty_like(self.mean)
        self._s = np.empty_like(self.mean)

    @property
    def std(self) -> np.ndarray:
        """``max(σ, min_std)`` per pixel and channel, ``(H, W, 3)`` float32."""
        return np.maximum(cv2.sqrt(self.var), np.float32(self.min_std))

    def _as_float(self, frame: np.ndarray) -> np.ndarray:
        np.copyto(self._I, frame, casting="unsafe")
        return self._I

    def classify(self, frame: np.ndarray) -> np.ndarray:
        """Foreground mask of ``frame`` under the current model, without updating it."""
        frame = _check_frame(frame, self.mean.shape)
        I = self._as_float(frame)
        cv2.sqrt(self.var, dst=self._s)
        np.maximum(self._s, np.float32(self.min_std), out=self._s)  # σ
        np.multiply(self._s, np.float32(self.k), out=self._d)  # k σ
        over = cv2.compare(cv2.absdiff(I, self.mean), self._d, cv2.CMP_GT)  # (H, W, 3) 0/255
        b, g, r = cv2.split(over)
        mask = cv2.bitwise_or(cv2.bitwise_or(b, g), r)
        if self.shadow is not None:
            mask = without_shadows(mask, I, self.mean, self._s, self.shadow)
        return clean_mask(mask, self.open_size, self.dilate_size)

    def learn(self, frame: np.ndarray, mask: np.ndarray | None = None) -> None:
        """Apply eq. 4.1–4.2 to every pixel (or, with ``mask``, only where ``mask == 0``), in place."""
        I = self._as_float(_check_frame(frame, self.mean.shape))
        keep_out = None if mask is None else cv2.compare(np.asarray(mask), 0, cv2.CMP_EQ)
        cv2.accumulateWeighted(I, self.mean, self.rho, mask=keep_out)  # μ ← ρ I + (1 − ρ) μ
        d = cv2.subtract(I, self.mean, dst=self._d)
        cv2.multiply(d, d, dst=d)
        cv2.accumulateWeighted(d, self.var, self.rho, mask=keep_out)  # σ² ← ρ (I − μ)² + (1 − ρ) σ²

    def update(self, frame: np.ndarray) -> np.ndarray:
        if self.mean is None:
            self.initialise(frame)
            return np.zeros(frame.shape[:2], np.uint8)
        mask = self.classify(frame)
        self.learn(frame, mask if self.selective else None)
        return mask


class Mog2Background:
    """OpenCV MOG2 background subtractor; shadows (label 127) count as background, then ``clean_mask``.

    ``learning_rate < 0`` lets OpenCV choose ``1 / min(frames seen, history)``.
    """

    def __init__(
        self,
        history: int = 200,
        var_threshold: float = 16.0,
        detect_shadows: bool = True,
        learning_rate: float = -1.0,
        open_size: int = 3,
        dilate_size: int = 3,
    ):
        self.subtractor = cv2.createBackgroundSubtractorMOG2(
            history=history, varThreshold=var_threshold, detectShadows=detect_shadows
        )
        self.learning_rate = float(learning_rate)
        self.open_size = open_size
        self.dilate_size = dilate_size

    def update(self, frame: np.ndarray) -> np.ndarray:
        labels = self.subtractor.apply(_check_frame(frame), learningRate=self.learning_rate)
        mask = np.where(labels == 255, np.uint8(255), np.uint8(0))
        return clean_mask(mask, self.open_size, self.dilate_size)


def depth_foreground(
    depth: np.ndarray,
    background_depth: np.ndarray,
    margin: float = 0.1,
    max_depth: float | None = None,
) -> np.ndarray:
    """Foreground from depth: ``d > 0`` and (``d < d_bg − margin`` or ``d_bg = 0``), and ``d < max_depth``.

    Depths in metres along the camera axis, 0 = no measurement; where the background depth is unknown (0) any
    measured depth is closer than it, hence foreground. Returns ``uint8`` 0/255.
    """
    depth = np.asarray(depth, np.float32)
    bg = np.asarray(background_depth, np.float32)
    if depth.shape != bg.shape:
        raise MocapInputError(None, f"depth {depth.shape} and background depth {bg.shape} differ in shape")
    fg = (depth > 0) & ((bg <= 0) | (depth < bg - margin))
    if max_depth is not None:
        fg &= depth < max_depth
    return fg.astype(np.uint8) * np.uint8(255)


class DepthBackground:
    """Static background depth (per-pixel median of the non-zero depths of some frames) + ``depth_foreground``."""

    def __init__(
        self,
        background_depth: np.ndarray,
        margin: float = 0.1,
        max_depth: float | None = None,
        open_size: int = 3,
        dilate_size: int = 1,
    ):
        self.background_depth = np.asarray(background_depth, np.float32)
        self.margin = float(margin)
        self.max_depth = max_depth
        self.open_size = open_size
        self.dilate_size = dilate_size

    @classmethod
    def from_frames(cls, depths, **kwargs) -> DepthBackground:
        d = np.asarray(depths, np.float32)
        d = np.where(d > 0, d, np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN pixels: no background depth (0)
            med = np.nanmedian(d, axis=0)
        return cls(np.nan_to_num(med, nan=0.0).astype(np.float32), **kwargs)

    def update(self, depth: np.ndarray) -> np.ndarray:
        mask = depth_foreground(depth, self.background_depth, self.margin, self.max_depth)
        return clean_mask(mask, self.open_size, self.dilate_size)
