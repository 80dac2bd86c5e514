"""The exported track a run ends with (tracking/outputs.py), on a run folder made without tracking: gaps filled and
flagged, and every file read back by its reader (the project's BVH / TRC readers, the ``c3d`` package) equal to
the joints of ``poses.npz`` (with ``--smooth none``) or of the smoothed states; ``jaxmocap plot``."""

import json

import cv2
import jax
import numpy as np
import pytest

from jaxmocap import cli
from jaxmocap.geometry import body
from jaxmocap.io import body_bvh, bvh, export, trc
from jaxmocap.io import c3d as c3d_io
from jaxmocap.tracking import outputs, smoothing
from jaxmocap.tracking.options import build_model

FPS = 30.0
FRAMES = [f for f in range(20) if f != 5]  # frame 5 unreadable (skipped)
LOST = 9


@pytest.fixture(scope="module")
def model():
    return build_model("full25", None)


@pytest.fixture(scope="module")
def run(model, tmp_path_factory):
    """A run folder as the loop leaves it: poses.npz / diagnostics of a walk-like motion with noise, frame 5
    skipped, frame 9 lost; ``joints`` of poses.npz from the JAX kinematics (as the loop computes them)."""
    out = tmp_path_factory.mktemp("run")
    rng = np.random.default_rng(0)
    t = np.asarray(FRAMES) / FPS
    X = np.tile(np.asarray(model.rest_pose, np.float64), (len(FRAMES), 1))
    X[:, 0] = 1.2 * t  # walking along x
    for d, name in enumerate(model.dof_names):
        if name.endswith(("hip_ry", "shoulder_ry")):
            X[:, d] = 0.4 * np.sin(2 * np.pi * 1.0 * t + d)
    X += rng.normal(0.0, 0.01, X.shape)
    X[FRAMES.index(LOST)] += 0.5  # the lost frame's estimate is off
    J = np.asarray(jax.jit(jax.vmap(lambda x: body.joint_positions(model, x)))(X.astype(np.float32)))
    w = export.PoseWriter(out, model.dof_names, model.name, FPS)
    d = export.DiagnosticsWriter(out, {"test": 1})
    for k, f in enumerate(range(20)):
        if f == 5:
            d.append({"frame": f, "skipped": True, "reason": "unreadable"})
            continue
        i = FRAMES.index(f)
        w.append(f, X[i], export.eval_joints_of(model, J[i]))
        last = {"beta": 0.1, "survival_rate": 0.5, "ess": 40.0 + k, "loglik_max": -1.0}
        d.append({"frame": f, "quality": 1.0 + 0.01 * k, "lost": f == LOST, "reinitialised": f == LOST,
                  "layers": [last]})  # fmt: skip
    w.close()
    d.close()
    return out, X


def _export(out, model, X, **kw):
    records = [json.loads(line) for line in (out / "diagnostics.jsonl").read_text().splitlines()]
    return outputs.export_track(out, model, list(range(20)), FRAMES, X, records, FPS, **kw)


def test_unsmoothed_export_equals_poses_npz(run, model):
    out, X = run
    summary = _export(out, model, X, smooth="none", bvh_units="m", plots=False)
    assert summary["smooth"] == "none" and summary["interpolated_frames"] == 2
    assert summary["exports"] == ["poses_smoothed.npz", "track.bvh", "poses.trc", "poses.c3d"]
    raw = export.load_poses(out)
    sm = np.load(out / "poses_smoothed.npz")
    np.testing.assert_array_equal(sm["frame_index"], np.arange(20))
    np.testing.assert_array_equal(np.flatnonzero(sm["interpolated"]), [5, LOST])
    assert str(sm["smooth"]) == "none"
    keep = [f for f in FRAMES if f != LOST]
    rows_raw = [FRAMES.index(f) for f in keep]
    np.testing.assert_allclose(
        sm["joints"][keep], raw["joints"][rows_raw], atol=2e-6
    )  # float64 vs float32 FK
    np.testing.assert_allclose(sm["state"][keep], X[rows_raw], atol=1e-12)
    # the gaps: the states halfway between their neighbours (linear in time)
    np.testing.assert_allclose(sm["state"][5], (X[FRAMES.index(4)] + X[FRAMES.index(6)]) / 2, atol=1e-12)
    np.testing.assert_allclose(sm["state"][LOST], (X[FRAMES.index(8)] + X[FRAMES.index(10)]) / 2, atol=1e-12)
    names = [str(n) for n in sm["marker_names"]]
    cols = [body.EVAL_JOINTS.index(n) for n in names]
    # TRC read back by the project's reader
    tn, tp, fps = trc.load_trc(out / "poses.trc")
    assert list(tn) == names and fps == FPS
    np.testing.assert_allclose(tp, sm["joints"][:, cols], atol=1e-9)
    np.testing.assert_allclose(tp[keep], raw["joints"][rows_raw][:, cols], atol=2e-6)
    # C3D read back by the c3d package
    cn, cp, fps = c3d_io.load_c3d(out / "poses.c3d")
    assert list(cn) == names and fps == FPS
    np.testing.assert_allclose(cp[keep], raw["joints"][rows_raw][:, cols], atol=1e-6)  # float32 millimetres
    # BVH in metres read back by the project's reader
    m = bvh.load_bvh(out / "track.bvh", scale=1.0)
    assert m.num_frames == 20
    J = body_bvh.bvh_eval_joints(m, model)
    np.testing.assert_allclose(export.eval_joints_of(model, J)[keep], raw["joints"][rows_raw], atol=2e-6)


def test_smoothed_export_is_the_butterworth_of_the_filled_states(run, model):
    out, X = run
    summary = _export(out, model, X, smooth="butterworth:4", plots=False)
    sm = np.load(out / "poses_smoothed.npz")
    filled, _ = smoothing.fill_gaps(np.arange(20), FRAMES, X, np.asarray(FRAMES) != LOST,
                                    np.asarray([k == "R" for k in model.topology.dof_kinds]))  # fmt: skip
    np.testing.assert_allclose(sm["state"], smoothing.butterworth(filled, FPS, 4.0), atol=1e-12)
    assert str(sm["smooth"]) == summary["smooth"] == "butterworth:4"
    m = bvh.load_bvh(out / "track.bvh", scale=0.01)  # centimetres by default
    J = export.eval_joints_of(model, body_bvh.bvh_eval_joints(m, model))
    np.testing.assert_allclose(J, sm["joints"], atol=1e-7)
    raw = export.load_poses(out)  # the raw estimates are kept
    np.testing.assert_array_equal(raw["state"], X)


def test_bad_export_options(model, run):
    with pytest.raises(ValueError, match="bvh-units"):
        outputs.check_export_options("none", "mm", FPS)
    with pytest.raises(ValueError, match="below half"):
        outputs.check_export_options("butterworth:20", "cm", FPS)


def test_plots_and_the_plot_command(run, model, capsys, tmp_path):
    out, X = run
    summary = _export(out, model, X, plots=True)
    assert summary["plots"] == ["trajectories.png", "skeleton.png", "quality.png"]
    for name in summary["plots"]:
        img = cv2.imread(str(out / "plots" / name))
        assert img is not None and img.shape[0] >= 300 and img.shape[1] >= 600
        assert img.std() > 10  # not a blank picture
    assert cli.main(["plot", str(out), "--out", str(tmp_path / "p")]) == 0
    assert sorted(p.name for p in (tmp_path / "p").iterdir()) == [
        "quality.png",
        "skeleton.png",
        "trajectories.png",
    ]
    assert "trajectories.png" in capsys.readouterr().out
    assert cli.main(["plot", str(tmp_path / "missing")]) == 2
    (tmp_path / "empty").mkdir()
    assert cli.main(["plot", str(tmp_path / "empty")]) == 2
    assert "not a tracking run" in capsys.readouterr().err
