"""The exported track of a run, written once at its end (:func:`export_track`), each file atomically (a temporary
file in the run folder moved into place): the raw per-frame estimates (``poses.npz`` / ``poses.csv``, written
during the run) stay as they are.

* ``poses_smoothed.npz`` — the exported track on the output grid (the requested frames from the first to the last
  tracked one): gaps filled and flagged, smoothed as ``--smooth`` says (:mod:`jaxmocap.tracking.smoothing`).
  Arrays: ``state (G, D)``, ``joints (G, 15, 3)`` (metres, NaN for joints the model lacks), ``frame_index``,
  ``time``, ``interpolated (G,)`` bool, ``markers (G, M, 3)`` / ``marker_names``, ``joint_names``,
  ``dof_names``, ``fps``, ``model``, ``smooth`` (its ``--smooth`` spelling) — readable by ``jaxmocap eval --pred``.
* ``track.bvh`` — that track as BVH (:mod:`jaxmocap.io.body_bvh`), in ``--bvh-units`` (``cm`` by default).
* ``poses.trc`` — its markers (:mod:`jaxmocap.io.markers`) in Pose2Sim's layout (:func:`jaxmocap.io.trc.save_trc`:
  metres, y up).
* ``poses.c3d`` — the same markers in millimetres, z up (:mod:`jaxmocap.io.c3d`).
* ``plots/`` — :func:`jaxmocap.eval.plots.plot_run`.

Joints and markers of the exported track come from the float64 kinematics of the smoothed states, so the BVH,
TRC, C3D and ``poses_smoothed.npz`` describe one motion; with ``--smooth none`` and no gaps they equal
``poses.npz``'s joints to float32 rounding.
"""

from __future__ import annotations

import pathlib
from collections.abc import Mapping, Sequence

import numpy as np

from jaxmocap.geometry import body as body_mod
from jaxmocap.io import body_bvh, export, markers, trc
from jaxmocap.io import c3d as c3d_io
from jaxmocap.tracking import smoothing

__all__ = [
    "EXPORTS",
    "POSES_C3D",
    "POSES_SMOOTHED_NPZ",
    "POSES_TRC",
    "check_export_options",
    "export_track",
    "preload",
    "lost_frames",
]

POSES_SMOOTHED_NPZ = "poses_smoothed.npz"
POSES_TRC = "poses.trc"
POSES_C3D = "poses.c3d"
#: The files :func:`export_track` writes (``plots/`` besides).
EXPORTS = (POSES_SMOOTHED_NPZ, export.TRACK_BVH, POSES_TRC, POSES_C3D)


def check_export_options(smooth: str | None, bvh_units: str, fps: float) -> float | None:
    """Check ``--smooth`` against the input's frame rate and ``--bvh-units`` (before a run starts); returns the
    cut-off (None: no smoothing). Raises ``ValueError``."""
    if bvh_units not in body_bvh.UNITS:
        raise ValueError(f"--bvh-units must be one of {', '.join(body_bvh.UNITS)}, got {bvh_units!r}")
    return smoothing.parse_smooth(smooth, fps)


def lost_frames(records: Sequence[Mapping]) -> set[int]:
    """Frames whose diagnostics record says the track was lost there."""
    return {int(r["frame"]) for r in records if r.get("lost")}


def preload() -> None:
    """Import what :func:`export_track` will need for its plots (Matplotlib: about 0.4 s of a run's end) — called
    in a thread of its own while the frames are tracked, by a run that draws them."""
    import matplotlib.figure  # noqa: F401
    from matplotlib.backends import backend_agg  # noqa: F401


def export_track(
    out: str | pathlib.Path,
    model: body_mod.BodyModel,
    requested: Sequence[int],
    frames: Sequence[int],
    states: np.ndarray,
    records: Sequence[Mapping],
    fps: float,
    *,
    smooth: str | None = smoothing.DEFAULT_SMOOTH,
    bvh_units: str = "cm",
    plots: bool = True,
    groundtruth=None,
) -> dict:
    """Write the exported track of a run (module docstring) and return what to add to its summary.

    Args:
      out: the run folder. model: the tracked body (metres). requested: the frames of the run; frames, states
        ``(N, D)``: the tracked frames and their estimates (``poses.npz``). records: the diagnostics records
        (``lost`` frames are gaps). fps: the input's frame rate.
      smooth: ``--smooth`` (:func:`jaxmocap.tracking.smoothing.parse_smooth`); bvh_units: ``cm`` or ``m``.
      plots: also draw ``plots/``. groundtruth: optional ``(T_gt, 15, 3)`` joints indexed by frame: adds the
        exported track's mean error (``mean_error_smoothed_mm``).

    Returns:
      ``{"smooth": …, "bvh_units": …, "interpolated_frames": n, "exports": [file names]}`` (+ the error).
    """
    out = pathlib.Path(out)
    cutoff = check_export_options(smooth, bvh_units, fps)
    frames = np.asarray(frames, np.int64)
    if frames.size == 0:
        return {"smooth": smoothing.smooth_text(cutoff), "bvh_units": bvh_units, "exports": []}
    grid = np.asarray([f for f in requested if frames[0] <= f <= frames[-1]], np.int64)
    lost = lost_frames(records)
    good = np.asarray([int(f) not in lost for f in frames])
    angles = np.asarray([k == "R" for k in model.topology.dof_kinds])
    X, interpolated = smoothing.fill_gaps(grid, frames, states, good, angles)
    if cutoff is not None:
        X = smoothing.butterworth(X, fps, cutoff)
    names, M = markers.marker_positions(model, X)
    joints = np.full((len(grid), len(body_mod.EVAL_JOINTS), 3), np.nan)
    for k, n in enumerate(names):
        if n in body_mod.EVAL_JOINTS:
            joints[:, body_mod.EVAL_JOINTS.index(n)] = M[:, k]
    export.atomic_write_npz(
        out / POSES_SMOOTHED_NPZ,
        {
            "joints": joints,
            "joint_names": np.asarray(body_mod.EVAL_JOINTS),
            "state": X,
            "dof_names": np.asarray(model.dof_names),
            "frame_index": grid,
            "time": grid / fps,
            "interpolated": interpolated,
            "markers": M,
            "marker_names": np.asarray(names),
            "fps": np.asarray(float(fps)),
            "model": np.asarray(model.name),
            "smooth": np.asarray(smoothing.smooth_text(cutoff)),
        },
    )
    body_bvh.save_model_bvh(out / export.TRACK_BVH, model, X, fps, scale=body_bvh.UNITS[bvh_units])
    trc.save_trc(out / POSES_TRC, names, M, fps, grid)
    c3d_io.save_c3d(out / POSES_C3D, names, M, fps, grid)
    summary = {
        "smooth": smoothing.smooth_text(cutoff),
        "bvh_units": bvh_units,
        "interpolated_frames": int(interpolated.sum()),
        "exports": list(EXPORTS),
    }
    if groundtruth is not None:
        from jaxmocap.eval import metrics

        try:
            rep = metrics.evaluate([(grid, joints)], groundtruth)
            summary["mean_error_smoothed_mm"] = rep["overall_mean_mm"]
        except ValueError:  # nothing to compare (e.g. a diverged, non-finite track)
            summary["mean_error_smoothed_mm"] = None
    if plots:
        from jaxmocap.eval import plots as plots_mod

        summary["plots"] = [p.name for p in plots_mod.plot_run(out)]
    return summary
