"""Gradients of the log-likelihood w.r.t. pose, cameras and body dimensions: JAX's derivatives against finite
differences (``check_grads``), the camera gradient against OpenCV's ``projectPoints`` Jacobian, the body-dimension
gradient against a closed form, and the batched form against the per-particle one."""

import dataclasses

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxmocap.features.observation import make_observation
from jaxmocap.geometry import body, camera, render
from jaxmocap.likelihood import compose as L
from jaxmocap.likelihood import gradients
from jaxmocap.synth.generate import look_at

W, H = 160, 120


def _rig():
    """Two cameras in front of and beside the subject, mild distortion (so every camera parameter matters)."""
    Rs, ts = zip(
        *[look_at(np.array(c), [0.0, 0.0, 1.0]) for c in ([3.0, 0.4, 1.4], [0.5, 3.2, 1.2])], strict=True
    )
    K = np.array([[131.0, 0.0, 79.5], [0.0, 133.0, 59.5], [0.0, 0.0, 1.0]])
    dist = np.array([[-0.05, 0.01, 0.001, -0.002, 0.0], [0.03, -0.01, 0.0, 0.001, 0.002]])
    return camera.from_opencv(np.stack([K, K]), dist, np.stack(Rs), np.stack(ts), image_size=[(W, H)] * 2)


def _pose(model):
    x = model.rest_pose
    for name, v in (
        ("left_shoulder_rx", 0.7),
        ("left_elbow", 0.8),
        ("right_shoulder_ry", -0.4),
        ("root_rz", 0.3),
    ):
        x = x.at[model.dof_index(name)].set(v)
    return x


@pytest.fixture(scope="module")
def scene():
    """A full25 subject seen by two cameras; maps rendered from the model, keypoints its projected joints + noise."""
    model = body.full25()
    rig = _rig()
    x = _pose(model)
    prims = render.primitives_from_model(model, x)
    fgs, dts = [], []
    for v in range(2):
        depth = np.asarray(render.render_view(rig.K[v], rig.dist[v], rig.R[v], rig.t[v], (W, H), prims).depth)
        mask = (depth > 0).astype(np.uint8)
        e = cv2.Canny(mask * 255, 50, 150)
        fgs.append(cv2.GaussianBlur(mask.astype(np.float32), (5, 5), 1.5))
        dts.append(cv2.distanceTransform((e == 0).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE))
    J = np.asarray(body.joint_positions(model, x))
    uv = np.asarray(camera.project(rig, J)) + np.random.default_rng(0).normal(0, 3.0, (2, J.shape[0], 2))
    kp = np.concatenate([uv, np.ones((2, J.shape[0], 1))], -1)
    obs = make_observation(rig, foreground=fgs, edge_dt=dts, keypoints2d=kp)
    return model, rig, x, obs


def _to64(tree):
    return jax.tree_util.tree_map(
        lambda a: jnp.asarray(a, jnp.float64) if jnp.issubdtype(jnp.asarray(a).dtype, jnp.floating) else a,
        tree,
    )


PAIRS = tuple((n, i) for i, n in enumerate(body.EVAL_JOINTS))


def _check_grads(value, value_and_grad, x, tol, eps=None):
    """``check_grads`` (reverse mode, first order, ``atol = rtol = tol``) of ``value`` at ``x``, with the gradient
    that ``value_and_grad`` returns as its reverse-mode derivative.

    It compares that gradient against central differences of ``value`` (the plain forward program, no derivative
    in it) along a random direction, and the value ``value_and_grad`` returns against ``value``'s. Both are compiled
    once: differentiating a jitted ``value`` instead would compile its linearised and transposed forms as two more
    programs, and evaluating eagerly compiles every primitive on its own.
    """

    @jax.custom_vjp
    def f(a):
        return value(a)

    def bwd(grad, ct):
        return (jax.tree_util.tree_map(lambda g: ct * g, grad),)

    f.defvjp(value_and_grad, bwd)
    check_grads(f, (x,), order=1, modes=["rev"], atol=tol, rtol=tol, eps=eps)


def _cues():
    return [
        L.Cue("edge_distance", params={"bilinear": True}),
        L.Cue("foreground", params={"bilinear": True}),
        L.Cue("keypoints", params={"pairs": PAIRS, "sigma_px": 15.0}),
        L.Cue("ground", params={"floor": 0.08}),  # the ankles stand at z ≈ 0: the cue is active
    ]


def test_pose_gradient_against_finite_differences(scene):
    model, rig, x, obs = scene
    with jax.enable_x64(True):
        m64 = body.full25(dtype=jnp.float64)
        lik = L.Likelihood.create(m64, rig, _cues(), surface_points=80, contour_points=3)
        obs64, x64 = _to64(obs), jnp.asarray(x, jnp.float64) + 0.011
        value = jax.jit(lambda lik, s, o: lik.log_likelihood(s, o))
        value_and_grad = jax.jit(gradients.value_and_grad_pose)
        f = lambda s: value(lik, s, obs64)  # noqa: E731
        # bilinear lookups are piecewise linear: a small step (1e-6) rarely crosses a pixel cell boundary
        _check_grads(f, lambda s: value_and_grad(lik, s, obs64), x64, 1e-3, eps=1e-6)
        v, g = value_and_grad(lik, x64, obs64)
        assert float(v) == pytest.approx(float(f(x64)), rel=1e-12)
        # central differences of the value for a few entries (root translation and heading, arm, leg, neck)
        h = 1e-6
        dofs = [
            model.dof_index(n)
            for n in ("root_tx", "root_rz", "left_elbow", "left_shoulder_rx", "right_hip_ry")
        ]
        fd = np.array([(f(x64.at[d].add(h)) - f(x64.at[d].add(-h))) / (2 * h) for d in dofs])
        np.testing.assert_allclose(np.asarray(g)[dofs], fd, rtol=1e-4, atol=1e-5)
        assert np.abs(fd).max() > 1e-2  # the test is not vacuous


def test_batched_gradients_match_single_and_mask_dead_particles(scene):
    """Both paths of ``batch_value_and_grad`` (a bound ``Likelihood.batch``: vmapped per-particle gradients; any
    other batched function: one ``vjp``) agree with the per-particle gradient; dead particles get −inf and 0."""
    model, rig, x, obs = scene
    lik = L.Likelihood.create(model, rig, _cues()[2:], surface_points=60, contour_points=3)
    X = x + 0.05 * jax.random.normal(jax.random.key(0), (5, x.shape[0]))
    single = jax.jit(lambda lik, X, o: jax.vmap(lambda s: gradients.value_and_grad_pose(lik, s, o))(X))(
        lik, X, obs
    )
    values, G = jax.jit(lambda lik, X, o: gradients.batch_value_and_grad(lik.batch, X, o, 0))(lik, X, obs)
    np.testing.assert_allclose(values, single[0], rtol=1e-6)
    np.testing.assert_allclose(G, single[1], rtol=1e-5, atol=1e-7)
    assert float(jnp.abs(G).max()) > 0
    # more particles than a chunk: in chunks (the last one padded), the same values and gradients
    chunked = dataclasses.replace(lik, chunk_size=2)
    vc, Gc = jax.jit(lambda lik, X, o: lik.batch_value_and_grad(X, o, 0))(chunked, X, obs)
    np.testing.assert_allclose(vc, values, rtol=1e-6)
    np.testing.assert_allclose(Gc, G, rtol=1e-5, atol=1e-7)

    def dead_rows(lik):  # a batched likelihood whose rows 1 and 3 give NaN / +inf
        def loglik(X, o, layer):
            ll = lik.batch(X, o, layer)
            return ll.at[1].set(jnp.nan).at[3].set(jnp.inf)

        return loglik

    v2, G2 = jax.jit(lambda lik, X, o: gradients.batch_value_and_grad(dead_rows(lik), X, o, 0))(lik, X, obs)
    assert np.isneginf(v2[1]) and np.isneginf(v2[3])
    assert np.all(np.asarray(G2[1]) == 0) and np.all(np.asarray(G2[3]) == 0)
    np.testing.assert_allclose(
        np.asarray(G2)[[0, 2, 4]], np.asarray(G)[[0, 2, 4]], rtol=1e-4, atol=1e-6
    )  # vjp vs vmapped grads (float32)


def test_camera_gradient_against_opencv_jacobian(scene):
    """With only the keypoint cue, ``ℓ = −Σ_v Σ_k ρ(‖u_vk − z_vk‖/σ) / K`` and ``∂ℓ/∂θ_v = Σ_k ∂ℓ/∂u_vk · ∂u_vk/∂θ_v``
    with ``∂u/∂θ`` from ``cv2.projectPoints`` (rvec, tvec, f, c, distortion) and the Geman–McClure derivative in closed
    form. Also ``check_grads`` on every camera parameter (skew included)."""
    model, rig, x, obs = scene
    sigma = 15.0
    with jax.enable_x64(True):
        m64 = body.full25(dtype=jnp.float64)
        lik = L.Likelihood.create(m64, rig, [L.Cue("keypoints", params={"pairs": PAIRS, "sigma_px": sigma})])
        obs64, x64 = _to64(obs), jnp.asarray(x, jnp.float64)
        params = gradients.camera_params(rig, jnp.float64)
        total = jax.jit(
            lambda p, x, o: gradients.total_log_likelihood(
                dataclasses.replace(lik, rig=gradients.rig_from_params(p, lik.rig)), x, o
            )
        )
        value_and_grad = jax.jit(lambda p, x, o: gradients.camera_value_and_grad(lik, p, x, o))
        value, g = value_and_grad(params, x64, obs64)
        _check_grads(lambda p: total(p, x64, obs64), lambda p: value_and_grad(p, x64, obs64), params, 1e-4)
        J = np.asarray(body.joint_positions(m64, x64), np.float64)
    z = np.asarray(obs.keypoints2d, np.float64)
    total = 0.0
    for v in range(2):
        rvec = cv2.Rodrigues(np.asarray(rig.R[v], np.float64))[0]
        uv, jac = cv2.projectPoints(
            J, rvec, np.asarray(rig.t[v], np.float64), np.asarray(rig.K[v]), rig.dist[v]
        )
        uv, jac = uv.reshape(-1, 2), jac.reshape(-1, 2, jac.shape[-1])
        d = uv - z[v, :, :2]
        r2 = np.sum(d * d, axis=1) / sigma**2
        total += -np.mean(r2 / (1 + r2))
        dl_du = -(2 * d / sigma**2) / ((1 + r2) ** 2)[:, None] / len(J)  # (K, 2)
        grad = np.einsum("ki,kij->j", dl_du, jac)  # rvec 3, tvec 3, f 2, c 2, dist 5
        np.testing.assert_allclose(np.asarray(g.rvec[v]), grad[0:3], rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(np.asarray(g.t[v]), grad[3:6], rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(np.asarray(g.focal[v]), grad[6:8], rtol=1e-6, atol=1e-12)
        np.testing.assert_allclose(np.asarray(g.centre[v]), grad[8:10], rtol=1e-6, atol=1e-12)
        np.testing.assert_allclose(np.asarray(g.dist[v]), grad[10:15], rtol=1e-6, atol=1e-9)
    assert float(value) == pytest.approx(total, rel=1e-9)


def test_rig_round_trip(scene):
    _, rig, _, _ = scene
    with jax.enable_x64(True):
        back = gradients.rig_from_params(gradients.camera_params(rig, jnp.float64), rig)
        for k in ("K", "dist", "R", "t"):
            np.testing.assert_allclose(np.asarray(getattr(back, k)), np.asarray(getattr(rig, k)), atol=1e-12)
        assert back.names == rig.names and back.image_size == rig.image_size


def test_body_dimension_gradient_closed_form_and_finite_differences(scene):
    """One 3D blob near the left wrist: ``ℓ = −‖X_w − b‖² / (2σ²)``, so ``∂ℓ/∂(forearm length) = −(X_w − b)·ê_fa / σ²``
    and ``∂ℓ/∂(upper-arm length) = −(X_w − b)·ê_ua / σ²`` with ``ê`` the unit vectors elbow→wrist and shoulder→elbow.
    Then ``check_grads`` w.r.t. lengths and radii through the image cues (flesh points follow the dimensions)."""
    model, rig, x, obs = scene
    sigma = 0.1
    with jax.enable_x64(True):
        m64 = body.full25(dtype=jnp.float64)
        x64 = jnp.asarray(x, jnp.float64)
        J = np.asarray(body.joint_positions(m64, x64))
        idx = {n: i for i, n in enumerate(m64.joint_names)}
        b = J[idx["left_wrist"]] + np.array([0.03, -0.02, 0.04])
        obs_b = _to64(
            obs._replace(blobs3d=jnp.asarray(np.stack([b, b + 50, b + 50])), blob_conf=jnp.array([1.0, 0, 0]))
        )
        lik = L.Likelihood.create(
            m64, rig, [L.Cue("blobs3d", params={"joints": ("left_wrist",), "sigma_m": sigma})]
        )
        dims = {"left_forearm_length": 0.26, "left_upper_arm_length": 0.29, "thigh_length": 0.43}
        value, g = jax.jit(lambda d, x, o: gradients.body_value_and_grad(lik, d, x, o))(dims, x64, obs_b)
        r = J[idx["left_wrist"]] - b
        e_fa = J[idx["left_wrist"]] - J[idx["left_elbow"]]
        e_ua = J[idx["left_elbow"]] - J[idx["left_shoulder"]]
        assert float(value) == pytest.approx(-r @ r / (2 * sigma**2), rel=1e-10)
        assert float(g["left_forearm_length"]) == pytest.approx(
            -r @ e_fa / np.linalg.norm(e_fa) / sigma**2, rel=1e-8
        )
        assert float(g["left_upper_arm_length"]) == pytest.approx(
            -r @ e_ua / np.linalg.norm(e_ua) / sigma**2, rel=1e-8
        )
        assert float(g["thigh_length"]) == pytest.approx(
            0.0, abs=1e-10
        )  # the wrist does not depend on the legs

        # image cues: finite differences through the rebuilt model and its flesh points
        lik_img = L.Likelihood.create(m64, rig, _cues()[:2], surface_points=80, contour_points=3)
        obs64 = _to64(obs)
        names = ("left_forearm_length", "upper_arm_radius_top", "torso_radius_top", "shoulder_width")
        d0 = {k: jnp.asarray(body.DEFAULT_DIMENSIONS[k.removeprefix("left_")], jnp.float64) for k in names}
        d0 = {k: v * 1.03 for k, v in d0.items()}  # away from the rendered subject's optimum
        value = jax.jit(
            lambda d, x, o: gradients.total_log_likelihood(
                gradients.likelihood_with_dimensions(lik_img, d), x, o
            )
        )
        value_and_grad = jax.jit(lambda d, x, o: gradients.body_value_and_grad(lik_img, d, x, o))
        x1 = x64 + 0.01
        _check_grads(
            lambda d: value(d, x1, obs64), lambda d: value_and_grad(d, x1, obs64), d0, 1e-3, eps=1e-6
        )
        _, g_img = value_and_grad(d0, x1, obs64)
        assert max(abs(float(v)) for v in g_img.values()) > 1e-3


def test_with_body_reproduces_the_likelihood(scene):
    model, rig, x, obs = scene
    lik = L.Likelihood.create(model, rig, _cues()[:3], surface_points=80, contour_points=3)
    same = gradients.with_body(lik, body.full25())
    X = x + 0.05 * jax.random.normal(jax.random.key(1), (4, x.shape[0]))
    batch = jax.jit(lambda lik, X, o: lik.batch(X, o, 0))  # one program: the two differ in their leaves only
    np.testing.assert_array_equal(np.asarray(batch(same, X, obs)), np.asarray(batch(lik, X, obs)))
    with pytest.raises(ValueError, match="same preset"):
        gradients.with_body(lik, body.upper14())
