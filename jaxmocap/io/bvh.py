"""Biovision Hierarchy (BVH) files: reader, writer, and conversion to :class:`~jaxmocap.io.mocap.Motion`.

A BVH file is a ``HIERARCHY`` of joints (``ROOT``/``JOINT`` name, ``OFFSET x y z`` in the parent's frame,
``CHANNELS n ...``, children, ``End Site { OFFSET ... }``) followed by ``MOTION``, ``Frames: T``,
``Frame Time: dt`` and one line of channel values per frame. Conventions implemented here:

* rotation channels (degrees) compose in the order they are listed, outermost first: ``Zrotation Yrotation
  Xrotation`` is ``L = Rz·Ry·Rx``; any order and any subset (including repeated axes) is accepted;
* position channels set that component of the joint's translation in its parent's frame, replacing the
  ``OFFSET`` component (on the root too); components without a channel keep the ``OFFSET`` value. Non-root
  joints may carry position channels;
* several roots are not supported; a joint may have any number of channels, zero included.

Units: a BVH file does not state its unit, so :func:`load_bvh` takes an explicit ``scale`` (metres per file
unit). For B. Hahne's "cgspeed" conversion of the CMU database, :data:`CMU_BVH_SCALE` is the unit of the CMU
ASF skeletons, ``(1/0.45)`` inch: the conversion keeps the ASF numbers (bone offsets equal the ASF bone lengths
to a few percent across subjects and the root height, ~17 units, equals the AMC root ``TY``; see
``tests/test_bvh.py``). With it the CMU subjects measure 1.4–1.7 m. The cgspeed skeleton drops the length of
the ASF ``thorax`` bone (its ``lowerneck`` sits at ``Chest2``), so these BVH bodies are ~0.1 m shorter than the
ASF ones.

Axes: BVH is y-up; ``up_axis="y"`` turns it into the project's z-up world by ``(x, y, z) -> (z, x, y)``
(:data:`jaxmocap.io.mocap.Y_UP_TO_Z_UP`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.io.mocap import (
    INCH,
    Motion,
    build_motion,
    euler_to_matrix,
    matrix_to_euler,
    read_lines,
    up_axis_matrix,
)

#: Metres per unit of the CMU "cgspeed" BVH conversion: the CMU ASF length unit, 1/0.45 inch = 0.05644 m.
CMU_BVH_SCALE = INCH / 0.45

#: Numbers beyond this magnitude are rejected as malformed (they would overflow the kinematics).
MAX_ABS = 1e12

_CHANNELS = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
_CHANNEL_LOOKUP = {c.lower(): c for c in _CHANNELS}


class BvhData(NamedTuple):
    """The content of a BVH file as written (file units, file axes, degrees).

    Attributes:
      names: ``J`` joint names in file order (depth first, parents before children).
      parents: ``J`` parent indices, ``-1`` for the root.
      offsets: ``(J, 3)`` ``OFFSET`` of every joint.
      channels: per joint, its channel names in file order.
      frames: ``(T, C)`` channel values, ``C`` = total number of channels, joints in file order.
      frame_time: seconds per frame.
      end_parents: ``E`` joints carrying an ``End Site``; end_offsets: ``(E, 3)`` their offsets.
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    frames: np.ndarray
    frame_time: float
    end_parents: tuple[int, ...] = ()
    end_offsets: np.ndarray = np.zeros((0, 3))


# ---------------------------------------------------------------------------------------------------------------
# Reading


class _Tokens:
    """Whitespace tokens of the hierarchy section with their 1-based line numbers."""

    def __init__(self, path, lines: list[str]):
        self.path = path
        self.lines = lines
        self.toks: list[tuple[str, int]] = []
        self.pos = 0
        self.end_line = max(1, len(lines))

    def fill_until_motion(self) -> int:
        """Tokenise lines until a line starting with MOTION; returns that line's index (or len(lines))."""
        for i, line in enumerate(self.lines):
            parts = line.split()
            if parts and parts[0] == "MOTION":
                self.toks.append(("MOTION", i + 1))
                return i
            self.toks.extend((p, i + 1) for p in parts)
        return len(self.lines)

    def error(self, message: str, line: int | None = None) -> MocapInputError:
        return MocapInputError(self.path, message, line)

    def peek(self) -> tuple[str, int]:
        if self.pos >= len(self.toks):
            raise self.error("unexpected end of file in the HIERARCHY section", self.end_line)
        return self.toks[self.pos]

    def next(self) -> tuple[str, int]:
        tok = self.peek()
        self.pos += 1
        return tok

    def expect(self, word: str) -> int:
        tok, line = self.next()
        if tok != word:
            raise self.error(f"expected {word!r}, found {tok!r}", line)
        return line

    def _converted(self, convert, kind: str, what: str):
        """``(value, token, line)`` of the next token read by ``convert``; an error names ``what`` and the
        ``kind`` expected when it does not read."""
        tok, line = self.next()
        try:
            return convert(tok), tok, line
        except ValueError:
            raise self.error(f"expected {kind} for {what}, found {tok!r}", line) from None

    def number(self, what: str) -> float:
        v, tok, line = self._converted(float, "a number", what)
        if not math.isfinite(v) or abs(v) > MAX_ABS:
            raise self.error(f"{what} is not finite or out of range: {tok!r}", line)
        return v

    def integer(self, what: str) -> int:
        v, _, line = self._converted(int, "an integer", what)
        if v < 0:
            raise self.error(f"{what} must not be negative, found {v}", line)
        return v

    def rest_of_line(self, line: int) -> str:
        """Join the tokens that remain on ``line`` up to a ``{`` (a joint name may contain spaces)."""
        parts = []
        while self.pos < len(self.toks) and self.toks[self.pos][1] == line and self.toks[self.pos][0] != "{":
            parts.append(self.toks[self.pos][0])
            self.pos += 1
        return " ".join(parts)


def read_bvh(path: str | os.PathLike) -> BvhData:
    """Parse a BVH file as written (no unit or axis change). Raises :class:`MocapInputError` (file, line)."""
    lines = read_lines(path)
    tk = _Tokens(path, lines)
    motion_idx = tk.fill_until_motion()
    tk.expect("HIERARCHY")
    tok, line = tk.next()
    if tok != "ROOT":
        raise tk.error(f"expected 'ROOT', found {tok!r}", line)

    names: list[str] = []
    parents: list[int] = []
    offsets: list[tuple[float, float, float]] = []
    channels: list[tuple[str, ...]] = []
    end_parents: list[int] = []
    end_offsets: list[tuple[float, float, float]] = []

    def offset() -> tuple[float, float, float]:
        return (tk.number("OFFSET x"), tk.number("OFFSET y"), tk.number("OFFSET z"))

    def joint(parent: int, keyword_line: int) -> None:
        name = tk.rest_of_line(keyword_line)
        if not name:
            raise tk.error("joint without a name", keyword_line)
        if name in names:
            raise tk.error(f"duplicate joint name {name!r}", keyword_line)
        tk.expect("{")
        j = len(names)
        names.append(name)
        parents.append(parent)
        offsets.append((0.0, 0.0, 0.0))
        channels.append(())
        seen_offset = seen_channels = False
        while True:
            tok, line = tk.next()
            if tok == "}":
                break
            if tok == "OFFSET":
                if seen_offset:
                    raise tk.error(f"second OFFSET in joint {name!r}", line)
                offsets[j] = offset()
                seen_offset = True
            elif tok == "CHANNELS":
                if seen_channels:
                    raise tk.error(f"second CHANNELS in joint {name!r}", line)
                n = tk.integer("the channel count")
                chans = []
                for _ in range(n):
                    c, cl = tk.next()
                    canon = _CHANNEL_LOOKUP.get(c.lower())
                    if canon is None:
                        raise tk.error(f"unknown channel {c!r} (expected one of {', '.join(_CHANNELS)})", cl)
                    chans.append(canon)
                channels[j] = tuple(chans)
                seen_channels = True
            elif tok == "JOINT":
                joint(j, line)
            elif tok == "End":
                tk.expect("Site")
                tk.expect("{")
                tk.expect("OFFSET")
                end_parents.append(j)
                end_offsets.append(offset())
                tk.expect("}")
            elif tok == "ROOT":
                raise tk.error("several ROOT joints are not supported", line)
            else:
                raise tk.error(f"unexpected {tok!r} in joint {name!r}", line)
        if not seen_offset:
            raise tk.error(f"joint {name!r} has no OFFSET", line)

    joint(-1, line)
    tok, line = tk.next()
    if tok == "ROOT":
        raise tk.error("several ROOT joints are not supported", line)
    if tok != "MOTION":
        raise tk.error(f"expected 'MOTION' after the hierarchy, found {tok!r}", line)
    if tk.pos != len(tk.toks):  # pragma: no cover - MOTION is the last token collected
        raise tk.error("unexpected tokens before MOTION", line)

    # MOTION header: "Frames: T" and "Frame Time: dt", then one line per frame.
    i = motion_idx + 1
    head = lines[motion_idx].split()[1:]
    if head:
        raise MocapInputError(path, f"unexpected {head[0]!r} after MOTION", motion_idx + 1)

    def next_content_line(i: int, what: str) -> tuple[int, list[str]]:
        while i < len(lines) and not lines[i].split():
            i += 1
        if i >= len(lines):
            raise MocapInputError(path, f"file ends before {what}", max(1, len(lines)))
        return i, lines[i].split()

    i, parts = next_content_line(i, "'Frames:'")
    if len(parts) != 2 or parts[0] != "Frames:":
        raise MocapInputError(path, "expected 'Frames: <count>'", i + 1)
    try:
        num_frames = int(parts[1])
    except ValueError:
        raise MocapInputError(path, f"frame count {parts[1]!r} is not an integer", i + 1) from None
    if num_frames < 0:
        raise MocapInputError(path, f"frame count must not be negative, found {num_frames}", i + 1)
    i, parts = next_content_line(i + 1, "'Frame Time:'")
    if len(parts) != 3 or parts[:2] != ["Frame", "Time:"]:
        raise MocapInputError(path, "expected 'Frame Time: <seconds>'", i + 1)
    try:
        frame_time = float(parts[2])
    except ValueError:
        raise MocapInputError(path, f"frame time {parts[2]!r} is not a number", i + 1) from None
    if not (math.isfinite(frame_time) and 1e-9 <= frame_time <= 1e9):
        raise MocapInputError(path, f"frame time must be between 1e-9 and 1e9 s, found {parts[2]!r}", i + 1)

    C = sum(len(c) for c in channels)
    rows: list[np.ndarray] = []
    for k in range(i + 1, len(lines)):
        parts = lines[k].split()
        if not parts:
            continue
        if len(rows) == num_frames:
            raise MocapInputError(path, f"more frame lines than 'Frames: {num_frames}'", k + 1)
        if len(parts) != C:
            raise MocapInputError(path, f"frame {len(rows) + 1} has {len(parts)} values, expected {C}", k + 1)
        try:
            row = np.array([float(p) for p in parts], dtype=np.float64)
        except ValueError:
            bad = next((p for p in parts if not _is_float(p)), parts[0])
            raise MocapInputError(path, f"frame {len(rows) + 1}: {bad!r} is not a number", k + 1) from None
        if not np.all(np.abs(row) <= MAX_ABS):  # also false for NaN
            raise MocapInputError(
                path, f"frame {len(rows) + 1} has a non-finite or out-of-range value", k + 1
            )
        rows.append(row)
    if len(rows) < num_frames and C > 0:
        raise MocapInputError(
            path, f"file ends after {len(rows)} of the {num_frames} frames it announces", len(lines)
        )
    frames = np.stack(rows) if rows else np.zeros((num_frames if C == 0 else 0, C))
    return BvhData(
        names=tuple(names),
        parents=tuple(parents),
        offsets=np.asarray(offsets, dtype=np.float64).reshape(-1, 3),
        channels=tuple(channels),
        frames=frames,
        frame_time=frame_time,
        end_parents=tuple(end_parents),
        end_offsets=np.asarray(end_offsets, dtype=np.float64).reshape(-1, 3),
    )


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def frame_rate(frame_time: float) -> float:
    """``1 / frame_time``, snapped to the nearest integer when within 0.01 % (files print few digits)."""
    fps = 1.0 / frame_time
    r = round(fps)
    return float(r) if r > 0 and abs(fps - r) <= 1e-4 * fps else fps


def motion_from_bvh(data: BvhData, *, scale: float, up_axis: str = "y", source: str = "") -> Motion:
    """Turn parsed BVH content into a :class:`Motion` (metres, z up) by forward kinematics."""
    J = len(data.names)
    T = data.frames.shape[0]
    rotations = np.broadcast_to(np.eye(3), (T, J, 3, 3)).copy()
    translations = np.broadcast_to(data.offsets, (T, J, 3)).copy()
    col = 0
    for j, chans in enumerate(data.channels):
        values = data.frames[:, col : col + len(chans)]
        col += len(chans)
        order = "".join(c[0] for c in chans if c.endswith("rotation"))
        rot_cols = [k for k, c in enumerate(chans) if c.endswith("rotation")]
        if order:
            rotations[:, j] = euler_to_matrix(np.deg2rad(values[:, rot_cols]), order)
        for k, c in enumerate(chans):
            if c.endswith("position"):
                translations[:, j, "XYZ".index(c[0])] = values[:, k]
    return build_motion(
        data.names,
        data.parents,
        data.offsets,
        rotations,
        translations,
        frame_rate(data.frame_time),
        source,
        data.end_parents,
        data.end_offsets,
        scale=scale,
        up_axis=up_axis,
    )


def load_bvh(path: str | os.PathLike, *, scale: float, up_axis: str = "y") -> Motion:
    """Load a BVH file as a :class:`Motion` in metres, z up.

    Args:
      path: the file.
      scale: metres per file unit (explicit: BVH does not record its unit); :data:`CMU_BVH_SCALE` for the CMU
        cgspeed files, 0.01 for centimetres.
      up_axis: ``"y"`` (the BVH default) or ``"z"`` (already z up).
    """
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number of metres per unit, got {scale!r}")
    return motion_from_bvh(read_bvh(path), scale=scale, up_axis=up_axis, source=os.fspath(path))


# ---------------------------------------------------------------------------------------------------------------
# Writing


def bvh_from_motion(
    motion: Motion, *, scale: float = 0.01, up_axis: str = "y", rotation_order: str = "ZYX"
) -> BvhData:
    """The BVH content of a :class:`Motion`: ``A⁻¹`` back to the file's axes, lengths divided by ``scale``.

    The root gets ``X/Y/Zposition`` and three rotation channels in ``rotation_order`` (e.g. ``"ZYX"`` for
    ``Zrotation Yrotation Xrotation``), every other joint three rotation channels, plus position channels where
    ``motion.local_translations`` animates it.
    """
    A = up_axis_matrix(up_axis)
    offsets = motion.offsets @ A / scale  # A⁻¹ t = Aᵀ t, row form t A
    trans = motion.translations() @ A / scale
    rots = np.swapaxes(A, 0, 1) @ motion.local_rotations @ A
    euler = np.rad2deg(matrix_to_euler(rots, rotation_order))  # (T, J, 3)
    rot_names = tuple(f"{a.upper()}rotation" for a in rotation_order)
    pos_names = ("Xposition", "Yposition", "Zposition")
    channels, cols = [], []
    for j in range(motion.num_joints):
        moves = j == 0 or (
            motion.local_translations is not None
            and not np.allclose(motion.local_translations[:, j], motion.offsets[j], rtol=0, atol=1e-12)
        )
        chans = (pos_names if moves else ()) + rot_names
        channels.append(chans)
        if moves:
            cols.append(trans[:, j])
        cols.append(euler[:, j])
    frames = np.concatenate(cols, axis=1) if cols else np.zeros((motion.num_frames, 0))
    return BvhData(
        names=motion.joint_names,
        parents=motion.parents,
        offsets=offsets,
        channels=tuple(channels),
        frames=frames,
        frame_time=1.0 / motion.fps,
        end_parents=motion.end_parents,
        end_offsets=motion.end_offsets @ A / scale,
    )


def save_bvh(
    path: str | os.PathLike,
    motion: Motion | BvhData | Sequence,
    fps: float | None = None,
    *,
    scale: float = 0.01,
    up_axis: str = "y",
    rotation_order: str = "ZYX",
    precision: int = 6,
) -> None:
    """Write a BVH file.

    Args:
      path: output file.
      motion: a :class:`Motion` (converted with :func:`bvh_from_motion`: ``scale`` metres per written unit,
        default centimetres, ``up_axis`` of the file, Euler ``rotation_order``), or raw content written as is:
        a :class:`BvhData` or a tuple ``(names, parents, offsets, channels, frames[, end_parents,
        end_offsets])`` with ``offsets (J, 3)``, per-joint channel names and ``frames (T, C)`` in degrees.
      fps: frames per second; defaults to the motion's (required for a raw tuple).
      precision: decimals written.
    """
    if isinstance(motion, Motion):
        data = bvh_from_motion(motion, scale=scale, up_axis=up_axis, rotation_order=rotation_order)
    elif isinstance(motion, BvhData):
        data = motion
    else:
        names, parents, offsets, channels, frames, *rest = motion
        if fps is None:
            raise ValueError("fps is required when writing raw BVH content")
        data = BvhData(
            tuple(names),
            tuple(int(p) for p in parents),
            np.asarray(offsets, dtype=np.float64).reshape(-1, 3),
            tuple(tuple(c) for c in channels),
            np.asarray(frames, dtype=np.float64),
            1.0 / fps,
            tuple(rest[0]) if rest else (),
            np.asarray(rest[1], dtype=np.float64).reshape(-1, 3) if len(rest) > 1 else np.zeros((0, 3)),
        )
    if fps is not None:
        data = data._replace(frame_time=1.0 / fps)
    _write(path, data, precision)


def _write(path, data: BvhData, precision: int) -> None:
    J = len(data.names)
    if not (len(data.parents) == len(data.channels) == J and data.offsets.shape == (J, 3)):
        raise ValueError("names, parents, offsets and channels must have one entry a joint")
    if J == 0 or data.parents[0] != -1 or any(p == -1 for p in data.parents[1:]):
        raise ValueError("the first joint must be the only root")
    for c in (c for chans in data.channels for c in chans):
        if c not in _CHANNELS:
            raise ValueError(f"unknown channel {c!r}")
    starts = np.cumsum([0] + [len(c) for c in data.channels])
    C = int(starts[-1])
    frames = np.asarray(data.frames, dtype=np.float64).reshape(-1, C)
    children: list[list[int]] = [[] for _ in range(J)]
    for j, p in enumerate(data.parents[1:], start=1):
        if not 0 <= p < J:
            raise ValueError(f"joint {data.names[j]!r}: bad parent index {p}")
        children[p].append(j)
    ends: list[list[np.ndarray]] = [[] for _ in range(J)]
    for e, p in enumerate(data.end_parents):
        ends[p].append(data.end_offsets[e])
    fmt = lambda v: f"{v:.{precision}f}"
    out: list[str] = ["HIERARCHY"]
    order: list[int] = []

    def emit(j: int, depth: int) -> None:
        ind = "\t" * depth
        out.append(f"{ind}{'ROOT' if depth == 0 else 'JOINT'} {data.names[j]}")
        out.append(f"{ind}{{")
        out.append(f"{ind}\tOFFSET {' '.join(fmt(v) for v in data.offsets[j])}")
        chans = data.channels[j]
        out.append(f"{ind}\tCHANNELS {len(chans)}{''.join(' ' + c for c in chans)}")
        order.append(j)
        for c in children[j]:
            emit(c, depth + 1)
        for off in ends[j]:
            out.extend(
                [
                    f"{ind}\tEnd Site",
                    f"{ind}\t{{",
                    f"{ind}\t\tOFFSET {' '.join(fmt(v) for v in off)}",
                    f"{ind}\t}}",
                ]
            )
        out.append(f"{ind}}}")

    emit(0, 0)
    if len(order) != J:
        raise ValueError("the joints do not form one tree")
    cols = np.concatenate([np.arange(starts[j], starts[j + 1]) for j in order]).astype(np.int64)
    out += ["MOTION", f"Frames: {frames.shape[0]}", f"Frame Time: {data.frame_time:.10g}"]
    row_format = " ".join([f"%.{precision}f"] * len(cols))  # one format per row (the same text as fmt)
    out += [row_format % tuple(row) for row in frames[:, cols].tolist()]
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write("\n".join(out) + "\n")
