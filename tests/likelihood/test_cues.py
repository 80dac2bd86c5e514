"""Cue energies against closed forms, OpenCV and the ray caster, on scenes rendered from the tracker's own model;
``check_grads`` on every cue marked differentiable."""

import dataclasses

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.features.colour import bhattacharyya_distance, roi_histograms
from jaxmocap.features.observation import make_observation
from jaxmocap.geometry import body, camera, flesh, render
from jaxmocap.likelihood import colour_cues, cues
from jaxmocap.likelihood import compose as L
from jaxmocap.synth.stage import look_at

W, H = 160, 120
#: a colour per primitive label (cones, then the head), and the background grey
COLOURS = np.array(
    [
        [0.2, 0.3, 0.7],
        [0.7, 0.2, 0.2],
        [0.2, 0.6, 0.3],
        [0.9, 0.7, 0.1],
        [0.5, 0.2, 0.6],
        [0.1, 0.6, 0.6],
        [0.4, 0.4, 0.4],
        [0.8, 0.4, 0.1],
        [0.3, 0.5, 0.9],
        [0.87, 0.67, 0.55],
    ],
    np.float32,
)
BACKGROUND = 0.55


def _rig(dist=None, scale=1):
    """The stereo pair, ``W × H`` images (``scale`` times that: the same views at another resolution)."""
    Rs, ts = zip(*[look_at(np.array([3.0, y, 1.3]), [0.0, 0.0, 1.0]) for y in (-0.15, 0.15)], strict=True)
    w, h = int(W * scale), int(H * scale)
    f = 140.0 * scale
    K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
    d = np.zeros((2, 5)) if dist is None else np.asarray(dist)
    return camera.from_opencv(np.stack([K, K]), d, np.stack(Rs), np.stack(ts), image_size=[(w, h)] * 2)


def _renders(model, rig, x):
    prims = render.primitives_from_model(model, x)
    return [
        render.render_view(rig.K[v], rig.dist[v], rig.R[v], rig.t[v], tuple(rig.image_size[v]), prims)
        for v in range(rig.num_views)
    ]


def _observe(model, rig, x, **over):
    fg, ed, dt, dep, sk, rgb = [], [], [], [], [], []
    head = len(flesh.cone_segments(model))  # the head's label
    for r in _renders(model, rig, x):
        lab = np.asarray(r.label)
        mask = lab >= 0
        e = cv2.Canny(mask.astype(np.uint8) * 255, 50, 150)
        fg.append(mask.astype(np.float32))
        ed.append(
            cv2.GaussianBlur(cv2.dilate(e, np.ones((3, 3), np.uint8)).astype(np.float32) / 255, (5, 5), 1.0)
        )
        dt.append(cv2.distanceTransform((e == 0).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE))
        dep.append(np.asarray(r.depth, np.float32))
        sk.append((lab == head).astype(np.float32))
        rgb.append(
            np.where(mask[..., None], COLOURS[np.maximum(lab, 0) % len(COLOURS)], BACKGROUND).astype(
                np.float32
            )
        )
    maps = dict(foreground=fg, edges=ed, edge_dt=dt, depth=dep, skin=sk, rgb=rgb)
    maps.update(over)
    return make_observation(rig, **maps)


@pytest.fixture(scope="module")
def scene():
    model = body.full25()
    rig = _rig()
    x = (
        model.rest_pose.at[model.dof_index("left_shoulder_rx")]
        .set(0.9)
        .at[model.dof_index("left_elbow")]
        .set(0.8)
        .at[model.dof_index("right_shoulder_rx")]
        .set(-0.5)
    )
    return model, rig, x, _observe(model, rig, x)


#: ``Likelihood.view_energies`` as one compiled program per likelihood structure (run eagerly, each of its hundreds
#: of operations would be compiled for its shapes on its own)
_view_energies = jax.jit(L.Likelihood.view_energies)


def _energy(model, rig, x, obs, cue, surface_points=300, ref=None):
    lik = L.Likelihood.create(model, rig, [cue], surface_points=surface_points)
    if cue.spec.reference:
        lik = lik.with_references(x if ref is None else ref[0], obs if ref is None else ref[1])
    return np.asarray(_view_energies(lik, x, obs))[0], lik


# ---------------------------------------------------------------------------------------------------------------
# Silhouettes


def _pixel_cover(cover, prims, rig, v, uv, *args):
    """``cover(prims, R, t, x, y, *args)`` of view ``v`` at the pixels ``uv (M, 2)``, undistorted by OpenCV into
    the normalised coordinates ``x, y`` (float32)."""
    xy = cv2.undistortPoints(uv[:, None, :], np.asarray(rig.K[v]), np.asarray(rig.dist[v]))[:, 0]
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    return np.asarray(cover(prims, f32(rig.R[v]), f32(rig.t[v]), f32(xy[:, 0]), f32(xy[:, 1]), *args))


def test_silhouette_cover_matches_ray_casting(scene):
    """The analytic projected-silhouette test of the divergence cue against the ray caster's mask, pixel by pixel,
    with lens distortion (pixels undistorted as the cue's prepare step does): they differ only on the boundary."""
    model, _, x, _ = scene
    rig = _rig(dist=[[-0.2, 0.05, 0.001, -0.001, 0.0]] * 2)
    R, t = body.segment_poses(model, x)
    prims = flesh.world_primitives(model, R, t)
    uv = np.stack(np.meshgrid(np.arange(W), np.arange(H)), -1).reshape(-1, 2).astype(np.float64)
    for v, r in enumerate(_renders(model, rig, x)):
        mask = np.asarray(r.label).reshape(-1) >= 0
        cov = _pixel_cover(cues._silhouette_cover, prims, rig, v, uv)
        boundary = (
            cv2.morphologyEx(
                mask.reshape(H, W).astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)
            ).reshape(-1)
            > 0
        )
        assert mask.sum() > 500
        assert np.all(cov[~boundary] == mask[~boundary])


def test_silhouette_divergence_is_the_uncovered_fraction(scene):
    """With at least as many samples as foreground grid pixels, eq. 4.6 on the grid is exactly the fraction of
    the observed foreground grid pixels the particle's rendered silhouette leaves uncovered (ray caster)."""
    model, rig, x, obs = scene
    xp = x.at[model.dof_index("left_shoulder_rx")].set(0.4)
    cue = L.Cue("silhouette_divergence", params={"grid": (40, 30), "samples": 1200})
    E, _ = _energy(model, rig, xp, obs, cue)
    us = np.floor((np.arange(40) + 0.5) * (W / 40)).astype(int)
    vs = np.floor((np.arange(30) + 0.5) * (H / 30)).astype(int)
    for v, r in enumerate(_renders(model, rig, xp)):
        F = np.asarray(obs.foreground[v])[np.ix_(vs, us)]
        model_mask = (np.asarray(r.label) >= 0)[np.ix_(vs, us)]
        ref = (F * ~model_mask).sum() / F.sum()
        assert abs(E[v] - ref) <= 2.0 / F.sum()  # a boundary pixel or two may go either way
        assert ref > 0.05


def _numpy_divergence(prims, rig, F, grid, samples):
    """Eq. 4.6 in NumPy, from :func:`cues.silhouette_divergence`'s docstring: ``(V,)`` energies
    ``Σ_s F(s) (1 − inside_v(s)) / Σ_s F(s)`` over the foreground grid pixels (raster order; every
    ``(count/samples)``-th, the ``⌊(j + ½) count / samples⌋``-th for ``j < samples``, when there are more than
    ``samples``), each undistorted by OpenCV and tested by marching its ray in 2 mm steps through the truncated
    cones (flat caps) and the ellipsoids."""
    gc, gr = grid
    us = np.floor((np.arange(gc) + 0.5) * (W / gc)).astype(int)
    vs = np.floor((np.arange(gr) + 0.5) * (H / gr)).astype(int)
    ca, cb = np.asarray(prims.cone_a, np.float64), np.asarray(prims.cone_b, np.float64)
    ra, rb = np.asarray(prims.r_a, np.float64), np.asarray(prims.r_b, np.float64)
    axis = cb - ca
    length = np.linalg.norm(axis, axis=-1)
    ahat = axis / length[:, None]
    centre, axes = np.asarray(prims.ell_centre, np.float64), np.asarray(prims.ell_axes, np.float64)
    depths = np.arange(1.5, 4.5, 0.002)
    out = []
    for v in range(rig.num_views):
        Fv = F[v][np.ix_(vs, us)].reshape(-1)
        uv = np.stack(np.meshgrid(us, vs), -1).reshape(-1, 2).astype(np.float64)
        idx = np.flatnonzero(Fv > 0)
        if len(idx) > samples:
            idx = idx[np.floor((np.arange(samples) + 0.5) * len(idx) / samples).astype(int)]
        xy = cv2.undistortPoints(uv[idx, None, :], np.asarray(rig.K[v]), np.asarray(rig.dist[v]))[:, 0]
        ray = np.concatenate([xy, np.ones((len(idx), 1))], 1)  # camera frame
        Rv, tv = np.asarray(rig.R[v], np.float64), np.asarray(rig.t[v], np.float64)
        pts = (depths[None, :, None] * ray[:, None, :] - tv) @ Rv  # (S, T, 3) world points along each ray
        inside = np.zeros(len(idx), bool)
        for c in range(len(length)):
            d = pts - ca[c]
            s = d @ ahat[c]
            radial = np.linalg.norm(d - s[..., None] * ahat[c], axis=-1)
            r = ra[c] + (rb[c] - ra[c]) * s / length[c]
            inside |= np.any((s >= 0) & (s <= length[c]) & (radial <= r), axis=1)
        for e in range(len(centre)):
            y = np.linalg.solve(axes[e], (pts - centre[e]).reshape(-1, 3).T).T
            inside |= np.any(np.sum(y * y, -1).reshape(pts.shape[:2]) <= 1.0, axis=1)
        w = Fv[idx]
        out.append((np.sum(w * ~inside) / np.sum(w), np.sum(w), len(idx)))
    return out


@pytest.fixture(scope="module")
def divergence_scene():
    """``upper9`` (the thesis' model) seen through distorting lenses; the observed foreground is the silhouette
    of another pose (arms elsewhere) with a legs-like block below it, weighted by a ramp in [0.4, 1]."""
    model = body.upper9()
    rig = _rig(dist=[[-0.25, 0.08, 0.002, -0.001, 0.0]] * 2)
    x = model.rest_pose.at[model.dof_index("left_shoulder_rx")].set(0.6)
    other = model.rest_pose.at[model.dof_index("right_shoulder_rx")].set(-0.9)
    ramp = np.linspace(0.4, 1.0, W, dtype=np.float32)[None, :]
    fg = []
    for r in _renders(model, rig, other):
        m = (np.asarray(r.label) >= 0).astype(np.float32)
        m[95:118, 65:95] = 1.0
        fg.append(m * ramp)
    R, t = body.segment_poses(model, x)
    return model, rig, x, np.stack(fg), flesh.world_primitives(model, R, t)


@pytest.mark.parametrize("samples", [64, 1200])
def test_silhouette_divergence_matches_numpy_eq_4_6(divergence_scene, samples):
    """The cue (its host-side undistorted grid, and the traced path a rig passed into ``jit`` takes) against a
    NumPy eq. 4.6 with OpenCV's undistortion and ray marching, on a subsample (64 of the foreground grid pixels)
    and on all of them: equal up to a sample on the silhouette's boundary (the ray march misses a grazing chord
    shorter than its step)."""
    model, rig, x, fg, prims = divergence_scene
    obs = make_observation(rig, foreground=list(fg))
    params = {"grid": (80, 60), "samples": samples}
    E, lik = _energy(model, rig, x, obs, L.Cue("silhouette_divergence", params=params))
    ref = _numpy_divergence(prims, rig, fg, (80, 60), samples)
    for v, (e_ref, total_w, n) in enumerate(ref):
        assert n == min(samples, int(np.sum(fg[v][1::2, 1::2] > 0)))  # the subsample, or all
        assert 0.1 < e_ref < 0.9
        assert abs(E[v] - e_ref) <= 1.0 / total_w + 1e-6  # at most one sample (weight ≤ 1) on the boundary
    ctx = lik._context(0)
    assert cues._grid_rays(rig, np.zeros((3, 2), np.float32)).shape == (
        2,
        3,
        2,
    )  # a concrete rig: the host table
    host = cues._prepare_divergence(obs, ctx, {})
    traced = jax.jit(lambda r: cues._prepare_divergence(obs, ctx._replace(rig=r), {}))(rig)
    for k in ("x", "y", "w"):
        np.testing.assert_allclose(np.asarray(traced[k]), np.asarray(host[k]), rtol=0, atol=1e-6)


def test_foreground_edges_and_depth_closed_forms(scene):
    model, rig, x, obs = scene
    ones = [np.ones((H, W), np.float32)] * 2
    zeros = [np.zeros((H, W), np.float32)] * 2
    # every sample on foreground / on an edge: E = 0 (the rig keeps the body inside both images)
    for name, field in (("foreground", "foreground"), ("edges", "edges")):
        E, _ = _energy(model, rig, x, _observe(model, rig, x, **{field: ones}), L.Cue(name))
        np.testing.assert_allclose(E, 0.0, atol=1e-6)
    # constant distance transform c: D = min(c, d_max) at every contour point, E = D² / 2σ²
    E, _ = _energy(
        model,
        rig,
        x,
        _observe(model, rig, x, edge_dt=[np.full((H, W), 12.0, np.float32)] * 2),
        L.Cue("edge_distance", params={"sigma_px": 5.0}),
    )
    np.testing.assert_allclose(E, 12.0**2 / 50.0, rtol=1e-5)
    # Li & Kulić depth: no foreground anywhere → every sample takes the 2.8 m penalty → E = 1
    E, _ = _energy(model, rig, x, _observe(model, rig, x, foreground=zeros), L.Cue("depth"))
    np.testing.assert_allclose(E, 1.0, rtol=1e-6)
    # the rendered depth of the true pose: facing samples that are visible match it; E is small and grows
    # when the arm moves. Foreground and depth are dilated by one pixel: at 160×120 a limb is a few pixels wide
    # and a sample on its rim may round to a background pixel (2.8 m each); here it reads the neighbour's depth.
    k = np.ones((3, 3), np.uint8)
    rs = _renders(model, rig, x)
    dil = _observe(
        model,
        rig,
        x,
        foreground=[
            cv2.dilate((np.asarray(r.label) >= 0).astype(np.uint8), k).astype(np.float32) for r in rs
        ],
        depth=[cv2.dilate(np.asarray(r.depth, np.float32), k) for r in rs],
    )
    E0, lik = _energy(model, rig, x, dil, L.Cue("depth"))
    E1 = np.asarray(_view_energies(lik, x.at[model.dof_index("left_shoulder_rx")].set(0.3), dil))[0]
    assert np.all(E0 < 0.02) and np.all(E1 > E0 + 0.05), (E0, E1)


# ---------------------------------------------------------------------------------------------------------------
# Colour and skin


def test_colour_bins_match_roi_histograms():
    """The device-side colour binning reproduces features.colour.roi_histograms (both spaces)."""
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (20, 30, 3)).astype(np.uint8)  # BGR
    rgb8 = jnp.asarray(img[..., ::-1].astype(np.int32))
    for space, bins in (("rgb", 4), ("rgb", 8), ("rg", 5)):
        ref = roi_histograms(img, [np.ones((20, 30), bool)], bins=bins, space=space)[0]
        b = np.asarray(colour_cues._colour_bins(rgb8, bins, space)).ravel()
        np.testing.assert_allclose(np.bincount(b, minlength=ref.size) / b.size, ref)


def test_slot_counts_batch_as_bincount():
    """The histogram counter equals np.bincount per particle, alone, under vmap (its flat batching rule), nested
    vmap and jit; a gradient through a cue that uses it is defined (the counts are constant in the pose)."""
    rng = np.random.default_rng(7)
    size = 11
    slots = rng.integers(0, size, size=(3, 4, 2, 25)).astype(np.int32)
    ref = np.stack([[np.bincount(s.reshape(-1), minlength=size) for s in row] for row in slots])
    count = colour_cues._counter(size)
    np.testing.assert_array_equal(np.asarray(count(jnp.asarray(slots[0, 0]))), ref[0, 0])
    np.testing.assert_array_equal(np.asarray(jax.vmap(count)(jnp.asarray(slots[0]))), ref[0])
    np.testing.assert_array_equal(np.asarray(jax.jit(jax.vmap(jax.vmap(count)))(jnp.asarray(slots))), ref)

    def f(x):
        h = count(jnp.clip(jnp.floor(x * size), 0, size - 1).astype(jnp.int32))
        return jnp.sum(h * jnp.arange(size)) + jnp.sum(x * x)

    x = jnp.asarray(rng.uniform(size=(2, 9)), jnp.float32)
    np.testing.assert_allclose(np.asarray(jax.vmap(jax.grad(f))(x)), 2 * np.asarray(x), rtol=1e-6)


def test_colour_histogram_closed_forms(scene):
    """Against the first frame's ROI histograms (features.colour.roi_histograms over rendered masks) the
    particle's own frame has D_r ≈ 0; a uniformly coloured image gives one-bin histograms, so
    D_r² = 1 − √q_r,b exactly (Bhattacharyya distance of features.colour)."""
    model, rig, x, obs = scene
    cue = L.Cue("colour_histogram", params={"sigma": 0.5})
    E, lik = _energy(model, rig, x, obs, cue)
    segs = sorted(set(lik.surface.segment))
    assert lik.references[0].shape == (2, len(segs), 64)
    np.testing.assert_allclose(np.asarray(lik.references[0]).sum(-1), 1.0, rtol=1e-5)
    # at the truth, only samples near an occluding limb or the outline land on another colour
    assert np.all(E / (len(segs) / (2 * 0.25)) < 0.1)
    c = np.array([0.1, 0.8, 0.45], np.float32)
    flat = _observe(model, rig, x, rgb=[np.broadcast_to(c, (H, W, 3)).copy()] * 2)
    E_flat = np.asarray(_view_energies(lik, x, flat))[0]
    b = int(colour_cues._colour_bins(jnp.asarray(np.round(c * 255).astype(np.int32)), 4, "rgb"))
    q = np.asarray(lik.references[0])  # (V, R, B)
    onehot = np.zeros(64)
    onehot[b] = 1.0
    ref = (bhattacharyya_distance(onehot, q) ** 2).sum(-1) / (2 * 0.25)
    np.testing.assert_allclose(E_flat, ref, rtol=1e-5)


def test_homogeneous_colour_of_noise(scene):
    """Per-limb colour spread of an image of i.i.d. uniform bytes: σ_l → √(var of a uniform byte / 255²) ≈ 0.289
    for every limb; the mean over limbs of the sample std is within its sampling error of that."""
    model, rig, x, _ = scene
    rng = np.random.default_rng(1)
    noise = [rng.integers(0, 256, (H, W, 3)).astype(np.float32) / 255 for _ in range(2)]
    E, lik = _energy(
        model, rig, x, _observe(model, rig, x, rgb=noise), L.Cue("homogeneous_colour"), surface_points=600
    )
    sd = np.sqrt(E * 2 * 0.1**2)
    expect = np.sqrt((256**2 - 1) / 12) / 255
    assert np.all(np.abs(sd - expect) < 0.03), (sd, expect)  # ~20-100 samples a limb, 8 limbs
    uniform = _observe(model, rig, x, rgb=[np.full((H, W, 3), 0.3, np.float32)] * 2)
    np.testing.assert_allclose(np.asarray(_view_energies(lik, x, uniform))[0], 0.0, atol=1e-5)


def test_colour_template_closed_forms(scene):
    """Li & Kulić eq. 3: zero against its own template; a uniform shift δ of all channels gives δ, up to the 8-bit
    colour quantisation (each channel's byte difference is within one byte of 255 δ, so E within 1/255 of δ)."""
    model, rig, x, obs = scene
    E, lik = _energy(model, rig, x, obs, L.Cue("colour_template"))
    np.testing.assert_allclose(E, 0.0, atol=1e-6)
    shifted = _observe(
        model, rig, x, rgb=[np.asarray(obs.rgb[v]) + 0.08 for v in range(2)]
    )  # max 0.98: no clip
    np.testing.assert_allclose(np.asarray(_view_energies(lik, x, shifted))[0], 0.08, atol=1.0 / 255)
    # bilinear reading: the template is read the same way, so the energy at the first frame is 0 as well
    E, _ = _energy(model, rig, x, obs, L.Cue("colour_template", params={"bilinear": True}))
    np.testing.assert_allclose(E, 0.0, atol=1e-6)


def test_skin_and_head_skin_closed_forms(scene):
    model, rig, x, obs = scene
    ones = [np.ones((H, W), np.float32)] * 2
    zeros = [np.zeros((H, W), np.float32)] * 2
    for field, Es, Eh in ((ones, 0.0, 0.0), (zeros, 3.0 / (2 * 0.25), 1.0)):
        o = _observe(model, rig, x, skin=field)
        np.testing.assert_allclose(_energy(model, rig, x, o, L.Cue("skin"))[0], Es, atol=1e-6)
        np.testing.assert_allclose(_energy(model, rig, x, o, L.Cue("head_skin"))[0], Eh, atol=1e-6)
    # the skin map is the rendered head, dilated by one pixel (a rim sample of the ~4-pixel head may round to
    # the pixel beside it): head term 0, both hands not skin (1) → skin E = 2 / 2σ², head_skin E = 0
    head = len(flesh.cone_segments(model))
    sk = [
        cv2.dilate((np.asarray(r.label) == head).astype(np.uint8), np.ones((3, 3), np.uint8))
        for r in _renders(model, rig, x)
    ]
    o = _observe(model, rig, x, skin=[s.astype(np.float32) for s in sk])
    np.testing.assert_allclose(_energy(model, rig, x, o, L.Cue("skin"))[0], 2.0 / (2 * 0.25), atol=1e-6)
    np.testing.assert_allclose(_energy(model, rig, x, o, L.Cue("head_skin"))[0], 0.0, atol=1e-6)
    # undilated: at most one rim sample of the head's ~11 camera-facing samples is off the skin map
    assert np.all(_energy(model, rig, x, obs, L.Cue("head_skin"))[0] <= 1.0 / 10)


# ---------------------------------------------------------------------------------------------------------------
# Detections and priors


def test_keypoints_against_opencv_projection(scene):
    """BODY_25B detections placed at cv2.projectPoints of the model's joints give E = 0; shifting every detection
    by d pixels gives the Geman–McClure value ρ(d/σ) exactly."""
    model, rig, x, obs = scene
    J = np.asarray(body.joint_positions(model, x), np.float64)
    kp = np.zeros((2, 25, 3), np.float32)
    for v in range(2):
        rvec, _ = cv2.Rodrigues(np.asarray(rig.R[v]))
        uv, _ = cv2.projectPoints(
            J, rvec, np.asarray(rig.t[v]), np.asarray(rig.K[v]), np.asarray(rig.dist[v])
        )
        for name, k in cues.BODY_25B_PAIRS:
            kp[v, k] = (*uv[model.joint_names.index(name), 0], 0.9)
    cue = L.Cue("keypoints", params={"layout": "body25b", "sigma_px": 10.0})
    E, lik = _energy(model, rig, x, obs._replace(keypoints2d=jnp.asarray(kp)), cue)
    np.testing.assert_allclose(E, 0.0, atol=1e-6)
    kp[..., 0] += 6.0
    kp[..., 1] -= 8.0
    E = np.asarray(_view_energies(lik, x, obs._replace(keypoints2d=jnp.asarray(kp))))[0]
    np.testing.assert_allclose(E, 1.0 / (1.0 + 1.0), rtol=1e-4)  # r = 10/10


def test_blob_and_distance_cues_closed_forms(scene):
    model, rig, x, obs = scene
    J = np.asarray(body.joint_positions(model, x))
    names = model.joint_names
    d = np.array([0.03, 0.0, 0.04])  # 5 cm
    blobs = np.stack(
        [J[names.index("head")] + d, J[names.index("left_wrist")], J[names.index("right_wrist")]]
    )
    o = obs._replace(blobs3d=jnp.asarray(blobs), blob_conf=jnp.asarray([1.0, 1.0, 0.0]))
    E, _ = _energy(model, rig, x, o, L.Cue("blobs3d", params={"sigma_m": 0.1}))
    np.testing.assert_allclose(E[0], 0.05**2 / (2 * 0.01) / 2, rtol=1e-4)
    o = obs._replace(blobs3d=jnp.asarray(blobs[[1, 2, 0]] + d), blob_conf=jnp.asarray([1.0, 0.5, 0.0]))
    E, _ = _energy(model, rig, x, o, L.Cue("wristband", params={"max_m": 0.5}))
    np.testing.assert_allclose(E[0], 0.05 / 0.5, rtol=1e-4)  # both wrists 5 cm from their band
    E, _ = _energy(
        model, rig, x, o, L.Cue("wristband", params={"slots": (("left_wrist", 1), ("right_wrist", 0))})
    )
    np.testing.assert_allclose(E[0], 1.0, rtol=1e-4)  # the wrong bands are far away: capped at 1
    # ground: lower the root 3 cm below standing → each ankle 3 cm under the floor
    E, _ = _energy(
        model, rig, x.at[2].add(-0.03 - float(J[names.index("left_ankle"), 2])), obs, L.Cue("ground")
    )
    np.testing.assert_allclose(E[0], 2 * 0.03 / 0.05, rtol=1e-3)


def test_interpenetration_closed_form(scene):
    """Closed forms: two parallel vertical cylinders whose axes are d apart: E = (r_i + r_j − d)² / s² when they
    overlap, else 0; a tapered cone crossing another at right angles: the radii are those at the crossing point.
    The rest pose (forearms beside the torso) does not penetrate (default pairs)."""
    model, rig, x, obs = scene
    E0, lik = _energy(model, rig, model.rest_pose, obs, L.Cue("interpenetration"))
    np.testing.assert_allclose(E0, 0.0)
    ctx = cues.CueContext(model.joint_names, {"pairs": ((0, 1),), "scale": 0.02}, rig, model)

    def energy(a, b, ra, rb):
        prims = flesh.Primitives(
            cone_a=jnp.asarray(a, jnp.float32),
            cone_b=jnp.asarray(b, jnp.float32),
            r_a=jnp.asarray(ra, jnp.float32),
            r_b=jnp.asarray(rb, jnp.float32),
            ell_centre=jnp.zeros((0, 3)),
            ell_axes=jnp.zeros((0, 3, 3)),
        )
        return float(cues.interpenetration(cues.Geometry(primitives=prims), obs, ctx))

    for d, ref in ((0.15, 0.0), (0.10, (0.11 - 0.10) ** 2 / 0.02**2), (0.05, (0.11 - 0.05) ** 2 / 0.02**2)):
        E = energy(
            [[0.0, 0.0, 1.0], [d, 0.0, 1.2]], [[0.0, 0.0, 0.5], [d, 0.0, 0.6]], [0.05, 0.06], [0.05, 0.06]
        )
        np.testing.assert_allclose(E, ref, rtol=1e-4, atol=1e-6)
    # cone 0 along z from 1.0 (r 0.08) to 0.0 (r 0.04); cone 1 along x at height 0.25, offset d in y,
    # from x = −0.5 (r 0.02) to 0.5 (r 0.06): at the crossing r_0 = 0.05, r_1 = 0.04
    for d, ref in ((0.095, 0.0), (0.07, (0.09 - 0.07) ** 2 / 0.02**2)):
        E = energy(
            [[0.0, 0.0, 1.0], [-0.5, d, 0.25]], [[0.0, 0.0, 0.0], [0.5, d, 0.25]], [0.08, 0.02], [0.04, 0.06]
        )
        np.testing.assert_allclose(E, ref, rtol=1e-4, atol=1e-6)


# ---------------------------------------------------------------------------------------------------------------
# Gradients


#: every cue in its differentiable configuration but the soft divergence, whose unrolled loop over the pieces of
#: every primitive at each sample would double the compilation of the Jacobian below: its derivative is checked in
#: the primitives it reads (test_smooth_cues.py)
DIFFERENTIABLE_CONFIGS = [
    (n, {"bilinear": True, "soft": True} if d == "soft" else {"bilinear": True} if d == "bilinear" else {})
    for n, d in cues.DIFFERENTIABLE.items()
    if d != "no" and n != "silhouette_divergence"
]


def test_differentiability_table_is_complete():
    """Every cue has a differentiable configuration; the three whose default reads are thresholds or inside tests
    (Li & Kulić's depth and edge fraction, López Méndez's divergence) have it with ``soft=True``."""
    assert set(cues.DIFFERENTIABLE) == set(cues.CUES)
    assert set(cues.DIFFERENTIABLE.values()) <= {"yes", "bilinear", "soft"}
    for name in ("edge_fraction", "depth", "silhouette_divergence", "colour_histogram"):
        assert cues.DIFFERENTIABLE[name] == "soft", name


#: parameters that make a cue active (non-zero, with a non-zero gradient) at the test pose, so the check can fail
ACTIVE_PARAMS = {
    "keypoints": {"pairs": (("left_wrist", 9), ("right_elbow", 8), ("head", 0))},
    "ground": {"floor": 0.06},  # the ankles stand at z ≈ 0.01: 5 cm below this floor
    "interpenetration": {"pairs": (("left_upper_arm", "torso"), ("right_upper_arm", "torso")), "scale": 0.02},
}


@pytest.fixture(scope="module")
def grads64(scene):
    """All differentiable cues in one float64 likelihood at a pose off the pixel grid: the reverse-mode Jacobian
    of the ``(C,)`` cue energies (one compiled program for every cue) and central differences along three fixed
    random directions."""
    with jax.enable_x64(True):
        model = body.full25(dtype=jnp.float64)
        rig = _rig()
        x0 = jnp.asarray(scene[2], jnp.float64)
        x = x0 + 0.011
        obs = jax.tree_util.tree_map(
            lambda a: jnp.asarray(a, jnp.float64) if a.dtype == jnp.float32 else a, scene[3]
        )
        J = np.asarray(body.joint_positions(model, x))
        obs = obs._replace(
            blobs3d=jnp.asarray(J[[2, 5, 8]] + 0.02),
            blob_conf=jnp.asarray([1.0, 1.0, 0.5]),
            keypoints2d=jnp.asarray(np.random.default_rng(2).uniform(20, 100, (2, 25, 3))),
        )
        cue_list = [L.Cue(n, params={**p, **ACTIVE_PARAMS.get(n, {})}) for n, p in DIFFERENTIABLE_CONFIGS]
        lik = L.Likelihood.create(model, rig, cue_list, surface_points=150, contour_points=4)

    # reference data (first-frame colours) built in float32, as the scene was rendered
    ref = L.Likelihood.create(body.full25(), rig, cue_list, surface_points=150, contour_points=4)
    ref = ref.with_references(scene[2], scene[3]).references

    with jax.enable_x64(True):
        to64 = lambda a: jnp.asarray(a, jnp.float64) if jnp.issubdtype(a.dtype, jnp.floating) else a  # noqa: E731
        lik = dataclasses.replace(lik, references=jax.tree_util.tree_map(to64, ref))
        aux = lik.prepare(obs)

        def value_and_jacobian(lik, x, obs, aux):
            e, vjp = jax.vjp(lambda x: lik.energies(x, obs, aux), x)
            return e, jax.vmap(vjp)(jnp.eye(e.shape[0], dtype=e.dtype))[0]  # (C,), (C, D)

        # one compiled program for every cue and every evaluation, at XLA's lowest backend optimisation level: the
        # same operations (the finite differences below evaluate the same program), compiled in ≈ 35 % less time
        f = (
            jax.jit(value_and_jacobian)
            .lower(lik, x, obs, aux)
            .compile(compiler_options={"xla_backend_optimization_level": 0})
        )
        E, jac = (np.asarray(a) for a in f(lik, x, obs, aux))
        u = np.random.default_rng(3).normal(size=(3, model.num_dofs))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        # bilinear maps are piecewise smooth: steps well inside a pixel (eps 1e-5 rad ≈ 1e-3 px)
        eps = 1e-5
        fd = np.stack(
            [
                (np.asarray(f(lik, x + eps * d, obs, aux)[0]) - np.asarray(f(lik, x - eps * d, obs, aux)[0]))
                / (2 * eps)
                for d in u
            ],
            1,
        )  # (C, 3)
        yield {c.name: (E[i], jac[i], jac[i] @ u.T, fd[i]) for i, c in enumerate(lik.cues)}


@pytest.mark.parametrize("name", [c[0] for c in DIFFERENTIABLE_CONFIGS])
def test_check_grads(grads64, name):
    """Reverse-mode gradients of every differentiable cue (in its differentiable configuration, active at the test
    pose) against central finite differences, in float64, along three random directions."""
    E, g, directional, fd = grads64[name]
    assert np.all(np.isfinite(g)) and np.abs(g).max() > 0, (name, E, g)
    np.testing.assert_allclose(directional, fd, atol=2e-3, rtol=2e-3, err_msg=name)


def test_nearest_capsule_distance_against_brute_force_and_numerical_derivatives():
    """The coverage cue's distance from each silhouette sample to the nearest projected capsule, against a NumPy
    loop over samples and capsules (foot of the perpendicular on the axis, clamped, less the radius interpolated
    there); its own derivative (the nearest capsule's alone) against numerical differences, forward and reverse,
    and against the automatic derivative of the plain minimum over capsules."""
    from jax.test_util import check_grads

    from jaxmocap.likelihood import coverage

    rng = np.random.default_rng(5)
    V, S, M = 2, 4, 6
    with jax.enable_x64(True):
        args = (
            rng.uniform(0, 60, (V, S, 2)),
            rng.uniform(0, 60, (V, S, 2)),
            rng.uniform(1, 5, (V, S, 1)),
            rng.uniform(1, 5, (V, S, 1)),
            rng.uniform(0, 60, (V, M, 2)),
        )
        ua, ub, pa, pb, uv = args
        ref = np.empty((V, M))
        for v in range(V):
            for m in range(M):
                d = []
                for s in range(S):
                    a, ab = ua[v, s], ub[v, s] - ua[v, s]
                    tau = np.clip(np.dot(uv[v, m] - a, ab) / np.dot(ab, ab), 0.0, 1.0)
                    r = pa[v, s, 0] + tau * (pb[v, s, 0] - pa[v, s, 0])
                    d.append(np.linalg.norm(uv[v, m] - a - tau * ab) - r)
                ref[v, m] = min(d)
        args = tuple(jnp.asarray(a) for a in args)
        f = jax.jit(coverage.nearest_capsule_distance)
        np.testing.assert_allclose(f(*args), ref, rtol=1e-10, atol=1e-9)
        check_grads(f, args, order=1, modes=("fwd", "rev"), eps=1e-6)
        plain = jax.jit(
            jax.grad(lambda *a: jnp.sum(jnp.min(coverage._capsule_distances(*a), axis=1)), range(5))
        )
        own = jax.jit(jax.grad(lambda *a: jnp.sum(f(*a)), range(5)))
        for g, h in zip(own(*args), plain(*args), strict=True):
            np.testing.assert_allclose(g, h, rtol=1e-10, atol=1e-12)
