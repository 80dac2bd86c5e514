"""Kinematics against closed forms, SciPy and the spatial product of exponentials (eq. 2.5)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
from jax import enable_x64
from jax.test_util import check_grads
from scipy.spatial.transform import Rotation

from jaxmocap.geometry import body, kinematics


def _rotvecs(rng, n):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    angles = np.concatenate([rng.uniform(0, np.pi - 1e-3, n - 3), [0.0, 1e-9, 1e-4]])
    return v * angles[:, None]


def test_so3_exp_matches_scipy_and_log_inverts():
    rng = np.random.default_rng(0)
    w = _rotvecs(rng, 200)
    with enable_x64(True):
        R = np.asarray(kinematics.so3_exp(jnp.asarray(w)))
        np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
        np.testing.assert_allclose(np.asarray(kinematics.so3_log(jnp.asarray(R))), w, atol=1e-7)


def test_se3_exp_matches_matrix_exponential():
    rng = np.random.default_rng(1)
    xi = np.concatenate([rng.normal(size=(50, 3)), _rotvecs(rng, 50)], axis=1)
    with enable_x64(True):
        G = np.asarray(kinematics.se3_exp(jnp.asarray(xi)))
    for k in range(len(xi)):
        M = np.zeros((4, 4))
        wx, wy, wz = xi[k, 3:]
        M[:3, :3] = [[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]]
        M[:3, 3] = xi[k, :3]
        np.testing.assert_allclose(G[k], scipy.linalg.expm(M), atol=1e-10)


def test_revolute_twist_rotates_about_its_point():
    """exp of ξ = (−ω×q, ω) fixes the point q and rotates others about the axis through q (eq. 2.9)."""
    with enable_x64(True):
        q = jnp.asarray([0.3, -0.2, 1.0])
        axis = jnp.asarray([0.0, 0.0, 1.0])
        G = np.asarray(kinematics.se3_exp(kinematics.revolute_twist(axis, q) * (np.pi / 2)))
    np.testing.assert_allclose(G[:3, :3] @ np.asarray(q) + G[:3, 3], q, atol=1e-12)
    p = np.asarray(q) + np.asarray([1.0, 0.0, 0.5])
    np.testing.assert_allclose(G[:3, :3] @ p + G[:3, 3], np.asarray(q) + [0.0, 1.0, 0.5], atol=1e-12)


def test_gradients_of_exponentials():
    with enable_x64(True):
        w = jnp.asarray([0.3, -0.7, 0.2])
        so3_exp, se3_exp = jax.jit(kinematics.so3_exp), jax.jit(kinematics.se3_exp)  # compiled, not op by op
        check_grads(so3_exp, (w,), order=2, modes=["fwd", "rev"])
        check_grads(so3_exp, (jnp.zeros(3),), order=1, modes=["fwd", "rev"])
        xi = jnp.asarray([0.1, 0.4, -0.3, 0.3, -0.7, 0.2])
        check_grads(se3_exp, (xi,), order=2, modes=["fwd", "rev"])


def _spatial_chain(model, x, segment):
    """Spatial PoE (eq. 2.5) for the chain from the root to ``segment``, built from the model's rest geometry."""
    chain = []
    s = segment
    while s >= 0:
        chain.append(s)
        s = model.topology.parents[s]
    chain.reverse()
    R0, t0 = body.segment_poses(model, jnp.zeros(model.num_dofs, x.dtype))
    twists, thetas = [], []
    for s in chain:
        for k in model.topology.segment_dofs[s]:
            axis_world = R0[s] @ model.dof_axis[k]
            if model.topology.dof_kinds[k] == "P":
                twists.append(kinematics.prismatic_twist(axis_world))
            else:
                twists.append(kinematics.revolute_twist(axis_world, t0[s]))
            thetas.append(x[k])
    g0 = jnp.eye(4, dtype=x.dtype).at[:3, :3].set(R0[segment]).at[:3, 3].set(t0[segment])
    return kinematics.poe(jnp.stack(twists), jnp.stack(thetas), g0)


@pytest.mark.parametrize("name", ["upper9", "upper14", "full25"])
def test_tree_fk_equals_spatial_product_of_exponentials(name):
    rng = np.random.default_rng(2)
    with enable_x64(True):
        model = body.build(name, dtype=jnp.float64)
        # both sides compiled once (the same operations as op by op, which dispatches thousands of small programs)
        tree = jax.jit(lambda x: body.segment_poses(model, x))
        chains = jax.jit(
            lambda x: jnp.stack([_spatial_chain(model, x, s) for s in range(model.topology.num_segments)])
        )
        for _ in range(3):
            x = jnp.asarray(rng.uniform(np.maximum(model.lower, -3.0), np.minimum(model.upper, 3.0)))
            R, t = tree(x)
            g = np.asarray(chains(x))
            np.testing.assert_allclose(np.asarray(R), g[:, :3, :3], atol=1e-12)
            np.testing.assert_allclose(np.asarray(t), g[:, :3, 3], atol=1e-12)


def test_tree_fk_against_scipy_composition():
    """An independent composition of homogeneous matrices with SciPy rotations."""
    rng = np.random.default_rng(3)
    with enable_x64(True):
        model = body.full25(dtype=jnp.float64)
        x = np.asarray(rng.uniform(np.maximum(model.lower, -3.0), np.minimum(model.upper, 3.0)))
        R, t = body.segment_poses(model, jnp.asarray(x))
    G = []
    for s in range(model.topology.num_segments):
        g = np.eye(4)
        g[:3, 3] = np.asarray(model.offset[s])
        for k in model.topology.segment_dofs[s]:
            a = np.asarray(model.dof_axis[k])
            e = np.eye(4)
            if model.topology.dof_kinds[k] == "P":
                e[:3, 3] = a * x[k]
            else:
                e[:3, :3] = Rotation.from_rotvec(a * x[k]).as_matrix()
            g = g @ e
        p = model.topology.parents[s]
        G.append(g if p < 0 else G[p] @ g)
    np.testing.assert_allclose(np.asarray(R), np.stack(G)[:, :3, :3], atol=1e-12)
    np.testing.assert_allclose(np.asarray(t), np.stack(G)[:, :3, 3], atol=1e-12)


def test_fk_gradients():
    with enable_x64(True):
        model = body.full25(dtype=jnp.float64)
        x = model.rest_pose + 0.1
        check_grads(jax.jit(lambda x: body.joint_positions(model, x)), (x,), order=1, modes=["fwd", "rev"])


def test_vmap_over_10000_particles_compiles_once():
    model = body.full25()
    traces = []

    def joints(X):
        traces.append(1)
        return jax.vmap(lambda x: body.joint_positions(model, x))(X)

    f = jax.jit(joints)
    X1 = jax.random.uniform(jax.random.key(0), (10_000, model.num_dofs), minval=-0.5, maxval=0.5)
    X2 = jax.random.uniform(jax.random.key(1), (10_000, model.num_dofs), minval=-0.5, maxval=0.5)
    J1 = f(X1)
    J2 = f(X2)
    assert J1.shape == (10_000, 15, 3) and bool(jnp.all(jnp.isfinite(J2)))
    assert len(traces) == 1
    # the batched result equals the per-particle one
    np.testing.assert_allclose(np.asarray(J1[17]), np.asarray(body.joint_positions(model, X1[17])), atol=1e-5)


def test_transform_points_matches_per_point_products():
    rng = np.random.default_rng(4)
    R = jnp.asarray(Rotation.random(5, random_state=5).as_matrix(), jnp.float32)[None].repeat(2, 0)
    t = jnp.asarray(rng.normal(size=(2, 5, 3)), jnp.float32)
    pts = jnp.asarray(rng.normal(size=(7, 3)), jnp.float32)
    seg = np.asarray([0, 0, 1, 2, 3, 4, 4])
    assert kinematics.segment_runs(seg) == [(0, 2, 0), (2, 3, 1), (3, 4, 2), (4, 5, 3), (5, 7, 4)]
    out = np.asarray(kinematics.transform_points(R, t, pts, seg))
    ref = np.einsum("npij,pj->npi", np.asarray(R)[:, seg], np.asarray(pts)) + np.asarray(t)[:, seg]
    np.testing.assert_allclose(out, ref, atol=1e-5)
    # interleaved segments (more runs than MAX_RUNS: the per-point gather) give the same products
    seg = np.arange(2 * kinematics.MAX_RUNS + 1) % 5
    pts = jnp.asarray(rng.normal(size=(seg.size, 3)), jnp.float32)
    assert len(kinematics.segment_runs(seg)) > kinematics.MAX_RUNS
    out = np.asarray(kinematics.transform_points(R, t, pts, seg))
    ref = np.einsum("npij,pj->npi", np.asarray(R)[:, seg], np.asarray(pts)) + np.asarray(t)[:, seg]
    np.testing.assert_allclose(out, ref, atol=1e-5)


def test_transform_points_runs_and_gather_agree(monkeypatch):
    """Long runs go through static slices, short ones through the per-point gather: the same products."""
    rng = np.random.default_rng(6)
    R = jnp.asarray(Rotation.random(5, random_state=7).as_matrix(), jnp.float32)[None].repeat(3, 0)
    t = jnp.asarray(rng.normal(size=(3, 5, 3)), jnp.float32)
    seg = np.repeat(np.arange(5), 3)
    pts = jnp.asarray(rng.normal(size=(seg.size, 3)), jnp.float32)
    assert len(kinematics.segment_runs(seg)) * kinematics.MIN_RUN_LENGTH <= seg.size  # the sliced path
    sliced = np.asarray(kinematics.transform_points(R, t, pts, seg))
    monkeypatch.setattr(kinematics, "MIN_RUN_LENGTH", seg.size + 1)  # the gather
    gathered = np.asarray(kinematics.transform_points(R, t, pts, seg))
    np.testing.assert_array_equal(sliced, gathered)
    ref = np.einsum("npij,pj->npi", np.asarray(R)[:, seg], np.asarray(pts)) + np.asarray(t)[:, seg]
    np.testing.assert_allclose(sliced, ref, atol=1e-5)


@pytest.mark.parametrize("name", ["upper9", "full25", "parsec31"])
def test_loop_and_written_out_fk_agree(name):
    """The two forms of segment_poses (loops on the CPU, written out elsewhere) give the same numbers, rest
    rotations (parsec31) and prismatic DOFs included, bit for bit with XLA's default code generation (the one users
    run; the suite's compile-time flags, tests/conftest.py, fuse the two forms differently). Three models, 9 to 31
    DOFs; full32 (10 s of compilation at XLA's default level) has no joint type these lack."""
    if name == "parsec31":
        from jaxmocap.parsec.model import parsec31 as build
    else:
        build = getattr(body, name)
    model = build()
    X = model.rest_pose + 0.4 * jax.random.normal(jax.random.key(3), (64, model.num_dofs))
    args = (model.topology, model.rest_rotation, model.offset, model.dof_axis)
    forms = [kinematics._segment_poses_loop, kinematics._segment_poses_unrolled]
    defaults = {"xla_backend_optimization_level": 3, "xla_cpu_use_fusion_emitters": True}
    (R1, t1), (R2, t2) = (
        jax.jit(jax.vmap(lambda x, f=f: f(*args, x)), compiler_options=defaults)(X) for f in forms
    )
    np.testing.assert_array_equal(np.asarray(R1), np.asarray(R2))
    np.testing.assert_array_equal(np.asarray(t1), np.asarray(t2))


def test_fk_derivative_from_joint_twists():
    """The CPU form's derivative, written from the joints' world twists, against finite differences in the state
    and, through the fallback, in the segment offsets (body dimensions), on parsec31 (rest rotations, prismatic
    DOFs); and equal, up to rounding, to the automatic derivative of the loops (full25: test_fk_gradients)."""
    from jaxmocap.parsec.model import parsec31_in_metres

    with enable_x64(True):
        model = parsec31_in_metres()
        f64 = lambda a: jnp.asarray(a, jnp.float64)  # noqa: E731
        offset, rest, axis = f64(model.offset), f64(model.rest_rotation), f64(model.dof_axis)
        x = f64(model.rest_pose) + 0.3 * jax.random.normal(jax.random.key(5), (model.num_dofs,), jnp.float64)

        def fk(form):
            return lambda offset, x: form(model.topology, rest, offset, axis, x)

        check_grads(jax.jit(fk(kinematics._segment_poses_cpu)), (offset, x), order=1, modes=["fwd", "rev"])
        for jac in (jax.jacfwd, jax.jacrev):
            ours = jax.jit(jac(fk(kinematics._segment_poses_cpu), argnums=(0, 1)))(offset, x)
            auto = jax.jit(jac(fk(kinematics._segment_poses_loop), argnums=(0, 1)))(offset, x)
            for a, b in zip(jax.tree_util.tree_leaves(ours), jax.tree_util.tree_leaves(auto), strict=True):
                np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-12)


def test_affine_by_runs_adjoint_is_the_closed_form_reverse_pass():
    """The written-out reverse pass of the runs (``adjoint=True``): ``Ā_s = Σ_{p∈s} ḡ_p p_pᵀ``, ``b̄_s = Σ_{p∈s} ḡ_p``,
    ``p̄_p = Σ_lead A_{s(p)}ᵀ ḡ_p`` (numpy), equal to JAX's own transpose of the sliced products, including a segment
    with two runs, segments with none and a leading axis; finite differences (``check_grads``) in float64; forward
    mode is refused."""
    rng = np.random.default_rng(8)
    runs = [(0, 3, 1), (3, 7, 4), (7, 9, 1), (9, 12, 0)]
    seg = np.concatenate([[s] * (b - a) for a, b, s in runs])
    with enable_x64(True):
        A = jnp.asarray(rng.normal(size=(2, 5, 3, 3)))
        b = jnp.asarray(rng.normal(size=(2, 5, 3)))
        pts = jnp.asarray(rng.normal(size=(12, 3)))
        g = rng.normal(size=(3, 2, 12))

        def f(adjoint):
            return lambda A, b, p: jnp.stack(kinematics.apply_by_runs(A, b, p, runs, adjoint), 0)

        out, pull = jax.vjp(f(True), A, b, pts)
        gA, gb, gp = (np.asarray(a) for a in pull(jnp.asarray(g)))
        np.testing.assert_allclose(
            out,
            np.einsum("lpij,pj->ilp", np.asarray(A)[:, seg], pts) + np.moveaxis(np.asarray(b)[:, seg], -1, 0),
        )
        refA, refb = np.zeros((2, 5, 3, 3)), np.zeros((2, 5, 3))
        for p, s in enumerate(seg):
            refA[:, s] += np.einsum("il,j->lij", g[:, :, p], np.asarray(pts)[p])
            refb[:, s] += g[:, :, p].T
        refp = np.einsum("lpij,ilp->pj", np.asarray(A)[:, seg], g)
        np.testing.assert_allclose(gA, refA, atol=1e-12)
        np.testing.assert_allclose(gb, refb, atol=1e-12)
        np.testing.assert_allclose(gp, refp, atol=1e-12)
        assert np.all(gA[:, [2, 3]] == 0) and np.all(gb[:, [2, 3]] == 0)  # segments without a run
        auto = jax.vjp(f(False), A, b, pts)[1](jnp.asarray(g))
        for mine, theirs in zip((gA, gb, gp), auto, strict=True):
            np.testing.assert_allclose(mine, theirs, atol=1e-12)
        check_grads(f(True), (A, b, pts), order=1, modes=["rev"])
        with pytest.raises(TypeError):
            jax.jvp(f(True), (A, b, pts), (A, b, pts))
