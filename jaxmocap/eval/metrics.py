"""3D joint-position errors of tracked motion against ground truth, in millimetres.

Notation: runs ``r = 1 … R`` (the same sequence tracked with different seeds), frames ``t = 1 … T``, joints
``j = 1 … J`` (the evaluation joints :data:`jaxmocap.geometry.body.EVAL_JOINTS` that the tracked model has), and the error of
one joint in one frame of one run

    e_{r,t,j} = 1000 · ‖p̂_{r,t,j} − p_{t,j}‖₂        (mm; p̂ tracked, p ground truth, both in metres)

Li & Kulić (stereo full-body partitioned particle filter, evaluation section):

* **Average Error per frame** ``AE_{r,t} = (1/J) Σ_j e_{r,t,j}``; reported per frame as its mean over runs
  ``per_frame_mm[t] = (1/R) Σ_r AE_{r,t}`` with ``per_frame_std_mm[t]`` the standard deviation over runs;
* **Joint Average Error** ``JAE_j = (1/(R T)) Σ_{r,t} e_{r,t,j}`` → ``per_joint_mm[j]``, with ``per_joint_std_mm[j]``
  the standard deviation of ``e_{r,t,j}`` over runs and frames;
* **Overall Average Error** ``OAE = (1/(R T J)) Σ_{r,t,j} e_{r,t,j}`` → ``overall_mean_mm``, with
  ``overall_std_mm`` the standard deviation of all ``e_{r,t,j}``.

López Méndez (2009), eq. 7.1–7.3 (the HumanEva form of the same error), per run ``r``:

* eq. 7.1: ``ε_r(t) = (1/J) Σ_j e_{r,t,j}`` (mean joint error of a frame; equal to ``AE_{r,t}``);
* eq. 7.2: ``ε̄_r = (1/T) Σ_t ε_r(t)`` (its mean over the sequence);
* eq. 7.3: ``σ_r = sqrt((1/T) Σ_t (ε_r(t) − ε̄_r)²)`` (its standard deviation over the sequence; population form);

reported per run and as their mean over runs (``thesis.mean_mm`` = mean of ``ε̄_r``, ``thesis.std_mm`` = mean of
``σ_r``) together with the spread of ``ε̄_r`` across runs (``thesis.between_runs_std_mm``). All standard deviations
here are population standard deviations (divisor ``n``).

Joints the model lacks (NaN in the tracked joints, e.g. the legs of an upper-body model) are left out of every mean;
``J`` is then the number of joints present. Frames are matched by their sequence frame number (``frame_index`` of
``poses.npz``); only the frames every run has are evaluated.
"""

from __future__ import annotations

import json
import os
import pathlib
from collections.abc import Mapping, Sequence

import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io.export import _read_npz

__all__ = ["Evaluation", "evaluate", "joint_errors", "load_groundtruth", "load_prediction", "format_table"]


def joint_errors(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """``e = 1000 ‖pred − gt‖₂`` in mm over the last axis: ``(..., J, 3)`` metres → ``(..., J)``; NaN where the
    prediction (or ground truth) of a joint is missing."""
    pred = np.asarray(pred, np.float64)
    gt = np.asarray(gt, np.float64)
    if pred.shape[-2:] != gt.shape[-2:] or pred.shape[-1] != 3:
        raise ValueError(f"joint arrays disagree: {pred.shape} vs {gt.shape}")
    return 1000.0 * np.sqrt(np.sum((pred - gt) ** 2, axis=-1))


def _nanmean(a: np.ndarray, axis=None) -> np.ndarray:
    """Mean ignoring NaN; NaN (without a warning) where everything is NaN."""
    a = np.asarray(a, np.float64)
    ok = np.isfinite(a)
    n = np.sum(ok, axis=axis)
    s = np.sum(np.where(ok, a, 0.0), axis=axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, s / np.maximum(n, 1), np.nan)


def _nanstd(a: np.ndarray, axis=None) -> np.ndarray:
    """Population standard deviation ignoring NaN; NaN where everything is NaN."""
    a = np.asarray(a, np.float64)
    m = _nanmean(a, axis=axis)
    mk = m if axis is None else np.expand_dims(m, axis)
    return np.sqrt(_nanmean((a - mk) ** 2, axis=axis))


def _num(x) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


class Evaluation(dict):
    """The report of :func:`evaluate`: a JSON-ready ``dict`` (see the module docstring for every field)."""

    def save(self, path: str | os.PathLike) -> None:
        """Write the report as JSON (sorted keys, 2-space indent)."""
        pathlib.Path(path).write_text(json.dumps(self, indent=2, sort_keys=True, allow_nan=False) + "\n")


def evaluate(
    runs: Sequence[tuple[np.ndarray, np.ndarray]],
    gt_joints: np.ndarray,
    gt_frames: np.ndarray | None = None,
    joint_names: Sequence[str] = EVAL_JOINTS,
    run_names: Sequence[str] | None = None,
) -> Evaluation:
    """Li & Kulić's errors and the thesis' eq. 7.1–7.3 over several runs.

    Args:
      runs: one ``(frame_index (T_r,), joints (T_r, J, 3))`` pair per run, metres (NaN rows for missing joints).
      gt_joints: ``(T_gt, J, 3)`` ground truth in metres; gt_frames: the frame number of each of its rows (default
        ``0 … T_gt−1``).
      joint_names: the ``J`` joint names (default :data:`jaxmocap.geometry.body.EVAL_JOINTS`).
      run_names: a label per run for the report.

    Returns:
      :class:`Evaluation` with ``overall_mean_mm``, ``overall_std_mm``, ``per_joint_mm``, ``per_joint_std_mm``,
      ``per_frame_mm``, ``per_frame_std_mm``, ``frame_index``, ``thesis`` and ``runs`` (per-run numbers).

    Raises:
      ValueError: no run, shapes that disagree, or no frame common to every run and the ground truth.
    """
    if not runs:
        raise ValueError("no run to evaluate")
    gt_joints = np.asarray(gt_joints, np.float64)
    J = len(joint_names)
    if gt_joints.ndim != 3 or gt_joints.shape[1:] != (J, 3):
        raise ValueError(f"ground truth must be (T, {J}, 3), got {gt_joints.shape}")
    gt_frames = np.arange(gt_joints.shape[0]) if gt_frames is None else np.asarray(gt_frames, np.int64)
    common = set(gt_frames.tolist())
    for frames, joints in runs:
        joints = np.asarray(joints)
        if joints.ndim != 3 or joints.shape[1:] != (J, 3) or len(frames) != joints.shape[0]:
            raise ValueError(
                f"a run's joints must be (T, {J}, 3) with one frame number per row, got {joints.shape}"
            )
        common &= set(np.asarray(frames, np.int64).tolist())
    frames = np.asarray(sorted(common), np.int64)
    if frames.size == 0:
        raise ValueError("the runs and the ground truth have no frame in common")
    gt_row = {int(f): i for i, f in enumerate(gt_frames)}
    gt = gt_joints[[gt_row[int(f)] for f in frames]]
    errs = []
    for run_frames, joints in runs:
        row = {int(f): i for i, f in enumerate(np.asarray(run_frames, np.int64))}
        errs.append(joint_errors(np.asarray(joints, np.float64)[[row[int(f)] for f in frames]], gt))
    e = np.stack(errs)  # (R, T, J)
    R, T = e.shape[:2]
    present = np.any(np.isfinite(e), axis=(0, 1))  # joints the model has
    if not np.any(present):
        raise ValueError("no tracked joint has a value")

    ae = _nanmean(e, axis=2)  # (R, T): Li & Kulić AE per frame = thesis eq. 7.1
    eq72 = _nanmean(ae, axis=1)  # (R,)
    eq73 = _nanstd(ae, axis=1)  # (R,)
    names = list(run_names) if run_names is not None else [f"run{r}" for r in range(R)]
    per_joint = _nanmean(e, axis=(0, 1))
    per_joint_std = _nanstd(e.reshape(R * T, J), axis=0)
    report = Evaluation(
        units="mm",
        joint_names=list(joint_names),
        num_runs=R,
        num_frames=T,
        frame_index=frames.tolist(),
        overall_mean_mm=_num(_nanmean(e)),
        overall_std_mm=_num(_nanstd(e)),
        per_joint_mm={n: _num(v) for n, v in zip(joint_names, per_joint, strict=True)},
        per_joint_std_mm={n: _num(v) for n, v in zip(joint_names, per_joint_std, strict=True)},
        per_frame_mm=[_num(v) for v in _nanmean(ae, axis=0)],
        per_frame_std_mm=[_num(v) for v in _nanstd(ae, axis=0)],
        joints_evaluated=[n for n, p in zip(joint_names, present, strict=True) if p],
        thesis={
            "eq7_1_per_frame_mm": [[_num(v) for v in row] for row in ae],
            "eq7_2_mean_mm": [_num(v) for v in eq72],
            "eq7_3_std_mm": [_num(v) for v in eq73],
            "mean_mm": _num(np.mean(eq72)),
            "std_mm": _num(np.mean(eq73)),
            "between_runs_std_mm": _num(np.std(eq72)),
        },
        runs=[
            {
                "name": names[r],
                "overall_mean_mm": _num(_nanmean(e[r])),
                "overall_std_mm": _num(_nanstd(e[r])),
                "per_joint_mm": {
                    n: _num(v) for n, v in zip(joint_names, _nanmean(e[r], axis=0), strict=True)
                },
            }
            for r in range(R)
        ],
        definitions={
            "e": "e[r,t,j] = 1000 * |tracked - ground truth| (mm) of joint j in frame t of run r",
            "per_frame_mm": "mean over runs of AE[r,t] = mean_j e[r,t,j] (Li & Kulic average error per frame)",
            "per_frame_std_mm": "std over runs of AE[r,t]",
            "per_joint_mm": "mean over runs and frames of e[r,t,j] (Li & Kulic joint average error)",
            "per_joint_std_mm": "std over runs and frames of e[r,t,j]",
            "overall_mean_mm": "mean of e over runs, frames and joints (Li & Kulic overall average error)",
            "overall_std_mm": "std of e over runs, frames and joints",
            "thesis.eq7_1_per_frame_mm": "eps_r(t) = mean_j e[r,t,j] per run (Lopez Mendez eq. 7.1)",
            "thesis.eq7_2_mean_mm": "mean over frames of eps_r(t) per run (eq. 7.2)",
            "thesis.eq7_3_std_mm": "std over frames of eps_r(t) per run (eq. 7.3)",
            "thesis.mean_mm / std_mm": "means over runs of eq. 7.2 / eq. 7.3",
            "thesis.between_runs_std_mm": "std over runs of eq. 7.2",
            "std": "population standard deviations (divisor n); NaN joints (absent from the model) left out",
        },
    )
    return report


# ---------------------------------------------------------------------------------------------------------------
# Files


#: The messages of a missing file and of a missing ``joints`` array, by file name.
_NPZ_ERRORS = {
    "poses.npz": (
        "no such file (expected a tracking output folder or its poses.npz)",
        "no 'joints' array: not a jaxmocap poses.npz",
    ),
    "groundtruth.npz": (
        "no ground truth (expected a sequence folder with groundtruth.npz)",
        "ground truth needs 'joints'",
    ),
}


def _npz_joints(path: str | os.PathLike, name: str) -> tuple[pathlib.Path, dict, np.ndarray]:
    """``(file, arrays, joints (T, 15, 3) float64)`` of the ``.npz`` at ``path`` (or ``path / name`` for a folder;
    ``name`` a key of :data:`_NPZ_ERRORS`), its ``joints`` checked against
    :data:`~jaxmocap.geometry.body.EVAL_JOINTS`; raises :class:`MocapInputError`."""
    no_file, no_joints = _NPZ_ERRORS[name]
    p = pathlib.Path(path)
    if p.is_dir():
        p = p / name
    if not p.is_file():
        raise MocapInputError(p, no_file)
    data = _read_npz(p)
    if "joints" not in data:
        raise MocapInputError(p, no_joints)
    joints = np.asarray(data["joints"], np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (len(EVAL_JOINTS), 3):
        raise MocapInputError(p, f"'joints' must be (T, {len(EVAL_JOINTS)}, 3), got {joints.shape}")
    return p, data, joints


def load_prediction(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """``(frame_index (T,), joints (T, 15, 3))`` of a tracking run: its output folder or its ``poses.npz``."""
    p, data, joints = _npz_joints(path, "poses.npz")
    if "joint_names" in data and tuple(str(n) for n in data["joint_names"]) != EVAL_JOINTS:
        raise MocapInputError(p, "'joint_names' must be jaxmocap.geometry.body.EVAL_JOINTS")
    frames = np.asarray(data.get("frame_index", np.arange(joints.shape[0])), np.int64)
    if frames.shape != (joints.shape[0],):
        raise MocapInputError(p, "'frame_index' needs one entry per row of 'joints'")
    if joints.shape[0] == 0:
        raise MocapInputError(p, "holds no tracked frame")
    return frames, joints


def load_groundtruth(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """``(frame_index (T,), joints (T, 15, 3))`` of a sequence folder's ground truth (or a ``groundtruth.npz``)."""
    p, _, joints = _npz_joints(path, "groundtruth.npz")
    if not np.all(np.isfinite(joints)):
        raise MocapInputError(p, "'joints' has non-finite values")
    return np.arange(joints.shape[0]), joints


def format_table(report: Mapping, title: str | None = None) -> str:
    """A small plain-text table of a report: the overall and per-joint errors (mean ± std, mm)."""
    lines = [] if title is None else [title]
    lines.append(
        f"{'joint':<16}{'mean mm':>10}{'std mm':>10}"
        + ("" if report["num_runs"] == 1 else f"   ({report['num_runs']} runs)")
    )
    lines.append("-" * 36)
    for n in report["joint_names"]:
        m, s = report["per_joint_mm"][n], report["per_joint_std_mm"][n]
        if m is not None:
            lines.append(f"{n:<16}{m:>10.1f}{s:>10.1f}")
    lines.append("-" * 36)
    lines.append(f"{'overall':<16}{report['overall_mean_mm']:>10.1f}{report['overall_std_mm']:>10.1f}")
    th = report["thesis"]
    lines.append(f"{'eq. 7.2 / 7.3':<16}{th['mean_mm']:>10.1f}{th['std_mm']:>10.1f}")
    lines.append(f"frames: {report['num_frames']}")
    return "\n".join(lines)


def evaluate_folders(pred: list, gt: str, out: str | None = None, quiet: bool = False):
    """Evaluate tracking output folders against a sequence's ground truth; write JSON and plots when ``out``."""
    from jaxmocap.eval import viz

    gt_frames, gt_joints = load_groundtruth(gt)
    runs = [load_prediction(p) for p in pred]
    try:
        report = evaluate(runs, gt_joints, gt_frames, run_names=[str(p) for p in pred])
    except ValueError as e:
        raise MocapInputError(pred[0], str(e)) from None
    if out is not None:
        out = pathlib.Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        report.save(out)
        stem = out.with_suffix("")
        viz.plot_error_over_time(report, f"{stem}_error_over_time.png")
        viz.plot_per_joint(report, f"{stem}_per_joint.png")
    return report
