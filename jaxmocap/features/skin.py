"""Skin colour models: RGB histogram likelihood ratio (López Méndez 2009) and hue–saturation back-projection
(Fontmarty et al., IROS 2007), trained from labelled pixels.

RGB model: colour histograms with ``b`` bins per channel (default 8, i.e. 512 bins) of skin pixels ``h_s`` and
non-skin pixels ``h_n`` give, with a pseudo-count ``a`` per bin (additive smoothing),

    P(c | skin) = (h_s[c] + a) / (N_s + a B),    P(c | non-skin) = (h_n[c] + a) / (N_n + a B),
    L(c) = P(c | skin) / P(c | non-skin),         p(skin | c) = π L / (π L + 1 − π)

with ``B = b³`` bins and prior ``π`` (default 0.5, so ``p = L / (1 + L)``). ``SkinModel.probability`` evaluates
``p`` as a lookup table through ``cv2.calcBackProject``.

HS model: the hue–saturation histogram of skin pixels (OpenCV HSV: H in [0, 180), S in [0, 256)), scaled so that
its largest bin is 1, back-projected onto the image (``SkinModel.hs_backprojection``).

A default model trained on real images ships in ``jaxmocap/data/skin/`` (see its README and
``jaxmocap.features.skin_training``).
"""

from __future__ import annotations

import os
import pathlib
from dataclasses import dataclass

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError

DEFAULT_MODEL_PATH = pathlib.Path(__file__).resolve().parent.parent / "data" / "skin" / "skin_model.npz"


def _rgb_bin_index(bgr: np.ndarray, bins: int) -> np.ndarray:
    """``(..., 3)`` BGR ``uint8`` → flat bin index ``(r_bin · b + g_bin) · b + b_bin``."""
    q = (bgr.astype(np.int64) * bins) // 256
    return (q[..., 2] * bins + q[..., 1]) * bins + q[..., 0]


def _hs_counts(bgr_pixels: np.ndarray, hs_bins: tuple[int, int]) -> np.ndarray:
    if len(bgr_pixels) == 0:
        return np.zeros(hs_bins, np.float64)
    hsv = cv2.cvtColor(bgr_pixels.reshape(-1, 1, 3), cv2.COLOR_BGR2HSV).reshape(-1, 3).astype(np.int64)
    hb = np.minimum(hsv[:, 0] * hs_bins[0] // 180, hs_bins[0] - 1)
    sb = hsv[:, 1] * hs_bins[1] // 256
    return (
        np.bincount(hb * hs_bins[1] + sb, minlength=hs_bins[0] * hs_bins[1])
        .reshape(hs_bins)
        .astype(np.float64)
    )


def _check_pixels(pixels, what: str) -> np.ndarray:
    p = np.asarray(pixels)
    if p.dtype != np.uint8:
        raise MocapInputError(None, f"{what}: expected uint8 BGR pixels, got dtype {p.dtype}")
    p = p.reshape(-1, 3) if p.ndim >= 2 and p.shape[-1] == 3 else None
    if p is None:
        raise MocapInputError(None, f"{what}: expected (..., 3) BGR pixels, got shape {np.shape(pixels)}")
    return p


@dataclass
class SkinModel:
    """Histograms of skin / non-skin colours.

    ``rgb_skin``, ``rgb_nonskin``: counts ``(b, b, b)`` indexed ``[R, G, B]`` bins; ``hs_skin``, ``hs_nonskin``:
    counts ``(h, s)``; ``pseudo_count``: additive smoothing per bin; ``prior``: π of the posterior.
    """

    rgb_skin: np.ndarray
    rgb_nonskin: np.ndarray
    hs_skin: np.ndarray
    hs_nonskin: np.ndarray
    pseudo_count: float = 1.0
    prior: float = 0.5
    description: str = ""

    def __post_init__(self):
        self.rgb_skin = np.asarray(self.rgb_skin, np.float64)
        self.rgb_nonskin = np.asarray(self.rgb_nonskin, np.float64)
        self.hs_skin = np.asarray(self.hs_skin, np.float64)
        self.hs_nonskin = np.asarray(self.hs_nonskin, np.float64)
        b = self.rgb_skin.shape[0]
        if self.rgb_skin.shape != (b, b, b) or self.rgb_nonskin.shape != (b, b, b):
            raise MocapInputError(None, "skin model: RGB histograms must both be (b, b, b)")
        if not 2 <= b <= 16 or 256 % b:
            raise MocapInputError(
                None, f"skin model: RGB bins per channel must divide 256 and be ≤ 16, got {b}"
            )
        if self.hs_skin.ndim != 2 or self.hs_skin.shape != self.hs_nonskin.shape:
            raise MocapInputError(None, "skin model: HS histograms must both be (h, s)")
        self._lut_cache: dict = {}

    @property
    def rgb_bins(self) -> int:
        return int(self.rgb_skin.shape[0])

    @property
    def hs_bins(self) -> tuple[int, int]:
        return tuple(int(x) for x in self.hs_skin.shape)

    # --- RGB likelihood ratio -------------------------------------------------------------------------------
    def likelihood_ratio_table(self) -> np.ndarray:
        """``L`` per bin, ``(b, b, b)`` indexed ``[R, G, B]``."""
        a = self.pseudo_count
        B = self.rgb_skin.size
        ps = (self.rgb_skin + a) / (self.rgb_skin.sum() + a * B)
        pn = (self.rgb_nonskin + a) / (self.rgb_nonskin.sum() + a * B)
        return ps / pn

    def probability_table(self, prior: float | None = None) -> np.ndarray:
        """``p(skin | c) = π L / (π L + 1 − π)`` per bin, ``(b, b, b)``."""
        pi = self.prior if prior is None else prior
        L = self.likelihood_ratio_table()
        return pi * L / (pi * L + (1.0 - pi))

    def likelihood_ratio(self, image: np.ndarray) -> np.ndarray:
        """``(H, W)`` float32 map of ``L`` at each pixel of a BGR ``uint8`` image."""
        image = _check_image(image)
        return (
            self.likelihood_ratio_table().reshape(-1)[_rgb_bin_index(image, self.rgb_bins)].astype(np.float32)
        )

    def _lut(self, prior: float) -> tuple[np.ndarray, np.ndarray]:
        key = float(prior)
        if key not in self._lut_cache:
            b = self.rgb_bins
            table = np.rint(self.probability_table(prior) * 255.0).astype(np.float32)
            bin_of_value = ((np.arange(256) * b) // 256).astype(np.uint8)
            self._lut_cache[key] = (bin_of_value, table.reshape(b, b * b))
        return self._lut_cache[key]

    def probability_u8(self, image: np.ndarray, prior: float | None = None) -> np.ndarray:
        """``(H, W)`` ``uint8`` map ``round(255 · p(skin | c))`` of a BGR ``uint8`` image (fast path)."""
        image = _check_image(image)
        b = self.rgb_bins
        bin_of_value, table = self._lut(self.prior if prior is None else prior)
        q = cv2.LUT(image, bin_of_value)
        qb, qg, qr = cv2.split(q)
        gb = cv2.scaleAdd(qg, float(b), qb)  # g_bin · b + b_bin < b² ≤ 256
        return cv2.calcBackProject([qr, gb], [0, 1], table, [0, b, 0, b * b], 1)

    def probability(self, image: np.ndarray, prior: float | None = None) -> np.ndarray:
        """``(H, W)`` float32 skin probability in [0, 1] (quantised to 1/255 steps)."""
        return self.probability_u8(image, prior).astype(np.float32) * np.float32(1.0 / 255.0)

    # --- HS back-projection ---------------------------------------------------------------------------------
    def hs_backprojection(self, image: np.ndarray) -> np.ndarray:
        """``(H, W)`` float32 in [0, 1]: skin HS histogram (largest bin = 1) at each pixel's hue–saturation."""
        image = _check_image(image)
        hist = self.hs_skin.astype(np.float32)
        top = float(hist.max())
        hist = hist * np.float32(255.0 / top) if top > 0 else hist
        hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
        bp = cv2.calcBackProject([hsv], [0, 1], hist, [0, 180, 0, 256], 1)
        return bp.astype(np.float32) * np.float32(1.0 / 255.0)

    # --- I/O ------------------------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> None:
        np.savez_compressed(
            path,
            rgb_skin=self.rgb_skin.astype(np.int64),
            rgb_nonskin=self.rgb_nonskin.astype(np.int64),
            hs_skin=self.hs_skin.astype(np.int64),
            hs_nonskin=self.hs_nonskin.astype(np.int64),
            pseudo_count=self.pseudo_count,
            prior=self.prior,
            description=np.array(self.description),
        )

    @classmethod
    def load(cls, path: str | os.PathLike) -> SkinModel:
        try:
            with np.load(path, allow_pickle=False) as z:
                return cls(
                    rgb_skin=z["rgb_skin"],
                    rgb_nonskin=z["rgb_nonskin"],
                    hs_skin=z["hs_skin"],
                    hs_nonskin=z["hs_nonskin"],
                    pseudo_count=float(z["pseudo_count"]),
                    prior=float(z["prior"]),
                    description=str(z["description"]),
                )
        except FileNotFoundError:
            raise MocapInputError(path, "skin model file not found") from None
        except (KeyError, ValueError, OSError) as e:
            raise MocapInputError(path, f"not a skin model file: {e}") from None


def _check_image(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise MocapInputError(None, f"expected a BGR uint8 image (H, W, 3), got {image.dtype} {image.shape}")
    return image


def train_skin_model(
    skin_pixels: np.ndarray,
    nonskin_pixels: np.ndarray,
    rgb_bins: int = 8,
    hs_bins: tuple[int, int] = (30, 32),
    pseudo_count: float = 1.0,
    prior: float = 0.5,
    description: str = "",
) -> SkinModel:
    """Histograms from labelled BGR ``uint8`` pixels ``(..., 3)`` of skin and non-skin."""
    s = _check_pixels(skin_pixels, "skin pixels")
    n = _check_pixels(nonskin_pixels, "non-skin pixels")
    if len(s) == 0 or len(n) == 0:
        raise MocapInputError(None, "training a skin model needs at least one skin and one non-skin pixel")
    B = rgb_bins**3
    rgb_s = np.bincount(_rgb_bin_index(s, rgb_bins), minlength=B).reshape(rgb_bins, rgb_bins, rgb_bins)
    rgb_n = np.bincount(_rgb_bin_index(n, rgb_bins), minlength=B).reshape(rgb_bins, rgb_bins, rgb_bins)
    return SkinModel(
        rgb_skin=rgb_s,
        rgb_nonskin=rgb_n,
        hs_skin=_hs_counts(s, hs_bins),
        hs_nonskin=_hs_counts(n, hs_bins),
        pseudo_count=pseudo_count,
        prior=prior,
        description=description,
    )


def train_from_masks(images, skin_masks, nonskin_masks, **kwargs) -> SkinModel:
    """Train from BGR images and per-image ``uint8``/bool masks of skin and of non-skin pixels."""
    s, n = [], []
    for img, ms, mn in zip(images, skin_masks, nonskin_masks, strict=True):
        img = _check_image(img)
        s.append(img[np.asarray(ms) > 0])
        n.append(img[np.asarray(mn) > 0])
    return train_skin_model(np.concatenate(s), np.concatenate(n), **kwargs)


def default_skin_model() -> SkinModel:
    """The model shipped in ``jaxmocap/data/skin/skin_model.npz`` (see the README there)."""
    if not DEFAULT_MODEL_PATH.exists():
        raise MocapInputError(DEFAULT_MODEL_PATH, "default skin model missing from the installed package")
    return SkinModel.load(DEFAULT_MODEL_PATH)
