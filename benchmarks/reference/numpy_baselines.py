"""NumPy baselines of the benchmarks: the same computations as the compiled JAX paths, written with NumPy and
vectorised over particles (the leading axis), run in the same process as the JAX side and checked to agree with it
before timing.

* :func:`np_segment_poses`, :func:`fk_projection`: forward kinematics (product of exponentials over the tree) and
  projection of flesh points (``perf/bench_kinematics.py``);
* :class:`NumpyLikelihood`: the composed cue likelihood of :class:`jaxmocap.likelihood.compose.Likelihood` for the
  cues of ``perf/bench_likelihood.py``, on the 640×480 stereo scene of :mod:`scenes` (FK, flesh points, occluding
  contours of cones and ellipsoids, projection, facing test, nearest-pixel lookups, cue energies; float32);
* :func:`np_loglik`: PARSEC bodytrack's likelihood (``perf/bench_parsec.py``), written with batched 3×3 matrices
  following bodytrack's C++ step by step, float32 like the C++.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from scenes import H, W

from jaxmocap import parsec
from jaxmocap.geometry import camera, flesh
from jaxmocap.likelihood import colour_cues, cues
from jaxmocap.likelihood import compose as L
from jaxmocap.parsec import likelihood as pl

F = np.float32

# ---------------------------------------------------------------------------------------------------------------
# Body model: FK, projection, contours, the composed likelihood (particles on the first axis)


def _axis_angle(a, th, dtype=F):
    """``(N, 3, 3)`` rotations about unit axis ``a (3,)`` by angles ``th (N,)`` (Rodrigues)."""
    a = np.asarray(a, dtype)
    Kx = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]], dtype)
    s, c = np.sin(th)[:, None, None], np.cos(th)[:, None, None]
    return np.eye(3, dtype=dtype) + s * Kx + (1 - c) * (Kx @ Kx)


def np_segment_poses(model, X, dtype=F):
    """FK (product of exponentials, :func:`jaxmocap.geometry.kinematics.segment_poses`) for ``X (N, D)`` in ``dtype``
    → world rotations ``(N, S, 3, 3)`` and translations ``(N, S, 3)`` of the segments."""
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


def fk_projection(model, pts_local, seg, rig, X):
    """FK + projection of flesh points in NumPy (float64), the arithmetic of ``perf/bench_kinematics.py``'s JAX
    path: FK over the tree (:func:`np_segment_poses`, batched over particles), transform of the points
    ``pts_local (P, 3)`` of segments ``seg (P,)``, pinhole projection by ``rig`` (no distortion) → ``(N, V, P, 2)``."""
    R, t = np_segment_poses(model, X, np.float64)
    R, t = R[:, seg], t[:, seg]
    Xw = np.einsum("npij,pj->npi", R, pts_local) + t
    Xc = np.einsum("vij,npj->nvpi", np.asarray(rig.R), Xw) + np.asarray(rig.t)[None, :, None, :]
    K = np.asarray(rig.K)
    u = K[None, :, 0, 0, None] * Xc[..., 0] / Xc[..., 2] + K[None, :, 0, 2, None]
    v = K[None, :, 1, 1, None] * Xc[..., 1] / Xc[..., 2] + K[None, :, 1, 2, None]
    return np.stack([u, v], -1)


# ---------------------------------------------------------------------------------------------------------------
# PARSEC bodytrack's likelihood, vectorised over particles

_XR90 = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], F)
_XR180 = np.diag([1, -1, -1]).astype(F)
_XR270 = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], F)
_YR90 = np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]], F)
_YR180 = np.diag([-1, 1, -1]).astype(F)
_ZR180 = np.diag([-1, -1, 1]).astype(F)


def _rot(axis, a):
    c, s = np.cos(a).astype(F), np.sin(a).astype(F)
    o, z = np.ones_like(c), np.zeros_like(c)
    if axis == 0:
        m = [[o, z, z], [z, c, -s], [z, s, c]]
    elif axis == 1:
        m = [[c, z, s], [z, o, z], [-s, z, c]]
    else:
        m = [[c, -s, z], [s, c, z], [z, z, o]]
    return np.stack([np.stack(r, -1) for r in m], -2)


def _euler_inv(th, ph, ta):
    """``inv(Rz(ta) Rx(th) Ry(ph))`` for ``(N,)`` angles."""
    E = _rot(2, ta) @ _rot(0, th) @ _rot(1, ph)
    return np.swapaxes(E, -1, -2)


def np_cylinder_poses(limbs, L, X):
    """``(N, 10, 3, 4)`` poses following BodyGeometry.cpp step by step."""
    N = len(X)
    a = X.T
    z = np.zeros(N, F)
    Rp = _rot(2, a[2]) @ _rot(0, a[0]) @ _rot(1, a[1])
    tp = np.stack([a[3], a[4], a[5]], -1)

    def pre(R, t, v):
        return t + R @ np.asarray(v, F)

    out = [None] * 10
    out[0] = (Rp, tp)
    for side, (hip, knee, off, l1) in enumerate(((6, 9, L[1], 2), (10, 13, -L[5], 6))):
        R = Rp @ _YR180
        t = pre(R, tp, [0, off, 0])
        R = R @ _euler_inv(a[hip], a[hip + 1], a[hip + 2])
        out[1 + 2 * side] = (R, t)
        t = pre(R, t, [0, 0, L[l1]])
        R = R @ _euler_inv(z, a[knee], z)
        out[2 + 2 * side] = (R, t)
    Rt = Rp @ _XR180 @ _euler_inv(z, a[26], a[27])
    tt = pre(Rt, tp, [0, 0, -L[0]])
    r = _XR90 @ _ZR180 @ _YR90
    for side, (cl, sh, el, rot, lc, lu) in enumerate(
        ((14, 16, 19, _XR90, 9, 10), (20, 22, 25, _XR270, 13, 14))
    ):
        R = Rt @ rot @ _euler_inv(a[cl], a[cl + 1], z)
        t = pre(R, tt, [0, 0, -L[lc]])
        R = R @ r @ _euler_inv(a[sh], a[sh + 1], a[sh + 2])
        out[5 + 2 * side] = (R, t)
        t = pre(R, t, [0, 0, -L[lu]])
        R = R @ _euler_inv(z, a[el], z)
        out[6 + 2 * side] = (R, t)
    out[9] = (Rt @ _XR180 @ _euler_inv(a[28], a[29], a[30]), tt)
    R = (
        np.stack([o[0] for o in out], 1)
        * np.concatenate([limbs[:, 2:4], np.ones((10, 1), F)], 1)[None, :, None, :]
    )
    t = np.stack([o[1] for o in out], 1)
    return np.concatenate([R, t[..., None]], -1)


def np_corners(limbs, length, cams, P):
    """``(N, V, 10, 4, 2)`` projected corners."""
    A, t = P[..., :3], P[..., 3]
    Ainv = np.linalg.inv(A)
    out = []
    for v in range(len(cams.fc)):
        e = np.einsum("npij,npj->npi", Ainv, cams.eye[v].astype(F) - t)
        r = np.stack([-e[..., 0], -e[..., 1]], -1)
        r2 = np.stack([-r[..., 1], r[..., 0]], -1) / np.linalg.norm(r, axis=-1, keepdims=True)
        pts = []
        for rad, zz in (
            (-limbs[:, 0], 0.0),
            (-limbs[:, 1], length),
            (limbs[:, 1], length),
            (limbs[:, 0], 0.0),
        ):
            loc = np.concatenate(
                [
                    rad[:, None] * r2,
                    np.broadcast_to(np.asarray(zz, F), rad.shape)[None, :, None] + 0 * r2[..., :1],
                ],
                -1,
            )
            pts.append(np.einsum("npij,npj->npi", A, loc) + t)
        X = np.stack(pts, 2)  # (N, 10, 4, 3)
        Xc = X @ cams.R[v].T.astype(F) + cams.T[v].astype(F)
        x, y = Xc[..., 0] / Xc[..., 2], Xc[..., 1] / Xc[..., 2]
        r2_ = x * x + y * y
        kc = cams.kc[v].astype(F)
        d = 1 + kc[0] * r2_ + kc[1] * r2_ * r2_ + kc[4] * r2_**3
        xd = d * x + kc[2] * 2 * x * y + kc[2] * (r2_ + 2 * x * x)
        yd = d * y + kc[2] * (r2_ + 2 * y * y) + kc[2] * 2 * x * y
        u = cams.fc[v, 0] * (xd + cams.alpha[v] * yd) + cams.cc[v, 0]
        w = cams.fc[v, 1] * yd + cams.cc[v, 1]
        out.append(np.stack([u, w], -1).astype(F))
    return np.stack(out, 1)


def _steps(d, n_max):
    """Float32 running sums 0, d, 2d, … (sequential, as the C++ loop) → ``(N, n_max + 1)``."""
    inc = np.broadcast_to(d[:, None], (len(d), n_max)).astype(F)
    return np.concatenate([np.zeros((len(d), 1), F), np.cumsum(inc, axis=1, dtype=F)], 1)


def _take(flat, offset, x, y, mask, W, H):
    xs, ys = (x + F(0.5)).astype(F), (y + F(0.5)).astype(F)
    m = mask & (xs > -1) & (xs < W) & (ys > -1) & (ys < H)
    idx = (
        offset
        + np.floor(np.maximum(ys, 0)).astype(np.int64) * W
        + np.floor(np.maximum(xs, 0)).astype(np.int64)
    )
    return np.take(flat, np.where(m, idx, 0)), m


def np_loglik(shape, cams, edge, fg, X):
    """bodytrack's log-likelihood of particles ``X (N, 31)`` with NumPy."""
    limbs, L = shape.limbs.astype(F), shape.lengths.astype(F)
    length = np.asarray(parsec.cylinder_lengths(shape), F)
    P = np_cylinder_poses(limbs, L, X.astype(F))
    uv = np_corners(limbs, length, cams, P)
    V, H, W = edge.shape
    fe, ff = edge.reshape(-1), fg.reshape(-1)
    N = len(X)
    ssd, ne, bg, ni = (np.zeros(N) for _ in range(4))
    for v in range(V):
        off = v * H * W
        for p in range(10):
            c = uv[:, v, p]
            for a, b in ((0, 1), (2, 3)):
                s = c[:, b] - c[:, a]
                n = np.maximum(np.floor(np.hypot(s[:, 0], s[:, 1]) / 5 + 0.5), 4).astype(np.int64)
                t = _steps((1 / n).astype(F), n.max())
                mask = np.arange(n.max() + 1)[None] <= n[:, None]
                val, m = _take(fe, off, c[:, a, :1] + t * s[:, :1], c[:, a, 1:] + t * s[:, 1:], mask, W, H)
                e = 255 - val.astype(np.int64)
                ssd += np.where(m, e * e, 0).sum(1)
                ne += m.sum(1)
            s1, s2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 3]
            mm = c[:, 0] + s1 / F(2) - (c[:, 3] + s2 / F(2))
            n1 = np.maximum(np.floor(np.hypot(s1[:, 0], s1[:, 1]) / 10 + 0.5), 4).astype(np.int64)
            n2 = np.maximum(np.floor(np.hypot(mm[:, 0], mm[:, 1]) / 10 + 0.5), 4).astype(np.int64)
            t1 = _steps((1 / n1).astype(F), n1.max())  # (N, R)
            t2 = _steps((1 / n2).astype(F), n2.max())[:, :-1]  # (N, C)
            e1 = c[:, None, 0] + t1[..., None] * s1[:, None]
            e2 = c[:, None, 3] + t1[..., None] * s2[:, None]
            md = e2 - e1
            x = e1[:, :, None, 0] + t2[:, None, :] * md[:, :, None, 0]
            y = e1[:, :, None, 1] + t2[:, None, :] * md[:, :, None, 1]
            mask = (np.arange(n1.max() + 1)[None, :, None] <= n1[:, None, None]) & (
                np.arange(n2.max())[None, None, :] < n2[:, None, None]
            )
            val, m = _take(ff, off, x, y, mask, W, H)
            bg += (m & (val == 0)).sum((1, 2))
            ni += m.sum((1, 2))
    ll = -(ssd / 255.0**2 / ne + bg / ni)
    valid = np.asarray(jax.vmap(lambda q: pl.geometry_valid(shape, q))(jnp.asarray(P)))
    return np.where(valid, ll, pl.INVALID)
