"""TRC marker / keypoint trajectories (OpenSim's tab-separated text format, as written by Pose2Sim).

Layout: line 1 ``PathFileType …``; line 2 the header keys (``DataRate CameraRate NumFrames NumMarkers Units …``);
line 3 their values; line 4 ``Frame# Time`` and one name per marker (each followed by two empty columns); line 5
``X1 Y1 Z1 X2 …``; then (after an optional blank line) one row per frame: frame number, time, then x y z per
marker. Empty fields are missing samples.
"""

from __future__ import annotations

import os

import numpy as np

from jaxmocap.errors import MocapInputError

__all__ = ["load_trc"]

_UNIT_SCALE = {"m": 1.0, "mm": 1e-3, "cm": 1e-2}


def load_trc(path: str | os.PathLike, y_up: bool = True) -> tuple[tuple[str, ...], np.ndarray, float]:
    """Read a ``.trc`` file.

    Returns ``(names, positions, fps)``: the ``M`` marker names, positions ``(T, M, 3)`` in metres in the
    project's z-up world (NaN where a sample is missing) and the data rate in Hz. TRC files are y-up by
    convention; with ``y_up`` the axes are mapped ``(X_z, Y_z, Z_z) = (Z_trc, X_trc, Y_trc)`` (a proper rotation,
    the inverse of the Pose2Sim export), otherwise they are kept as stored.
    """
    try:
        with open(path, encoding="utf-8") as f:
            lines = f.read().splitlines()
    except OSError as e:
        raise MocapInputError(path, f"cannot read: {e.strerror or e}") from None
    except UnicodeDecodeError:
        raise MocapInputError(path, "not a UTF-8 text file") from None
    if len(lines) < 5:
        raise MocapInputError(path, "truncated header (a TRC file has 5 header lines)", len(lines) or 1)
    if not lines[0].startswith("PathFileType"):
        raise MocapInputError(path, "does not start with 'PathFileType': not a TRC file", 1)
    keys = lines[1].split("\t")
    values = lines[2].split("\t")
    header = {k.strip(): v.strip() for k, v in zip(keys, values, strict=False)}
    try:
        fps = float(header["DataRate"])
        n_frames = int(header["NumFrames"])
        n_markers = int(header["NumMarkers"])
    except (KeyError, ValueError):
        raise MocapInputError(path, "header lacks numeric DataRate, NumFrames or NumMarkers", 3) from None
    if not fps > 0 or n_frames < 0 or n_markers <= 0:
        raise MocapInputError(path, "DataRate must be > 0, NumFrames >= 0, NumMarkers > 0", 3)
    units = header.get("Units", "m")
    if units not in _UNIT_SCALE:
        raise MocapInputError(path, f"unknown Units {units!r} (expected m, cm or mm)", 3)
    cols = lines[3].split("\t")
    if len(cols) < 2 or cols[0].strip() != "Frame#":
        raise MocapInputError(path, "line 4 must start with 'Frame#' and 'Time'", 4)
    names = tuple(c.strip() for c in cols[2:] if c.strip())
    if len(names) != n_markers:
        raise MocapInputError(path, f"header says {n_markers} markers but names {len(names)}", 4)

    rows = []
    for i in range(5, len(lines)):
        text = lines[i]
        if not text.strip():
            continue
        fields = text.split("\t")
        if len(fields) < 2 + 3 * n_markers:
            fields = fields + [""] * (2 + 3 * n_markers - len(fields))
        coords = fields[2 : 2 + 3 * n_markers]
        if any(f.strip() for f in fields[2 + 3 * n_markers :]):
            raise MocapInputError(path, f"more than {3 * n_markers} coordinates", i + 1)
        try:
            rows.append([float(c) if c.strip() else np.nan for c in coords])
            float(fields[0])
        except ValueError:
            raise MocapInputError(path, "a field is not a number", i + 1) from None
    if len(rows) != n_frames:
        raise MocapInputError(path, f"header says {n_frames} frames but the file has {len(rows)}", len(lines))
    pos = np.asarray(rows, dtype=np.float64).reshape((n_frames, n_markers, 3)) * _UNIT_SCALE[units]
    if not np.all(np.isfinite(pos) | np.isnan(pos)):
        raise MocapInputError(path, "infinite coordinates")
    if y_up:
        pos = pos[..., [2, 0, 1]]
    return names, pos, fps
