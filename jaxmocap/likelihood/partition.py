"""A likelihood restricted to the body parts of one partition, by data (Li & Kulić: each partition of the
partitioned filter is weighed with the cues of its own body parts).

A partitioned likelihood is built from a ``(K, S)`` table ``A`` of per-partition, per-segment weights (1 for a
body part of partition ``k``, 0 otherwise; :func:`segment_table`), spread once over the samples
(:func:`sample_tables`) so that partition ``k`` (a Python int or a traced int32: one compiled likelihood serves
every partition) reads one row per sample set (:func:`part_weights`):

* a flesh-surface point ``p`` on segment ``s(p)``: ``a_p = A[k, s(p)]``;
* an occluding-contour point ``q`` of primitive ``s(q)``: ``a_q = A[k, s(q)]``;
* an evaluation joint ``j``: ``A[k, s(j)]`` with ``s(j)`` the segment whose pose places the joint — the joint's own
  segment when it lies away from that segment's origin (wrists, ankles, the head centre, the thorax), else the
  parent segment (a shoulder, elbow, hip or knee sits at its segment's origin, which the parent's DOFs move; the
  root joint stays on the root segment).

A cue that honours the weights (``CueSpec.partial``: foreground, edges, edge distance and fraction, depth,
colour template, keypoints, wrist bands, ground) replaces its mean over samples by the weighted mean
``Σ_p a_p e_p / Σ_p a_p`` (Li & Kulić eq. 1–3: sums over "the body parts in this partition"), and a joint cue
multiplies each joint's term by its weight (the ground term of a partition without an ankle is 0); the others
are evaluated over the whole body in every partition. Without a table the cues run unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp
import numpy as np

from jaxmocap.geometry import flesh
from jaxmocap.likelihood.cue_context import PartWeights

__all__ = [
    "PartWeights",
    "contour_segments",
    "joint_segments",
    "part_weights",
    "sample_tables",
    "segment_table",
]


def segment_table(model, parts: Sequence[Sequence[str | int]]) -> np.ndarray:
    """``(K, S)`` float32 table: row ``k`` is 1 on the segments of ``parts[k]`` (names or indices), else 0."""
    names = model.segment_names
    table = np.zeros((len(parts), len(names)), np.float32)
    for k, segs in enumerate(parts):
        for s in segs:
            if isinstance(s, str):
                if s not in names:
                    raise ValueError(f"unknown segment {s!r}; {model.name} has {', '.join(names)}")
                s = names.index(s)
            table[k, int(s)] = 1.0
    if not np.all(table.sum(axis=1) > 0):
        raise ValueError("every partition needs at least one body part")
    return table


def contour_segments(model, contour_points: int) -> np.ndarray:
    """``(Q,)`` segment of each occluding-contour point, in the order the likelihood samples them: ``2k`` points
    per cone (two generators), then ``2k`` on each ellipsoid's outline (``k = contour_points``)."""
    per = 2 * int(contour_points)
    segs = list(flesh.cone_segments(model)) + list(flesh.ellipsoid_segments(model))
    return np.repeat(np.asarray(segs, np.int32), per)


def joint_segments(model) -> np.ndarray:
    """``(J,)`` segment whose pose places each evaluation joint (module docstring)."""
    parents = model.topology.parents
    point = np.asarray(model.joint_point, np.float64)
    out = []
    for j, s in enumerate(model.joint_segment):
        at_origin = float(np.linalg.norm(point[j])) < 1e-9
        out.append(parents[s] if at_origin and parents[s] >= 0 else s)
    return np.asarray(out, np.int32)


def sample_tables(model, table: np.ndarray, surface_segment, contour_points: int) -> PartWeights:
    """The ``(K, S)`` segment ``table`` spread over the samples (host side, once): :class:`PartWeights` of
    ``(K, P)``, ``(K, Q)`` and ``(K, J)`` tables; row ``k`` is partition ``k``'s sample weights."""
    table = np.asarray(table, np.float32)
    return PartWeights(
        table[:, np.asarray(surface_segment, np.int32)],
        table[:, contour_segments(model, contour_points)],
        table[:, joint_segments(model)],
    )


def part_weights(tables: PartWeights, partition) -> PartWeights:
    """Row ``partition`` (an int or a traced int32) of each of :func:`sample_tables`' tables."""
    return PartWeights(*(jnp.asarray(t)[partition] for t in tables))
