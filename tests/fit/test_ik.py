"""Solvers and pose fitting: closed forms and SciPy for the solvers, full25 fitted to real CMU mocap, IK from head
and hands, Procrustes against SciPy, limits, missing targets, warm-started sequences, compile-once."""

import logging
import pathlib

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize
from jax import enable_x64
from scipy.spatial.transform import Rotation

from jaxmocap.fit import ik, solvers
from jaxmocap.geometry import body
from jaxmocap.io import asfamc, bvh, mocap

CMU = pathlib.Path(__file__).parents[1] / "data" / "cmu"
F = 24  # frames per batch: one shape, so one compilation for every batched fit below


# ---------------------------------------------------------------------------------------------------------------
# Solvers


def test_least_squares_matches_lstsq_and_scipy():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(12, 4))
    b = rng.normal(size=12)
    with enable_x64(True):
        x, _ = solvers.least_squares(lambda x, A, b: A @ x - b, jnp.zeros(4), jnp.asarray(A), jnp.asarray(b))
        np.testing.assert_allclose(x, np.linalg.lstsq(A, b, rcond=None)[0], atol=1e-8)
        # a nonlinear fit, y = a exp(-k t) + c, against scipy.optimize.least_squares (Trust Region Reflective)
        t = np.linspace(0, 4, 30)
        y = 2.0 * np.exp(-1.3 * t) + 0.5 + 0.01 * rng.normal(size=30)
        res = lambda p, t, y: p[0] * jnp.exp(-p[1] * t) + p[2] - y
        p, _ = solvers.least_squares(
            res, jnp.asarray([1.0, 1.0, 0.0]), jnp.asarray(t), jnp.asarray(y), tol=1e-12
        )
        ref = scipy.optimize.least_squares(lambda p: np.asarray(res(p, t, y)), [1.0, 1.0, 0.0]).x
        np.testing.assert_allclose(p, ref, atol=1e-6)


def test_bisection_under_jit_and_vmap():
    f = jax.jit(jax.vmap(lambda c: solvers.bisection(lambda x, c: x**3 - c, 0.0, c + 1.0, c, tol=1e-7)))
    c = jnp.asarray([0.5, 2.0, 3.0, 10.0])
    np.testing.assert_allclose(f(c), np.cbrt(np.asarray(c)), rtol=2e-6)


def test_minimize_quadratic_closed_form():
    rng = np.random.default_rng(1)
    M = rng.normal(size=(5, 5))
    H = M @ M.T + 5 * np.eye(5)
    g = rng.normal(size=5)
    with enable_x64(True):
        x, _ = solvers.minimize(
            lambda x: 0.5 * x @ jnp.asarray(H) @ x - jnp.asarray(g) @ x, jnp.zeros(5), tol=1e-10
        )
        np.testing.assert_allclose(x, np.linalg.solve(H, g), atol=1e-7)


# ---------------------------------------------------------------------------------------------------------------
# Building blocks


@pytest.fixture(scope="module")
def random_poses():
    """States drawn in the middle half of every range with any heading (fixed keys), and their joints by
    body.joint_positions (eager vmap: cheaper here than compiling the unrolled kinematics)."""
    model = body.full25()
    lo, hi = np.asarray(model.lower), np.asarray(model.upper)
    inside = np.asarray(ik.prior_mask(model))
    u = np.asarray(jax.random.uniform(jax.random.key(1), (F, model.num_dofs), minval=-0.5, maxval=0.5))
    x = np.where(inside, 0.5 * (lo + hi) + 0.5 * (hi - lo) * u, 0.0)
    x[:, model.dof_index("root_rz")] = np.asarray(
        jax.random.uniform(jax.random.key(2), (F,), minval=-3, maxval=3)
    )
    x[:, :3] = np.asarray(jax.random.normal(jax.random.key(3), (F, 3)))
    x = jnp.asarray(x, jnp.float32)
    return model, x, jax.vmap(body.joint_positions, in_axes=(None, 0))(model, x)


JAC = jax.jit(jax.vmap(ik.joints_and_jacobian, in_axes=(None, 0)))  # one compilation for all uses below


def _joints(model, xs):
    return JAC(model, xs)[0]


def test_compact_kinematics_equals_the_body_model_and_its_jacobian(random_poses):
    model, xs, ref_X = random_poses
    X, Jac = JAC(model, xs)
    np.testing.assert_allclose(X, ref_X, atol=1e-5)
    # central differences, h = 0.01 (rad or m): truncation ~h²/6 ≈ 2e-5, float32 rounding ~1e-5
    h = 0.01
    for k in range(model.num_dofs):
        fd = (_joints(model, xs.at[:, k].add(h)) - _joints(model, xs.at[:, k].add(-h))) / (2 * h)
        np.testing.assert_allclose(Jac[..., k], fd, atol=2e-4)


def test_kabsch_matches_scipy_align_vectors():
    rng = np.random.default_rng(4)
    P = rng.normal(size=(6, 3))
    w = rng.uniform(0.5, 2.0, size=6)
    R_true = Rotation.from_rotvec([0.3, -2.0, 1.1]).as_matrix()
    Q = P @ R_true.T + np.array([1.0, -2.0, 0.5]) + 0.01 * rng.normal(size=(6, 3))
    R, t = ik.kabsch(jnp.asarray(P), jnp.asarray(Q), jnp.asarray(w))
    pm, qm = (w @ P) / w.sum(), (w @ Q) / w.sum()
    ref, _ = Rotation.align_vectors(Q - qm, P - pm, weights=w)
    np.testing.assert_allclose(R, ref.as_matrix(), atol=1e-5)
    np.testing.assert_allclose(t, qm - ref.as_matrix() @ pm, atol=1e-5)


def test_root_init_recovers_any_heading_and_tilt(random_poses):
    """Random states (any heading in ±3 rad, tilts within ±45°, limbs anywhere): Procrustes on the torso
    joints gives the root translation and Rz·Ry·Rx angles exactly."""
    model, x, Y = random_poses
    x0 = jax.vmap(ik.root_init, in_axes=(None, 0, None))(model, Y, jnp.ones(Y.shape[1]))
    np.testing.assert_allclose(x0[:, :6], x[:, :6], atol=2e-5)


@pytest.mark.parametrize("name", ["upper9", "upper14"])
def test_root_init_for_the_upper_body_presets(name):
    """Roots at the base of the neck: translation and heading (upper9's single ``body_rz``, upper14's
    Rz·Ry·Rx) come back from the torso joints."""
    model = body.build(name)
    x = model.rest_pose.at[:3].set(jnp.asarray([0.4, -1.2, 1.3])).at[3].set(-2.5)
    if name == "upper14":
        x = x.at[4].set(0.3).at[5].set(-0.2)
    x = x.at[model.dof_index("left_elbow")].set(1.0).at[model.dof_index("right_shoulder_rx")].set(-0.8)
    x0 = ik.root_init(model, jax.jit(ik.model_joints)(model, x))
    n_root = len(model.topology.segment_dofs[0])
    np.testing.assert_allclose(x0[:n_root], x[:n_root], atol=2e-5)


def test_root_init_for_full32_uses_the_trunk():
    """full32's girdles move the shoulders: the root comes from root, thorax and hips (the trunk's joints at its
    rest pose), exactly when the spine is straight, whatever the girdles and limbs do."""
    model = body.full32()
    x = model.rest_pose.at[:6].set(jnp.asarray([0.4, -1.2, 1.0, 2.0, 0.2, -0.3]))
    for name, v in (("left_clavicle_rx", 0.3), ("right_clavicle_rz", -0.3), ("left_elbow", 1.0)):
        x = x.at[model.dof_index(name)].set(v)
    x0 = ik.root_init(model, jax.jit(ik.model_joints)(model, x))
    np.testing.assert_allclose(x0[:6], x[:6], atol=2e-5)


def test_reparametrisation_stays_in_limits():
    model = body.full25()
    u = jnp.linspace(-20, 20, 101)[:, None] * jnp.ones(model.num_dofs)
    x = jax.vmap(lambda u: ik.to_state(model, u))(u)
    inside = ik.prior_mask(model)  # bounded angles; translation and full-turn heading pass through (u = x)
    assert bool(jnp.all(jnp.where(inside, (x >= model.lower) & (x <= model.upper), x == u)))
    back = ik.to_state(model, ik.from_state(model, model.rest_pose))
    span = model.upper - model.lower
    assert bool(jnp.all(jnp.abs(back - model.rest_pose) <= jnp.where(inside, 0.02 * span, 0.0) + 1e-6))


# ---------------------------------------------------------------------------------------------------------------
# Fitting real mocap

# eager vmaps: the jitted solver core of ik is compiled once for the batch shape and shared by every fit below
FIT = jax.vmap(lambda m, y, w, pw: ik.fit_pose(m, y, w, prior_weight=pw), in_axes=(None, 0, None, None))


def _solver_compilations(caplog, fn):
    """Run ``fn`` and count the compilations of ik's solver core it triggers."""
    caplog.clear()
    with caplog.at_level(logging.WARNING), jax.log_compiles(True):
        out = fn()
    return out, sum("Compiling jit(_solve)" in r.getMessage() for r in caplog.records)


@pytest.fixture(scope="module")
def cmu():
    walk = asfamc.load_asfamc(CMU / "02.asf", CMU / "02_01.amc")
    other = bvh.load_bvh(CMU / "131_01.bvh", scale=bvh.CMU_BVH_SCALE)
    out = {}
    for name, m in (("02_01", walk), ("131_01", other)):
        ev = mocap.eval_joints(m)
        frames = np.linspace(0, m.num_frames - 1, F).astype(int)
        out[name] = (
            body.full25(mocap.body_dimensions_from_motion(m)),
            jnp.asarray(ev[frames], jnp.float32),
            ev,
        )
    return out


def _fit(model, targets, weights=None, prior_weight=1e-4):
    w = jnp.ones(targets.shape[1], jnp.float32) if weights is None else weights
    return FIT(model, targets, w, prior_weight)


@pytest.mark.parametrize(("clip", "mean_cm", "p95_cm"), [("02_01", 1.0, 3.0), ("131_01", 1.5, 4.0)])
def test_full25_fits_cmu_mocap(cmu, caplog, clip, mean_cm, p95_cm):
    model, targets, ev = cmu[clip]
    fit = _fit(model, targets)
    err = np.asarray(fit.errors)
    # measured: 02_01 mean 0.70 cm, 95th pct 2.61 cm, max 3.4 cm; 131_01 mean 1.02 cm, 95th pct 3.16 cm, max
    # 6.5 cm (a deep crouch: full25's torso is one rigid segment while the CMU spine bends). The largest
    # per-joint residual is the root (2.7 cm): CMU hips sit ~3.5 cm in front of the root, full25's below it.
    assert err.mean() < mean_cm / 100
    assert np.percentile(err, 95) < p95_cm / 100
    assert bool(jnp.all(body.within_limits(model, fit.state)))
    # the subject's own dimensions matter: default dimensions leave a much larger residual (measured 3.7 cm)
    if clip == "02_01":
        default = _fit(body.full25(), targets)
        assert np.asarray(default.errors).mean() > 3 * err.mean()
    # new frames, new body dimensions: no recompilation
    _, n = _solver_compilations(caplog, lambda: _fit(body.full25(), jnp.asarray(ev[:F], jnp.float32)))
    assert n == 0


def test_missing_targets_and_masks_are_ignored(cmu):
    model, targets, _ = cmu["02_01"]
    missing = targets.at[:, 5].set(jnp.nan).at[:, 11].set(jnp.nan)  # left wrist and left ankle unknown
    w = jnp.ones(targets.shape[1], jnp.float32)
    a = _fit(model, missing, w)
    b = _fit(model, targets, w.at[5].set(0.0).at[11].set(0.0))
    np.testing.assert_allclose(a.state, b.state, atol=1e-5)
    assert np.all(np.isnan(np.asarray(a.errors)[:, [5, 11]]))
    assert np.all(np.isfinite(np.asarray(a.errors)[:, [0, 1, 2, 3, 4, 6]]))


def test_limits_hold_when_targets_ask_for_more(cmu):
    model, targets, _ = cmu["02_01"]
    # push the ankles forward and up in front of the knees: a hyper-extended knee would be the best fit
    knee, ankle = 10, 11
    bent = targets.at[:, ankle].set(targets[:, knee] + jnp.asarray([0.3, 0.0, 0.1]))
    fit = _fit(model, bent)
    assert bool(jnp.all(body.within_limits(model, fit.state)))
    k = model.dof_index("left_knee")
    assert float(jnp.min(fit.state[:, k])) >= float(model.lower[k])


def test_random_poses_are_recovered_exactly_mostly(random_poses):
    """Targets from body.joint_positions of random states: LM from the Procrustes start recovers the joints to
    0.1 mm except where a shoulder ends in a local minimum at a limit."""
    model, _, Y = random_poses
    fit = _fit(model, Y, prior_weight=1e-8)
    worst = np.asarray(fit.errors).max(axis=1)
    assert np.sum(worst < 1e-4) >= 0.75 * F  # measured 20 of 24 (others: 0.6, 1.9, 11, 61 mm)


def test_fit_sequence_warm_starts(cmu):
    model, _, ev = cmu["02_01"]
    targets = jnp.asarray(ev[100:160], jnp.float32)  # half a second at 120 fps
    seq = ik.fit_sequence(model, targets)
    assert seq.state.shape == (60, model.num_dofs)
    err = np.asarray(seq.errors)
    assert err.mean() < 0.01  # measured 0.73 cm
    assert bool(jnp.all(body.within_limits(model, seq.state)))
    # warm starts converge quickly: from the second frame on, far fewer iterations than the cap
    assert np.median(np.asarray(seq.iterations)[1:]) < 10  # measured 4 (11 for the first frame)
    # the same minima as independent fits of the same frames
    idx = np.arange(0, 60, 60 // F)[:F]
    ind = _fit(model, targets[idx])
    np.testing.assert_allclose(err[idx].mean(), np.asarray(ind.errors).mean(), atol=1e-3)


# ---------------------------------------------------------------------------------------------------------------
# IK from head and hands

HH = jax.vmap(
    lambda m, o, x0, free: ik.from_head_hands(m, o[0], o[1], o[2], init=x0, free=free),
    in_axes=(None, 0, 0, None),
)


def test_from_head_hands_recovers_the_arms(cmu, caplog):
    """Ground truth: full25 fitted to the 02_01 walk. Observations: its head and wrists plus 1 cm Gaussian noise
    per coordinate (fixed key). With the torso known (the tracker's case), the arms come back within a few cm;
    with everything free, the head and hands are still reached."""
    model, targets, _ = cmu["02_01"]
    truth = _fit(model, targets).state
    joints = _joints(model, truth)
    names = model.joint_names
    ih, il, ir = (names.index(n) for n in ("head", "left_wrist", "right_wrist"))
    obs = joints[:, jnp.asarray([ih, il, ir])] + 0.01 * jax.random.normal(jax.random.key(0), (F, 3, 3))
    arms = jnp.asarray(
        ik.dof_mask(model, "left_shoulder", "left_elbow", "right_shoulder", "right_elbow", "neck")
    )
    start = jnp.where(arms, model.rest_pose, truth)  # torso from the truth, arms at rest
    hh = HH(model, obs, start, arms)
    got = _joints(model, hh.state)
    err = {n: float(np.linalg.norm(got[:, k] - joints[:, k], axis=-1).mean()) for k, n in enumerate(names)}
    # measured: wrists 1.55 / 1.45 cm (the noise is 1.67 cm rms), elbows 2.96 / 2.93 cm (max 5.4 cm)
    assert err["left_wrist"] < 0.025 and err["right_wrist"] < 0.025
    assert err["left_elbow"] < 0.05 and err["right_elbow"] < 0.05
    assert err["left_shoulder"] < 1e-6 and err["root"] < 1e-6  # not free
    assert bool(jnp.all(body.within_limits(model, hh.state)))

    # everything free from the default start (heading from the hands): same compiled function
    start = jax.vmap(ik.head_hands_init, in_axes=(None, 0, 0, 0))(model, obs[:, 0], obs[:, 1], obs[:, 2])
    free = jnp.ones(model.num_dofs, bool)
    hh, n = _solver_compilations(caplog, lambda: HH(model, obs, start, free))
    assert n == 0  # one compiled solver for both uses (and for fit_pose's batches of this shape)
    reached = np.asarray(hh.errors)[:, [ih, il, ir]]
    assert reached.mean() < 0.01  # the three (noisy) targets are met: measured 0.26 cm
    # (the torso's heading is not observable from three points when the arms swing: shoulders then err by
    # 6-10 cm, which is why a tracker passes its torso estimate)


# ---------------------------------------------------------------------------------------------------------------
# Fitting to 2D detections


def _stereo_rig(target, baseline=0.3, distance=3.4, f=300.0, size=(320, 240)):
    """Two cameras ``baseline`` apart, ``distance`` from ``target`` along +x, looking at it along −x (z up)."""
    from jaxmocap.geometry import camera

    R = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])  # camera z = −world x
    K = np.array([[f, 0, size[0] / 2], [0, f, size[1] / 2], [0, 0, 1.0]])
    C = [np.asarray(target) + [distance, dy, 0.0] for dy in (-baseline / 2, baseline / 2)]
    return camera.from_opencv([K, K], np.zeros((2, 5)), [R, R], [-R @ c for c in C], image_size=[size, size])


def _opencv_pixels(rig, X):
    """``(V, J, 2)`` projections of ``X (J, 3)`` by ``cv2.projectPoints``."""
    out = []
    for v in range(rig.num_views):
        uv, _ = cv2.projectPoints(
            np.asarray(X, np.float64),
            cv2.Rodrigues(np.asarray(rig.R[v], np.float64))[0],
            np.asarray(rig.t[v], np.float64),
            np.asarray(rig.K[v], np.float64),
            np.asarray(rig.dist[v], np.float64),
        )
        out.append(uv.reshape(-1, 2))
    return np.stack(out)


def test_fit_pose_2d_recovers_a_mocap_pose_from_its_pixels(cmu):
    """Exact pixels of a real walk pose (OpenCV's projection) in a stereo pair 0.3 m apart at 3.4 m: from a start
    0.5 m too far along the ray and 0.15 rad off in every angle, the reprojection fit puts every joint within
    1 cm of the truth (the start: ≈ 0.5 m)."""
    model, targets, _ = cmu["02_01"]
    x_true = np.asarray(_fit(model, targets).state[5], np.float64)
    X = np.asarray(ik.model_joints(model, jnp.asarray(x_true, jnp.float32)), np.float64)
    rig = _stereo_rig(X[0])
    uv = _opencv_pixels(rig, X)
    x0 = x_true + 0.15 * np.random.default_rng(3).choice([-1.0, 1.0], size=x_true.shape)
    x0[:3] = x_true[:3] + [0.5, 0.0, 0.0]  # root_tx: along the cameras' axis
    x0 = np.asarray(ik.clip_into(model, jnp.asarray(x0, jnp.float32)))
    fitted = ik.fit_pose_2d(model, rig.to_jax(jnp.float32), uv, np.ones(uv.shape[:2]), x0, maxiter=60)
    err = np.linalg.norm(np.asarray(ik.model_joints(model, fitted)) - X, axis=-1)
    start = np.linalg.norm(np.asarray(ik.model_joints(model, jnp.asarray(x0))) - X, axis=-1)
    assert start.mean() > 0.4
    assert err.max() < 0.01, err


def test_fit_pose_2d_depth_its_jacobian_and_exact_depths(cmu):
    from jaxmocap.geometry import camera

    """The depth term of :func:`ik.fit_pose_2d` (``depth``, ``depth_weights``): its hand-written Jacobian equals automatic differentiation
    of its residual; with exact pixels (OpenCV) and exact camera depths of the five trunk joints (``R X + t``,
    third row), from the start of :func:`test_fit_pose_2d_recovers_a_mocap_pose_from_its_pixels`, the fit
    reprojects every joint within 1 px of its pixels and puts the trunk within 1 cm of the truth (a lower leg
    can settle in the pair's depth ambiguity: measured 13 cm for the right ankle, 0.6 px from its pixels);
    depths alone (no pixel weight) bring those joints' depths within 1 cm."""
    model, targets, _ = cmu["02_01"]
    x_true = np.asarray(_fit(model, targets).state[5], np.float64)
    X = np.asarray(ik.model_joints(model, jnp.asarray(x_true, jnp.float32)), np.float64)
    rig = _stereo_rig(X[0])
    uv = _opencv_pixels(rig, X)
    R, t = np.asarray(rig.R, np.float64), np.asarray(rig.t, np.float64)
    z_true = np.einsum("vb,jb->vj", R[:, 2], X) + t[:, 2:3]  # (V, J)
    some = [
        model.joint_names.index(j)
        for j in ("thorax", "left_hip", "right_hip", "left_shoulder", "right_shoulder")
    ]
    wz = np.zeros_like(z_true)
    wz[:, some] = 1.0 / 0.05**2
    x0 = x_true + 0.15 * np.random.default_rng(3).choice([-1.0, 1.0], size=x_true.shape)
    x0[:3] = x_true[:3] + [0.5, 0.0, 0.0]
    x0 = np.asarray(ik.clip_into(model, jnp.asarray(x0, jnp.float32)))
    rj = rig.to_jax(jnp.float32)
    u = ik.from_state(model, jnp.asarray(x0))
    args = (model, rj, jnp.asarray(uv, jnp.float32), jnp.ones(uv.shape[:2]), jnp.ones_like(u), u)
    args += (jnp.asarray(z_true, jnp.float32), jnp.sqrt(jnp.asarray(wz, jnp.float32)))
    # both compiled (run eagerly, each of their hundreds of operations would be compiled on its own)
    auto = jax.jit(jax.jacfwd(ik._residual_2d_depth))(u, *args)
    np.testing.assert_allclose(
        np.asarray(jax.jit(ik._residual_2d_depth_jac)(u, *args)), np.asarray(auto), atol=2e-3, rtol=1e-3
    )
    fitted = ik.fit_pose_2d(
        model, rj, uv, np.ones(uv.shape[:2]), x0, maxiter=60, depth=z_true, depth_weights=wz
    )
    Xf = ik.model_joints(model, fitted)
    err = np.linalg.norm(np.asarray(Xf) - X, axis=-1)
    assert err[some].max() < 0.01, err
    assert np.abs(np.asarray(camera.project(rj, Xf)) - uv).max() < 1.0
    alone = ik.fit_pose_2d(
        model,
        rj,
        uv,
        np.zeros(uv.shape[:2]),
        x0,
        prior_weight=1e-3,
        maxiter=60,
        depth=z_true,
        depth_weights=wz,
    )
    Xa = np.asarray(ik.model_joints(model, alone), np.float64)
    z = np.einsum("vb,jb->vj", R[:, 2], Xa) + t[:, 2:3]
    assert np.abs(z - z_true)[:, some].max() < 0.01
