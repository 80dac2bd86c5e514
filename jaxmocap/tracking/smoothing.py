"""Post-processing of a tracked state sequence for the exported track: gap filling and zero-phase smoothing.

**Gaps.** On the output grid (the requested frames from the first to the last tracked one), a frame is a gap when
it was not tracked (unreadable, skipped) or the track was lost there (``lost`` in its diagnostics record). Gap
frames are filled per DOF by linear interpolation in time between the nearest good frames (held constant before
the first and after the last), angles first unwrapped over the good frames (``np.unwrap``: a circular estimate
that crossed ±π does not swing the other way round), and flagged (``interpolated``).

**Smoothing** (``--smooth``): ``butterworth[:CUTOFF_HZ]`` is a low-pass Butterworth filter of order 4 in all,
applied forward and backward so that it has no phase lag: ``scipy.signal.butter(2, f_c / (fps / 2))`` run by
``scipy.signal.filtfilt`` (each pass is order 2; the two passes square the magnitude response, so ``f_c`` is
where the gain is 1/2, −6 dB) — the filter Pose2Sim and anipose apply, with their convention of halving the
order for ``filtfilt``. ``filtfilt`` pads with ``min(3·max(len(a), len(b)), T − 1)`` odd-extended samples (none
for ``T < 2``, which is returned as is). ``none`` only fills the gaps. The default cut-off
(:data:`DEFAULT_CUTOFF_HZ`, 2 Hz) was chosen by measuring the joint error of the exported tracks of synthetic
sequences of three real CMU clips with cut-offs from 1 to 10 Hz and without smoothing
(``benchmarks/results/smoothing.md``): every cut-off lowered it; 1.5 Hz had the lowest mean, 2 Hz was within 0.7 mm
of it (and as good on the fastest clip) and keeps more of fast motion.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "DEFAULT_CUTOFF_HZ",
    "DEFAULT_SMOOTH",
    "ORDER",
    "butterworth",
    "fill_gaps",
    "parse_smooth",
    "smooth_text",
]

#: Default cut-off frequency (Hz) of ``--smooth butterworth``.
DEFAULT_CUTOFF_HZ = 2.0
#: Default ``--smooth``.
DEFAULT_SMOOTH = "butterworth"
#: Order of the zero-phase filter in all (two passes of order ``ORDER // 2``).
ORDER = 4


def parse_smooth(spec: str | None, fps: float | None = None) -> float | None:
    """``--smooth``: ``"none"`` → None; ``"butterworth"`` → :data:`DEFAULT_CUTOFF_HZ`; ``"butterworth:4.5"`` →
    4.5. With ``fps``, the cut-off must lie below the Nyquist frequency ``fps / 2``. Raises ``ValueError``."""
    text = "none" if spec is None else str(spec).strip().lower()
    if text == "none":
        return None
    kind, sep, value = text.partition(":")
    if kind != "butterworth":
        raise ValueError(f"--smooth must be 'butterworth[:CUTOFF_HZ]' or 'none', got {spec!r}")
    try:
        cutoff = float(value) if sep else DEFAULT_CUTOFF_HZ
    except ValueError:
        raise ValueError(f"--smooth cut-off must be a number of Hz, got {value!r}") from None
    if not (math.isfinite(cutoff) and cutoff > 0):
        raise ValueError(f"--smooth cut-off must be a positive number of Hz, got {value!r}")
    if fps is not None and cutoff >= fps / 2:
        raise ValueError(f"--smooth cut-off {cutoff:g} Hz must be below half the frame rate ({fps / 2:g} Hz)")
    return cutoff


def smooth_text(cutoff: float | None) -> str:
    """The ``--smooth`` spelling of a cut-off (None: ``none``)."""
    return "none" if cutoff is None else f"butterworth:{cutoff:g}"


def butterworth(x: np.ndarray, fps: float, cutoff_hz: float, order: int = ORDER) -> np.ndarray:
    """Zero-phase low-pass of ``x (T, ...)`` along axis 0 (module docstring); NaN-free input."""
    x = np.asarray(x, np.float64)
    if x.shape[0] < 2:
        return x.copy()
    from scipy import signal  # imported when used: about 1 s

    b, a = signal.butter(order // 2, cutoff_hz / (fps / 2.0), btype="low")
    padlen = min(3 * max(len(a), len(b)), x.shape[0] - 1)
    return signal.filtfilt(b, a, x, axis=0, padlen=padlen)


def fill_gaps(
    grid: np.ndarray,
    frames: np.ndarray,
    values: np.ndarray,
    good: np.ndarray,
    angles: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Values on the frame ``grid (G,)`` from samples at ``frames (N,)`` (``values (N, D)``), of which ``good
    (N,)`` are kept and the rest, with every grid frame that has no sample, interpolated (module docstring).

    ``angles (D,)`` bool marks the angle DOFs to unwrap (their good samples come back unwrapped: the same
    rotations, continuous). With no good sample all samples count as good. Returns ``(values (G, D),
    interpolated (G,) bool)``.
    """
    grid = np.asarray(grid, np.float64)
    frames = np.asarray(frames, np.float64)
    values = np.asarray(values, np.float64).reshape(len(frames), -1)
    good = np.asarray(good, bool) & np.all(np.isfinite(values), axis=1)
    if not good.any():
        good = np.all(np.isfinite(values), axis=1)
    if not good.any():
        return np.full((len(grid), values.shape[1]), np.nan), np.ones(len(grid), bool)
    f, v = frames[good], values[good].copy()
    if angles is not None and len(v) > 1:
        a = np.asarray(angles, bool)
        v[:, a] = np.unwrap(v[:, a], axis=0)
    out = np.stack([np.interp(grid, f, v[:, d]) for d in range(v.shape[1])], axis=1)
    return out, ~np.isin(grid, f)
