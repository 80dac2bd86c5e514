"""Speed of the composed cue likelihood (``Likelihood.batch``, jitted) against a NumPy implementation of the same
computation in the same process (issue 5).

Configurations (2 views, 640×480, synthetic observation maps):

* ``upper14-iros``: ``upper14`` with the IROS 2007 cue set (edge_distance, colour_histogram, blobs3d, skin,
  homogeneous_colour); target ≥ 100 k particles/s on 2 cores;
* ``full25-lk``: ``full25`` with edges + foreground + depth; target ≥ 50 k particles/s.

Particles are drawn around a standing pose in view of both cameras. JAX: median (and minimum) wall time of
``--repeats`` calls after compilation. NumPy: the same FK (twists), flesh points, occluding contours,
projection, facing test, nearest-pixel lookups and cue energies, vectorised over particles (float32), median of
``--numpy-repeats``; both are checked to agree on the first 64 particles before timing.

``upper14-iros-P300`` / ``-P150``: the IROS 2007 set with 300 / 150 flesh surface samples instead of 600 (the
cost is linear in them). ``--per-cue`` times each IROS 2007 cue alone, with the geometry it needs. ``--sweep``
times the first two configurations at 10², 10³, 10⁴ and 10⁵ particles, each against NumPy.

    .venv/bin/python benchmarks/bench_likelihood.py [--particles 8192] [--repeats 7] [--per-cue] [--sweep] [--quick]
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.features.observation import make_observation
from jaxmocap.geometry import body, camera, flesh
from jaxmocap.likelihood import colour_cues, cues
from jaxmocap.likelihood import compose as L
from jaxmocap.synth.stage import look_at

W, H = 640, 480
F = np.float32

IROS_CUES = ("edge_distance", "colour_histogram", "blobs3d", "skin", "homogeneous_colour")
#: name -> (body model, cues, target particles/s, flesh surface samples)
CONFIGS = {
    "upper14-iros": ("upper14", IROS_CUES, 100_000, 600),
    "full25-lk": ("full25", ("edges", "foreground", "depth"), 50_000, 600),
}
#: the IROS 2007 set with fewer surface samples (the cost is linear in them): how far the default is from the target
SAMPLE_SWEEP = {
    "upper14-iros-P300": ("upper14", IROS_CUES, 100_000, 300),
    "upper14-iros-P150": ("upper14", IROS_CUES, 100_000, 150),
}


# ---------------------------------------------------------------------------------------------------------------
# Scene


def stereo_rig() -> camera.Rig:
    """Two cameras 30 cm apart, 1.3 m high, 3.5 m from the subject (the IROS 2007 robot head), 640×480."""
    Rs, ts = zip(*[look_at(np.array([3.5, y, 1.3]), [0.0, 0.0, 1.0]) for y in (-0.15, 0.15)], strict=True)
    K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
    return camera.from_opencv(
        np.stack([K, K]), np.zeros((2, 5)), np.stack(Rs), np.stack(ts), image_size=[(W, H)] * 2
    )


def observation(rig, rng):
    """Synthetic maps of the right shapes and ranges (smooth random fields: the timing does not depend on content)."""

    def field(scale=1.0):
        small = rng.uniform(0, 1, (2, H // 16 + 1, W // 16 + 1)).astype(F)
        return np.repeat(np.repeat(small, 16, 1), 16, 2)[:, :H, :W] * scale

    fg = (field() > 0.3).astype(F)
    return make_observation(
        rig,
        foreground=fg,
        edges=field(),
        edge_dt=field(40.0),
        skin=field(),
        depth=np.where(fg > 0, 2.5 + field(1.0), 0.0).astype(F),
        rgb=np.stack([field(), field(), field()], -1),
        blobs3d=np.array([[0.0, 0.0, 1.6], [0.3, 0.25, 1.2], [0.3, -0.25, 1.2]]),
    )


def particles(model, n, rng):
    x = np.asarray(model.rest_pose, F).copy()
    noise = rng.normal(0.0, 0.05, (n, model.num_dofs)).astype(F)
    return np.clip(x + noise, np.asarray(model.lower), np.asarray(model.upper)).astype(F)


# ---------------------------------------------------------------------------------------------------------------
# NumPy implementation (particles on the first axis)


def _axis_angle(a, th, dtype=F):
    """``(N, 3, 3)`` rotations about unit axis ``a (3,)`` by angles ``th (N,)`` (Rodrigues)."""
    a = np.asarray(a, dtype)
    Kx = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]], dtype)
    s, c = np.sin(th)[:, None, None], np.cos(th)[:, None, None]
    return np.eye(3, dtype=dtype) + s * Kx + (1 - c) * (Kx @ Kx)


def np_segment_poses(model, X, dtype=F):
    """FK (product of exponentials, :func:`jaxmocap.geometry.kinematics.segment_poses`) for ``X (N, D)`` in ``dtype``
    (also the NumPy baseline of ``bench_kinematics.py``)."""
    top = model.topology
    rest, off, axis = (np.asarray(a, dtype) for a in (model.rest_rotation, model.offset, model.dof_axis))
    N = X.shape[0]
    Rs, ts = [], []
    for s in range(top.num_segments):
        R = np.broadcast_to(rest[s] if top.rest_rotated[s] else np.eye(3, dtype=dtype), (N, 3, 3))
        t = np.broadcast_to(off[s], (N, 3))
        for k in top.segment_dofs[s]:
            if top.dof_kinds[k] == "P":
                t = t + (R @ axis[k]) * X[:, k, None]
            else:
                R = R @ _axis_angle(axis[k], X[:, k], dtype)
        p = top.parents[s]
        if p >= 0:
            t = ts[p] + np.einsum("nij,nj->ni", Rs[p], t)
            R = Rs[p] @ R
        Rs.append(R)
        ts.append(t)
    return np.stack(Rs, 1), np.stack(ts, 1)  # (N, S, 3, 3), (N, S, 3)


def _project(rig, X):
    """Pinhole projection (the rig has no distortion) of ``X (N, V, P, 3)`` or ``(N, P, 3)``: uv, z."""
    R, t, K = (np.asarray(a, F) for a in (rig.R, rig.t, rig.K))
    if X.ndim == 3:
        Xc = np.einsum("vij,npj->nvpi", R, X) + t[None, :, None]
    else:
        Xc = np.einsum("vij,nvpj->nvpi", R, X) + t[None, :, None]
    z = Xc[..., 2]
    a, b = Xc[..., 0] / z, Xc[..., 1] / z
    u = K[None, :, 0, 0, None] * a + K[None, :, 0, 2, None]
    v = K[None, :, 1, 1, None] * b + K[None, :, 1, 2, None]
    return u, v, z


def _index(u, v):
    inside = (u > -0.5) & (u < W - 0.5) & (v > -0.5) & (v < H - 0.5)
    iu = np.clip(np.nan_to_num(u) + 0.5, 0, W - 0.5).astype(np.int32)
    iv = np.clip(np.nan_to_num(v) + 0.5, 0, H - 0.5).astype(np.int32)
    return (np.arange(2, dtype=np.int32)[None, :, None] * (H * W) + iv * W + iu), inside


def _basis(axis):
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    sgn = np.where(z >= 0, 1.0, -1.0).astype(F)
    h = -1.0 / (sgn + z)
    g = x * y * h
    return np.stack([1.0 + sgn * x * x * h, sgn * g, -sgn * x], -1), np.stack([g, sgn + y * y * h, -y], -1)


def np_contours(model, Rw, tw, centres, k):
    """Occluding-contour points ``(N, V, Q, 3)`` of the cones (then the ellipsoids, 2k points each)."""
    ci = np.asarray(flesh.cone_segments(model))
    ei = np.asarray(flesh.ellipsoid_segments(model))
    out = []
    if ci.size:
        a = np.einsum("nsij,sj->nsi", Rw[:, ci], np.asarray(model.shape_start, F)[ci]) + tw[:, ci]
        b = np.einsum("nsij,sj->nsi", Rw[:, ci], np.asarray(model.shape_end, F)[ci]) + tw[:, ci]
        ra, rb = np.asarray(model.radius_start, F)[ci], np.asarray(model.radius_end, F)[ci]
        v = b - a
        Ln = np.sqrt(np.sum(v * v, -1))
        ahat = v / Ln[..., None]
        e1, _ = _basis(ahat)
        s = np.linspace(0.0, 1.0, k, dtype=F)
        for c in centres:
            d = c - a
            dpar = np.sum(d * ahat, -1)
            dperp = d - dpar[..., None] * ahat
            rho = np.sqrt(np.sum(dperp * dperp, -1))
            dhat = dperp / rho[..., None]
            side = np.cross(ahat, dhat)
            gamma = np.clip((ra + (rb - ra) / Ln * dpar) / rho, -1.0, 1.0)
            sg = np.sqrt(np.maximum(1.0 - gamma * gamma, 1e-12))
            u = np.stack(
                [
                    gamma[..., None] * dhat + sg[..., None] * side,
                    gamma[..., None] * dhat - sg[..., None] * side,
                ],
                -2,
            )
            axis_pts = (
                a[:, :, None] + (s[None, None, :, None] * Ln[..., None, None]) * ahat[:, :, None]
            )  # (N,C,k,3)
            radius = ra[:, None] + s[None] * (rb - ra)[:, None]  # (C, k)
            pts = axis_pts[:, :, None] + radius[None, :, None, :, None] * u[:, :, :, None]  # (N, C, 2, k, 3)
            out.append(pts.reshape(len(Rw), -1, 3))
    cones = np.stack(out, 1) if out else None
    if ei.size:
        c_loc, ax_loc = (
            np.asarray(q, F)
            for q in flesh._local_ellipsoid_axes(
                np.asarray(model.shape_start)[ei],
                np.asarray(model.shape_end)[ei],
                np.asarray(model.radius_start)[ei],
            )
        )
        m = np.einsum("nsij,sj->nsi", Rw[:, ei], c_loc) + tw[:, ei]
        A = Rw[:, ei] @ ax_loc  # (N, E, 3, 3)
        th = 2 * np.pi * np.arange(2 * k, dtype=F) / (2 * k)
        ells = []
        for c in centres:
            y = np.linalg.solve(A, (c - m)[..., None])[..., 0]
            n2 = np.sum(y * y, -1)
            f1, f2 = _basis(y / np.sqrt(n2)[..., None])
            rho = np.sqrt(np.maximum(1.0 - 1.0 / n2, 0.0))
            circ = (y / n2[..., None])[:, :, None] + rho[..., None, None] * (
                np.cos(th)[:, None] * f1[:, :, None] + np.sin(th)[:, None] * f2[:, :, None]
            )
            ells.append((m[:, :, None] + np.einsum("neij,nekj->neki", A, circ)).reshape(len(Rw), -1, 3))
        ells = np.stack(ells, 1)
        cones = ells if cones is None else np.concatenate([cones, ells], 2)
    return cones


class NumpyLikelihood:
    """The composed log-likelihood of :class:`jaxmocap.likelihood.compose.Likelihood` (schedule 1, weights 1, default cue
    parameters) for the cues of this benchmark, in NumPy."""

    def __init__(self, lik: L.Likelihood, obs):
        self.lik, self.model, self.rig = lik, lik.model, lik.rig
        self.names = [c.name for c in lik.cues]
        self.seg = np.asarray(lik.surface.segment)
        self.local = np.asarray(lik.surface.local, F)
        self.normal = np.asarray(lik.surface.normal, F)
        self.centres = np.asarray(camera.camera_centres(lik.rig), F)
        self.maps = {
            k: np.asarray(getattr(obs, k)).reshape(-1)
            for k in ("foreground", "edges", "edge_dt", "skin")
            if obs.has(k)
        }
        if obs.has("depth"):
            fg = np.asarray(obs.foreground) >= 0.5
            self.maps["depth"] = np.where(fg, np.asarray(obs.depth), 0.0).astype(F).reshape(-1)
        if obs.has("rgb"):
            c8 = np.round(np.clip(np.asarray(obs.rgb), 0, 1) * 255).astype(np.int32)
            self.rgb = (c8.reshape(-1, 3) / F(255)).astype(F)
            self.bins = np.asarray(colour_cues._colour_bins(jnp.asarray(c8), 4, "rgb")).reshape(-1)
        self.obs = obs
        self.refs = lik.references

    def __call__(self, X):
        N = X.shape[0]
        Rw, tw = np_segment_poses(self.model, X)
        need_surface = any(
            n in self.names for n in ("foreground", "depth", "skin", "colour_histogram", "homogeneous_colour")
        )
        E = np.zeros(N, F)
        if need_surface:
            Xs = np.einsum("npij,pj->npi", Rw[:, self.seg], self.local) + tw[:, self.seg]  # (N, P, 3)
            u, v, z = _project(self.rig, Xs)
            idx, inside = _index(u, v)
            nw = np.einsum("npij,pj->npi", Rw[:, self.seg], self.normal)
            facing = (np.einsum("npi,vnpi->nvp", nw, self.centres[:, None, None] - Xs[None]) > 0) & (z > 0)
        if any(n in self.names for n in ("edges", "edge_distance")):
            Q = np_contours(self.model, Rw, tw, self.centres, self.lik.contour_points)
            qu, qv, _ = _project(self.rig, Q)
            qidx, qin = _index(qu, qv)
        J = None
        if any(n in self.names for n in ("blobs3d", "skin")):
            jseg = np.asarray(self.model.joint_segment)
            J = np.einsum("njik,jk->nji", Rw[:, jseg], np.asarray(self.model.joint_point, F)) + tw[:, jseg]
        jn = self.model.joint_names
        for c, name in enumerate(self.names):
            if name == "foreground":
                f = self.maps["foreground"][idx]
                e = np.mean(np.where(inside, 1.0 - f, 1.0), -1)
            elif name == "edges":
                e = np.mean(np.where(qin, 1.0 - self.maps["edges"][qidx], 1.0), -1)
            elif name == "edge_distance":
                D = np.mean(np.where(qin, np.minimum(self.maps["edge_dt"][qidx], 30.0), 30.0), -1)
                e = D * D / (2 * 36.0)
            elif name == "depth":
                Dm = self.maps["depth"][idx]
                d = np.where(inside & (Dm > 0), np.abs(z - Dm), cues.DEPTH_PENALTY_M)
                w = facing.astype(F)
                e = np.minimum(np.sum(d * w, -1) / np.maximum(np.sum(w, -1), 1.0), 2.8) / 2.8
            elif name == "blobs3d":
                Xj = J[:, [jn.index(n) for n in ("head", "left_wrist", "right_wrist")]]
                b, conf = np.asarray(self.obs.blobs3d, F), np.asarray(self.obs.blob_conf, F)
                d2 = np.min(np.sum((b[None, :, None] - Xj[:, None]) ** 2, -1), -1)  # (N, K)
                e = (np.sum(conf * d2, -1) / (2 * 0.01) / max(conf.sum(), 1.0))[:, None]
            elif name == "skin":
                sl = self.seg == self.model.segment_names.index("head")
                S = np.where(inside, self.maps["skin"][idx], 0.0)[..., sl]
                fw = facing[..., sl].astype(F)
                sw = fw.sum(-1)
                head = np.where(sw > 0, np.sum(S * fw, -1) / np.maximum(sw, 1e-12), 0.0)
                wr = J[:, [jn.index("left_wrist"), jn.index("right_wrist")]]
                el = J[:, [jn.index("left_elbow"), jn.index("right_elbow")]]
                d = wr - el
                hc = wr + 0.08 * d / np.sqrt(np.sum(d * d, -1, keepdims=True) + 1e-12)
                hu, hv, hz = _project(self.rig, hc)  # (N, V, 2)
                rad = 0.6 * np.asarray(self.rig.K, F)[None, :, 0, 0, None] * 0.05 / np.maximum(hz, 1e-3)
                ang = np.linspace(0, 2 * np.pi, 6, endpoint=False)
                off = np.concatenate([np.zeros((1, 2)), np.stack([np.cos(ang), np.sin(ang)], -1)]).astype(F)
                su = (hu[..., None] + rad[..., None] * off[:, 0]).reshape(N, 2, -1)
                sv = (hv[..., None] + rad[..., None] * off[:, 1]).reshape(N, 2, -1)
                hi, hin = _index(su, sv)
                hands = np.mean(np.where(hin, self.maps["skin"][hi], 0.0).reshape(N, 2, 2, -1), -1)
                D = 1.0 - np.concatenate([head[..., None], hands], -1)
                e = np.sum(D * D, -1) / (2 * 0.25)
            elif name == "colour_histogram":
                segs = sorted(set(self.seg.tolist()))
                w = (facing & inside).astype(F)
                b = self.bins[idx]
                sref = np.sqrt(np.asarray(self.refs[c], F))  # (V, R, 64)
                e = np.zeros((N, 2), F)
                for r, s in enumerate(segs):
                    sl = self.seg == s
                    ws, bs = w[..., sl], b[..., sl]
                    n = ws.sum(-1)
                    flat = (np.arange(N * 2)[:, None] * 64 + bs.reshape(N * 2, -1)).reshape(-1)
                    h = np.bincount(flat, ws.reshape(-1), N * 2 * 64).reshape(N, 2, 64).astype(F)
                    h = h / np.maximum(n, 1e-12)[..., None]
                    bc = np.sum(np.sqrt(h) * sref[None, :, r], -1)
                    e += np.where(n > 0, np.clip(1.0 - bc, 0.0, 1.0), 1.0)
                e = e / (2 * 0.04)
            elif name == "homogeneous_colour":
                w = (facing & inside).astype(F)
                col = self.rgb[idx]  # (N, V, P, 3)
                head = self.model.segment_names.index("head")
                sds, ok = [], []
                for s in sorted(set(self.seg.tolist()) - {head}):
                    sl = self.seg == s
                    ws = w[..., sl]
                    n = ws.sum(-1)
                    ns = np.maximum(n, 1e-12)
                    cs = col[..., sl, :]
                    m1 = np.sum(cs * ws[..., None], -2) / ns[..., None]
                    m2 = np.sum(cs * cs * ws[..., None], -2) / ns[..., None]
                    var = np.sum(m2 - m1 * m1, -1)
                    sds.append(np.sqrt(np.maximum(var, 0.0) / 3.0 + 1e-8))
                    ok.append((n >= 2).astype(F))
                sds, ok = np.stack(sds, -1), np.stack(ok, -1)
                D = np.where(ok.sum(-1) > 0, np.sum(sds * ok, -1) / np.maximum(ok.sum(-1), 1e-12), 0.0)
                e = D * D / (2 * 0.01)
            else:
                raise ValueError(name)
            E = E + np.sum(e, -1)
        ll = -E
        return np.where(np.isfinite(ll), ll, -np.inf)


# ---------------------------------------------------------------------------------------------------------------


def build(config: str, rng):
    preset, names, target, points = {**CONFIGS, **SAMPLE_SWEEP}[config]
    model = getattr(body, preset)()
    rig = stereo_rig()
    obs = observation(rig, rng)
    lik = L.Likelihood.create(model, rig, [L.Cue(n) for n in names], surface_points=points)
    if lik.needs_references:
        lik = lik.with_references(model.rest_pose, obs)
    return model, rig, obs, lik, target


def _time(f, repeats):
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)), float(np.min(ts))


def run(config, n, repeats, np_repeats, rng):
    model, rig, obs, lik, target = build(config, rng)
    X = jnp.asarray(particles(model, n, rng))
    fj = jax.jit(lik.batch)
    t0 = time.perf_counter()
    ll = np.asarray(fj(X, obs, 0))
    compile_s = time.perf_counter() - t0
    nl = NumpyLikelihood(lik, obs)
    Xn = np.asarray(X)
    ref = nl(Xn[:64])
    # nearest-pixel rounding of a sample exactly on a pixel edge may differ between the two: compare robustly
    rel = np.abs(ll[:64] - ref) / np.maximum(np.abs(ref), 1e-3)
    agree = float(np.median(rel)), float(np.quantile(rel, 0.9))
    tj, tj_min = _time(lambda: fj(X, obs, 0).block_until_ready(), repeats)
    tn, _ = _time(lambda: nl(Xn), np_repeats)
    return dict(
        config=config,
        particles=n,
        compile_s=compile_s,
        jax_s=tj,
        jax_min_s=tj_min,
        numpy_s=tn,
        jax_pps=n / tj,
        numpy_pps=n / tn,
        target=target,
        agree=agree,
        P=lik.surface.local.shape[0],
    )


def per_cue(config: str, n: int, repeats: int, rng) -> list[tuple[str, float]]:
    """``(cue, median seconds)`` of the jitted likelihood of each cue of ``config`` alone (same particles and
    surface samples; each includes the FK / projection that cue needs, which the full set shares), then of the
    full set."""
    model, rig, obs, lik, _ = build(config, rng)
    X = jnp.asarray(particles(model, n, rng))
    points = lik.surface.local.shape[0]
    out = []
    for cue in lik.cues:
        one = L.Likelihood.create(model, rig, [cue], surface_points=points)
        if one.needs_references:
            one = one.with_references(model.rest_pose, obs)
        f = jax.jit(one.batch)
        f(X, obs, 0).block_until_ready()
        out.append((cue.name, _time(lambda f=f: f(X, obs, 0).block_until_ready(), repeats)[0]))
    f = jax.jit(lik.batch)
    f(X, obs, 0).block_until_ready()
    out.append(("all together", _time(lambda: f(X, obs, 0).block_until_ready(), repeats)[0]))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--particles", type=int, default=8192)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--numpy-repeats", type=int, default=3)
    ap.add_argument(
        "--configs",
        nargs="*",
        default=None,
        help=f"default: all of {[*CONFIGS, *SAMPLE_SWEEP]} (quick: the first two)",
    )
    ap.add_argument("--quick", action="store_true", help="1024 particles, 3 repeats, 1 NumPy repeat")
    ap.add_argument(
        "--sweep",
        action="store_true",
        help="also time upper14-iros and full25-lk at 10^2 ... 10^5 particles against NumPy (1 NumPy repeat)",
    )
    ap.add_argument(
        "--per-cue",
        action="store_true",
        help="also time each cue of upper14-iros alone (where its time goes)",
    )
    a = ap.parse_args(argv)
    if a.quick:
        a.particles, a.repeats, a.numpy_repeats = 1024, 3, 1
    if a.configs is None:
        a.configs = list(CONFIGS) if a.quick else [*CONFIGS, *SAMPLE_SWEEP]
    rng = np.random.default_rng(0)
    print(f"jax {jax.__version__}, {jax.devices()[0].platform}, load average {os.getloadavg()[0]:.2f}")
    print(
        "| config | P | particles | JAX median (min) s | JAX particles/s | NumPy s | NumPy particles/s | "
        "speed-up | target | rel. diff median / p90 |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for cfg in a.configs:
        r = run(cfg, a.particles, a.repeats, a.numpy_repeats, rng)
        print(
            f"| {cfg} | {r['P']} | {r['particles']} | {r['jax_s']:.4f} ({r['jax_min_s']:.4f}) | "
            f"{r['jax_pps']:,.0f} | {r['numpy_s']:.3f} | {r['numpy_pps']:,.0f} | "
            f"{r['numpy_s'] / r['jax_s']:.1f}× | {r['target']:,} | {r['agree'][0]:.1e} / {r['agree'][1]:.1e} |",
            flush=True,
        )
    if a.sweep:
        print("\nThroughput against the particle count (JAX: median of the repeats; NumPy: one run):")
        print(
            "| config | particles | JAX particles/s | NumPy particles/s | speed-up |\n|---|---|---|---|---|"
        )
        for cfg in CONFIGS:
            for n in (100, 1_000, 10_000, 100_000):
                r = run(cfg, n, a.repeats, 1, rng)
                print(
                    f"| {cfg} | {n:,} | {r['jax_pps']:,.0f} | {r['numpy_pps']:,.0f} | "
                    f"{r['numpy_s'] / r['jax_s']:.1f}× |",
                    flush=True,
                )
    if a.per_cue:
        print(f"\nupper14-iros, each cue alone ({a.particles} particles, with the geometry that cue needs):")
        print("| cue | median ms | particles/s |\n|---|---|---|")
        for name, sec in per_cue("upper14-iros", a.particles, a.repeats, rng):
            print(f"| {name} | {sec * 1e3:.1f} | {a.particles / sec:,.0f} |", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
