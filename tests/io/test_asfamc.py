"""ASF/AMC loader: file facts, an independent SciPy forward kinematics, rigid bones, heights, errors, fuzz."""

import pathlib
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry.body import DEFAULT_DIMENSIONS, EVAL_JOINTS
from jaxmocap.io import asfamc, mocap

CMU = pathlib.Path(__file__).parents[1] / "data" / "cmu"
CLIPS = (("02.asf", "02_01.amc"), ("charleston.asf", "charleston1.amc"))
A = mocap.Y_UP_TO_Z_UP
SCALE = 0.0254 / 0.45


@pytest.fixture(scope="module")
def motions():
    return {amc: asfamc.load_asfamc(CMU / asf, CMU / amc) for asf, amc in CLIPS}


def test_parsed_values_are_the_file_values():
    skel = asfamc.read_asf(CMU / "02.asf")
    assert len(skel.bones) == 30 and skel.length_unit == 0.45 and skel.angle_unit == "deg"
    assert skel.root_order == ("TX", "TY", "TZ", "RX", "RY", "RZ") and skel.root_axis == "XYZ"
    f = skel.bones["lfemur"]
    assert f.length == 7.59371 and f.dofs == ("rx", "ry", "rz") and f.axis_order == "XYZ"
    np.testing.assert_allclose(
        f.direction, [0.34202, -0.939693, 0.0] / np.linalg.norm([0.34202, -0.939693, 0])
    )
    np.testing.assert_allclose(np.rad2deg(f.axis), [0, 0, 20])
    np.testing.assert_allclose(np.rad2deg(f.limits), [(-160, 20), (-70, 70), (-60, 70)])
    assert skel.bones["lwrist"].dofs == ("ry",) and skel.bones["lhipjoint"].dofs == ()
    assert skel.children["thorax"] == ["lowerneck", "lclavicle", "rclavicle"]
    values, unit = asfamc.read_amc(CMU / "02_01.amc", skel)
    assert unit == "deg" and values["root"].shape == (343, 6)
    np.testing.assert_array_equal(
        values["root"][0], [10.4194, 16.7048, -30.1003, -2.48972, -9.82194, -3.00914]
    )
    np.testing.assert_array_equal(values["rclavicle"][0], [-1.6201e-014, -1.43125e-014])
    assert skel.scale == pytest.approx(SCALE)


def _scipy_reference(skel, values, frame):
    """World bone starts and ends (file units, y up) by a separate recursion with SciPy rotations.

    Convention (CMU ASF/AMC): W_b = W_parent C_b M_b C_b⁻¹, with C_b the ``axis`` angles and M_b the dof angles,
    each applied in the order listed (extrinsic, SciPy lower-case axes); end_b = start_b + W_b ℓ_b d_b.
    """
    root = values["root"][frame]
    order = skel.root_order
    pos = np.array([root[order.index(t)] for t in ("TX", "TY", "TZ")])
    rot_names = [o for o in order if o.startswith("R")]
    W_root = Rotation.from_euler(
        "".join(o[1].lower() for o in rot_names), [root[order.index(o)] for o in rot_names], degrees=True
    )
    starts, ends = {"root": pos}, {"root": pos}

    def visit(parent, W_parent):
        for name in skel.children.get(parent, []):
            b = skel.bones[name]
            C = Rotation.from_euler(b.axis_order.lower(), b.axis)  # radians already
            if b.dofs:
                M = Rotation.from_euler("".join(d[1] for d in b.dofs), values[name][frame], degrees=True)
            else:
                M = Rotation.identity()
            W = W_parent * C * M * C.inv()
            starts[name] = ends[parent]
            ends[name] = starts[name] + W.apply(b.length * b.direction)
            visit(name, W)

    visit("root", W_root)
    return starts, ends


@pytest.mark.parametrize(("asf", "amc"), CLIPS)
def test_positions_match_an_independent_scipy_forward_kinematics(motions, asf, amc):
    m = motions[amc]
    skel = asfamc.read_asf(CMU / asf)
    values, _ = asfamc.read_amc(CMU / amc, skel)
    for frame in (0, 1, m.num_frames // 2, m.num_frames - 1):
        starts, ends = _scipy_reference(skel, values, frame)
        for j, name in enumerate(m.joint_names):
            np.testing.assert_allclose(m.positions[frame, j], SCALE * A @ starts[name], atol=1e-9)
        for e, j in enumerate(m.end_parents):
            np.testing.assert_allclose(
                m.end_positions[frame, e], SCALE * A @ ends[m.joint_names[j]], atol=1e-9
            )


@pytest.mark.parametrize(("asf", "amc"), CLIPS)
def test_bones_are_rigid_in_every_frame_and_the_rest_pose_is_the_asf_geometry(motions, asf, amc):
    m = motions[amc]
    skel = asfamc.read_asf(CMU / asf)
    X, E = mocap.rest_positions(m)
    for j, name in enumerate(m.joint_names[1:], start=1):
        b = skel.bones[name]
        kids = [k for k, p in enumerate(m.parents) if p == j]
        end_now = m.positions[:, kids[0]] if kids else m.end_positions[:, m.end_parents.index(j)]
        lengths = np.linalg.norm(end_now - m.positions[:, j], axis=1)
        np.testing.assert_allclose(lengths, SCALE * b.length, rtol=1e-12, atol=1e-12)
        end_rest = X[kids[0]] if kids else E[m.end_parents.index(j)]
        # rest pose: every bone points along its ASF direction (y up -> z up)
        np.testing.assert_allclose(end_rest - X[j], SCALE * b.length * A @ b.direction, atol=1e-12)


@pytest.mark.parametrize(("asf", "amc"), CLIPS)
def test_plausible_heights(motions, asf, amc):
    m = motions[amc]
    z = np.concatenate([m.positions[..., 2], m.end_positions[..., 2]], axis=1)
    head_top = m.end_positions[:, m.end_site_of("head"), 2]
    h = float(np.median(head_top - z.min()))
    assert 1.4 <= h <= 2.0  # measured 1.591 m (subject 2), 1.596 m (Charleston dancer)


def test_axes_subject_stands_on_z_faces_plus_x(motions):
    m = motions["02_01.amc"]
    ev = mocap.eval_joints(m)
    i = {n: k for k, n in enumerate(EVAL_JOINTS)}
    assert np.all(ev[:, i["head"], 2] > ev[:, i["root"], 2] + 0.4)
    X, E = mocap.rest_positions(m)
    J = dict(zip(m.joint_names, X, strict=True))
    assert J["lfemur"][1] > 0 > J["rfemur"][1]  # left towards +y
    assert E[m.end_parents.index(m.joint_index("ltoes"))][0] > J["lfoot"][0]  # toes forward (+x)
    # the subject walks about 3.5 m along the floor in this clip
    assert np.linalg.norm(m.root_positions[-1, :2] - m.root_positions[0, :2]) > 2.0


def test_eval_joints_and_body_dimensions(motions):
    m = motions["02_01.amc"]
    skel = asfamc.read_asf(CMU / "02.asf")
    ev = mocap.eval_joints(m)
    i = {n: k for k, n in enumerate(EVAL_JOINTS)}
    np.testing.assert_array_equal(ev[:, i["thorax"]], m.positions[:, m.joint_index("lowerneck")])
    np.testing.assert_array_equal(ev[:, i["left_wrist"]], m.positions[:, m.joint_index("lhand")])
    head_end = m.end_positions[:, m.end_parents.index(m.joint_index("head"))]
    np.testing.assert_allclose(ev[:, i["head"]], 0.5 * (m.positions[:, m.joint_index("head")] + head_end))
    d = mocap.body_dimensions_from_motion(m)
    L = {n: SCALE * b.length for n, b in skel.bones.items()}
    assert d["left_thigh_length"] == pytest.approx(L["lfemur"])
    assert d["right_shin_length"] == pytest.approx(L["rtibia"])
    assert d["left_upper_arm_length"] == pytest.approx(L["lhumerus"])
    assert d["right_forearm_length"] == pytest.approx(L["rradius"] + L["rwrist"])
    assert d["head_length"] == pytest.approx(L["head"])
    assert 0.3 < d["torso_length"] < 0.45 and 0.3 < d["shoulder_width"] < 0.5
    assert set(d) >= set(DEFAULT_DIMENSIONS) - {k for k in DEFAULT_DIMENSIONS if "radius" in k}


def _asf_by_hand(path):
    """An ASF read with string operations only: bone -> (unit direction, length, axis rotation C, dofs) and
    bone -> parent ("root" at the top)."""
    lines = [ln.split("#")[0].split() for ln in path.read_text().splitlines()]
    bones, parent, section, cur, in_h = {}, {}, None, None, False
    for w in (w for w in lines if w):
        if w[0].startswith(":"):
            section = w[0]
        elif section == ":bonedata" and w == ["begin"]:
            cur = {}
        elif section == ":bonedata" and w == ["end"]:
            d = np.array(cur["direction"], float)
            C = Rotation.from_euler("xyz", np.array(cur["axis"][:3], float), degrees=True).as_matrix()
            bones[cur["name"][0]] = (d / np.linalg.norm(d), float(cur["length"][0]), C, cur.get("dof", []))
        elif section == ":bonedata" and cur is not None:
            cur[w[0]] = w[1:]
        elif section == ":hierarchy" and w in (["begin"], ["end"]):
            in_h = w == ["begin"]
        elif section == ":hierarchy" and in_h:
            parent.update(dict.fromkeys(w[1:], w[0]))
    return bones, parent


def _articulations(bones, parent, first, leaf):
    """Bones from ``first`` down to ``leaf`` that bend the limb: some dof axis ``C e`` is not along the bone (a
    dof about the bone's own direction only twists it, as the ASF ``wrist`` bones' ``ry``)."""
    chain = [leaf]
    while chain[-1] != first:
        chain.append(parent[chain[-1]])
    axis = {"rx": 0, "ry": 1, "rz": 2}
    bends = lambda b: any(abs(bones[b][2][:, axis[d]] @ bones[b][0]) < 0.99 for d in bones[b][3])
    return [b for b in reversed(chain) if bends(b)]


@pytest.mark.parametrize(("asf", "amc"), CLIPS)
def test_eval_joints_are_where_the_asf_articulates(motions, asf, amc):
    """An independent reading of the ASF's degrees of freedom: along the arm (clavicle to fingers) the bones that
    bend are the clavicle, humerus, radius, hand and fingers (the wrist bone only twists), so the shoulder, elbow
    and wrist are the starts of the 2nd, 3rd and 4th; along the leg the hip, knee and ankle are the starts of the
    1st, 2nd and 3rd. Bone starts at rest are sums of ``length · direction`` from the text; the evaluation joints
    of the motion sit there. Then the kinematics: turning the hand's own dofs by 25° keeps the wrist still and
    every hand point at the same distance from it (it is the centre of that rotation); from the start of the
    twisting wrist bone, the old choice, the fingertip's distance changes."""
    bones, parent = _asf_by_hand(CMU / asf)
    start = {}
    for b in bones:
        chain, p = [], parent[b]
        while p != "root":
            chain.append(p)
            p = parent[p]
        start[b] = sum((bones[a][1] * bones[a][0] for a in chain), np.zeros(3))
    m = motions[amc]
    rest = dict(zip(EVAL_JOINTS, mocap.rest_eval_joints(m), strict=True))
    root = mocap.rest_positions(m)[0][0]
    for side in ("l", "r"):
        s = "left" if side == "l" else "right"
        arm = _articulations(bones, parent, f"{side}clavicle", f"{side}fingers")
        leg = _articulations(bones, parent, f"{side}hipjoint", f"{side}toes")
        assert arm == [f"{side}{b}" for b in ("clavicle", "humerus", "radius", "hand", "fingers")]
        assert leg == [f"{side}{b}" for b in ("femur", "tibia", "foot", "toes")]
        for joint, bone in zip(("shoulder", "elbow", "wrist"), arm[1:4], strict=True):
            np.testing.assert_allclose(rest[f"{s}_{joint}"] - root, SCALE * A @ start[bone], atol=1e-12)
        for joint, bone in zip(("hip", "knee", "ankle"), leg[:3], strict=True):
            np.testing.assert_allclose(rest[f"{s}_{joint}"] - root, SCALE * A @ start[bone], atol=1e-12)

    skel = asfamc.read_asf(CMU / asf)
    values, unit = asfamc.read_amc(CMU / amc, skel)
    frames = slice(0, 60, 10)
    turned = {k: v.copy() for k, v in values.items()}
    turned["lhand"] += 25.0
    m2 = asfamc.motion_from_asfamc(skel, turned, unit, fps=120)
    wrist = lambda mo: mocap.eval_joints(mo)[frames, EVAL_JOINTS.index("left_wrist")]
    tip = lambda mo: mo.end_positions[frames, mo.end_site_of("lfingers")]
    np.testing.assert_allclose(wrist(m2), wrist(m), atol=1e-12)
    assert np.abs(tip(m2) - tip(m)).max() > 0.01
    dist = lambda mo, p: np.linalg.norm(tip(mo) - p, axis=-1)
    np.testing.assert_allclose(dist(m2, wrist(m2)), dist(m, wrist(m)), atol=1e-12)
    twist_start = lambda mo: mo.positions[frames, mo.joint_index("lwrist")]
    assert np.abs(dist(m2, twist_start(m2)) - dist(m, twist_start(m))).max() > 0.005


def test_asf_motion_exports_to_bvh(tmp_path, motions):
    """An ASF/AMC motion is a BVH-shaped tree (joint = bone start, rotation L_b): written as BVH and read back,
    by our reader and by bvhio, it has the same joints."""
    import warnings

    from jaxmocap.io import bvh

    m = motions["02_01.amc"]
    out = tmp_path / "02_01.bvh"
    bvh.save_bvh(out, m)  # centimetres, y up
    back = bvh.load_bvh(out, scale=0.01)
    np.testing.assert_allclose(back.positions, m.positions, atol=2e-7)
    np.testing.assert_allclose(back.end_positions, m.end_positions, atol=2e-7)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        import bvhio
    root = bvhio.readAsHierarchy(str(out))
    root.loadPose(200)
    ref = np.asarray([[*j.PositionWorld] for j, _, _ in root.layout()], dtype=np.float64)
    np.testing.assert_allclose(0.01 * ref @ A.T, m.positions[200], atol=1e-5)


# ---------------------------------------------------------------------------------------------------------------
# Errors

ASF_TEXT = (CMU / "02.asf").read_text()
AMC_TEXT = "\n".join((CMU / "02_01.amc").read_text().splitlines()[: 3 + 20 * 30]) + "\n"  # first 20 frames


def _lines_of(text, needle):
    return text[: text.index(needle)].count("\n") + 1


@pytest.mark.parametrize(
    ("edit", "needle", "words"),
    [
        (lambda s: s.replace("length 7.59371", "length seven"), "length seven", "not all numbers"),
        (
            lambda s: s.replace("dof rx ry rz\n    limits (-160.0", "dof rx ry qz\n    limits (-160.0"),
            "qz",
            "dof",
        ),
        (
            lambda s: s.replace("(-70.0 70.0)\n           (-60.0 70.0)", "(-70.0 70.0)"),
            "(-70.0 70.0)",
            "limits",
        ),
        (lambda s: s.replace("axis 0 0 20  XYZ", "axis 0 0 20  XYW"), "XYW", "permutation of XYZ"),
        (lambda s: s.replace("    lfemur ltibia", "    lfemur ltibio"), "lfemur ltibio", "unknown bone"),
        (lambda s: s.replace("    lfemur ltibia", "    lfemur lfemur"), "lfemur lfemur", "two parents"),
        (
            lambda s: s.replace("dof rx ry rz\n    limits (-160.0", "dof rx ry tz\n    limits (-160.0"),
            "tz",
            "not supported",
        ),
    ],
)
def test_malformed_asf_names_file_and_line(tmp_path, edit, needle, words):
    text = edit(ASF_TEXT)
    (tmp_path / "s.asf").write_text(text)
    with pytest.raises(MocapInputError) as e:
        asfamc.read_asf(tmp_path / "s.asf")
    expected = _lines_of(text, needle)
    if words == "limits":  # one limit for three dofs: reported at the end of the lfemur block
        expected = text[: text.index("  end", text.index("name lfemur"))].count("\n") + 1
    assert e.value.line == expected, str(e.value)
    assert words in str(e.value) and "s.asf" in str(e.value)


@pytest.mark.parametrize(
    ("edit", "needle", "words"),
    [
        (lambda s: s.replace("rtibia 11.5302", "rtibia 11.5302 3"), "rtibia 11.5302 3", "needs 1 numbers"),
        (lambda s: s.replace("rfoot -15.9687 0.925564", "rfoot -15.9687 x"), "rfoot -15.9687 x", "numbers"),
        (lambda s: s.replace("lhand -21.8909 22.8474", "lhandy 1 2"), "lhandy", "unknown bone"),
        (lambda s: s.replace("\n2\n", "\n4\n", 1), "\n4\n", "does not follow"),
        (lambda s: s.replace("rtibia 11.5302\n", "", 1), "\n2\n", "lacks rtibia"),
        (lambda s: s.replace("rtibia 11.5302\n", "rtibia 11.5302\nrtibia 1\n", 1), "rtibia 1\n", "twice"),
    ],
)
def test_malformed_amc_names_file_and_line(tmp_path, edit, needle, words):
    skel = asfamc.read_asf(CMU / "02.asf")
    text = edit(AMC_TEXT)
    (tmp_path / "m.amc").write_text(text)
    with pytest.raises(MocapInputError) as e:
        asfamc.read_amc(tmp_path / "m.amc", skel)
    expected = _lines_of(text, needle) + (1 if needle.startswith("\n") else 0)
    assert e.value.line == expected, str(e.value)
    assert words in str(e.value) and "m.amc" in str(e.value)


def test_truncated_last_frame_names_the_frame(tmp_path):
    skel = asfamc.read_asf(CMU / "02.asf")
    text = "\n".join(AMC_TEXT.splitlines()[:-5]) + "\n"
    (tmp_path / "m.amc").write_text(text)
    with pytest.raises(MocapInputError, match="frame 20 .* lacks") as e:
        asfamc.read_amc(tmp_path / "m.amc", skel)
    assert e.value.line == len(text.splitlines())


GARBAGE = st.one_of(
    st.sampled_from(
        [
            "",
            "(",
            ")",
            "(1",
            "2)",
            "begin",
            "end",
            "root",
            ":bonedata",
            ":hierarchy",
            "dof",
            "rx",
            "tx",
            "limits",
        ]
        + [
            "axis",
            "XYZ",
            "nan",
            "inf",
            "1e999",
            "-1",
            "0",
            "3",
            "99999999999999999999",
            "1_0",
            "é",
            ":DEGREES",
        ]
    ),
    st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=8),
)
FUZZ = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _load(tmp_path, asf_text, amc_text):
    (tmp_path / "f.asf").write_bytes(asf_text.encode("utf-8", errors="surrogatepass"))
    (tmp_path / "f.amc").write_bytes(amc_text.encode("utf-8", errors="surrogatepass"))
    try:
        asfamc.load_asfamc(tmp_path / "f.asf", tmp_path / "f.amc")
    except MocapInputError as e:
        assert e.line is None or e.line >= 1
        assert "f.asf" in str(e) or "f.amc" in str(e)


def _garble(data, text):
    tokens = re.split(r"(\s+)", text)
    for _ in range(data.draw(st.integers(1, 3))):
        k = 2 * data.draw(st.integers(0, len(tokens) // 2 - 1))
        tokens[k] = data.draw(GARBAGE)
    return "".join(tokens)


def _delete_lines(data, text):
    lines = text.split("\n")
    for _ in range(data.draw(st.integers(1, 3))):
        del lines[data.draw(st.integers(0, len(lines) - 1))]
    return "\n".join(lines)


def test_fuzz_sources_are_valid(tmp_path):
    (tmp_path / "a.asf").write_text(ASF_TEXT)
    (tmp_path / "a.amc").write_text(AMC_TEXT)
    assert asfamc.load_asfamc(tmp_path / "a.asf", tmp_path / "a.amc").num_frames == 20


@FUZZ
@given(which=st.booleans(), frac=st.floats(0.0, 1.0))
def test_fuzz_truncation(tmp_path, which, frac):
    if which:
        _load(tmp_path, ASF_TEXT[: int(frac * len(ASF_TEXT))], AMC_TEXT)
    else:
        _load(tmp_path, ASF_TEXT, AMC_TEXT[: int(frac * len(AMC_TEXT))])


@FUZZ
@given(which=st.booleans(), data=st.data())
def test_fuzz_garbage_tokens(tmp_path, which, data):
    if which:
        _load(tmp_path, _garble(data, ASF_TEXT), AMC_TEXT)
    else:
        _load(tmp_path, ASF_TEXT, _garble(data, AMC_TEXT))


@FUZZ
@given(which=st.booleans(), data=st.data())
def test_fuzz_deleted_lines(tmp_path, which, data):
    if which:
        _load(tmp_path, _delete_lines(data, ASF_TEXT), AMC_TEXT)
    else:
        _load(tmp_path, ASF_TEXT, _delete_lines(data, AMC_TEXT))


def test_missing_files():
    with pytest.raises(MocapInputError, match="cannot read"):
        asfamc.read_asf(CMU / "nope.asf")
