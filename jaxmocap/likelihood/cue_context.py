"""What a cue reads besides the observation: the projected geometry of one particle (:class:`Geometry`), the
cue's context (:class:`CueContext`), and the sample lookups the cue modules share (map values at the surface and
contour samples, a segment's run of surface points, joint indices, masked means).

Shapes: ``V`` views, ``P`` flesh surface points, ``Q`` occluding-contour points, ``J`` evaluation joints.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxmocap.geometry import flesh
from jaxmocap.likelihood import maps


class Geometry(NamedTuple):
    """Projected geometry of one particle (fields a configuration does not need are ``None``).

    joints ``(J, 3)`` world evaluation joints; joints_uv ``(V, J, 2)``;
    surface ``(P, 3)`` world flesh points; surface_uv ``(V, P, 2)``; surface_depth ``(V, P)`` camera z;
    surface_facing ``(V, P)`` bool: outward normal faces the camera (and the point is in front of it);
    surface_index, surface_inside ``(V, P)``: nearest-pixel flat index into the ``(V, H, W)`` maps and the
    in-image mask (:func:`jaxmocap.likelihood.maps.nearest_index`), shared by every nearest-pixel surface cue;
    surface_visible_index ``(V, P)``: the same index where the sample faces the camera and lies in the image, else
    the sentinel ``V·H·W`` (:func:`jaxmocap.likelihood.maps.visible_index`): one gather from a map with a sentinel entry
    returns the value and the visibility together;
    contour_uv ``(V, Q, 2)`` occluding-contour points of the primitives seen from each camera;
    contour_index, contour_inside ``(V, Q)`` likewise;
    primitives: :class:`jaxmocap.geometry.flesh.Primitives` in the world frame.
    """

    joints: jnp.ndarray | None = None
    joints_uv: jnp.ndarray | None = None
    surface: jnp.ndarray | None = None
    surface_uv: jnp.ndarray | None = None
    surface_depth: jnp.ndarray | None = None
    surface_facing: jnp.ndarray | None = None
    surface_index: jnp.ndarray | None = None
    surface_inside: jnp.ndarray | None = None
    surface_visible_index: jnp.ndarray | None = None
    contour_uv: jnp.ndarray | None = None
    contour_index: jnp.ndarray | None = None
    contour_inside: jnp.ndarray | None = None
    primitives: flesh.Primitives | None = None


class PartWeights(NamedTuple):
    """Sample weights of one partition (:mod:`jaxmocap.likelihood.partition`): ``surface (P,)``, ``contour (Q,)``,
    ``joints (J,)``, each 1 on the partition's body parts and 0 elsewhere."""

    surface: jnp.ndarray
    contour: jnp.ndarray
    joints: jnp.ndarray


class CueContext(NamedTuple):
    """What a cue may read besides geometry and observation.

    Static: ``joint_names``, ``params`` (the cue's parameters), ``rig``, ``model`` (the body model),
    ``surface_segment`` (segment of each surface point). Per call: ``aux`` (the cue's ``prepare`` result) and
    ``ref`` (the reference data the likelihood holds for this cue: colour histograms or templates of the first
    frame, see :meth:`jaxmocap.likelihood.compose.Likelihood.with_references`); ``part``: the sample weights of the
    partition being weighed (:class:`PartWeights`), None for the whole body.
    """

    joint_names: tuple[str, ...]
    params: dict
    rig: object
    model: object = None
    surface_segment: tuple[int, ...] = ()
    aux: object = None
    ref: object = None
    part: PartWeights | None = None


def _unit_scale(a: jnp.ndarray) -> float:
    """Scale that maps a stored unit map to [0, 1] (``uint8`` maps store ``round(255·p)``)."""
    return 1.0 / 255.0 if a.dtype == jnp.uint8 else 1.0


def _map_values(obs_map, uv, index, inside, ctx: CueContext, unit: bool):
    """``(values (V, P), inside (V, P))`` of a ``(V, H, W)`` map at one sample set: bilinear at the pixels
    ``uv (V, P, 2)`` when the cue has ``bilinear=True``, else at the shared nearest-pixel ``index (V, P)`` with its
    ``inside`` mask; ``unit`` maps a stored unit map to [0, 1] (:func:`_unit_scale`)."""
    s = _unit_scale(obs_map) if unit else 1.0
    if ctx.params.get("bilinear", False):
        i00, fu, fv, inside = maps.bilinear_index(uv, obs_map.shape)
        return maps.gather_bilinear(obs_map, i00, fu, fv, s), inside
    return maps.gather(obs_map, index, s), inside


def _surface_values(obs_map, g: Geometry, ctx: CueContext, unit: bool = True, points: slice = slice(None)):
    """:func:`_map_values` at the surface points ``points`` (a static slice, default all; the nearest-pixel
    fields may be absent when the cue reads bilinearly)."""
    pick = lambda a: None if a is None else a[:, points]
    return _map_values(obs_map, pick(g.surface_uv), pick(g.surface_index), pick(g.surface_inside), ctx, unit)


def _contour_values(obs_map, g: Geometry, ctx: CueContext, unit: bool = True):
    """:func:`_map_values` at the occluding-contour points."""
    return _map_values(obs_map, g.contour_uv, g.contour_index, g.contour_inside, ctx, unit)


def _segment_points(ctx: CueContext, segment: int) -> slice:
    """The static slice of surface points on ``segment`` (points are stored segment by segment)."""
    seg = np.asarray(ctx.surface_segment)
    where = np.flatnonzero(seg == segment)
    if where.size == 0:
        raise ValueError(f"segment {ctx.model.segment_names[segment]!r} has no surface points")
    return slice(int(where[0]), int(where[-1]) + 1)


def _segment_ids(ctx: CueContext, names, default: str) -> tuple[int, ...]:
    """Segment indices of ``names`` (or of the default set: ``"fleshed"`` = every segment with surface points,
    ``"limbs"`` = those but the head)."""
    segs = ctx.model.segment_names
    have = sorted(set(ctx.surface_segment))
    if names is None:
        out = [s for s in have if not (default == "limbs" and segs[s] == "head")]
    else:
        unknown = [n for n in names if n not in segs]
        if unknown:
            raise ValueError(f"unknown segments {unknown}; the model has {segs}")
        out = [segs.index(n) for n in names]
    return tuple(out)


def _joint_index(ctx: CueContext, names) -> np.ndarray:
    missing = [j for j in names if j not in ctx.joint_names]
    if missing:
        raise ValueError(f"the model has no joints {missing}; it has {ctx.joint_names}")
    return np.asarray([ctx.joint_names.index(j) for j in names])


def _part_mean(values, ctx: CueContext, field: str, axis=-1):
    """``mean(values, axis)`` over the samples, or with a partition the weighted mean ``Σ a e / Σ a`` with the
    partition's weights ``ctx.part.<field>`` (0 when the partition has none of these samples)."""
    if ctx.part is None:
        return jnp.mean(values, axis=axis)
    a = getattr(ctx.part, field).astype(values.dtype)
    return jnp.sum(values * a, axis=axis) / jnp.maximum(jnp.sum(a), 1e-12)


def _weighted_mean(values, w, axis=-1, empty=0.0):
    s = jnp.sum(w, axis=axis)
    return jnp.where(s > 0, jnp.sum(values * w, axis=axis) / jnp.maximum(s, 1e-12), empty)
