"""C3D marker files (the biomechanics binary format) written and read with the ``c3d`` package.

:func:`save_c3d` writes 3D points only (no analog channels): ``POINT:UNITS`` ``mm``, floating-point samples
(``POINT:SCALE = -1``), ``POINT:RATE`` the frame rate, ``POINT:LABELS`` the marker names, the first frame
``frame_index[0] + 1`` (C3D counts from 1), in the project's z-up world (``POINT:X_SCREEN = +X``,
``POINT:Y_SCREEN = +Z``: viewers show z up). Every sample is a model-computed position, so its residual is 0 (the C3D
convention for computed or interpolated points); a missing sample (NaN) has residual −1 (invalid) and zeros.
The file is written to memory and moved into place atomically.
"""

from __future__ import annotations

import io
import os
import warnings

import numpy as np

from jaxmocap.errors import MocapInputError

__all__ = ["load_c3d", "save_c3d"]


def _c3d():
    import c3d

    return c3d


def c3d_bytes(names, positions: np.ndarray, fps: float, frame_index=None) -> bytes:
    """The bytes of a C3D file of ``positions (T, M, 3)`` metres named ``names`` (module docstring)."""
    c3d = _c3d()
    P = np.asarray(positions, np.float64)
    T, M = P.shape[0], len(names)
    if P.shape != (T, M, 3) or T == 0 or M == 0:
        raise ValueError(f"positions must be (T > 0, {M} > 0, 3), got {P.shape}")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be positive, got {fps!r}")
    w = c3d.Writer(point_rate=float(fps), analog_rate=0.0, point_scale=-1.0, point_units="mm  ")
    w.set_point_labels([str(n) for n in names])
    w.set_screen_axis(X="+X", Y="+Z")
    first = 1 if frame_index is None else int(np.asarray(frame_index).reshape(-1)[0]) + 1
    w.set_start_frame(max(first, 1))
    frames = []
    for p in P * 1000.0:
        ok = np.all(np.isfinite(p), axis=1)
        pts = np.zeros((M, 5), np.float32)
        pts[ok, :3] = p[ok]
        pts[~ok, 3] = -1.0
        frames.append((pts, np.zeros((0, 0), np.float32)))
    w.add_frames(frames)
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="No analog data found")  # points only, by design
        w.write(buf)
    return buf.getvalue()


def save_c3d(path: str | os.PathLike, names, positions: np.ndarray, fps: float, frame_index=None) -> None:
    """Write :func:`c3d_bytes` to ``path`` atomically."""
    from jaxmocap.io.export import atomic_write_bytes

    atomic_write_bytes(path, c3d_bytes(names, positions, fps, frame_index))


def load_c3d(path: str | os.PathLike) -> tuple[tuple[str, ...], np.ndarray, float]:
    """``(names, positions (T, M, 3) metres with NaN for invalid samples, fps)`` of a C3D file's points (read by
    ``c3d.Reader``; ``POINT:UNITS`` ``mm``, ``cm`` or ``m``)."""
    c3d = _c3d()
    scale = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}
    try:
        with open(path, "rb") as f, warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the reader warns about optional parameters it does not find
            r = c3d.Reader(f)
            units = r.get("POINT:UNITS").string_value.strip() if "POINT:UNITS" in r else "mm"
            names = tuple(n.strip() for n in r.point_labels)
            frames = [points.copy() for _, points, _ in r.read_frames()]
            fps = float(r.point_rate)
    except OSError as e:
        raise MocapInputError(path, f"cannot read: {e.strerror or e}") from None
    except (ValueError, AssertionError, KeyError, IndexError) as e:
        raise MocapInputError(path, f"not a readable C3D file: {e}") from None
    if units not in scale:
        raise MocapInputError(path, f"unknown POINT:UNITS {units!r}")
    pts = np.asarray(frames, np.float64).reshape(len(frames), len(names), 5)
    P = np.where(pts[..., 3:4] < 0, np.nan, pts[..., :3]) * scale[units]
    return names, P, fps
