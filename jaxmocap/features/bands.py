"""Coloured wrist bands (Li & Kulić's distance cue): the pixels of the band colour in each view.

Li & Kulić mark the wrists with bands of one colour and measure, in 3D, the distance from each model wrist to the
bands seen by the stereo pair. Here a band pixel is one whose HSV colour lies in a box (OpenCV's HSV of 8-bit
frames: ``H ∈ [0, 180)``, ``S, V ∈ [0, 255]``); the mask then goes through the blob pipeline of
:mod:`jaxmocap.features.blobs` (connected components, epipolar matching, triangulation) like a skin map does, and
fills the observation's 3D blob slots that the ``wristband`` cue reads.

The default box, :data:`LIME`, fits the saturated lime green (RGB ``(0.55, 0.90, 0.05)``, hue 85°) of the bands
that ``jaxmocap synth --wrist-bands`` draws: hue 76–94° (``H`` 38–47), saturation above 0.7, value above 0.39,
which leaves out skin (hue 0–50°), the clothing colours, grey backgrounds and the dark olive of the photo
background's curtain. A black band, as in the paper, cannot be told from hair, shadows and dark clothing by colour
alone; give the box of the bands actually worn.
"""

from __future__ import annotations

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError

__all__ = ["LIME", "band_mask"]

#: HSV box ``((H, S, V) low, (H, S, V) high)`` of lime-green bands (module docstring), OpenCV 8-bit units.
LIME: tuple[tuple[int, int, int], tuple[int, int, int]] = ((38, 180, 100), (47, 255, 255))


def band_mask(frame: np.ndarray, hsv_box=LIME) -> np.ndarray:
    """``(H, W)`` uint8 mask, 255 where the BGR uint8 ``frame`` ``(H, W, 3)`` has its HSV colour inside
    ``hsv_box`` (bounds included)."""
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise MocapInputError(None, f"expected a BGR uint8 image (H, W, 3), got {frame.dtype} {frame.shape}")
    lo, hi = (tuple(int(x) for x in b) for b in hsv_box)
    if not all(0 <= a <= b for a, b in zip(lo, hi, strict=True)) or hi[0] > 179 or max(hi) > 255:
        raise ValueError(
            f"an HSV box is ((H, S, V) low, (H, S, V) high) within H < 180, S, V ≤ 255; got {hsv_box}"
        )
    return cv2.inRange(cv2.cvtColor(frame, cv2.COLOR_BGR2HSV), lo, hi)
