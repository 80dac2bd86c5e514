"""TRC marker / keypoint trajectories (OpenSim's tab-separated text format, as written by Pose2Sim): reader and
writer.

Layout: line 1 ``PathFileType 4 (X/Y/Z) <file name>``; line 2 the header keys (``DataRate CameraRate NumFrames
NumMarkers Units OrigDataRate OrigDataStartFrame OrigNumFrames``); line 3 their values; line 4 ``Frame# Time`` and
one name per marker (each followed by two empty columns); line 5 two empty columns then ``X1 Y1 Z1 X2 …``; then
(after an optional blank line) one row per frame: frame number, time, then x y z per marker. Empty fields are
missing samples. :func:`save_trc` writes exactly Pose2Sim's layout (no blank line, ``\\n`` line ends), y up.
"""

from __future__ import annotations

import os

import numpy as np

from jaxmocap.errors import MocapInputError

__all__ = ["HEADER_KEYS", "load_trc", "save_trc", "trc_text"]

#: The keys of line 2, in Pose2Sim's order.
HEADER_KEYS = (
    "DataRate",
    "CameraRate",
    "NumFrames",
    "NumMarkers",
    "Units",
    "OrigDataRate",
    "OrigDataStartFrame",
    "OrigNumFrames",
)

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


def _num(v: float) -> str:
    return "" if not np.isfinite(v) else f"{v:.10g}"


def trc_text(
    names: tuple[str, ...] | list[str],
    positions: np.ndarray,
    fps: float,
    frame_index: np.ndarray | None = None,
    file_name: str = "poses.trc",
    y_up: bool = True,
) -> str:
    """The text of a ``.trc`` file (Pose2Sim's layout, units ``m``).

    Args:
      names: ``M`` marker names (no tabs). positions: ``(T, M, 3)`` metres in the project's z-up world (NaN:
        missing, written as empty fields); with ``y_up`` written as ``(X, Y, Z)_trc = (y, z, x)`` (the inverse of
        :func:`load_trc`'s mapping), else as given.
      fps: DataRate and CameraRate. frame_index: ``(T,)`` input frame numbers (default ``0..T-1``): ``Frame#`` is
        ``frame + 1`` and ``Time`` ``frame / fps`` (the ``time`` of ``poses.npz``); OrigDataStartFrame is the first.
      file_name: the name on line 1.
    """
    P = np.asarray(positions, np.float64)
    T, M = P.shape[0], len(names)
    if P.shape != (T, M, 3):
        raise ValueError(f"positions must be (T, {M}, 3), got {P.shape}")
    if any("\t" in n or not n for n in names):
        raise ValueError("marker names must be non-empty and free of tabs")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be positive, got {fps!r}")
    frames = np.arange(T) if frame_index is None else np.asarray(frame_index, np.int64).reshape(T)
    if y_up:
        P = P[..., [1, 2, 0]]
    rate = f"{fps:g}"
    start = int(frames[0]) if T else 0
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{file_name}",
        "\t".join(HEADER_KEYS),
        "\t".join([rate, rate, str(T), str(M), "m", rate, str(start), str(T)]),
        "Frame#\tTime\t" + "\t\t\t".join(names) + "\t\t",
        "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(M)),
    ]
    rows = P.reshape(T, 3 * M)
    whole = np.all(np.isfinite(rows), axis=1)
    row_format = "\t".join(
        ["%d", "%.10g"] + ["%.10g"] * (3 * M)
    )  # one format per row (as _num writes a number)
    for f, row, ok in zip(frames.tolist(), rows.tolist(), whole.tolist(), strict=True):
        if ok:
            lines.append(row_format % (f + 1, f / fps, *row))
        else:
            lines.append("\t".join([str(f + 1), f"{f / fps:.10g}", *(_num(v) for v in row)]))
    return "\n".join(lines) + "\n"


def save_trc(path: str | os.PathLike, names, positions: np.ndarray, fps: float, frame_index=None) -> None:
    """Write :func:`trc_text` to ``path`` atomically (the file name on line 1 is ``path``'s)."""
    from jaxmocap.io.export import atomic_write_text

    text = trc_text(names, positions, fps, frame_index, os.path.basename(os.fspath(path)))
    atomic_write_text(path, text)
