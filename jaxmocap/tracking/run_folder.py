"""The output folder of a tracking run: its lock, ``run.json`` (what ran, and how far it got), the resume checkpoint
``resume.npz`` (:class:`Checkpoints`), and the outputs of :mod:`jaxmocap.io.export` (poses, diagnostics, BVH).

**One writer.** :class:`RunLock` holds ``run.lock`` (an exclusive ``flock`` on it, which the kernel drops when the
process ends, however it ends) for the whole run: a second run into the same folder — fresh, ``--overwrite`` or
``--resume`` — is refused with a message naming the holder's pid and host, and the lock of a process that died
is taken over. A run that fails before writing anything removes the folder it created (no half-made ``--out``).

**Fresh or resumed.** A fresh run checks the folder before anything is written (:func:`check_out`: a folder with
a run's outputs needs ``--overwrite``), then removes the outputs of an earlier run and writes ``run.json``
(:func:`start_out`). ``--resume`` continues a run whose ``run.json`` has the same options and input from its
checkpoint (:func:`write_checkpoint`), after checking every output it continues from
(:func:`jaxmocap.io.export.resume_rows`, the diagnostics journal): a missing or foreign file is refused with one
line, never replaced. ``run.json``'s ``status`` is ``running`` until every output is written, then ``complete``
(:func:`set_status`): resuming a complete run is refused; resuming a run whose frames were all tracked but whose
final outputs were not (killed while writing its BVH or overlays) writes them.
"""

from __future__ import annotations

import contextlib
import datetime
import errno
import json
import os
import pathlib
import queue
import shutil
import socket
import threading

import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.io import export
from jaxmocap.tracking import outputs

__all__ = [
    "LOCK",
    "OVERLAY_TMP",
    "BackgroundWriter",
    "Checkpoints",
    "RESUME_NPZ",
    "RUN_JSON",
    "RunLock",
    "check_out",
    "set_status",
    "start_out",
    "write_checkpoint",
]

RUN_JSON = "run.json"
RESUME_NPZ = "resume.npz"
LOCK = "run.lock"
#: the folder the overlay videos are written into before they are moved next to the other outputs
OVERLAY_TMP = ".overlays.tmp"
#: the montage of the overlays (:class:`jaxmocap.eval.viz.OverlayVideo`)
OVERLAY_MONTAGE = "overlay_montage.png"
#: the outputs a run writes (a fresh run into a folder holding one of them needs --overwrite)
OUTPUTS = (
    RUN_JSON,
    RESUME_NPZ,
    export.POSES_NPZ,
    export.POSES_JOURNAL,
    export.POSES_CSV,
    export.DIAGNOSTICS_JSON,
    export.DIAGNOSTICS_JOURNAL,
    *outputs.EXPORTS,
    OVERLAY_MONTAGE,
)

try:
    import fcntl
except ImportError:  # not POSIX: the lock is the file's existence (see RunLock)
    fcntl = None


class RunLock:
    """The lock of one run on its output folder ``out`` (created when missing): ``run.lock`` holds the holder's
    ``{"pid", "host", "started"}``; :meth:`release` gives it up. Raises :class:`MocapInputError` when another live
    process holds it.

    On POSIX the lock is an ``flock`` on the file (released by the kernel when the holder ends, even by SIGKILL,
    so a stale file is simply taken over); ``stale`` is the previous holder's record then. Elsewhere the file is
    created exclusively and a file of a dead process on this host is taken over."""

    def __init__(self, out: str | os.PathLike):
        self.out = pathlib.Path(out)
        if self.out.exists() and not self.out.is_dir():
            raise MocapInputError(self.out, "exists and is not a folder")
        self.created = not self.out.exists()
        self.out.mkdir(parents=True, exist_ok=True)
        self.path = self.out / LOCK
        self.fd: int | None = None
        try:
            self.stale = self._acquire()
        except BaseException:
            self._remove_folder()
            raise

    def _refuse(self, holder: dict) -> MocapInputError:
        who = (
            f"pid {holder.get('pid', '?')} on {holder.get('host', '?')}, started {holder.get('started', '?')}"
        )
        return MocapInputError(
            self.out, f"is being written by another run ({who}); wait for it to end or choose another --out"
        )

    def _acquire(self) -> dict | None:
        me = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started": datetime.datetime.now().isoformat(timespec="seconds"),
        }
        for _ in range(100):
            if fcntl is None:
                return self._acquire_by_existence(me)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as e:
                holder = _read_holder(fd)
                os.close(fd)
                if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise self._refuse(holder) from None
                raise  # no locks on this file system: say so (OSError → one line)
            try:  # the holder may have released and removed the file between our open and flock
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if not same:
                os.close(fd)
                continue
            stale = _read_holder(fd) or None
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(me) + "\n").encode(), 0)
            self.fd = fd
            return stale
        raise MocapInputError(self.path, "cannot be locked (other runs keep replacing it)")

    def _acquire_by_existence(self, me: dict) -> dict | None:
        stale = None
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o666)
            except FileExistsError:
                with open(self.path, "rb") as f:
                    holder = _parse_holder(f.read())
                if holder.get("host") == me["host"] and not _alive(holder.get("pid")):
                    stale = holder
                    self.path.unlink(missing_ok=True)
                    continue
                raise self._refuse(holder) from None
            os.write(fd, (json.dumps(me) + "\n").encode())
            self.fd = fd
            return stale
        raise self._refuse({})

    def _remove_folder(self) -> None:
        if self.created:
            with contextlib.suppress(OSError):
                self.out.rmdir()  # only when empty

    def release(self, remove_created_folder: bool = False) -> None:
        """Remove ``run.lock`` and give up the lock; with ``remove_created_folder``, also the folder this lock
        created when nothing else was written to it (a run that failed before its first output)."""
        if self.fd is None:
            return
        with contextlib.suppress(OSError):
            self.path.unlink()  # while still holding it: a waiting process then locks a new file
        os.close(self.fd)
        self.fd = None
        if remove_created_folder:
            self._remove_folder()


def _parse_holder(data: bytes) -> dict:
    try:
        holder = json.loads(data.decode("utf-8", "replace") or "{}")
    except json.JSONDecodeError:
        return {}
    return holder if isinstance(holder, dict) else {}


def _read_holder(fd: int) -> dict:
    try:
        return _parse_holder(os.pread(fd, 4096, 0))
    except OSError:
        return {}


def _alive(pid) -> bool:
    try:
        os.kill(int(pid), 0)
    except (TypeError, ValueError, ProcessLookupError):
        return False
    except PermissionError:
        return True
    return True


def _read_run_json(out: pathlib.Path) -> dict:
    try:
        old = json.loads((out / RUN_JSON).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise MocapInputError(out / RUN_JSON, f"cannot read: {e}") from None
    if not isinstance(old, dict):
        raise MocapInputError(out / RUN_JSON, "not a jaxmocap run.json")
    return old


def check_out(
    out: pathlib.Path, description: dict, resume: bool, overwrite: bool, resumable: bool = True
) -> dict | None:
    """Check the output folder (nothing is written): returns the resume checkpoint, or None to start afresh.

    ``description``: the ``run.json`` of this run; a resumed run must have the same ``options`` and ``input``, the
    same resolved defaults (:data:`RESOLVED`: a default that changed between the two versions is named with the
    option that sets it), and every output it continues from must be there and this run's (module docstring).
    Raises :class:`MocapInputError` with the reason."""
    if out.exists() and not out.is_dir():
        raise MocapInputError(out, "exists and is not a folder")
    present = [n for n in OUTPUTS if (out / n).exists()]
    if not resume:
        if present and not overwrite:
            how = "--resume to continue it or --overwrite" if resumable else "--overwrite"
            raise MocapInputError(
                out, f"already holds a tracking run ({', '.join(present)}): pass {how} to replace it"
            )
        return None
    if not (out / RUN_JSON).exists():
        if present:
            raise MocapInputError(
                out / RUN_JSON, f"missing ({', '.join(present)} are there): cannot resume this folder"
            )
        return None
    old = _read_run_json(out)
    desc = json.loads(json.dumps(description))
    if not _same_options(old.get("options"), desc["options"], old) or old.get("input") != desc["input"]:
        raise MocapInputError(
            out / RUN_JSON,
            "was written by a run with other options or input: cannot resume it with these",
        )
    _check_resolved(out, old, desc)
    if old.get("status") == "complete":
        raise MocapInputError(
            out, "holds a complete run: nothing to resume (--overwrite to track it again, or another --out)"
        )
    dof_names, model = desc.get("dof_names", ()), desc.get("model", "")
    ck_path = out / RESUME_NPZ
    if not ck_path.exists():
        rows = 0
        if (out / export.POSES_JOURNAL).exists():
            rows = len(export.read_pose_journal(out / export.POSES_JOURNAL)["frame_index"])
        elif (out / export.POSES_NPZ).exists():
            rows = len(export.load_poses(out / export.POSES_NPZ)["frame_index"])
        if rows:
            raise MocapInputError(
                ck_path,
                f"missing: the {rows} frames tracked here cannot be continued (--overwrite starts afresh)",
            )
        return None  # killed before its first frame: nothing to continue from
    ck = export._read_npz(ck_path)
    if "rows" not in ck or "frame" not in ck:
        raise MocapInputError(ck_path, "not a jaxmocap resume checkpoint")
    rows = int(ck["rows"])
    export.resume_rows(out, dof_names, model, rows)
    if rows and not (out / export.DIAGNOSTICS_JOURNAL).exists():
        raise MocapInputError(
            out / export.DIAGNOSTICS_JOURNAL, f"missing: the records of the {rows} frames tracked are gone"
        )
    return ck


#: What the options resolved to that shapes a checkpoint or the track continued from it (``run.json`` keys): each
#: with the option that sets it, or None where no option does (the body measured from the detections, the model's
#: DOFs, the diffusion of its state): a resumed run must resolve them alike (:func:`check_out`). A key that a run's
#: ``run.json`` lacks (written by a version that did not record it) stands for the option given explicitly, else
#: it is not compared.
RESOLVED = {
    "model": "--model",
    "dof_names": None,
    "particles": "--particles",
    "layers": "--layers",
    "cues": "--cues",
    "refine": "--refine",
    "refine_prior": "--refine-prior",
    "refine_depth": "--refine-depth",
    "diffusion_std": None,
    "body_dimensions": None,
}


def _check_resolved(out: pathlib.Path, old: dict, desc: dict) -> None:
    """Refuse to resume when a default resolved otherwise than in the run being continued (:data:`RESOLVED`;
    floats within a relative 1e-6, what another CPU's rounding may move): names each with the option that gives
    the old value back, or says that only ``--overwrite`` can track the folder again."""
    was, now = ({k: _resolved(d, k) for k in RESOLVED} for d in (old, desc))
    differ = [
        k for k in RESOLVED if was[k] is not _UNKNOWN and now[k] is not _UNKNOWN and not _same(was[k], now[k])
    ]
    if not differ:
        return
    told = ", ".join(
        f"other {k.replace('_', ' ')}" if RESOLVED[k] is None
        else f"{k.replace('_', ' ')} {_argument(k, was[k])} (this run: {_argument(k, now[k])})"
        for k in differ
    )  # fmt: skip
    if any(RESOLVED[k] is None for k in differ):
        how = "this version cannot continue it: --overwrite to track it again, or another --out"
    else:
        how = "resume with " + " ".join(f"{RESOLVED[k]} {_argument(k, was[k])}" for k in differ)
    raise MocapInputError(
        out / RUN_JSON, f"was tracked with {told}, where this run's defaults resolve otherwise: {how}"
    )


_UNKNOWN = object()
_DEFAULTS = (None, "auto")


def _resolved(desc: dict, key: str):
    """What ``key`` resolved to in the run of ``desc`` (its ``run.json``): the recorded value, else the option's
    when it was given explicitly (a version that did not record the resolved value), else unknown."""
    if key in desc:
        return desc[key]
    value = (desc.get("options") or {}).get(key)
    return _UNKNOWN if value in _DEFAULTS else value


def _same_options(old_options, options: dict, old: dict) -> bool:
    """The options of the run being continued and of this run agree: equal, or an option of :data:`RESOLVED` left
    to its default (None, ``auto``) in either run, where the old run recorded what it resolved to: those values
    :func:`_check_resolved` compares (so that the refusal's ``--particles 300`` continues a run of the default's
    300)."""
    if not isinstance(old_options, dict):
        return False
    for k in set(old_options) | set(options):
        a, b = old_options.get(k), options.get(k)
        if _same(a, b) or (RESOLVED.get(k) and (a in _DEFAULTS or b in _DEFAULTS) and k in old):
            continue
        return False
    return True


def _same(a, b) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return a == b or abs(a - b) <= 1e-6 * max(abs(a), abs(b))
    return a == b


def _argument(key: str, value) -> str:
    """``value`` as the command line takes it for the option of ``key``."""
    if key == "cues":
        from jaxmocap.tracking.options import cues_text

        return repr(cues_text(value).replace(" ", ""))
    if isinstance(value, list):
        return ",".join(map(str, value))
    return repr(value) if isinstance(value, float) else str(value)


def start_out(out: pathlib.Path, fresh: bool, description: dict) -> None:
    """Create the folder, remove temporary files of a killed process and, for a fresh run, the old outputs (and
    overlay videos); a fresh run writes ``run.json`` (``status: running``)."""
    out.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(out / OVERLAY_TMP, ignore_errors=True)  # left by a process killed while writing overlays
    for stale in out.glob(".*.tmp"):  # left by a process killed during an atomic rewrite
        if stale.is_file():
            stale.unlink()
    if not fresh:
        return
    for name in OUTPUTS:
        if (out / name).exists():
            (out / name).unlink()
    for video in out.glob("overlay_*.mp4"):
        video.unlink()
    export.atomic_write_text(out / RUN_JSON, _run_json(description, "running"))


def _run_json(description: dict, status: str) -> str:
    return json.dumps({**description, "status": status}, indent=1, sort_keys=True) + "\n"


def set_status(out: pathlib.Path, status: str) -> None:
    """Rewrite ``run.json`` with ``status`` (``running``, ``interrupted``, ``stopped``, ``complete``)."""
    old = _read_run_json(out)
    export.atomic_write_text(
        out / RUN_JSON, _run_json({k: v for k, v in old.items() if k != "status"}, status)
    )


class BackgroundWriter:
    """Runs the writes of a run's outputs in order, in a thread of their own, so that they overlap the tracking of
    the next frame instead of adding to it (``benchmarks/results/run_rate.md``).

    :meth:`submit` queues a callable (at most ``maxsize`` wait; then the tracking waits for the disk);
    :meth:`drain` waits until every queued write is done. The first exception of a write is kept, the writes after
    it are dropped, and it is raised in the tracking thread by the next :meth:`submit`, :meth:`check` or
    :meth:`drain`. Signals reach the tracking thread only, so a write that has started always ends; a process
    killed (SIGKILL) with writes still queued loses them, as it loses the frame being tracked: the checkpoint,
    written in the same order after its frame's outputs, never runs ahead of them."""

    def __init__(self, maxsize: int = 64):
        self.queue: queue.Queue = queue.Queue(maxsize)
        self.error: BaseException | None = None
        self._raised = False
        self.thread = threading.Thread(target=self._work, name="jaxmocap-outputs", daemon=True)
        self.thread.start()

    def _work(self) -> None:
        while True:
            job = self.queue.get()
            try:
                if job is None:
                    return
                if self.error is None:
                    job()
            except BaseException as e:  # noqa: BLE001 (handed to the tracking thread)
                self.error = e
            finally:
                self.queue.task_done()

    def check(self) -> None:
        """Raise the exception of a failed write (once)."""
        if self.error is not None and not self._raised:
            self._raised = True
            raise self.error

    def submit(self, job) -> None:
        self.check()
        self.queue.put(job)

    def drain(self) -> None:
        """Wait for every queued write, then :meth:`check`."""
        self.queue.join()
        self.check()

    def close(self) -> None:
        """Wait for the queued writes and end the thread (an exception of theirs is not raised here)."""
        self.queue.put(None)
        self.thread.join()


class Checkpoints:
    """The resume checkpoints of a run: :meth:`update` after every frame's outputs notes the frame's state and
    writes ``resume.npz`` when a checkpoint is due — at most once per ``interval`` seconds and 100 times the time
    a write takes (:class:`jaxmocap.io.export.Throttle`) —; :meth:`flush` writes the last frame's on the way out.
    A process killed in between is resumed from the last one written, and the frames after it are tracked again
    (the same bits: each frame's key derives from the seed and the frame number)."""

    def __init__(self, out: pathlib.Path, fsync: bool, num_dofs: int, x0, ref_frame, interval: float = 1.0):
        self.args = (out, fsync, num_dofs)
        self.x0, self.ref_frame = x0, ref_frame
        self.throttle = export.Throttle(interval)
        self.pending = None

    def update(self, t: int, state, loss, stats: dict, rows: int) -> None:
        """After frame ``t``'s outputs (``rows`` pose rows in all): its filter ``state``, the track-loss
        bookkeeping ``loss`` (:class:`jaxmocap.tracking.loop.LossTracker`) and the counters ``stats`` as they were
        after that frame (copies that later frames do not change)."""
        self.pending = (t, state, loss, stats, rows)
        if self.throttle.due():
            self.flush()

    def flush(self) -> None:
        """Write the last frame's checkpoint if it is not written yet."""
        if self.pending is None:
            return
        with self.throttle.timing():
            write_checkpoint(*self.args, *self.pending, self.x0, self.ref_frame)
        self.pending = None


def write_checkpoint(
    out: pathlib.Path, fsync: bool, num_dofs: int, t: int, state, loss, stats, rows, x0, ref_frame
):
    """``resume.npz`` after frame ``t``: the filter ``state``, the track-loss bookkeeping ``loss``
    (:class:`jaxmocap.tracking.loop.LossTracker`), the counters ``stats``, the rows written, ``x0`` and the frame
    of the colour references."""
    hist = loss.hist
    export.atomic_write_npz(
        out / RESUME_NPZ,
        {
            "frame": np.asarray(t),
            "rows": np.asarray(rows),
            "particles": np.asarray(state.particles),
            "log_weights": np.asarray(state.log_weights),
            "estimate": np.asarray(state.estimate),
            "hist_frames": np.asarray([f for f, _ in hist], np.int64),
            "hist_states": np.asarray([x for _, x in hist], np.float64).reshape(len(hist), num_dofs),
            "last_good": np.asarray(loss.last_good),
            "x0": np.asarray(x0),
            "ref_frame": np.asarray(ref_frame),
            "q_ref": np.asarray(loss.q_ref),
            "q_hist": np.asarray(loss.q_hist, np.float64),
            "lost_run": np.asarray(loss.lost_run),
            **{k: np.asarray(stats[k]) for k in ("reinitialisations", "lost_frames", "skipped")},
        },
        fsync,
    )
