"""Outputs of a tracking run: incremental ``poses.npz`` / ``poses.csv`` / diagnostics, and BVH of a model's motion.

**Crash safety** (:class:`PoseWriter`, :class:`DiagnosticsWriter`). After every frame:

* ``poses.journal`` gets the frame appended and flushed: one little-endian float64 record
  ``[frame, state (D), joints (15 × 3)]`` after a header (a magic line and a JSON line with ``dof_names``,
  ``model``, ``fps``). It is the run's record of every frame: a process killed during a write leaves a torn last
  record, which readers leave out (:func:`read_pose_journal`).
* ``poses.csv`` gets one line appended and flushed (one ``write`` call per line).
* ``diagnostics.jsonl`` gets one JSON line appended and flushed.

``poses.npz`` and ``diagnostics.json`` (the same records as whole documents) are **rewritten atomically** — to a
temporary file in the same folder, then moved over the old one with ``os.replace``, so that a process killed at
any moment leaves the previous or the new complete file — at most once per ``2 s`` and never more often than 100
times the time a rewrite takes (:class:`Throttle`: rewriting costs at most 1 % of a run however long it is), and
on every way out of a run (:meth:`PoseWriter.flush`, :meth:`DiagnosticsWriter.close`). Files are flushed but not
``fsync``-ed by default (``fsync=True`` also survives power loss). :func:`load_poses` of a run's folder reads the
journal when it holds more frames than ``poses.npz`` (a killed run), and :func:`resume_rows` checks every pose file
a resumed run continues from.

``poses.npz`` holds ``joints (T, 15, 3)`` metres named by ``joint_names`` (:data:`jaxmocap.geometry.body.EVAL_JOINTS`;
NaN for joints the model lacks), ``state (T, D)`` named by ``dof_names``, ``frame_index (T,)`` (frame numbers of
the input), ``time (T,)`` seconds, ``fps`` and ``model``. Reopening a folder with ``keep`` keeps the first
``keep`` frames (the ones a resume checkpoint covers) and rewrites the CSV and the journals to match.

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
    "POSES_JOURNAL",
    "TRACK_BVH",
    "DiagnosticsWriter",
    "PoseWriter",
    "Throttle",
    "atomic_write_bytes",
    "atomic_write_npz",
    "atomic_write_text",
    "bvh_eval_joints",
    "eval_joints_of",
    "load_poses",
    "model_bvh",
    "read_pose_journal",
    "resume_rows",
    "save_model_bvh",
]

POSES_NPZ = "poses.npz"
POSES_CSV = "poses.csv"
POSES_JOURNAL = "poses.journal"
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


class Throttle:
    """When to rewrite a whole file that grows with the run (``poses.npz``, ``diagnostics.json``): :meth:`due` once
    ``interval`` seconds have passed since the last rewrite **and** ``ratio`` times the time that rewrite took, so
    that rewriting costs at most ``1 / ratio`` of the run however long it gets. ``interval=0``: every time."""

    def __init__(self, interval: float, ratio: float = 100.0):
        self.interval, self.ratio = float(interval), float(ratio)
        self.last, self.cost = -math.inf, 0.0

    def due(self) -> bool:
        if self.interval <= 0:
            return True
        return time.monotonic() - self.last >= max(self.interval, self.ratio * self.cost)

    @contextlib.contextmanager
    def timing(self):
        t0 = time.monotonic()
        yield
        self.last = time.monotonic()
        self.cost = self.last - t0


_JOURNAL_MAGIC = b"JAXMOCAP POSES JOURNAL 1\n"


def _journal_header(dof_names: Sequence[str], model: str, fps: float) -> bytes:
    head = {
        "dof_names": list(dof_names),
        "model": str(model),
        "fps": float(fps),
        "joints": len(body_mod.EVAL_JOINTS),
    }
    return _JOURNAL_MAGIC + json.dumps(head, sort_keys=True).encode("utf-8") + b"\n"


def read_pose_journal(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The arrays of a ``poses.journal`` (the ones :class:`PoseWriter` gives ``poses.npz``); a torn last record
    (a process killed during its write) is left out. Raises :class:`MocapInputError`."""
    p = pathlib.Path(path)
    try:
        data = p.read_bytes()
    except OSError as e:
        raise MocapInputError(p, f"cannot read: {e}") from None
    end = data.find(b"\n", len(_JOURNAL_MAGIC))
    if not data.startswith(_JOURNAL_MAGIC) or end < 0:
        raise MocapInputError(p, "not a jaxmocap pose journal")
    try:
        head = json.loads(data[len(_JOURNAL_MAGIC) : end])
        dof_names, model, fps = [str(n) for n in head["dof_names"]], str(head["model"]), float(head["fps"])
    except (ValueError, KeyError, TypeError):
        raise MocapInputError(p, "not a jaxmocap pose journal (bad header)") from None
    J, D = len(body_mod.EVAL_JOINTS), len(dof_names)
    width = 1 + D + 3 * J
    body = data[end + 1 :]
    rows = np.frombuffer(body, "<f8", count=(len(body) // (8 * width)) * width).reshape(-1, width)
    frames = rows[:, 0].astype(np.int64)
    return _pose_arrays(frames, rows[:, 1 : 1 + D], rows[:, 1 + D :].reshape(-1, J, 3), dof_names, model, fps)


def _pose_arrays(frames, states, joints, dof_names, model, fps) -> dict[str, np.ndarray]:
    frames = np.asarray(frames, np.int64)
    return {
        "joints": np.asarray(joints, np.float64),
        "joint_names": np.asarray(body_mod.EVAL_JOINTS),
        "state": np.asarray(states, np.float64),
        "dof_names": np.asarray(dof_names),
        "frame_index": frames,
        "time": frames / float(fps),
        "fps": np.asarray(float(fps)),
        "model": np.asarray(str(model)),
    }


def resume_rows(
    out: str | os.PathLike, dof_names: Sequence[str], model: str, rows: int
) -> dict[str, np.ndarray]:
    """The first ``rows`` tracked frames of the run in ``out``, after checking every pose output a resumed run
    continues from (nothing is written); raises :class:`MocapInputError` naming the file that fails.

    The rows come from ``poses.journal`` (every frame, appended), or from ``poses.npz`` when that holds them all
    (a run of a version without the journal). ``poses.npz``, where present, must be this model's and agree with
    the journal; ``poses.csv``, where present, must have this run's header and frame numbers (a file of the same
    name that another program wrote is never replaced). Missing ``poses.npz`` / ``poses.csv`` are rewritten from
    the rows."""
    out = pathlib.Path(out)
    dof_names = [str(n) for n in dof_names]
    found = {}
    for name in (POSES_JOURNAL, POSES_NPZ):
        p = out / name
        if not p.exists():
            continue
        a = read_pose_journal(p) if name == POSES_JOURNAL else load_poses(p)
        if [str(n) for n in a.get("dof_names", ())] != dof_names or str(a.get("model", "")) != str(model):
            raise MocapInputError(
                p, f"holds poses of another model than this run's ({model}, {len(dof_names)} DOFs)"
            )
        found[name] = a
    have = {name: len(a["frame_index"]) for name, a in found.items()}
    src = next((n for n in (POSES_JOURNAL, POSES_NPZ) if have.get(n, -1) >= rows), None)
    if src is None:
        what = (
            ", ".join(f"{n} {k}" for n, k in have.items())
            or f"neither {POSES_JOURNAL} nor {POSES_NPZ} exists"
        )
        raise MocapInputError(
            out,
            f"the checkpoint covers {rows} tracked frames but the pose files hold fewer ({what}): cannot resume",
        )
    a = {
        k: (v[:rows] if k in ("joints", "state", "frame_index", "time") else v) for k, v in found[src].items()
    }
    for name, b in found.items():
        n = min(have[name], rows)
        same = np.array_equal(b["frame_index"][:n], a["frame_index"][:n]) and np.array_equal(
            b["state"][:n], a["state"][:n], equal_nan=True
        )
        if not same:
            raise MocapInputError(out / name, f"disagrees with {src}: not this run's poses, cannot resume")
    _check_csv(out / POSES_CSV, _csv_header(dof_names), a["frame_index"])
    return a


def _check_csv(path: pathlib.Path, header: str, frames: np.ndarray) -> None:
    """A resumed run's ``poses.csv``: absent, or this run's header and (a prefix of) its frame numbers."""
    if not path.exists():
        return
    try:
        with open(path, encoding="utf-8", newline="") as f:
            if f.readline() != header:
                raise MocapInputError(
                    path, "was not written by this run (another header): move it away to resume"
                )
            got = []
            for line in f:
                if not line.endswith("\n"):
                    break  # a torn last line
                got.append(line.split(",", 1)[0])
    except (OSError, UnicodeDecodeError) as e:
        raise MocapInputError(path, f"cannot read: {e}") from None
    n = min(len(got), len(frames))
    if got[:n] != [str(int(f)) for f in frames[:n]]:
        raise MocapInputError(path, "its frame numbers disagree with the run's poses: move it away to resume")


def _csv_header(dof_names: Sequence[str]) -> str:
    cols = ["frame", "time_s", *dof_names]
    cols += [f"{j}_{a}" for j in body_mod.EVAL_JOINTS for a in "xyz"]
    return ",".join(cols) + "\n"


class PoseWriter:
    """The incremental pose outputs of a tracking run (see the module docstring): ``poses.journal`` and
    ``poses.csv`` appended every frame, ``poses.npz`` rewritten from time to time (:class:`Throttle`) and on
    :meth:`flush` / :meth:`close`.

    Args:
      out: the output folder (created).
      dof_names: the model's state entries; model: its name; fps: frames per second of the input.
      keep: with ``None`` start afresh (existing files are replaced); with an int, continue the run in ``out``
        from its first ``keep`` frames (a resume: :func:`resume_rows` checks its files first).
      fsync: also ``fsync`` every write.
      snapshot_interval: seconds between rewrites of ``poses.npz`` (at least; see :class:`Throttle`).
    """

    def __init__(
        self,
        out: str | os.PathLike,
        dof_names: Sequence[str],
        model: str,
        fps: float,
        keep: int | None = None,
        fsync: bool = False,
        snapshot_interval: float = 2.0,
    ):
        self.out = pathlib.Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.dof_names = tuple(str(n) for n in dof_names)
        self.model = str(model)
        self.fps = float(fps)
        self.fsync = fsync
        self._throttle = Throttle(snapshot_interval)
        D, J = len(self.dof_names), len(body_mod.EVAL_JOINTS)
        self._frames: list[int] = []
        self._states: list[np.ndarray] = [np.zeros((0, D))]
        self._joints: list[np.ndarray] = [np.zeros((0, J, 3))]
        if keep is not None:
            old = resume_rows(self.out, self.dof_names, self.model, int(keep))
            self._frames = [int(f) for f in old["frame_index"]]
            self._states, self._joints = [old["state"]], [old["joints"]]
        head = _journal_header(self.dof_names, self.model, self.fps)
        atomic_write_bytes(self.out / POSES_JOURNAL, head + self._records(0), fsync)
        self._written = self.num_frames
        self._write_npz()
        atomic_write_text(self.out / POSES_CSV, _csv_header(self.dof_names) + self._rows_text(0), fsync)
        self._journal = open(self.out / POSES_JOURNAL, "ab")  # noqa: SIM115
        self._csv = open(self.out / POSES_CSV, "a", encoding="utf-8", newline="\n")  # noqa: SIM115

    @property
    def num_frames(self) -> int:
        return len(self._frames)

    @property
    def frames(self) -> list[int]:
        return self._frames

    @property
    def states(self) -> np.ndarray:
        """``(T, D)``: every frame's state (one array; appending keeps a list of rows until it is asked for)."""
        if len(self._states) > 1:
            self._states = [np.concatenate(self._states)]
        return self._states[0]

    @property
    def joints(self) -> np.ndarray:
        """``(T, 15, 3)``: every frame's evaluation joints."""
        if len(self._joints) > 1:
            self._joints = [np.concatenate(self._joints)]
        return self._joints[0]

    def _records(self, start: int) -> bytes:
        s, j, f = self.states[start:], self.joints[start:], np.asarray(self._frames[start:], np.float64)
        rows = [f[:, None], s, j.reshape(len(f), 3 * len(body_mod.EVAL_JOINTS))]
        return np.concatenate(rows, axis=1).astype("<f8").tobytes()

    def _row(self, frame: int, state: np.ndarray, joints: np.ndarray) -> str:
        vals = [str(int(frame)), _fmt(frame / self.fps)]
        vals += [_fmt(float(v)) for v in state]
        vals += [_fmt(float(v)) for v in np.asarray(joints).reshape(-1)]
        return ",".join(vals) + "\n"

    def _rows_text(self, start: int) -> str:
        return "".join(
            self._row(f, s, j)
            for f, s, j in zip(self._frames[start:], self.states[start:], self.joints[start:], strict=True)
        )

    def arrays(self) -> dict[str, np.ndarray]:
        return _pose_arrays(self._frames, self.states, self.joints, self.dof_names, self.model, self.fps)

    def _write_npz(self) -> None:
        with self._throttle.timing():
            atomic_write_npz(self.out / POSES_NPZ, self.arrays(), self.fsync)

    def append(self, frame: int, state: np.ndarray, joints15: np.ndarray) -> None:
        """Add one frame: ``state (D,)``, ``joints15 (15, 3)`` metres (NaN for absent joints)."""
        state = np.asarray(state, np.float64).reshape(1, -1)
        joints15 = np.asarray(joints15, np.float64).reshape(1, len(body_mod.EVAL_JOINTS), 3)
        self._frames.append(int(frame))
        self._states.append(state)
        self._joints.append(joints15)
        rec = np.concatenate([[float(frame)], state[0], joints15.reshape(-1)]).astype("<f8").tobytes()
        self._journal.write(rec)
        self._journal.flush()
        if self.fsync:
            os.fsync(self._journal.fileno())
        self._csv.write(self._row(frame, state[0], joints15[0]))
        self._csv.flush()
        if self._throttle.due():
            self._write_npz()

    def flush(self) -> None:
        """Rewrite ``poses.npz`` with every frame so far."""
        self._write_npz()

    def close(self) -> None:
        """:meth:`flush` and close the appended files (again: nothing)."""
        if self._csv.closed:
            return
        self.flush()
        self._journal.close()
        self._csv.close()


def load_poses(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The arrays of a ``poses.npz`` (or of a run's folder: its ``poses.npz``, or its ``poses.journal`` when that
    holds more frames, as after a killed run), checked; raises :class:`MocapInputError`."""
    p = pathlib.Path(path)
    journal = None
    if p.is_dir():
        journal, p = p / POSES_JOURNAL, p / POSES_NPZ
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
    if journal is not None and journal.is_file():
        more = read_pose_journal(journal)
        if len(more["frame_index"]) > T and more["state"].shape[1] == data["state"].shape[1]:
            return more
    return data


class DiagnosticsWriter:
    """Per-frame diagnostics: ``diagnostics.jsonl`` (one line per frame, appended and flushed) and
    ``diagnostics.json`` (``{"run": …, "frames": [...], "summary": …}``, rewritten atomically at most every
    ``json_interval`` seconds (:class:`Throttle`) and on :meth:`close`). With ``keep`` (a resume) the journal's
    records of frames ``< keep_until`` (frame numbers) are kept."""

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
        self._throttle = Throttle(json_interval)
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
        if self._throttle.due():
            self.write_json()

    def write_json(self, summary: Mapping | None = None) -> None:
        doc = {"run": _jsonable(self.run), "frames": self.records}
        if summary is not None:
            doc["summary"] = _jsonable(summary)
        with self._throttle.timing():
            atomic_write_text(self.out / DIAGNOSTICS_JSON, _json_with_records(doc, "frames"))

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


def _json_with_records(doc: Mapping, key: str) -> str:
    """``doc`` as JSON text, its keys sorted: the list ``doc[key]`` one compact record per line, every other entry
    indented. The same document as ``json.dumps(doc, indent=1, sort_keys=True)``, written by the json module's C
    encoder record by record (the indenting encoder is pure Python: 0.8 s for 3000 frames of diagnostics)."""
    parts = []
    for k in sorted(doc):
        if k == key:
            rows = ",\n".join(json.dumps(r, sort_keys=True) for r in doc[k])
            value = f"[\n{rows}\n]" if rows else "[]"
        else:
            value = json.dumps(doc[k], indent=1, sort_keys=True).replace("\n", "\n ")
        parts.append(f" {json.dumps(k)}: {value}")
    return "{\n" + ",\n".join(parts) + "\n}\n"
