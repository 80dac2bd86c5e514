"""BVH reader/writer: agreement with bvhio on real CMU clips, closed forms, round trips, errors and a fuzz."""

import pathlib
import re
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io import bvh, mocap

with warnings.catch_warnings():  # PyGLM (under bvhio) warns about its import name on import
    warnings.simplefilter("ignore", PendingDeprecationWarning)
    import bvhio

CMU = pathlib.Path(__file__).parents[1] / "data" / "cmu"
CLIPS = ("131_01.bvh", "131_03.bvh")
A = mocap.Y_UP_TO_Z_UP


@pytest.fixture(scope="module")
def motions():
    return {c: bvh.load_bvh(CMU / c, scale=bvh.CMU_BVH_SCALE) for c in CLIPS}


def _bvhio_world(path, frames):
    """World joint positions (file units, y up) computed by bvhio, in its layout order."""
    root = bvhio.readAsHierarchy(str(path))
    names = [j.Name for j, _, _ in root.layout()]
    out = []
    for f in frames:
        root.loadPose(f)
        out.append([[*j.PositionWorld] for j, _, _ in root.layout()])
    return names, np.asarray(out, dtype=np.float64)


@pytest.mark.parametrize("clip", CLIPS)
def test_world_positions_agree_with_bvhio(motions, clip):
    m = motions[clip]
    frames = [0, 1, m.num_frames // 3, m.num_frames // 2, m.num_frames - 1]
    names, ref = _bvhio_world(CMU / clip, frames)
    assert tuple(names) == m.joint_names
    ours = m.positions[frames] @ A / bvh.CMU_BVH_SCALE  # back to file units and y up: A⁻¹ = Aᵀ
    err_m = np.abs(ours - ref).max() * bvh.CMU_BVH_SCALE
    assert err_m < 1e-4  # < 0.1 mm; measured ~2.4e-7 m (bvhio computes in float32)


@pytest.mark.parametrize("clip", CLIPS)
def test_raw_content_agrees_with_bvhio(clip):
    data = bvh.read_bvh(CMU / clip)
    ref = bvhio.readAsBvh(str(CMU / clip))
    layout = ref.Root.layout()
    assert tuple(j.Name for j, _, _ in layout) == data.names
    for j, (joint, _, _) in enumerate(layout):
        assert tuple(joint.Channels) == data.channels[j]
        np.testing.assert_allclose([*joint.Offset], data.offsets[j], atol=1e-5)
    assert ref.FrameCount == data.frames.shape[0]
    assert data.frame_time == pytest.approx(ref.FrameTime)
    np.testing.assert_allclose([*ref.Root.Keyframes[7].Position], data.frames[7, :3], atol=1e-4)


def test_cmu_files_facts():
    data = bvh.read_bvh(CMU / "131_01.bvh")
    assert len(data.names) == 31 and data.names[0] == "Hips"
    assert data.channels[0] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
    assert data.frames.shape == (994, sum(len(c) for c in data.channels))
    assert bvh.frame_rate(data.frame_time) == 120.0


def _head_top_above_floor(m: mocap.Motion) -> float:
    """Median over frames of the head end site's height above the clip's lowest point (a stature proxy)."""
    z = np.concatenate([m.positions[..., 2], m.end_positions[..., 2]], axis=1)
    head = m.end_positions[:, m.end_site_of("Head"), 2]
    return float(np.median(head - z.min()))


@pytest.mark.parametrize("clip", CLIPS)
def test_cmu_scale_gives_plausible_heights(motions, clip):
    h = _head_top_above_floor(motions[clip])
    # measured 1.425 m (131_01), 1.401 m (131_03): subject 131 reads short because the cgspeed skeleton drops
    # the ASF thorax bone (~0.11 m; its lowerneck sits at Chest2)
    assert 1.4 <= h <= 2.0


def test_cmu_bvh_unit_is_the_asf_unit():
    """The cgspeed conversion keeps the ASF numbers: leg bones and standing root height in file units match a
    CMU ASF subject (02.asf, another person) to within 15 %, which a 0.07 m unit would not allow
    (0.07 / 0.0564 = 1.24)."""
    from jaxmocap.io import asfamc

    data = bvh.read_bvh(CMU / "131_01.bvh")
    off = dict(zip(data.names, np.linalg.norm(data.offsets, axis=1), strict=True))
    leg_bvh = off["LeftKnee"] + off["LeftAnkle"]  # femur + tibia in file units
    skel = asfamc.read_asf(CMU / "02.asf")
    leg_asf = skel.bones["lfemur"].length + skel.bones["ltibia"].length
    assert 0.85 < leg_bvh / leg_asf < 1.15
    root_y_bvh = np.median(data.frames[:, 1])
    values, _ = asfamc.read_amc(CMU / "02_01.amc", skel)
    assert 0.85 < root_y_bvh / np.median(values["root"][:, 1]) < 1.15
    assert bvh.CMU_BVH_SCALE == pytest.approx(0.0254 / 0.45)


def test_axes_rest_pose_faces_plus_x_with_left_towards_plus_y(motions):
    m = motions["131_01.bvh"]
    X, E = mocap.rest_positions(m)
    J = dict(zip(m.joint_names, X, strict=True))
    # LeftHip OFFSET (1.24777, -1.64261, 0.71711) in y-up file axes -> (z, x, y)
    np.testing.assert_allclose(J["LeftHip"], bvh.CMU_BVH_SCALE * np.array([0.71711, 1.24777, -1.64261]))
    assert J["LeftHip"][1] > 0 > J["RightHip"][1]
    assert E[m.end_site_of("LeftToe")][0] > J["LeftAnkle"][0]  # toes point forward (+x)
    assert E[m.end_site_of("Head")][2] > J["Hips"][2]  # head above the pelvis


def test_eval_joints_mapping(motions):
    m = motions["131_01.bvh"]
    ev = mocap.eval_joints(m)
    assert ev.shape == (m.num_frames, 15, 3)
    i = {n: k for k, n in enumerate(EVAL_JOINTS)}
    np.testing.assert_array_equal(ev[:, i["left_knee"]], m.positions[:, m.joint_index("LeftKnee")])
    np.testing.assert_array_equal(ev[:, i["thorax"]], m.positions[:, m.joint_index("lowerneck")])
    head = 0.5 * (m.positions[:, m.joint_index("Head")] + m.end_positions[:, m.end_site_of("Head")])
    np.testing.assert_allclose(ev[:, i["head"]], head)
    # bone lengths between evaluation joints are constant over the clip (rigid bones)
    for a, b in (("left_shoulder", "left_elbow"), ("right_hip", "right_knee"), ("left_knee", "left_ankle")):
        d = np.linalg.norm(ev[:, i[a]] - ev[:, i[b]], axis=1)
        assert np.ptp(d) < 1e-9


SMALL = (
    "HIERARCHY\r\n"
    "ROOT Pelvis\r\n{\r\n"
    "  OFFSET 1 2 3\r\n"
    "  CHANNELS 6 Zposition Xposition Yposition Xrotation Zrotation Yrotation\r\n"
    "  JOINT Arm\r\n  {\r\n"
    "    OFFSET 0 4 0\r\n"
    "    CHANNELS 1 Yrotation\r\n"
    "    JOINT Hand\r\n    {\r\n"
    "OFFSET 2 0 0\r\n"
    "CHANNELS 4 Yposition Zrotation Xposition Xrotation\r\n"
    "      End Site\r\n      {\r\n        OFFSET 0 0 1\r\n      }\r\n"
    "    }\r\n  }\r\n}\r\n"
    "MOTION\r\nFrames: 2\r\nFrame Time: 0.04\r\n"
    "0.5 1.5 2.5 10 20 30 40 0.7 50 0.3 60\r\n"
    "-1 0 1 -30 45 90 -5 -2 170 0 -90\r\n"
)


def _small_reference(frame):
    """The closed form of SMALL with scipy (intrinsic Euler angles in channel order), y-up file units."""
    pz, px, py, r_x, r_z, r_y, arm_y, hy, hz, hx, hrx = frame
    R0 = Rotation.from_euler("XZY", [r_x, r_z, r_y], degrees=True).as_matrix()
    R1 = Rotation.from_euler("Y", arm_y, degrees=True).as_matrix()
    R2 = Rotation.from_euler("ZX", [hz, hrx], degrees=True).as_matrix()
    p0 = np.array([px, py, pz])  # position channels replace the root OFFSET
    p1 = p0 + R0 @ np.array([0.0, 4.0, 0.0])
    p2 = p1 + R0 @ R1 @ np.array([hx, hy, 0.0])  # Hand: x, y from channels, z from its OFFSET
    end = p2 + R0 @ R1 @ R2 @ np.array([0.0, 0.0, 1.0])
    return np.stack([p0, p1, p2]), end


def test_any_channel_order_subset_and_position_channels_on_a_child(tmp_path):
    path = tmp_path / "small.bvh"
    path.write_bytes(SMALL.encode())
    data = bvh.read_bvh(path)
    assert data.names == ("Pelvis", "Arm", "Hand") and data.parents == (-1, 0, 1)
    assert data.channels[2] == ("Yposition", "Zrotation", "Xposition", "Xrotation")
    m = bvh.load_bvh(path, scale=0.5)
    assert m.fps == 25.0 and m.local_translations is not None
    for f in range(2):
        joints, end = _small_reference(data.frames[f])
        np.testing.assert_allclose(m.positions[f], 0.5 * joints @ A.T, atol=1e-12)
        np.testing.assert_allclose(m.end_positions[f, 0], 0.5 * A @ end, atol=1e-12)
    z_up = bvh.load_bvh(path, scale=1.0, up_axis="z")
    np.testing.assert_allclose(z_up.positions[1], _small_reference(data.frames[1])[0], atol=1e-12)


def test_braces_on_the_joint_line_and_names_with_spaces(tmp_path):
    text = SMALL.replace("ROOT Pelvis\r\n{", "ROOT Pelvis {").replace("JOINT Arm\r\n  {", "JOINT Left Arm {")
    path = tmp_path / "b.bvh"
    path.write_bytes(text.encode())
    data = bvh.read_bvh(path)
    assert data.names == ("Pelvis", "Left Arm", "Hand")
    np.testing.assert_array_equal(data.frames, bvh.read_bvh(_write(tmp_path, SMALL, "a.bvh")).frames)


def test_matrix_to_euler_inverts_scipy_for_every_order():
    rng = np.random.default_rng(3)
    for order in ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"):
        ang = rng.uniform(-1.4, 1.4, size=(50, 3))
        R = Rotation.from_euler(order, ang).as_matrix()  # uppercase: intrinsic = R_a R_b R_c
        np.testing.assert_allclose(mocap.euler_to_matrix(ang, order), R, atol=1e-12)
        np.testing.assert_allclose(mocap.matrix_to_euler(R, order), ang, atol=1e-9)
    # gimbal lock still reproduces the matrix
    R = Rotation.from_euler("ZYX", [0.3, np.pi / 2, -0.2]).as_matrix()
    # (asin loses half the digits next to ±90°)
    np.testing.assert_allclose(mocap.euler_to_matrix(mocap.matrix_to_euler(R, "ZYX"), "ZYX"), R, atol=1e-7)


def test_raw_round_trip(tmp_path):
    data = bvh.read_bvh(CMU / "131_03.bvh")
    out = tmp_path / "raw.bvh"
    bvh.save_bvh(out, data)
    back = bvh.read_bvh(out)
    assert back.names == data.names and back.parents == data.parents and back.channels == data.channels
    np.testing.assert_allclose(back.offsets, data.offsets, atol=1e-6)
    np.testing.assert_allclose(back.frames, data.frames, atol=1e-6)
    np.testing.assert_allclose(back.end_offsets, data.end_offsets, atol=1e-6)
    assert back.end_parents == data.end_parents
    assert back.frame_time == pytest.approx(data.frame_time, rel=1e-9)


def test_motion_round_trip_and_bvhio_reads_our_file(tmp_path, motions):
    m = motions["131_03.bvh"]
    out = tmp_path / "export.bvh"
    bvh.save_bvh(out, m, scale=0.01)  # centimetres, y up, ZYX channels
    back = bvh.load_bvh(out, scale=0.01)
    assert back.joint_names == m.joint_names and back.fps == m.fps
    np.testing.assert_allclose(back.positions, m.positions, atol=2e-7)
    np.testing.assert_allclose(back.end_positions, m.end_positions, atol=2e-7)
    np.testing.assert_allclose(back.local_rotations, m.local_rotations, atol=1e-7)
    frames = [0, 500, m.num_frames - 1]
    names, ref = _bvhio_world(out, frames)
    assert tuple(names) == m.joint_names
    np.testing.assert_allclose(0.01 * ref @ A.T, m.positions[frames], atol=1e-5)


def test_tuple_writer_with_child_position_channels(tmp_path):
    names = ("root", "a", "b")
    parents = (-1, 0, 1)
    offsets = np.array([[0.0, 0, 0], [0, 1, 0], [1, 0, 0]])
    channels = (
        ("Xposition", "Yposition", "Zposition", "Yrotation"),
        ("Xrotation",),
        ("Zposition", "Zrotation"),
    )
    frames = np.array([[1.0, 2, 3, 30, 45, 0.5, 60], [0, 0, 0, 0, 0, 0, 0]])
    out = tmp_path / "t.bvh"
    bvh.save_bvh(out, (names, parents, offsets, channels, frames, (2,), [[0.0, 0.0, 2.0]]), 30.0)
    data = bvh.read_bvh(out)
    assert data.channels == channels and data.end_parents == (2,)
    np.testing.assert_allclose(data.frames, frames, atol=1e-6)
    m = bvh.load_bvh(out, scale=1.0, up_axis="z")
    again = tmp_path / "again.bvh"
    bvh.save_bvh(again, m, scale=1.0, up_axis="z", rotation_order="XYZ")
    m2 = bvh.load_bvh(again, scale=1.0, up_axis="z")
    assert bvh.read_bvh(again).channels[2][:3] == ("Xposition", "Yposition", "Zposition")
    np.testing.assert_allclose(m2.positions, m.positions, atol=1e-6)
    np.testing.assert_allclose(m2.end_positions, m.end_positions, atol=1e-6)


# ---------------------------------------------------------------------------------------------------------------
# Errors


def _write(tmp_path, text, name="bad.bvh"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    ("edit", "line", "words"),
    [
        (lambda s: s.replace("CHANNELS 1 Yrotation", "CHANNELS 1 Wrotation"), 9, "unknown channel"),
        (lambda s: s.replace("OFFSET 2 0 0", "OFFSET 2 zero 0"), 12, "number for OFFSET y"),
        (lambda s: s.replace("Frames: 2", "Frames: two"), 22, "integer"),
        (lambda s: s.replace("Frames: 2", "Frames: 3"), 25, "ends after 2 of the 3"),
        (lambda s: s.replace("Frames: 2", "Frames: 1"), 25, "more frame lines"),
        (lambda s: s.replace("0.3 60", "0.3"), 24, "has 10 values, expected 11"),
        (lambda s: s.replace("-5 -2 170", "-5 nan 170"), 25, "non-finite"),
        (lambda s: s.replace("-5 -2 170", "-5 x 170"), 25, "'x' is not a number"),
        (lambda s: s.replace("Frame Time: 0.04", "Frame Time: 0"), 23, "frame time"),
        (lambda s: s.replace("JOINT Hand", "JOINT Arm"), 10, "duplicate joint"),
        (lambda s: s.replace("MOTION", "MOTON"), 21, "expected 'MOTION'"),
        (lambda s: s.split("MOTION")[0], 20, "unexpected end of file"),
        (lambda s: s[: s.index("JOINT Hand")], 10, "unexpected end of file"),
        (lambda s: s.replace("  JOINT Arm", "}\nROOT Arm"), 7, "several ROOT"),
    ],
)
def test_malformed_files_name_file_and_line(tmp_path, edit, line, words):
    path = _write(tmp_path, edit(SMALL.replace("\r\n", "\n")))
    with pytest.raises(MocapInputError) as e:
        bvh.load_bvh(path, scale=1.0)
    assert e.value.line == line, str(e.value)
    assert words in str(e.value) and str(path) in str(e.value)


def test_missing_file():
    with pytest.raises(MocapInputError, match="cannot read"):
        bvh.read_bvh(CMU / "nope.bvh")


GARBAGE = st.one_of(
    st.sampled_from(
        [
            "",
            "{",
            "}",
            "JOINT",
            "ROOT",
            "End",
            "Site",
            "MOTION",
            "Frames:",
            "Frame",
            "Time:",
            "CHANNELS",
            "OFFSET",
        ]
        + [
            "nan",
            "inf",
            "-inf",
            "1e999",
            "1e-999",
            "-1",
            "0",
            "7",
            "99999999999999999999",
            "1_0",
            "0x10",
            "é",
        ]
    ),
    st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=8),
)
SOURCE = (CMU / "131_01.bvh").read_text()
# a shorter clip from the real file keeps each example fast: the header and the first 40 frames
_HEAD, _FRAMES = SOURCE.split("Frame Time: .0083333")
SOURCE = (
    _HEAD.replace("Frames: 994", "Frames: 40") + "Frame Time: .0083333" + "\n".join(_FRAMES.split("\n")[:41])
)
FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _load_text(tmp_path, text):
    p = tmp_path / "fuzz.bvh"
    p.write_bytes(text.encode("utf-8", errors="surrogatepass"))
    try:
        bvh.load_bvh(p, scale=bvh.CMU_BVH_SCALE)
    except MocapInputError as e:
        assert e.line is None or 1 <= e.line <= text.count("\n") + 2
        assert str(p) in str(e)


def test_fuzz_source_is_valid(tmp_path):
    p = tmp_path / "ok.bvh"
    p.write_text(SOURCE)
    assert bvh.load_bvh(p, scale=1.0).num_frames == 40


@FUZZ
@given(cut=st.integers(0, len(SOURCE)))
def test_fuzz_truncation(tmp_path, cut):
    _load_text(tmp_path, SOURCE[:cut])


@FUZZ
@given(data=st.data())
def test_fuzz_garbage_tokens(tmp_path, data):
    tokens = re.split(r"(\s+)", SOURCE)  # words at even indices, whitespace at odd ones
    for _ in range(data.draw(st.integers(1, 3))):
        k = 2 * data.draw(st.integers(0, len(tokens) // 2 - 1))
        tokens[k] = data.draw(GARBAGE)
    _load_text(tmp_path, "".join(tokens))


@FUZZ
@given(data=st.data())
def test_fuzz_deleted_lines(tmp_path, data):
    lines = SOURCE.split("\n")
    for _ in range(data.draw(st.integers(1, 3))):
        del lines[data.draw(st.integers(0, len(lines) - 1))]
    _load_text(tmp_path, "\n".join(lines))
