"""Empty-scene plates: every view's plate is its frames' background under independent sensor noise, and background
subtraction against the plates recovers the rendered silhouettes of a walk (IoU per frame above a bound set from a
measurement)."""

import numpy as np
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.synth import generate as synth
from jaxmocap.synth import plates

SIZE = (160, 120)


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """The whole bundled walk at 5 frames/s, stereo, 160×120 (15 frames)."""
    return synth.synthesize("demo", tmp_path_factory.mktemp("walk"), rig="stereo", fps=5, size=SIZE, seed=4)


def test_plate_is_the_background_under_independent_noise(walk):
    """Where the mask is empty, frame − plate has mean 0 and variance 2σ² (two independent exposures of the same
    scene, σ = 0.01 · 255); bounds are four standard errors of the mean and of the variance (Gaussian fourth
    moment), widened by the 8-bit rounding (variance 1/12 per image)."""
    sigma2 = (0.01 * 255) ** 2
    for view in walk.views:
        plate = plates.read_plate(walk.root, view.name).astype(np.float64)
        assert plate.shape == (SIZE[1], SIZE[0], 3)
        d = np.concatenate([(view.rgb(t) - plate)[view.mask(t) == 0] for t in (0, 7, 14)]).ravel()
        n = d.size
        var = 2 * sigma2 + 2 / 12
        assert abs(d.mean()) < 4 * np.sqrt(var / n)
        assert abs(d.var() - var) < 4 * np.sqrt(2 * var**2 / n) + 0.05 * var  # saturated pixels clip a little


def test_subtraction_recovers_the_silhouettes(walk):
    """Measured on this walk (seed 4, 160×120): IoU per frame 0.959–0.995 over both views (mean 0.986); the
    bounds 0.90 per frame and 0.95 on the mean leave room for other platforms' rounding of the renders, not for a
    broken plate (the two views' plates exchanged score at most 0.044)."""
    iou = plates.subtraction_iou(walk)
    assert iou.shape == (walk.num_frames, 2)
    assert iou.min() > 0.90 and iou.mean() > 0.95


def test_missing_plate_is_a_clear_error(walk, tmp_path):
    with pytest.raises(MocapInputError, match="no background plate"):
        plates.read_plate(tmp_path, "left")
