"""BVH of body-model motion (io/body_bvh): the joints read back by the project's reader and by two independent
readers (bvhio, pybvh — which, like Blender's importer and the common NumPy loaders, requires three rotation
channels on every joint) equal the JAX forward kinematics; the layout rules (channels, order, end sites, rest
pose, units)."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmocap.parsec  # noqa: F401  (registers the parsec31 body)
from jaxmocap.geometry import body
from jaxmocap.io import body_bvh, bvh, mocap
from jaxmocap.tracking.options import build_model

with warnings.catch_warnings():  # PyGLM (under bvhio) warns about its import name on import
    warnings.simplefilter("ignore", PendingDeprecationWarning)
    import bvhio
import pybvh

A = mocap.Y_UP_TO_Z_UP
MODELS = ("upper9", "upper14", "full25", "full32", "parsec31")


@pytest.fixture(scope="module")
def models():
    return {name: build_model(name, None) for name in MODELS}


def random_states(model, T, seed):
    """States spread over the inner half of every joint range (angles of unlimited DOFs within ±π), the root
    translated by up to 1 m from its rest position."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(model.lower, np.float64), np.asarray(model.upper, np.float64)
    lo, hi = np.maximum(lo, -np.pi), np.minimum(hi, np.pi)
    X = 0.5 * (lo + hi) + 0.25 * (hi - lo) * rng.uniform(-1, 1, (T, model.num_dofs))
    trans = [d for d in model.topology.segment_dofs[0] if model.topology.dof_kinds[d] == "P"]
    X[:, trans] = np.asarray(model.rest_pose)[trans] + rng.uniform(-1.0, 1.0, (T, len(trans)))
    return X


@pytest.fixture(scope="module")
def written(models, tmp_path_factory):
    """Per model: the path of a 6-frame track.bvh in cm, its states ``X (6, D)`` and the JAX kinematics (one
    compiled call) of ``X`` and of the rest pose: segment rotations ``R (7, S, 3, 3)``, origins ``t (7, S, 3)``,
    joints ``J (7, J, 3)`` (row 6: the rest pose)."""
    out = {}
    for k, name in enumerate(MODELS):
        model = models[name]
        X = random_states(model, 6, seed=k)
        path = tmp_path_factory.mktemp(name) / "track.bvh"
        body_bvh.save_model_bvh(path, model, X, fps=30.0)
        fk = lambda x, model=model: (*body.segment_poses(model, x), body.joint_positions(model, x))
        X_all = np.concatenate([X, np.asarray(model.rest_pose, np.float64)[None]])
        R, t, J = (np.asarray(a, np.float64) for a in jax.jit(jax.vmap(fk))(jnp.asarray(X_all, jnp.float32)))
        out[name] = (path, X, R, t, J)
    return out


@pytest.mark.parametrize("name", MODELS)
def test_segment_poses_np_equals_the_jax_kinematics(models, written, name):
    path, X, Rj, tj, _ = written[name]
    R, t = body_bvh.segment_poses_np(models[name], X)
    np.testing.assert_allclose(R, Rj[:6], atol=2e-6)  # float32 JAX against float64
    np.testing.assert_allclose(t, tj[:6], atol=2e-6)


@pytest.mark.parametrize("name", MODELS)
def test_round_trip_reproduces_the_joints(models, written, name):
    path, X, *_, J = written[name]
    J = J[:6]
    m = bvh.load_bvh(path, scale=0.01)
    assert m.fps == 30.0 and m.num_frames == 6
    np.testing.assert_allclose(body_bvh.bvh_eval_joints(m, models[name]), J, atol=2e-6)


@pytest.mark.parametrize("name", MODELS)
def test_bvhio_reads_the_same_joints(models, written, name):
    path, X, *_, J = written[name]
    root = bvhio.readAsHierarchy(str(path))
    names = [j.Name for j, _, _ in root.layout()]
    cols = [names.index(n) for n in body_bvh.bvh_joint_names(models[name])]
    for f in range(len(X)):
        root.loadPose(f)
        world = np.asarray([[*j.PositionWorld] for j, _, _ in root.layout()], np.float64) * 0.01 @ A.T
        np.testing.assert_allclose(world[cols], J[f], atol=2e-5)  # bvhio computes in float32


@pytest.mark.parametrize("name", MODELS)
def test_pybvh_reads_the_same_joints(models, written, name):
    path, X, *_, J = written[name]
    J = J[:6]
    b = pybvh.read_bvh_file(path, world_up="+y")
    P = b.joint_positions() * 0.01 @ A.T
    cols = [list(b.joint_names).index(n) for n in body_bvh.bvh_joint_names(models[name])]
    np.testing.assert_allclose(P[:, cols], J, atol=2e-6)


@pytest.mark.parametrize("name", MODELS)
def test_layout_three_rotations_one_order_end_sites_on_leaves(models, written, name):
    data = bvh.read_bvh(written[name][0])
    rot = ("Zrotation", "Xrotation", "Yrotation")
    assert data.channels[0] == ("Xposition", "Yposition", "Zposition", *rot)
    assert all(c == rot for c in data.channels[1:])
    assert len(set(data.names)) == len(data.names)
    leaves = {j for j in range(len(data.names)) if j not in data.parents}
    assert sorted(data.end_parents) == sorted(leaves)  # one end site per leaf, none elsewhere
    assert np.all(np.linalg.norm(data.end_offsets, axis=1) > 1.0)  # no zero-length bone (cm)
    # every evaluation joint is a joint of the file
    assert set(body_bvh.bvh_joint_names(models[name])) <= set(data.names)


def test_full25_channels_are_the_dofs(models):
    """full25's limbs and neck: the DOFs themselves in degrees (rx ry rz of the z-up world are the file's Z X Y;
    an elbow turns about -y (the file's -X), a knee about +y)."""
    model = models["full25"]
    X = random_states(model, 3, seed=5)
    data = body_bvh.model_bvh(model, X, fps=30.0)
    starts = np.cumsum([0] + [len(c) for c in data.channels])
    col = lambda seg: data.frames[:, starts[data.names.index(seg)] : starts[data.names.index(seg) + 1]]
    deg = lambda dof: np.rad2deg(X[:, model.dof_index(dof)])
    for side in ("left", "right"):
        np.testing.assert_array_equal(
            col(f"{side}_upper_arm"), np.stack([deg(f"{side}_shoulder_r{a}") for a in "xyz"], axis=1)
        )
        np.testing.assert_array_equal(
            col(f"{side}_forearm"),
            np.stack([0 * deg("left_elbow"), -deg(f"{side}_elbow"), 0 * deg("left_elbow")], axis=1),
        )
        np.testing.assert_array_equal(col(f"{side}_shin")[:, 1], deg(f"{side}_knee"))
    np.testing.assert_array_equal(col("head"), np.stack([deg(f"neck_r{a}") for a in "xyz"], axis=1))
    for extra in ("thorax", "head_centre", "left_wrist", "right_ankle"):
        np.testing.assert_array_equal(col(extra), 0.0)
    # the root's rotation (rz ry rx, the file's Y X Z) is written as Z X Y Euler angles of the same matrix
    root = col("torso")
    R = mocap.euler_to_matrix(np.deg2rad(root[:, 3:]), "ZXY")
    np.testing.assert_allclose(A @ R @ A.T, body_bvh.segment_poses_np(model, X)[0][:, 0], atol=1e-12)
    np.testing.assert_allclose(root[:, :3], X[:, :3][:, [1, 2, 0]] * 100, atol=1e-9)


@pytest.mark.parametrize("name", MODELS)
def test_rest_pose_is_the_model_at_rest(models, written, name, tmp_path):
    """All channels zero but the root's position: the model at ``rest_pose`` (frames parallel to the axes), and
    the root's OFFSET is its rest position, so that Blender's rest pose stands upright."""
    model = models[name]
    data = body_bvh.model_bvh(model, np.asarray(model.rest_pose, np.float64)[None], fps=30.0)
    np.testing.assert_allclose(data.frames[0, 3:], 0.0, atol=1e-9)
    np.testing.assert_allclose(data.frames[0, :3], data.offsets[0], atol=1e-9)
    rest = data._replace(frames=np.zeros_like(data.frames))
    rest.frames[0, :3] = data.offsets[0]
    bvh.save_bvh(tmp_path / "rest.bvh", rest)
    m = bvh.load_bvh(tmp_path / "rest.bvh", scale=0.01)
    J0 = written[name][4][6:]
    np.testing.assert_allclose(body_bvh.bvh_eval_joints(m, model), J0, atol=2e-6)
    if name == "full25":  # pelvis 0.92 m above the floor, ankles on it
        assert data.offsets[0, 1] == pytest.approx(92.0)
        np.testing.assert_allclose(J0[0, [model.joint_names.index("left_ankle")], 2], 0.0, atol=1e-6)


def test_metres_are_centimetres_divided_by_100(models):
    model = models["full25"]
    X = random_states(model, 2, seed=3)
    cm = body_bvh.model_bvh(model, X, 30.0, scale=body_bvh.UNITS["cm"])
    m = body_bvh.model_bvh(model, X, 30.0, scale=body_bvh.UNITS["m"])
    np.testing.assert_allclose(m.offsets * 100, cm.offsets, rtol=1e-12)
    np.testing.assert_allclose(m.frames[:, :3] * 100, cm.frames[:, :3], rtol=1e-12)
    np.testing.assert_array_equal(m.frames[:, 3:], cm.frames[:, 3:])


def test_euler_channels_are_continuous_over_a_full_turn(models):
    """The root turning by 4π over 60 frames: its unwrapped Euler channel never jumps by more than a step."""
    model = models["full25"]
    X = np.tile(np.asarray(model.rest_pose, np.float64), (60, 1))
    X[:, model.dof_index("root_rz")] = np.linspace(0, 4 * np.pi, 60)
    root_y = body_bvh.model_bvh(model, X, 30.0).frames[:, 5]  # Yrotation (the world's heading)
    assert np.max(np.abs(np.diff(root_y))) < 13.0
    np.testing.assert_allclose(root_y[-1] - root_y[0], 720.0, atol=1e-9)


def test_no_frames_and_bad_input(models):
    model = models["upper9"]
    assert body_bvh.model_bvh(model, np.zeros((0, model.num_dofs)), fps=30.0).frames.shape[0] == 0
    with pytest.raises(ValueError, match="states must be"):
        body_bvh.model_bvh(model, np.zeros((3, 2)), fps=30.0)
    with pytest.raises(ValueError, match="scale"):
        body_bvh.model_bvh(model, np.zeros((1, model.num_dofs)), fps=30.0, scale=0.0)
