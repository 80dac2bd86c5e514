"""The filters by name: :func:`make_filter` builds any of :data:`FILTERS` around a body model, with the DOF groups
of partitioned / hierarchical sampling (:func:`partition_groups`) and per-partition particle counts
(:func:`partition_counts`).

Every filter receives the one likelihood signature ``loglik(X (N, D), observation, layer) -> (N,)``, ``layer`` a
:class:`jaxmocap.filters.base.Layer`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from jaxmocap.choices import ANNEALED, FILTERS, GRADIENT_FILTERS, PARTITIONED
from jaxmocap.filters.annealing import Schedule
from jaxmocap.filters.apf import APF
from jaxmocap.filters.hybrid import GradientMove, HybridAPF
from jaxmocap.filters.icondensation import ICondensation
from jaxmocap.filters.partitioned import Partitioned, hierarchical
from jaxmocap.filters.sir import SIR
from jaxmocap.geometry import body as body_mod
from jaxmocap.transfer import to_device

__all__ = [
    "ANNEALED",
    "FILTERS",
    "GRADIENT_FILTERS",
    "HYBRID_MOVE",
    "PARTITIONED",
    "make_filter",
    "partition_counts",
    "partition_groups",
    "particles_text",
]

#: The gradient move of ``--filter hybrid``: S = 3 normalised steps of one diffusion std on the k = 5 best distinct
#: particles per layer (the configuration of ``benchmarks/results/hybrid_vs_apf.md``).
HYBRID_MOVE = dict(steps=3, learning_rate=1.0, optimizer="normalised", best_k=5)


def partition_groups(model: body_mod.BodyModel) -> tuple[tuple[int, ...], ...]:
    """DOF groups for partitioned / hierarchical sampling: the trunk's DOFs first
    (:func:`jaxmocap.geometry.body.trunk_segments`: the root's, with ``full32``'s spine), then one group per branch
    hanging from the trunk (head, each arm with its girdle, each leg), in segment order; empty groups left out."""
    topo = model.topology
    trunk = set(body_mod.trunk_segments(model))
    top = []  # the branch (its first segment) each segment belongs to; -1 on the trunk
    for s, p in enumerate(topo.parents):
        if s in trunk:
            top.append(-1)
        elif p in trunk:
            top.append(s)
        else:
            top.append(top[p])
    groups = [tuple(d for s in sorted(trunk) for d in topo.segment_dofs[s])]
    for c in [s for s in range(len(top)) if top[s] == s]:
        g = tuple(d for s in range(len(top)) if top[s] == c for d in topo.segment_dofs[s])
        if g:
            groups.append(g)
    return tuple(g for g in groups if g)


def partition_counts(
    model: body_mod.BodyModel,
    filter_name: str,
    num_particles: int | Sequence[int],
    groups: Sequence[Sequence[int]] | None = None,
) -> tuple[int, ...] | int:
    """Particle counts of ``filter_name``: for partitioned / hierarchical sampling one count per group of
    ``groups`` (default :func:`partition_groups`; an int is used for every group), else the int itself. Raises
    ``ValueError`` for a sequence given to another filter, a sequence of the wrong length, or a count below 2."""
    groups = partition_groups(model) if groups is None else tuple(tuple(g) for g in groups)
    if isinstance(num_particles, (int, np.integer)):
        n = int(num_particles)
        if n < 2:
            raise ValueError("--particles must be at least 2")
        if filter_name not in PARTITIONED:
            return n
        return (n,) * len(groups)
    counts = tuple(int(c) for c in num_particles)
    if filter_name not in PARTITIONED:
        raise ValueError(
            f"one particle count per partition is for the partitioned / hierarchical filters, not {filter_name!r}"
        )
    if len(counts) != len(groups):
        names = ", ".join(_group_label(model, g) for g in groups)
        raise ValueError(
            f"{model.name} has {len(groups)} partitions ({names}): give {len(groups)} particle counts, "
            f"got {len(counts)}"
        )
    if min(counts) < 2:
        raise ValueError("--particles must be at least 2 in every partition")
    return counts


def particles_text(particles: int | Sequence[int]) -> str:
    """``300`` → ``"300"``; one count per partition ``[1000, 200, 350]`` → ``"1000/200/350"``."""
    return "/".join(map(str, particles)) if isinstance(particles, (list, tuple)) else str(particles)


def _group_label(model: body_mod.BodyModel, group: tuple[int, ...]) -> str:
    """The name of the segment that owns the first DOF of ``group``."""
    topo = model.topology
    seg = next(s for s, dofs in enumerate(topo.segment_dofs) if group[0] in dofs)
    return model.segment_names[seg]


def _proposal_centre(observation):
    """The detection-driven proposal centre of an observation and whether it is valid (one function for every
    filter built here, so that filters built twice have the same structure)."""
    return observation.centre, observation.valid


def make_filter(
    name: str,
    loglik: Callable,
    model: body_mod.BodyModel,
    std: np.ndarray,
    num_particles: int | Sequence[int],
    num_layers: int,
    prior_mean: np.ndarray,
    prior_std: np.ndarray,
    survival_target: float = 0.5,
    groups: Sequence[Sequence[int]] | None = None,
    keep_layers: bool = False,
    annealing: Schedule | None = None,
    importance: dict | None = None,
):
    """Filter ``name`` (:data:`FILTERS`) on ``loglik(X, observation, layer) -> (N,)``.

    ``std (D,)``: diffusion per frame; the annealed filters shrink it over the layers by ``s_l = 0.25^{l/(L−1)}``
    and choose β by Deutscher's survival-rate rule (``survival_target``), except ``m-apf`` (the thesis' single correction,
    :func:`jaxmocap.filters.annealing.corrected_beta`). ``fbapf*`` differ from ``apf`` only in the likelihood's per-layer
    cue weights (built by the caller). ``icondensation`` / ``iapf`` draw part of their particles around
    ``observation.centre`` (when ``observation.valid``) and from the prior ``N(prior_mean, prior_std²)``.
    ``partitioned`` / ``hierarchical`` split the DOFs by ``groups`` (default :func:`partition_groups`; a preset's
    partitions, :mod:`jaxmocap.tracking.presets`) in that order; ``num_particles`` is one count
    for every partition or a sequence of one count per partition (Li & Kulić on ``full25``: torso 1000, head 200,
    each arm and leg 350; the other filters take an int). ``hybrid`` is the APF with
    gradient moves (:data:`HYBRID_MOVE`) and ``apf-refine`` the APF whose estimate is refined by gradient ascent
    (:class:`jaxmocap.filters.hybrid.HybridAPF`); both need ``loglik`` differentiable in ``X``. ``keep_layers``:
    the APF-based filters (``apf``, ``iapf``, ``fbapf*``, ``m-apf``) return each layer's weighted set in
    ``Info.layer_sets`` (the others ignore it).

    ``annealing``: a schedule replacing the one above for ``apf`` / ``iapf`` (e.g.
    :meth:`~jaxmocap.filters.annealing.Schedule.iros2007`; its layer count must be ``num_layers``);
    ``importance``: fields of :class:`~jaxmocap.filters.icondensation.ImportanceOptions`
    (``dynamics_fraction``, ``detection_fraction``) for ``icondensation`` / ``iapf``.
    """
    if name not in FILTERS:
        raise ValueError(f"unknown filter {name!r}; choose one of {', '.join(FILTERS)}")
    counts = partition_counts(model, name, num_particles, groups)
    groups = partition_groups(model) if groups is None else tuple(tuple(int(i) for i in g) for g in groups)
    dt = model.offset.dtype
    std = to_device(std, dt)
    span = np.asarray(model.upper) - np.asarray(model.lower)
    circular = tuple(bool(a and s >= 2 * math.pi - 1e-3) for a, s in zip(model.angular, span, strict=True))
    common = dict(lower=model.lower, upper=model.upper, circular=circular)
    L = int(num_layers)
    scales = tuple(0.25 ** (l / (L - 1)) for l in range(L)) if L > 1 else (1.0,)
    centre = _proposal_centre
    prior = dict(prior_mean=to_device(prior_mean, dt), prior_std=to_device(prior_std, dt))
    prior.update(importance or {})
    if annealing is not None and annealing.num_layers != L:
        raise ValueError(f"the annealing schedule has {annealing.num_layers} layers, the filter {L}")
    if name == "sir":
        return SIR(loglik, std, num_particles, **common)
    if name == "icondensation":
        return ICondensation(
            loglik,
            std,
            num_particles=num_particles,
            proposal_centre=centre,
            **prior,
            **common,
        )
    # the partitions run as one lax.scan (the likelihood compiled once; unequal counts through a padded buffer,
    # jaxmocap.filters.partitioned): full25 with Li & Kulić's counts compiles in a third of the CPU time of the
    # unrolled step, at no loss of step time (benchmarks/results/compile_time.md)
    if name == "partitioned":
        return Partitioned(loglik, std, groups, counts, scan_partitions=True, **common)
    if name == "hierarchical":
        sched = Schedule.deutscher(L, survival_target, diffusion_scales=scales)
        return hierarchical(loglik, std, groups, counts, sched, scan_partitions=True, **common)
    if name == "m-apf":
        sched = Schedule(
            kind="corrected", num_layers=L, diffusion_scales=scales, survival_target=survival_target
        )
    else:
        sched = Schedule.deutscher(L, survival_target, diffusion_scales=scales)
    if annealing is not None:
        sched = annealing
    if name == "iapf":
        return APF(
            loglik,
            std,
            num_particles,
            sched,
            first_layer="icondensation",
            proposal_centre=centre,
            keep_layers=keep_layers,
            **prior,
            **common,
        )
    if name in GRADIENT_FILTERS:
        if name == "apf-refine":
            return HybridAPF.refined(loglik, std, num_particles, sched, **common)
        move = GradientMove(**{**HYBRID_MOVE, "best_k": min(HYBRID_MOVE["best_k"], num_particles)})
        return HybridAPF(loglik, std, num_particles, sched, move=move, **common)
    return APF(loglik, std, num_particles, sched, keep_layers=keep_layers, **common)
