"""Sequence folders: writers and the reader round-trip against OpenCV / NumPy readers; every missing or corrupt
part is one MocapInputError naming the file."""

import json
import tomllib

import cv2
import numpy as np
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import camera
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io import sequence as seqio

T = 3
SIZES = ((64, 48), (40, 30))


def _rig():
    rng = np.random.default_rng(1)
    K = np.array(
        [
            [[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]],
            [[40.0, 0.0, 19.5], [0.0, 41.0, 14.5], [0, 0, 1]],
        ]
    )
    dist = np.array([[-0.1, 0.02, 0.001, -0.002, 0.0], [0.0, 0.0, 0.0, 0.0, 0.0]])
    return camera.from_opencv(
        K, dist, rng.normal(size=(2, 3)), rng.normal(size=(2, 3)), ("front", "side"), SIZES
    )


def _write(root, rng, channels=seqio.CHANNELS, groundtruth=True):
    rig = _rig()
    seqio.write_calibration(root, rig)
    seqio.write_meta(root, {"frames": T, "fps": 30.0, "body": "body.toml"})
    (root / "body.toml").write_text('model = "full25"\n[dimensions]\ntorso_length = 0.5\n')
    content = {}
    for name, (w, h) in zip(rig.names, SIZES, strict=True):
        for t in range(T):
            rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
            labels = rng.integers(-1, 31, (h, w)).astype(np.int32)
            depth = np.where(labels >= 0, rng.integers(1, 65536, (h, w)), 0).astype(np.uint16)
            content[name, t] = dict(rgb=rgb, mask=labels >= 0, depth=depth, labels=labels)
            for c in channels:
                path = seqio.frame_path(root, name, c, t)
                getattr(seqio, f"write_{c}")(path, content[name, t][c])
    if groundtruth:
        joints = rng.normal(size=(T, 15, 3))
        seqio.write_groundtruth(
            root, joints, rng.normal(size=(T, 4, 3)), ("a", "b", "c", "d"), frame_index=np.arange(T)
        )
    return rig, content


def test_round_trip_against_opencv(tmp_path):
    rig, content = _write(tmp_path, np.random.default_rng(0))
    seq = seqio.load_sequence(tmp_path)
    assert seq.num_frames == T and len(seq) == T and seq.fps == 30.0
    assert seq.view_names == ("front", "side") and seq.channels == seqio.CHANNELS
    assert seq.body_path == tmp_path / "body.toml"
    for name in rig.names:
        view = seq.view(name)
        for t in range(T):
            ref = content[name, t]
            # the files are ordinary images: OpenCV reads them back (BGR, 16-bit depth, label + 1)
            bgr = cv2.imread(str(view.path("rgb", t)), cv2.IMREAD_UNCHANGED)
            np.testing.assert_array_equal(bgr[..., ::-1], ref["rgb"])
            raw_depth = cv2.imread(str(view.path("depth", t)), cv2.IMREAD_UNCHANGED)
            assert raw_depth.dtype == np.uint16
            np.testing.assert_array_equal(raw_depth, ref["depth"])
            raw_labels = cv2.imread(str(view.path("labels", t)), cv2.IMREAD_UNCHANGED)
            np.testing.assert_array_equal(raw_labels.astype(int) - 1, ref["labels"])
            np.testing.assert_array_equal(view.rgb(t), ref["rgb"])
            np.testing.assert_array_equal(view.mask(t), ref["mask"])
            np.testing.assert_array_equal(view.labels(t), ref["labels"])
            np.testing.assert_allclose(view.depth(t), ref["depth"] / 1000.0, rtol=1e-6)
    frames = seq.frame(1, "labels")
    assert [f.shape for f in frames] == [(48, 64), (30, 40)]
    # calibration: what cv2.projectPoints makes of the written TOML equals the rig that was written
    X = np.random.default_rng(2).normal(size=(20, 3)) + [0, 0, 5]
    doc = tomllib.loads((tmp_path / seqio.CALIBRATION).read_text())
    for v, name in enumerate(rig.names):
        cam = doc[name]
        assert cam["size"] == list(SIZES[v])
        from_toml, _ = cv2.projectPoints(
            X,
            np.asarray(cam["rotation"]),
            np.asarray(cam["translation"]),
            np.asarray(cam["matrix"]),
            np.asarray(cam["distortions"]),
        )
        written, _ = cv2.projectPoints(
            X,
            cv2.Rodrigues(np.asarray(rig.R[v]))[0],
            np.asarray(rig.t[v]),
            np.asarray(rig.K[v]),
            np.asarray(rig.dist[v]),
        )
        np.testing.assert_allclose(from_toml, written, atol=1e-9)
        uv = np.asarray(camera.project(seq.rig.to_jax(np.float32), X.astype(np.float32)))[v]
        np.testing.assert_allclose(uv, written[:, 0], rtol=1e-5, atol=2e-3)
    assert seq.rig.image_size == SIZES
    gt = seq.groundtruth
    assert gt.joint_names == EVAL_JOINTS and gt.joints.shape == (T, 15, 3)
    assert gt.all_joint_names == ("a", "b", "c", "d") and gt.all_joints.shape == (T, 4, 3)
    np.testing.assert_array_equal(gt.extra["frame_index"], np.arange(T))


def test_npz_is_byte_identical_and_numpy_readable(tmp_path):
    arrays = {"x": np.arange(12.0).reshape(3, 4), "names": np.asarray(["a", "bc"])}
    seqio.write_npz(tmp_path / "a.npz", arrays)
    seqio.write_npz(tmp_path / "b.npz", arrays)
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    with np.load(tmp_path / "a.npz") as z:
        np.testing.assert_array_equal(z["x"], arrays["x"])
        assert z["names"].tolist() == ["a", "bc"]


def test_optional_parts(tmp_path):
    _write(tmp_path, np.random.default_rng(3), channels=("rgb",), groundtruth=False)
    (tmp_path / "body.toml").unlink()
    meta = json.loads((tmp_path / seqio.META).read_text())
    del meta["body"]
    seqio.write_meta(tmp_path, meta)
    seq = seqio.load_sequence(tmp_path)
    assert seq.channels == ("rgb",) and seq.groundtruth is None and seq.body_path is None
    with pytest.raises(MocapInputError, match="no such channel"):
        seq.view("front").depth(0)
    with pytest.raises(IndexError):
        seq.view("side").rgb(T)
    with pytest.raises(KeyError):
        seq.view("top")


def _break(kind, root):
    if kind == "no folder":
        return root / "nope", "nope"
    if kind == "no calibration":
        (root / seqio.CALIBRATION).unlink()
        return root, "calibration.toml"
    if kind == "bad calibration":
        (root / seqio.CALIBRATION).write_text("[front]\nmatrix = [[1, 0\n")
        return root, "calibration.toml"
    if kind == "no meta":
        (root / seqio.META).unlink()
        return root, "meta.json"
    if kind == "bad meta json":
        (root / seqio.META).write_text('{\n  "frames": 3,\n  "fps": \n}\n')
        return root, "meta.json:4"
    if kind == "meta frames":
        (root / seqio.META).write_text('{"frames": "3", "fps": 30}')
        return root, "meta.json"
    if kind == "no view":
        import shutil

        shutil.rmtree(root / "views" / "side")
        return root, "side"
    if kind == "missing frame":
        seqio.frame_path(root, "side", "depth", 1).unlink()
        return root, "side/depth/000001.png"
    if kind == "extra frame":
        seqio.write_mask(seqio.frame_path(root, "front", "mask", T), np.zeros((48, 64), bool))
        return root, "front/mask/000003.png"
    if kind == "no body":
        (root / "body.toml").unlink()
        return root, "body.toml"
    if kind == "gt shape":
        seqio.write_npz(
            root / seqio.GROUNDTRUTH,
            {"joints": np.zeros((T + 1, 15, 3)), "joint_names": np.asarray(EVAL_JOINTS)},
        )
        return root, "groundtruth.npz"
    if kind == "gt corrupt":
        (root / seqio.GROUNDTRUTH).write_bytes(b"PK\x03\x04 truncated")
        return root, "groundtruth.npz"
    if kind == "gt names":
        seqio.write_npz(
            root / seqio.GROUNDTRUTH,
            {"joints": np.zeros((T, 15, 3)), "joint_names": np.asarray([f"j{i}" for i in range(15)])},
        )
        return root, "groundtruth.npz"
    raise AssertionError(kind)


BROKEN = [
    "no folder",
    "no calibration",
    "bad calibration",
    "no meta",
    "bad meta json",
    "meta frames",
    "no view",
    "missing frame",
    "extra frame",
    "no body",
    "gt shape",
    "gt corrupt",
    "gt names",
]


@pytest.mark.parametrize("kind", BROKEN)
def test_broken_folder_names_the_file(tmp_path, kind):
    _write(tmp_path, np.random.default_rng(4))
    root, where = _break(kind, tmp_path)
    with pytest.raises(MocapInputError) as e:
        seqio.load_sequence(root)
    assert where in str(e.value).replace("\\", "/")


@pytest.mark.parametrize("kind", ["corrupt", "wrong size", "depth is 8-bit", "mask is colour"])
def test_bad_images_fail_lazily_with_the_file(tmp_path, kind):
    _write(tmp_path, np.random.default_rng(5))
    seq = seqio.load_sequence(tmp_path)
    view = seq.view("front")
    if kind == "corrupt":
        view.path("rgb", 2).write_bytes(b"\x89PNG\r\n\x1a\n not really")
        bad = lambda: view.rgb(2)
        name = "rgb/000002.png"
    elif kind == "wrong size":
        cv2.imwrite(str(view.path("labels", 0)), np.zeros((30, 40), np.uint8))
        bad = lambda: view.labels(0)
        name = "labels/000000.png"
    elif kind == "depth is 8-bit":
        cv2.imwrite(str(view.path("depth", 1)), np.zeros((48, 64), np.uint8))
        bad = lambda: view.depth(1)
        name = "depth/000001.png"
    else:
        cv2.imwrite(str(view.path("mask", 1)), np.zeros((48, 64, 3), np.uint8))
        bad = lambda: view.mask(1)
        name = "mask/000001.png"
    with pytest.raises(MocapInputError) as e:
        bad()
    assert name in str(e.value).replace("\\", "/")


def test_writers_reject_bad_arrays(tmp_path):
    with pytest.raises(ValueError):
        seqio.write_depth(tmp_path / "d.png", np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError):
        seqio.write_labels(tmp_path / "l.png", np.full((4, 4), 300))
    with pytest.raises(ValueError):
        seqio.write_rgb(tmp_path / "r.png", np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError):
        seqio.write_groundtruth(tmp_path, np.zeros((2, 14, 3)))
    with pytest.raises(ValueError):
        seqio.frame_path(tmp_path, "v", "normals", 0)
