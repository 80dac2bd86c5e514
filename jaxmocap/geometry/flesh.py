"""Flesh of a body model: surface and interior sample points, occluding contours, silhouette tests.

Each segment of a :class:`jaxmocap.geometry.body.BodyModel` carries one primitive in its own frame
(``shape_kind[s]``):

* ``"cone"`` — a truncated cone with flat end caps, axis from ``a = shape_start[s]`` to ``b = shape_end[s]``,
  radius ``r_a = radius_start[s]`` at ``a`` and ``r_b = radius_end[s]`` at ``b``. With ``L = |b − a|``,
  ``â = (b − a)/L`` and ``(e₁, e₂, â)`` a right-handed orthonormal frame, its lateral surface is
  ``p(s, φ) = a + s L â + (r_a + s Δ) u(φ)``, ``u(φ) = cos φ e₁ + sin φ e₂``, ``Δ = r_b − r_a``, ``s ∈ [0, 1]``,
  with outward unit normal ``n(φ) = (L u(φ) − Δ â) / √(L² + Δ²)`` (constant along a generator).
* ``"ellipsoid"`` — a spheroid centred at ``m = (a + b)/2`` with polar semi-axis ``h = L/2`` along ``â`` and
  equatorial radius ``r = radius_start[s]``: ``x = m + M y`` for ``|y| = 1`` with ``M = [r e₁, r e₂, h â]``.
* ``"none"`` — no flesh.

Everything here is a pure function of traced arrays (body dimensions and poses are differentiable); point
counts and the ring layout are static. The same primitives in world coordinates (:class:`Primitives`) are what
:mod:`jaxmocap.geometry.render` ray-casts, so the sample points, the contours and the rendered images agree.

Occluding contours (López Méndez 2009, §4.1): seen from a camera centre ``c``, the silhouette of a cone is
traced by the two generators whose tangent plane contains ``c``: ``(p − c)·n = 0``. Because ``n`` is
constant along a generator and the plane through the generator contains the apex, the condition does not depend
on ``s``: with ``d = c − a``, ``d∥ = d·â``, ``d⊥ = d − d∥ â = ρ d̂⊥``,

    ``d·u(φ) = r_a + (Δ/L) d∥   ⇔   cos(φ − ψ) = (r_a + (Δ/L) d∥) / ρ``,

so ``u± = γ d̂⊥ ± √(1 − γ²) (â × d̂⊥)`` with ``γ = (r_a + Δ d∥ / L)/ρ``. For an ellipsoid ``x = m + M y`` the
contour is the image under ``M`` of the circle where the polar plane of ``c' = M⁻¹(c − m)`` cuts the unit sphere:
centre ``c'/|c'|²``, radius ``√(1 − 1/|c'|²)`` in the plane ``y·c' = 1``. Degenerate views (camera on a cone
axis, inside the tangent cone or inside a primitive) clamp ``γ`` / the radius and never produce NaN.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.geometry import kinematics
from jaxmocap.geometry.body import SHAPE_CONE, SHAPE_ELLIPSOID, SHAPE_NONE, BodyModel
from jaxmocap.stored_programs import stored_jit

_EPS = 1e-12

# ---------------------------------------------------------------------------------------------------------------
# Small vector helpers (per coordinate, broadcast over leading axes)


def _dot(a: jnp.ndarray, b: jnp.ndarray) -> jnp.ndarray:
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _solve3(A: jnp.ndarray, b: jnp.ndarray) -> jnp.ndarray:
    """``A⁻¹ b`` for ``A (..., 3, 3)``, ``b (..., 3)`` by Cramer's rule: ``x = (c₀ · b, c₁ · b, c₂ · b) / det A``
    with ``c_i`` the rows of the adjugate (cross products of the columns). Element-wise arithmetic that XLA fuses;
    ``jnp.linalg.solve`` is an LU factorisation call per matrix."""
    a0, a1, a2 = A[..., :, 0], A[..., :, 1], A[..., :, 2]
    c0, c1, c2 = _cross(a1, a2), _cross(a2, a0), _cross(a0, a1)
    det = _dot(a0, c0)
    return jnp.stack([_dot(c0, b), _dot(c1, b), _dot(c2, b)], -1) / det[..., None]


def _cross(a: jnp.ndarray, b: jnp.ndarray) -> jnp.ndarray:
    return jnp.stack(
        [
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ],
        -1,
    )


def _safe_norm(v: jnp.ndarray, eps: float = _EPS) -> tuple[jnp.ndarray, jnp.ndarray]:
    """``(|v|, ok)`` with a finite gradient at ``v = 0`` (double ``where``); ``|v|`` is 1 where not ``ok``."""
    sq = _dot(v, v)
    ok = sq > eps
    return jnp.sqrt(jnp.where(ok, sq, 1.0)), ok


def _safe_normalise(v: jnp.ndarray, fallback: jnp.ndarray) -> jnp.ndarray:
    n, ok = _safe_norm(v)
    return jnp.where(ok[..., None], v / n[..., None], fallback)


def orthonormal_basis(axis: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Two unit vectors ``e₁, e₂`` with ``(e₁, e₂, axis)`` right-handed orthonormal; ``axis (..., 3)`` unit.

    Branch-free construction (Duff et al., "Building an orthonormal basis, revisited", JCGT 2017):
    ``σ = sign(z)``, ``h = −1/(σ + z)``, ``g = x y h``, ``e₁ = (1 + σ x² h, σ g, −σ x)``, ``e₂ = (g, σ + y² h, −y)``.
    """
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    sgn = jnp.where(z >= 0, 1.0, -1.0).astype(axis.dtype)
    h = -1.0 / (sgn + z)
    g = x * y * h
    e1 = jnp.stack([1.0 + sgn * x * x * h, sgn * g, -sgn * x], -1)
    e2 = jnp.stack([g, sgn + y * y * h, -y], -1)
    return e1, e2


def axis_length(a: jnp.ndarray, b: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Unit axis ``â`` (``+z`` for a zero-length segment) and length ``L`` of ``a → b``, ``(..., 3)``."""
    v = b - a
    L, ok = _safe_norm(v)
    z = jnp.zeros_like(v).at[..., 2].set(1.0)
    ahat = jnp.where(ok[..., None], v / L[..., None], z)
    return ahat, jnp.where(ok, L, 0.0)


# ---------------------------------------------------------------------------------------------------------------
# Segment classification and world primitives


def cone_segments(model: BodyModel) -> tuple[int, ...]:
    """Static indices of the segments whose primitive is a truncated cone, in segment order."""
    return tuple(s for s, k in enumerate(model.shape_kind) if k == SHAPE_CONE)


def ellipsoid_segments(model: BodyModel) -> tuple[int, ...]:
    """Static indices of the segments whose primitive is an ellipsoid, in segment order."""
    return tuple(s for s, k in enumerate(model.shape_kind) if k == SHAPE_ELLIPSOID)


class Primitives(NamedTuple):
    """Flesh primitives in one coordinate frame (world, unless said otherwise).

    ``C`` truncated cones: ``cone_a``, ``cone_b`` ``(C, 3)`` axis end points, ``r_a``, ``r_b`` ``(C,)`` radii there.
    ``E`` ellipsoids: ``ell_centre (E, 3)``, ``ell_axes (E, 3, 3)`` whose columns are the three semi-axis vectors
    (rotation × diag(semi-axes)): the surface is ``centre + ell_axes @ y`` for unit ``y``.
    Labels used by the renderer and the silhouette tests: cones ``0 … C−1``, then ellipsoids ``C … C+E−1``.
    """

    cone_a: jnp.ndarray
    cone_b: jnp.ndarray
    r_a: jnp.ndarray
    r_b: jnp.ndarray
    ell_centre: jnp.ndarray
    ell_axes: jnp.ndarray

    @property
    def num_cones(self) -> int:
        return self.cone_a.shape[-2]

    @property
    def num_ellipsoids(self) -> int:
        return self.ell_centre.shape[-2]

    def transformed(self, R: jnp.ndarray, t: jnp.ndarray) -> Primitives:
        """The same primitives after ``x ↦ R x + t`` (e.g. world → camera). ``R (3, 3)``, ``t (3,)``."""
        return Primitives(
            cone_a=self.cone_a @ R.T + t,
            cone_b=self.cone_b @ R.T + t,
            r_a=self.r_a,
            r_b=self.r_b,
            ell_centre=self.ell_centre @ R.T + t,
            ell_axes=jnp.einsum("ij,ejk->eik", R, self.ell_axes),
        )


def _local_ellipsoid_axes(a: jnp.ndarray, b: jnp.ndarray, r: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Centre ``(E, 3)`` and axes ``(E, 3, 3)`` (columns ``r e₁, r e₂, (L/2) â``) of segment spheroids."""
    ahat, L = axis_length(a, b)
    e1, e2 = orthonormal_basis(ahat)
    cols = jnp.stack([r[:, None] * e1, r[:, None] * e2, 0.5 * L[:, None] * ahat], -1)
    return 0.5 * (a + b), cols


@jax.jit
def world_primitives(model: BodyModel, R: jnp.ndarray, t: jnp.ndarray) -> Primitives:
    """The model's flesh in world coordinates for one particle's segment poses ``R (S,3,3)``, ``t (S,3)``.

    Cones come in the order of :func:`cone_segments`, ellipsoids in that of :func:`ellipsoid_segments`.
    vmap over particles.
    """
    ci, ei = cone_segments(model), ellipsoid_segments(model)
    ci_a = np.asarray(ci, dtype=np.int32)
    ei_a = np.asarray(ei, dtype=np.int32)
    cone_a = kinematics.transform_points(R, t, model.shape_start[ci_a], ci_a)
    cone_b = kinematics.transform_points(R, t, model.shape_end[ci_a], ci_a)
    c_loc, ax_loc = _local_ellipsoid_axes(
        model.shape_start[ei_a], model.shape_end[ei_a], model.radius_start[ei_a]
    )
    ell_centre = kinematics.transform_points(R, t, c_loc, ei_a)
    ell_axes = jnp.einsum("eij,ejk->eik", R[ei_a], ax_loc)
    return Primitives(cone_a, cone_b, model.radius_start[ci_a], model.radius_end[ci_a], ell_centre, ell_axes)


# ---------------------------------------------------------------------------------------------------------------
# Areas and the static layout of surface points


def segment_areas(model: BodyModel) -> np.ndarray:
    """``(S,)`` surface areas (host side, needs a concrete model): cone lateral area ``π (r_a + r_b) √(L² + Δ²)``,
    spheroid area by Thomsen's formula (``p = 1.6075``, within 1.1 %), 0 for ``"none"``."""
    try:
        a = np.asarray(model.shape_start, dtype=np.float64)
        b = np.asarray(model.shape_end, dtype=np.float64)
        ra = np.asarray(model.radius_start, dtype=np.float64)
        rb = np.asarray(model.radius_end, dtype=np.float64)
    except jax.errors.TracerArrayConversionError:
        raise ValueError(
            "segment areas need concrete body dimensions: build the SurfaceLayout outside jit "
            "(surface_layout(model, total=...)) and pass it to surface_points"
        ) from None
    L = np.linalg.norm(b - a, axis=-1)
    out = np.zeros(len(model.shape_kind))
    for s, kind in enumerate(model.shape_kind):
        if kind == SHAPE_CONE:
            out[s] = math.pi * (ra[s] + rb[s]) * math.hypot(L[s], rb[s] - ra[s])
        elif kind == SHAPE_ELLIPSOID:
            p = 1.6075
            r, h = ra[s], 0.5 * L[s]
            out[s] = 4 * math.pi * ((2 * (r * h) ** p + r ** (2 * p)) / 3) ** (1 / p)
    return out


@dataclasses.dataclass(frozen=True)
class SurfaceLayout:
    """Static layout of surface sample points: for each segment, the number of points on each of its rings
    (rings run along the axis; an empty tuple for a segment without flesh). Hashable, so it can be static."""

    rings: tuple[tuple[int, ...], ...]

    @property
    def counts(self) -> tuple[int, ...]:
        """Points per segment."""
        return tuple(sum(r) for r in self.rings)

    @property
    def total(self) -> int:
        return sum(self.counts)


def allocate(total: int, weights: Sequence[float]) -> tuple[int, ...]:
    """Split ``total`` into integers proportional to ``weights`` (largest remainder; each within 1 of exact)."""
    w = np.asarray(weights, dtype=np.float64)
    if total < 0 or w.sum() <= 0:
        raise ValueError("need a non-negative total and positive weights")
    exact = total * w / w.sum()
    base = np.floor(exact).astype(int)
    order = np.argsort(-(exact - base), kind="stable")
    base[order[: total - base.sum()]] += 1
    return tuple(int(v) for v in base)


def _ring_counts(n: int, rings: int) -> tuple[int, ...]:
    """``n`` points on ``rings`` rings, as even as possible."""
    if n == 0:
        return ()
    rings = max(1, min(rings, n))
    return allocate(n, [1.0] * rings)


def surface_layout(
    model: BodyModel,
    total: int | None = None,
    *,
    density: float | None = None,
    counts: Sequence[int] | None = None,
) -> SurfaceLayout:
    """Choose how many surface points each segment gets and how they sit on rings (host side).

    Exactly one of: ``total`` (split in proportion to the segment areas, largest remainder, so the total is
    fixed: Li & Kulić use 15–75 points per cone), ``density`` (points per m², rounded per segment) or ``counts``
    (per segment). Rings: about ``√(n L / (2π r̄))`` for a cone (square-ish spacing), ``√(n (π/2)(h + r)/(2π r))``
    for a spheroid; points are split evenly over the rings.
    """
    if sum(v is not None for v in (total, density, counts)) != 1:
        raise ValueError("give exactly one of total, density, counts")
    areas = segment_areas(model)
    if counts is not None:
        counts = tuple(int(c) for c in counts)
        if len(counts) != len(areas):
            raise ValueError(f"counts needs {len(areas)} entries, one per segment")
    elif total is not None:
        counts = allocate(int(total), areas)
    else:
        counts = tuple(int(round(a * density)) for a in areas)
    a = np.asarray(model.shape_start, dtype=np.float64)
    b = np.asarray(model.shape_end, dtype=np.float64)
    ra = np.asarray(model.radius_start, dtype=np.float64)
    rb = np.asarray(model.radius_end, dtype=np.float64)
    L = np.linalg.norm(b - a, axis=-1)
    rings = []
    for s, kind in enumerate(model.shape_kind):
        n = counts[s] if kind != SHAPE_NONE else 0
        if n and kind == SHAPE_CONE:
            nr = round(math.sqrt(n * L[s] / (2 * math.pi * max(0.5 * (ra[s] + rb[s]), 1e-6))))
        elif n:
            half_meridian = 0.5 * math.pi * (0.5 * L[s] + ra[s])
            nr = round(math.sqrt(n * half_meridian / (2 * math.pi * max(ra[s], 1e-6))))
        else:
            nr = 0
        rings.append(_ring_counts(n, nr))
    return SurfaceLayout(tuple(rings))


@functools.lru_cache(maxsize=64)
def _layout_tables(layout: SurfaceLayout, kinds: tuple[str, ...]):
    """Static per-point tables: segment, area fraction ``f`` of the ring centre, angle ``φ``; split by kind."""
    seg, frac, phi, is_ell = [], [], [], []
    for s, rings in enumerate(layout.rings):
        n = sum(rings)
        if n == 0:
            continue
        if kinds[s] == SHAPE_NONE:
            raise ValueError(f"segment {s} has no flesh but the layout gives it points")
        before = 0
        for i, m in enumerate(rings):
            f = (before + 0.5 * m) / n
            before += m
            off = (math.pi / m) * (i % 2)
            for j in range(m):
                seg.append(s)
                frac.append(f)
                phi.append(off + 2 * math.pi * j / m)
                is_ell.append(kinds[s] == SHAPE_ELLIPSOID)
    return (
        np.asarray(seg, dtype=np.int32),
        np.asarray(frac, dtype=np.float64),
        np.asarray(phi, dtype=np.float64),
        np.asarray(is_ell, dtype=bool),
    )


@dataclasses.dataclass(frozen=True)
class FleshPoints:
    """Sample points on (or in) the flesh, in segment frames.

    ``local (P, 3)`` coordinates (traced: they follow the body dimensions), ``normal (P, 3)`` outward unit normals
    in the same frames (zero for interior points), static ``segment`` (``P`` ints).
    """

    local: jnp.ndarray
    normal: jnp.ndarray
    segment: tuple[int, ...] = dataclasses.field(metadata=dict(static=True), default=())

    def world(self, R: jnp.ndarray, t: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
        """World points and normals ``(..., P, 3)`` for segment poses ``R (..., S, 3, 3)``, ``t (..., S, 3)``."""
        X = kinematics.transform_points(R, t, self.local, self.segment)
        N = kinematics.transform_points(R, jnp.zeros_like(t), self.normal, self.segment)
        return X, N


jax.tree_util.register_dataclass(FleshPoints, data_fields=["local", "normal"], meta_fields=["segment"])


def _segment_geometry(model: BodyModel, seg: np.ndarray):
    a = model.shape_start[seg]
    b = model.shape_end[seg]
    ahat, L = axis_length(a, b)
    e1, e2 = orthonormal_basis(ahat)
    return a, b, ahat, L, e1, e2, model.radius_start[seg], model.radius_end[seg]


def _cone_param(f: jnp.ndarray, ra: jnp.ndarray, rb: jnp.ndarray) -> jnp.ndarray:
    """Axial fraction ``s`` at which a fraction ``f`` of the lateral area lies below: the root of
    ``(Δ/2) s² + r_a s = f r̄`` written without dividing by ``Δ``: ``s = 2 f r̄ / (r_a + √(r_a² + f (r_b² − r_a²)))``."""
    rbar = 0.5 * (ra + rb)
    return 2.0 * f * rbar / (ra + jnp.sqrt(ra * ra + f * (rb * rb - ra * ra)))


def surface_points(model: BodyModel, layout: SurfaceLayout | int) -> FleshPoints:
    """Points on the flesh surface with outward normals, placed on rings along each axis (deterministic).

    Cones: ring ``i`` sits at the axial fraction where the lateral area below it is the fraction ``f_i`` of the
    points below it (:func:`_cone_param`), so the density is uniform in area for any taper; points are evenly
    spaced around each ring, alternate rings offset by half a step. Spheroids: rings at ``y_z = 2 f_i − 1`` on the
    unit sphere (equal-area bands, Archimedes) mapped by ``M``, so the density is uniform for a sphere and close
    to it for the head's mild elongation.

    Args:
      model: body model (dimensions may be traced).
      layout: a :class:`SurfaceLayout` (static; required under ``jit``) or a total point count, which is split in
        proportion to the segment areas (needs a concrete model).
    """
    if not isinstance(layout, SurfaceLayout):
        layout = surface_layout(model, total=int(layout))
    if len(layout.rings) != len(model.shape_kind):
        raise ValueError("layout does not match the model's segments")
    seg, frac, phi, is_ell = _layout_tables(layout, model.shape_kind)
    dtype = model.shape_start.dtype
    a, b, ahat, L, e1, e2, ra, rb = _segment_geometry(model, seg)
    f = jnp.asarray(frac, dtype)
    c, s_ = jnp.asarray(np.cos(phi), dtype)[:, None], jnp.asarray(np.sin(phi), dtype)[:, None]
    u = c * e1 + s_ * e2
    # cones
    sc = _cone_param(f, jnp.where(is_ell, 1.0, ra), jnp.where(is_ell, 1.0, rb))
    delta = rb - ra
    p_cone = a + (sc * L)[:, None] * ahat + (ra + sc * delta)[:, None] * u
    n_cone = L[:, None] * u - delta[:, None] * ahat
    # spheroids
    z = 2.0 * f - 1.0
    rho = jnp.sqrt(jnp.clip(1.0 - z * z, 0.0, 1.0))
    h = 0.5 * L
    p_ell = 0.5 * (a + b) + (ra * rho)[:, None] * u + (h * z)[:, None] * ahat
    n_ell = (h * rho)[:, None] * u + (ra * z)[:, None] * ahat
    ell = jnp.asarray(is_ell)[:, None]
    local = jnp.where(ell, p_ell, p_cone)
    normal = jnp.where(ell, n_ell, n_cone)
    normal = normal / _safe_norm(normal)[0][:, None]
    return FleshPoints(local, normal, tuple(int(v) for v in seg))


@stored_jit(static_argnames=("layout",))
def surface_points_compiled(model: BodyModel, layout: SurfaceLayout) -> FleshPoints:
    """:func:`surface_points` for a :class:`SurfaceLayout` as one compiled program (its trace kept on disk by a
    run of the command line, :func:`jaxmocap.stored_programs.stored_jit`): called on a concrete model, as when a
    likelihood is built, it is one program instead of some thirty eager operations, each of which a warm start
    would otherwise lower and read back from the compilation cache (about 0.3 s of a run's start). Under a
    transformation it is :func:`surface_points` inlined."""
    return surface_points(model, layout)


def interior_points(model: BodyModel, levels: int = 3, around: int = 4, fraction: float = 0.5) -> FleshPoints:
    """Points inside each fleshed segment (foreground occupancy cues), ``levels·(1 + around)`` per segment.

    At ``levels`` axial fractions ``(i + ½)/levels`` (cones: along ``a → b``; spheroids: ``y_z = 2·frac − 1``):
    one point on the axis and ``around`` points at ``fraction`` of the local radius. Normals are zero.
    """
    kinds = model.shape_kind
    segs = [s for s, k in enumerate(kinds) if k != SHAPE_NONE]
    per = levels * (1 + around)
    seg = np.repeat(np.asarray(segs, dtype=np.int32), per)
    fr = np.tile(np.repeat((np.arange(levels) + 0.5) / levels, 1 + around), len(segs))
    ring = np.tile(np.concatenate([[0.0], np.full(around, fraction)]), levels * len(segs))
    ang = np.tile(np.concatenate([[0.0], 2 * np.pi * np.arange(around) / max(around, 1)]), levels * len(segs))
    is_ell = np.asarray([kinds[s] == SHAPE_ELLIPSOID for s in seg], dtype=bool)
    dtype = model.shape_start.dtype
    a, b, ahat, L, e1, e2, ra, rb = _segment_geometry(model, seg)
    f = jnp.asarray(fr, dtype)
    u = jnp.asarray(np.cos(ang), dtype)[:, None] * e1 + jnp.asarray(np.sin(ang), dtype)[:, None] * e2
    z = 2.0 * f - 1.0
    radial = jnp.where(is_ell, ra * jnp.sqrt(1.0 - z * z), ra + f * (rb - ra)) * jnp.asarray(ring, dtype)
    axial = jnp.where(is_ell, 0.5 * L * (1.0 + z), f * L)
    local = a + axial[:, None] * ahat + radial[:, None] * u
    return FleshPoints(local, jnp.zeros_like(local), tuple(int(v) for v in seg))


# ---------------------------------------------------------------------------------------------------------------
# Occluding contours


def cone_contour_lines(
    a: jnp.ndarray, b: jnp.ndarray, r_a: jnp.ndarray, r_b: jnp.ndarray, centre: jnp.ndarray
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """The two silhouette generators of truncated cones seen from ``centre`` as segments ``start + s·step``,
    ``s ∈ [0, 1]``: ``start = a + r_a u_j``, ``step = L â + Δ u_j`` (``(C, 2, 3)`` each; see
    :func:`cone_contours`, which samples them). Eight vectors per cone instead of its ``2k`` points: the
    likelihood keeps these for all particles and samples the points where it projects them."""
    ahat, L = axis_length(a, b)
    e1, _ = orthonormal_basis(ahat)
    d = centre - a
    dpar = _dot(d, ahat)
    dperp = d - dpar[:, None] * ahat
    rho, ok = _safe_norm(dperp)
    dhat = jnp.where(ok[:, None], dperp / rho[:, None], e1)
    side = _cross(ahat, dhat)
    delta = r_b - r_a
    Ls = jnp.where(L > 0, L, 1.0)
    gamma = jnp.clip((r_a + jnp.where(L > 0, delta / Ls, 0.0) * dpar) / rho, -1.0, 1.0)
    sin_g = jnp.sqrt(jnp.maximum(1.0 - gamma * gamma, 1e-12))
    u = jnp.stack(
        [gamma[:, None] * dhat + sin_g[:, None] * side, gamma[:, None] * dhat - sin_g[:, None] * side], 1
    )  # (C, 2, 3)
    start = a[:, None, :] + r_a[:, None, None] * u
    step = (L[:, None] * ahat)[:, None, :] + delta[:, None, None] * u
    return start, step


def contour_line_points(start: jnp.ndarray, step: jnp.ndarray, k: int) -> jnp.ndarray:
    """``k`` points ``start + s_i step``, ``s_i = i/(k−1)`` (``s = 0`` for ``k = 1``) on each segment:
    ``(..., 3)`` → ``(..., k, 3)``."""
    s = jnp.linspace(0.0, 1.0, k, dtype=start.dtype) if k > 1 else jnp.zeros((1,), start.dtype)
    return start[..., None, :] + s[:, None] * step[..., None, :]


@functools.partial(jax.jit, static_argnames="k")
def cone_contours(
    a: jnp.ndarray, b: jnp.ndarray, r_a: jnp.ndarray, r_b: jnp.ndarray, centre: jnp.ndarray, k: int
) -> jnp.ndarray:
    """The two silhouette generators of truncated cones seen from ``centre``, ``k`` points on each.

    Args:
      a, b: ``(C, 3)`` axis end points; r_a, r_b: ``(C,)`` radii; centre: ``(3,)`` camera centre; k: static.

    Returns:
      ``(C, 2, k, 3)``: ``[:, j, i] = a + s_i (b − a) + (r_a + s_i Δ) u_j``, ``s_i = i/(k−1)``, ``u_j = u±`` of the
      module docstring (generator 0 is ``u₊``: on the ``+â × d̂⊥`` side).
    """
    return contour_line_points(*cone_contour_lines(a, b, r_a, r_b, centre), k)


def ellipsoid_contour_frames(
    centre: jnp.ndarray, axes: jnp.ndarray, camera_centre: jnp.ndarray
) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """The occluding contour of ellipsoids as the ellipse ``c₀ + cos θ e₁ + sin θ e₂`` (``(E, 3)`` each; see
    :func:`ellipsoid_contours`): ``c₀ = centre + axes c'/|c'|²``, ``e_i = ρ axes f_i``."""
    y = _solve3(axes, camera_centre - centre)
    n2 = jnp.maximum(_dot(y, y), 1e-12)
    n = jnp.sqrt(n2)
    f1, f2 = orthonormal_basis(y / n[:, None])
    v = 1.0 - 1.0 / n2
    pos = v > 1e-12
    rho = jnp.where(pos, jnp.sqrt(jnp.where(pos, v, 1.0)), 0.0)

    def mul(
        w,
    ):  # axes @ w written out (a batched 3×3 product is a library call per particle on XLA's CPU backend)
        return sum(axes[..., :, j] * w[..., j, None] for j in range(3))

    return centre + mul(y / n2[:, None]), mul(rho[:, None] * f1), mul(rho[:, None] * f2)


def ellipse_points(c0: jnp.ndarray, e1: jnp.ndarray, e2: jnp.ndarray, k: int) -> jnp.ndarray:
    """``k`` points ``c₀ + cos θ_i e₁ + sin θ_i e₂``, ``θ_i = 2π i/k``: ``(..., 3)`` → ``(..., k, 3)``."""
    th = 2.0 * jnp.pi * jnp.arange(k, dtype=c0.dtype) / k
    return (
        c0[..., None, :] + jnp.cos(th)[:, None] * e1[..., None, :] + jnp.sin(th)[:, None] * e2[..., None, :]
    )


@functools.partial(jax.jit, static_argnames="k")
def ellipsoid_contours(
    centre: jnp.ndarray, axes: jnp.ndarray, camera_centre: jnp.ndarray, k: int
) -> jnp.ndarray:
    """Occluding contour of ellipsoids ``x = centre + axes @ y, |y| = 1`` seen from ``camera_centre``.

    Args:
      centre: ``(E, 3)``; axes: ``(E, 3, 3)``; camera_centre: ``(3,)``; k: static number of points.

    Returns:
      ``(E, k, 3)`` points ``centre + axes @ (c'/|c'|² + ρ (cos θ_i f₁ + sin θ_i f₂))``, ``θ_i = 2π i/k``, with
      ``c' = axes⁻¹ (camera_centre − centre)``, ``ρ = √(1 − 1/|c'|²)`` and ``f₁, f₂ ⟂ c'`` (polar plane of ``c'``).
    """
    return ellipse_points(*ellipsoid_contour_frames(centre, axes, camera_centre), k)


@functools.partial(jax.jit, static_argnames="k")
def contour_points(
    model: BodyModel, R: jnp.ndarray, t: jnp.ndarray, camera_centre: jnp.ndarray, k: int
) -> jnp.ndarray:
    """Occluding-contour points of the model's cones for one particle and one camera centre.

    ``R (S,3,3)``, ``t (S,3)`` from :func:`jaxmocap.geometry.body.segment_poses`; ``camera_centre (3,)``; ``k`` static.
    Returns ``(S_cones, 2, k, 3)`` world points (cones in :func:`cone_segments` order). vmap over particles/views.
    """
    p = world_primitives(model, R, t)
    return cone_contours(p.cone_a, p.cone_b, p.r_a, p.r_b, camera_centre, k)


@functools.partial(jax.jit, static_argnames="k")
def ellipse_contour_points(
    model: BodyModel, R: jnp.ndarray, t: jnp.ndarray, camera_centre: jnp.ndarray, k: int
) -> jnp.ndarray:
    """Occluding-contour points of the model's ellipsoids (the head): ``(S_ellipsoids, k, 3)`` world points."""
    p = world_primitives(model, R, t)
    return ellipsoid_contours(p.ell_centre, p.ell_axes, camera_centre, k)


# ---------------------------------------------------------------------------------------------------------------
# Silhouette test


def _in_triangle(x, y, p0, p1, p2):
    """Point ``(x, y)`` in the closed triangle ``p0 p1 p2`` (either orientation). Broadcasts."""

    def side(pa, pb):
        return (pb[..., 0] - pa[..., 0]) * (y - pa[..., 1]) - (pb[..., 1] - pa[..., 1]) * (x - pa[..., 0])

    s0, s1, s2 = side(p0, p1), side(p1, p2), side(p2, p0)
    return ((s0 >= 0) & (s1 >= 0) & (s2 >= 0)) | ((s0 <= 0) & (s1 <= 0) & (s2 <= 0))


@jax.jit
def inside_per_primitive(prims: Primitives, K: jnp.ndarray, R: jnp.ndarray, t: jnp.ndarray, uv: jnp.ndarray):
    """Whether pixel samples fall inside the projected silhouette of each primitive (pinhole camera).

    For the thesis' foreground-divergence cue. Camera ``x_cam = R x + t``, intrinsics ``K``; pixel samples
    ``uv (M, 2)`` (undistort them first, e.g. ``cv2.undistortPoints(..., P=K)``, when the lens distorts).

    A flat-capped truncated cone is convex, so its image is the convex hull of its two projected cap discs. The
    test is the union of

    * the convex hull of the four projected end points of the two contour generators (union of the four
      triangles on them, so their order does not matter) — the "quad" between the silhouette lines, and
    * the two cap discs, tested exactly by intersecting the pixel's ray with each cap plane.

    The contour generators touch both cap circles and are tangent to their images, so the union equals the true
    silhouette whenever the generators exist (the camera outside the cone's tangent cone); inside it (looking
    down the axis) the generators are clamped onto the caps and the union of the cap discs remains. A cone that
    crosses the camera plane keeps only its cap-disc part. Ellipsoids are exact: the ray meets the ellipsoid in
    front of the camera (non-negative discriminant, far root positive).

    Returns:
      ``(C + E, M)`` bool, cones first.
    """
    pc = prims.transformed(R, t)
    Kinv = jnp.linalg.inv(K)
    x = Kinv[0, 0] * uv[:, 0] + Kinv[0, 1] * uv[:, 1] + Kinv[0, 2]
    y = Kinv[1, 0] * uv[:, 0] + Kinv[1, 1] * uv[:, 1] + Kinv[1, 2]
    w = Kinv[2, 0] * uv[:, 0] + Kinv[2, 1] * uv[:, 1] + Kinv[2, 2]
    x, y = x / w, y / w
    out = []
    if pc.num_cones:
        g = cone_contours(pc.cone_a, pc.cone_b, pc.r_a, pc.r_b, jnp.zeros(3, pc.cone_a.dtype), 2)  # (C,2,2,3)
        g = g.reshape(-1, 4, 3)
        front = jnp.all(g[..., 2] > 1e-6, axis=-1)  # (C,)
        zs = jnp.where(g[..., 2:3] > 1e-6, g[..., 2:3], 1.0)
        q = (g[..., :2] / zs)[:, :, None, :]  # (C, 4, 1, 2)
        xx, yy = x[None, :], y[None, :]
        hull = (
            _in_triangle(xx, yy, q[:, 0], q[:, 1], q[:, 2])
            | _in_triangle(xx, yy, q[:, 0], q[:, 1], q[:, 3])
            | _in_triangle(xx, yy, q[:, 0], q[:, 2], q[:, 3])
            | _in_triangle(xx, yy, q[:, 1], q[:, 2], q[:, 3])
        ) & front[:, None]
        ahat, _ = axis_length(pc.cone_a, pc.cone_b)
        dz = ahat[:, 0:1] * xx + ahat[:, 1:2] * yy + ahat[:, 2:3]  # ray d = (x, y, 1)
        dz_safe = jnp.where(jnp.abs(dz) > 1e-12, dz, 1e-12)

        def disc(centre, r):
            tt = _dot(centre, ahat)[:, None] / dz_safe
            px = tt * xx - centre[:, 0:1]
            py = tt * yy - centre[:, 1:2]
            pz = tt - centre[:, 2:3]
            return (tt > 0) & (px * px + py * py + pz * pz <= (r * r)[:, None])

        out.append(hull | disc(pc.cone_a, pc.r_a) | disc(pc.cone_b, pc.r_b))
    if pc.num_ellipsoids:
        Minv = jnp.linalg.inv(pc.ell_axes)  # (E,3,3)
        o = -jnp.einsum("eij,ej->ei", Minv, pc.ell_centre)
        d = Minv[:, :, 0, None] * x[None, None] + Minv[:, :, 1, None] * y[None, None] + Minv[:, :, 2, None]
        A = jnp.sum(d * d, axis=1)
        bb = jnp.sum(o[:, :, None] * d, axis=1)
        cr = _cross(o[:, None, :], jnp.moveaxis(d, 1, -1))
        disc_ = A - _dot(cr, cr)
        far = -bb + jnp.sqrt(jnp.maximum(disc_, 0.0))
        out.append((disc_ >= 0) & (far > 0))
    return jnp.concatenate(out, axis=0)


@jax.jit
def inside_projected(prims: Primitives, K: jnp.ndarray, R: jnp.ndarray, t: jnp.ndarray, uv: jnp.ndarray):
    """``(M,)`` bool: pixel samples inside the projected silhouette of any limb (see :func:`inside_per_primitive`)."""
    return jnp.any(inside_per_primitive(prims, K, R, t, uv), axis=0)
