"""Real footage: a few frames of the Pose2Sim demo recording (tests/data/pose2sim_small, 1/8 scale, see its
PROVENANCE.md) tracked with full25 and compared with Pose2Sim's triangulated reference."""

from __future__ import annotations

import json
import pathlib

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import camera
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io.pose2sim import JOINT_OF_TRC, Pose2SimSource, reference_joints
from jaxmocap.io.subject import body_dimensions

DATA = pathlib.Path(__file__).parents[1] / "data" / "pose2sim_small"
CAMS = [f"cam0{c}" for c in range(1, 5)]
FRAMES = [0, 1, 2, 3]
SCALE = 0.125


def _source(cameras=None) -> Pose2SimSource:
    return Pose2SimSource(
        DATA / "calibration.toml",
        [DATA / "pose" / f"{c}_json" for c in CAMS],
        image_dirs=[DATA / "images" / c for c in CAMS],
        cameras=cameras,
        scale=SCALE,
        frames=FRAMES,
    )


def test_reference_reprojects_onto_detections():
    """The y-up .trc mapped to the z-up world and projected through the scaled rig lands on the scaled detections
    (Pose2Sim's own agreement is ≈ 10–17 px at full size, i.e. ≈ 1–2 px at 1/8)."""
    src = _source()
    _, markers, fps = reference_joints(DATA / "reference.trc")
    assert fps == 60.0
    rj = src.rig.to_jax(jnp.float32)
    errs = []
    for t in range(len(FRAMES)):
        for name, k in JOINT_OF_TRC.items():
            uv = np.asarray(camera.project(rj, jnp.asarray(markers[name][t][None], jnp.float32)))[:, 0]
            kp = src.keypoints[t, :, k]
            ok = kp[:, 2] > 0.3
            errs += list(np.linalg.norm(uv[ok] - kp[ok, :2], axis=-1))
    assert len(errs) > 100
    assert np.median(errs) < 2.5
    # the images are those the rig describes (cam01/02 padded from 1080 to 1088 before scaling)
    fd = src.read(0)
    assert [im.shape[1::-1] for im in fd.images] == [tuple(s) for s in src.rig.image_size]
    assert src.rig.image_size[0] == (136, 240)


def test_subject_is_the_nearest_person():
    """cam01/cam02 files also hold a bystander; the subject's hip is within 100 px of where the reference projects it (a bystander is > 300 px away)."""
    src = _source()
    _, markers, _ = reference_joints(DATA / "reference.trc")
    rj = src.full_rig.to_jax(jnp.float32)
    uv = np.asarray(camera.project(rj, jnp.asarray(markers["LHip"][0][None], jnp.float32)))[:, 0]
    assert np.all(
        np.linalg.norm(src.keypoints_full[0, :, EVAL_JOINTS.index("left_hip"), :2] - uv, axis=-1) < 100.0
    )


def test_body_dimensions_plausible():
    """Limb lengths from the triangulated detections of an adult: 0.2–0.6 m, shoulders wider than hips."""
    src = _source()
    d = body_dimensions(src.keypoints_full, src.full_rig)
    for k in ("upper_arm_length", "forearm_length", "thigh_length", "shin_length", "torso_length"):
        assert 0.2 < d[k] < 0.6, (k, d[k])
    assert d["shoulder_width"] > d["hip_width"] > 0.1


def test_missing_frame_is_an_input_error():
    with pytest.raises(MocapInputError):
        Pose2SimSource(
            DATA / "calibration.toml",
            [DATA / "pose" / f"{c}_json" for c in CAMS],
            image_dirs=[DATA / "images" / c for c in CAMS],
            scale=SCALE,
            frames=[0, 50],
        )


def _make_project(root: pathlib.Path) -> pathlib.Path:
    """A Pose2Sim project of the four stored frames at 1/8 scale: Config.toml (pose_model 'Body_with_feet', as
    Pose2Sim's current demo says, while the detections are BODY_25B), calibration/Calib_scaled.toml (the demo's
    calibration for 1/8-size images) with extrinsics/camNN_ext.jpg scene images (the stored backgrounds),
    videos/camNN.avi (cam01 and cam02 cropped to 130 px, as a codec crops its padding) and pose/camNN_json (the
    detections mapped to 1/8 size)."""
    import json

    from jaxmocap.io import calibration

    root.mkdir()
    (root / "Config.toml").write_text(
        "[project]\nframe_rate = 60\nframe_range = [0, 4]\nmulti_person = false\n\n"
        "[pose]\npose_model = 'Body_with_feet'\n"
    )
    (root / "calibration" / "extrinsics").mkdir(parents=True)
    rig = camera.scale_images(calibration.load_calibration(DATA / "calibration.toml"), SCALE)
    calibration.save_calibration(root / "calibration" / "Calib_scaled.toml", rig)
    (root / "videos").mkdir()
    for v, c in enumerate(CAMS):
        bg = cv2.imread(str(DATA / "background" / f"{c}.jpg"), cv2.IMREAD_COLOR)
        cv2.imwrite(str(root / "calibration" / "extrinsics" / f"{c}_ext.jpg"), bg)
        w, h = rig.image_size[v]
        w = 130 if v < 2 else w
        vw = cv2.VideoWriter(str(root / "videos" / f"{c}.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 60.0, (w, h))
        for f in FRAMES:
            vw.write(cv2.imread(str(DATA / "images" / c / f"{f:04d}.jpg"), cv2.IMREAD_COLOR)[:, :w])
        vw.release()
        out = root / "pose" / f"{c}_json"
        out.mkdir(parents=True)
        for src in sorted((DATA / "pose" / f"{c}_json").glob("*.json")):
            doc = json.loads(src.read_text())
            for p in doc["people"]:
                kp = np.asarray(p["pose_keypoints_2d"], np.float64).reshape(-1, 3)
                kp[:, :2] = np.where(kp[:, 2:] > 0, (kp[:, :2] + 0.5) * SCALE - 0.5, 0.0)
                p["pose_keypoints_2d"] = kp.reshape(-1).tolist()
            (out / src.name).write_text(json.dumps(doc))
    return root


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    return _make_project(tmp_path_factory.mktemp("p2s") / "trial")


def test_project_folder_source(project):
    """The project folder opens as a video source: the calibration found in calibration/, cam01/cam02 taken as
    the calibrated images cropped (a note each), the BODY_25B layout read from the files (a note that
    Config.toml names another), the subject's detections on Pose2Sim's reference, the scene images found."""
    from jaxmocap.io.pose2sim import open_project, project_settings

    src = open_project(project)
    try:
        assert src.num_frames == 4 and src.fps == 60.0 and src.keypoint_layout == "BODY_25B"
        assert src.rig.image_size[:2] == ((130, 240), (130, 240)) and src.rig.image_size[2] == (136, 240)
        notes = " | ".join(src.notes)
        assert notes.count("cropped by the codec's padding") == 2, notes
        assert "read as BODY_25B, not HALPE_26" in notes, notes
        assert [p.name for p in src.scene_images] == [f"{c}_ext.jpg" for c in CAMS]
        _, markers, _ = reference_joints(DATA / "reference.trc")
        rj = src.rig.to_jax(jnp.float32)
        errs = []
        for t in range(4):
            for name, k in JOINT_OF_TRC.items():
                uv = np.asarray(camera.project(rj, jnp.asarray(markers[name][t][None], jnp.float32)))[:, 0]
                kp = src.keypoints[t, :, k]
                ok = kp[:, 2] > 0.3
                errs += list(np.linalg.norm(uv[ok] - kp[ok, :2], axis=-1))
        assert len(errs) > 150 and np.median(errs) < 2.5
        assert [im.shape[1] for im in src.read(0).images] == [130, 130, 136, 136]
    finally:
        src.close()
    assert project_settings(project) == {
        "fps": 60.0,
        "frames": "0:4",
        "layout": "HALPE_26",
        "multi_person": False,
    }


@pytest.mark.slow
@pytest.mark.parametrize("model", ["full25", "full32"])
def test_track_real_frames_close_to_reference(project, tmp_path, model):
    """Four frames, four cameras, keypoint + image cues, the project folder as the input of ``jaxmocap.track``
    (body dimensions from the detections, IK initialisation, a median background without the subject filled from
    the scene images), with the default body and with ``full32`` (spine and shoulder girdles): the tracked joints
    (head left out: the model's head centre has no keypoint counterpart) stay within 80 mm (mean) of Pose2Sim's
    triangulation; a wrong axis, scale, camera order or joint mapping gives hundreds."""
    import jaxmocap

    res = jaxmocap.track(
        input=project,
        model=model,
        particles=100,
        layers=3,
        cues="foreground,edge_distance,coverage:4,keypoints:4",
        seed=0,
        out=tmp_path / "run",
    )
    assert any("body dimensions measured" in n for n in res.notes)
    # each camera's keypoint noise (jaxmocap.io.subject.view_noise) told, for the four cameras
    (noise,) = [n for n in res.notes if n.startswith("keypoint noise per camera")]
    assert len(noise.split(": ", 1)[1].split(", ")) == 4, noise
    ref, _, _ = reference_joints(DATA / "reference.trc")
    err = np.linalg.norm(res.joints - ref, axis=-1) * 1000.0
    assert err.shape == (len(FRAMES), len(EVAL_JOINTS))
    assert np.all(np.isfinite(err))
    no_head = np.delete(err, EVAL_JOINTS.index("head"), axis=1)
    assert np.mean(no_head) < 80.0, np.mean(no_head, axis=0)
    assert np.max(np.mean(no_head, axis=0)) < 200.0
    assert (tmp_path / "run" / "config.toml").is_file()
    assert json.loads((tmp_path / "run" / "run.json").read_text())["model"] == model


def test_four_cameras_with_detections_take_the_refined_particle_count(project):
    """A project of four cameras with detections: the estimate is refined on them (``refine = "track"``), so the
    APF takes REFINED_VIEWS_PARTICLES per layer; without the refinement it keeps the body's 300."""
    from jaxmocap.io.pose2sim import open_project
    from jaxmocap.tracking.options import REFINED_VIEWS_PARTICLES, TrackOptions
    from jaxmocap.tracking.setup import TrackSetup

    for refine, count in (("auto", REFINED_VIEWS_PARTICLES), ("none", 300)):
        src = open_project(project)
        try:
            setup = TrackSetup(src, TrackOptions(refine=refine))
            assert (setup.refine, setup.num_particles) == ("track" if refine == "auto" else "none", count)
        finally:
            src.close()
