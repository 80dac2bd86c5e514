"""Wrist bands (Li & Kulić's distance cue): band pixels by colour, matched across the stereo pair and triangulated,
against the renderer's ground-truth wrists of a real CMU walk."""

import numpy as np
import pytest

from jaxmocap.features import bands
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io import sequence as seqio
from jaxmocap.io.sources import SequenceSource
from jaxmocap.synth import generate as synth
from jaxmocap.tracking.features import FeatureBuilder

WRISTS = [EVAL_JOINTS.index("left_wrist"), EVAL_JOINTS.index("right_wrist")]


def _blobs(root):
    src = SequenceSource(root)
    fb = FeatureBuilder(src, ["wristband"], foreground="none")
    for t in range(src.num_frames):
        obs, _ = fb(src.read(t), dof=6)
        yield t, np.asarray(obs.image.blobs3d), np.asarray(obs.image.blob_conf)


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """Six frames at 320×240 of the bundled CMU walk, stereo, with and without lime wrist bands."""
    out = {}
    for worn in (True, False):
        d = tmp_path_factory.mktemp("bands") / str(worn)
        synth.synthesize(
            "demo", d, rig="stereo", frames="0:48", fps=15.0, size="320x240", seed=0, overwrite=True,
            wrist_bands=worn,
        )  # fmt: skip
        out[worn] = d
    return out


def test_bands_triangulate_at_the_wrists(walk):
    """Both bands are found in every frame, one at each wrist: the band (4 cm wide, ending at the wrist) is seen
    on the forearm's surface (radius ≈ 4 cm), so its centroid lies within about 2 + 4 cm of the wrist joint, plus
    the triangulation error of centroids a few pixels across on a 0.3 m baseline: bound 80 mm (the median over
    these frames is about 32 mm)."""
    gt = seqio.load_sequence(walk[True]).groundtruth.joints
    n = 0
    for t, b, c in _blobs(walk[True]):
        seen = b[c > 0]
        assert len(seen) == 2, (t, c)
        d = np.linalg.norm(seen[:, None, :] - gt[t][WRISTS][None], axis=-1)  # (blob, wrist)
        nearest = np.argmin(d, axis=1)
        assert sorted(nearest) == [0, 1], d  # one band at each wrist
        assert np.all(np.min(d, axis=1) < 0.08), d
        n += 1
    assert n == 6


def test_no_bands_no_blobs(walk):
    """Without bands nothing in the scene (skin, clothing, the photo background) passes the colour box."""
    assert all(np.all(c == 0) for _, _, c in _blobs(walk[False]))


def test_band_mask_colour_box():
    """The box in OpenCV's HSV: the synthesiser's lime (RGB 0.55, 0.90, 0.05 → H 42, S 240) in, skin and grey
    out; a box outside OpenCV's ranges is refused."""
    lime = np.array([[[round(0.05 * 255), round(0.90 * 255), round(0.55 * 255)]]], np.uint8)  # BGR
    skin = np.array([[[120, 150, 210]]], np.uint8)
    grey = np.array([[[128, 128, 128]]], np.uint8)
    assert [int(bands.band_mask(x)[0, 0]) for x in (lime, skin, grey)] == [255, 0, 0]
    with pytest.raises(ValueError, match="HSV box"):
        bands.band_mask(lime, ((0, 0, 0), (200, 255, 255)))
