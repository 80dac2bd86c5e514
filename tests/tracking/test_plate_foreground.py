"""``--foreground plate``: subtraction against each camera's recorded empty-scene plate, with the threshold from the
plate's own sensor noise. References: closed forms for the noise estimate (white Gaussian noise of a known σ, and
Immerkær's mean estimator on a flat image), the renderer's exact masks for the subtraction, and the command line's
one-line errors."""

import shutil

import cv2
import numpy as np
import pytest

from jaxmocap import cli
from jaxmocap.features import foreground as fg
from jaxmocap.io import sequence as seqio
from jaxmocap.io.sources import SequenceSource, VideoSource
from jaxmocap.tracking.features import FeatureBuilder

RNG = np.random.default_rng(20261125)


def _immerkaer_mean(image: np.ndarray) -> float:
    """Immerkær (1996): σ = √(π/2) / (6 (W − 2)(H − 2)) Σ |I ∗ N| over the interior (one channel)."""
    n = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float64)
    img = np.asarray(image, np.float64)
    h, w = img.shape
    r = sum(n[i, j] * img[i : h - 2 + i, j : w - 2 + j] for i in range(3) for j in range(3))
    return float(np.sqrt(np.pi / 2) * np.abs(r).sum() / (6 * (w - 2) * (h - 2)))


@pytest.mark.parametrize("sigma", [1.5, 3.0, 6.0])
def test_noise_estimate_of_white_noise_on_a_ramp(sigma):
    """A linear ramp plus N(0, σ²): the residual of the mask is pure noise, so the estimate is σ up to the spread
    of a median of ~75 000 residuals per channel (relative standard error ≈ 1.25 / √n ≈ 0.5 %; residuals of
    overlapping masks are correlated, so 4 % is several standard errors), and agrees with Immerkær's mean."""
    y, x = np.mgrid[0:240, 0:320].astype(np.float64)
    ramp = 40 + 0.3 * x + 0.2 * y
    img = ramp[..., None] + RNG.normal(0.0, sigma, (240, 320, 3))
    est = fg.noise_sigma(img)
    assert est == pytest.approx(sigma, rel=0.04)
    assert _immerkaer_mean(img[..., 0]) == pytest.approx(sigma, rel=0.04)


def test_noise_estimate_ignores_the_edges_of_the_scene():
    """Rings 40 px wide of contrast 80 (about one pixel in twenty lies on a curved edge, which the mask, zero on
    straight axis-aligned edges, does not cancel): the median estimate stays within 10 % of σ = 3, where the mean
    estimator is inflated by the edges by a third."""
    y, x = np.mgrid[0:240, 0:320]
    board = np.where((np.hypot(x - 160, y - 120) // 40) % 2 == 0, 60.0, 140.0)
    img = board + RNG.normal(0.0, 3.0, board.shape)
    assert fg.noise_sigma(img) == pytest.approx(3.0, rel=0.10)
    assert _immerkaer_mean(img) > 1.25 * 3.0


def test_plate_threshold_follows_the_noise():
    """T = max(8, 4 √2 σ) per channel; σ = 0 gives the floor of 8 grey levels."""
    plate = np.full((8, 8, 3), 100, np.uint8)
    assert fg.plate_background(plate, sigma=5.0)._upper == (
        28.0,
        28.0,
        28.0,
    )  # floor(4 √2 · 5) = floor(28.28)
    assert fg.plate_background(plate)._upper == (8.0, 8.0, 8.0)  # a flat plate: σ̂ = 0
    with pytest.raises(ValueError, match="non-negative"):
        fg.plate_background(plate, sigma=-1.0)


@pytest.fixture(scope="module")
def without_masks(sequence, tmp_path_factory):
    """The command-line tests' synthetic stereo walk as a recording has it: images, calibration, the plates; no
    masks, depth, labels or ground truth."""
    out = tmp_path_factory.mktemp("recording") / "seq"
    shutil.copytree(
        sequence, out, ignore=shutil.ignore_patterns("mask", "depth", "labels", seqio.GROUNDTRUTH)
    )
    return out


def test_plate_subtraction_matches_the_rendered_masks(sequence, without_masks):
    """``auto`` on a folder without masks but with plates subtracts against them; the masks agree with the
    renderer's (mean IoU ≥ 0.85 over 10 frames at 96×72, where a one-pixel band around a 20-px-wide silhouette
    is already ~10 % of it)."""
    src = SequenceSource(without_masks)
    assert not src.has_masks and src.plate_files is not None
    fb = FeatureBuilder(src, ["foreground"], foreground="auto")
    assert fb.foreground == "plate"
    truth = seqio.load_sequence(sequence)
    ious = []
    for t in range(0, 60, 6):
        _, masks = fb(src.read(t), dof=6)
        for v, view in enumerate(truth.views):
            ref = view.mask(t) > 0
            ious.append(np.logical_and(masks[v], ref).sum() / np.logical_or(masks[v], ref).sum())
    assert np.mean(ious) >= 0.85, ious
    # the median of the run's frames is the other choice, and it is not the plate
    assert FeatureBuilder(src, ["foreground"], foreground="median").foreground == "median"


def test_a_folder_without_plates_cannot_subtract_them(without_masks, tmp_path):
    folder = tmp_path / "seq"
    shutil.copytree(without_masks, folder)
    (folder / seqio.VIEWS / SequenceSource(folder).view_names[0] / seqio.PLATE).unlink()
    src = SequenceSource(folder)
    assert src.plate_files is None
    assert FeatureBuilder(src, ["foreground"], foreground="auto").foreground == "median"
    with pytest.raises(ValueError, match="--foreground plate needs an empty-scene image per camera"):
        FeatureBuilder(src, ["foreground"], foreground="plate")


def _video(path, frames):
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, frames[0].shape[1::-1])
    for f in frames:
        w.write(f)
    w.release()


def test_video_plates_are_checked(sequence, tmp_path):
    """``--plates`` with ``--videos``: one per video; a plate of another size names the file."""
    seq = seqio.load_sequence(sequence)
    videos, plates = [], []
    for view in seq.views:
        _video(tmp_path / f"{view.name}.avi", [view.bgr(t) for t in range(3)])
        videos.append(tmp_path / f"{view.name}.avi")
        plates.append(sequence / seqio.VIEWS / view.name / seqio.PLATE)
    calib = sequence / seqio.CALIBRATION
    src = VideoSource(videos, calib, plates=plates)
    assert [p.shape for p in src.plates()] == [(72, 96, 3)] * 2
    with pytest.raises(Exception, match="1 plates for 2 videos"):
        VideoSource(videos, calib, plates=plates[:1])
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((10, 12, 3), np.uint8))
    with pytest.raises(Exception, match="the plate is 12x10 but the camera's images are 96x72"):
        VideoSource(videos, calib, plates=[small, small]).plates()
    code = cli.main(
        ["track", "--videos", *map(str, videos), "--calibration", str(calib), "--plates", str(plates[0]),
         "--out", str(tmp_path / "run")]
    )  # fmt: skip
    assert code == 2
