"""Down-sampling of frames by 2 or 4 and the matching rescaled calibration.

Frames are resized with ``cv2.resize(img, None, fx=1/f, fy=1/f, interpolation=INTER_AREA)`` (area averaging),
which maps pixel centres as ``u' = (u + ½)/f − ½``; ``jaxmocap.geometry.camera.scale_images(rig, 1/f)`` applies the same
mapping to the intrinsics (``f_x' = f_x / f``, ``c_x' = (c_x + ½)/f − ½``) and gives the same image sizes
(``round(w / f)``). Distortion coefficients act on normalised coordinates and are unchanged.
"""

from __future__ import annotations

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry.camera import scale_images

FACTORS = (1, 2, 4)


def _check_factor(factor: int) -> int:
    if factor not in FACTORS:
        raise ValueError(f"down-sampling factor must be one of {FACTORS}, got {factor}")
    return int(factor)


def downsample(image: np.ndarray, factor: int) -> np.ndarray:
    """Area-averaged down-sampling by ``factor`` (1, 2 or 4); see the module docstring for the geometry."""
    factor = _check_factor(factor)
    if factor == 1:
        return image
    h, w = image.shape[:2]
    if w < factor or h < factor:
        raise MocapInputError(None, f"image {w}x{h} too small to down-sample by {factor}")
    return cv2.resize(image, None, fx=1.0 / factor, fy=1.0 / factor, interpolation=cv2.INTER_AREA)


def scale_rig(rig, factor: int):
    """The ``Rig`` of frames down-sampled by ``factor`` with ``downsample`` (``camera.scale_images(rig, 1/f)``)."""
    factor = _check_factor(factor)
    if factor == 1:
        return rig
    return scale_images(rig, 1.0 / factor)
