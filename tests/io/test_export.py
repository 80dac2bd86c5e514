"""Tracking outputs: incremental poses.npz / poses.csv, the diagnostics journal, atomic rewrites (the BVH of a
body model's motion: test_body_bvh.py)."""

import csv
import json
import os

import numpy as np
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import body
from jaxmocap.io import export
from jaxmocap.tracking.options import build_model


def _model(name):
    return build_model(name, None)


def test_eval_joints_of_fills_missing_with_nan():
    model = _model("upper9")
    J = np.arange(len(model.joint_names) * 3, dtype=float).reshape(-1, 3)
    out = export.eval_joints_of(model, J)
    assert out.shape == (15, 3)
    for k, n in enumerate(body.EVAL_JOINTS):
        if n in model.joint_names:
            np.testing.assert_array_equal(out[k], J[model.joint_names.index(n)])
        else:
            assert np.all(np.isnan(out[k]))


def _read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], np.asarray([[float(v) for v in r] for r in rows[1:]]).reshape(len(rows) - 1, len(rows[0]))


def test_pose_writer_is_valid_after_every_frame(tmp_path):
    dofs = ("a", "b", "c")
    w = export.PoseWriter(tmp_path, dofs, "test", fps=25.0)
    rng = np.random.default_rng(0)
    states, joints = rng.normal(size=(5, 3)), rng.normal(size=(5, 15, 3))
    joints[:, 3] = np.nan  # a joint the model lacks
    for k in range(5):
        w.append(10 + k, states[k], joints[k])
        p = export.load_poses(tmp_path)
        np.testing.assert_array_equal(p["frame_index"], np.arange(10, 11 + k))
        np.testing.assert_array_equal(p["state"], states[: k + 1])
        np.testing.assert_array_equal(p["joints"], joints[: k + 1])
        header, rows = _read_csv(tmp_path / "poses.csv")
        assert rows.shape == (k + 1, 2 + 3 + 45)
        np.testing.assert_allclose(rows[:, 2:5], states[: k + 1], rtol=1e-8)
        np.testing.assert_allclose(rows[:, 5:], joints[: k + 1].reshape(k + 1, -1), rtol=1e-8)
    w.close()
    assert header[:5] == ["frame", "time_s", "a", "b", "c"] and header[5] == "root_x"
    p = export.load_poses(tmp_path)
    assert list(p["dof_names"]) == list(dofs) and list(p["joint_names"]) == list(body.EVAL_JOINTS)
    np.testing.assert_allclose(p["time"], np.arange(10, 15) / 25.0)
    assert not [f for f in os.listdir(tmp_path) if f.endswith(".tmp")]


def test_pose_writer_resume_keeps_a_prefix(tmp_path):
    w = export.PoseWriter(tmp_path, ("a",), "test", fps=30.0)
    for k in range(6):
        w.append(k, [k], np.full((15, 3), k))
    w.close()
    w = export.PoseWriter(tmp_path, ("a",), "test", fps=30.0, keep=4)
    w.append(4, [40.0], np.full((15, 3), 40.0))
    w.close()
    p = export.load_poses(tmp_path)
    np.testing.assert_array_equal(p["state"][:, 0], [0, 1, 2, 3, 40])
    _, rows = _read_csv(tmp_path / "poses.csv")
    np.testing.assert_array_equal(rows[:, 0], [0, 1, 2, 3, 4])
    np.testing.assert_array_equal(rows[:, 2], [0, 1, 2, 3, 40])


def test_atomic_rewrite_leaves_the_old_file_when_interrupted(tmp_path, monkeypatch):
    path = tmp_path / "x.npz"
    export.atomic_write_npz(path, {"a": np.arange(3)})

    def boom(src, dst):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(KeyboardInterrupt):
        export.atomic_write_npz(path, {"a": np.arange(5)})
    monkeypatch.undo()
    with np.load(path) as z:
        np.testing.assert_array_equal(z["a"], np.arange(3))
    assert os.listdir(tmp_path) == ["x.npz"]


def test_diagnostics_journal_and_document(tmp_path):
    d = export.DiagnosticsWriter(tmp_path, {"filter": "apf"}, json_interval=0.0)
    for t in range(4):
        d.append({"frame": t, "quality": float(t), "beta": np.float32(0.5), "bad": float("nan")})
    doc = json.loads((tmp_path / "diagnostics.json").read_text())
    assert [r["frame"] for r in doc["frames"]] == [0, 1, 2, 3]
    assert doc["frames"][0]["bad"] is None and doc["frames"][2]["beta"] == 0.5
    d.close({"frames_tracked": 4})
    lines = (tmp_path / "diagnostics.jsonl").read_text().splitlines()
    assert len(lines) == 4
    # a torn last line (a kill during a write) is dropped on resume, and frames from keep_until on too
    with open(tmp_path / "diagnostics.jsonl", "a") as f:
        f.write('{"frame": 4, "qual')
    d = export.DiagnosticsWriter(tmp_path, {"filter": "apf"}, keep_until=3)
    d.close()
    doc = json.loads((tmp_path / "diagnostics.json").read_text())
    assert [r["frame"] for r in doc["frames"]] == [0, 1, 2]
    assert "summary" not in doc


def test_load_poses_rejects_bad_files(tmp_path):
    from jaxmocap.errors import MocapInputError

    (tmp_path / "poses.npz").write_bytes(b"not a zip")
    with pytest.raises(MocapInputError, match="cannot read"):
        export.load_poses(tmp_path)
    export.atomic_write_npz(tmp_path / "poses.npz", {"joints": np.zeros((2, 15, 3))})
    with pytest.raises(MocapInputError, match="not a jaxmocap poses.npz"):
        export.load_poses(tmp_path / "poses.npz")


def test_pose_journal_holds_every_frame_and_drops_a_torn_record(tmp_path):
    """Between two rewrites of ``poses.npz`` the journal holds the frames (``load_poses`` of the folder reads it);
    the half-written record of a killed process is left out; ``flush`` brings ``poses.npz`` up to date."""
    w = export.PoseWriter(tmp_path, ("a", "b"), "test", fps=10.0, snapshot_interval=1e9)
    rng = np.random.default_rng(1)
    states, joints = rng.normal(size=(4, 2)), rng.normal(size=(4, 15, 3))
    for k in range(4):
        w.append(3 + k, states[k], joints[k])
    snapshot = export.load_poses(tmp_path / "poses.npz")  # as the writer opened: no rewrite due since
    assert len(snapshot["frame_index"]) == 0
    p = export.load_poses(tmp_path)
    np.testing.assert_array_equal(p["frame_index"], [3, 4, 5, 6])
    np.testing.assert_array_equal(p["state"], states)
    np.testing.assert_array_equal(p["joints"], joints)
    assert list(p["dof_names"]) == ["a", "b"] and str(p["model"]) == "test" and float(p["fps"]) == 10.0
    with open(tmp_path / "poses.journal", "ab") as f:
        f.write(np.arange(7, dtype="<f8").tobytes())  # a torn fifth record
    np.testing.assert_array_equal(
        export.read_pose_journal(tmp_path / "poses.journal")["frame_index"], [3, 4, 5, 6]
    )
    w.flush()
    np.testing.assert_array_equal(export.load_poses(tmp_path / "poses.npz")["state"], states)
    w.close()
    (tmp_path / "poses.journal").write_bytes(b"something else\n")
    with pytest.raises(MocapInputError, match="not a jaxmocap pose journal"):
        export.read_pose_journal(tmp_path / "poses.journal")


def test_throttle_keeps_rewrites_to_a_hundredth_of_the_time(monkeypatch):
    """A rewrite is due ``interval`` seconds after the last one and no sooner than 100 times its duration."""
    clock = [100.0]
    monkeypatch.setattr(export.time, "monotonic", lambda: clock[0])
    th = export.Throttle(2.0)
    assert th.due()
    with th.timing():
        clock[0] += 0.5  # a rewrite that takes 0.5 s
    clock[0] += 2.0
    assert not th.due()  # 2 s passed, but 100 x 0.5 s = 50 s have not
    clock[0] += 47.9
    assert not th.due()
    clock[0] += 0.2
    assert th.due()
    assert export.Throttle(0.0).due()


def test_diagnostics_text_is_the_document_json_writes():
    """The diagnostics file's layout (one record per line) holds the document the json module writes indented."""
    import json

    doc = {
        "run": {"options": {"seed": 0, "cues": ["foreground", "depth"]}, "name": "x"},
        "frames": [{"frame": i, "layers": [{"beta": 0.1 * i}], "lost": i == 2} for i in range(5)],
        "summary": {"frames_tracked": 5},
    }
    for d in (doc, {**doc, "frames": []}):
        text = export._json_with_records(d, "frames")
        assert json.loads(text) == json.loads(json.dumps(d, indent=1, sort_keys=True))
        lines = {line.rstrip(",") for line in text.splitlines()}
        assert all(json.dumps(r, sort_keys=True) in lines for r in d["frames"])
