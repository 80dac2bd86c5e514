"""Gap filling and zero-phase Butterworth smoothing of the exported track, against closed forms."""

import numpy as np
import pytest

from jaxmocap.tracking import smoothing


def test_parse_smooth():
    assert smoothing.parse_smooth("none") is None and smoothing.parse_smooth(None) is None
    assert smoothing.parse_smooth("butterworth") == smoothing.DEFAULT_CUTOFF_HZ
    assert smoothing.parse_smooth("Butterworth:4.5", fps=30.0) == 4.5
    for bad, words in [("gauss", "butterworth"), ("butterworth:x", "number"), ("butterworth:-1", "positive")]:
        with pytest.raises(ValueError, match=words):
            smoothing.parse_smooth(bad)
    with pytest.raises(ValueError, match="below half the frame rate"):
        smoothing.parse_smooth("butterworth:15", fps=30.0)
    assert smoothing.smooth_text(None) == "none" and smoothing.smooth_text(6.0) == "butterworth:6"


def test_gain_is_one_half_at_the_cutoff_and_phase_is_zero():
    """Order 4 in all, zero phase: a sine at the cut-off comes out at half its amplitude (−6 dB, the squared
    order-2 response ``1/√2``) and in phase; one well below it passes unchanged, one well above it vanishes."""
    fps, fc = 100.0, 5.0
    t = np.arange(4000) / fps
    mid = slice(1000, 3000)  # away from the ends
    for f, gain in [(fc, 0.5), (0.5, 1.0), (25.0, 0.0)]:
        x = np.sin(2 * np.pi * f * t + 0.3)
        y = smoothing.butterworth(x, fps, fc)
        expected = 1.0 / (1.0 + (f / fc) ** 4)  # |H|² of an order-2 Butterworth: 1 / (1 + (f/fc)^(2·2))
        assert expected == pytest.approx(gain, abs=2e-3)
        np.testing.assert_allclose(y[mid], expected * x[mid], atol=2e-3)


def test_butterworth_works_on_every_column_and_short_sequences():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(50, 3, 2))
    y = smoothing.butterworth(x, 30.0, 6.0)
    for i in range(3):
        np.testing.assert_allclose(y[:, i, 1], smoothing.butterworth(x[:, i, 1], 30.0, 6.0))
    assert np.std(np.diff(y, axis=0)) < 0.5 * np.std(np.diff(x, axis=0))
    np.testing.assert_array_equal(smoothing.butterworth(x[:1], 30.0, 6.0), x[:1])
    assert smoothing.butterworth(x[:3], 30.0, 6.0).shape == (3, 3, 2)  # padding shortened to T - 1


def test_fill_gaps_interpolates_linearly_holds_the_ends_and_flags():
    grid = np.arange(10, 20)
    frames = np.array([11, 12, 13, 15, 16, 18])  # 10, 14, 17, 19 were not tracked
    values = np.array([[1.0], [2.0], [99.0], [5.0], [6.0], [8.0]])
    good = np.array([True, True, False, True, True, True])  # frame 13 was lost
    out, interp = smoothing.fill_gaps(grid, frames, values, good)
    np.testing.assert_allclose(out[:, 0], [1, 1, 2, 3, 4, 5, 6, 7, 8, 8])
    np.testing.assert_array_equal(grid[interp], [10, 13, 14, 17, 19])


def test_fill_gaps_unwraps_angles():
    """A heading crossing ±π: the gap between 3.0 and −3.0 rad (0.28 rad apart) is bridged the short way."""
    grid = np.arange(3)
    v = np.array([[3.0, 3.0], [-3.0, -3.0]])
    out, _ = smoothing.fill_gaps(grid, np.array([0, 2]), v, np.array([True, True]), np.array([True, False]))
    assert out[1, 0] == pytest.approx(np.pi, abs=1e-9)  # the angle: through π
    assert out[1, 1] == pytest.approx(0.0)  # not an angle: straight through 0
    assert out[2, 0] == pytest.approx(-3.0 + 2 * np.pi)  # the same rotation, continuous


def test_fill_gaps_without_a_good_frame_keeps_the_samples():
    out, interp = smoothing.fill_gaps(np.arange(3), np.arange(3), np.ones((3, 2)), np.zeros(3, bool))
    np.testing.assert_array_equal(out, 1.0)
    assert not interp.any()


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_butter_lowpass_is_scipys_design(n):
    """The NumPy design of the digital Butterworth low-pass gives SciPy's coefficients for every order and cut-off
    (``scipy.signal.butter``, the reference), with unit gain at DC."""
    from scipy import signal

    for wn in (0.01, 2.0 / 15.0, 0.5, 0.93):
        b, a = smoothing.butter_lowpass(n, wn)
        b_ref, a_ref = signal.butter(n, wn)
        np.testing.assert_allclose(b, b_ref, rtol=1e-11, atol=1e-16)
        np.testing.assert_allclose(a, a_ref, rtol=1e-11, atol=1e-13)
        # unit DC gain; Σ a_k cancels to about (π wn / 2)^n, so its rounding grows as the cut-off falls
        assert np.sum(b) / np.sum(a) == pytest.approx(1.0, rel=1e-16 / (np.pi * wn / 2) ** n)
    for bad in [(0, 0.5), (2, 0.0), (2, 1.0)]:
        with pytest.raises(ValueError, match="Butterworth"):
            smoothing.butter_lowpass(*bad)


def test_smoothing_equals_scipys_filtfilt():
    """The exported track's smoothing equals ``scipy.signal.filtfilt`` of ``scipy.signal.butter(2, …)`` with the
    padding of the module docstring, for random walks of every length from the shortest (2 samples) and several
    frame rates, to float rounding; and ``lfilter`` from a state equals ``scipy.signal.lfilter``'s."""
    from scipy import signal

    rng = np.random.default_rng(1)
    for T in (2, 3, 4, 6, 7, 31, 400):
        x = np.cumsum(rng.normal(size=(T, 5, 3)), axis=0)
        for fps, fc in ((30.0, 2.0), (60.0, 6.0), (240.0, 2.0)):
            b, a = signal.butter(2, fc / (fps / 2))
            ref = signal.filtfilt(b, a, x, axis=0, padlen=min(3 * max(len(a), len(b)), T - 1))
            np.testing.assert_allclose(
                smoothing.butterworth(x, fps, fc), ref, rtol=0, atol=1e-10 * np.abs(ref).max()
            )
    b, a = signal.butter(3, 0.2)
    x, zi = rng.normal(size=(50, 4)), rng.normal(size=(3, 4))
    np.testing.assert_allclose(
        smoothing.lfilter(b, a, x, zi), signal.lfilter(b, a, x, axis=0, zi=zi)[0], rtol=1e-12, atol=1e-12
    )
