"""The output folder of a tracking run: ``run.json`` (what ran), the resume checkpoint ``resume.npz`` after each
frame, and the outputs of :mod:`jaxmocap.io.export` (poses, diagnostics, BVH).

A fresh run checks the folder before anything is written (:func:`check_out`), then removes the outputs of an
earlier run and writes ``run.json`` (:func:`start_out`). ``--resume`` continues a run whose ``run.json`` has the
same options and input, from its checkpoint (:func:`write_checkpoint`).
"""

from __future__ import annotations

import json
import pathlib

import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.io import export
from jaxmocap.tracking import outputs

__all__ = ["RESUME_NPZ", "RUN_JSON", "check_out", "start_out", "write_checkpoint"]

RUN_JSON = "run.json"
RESUME_NPZ = "resume.npz"


def check_out(
    out: pathlib.Path, description: dict, resume: bool, overwrite: bool, resumable: bool = True
) -> dict | None:
    """Check the output folder (nothing is written): returns the resume checkpoint, or None to start afresh.

    ``description``: the ``run.json`` of this run; a resumed run must have the same ``options`` and ``input``."""
    if out.exists() and not out.is_dir():
        raise MocapInputError(out, "exists and is not a folder")
    has_run = (out / export.POSES_NPZ).exists() or (out / RUN_JSON).exists()
    if resume:
        if not (out / RUN_JSON).exists():
            if has_run:
                raise MocapInputError(out / RUN_JSON, "missing: cannot resume this folder")
            return None
        try:
            old = json.loads((out / RUN_JSON).read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise MocapInputError(out / RUN_JSON, f"cannot read: {e}") from None
        desc = json.loads(json.dumps(description))
        if old.get("options") != desc["options"] or old.get("input") != desc["input"]:
            raise MocapInputError(
                out / RUN_JSON,
                "was written by a run with other options or input: cannot resume it with these",
            )
        ck = out / RESUME_NPZ
        return export._read_npz(ck) if ck.exists() else None
    if has_run and not overwrite:
        how = "--resume to continue it or --overwrite" if resumable else "--overwrite"
        raise MocapInputError(out, f"already holds a tracking run: pass {how} to replace it")
    return None


def start_out(out: pathlib.Path, fresh: bool, description: dict) -> None:
    """Create the folder, remove temporary files of a killed process and, for a fresh run, the old outputs; a
    fresh run writes ``run.json``."""
    out.mkdir(parents=True, exist_ok=True)
    for stale in out.glob(".*.tmp"):  # left by a process killed during an atomic rewrite
        stale.unlink()
    if not fresh:
        return
    names = (
        RESUME_NPZ,
        export.POSES_NPZ,
        export.POSES_CSV,
        export.DIAGNOSTICS_JSON,
        export.DIAGNOSTICS_JOURNAL,
        export.TRACK_BVH,
        *outputs.EXPORTS,
    )
    for name in names:
        if (out / name).exists():
            (out / name).unlink()
    export.atomic_write_text(out / RUN_JSON, json.dumps(description, indent=1, sort_keys=True) + "\n")


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
