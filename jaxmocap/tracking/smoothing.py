"""Post-processing of a tracked state sequence for the exported track: gap filling and zero-phase smoothing.

**Gaps.** On the output grid (the requested frames from the first to the last tracked one), a frame is a gap when
it was not tracked (unreadable, skipped) or the track was lost there (``lost`` in its diagnostics record). Gap
frames are filled per DOF by linear interpolation in time between the nearest good frames (held constant before
the first and after the last), angles first unwrapped over the good frames (``np.unwrap``: a circular estimate
that crossed ±π does not swing the other way round), and flagged (``interpolated``).

**Smoothing** (``--smooth``): ``butterworth[:CUTOFF_HZ]`` is a low-pass Butterworth filter of order 4 in all,
applied forward and backward so that it has no phase lag (each pass is order 2; the two passes square the
magnitude response, so ``f_c`` is where the gain is 1/2, −6 dB) — the filter Pose2Sim and anipose apply with
``scipy.signal.butter(2, f_c / (fps / 2))`` and ``scipy.signal.filtfilt``, with their convention of halving the
order for ``filtfilt``. Written here in NumPy (:func:`butter_lowpass`, :func:`filtfilt`; equal to SciPy's to
float rounding, ``tests/tracking/test_smoothing.py``): importing ``scipy.signal`` took 0.5–1.1 s of every run.
The passes pad with ``min(3·max(len(a), len(b)), T − 1)`` odd-extended samples (none for ``T < 2``, which is
returned as is). ``none`` only fills the gaps. The default cut-off
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
    "butter_lowpass",
    "butterworth",
    "fill_gaps",
    "filtfilt",
    "lfilter",
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
    b, a = butter_lowpass(order // 2, cutoff_hz / (fps / 2.0))
    return filtfilt(b, a, x, padlen=min(3 * max(len(a), len(b)), x.shape[0] - 1))


def butter_lowpass(n: int, wn: float) -> tuple[np.ndarray, np.ndarray]:
    """The digital Butterworth low-pass of order ``n`` and cut-off ``wn`` (a fraction of the Nyquist frequency,
    ``0 < wn < 1``; the gain there is ``1/√2``): ``(b (n+1,), a (n+1,))`` of ``H(z) = Σ b_k z^-k / Σ a_k z^-k``,
    ``a_0 = 1`` — what ``scipy.signal.butter(n, wn)`` returns.

    The analog prototype's poles ``p_k = exp(iπ (2k + n − 1) / 2n)``, ``k = 1 … n``, are scaled to the pre-warped
    cut-off ``ω = 4 tan(π wn / 2)`` (the bilinear transform with ``fs = 2``, so that the digital cut-off lands on
    ``wn``) and mapped by ``z = (4 + p) / (4 − p)``; the ``n`` zeros go to ``z = −1`` and the gain to
    ``ω^n / Π (4 − p_k)``: unit gain at DC."""
    if not (n >= 1 and 0.0 < wn < 1.0):
        raise ValueError(f"a Butterworth low-pass needs order ≥ 1 and 0 < wn < 1, got {n}, {wn}")
    k = np.arange(1, n + 1)
    p = np.exp(1j * np.pi * (2 * k + n - 1) / (2 * n)) * (4.0 * np.tan(np.pi * wn / 2.0))
    gain = np.real(np.prod(4.0 * np.tan(np.pi * wn / 2.0) / (4.0 - p)))
    b = gain * np.poly(-np.ones(n))
    a = np.real(np.poly((4.0 + p) / (4.0 - p)))
    return b, a


def lfilter(b: np.ndarray, a: np.ndarray, x: np.ndarray, zi: np.ndarray) -> np.ndarray:
    """``y`` of the IIR filter ``(b, a)`` (``a_0 = 1``, ``len(a) == len(b) = m + 1``) over ``x (T, C)`` along axis
    0, from the state ``zi (m, C)`` of its transposed direct form II: ``y_t = b_0 x_t + z_0``, then
    ``z_i ← b_{i+1} x_t − a_{i+1} y_t + z_{i+1}`` (``z_m = 0``) — ``scipy.signal.lfilter(b, a, x, zi=zi)[0]``.
    A loop over the T samples, each a few operations on C values: the two passes over a 10 000-frame track of 60
    values took 0.35 s (on a busy 2-core machine), SciPy's compiled loop a few milliseconds."""
    z = [zi[i].copy() for i in range(len(zi))]
    m = len(z)
    y = np.empty_like(x)
    for t in range(x.shape[0]):
        xt = x[t]
        yt = b[0] * xt + z[0]
        for i in range(m - 1):
            z[i] = b[i + 1] * xt - a[i + 1] * yt + z[i + 1]
        z[m - 1] = b[m] * xt - a[m] * yt
        y[t] = yt
    return y


def _step_state(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """The state ``(m,)`` that :func:`lfilter` reaches on a unit step held forever (``scipy.signal.lfilter_zi``):
    ``(I − Aᵀ) z = b_{1:} − a_{1:} b_0``, with ``A`` the companion matrix of ``a`` (first row ``−a_{1:}``)."""
    m = len(a) - 1
    companion = np.zeros((m, m))
    companion[0] = -a[1:]
    companion[1:, :-1] += np.eye(m - 1)
    return np.linalg.solve(np.eye(m) - companion.T, b[1:] - a[1:] * b[0])


def filtfilt(b: np.ndarray, a: np.ndarray, x: np.ndarray, padlen: int) -> np.ndarray:
    """The filter ``(b, a)`` run forward and backward along axis 0 of ``x (T, ...)`` (zero phase, the squared
    magnitude): ``x`` extended by ``padlen`` odd reflections at each end (``2 x_0 − x_k``, ``0 < padlen < T``),
    each pass started in the step state (:func:`_step_state`) scaled by its first sample, the padding cut off —
    ``scipy.signal.filtfilt(b, a, x, axis=0, padlen=padlen)``."""
    x = np.asarray(x, np.float64)
    flat = x.reshape(x.shape[0], -1)
    if padlen > 0:
        flat = np.concatenate(
            [2 * flat[:1] - flat[padlen:0:-1], flat, 2 * flat[-1:] - flat[-2 : -padlen - 2 : -1]]
        )
    zi = _step_state(b, a)[:, None]
    y = lfilter(b, a, flat, zi * flat[0])
    y = lfilter(b, a, y[::-1], zi * y[-1])[::-1]
    if padlen > 0:
        y = y[padlen:-padlen]
    return np.ascontiguousarray(y).reshape(x.shape)


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
