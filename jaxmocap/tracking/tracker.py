"""The high-level tracking loop: a calibrated multi-view sequence in, poses out.

Pieces, in the order a frame goes through them:

* **sources** — :class:`SequenceSource` (a sequence folder, :mod:`jaxmocap.io.sequence`) and :class:`VideoSource`
  (synchronised videos + a calibration, optional OpenPose keypoint folders and depth-map folders) give, per frame,
  the BGR images of every view, optional foreground masks, depth maps (metres) and 2D keypoints
  (:class:`FrameData`) from ``read(t, masks=True, depth=True)``; the tracker asks only for the masks and depth
  maps its features use (decoding two unused PNGs per view cost 7–8 ms per 640×480 stereo frame). A frame that
  cannot be read raises :class:`BadFrame` (skipped with a warning or fatal, by option); everything else that is
  wrong with the input raises :class:`~jaxmocap.errors.MocapInputError`.
* **features** — :class:`FeatureBuilder` runs :class:`jaxmocap.features.FeatureExtractor` (foreground from the
  sequence's masks, a median background, MOG2 or none; edges; distance transform; depth; the colour map, skin
  probability and triangulated skin blobs when a cue reads them) and adds what the tracker itself uses: silhouette
  samples for the coverage term and the detection-driven proposal centre (:class:`TrackObservation`). The colour
  cues' references (ROI histograms, colour templates) come from the first tracked frame at the initial pose.
* **likelihood** — :class:`jaxmocap.likelihood.compose.Likelihood` over the image cues, plus the tracker's **coverage**
  term (:func:`coverage_energy`): the model-on-silhouette cues (``foreground``, Li & Kulić's ``depth``) do not
  penalise a limb hidden in front of the torso, so ``M`` samples of the observed silhouette per view must each be
  covered by some projected limb. Its energy is ``E_v = (1/M) Σ_m min(d_m / d_max, 1)`` with ``d_m`` the distance
  from sample ``m`` to the nearest projected flesh capsule (axis segment minus the projected radius ``f r / z``,
  clipped at 0), a cheap stand-in for López Méndez's foreground divergence (eq. 4.6).
* **filter** — :func:`make_filter` builds any of :data:`FILTERS` (SIR, ICONDENSATION, APF, IAPF, partitioned,
  hierarchical, the feature-based annealing variants FBAPF/FBAPF2/FBAPF3 and the thesis' M-APF) with per-model
  defaults (:func:`default_particles`, :func:`default_layers`, :func:`diffusion_std`, :func:`default_cues`). Its
  ``step`` is jitted **once**; every frame reuses the compilation (``Tracker.trace_count`` stays 1).
* **loop** — :class:`Tracker`: per frame, the key is ``fold_in(key(seed), frame)`` (never carried), so that a
  resumed run reproduces an uninterrupted one; a damped constant-velocity prediction of the root translation,
  the filter step, track-loss detection and re-initialisation, and incremental outputs
  (:mod:`jaxmocap.io.export`) with a resume checkpoint (``resume.npz``) after each frame.

**Track loss.** ``q_t = −max_i log p(z | x_i)`` of the last layer (the energy of the best particle) is compared
with its median ``q_ref`` over the first frames after the initialisation: the track is lost when
``q_t > loss_ratio · q_ref`` for ``loss_frames`` consecutive frames, when the filter found no finite weight
(``Info.recovered``), or when no view shows any foreground (no person). The filter is then re-initialised around a
detection: the IK fit of the triangulated 2D keypoints when there are keypoints, else the last good estimate with
its root moved over the triangulated silhouette centroid, with ``reinit_widen`` times the diffusion spread. Every
frame's record in ``diagnostics.json`` has ``quality``, ``lost``, ``reinitialised`` and ``reinit_source``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pathlib
import sys
import time
from collections.abc import Callable, Sequence
from typing import NamedTuple

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.features.observation import Observation
from jaxmocap.features.pipeline import FeatureConfig, FeatureExtractor
from jaxmocap.features.resample import downsample as downsample_image
from jaxmocap.filters import APF, SIR, ICondensation, Partitioned, hierarchical
from jaxmocap.filters.annealing import Schedule
from jaxmocap.fit import ik
from jaxmocap.geometry import body as body_mod
from jaxmocap.geometry import camera
from jaxmocap.io import export
from jaxmocap.likelihood import compose as lk
from jaxmocap.likelihood import cues as cues_mod

__all__ = [
    "FILTERS",
    "MODELS",
    "FOREGROUNDS",
    "TRACKER_CUES",
    "BadFrame",
    "FeatureBuilder",
    "FrameData",
    "SequenceSource",
    "TrackObservation",
    "TrackOptions",
    "Tracker",
    "VideoSource",
    "build_model",
    "coverage_energy",
    "default_cues",
    "default_layers",
    "default_particles",
    "diffusion_std",
    "make_filter",
    "parse_cues",
    "partition_groups",
]

MODELS = ("upper9", "upper14", "full25", "parsec31")
FILTERS = (
    "sir",
    "icondensation",
    "apf",
    "iapf",
    "partitioned",
    "hierarchical",
    "fbapf",
    "fbapf2",
    "fbapf3",
    "m-apf",
    "hybrid",
    "apf-refine",
)
ANNEALED = ("apf", "iapf", "hierarchical", "fbapf", "fbapf2", "fbapf3", "m-apf", "hybrid", "apf-refine")
#: Filters that differentiate the likelihood (:mod:`jaxmocap.filters.hybrid`): their cues use bilinear lookups.
GRADIENT_FILTERS = ("hybrid", "apf-refine")
#: The gradient move of ``--filter hybrid``: S = 3 normalised steps of one diffusion std on the k = 5 best distinct
#: particles per layer (the configuration of ``benchmarks/results/hybrid_vs_apf.md``).
HYBRID_MOVE = dict(steps=3, learning_rate=1.0, optimizer="normalized", best_k=5)
FOREGROUNDS = ("auto", "mask", "median", "mog2", "none")
#: Cues computed by the tracker itself (besides :data:`jaxmocap.likelihood.cues.CUES`).
TRACKER_CUES = ("coverage",)
#: ``d_max`` of the coverage term as a fraction of the image width (at least one pixel): about one pixel, so that
#: a silhouette sample counts as uncovered as soon as it lies outside every projected limb, the mirror image of the
#: ``foreground`` cue (a model sample counts as soon as it lies outside the silhouette).
COVERAGE_DMAX = 0.004

#: OpenPose BODY_25B keypoint of each evaluation joint it measures (``thorax`` ≈ the upper neck).
KEYPOINT_OF = {
    "thorax": 17,
    "left_shoulder": 5,
    "right_shoulder": 6,
    "left_elbow": 7,
    "right_elbow": 8,
    "left_wrist": 9,
    "right_wrist": 10,
    "left_hip": 11,
    "right_hip": 12,
    "left_knee": 13,
    "right_knee": 14,
    "left_ankle": 15,
    "right_ankle": 16,
}


# ---------------------------------------------------------------------------------------------------------------
# Models and per-model defaults


def build_model(
    name: str | None, body_file: str | os.PathLike | None, fallback_body: os.PathLike | None = None
):
    """The body model to track with: preset ``name`` with the dimensions of ``body_file`` (or of the sequence's
    ``fallback_body``); without a name, the model the body file names (default ``full25``).

    ``parsec31`` is built in **metres** (its PARSEC shape scaled by 1/1000) so that it shares the calibration and
    cues of the other models.
    """
    path = body_file if body_file is not None else fallback_body
    dims: dict = {}
    file_model = None
    if path is not None:
        file_model, dims = body_mod.load_body_file(path)
    name = name or file_model or "full25"
    if name not in MODELS:
        raise ValueError(f"unknown model {name!r}; choose one of {', '.join(MODELS)}")
    if name == "parsec31":
        from jaxmocap.parsec import model as parsec

        shape = parsec.shape_from_dims(dims if file_model == "parsec31" else None)
        limbs = np.asarray(shape.limbs, np.float64).copy()
        limbs[:, :2] /= parsec.MM_PER_M
        shape = parsec.BodyShape(jnp.asarray(limbs), jnp.asarray(np.asarray(shape.lengths) / parsec.MM_PER_M))
        return parsec.parsec31(shape)
    if file_model == "parsec31":
        dims = {}
    try:
        return body_mod.build(name, dims)
    except (KeyError, ValueError) as e:
        raise MocapInputError(path, str(e)) from None


def diffusion_std(model: body_mod.BodyModel, fps: float = 30.0) -> np.ndarray:
    """Per-DOF random-walk standard deviation per frame ``(D,)``, chosen for walking-speed motion at 30 fps and
    scaled by ``30 / fps``: root translation 3 cm, root heading 0.06 rad, root tilt 0.04 rad, neck 0.06 rad,
    shoulders and hips 0.10 rad, elbows and knees 0.12 rad (other angles 0.08 rad)."""
    out = np.empty(model.num_dofs, np.float64)
    root = set(model.topology.segment_dofs[0])
    for d, (name, kind) in enumerate(zip(model.dof_names, model.topology.dof_kinds, strict=True)):
        if kind == "P":
            out[d] = 0.03
        elif d in root:
            out[d] = 0.06 if name.endswith("rz") else 0.04
        elif "neck" in name or "head" in name:
            out[d] = 0.06
        elif "elbow" in name or "knee" in name:
            out[d] = 0.12
        elif "shoulder" in name or "hip" in name:
            out[d] = 0.10
        else:
            out[d] = 0.08
    return (out * (30.0 / float(fps))).astype(np.float32)


def default_particles(model_name: str, filter_name: str) -> int:
    """Particles per layer (annealed filters) or in all (the others: as many likelihood evaluations per frame)."""
    base = {"upper9": 150, "upper14": 200, "full25": 300, "parsec31": 300}[model_name]
    if filter_name in ("sir", "icondensation"):
        return base * default_layers(filter_name)[1]
    if filter_name in ("partitioned", "hierarchical"):
        return max(base // 2, 50)
    return base


def default_layers(filter_name: str) -> tuple[int, int]:
    """``(layers of this filter, layers of the APF)``: 5 for the annealed filters, 2 per level for the
    hierarchical one, 1 for SIR / ICONDENSATION / partitioned sampling."""
    apf = 5
    if filter_name in ("sir", "icondensation", "partitioned"):
        return 1, apf
    if filter_name == "hierarchical":
        return 2, apf
    return apf, apf


def default_cues(model_name: str, has_depth: bool, has_keypoints: bool) -> tuple[tuple[str, float], ...]:
    """``(name, weight)`` of the default cues: silhouette (``foreground``), edges (``edge_distance``), the
    silhouette coverage term (weight 4: with a one-pixel ``d_max`` it balances the foreground cue's preference for a
    model that shrinks into the silhouette; chosen on the demo sequence, see ``benchmarks/results/demo_table.txt``),
    ``depth`` when the input has depth maps (full body only: Li & Kulić's cue), and the 2D ``keypoints`` when
    there are detections."""
    out = [("foreground", 1.0), ("edge_distance", 1.0), ("coverage", 4.0)]
    if has_depth and model_name == "full25":
        out.append(("depth", 1.0))
    if has_keypoints:
        out.append(("keypoints", 1.0))
    return tuple(out)


def parse_cues(spec: str | Sequence | None) -> tuple[tuple[str, float], ...] | None:
    """``"foreground,edge_distance:2,coverage"`` → ``(("foreground", 1.0), ("edge_distance", 2.0), …)``."""
    if spec is None:
        return None
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    out = []
    for it in items:
        if isinstance(it, tuple):
            name, w = it
        else:
            name, _, w = str(it).strip().partition(":")
            w = w or 1.0
        try:
            w = float(w)
        except ValueError:
            raise ValueError(f"cue weight of {name!r} must be a number, got {w!r}") from None
        if name not in cues_mod.CUES and name not in TRACKER_CUES:
            known = sorted([*cues_mod.CUES, *TRACKER_CUES])
            raise ValueError(f"unknown cue {name!r}; choose from {', '.join(known)}")
        if not (w > 0 and math.isfinite(w)):
            raise ValueError(f"cue weight of {name!r} must be positive, got {w}")
        out.append((name, w))
    if not out:
        raise ValueError("no cue given")
    return tuple(out)


def partition_groups(model: body_mod.BodyModel) -> tuple[tuple[int, ...], ...]:
    """DOF groups for partitioned / hierarchical sampling: the root segment's DOFs first, then one group per
    subtree hanging from the root (head, each arm, each leg), in segment order; empty groups left out."""
    topo = model.topology
    top = []  # the child of the root each segment descends from
    for s, p in enumerate(topo.parents):
        if p < 0:
            top.append(-1)
        elif topo.parents[p] < 0:
            top.append(s)
        else:
            top.append(top[p])
    groups = [tuple(topo.segment_dofs[0])]
    for c in [s for s in range(len(top)) if top[s] == s]:
        g = tuple(d for s in range(len(top)) if top[s] == c for d in topo.segment_dofs[s])
        if g:
            groups.append(g)
    return tuple(g for g in groups if g)


# ---------------------------------------------------------------------------------------------------------------
# The coverage term


class TrackObservation(NamedTuple):
    """What the filter step sees of one frame: the image ``Observation``, silhouette samples ``cover_uv (V, M, 2)``
    with weights ``cover_w (V, M)`` (0 = empty slot), and the proposal centre ``center (D,)`` with ``valid``."""

    image: Observation
    cover_uv: jnp.ndarray
    cover_w: jnp.ndarray
    center: jnp.ndarray
    valid: jnp.ndarray


def _capsules(model: body_mod.BodyModel, x: jnp.ndarray):
    """World capsules of the flesh: cones as they are, each ellipsoid as its polar axis with its equatorial
    radius. Returns ``a, b (S, 3)``, ``r_a, r_b (S,)``."""
    from jaxmocap.geometry import flesh

    R, t = body_mod.segment_poses(model, x)
    p = flesh.world_primitives(model, R, t)
    a, b, ra, rb = p.cone_a, p.cone_b, p.r_a, p.r_b
    if p.num_ellipsoids:
        polar = p.ell_axes[:, :, 2]
        r = jnp.sqrt(jnp.sum(p.ell_axes[:, :, 0] ** 2, axis=-1))
        a = jnp.concatenate([a, p.ell_centre - polar])
        b = jnp.concatenate([b, p.ell_centre + polar])
        ra = jnp.concatenate([ra, r])
        rb = jnp.concatenate([rb, r])
    return a, b, ra, rb


def coverage_energy(
    model: body_mod.BodyModel,
    rig: camera.Rig,
    x: jnp.ndarray,
    uv: jnp.ndarray,
    w: jnp.ndarray,
    d_max: jnp.ndarray,
) -> jnp.ndarray:
    """Silhouette coverage energy per view ``(V,)`` of one state ``x (D,)`` (module docstring).

    ``uv (V, M, 2)`` silhouette samples (pixels), ``w (V, M)`` their weights, ``d_max (V,)`` the distance (pixels)
    at which a sample counts as fully uncovered. For capsule ``s`` with projected axis ``a_s b_s`` and projected
    radii ``ρ = f_x r / z`` at its ends: ``d_m = max(0, min_s (‖u_m − (a_s + τ (b_s − a_s))‖ − ρ_s(τ)))`` with ``τ``
    the clamped foot of the perpendicular; ``E_v = Σ_m w_m min(d_m / d_max, 1) / max(Σ_m w_m, 1)``.
    """
    a, b, ra, rb = _capsules(model, x)
    ua, za = camera.project_with_depth(rig, a)  # (V, S, 2), (V, S)
    ub, zb = camera.project_with_depth(rig, b)
    f = rig.K[:, 0, 0][:, None]
    pa = (f * ra[None] / jnp.maximum(za, 1e-3))[..., None]  # (V, S, 1)
    pb = (f * rb[None] / jnp.maximum(zb, 1e-3))[..., None]
    # (V, S, M) arrays, one coordinate at a time: the samples on the minor axis and the minimum over capsules
    # across rows vectorise on a CPU (with (V, M, S, 2) and reductions over the short minor axes: 2× slower)
    ax, ay = ua[..., 0:1], ua[..., 1:2]
    dx, dy = ub[..., 0:1] - ax, ub[..., 1:2] - ay
    len2 = jnp.maximum(dx * dx + dy * dy, 1e-9)
    qx = uv[:, None, :, 0] - ax
    qy = uv[:, None, :, 1] - ay
    tau = jnp.clip((qx * dx + qy * dy) / len2, 0.0, 1.0)
    cx, cy = qx - tau * dx, qy - tau * dy
    dist = jnp.sqrt(cx * cx + cy * cy + 1e-12) - (pa + tau * (pb - pa))
    dmin = jnp.maximum(jnp.min(dist, axis=1), 0.0)  # (V, M)
    e = jnp.minimum(dmin / d_max[:, None], 1.0)
    return jnp.sum(w * e, axis=-1) / jnp.maximum(jnp.sum(w, axis=-1), 1.0)


def silhouette_samples(mask: np.ndarray, M: int) -> tuple[np.ndarray, np.ndarray]:
    """``M`` foreground pixels of a boolean mask, evenly spaced in raster order: ``(uv (M, 2), w (M,))``; slots
    beyond the number of foreground pixels have weight 0."""
    ys, xs = np.nonzero(mask)
    uv = np.zeros((M, 2), np.float32)
    w = np.zeros(M, np.float32)
    if xs.size:
        idx = np.round(np.linspace(0, xs.size - 1, min(M, xs.size))).astype(np.int64)
        uv[: idx.size, 0] = xs[idx]
        uv[: idx.size, 1] = ys[idx]
        w[: idx.size] = 1.0
    return uv, w


# ---------------------------------------------------------------------------------------------------------------
# Filters


def _layer_index(layer):
    return getattr(layer, "index", layer)


def partition_counts(
    model: body_mod.BodyModel, filter_name: str, num_particles: int | Sequence[int]
) -> tuple[int, ...] | int:
    """Particle counts of ``filter_name``: for partitioned / hierarchical sampling one count per group of
    :func:`partition_groups` (an int is used for every group), else the int itself. Raises ``ValueError`` for a
    sequence given to another filter, a sequence of the wrong length, or a count below 2."""
    if isinstance(num_particles, (int, np.integer)):
        n = int(num_particles)
        if n < 2:
            raise ValueError("--particles must be at least 2")
        if filter_name not in ("partitioned", "hierarchical"):
            return n
        return (n,) * len(partition_groups(model))
    counts = tuple(int(c) for c in num_particles)
    if filter_name not in ("partitioned", "hierarchical"):
        raise ValueError(
            f"one particle count per partition is for the partitioned / hierarchical filters, not {filter_name!r}"
        )
    groups = partition_groups(model)
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
):
    """Filter ``name`` (:data:`FILTERS`) on ``loglik(X, observation, layer) -> (N,)``.

    ``std (D,)``: diffusion per frame; the annealed filters shrink it over the layers by ``s_l = 0.25^{l/(L−1)}``
    and choose β by Deutscher's survival-rate rule (``survival_target``), except ``m-apf`` (the thesis' single correction,
    :func:`jaxmocap.filters.annealing.corrected_beta`). ``fbapf*`` differ from ``apf`` only in the likelihood's per-layer
    cue weights (built by the caller). ``icondensation`` / ``iapf`` draw part of their particles around
    ``observation.center`` (when ``observation.valid``) and from the prior ``N(prior_mean, prior_std²)``.
    ``partitioned`` / ``hierarchical`` split the DOFs by :func:`partition_groups`; ``num_particles`` is one count
    for every partition or a sequence of one count per partition (Li & Kulić on ``full25``: torso 1000, head 200,
    each arm and leg 350; the other filters take an int). ``hybrid`` is the APF with
    gradient moves (:data:`HYBRID_MOVE`) and ``apf-refine`` the APF whose estimate is refined by gradient ascent
    (:class:`jaxmocap.filters.hybrid.HybridAPF`); both need ``loglik`` differentiable in ``X``.
    """
    if name not in FILTERS:
        raise ValueError(f"unknown filter {name!r}; choose one of {', '.join(FILTERS)}")
    counts = partition_counts(model, name, num_particles)
    dt = model.offset.dtype
    std = jnp.asarray(std, dt)
    span = np.asarray(model.upper) - np.asarray(model.lower)
    circular = tuple(bool(a and s >= 2 * math.pi - 1e-3) for a, s in zip(model.angular, span, strict=True))
    common = dict(lower=model.lower, upper=model.upper, circular=circular)
    L = int(num_layers)
    scales = tuple(0.25 ** (l / (L - 1)) for l in range(L)) if L > 1 else (1.0,)
    centre = lambda o: (o.center, o.valid)
    prior = dict(prior_mean=jnp.asarray(prior_mean, dt), prior_std=jnp.asarray(prior_std, dt))
    if name == "sir":
        return SIR(lambda X, o: loglik(X, o, 0), std, num_particles, **common)
    if name == "icondensation":
        return ICondensation(
            lambda X, o: loglik(X, o, 0),
            std,
            num_particles=num_particles,
            proposal_center=centre,
            **prior,
            **common,
        )
    # one count for every partition: the partitions run as one lax.scan (compiled once: full25 2.6–5.3× faster to
    # compile, 9–15 % slower per step); with unequal counts the scan saved little compile time for 6–7 % per step
    # (benchmarks/compile_partitions.py)
    scan = isinstance(counts, tuple) and len(set(counts)) == 1
    if name == "partitioned":
        groups = partition_groups(model)
        return Partitioned(
            lambda X, o, k: loglik(X, o, 0), std, groups, counts, scan_partitions=scan, **common
        )
    if name == "hierarchical":
        groups = partition_groups(model)
        sched = Schedule.deutscher(L, survival_target, diffusion_scales=scales)
        return hierarchical(loglik, std, groups, counts, sched, scan_partitions=scan, **common)
    if name == "m-apf":
        sched = Schedule(
            kind="corrected", num_layers=L, diffusion_scales=scales, survival_target=survival_target
        )
    else:
        sched = Schedule.deutscher(L, survival_target, diffusion_scales=scales)
    if name == "iapf":
        return APF(
            loglik,
            std,
            num_particles,
            sched,
            first_layer="icondensation",
            proposal_center=centre,
            **prior,
            **common,
        )
    if name in GRADIENT_FILTERS:
        from jaxmocap.filters.hybrid import GradientMove, HybridAPF

        if name == "apf-refine":
            return HybridAPF.refined(loglik, std, num_particles, sched, **common)
        move = GradientMove(**{**HYBRID_MOVE, "best_k": min(HYBRID_MOVE["best_k"], num_particles)})
        return HybridAPF(loglik, std, num_particles, sched, move=move, **common)
    return APF(loglik, std, num_particles, sched, **common)


# ---------------------------------------------------------------------------------------------------------------
# Sources


class BadFrame(Exception):
    """A frame that cannot be read (a corrupt image, a video frame that does not decode)."""


class FrameData(NamedTuple):
    """One frame of every view: ``images`` BGR uint8 ``(H, W, 3)``; ``masks`` bool ``(H, W)`` or None; ``depth``
    float32 metres (0 = none) or None; ``keypoints`` ``(V, K, 3)`` (u, v, confidence) or None."""

    images: list
    masks: list | None
    depth: list | None
    keypoints: np.ndarray | None


def _check_depth(path, d: np.ndarray) -> np.ndarray:
    d = np.asarray(d, np.float32)
    if d.ndim != 2:
        raise MocapInputError(path, f"a depth map must be 2-D, got shape {d.shape}")
    if not np.all(np.isfinite(d)):
        bad = int(np.sum(~np.isfinite(d)))
        raise MocapInputError(path, f"depth map has {bad} NaN/inf values (use 0 for 'no depth')")
    if np.any(d < 0):
        raise MocapInputError(path, "depth map has negative values")
    return d


def _read_depth_file(path: pathlib.Path, size) -> np.ndarray:
    """A depth map file: ``.npy`` float metres, or a 16-bit PNG / float TIFF (millimetres / metres)."""
    if not path.is_file():
        raise MocapInputError(path, "missing depth map")
    if path.suffix.lower() == ".npy":
        try:
            d = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise MocapInputError(path, f"cannot read depth map: {e}") from None
    else:
        img = cv2.imread(os.fspath(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise MocapInputError(path, "cannot read depth map (corrupt or unknown format)")
        d = img.astype(np.float32) / 1000.0 if img.dtype == np.uint16 else img
    d = _check_depth(path, d)
    if size is not None and (d.shape[1], d.shape[0]) != tuple(size):
        raise MocapInputError(
            path, f"depth map is {d.shape[1]}x{d.shape[0]}, the calibration says {size[0]}x{size[1]}"
        )
    return d


class SequenceSource:
    """Frames of a sequence folder (:func:`jaxmocap.io.sequence.load_sequence`)."""

    def __init__(self, root: str | os.PathLike):
        from jaxmocap.io import sequence as seqio

        self.seq = seqio.load_sequence(root)
        self.root = pathlib.Path(root)
        self.rig = self.seq.rig
        self.fps = self.seq.fps
        self.num_frames = self.seq.num_frames
        self.view_names = self.seq.view_names
        self.has_masks = "mask" in self.seq.channels
        self.has_depth = "depth" in self.seq.channels
        self.has_keypoints = False
        self.body_path = self.seq.body_path
        gt = self.seq.groundtruth
        self.groundtruth = None if gt is None else gt.joints
        self.description = {"sequence": os.fspath(self.root)}

    def read(self, t: int, masks: bool = True, depth: bool = True) -> FrameData:
        """Frame ``t``: BGR images, and the masks / depth maps the sequence has unless ``masks`` / ``depth`` is
        False (each is a PNG to decode: a tracker that does not use them skips them)."""
        try:
            images = [v.bgr(t) for v in self.seq.views]
            m = [v.mask(t) for v in self.seq.views] if (masks and self.has_masks) else None
            d = (
                [_check_depth(v.path("depth", t), v.depth(t)) for v in self.seq.views]
                if (depth and self.has_depth)
                else None
            )
        except MocapInputError as e:
            if "cannot read image" in str(e) or "missing image" in str(e):
                raise BadFrame(str(e)) from None
            raise
        return FrameData(images, m, d, None)

    def close(self) -> None:
        pass


class VideoSource:
    """Synchronised videos (frame ``t`` of every video is the same instant) with their calibration, optional
    OpenPose JSON folders (one per camera) and depth-map folders (one per camera: ``.npy`` metres, 16-bit PNG
    millimetres, or float TIFF metres, one file per frame in name order)."""

    def __init__(
        self,
        videos: Sequence[str | os.PathLike],
        calibration: str | os.PathLike,
        keypoints: Sequence[str | os.PathLike] | None = None,
        depth: Sequence[str | os.PathLike] | None = None,
    ):
        self.videos = [pathlib.Path(v) for v in videos]
        if not self.videos:
            raise MocapInputError(None, "no video given")
        for v in self.videos:
            if not v.is_file():
                raise MocapInputError(v, "no such video file")
            if not os.access(v, os.R_OK):
                raise MocapInputError(v, "video file is not readable")
        calibration = pathlib.Path(calibration)
        if not calibration.exists():
            raise MocapInputError(calibration, "no such calibration file")
        rig = camera.load_calibration(calibration)
        if rig.num_views != len(self.videos):
            raise MocapInputError(
                calibration,
                f"the calibration has {rig.num_views} cameras but {len(self.videos)} videos were given",
            )
        self.caps, counts, sizes, fpss = [], [], [], []
        for v in self.videos:
            cap = cv2.VideoCapture(os.fspath(v))
            if not cap.isOpened():
                raise MocapInputError(v, "cannot open the video (unknown format or corrupt)")
            self.caps.append(cap)
            counts.append(int(round(cap.get(cv2.CAP_PROP_FRAME_COUNT))))
            sizes.append((int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))))
            fpss.append(float(cap.get(cv2.CAP_PROP_FPS)))
        for v, n in zip(self.videos, counts, strict=True):
            if n != counts[0]:
                raise MocapInputError(
                    v,
                    f"has {n} frames but {self.videos[0]} has {counts[0]}: the videos must be synchronised frame by frame",
                )
        if counts[0] <= 0:
            raise MocapInputError(self.videos[0], "the video has no frame")
        fixed = []
        for k, (v, s) in enumerate(zip(self.videos, sizes, strict=True)):
            want = tuple(rig.image_size[k])
            if want == (0, 0):
                fixed.append(s)
            elif want != s:
                raise MocapInputError(
                    calibration,
                    f"camera {rig.names[k]!r} is calibrated for {want[0]}x{want[1]} images but {v.name} is {s[0]}x{s[1]}",
                )
            else:
                fixed.append(want)
        self.rig = dataclasses.replace(rig, image_size=tuple(fixed))
        self.num_frames = counts[0]
        self.fps = fpss[0] if fpss[0] > 0 and math.isfinite(fpss[0]) else 30.0
        self.view_names = self.rig.names
        self.positions = [0] * len(self.caps)
        self.has_masks = False
        self.body_path = None
        self.groundtruth = None
        self.keypoints = None
        if keypoints:
            from jaxmocap.io.openpose import load_openpose_folder

            if len(keypoints) != len(self.videos):
                raise MocapInputError(
                    keypoints[0], f"{len(keypoints)} keypoint folders for {len(self.videos)} videos"
                )
            kps = []
            for folder in keypoints:
                kp = load_openpose_folder(folder)
                if kp.shape[0] != self.num_frames:
                    raise MocapInputError(
                        folder, f"has {kp.shape[0]} keypoint files for {self.num_frames} video frames"
                    )
                kps.append(kp)
            self.keypoints = np.stack(kps, axis=1).astype(np.float32)  # (T, V, K, 3)
        self.has_keypoints = self.keypoints is not None
        self.depth_files = None
        if depth:
            if len(depth) != len(self.videos):
                raise MocapInputError(depth[0], f"{len(depth)} depth folders for {len(self.videos)} videos")
            self.depth_files = []
            for folder in depth:
                folder = pathlib.Path(folder)
                if not folder.is_dir():
                    raise MocapInputError(folder, "no such depth folder")
                files = sorted(
                    p for p in folder.iterdir() if p.suffix.lower() in (".npy", ".png", ".tif", ".tiff")
                )
                if len(files) != self.num_frames:
                    raise MocapInputError(
                        folder, f"has {len(files)} depth maps for {self.num_frames} video frames"
                    )
                self.depth_files.append(files)
        self.has_depth = self.depth_files is not None
        self.description = {
            "videos": [os.fspath(v) for v in self.videos],
            "calibration": os.fspath(calibration),
            "keypoints": [os.fspath(k) for k in keypoints or []],
            "depth": [os.fspath(d) for d in depth or []],
        }

    def read(self, t: int, masks: bool = True, depth: bool = True) -> FrameData:
        """Frame ``t`` of every video (BGR), with the depth maps unless ``depth`` is False (videos have no
        masks: ``masks`` is accepted for the common interface)."""
        images = []
        for k, cap in enumerate(self.caps):
            if self.positions[k] != t:
                cap.set(cv2.CAP_PROP_POS_FRAMES, t)
            ok, frame = cap.read()
            self.positions[k] = t + 1
            if not ok or frame is None:
                self.positions[k] = -1
                raise BadFrame(f"{self.videos[k]}: frame {t} could not be decoded")
            images.append(frame)
        d = None
        if self.depth_files is not None and depth:
            d = [
                _read_depth_file(files[t], self.rig.image_size[k]) for k, files in enumerate(self.depth_files)
            ]
        kp = None if self.keypoints is None else self.keypoints[t]
        return FrameData(images, None, d, kp)

    def close(self) -> None:
        for cap in self.caps:
            cap.release()


# ---------------------------------------------------------------------------------------------------------------
# Features


class _Extractor(FeatureExtractor):
    """The feature pipeline with foreground masks supplied from outside (a sequence's mask channel)."""

    given_masks: list | None = None

    def foreground_masks(self, frames, depth):
        if self.given_masks is not None:
            f = self.config.downsample
            return [downsample_image(m.astype(np.float32), f) >= 0.5 for m in self.given_masks]
        return super().foreground_masks(frames, depth)


class FeatureBuilder:
    """Frames → :class:`TrackObservation` (image maps through :class:`jaxmocap.features.FeatureExtractor`).

    ``foreground``: ``mask`` (the source's masks), ``median`` (static background = per-pixel median of up to 15
    frames spread over the input), ``mog2`` (adaptive; stateful, so not reproduced exactly by ``--resume``),
    ``none``; ``auto`` = ``mask`` when the source has masks, else ``median``.
    """

    def __init__(
        self,
        source,
        cue_names: Sequence[str],
        foreground: str = "auto",
        downsample: int = 1,
        num_samples: int = 128,
        frames: Sequence[int] | None = None,
    ):
        if foreground not in FOREGROUNDS:
            raise ValueError(f"unknown foreground {foreground!r}; choose one of {', '.join(FOREGROUNDS)}")
        if foreground == "auto":
            foreground = "mask" if source.has_masks else "median"
        if foreground == "mask" and not source.has_masks:
            raise ValueError(
                "--foreground mask needs an input with foreground masks (a sequence folder's mask/)"
            )
        self.foreground = foreground
        self.source = source
        names = set(cue_names)
        reads = {f for n in names for f in cues_mod.REQUIRES.get(n, ())}
        # IROS 2007's 3D head / hand blobs: skin blobs matched across the first pair
        blobs = "blobs3d" in names
        cfg = FeatureConfig(
            foreground={"mask": "none", "median": "static", "mog2": "mog2", "none": "none"}[foreground],
            edges=bool(names & {"edges", "edge_fraction"}),
            edge_dt="edge_distance" in names,
            skin="rgb" if ("skin" in reads or blobs) else None,
            rgb="rgb" in reads,
            blobs=blobs,
            downsample=int(downsample),
        )
        self.extractor = _Extractor(source.rig, cfg)
        self.rig = self.extractor.rig
        #: what ``source.read`` must decode for these features: masks for ``--foreground mask``, depth maps for a
        #: depth cue (each is a PNG or file per view to read)
        self.needs_masks = foreground == "mask"
        self.needs_depth = "depth" in reads
        self.num_samples = int(num_samples)
        if foreground == "median":
            frames = list(range(source.num_frames)) if frames is None else list(frames)
            pick = sorted(
                {frames[int(i)] for i in np.round(np.linspace(0, len(frames) - 1, min(15, len(frames))))}
            )
            stacks = None
            for t in pick:
                try:
                    fd = source.read(t, masks=False)
                except BadFrame:
                    continue
                stacks = (
                    [[im] for im in fd.images]
                    if stacks is None
                    else [s + [im] for s, im in zip(stacks, fd.images, strict=True)]
                )
            if stacks is None:
                raise MocapInputError(None, "no readable frame to estimate the background from")
            self.extractor.set_background([np.stack(s) for s in stacks])

    def __call__(self, fd: FrameData, dof: int) -> tuple[TrackObservation, np.ndarray]:
        """The observation (with a placeholder centre) and the host foreground masks ``(V, H, W)`` bool."""
        self.extractor.given_masks = fd.masks if self.foreground == "mask" else None
        obs = self.extractor(fd.images, depth=fd.depth)
        if fd.keypoints is not None:
            f = self.extractor.config.downsample
            kp = np.asarray(fd.keypoints, np.float32).copy()
            kp[..., :2] = np.where(kp[..., 2:3] > 0, (kp[..., :2] + 0.5) / f - 0.5, 0.0)
            obs = obs._replace(keypoints2d=jnp.asarray(kp))
        if obs.has("foreground"):
            fg = np.asarray(obs.foreground)
            masks = (fg >= (128 if fg.dtype == np.uint8 else 0.5)) if fg.ndim == 3 else None
        else:
            masks = None
        V = len(fd.images)
        M = self.num_samples
        uv = np.zeros((V, M, 2), np.float32)
        w = np.zeros((V, M), np.float32)
        if masks is not None:
            for v in range(V):
                uv[v], w[v] = silhouette_samples(masks[v], M)
        tobs = TrackObservation(
            obs, jnp.asarray(uv), jnp.asarray(w), jnp.zeros(dof, jnp.float32), jnp.asarray(False)
        )
        return tobs, masks


# ---------------------------------------------------------------------------------------------------------------
# Detections


def silhouette_centroid(rig: camera.Rig, masks: np.ndarray | None, min_pixels: int = 20) -> np.ndarray | None:
    """Triangulated centroid ``(3,)`` of the foreground of every view with at least ``min_pixels`` pixels (needs
    two such views), else None."""
    if masks is None:
        return None
    uv, wts = [], []
    for m in masks:
        ys, xs = np.nonzero(m)
        ok = xs.size >= min_pixels
        uv.append([xs.mean(), ys.mean()] if ok else [0.0, 0.0])
        wts.append(1.0 if ok else 0.0)
    if sum(wts) < 2:
        return None
    X = camera.triangulate(
        rig.to_jax(jnp.float32), jnp.asarray(uv, jnp.float32), jnp.asarray(wts, jnp.float32)
    )
    X = np.asarray(X, np.float64)
    return X if np.all(np.isfinite(X)) else None


_joint_positions = jax.jit(body_mod.joint_positions)


def _root_translation_dofs(model) -> list[int]:
    return [d for d in model.topology.segment_dofs[0] if model.topology.dof_kinds[d] == "P"]


def _move_root_over(model, x: np.ndarray, point: np.ndarray) -> np.ndarray:
    """``x`` with its root translated horizontally so that the model's mean joint lies above ``point``."""
    x = np.asarray(x, np.float64).copy()
    J = np.asarray(_joint_positions(model, jnp.asarray(x, model.offset.dtype)), np.float64)
    shift = np.zeros(3)
    shift[:2] = point[:2] - J.mean(axis=0)[:2]
    trans = _root_translation_dofs(model)
    if trans:
        A = np.asarray(model.dof_axis, np.float64)[trans].T  # (3, k)
        x[trans] += np.linalg.pinv(A) @ shift
    return x


def keypoint_pose(
    model, rig: camera.Rig, keypoints: np.ndarray, init: np.ndarray | None = None
) -> np.ndarray | None:
    """IK state from 2D keypoints ``(V, K, 3)`` of every view (full-size pixels): each evaluation joint of
    :data:`KEYPOINT_OF` triangulated from the views that detect it (confidence > 0.1, at least two), the root as
    the middle of the hips, then :func:`jaxmocap.fit.ik.fit_pose`. None with fewer than four joints."""
    kp = np.asarray(keypoints, np.float64)
    rj = rig.to_jax(jnp.float32)
    targets = {}
    for name, k in KEYPOINT_OF.items():
        c = np.where(kp[:, k, 2] > 0.1, kp[:, k, 2], 0.0)
        if np.sum(c > 0) >= 2:
            X = np.asarray(
                camera.triangulate(rj, jnp.asarray(kp[:, k, :2], jnp.float32), jnp.asarray(c, jnp.float32))
            )
            if np.all(np.isfinite(X)):
                targets[name] = X
    if "left_hip" in targets and "right_hip" in targets:
        targets["root"] = 0.5 * (targets["left_hip"] + targets["right_hip"])
    names = model.joint_names
    Y = np.full((len(names), 3), np.nan)
    for i, n in enumerate(names):
        if n in targets:
            Y[i] = targets[n]
    if np.sum(np.all(np.isfinite(Y), axis=1)) < 4:
        return None
    fit = ik.fit_pose(
        model, jnp.asarray(Y, model.offset.dtype), init=None if init is None else jnp.asarray(init)
    )
    x = np.asarray(fit.state, np.float64)
    return x if np.all(np.isfinite(x)) else None


def _rest_facing(model, rig: camera.Rig, point: np.ndarray) -> np.ndarray:
    """The rest pose standing below ``point`` (horizontally) and facing the first camera."""
    x = np.asarray(model.rest_pose, np.float64).copy()
    centre = np.asarray(camera.camera_centres(rig.to_jax(jnp.float32)), np.float64)[0]
    heading = [d for d in model.topology.segment_dofs[0] if model.dof_names[d].endswith("rz")]
    if heading:
        v = centre[:2] - point[:2]
        x[heading[0]] = math.atan2(v[1], v[0])
    return _move_root_over(model, x, point)


# ---------------------------------------------------------------------------------------------------------------
# Options and the loop


@dataclasses.dataclass
class TrackOptions:
    """Options of a tracking run (``None`` = the per-model / per-input default).

    ``model``/``body``: :func:`build_model`; ``filter``, ``particles``, ``layers``: :func:`make_filter` (defaults
    :func:`default_particles`, :func:`default_layers`); ``cues``: :func:`parse_cues` (default :func:`default_cues`);
    ``seed``: frame ``t`` uses the key ``fold_in(key(seed), t)``; ``frames``: ``"A:B"``; ``init``: ``groundtruth``,
    ``ik``, a file, or ``auto``; ``foreground``/``downsample``/``samples``: :class:`FeatureBuilder`;
    ``velocity``: damping ``k`` of the constant-velocity prediction ``x_root += k (x̂_{t−1} − x̂_{t−2})`` (0 =
    random walk only); ``diffusion_scale``: multiplies :func:`diffusion_std`; ``survival_target``: α of
    Deutscher's rule; ``loss_*``/``reinit_widen``: track loss (module docstring); ``on_bad_frame``: ``skip`` or
    ``stop``; ``overlay``: MP4 per view; ``resume``/``overwrite``: what to do with a previous run in the output
    folder; ``fsync``: ``fsync`` every rewrite.
    """

    model: str | None = None
    body: str | None = None
    filter: str = "apf"
    particles: int | Sequence[int] | None = None
    layers: int | None = None
    cues: str | Sequence | None = None
    seed: int = 0
    frames: str | None = None
    init: str = "auto"
    foreground: str = "auto"
    downsample: int = 1
    velocity: float = 0.5
    diffusion_scale: float = 1.0
    survival_target: float = 0.5
    samples: int = 128
    loss_ratio: float = 2.5
    loss_frames: int = 3
    loss_window: int = 5
    reinit_widen: float = 3.0
    on_bad_frame: str = "skip"
    overlay: bool = False
    resume: bool = False
    overwrite: bool = False
    fsync: bool = False

    def identity(self) -> dict:
        """The options a resumed run must share with the run it continues."""
        keys = (
            "model",
            "body",
            "filter",
            "particles",
            "layers",
            "cues",
            "seed",
            "frames",
            "init",
            "foreground",
        )
        keys += (
            "downsample",
            "velocity",
            "diffusion_scale",
            "samples",
            "loss_ratio",
            "loss_frames",
            "loss_window",
        )
        keys += ("reinit_widen",)
        out = {k: getattr(self, k) for k in keys}
        if isinstance(self.particles, (list, tuple)):
            out["particles"] = [int(c) for c in self.particles]
        out["cues"] = None if self.cues is None else [list(c) for c in parse_cues(self.cues)]
        return out


RUN_JSON = "run.json"
RESUME_NPZ = "resume.npz"


class Progress:
    """A one-line progress bar with frames per second on a terminal (a line every 10 % otherwise)."""

    def __init__(self, total: int, stream=None, enabled: bool = True, label: str = "track"):
        self.total, self.label = total, label
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.tty = enabled and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.t0 = time.monotonic()
        self.first_done = None
        self.last_pct = -1

    def end_line(self) -> None:
        """Finish a partly drawn terminal line (before an error message)."""
        if self.tty and self.first_done is not None:
            self.stream.write("\n")
            self.stream.flush()

    def update(self, done: int, note: str = "") -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if self.first_done is None and done > 0:
            self.first_done = (now, done)
        fps = 0.0
        if self.first_done is not None and done > self.first_done[1]:
            fps = (done - self.first_done[1]) / max(now - self.first_done[0], 1e-9)
        frac = done / max(self.total, 1)
        eta = (self.total - done) / fps if fps > 0 else float("nan")
        bar = "#" * int(round(24 * frac))
        text = f"{self.label} {done:>5}/{self.total} [{bar:<24}] {fps:5.2f} frames/s"
        if math.isfinite(eta):
            text += f"  ETA {eta:4.0f} s"
        if note:
            text += f"  {note}"
        if self.tty:
            self.stream.write("\r" + text + "\x1b[K")
            if done >= self.total:
                self.stream.write("\n")
            self.stream.flush()
        else:
            pct = int(10 * frac)
            if pct != self.last_pct or done >= self.total:
                self.last_pct = pct
                self.stream.write(text + "\n")
                self.stream.flush()


def _warn(msg: str) -> None:
    sys.stderr.write(f"jaxmocap: warning: {msg}\n")
    sys.stderr.flush()


class Tracker:
    """One tracking run: ``Tracker(source, out, options).run()``.

    Attributes after construction: ``model``, ``likelihood``, ``filter``, ``cues`` (``(name, weight)``),
    ``frames`` (the input frame numbers to track), ``trace_count`` (compilations of the filter step).
    """

    def __init__(
        self, source, out: str | os.PathLike, options: TrackOptions | None = None, quiet: bool = False
    ):
        from jaxmocap.synth.generate import parse_frames

        o = TrackOptions() if options is None else options
        self.o, self.source, self.quiet = o, source, quiet
        self.out = pathlib.Path(out)
        if o.filter not in FILTERS:
            raise ValueError(f"unknown filter {o.filter!r}; choose one of {', '.join(FILTERS)}")
        if o.on_bad_frame not in ("skip", "stop"):
            raise ValueError("on_bad_frame must be 'skip' or 'stop'")
        a, b = parse_frames(o.frames, source.num_frames)
        self.frames = list(range(a, b))
        self.model = build_model(o.model, o.body, source.body_path)
        cues = parse_cues(o.cues) or default_cues(self.model.name, source.has_depth, source.has_keypoints)
        for name, _ in cues:
            if name == "depth" and not source.has_depth:
                raise ValueError("the depth cue needs depth maps (a sequence with depth/ or --depth)")
            if name == "keypoints" and not source.has_keypoints:
                raise ValueError("the keypoints cue needs 2D keypoints (--keypoints)")
        self.cues = cues
        self.features = FeatureBuilder(
            source, [n for n, _ in cues], o.foreground, o.downsample, o.samples, self.frames
        )
        if (
            any(n in ("foreground", "coverage", "silhouette_divergence") for n, _ in cues)
            and self.features.foreground == "none"
        ):
            raise ValueError("the foreground / coverage cues need a foreground (not --foreground none)")
        self.layers = o.layers if o.layers is not None else default_layers(o.filter)[0]
        if self.layers < 1:
            raise ValueError("--layers must be at least 1")
        if o.filter in ("sir", "icondensation", "partitioned") and self.layers != 1:
            raise ValueError(
                f"the {o.filter} filter has no annealing layers (leave --layers out or set it to 1)"
            )
        n = o.particles if o.particles is not None else default_particles(self.model.name, o.filter)
        counts = partition_counts(self.model, o.filter, n)  # raises on a bad count
        #: particles (per layer), or a list of one count per partition
        self.num_particles = list(counts) if isinstance(n, (list, tuple)) else int(n)
        self.std = diffusion_std(self.model, source.fps) * float(o.diffusion_scale)
        self._build_likelihood()
        self.trace_count = 0
        self.filter = None  # built once the initial state is known (the prior of ICONDENSATION / IAPF)

    # -- likelihood ---------------------------------------------------------------------------------------------

    def _build_likelihood(self) -> None:
        o = self.o
        image_cues = [(n, w) for n, w in self.cues if n not in TRACKER_CUES]
        names = [n for n, _ in self.cues]
        preset = o.filter if o.filter in ("fbapf", "fbapf2", "fbapf3", "m-apf") else "apf"
        stand_in = ["silhouette_divergence" if n == "coverage" else n for n in names]
        table = lk.schedule_preset(preset, stand_in, self.layers)  # (L, C): λ_c(l)
        cols = [i for i, n in enumerate(names) if n not in TRACKER_CUES]
        cue_objs = []
        gradient = o.filter in GRADIENT_FILTERS
        if gradient:
            from jaxmocap.likelihood.cues import DIFFERENTIABLE

            flat = [n for n, _ in image_cues if DIFFERENTIABLE.get(n) == "no"]
            if flat:
                raise ValueError(
                    f"the {o.filter} filter needs a differentiable likelihood, but cue(s) {', '.join(flat)} "
                    "are piecewise constant in the pose; choose others with --cues (differentiable: "
                    + ", ".join(n for n, d in DIFFERENTIABLE.items() if d != "no")
                    + ", coverage)"
                )
        for n, w in image_cues:
            params = {}
            if gradient and DIFFERENTIABLE[n] in ("bilinear", "soft"):
                params = {"bilinear": True, **({"soft": True} if DIFFERENTIABLE[n] == "soft" else {})}
            if n == "keypoints":
                pairs = tuple((j, k) for j, k in KEYPOINT_OF.items() if j in self.model.joint_names)
                params = {**params, "pairs": pairs}
            cue_objs.append(lk.Cue(n, w, params))
        rig = self.features.rig
        self.likelihood = (
            lk.Likelihood.create(self.model, rig, cue_objs, num_layers=self.layers, schedule=table[:, cols])
            if cue_objs
            else None
        )
        cov = [(i, w) for i, (n, w) in enumerate(self.cues) if n == "coverage"]
        cov_lam = jnp.asarray(table[:, cov[0][0]] * cov[0][1], jnp.float32) if cov else None
        rj = rig.to_jax(jnp.float32)
        d_max = jnp.asarray([max(1.0, COVERAGE_DMAX * w) for w, _ in rig.image_size], jnp.float32)
        model, L = self.model, self.layers

        def loglik(X, tobs, layer):
            lik = self.likelihood  # read when traced: after the first frame's colour references are set
            l = jnp.clip(jnp.asarray(_layer_index(layer)), 0, L - 1)
            ll = jnp.zeros(X.shape[0], X.dtype) if lik is None else lik.batch(X, tobs.image, l)
            if cov_lam is not None:
                e = jax.vmap(
                    lambda x: jnp.sum(coverage_energy(model, rj, x, tobs.cover_uv, tobs.cover_w, d_max))
                )(X)
                ll = ll - cov_lam[l] * e
            return jnp.where(jnp.isfinite(ll), ll, -jnp.inf)

        self.loglik = loglik

    def _set_references(self, x0: np.ndarray, first: TrackObservation) -> None:
        """Reference data of the colour cues (histograms, templates) from the first tracked frame at ``x0``
        (:meth:`jaxmocap.likelihood.compose.Likelihood.with_references`); a resumed run recomputes them from the same
        frame and pose, so that it continues with the same likelihood."""
        lik = self.likelihood
        if lik is not None and lik.needs_references:
            dt = self.model.offset.dtype
            self.likelihood = lik.with_references(jnp.asarray(x0, dt), first.image)

    def _make_filter(self, x0: np.ndarray):
        self.filter = make_filter(
            self.o.filter,
            self.loglik,
            self.model,
            self.std,
            self.num_particles,
            self.layers,
            prior_mean=x0,
            prior_std=3.0 * self.std,
            survival_target=self.o.survival_target,
        )

        def step(key, state, tobs):
            self.trace_count += 1
            return self.filter.step(key, state, tobs)

        self._step = jax.jit(step)

    # -- initialisation -----------------------------------------------------------------------------------------

    def initial_state(self, t0: int, masks, fd: FrameData) -> tuple[np.ndarray, float, str]:
        """``(x0, spread factor, how)`` for the first frame."""
        o = self.o
        init = o.init
        if init == "auto":
            init = "groundtruth" if self.source.groundtruth is not None else "ik"
        if init == "groundtruth":
            gt = self.source.groundtruth
            if gt is None:
                raise MocapInputError(
                    getattr(self.source, "root", None),
                    "--init groundtruth needs a sequence with groundtruth.npz",
                )
            dt = self.model.offset.dtype
            targets = jnp.asarray(ik.select_joints(self.model, gt[t0]), dt)
            x = np.asarray(ik.fit_pose(self.model, targets).state, np.float64)
            if np.all(np.isfinite(x)):
                return x, 0.5, "groundtruth"
            # the pose fit failed (non-finite): the rest pose placed on the ground truth by Procrustes
            x = np.asarray(ik.root_init(self.model, targets), np.float64)
            if not np.all(np.isfinite(x)):
                x = _move_root_over(self.model, np.asarray(self.model.rest_pose), np.nanmean(gt[t0], axis=0))
            return x, 2.0, "groundtruth-root"
        if init == "ik":
            if fd.keypoints is not None:
                x = keypoint_pose(self.model, self.source.rig, fd.keypoints)
                if x is not None:
                    return x, 1.0, "ik-keypoints"
            c = silhouette_centroid(self.features.rig, masks)
            if c is None:
                raise MocapInputError(
                    None,
                    f"cannot initialise at frame {t0}: no detection (no keypoints, and the person is not seen in two views)",
                )
            return _rest_facing(self.model, self.features.rig, c), 2.0, "ik-silhouette"
        return self._init_from_file(pathlib.Path(init), t0), 0.5, "file"

    def _init_from_file(self, path: pathlib.Path, t0: int) -> np.ndarray:
        D = self.model.num_dofs
        if not path.is_file():
            raise MocapInputError(path, "no such initial pose file (--init groundtruth|ik|FILE)")
        if path.suffix.lower() == ".npz":
            data = export._read_npz(path)
            if "state" not in data:
                raise MocapInputError(path, "no 'state' array")
            st = np.asarray(data["state"], np.float64).reshape(-1, data["state"].shape[-1])
            row = 0
            if "frame_index" in data and t0 in set(np.asarray(data["frame_index"]).tolist()):
                row = int(np.nonzero(np.asarray(data["frame_index"]) == t0)[0][0])
            x = st[row]
        elif path.suffix.lower() == ".npy":
            try:
                x = np.asarray(np.load(path, allow_pickle=False), np.float64).reshape(-1)
            except (OSError, ValueError) as e:
                raise MocapInputError(path, f"cannot read: {e}") from None
        else:
            try:
                x = np.asarray(path.read_text().split(), np.float64)
            except (OSError, ValueError) as e:
                raise MocapInputError(path, f"expected {D} numbers: {e}") from None
        if x.shape != (D,):
            raise MocapInputError(
                path, f"the initial pose has {x.size} values, the {self.model.name} model {D} DOFs"
            )
        if not np.all(np.isfinite(x)):
            raise MocapInputError(path, "the initial pose has non-finite values")
        return np.clip(x, np.asarray(self.model.lower), np.asarray(self.model.upper))

    # -- outputs ------------------------------------------------------------------------------------------------

    def _run_description(self) -> dict:
        return {
            "options": self.o.identity(),
            "input": self.source.description,
            "model": self.model.name,
            "dof_names": list(self.model.dof_names),
            "cues": [list(c) for c in self.cues],
            "particles": self.num_particles,
            "layers": self.layers,
            "frames": [self.frames[0], self.frames[-1] + 1],
            "fps": self.source.fps,
            "diffusion_std": self.std.tolist(),
            "jax": jax.__version__,
        }

    def _check_out(self) -> dict | None:
        """Check the output folder (nothing is written): returns the resume checkpoint, or None to start afresh."""
        out = self.out
        if out.exists() and not out.is_dir():
            raise MocapInputError(out, "exists and is not a folder")
        has_run = (out / export.POSES_NPZ).exists() or (out / RUN_JSON).exists()
        if self.o.resume:
            if not (out / RUN_JSON).exists():
                if has_run:
                    raise MocapInputError(out / RUN_JSON, "missing: cannot resume this folder")
                return None
            try:
                old = json.loads((out / RUN_JSON).read_text())
            except (OSError, json.JSONDecodeError) as e:
                raise MocapInputError(out / RUN_JSON, f"cannot read: {e}") from None
            desc = json.loads(json.dumps(self._run_description()))
            if old.get("options") != desc["options"] or old.get("input") != desc["input"]:
                raise MocapInputError(
                    out / RUN_JSON,
                    "was written by a run with other options or input: cannot resume it with these",
                )
            ck = out / RESUME_NPZ
            return export._read_npz(ck) if ck.exists() else None
        if has_run and not self.o.overwrite:
            raise MocapInputError(
                out, "already holds a tracking run: pass --resume to continue it or --overwrite to replace it"
            )
        return None

    def _start_out(self, fresh: bool) -> None:
        """Create the folder, remove temporary files of a killed process and, for a fresh run, the old outputs."""
        out = self.out
        out.mkdir(parents=True, exist_ok=True)
        for stale in out.glob(".*.tmp"):  # left by a process killed during an atomic rewrite
            stale.unlink()
        if not fresh:
            return
        names = (
            RESUME_NPZ,
            export.POSES_NPZ,
            export.POSES_CSV,
            export.DIAGNOSTICS_JSON,
            export.DIAGNOSTICS_JOURNAL,
        )
        names += (export.TRACK_BVH,)
        for name in names:
            if (out / name).exists():
                (out / name).unlink()
        desc = self._run_description()
        export.atomic_write_text(out / RUN_JSON, json.dumps(desc, indent=1, sort_keys=True) + "\n")

    # -- the loop -----------------------------------------------------------------------------------------------

    def _observe(
        self, t: int
    ) -> tuple[TrackObservation | None, np.ndarray | None, FrameData | None, str | None]:
        try:
            fd = self.source.read(t, masks=self.features.needs_masks, depth=self.features.needs_depth)
        except BadFrame as e:
            if self.o.on_bad_frame == "stop":
                raise MocapInputError(None, f"{e} (--on-bad-frame stop)") from None
            _warn(f"skipping frame {t}: {e}")
            return None, None, None, str(e)
        tobs, masks = self.features(fd, self.model.num_dofs)
        return tobs, masks, fd, None

    def _key(self, t: int, purpose: int = 0):
        k = jax.random.fold_in(jax.random.key(int(self.o.seed)), int(t))
        return k if purpose == 0 else jax.random.fold_in(k, purpose)

    def _first_frame(self):
        """Find the first readable frame, check that a person is visible there and initialise the filter.

        Returns ``(index into frames, its observation tuple, the skipped frames, x0, how)``."""
        skipped = []
        for i, t in enumerate(self.frames):
            obs = self._observe(t)
            if obs[0] is None:
                skipped.append((t, obs[3]))
                continue
            masks = obs[1]
            if masks is not None and int(np.sum(masks)) < 20:
                raise MocapInputError(
                    None,
                    f"no person in frame {t}: the foreground ({self.features.foreground}) is empty in every view (an "
                    "empty scene? a median background of frames where the person hardly moves?); use --frames to "
                    "start where the person is visible, or another --foreground",
                )
            x0, spread, how = self.initial_state(t, masks, obs[2])
            return i, obs, skipped, np.asarray(x0, np.float64), spread, how
        raise MocapInputError(None, "no frame of the input could be read")

    def run(self) -> dict:
        """Track every frame; returns the summary (also in ``diagnostics.json``)."""
        from jaxmocap.filters.base import State

        o = self.o
        ck = self._check_out()
        model = self.model
        D = model.num_dofs
        dt = model.offset.dtype
        trans = np.zeros(D, bool)
        trans[_root_translation_dofs(model)] = True
        frames = self.frames
        stats = {"reinitialisations": 0, "lost_frames": 0, "skipped": 0, "first_frame_s": None}
        last_good = None
        hist: list[tuple[int, np.ndarray]] = []  # (frame, estimate) of the last two frames, for the velocity
        q_ref, q_hist, lost_run = float("nan"), [], 0
        t_begin = time.monotonic()
        if (
            ck is None
        ):  # a fresh run: everything that can fail on the input fails before any output is written
            start, pending, skipped, x0, spread, how = self._first_frame()
            self._ref_frame = frames[start]
            self._set_references(x0, pending[0])
            self._make_filter(x0)
            t0 = frames[start]
            state = self.filter.init(
                self._key(t0, 1), jnp.asarray(x0, dt), jnp.asarray(spread * self.std, dt)
            )
            last_good = x0
        else:
            done = int(ck["frame"])
            if done not in frames:
                raise MocapInputError(
                    self.out / RESUME_NPZ, f"checkpoint of frame {done}, outside the frames of this run"
                )
            start, skipped, how = frames.index(done) + 1, [], None
            x0 = np.asarray(ck["x0"], np.float64)
            self._ref_frame = int(ck["ref_frame"]) if "ref_frame" in ck else frames[0]
            if self.likelihood is not None and self.likelihood.needs_references:
                first = self._observe(self._ref_frame)[0]
                if first is None:
                    raise MocapInputError(
                        None, f"frame {self._ref_frame} of the colour references is unreadable"
                    )
                self._set_references(x0, first)
            self._make_filter(x0)
            state = State(*(jnp.asarray(ck[k], dt) for k in ("particles", "log_weights", "estimate")))
            hist = [
                (int(f), np.asarray(x)) for f, x in zip(ck["hist_frames"], ck["hist_states"], strict=True)
            ]
            last_good = np.asarray(ck["last_good"])
            q_ref = float(ck["q_ref"])
            q_hist = [float(v) for v in np.asarray(ck["q_hist"]).reshape(-1)]
            lost_run = int(ck["lost_run"])
            for k in ("reinitialisations", "lost_frames", "skipped"):
                stats[k] = int(ck[k])
            pending = self._observe(frames[start]) if start < len(frames) else None
        self._start_out(fresh=ck is None)
        pose_writer = export.PoseWriter(
            self.out,
            model.dof_names,
            model.name,
            self.source.fps,
            keep=None if ck is None else int(ck["rows"]),
            fsync=o.fsync,
        )
        diag = export.DiagnosticsWriter(
            self.out, self._run_description(), keep_until=None if ck is None else frames[start - 1] + 1
        )
        resumed_at = None if ck is None else (frames[start] if start < len(frames) else None)
        for t, why in skipped:
            stats["skipped"] += 1
            diag.append({"frame": t, "skipped": True, "reason": why})
        progress = Progress(len(frames), enabled=not self.quiet)
        interrupted = False
        try:
            for i in range(start, len(frames)):
                t = frames[i]
                t_frame = time.monotonic()
                tobs, masks, fd, bad = pending
                if tobs is None:  # an unreadable frame, skipped
                    stats["skipped"] += 1
                    diag.append({"frame": t, "skipped": True, "reason": bad})
                    pending = self._observe(frames[i + 1]) if i + 1 < len(frames) else None
                    progress.update(i + 1)
                    continue
                record = {"frame": t, "time_s": t / self.source.fps}
                if how is not None:
                    record["init"], how = how, None
                # detection-driven proposal centre (ICONDENSATION / IAPF) and the no-person test
                no_person = masks is not None and not np.any(np.sum(masks, axis=(1, 2)) >= 20)
                centre = self._detection(fd, masks, last_good)
                if centre is not None:
                    tobs = tobs._replace(center=jnp.asarray(centre, jnp.float32), valid=jnp.asarray(True))
                # damped constant-velocity prediction of the root translation
                if len(hist) == 2 and hist[0][0] == t - 2 and hist[1][0] == t - 1 and o.velocity > 0:
                    v = np.where(trans, hist[1][1] - hist[0][1], 0.0) * o.velocity
                    state = state._replace(particles=state.particles + jnp.asarray(v, dt))
                state, info = self._step(self._key(t), state, tobs)
                # prepare the next frame on the host while the step runs
                pending = self._observe(frames[i + 1]) if i + 1 < len(frames) else None
                info = jax.device_get(info)
                est = np.asarray(info.estimate, np.float64)
                q = float(-np.asarray(info.layers.loglik_max).reshape(-1)[-1])
                recovered = bool(np.asarray(info.recovered))
                # track loss
                if not math.isfinite(q_ref):
                    if math.isfinite(q):
                        q_hist.append(q)
                    if len(q_hist) >= o.loss_window:
                        q_ref = float(np.median(q_hist))
                bad_quality = math.isfinite(q_ref) and (not math.isfinite(q) or q > o.loss_ratio * q_ref)
                lost_run = lost_run + 1 if bad_quality else 0
                lost = recovered or no_person or lost_run >= o.loss_frames
                reinit_source = None
                if lost:
                    stats["lost_frames"] += 1
                    mean, reinit_source = self._reinit_mean(fd, masks, last_good)
                    if mean is not None:
                        state = self.filter.init(
                            self._key(t, 2), jnp.asarray(mean, dt), jnp.asarray(o.reinit_widen * self.std, dt)
                        )
                        stats["reinitialisations"] += 1
                        lost_run = 0
                        hist = []
                    else:
                        hist = [*hist, (t, est)][-2:]
                else:
                    last_good = est if not bad_quality else last_good
                    hist = [*hist, (t, est)][-2:]
                joints = np.asarray(_joint_positions(model, jnp.asarray(est, dt)), np.float64)
                pose_writer.append(t, est, export.eval_joints_of(model, joints))
                record.update(
                    quality=q,
                    recovered=recovered,
                    no_person=bool(no_person),
                    lost=bool(lost),
                    reinitialised=reinit_source is not None,
                    reinit_source=reinit_source,
                    seconds=time.monotonic() - t_frame,
                    layers=_layer_records(info.layers),
                )
                diag.append(record)
                self._checkpoint(
                    t, state, hist, last_good, q_ref, q_hist, lost_run, stats, pose_writer.num_frames, x0
                )
                if stats["first_frame_s"] is None:
                    stats["first_frame_s"] = time.monotonic() - t_frame
                progress.update(i + 1, "lost" if lost else "")
        except KeyboardInterrupt:
            interrupted = True
            progress.end_line()
        except BaseException:
            progress.end_line()
            pose_writer.close()
            diag.close()
            raise
        pose_writer.close()
        summary = self._finish(pose_writer, diag, stats, time.monotonic() - t_begin, interrupted, resumed_at)
        if interrupted:
            raise KeyboardInterrupt
        return summary

    def _detection(self, fd, masks, last_good) -> np.ndarray | None:
        """A detection-driven pose for the proposal: IK of triangulated keypoints, else the last good estimate
        moved over the silhouette centroid; None without a detection."""
        if self.o.filter not in ("icondensation", "iapf") or fd is None:
            return None
        mean, _ = self._reinit_mean(fd, masks, last_good)
        return mean

    def _reinit_mean(self, fd, masks, last_good) -> tuple[np.ndarray | None, str | None]:
        if fd is not None and fd.keypoints is not None:
            x = keypoint_pose(self.model, self.source.rig, fd.keypoints, init=last_good)
            if x is not None:
                return x, "keypoints"
        c = silhouette_centroid(self.features.rig, masks)
        if c is not None and last_good is not None:
            return _move_root_over(self.model, last_good, c), "silhouette"
        if last_good is not None:
            return np.asarray(last_good), "last_estimate"
        return None, None

    def _checkpoint(self, t, state, hist, last_good, q_ref, q_hist, lost_run, stats, rows, x0) -> None:
        D = self.model.num_dofs
        export.atomic_write_npz(
            self.out / RESUME_NPZ,
            {
                "frame": np.asarray(t),
                "rows": np.asarray(rows),
                "particles": np.asarray(state.particles),
                "log_weights": np.asarray(state.log_weights),
                "estimate": np.asarray(state.estimate),
                "hist_frames": np.asarray([f for f, _ in hist], np.int64),
                "hist_states": np.asarray([x for _, x in hist], np.float64).reshape(len(hist), D),
                "last_good": np.asarray(last_good),
                "x0": np.asarray(x0),
                "ref_frame": np.asarray(self._ref_frame),
                "q_ref": np.asarray(q_ref),
                "q_hist": np.asarray(q_hist, np.float64),
                "lost_run": np.asarray(lost_run),
                **{k: np.asarray(stats[k]) for k in ("reinitialisations", "lost_frames", "skipped")},
            },
            self.o.fsync,
        )

    def _finish(self, pose_writer, diag, stats, wall, interrupted, resumed_at) -> dict:
        model = self.model
        n = pose_writer.num_frames
        fps_steady = diag.frames_per_s()
        summary = {
            "frames_tracked": n,
            "frames_requested": len(self.frames),
            "frames_skipped": stats["skipped"],
            "lost_frames": stats["lost_frames"],
            "reinitialisations": stats["reinitialisations"],
            "wall_s": wall,
            "first_frame_s": stats["first_frame_s"],
            "frames_per_s": fps_steady,
            "interrupted": interrupted,
            "resumed_at": resumed_at,
            "compilations": self.trace_count,
            "model": model.name,
            "filter": self.o.filter,
            "particles": self.num_particles,
            "layers": self.layers,
            "cues": [list(c) for c in self.cues],
        }
        if n:
            export.save_model_bvh(self.out / export.TRACK_BVH, model, pose_writer.states, self.source.fps)
        if self.source.groundtruth is not None and n:
            from jaxmocap.eval import metrics

            try:
                rep = metrics.evaluate(
                    [(np.asarray(pose_writer.frames), pose_writer.joints)], self.source.groundtruth
                )
                summary["mean_error_mm"] = rep["overall_mean_mm"]
            except ValueError:  # nothing to compare (e.g. a diverged, non-finite track)
                summary["mean_error_mm"] = None
        diag.close(summary)
        if self.o.overlay and n and not interrupted:
            summary["overlays"] = [os.fspath(p) for p in self.write_overlays(pose_writer)]
        return summary

    def write_overlays(self, pose_writer) -> list[pathlib.Path]:
        """One MP4 per view of the tracked model drawn over the input (full size)."""
        from jaxmocap.eval import viz

        rig = self.source.rig
        rj = rig.to_jax(jnp.float32)
        model = self.model
        states = dict(zip(pose_writer.frames, pose_writer.states, strict=True))
        gt = self.source.groundtruth
        with viz.OverlayVideo(self.out, rig.names, rig.image_size, self.source.fps) as video:
            for t in self.frames:
                if t not in states:
                    continue
                try:
                    fd = self.source.read(t, masks=False)
                except BadFrame:
                    continue
                truth = None if gt is None else gt[t]
                video.write(viz.overlay_image(fd.images, model, rj, states[t], truth))
            return list(video.paths)


def _layer_records(layers) -> list[dict]:
    """Per-layer statistics (``LayerStats`` with a ``(L,)`` or ``(K, L)`` leading shape) as JSON records."""
    arrays = {k: np.asarray(v) for k, v in layers._asdict().items()}
    shape = arrays["beta"].shape
    out = []
    for idx in np.ndindex(*shape):
        rec = {k: (int(v[idx]) if v.dtype.kind in "iu" else float(v[idx])) for k, v in arrays.items()}
        if len(shape) == 2:
            rec["partition"], rec["layer"] = int(idx[0]), int(idx[1])
        else:
            rec["layer"] = int(idx[0])
        out.append(rec)
    return out
