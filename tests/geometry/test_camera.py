"""Camera rigs: projection and triangulation against OpenCV, calibration loaders against real files and third-party
reference values (PARSEC bodytrack, caliscope, Pose2Sim), gradients, batching and parser fuzzing."""

import dataclasses
import os
import pathlib
import re
import tempfile
import tomllib

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from jax import enable_x64
from jax.test_util import check_grads

from jaxmocap import parsec  # registers the PARSEC .cal reader with load_calibration
from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import camera as C
from jaxmocap.io import calibration as IO
from jaxmocap.io.openpose import BODY_25B_KEYPOINTS, load_openpose_folder, load_openpose_json
from jaxmocap.io.trc import load_trc

CALIB = pathlib.Path(__file__).parents[1] / "data" / "calib"

# jit-compiled entry points: one compilation per shape and dtype instead of one per primitive in eager mode
project = jax.jit(C.project)
project_with_depth = jax.jit(C.project_with_depth)
world_to_camera = jax.jit(C.world_to_camera)
undistort_points = jax.jit(C.undistort_points)
triangulate = jax.jit(C.triangulate)
in_view = jax.jit(C.in_view)
P2S = CALIB / "pose2sim"
CALIBRATIONS = {
    "opencv_left": CALIB / "opencv" / "left_intrinsics.yml",
    "opencv_stereo": CALIB / "opencv" / "intrinsics.yml",
    "pose2sim": P2S / "Calib_qualisys_converted_by_pose2sim_a948c20.toml",
    "qualisys": P2S / "Calib.qca.txt",
    "caliscope": CALIB / "caliscope" / "camera_array.toml",
    "parsec": CALIB / "parsec" / "CALIB",
}


def _points_in_front(rig, v, n, rng, depth=(0.5, 8.0)):
    """World points that project inside camera v's image (ignoring distortion) at the given depths."""
    w, h = rig.image_size[v] if rig.image_size[v][0] else (640, 480)
    px = np.stack([rng.uniform(0, w - 1, n), rng.uniform(0, h - 1, n), np.ones(n)], -1)
    rays = px @ np.linalg.inv(rig.K[v]).T
    cam = rays * rng.uniform(*depth, n)[:, None]
    return (cam - rig.t[v]) @ rig.R[v]  # R^T (x_c - t), row form


def _rvecs_as_stored(name, rig):
    """Rotation argument for cv2.projectPoints: the file's own Rodrigues vectors where it stores them."""
    if name == "pose2sim":
        data = tomllib.loads(CALIBRATIONS[name].read_text())
        return [np.asarray(data[k]["rotation"]) for k in data if k != "metadata"]
    return [rig.R[v] for v in range(rig.num_views)]


# ---------------------------------------------------------------------------------------------------------------
# Projection


@pytest.mark.parametrize("name", list(CALIBRATIONS))
def test_projection_matches_opencv(name):
    rig = IO.load_calibration(CALIBRATIONS[name])
    rng = np.random.default_rng(0)
    rvecs = _rvecs_as_stored(name, rig)
    with enable_x64(True):
        for v in range(rig.num_views):
            X = _points_in_front(rig, v, 500, rng)
            ours = np.asarray(project(rig, X))[v]
            ref, _ = cv2.projectPoints(X, rvecs[v], rig.t[v], rig.K[v], rig.dist[v])
            assert np.max(np.abs(ours - ref[:, 0])) < 1e-3
    # float32 (the default) stays within a hundredth of a pixel on real calibrations
    X = _points_in_front(rig, 0, 500, rng)
    ours32 = np.asarray(project(rig, X.astype(np.float32)))[0]
    assert ours32.dtype == np.float32
    ref, _ = cv2.projectPoints(X, rvecs[0], rig.t[0], rig.K[0], rig.dist[0])
    assert np.max(np.abs(ours32 - ref[:, 0])) < 1e-2


def test_projection_depth_and_camera_frame():
    rig = IO.load_calibration(CALIBRATIONS["caliscope"])
    X = _points_in_front(rig, 2, 50, np.random.default_rng(1))
    with enable_x64(True):
        uv, depth = project_with_depth(rig, X)
        Xc = np.asarray(world_to_camera(rig, X))
        centres = np.asarray(C.camera_centres(rig))
    assert uv.shape == (4, 50, 2) and depth.shape == (4, 50) and Xc.shape == (4, 50, 3)
    np.testing.assert_allclose(Xc, np.einsum("vij,pj->vpi", rig.R, X) + rig.t[:, None], atol=1e-12)
    np.testing.assert_allclose(depth, Xc[..., 2], atol=1e-12)
    # the centre maps to the camera-frame origin
    np.testing.assert_allclose(np.einsum("vij,vj->vi", rig.R, centres) + rig.t, 0.0, atol=1e-12)


def test_skew_follows_bouguet_model():
    """u = fx·a_d + alpha_c·fx·b_d + cx (Bouguet); distorted normalised coordinates from OpenCV with K = I."""
    rng = np.random.default_rng(2)
    rvec, tvec = np.array([0.1, -0.2, 0.05]), np.array([0.1, 0.2, 3.0])
    dist = np.array([-0.3, 0.12, 0.001, -0.002, 0.01])
    K = np.array([[600.0, 600.0 * 0.01, 320.0], [0.0, 610.0, 240.0], [0.0, 0.0, 1.0]])
    rig = C.from_opencv(K, dist, rvec, tvec)
    X = rng.uniform(-0.5, 0.5, (40, 3))
    nd, _ = cv2.projectPoints(X, rvec, tvec, np.eye(3), dist)
    ad, bd = nd[:, 0, 0], nd[:, 0, 1]
    expected = np.stack([K[0, 0] * ad + K[0, 1] * bd + K[0, 2], K[1, 1] * bd + K[1, 2]], -1)
    with enable_x64(True):
        np.testing.assert_allclose(np.asarray(project(rig, X))[0], expected, atol=1e-9)


def _parsec_reference():
    """Camera eyes, cylinder poses and projected corners of frame 0 from the PARSEC bodytrack reference run."""
    text = (CALIB / "parsec" / "probe_frame0.txt").read_text()
    pose_block = text.split("POSE InitialPose.txt")[1].split("\nPOSE")[0].split("LAYER")[0]
    eyes = np.array([[float(x) for x in m.split(",")] for m in re.findall(r"eye=([-\d.,e]+)", text)])
    cyl = {}
    for m in re.finditer(r"CYL (\d+) bottom=(\S+) top=(\S+) length=(\S+) pose3x4=(\S+)", pose_block):
        M = np.array([float(x) for x in m.group(5).split(",")]).reshape(3, 4)
        cyl[int(m.group(1))] = (float(m.group(2)), float(m.group(3)), float(m.group(4)), M)
    proj = {}
    for m in re.finditer(r"PROJ cam(\d) part(\d+) ((?:\([-\d.,e]+\) ?){4})", pose_block):
        pts = re.findall(r"\(([-\d.,e]+)\)", m.group(3))
        proj[(int(m.group(1)) - 1, int(m.group(2)))] = np.array(
            [[float(a) for a in p.split(",")] for p in pts]
        )
    return eyes, cyl, proj


def test_parsec_reference_projections():
    """PARSEC's C++ tracker projected 4 corners of each of 10 cylinders into 4 cameras (mm world); we agree."""
    rig = parsec.load_parsec_calibration(CALIB / "parsec" / "CALIB", units="mm")
    eyes, cyl, proj = _parsec_reference()
    assert len(proj) == 40
    with enable_x64(True):
        np.testing.assert_allclose(np.asarray(C.camera_centres(rig)), eyes, atol=5e-3)
        np.testing.assert_allclose(C.camera_centres_host(rig), eyes, atol=5e-3)  # the host form too
        worst = 0.0
        for (v, part), ref in proj.items():
            bottom, top, length, M = cyl[part]
            A, b = M[:, :3], M[:, 3]
            # silhouette corners in the cylinder's (scaled) frame, facing the camera eye (ImageProjection.cpp)
            r = np.array([0.0, 0.0, length / 2]) - np.linalg.solve(A, eyes[v] - b)
            r2 = np.array([-r[1], r[0], 0.0]) / np.hypot(r[0], r[1])
            tip = np.array([0.0, 0.0, length])
            local = np.stack([-bottom * r2, -top * r2 + tip, top * r2 + tip, bottom * r2])
            uv = np.asarray(project(rig, local @ A.T + b))[v]
            worst = max(worst, float(np.max(np.abs(uv - ref))))
    assert worst < 1e-3  # the reference is float32, printed to ~9 digits


def test_in_view():
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    rig = C.from_opencv(K, [-0.3, 0, 0, 0, 0], np.zeros(3), np.zeros(3), image_size=[(640, 480)])
    # inside; behind the camera (mirrors into the image); past the fold of r(1 + k1 r²) at r² = 1/(3·0.3),
    # where r = 1.5 lands back at 0.49 normalised = 245 px from the centre: inside the picture, yet not visible
    X = np.array([[0.1, 0.05, 2.0], [-0.1, -0.05, -2.0], [1.5, 0.0, 1.0], [0.0, 2.0, 1.0]])
    uv = np.asarray(project(rig, X))[0]
    assert 0 <= uv[1, 0] < 640 and 0 <= uv[2, 0] < 640  # the two traps do land in the image
    np.testing.assert_array_equal(np.asarray(in_view(rig, X))[0], [True, False, False, False])


# ---------------------------------------------------------------------------------------------------------------
# Undistortion and triangulation


@pytest.mark.parametrize("name", ["caliscope", "parsec", "opencv_left"])
def test_undistort_matches_opencv(name):
    rig = IO.load_calibration(CALIBRATIONS[name])
    rng = np.random.default_rng(3)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    with enable_x64(True):
        for v in range(rig.num_views):
            w, h = rig.image_size[v]
            uv = np.stack([rng.uniform(0, w - 1, 300), rng.uniform(0, h - 1, 300)], -1)
            ref = cv2.undistortPointsIter(uv[:, None], rig.K[v], rig.dist[v], None, None, crit)[:, 0]
            full = np.zeros((300, rig.num_views, 2))
            full[:, v] = uv
            ours = np.asarray(undistort_points(rig, full))[:, v]
            assert np.max(np.abs(ours - ref)) < 1e-9
            # and it inverts the projection exactly
            X = _points_in_front(rig, v, 100, rng)
            Xc = np.asarray(world_to_camera(rig, X))[v]
            back = np.asarray(undistort_points(rig, np.asarray(project(rig, X)).transpose(1, 0, 2)))[:, v]
            np.testing.assert_allclose(back, Xc[:, :2] / Xc[:, 2:], atol=1e-10)


def test_triangulation_matches_opencv():
    rig = C.select(IO.load_calibration(CALIBRATIONS["pose2sim"]), [0, 1])
    rng = np.random.default_rng(4)
    X = rng.uniform([-1.0, -1.0, 0.0], [1.0, 1.0, 2.0], (200, 3))
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    with enable_x64(True):
        uv = np.asarray(project(rig, X)).transpose(1, 0, 2)  # (P, V, 2)
        np.testing.assert_allclose(np.asarray(triangulate(rig, uv)), X, atol=1e-9)
        noisy = uv + rng.normal(0.0, 2.0, uv.shape)
        ours = np.asarray(triangulate(rig, noisy))
    und = [
        cv2.undistortPointsIter(noisy[:, v, None], rig.K[v], rig.dist[v], None, None, crit)[:, 0]
        for v in (0, 1)
    ]
    Ps = [np.hstack([rig.R[v], rig.t[v, :, None]]) for v in (0, 1)]
    h = cv2.triangulatePoints(Ps[0], Ps[1], und[0].T, und[1].T)
    ref = (h[:3] / h[3]).T
    assert np.max(np.abs(ours - ref)) < 1e-8
    assert 1e-4 < np.median(np.linalg.norm(ours - X, axis=-1)) < 2e-2  # the noise does move the points


def test_triangulation_weights_drop_views():
    rig = IO.load_calibration(CALIBRATIONS["caliscope"])
    rng = np.random.default_rng(5)
    X = rng.uniform(-0.3, 0.3, (50, 3)) + np.array([0.0, 0.0, 0.5])
    with enable_x64(True):
        uv = np.asarray(project(rig, X)).transpose(1, 0, 2) + rng.normal(0, 1.0, (50, 4, 2))
        w = np.array([1.0, 0.0, 1.0, 1.0])
        dropped = np.asarray(triangulate(rig, uv, w))
        sub = np.asarray(triangulate(C.select(rig, ["cam_0", "cam_2", "cam_3"]), uv[:, [0, 2, 3]]))
        np.testing.assert_allclose(dropped, sub, atol=1e-10)
        one = np.asarray(triangulate(rig, uv, np.array([0.0, 1.0, 0.0, 0.0])))
    assert np.all(np.isnan(one))


def test_caliscope_charuco_reprojection():
    """Corners seen by >= 2 cameras, triangulated from camera_array.toml and reprojected (caliscope: 0.46 px)."""
    rig = IO.load_calibration(CALIBRATIONS["caliscope"])
    d = np.genfromtxt(CALIB / "caliscope" / "xy.csv", delimiter=",", names=True)
    assert len(d) == 1725
    keys = sorted({(int(s), int(k)) for s, k in zip(d["sync_index"], d["keypoint_id"], strict=True)})
    index = {k: i for i, k in enumerate(keys)}
    views = [rig.names.index(f"cam_{int(c)}") for c in d["cam_id"]]
    uv = np.zeros((len(keys), rig.num_views, 2))
    w = np.zeros((len(keys), rig.num_views))
    for row, v in zip(d, views, strict=True):
        i = index[(int(row["sync_index"]), int(row["keypoint_id"]))]
        uv[i, v] = row["img_loc_x"], row["img_loc_y"]
        w[i, v] = 1.0
    multi = w.sum(1) >= 2
    with enable_x64(True):
        X = triangulate(rig, uv[multi], w[multi])
        re_uv = np.asarray(project(rig, X)).transpose(1, 0, 2)  # (Q, V, 2)
    err = np.linalg.norm(re_uv - uv[multi], axis=-1)[w[multi] > 0]
    assert len(err) > 1700
    assert np.median(err) < 1.0


def test_pose2sim_trc_reprojects_onto_openpose_keypoints():
    """Pose2Sim's triangulated .trc, projected through its calibration, lands on the BODY_25B detections."""
    rig = IO.load_calibration(CALIBRATIONS["pose2sim"])
    names, pos, fps = load_trc(P2S / "S00_P00_T01_BalancingTrial_0-100.trc")
    assert pos.shape == (100, 21, 3) and fps == 60.0
    # marker name -> BODY_25B column, from the (commented) BODY_25B skeleton in Pose2Sim's Config.toml
    config = (P2S / "Config_a948c20.toml").read_text()
    mapping = {n: int(i) for i, n in re.findall(r"#\s*id\s*=\s*(\d+)\s*\n#\s*name\s*=\s*\"(\w+)\"", config)}
    for name, i in mapping.items():
        assert BODY_25B_KEYPOINTS[i] == {"Neck": "UpperNeck", "Head": "HeadTop"}.get(name, name)
    idx = [mapping[n] for n in names]
    kp = np.stack(
        [load_openpose_folder(P2S / "pose" / f"cam0{c}_json", frames=range(10)) for c in range(1, 5)], 1
    )  # (10,V,25,3)
    assert kp.shape == (10, 4, 25, 3)
    with enable_x64(True):
        uv = np.asarray(project(rig, pos[:10]))  # (10, V, 21, 2)
    obs = kp[:, :, idx]
    err = np.linalg.norm(uv - obs[..., :2], axis=-1)
    for v in range(4):
        ok = obs[:, v, :, 2] > 0.3
        assert ok.sum() > 100
        assert np.median(err[:, v][ok]) < 25.0


# ---------------------------------------------------------------------------------------------------------------
# Gradients, batching, compilation


def test_projection_gradients():
    rig = IO.load_calibration(CALIBRATIONS["caliscope"])
    X = _points_in_front(rig, 0, 6, np.random.default_rng(6), depth=(1.0, 3.0))
    with enable_x64(True):
        rig64 = rig.to_jax(jnp.float64)
        check_grads(lambda X: project(rig64, X), (jnp.asarray(X),), order=1, modes=["fwd", "rev"])
        check_grads(lambda r: project(r, X), (rig64,), order=1, modes=["fwd", "rev"])


def test_batched_particles_jit_and_no_recompilation():
    rig = C.select(IO.load_calibration(CALIBRATIONS["pose2sim"]), [0, 2]).to_jax()
    traces = []

    @jax.jit
    def f(rig, X):
        traces.append(1)
        return jax.vmap(lambda x: project_with_depth(rig, x))(X)

    X = jax.random.uniform(jax.random.key(0), (10_000, 600, 3), minval=-1.0, maxval=1.0) + jnp.array(
        [0, 0, 1.0]
    )
    uv, depth = f(rig, X)
    assert uv.shape == (10_000, 2, 600, 2) and depth.shape == (10_000, 2, 600)
    assert uv.dtype == jnp.float32
    for n in (0, 4321, 9999):
        np.testing.assert_allclose(uv[n], project(rig, X[n]), rtol=1e-6, atol=1e-3)
    moved = C.Rig(
        K=rig.K * 1.01, dist=rig.dist, R=rig.R, t=rig.t + 0.1, names=rig.names, image_size=rig.image_size
    )
    f(moved, X + 0.01)
    assert len(traces) == 1


# ---------------------------------------------------------------------------------------------------------------
# Rig helpers and calibration files


def test_from_opencv_select_and_names():
    rig = IO.load_calibration(CALIBRATIONS["pose2sim"])
    data = tomllib.loads(CALIBRATIONS["pose2sim"].read_text())
    rv = np.array([data[k]["rotation"] for k in data if k != "metadata"])
    again = C.from_opencv(rig.K, rig.dist[:, :4], rv, rig.t, names=rig.names, image_size=rig.image_size)
    np.testing.assert_allclose(again.R, rig.R, atol=1e-15)
    np.testing.assert_allclose(again.R, np.stack([cv2.Rodrigues(r)[0] for r in rv]), atol=1e-12)
    assert rig.num_views == 4 and rig.names == ("cam_01", "cam_02", "cam_03", "cam_04")
    assert rig.image_size == ((1088, 1920),) * 4
    sub = C.select(rig, ["cam_03", 0])
    assert sub.names == ("cam_03", "cam_01") and sub.num_views == 2
    np.testing.assert_array_equal(sub.K, rig.K[[2, 0]])
    with pytest.raises(ValueError):
        C.from_opencv(np.eye(3), [0.1, 0, 0, 0, 0, 0.2, 0, 0], np.zeros(3), np.zeros(3))


def test_scale_images_matches_cv2_resize():
    """A blob rendered at the projection of a point, shrunk with cv2.resize, has its centroid at the projection
    through the scaled rig (pixel-centre convention)."""
    rig = IO.load_calibration(CALIBRATIONS["opencv_left"])
    X = np.array([[0.05, -0.03, 1.0]])
    with enable_x64(True):
        u, v = np.asarray(project(rig, X))[0, 0]
        for f in (0.5, 0.25):
            small_rig = C.scale_images(rig, f)
            yy, xx = np.mgrid[0:480, 0:640]
            img = np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * 6.0**2))
            small = cv2.resize(img, None, fx=f, fy=f, interpolation=cv2.INTER_AREA)
            assert small.shape[::-1] == small_rig.image_size[0]
            ys, xs = np.mgrid[0 : small.shape[0], 0 : small.shape[1]]
            centroid = np.array([(xs * small).sum(), (ys * small).sum()]) / small.sum()
            np.testing.assert_allclose(np.asarray(project(small_rig, X))[0, 0], centroid, atol=1e-3)
        back = C.scale_images(C.scale_images(rig, 0.5), 2.0)
        np.testing.assert_allclose(back.K, rig.K, atol=1e-12)


def test_opencv_files():
    left = IO.load_calibration(CALIBRATIONS["opencv_left"])
    assert left.image_size == ((640, 480),)
    np.testing.assert_allclose(left.K[0, 0, 0], 5.3591573396163199e02)
    np.testing.assert_allclose(left.R[0], np.eye(3))
    stereo = IO.load_calibration(CALIBRATIONS["opencv_stereo"])
    assert stereo.num_views == 2
    np.testing.assert_allclose(stereo.dist[1], [-1.6916358306948096e-01, -1.1214173641213163e-01, 0, 0, 0])


def test_opencv_stereo_extrinsics_and_xml(tmp_path):
    """R T from a sibling extrinsics file written by cv2.FileStorage (as the stereo_calib sample does), and XML."""
    rvec, T = np.array([0.01, -0.2, 0.03]), np.array([-3.3, 0.04, 0.05])
    for ext in ("yml", "xml"):
        d = tmp_path / ext
        d.mkdir()
        fs = cv2.FileStorage(str(d / f"intrinsics.{ext}"), cv2.FILE_STORAGE_WRITE)
        for i in (1, 2):
            fs.write(f"M{i}", np.array([[500.0 + i, 0, 320], [0, 501, 240], [0, 0, 1]]))
            fs.write(f"D{i}", np.array([[0.1 * i, -0.01, 0, 0, 0]]))
        fs.release()
        fs = cv2.FileStorage(str(d / f"extrinsics.{ext}"), cv2.FILE_STORAGE_WRITE)
        fs.write("R", cv2.Rodrigues(rvec)[0])
        fs.write("T", T[:, None])
        fs.release()
        rig = IO.load_calibration(d / f"intrinsics.{ext}")
        np.testing.assert_allclose(rig.R[1], cv2.Rodrigues(rvec)[0], atol=1e-15)
        np.testing.assert_allclose(rig.t[1], T)
        np.testing.assert_allclose(rig.K[1, 0, 0], 502.0)
        np.testing.assert_allclose(rig.dist[0], [0.1, -0.01, 0, 0, 0])
        scaled = IO.load_opencv_storage(d / f"intrinsics.{ext}", translation_scale=0.025)
        np.testing.assert_allclose(scaled.t[1], 0.025 * T)


def test_qualisys_matches_pose2sim_conversion():
    """The QCA file read directly equals Pose2Sim's own conversion of it, except that Pose2Sim divided the
    distortion coefficients by 64; the undivided values are the ones a fresh OpenCV calibration of these cameras
    finds (k1 ≈ −0.05, k2 ≈ 0.15), so they are kept."""
    qca = IO.load_calibration(CALIBRATIONS["qualisys"])
    p2s = IO.load_calibration(CALIBRATIONS["pose2sim"])
    np.testing.assert_allclose(qca.K, p2s.K, atol=1e-9)
    np.testing.assert_allclose(qca.R, p2s.R, atol=1e-12)
    np.testing.assert_allclose(qca.t, p2s.t, atol=1e-12)
    np.testing.assert_allclose(qca.dist, 64.0 * p2s.dist, atol=1e-9)
    assert qca.image_size == p2s.image_size


def test_parsec_units():
    m = parsec.load_parsec_calibration(CALIB / "parsec" / "CALIB")
    mm = parsec.load_parsec_calibration(sorted((CALIB / "parsec" / "CALIB").glob("*.cal")), units="mm")
    assert m.names == ("Camera1", "Camera2", "Camera3", "Camera4") and m.image_size == ((640, 480),) * 4
    np.testing.assert_allclose(m.t * 1000.0, mm.t)
    np.testing.assert_allclose(mm.t[0], [206.1183200800, -197.3226847369, 4524.5364798878])
    K0 = [[584.2422154909, 0, 332.0840069600], [0, 583.3105673832, 228.5791724770], [0, 0, 1]]
    np.testing.assert_allclose(m.K[0], K0)
    np.testing.assert_allclose(m.dist[0], [-0.3172978596, 0.1387289551, 0, 0, 0])
    with enable_x64(True):
        X = _points_in_front(m, 1, 20, np.random.default_rng(7))
        np.testing.assert_allclose(project(m, X), project(mm, X * 1000.0), atol=1e-9)


@pytest.mark.parametrize("name", ["pose2sim", "caliscope", "parsec", "qualisys", "opencv_stereo"])
def test_save_round_trip(name, tmp_path):
    rig = IO.load_calibration(CALIBRATIONS[name])
    out = tmp_path / "calib.toml"
    IO.save_calibration(out, rig)
    back = IO.load_calibration(out)
    assert back.names == rig.names and back.image_size == rig.image_size
    for a, b in ((back.K, rig.K), (back.dist, rig.dist), (back.R, rig.R), (back.t, rig.t)):
        np.testing.assert_allclose(a, b, atol=1e-12)
    # a Pose2Sim/OpenCV user needs nothing but the file and cv2.projectPoints
    data = tomllib.loads(out.read_text())
    X = _points_in_front(rig, 0, 20, np.random.default_rng(8))
    cam = data[rig.names[0]]
    rvec, tvec, K, dist = (np.array(cam[k]) for k in ("rotation", "translation", "matrix", "distortions"))
    ref, _ = cv2.projectPoints(X, rvec, tvec, K, dist)
    with enable_x64(True):
        np.testing.assert_allclose(np.asarray(project(rig, X))[0], ref[:, 0], atol=1e-6)


def test_errors_name_file_and_line(tmp_path):
    cal = (CALIB / "parsec" / "CALIB" / "Camera1.cal").read_text().splitlines()
    bad = tmp_path / "Camera1.cal"
    bad.write_text("\n".join(cal[:6] + ["0.13x"] + cal[7:]))
    with pytest.raises(MocapInputError) as e:
        IO.load_calibration(bad)
    assert e.value.line == 7 and str(bad) in str(e.value)
    bad.write_text("\n".join(cal[:20]))
    with pytest.raises(MocapInputError, match="truncated"):
        IO.load_calibration(bad)
    toml = CALIBRATIONS["pose2sim"].read_text().replace("translation = [ -0.79", "transl = [ -0.79")
    (tmp_path / "c.toml").write_text(toml)
    with pytest.raises(MocapInputError, match="translation") as e:
        IO.load_calibration(tmp_path / "c.toml")
    assert e.value.line == 19  # the [cam_03] header
    (tmp_path / "c.toml").write_text(
        CALIBRATIONS["pose2sim"].read_text().replace("fisheye = false", "fisheye = true")
    )
    with pytest.raises(MocapInputError, match="fisheye"):
        IO.load_calibration(tmp_path / "c.toml")
    (tmp_path / "s.yml").write_text(
        CALIBRATIONS["opencv_stereo"].read_text().replace("cols: 3", "cols: 4", 1)
    )
    with pytest.raises(MocapInputError):
        IO.load_calibration(tmp_path / "s.yml")
    with pytest.raises(MocapInputError):
        IO.load_calibration(tmp_path / "missing.toml")


# ---------------------------------------------------------------------------------------------------------------
# Keypoint files


def test_trc_reader_against_numpy():
    path = P2S / "S00_P00_T01_BalancingTrial_0-100.trc"
    names, pos, fps = load_trc(path)
    raw = np.loadtxt(path, skiprows=5, delimiter="\t", usecols=range(2, 2 + 63))
    assert raw.shape == (100, 63)
    trc = raw.reshape(100, 21, 3)
    np.testing.assert_array_equal(pos, trc[..., [2, 0, 1]])
    assert names[13] == "Head" and names[2] == "RAnkle"
    # z-up: the head is above the ankles in every frame
    assert np.all(pos[:, 13, 2] > pos[:, 2, 2] + 1.0)
    _, stored, _ = load_trc(path, y_up=False)
    np.testing.assert_array_equal(stored, trc)


def test_openpose_person_selection():
    path = P2S / "pose" / "cam01_json" / "cam01.0000.json"
    import json

    people = json.loads(path.read_text())["people"]
    assert len(people) > 1
    first = load_openpose_json(path)
    np.testing.assert_array_equal(first, np.reshape(people[0]["pose_keypoints_2d"], (25, 3)))
    best = int(np.argmax([np.sum(p["pose_keypoints_2d"][2::3]) for p in people]))
    np.testing.assert_array_equal(
        load_openpose_json(path, "most_confident"), np.reshape(people[best]["pose_keypoints_2d"], (25, 3))
    )
    np.testing.assert_array_equal(load_openpose_json(path, 99), np.zeros((25, 3)))


# ---------------------------------------------------------------------------------------------------------------
# Fuzzing: a corrupted file gives a Rig or a MocapInputError, nothing else


FUZZ_FILES = {
    "opencv_left": (CALIBRATIONS["opencv_left"], ".yml"),
    "opencv_stereo": (CALIBRATIONS["opencv_stereo"], ".yml"),
    "pose2sim": (CALIBRATIONS["pose2sim"], ".toml"),
    "caliscope": (CALIBRATIONS["caliscope"], ".toml"),
    "parsec": (CALIB / "parsec" / "CALIB" / "Camera2.cal", ".cal"),
    "qualisys": (CALIBRATIONS["qualisys"], ".qca.txt"),
    "trc": (P2S / "S00_P00_T01_BalancingTrial_0-100.trc", ".trc"),
    "openpose": (P2S / "pose" / "cam02_json" / "cam02.0003.json", ".json"),
}


@st.composite
def _corruption(draw, data: bytes):
    kind = draw(st.sampled_from(["truncate", "replace", "insert", "delete", "several"]))
    n = len(data)
    if kind == "truncate":
        return data[: draw(st.integers(0, n - 1))]
    if kind == "delete":
        i = draw(st.integers(0, n - 1))
        return data[:i] + data[i + draw(st.integers(1, 40)) :]
    tokens = [b"[", b"]", b"=", b",", b"\n", b"-", b"e9", b"nan", b"inf", b'"', b":", b"<", b"0", b"1e400"]
    chars = st.binary(min_size=1, max_size=4) | st.sampled_from(tokens)
    out = data
    for _ in range(draw(st.integers(2, 6)) if kind == "several" else 1):
        i = draw(st.integers(0, len(out) - 1))
        c = draw(chars)
        out = out[:i] + c + out[i + (len(c) if kind != "insert" else 0) :]
    return out


def _load_any(name, path):
    if name == "trc":
        return load_trc(path)
    if name == "openpose":
        return load_openpose_json(path)
    return IO.load_calibration(path)


@pytest.mark.parametrize("name", list(FUZZ_FILES))
def test_parsers_fuzz(name):
    src, suffix = FUZZ_FILES[name]
    data = src.read_bytes()
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "file" + suffix)

        @settings(
            max_examples=120, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
        )
        @given(_corruption(data))
        def run(bad):
            with open(path, "wb") as f:
                f.write(bad)
            try:
                out = _load_any(name, path)
            except MocapInputError as e:
                assert str(path) in str(e)
                return
            if isinstance(out, C.Rig):
                for a in (out.K, out.dist, out.R, out.t):
                    assert np.all(np.isfinite(a))

        run()


@pytest.mark.parametrize("mode", ["fwd", "rev"])
def test_pixel_jacobian_matches_opencv(mode):
    """The written-out derivative of the projection (``pixels_from_camera``'s own JVP) in the camera-frame point:
    OpenCV's ``projectPoints`` Jacobian in ``tvec`` for the object point at the origin (``x_c = tvec``), with all five
    distortion coefficients; and in the distortion coefficients (the automatic derivative there)."""
    rng = np.random.default_rng(3)
    K = np.array([[420.0, 0.0, 161.0], [0.0, 415.0, 118.0], [0.0, 0.0, 1.0]])
    dist = np.array([-0.21, 0.08, 0.0013, -0.0021, -0.012])
    pts = np.column_stack([rng.uniform(-0.6, 0.6, 20), rng.uniform(-0.5, 0.5, 20), rng.uniform(1.5, 4.0, 20)])
    jac = jax.jacfwd if mode == "fwd" else jax.jacrev
    with enable_x64(True):
        rig = C.from_opencv(K[None], dist[None], np.eye(3)[None], np.zeros((1, 3)), image_size=[(320, 240)])
        rig = rig.to_jax(jnp.float64)

        def pixel(xc, rig=rig):  # (3,) camera-frame point -> (2,) pixel
            return C.pixels_from_camera(rig, *(xc[i].reshape(1, 1) for i in range(3)))[0][0, 0]

        for X in pts:
            uv, J = cv2.projectPoints(np.zeros((1, 3)), np.zeros(3), X, K, dist)
            J = J.reshape(2, -1)
            np.testing.assert_allclose(np.asarray(pixel(jnp.asarray(X))), uv.reshape(2), rtol=1e-12)
            np.testing.assert_allclose(
                np.asarray(jac(pixel)(jnp.asarray(X))), J[:, 3:6], rtol=1e-9, atol=1e-9
            )
        # in the distortion coefficients, at the last point
        Jd = jac(lambda d: pixel(jnp.asarray(X), dataclasses.replace(rig, dist=d[None])))(jnp.asarray(dist))
        np.testing.assert_allclose(np.asarray(Jd), J[:, 10:15], rtol=1e-9, atol=1e-9)
