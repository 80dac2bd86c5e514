"""The smooth variants of the depth, edge-fraction and silhouette-divergence cues (``soft=True``, with
``bilinear=True`` for the map reads): the default reads unchanged bit for bit, the smooth ones against closed forms
and the hard ones within derived bounds, the soft silhouette against the ray caster, and ``check_grads`` of all
three."""

import pathlib
import sys

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxmocap.geometry import body, flesh
from jaxmocap.likelihood import compose as L
from jaxmocap.likelihood import cues, maps

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from test_cues import H, W, _observe, _pixel_cover, _renders, _rig  # noqa: E402

#: XLA's default code generation (the suite compiles for compile time, tests/conftest.py): the pinned values are
#: those of the programs users run
PRODUCTION = {"xla_backend_optimization_level": 3, "xla_cpu_use_fusion_emitters": True}
SMOOTH = {"bilinear": True, "soft": True}
NEW = ("depth", "edge_fraction", "silhouette_divergence")


def _pose(model, **dofs):
    x = model.rest_pose
    for k, v in dofs.items():
        x = x.at[model.dof_index(k)].set(v)
    return x


@pytest.fixture(scope="module")
def scene():
    """``full25`` at 160×120 (the scene of ``test_cues.py``) observed at ``x``, and another pose ``xp``."""
    model = body.full25()
    rig = _rig()
    x = _pose(model, left_shoulder_rx=0.9, left_elbow=0.8, right_shoulder_rx=-0.5)
    xp = x.at[model.dof_index("left_shoulder_rx")].set(0.5).at[model.dof_index("right_knee")].set(0.3)
    return model, rig, x, xp, _observe(model, rig, x)


def _lik(model, rig, name, params=None):
    return L.Likelihood.create(model, rig, [L.Cue(name, params=params or {})], surface_points=300)


def _energy(lik, x, obs):
    return np.asarray(lik.view_energies(x, obs))[0]


def _numpy_depth(model, rig, x):
    """Depth maps made in NumPy from the rendered labels (integers: the same whatever code generation rendered
    them): ``2.6 + 0.004 u − 0.003 v + 0.05 label`` metres on the body, 0 elsewhere."""
    uu, vv = np.meshgrid(np.arange(W), np.arange(H))
    out = []
    for r in _renders(model, rig, x):
        lab = np.asarray(r.label)
        out.append(np.where(lab >= 0, 2.6 + 0.004 * uu - 0.003 * vv + 0.05 * lab, 0.0).astype(np.float32))
    return out


def test_default_reads_are_unchanged(scene):
    """The default (nearest-pixel, hard) energies of the three cues at ``xp``, compiled with XLA's defaults, are
    those of the code before the smooth variants existed (commit af53d3f), bit for bit (maps made from the
    rendered labels, so that they do not depend on the suite's code generation)."""
    model, rig, x, xp, _ = scene
    obs = _observe(model, rig, x, depth=_numpy_depth(model, rig, x))
    before = {  # float32 bit patterns, views 0 and 1
        "depth": (0x3E75A122, 0x3E6ED22A),
        "edge_fraction": (0x3E1FFFFF, 0x3E1FFFFF),
        "silhouette_divergence": (0x3DAE1F18, 0x3DAF8AF9),
    }
    for name, bits in before.items():
        lik = _lik(model, rig, name)
        E = jax.jit(lambda lik, x, o: lik.view_energies(x, o)[0], compiler_options=PRODUCTION)(lik, xp, obs)
        np.testing.assert_array_equal(np.asarray(E, np.float32).view(np.uint32), np.asarray(bits, np.uint32))


def test_depth_on_a_plane_closed_form(scene):
    """On a depth map that is a plane in the pixel coordinates, ``D = a + b u + c v``, with foreground everywhere,
    every in-image sample has four valid texels and the bilinear read is the plane itself: the smooth cue is
    ``min(mean_p ρ_δ(z_p − D(u_p)), c) / c`` over the camera-facing samples (out-of-image ones ``c``), computed
    here from the particle's geometry. The hard cue reads the nearest pixel (within ``(|b| + |c|) / 2`` of the
    plane) with ``|r|`` (``0 ≤ |r| − ρ_δ(r) ≤ δ``), so ``|E_smooth − E_hard| ≤ (δ + (|b| + |c|) / 2) / c``. With no
    foreground both are 1."""
    model, rig, _, xp, obs = scene
    a, b, c, delta = 3.0, 0.02, 0.01, 0.02
    uu, vv = np.meshgrid(np.arange(W), np.arange(H))
    plane = (a + b * (uu - W / 2) + c * (vv - H / 2)).astype(np.float32)
    assert plane.min() > 0.5
    o = _observe(model, rig, xp, depth=[plane] * 2, foreground=[np.ones((H, W), np.float32)] * 2)
    smooth = _lik(model, rig, "depth", {**SMOOTH, "delta_m": delta})
    E = _energy(smooth, xp, o)
    g = smooth.geometry(xp, (H, W))
    uv, z, facing = (np.asarray(t, np.float64) for t in (g.surface_uv, g.surface_depth, g.surface_facing))
    inside = np.asarray(maps.inside_image(jnp.asarray(uv), H, W))
    uc, vc = np.clip(uv[..., 0], 0, W - 1), np.clip(uv[..., 1], 0, H - 1)
    r = z - (a + b * (uc - W / 2) + c * (vc - H / 2))
    d = np.where(inside, np.sqrt(r * r + delta**2) - delta, cues.DEPTH_PENALTY_M)
    ref = np.minimum((d * facing).sum(-1) / facing.sum(-1), cues.DEPTH_PENALTY_M) / cues.DEPTH_PENALTY_M
    assert np.all(ref > 0.05) and facing.sum() > 100
    np.testing.assert_allclose(E, ref, rtol=1e-5)
    E_hard = _energy(_lik(model, rig, "depth"), xp, o)
    bound = (delta + (b + c) / 2) / cues.DEPTH_PENALTY_M
    assert np.all(np.abs(E - E_hard) <= bound + 1e-6), (E, E_hard, bound)
    zero = _observe(model, rig, xp, foreground=[np.zeros((H, W), np.float32)] * 2)
    np.testing.assert_allclose(_energy(smooth, xp, zero), 1.0, rtol=1e-6)


def test_edge_fraction_on_a_ramp_and_as_the_ramp_narrows(scene):
    """On the edge map ``Ẽ = u / (W − 1)`` (linear: the bilinear read is exact) the smooth cue is
    ``1 − mean_q s((ū_q / (W − 1) − t) / h)`` (``ū`` clamped to the image, out-of-image points 0; the C¹ step
    ``s``), computed from the contour points. As the ramp narrows (``h`` → 0, nearest reads) the soft count differs
    from the hard one only at samples within ``h`` of the threshold: ``|ΔE| ≤ #{q: |Ẽ_q − t| < h} / Q``, counted
    here on the scene's own edge map. Constant maps give 0 and 1 exactly."""
    model, rig, _, xp, obs = scene
    ramp = np.broadcast_to(np.arange(W, dtype=np.float32) / (W - 1), (H, W)).copy()
    o = _observe(model, rig, xp, edges=[ramp] * 2)
    t, h = 0.45, 0.2
    smooth = _lik(model, rig, "edge_fraction", {**SMOOTH, "threshold": t, "softness": h})
    E = _energy(smooth, xp, o)
    cu = np.asarray(smooth.geometry(xp, (H, W)).contour_uv, np.float64)
    inside = np.asarray(maps.inside_image(jnp.asarray(cu), H, W))
    zz = np.clip((np.clip(cu[..., 0], 0, W - 1) / (W - 1) - t) / h, -1, 1)
    ref = 1.0 - np.where(inside, 0.5 + 0.75 * zz - 0.25 * zz**3, 0.0).mean(-1)
    assert np.all((ref > 0.2) & (ref < 0.8))
    np.testing.assert_allclose(E, ref, rtol=1e-5)
    for const, expect in ((1.0, 0.0), (0.0, 1.0)):
        oc = _observe(model, rig, xp, edges=[np.full((H, W), const, np.float32)] * 2)
        np.testing.assert_allclose(_energy(smooth, xp, oc), expect, atol=1e-6)
    # h → 0 on the scene's edge map, nearest reads, against the hard count
    hard = _lik(model, rig, "edge_fraction")
    narrow = _lik(model, rig, "edge_fraction", {"soft": True, "softness": 1e-4})
    g = hard.geometry(xp, (H, W))
    Ev = np.asarray(obs.edges).reshape(-1)[np.asarray(g.contour_index)]
    near = (np.asarray(g.contour_inside) & (np.abs(Ev - 0.5) < 1e-4)).sum(-1)
    Q = Ev.shape[-1]
    diff = np.abs(_energy(narrow, xp, obs) - _energy(hard, xp, obs))
    assert np.all(diff <= near / Q + 1e-6), (diff, near, Q)


def test_soft_silhouette_against_the_ray_caster(scene):
    """The soft silhouette (τ = 0.1 px) against the ray caster's mask: 1 at pixels at least 3 pixels (Chebyshev)
    inside the mask, 0 at pixels at least 5 pixels outside it, within ``K σ(−d/τ)`` for ``K`` nearby pieces at a
    first-order distance ``d``. The quadrilaterals' distances are exact by an edge; a conic's first-order distance
    a few pixels off a thin or strongly foreshortened outline can be a fifth of the true one (0.46 px measured here
    at ≥ 2.5 px from a cap), so ``d`` ≥ 0.9 px outside: 1e-2 for a few pieces."""
    model, rig, x, _, _ = scene
    R, t = body.segment_poses(model, x)
    prims = flesh.world_primitives(model, R, t)
    uv = np.stack(np.meshgrid(np.arange(W), np.arange(H)), -1).reshape(-1, 2).astype(np.float64)
    k_in, k_out = np.ones((7, 7), np.uint8), np.ones((11, 11), np.uint8)
    for v, r in enumerate(_renders(model, rig, x)):
        mask = (np.asarray(r.label) >= 0).astype(np.uint8)
        far_in = cv2.erode(mask, k_in).reshape(-1) > 0
        far_out = cv2.dilate(mask, k_out).reshape(-1) == 0
        f = float(rig.K[v, 0, 0])
        cov = _pixel_cover(cues._soft_silhouette_cover, prims, rig, v, uv, f / 0.1, 1.0 / f)
        assert far_in.sum() > 100 and far_out.sum() > 1000
        assert cov[far_in].min() >= 1 - 1e-2 and cov[far_out].max() <= 1e-2, (
            cov[far_in].min(),
            cov[far_out].max(),
        )


def test_soft_divergence_tends_to_the_hard_one(scene):
    """As τ → 0 the soft divergence is the hard one: where the sample's first-order distance to every piece's
    outline is ``|d_k| ≥ 20 τ`` and every piece it lies in (``d_k > 0``) has its hard test as weight (0 or 1; a cap
    seen within a few degrees of edge-on, or a sample beyond its plane's vanishing line, has a weight in between),
    the soft cover is within ``K e⁻²⁰`` of the hard one (``K`` pieces). So ``|ΔE_v| ≤ (Σ_other w + K e⁻²⁰ Σ w) / Σ w``, the other samples
    counted from the pieces' distances and weights."""
    model, rig, x, xp, obs = scene
    tau = 1e-3
    hard = _lik(model, rig, "silhouette_divergence")
    soft = _lik(model, rig, "silhouette_divergence", {"soft": True, "scale_px": tau})
    E_hard, E_soft = _energy(hard, xp, obs), _energy(soft, xp, obs)
    ctx = hard._context(0)
    aux = cues._prepare_divergence(obs, ctx, {})
    R, t = body.segment_poses(model, xp)
    prims = flesh.world_primitives(model, R, t)
    for v in range(2):
        f = float(rig.K[v, 0, 0])
        Rv, tv = jnp.asarray(rig.R[v], jnp.float32), jnp.asarray(rig.t[v], jnp.float32)
        at = (prims, Rv, tv, aux["x"][v], aux["y"][v])
        M = aux["x"].shape[1]
        ok_hard = np.stack([np.broadcast_to(np.asarray(ok), (M,)) for _, ok in cues._silhouette_pieces(*at)])
        pieces = list(cues._silhouette_pieces(*at, pixel=1.0 / f))
        d = np.stack([np.asarray(p) * f for p, _ in pieces])  # (K, M) pixels
        ok_soft = np.stack([np.broadcast_to(np.asarray(ok, np.float32), (M,)) for _, ok in pieces])
        w = np.asarray(aux["w"][v])
        other = np.any((np.abs(d) < 20 * tau) | ((ok_soft != ok_hard) & (d > -20 * tau)), axis=0)
        bound = (w[other].sum() + len(pieces) * np.exp(-20.0) * w.sum()) / w.sum()
        assert abs(E_soft[v] - E_hard[v]) <= bound + 1e-6, (v, E_soft[v], E_hard[v], bound)
        assert bound < 0.05
    assert np.all(E_hard > 0.05)


@pytest.fixture(scope="module")
def small():
    """``upper9`` at 80×60, observed at ``x0`` and seen at another pose: the three smooth cues' likelihood, the
    particle's geometry (camera-facing flags, surface and contour points, world primitives) and the observation."""
    model = body.upper9()
    rig = _rig(scale=0.5)
    x0 = _pose(model, left_shoulder_rx=0.7, left_elbow=0.6, right_shoulder_rx=-0.4)
    obs = _observe(model, rig, x0)
    x = x0 + 0.04 * jnp.asarray(np.random.default_rng(4).normal(size=x0.shape), jnp.float32)
    params = {"depth": {}, "edge_fraction": {}, "silhouette_divergence": {"grid": (40, 30), "samples": 128}}
    cue_list = [L.Cue(n, params={**SMOOTH, **p}) for n, p in params.items()]
    lik = L.Likelihood.create(model, rig, cue_list, surface_points=80, contour_points=4)
    return lik, lik.geometry(x, obs.image_shape), obs


#: the geometry each smooth cue is differentiated in: surface points (pixels) and their camera depths (metres),
#: contour points (pixels), the world primitives (metres)
INPUTS = {
    "depth": ("surface_uv", "surface_depth"),
    "edge_fraction": ("contour_uv",),
    "silhouette_divergence": ("primitives",),
}


CONE = ("cone_a", "cone_b", "r_a", "r_b")


@pytest.mark.parametrize("c", range(3), ids=NEW)
def test_check_grads_of_the_smooth_cues(small, c):
    """``check_grads`` (order 1, forward and reverse mode) of each smooth cue's ``(V,)`` energies in float64, as a
    function of the geometry it reads (:data:`INPUTS`; the derivative in the pose is the likelihood's,
    ``test_cues.py::test_check_grads``). The energies are piecewise smooth (bilinear between texel edges, the
    quadrilaterals' minimum of edge distances, the clamps), so the step is small: ``eps`` = 1e-5 along a random
    unit-normal tangent per entry moves a sample by ~1e-5 px, and none of the ~100 samples is likely to cross a
    texel edge, while the central differences' truncation (``eps² f‴`` < 1e-8 at a pixel's scale) and rounding
    (~1e-11) errors stay far below the tolerance 1e-4. The energy lies inside (0, 1) and its gradient is non-zero:
    the check can fail."""
    lik, g, obs = small
    name = NEW[c]
    with jax.enable_x64(True):
        to64 = lambda a: jnp.asarray(a, jnp.float64) if jnp.issubdtype(a.dtype, jnp.floating) else a  # noqa: E731
        g = jax.tree_util.tree_map(to64, g)
        ctx = lik._context(c, aux=lik.prepare(obs)[c])
        if (
            name == "silhouette_divergence"
        ):  # the torso, one upper arm and the head: a third of the pieces to compile
            g = g._replace(
                primitives=g.primitives._replace(**{k: getattr(g.primitives, k)[:2] for k in CONE})
            )
        args = tuple(getattr(g, k) for k in INPUTS[name])
        energy = getattr(cues, name)

        @jax.jit
        def f(*args):
            return energy(g._replace(**dict(zip(INPUTS[name], args, strict=True))), obs, ctx)

        E = np.asarray(f(*args))
        assert np.all((E > 1e-3) & (E < 0.99)), E
        grads = jax.grad(lambda *a: jnp.sum(f(*a)), range(len(args)))(*args)
        leaves = [np.asarray(v) for v in jax.tree_util.tree_leaves(grads)]
        assert all(np.all(np.isfinite(v)) for v in leaves) and max(np.abs(v).max() for v in leaves) > 1e-4
        check_grads(f, args, order=1, modes=("fwd", "rev"), eps=1e-5, atol=1e-4, rtol=1e-4)
