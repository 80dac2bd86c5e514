"""Empty-scene background plates of a synthetic sequence, and background subtraction scored against its masks.

A real multi-camera setup records each camera's empty scene before the subject walks in; the synthesiser writes
the same: ``views/<camera>/background.png``, the view's background at the base illumination (no global change)
with one exposure's sensor noise ``N(0, noise²)`` from ``default_rng([seed, 2²⁰, view, 3])``, quantised to 8 bits.
Trackers subtract it as they would a recorded plate.

:func:`subtraction_iou` segments every frame of a sequence against its plates with the static-background model
of :mod:`jaxmocap.features.foreground` (per-channel thresholds at four standard deviations of the noise, shadow
removal in the room, no morphology) and scores the masks against the rendered ones: intersection over union per
frame and view.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.features import foreground as fg
from jaxmocap.io import sequence as seqio

__all__ = [
    "PLATE",
    "ROOM_SHADOW",
    "plate_path",
    "plate_image",
    "read_plate",
    "subtractors",
    "subtraction_iou",
]

#: File name of a view's plate inside ``views/<camera>/``.
PLATE = seqio.PLATE


def plate_path(root: str | os.PathLike, view: str) -> pathlib.Path:
    """``root/views/<view>/background.png``."""
    return pathlib.Path(root) / seqio.VIEWS / view / PLATE


def plate_image(rng: np.random.Generator, background: np.ndarray, noise: float) -> np.ndarray:
    """``(H, W, 3)`` uint8 plate: ``background`` (float in [0, 1]) plus ``N(0, noise²)`` per pixel and channel,
    times 255, rounded and saturated."""
    image = np.asarray(background, np.float32) * np.float32(255.0)
    image = image + rng.standard_normal(image.shape, dtype=np.float32) * np.float32(255.0 * noise)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def read_plate(root: str | os.PathLike, view: str) -> np.ndarray:
    """The ``(H, W, 3)`` uint8 RGB plate of ``view``; :class:`MocapInputError` when missing or unreadable."""
    path = plate_path(root, view)
    if not path.is_file():
        raise MocapInputError(path, "no background plate (sequences written before plates existed have none)")
    return seqio.read_rgb(path)


#: Shadow test for the room's shadows: a full shadow darkens the floor to ``ROOM_AMBIENT / (ROOM_AMBIENT + (1 −
#: ROOM_AMBIENT) n·l̂)`` ≈ 0.64 of its lit colour (:mod:`jaxmocap.synth.scene`); partial shadows lie between.
ROOM_SHADOW = fg.PLATE_SHADOW


def subtractors(
    seq: seqio.Sequence,
    thresholds: float | None = None,
    shadow: fg.ShadowParams | None | str = "auto",
    open_size: int = 1,
) -> list[fg.StaticBackground]:
    """One static-background model per view of ``seq``, against its plate (BGR, like the frames it segments):
    :func:`jaxmocap.features.foreground.plate_background` with the sequence's known sensor noise ``σ``
    (``meta["noise"]["rgb_sigma"] · 255``).

    ``thresholds`` (8-bit units) default to ``max(8, 4 √2 σ)``: four standard deviations of the difference of two
    noisy exposures. ``shadow``: Horprasert shadow removal parameters, or ``"auto"``: :data:`ROOM_SHADOW` for a
    sequence rendered in the room (where the body casts shadows), none otherwise; its noise scale is ``√2 σ``.
    ``open_size``: the opening's square (1: none); no dilation.
    """
    sigma = 255.0 * float(seq.meta.get("noise", {}).get("rgb_sigma", 0.01))
    if isinstance(shadow, str):
        shadow = ROOM_SHADOW if seq.meta.get("background") == "room" else None
    return [
        fg.plate_background(
            np.ascontiguousarray(read_plate(seq.root, view.name)[..., ::-1]),
            sigma,
            shadow,
            open_size=open_size,
            threshold=thresholds,
        )
        for view in seq.views
    ]


def subtraction_iou(
    seq: seqio.Sequence,
    thresholds: float | None = None,
    shadow: fg.ShadowParams | None | str = "auto",
    open_size: int = 1,
) -> np.ndarray:
    """``(T, V)`` IoU of the static-background masks against the plates (:func:`subtractors`, same arguments) with
    the rendered masks (module docstring); a frame where both masks are empty scores 1."""
    out = np.zeros((seq.num_frames, len(seq.views)))
    for v, (view, model) in enumerate(
        zip(seq.views, subtractors(seq, thresholds, shadow, open_size), strict=True)
    ):
        for t in range(seq.num_frames):
            pred = model.update(np.ascontiguousarray(view.rgb(t)[..., ::-1])) > 0
            truth = view.mask(t) > 0
            union = np.logical_or(pred, truth).sum()
            out[t, v] = np.logical_and(pred, truth).sum() / union if union else 1.0
    return out
