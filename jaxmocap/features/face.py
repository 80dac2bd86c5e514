"""Frontal face detection with OpenCV's Viola–Jones Haar cascade (``haarcascade_frontalface_default.xml``)."""

from __future__ import annotations

import os

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.features.edges import luminance

DEFAULT_CASCADE = "haarcascade_frontalface_default.xml"


def default_cascade_path() -> str:
    """Path of the frontal-face cascade shipped with opencv-python (``cv2.data.haarcascades``)."""
    data = getattr(cv2, "data", None)
    base = getattr(data, "haarcascades", None)
    if base is None:
        raise MocapInputError(
            DEFAULT_CASCADE,
            "this OpenCV build has no cv2.data.haarcascades; install opencv-python(-headless) or pass "
            "cascade_path explicitly",
        )
    return os.path.join(base, DEFAULT_CASCADE)


class FaceDetector:
    """Haar-cascade face detector.

    ``detect(image) -> (F, 4)`` int boxes ``(x, y, w, h)`` in pixels, largest first. The image is converted to
    luminance and histogram-equalised first. Raises ``MocapInputError`` naming the file when the cascade is
    missing or cannot be loaded.
    """

    def __init__(
        self,
        cascade_path: str | os.PathLike | None = None,
        scale_factor: float = 1.1,
        min_neighbors: int = 5,
        min_size: tuple[int, int] = (30, 30),
        equalize: bool = True,
    ):
        path = default_cascade_path() if cascade_path is None else os.fspath(cascade_path)
        if not os.path.isfile(path):
            raise MocapInputError(path, "Haar cascade file not found")
        try:
            self.classifier = cv2.CascadeClassifier(path)
        except (cv2.error, SystemError) as e:
            raise MocapInputError(path, f"OpenCV could not load this Haar cascade: {e}") from None
        if self.classifier.empty():
            raise MocapInputError(path, "OpenCV could not load this Haar cascade")
        self.path = path
        self.scale_factor = scale_factor
        self.min_neighbors = min_neighbors
        self.min_size = tuple(min_size)
        self.equalize = equalize

    @property
    def window(self) -> tuple[int, int]:
        """The cascade's own window ``(w, h)``, pixels (24 × 24 for the default cascade): no face smaller than
        this is found, whatever ``min_size``."""
        return tuple(int(v) for v in self.classifier.getOriginalWindowSize())

    def detect(self, image: np.ndarray, min_size=None, max_size=None) -> np.ndarray:
        """Face boxes of ``image``; ``min_size``/``max_size`` ``(w, h)`` bound the boxes searched for (default:
        the detector's ``min_size``, no upper bound): the cascade scans only the scales between them."""
        grey = luminance(image)
        if self.equalize:
            grey = cv2.equalizeHist(grey)
        boxes = self.classifier.detectMultiScale(
            grey,
            scaleFactor=self.scale_factor,
            minNeighbors=self.min_neighbors,
            minSize=self.min_size if min_size is None else tuple(int(v) for v in min_size),
            maxSize=(0, 0) if max_size is None else tuple(int(v) for v in max_size),
        )
        boxes = np.asarray(boxes, np.int64).reshape(-1, 4)
        order = np.argsort(-(boxes[:, 2] * boxes[:, 3]), kind="stable")
        return boxes[order]
