"""PARSEC bodytrack parity: inputs, the 31-DOF body, cylinder projection, edge maps and the likelihood.

References: the values measured with the unmodified bodytrack C++ code on sequenceB_2 (``tests/data/parsec``,
see PROVENANCE.md there), OpenCV's ``projectPoints`` and closed forms.
"""

import os
import pathlib
import re
import shutil
import signal
import time
import warnings

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap import host, parsec  # also registers the parsec31 body with jaxmocap.geometry.body
from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import body
from jaxmocap.parsec import cylinders
from jaxmocap.parsec import likelihood as pl
from jaxmocap.parsec.inputs import ParsecSource

DATA = pathlib.Path(__file__).parents[1] / "data" / "parsec"
PROBE_POSES = ("InitialPose.txt", "poses.txt line 0", "poses.txt line 1")


def _parse_probe(path):
    """``{pose name: dict(errors=(edge, inside, loglik), cyl (10, 3, 4), proj (4, 10, 4, 2))}`` and the cameras."""
    out, cams, cur = {}, {}, None
    for line in pathlib.Path(path).read_text().splitlines():
        if line.startswith("CAM "):
            k = int(line.split()[1])
            cams[k] = np.asarray([float(v) for v in line.split("eye=")[1].split(",")])
        elif line.startswith("POSE"):
            m = re.search(r"edge_err=(\S+) inside_err=(\S+) loglik=(\S+)", line)
            cur = dict(errors=tuple(float(v) for v in m.groups()), cyl=[], proj=[])
            out[line[5:].split(" valid")[0]] = cur
        elif "CYL" in line and cur is not None:
            cur["cyl"].append([float(v) for v in line.split("pose3x4=")[1].split(",")])
        elif "PROJ" in line and cur is not None:
            cur["proj"].append([float(v) for p in re.findall(r"\(([^,]+),([^)]+)\)", line) for v in p])
    for v in out.values():
        v["cyl"] = np.asarray(v["cyl"]).reshape(10, 3, 4)
        v["proj"] = np.asarray(v["proj"]).reshape(4, 10, 4, 2)
    return out, cams


def _png(path):
    im = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert im is not None, path
    return im


@pytest.fixture(scope="module")
def pdata():
    d = DATA
    seq = d / "sequenceB_2"
    probes = [_parse_probe(d / "reference" / f"probe_frame{f}.txt") for f in (0, 1)]
    poses = parsec.load_poses(d / "reference" / "poses_4000p5l.txt")
    states = dict(
        zip(PROBE_POSES, [parsec.load_pose(seq / "InitialPose.txt"), poses[0], poses[1]], strict=True)
    )
    frames = [
        (
            np.stack([_png(d / "frames" / f"cam{k}_f{f:04d}.png") for k in range(1, 5)]),
            np.stack([_png(d / "frames" / f"fg{k}_f{f:04d}.png") for k in range(1, 5)]),
        )
        for f in (0, 1)
    ]
    return dict(
        dir=d,
        seq=seq,
        probes=probes,
        states=states,
        shape=parsec.load_body_shape(seq / "BodyShapeParameters.txt"),
        cams=parsec.load_cameras(seq),
        frames=frames,
        edge_ref=np.stack([_png(d / "reference" / f"edge_cam{k}_f0000.png") for k in range(1, 5)]),
        fg_ref=np.stack([_png(d / "reference" / f"fgbin_cam{k}_f0000.png") for k in range(1, 5)]),
    )


@pytest.fixture(scope="module")
def loglik_fn(pdata):
    """The float32 batch log-likelihood the filters use, compiled once for the module: always 8 particles."""
    return jax.jit(pl.make_loglik_batch(pdata["shape"], pdata["cams"]))


@pytest.fixture(scope="module")
def probe_corners(pdata):
    """float32 projected corners ``(3, V, 10, 4, 2)`` of the three probe states, by the likelihood's own path."""
    X = jnp.asarray(np.stack([pdata["states"][n] for n in PROBE_POSES]), jnp.float32)
    return jax.jit(jax.vmap(lambda x: pl.corners(pdata["shape"], pdata["cams"], x)[1]))(X)


@pytest.fixture(scope="module")
def corners_fn():
    """:func:`terms_from_corners` compiled once per number of cameras."""
    return jax.jit(pl.terms_from_corners, static_argnames="config")


def _eight(pdata, scale=1.0, seed=2):
    """The three probe states then five perturbed ones, float32 ``(8, 31)``."""
    x0 = pdata["states"]["InitialPose.txt"]
    std = parsec.load_pose_parameters(pdata["seq"] / "PoseParameters.txt").std
    X = x0 + np.random.default_rng(seed).normal(size=(5, 31)) * std * scale
    return jnp.asarray(np.concatenate([np.stack([pdata["states"][n] for n in PROBE_POSES]), X]), jnp.float32)


# ---------------------------------------------------------------------------------------------------------------
# Inputs


def test_text_inputs_match_the_documented_values(pdata):
    shape = pdata["shape"]
    np.testing.assert_allclose(shape.limbs[0], [160, 160, 0.883801457794, 1.0])
    np.testing.assert_allclose(shape.limbs[9], [108.219779804448, 108.219779804448, 1.0, 0.739581901676])
    L = dict(zip(parsec.LENGTH_NAMES, shape.lengths, strict=True))
    np.testing.assert_allclose(
        [L["torso_length"], L["left_thigh_length"], L["head_length"]], [578.6, 424.8, 268.0], atol=0.05
    )
    assert L["length_4"] == L["length_8"] == L["length_12"] == L["length_16"] == 0.0
    x0 = pdata["states"]["InitialPose.txt"]
    assert x0.shape == (31,) and x0[3] == 134.693
    pp = parsec.load_pose_parameters(pdata["seq"] / "PoseParameters.txt")
    np.testing.assert_allclose(pp.std[3:6], [13.73, 17.19, 2.38], atol=0.005)
    np.testing.assert_array_equal(pp.min[3:5], [-1e5, -1e5])
    np.testing.assert_array_equal(pp.max[3:5], [1e5, 1e5])
    poses = parsec.load_poses(pdata["dir"] / "reference" / "poses_4000p5l.txt")
    assert poses.shape == (2, 31)
    # the shipped default body is sequenceB's
    np.testing.assert_array_equal(parsec.default_shape().lengths, shape.lengths)


@pytest.mark.parametrize(
    "loader, text, line",
    [
        (parsec.load_body_shape, "1 2 3\n", 1),  # truncated
        (parsec.load_body_shape, "\n".join(["1"] * 57) + "\nabc\n", 58),
        (parsec.load_body_shape, "\n".join(["1"] * 59) + "\n", 59),  # one number too many
        (parsec.load_pose, " ".join(["0.1"] * 30), 1),
        (parsec.load_pose, " ".join(["0.1"] * 30) + " nan", 1),
        (parsec.load_pose_parameters, "\n".join(["1"] * 92), 92),
        (parsec.load_poses, " ".join(["1"] * 31) + " \n" + " ".join(["1"] * 30) + "\n", 2),
    ],
)
def test_malformed_text_inputs_raise_with_file_and_line(tmp_path, loader, text, line):
    p = tmp_path / "bad.txt"
    p.write_text(text)
    with pytest.raises(MocapInputError) as e:
        loader(p)
    assert e.value.path == str(p) and e.value.line == line
    with pytest.raises(MocapInputError):
        loader(tmp_path / "missing.txt")


def test_bmp_rows_come_top_first_like_bodytrack(pdata):
    """cv2 reads the bottom-up BMP with row 0 at the top, as bodytrack's dumped binary foreground map has it."""
    fg = parsec.load_image(pdata["seq"] / "FG1" / "image0000.bmp")
    ref = pdata["fg_ref"][0] != 0
    np.testing.assert_array_equal(parsec.foreground_map(fg), ref)
    assert not np.array_equal(parsec.foreground_map(fg[::-1]), ref)
    cam = parsec.load_image(pdata["seq"] / "CAM1" / "image0000.bmp")
    np.testing.assert_array_equal(cam, pdata["frames"][0][0][0])
    assert cam.shape == (480, 640) and cam.dtype == np.uint8


def test_load_sequence(pdata, tmp_path):
    """A full sequence folder (CAM1/FG1 frame 0 the original BMPs, the rest written back to BMP)."""
    root = tmp_path / "seq"
    shutil.copytree(pdata["seq"], root)
    for f in (0, 1):
        ims, fgs = pdata["frames"][f]
        for k in range(4):
            for kind, a in (("CAM", ims[k]), ("FG", fgs[k])):
                p = root / f"{kind}{k + 1}" / f"image{f:04d}.bmp"
                p.parent.mkdir(exist_ok=True)
                if not p.exists():
                    assert cv2.imwrite(str(p), a)
    seq = parsec.load_sequence(root)
    assert seq.images.shape == (2, 4, 480, 640) and seq.frames == (0, 1)
    np.testing.assert_array_equal(seq.images[1], pdata["frames"][1][0])
    np.testing.assert_array_equal(seq.foreground[0], (pdata["fg_ref"] != 0).astype(np.uint8))
    np.testing.assert_array_equal(seq.initial_pose, pdata["states"]["InitialPose.txt"])
    np.testing.assert_allclose(seq.pose_std[3], 13.7278869812)
    np.testing.assert_allclose(np.asarray(seq.rig.t) * 1000.0, np.asarray(seq.cameras.T))
    # camera centres: bodytrack's eye positions (float32 in the C++)
    _, cams = pdata["probes"][0]
    np.testing.assert_allclose(seq.cameras.eye, np.stack([cams[k] for k in range(1, 5)]), atol=2e-3)
    np.testing.assert_array_equal(seq.edge_maps(0), pdata["edge_ref"])
    np.testing.assert_array_equal(np.asarray(seq.observation(0).fg), (pdata["fg_ref"] != 0).astype(np.uint8))
    # read frame by frame as `jaxmocap track` reads it (the cameras side by side): the same maps
    source = ParsecSource(root)
    obs = source.observation(0)
    np.testing.assert_array_equal(np.asarray(obs.edge), pdata["edge_ref"])
    np.testing.assert_array_equal(np.asarray(obs.fg), (pdata["fg_ref"] != 0).astype(np.uint8))
    ims, fgs = source.images(1)
    np.testing.assert_array_equal(ims, pdata["frames"][1][0])
    np.testing.assert_array_equal(fgs, seq.foreground[1])
    # a missing camera image names the file
    (root / "FG3" / "image0001.bmp").unlink()
    with pytest.raises(MocapInputError, match="FG3"):
        source.observation(1)
    assert parsec.load_sequence(root).frames == (0,)
    (root / "CAM2" / "image0000.bmp").write_bytes(b"not an image")
    with pytest.raises(MocapInputError, match="CAM2"):
        parsec.load_sequence(root)
    with pytest.raises(MocapInputError, match="CAM2"):
        source.observation(0)


def test_edge_map_equals_bodytrack(pdata):
    """§6.1 edge maps of the 4 frame-0 images against the maps dumped from bodytrack (±1 grey level allowed)."""
    ims = pdata["frames"][0][0]
    for k in range(4):
        e = parsec.edge_map(ims[k])
        diff = np.abs(e.astype(int) - pdata["edge_ref"][k].astype(int))
        assert diff.max() <= 1
        assert np.mean(diff == 0) == 1.0  # in fact bit for bit
    assert parsec.edge_map(ims[0])[:3].max() == 0 and parsec.edge_map(ims[0])[:, -3:].max() == 0


def _edge_map_direct(I, threshold):
    """bodytrack's edge map transcribed directly: float32 Sobel / 8 summed in its term order, threshold, 7-tap row
    then column blur accumulated in float32 in kernel order, each truncated to uint8, zero margins."""
    f = I.astype(np.float32)
    c8, c4 = np.float32(0.125), np.float32(0.25)
    up, mid, dn = f[:-2], f[1:-1], f[2:]
    gx = (
        -c8 * up[:, :-2]
        + c8 * up[:, 2:]
        - c4 * mid[:, :-2]
        + c4 * mid[:, 2:]
        - c8 * dn[:, :-2]
        + c8 * dn[:, 2:]
    )
    gy = (
        -c8 * up[:, :-2]
        - c4 * up[:, 1:-1]
        - c8 * up[:, 2:]
        + c8 * dn[:, :-2]
        + c4 * dn[:, 1:-1]
        + c8 * dn[:, 2:]
    )
    b = np.zeros(I.shape, np.float32)
    b[1:-1, 1:-1] = np.where(gx * gx + gy * gy >= np.float32(threshold), 255.0, 0.0)
    w = parsec.images._BLUR
    H, W = I.shape
    acc = np.zeros((H, W - 6), np.float32)
    for i in range(7):
        acc = acc + b[:, i : i + W - 6] * w[i]
    tmp = np.zeros((H, W), np.float32)
    tmp[:, 3:-3] = acc.astype(np.uint8)
    acc = np.zeros((H - 6, W), np.float32)
    for i in range(7):
        acc = acc + tmp[i : i + H - 6] * w[i]
    out = np.zeros((H, W), np.uint8)
    out[3:-3] = acc.astype(np.uint8)
    return out


@pytest.mark.parametrize("threshold", [16.0, 4.5, 100.0])
def test_edge_map_equals_the_direct_float32_computation(threshold):
    """The integer Sobel and the tabulated row pass give bodytrack's float32 arithmetic bit for bit, on noise, on
    smooth images and on flat ones with steps near the threshold."""
    rng = np.random.default_rng(7)
    smooth = np.cumsum(rng.integers(-3, 4, (60, 80)), axis=1) % 256
    steps = np.tile(np.repeat(np.arange(0, 80, 4) % 7, 4), (60, 1))
    for im in (rng.integers(0, 256, (60, 80)), smooth, steps):
        im = im.astype(np.uint8)
        np.testing.assert_array_equal(parsec.edge_map(im, threshold), _edge_map_direct(im, threshold))


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork")
def test_edge_maps_in_a_forked_child():
    """A child made by ``fork`` after the parent's threads computed maps makes its own threads (the parent's pool
    has no threads there: without its reset the child's first frame would wait for ever)."""
    ims = np.random.default_rng(5).integers(0, 256, (3, 40, 50)).astype(np.uint8)
    want = parsec.images.edge_maps(ims)  # the pool's threads started in this process
    r, w = os.pipe()
    with warnings.catch_warnings():  # JAX warns at every fork once its backends run (this child calls no JAX)
        warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
        pid = os.fork()
    if pid == 0:  # the child: compute, report, leave without running the parent's exit handlers
        try:
            ok = np.array_equal(parsec.images.edge_maps(ims), want)
            os.write(w, b"1" if ok else b"0")
        finally:
            os._exit(0)
    os.close(w)
    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline:
        done, _ = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        time.sleep(0.05)
    else:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        pytest.fail("the forked child's edge maps did not finish")
    assert os.read(r, 1) == b"1"
    os.close(r)


def test_edge_maps_side_by_side_are_the_direct_computation():
    """:func:`edge_maps` (the cameras in threads, each thread's buffers reused) gives every camera the direct
    float32 computation bit for bit, also after images of another size (the buffers remade) and into ``out``."""
    rng = np.random.default_rng(3)
    for shape in ((60, 80), (37, 51), (60, 80)):
        ims = rng.integers(0, 256, (5, *shape)).astype(np.uint8)
        ims[2] = np.tile(np.repeat(np.arange(0, shape[1]) % 7 * 3, 1), (shape[0], 1)).astype(np.uint8)
        got = parsec.images.edge_maps(ims, 16.0)
        assert got.shape == ims.shape and got.dtype == np.uint8
        for k in range(len(ims)):
            np.testing.assert_array_equal(got[k], _edge_map_direct(ims[k], 16.0))
    out = np.full(ims.shape[1:], 77, np.uint8)
    assert parsec.edge_map(ims[0], out=out) is out
    np.testing.assert_array_equal(out, _edge_map_direct(ims[0], 16.0))  # margins zeroed too
    with pytest.raises(ValueError, match="uint8"):
        parsec.edge_map(ims[0], out=np.zeros(ims.shape[1:], np.int32))
    with pytest.raises(ValueError, match="one size"):
        parsec.images.edge_maps([ims[0], ims[0][:-1]])


# ---------------------------------------------------------------------------------------------------------------
# Body model


def test_parsec31_in_metres_is_the_millimetre_body_scaled():
    """The metric build the tracker asks for (``in_metres=True``): PARSEC's radii and lengths over 1000, the same
    chain, for no dimensions as for sequenceB's."""
    mm, m = body.build("parsec31"), body.build("parsec31", in_metres=True)
    assert m.name == "parsec31" and m.topology == mm.topology
    for field in (
        "offset",
        "shape_start",
        "shape_end",
        "radius_start",
        "radius_end",
        "joint_point",
        "rest_pose",
    ):
        np.testing.assert_allclose(
            np.asarray(getattr(m, field)) * 1000.0, getattr(mm, field), rtol=1e-6, atol=1e-4
        )
    np.testing.assert_array_equal(m.offset, body.build("parsec31", {}, in_metres=True).offset)
    np.testing.assert_array_equal(m.offset, parsec.parsec31_in_metres(parsec.default_shape()).offset)


def test_parsec31_is_a_body_model(tmp_path):
    m = body.build("parsec31")
    assert m.num_dofs == 31 and m.dof_names == parsec.DOF_NAMES
    assert m.joint_names == body.EVAL_JOINTS
    assert m.angular.sum() == 28 and not m.angular[3:6].any()
    J = dict(zip(m.joint_names, np.asarray(body.joint_positions(m, m.rest_pose)), strict=True))
    L = dict(zip(parsec.LENGTH_NAMES, parsec.default_shape().lengths, strict=True))
    # standing: the longer leg's ankle on the floor, legs straight down, thorax above the pelvis, left is +y
    assert min(J["left_ankle"][2], J["right_ankle"][2]) == pytest.approx(0.0, abs=1e-3)
    np.testing.assert_allclose(
        J["left_hip"] - J["left_ankle"], [0, 0, L["left_thigh_length"] + L["left_shin_length"]], atol=1e-3
    )
    np.testing.assert_allclose(J["thorax"] - J["root"], [0, 0, L["torso_length"]], atol=1e-3)
    np.testing.assert_allclose(J["left_hip"] - J["root"], [0, L["left_hip_offset"], 0], atol=1e-3)
    np.testing.assert_allclose(J["right_hip"] - J["root"], [0, -L["right_hip_offset"], 0], atol=1e-3)
    np.testing.assert_allclose(J["left_shoulder"] - J["thorax"], [0, L["left_clavicle_length"], 0], atol=1e-3)
    # metres for the rest of the project
    np.testing.assert_allclose(
        parsec.joint_positions_metres(m, m.rest_pose), np.stack(list(J.values())) / 1000.0, rtol=1e-6
    )
    x = parsec.to_metres(m.rest_pose)
    assert float(x[5]) == pytest.approx(float(m.rest_pose[5]) / 1000.0)
    np.testing.assert_allclose(parsec.from_metres(x), m.rest_pose, rtol=1e-6)
    # named dimensions (body files) and gradients to them: d(thorax z)/d(torso length) = 1 upright
    dims = parsec.shape_to_dims(parsec.default_shape())
    assert body.build("parsec31", {"torso_length": 500.0}).offset[6, 2] == pytest.approx(-500.0)
    body.save_body(tmp_path / "b.toml", "parsec31", {**dims, "left_thigh_length": 400.0})
    assert body.load_body(tmp_path / "b.toml").offset[2, 2] == pytest.approx(400.0)  # the knee
    with pytest.raises(ValueError, match="unknown"):
        parsec.parsec31({"torso_lenght": 500.0})
    # the head cylinder starts at the thorax
    g = jax.jit(jax.grad(lambda t: parsec.cylinder_poses({**dims, "torso_length": t}, m.rest_pose)[9, 2, 3]))(
        578.0
    )
    assert float(g) == pytest.approx(1.0)


def test_cylinder_poses_match_bodytrack(pdata):
    """Every cylinder's 3×4 pose at the three probe states: ``cylinder_poses`` and the generic BodyModel FK."""
    probe, _ = pdata["probes"][0]
    shape = pdata["shape"]
    with jax.enable_x64(True):
        model = parsec.parsec31(shape, dtype=jnp.float64)
        for name, x in pdata["states"].items():
            ref = probe[name]["cyl"]
            P = np.asarray(parsec.cylinder_poses(shape, jnp.asarray(x)))
            np.testing.assert_allclose(P[..., :3], ref[..., :3], atol=2e-6)  # rotations, printed to 9 digits
            np.testing.assert_allclose(P[..., 3], ref[..., 3], atol=1e-3)  # mm
            P2 = np.asarray(cylinders._scaled_poses(shape, *body.segment_poses(model, jnp.asarray(x))))
            np.testing.assert_allclose(P2, P, atol=1e-9)
    # float32, the default: same poses to float32 precision
    P32 = parsec.cylinder_poses(shape, jnp.asarray(pdata["states"]["InitialPose.txt"], jnp.float32))
    np.testing.assert_allclose(P32, probe["InitialPose.txt"]["cyl"], atol=2e-3)


def test_fast_sincos_is_accurate():
    x = np.random.default_rng(0).uniform(-60.0, 60.0, 100_000).astype(np.float32)
    s, c = cylinders._sincos(jnp.asarray(x))
    np.testing.assert_allclose(np.asarray(s, np.float64), np.sin(x.astype(np.float64)), atol=1.2e-7)
    np.testing.assert_allclose(np.asarray(c, np.float64), np.cos(x.astype(np.float64)), atol=1.2e-7)


# ---------------------------------------------------------------------------------------------------------------
# Projection


def test_projection_equals_opencv(pdata):
    cams = pdata["cams"]
    rig = parsec.load_parsec_calibration(pdata["seq"], units="mm")
    X = np.random.default_rng(1).uniform([-800, 500, 0], [800, 1500, 1800], (50, 3))
    with jax.enable_x64(True):
        uv = np.asarray(parsec.project(cams, jnp.asarray(X)))
    for v in range(4):
        rvec, _ = cv2.Rodrigues(np.asarray(rig.R[v]))
        ref, _ = cv2.projectPoints(
            X, rvec, np.asarray(rig.t[v]), np.asarray(rig.K[v]), np.asarray(rig.dist[v])
        )
        np.testing.assert_allclose(uv[v], ref[:, 0], atol=1e-8)


def test_projected_corners_match_bodytrack(pdata):
    """Every projected corner of every cylinder in the 4 cameras, 3 states, within 0.01 px (x64)."""
    probe, _ = pdata["probes"][0]
    with jax.enable_x64(True):
        for name, x in pdata["states"].items():
            poses, uv = pl.corners(pdata["shape"], pdata["cams"], jnp.asarray(x))
            np.testing.assert_allclose(np.asarray(uv), probe[name]["proj"], atol=1e-2)
            assert np.abs(np.asarray(uv) - probe[name]["proj"]).max() < 2e-4
            np.testing.assert_allclose(
                np.asarray(parsec.cylinder_corners(pdata["shape"], pdata["cams"], poses)), uv
            )
    # frame 1 reports the same geometry
    probe1, _ = pdata["probes"][1]
    for name in PROBE_POSES:
        np.testing.assert_array_equal(probe1[name]["proj"], probe[name]["proj"])


# ---------------------------------------------------------------------------------------------------------------
# Likelihood


def _obs(pdata, frame):
    if frame == 0:  # bodytrack's own maps
        return pl.observation(pdata["edge_ref"], pdata["fg_ref"])
    ims, fgs = pdata["frames"][frame]
    return pl.observation(np.stack([parsec.edge_map(im) for im in ims]), fgs)


@pytest.mark.parametrize("frame", [0, 1])
def test_likelihood_matches_bodytrack(pdata, loglik_fn, corners_fn, probe_corners, frame):
    """Edge error, inside error and log-likelihood of the three probe states (float32, the filters' path).

    At "poses.txt line 0" one corner of bodytrack's float32 geometry is 227.5 exactly and ours 227.499991, so one
    edge sample reads the neighbouring pixel: 7.7e-5 in frame 0, 3.3e-5 in frame 1. Fed bodytrack's own corners
    the sampling agrees to float rounding.
    """
    probe, _ = pdata["probes"][frame]
    obs = _obs(pdata, frame)
    ll = np.asarray(loglik_fn(_eight(pdata), obs))
    assert np.all(ll > -2.0)
    for i, name in enumerate(PROBE_POSES):
        ref = probe[name]["errors"]
        ssd, ne, bg, ni = corners_fn(probe_corners[i], obs)  # the errors from our corners ...
        ours = (
            float(jnp.sum(ssd)) / 255.0**2 / float(jnp.sum(ne)),
            float(jnp.sum(bg)) / float(jnp.sum(ni)),
            ll[i],
        )
        np.testing.assert_allclose(ours, ref, atol=1e-4)
        if name == "InitialPose.txt":
            np.testing.assert_allclose(ours, ref, atol=1e-7)
        ssd, ne, bg, ni = corners_fn(
            jnp.asarray(probe[name]["proj"], jnp.float32), obs
        )  # ... and from bodytrack's
        edge = float(jnp.sum(ssd)) / 255.0**2 / float(jnp.sum(ne))
        inside = float(jnp.sum(bg)) / float(jnp.sum(ni))
        np.testing.assert_allclose([edge, inside], ref[:2], atol=2e-7)


def test_single_particle_function_agrees_with_the_batch(pdata, loglik_fn, corners_fn):
    """The single-state terms equal the batch's log-likelihood, and their totals (summed as integers in the scan
    over part groups) the per-camera, per-part sums of :func:`terms_from_corners`."""
    obs = _obs(pdata, 0)
    X = _eight(pdata)
    ll = np.asarray(loglik_fn(X, obs))
    one = jax.jit(lambda x, obs: pl.likelihood_terms(pdata["shape"], pdata["cams"], obs, x))
    for i in (0, 5):
        t = one(X[i], obs)
        assert bool(t.valid) and float(t.loglik) == ll[i]
        assert float(t.loglik) == pytest.approx(-(float(t.edge_error) + float(t.inside_error)), abs=1e-7)
        assert 800 < float(t.edge_samples) < 1000 and 1000 < float(t.inside_samples) < 1200
        ssd, ne, bg, ni = (
            np.asarray(a, np.int64)
            for a in corners_fn(pl.corners(pdata["shape"], pdata["cams"], X[i])[1], obs)
        )
        assert (float(t.edge_samples), float(t.inside_samples)) == (ne.sum(), ni.sum())
        assert float(t.edge_error) == pytest.approx(ssd.sum() / 255.0**2 / ne.sum(), rel=1e-6)
        assert float(t.inside_error) == pytest.approx(bg.sum() / ni.sum(), rel=1e-6)
    # a batch larger than max_batch is evaluated in equal chunks (3 of 3 here, padded): the same values, bit for bit
    # as a rule; but the chunked program is another XLA program, and in one ordering of the suite's files (which
    # share compiled programs between processes) one particle of eight came out 7.7e-5 apart, float32 rounding
    # moving a projected sample across a pixel border: at most one particle, by at most one edge sample's share of
    # the error (1 / 800, the least edge sample count asserted above)
    chunked = jax.jit(pl.make_loglik_batch(pdata["shape"], pdata["cams"], pl.Config(max_batch=3)))
    got = np.asarray(chunked(X, obs))
    np.testing.assert_allclose(got, ll, rtol=0, atol=1.0 / 800)
    assert np.sum(got != ll) <= 1
    # a new frame does not recompile
    n = loglik_fn._cache_size()
    loglik_fn(X, _obs(pdata, 1))
    assert loglik_fn._cache_size() == n


@pytest.mark.parametrize("edge_step", [5.0, 1.0])  # 1 px: more than 255 samples a side fit the image
def test_sampling_closed_form(corners_fn, edge_step):
    """One axis-aligned 40×100 px cylinder: sample counts, C truncation toward zero, e2 end excluded."""
    W, H = 640, 480
    cfg = pl.Config(edge_step=edge_step)
    uv = np.full((1, 10, 4, 2), -1000.0, np.float32)  # every other part far outside the image
    # P0 (x0, 100) → P1 (x0, 200); P3 (x0 + 40, 100) → P2 (x0 + 40, 200)
    x0 = -0.9  # int(−0.9 + 0.5) = int(−0.4) = 0: these samples read column 0
    uv[0, 0] = [[x0, 100.0], [x0, 200.0], [x0 + 40, 200.0], [x0 + 40, 100.0]]
    edge = np.zeros((1, H, W), np.uint8)
    edge[0, :, 0] = 255  # side P0→P1 lies on an edge, side P2→P3 (column 39) does not
    fg = np.zeros((1, H, W), np.uint8)
    fg[0, :, :25] = 1  # the inside columns at x0 + 0, 10, 20 are foreground, x0 + 30 is not
    obs = pl.Observation(jnp.asarray(edge), jnp.asarray(fg))
    ssd, ne, bg, ni = (np.asarray(a) for a in corners_fn(uv, obs, config=cfg))
    # edge: n = max(int(100/step + 0.5), 4) → n + 1 samples a side; only side P2→P3 adds 255² a sample
    k = int(100 / edge_step + 0.5) + 1
    assert ne[0, 0] == 2 * k and ssd[0, 0] == k * 255**2
    # inside: n1 = 10 → 11 rows; |mid(P0P1) − mid(P3P2)| = 40 → n2 = 4 columns, the last one at x0 + 30
    assert ni[0, 0] == 44 and bg[0, 0] == 11
    assert ne[0, 1:].sum() == 0 and ni[0, 1:].sum() == 0
    # one column further left every sample leaves the image: int(−1.9 + 0.5) = int(−1.4) = −1
    uv[0, 0, :, 0] -= 1.0
    ssd, ne, bg, ni = (np.asarray(a) for a in corners_fn(uv, obs, config=cfg))
    assert ne[0, 0] == k and ni[0, 0] == 33  # the P0→P1 side and the x0 column are out


@pytest.mark.parametrize("exact_float", [True, False])
def test_pixel_index_is_c_truncation(monkeypatch, exact_float):
    """Both ways of computing a sample's flat pixel index (float arithmetic below 2**23, used for PARSEC's maps,
    and the integer conversion for larger maps) read C's pixel: ``int(x + 0.5)`` truncated toward zero, counted
    only inside the image; NaN and ±inf never count, and a sample not counted reads pixel 0."""
    # the float path is exact while every index stays below 2**23
    fits = pl._exact_float_index
    assert fits(27, 640, 480) and not fits(28, 640, 480) and fits(4, 1920, 1080) and not fits(5, 1920, 1080)
    monkeypatch.setattr(pl, "_exact_float_index", lambda V, W, H: exact_float)
    V, W, H = 3, 640, 480
    edge = [-2.0, -1.5, -1.5000001, -1.4999999, -0.5, -0.50000006, 0.0, 0.49999997, 0.5, 1.3, 318.7]
    edge += [478.5, 479.49997, 479.5, 638.5, 639.49997, 639.5, 640.0, 1e9, -1e9, np.inf, -np.inf, np.nan]
    vals = np.asarray(edge, np.float32)
    x, y = (np.broadcast_to(a.ravel(), (V, vals.size**2)) for a in np.meshgrid(vals, vals))
    offset = pl._offsets(V, W, H, jnp.zeros(x.shape, jnp.float32))
    assert offset.dtype == (jnp.float32 if exact_float else jnp.int32)
    idx, m = (
        np.asarray(a) for a in pl._index(jnp.asarray(x), jnp.asarray(y), offset, W, H, jnp.asarray(True))
    )
    with np.errstate(invalid="ignore"):
        col, row = np.trunc(x + np.float32(0.5)), np.trunc(y + np.float32(0.5))
        inside = (col >= 0) & (col < W) & (row >= 0) & (row < H)
    col, row = np.where(inside, col, 0), np.where(inside, row, 0)
    expected = np.where(inside, np.arange(V)[:, None] * W * H + row * W + col, 0)
    np.testing.assert_array_equal(m, inside)
    np.testing.assert_array_equal(idx, expected.astype(np.uint32))
    assert inside.sum() == V * 12 * 10  # 12 of the values are columns of the image, 10 are rows


def test_edge_chunks_change_the_work_not_the_sums(pdata, corners_fn, probe_corners):
    """The edge loop's samples per iteration (one for all groups, or one per group, the default) change only how
    many masked slots are visited: the per-part sums of the probe states are equal to the integer."""
    obs = _obs(pdata, 0)
    configs = [pl.Config(chunk=8), pl.Config(), pl.Config(chunk=(5, 3, 7, 16, 1, 2))]
    for uv in probe_corners:
        sums = [[np.asarray(a) for a in corners_fn(uv, obs, config=c)] for c in configs]
        assert sums[0][1].sum() > 800  # edge samples in the images
        for other in sums[1:]:
            for a, b in zip(sums[0], other, strict=True):
                np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="chunk needs one entry per group"):
        pl.Config(chunk=(8, 8))


def test_reads_apart_or_fused_give_the_same_values(pdata, corners_fn, probe_corners):
    """The pixel reads as gathers of their own (``Config(gathers_apart=True)``: the sample indices materialised
    behind an optimisation barrier) or fused into the sampling loop give the same per-part sums of the probe
    corners, to the integer, and the same log-likelihoods of eight states, bit for bit but where a sample lies on a
    pixel border: the two are different XLA programs, whose multiply-adds may be contracted differently, and one of
    the probe states ("poses.txt line 0") has a corner on a border (:func:`test_likelihood_matches_bodytrack`) —
    at most one particle, by at most one edge sample's share (1 / 800). Only the program differs (the barrier is in
    its StableHLO). By default the machine decides (:func:`jaxmocap.host.gathers_apart`). A foreground map of
    another dtype than bytes (non-zero: foreground) gives the same sums."""
    obs = _obs(pdata, 0)
    apart, fused = pl.Config(gathers_apart=True), pl.Config(gathers_apart=False)
    # foreground maps of bytes (summed by table lookup when apart) and of another dtype (by comparison)
    wide = pl.Observation(obs.edge, jnp.asarray(obs.fg, jnp.int32) * 300)
    for uv in probe_corners:
        a, f, w = (corners_fn(uv, o, config=c) for o, c in ((obs, apart), (obs, fused), (wide, apart)))
        for x, y, z in zip(a, f, w, strict=True):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
            np.testing.assert_array_equal(np.asarray(z), np.asarray(y))
    X = _eight(pdata, scale=3.0)
    fns = [jax.jit(pl.make_loglik_batch(pdata["shape"], pdata["cams"], c)) for c in (apart, fused)]
    got, ref = (np.asarray(fn(X, obs)) for fn in fns)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1.0 / 800)
    assert np.sum(got != ref) <= 1
    texts = [fn.lower(X, obs).as_text() for fn in fns]
    assert "optimization_barrier" in texts[0] and "optimization_barrier" not in texts[1]
    assert pl.Config().apart == host.gathers_apart()


def test_intersecting_parts_are_invalid(pdata, loglik_fn):
    """bodytrack's sphere test: the left forearm folded into the torso is rejected with −1e10."""
    shape = pdata["shape"]
    x0 = np.asarray(pdata["states"]["InitialPose.txt"])
    P = np.asarray(parsec.cylinder_poses(shape, jnp.asarray(x0, jnp.float32)))
    assert bool(pl.geometry_valid(shape, jnp.asarray(P)))
    # move the left forearm cylinder onto the torso axis: must intersect
    bad = P.copy()
    bad[6, :, 3] = P[0, :, 3] + P[0, :, 2] * 200.0
    assert not bool(pl.geometry_valid(shape, jnp.asarray(bad)))
    # traced shape (masked 21 spheres) and concrete shape (static counts) agree on strongly perturbed poses
    X = np.asarray(_eight(pdata, scale=20.0, seed=3))
    poses = jax.jit(jax.vmap(lambda x: parsec.cylinder_poses(shape, x)))(jnp.asarray(X))
    concrete = np.asarray(jax.jit(jax.vmap(lambda p: pl.geometry_valid(shape, p)))(poses))
    traced = np.asarray(jax.jit(jax.vmap(pl.geometry_valid, (None, 0)))(shape, poses))
    np.testing.assert_array_equal(concrete, traced)
    assert concrete[:3].all() and not concrete.all()
    ll = np.asarray(loglik_fn(jnp.asarray(X), _obs(pdata, 0)))
    assert np.all(ll[~concrete] == pl.INVALID)
    assert np.all((ll[concrete] > -2.0) & (ll[concrete] < 0.0))
    # the batch evaluated the sphere test above as a computation of its own (a conditional's branch), where
    # geometry_valid runs it inline: the same flags
    assert "stablehlo.case" in loglik_fn.lower(jnp.asarray(X), _obs(pdata, 0)).as_text()
    # a NaN first particle takes the same branch (its other branch only returns zeros): the others keep their flags
    Xn = X.copy()
    Xn[0] = np.nan
    ll_nan = np.asarray(loglik_fn(jnp.asarray(Xn), _obs(pdata, 0)))
    assert ll_nan[0] == pl.INVALID
    np.testing.assert_array_equal(ll_nan[1:], ll[1:])


def test_sphere_counts_stay_static_under_jit(pdata):
    """A concrete body shape gives the sphere test its static counts inside a jit trace too (the filters' path),
    the same as outside (computed with jnp there, they had become tracers and the 21-sphere masked test ran)."""
    shape = pdata["shape"]
    outside = pl._static_sphere_counts(shape)
    inside = []
    jax.jit(lambda x: inside.append(pl._static_sphere_counts(shape)) or x)(1.0)
    assert outside is not None and inside == [outside]


def test_huge_projection_is_bounded(pdata, corners_fn):
    """A body next to camera 1 projects far larger than the image: sample counts stay within the image bound."""
    x = np.array(pdata["states"]["InitialPose.txt"])
    x[3:6] = np.asarray(pdata["cams"].eye[0]) * 0.9  # pelvis 10 % of the way from camera 1
    cfg = pl.Config()
    _, uv = pl.corners(pdata["shape"], pdata["cams"], jnp.asarray(x, jnp.float32))
    ssd, ne, bg, ni = (np.asarray(a) for a in corners_fn(uv, _obs(pdata, 0)))
    assert np.isfinite(ssd).all()
    assert ne.max() <= 2 * (cfg.max_edge_n + 1)
    assert ni.max() <= (cfg.max_rows_n + 1) * cfg.max_cols_n
