"""Synthetic sequences: depth against an analytic float64 ray–primitive intersection written here, masks and
labels against that depth, ground-truth joints against the silhouettes through OpenCV's projection of the written
calibration, ground truth against the clip's forward kinematics, rigs, byte-identical reruns, the command.

Everything renders the bundled CMU walk at 160×120 so the ray caster compiles once for the file.
"""

import pathlib
import tomllib

import cv2
import numpy as np
import pytest

import jaxmocap.parsec  # noqa: F401  (registers the PARSEC .cal camera reader)
from jaxmocap import cli
from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import body, camera
from jaxmocap.io import asfamc, calibration
from jaxmocap.io import sequence as seqio
from jaxmocap.io.bvh import CMU_BVH_SCALE, load_bvh
from jaxmocap.io.mocap import eval_joints
from jaxmocap.synth import generate as synth

SIZE = (160, 120)
EVAL_JOINTS_INDEX = {n: i for i, n in enumerate(body.EVAL_JOINTS)}


@pytest.fixture(scope="module")
def exact(tmp_path_factory):
    """Three frames per view of each preset without depth noise or smoothing (depth = exact z to the mm)."""
    out = {}
    for rig in synth.PRESETS:
        root = tmp_path_factory.mktemp(f"exact_{rig}")
        out[rig] = synth.synthesize(
            "demo", root, rig=rig, frames="150:162", size=SIZE, depth_noise=0.0, depth_smooth=0.0, seed=3
        )
    return out


def _opencv_cameras(root):
    """Cameras read from the written TOML with tomllib and OpenCV only: name -> (K, dist, R, t, (w, h))."""
    doc = tomllib.loads((pathlib.Path(root) / "calibration.toml").read_text())
    cams = {}
    for key, cam in doc.items():
        if key == "metadata":
            continue
        R = cv2.Rodrigues(np.asarray(cam["rotation"], np.float64))[0]
        size = tuple(int(s) for s in cam["size"])
        cams[cam["name"]] = (
            np.asarray(cam["matrix"]),
            np.asarray(cam["distortions"]),
            R,
            np.asarray(cam["translation"]),
            size,
        )
    return cams


def _reference_hits(o, d, gt, t):
    """Nearest hit ``(τ, label, τ per primitive)`` of rays ``o + τ d`` (``d`` with camera-z component 1, so ``τ``
    is the depth) with the frame's sphere-capped cones and ellipsoid, in float64, by solving each quadric in
    closed form."""
    a, b = gt["scene_cone_a"][t].astype(np.float64), gt["scene_cone_b"][t].astype(np.float64)
    ra, rb = gt["scene_cone_r_a"].astype(np.float64), gt["scene_cone_r_b"].astype(np.float64)
    best = np.full(len(d), np.inf)
    label = np.full(len(d), -1)
    per = np.full((len(d), len(ra) + gt["scene_ellipsoid_centre"].shape[1]), np.inf)

    def first_root(A, B, C):  # smallest positive root of A τ² + B τ + C
        disc = B * B - 4 * A * C
        s = np.sqrt(np.where(disc >= 0, disc, np.nan))
        r = np.stack([(-B - s) / (2 * A), (-B + s) / (2 * A)])
        return r, disc >= 0

    def update(tau, ok, lab):
        tau = np.where(ok & (tau > 0), tau, np.inf)
        per[:, lab] = np.minimum(per[:, lab], tau)
        better = tau < best
        best[better] = tau[better]
        label[better] = lab

    for c in range(len(ra)):
        L = np.linalg.norm(b[c] - a[c])
        u = (b[c] - a[c]) / L
        k = (rb[c] - ra[c]) / L
        w = o - a[c]
        wu, du = w @ u, d @ u
        wp, dp = w - wu * u, d - du[:, None] * u
        rho0 = ra[c] + k * wu  # radius at the axial coordinate of the camera centre
        A = np.sum(dp * dp, -1) - (k * du) ** 2
        B = 2 * (dp @ wp - k * rho0 * du)
        C = wp @ wp - rho0**2
        roots, ok = first_root(A, B, C)
        for r in roots:
            s = wu + r * du
            update(r, ok & (s >= 0) & (s <= L) & (rho0 + k * r * du >= 0), c)
        for centre, rad in ((a[c], ra[c]), (b[c], rb[c])):
            w = o - centre
            roots, ok = first_root(np.sum(d * d, -1), 2 * d @ w, w @ w - rad**2)
            update(roots[0], ok, c)
    for e in range(gt["scene_ellipsoid_centre"].shape[1]):
        Minv = np.linalg.inv(gt["scene_ellipsoid_axes"][t, e].astype(np.float64))
        oo = Minv @ (o - gt["scene_ellipsoid_centre"][t, e])
        dd = d @ Minv.T
        roots, ok = first_root(np.sum(dd * dd, -1), 2 * dd @ oo, oo @ oo - 1)
        update(roots[0], ok, len(ra) + e)
    return np.where(np.isfinite(best), best, 0.0), label, per


@pytest.mark.parametrize("rig", synth.PRESETS)
def test_depth_and_labels_equal_analytic_intersection(exact, rig):
    seq = exact[rig]
    cams = _opencv_cameras(seq.root)
    with np.load(seq.root / "groundtruth.npz") as z:
        gt = {k: z[k] for k in z.files}
    rng = np.random.default_rng(0)
    for t in range(seq.num_frames):
        for view in seq.views:
            K, dist, R, tv, (w, h) = cams[view.name]
            labels = view.labels(t)
            mask = view.mask(t)
            depth = view.depth(t)
            # pixels on the body and around it, away from the silhouette edge (where a ray grazes a surface)
            inner = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
            outer = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
            ring = cv2.dilate(mask.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
            candidates = np.flatnonzero(inner | (ring & ~outer))
            pix = rng.choice(candidates, size=min(300, len(candidates)), replace=False)
            v, u = np.unravel_index(pix, mask.shape)
            xy = cv2.undistortPointsIter(
                np.stack([u, v], -1).astype(np.float64)[:, None],
                K,
                dist,
                None,
                None,
                (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12),
            )[:, 0]
            d_cam = np.concatenate([xy, np.ones((len(xy), 1))], -1)
            o = -R.T @ tv
            tau, lab, per = _reference_hits(o, d_cam @ R, gt, t)
            hit = lab >= 0
            np.testing.assert_array_equal(mask[v, u], hit)
            # the label is the nearest primitive; where two surfaces meet (a joint between cones of equal
            # radius) either of them, i.e. the labelled primitive's own hit is the nearest one
            got = labels[v, u][hit]
            ok = (got == lab[hit]) | (per[hit, got] - tau[hit] < 1e-4)
            assert ok.all() and np.mean(got == lab[hit]) > 0.95
            # the PNG stores millimetres: rounding (0.5 mm) plus float32 ray casting
            np.testing.assert_allclose(depth[v, u][hit], tau[hit], atol=1e-3, rtol=0)
            assert np.all(depth[v, u][~hit] == 0)


def test_mask_is_depth_positive_and_labels_agree(exact, tmp_path):
    """With the default virtual depth sensor (smoothing 1.5 px, noise 2 cm): mask = depth > 0 = labels ≥ 0 in
    every image; against the same sensor without noise the depth differs by N(0, 0.02²) (mean and standard
    deviation within 4 standard errors, plus the millimetre rounding)."""
    kw = dict(rig="ring4", frames="150:162", size=SIZE, seed=3)
    seq = synth.synthesize("demo", tmp_path / "noisy", clutter="low", **kw)
    smooth = synth.synthesize("demo", tmp_path / "smooth", depth_noise=0.0, **kw)
    noise = []
    for view, ref, ex in zip(seq.views, smooth.views, exact["ring4"].views, strict=True):
        for t in range(seq.num_frames):
            mask, depth, labels = view.mask(t), view.depth(t), view.labels(t)
            assert mask.any()
            np.testing.assert_array_equal(mask, depth > 0)
            np.testing.assert_array_equal(mask, labels >= 0)
            np.testing.assert_array_equal(labels, ex.labels(t))
            noise.append((depth - ref.depth(t))[mask])
    noise = np.concatenate(noise).astype(np.float64)
    n = len(noise)
    assert n > 1000
    assert abs(np.mean(noise)) < 4 * 0.02 / np.sqrt(n) + 5e-4
    assert abs(np.std(noise) - 0.02) < 4 * 0.02 / np.sqrt(2 * n) + 5e-4


@pytest.mark.parametrize("rig", synth.PRESETS)
def test_ground_truth_joints_project_on_the_silhouette(exact, rig):
    seq = exact[rig]
    cams = _opencv_cameras(seq.root)
    joints = seq.groundtruth.joints
    for view in seq.views:
        K, dist, R, tv, (w, h) = cams[view.name]
        uv, _ = cv2.projectPoints(joints.reshape(-1, 3), cv2.Rodrigues(R)[0], tv, K, dist)
        uv = uv.reshape(seq.num_frames, 15, 2)
        for t in range(seq.num_frames):
            mask = view.mask(t)
            px = np.rint(uv[t]).astype(int)
            inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
            assert inside.all(), "the presets keep the whole body in view"
            assert mask[px[:, 1], px[:, 0]].all()


def test_ground_truth_is_the_clip_forward_kinematics(exact):
    seq = exact["stereo"]
    amc, asf = synth.demo_clip()
    motion = asfamc.load_asfamc(asf, amc)
    frames = np.arange(150, 162, 4)  # 120 fps -> 30 fps
    gt = seq.groundtruth
    np.testing.assert_array_equal(gt.extra["frame_index"], frames)
    np.testing.assert_allclose(gt.joints, eval_joints(motion)[frames], atol=1e-12)
    np.testing.assert_allclose(gt.all_joints, motion.positions[frames], atol=1e-12)
    assert gt.all_joint_names == motion.joint_names and gt.joint_names == body.EVAL_JOINTS
    assert seq.fps == 30.0 and seq.meta["source"]["clip"] == "02_01.amc"
    assert "mocap.cs.cmu.edu" in seq.meta["source"]["licence"]
    # the body file the trackers load: the subject's measured lengths and the rendered radii
    doc = tomllib.loads(seq.body_path.read_text())
    assert doc["model"] == "full25"
    dims = doc["dimensions"]
    model = body.full25(dims)
    assert model.name == "full25"
    thigh = np.linalg.norm(gt.joints[0, 9] - gt.joints[0, 10])
    assert dims["left_thigh_length"] == pytest.approx(thigh, abs=1e-6)
    assert dims["thigh_radius_top"] == synth.ROLE_RADII["thigh"][0]
    # the model's head centre is the rendered head's centre (the middle of the head bone)
    head = np.asarray(gt.extra["scene_ellipsoid_centre"])[0, 0]
    np.testing.assert_allclose(head, gt.joints[0, 2], atol=1e-5)


def test_rig_presets_geometry():
    amc, asf = synth.demo_clip()
    motion = asfamc.load_asfamc(asf, amc)
    frames = np.arange(0, motion.num_frames)
    joints = eval_joints(motion)[frames]
    points = motion.positions[frames]
    c, f, left = synth.subject_frame(joints)
    # CMU subject 2 walks along +x in the z-up world (the file's +z), so that is where it faces
    assert f @ [1, 0, 0] > 0.95
    root = joints[:, 0]
    stereo = synth.preset_rig("stereo", points, joints, (640, 480))
    centres = np.einsum("vji,vj->vi", stereo.R, -np.asarray(stereo.t))  # C = -Rᵀ t
    assert np.linalg.norm(centres[0] - centres[1]) == pytest.approx(0.30, abs=1e-5)
    assert centres[:, 2] == pytest.approx([1.3, 1.3], abs=1e-6)
    np.testing.assert_allclose(stereo.R[0], stereo.R[1], atol=1e-12)
    horizontal = np.linalg.norm(root[:, None, :2] - centres[None, :, :2], axis=-1)
    assert horizontal.min() >= 2.5 - 1e-6
    fl = synth.preset_rig("frontal-lateral", points, joints, (640, 480))
    axes = np.asarray(fl.R)[:, 2]
    assert abs(axes[0] @ axes[1]) < 0.05  # frontal and lateral views are perpendicular
    assert axes[0] @ f < -0.95 and axes[1] @ left < -0.95  # looking back at the subject
    assert all(-0.3 < a[2] < -0.05 for a in axes)  # a slight down-tilt
    # in the frontal view the subject's left side appears on the image's right
    uv = np.asarray(camera.project(fl.to_jax(np.float32), joints[100].astype(np.float32)))
    assert uv[0, 9, 0] > uv[0, 12, 0]
    ring = synth.preset_rig("ring4", points, joints, (640, 480))
    centres = np.einsum("vji,vj->vi", ring.R, -np.asarray(ring.t))
    assert ring.num_views == 4 and centres[:, 2] == pytest.approx([2.5] * 4)
    radius = np.linalg.norm(centres[:, :2] - c[:2], axis=-1)
    assert radius.min() >= 3.5 - 1e-9 and np.ptp(radius) < 1e-9
    for rig in (stereo, fl, ring):
        uv = np.asarray(camera.project(rig.to_jax(np.float32), points.reshape(-1, 3).astype(np.float32)))
        assert np.all((uv[..., 0] > 0) & (uv[..., 0] < 639) & (uv[..., 1] > 0) & (uv[..., 1] < 479))


def test_two_runs_with_one_seed_are_byte_identical(tmp_path):
    kw = dict(rig="stereo", frames="200:208", size=SIZE, clutter="low", illumination=0.2, blur=2)
    a = synth.synthesize("demo", tmp_path / "a", seed=11, **kw).root
    b = synth.synthesize("demo", tmp_path / "b", seed=11, **kw).root
    c = synth.synthesize("demo", tmp_path / "c", seed=12, **kw).root
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert len(files) == 4 + 2 * (
        1 + 5 * 2
    )  # 4 sequence files; 2 views x (a plate + (4 images + detections) x 2 frames)
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    # another seed: other noise and clutter, the same geometry
    rgb = pathlib.Path("views/left/rgb/000001.png")
    assert (a / rgb).read_bytes() != (c / rgb).read_bytes()
    for rel in ("views/left/mask/000001.png", "views/right/labels/000000.png", "groundtruth.npz"):
        assert (a / rel).read_bytes() == (c / rel).read_bytes()


def test_calibration_file_rig(tmp_path, data_dir):
    """PARSEC's four calibrated cameras (640×480, strong radial distortion), rendered at 160×120."""
    seq = synth.synthesize(
        "demo", tmp_path, rig=data_dir / "calib" / "parsec" / "CALIB", frames="150:152", size=SIZE
    )
    ref = calibration.load_calibration(data_dir / "calib" / "parsec" / "CALIB")
    assert seq.rig.names == ref.names and seq.rig.image_size == (SIZE,) * 4
    np.testing.assert_allclose(np.asarray(seq.rig.R), np.asarray(ref.R), atol=1e-12)
    np.testing.assert_allclose(np.asarray(seq.rig.K)[:, 0, 0], np.asarray(ref.K)[:, 0, 0] / 4, rtol=1e-12)
    offset = np.asarray(seq.meta["world_offset"])
    assert offset[2] == 0
    cams = _opencv_cameras(seq.root)
    for view in seq.views:
        K, dist, R, tv, (w, h) = cams[view.name]
        mask = view.mask(0)
        assert mask.sum() > 30
        uv, _ = cv2.projectPoints(seq.groundtruth.joints[0], cv2.Rodrigues(R)[0], tv, K, dist)
        px = np.rint(uv[:, 0]).astype(int)
        inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
        assert mask[px[inside, 1], px[inside, 0]].all()


def test_simulated_detections_are_written_near_the_truth(exact):
    """Every view has BODY_25B JSON per frame, read by the project's OpenPose reader; each detected limb keypoint
    lies within 6 σ of the OpenCV projection of its ground-truth joint (σ at most 3 × 3 px × the largest COCO
    constant × the distance factor at 10 m), or at the opposite side's joint where swapped."""
    from jaxmocap.io import openpose

    seq = exact["ring4"]
    assert seq.meta["detections"]["simulated"] is True
    cams = _opencv_cameras(seq.root)
    limb = {
        n: EVAL_JOINTS_INDEX[j]
        for j, n in ((j, openpose.BODY_25B_KEYPOINTS[k]) for j, k in openpose.BODY_25B_OF_JOINT.items())
        if j != "thorax"
    }
    bound = 6 * 3 * 3.0 * SIZE[0] / 640 * (0.107 / 0.072) * (1 + 0.2 * 8)
    found = 0
    for view in seq.views:
        det = openpose.load_openpose_folder(seq.root / "views" / view.name / "openpose")
        assert det.shape == (seq.num_frames, 25, 3)
        K, dist, R, tv, _ = cams[view.name]
        for t in range(seq.num_frames):
            uv, _ = cv2.projectPoints(seq.groundtruth.joints[t], cv2.Rodrigues(R)[0], tv, K, dist)
            uv = uv[:, 0]
            for name, j in limb.items():
                k = openpose.BODY_25B_INDEX[name]
                if det[t, k, 2] > 0:
                    other = limb[("R" if name[0] == "L" else "L") + name[1:]]
                    err = min(
                        np.linalg.norm(det[t, k, :2] - uv[j]), np.linalg.norm(det[t, k, :2] - uv[other])
                    )
                    assert err < bound, (view.name, t, name, err)
                    found += 1
    assert found > 0.5 * len(seq.views) * seq.num_frames * len(limb)


def test_dressing_of_cmu_skeletons(data_dir):
    amc, asf = synth.demo_clip()
    for motion in (
        asfamc.load_asfamc(asf, amc),
        load_bvh(data_dir / "cmu" / "131_01.bvh", scale=CMU_BVH_SCALE),
        asfamc.load_asfamc(data_dir / "cmu" / "charleston.asf", data_dir / "cmu" / "charleston1.amc"),
    ):
        d = synth.dress(motion)
        roles = d.part_roles
        assert "limb" not in roles and roles[-1] == "head" and len(set(d.part_names)) == len(d.part_names)
        for role in ("torso", "pelvis", "clavicle", "upper_arm", "forearm", "hand", "thigh", "shin", "foot"):
            assert roles.count(role) >= (1 if role == "torso" else 2), (motion.source, role)
        colours = d.colours()
        skin = [i for i, r in enumerate(roles) if r in ("hand", "finger", "thumb", "head", "neck")]
        assert np.allclose(colours[skin], synth.ROLE_COLOURS["head"])
        assert not np.allclose(colours[roles.index("thigh")], synth.ROLE_COLOURS["head"])


def test_dressing_of_other_skeletons(data_dir):
    """The Bandai-Namco excerpt's parts follow its recognised joints (its names say little: ``Shoulder_L`` is a
    clavicle, ``LowerArm_L`` a forearm)."""
    m, rec = synth.load_clip(data_dir / "bandai" / "dataset-1_walk_normal_001_excerpt.bvh")
    d = synth.dress(m, rec.mapping)
    role = dict(zip(d.part_names, d.part_roles, strict=True))
    assert role["Shoulder_L"] == "clavicle" and role["UpperArm_L"] == "upper_arm"
    assert role["LowerArm_L"] == "forearm" and role["UpperLeg_R"] == "thigh" and role["LowerLeg_R"] == "shin"
    assert role["Foot_L"] == "foot" and role["Neck"] == "neck" and "joint_Root" not in role
    assert role["Hand_L"] == role["Hand_R"] == "hand"  # a nominal hand past the bare wrist
    assert "limb" not in d.part_roles and d.part_roles[-1] == "head"


def test_command_any_skeleton(tmp_path, data_dir, capsys):
    """``--mapping`` names joints for the clip; a joint the file lacks is one line and status 2."""
    clip = data_dir / "bandai" / "dataset-1_walk_normal_001_excerpt.bvh"
    mapping = tmp_path / "map.toml"
    mapping.write_text('left_wrist = "Hand_L"\nright_wrist = "Hand_R"\n')
    out = tmp_path / "seq"
    argv = ["synth", "--motion", str(clip), "--frames", "0:2", "--size", "160x120", "--quiet"]
    assert cli.main([*argv, "--mapping", str(mapping), "--out", str(out)]) == 0
    meta = seqio.load_sequence(out).meta
    assert meta["source"]["skeleton"]["family"] == "file+bandai_namco"
    assert meta["source"]["skeleton"]["scale"] == 0.01 and "CC BY-NC" in meta["source"]["licence"]
    mapping.write_text('left_wrist = "Wrist_L"\n')
    capsys.readouterr()
    assert cli.main([*argv, "--mapping", str(mapping), "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "left_wrist = 'Wrist_L': no such joint" in err and str(clip) in err


def test_options_are_checked(tmp_path):
    assert synth.parse_frames("10:20", 100) == (10, 20)
    assert synth.parse_frames(":-10", 100) == (0, 90)
    assert synth.parse_size("320x240") == (320, 240)
    assert synth.parse_clutter("high") == 1.0
    for bad in ("20:10", "a:b", "5"):
        with pytest.raises(ValueError):
            synth.parse_frames(bad, 100)
    with pytest.raises(ValueError):
        synth.parse_clutter(2)
    with pytest.raises(ValueError):
        synth.synthesize("demo", tmp_path / "x", fps=240.0)
    with pytest.raises(ValueError):
        synth.synthesize("demo", tmp_path / "x", rig="ring5")
    with pytest.raises(MocapInputError, match="nope.bvh"):
        synth.synthesize(tmp_path / "nope.bvh", tmp_path / "x")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("x")
    with pytest.raises(FileExistsError):
        synth.synthesize("demo", tmp_path / "full", frames="0:4", size=SIZE)


def test_command(tmp_path, capsys):
    out = tmp_path / "seq"
    argv = ["synth", "--motion", "demo", "--rig", "frontal-lateral", "--frames", "40:48", "--size", "160x120"]
    assert (
        cli.main([*argv, "--seed", "2", "--sleeves", "short", "--wrist-bands", "--quiet", "--out", str(out)])
        == 0
    )
    seq = seqio.load_sequence(out)
    assert seq.num_frames == 2 and seq.view_names == ("frontal", "lateral") and seq.meta["seed"] == 2
    assert seq.meta["sleeves"] == "short" and seq.meta["wrist_bands"]["width_m"] > 0
    assert cli.main([*argv, "--out", str(out)]) == 2  # not empty
    assert cli.main([*argv, "--fps", "0", "--overwrite", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "not empty" in err and "fps" in err and "Traceback" not in err


def test_demo_clip_is_not_shadowed_by_a_folder_named_demo(tmp_path, monkeypatch):
    """``jaxmocap demo --out demo`` creates ./demo before loading the bundled clip by its name."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "demo").mkdir()
    motion = synth.load_motion("demo")
    reference = synth.load_motion(synth.demo_clip()[0], synth.demo_clip()[1])
    np.testing.assert_array_equal(motion.positions, reference.positions)
