"""Flesh sample points, occluding contours and silhouette tests against closed forms and OpenCV."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import enable_x64
from jax.test_util import check_grads

from jaxmocap.geometry import body, flesh, render

# A few truncated cones (a, b, r_a, r_b) in general position, and camera centres around them.
CONES = [
    ((0.0, 0.0, 1.0), (0.05, 0.02, 1.4), 0.06, 0.04),
    ((0.3, -0.2, 0.8), (0.1, 0.25, 0.9), 0.05, 0.08),
    ((-0.2, 0.1, 1.2), (-0.25, 0.1, 0.7), 0.045, 0.045),
]
CENTRES = [(3.0, 0.4, 1.3), (-1.5, 2.5, 2.0), (0.4, -2.0, 0.2), (0.0, 0.0, 4.0)]


def _cone_arrays(dtype=np.float64):
    a = np.array([c[0] for c in CONES], dtype)
    b = np.array([c[1] for c in CONES], dtype)
    ra = np.array([c[2] for c in CONES], dtype)
    rb = np.array([c[3] for c in CONES], dtype)
    return a, b, ra, rb


def _cone_frame(a, b):
    ax = b - a
    L = np.linalg.norm(ax)
    return ax / L, L


def _on_cone(p, a, b, ra, rb):
    """(axial fraction, radial distance − radius at that height) of points ``p (..., 3)`` for one cone."""
    ahat, L = _cone_frame(a, b)
    w = p - a
    z = w @ ahat
    rho = np.linalg.norm(w - z[..., None] * ahat, axis=-1)
    s = z / L
    return s, rho - (ra + s * (rb - ra))


def _cone_normal_reference(p, a, b, ra, rb):
    """Outward normal at a lateral point, as the cross product of the circle tangent and the generator."""
    ahat, L = _cone_frame(a, b)
    w = p - a
    z = w @ ahat
    radial = w - z[..., None] * ahat
    u = radial / np.linalg.norm(radial, axis=-1, keepdims=True)
    tangent = np.cross(ahat, u)  # along the circle
    generator = (b + rb * u) - (a + ra * u)  # along the surface line through p
    n = np.cross(tangent, generator)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return np.where((n * u).sum(-1, keepdims=True) < 0, -n, n)


# ---------------------------------------------------------------------------------------------------------------
# Surface and interior points


@pytest.mark.parametrize("name", ["full25", "upper9"])
def test_surface_points_on_surface_with_outward_normals(name):
    with enable_x64(True):
        model = body.build(name, dtype=jnp.float64)
        fp = flesh.surface_points(model, 600)
        local, normal = np.asarray(fp.local), np.asarray(fp.normal)
        seg = np.asarray(fp.segment)
        assert local.shape == (600, 3) and seg.shape == (600,)
        start, end = np.asarray(model.shape_start), np.asarray(model.shape_end)
        r0, r1 = np.asarray(model.radius_start), np.asarray(model.radius_end)
        for s, kind in enumerate(model.shape_kind):
            p, n = local[seg == s], normal[seg == s]
            if kind == "none":
                assert len(p) == 0
                continue
            assert len(p) > 0
            if kind == "cone":
                frac, off = _on_cone(p, start[s], end[s], r0[s], r1[s])
                np.testing.assert_allclose(off, 0.0, atol=1e-12)
                assert np.all((frac > 0) & (frac < 1))
                np.testing.assert_allclose(
                    n, _cone_normal_reference(p, start[s], end[s], r0[s], r1[s]), atol=1e-12
                )
            else:  # spheroid: implicit (ρ/r)² + (z/h)² = 1, normal along its gradient
                ahat, L = _cone_frame(start[s], end[s])
                w = p - 0.5 * (start[s] + end[s])
                z = w @ ahat
                radial = w - z[:, None] * ahat
                h = 0.5 * L
                np.testing.assert_allclose((radial**2).sum(-1) / r0[s] ** 2 + z**2 / h**2, 1.0, atol=1e-12)
                grad = radial / r0[s] ** 2 + (z / h**2)[:, None] * ahat
                grad /= np.linalg.norm(grad, axis=-1, keepdims=True)
                np.testing.assert_allclose(n, grad, atol=1e-12)


def test_counts_proportional_to_area_and_fixed_total():
    model = body.full25()
    for total in (150, 600, 1001):
        layout = flesh.surface_layout(model, total=total)
        assert layout.total == total
        a = np.asarray(model.shape_start, np.float64)
        b = np.asarray(model.shape_end, np.float64)
        r0 = np.asarray(model.radius_start, np.float64)
        r1 = np.asarray(model.radius_end, np.float64)
        areas = []
        for s, kind in enumerate(model.shape_kind):
            L = np.linalg.norm(b[s] - a[s])
            if kind == "cone":  # frustum lateral area: π (r0 + r1) × slant height
                areas.append(np.pi * (r0[s] + r1[s]) * np.hypot(L, r1[s] - r0[s]))
            elif kind == "ellipsoid":  # prolate spheroid, exact: 2π r² (1 + h/(r e) asin e)
                r, h = r0[s], L / 2
                e = np.sqrt(1 - (r / h) ** 2)
                areas.append(2 * np.pi * r**2 * (1 + h / (r * e) * np.arcsin(e)))
            else:
                areas.append(0.0)
        areas = np.asarray(areas)
        exact = total * areas / areas.sum()
        # Thomsen's area formula is within 1.1 % for the head: allow one point of rounding plus that.
        assert np.all(np.abs(np.asarray(layout.counts) - exact) <= 1.0 + 0.011 * exact)
    # density mode: rounded area × density
    lay = flesh.surface_layout(model, density=2000.0)
    np.testing.assert_allclose(lay.counts, np.round(flesh.segment_areas(model) * 2000.0))


def test_cone_rings_have_uniform_area_density():
    """The fraction of a tapered cone's lateral area below each ring equals the fraction of points below it."""
    with enable_x64(True):
        model = body.full25(dtype=jnp.float64, dims={"thigh_radius_top": 0.12, "thigh_radius_bottom": 0.04})
        layout = flesh.surface_layout(model, total=2000)
        fp = flesh.surface_points(model, layout)
        s = model.segment_names.index("left_thigh")
        p = np.asarray(fp.local)[np.asarray(fp.segment) == s]
        a, b = np.asarray(model.shape_start[s]), np.asarray(model.shape_end[s])
        ra, rb = float(model.radius_start[s]), float(model.radius_end[s])
        frac, _ = _on_cone(p, a, b, ra, rb)
        rings = np.unique(np.round(frac, 9))
        below = np.array([np.mean(frac < f - 1e-9) + 0.5 * np.mean(np.abs(frac - f) < 1e-9) for f in rings])
        area_below = (ra * rings + 0.5 * (rb - ra) * rings**2) / (0.5 * (ra + rb))
        np.testing.assert_allclose(below, area_below, atol=1e-9)


def test_layout_static_under_jit_and_traced_dimensions():
    model = body.full25()
    layout = flesh.surface_layout(model, total=300)

    def f(scale):
        m = body.full25({"thigh_length": 0.43 * scale, "upper_arm_radius_top": 0.05 * scale})
        return flesh.surface_points(m, layout).local

    out = jax.jit(f)(1.0)
    np.testing.assert_allclose(out, flesh.surface_points(model, layout).local, atol=1e-6)
    g = jax.grad(lambda sc: jnp.sum(f(sc) ** 2))(1.0)
    assert np.isfinite(g) and g != 0
    with pytest.raises(ValueError, match="concrete"):
        jax.jit(lambda sc: flesh.surface_points(body.full25({"thigh_length": sc}), 300).local)(0.4)


def test_the_compiled_surface_points_are_the_eager_ones_and_are_stored(tmp_path):
    """``surface_points_compiled`` (one program, what ``Likelihood.create`` calls) gives the eager
    ``surface_points`` to float32 rounding, with the same segments; inside ``stored_programs.use`` its trace is
    written once and a new function object of the same code reads it back instead of tracing (``loaded``)."""
    from jaxmocap import stored_programs

    model = body.full25({"thigh_length": 0.47})
    layout = flesh.surface_layout(model, total=300)
    eager = flesh.surface_points(model, layout)
    with stored_programs.use(tmp_path):
        first = flesh.surface_points_compiled(model, layout)
        again = stored_programs.stored_jit(flesh.surface_points_compiled.fn, static_argnames=("layout",))
        second = again(model, layout)
    assert first.segment == second.segment == eager.segment
    for a in (first, second):
        np.testing.assert_allclose(a.local, eager.local, rtol=0, atol=1e-6)
        np.testing.assert_allclose(a.normal, eager.normal, rtol=0, atol=1e-6)
    assert len(list((tmp_path / stored_programs.FOLDER).glob("*.jaxexport"))) == 1
    stored = next(iter(again._stored.values()))
    assert (stored.loaded, stored.exported) == (1, 0)


def test_interior_points_are_inside():
    model = body.full25()
    ip = flesh.interior_points(model, levels=3, around=4)
    R, t = body.segment_poses(model, model.rest_pose)
    X, _ = ip.world(R, t)
    prims = jax.jit(flesh.world_primitives)(model, R, t)
    assert X.shape == (10 * 15, 3)
    seg = np.asarray(ip.segment)
    cones, ells = flesh.cone_segments(model), flesh.ellipsoid_segments(model)
    a, b = np.asarray(prims.cone_a, np.float64), np.asarray(prims.cone_b, np.float64)
    for i, s in enumerate(cones):
        frac, off = _on_cone(
            np.asarray(X, np.float64)[seg == s], a[i], b[i], float(prims.r_a[i]), float(prims.r_b[i])
        )
        assert np.all(off < -1e-3) and np.all((frac > 0) & (frac < 1))
    for i, s in enumerate(ells):
        y = np.linalg.solve(
            np.asarray(prims.ell_axes[i], np.float64), (np.asarray(X)[seg == s] - prims.ell_centre[i]).T
        )
        assert np.all(np.linalg.norm(y, axis=0) < 0.9)


# ---------------------------------------------------------------------------------------------------------------
# Occluding contours


def test_cone_contours_lie_on_surface_and_are_tangent():
    with enable_x64(True):
        a, b, ra, rb = _cone_arrays()
        for c in CENTRES:
            c = np.asarray(c)
            pts = np.asarray(
                flesh.cone_contours(
                    jnp.asarray(a), jnp.asarray(b), jnp.asarray(ra), jnp.asarray(rb), jnp.asarray(c), 7
                )
            )
            assert pts.shape == (3, 2, 7, 3)
            for i in range(3):
                p = pts[i].reshape(-1, 3)
                frac, off = _on_cone(p, a[i], b[i], ra[i], rb[i])
                np.testing.assert_allclose(off, 0.0, atol=1e-12)
                np.testing.assert_allclose(frac, np.tile(np.linspace(0, 1, 7), 2), atol=1e-12)
                n = _cone_normal_reference(p, a[i], b[i], ra[i], rb[i])
                view = (p - c) / np.linalg.norm(p - c, axis=-1, keepdims=True)
                np.testing.assert_allclose((view * n).sum(-1), 0.0, atol=1e-12)
                # the two generators are distinct (both silhouette sides)
                assert np.linalg.norm(pts[i, 0, 0] - pts[i, 1, 0]) > 1e-3
    # float32: tangent to float tolerance
    a, b, ra, rb = _cone_arrays(np.float32)
    pts = np.asarray(flesh.cone_contours(a, b, ra, rb, jnp.asarray(CENTRES[0], jnp.float32), 5), np.float64)
    for i in range(3):
        p = pts[i].reshape(-1, 3)
        n = _cone_normal_reference(
            p, a[i].astype(np.float64), b[i].astype(np.float64), float(ra[i]), float(rb[i])
        )
        view = (p - CENTRES[0]) / np.linalg.norm(p - CENTRES[0], axis=-1, keepdims=True)
        assert np.abs((view * n).sum(-1)).max() < 1e-5


def test_ellipsoid_contour_on_surface_and_tangent():
    with enable_x64(True):
        rng = np.random.default_rng(3)
        Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        axes = Q @ np.diag([0.09, 0.11, 0.14])
        centre = np.array([0.1, -0.2, 1.6])
        for c in CENTRES:
            c = np.asarray(c)
            pts = np.asarray(
                flesh.ellipsoid_contours(
                    jnp.asarray(centre[None]), jnp.asarray(axes[None]), jnp.asarray(c), 16
                )
            )[0]
            Minv = np.linalg.inv(axes)
            y = (pts - centre) @ Minv.T
            np.testing.assert_allclose(np.linalg.norm(y, axis=-1), 1.0, atol=1e-12)
            grad = y @ Minv  # ∇ |M⁻¹(x − m)|² / 2 = M⁻ᵀ y
            np.testing.assert_allclose(((pts - c) * grad).sum(-1), 0.0, atol=1e-12)
            # spread around the contour, not collapsed
            assert np.linalg.norm(pts - pts.mean(0), axis=-1).min() > 0.05


def test_model_contours_shapes_and_vmap():
    model = body.full25()
    N, V, k = 4, 3, 5
    x = model.rest_pose + 0.2 * jax.random.normal(jax.random.key(0), (N, model.num_dofs))
    R, t = jax.vmap(lambda xi: body.segment_poses(model, xi))(x)
    centres = jnp.asarray(CENTRES[:V], jnp.float32)
    f = jax.jit(
        jax.vmap(
            jax.vmap(lambda Ri, ti, c: flesh.contour_points(model, Ri, ti, c, k), (None, None, 0)),
            (0, 0, None),
        )
    )
    out = f(R, t, centres)
    assert out.shape == (N, V, len(flesh.cone_segments(model)), 2, k, 3)
    one = flesh.contour_points(model, R[2], t[2], centres[1], k)
    np.testing.assert_allclose(out[2, 1], one, atol=1e-6)
    e = jax.jit(flesh.ellipse_contour_points, static_argnums=4)(model, R[0], t[0], centres[0], 8)
    assert e.shape == (1, 8, 3)


def test_degenerate_views_are_finite_with_finite_gradients():
    b = jnp.asarray([[0.0, 0.0, 1.4]])
    ra, rb = jnp.asarray([0.05]), jnp.asarray([0.04])
    m = jnp.asarray([[0.0, 0.0, 1.2]])
    ax = jnp.asarray([[[0.09, 0, 0], [0, 0.09, 0], [0, 0, 0.12]]])

    def both(c, a):
        return jnp.sum(flesh.cone_contours(a, b, ra, rb, c, 4) ** 2) + jnp.sum(
            flesh.ellipsoid_contours(m, ax, c, 6)
        )

    f = jax.jit(lambda c, a: (flesh.cone_contours(a, b, ra, rb, c, 4), flesh.ellipsoid_contours(m, ax, c, 6)))
    g = jax.jit(jax.grad(both, argnums=(0, 1)))
    a = jnp.asarray([[0.0, 0.0, 1.0]])
    # on the cone axis; inside the cone (and the ellipsoid); at the ellipsoid centre
    for c in ([0.0, 0.0, 3.0], [0.0, 0.01, 1.2], [0.0, 0.0, 1.2]):
        c = jnp.asarray(c)
        for v in (*f(c, a), *g(c, a)):
            assert np.all(np.isfinite(v))


def test_contour_gradients_finite_and_correct():
    """Gradients reach segment poses, body dimensions and the camera centre (FK's own gradients are tested with
    the kinematics)."""
    model = body.upper9()
    R, t = body.segment_poses(model, model.rest_pose + 0.1)

    def loss(R, t, arm, c):
        m = body.upper9({"upper_arm_length": arm, "head_radius": 0.5 * arm})
        return jnp.sum(flesh.contour_points(m, R, t, c, 3) ** 2) + jnp.sum(
            flesh.ellipse_contour_points(m, R, t, c, 4) ** 2
        )

    g = jax.jit(jax.grad(loss, argnums=(0, 1, 2, 3)))(R, t, 0.29, jnp.asarray([3.0, 0.5, 1.2]))
    assert all(np.all(np.isfinite(v)) for v in g)
    assert float(jnp.abs(g[2])) > 0 and float(jnp.sum(jnp.abs(g[0]))) > 0
    with enable_x64(True):
        a, b, ra, rb = (jnp.asarray(v) for v in _cone_arrays())
        f = jax.jit(lambda c, r: flesh.cone_contours(a, b, r, rb, c, 3))
        check_grads(f, (jnp.asarray(CENTRES[1]), ra), order=1, modes=["rev"])


# ---------------------------------------------------------------------------------------------------------------
# Projection: contour lines are the outermost lines; silhouette test


def _look_at(c, target):
    f = np.asarray(target, float) - c
    f /= np.linalg.norm(f)
    up = np.array([0.0, 0.0, 1.0]) if abs(f[2]) < 0.95 else np.array([1.0, 0.0, 0.0])
    xr = np.cross(f, up)
    xr /= np.linalg.norm(xr)
    R = np.stack([xr, np.cross(f, xr), f])
    return R, -R @ c


K = np.array([[500.0, 0.0, 160.0], [0.0, 500.0, 120.0], [0.0, 0.0, 1.0]])


def _dense_cone_points(a, b, ra, rb, n=400):
    """Dense points on the lateral surface and both cap discs of a flat-capped truncated cone."""
    ahat, L = _cone_frame(a, b)
    e1 = np.cross(ahat, [1.0, 0.0, 0.0] if abs(ahat[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(ahat, e1)
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
    s = np.linspace(0, 1, 60)
    u = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
    lat = a + s[:, None, None] * (b - a) + (ra + s[:, None, None] * (rb - ra)) * u[None]
    rr = np.linspace(0, 1, 20)[:, None, None]
    caps = [a + rr * ra * u[None], b + rr * rb * u[None]]
    return np.concatenate([lat.reshape(-1, 3)] + [c.reshape(-1, 3) for c in caps])


def _project(X, R, t):
    uv, _ = cv2.projectPoints(np.asarray(X, np.float64), cv2.Rodrigues(R)[0], t, K, None)
    return uv.reshape(-1, 2)


def test_projected_contour_lines_are_outermost_lines_of_the_hull():
    a, b, ra, rb = _cone_arrays()
    for ci in range(3):
        target = 0.5 * (a[ci] + b[ci])
        for c in CENTRES[:3]:
            c = np.asarray(c, float)
            R, t = _look_at(c, target)
            hull = cv2.convexHull(
                _project(_dense_cone_points(a[ci], b[ci], ra[ci], rb[ci]), R, t).astype(np.float32)
            )
            hull = hull.reshape(-1, 2).astype(np.float64)
            with enable_x64(True):
                gen = np.asarray(
                    flesh.cone_contours(
                        *(jnp.asarray(v[ci : ci + 1]) for v in (a, b, ra, rb)), jnp.asarray(c), 2
                    )
                )[0]
            for j in range(2):
                p0, p1 = _project(gen[j], R, t)
                dvec = (p1 - p0) / np.linalg.norm(p1 - p0)
                nrm = np.array([-dvec[1], dvec[0]])
                dist = (hull - p0) @ nrm
                # the whole hull is on one side of the line and touches it
                side = np.sign(dist[np.argmax(np.abs(dist))])
                assert np.min(side * dist) > -0.05, "hull crosses a contour line"
                assert np.min(np.abs(dist)) < 0.05, "contour line does not touch the hull"
                # the line touches the hull between the projected generator's end points (the hull leaves the
                # line along the cap ellipses, within a few pixels of the tangent points)
                near = hull[np.abs(dist) < 0.05]
                along = (near - p0) @ dvec
                assert along.min() > -3.0 and along.max() < np.linalg.norm(p1 - p0) + 3.0


def _hull_inside(hull, pts, margin):
    """(inside, decided): ``cv2.pointPolygonTest`` signed distance, decided only farther than ``margin``."""
    d = np.array([cv2.pointPolygonTest(hull, (float(x), float(y)), True) for x, y in pts])
    return d > 0, np.abs(d) > margin


def test_inside_projected_matches_opencv_hull():
    a, b, ra, rb = _cone_arrays()
    us, vs = np.meshgrid(np.arange(0, 320, 3.0), np.arange(0, 240, 3.0))
    grid = np.stack([us.ravel(), vs.ravel()], -1)
    views = [np.asarray(c, float) for c in CENTRES[:3]]
    views.append(a[0] + 1.5 * (a[0] - b[0]) / np.linalg.norm(a[0] - b[0]))  # looking down the axis of cone 0
    for ci in range(3):
        prims = flesh.Primitives(
            jnp.asarray(a[ci : ci + 1], jnp.float32),
            jnp.asarray(b[ci : ci + 1], jnp.float32),
            jnp.asarray(ra[ci : ci + 1], jnp.float32),
            jnp.asarray(rb[ci : ci + 1], jnp.float32),
            jnp.zeros((0, 3), jnp.float32),
            jnp.zeros((0, 3, 3), jnp.float32),
        )
        for c in views:
            R, t = _look_at(c, 0.5 * (a[ci] + b[ci]))
            hull = cv2.convexHull(
                _project(_dense_cone_points(a[ci], b[ci], ra[ci], rb[ci], 720), R, t).astype(np.float32)
            )
            ref, decided = _hull_inside(hull, grid, 1.0)
            got = np.asarray(
                flesh.inside_projected(
                    prims,
                    jnp.asarray(K, jnp.float32),
                    jnp.asarray(R, jnp.float32),
                    jnp.asarray(t, jnp.float32),
                    jnp.asarray(grid, jnp.float32),
                )
            )
            assert ref.sum() > 20
            np.testing.assert_array_equal(got[decided], ref[decided])


def test_inside_projected_ellipsoid_and_render_agree():
    """Both silhouette tests are exact for flat-capped cones seen from outside and for ellipsoids: they agree with
    the ray-cast mask (flat caps) away from the silhouette boundary."""
    model = body.full25()
    x = (
        model.rest_pose.at[model.dof_index("left_elbow")]
        .set(1.2)
        .at[model.dof_index("right_hip_ry")]
        .set(-0.6)
    )
    prims = render.primitives_from_model(model, x)
    c = np.array([3.2, 1.0, 1.3])
    R, t = _look_at(c, np.array([0.0, 0.0, 1.0]))
    Kj = jnp.asarray([[220.0, 0, 120], [0, 220.0, 90], [0, 0, 1]], jnp.float32)
    rays = render.pixel_rays(np.asarray(Kj), None, (240, 180))
    out = render.render(
        jnp.asarray(rays), jnp.asarray(R, jnp.float32), jnp.asarray(t, jnp.float32), prims, caps="flat"
    )
    us, vs = np.meshgrid(np.arange(240.0), np.arange(180.0))
    uv = jnp.asarray(np.stack([us.ravel(), vs.ravel()], -1), jnp.float32)
    per = np.asarray(
        flesh.inside_per_primitive(prims, Kj, jnp.asarray(R, jnp.float32), jnp.asarray(t, jnp.float32), uv)
    )
    assert per.shape == (prims.num_cones + prims.num_ellipsoids, 240 * 180)
    ins = per.any(0).reshape(180, 240)
    mask = np.asarray(out.mask)
    edge = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3))) != cv2.erode(
        mask.astype(np.uint8), np.ones((3, 3))
    )
    assert mask.sum() > 1000
    np.testing.assert_array_equal(ins[~edge], mask[~edge])
    # the head's own test agrees with the pixels labelled as head
    head = per[-1].reshape(180, 240)
    lab = np.asarray(out.label) == prims.num_cones
    assert lab.sum() > 50 and np.all(head[lab])
