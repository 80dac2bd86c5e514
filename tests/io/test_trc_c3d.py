"""Marker files of the exported track: ``poses.trc`` in Pose2Sim's layout (checked against a file Pose2Sim wrote,
read back by the project's reader) and ``poses.c3d`` (read back by the ``c3d`` package's own reader)."""

import pathlib
import warnings

import c3d
import numpy as np
import pytest

import jaxmocap.parsec  # noqa: F401  (registers the parsec31 body)
from jaxmocap.geometry import body
from jaxmocap.io import c3d as c3d_io
from jaxmocap.io import markers, trc
from jaxmocap.tracking.options import build_model

POSE2SIM_TRC = pathlib.Path(__file__).parents[1] / "data" / "pose2sim_small" / "reference.trc"


@pytest.fixture(scope="module")
def track():
    """Random marker positions (metres, z up) with one missing sample, 7 frames starting at frame 40."""
    rng = np.random.default_rng(0)
    P = rng.normal(size=(7, 4, 3)) + np.array([0.0, 0.0, 1.0])
    P[3, 2] = np.nan
    return ("root", "left_wrist", "head", "spine"), P, np.arange(40, 47)


def test_trc_header_follows_pose2sim(track, tmp_path):
    """Line by line the layout of a .trc that Pose2Sim wrote (tests/data/pose2sim_small/reference.trc): the same
    first line, the same 8 header keys, values in the same places, the same name and coordinate lines."""
    names, P, frames = track
    trc.save_trc(tmp_path / "poses.trc", names, P, 30.0, frames)
    ours = (tmp_path / "poses.trc").read_text().split("\n")
    theirs = POSE2SIM_TRC.read_text().split("\n")
    assert ours[0] == "PathFileType\t4\t(X/Y/Z)\tposes.trc"
    assert theirs[0].split("\t")[:3] == ours[0].split("\t")[:3]
    assert ours[1] == theirs[1] and tuple(ours[1].split("\t")) == trc.HEADER_KEYS
    header = dict(zip(ours[1].split("\t"), ours[2].split("\t"), strict=True))
    assert header == {
        "DataRate": "30",
        "CameraRate": "30",
        "NumFrames": "7",
        "NumMarkers": "4",
        "Units": "m",
        "OrigDataRate": "30",
        "OrigDataStartFrame": "40",
        "OrigNumFrames": "7",
    }
    assert theirs[2].split("\t")[4] == "m"
    # names: 'Frame#', 'Time', then each name followed by two empty columns (the last one too)
    theirs_names = theirs[3].split("\t")
    ours_names = ours[3].split("\t")
    assert ours_names[:2] == theirs_names[:2] == ["Frame#", "Time"]
    assert ours_names[2:] == [c for n in names for c in (n, "", "")]
    assert theirs_names[2:5] == ["RHip", "", ""] and theirs_names[-3:] == ["LWrist", "", ""]
    # coordinates: two empty columns, then X1 Y1 Z1 X2 ...
    assert ours[4].split("\t") == ["", ""] + [f"{a}{i}" for i in range(1, 5) for a in "XYZ"]
    assert theirs[4].split("\t")[:5] == ["", "", "X1", "Y1", "Z1"]
    # data rows right after: Frame# (1-based), Time, 3 values per marker; a missing sample is three empty fields
    row = ours[5 + 3].split("\t")
    assert row[0] == "44" and float(row[1]) == pytest.approx(43 / 30.0)
    assert len(row) == 2 + 3 * 4 and row[2 + 3 * 2 : 2 + 3 * 3] == ["", "", ""]
    assert len(theirs[5].split("\t")) == 2 + 3 * 21


def test_trc_round_trip_through_the_project_reader(track, tmp_path):
    names, P, frames = track
    trc.save_trc(tmp_path / "poses.trc", names, P, 30.0, frames)
    got_names, got, fps = trc.load_trc(tmp_path / "poses.trc")  # y up in the file, back to z up
    assert got_names == names and fps == 30.0
    np.testing.assert_allclose(got, P, rtol=1e-9, atol=1e-12)
    assert np.isnan(got[3, 2]).all() and np.isfinite(np.delete(got.reshape(-1, 3), 3 * 4 + 2, axis=0)).all()
    # the file is y up: the up coordinate (z in the world) is the second column
    raw = (tmp_path / "poses.trc").read_text().split("\n")[5].split("\t")
    assert float(raw[3]) == pytest.approx(P[0, 0, 2], abs=1e-9)


def test_c3d_read_back_by_the_c3d_reader(track, tmp_path):
    names, P, frames = track
    c3d_io.save_c3d(tmp_path / "poses.c3d", names, P, 30.0, frames)
    with open(tmp_path / "poses.c3d", "rb") as f, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # it warns that the file has no analog channels
        r = c3d.Reader(f)
        assert [n.strip() for n in r.point_labels] == list(names)
        assert r.point_rate == 30.0 and r.first_frame == 41 and r.last_frame == 47
        assert r.get("POINT:UNITS").string_value.strip() == "mm"
        assert r.point_scale < 0  # floating-point samples
        rows = [(i, p.copy()) for i, p, _ in r.read_frames()]
    assert [i for i, _ in rows] == list(range(41, 48))
    pts = np.stack([p for _, p in rows])
    valid = pts[..., 3] >= 0
    assert not valid[3, 2] and valid.sum() == P.size // 3 - 1
    np.testing.assert_allclose(pts[valid][:, :3], (P * 1000.0)[valid], rtol=1e-6, atol=1e-3)  # float32 mm
    assert np.all(pts[valid][:, 3] == 0.0)  # computed points: residual 0
    got_names, got, fps = c3d_io.load_c3d(tmp_path / "poses.c3d")
    assert got_names == names and fps == 30.0
    np.testing.assert_allclose(got, P, rtol=1e-6, atol=1e-6)


def test_writers_reject_bad_input(tmp_path):
    with pytest.raises(ValueError, match="positions must be"):
        trc.trc_text(["a"], np.zeros((2, 3, 3)), 30.0)
    with pytest.raises(ValueError, match="tabs"):
        trc.trc_text(["a\tb"], np.zeros((2, 1, 3)), 30.0)
    with pytest.raises(ValueError, match="fps"):
        c3d_io.c3d_bytes(["a"], np.zeros((2, 1, 3)), 0.0)
    (tmp_path / "bad.c3d").write_bytes(b"not a c3d file" * 40)
    from jaxmocap.errors import MocapInputError

    with pytest.raises(MocapInputError, match="bad.c3d"):
        c3d_io.load_c3d(tmp_path / "bad.c3d")


@pytest.mark.parametrize("name", ["upper9", "full25", "parsec31"])
def test_markers_are_the_evaluation_joints_then_other_joint_centres(name):
    """The model's evaluation joints (EVAL_JOINTS order) at the JAX kinematics' positions; on these presets every
    segment origin lies on an evaluation joint, so there is no other joint centre."""
    import jax

    model = build_model(name, None)
    names = markers.marker_names(model)
    assert names == tuple(n for n in body.EVAL_JOINTS if n in model.joint_names)
    X = np.asarray(model.rest_pose, np.float64)[None] + 0.1
    got_names, M = markers.marker_positions(model, X)
    J = np.asarray(jax.jit(lambda x: body.joint_positions(model, x))(X[0].astype(np.float32)))
    np.testing.assert_allclose(M[0], J[[model.joint_names.index(n) for n in names]], atol=2e-6)


def test_a_segment_origin_off_the_evaluation_joints_is_a_marker():
    """A model whose upper-arm segments start 5 cm away from the shoulder joints: their origins are extra
    markers named after the segment."""
    import dataclasses

    import jax.numpy as jnp

    model = build_model("upper9", None)
    k = model.joint_names.index("left_shoulder")
    jp = np.asarray(model.joint_point).copy()
    jp[k] = [0.0, 0.0, 0.05]
    moved = dataclasses.replace(model, joint_point=jnp.asarray(jp, model.joint_point.dtype))
    names, M = markers.marker_positions(moved, np.asarray(model.rest_pose, np.float64)[None])
    assert names[-1] == "left_upper_arm" and len(names) == len(model.joint_names) + 1
    np.testing.assert_allclose(M[0, -1] + [0.0, 0.0, 0.05], M[0, names.index("left_shoulder")], atol=1e-12)
