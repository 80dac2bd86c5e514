"""Skeleton recognition on real and written files: a Bandai-Namco excerpt (checked joint by joint against bvhio's
forward kinematics), a Mixamo-named BVH written with the project's writer, the CMU files, name families, the
tree's shape alone, units, up axis, mapping files and the errors."""

import dataclasses
import pathlib
import warnings

import numpy as np
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io import asfamc, bvh, mocap, skeletons

with warnings.catch_warnings():  # PyGLM (under bvhio) warns about its import name on import
    warnings.simplefilter("ignore", PendingDeprecationWarning)
    import bvhio

DATA = pathlib.Path(__file__).parents[1] / "data"
BANDAI = DATA / "bandai" / "dataset-1_walk_normal_001_excerpt.bvh"
CMU = DATA / "cmu"
A = mocap.Y_UP_TO_Z_UP
I = {n: k for k, n in enumerate(EVAL_JOINTS)}

# Mixamo joints (after "mixamorig:"), their parents and the CMU cgspeed joint whose rotation and rest position
# they take; None for a point given by its own rule below.
MIXAMO = (
    ("Hips", None, "Hips"),
    ("Spine", "Hips", "lowerback"),
    ("Spine1", "Spine", "Chest"),
    ("Spine2", "Spine1", "Chest2"),
    ("Neck", "Spine2", "Neck"),
    ("Head", "Neck", "Head"),
    ("HeadTop_End", "Head", None),
    *(
        row
        for s, c in (("Left", "L"), ("Right", "R"))
        for row in (
            (f"{s}Shoulder", "Spine2", None),
            (f"{s}Arm", f"{s}Shoulder", f"{s}Shoulder"),
            (f"{s}ForeArm", f"{s}Arm", f"{s}Elbow"),
            (f"{s}Hand", f"{s}ForeArm", f"{s}Wrist"),
            (f"{s}HandIndex1", f"{s}Hand", f"{c}Fingers"),
            (f"{s}HandThumb1", f"{s}Hand", f"{c}Thumb"),
            (f"{s}UpLeg", "Hips", f"{s}Hip"),
            (f"{s}Leg", f"{s}UpLeg", f"{s}Knee"),
            (f"{s}Foot", f"{s}Leg", f"{s}Ankle"),
            (f"{s}ToeBase", f"{s}Foot", f"{s}Toe"),
        )
    ),
)


def mixamo_motion(frames: slice = slice(0, 240, 8)) -> mocap.Motion:
    """A walk on a Mixamo-named skeleton: every joint takes the local rotation of its CMU counterpart (131_01) and
    a rest position from the CMU rest pose (the clavicle start 30 % along the CMU clavicle, the head top at the
    CMU head's end site); lengths in centimetres, y up, as Mixamo exports them."""
    cm = bvh.CMU_BVH_SCALE / 0.01
    cmu = bvh.motion_from_bvh(bvh.read_bvh(CMU / "131_01.bvh"), scale=cm, up_axis="z")  # file axes, cm
    X, E = mocap.rest_positions(cmu)
    rest = {n: X[k] for k, n in enumerate(cmu.joint_names)}
    rest["HeadTop_End"] = E[cmu.end_site_of("Head")]
    for s in ("Left", "Right"):
        rest[f"{s}Shoulder_mx"] = rest["Chest2"] + 0.3 * (rest[f"{s}Shoulder"] - rest["Chest2"])
    names = [n for n, _, _ in MIXAMO]
    pos = np.stack([rest[c] if c else rest[n if n == "HeadTop_End" else n + "_mx"] for n, _, c in MIXAMO])
    parents = [-1 if p is None else names.index(p) for _, p, _ in MIXAMO]
    offsets = np.stack([pos[0] if p < 0 else pos[j] - pos[p] for j, p in enumerate(parents)])
    T = len(range(*frames.indices(cmu.num_frames)))
    L = np.broadcast_to(np.eye(3), (T, len(names), 3, 3)).copy()
    for j, (_, _, c) in enumerate(MIXAMO):
        if c:
            L[:, j] = cmu.local_rotations[frames, cmu.joint_index(c)]
    tr = np.broadcast_to(offsets, (T, len(names), 3)).copy()
    tr[:, 0] = cmu.root_positions[frames]
    leaves = [j for j in range(len(names)) if j not in parents]
    # finger, thumb and toe tips at the CMU end sites; the head top ends where it is (a zero end site)
    ends = np.stack(
        [cmu.end_offsets[cmu.end_site_of(c)] if c else np.zeros(3) for _, _, c in (MIXAMO[j] for j in leaves)]
    )
    return mocap.build_motion(
        ["mixamorig:" + n for n in names],
        parents,
        offsets,
        L,
        tr,
        cmu.fps / 8,
        "mixamo",
        leaves,
        ends,
        scale=0.01,
        up_axis="y",
    )


MIXAMO_EXPECTED = {
    "root": "Hips",
    "thorax": "Neck",
    "head": ("mid", "Head", "HeadTop_End"),
    **{
        f"{side}_{k}": f"{side.title()}{n}"
        for side in ("left", "right")
        for k, n in (
            ("shoulder", "Arm"),
            ("elbow", "ForeArm"),
            ("wrist", "Hand"),
            ("hip", "UpLeg"),
            ("knee", "Leg"),
            ("ankle", "Foot"),
        )
    },
}


def _prefixed(spec, prefix="mixamorig:"):
    return prefix + spec if isinstance(spec, str) else (spec[0], *(prefix + n for n in spec[1:]))


@pytest.fixture(scope="module")
def mixamo(tmp_path_factory):
    motion = mixamo_motion()
    path = tmp_path_factory.mktemp("mixamo") / "walk.bvh"
    bvh.save_bvh(path, motion)  # centimetres, y up: the writer's defaults
    return motion, path


def _strip_names(motion: mocap.Motion) -> mocap.Motion:
    return dataclasses.replace(motion, joint_names=tuple(f"j{k}" for k in range(motion.num_joints)))


# ---------------------------------------------------------------------------------------------------------------
# Names


@pytest.mark.parametrize(
    ("name", "side", "stem"),
    [
        ("mixamorig:LeftUpLeg", "left", "upleg"),
        ("Hand_L", "left", "hand"),
        ("UpperArm_R", "right", "upperarm"),
        ("Bip01 L Thigh", "left", "thigh"),
        ("Bip01 Pelvis", None, "pelvis"),
        ("lfemur", "left", "femur"),
        ("rradius", "right", "radius"),
        ("lowerneck", None, "lowerneck"),
        ("LFArm", "left", "farm"),
        ("LUArm", "left", "uarm"),
        ("Skeleton_001_RShin", "right", "shin"),
        ("m_avg_L_Knee", "left", "knee"),
        ("RightUpperLeg", "right", "upperleg"),
        ("thigh_l", "left", "thigh"),
        ("Neck1", None, "neck1"),
        ("LeftHandThumb1", "left", "handthumb1"),
        ("Head", None, "head"),
    ],
)
def test_split_name(name, side, stem):
    assert skeletons.split_name(name) == (side, stem)


# CMU cgspeed joints renamed in each convention (only the joints that matter; the others become b<k>), as the
# vendors document them: SMPL exports, Xsens MVN, Rokoko/MotionBuilder, OptiTrack Motive, 3ds Max Biped, UE4.
RENAMINGS = {
    "smpl": {
        "Hips": "m_avg_Pelvis",
        "Neck": "m_avg_Neck",
        "Head": "m_avg_Head",
        **{f"{s}Collar": f"m_avg_{c}_Collar" for s, c in (("Left", "L"), ("Right", "R"))},
        **{f"{s}Shoulder": f"m_avg_{c}_Shoulder" for s, c in (("Left", "L"), ("Right", "R"))},
        **{f"{s}Elbow": f"m_avg_{c}_Elbow" for s, c in (("Left", "L"), ("Right", "R"))},
        **{f"{s}Wrist": f"m_avg_{c}_Wrist" for s, c in (("Left", "L"), ("Right", "R"))},
        **{f"{c.lower()}hand": f"m_avg_{c}_Hand" for c in ("L", "R")},
        **{f"{s}Hip": f"m_avg_{c}_Hip" for s, c in (("Left", "L"), ("Right", "R"))},
        **{f"{s}Knee": f"m_avg_{c}_Knee" for s, c in (("Left", "L"), ("Right", "R"))},
        **{f"{s}Ankle": f"m_avg_{c}_Ankle" for s, c in (("Left", "L"), ("Right", "R"))},
        **{f"{s}Toe": f"m_avg_{c}_Foot" for s, c in (("Left", "L"), ("Right", "R"))},
    },
    "mvn": {
        "Hips": "Hips",
        "Neck": "Neck",
        "Head": "Head",
        **{f"{s}Collar": f"{s}Shoulder" for s in ("Left", "Right")},
        **{f"{s}Shoulder": f"{s}UpperArm" for s in ("Left", "Right")},
        **{f"{s}Elbow": f"{s}ForeArm" for s in ("Left", "Right")},
        **{f"{s}Wrist": f"{s}Hand" for s in ("Left", "Right")},
        **{f"{s}Hip": f"{s}UpperLeg" for s in ("Left", "Right")},
        **{f"{s}Knee": f"{s}LowerLeg" for s in ("Left", "Right")},
        **{f"{s}Ankle": f"{s}Foot" for s in ("Left", "Right")},
        **{f"{s}Toe": f"{s}Toe" for s in ("Left", "Right")},
    },
    "rokoko": {
        "Hips": "Hips",
        "Neck": "Neck",
        "Head": "Head",
        **{f"{s}Collar": f"{s}Shoulder" for s in ("Left", "Right")},
        **{f"{s}Shoulder": f"{s}Arm" for s in ("Left", "Right")},
        **{f"{s}Elbow": f"{s}ForeArm" for s in ("Left", "Right")},
        **{f"{s}Wrist": f"{s}Hand" for s in ("Left", "Right")},
        **{f"{s}Hip": f"{s}UpLeg" for s in ("Left", "Right")},
        **{f"{s}Knee": f"{s}Leg" for s in ("Left", "Right")},
        **{f"{s}Ankle": f"{s}Foot" for s in ("Left", "Right")},
        **{f"{s}Toe": f"{s}ToeBase" for s in ("Left", "Right")},
    },
    "motive": {
        "Hips": "Skeleton_001_Hip",
        "Neck": "Skeleton_001_Neck",
        "Head": "Skeleton_001_Head",
        **{f"{s}Collar": f"Skeleton_001_{s[0]}Shoulder" for s in ("Left", "Right")},
        **{f"{s}Shoulder": f"Skeleton_001_{s[0]}UArm" for s in ("Left", "Right")},
        **{f"{s}Elbow": f"Skeleton_001_{s[0]}FArm" for s in ("Left", "Right")},
        **{f"{s}Wrist": f"Skeleton_001_{s[0]}Hand" for s in ("Left", "Right")},
        **{f"{s}Hip": f"Skeleton_001_{s[0]}Thigh" for s in ("Left", "Right")},
        **{f"{s}Knee": f"Skeleton_001_{s[0]}Shin" for s in ("Left", "Right")},
        **{f"{s}Ankle": f"Skeleton_001_{s[0]}Foot" for s in ("Left", "Right")},
        **{f"{s}Toe": f"Skeleton_001_{s[0]}Toe" for s in ("Left", "Right")},
    },
    "biped": {
        "Hips": "Bip01 Pelvis",
        "Neck": "Bip01 Neck",
        "Head": "Bip01 Head",
        **{f"{s}Collar": f"Bip01 {s[0]} Clavicle" for s in ("Left", "Right")},
        **{f"{s}Shoulder": f"Bip01 {s[0]} UpperArm" for s in ("Left", "Right")},
        **{f"{s}Elbow": f"Bip01 {s[0]} Forearm" for s in ("Left", "Right")},
        **{f"{s}Wrist": f"Bip01 {s[0]} Hand" for s in ("Left", "Right")},
        **{f"{s}Hip": f"Bip01 {s[0]} Thigh" for s in ("Left", "Right")},
        **{f"{s}Knee": f"Bip01 {s[0]} Calf" for s in ("Left", "Right")},
        **{f"{s}Ankle": f"Bip01 {s[0]} Foot" for s in ("Left", "Right")},
        **{f"{s}Toe": f"Bip01 {s[0]} Toe0" for s in ("Left", "Right")},
    },
    "ue4": {
        "Hips": "pelvis",
        "Neck": "neck_01",
        "Head": "head",
        **{f"{s}Collar": f"clavicle_{s[0].lower()}" for s in ("Left", "Right")},
        **{f"{s}Shoulder": f"upperarm_{s[0].lower()}" for s in ("Left", "Right")},
        **{f"{s}Elbow": f"lowerarm_{s[0].lower()}" for s in ("Left", "Right")},
        **{f"{s}Wrist": f"hand_{s[0].lower()}" for s in ("Left", "Right")},
        **{f"{s}Hip": f"thigh_{s[0].lower()}" for s in ("Left", "Right")},
        **{f"{s}Knee": f"calf_{s[0].lower()}" for s in ("Left", "Right")},
        **{f"{s}Ankle": f"foot_{s[0].lower()}" for s in ("Left", "Right")},
        **{f"{s}Toe": f"ball_{s[0].lower()}" for s in ("Left", "Right")},
    },
}


@pytest.fixture(scope="module")
def cmu_bvh():
    return bvh.motion_from_bvh(bvh.read_bvh(CMU / "131_01.bvh"), scale=bvh.CMU_BVH_SCALE)


@pytest.mark.parametrize("convention", sorted(RENAMINGS))
def test_name_conventions_place_the_cmu_joints(cmu_bvh, convention):
    """Renamed in another convention, the CMU skeleton's evaluation joints are found by name at the same joints
    (the upper neck stands in for the base of the neck, as those skeletons have no lower-neck joint)."""
    table = RENAMINGS[convention]
    names = tuple(table.get(n, f"b{k}") for k, n in enumerate(cmu_bvh.joint_names))
    found, family = skeletons.match_names(names, cmu_bvh.parents)
    assert family == ("motionbuilder" if convention == "rokoko" else "names")
    assert set(found) == set(EVAL_JOINTS)
    expected = {**mocap.CMU_BVH_3DSMAX_EVAL, "thorax": "Neck"}
    for joint, spec in expected.items():
        want = mocap.spec_joints(spec)[0]
        assert mocap.spec_joints(found[joint])[0] == table[want], joint


def test_known_families_by_exact_name(cmu_bvh):
    assert skeletons.match_names(cmu_bvh.joint_names, cmu_bvh.parents)[1] == "cmu_bvh_3dsmax"
    skel = asfamc.read_asf(CMU / "02.asf")
    m = asfamc.motion_from_asfamc(skel, asfamc.read_amc(CMU / "02_01.amc", skel)[0], "deg", fps=120)
    assert skeletons.match_names(m.joint_names, m.parents)[1] == "cmu_asf"


# ---------------------------------------------------------------------------------------------------------------
# Real and written files


@pytest.fixture(scope="module")
def bandai():
    return skeletons.load_mocap(BANDAI)


def test_bandai_excerpt_joints_agree_with_bvhio(bandai):
    """The 15 joints of the Bandai-Namco excerpt (position channels replacing offsets, a static joint_Root above
    the hips, centimetres) are where bvhio's forward kinematics puts the named joints."""
    m, rec = bandai
    assert rec.family == "bandai_namco"
    assert (rec.scale, rec.scale_source, rec.up_axis) == (0.01, "detected", "y")
    assert m.joint_names[0] == "Hips" and "joint_Root" not in m.joint_names
    ev = mocap.eval_joints(m, rec.mapping)
    root = bvhio.readAsHierarchy(str(BANDAI))
    names = [j.Name for j, _, _ in root.layout()]
    for frame in (0, 22, 44):
        root.loadPose(frame)
        world = {
            n: 0.01 * A @ np.array([*j.PositionWorld])
            for n, (j, _, _) in zip(names, root.layout(), strict=True)
        }
        for joint in EVAL_JOINTS:
            if joint == "head":
                continue
            np.testing.assert_allclose(ev[frame, I[joint]], world[rec.mapping[joint]], atol=2e-6)
        # the head (the file's head end site has no length): a nominal bone above the Head joint
        head = world["Head"]
        assert np.linalg.norm(ev[frame, I["head"]] - head) == pytest.approx(
            skeletons.NOMINAL_HEAD_BONE / 2, abs=1e-5
        )
        assert ev[frame, I["head"], 2] - head[2] > 0.8 * skeletons.NOMINAL_HEAD_BONE / 2


def test_bandai_rest_pose_moved_to_a_standing_frame(bandai):
    """The file's rest pose lays the body along x; after loading, the rest pose is a frame of the clip (rest
    joints equal that frame's joints) and stands."""
    m, rec = bandai
    rest = mocap.rest_eval_joints(m, rec.mapping)
    frame = np.argmin(np.abs(mocap.eval_joints(m, rec.mapping) - rest).max(axis=(1, 2)))
    np.testing.assert_allclose(mocap.eval_joints(m, rec.mapping)[frame], rest, atol=1e-9)
    assert rest[I["head"], 2] > rest[I["thorax"], 2] > rest[I["root"], 2] > rest[I["left_knee"], 2]


def test_mixamo_bvh_written_by_the_project_imports_with_its_joints(mixamo):
    motion, path = mixamo
    m, rec = skeletons.load_mocap(path)
    assert rec.family == "mixamo"
    assert rec.mapping == {k: _prefixed(v) for k, v in MIXAMO_EXPECTED.items()}
    assert (rec.scale, rec.up_axis) == (0.01, "y")
    ev = mocap.eval_joints(m, rec.mapping)
    np.testing.assert_allclose(ev, mocap.eval_joints(motion, rec.mapping), atol=1e-5)  # written to 1e-6 cm


def test_shape_alone_places_the_same_joints(mixamo, cmu_bvh):
    """With every name replaced by j<k>, the tree's shape finds the joints the names find."""
    raw_mixamo = bvh.motion_from_bvh(bvh.read_bvh(mixamo[1]), scale=1.0)
    raw_bandai = bvh.motion_from_bvh(bvh.read_bvh(BANDAI), scale=1.0)
    cmu_asf = asfamc.load_asfamc(CMU / "02.asf", CMU / "02_01.amc")
    for motion in (raw_mixamo, raw_bandai, cmu_bvh, cmu_asf):
        by_name = skeletons.recognise(motion).mapping
        rec = skeletons.recognise(_strip_names(motion))
        assert rec.family == "shape"
        index = {n: f"j{k}" for k, n in enumerate(motion.joint_names)}
        assert rec.mapping == {
            k: index[v] if isinstance(v, str) else (v[0], *(index[n] for n in v[1:]))
            for k, v in by_name.items()
        }


# ---------------------------------------------------------------------------------------------------------------
# Units and axes


@pytest.mark.parametrize(("scale", "name"), [(0.001, "mm"), (0.01, "cm"), (0.0254, "inch"), (1.0, "m")])
def test_unit_detection(tmp_path, scale, name):
    motion = mixamo_motion(slice(0, 16, 8))
    path = tmp_path / f"{name}.bvh"
    bvh.save_bvh(path, motion, scale=scale)
    m, rec = skeletons.load_mocap(path)
    assert rec.scale == skeletons.UNIT_CANDIDATES[name]
    np.testing.assert_allclose(m.positions, skeletons.load_mocap(path, scale=scale)[0].positions, atol=1e-9)


def test_cmu_unit_detected(cmu_bvh):
    m, rec = skeletons.load_mocap(CMU / "131_01.bvh")
    assert rec.scale == bvh.CMU_BVH_SCALE and rec.family == "cmu_bvh_3dsmax"


def test_z_up_file_detected(tmp_path):
    motion = mixamo_motion(slice(0, 16, 8))
    path = tmp_path / "zup.bvh"
    bvh.save_bvh(path, motion, up_axis="z")
    m, rec = skeletons.load_mocap(path)
    assert rec.up_axis == "z"
    order = [motion.joint_index(n) for n in m.joint_names]
    np.testing.assert_allclose(m.positions, motion.positions[:, order], atol=1e-6)


def test_unit_error_for_a_giant(tmp_path):
    motion = mixamo_motion(slice(0, 16, 8))
    path = tmp_path / "giant.bvh"
    bvh.save_bvh(path, motion, scale=1e-5)
    with pytest.raises(MocapInputError, match="cannot tell the length unit"):
        skeletons.load_mocap(path)


# ---------------------------------------------------------------------------------------------------------------
# Motion operations


def test_reroot_and_rebase_keep_world_positions(cmu_bvh):
    m = cmu_bvh
    sub = skeletons.reroot(m, "LeftHip")
    idx = [m.joint_index(n) for n in sub.joint_names]
    np.testing.assert_allclose(sub.positions, m.positions[:, idx], atol=1e-12)
    re = skeletons.rebase_rest(m, 100)
    np.testing.assert_allclose(re.positions, m.positions, atol=1e-12)
    np.testing.assert_allclose(re.end_positions, m.end_positions, atol=1e-12)
    X, E = mocap.rest_positions(re)
    np.testing.assert_allclose(X, m.positions[100], atol=1e-12)
    np.testing.assert_allclose(E, m.end_positions[100], atol=1e-12)


# ---------------------------------------------------------------------------------------------------------------
# Mapping files and errors


def test_mapping_file_overrides_and_fills(tmp_path, mixamo):
    _, path = mixamo
    raw = bvh.motion_from_bvh(bvh.read_bvh(path), scale=0.01)
    renamed = dataclasses.replace(
        raw, joint_names=tuple("Xarm" if n == "mixamorig:LeftArm" else n for n in raw.joint_names)
    )
    mapping = tmp_path / "map.toml"
    mapping.write_text('left_shoulder = "Xarm"\nhead = ["mixamorig:Head", "mixamorig:HeadTop_End"]\n')
    rec = skeletons.recognise(renamed, skeletons.load_mapping(mapping))
    assert rec.mapping["left_shoulder"] == "Xarm" and rec.sources["left_shoulder"] == "file"
    assert rec.mapping["left_elbow"] == "mixamorig:LeftForeArm" and rec.sources["left_elbow"] == "names"


def test_mapping_file_errors(tmp_path, cmu_bvh):
    bad = tmp_path / "bad.toml"
    bad.write_text('left_thumb = "LThumb"\n')
    with pytest.raises(MocapInputError, match="unknown evaluation joint 'left_thumb'"):
        skeletons.load_mapping(bad)
    bad.write_text('left_wrist = "NoSuchJoint"\n')
    with pytest.raises(MocapInputError, match="left_wrist = 'NoSuchJoint': no such joint"):
        skeletons.recognise(cmu_bvh, skeletons.load_mapping(bad))
    bad.write_text("left_wrist = [")
    with pytest.raises(MocapInputError, match="not valid TOML"):
        skeletons.load_mapping(bad)


def test_error_names_the_joints_it_cannot_place(tmp_path):
    """A lone arm: no name or shape places most joints; one line names them."""
    path = tmp_path / "arm.bvh"
    names = ("Base", "Upper", "Lower", "Hand")
    offsets = np.array([[0.0, 100.0, 0.0], [20.0, 0.0, 0.0], [30.0, 0.0, 0.0], [25.0, 0.0, 0.0]])
    channels = (("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"),) + (
        ("Zrotation", "Yrotation", "Xrotation"),
    ) * 3
    bvh.save_bvh(
        path, (names, (-1, 0, 1, 2), offsets, channels, np.zeros((2, 15)), [3], [[10, 0, 0]]), fps=30
    )
    with pytest.raises(MocapInputError) as e:
        skeletons.load_mocap(path)
    msg = str(e.value)
    assert "\n" not in msg and str(path) in msg
    assert "cannot place the evaluation joints root, thorax, head, left_shoulder" in msg
    assert "--mapping" in msg
