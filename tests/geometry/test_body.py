"""Body presets: state layout of the three works, geometry in closed form, limits, body files, gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import body


def test_state_sizes_of_the_three_works():
    assert body.upper9().num_dofs == 13  # thesis eq. 6.1
    assert body.upper14().num_dofs == 14  # IROS 2007
    m = body.full25()
    assert m.num_dofs == 25  # Li & Kulić
    assert m.joint_names == body.EVAL_JOINTS
    # every angle of full25 is limited (translation is the only unbounded part)
    ang = m.angular
    assert np.all(np.asarray(m.upper - m.lower)[ang] <= 4 * np.pi + 1e-6)
    assert np.all(np.asarray(m.lower) <= np.asarray(m.rest_pose))
    assert np.all(np.asarray(m.rest_pose) <= np.asarray(m.upper))


def test_rest_pose_geometry_closed_form():
    d = body.DEFAULT_DIMENSIONS
    m = body.full25()
    J = dict(zip(m.joint_names, np.asarray(body.joint_positions(m, m.rest_pose)), strict=True))
    # standing on the floor, facing +x, left towards +y
    np.testing.assert_allclose(J["left_ankle"][2], 0.0, atol=1e-6)
    np.testing.assert_allclose(
        J["left_wrist"] - J["left_shoulder"], [0, 0, -d["upper_arm_length"] - d["forearm_length"]], atol=1e-6
    )
    np.testing.assert_allclose(J["left_shoulder"][1] - J["right_shoulder"][1], d["shoulder_width"], atol=1e-6)
    assert J["left_hip"][1] > 0 > J["right_hip"][1]


def test_elbow_and_knee_bend_the_natural_way():
    m = body.full25()
    x = m.rest_pose.at[m.dof_index("left_elbow")].set(np.pi / 2).at[m.dof_index("right_knee")].set(np.pi / 2)
    J = dict(zip(m.joint_names, np.asarray(body.joint_positions(m, x)), strict=True))
    forearm = J["left_wrist"] - J["left_elbow"]
    shin = J["right_ankle"] - J["right_knee"]
    assert forearm[0] > 0.2 and abs(forearm[2]) < 1e-6  # hand moves forward (+x)
    assert shin[0] < -0.2 and abs(shin[2]) < 1e-6  # foot moves backwards


def test_root_orientation_turns_the_whole_body():
    m = body.full25()
    x0 = m.rest_pose
    x = x0.at[m.dof_index("root_rz")].set(np.pi / 2)
    J0 = np.asarray(body.joint_positions(m, x0))
    J = np.asarray(body.joint_positions(m, x))
    rz = np.asarray([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    root = J0[0]
    np.testing.assert_allclose(J - root, (J0 - root) @ rz.T, atol=1e-6)


def _full25_state_in_full32(m25, m32, x25):
    return np.asarray(
        [x25[m25.dof_index(n)] if n in m25.dof_names else 0.0 for n in m32.dof_names], np.float32
    )


def test_full32_is_full25_with_a_spine_and_shoulder_girdles():
    """At zero spine and girdle angles full32's joints and flesh are full25's for any other state; its trunk is
    the pelvis part and the chest, and 32 DOFs in the documented order."""
    m25, m32 = body.full25(), body.full32()
    assert m32.num_dofs == 32 and m32.joint_names == body.EVAL_JOINTS
    added = [n for n in m32.dof_names if n not in m25.dof_names]
    assert added == ["spine_rx", "spine_ry", "spine_rz"] + [
        f"{s}_clavicle_r{a}" for s in ("left", "right") for a in "xz"
    ]
    assert body.trunk_segments(m32) == (0, 1) and body.trunk_segments(m25) == (0,)
    rng = np.random.default_rng(0)
    lo, hi = np.asarray(m25.lower), np.asarray(m25.upper)
    for _ in range(3):
        x25 = np.clip(np.asarray(m25.rest_pose) + rng.uniform(-0.4, 0.4, 25), lo, hi).astype(np.float32)
        x32 = _full25_state_in_full32(m25, m32, x25)
        np.testing.assert_allclose(
            body.joint_positions(m32, jnp.asarray(x32)),
            body.joint_positions(m25, jnp.asarray(x25)),
            atol=2e-6,
        )
    # the torso cone cut in two at the same radii: the same silhouette
    d = body.DEFAULT_DIMENSIONS
    T, r0, r1 = d["torso_length"], d["torso_radius_bottom"], d["torso_radius_top"]
    h = body.SPINE_HEIGHT * T
    np.testing.assert_allclose(np.asarray(m32.shape_end[:2, 2]), [h, T - h], atol=1e-7)
    np.testing.assert_allclose(
        np.asarray(m32.radius_start[:2]), [r0, r0 + body.SPINE_HEIGHT * (r1 - r0)], atol=1e-7
    )
    np.testing.assert_allclose(
        np.asarray(m32.radius_end[:2]), [r0 + body.SPINE_HEIGHT * (r1 - r0), r1], atol=1e-7
    )


_ABOVE_SPINE = (
    "thorax",
    "head",
    *(f"{s}_{j}" for s in ("left", "right") for j in ("shoulder", "elbow", "wrist")),
)


@pytest.mark.parametrize(
    "dof, axis, centre, carried",
    [
        ("spine_rx", "x", "spine", _ABOVE_SPINE),
        ("spine_ry", "y", "spine", _ABOVE_SPINE),
        ("spine_rz", "z", "spine", _ABOVE_SPINE),
        ("left_clavicle_rx", "x", "thorax", ("left_shoulder", "left_elbow", "left_wrist")),
        ("right_clavicle_rz", "z", "thorax", ("right_shoulder", "right_elbow", "right_wrist")),
    ],
)
def test_full32_spine_and_girdles_rotate_about_their_joints(dof, axis, centre, carried):
    """Closed form: one spine or girdle angle θ (the root at rest, facing +x) turns the joints it carries about
    its joint centre by R_axis(θ) (the spine joint at SPINE_HEIGHT of the torso above the pelvis centre, the
    girdles at the base of the neck) and leaves every other joint where it was."""
    m = body.full32()
    theta = -0.25 if dof == "spine_ry" else 0.3
    x0 = m.rest_pose
    J0 = dict(zip(m.joint_names, np.asarray(body.joint_positions(m, x0), np.float64), strict=True))
    x = x0.at[m.dof_index(dof)].set(theta)
    J = dict(zip(m.joint_names, np.asarray(body.joint_positions(m, x), np.float64), strict=True))
    spine = J0["root"] + [0.0, 0.0, body.SPINE_HEIGHT * body.DEFAULT_DIMENSIONS["torso_length"]]
    c = spine if centre == "spine" else J0["thorax"]
    R = Rotation.from_euler(axis, theta).as_matrix()  # the reference: SciPy's rotation about one axis
    for name in m.joint_names:
        want = c + R @ (J0[name] - c) if name in carried else J0[name]
        np.testing.assert_allclose(J[name], want, atol=2e-6, err_msg=name)
        if name in carried and dof != "spine_rz":  # (a twist leaves the joints on its axis in place)
            assert np.linalg.norm(J[name] - J0[name]) > 0.01, name


def test_limits_clip():
    m = body.upper9()
    x = jnp.full((4, m.num_dofs), 1e3)
    assert bool(jnp.all(body.within_limits(m, body.clip_to_limits(m, x))))
    assert not bool(jnp.any(body.within_limits(m, x)))


def test_gradient_with_respect_to_limb_length():
    """d(wrist height)/d(forearm length) = −1 with the arm hanging (closed form)."""

    def wrist_z(forearm):
        m = body.full25({"forearm_length": forearm})
        return body.joint_positions(m, m.rest_pose)[body.EVAL_JOINTS.index("left_wrist"), 2]

    g = jax.grad(wrist_z)(0.26)
    np.testing.assert_allclose(g, -1.0, atol=1e-6)


def test_body_file_round_trip_and_errors(tmp_path):
    dims = {"forearm_length": 0.3, "left_upper_arm_length": 0.31}
    p = tmp_path / "subject.toml"
    body.save_body(p, "full25", dims)
    m = body.load_body(p)
    ref = body.full25(dims)
    np.testing.assert_allclose(np.asarray(m.offset), np.asarray(ref.offset))
    bad = tmp_path / "bad.toml"
    bad.write_text('model = "full25"\n[dimensions]\nforearm_length = "long"\n')
    with pytest.raises(MocapInputError, match="bad.toml"):
        body.load_body(bad)
    bad.write_text('model = "full25"\n[dimensions]\nforearm_length = -0.2\n')
    with pytest.raises(MocapInputError, match="non-negative"):
        body.load_body(bad)
    signed = tmp_path / "signed.toml"
    body.save_body(signed, "full25", {"shoulder_drop": -0.047})  # CMU shoulders sit above the neck base
    np.testing.assert_allclose(
        np.asarray(body.load_body(signed).offset), np.asarray(body.full25({"shoulder_drop": -0.047}).offset)
    )
    bad.write_text("model = [\n")
    with pytest.raises(MocapInputError, match="not valid TOML"):
        body.load_body(bad)
    bad.write_text('model = "nobody"\n')
    with pytest.raises(MocapInputError, match="unknown body model"):
        body.load_body(bad)
    with pytest.raises(MocapInputError, match="cannot read"):
        body.load_body(tmp_path / "missing.toml")


@pytest.mark.parametrize("name", ["upper9", "upper14", "full25", "full32"])
def test_shipped_body_files_load(name):
    m = body.load_body(body.default_body_path(name))
    assert m.name == name
    np.testing.assert_allclose(np.asarray(m.offset), np.asarray(body.build(name).offset))


def test_registered_presets():
    """A wing's preset: built in its own units, or by its metric builder with ``in_metres``; unknown names list
    the choices; the built-in presets cannot be replaced."""
    native = lambda dims, dtype=jnp.float32: body.full25(dims, dtype=dtype)
    metric = lambda dims: body.upper9(dims)
    body.register_preset("test_wing_model", native, metric)
    try:
        assert "test_wing_model" in body.preset_names()
        assert body.build("test_wing_model").name == "full25"
        assert body.build("test_wing_model", in_metres=True).name == "upper9"
        assert body.build("full25", in_metres=True).name == "full25"  # built in: metres already
    finally:
        body._REGISTERED.pop("test_wing_model")
    with pytest.raises(ValueError, match="choose one of"):
        body.build("test_wing_model")
    with pytest.raises(ValueError, match="built-in"):
        body.register_preset("full25", native)


@pytest.mark.parametrize("name", ["upper9", "full25", "full32"])
def test_concrete_dimensions_build_on_the_host_and_match_the_traced_build(caplog, name):
    """A model of concrete dimensions is computed in NumPy and copied (no program staged: a warm tracker's set-up
    would read each from the compilation cache); the same dimensions traced build the same arrays with jax.numpy."""
    import logging

    dims = {"thigh_length": 0.47, "left_forearm_length": 0.21, "torso_radius_top": 0.17, "neck_length": 0.09}
    caplog.clear()
    with caplog.at_level(logging.WARNING), jax.log_compiles(True):
        m = body.build(name, dims)
    assert not [r.getMessage() for r in caplog.records if r.getMessage().startswith("Compiling ")]
    traced = jax.jit(lambda d: body.build(name, d))({k: jnp.float32(v) for k, v in dims.items()})
    leaves, traced_leaves = jax.tree.leaves(m), jax.tree.leaves(traced)
    assert len(leaves) == len(traced_leaves) == 11
    for a, b in zip(leaves, traced_leaves, strict=True):
        assert isinstance(a, jax.Array) and a.dtype == b.dtype == np.float32 and a.shape == b.shape
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-7, atol=1e-8)
    # the dimensions land where the closed form puts them: the left forearm 0.21, the right one the default
    J = np.asarray(body.joint_positions(m, m.rest_pose))
    ix = body.EVAL_JOINTS.index
    np.testing.assert_allclose(np.linalg.norm(J[ix("left_wrist")] - J[ix("left_elbow")]), 0.21, rtol=1e-6)
    np.testing.assert_allclose(
        np.linalg.norm(J[ix("right_wrist")] - J[ix("right_elbow")]),
        body.DEFAULT_DIMENSIONS["forearm_length"],
        rtol=1e-6,
    )
