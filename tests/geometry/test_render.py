"""Ray-casting renderer against independent float64 ray marching + brentq, OpenCV projection, and host-side images."""

import cv2
import jax.numpy as jnp
import numpy as np
import pytest
from jax import enable_x64
from scipy.optimize import brentq

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import body, flesh, render

W, H = 200, 150
K = np.array([[300.0, 0.0, 99.5], [0.0, 300.0, 74.5], [0.0, 0.0, 1.0]])
DIST = np.array([-0.25, 0.08, 0.002, -0.001, 0.0])


def _look_at(c, target):
    c = np.asarray(c, float)
    f = np.asarray(target, float) - c
    f /= np.linalg.norm(f)
    xr = np.cross(f, [0.0, 0.0, 1.0])
    xr /= np.linalg.norm(xr)
    R = np.stack([xr, np.cross(f, xr), f])
    return R, -R @ c


def _scene(dtype=np.float32):
    """Four cones and an ellipsoid, spread out so that each one's centre is visible from the camera."""
    a = np.array([[0.0, -0.5, 0.6], [0.1, 0.0, 0.5], [0.0, 0.45, 0.9], [-0.3, 0.2, 1.6]])
    b = np.array([[0.05, -0.45, 1.2], [0.0, 0.1, 1.0], [0.3, 0.65, 0.7], [0.2, 0.5, 1.5]])
    ra = np.array([0.07, 0.09, 0.05, 0.04])
    rb = np.array([0.05, 0.06, 0.05, 0.06])
    rot = cv2.Rodrigues(np.array([0.3, -0.2, 0.5]))[0]
    axes = (rot @ np.diag([0.08, 0.1, 0.13]))[None]
    centre = np.array([[0.0, -0.1, 1.55]])
    return flesh.Primitives(*(jnp.asarray(v, dtype) for v in (a, b, ra, rb, centre, axes)))


CAMERA = _look_at([3.0, 0.6, 1.4], [0.0, 0.0, 1.0])


def _implicit(prims, caps):
    """Signed inside functions (negative inside), one per primitive, for points ``(N, 3)`` in float64."""
    P = {k: np.asarray(v, np.float64) for k, v in prims._asdict().items()}
    fs = []
    for i in range(len(P["r_a"])):
        a, b, ra, rb = P["cone_a"][i], P["cone_b"][i], P["r_a"][i], P["r_b"][i]

        def f(X, a=a, b=b, ra=ra, rb=rb):
            ax = b - a
            L = np.linalg.norm(ax)
            ax = ax / L
            z = (X - a) @ ax
            rho = np.linalg.norm((X - a) - z[:, None] * ax, axis=1)
            val = np.maximum(rho - (ra + (rb - ra) * z / L), np.maximum(-z, z - L))
            if caps == "sphere":
                val = np.minimum(
                    val, np.minimum(np.linalg.norm(X - a, axis=1) - ra, np.linalg.norm(X - b, axis=1) - rb)
                )
            return val

        fs.append(f)
    for e in range(len(P["ell_centre"])):
        Minv = np.linalg.inv(P["ell_axes"][e])
        fs.append(lambda X, m=P["ell_centre"][e], Minv=Minv: np.linalg.norm((X - m) @ Minv.T, axis=1) - 1.0)
    return fs


def _reference_hit(fs, origin, d, t_max=8.0, step=1e-3):
    """First surface crossing along ``origin + τ d``: march in ``step`` then refine with brentq (float64).
    Returns ``(τ, label)`` or ``(0, −1)``."""
    taus = np.arange(0.05, t_max, step)
    X = origin + taus[:, None] * d
    vals = np.stack([f(X) for f in fs])  # (n_prims, n_steps)
    union = vals.min(0)
    inside = np.nonzero(union <= 0)[0]
    if len(inside) == 0:
        return 0.0, -1
    j = inside[0]
    lab = int(np.argmin(vals[:, j]))
    g = lambda tau: min(f((origin + tau * d)[None])[0] for f in fs)  # noqa: E731
    return brentq(g, taus[j - 1], taus[j], xtol=1e-13, rtol=1e-15), lab


def _kinv_xy(u, v):
    p = np.linalg.solve(K, [u, v, 1.0])
    return p[0] / p[2], p[1] / p[2]


def _interior(label, r=2):
    """Pixels whose (2r+1)² neighbourhood shares their label (away from silhouettes and occlusion edges)."""
    lab = label.astype(np.int32) + 1
    k = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
    lo = cv2.erode(lab.astype(np.float32), k)
    hi = cv2.dilate(lab.astype(np.float32), k)
    return (lo == hi) & (lab > 0)


@pytest.mark.parametrize("caps", ["flat", "sphere"])
def test_depth_matches_independent_ray_marching(caps):
    R, t = CAMERA
    origin = -R.T @ t
    rays = render.pixel_rays(K, None, (W, H))
    with enable_x64(True):
        prims64 = _scene(np.float64)
        out64 = render.render(
            jnp.asarray(rays, jnp.float64), jnp.asarray(R), jnp.asarray(t), prims64, caps=caps
        )
        assert out64.depth.dtype == jnp.float64
        depth64, label64 = np.asarray(out64.depth), np.asarray(out64.label)
    out32 = render.render(
        jnp.asarray(rays), jnp.asarray(R, jnp.float32), jnp.asarray(t, jnp.float32), _scene(), caps=caps
    )
    depth32, label32 = np.asarray(out32.depth), np.asarray(out32.label)
    fs = _implicit(prims64, caps)
    rng = np.random.default_rng(0)
    inner = np.argwhere(_interior(label64))
    assert len(inner) > 500
    picks = [tuple(p) for p in inner[rng.choice(len(inner), 40, replace=False)]]
    bg = np.argwhere(label64 < 0)
    picks += [tuple(p) for p in bg[rng.choice(len(bg), 10, replace=False)]]
    for v, u in picks:
        x, y = rays[v, u].astype(np.float64)  # the renderer's own (float32) ray; K⁻¹ checked below
        np.testing.assert_allclose((x, y), _kinv_xy(u, v), atol=1e-6)
        d = R.T @ np.array([x, y, 1.0])
        tau, lab = _reference_hit(fs, origin, d)
        assert label64[v, u] == lab and label32[v, u] == lab
        # τ along d with d_z = 1 in the camera frame is the camera depth
        np.testing.assert_allclose(depth64[v, u], tau, rtol=0, atol=1e-9)
        np.testing.assert_allclose(depth32[v, u], tau, rtol=0, atol=1e-4)
    # float32 everywhere on interior pixels: within 0.1 mm of the float64 render
    both = _interior(label64) & (label32 == label64)
    assert np.abs(depth32[both] - depth64[both]).max() < 1e-4


def test_normals_match_implicit_gradient():
    R, t = CAMERA
    with enable_x64(True):
        prims = _scene(np.float64)
        rays = render.pixel_rays(K, None, (W, H))
        out = render.render(
            jnp.asarray(rays, jnp.float64), jnp.asarray(R), jnp.asarray(t), prims, caps="sphere"
        )
        depth, label, normal = (np.asarray(v) for v in out)
    fs = _implicit(prims, "sphere")
    inner = np.argwhere(_interior(label))
    rng = np.random.default_rng(1)
    origin = -R.T @ t
    for v, u in inner[rng.choice(len(inner), 40, replace=False)]:
        x, y = rays[v, u].astype(np.float64)
        X = origin + depth[v, u] * (R.T @ np.array([x, y, 1.0]))
        f = fs[label[v, u]]
        h = 1e-6
        g = np.array([(f((X + h * e)[None]) - f((X - h * e)[None]))[0] / (2 * h) for e in np.eye(3)])
        g_cam = R @ (g / np.linalg.norm(g))
        assert np.dot(g_cam, normal[v, u]) > 0.999
        assert normal[v, u, 2] < 0.05  # faces the camera (within grazing tolerance)
    assert np.all(normal[label < 0] == 0)


def test_mask_labels_and_projected_centres_with_distortion():
    R, t = CAMERA
    prims = _scene()
    rays = render.pixel_rays(K, DIST, (W, H))
    out = render.render(jnp.asarray(rays), jnp.asarray(R, jnp.float32), jnp.asarray(t, jnp.float32), prims)
    depth, label = np.asarray(out.depth), np.asarray(out.label)
    np.testing.assert_array_equal(label >= 0, depth > 0)
    np.testing.assert_array_equal(np.asarray(out.mask), depth > 0)
    assert set(np.unique(label)) == {-1, 0, 1, 2, 3, 4}
    centres = np.concatenate(
        [0.5 * (np.asarray(prims.cone_a) + np.asarray(prims.cone_b)), np.asarray(prims.ell_centre)]
    )
    uv, _ = cv2.projectPoints(centres.astype(np.float64), cv2.Rodrigues(R)[0], t, K, DIST)
    for i, (u, v) in enumerate(uv.reshape(-1, 2)):
        assert label[int(round(v)), int(round(u))] == i, f"primitive {i}"
    # the distorted rays really invert the lens: projecting them with the lens model gives back the pixels
    pts = np.concatenate([rays.reshape(-1, 2), np.ones((H * W, 1))], 1)
    back, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, DIST)
    us, vs = np.meshgrid(np.arange(W), np.arange(H))
    np.testing.assert_allclose(back.reshape(H, W, 2), np.stack([us, vs], -1), atol=1e-3)


def test_culling_changes_nothing_and_no_recompilation():
    R, t = CAMERA
    prims = _scene()
    rays = jnp.asarray(render.pixel_rays(K, None, (W, H)))
    Rj, tj = jnp.asarray(R, jnp.float32), jnp.asarray(t, jnp.float32)
    a = render.render(rays, Rj, tj, prims, tile=16, cull=True)
    b = render.render(rays, Rj, tj, prims, tile=16, cull=False)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    n = render.render._cache_size()
    moved = prims._replace(cone_a=prims.cone_a + 0.05, ell_centre=prims.ell_centre - 0.02)
    c = render.render(
        rays, Rj @ jnp.asarray(cv2.Rodrigues(np.array([0.0, 0.05, 0.0]))[0], jnp.float32), tj, moved
    )
    assert render.render._cache_size() == n
    assert not np.array_equal(np.asarray(c.label), np.asarray(a.label))


def test_primitive_behind_camera_is_not_drawn():
    R, t = CAMERA
    prims = _scene()
    c = jnp.asarray(-R.T @ t, jnp.float32)
    mirrored = prims._replace(  # the scene reflected through the camera centre lies behind it
        cone_a=2 * c - prims.cone_a, cone_b=2 * c - prims.cone_b, ell_centre=2 * c - prims.ell_centre
    )
    rays = jnp.asarray(render.pixel_rays(K, None, (W, H)))
    out = render.render(rays, jnp.asarray(R, jnp.float32), jnp.asarray(t, jnp.float32), mirrored)
    assert np.all(np.asarray(out.label) == -1) and np.all(np.asarray(out.depth) == 0)


def test_primitives_from_model_and_skeleton():
    model = body.full25()
    x = model.rest_pose
    R, t = body.segment_poses(model, x)
    p = render.primitives_from_model(model, x)
    q = flesh.world_primitives(model, R, t)
    for u, v in zip(p, q, strict=True):
        np.testing.assert_allclose(u, v, atol=1e-6)
    assert p.num_cones == 9 and p.num_ellipsoids == 1
    # skeleton: joints 0-1-2 chain plus a head 2→3
    pos = jnp.asarray([[0, 0, 1.0], [0, 0, 1.3], [0, 0, 1.5], [0, 0, 1.75], [0.2, 0, 1.3]], jnp.float32)
    parents = [-1, 0, 1, 2, 1]
    s = render.primitives_from_skeleton(
        pos, parents, jnp.asarray([0.1, 0.05]), bones=[1, 4], head=(2, 3), head_radius=0.09
    )
    np.testing.assert_allclose(s.cone_a, pos[jnp.asarray([0, 1])])
    np.testing.assert_allclose(s.cone_b, pos[jnp.asarray([1, 4])])
    np.testing.assert_allclose(s.r_b, [0.1, 0.05])
    np.testing.assert_allclose(s.ell_centre[0], [0, 0, 1.625], atol=1e-6)
    np.testing.assert_allclose(jnp.linalg.norm(s.ell_axes[0], axis=0), [0.09, 0.09, 0.125], atol=1e-6)
    np.testing.assert_allclose(s.ell_axes[0][:, 2], [0, 0, 0.125], atol=1e-6)
    with pytest.raises(ValueError):
        render.primitives_from_skeleton(pos, parents, jnp.asarray([0.1]), bones=[0])


def test_images_are_deterministic_and_shading_is_lambert(tmp_path):
    R, t = CAMERA
    prims = _scene()
    rays = jnp.asarray(render.pixel_rays(K, None, (W, H)))
    Rj, tj = jnp.asarray(R, jnp.float32), jnp.asarray(t, jnp.float32)
    colours = render.label_colours(["left_arm", "torso", "right_arm", "left_hand", "head"])
    np.testing.assert_allclose(colours[0], colours[2])
    np.testing.assert_allclose(colours[3], render.SKIN)
    np.testing.assert_allclose(colours[4], render.SKIN)
    bg = np.full((H, W, 3), 90, np.uint8)

    def frame(seed):
        out = render.render(rays, Rj, tj, prims, caps="sphere")
        rgb, mask = render.shade(out, colours, illumination=0.8)
        img = render.composite(rgb, mask, bg)
        noisy = render.add_sensor_noise(np.random.default_rng(seed), img, 0.02)
        vd = render.virtual_depth(np.random.default_rng(seed), np.asarray(out.depth))
        return out, rgb, mask, noisy, vd

    o1, rgb, mask, im1, vd1 = frame(5)
    o2, _, _, im2, vd2 = frame(5)
    for x, y in zip(o1, o2, strict=True):
        assert np.asarray(x).tobytes() == np.asarray(y).tobytes()
    assert im1.tobytes() == im2.tobytes() and vd1.tobytes() == vd2.tobytes()
    # Lambert: intensity / colour = illumination (ambient + (1 − ambient) max(0, n·l))
    n = np.asarray(o1.normal)
    light = np.array([0.3, -0.6, -1.0]) / np.linalg.norm([0.3, -0.6, -1.0])
    expect = (
        0.8
        * colours[np.maximum(np.asarray(o1.label), 0)]
        * (0.35 + 0.65 * np.clip(n @ light, 0, None))[..., None]
    )
    np.testing.assert_allclose(rgb[mask], np.clip(expect[mask], 0, 1), atol=1e-6)
    np.testing.assert_allclose(render.composite(rgb, mask, bg)[~mask], 90 / 255)
    # motion blur as the mean of sub-frames
    blur = render.average_frames([rgb, np.zeros_like(rgb)])
    np.testing.assert_allclose(blur, rgb / 2)


def test_virtual_depth_noise_and_png_roundtrip(tmp_path):
    depth = np.zeros((120, 160))
    depth[20:100, 30:130] = 2.5
    rng = np.random.default_rng(7)
    vd = render.virtual_depth(rng, depth, smooth_px=1.5, noise_m=0.02)
    assert vd.dtype == np.uint16
    np.testing.assert_array_equal(vd > 0, depth > 0)
    err = vd[depth > 0].astype(np.float64) / 1000 - 2.5  # smoothing inside the mask keeps a flat surface flat
    n = err.size
    assert abs(err.mean()) < 4 * 0.02 / np.sqrt(n) + 0.0005  # + rounding to mm
    assert abs(err.std() - 0.02) < 4 * 0.02 / np.sqrt(2 * n) + 0.0003
    path = tmp_path / "d.png"
    render.write_depth_png(path, vd)
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    np.testing.assert_array_equal(raw, vd)
    np.testing.assert_allclose(render.read_depth_png(path), vd / 1000.0, rtol=1e-6)
    cv2.imwrite(str(tmp_path / "rgb.png"), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(MocapInputError):
        render.read_depth_png(tmp_path / "rgb.png")
    with pytest.raises(ValueError):
        render.write_depth_png(path, vd.astype(np.float32))


def test_render_view_several_views():
    """One compiled renderer serves every view of the same size; the rays are cached per camera."""
    prims = _scene()
    n = render.render._cache_size()
    masks = []
    for c in ([3.0, 0.6, 1.4], [0.3, 3.0, 1.2], [-2.5, -1.0, 2.0]):
        R, t = _look_at(c, [0.0, 0.0, 1.0])
        masks.append(np.asarray(render.render_view(K, None, R, t, (W, H), prims).mask))
    assert all(m.sum() > 1000 for m in masks)
    assert not np.array_equal(masks[0], masks[1])
    assert render.render._cache_size() <= n + 1
