"""Cue energies and their composition on scenes ray-cast from a known pose: minima near the truth, gradients,
schedules, compile-once."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.features.observation import make_observation
from jaxmocap.geometry import body, camera, kinematics, render
from jaxmocap.likelihood import compose as L
from jaxmocap.synth.generate import look_at

W, H = 320, 240


def _stereo_rig():
    """Two cameras 30 cm apart, 1.3 m high, 3 m in front of the subject (the IROS 2007 robot head)."""
    Rs, ts = zip(*[look_at(np.array([3.0, y, 1.3]), [0.0, 0.0, 1.0]) for y in (-0.15, 0.15)], strict=True)
    K = np.array([[262.5, 0.0, 159.5], [0.0, 262.5, 119.5], [0.0, 0.0, 1.0]])
    return camera.from_opencv(
        np.stack([K, K]), np.zeros((2, 5)), np.stack(Rs), np.stack(ts), image_size=[(W, H)] * 2
    )


def _observe(model, rig, x):
    prims = render.primitives_from_model(model, x)
    fgs, eds, dts, deps = [], [], [], []
    for v in range(rig.num_views):
        depth = np.asarray(render.render_view(rig.K[v], rig.dist[v], rig.R[v], rig.t[v], (W, H), prims).depth)
        mask = (depth > 0).astype(np.uint8)
        e = cv2.Canny(mask * 255, 50, 150)
        fgs.append(mask.astype(np.float32))
        eds.append(
            cv2.GaussianBlur(cv2.dilate(e, np.ones((3, 3), np.uint8)).astype(np.float32) / 255, (5, 5), 1.0)
        )
        dts.append(cv2.distanceTransform((e == 0).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE))
        deps.append(depth.astype(np.float32))
    return make_observation(rig, foreground=fgs, edges=eds, edge_dt=dts, depth=deps)


@pytest.fixture(scope="module")
def scene():
    model = body.full25()
    rig = _stereo_rig()
    x = (
        model.rest_pose.at[model.dof_index("left_shoulder_rx")]
        .set(0.8)
        .at[model.dof_index("left_elbow")]
        .set(0.9)
    )
    return model, rig, x, _observe(model, rig, x)


CUES = ("foreground", "edges", "edge_distance", "edge_fraction", "depth", "silhouette_divergence")


@pytest.fixture(scope="module")
def sweep(scene):
    """The likelihood of the sweep cues and one compiled per-particle energy function shared by the sweeps (the
    likelihood is an argument, so every sweep reuses the same program)."""
    model, rig, x, obs = scene
    lik = L.Likelihood.create(model, rig, [L.Cue(n) for n in CUES], surface_points=400)
    f = jax.jit(lambda lik, X, obs: jax.vmap(lik.energies, in_axes=(0, None))(X, obs))
    return lik, f


def test_surface_geometry_by_runs_equals_world_projection(scene):
    """The camera-from-segment transforms applied run by run give the projection of the world flesh points
    (transform_points, then camera.project_with_depth), and the visible index marks exactly the samples that face
    the camera (outward normal towards its centre) and lie in the image."""
    model, rig, x, obs = scene
    lik = L.Likelihood.create(model, rig, [L.Cue("depth")], surface_points=300)
    g = jax.jit(lambda lik, x: lik.geometry(x, (H, W)))(lik, x)
    R, t = body.segment_poses(model, x)
    Xw, Nw = lik.surface.world(R, t)
    uv, z = camera.project_with_depth(rig, Xw)
    np.testing.assert_allclose(np.asarray(g.surface_uv), np.asarray(uv), atol=2e-3)
    np.testing.assert_allclose(np.asarray(g.surface_depth), np.asarray(z), atol=1e-5)
    C = np.asarray(camera.camera_centres(rig))
    facing = np.einsum("pi,vpi->vp", np.asarray(Nw), C[:, None] - np.asarray(Xw)[None]) > 0
    np.testing.assert_array_equal(np.asarray(g.surface_facing), facing & (np.asarray(z) > 0))
    seen = np.asarray(g.surface_facing & g.surface_inside)
    vis = np.asarray(g.surface_visible_index)
    np.testing.assert_array_equal(vis[seen], np.asarray(g.surface_index)[seen])
    assert np.all(vis[~seen] == rig.num_views * H * W) and 0.2 < seen.mean() < 0.8
    # the per-point path (points not stored segment by segment) gives the same fields
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(kinematics, "MAX_RUNS", 0)
        g2 = jax.jit(lambda lik, x: lik.geometry(x, (H, W)))(lik, x)  # a new function: traced anew
    np.testing.assert_allclose(np.asarray(g2.surface_uv), np.asarray(g.surface_uv), atol=2e-3)
    for f in ("surface_facing", "surface_index", "surface_visible_index"):
        assert np.mean(np.asarray(getattr(g2, f)) == np.asarray(getattr(g, f))) > 0.99


@pytest.mark.parametrize("dof", ["left_elbow", "left_shoulder_rx"])
def test_energy_minimum_near_truth(scene, sweep, dof):
    """Sweeps of one arm angle (IROS 2007 Fig. 1, thesis Fig. 4.3): the unambiguous cues — the contour cues and the
    silhouette divergence — are minimal within one sweep step (0.1 rad) of the truth. The plain foreground match
    is not required to be: an arm moving inside the silhouette costs it nothing (the ambiguity eq. 4.6 removes)."""
    model, rig, x, obs = scene
    lik, f = sweep
    i = model.dof_index(dof)
    angles = np.round(np.arange(-0.5, 0.51, 0.1), 2) + float(x[i])
    E = np.asarray(f(lik, jnp.stack([x.at[i].set(a) for a in angles]), obs))
    truth = int(np.argmin(np.abs(angles - float(x[i]))))
    for c, name in enumerate(CUES):
        assert E[truth, c] <= E[:, c].max(), name
        if name in ("edges", "edge_distance", "edge_fraction", "silhouette_divergence"):
            assert abs(int(np.argmin(E[:, c])) - truth) <= 1, (name, E[:, c])
            assert E[truth, c] < E[0, c] and E[truth, c] < E[-1, c], (name, E[:, c])
    # the composed log-likelihood (APF schedule, λ = 1: −Σ_c E_c; that batch() equals −Σ λ E is tested in
    # test_schedules_and_compile_once) peaks at the truth as well
    ll = -E.sum(1)
    assert abs(int(np.argmax(ll)) - truth) <= 1


def test_differentiable_cue_gradients(scene):
    """The composed log-likelihood of differentiable cues (bilinear edge distance and foreground, ground active
    5 cm under a raised floor) has a finite non-zero reverse-mode gradient that matches central differences
    along three random directions, in float64 (one compiled program for value and gradient)."""
    model, rig, x, obs = scene
    with jax.enable_x64(True):
        m64 = body.full25(dtype=jnp.float64)
        cl = [
            L.Cue("edge_distance", params={"bilinear": True}),
            L.Cue("foreground", 2.0, params={"bilinear": True}),
            L.Cue("ground", params={"floor": 0.05}),
        ]
        lik64 = L.Likelihood.create(m64, rig, cl, surface_points=200, contour_points=4)
        obs64 = jax.tree_util.tree_map(
            lambda a: jnp.asarray(a, jnp.float64) if a.dtype == jnp.float32 else a, obs
        )
        x64 = jnp.asarray(x, jnp.float64) + 0.013
        f = jax.jit(jax.value_and_grad(lambda x, lik, obs: lik.log_likelihood(x, obs)))
        _, g = f(x64, lik64, obs64)
        g = np.asarray(g)
        assert np.all(np.isfinite(g)) and np.abs(g).max() > 0
        u = np.random.default_rng(0).normal(size=(3, m64.num_dofs))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        eps = 1e-7  # ≈ 1e-5 px: the bilinear maps are piecewise linear, a step must rarely cross a pixel edge
        fd = [
            (float(f(x64 + eps * d, lik64, obs64)[0]) - float(f(x64 - eps * d, lik64, obs64)[0])) / (2 * eps)
            for d in u
        ]
        np.testing.assert_allclose(u @ g, fd, atol=1e-3, rtol=1e-3)


def test_schedules_and_compile_once(scene):
    model, rig, x, obs = scene
    cl = [L.Cue("foreground"), L.Cue("edges")]
    lam = L.schedule_preset("fbapf", [c.name for c in cl], 3)
    np.testing.assert_allclose(lam, [[1, 0], [1, 0.5], [1, 1]])
    np.testing.assert_allclose(L.schedule_preset("li-kulic", ["depth"], 2), np.log(100.0))
    lik = L.Likelihood.create(model, rig, cl, num_layers=3, schedule="fbapf", surface_points=200)
    traces = []

    def f(X, obs, layer):
        traces.append(1)
        return lik.batch(X, obs, layer)

    jf = jax.jit(f)
    X = x + 0.05 * jax.random.normal(jax.random.key(0), (64, model.num_dofs))
    e = np.asarray(
        jax.jit(lambda lik, X, obs: jax.vmap(lik.energies, in_axes=(0, None))(X, obs))(lik, X, obs)
    )
    for layer in range(3):
        # separately compiled programs may round a sample to a neighbouring pixel: one sample is 1/P of an energy
        np.testing.assert_allclose(np.asarray(jf(X, obs, layer)), -(e * lam[layer]).sum(1), atol=1.0 / 200)
    obs2 = jax.tree_util.tree_map(lambda a: a * 1, obs)
    jf(X + 0.01, obs2, 1)
    assert len(traces) == 1


def test_missing_observation_field_is_a_clear_error(scene):
    model, rig, x, obs = scene
    lik = L.Likelihood.create(model, rig, [L.Cue("keypoints", params={"pairs": (("head", 0),)})])
    with pytest.raises(ValueError, match="keypoints2d"):
        lik.check_observation(obs)
    with pytest.raises(ValueError, match="unknown cue"):
        L.Cue("nonsense")


def test_all_invalid_particles_give_minus_inf_not_nan(scene):
    model, rig, x, obs = scene
    lik = L.Likelihood.create(model, rig, [L.Cue("edges")], surface_points=100)
    X = jnp.full((4, model.num_dofs), jnp.nan)
    ll = jax.jit(lambda lik, X, obs: lik.batch(X, obs, 0))(lik, X, obs)
    assert not bool(jnp.any(jnp.isnan(ll)))


def test_coverage_is_composed_as_a_term_after_the_table(scene):
    """The registered ``coverage`` cue enters ``Likelihood.batch`` as ``−λ_cov(l) k_cov Σ_v E_v`` subtracted after
    the λ table of the other cues: bit for bit a likelihood without it minus that term computed from
    :func:`jaxmocap.likelihood.coverage.coverage_energy` (the order of float operations on which tracks depend), in
    every layer (the table's particles in padded chunks); its λ may not differ between views."""
    from jaxmocap.likelihood.coverage import coverage_energy, d_max_of

    model, rig, x, obs = scene
    names = ["foreground", "coverage", "edges"]
    lam = L.schedule_preset("fbapf2", names, 3)  # coverage: max(1 − l/2, 0.25)
    kw = dict(num_layers=3, surface_points=200, chunk_size=16)
    full = L.Likelihood.create(
        model, rig, [L.Cue("foreground"), L.Cue("coverage", 1.5), L.Cue("edges", 2.0)], schedule=lam, **kw
    )
    table = L.Likelihood.create(
        model, rig, [L.Cue("foreground"), L.Cue("edges", 2.0)], schedule=lam[:, [0, 2]], **kw
    )
    d_max = d_max_of(rig)

    def reference(X, obs, layer):
        uv, w = full.prepare(obs)[1]  # the silhouette samples, from the foreground map
        cover = jax.vmap(lambda s: jnp.sum(coverage_energy(model, full.rig, s, uv, w, d_max)))(X)
        ll = table.batch(X, obs, layer) - jnp.asarray(lam[:, 1] * np.float32(1.5))[layer] * cover
        return jnp.where(jnp.isfinite(ll), ll, -jnp.inf)

    X = x + 0.05 * jax.random.normal(jax.random.key(3), (50, model.num_dofs))
    batch, reference = jax.jit(full.batch), jax.jit(reference)
    for layer in range(3):
        got = np.asarray(batch(X, obs, layer))
        np.testing.assert_array_equal(got, np.asarray(reference(X, obs, layer)))
    assert np.all(np.isfinite(got))
    per_view = np.repeat(lam[:, :, None], 2, axis=2)
    per_view[0, 1, 1] = 0.5
    with pytest.raises(ValueError, match="coverage.*same for every view"):
        L.Likelihood.create(model, rig, [L.Cue(n) for n in names], num_layers=3, schedule=per_view)
