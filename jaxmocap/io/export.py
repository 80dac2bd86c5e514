"""Outputs of a tracking run: incremental ``poses.npz`` / ``poses.csv`` / diagnostics, and BVH of a model's motion.

**Crash safety** (:class:`PoseWriter`, :class:`DiagnosticsWriter`). After every frame:

* ``poses.npz`` is **rewritten atomically**: the arrays of every finished frame go to a temporary file in the same
  folder, which then replaces the old file with ``os.replace`` (atomic on POSIX and Windows). A process killed at
  any moment therefore leaves either the previous or the new complete file, never a torn one. The cost is
  ``O(T)`` per frame (≈ 0.6 kB per frame for ``full25``), negligible next to tracking for sequences of thousands
  of frames. The file is flushed but not ``fsync``-ed by default (``fsync=True`` also survives power loss).
* ``poses.csv`` gets one line appended and flushed (one ``write`` call per line).
* ``diagnostics.jsonl`` gets one JSON line appended and flushed; ``diagnostics.json`` (the same records as one
  document) is rewritten atomically at most once per ``json_interval`` seconds and when the writer closes.

``poses.npz`` holds ``joints (T, 15, 3)`` metres named by ``joint_names`` (:data:`jaxmocap.geometry.body.EVAL_JOINTS`;
NaN for joints the model lacks), ``state (T, D)`` named by ``dof_names``, ``frame_index (T,)`` (frame numbers of
the input), ``time (T,)`` seconds, ``fps`` and ``model``. Reopening a folder with ``resume=True`` keeps the first
``keep`` frames (the ones a resume checkpoint covers) and rewrites the CSV and the journal to match.

**BVH** (:func:`model_bvh`, :func:`save_model_bvh`): the hierarchy is the model's segment tree; a joint's
``OFFSET`` is the segment's rest offset. Where a segment's DOFs are rotations about (±) coordinate axes of an
un-rotated joint frame, with any translations first, **the DOFs themselves are the channels** (one channel per DOF,
its value ±θ in degrees, or the offset component ± translation); otherwise (rotated rest frames, arbitrary axes)
the segment gets position channels where it translates and ``Z Y X`` Euler channels of its local rotation. The
evaluation joints that are not segment origins (wrists, ankles, head centre, …) are ``End Site`` s. Files are
y-up in centimetres by default (Blender's importer default); :func:`bvh_eval_joints` reads the evaluation joints
back from a :class:`~jaxmocap.io.mocap.Motion` loaded with :func:`jaxmocap.io.bvh.load_bvh`.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import pathlib
import tempfile
import time
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import body as body_mod
from jaxmocap.io import bvh
from jaxmocap.io import sequence as seqio
from jaxmocap.io.mocap import Motion, matrix_to_euler, up_axis_matrix

__all__ = [
    "POSES_NPZ",
    "POSES_CSV",
    "DIAGNOSTICS_JSON",
    "DIAGNOSTICS_JOURNAL",
    "TRACK_BVH",
    "DiagnosticsWriter",
    "PoseWriter",
    "atomic_write_bytes",
    "atomic_write_npz",
    "atomic_write_text",
    "bvh_eval_joints",
    "eval_joints_of",
    "load_poses",
    "model_bvh",
    "save_model_bvh",
]

POSES_NPZ = "poses.npz"
POSES_CSV = "poses.csv"
DIAGNOSTICS_JSON = "diagnostics.json"
DIAGNOSTICS_JOURNAL = "diagnostics.jsonl"
TRACK_BVH = "track.bvh"


# ---------------------------------------------------------------------------------------------------------------
# Atomic files


def _file_mode() -> int:
    """``0o666`` less the process umask (what ``open`` would give a new file)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def atomic_write_bytes(path: str | os.PathLike, data: bytes, fsync: bool = False) -> None:
    """Write ``data`` to a temporary file next to ``path`` and move it over ``path`` with ``os.replace``."""
    path = pathlib.Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.chmod(tmp, _file_mode())
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            if fsync:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def atomic_write_text(path: str | os.PathLike, text: str, fsync: bool = False) -> None:
    atomic_write_bytes(path, text.encode("utf-8"), fsync)


def atomic_write_npz(path: str | os.PathLike, arrays: Mapping[str, np.ndarray], fsync: bool = False) -> None:
    """An uncompressed ``.npz`` (readable by :func:`numpy.load`; the bytes of
    :func:`jaxmocap.io.sequence.write_npz`) written atomically."""
    buf = io.BytesIO()
    seqio.write_npz(buf, arrays)
    atomic_write_bytes(path, buf.getvalue(), fsync)


def _read_npz(path: pathlib.Path) -> dict:
    """Every array of the ``.npz`` at ``path`` (read eagerly, no pickles); raises :class:`MocapInputError`."""
    import zipfile

    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise MocapInputError(path, f"cannot read: {e}") from None


# ---------------------------------------------------------------------------------------------------------------
# Poses


def eval_joints_of(model: body_mod.BodyModel, joints: np.ndarray) -> np.ndarray:
    """Model joints ``(..., J_model, 3)`` (``model.joint_names`` order) → ``(..., 15, 3)`` in
    :data:`~jaxmocap.geometry.body.EVAL_JOINTS` order with NaN for the joints the model lacks."""
    joints = np.asarray(joints, np.float64)
    out = np.full(joints.shape[:-2] + (len(body_mod.EVAL_JOINTS), 3), np.nan)
    for k, name in enumerate(model.joint_names):
        out[..., body_mod.EVAL_JOINTS.index(name), :] = joints[..., k, :]
    return out


def _fmt(v: float) -> str:
    return "nan" if not math.isfinite(v) else f"{v:.9g}"


class PoseWriter:
    """Incremental ``poses.npz`` + ``poses.csv`` of a tracking run (see the module docstring).

    Args:
      out: the output folder (created).
      dof_names: the model's state entries; model: its name; fps: frames per second of the input.
      keep: with ``None`` start afresh (existing files are replaced); with an int, reopen the files of a previous
        run and keep its first ``keep`` frames (a resume).
      fsync: also ``fsync`` every rewrite.
    """

    def __init__(
        self,
        out: str | os.PathLike,
        dof_names: Sequence[str],
        model: str,
        fps: float,
        keep: int | None = None,
        fsync: bool = False,
    ):
        self.out = pathlib.Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.dof_names = tuple(dof_names)
        self.model = str(model)
        self.fps = float(fps)
        self.fsync = fsync
        D, J = len(self.dof_names), len(body_mod.EVAL_JOINTS)
        self.frames: list[int] = []
        self.states = np.zeros((0, D))
        self.joints = np.zeros((0, J, 3))
        if keep is not None and (self.out / POSES_NPZ).exists():
            old = load_poses(self.out / POSES_NPZ)
            if old["state"].shape[1] != D:
                raise MocapInputError(
                    self.out / POSES_NPZ, f"has {old['state'].shape[1]} DOFs, the model {D}"
                )
            keep = min(int(keep), len(old["frame_index"]))
            self.frames = [int(f) for f in old["frame_index"][:keep]]
            self.states = old["state"][:keep]
            self.joints = old["joints"][:keep]
        self._write_npz()
        self._rewrite_csv()
        self._csv = open(self.out / POSES_CSV, "a", encoding="utf-8", newline="\n")  # noqa: SIM115

    @property
    def num_frames(self) -> int:
        return len(self.frames)

    def _header(self) -> str:
        cols = ["frame", "time_s", *self.dof_names]
        cols += [f"{j}_{a}" for j in body_mod.EVAL_JOINTS for a in "xyz"]
        return ",".join(cols) + "\n"

    def _row(self, frame: int, state: np.ndarray, joints: np.ndarray) -> str:
        vals = [str(int(frame)), _fmt(frame / self.fps)]
        vals += [_fmt(float(v)) for v in state]
        vals += [_fmt(float(v)) for v in np.asarray(joints).reshape(-1)]
        return ",".join(vals) + "\n"

    def _rewrite_csv(self) -> None:
        text = self._header() + "".join(
            self._row(f, s, j) for f, s, j in zip(self.frames, self.states, self.joints, strict=True)
        )
        atomic_write_text(self.out / POSES_CSV, text, self.fsync)

    def arrays(self) -> dict[str, np.ndarray]:
        frames = np.asarray(self.frames, np.int64)
        return {
            "joints": self.joints,
            "joint_names": np.asarray(body_mod.EVAL_JOINTS),
            "state": self.states,
            "dof_names": np.asarray(self.dof_names),
            "frame_index": frames,
            "time": frames / self.fps,
            "fps": np.asarray(self.fps),
            "model": np.asarray(self.model),
        }

    def _write_npz(self) -> None:
        atomic_write_npz(self.out / POSES_NPZ, self.arrays(), self.fsync)

    def append(self, frame: int, state: np.ndarray, joints15: np.ndarray) -> None:
        """Add one frame: ``state (D,)``, ``joints15 (15, 3)`` metres (NaN for absent joints)."""
        state = np.asarray(state, np.float64).reshape(1, -1)
        joints15 = np.asarray(joints15, np.float64).reshape(1, len(body_mod.EVAL_JOINTS), 3)
        self.frames.append(int(frame))
        self.states = np.concatenate([self.states, state])
        self.joints = np.concatenate([self.joints, joints15])
        self._write_npz()
        self._csv.write(self._row(frame, state[0], joints15[0]))
        self._csv.flush()

    def close(self) -> None:
        if not self._csv.closed:
            self._csv.close()


def load_poses(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The arrays of a ``poses.npz`` (or of the one in a folder), checked; raises :class:`MocapInputError`."""
    p = pathlib.Path(path)
    if p.is_dir():
        p = p / POSES_NPZ
    if not p.is_file():
        raise MocapInputError(p, "no such file")
    data = _read_npz(p)
    for key in ("joints", "state", "frame_index"):
        if key not in data:
            raise MocapInputError(p, f"no {key!r} array: not a jaxmocap poses.npz")
    T = data["frame_index"].shape[0]
    if data["joints"].shape != (T, len(body_mod.EVAL_JOINTS), 3) or data["state"].ndim != 2:
        raise MocapInputError(p, "arrays of inconsistent shapes")
    if data["state"].shape[0] != T:
        raise MocapInputError(p, "arrays of inconsistent lengths")
    return data


class DiagnosticsWriter:
    """Per-frame diagnostics: ``diagnostics.jsonl`` (one line per frame, appended and flushed) and
    ``diagnostics.json`` (``{"run": …, "frames": [...], "summary": …}``, rewritten atomically at most every
    ``json_interval`` seconds and on :meth:`close`). With ``keep`` (a resume) the journal's records of frames
    ``< keep_until`` (frame numbers) are kept."""

    def __init__(
        self,
        out: str | os.PathLike,
        run: Mapping,
        keep_until: int | None = None,
        json_interval: float = 2.0,
    ):
        self.out = pathlib.Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.run = dict(run)
        self.records: list[dict] = []
        self.json_interval = json_interval
        self._last_json = -math.inf
        journal = self.out / DIAGNOSTICS_JOURNAL
        if keep_until is not None and journal.exists():
            for line in journal.read_text(encoding="utf-8").splitlines():
                try:
                    rec = json.loads(line)
                except json.JSONDecodeError:
                    break  # a torn last line
                if rec.get("frame", math.inf) < keep_until:
                    self.records.append(rec)
        atomic_write_text(journal, "".join(json.dumps(r, sort_keys=True) + "\n" for r in self.records))
        self._journal = open(journal, "a", encoding="utf-8", newline="\n")  # noqa: SIM115
        self.write_json()

    def frames_per_s(self) -> float | None:
        """Tracking rate after the first frame (which includes compilation): frame records with ``seconds``,
        first one left out; None with fewer than two."""
        recs = [r for r in self.records if "seconds" in r]
        if len(recs) < 2:
            return None
        return (len(recs) - 1) / max(sum(r["seconds"] for r in recs[1:]), 1e-9)

    def append(self, record: Mapping) -> None:
        rec = _jsonable(record)
        self.records.append(rec)
        self._journal.write(json.dumps(rec, sort_keys=True, allow_nan=False) + "\n")
        self._journal.flush()
        if time.monotonic() - self._last_json >= self.json_interval:
            self.write_json()

    def write_json(self, summary: Mapping | None = None) -> None:
        doc = {"run": _jsonable(self.run), "frames": self.records}
        if summary is not None:
            doc["summary"] = _jsonable(summary)
        atomic_write_text(self.out / DIAGNOSTICS_JSON, json.dumps(doc, indent=1, sort_keys=True) + "\n")
        self._last_json = time.monotonic()

    def close(self, summary: Mapping | None = None) -> None:
        self.write_json(summary)
        if not self._journal.closed:
            self._journal.close()


def _jsonable(x):
    """Plain JSON types; non-finite floats become None."""
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray | jax.Array):
        return _jsonable(np.asarray(x).tolist())
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, pathlib.PurePath):
        return os.fspath(x)
    return x


# ---------------------------------------------------------------------------------------------------------------
# BVH of a body model's motion

_AXES = "XYZ"


def _signed_axis(v: np.ndarray, tol: float = 1e-9) -> tuple[int, float] | None:
    """``(k, ±1)`` when ``v`` is ``±e_k``, else None."""
    k = int(np.argmax(np.abs(v)))
    s = float(np.sign(v[k]))
    e = np.zeros(3)
    e[k] = s
    return (k, s) if np.allclose(v, e, atol=tol) else None


def _segment_plan(model: body_mod.BodyModel, s: int, A: np.ndarray) -> tuple | None:
    """For segment ``s``: ``[(dof index, 'pos'|'rot', file axis, sign), ...]`` when its DOFs can be the channels
    (module docstring), else None."""
    topo = model.topology
    if not np.allclose(np.asarray(model.rest_rotation[s]), np.eye(3), atol=1e-9):
        return None
    plan, seen_rot, pos_axes = [], False, set()
    for d in topo.segment_dofs[s]:
        axis = np.asarray(model.dof_axis[d], np.float64)
        sa = _signed_axis(A.T @ axis)  # the DOF axis in the file's frame
        if sa is None:
            return None
        kind = topo.dof_kinds[d]
        if kind == "P":
            if seen_rot or sa[0] in pos_axes:
                return None
            pos_axes.add(sa[0])
            plan.append((d, "pos", sa[0], sa[1]))
        else:
            seen_rot = True
            plan.append((d, "rot", sa[0], sa[1]))
    return tuple(plan)


def _children(parents: Sequence[int]) -> list[list[int]]:
    out: list[list[int]] = [[] for _ in parents]
    for j, p in enumerate(parents):
        if p >= 0:
            out[p].append(j)
    return out


def model_bvh(
    model: body_mod.BodyModel,
    states: np.ndarray,
    fps: float,
    *,
    scale: float = 0.01,
    up_axis: str = "y",
    leaf_tips: bool = True,
) -> bvh.BvhData:
    """The BVH content of a state sequence ``states (T, D)`` of ``model`` (metres, radians, z up).

    Args:
      fps: frames per second; scale: metres per written unit (0.01: centimetres); up_axis: the file's up axis.
      leaf_tips: add an ``End Site`` at the far end of the flesh of every leaf segment that has none (so that
        viewers draw those bones with their length).

    Returns:
      :class:`jaxmocap.io.bvh.BvhData` (write it with :func:`jaxmocap.io.bvh.save_bvh`). Joint names are the
      segment names; end sites follow the module docstring.
    """
    states = np.asarray(states, np.float64)
    if states.ndim != 2 or states.shape[1] != model.num_dofs:
        raise ValueError(f"states must be (T, {model.num_dofs}), got {states.shape}")
    A = up_axis_matrix(up_axis)
    topo = model.topology
    S = len(topo.segment_names)
    offsets = np.asarray(model.offset, np.float64)
    T = states.shape[0]
    plans = [_segment_plan(model, s, A) for s in range(S)]
    local_R = local_t = None
    if any(p is None for p in plans) and T:
        R, t = jax.vmap(lambda x: body_mod.segment_poses(model, x))(jnp.asarray(states, model.offset.dtype))
        R, t = np.asarray(R, np.float64), np.asarray(t, np.float64)
        local_R = np.empty_like(R)
        local_t = np.empty_like(t)
        for s, p in enumerate(topo.parents):
            if p < 0:
                local_R[:, s], local_t[:, s] = R[:, s], t[:, s]
            else:
                Rp_T = np.swapaxes(R[:, p], -1, -2)
                local_R[:, s] = Rp_T @ R[:, s]
                local_t[:, s] = np.einsum("tab,tb->ta", Rp_T, t[:, s] - t[:, p])
    channels, cols = [], []
    for s in range(S):
        plan = plans[s]
        off_file = A.T @ offsets[s] / scale
        if plan is not None:
            chans = []
            for d, kind, k, sign in plan:
                if kind == "pos":
                    chans.append(f"{_AXES[k]}position")
                    cols.append(off_file[k] + sign * states[:, d] / scale)
                else:
                    chans.append(f"{_AXES[k]}rotation")
                    cols.append(np.rad2deg(sign * states[:, d]))
            channels.append(tuple(chans))
            continue
        moves = bool(topo.parents[s] < 0 or any(topo.dof_kinds[d] == "P" for d in topo.segment_dofs[s]))
        chans = ("Xposition", "Yposition", "Zposition") if moves else ()
        rotates = bool(topo.segment_dofs[s]) or not np.allclose(np.asarray(model.rest_rotation[s]), np.eye(3))
        if moves:
            tf = np.zeros((T, 3)) if local_t is None else local_t[:, s] @ A / scale  # Aᵀ t, row form
            cols.extend(tf.T)
        if rotates:
            chans += ("Zrotation", "Yrotation", "Xrotation")
            Rf = np.zeros((T, 3, 3)) if local_R is None else A.T @ local_R[:, s] @ A
            eul = np.rad2deg(matrix_to_euler(Rf, "ZYX")) if T else np.zeros((0, 3))
            cols.extend(eul.T)
        channels.append(chans)
    frames = np.stack(cols, axis=1) if cols else np.zeros((T, 0))
    # end sites: evaluation joints away from their segment's origin, then leaf tips
    end_parents, end_offsets = [], []
    jp = np.asarray(model.joint_point, np.float64)
    for k, s in enumerate(model.joint_segment):
        if np.linalg.norm(jp[k]) > 1e-9:
            end_parents.append(s)
            end_offsets.append(A.T @ jp[k] / scale)
    if leaf_tips:
        kids = _children(topo.parents)
        for s in range(S):
            if not kids[s] and s not in end_parents and model.shape_kind[s] != body_mod.SHAPE_NONE:
                end_parents.append(s)
                end_offsets.append(A.T @ np.asarray(model.shape_end[s], np.float64) / scale)
    return bvh.BvhData(
        names=tuple(topo.segment_names),
        parents=tuple(topo.parents),
        offsets=np.stack([A.T @ o / scale for o in offsets]),
        channels=tuple(channels),
        frames=frames,
        frame_time=1.0 / float(fps),
        end_parents=tuple(end_parents),
        end_offsets=np.asarray(end_offsets, np.float64).reshape(-1, 3),
    )


def save_model_bvh(
    path: str | os.PathLike,
    model: body_mod.BodyModel,
    states: np.ndarray,
    fps: float,
    *,
    scale: float = 0.01,
    up_axis: str = "y",
    precision: int = 6,
) -> None:
    """Write :func:`model_bvh` to ``path`` (atomically)."""
    data = model_bvh(model, states, fps, scale=scale, up_axis=up_axis)
    path = pathlib.Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        os.chmod(tmp, _file_mode())
        bvh.save_bvh(tmp, data, precision=precision)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def bvh_eval_joints(motion: Motion, model: body_mod.BodyModel, tol: float = 1e-4) -> np.ndarray:
    """Evaluation joints ``(T, J_model, 3)`` (``model.joint_names`` order, metres) of a BVH written by
    :func:`save_model_bvh` and read back by :func:`jaxmocap.io.bvh.load_bvh`: segment origins are BVH joints
    (by segment name), the other joints the ``End Site`` of their segment with the matching offset."""
    jp = np.asarray(model.joint_point, np.float64)
    out = np.empty((motion.num_frames, len(model.joint_names), 3))
    for k, s in enumerate(model.joint_segment):
        name = model.segment_names[s]
        j = motion.joint_index(name)
        if np.linalg.norm(jp[k]) <= 1e-9:
            out[:, k] = motion.positions[:, j]
            continue
        cands = [e for e, p in enumerate(motion.end_parents) if p == j]
        d = [np.linalg.norm(motion.end_offsets[e] - jp[k]) for e in cands]
        if not cands or min(d) > tol:
            raise ValueError(f"no end site of {name!r} at the offset of joint {model.joint_names[k]!r}")
        out[:, k] = motion.end_positions[:, cands[int(np.argmin(d))]]
    return out
