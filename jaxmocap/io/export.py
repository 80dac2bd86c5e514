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

**BVH**: :func:`save_model_bvh` (``track.bvh``), :func:`model_bvh` and :func:`bvh_eval_joints` are those of
:mod:`jaxmocap.io.body_bvh` (the layout Blender and the common BVH loaders read).
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
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import body as body_mod
from jaxmocap.io import sequence as seqio
from jaxmocap.io.body_bvh import bvh_eval_joints, model_bvh, save_model_bvh

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
