"""Joint-error metrics (Li & Kulić; López Méndez eq. 7.1–7.3): closed forms, missing joints, frame matching, files
and plots."""

import json

import cv2
import numpy as np
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.eval import metrics, viz
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io import export

J = len(EVAL_JOINTS)


def _offsets(rng, R, T):
    """Displacements of known length: random unit directions times lengths in metres."""
    d = rng.normal(size=(R, T, J, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    length = rng.uniform(0.01, 0.3, size=(R, T, J))
    return d * length[..., None], length * 1000.0


def test_closed_forms_over_runs():
    rng = np.random.default_rng(0)
    R, T = 3, 7
    gt = rng.normal(size=(T, J, 3))
    off, e = _offsets(rng, R, T)  # e[r, t, j] in mm, known exactly
    runs = [(np.arange(T), gt + off[r]) for r in range(R)]
    rep = metrics.evaluate(runs, gt)
    assert rep["num_runs"] == R and rep["num_frames"] == T
    # Li & Kulić
    assert rep["overall_mean_mm"] == pytest.approx(e.mean(), rel=1e-9)
    assert rep["overall_std_mm"] == pytest.approx(np.sqrt(np.mean((e - e.mean()) ** 2)), rel=1e-9)
    ae = e.mean(axis=2)  # (R, T)
    np.testing.assert_allclose(rep["per_frame_mm"], ae.mean(axis=0), rtol=1e-9)
    np.testing.assert_allclose(rep["per_frame_std_mm"], ae.std(axis=0), rtol=1e-9)
    for j, n in enumerate(EVAL_JOINTS):
        assert rep["per_joint_mm"][n] == pytest.approx(e[:, :, j].mean(), rel=1e-9)
        assert rep["per_joint_std_mm"][n] == pytest.approx(e[:, :, j].std(), rel=1e-9)
    # thesis eq. 7.1-7.3, per run, written out as loops
    for r in range(R):
        eps = [sum(e[r, t, j] for j in range(J)) / J for t in range(T)]
        mean = sum(eps) / T
        std = (sum((x - mean) ** 2 for x in eps) / T) ** 0.5
        np.testing.assert_allclose(rep["thesis"]["eq7_1_per_frame_mm"][r], eps, rtol=1e-9)
        assert rep["thesis"]["eq7_2_mean_mm"][r] == pytest.approx(mean, rel=1e-9)
        assert rep["thesis"]["eq7_3_std_mm"][r] == pytest.approx(std, rel=1e-9)
        assert rep["runs"][r]["overall_mean_mm"] == pytest.approx(e[r].mean(), rel=1e-9)
    assert rep["thesis"]["mean_mm"] == pytest.approx(np.mean(rep["thesis"]["eq7_2_mean_mm"]), rel=1e-12)
    assert rep["thesis"]["between_runs_std_mm"] == pytest.approx(
        np.std(rep["thesis"]["eq7_2_mean_mm"]), rel=1e-12
    )
    json.dumps(rep, allow_nan=False)  # JSON-ready


def test_missing_joints_are_left_out():
    """An upper-body model has no legs: those joints are NaN in its output and do not enter any mean."""
    rng = np.random.default_rng(1)
    T = 5
    gt = rng.normal(size=(T, J, 3))
    off, e = _offsets(rng, 1, T)
    pred = gt + off[0]
    legs = [EVAL_JOINTS.index(n) for n in EVAL_JOINTS if "hip" in n or "knee" in n or "ankle" in n]
    pred[:, legs] = np.nan
    keep = [j for j in range(J) if j not in legs]
    rep = metrics.evaluate([(np.arange(T), pred)], gt)
    assert rep["overall_mean_mm"] == pytest.approx(e[0][:, keep].mean(), rel=1e-9)
    np.testing.assert_allclose(rep["per_frame_mm"], e[0][:, keep].mean(axis=1), rtol=1e-9)
    assert rep["per_joint_mm"]["left_knee"] is None
    assert "left_knee" not in rep["joints_evaluated"] and "head" in rep["joints_evaluated"]


def test_frames_are_matched_by_number():
    rng = np.random.default_rng(2)
    gt = rng.normal(size=(10, J, 3))
    order = np.array([7, 3, 5, 4, 6])
    run_a = (order, gt[order] + 0.1)  # every joint 0.1 m off along all three axes
    run_b = (np.arange(2, 9), gt[2:9])  # exact, a different range
    rep = metrics.evaluate([run_a, run_b], gt)
    assert rep["frame_index"] == [3, 4, 5, 6, 7]
    assert rep["runs"][0]["overall_mean_mm"] == pytest.approx(100 * np.sqrt(3), rel=1e-9)
    assert rep["runs"][1]["overall_mean_mm"] == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match="no frame in common"):
        metrics.evaluate([(np.array([20, 21]), gt[:2])], gt)
    with pytest.raises(ValueError, match="must be"):
        metrics.evaluate([(np.arange(3), gt[:3, :4])], gt)


def test_files_table_and_plots(tmp_path):
    rng = np.random.default_rng(3)
    T = 6
    gt = rng.normal(size=(T, J, 3))
    from jaxmocap.io import sequence as seqio

    seqio.write_groundtruth(tmp_path / "seq", gt)
    for r in range(2):
        w = export.PoseWriter(tmp_path / f"run{r}", ("x",), "test", fps=30.0)
        for t in range(T):
            w.append(t, [0.0], gt[t] + 0.01 * (r + 1))
        w.close()
    frames, joints = metrics.load_groundtruth(tmp_path / "seq")
    runs = [metrics.load_prediction(tmp_path / f"run{r}") for r in range(2)]
    rep = metrics.evaluate(runs, joints, frames)
    assert rep["overall_mean_mm"] == pytest.approx(15 * np.sqrt(3), rel=1e-9)  # runs 10√3 and 20√3 mm
    rep.save(tmp_path / "eval.json")
    loaded = json.loads((tmp_path / "eval.json").read_text())
    for key in ("overall_mean_mm", "overall_std_mm", "per_joint_mm", "per_frame_mm"):
        assert key in loaded
    table = metrics.format_table(rep)
    assert f"{rep['overall_mean_mm']:.1f}" in table and "left_wrist" in table
    viz.plot_error_over_time(rep, tmp_path / "t.png")
    viz.plot_per_joint(rep, tmp_path / "j.png")
    for name in ("t.png", "j.png"):
        img = cv2.imread(str(tmp_path / name))
        assert img is not None and img.shape[0] > 200 and img.std() > 10


def test_bad_files(tmp_path):
    with pytest.raises(MocapInputError, match="no such file"):
        metrics.load_prediction(tmp_path / "nothing")
    with pytest.raises(MocapInputError, match="no ground truth"):
        metrics.load_groundtruth(tmp_path)
    (tmp_path / "poses.npz").write_text("garbage")
    with pytest.raises(MocapInputError, match="cannot read"):
        metrics.load_prediction(tmp_path)
    export.atomic_write_npz(tmp_path / "poses.npz", {"joints": np.zeros((3, 4, 3))})
    with pytest.raises(MocapInputError, match="must be"):
        metrics.load_prediction(tmp_path)
