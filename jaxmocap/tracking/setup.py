"""The one setup of a tracking run: options + source → model, features, likelihood and filter.

:class:`TrackSetup` is what ``jaxmocap track`` (:class:`jaxmocap.tracking.tracker.Tracker`), the experiment sweep
(:mod:`jaxmocap.tracking.sweep`) and the PARSEC run build on. It validates the options against the input, builds
the body model (:func:`jaxmocap.tracking.options.build_model`), the cues (:func:`~jaxmocap.tracking.options.default_cues`
unless given), the feature pipeline (:class:`jaxmocap.tracking.features.FeatureBuilder`), the likelihood (one
:class:`jaxmocap.likelihood.compose.Likelihood` over every cue, the silhouette ``coverage`` cue included, with the
λ_c(l) table of the filter's annealing variant; :func:`observation_loglik` hands it to the filter) and, once the
initial pose is known, the filter (:func:`jaxmocap.filters.factory.make_filter`).

The frame loop (:mod:`jaxmocap.tracking.loop`) reads these hooks of a setup: ``observe(t)``,
``initial_state(t, masks, fd)``, ``set_references(x0, obs)``, ``make_filter(x0)``, ``start(filter, key, x0,
spread, obs)``, ``detection(fd, masks, last_good)``, ``reinit_mean(fd, masks, last_good)``, ``output_state(x)``,
``joints(x)``, optionally ``estimate_joints(est)`` and ``refine_step(state, info, tobs)`` (traced into the step:
:mod:`jaxmocap.tracking.refine`), ``program_tag()`` (a string fixing everything the step closes over besides its
arguments, whose structure is keyed by itself: the step is then kept on disk inside ``stored_programs.use``,
:mod:`jaxmocap.stored_programs`; here the refinement and the body model, PARSEC's names its arguments too:
``tag_names_arguments``), ``description()`` and the flags ``track_loss`` / ``resumable`` / ``velocity``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import pickle
from concurrent.futures import Future, ThreadPoolExecutor

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.choices import ANNEALINGS, DETECTORS, PROPOSALS, REFINEMENTS, VELOCITY_DOFS, parse_frames
from jaxmocap.errors import MocapInputError
from jaxmocap.filters.annealing import Schedule
from jaxmocap.filters.factory import GRADIENT_FILTERS, make_filter, partition_counts
from jaxmocap.io.read_ahead import ReadAhead
from jaxmocap.io.sources import BadFrame
from jaxmocap.likelihood import compose as lk
from jaxmocap.likelihood.cues import DIFFERENTIABLE
from jaxmocap.tracking import init as init_mod
from jaxmocap.tracking import presets
from jaxmocap.tracking.features import FeatureBuilder, TrackObservation
from jaxmocap.tracking.options import (
    FILTERS,
    SINGLE_LAYER,
    TrackOptions,
    build_model,
    default_cues,
    default_layers,
    default_particles,
    default_refine,
    default_refine_depth,
    diffusion_std,
    parse_cues,
)
from jaxmocap.tracking.outputs import check_export_options
from jaxmocap.tracking.progress import warn
from jaxmocap.tracking.refine import REFINE_ROBUST_PX, KeypointRefiner, refine_pairs
from jaxmocap.transfer import to_device

__all__ = ["ObservationLoglik", "TrackSetup", "frame_range", "observation_loglik"]

#: Cues that read the foreground.
FOREGROUND_CUES = ("foreground", "coverage", "silhouette_divergence")


#: Frames read ahead of the one being tracked (:meth:`TrackSetup.observe`).
READ_AHEAD = 2


def frame_range(spec: str | None, num_frames: int) -> list[int]:
    """The input frames of ``--frames A:B`` (all without it)."""

    a, b = parse_frames(spec, num_frames)
    return list(range(a, b))


def observation_loglik(
    lik: lk.Likelihood, num_layers: int = 1, params_data: bool = True
) -> ObservationLoglik:
    """``loglik(X, tobs, layer) -> (N,)`` of a :class:`TrackObservation`: ``lik.batch`` on its image observation
    (the layer index clipped to ``num_layers``). It carries ``batch_value_and_grad(X, tobs, layer)``
    (:meth:`jaxmocap.likelihood.compose.Likelihood.batch_value_and_grad`), which the gradient filters take
    (:func:`jaxmocap.likelihood.gradients.batch_value_and_grad`). The result is a pytree
    (:class:`ObservationLoglik`): held by a filter, its likelihood's parameters (cue weights, λ, view weights) are
    data of the filter's step (constants with ``params_data=False``, see :class:`ObservationLoglik`)."""
    return ObservationLoglik(lik, num_layers, params_data)


@dataclasses.dataclass(frozen=True, eq=False)
class ObservationLoglik:
    """The tracker's likelihood (:func:`observation_loglik`) as a pytree.

    Data (traced when a filter holding it is an argument of ``jit``): the parameters of the likelihood, its cue
    weights ``k_c (C,)``, λ table ``(L, C, V)`` and view weights ``(V,)``. Static: ``num_layers`` and the
    likelihood's geometry — body model, rig, flesh points and references — held by identity (:class:`_Same`), so
    that they stay constants of the compiled program (folded by XLA as before: tracks identical bit for bit) while
    a likelihood that differs only in its parameters (``dataclasses.replace``) reuses it. Hashed by identity.

    ``params_data=False`` keeps the parameters constants too (a new value compiles anew): the tracker's gradient
    filters use it, since XLA compiles the reverse pass of ``λ_c k_c w_v E_c,v`` with traced factors into another
    order of float operations than with constant ones (the forward pass is the same bit for bit either way), and
    their tracks stay those of a program with the parameters folded in."""

    lik: lk.Likelihood
    num_layers: int = 1
    params_data: bool = True

    def _layer(self, layer):
        return jnp.clip(jnp.asarray(getattr(layer, "index", layer)), 0, self.num_layers - 1)

    def __call__(self, X, tobs, layer):
        return self.lik.batch(X, tobs.image, self._layer(layer), lk.layer_partition(layer))

    def batch_value_and_grad(self, X, tobs, layer):
        return self.lik.batch_value_and_grad(X, tobs.image, self._layer(layer), lk.layer_partition(layer))


class _Same:
    """Objects held in a tree structure: equal to another holder only when it holds the very same objects (hash by
    their ids; the holder keeps them alive)."""

    __slots__ = ("values",)

    def __init__(self, *values):
        self.values = values

    def __eq__(self, other):
        return (
            isinstance(other, _Same)
            and len(other.values) == len(self.values)
            and all(a is b for a, b in zip(self.values, other.values, strict=True))
        )

    def __hash__(self):
        return hash(tuple(id(v) for v in self.values))


_LIK_PARAMS = ("cue_weights", "schedule", "view_weights", "partition_weights")
_LIK_GEOMETRY = ("model", "rig", "surface", "references")


def _flatten_observation_loglik(f: ObservationLoglik):
    lik = f.lik
    params = tuple(getattr(lik, n) for n in _LIK_PARAMS)
    geometry = _Same(*(getattr(lik, n) for n in _LIK_GEOMETRY))
    config = (lik.cues, lik.contour_points, lik.chunk_size)
    # without params_data each array is held by identity (a new tuple of the same arrays is the same structure)
    children, constants = ((params,), None) if f.params_data else ((), _Same(*params))
    return children, (geometry, config, f.num_layers, constants)


def _unflatten_observation_loglik(aux, children) -> ObservationLoglik:
    geometry, config, num_layers, constants = aux
    params = children[0] if constants is None else tuple(constants.values)
    cues, contour_points, chunk_size = config
    lik = lk.Likelihood(
        **dict(zip(_LIK_GEOMETRY, geometry.values, strict=True)),
        **dict(zip(_LIK_PARAMS, params, strict=True)),
        cues=cues,
        contour_points=contour_points,
        chunk_size=chunk_size,
    )
    return ObservationLoglik(lik, num_layers, constants is None)


jax.tree_util.register_pytree_node(
    ObservationLoglik, _flatten_observation_loglik, _unflatten_observation_loglik
)


class TrackSetup:
    """Options + source → everything a run needs (module docstring).

    Attributes: ``o`` (the options), ``source``, ``frames``, ``model``, ``cues`` (``(name, weight)``),
    ``features``, ``layers``, ``num_particles`` (per layer, or a list of one count per partition), ``std``
    (diffusion per frame), ``likelihood`` (its colour references set by :meth:`set_references`), ``preset``
    (the :class:`~jaxmocap.tracking.presets.Preset` of ``o.preset`` or None), ``groups`` / ``parts`` (the
    preset's partitions for a partitioned filter: DOF groups and body parts; None: the model's default groups,
    :func:`jaxmocap.filters.factory.partition_groups`, weighed with the whole body).
    """

    track_loss = True
    resumable = True

    def __init__(self, source, options: TrackOptions | None = None):
        o = TrackOptions() if options is None else options
        self.o, self.source = o, source
        if o.filter not in FILTERS:
            raise ValueError(f"unknown filter {o.filter!r}; choose one of {', '.join(FILTERS)}")
        if o.on_bad_frame not in ("skip", "stop"):
            raise ValueError("on_bad_frame must be 'skip' or 'stop'")
        self.frames = frame_range(o.frames, source.num_frames)
        #: what was assumed or converted about the input, for the user (the source's notes, then the setup's)
        self.notes = list(getattr(source, "notes", []))
        self.preset = presets.get(o.preset) if o.preset is not None else None
        self.body_dimensions = self._measured_body()
        self._note_view_noise()
        body = None if o.body in ("detections", "calibrate") else o.body
        # dimensions measured from the detections replace the input's own body file (``body = "detections"``)
        fallback = None if self.body_dimensions else source.body_path
        check_export_options(o.smooth, o.bvh_units, source.fps)
        self.model = build_model(o.model, body, fallback, self.body_dimensions)
        self.groups, self.parts = presets.partition_layout(self.preset, self.model, o.filter)
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
        if any(n in FOREGROUND_CUES for n, _ in cues) and self.features.foreground == "none":
            raise ValueError("the foreground / coverage cues need a foreground (not --foreground none)")
        self._check_camera_order()
        if o.proposal not in PROPOSALS:
            raise ValueError(f"unknown proposal {o.proposal!r}; choose one of {', '.join(PROPOSALS)}")
        if o.velocity_dofs not in VELOCITY_DOFS:
            raise ValueError(
                f"unknown velocity_dofs {o.velocity_dofs!r}; choose one of {', '.join(VELOCITY_DOFS)}"
            )
        if o.annealing not in ANNEALINGS:
            raise ValueError(f"unknown annealing {o.annealing!r}; choose one of {', '.join(ANNEALINGS)}")
        if o.refine not in REFINEMENTS:
            raise ValueError(f"unknown refine {o.refine!r}; choose one of {', '.join(REFINEMENTS)}")
        if o.detector not in DETECTORS:
            raise ValueError(f"unknown detector {o.detector!r}; choose one of {', '.join(DETECTORS)}")
        fixed = Schedule.iros2007() if o.annealing == "iros2007" else None
        self.layers = o.layers if o.layers is not None else default_layers(o.filter)[0]
        if fixed is not None and o.layers is None and o.filter not in SINGLE_LAYER:
            self.layers = fixed.num_layers
        if fixed is not None and o.filter not in SINGLE_LAYER and self.layers != fixed.num_layers:
            raise ValueError(
                f"--annealing iros2007 has {fixed.num_layers} layers (leave --layers out or set it to 3)"
            )
        self.annealing = fixed if o.filter not in SINGLE_LAYER else None
        self.head_hands = None
        # the last frame's head-and-hands detection (:meth:`head_hands_pose`): its frame, reference, whether a head
        # was seen, and the pose
        self._hh_fd = self._hh_ref = self._hh_pose = None
        self._hh_seen = False
        # the detector's image work (:meth:`_sighting`): of the frame observed last, started in a thread when it
        # was read (frame, future), and of the frame decided last (frame, sighting)
        self._hh_look = self._hh_sight = self._hh_worker = None
        # the frames read ahead (:meth:`observe`), and each frame's place in the run (the frames after it)
        self._reader = ReadAhead(self._read)
        self._place = {t: k for k, t in enumerate(self.frames)}
        if o.proposal == "head-hands" or o.init == "head-hands":
            from jaxmocap.tracking.head_hands import HeadHandsDetector

            self.head_hands = HeadHandsDetector(source.rig)
        if self.layers < 1:
            raise ValueError("--layers must be at least 1")
        if o.filter in SINGLE_LAYER and self.layers != 1:
            raise ValueError(
                f"the {o.filter} filter has no annealing layers (leave --layers out or set it to 1)"
            )
        self.refine, prior = default_refine(source.rig.num_views, source.has_keypoints)
        self.refine = self.refine if o.refine == "auto" else o.refine
        self.refine_prior = prior if o.refine_prior is None else float(o.refine_prior)
        refined_views = self.refine == "track" and source.rig.num_views >= 3
        n = (
            o.particles
            if o.particles is not None
            else default_particles(self.model.name, o.filter, refined_views)
        )
        counts = partition_counts(self.model, o.filter, n, self.groups)  # raises on a bad count
        self.num_particles = list(counts) if isinstance(n, (list, tuple)) else int(n)
        if o.body == "calibrate":
            self.model = self._calibrated_model()
        self.std = diffusion_std(self.model, source.fps) * float(o.diffusion_scale)
        self.likelihood = self._build_likelihood()
        if self.refine != "none" and not source.has_keypoints:
            raise ValueError(f"--refine {self.refine} needs 2D keypoints (--keypoints)")
        depth_sigma = (
            default_refine_depth(self.refine, source.has_depth, source.rig.num_views)
            if o.refine_depth is None
            else o.refine_depth
        )
        self.refine_depth = float(depth_sigma) if self.refine != "none" else 0.0
        if self.refine_depth < 0:
            raise ValueError(
                f"refine_depth must be a standard deviation in metres (0 = none), got {o.refine_depth}"
            )
        if self.refine_depth > 0 and not source.has_depth:
            raise ValueError("--refine-depth needs depth maps (a sequence with depth/ or --depth)")
        if self.refine_depth > 0:  # the depth maps reach the step even when no cue reads them
            self.features.needs_depth = True
        self.refiner = None
        if self.refine != "none":
            f = self.features.extractor.config.downsample
            self.refiner = KeypointRefiner(
                self.model, self.features.rig, refine_pairs(self.model), init_mod.KEYPOINT_SIGMA_PX / f,
                self.refine_prior, self.refine, robust_px=REFINE_ROBUST_PX / f,
                depth_sigma=self.refine_depth or None,
            )  # fmt: skip

    def refine_step(self, state, info, tobs):
        """The filter's ``(State, Info)`` after a frame with its estimate refined on the frame's detections
        (:mod:`jaxmocap.tracking.refine`; traced into the step); unchanged without a refinement."""
        if self.refiner is None:
            return state, info
        return self.refiner(state, info, tobs.image)

    def _check_camera_order(self, num: int = 16) -> None:
        """Inputs whose calibration no detections have checked (``source.check_silhouettes``): the centroids of
        the foreground of ``num`` frames spread over the run, seen by the static background, must triangulate
        better in the calibration's camera order than in any other
        (:func:`jaxmocap.io.subject.check_rig_silhouettes`)."""
        src, fb = self.source, self.features
        if not getattr(src, "check_silhouettes", False) or fb.foreground != "median" or src.rig.num_views < 2:
            return
        from jaxmocap.io.subject import check_rig_silhouettes

        frames = self.frames
        pick = sorted(
            {frames[int(i)] for i in np.round(np.linspace(0, len(frames) - 1, min(num, len(frames))))}
        )
        centroids = np.full((len(pick), src.rig.num_views, 2), np.nan)
        for i, t in enumerate(pick):
            try:
                fd = src.read(t, masks=False, depth=False)
            except BadFrame:
                continue
            masks = fb.extractor.foreground_masks(fb.extractor._check_frames(fd.images), None)
            for v, m in enumerate(masks):
                ys, xs = np.nonzero(m)
                if xs.size >= 50:
                    centroids[i, v] = xs.mean(), ys.mean()
        check_rig_silhouettes(fb.rig, centroids, src.description.get("calibration"))

    def _note_view_noise(self) -> None:
        """With detections in three or more views: each camera's keypoint noise, measured from how its detections
        agree with the other cameras' (:func:`jaxmocap.io.subject.view_noise`), in the run's notes with the
        cameras to check (:func:`jaxmocap.io.subject.view_noise_notes`). Told, not used: weighing each view's
        detections in the refinement by ``(σ̄/σ_v)²`` moved the leave-one-camera-out errors of
        ``benchmarks/experiments/pose2sim_track.py --leave-one-out`` up for three of the four held-out cameras
        (35.0 / 14.7 / 42.5 / 18.4 px against 34.1 / 13.8 / 40.2 / 19.1, seeds 0-2 alike): the cameras there
        disagree by biases (calibration, where the detector puts a joint), not by noise."""
        src = self.source
        if not src.has_keypoints or src.rig.num_views < 3:
            return
        from jaxmocap.io.subject import view_noise, view_noise_notes

        self.notes.extend(view_noise_notes(list(src.rig.names), view_noise(src.keypoints, src.rig)))

    def _measured_body(self) -> dict | None:
        """The subject's dimensions measured from the input's detections (``body = "detections"``, or no body
        file and an input with detections), or None."""
        o, src = self.o, self.source
        wanted = o.body == "detections" or (o.body is None and src.body_path is None and src.has_keypoints)
        if not wanted or o.model == "parsec31":
            return None
        if not src.has_keypoints:
            raise ValueError("--body detections needs 2D keypoints (--keypoints)")
        from jaxmocap.io.subject import body_dimensions

        dims = body_dimensions(src.keypoints, src.rig)
        if len(dims) < 6:
            kept = "the input's body file" if src.body_path is not None else "preset body dimensions"
            self.notes.append(f"too few triangulated detections to measure the subject: {kept}")
            return None
        shown = ", ".join(
            f"{k.replace('_length', '')} {v:.2f}" for k, v in dims.items() if k.endswith("length")
        )
        self.notes.append(f"body dimensions measured from the triangulated detections (m): {shown}")
        return dims

    #: frames (the first of the run) that ``body = "calibrate"`` fits the dimensions to, and the lengths it fits
    #: (with every radius)
    CALIBRATION_FRAMES = 10
    CALIBRATED = (
        "shoulder_width",
        "hip_width",
        "upper_arm_length",
        "forearm_length",
        "thigh_length",
        "shin_length",
    )

    def _calibrated_model(self):
        """``body = "calibrate"``: the preset with the dimensions fitted to the first :data:`CALIBRATION_FRAMES`
        readable frames of the run (:func:`jaxmocap.fit.shape_start.calibrate_from_start` on this run's
        foreground and the input's detections), starting from the dimensions measured from the detections
        (:func:`jaxmocap.io.subject.body_dimensions`, as ``body = "detections"``); the :data:`CALIBRATED` lengths
        and the radii are fitted, the torso column (torso length, drops, neck) kept as measured. The calibration
        frames go through the run's feature builder, so an adaptive foreground (``mog2``, ``adaptive``) has seen
        them once more before the run starts."""
        from jaxmocap.fit.shape_start import calibrate_from_start

        src, fb = self.source, self.features
        if not src.has_keypoints:
            raise ValueError("--body calibrate needs 2D keypoints (--keypoints)")
        if self.o.model in ("parsec31",):
            raise ValueError(
                "--body calibrate fits the full25/full32/upper presets' dimensions, not parsec31's"
            )
        obs, kept = [], []
        for t in self.frames:
            if len(obs) == self.CALIBRATION_FRAMES:
                break
            try:
                fd = src.read(t, masks=fb.needs_masks, depth=False)
            except BadFrame:
                continue
            tobs, _ = fb(fd, self.model.num_dofs)
            if not tobs.image.has("foreground"):
                raise ValueError("--body calibrate needs a foreground (the foreground or coverage cue)")
            obs.append(tobs.image)
            kept.append(t)
        if not obs:
            raise ValueError("--body calibrate: no readable frame in the run")
        stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *obs)
        from jaxmocap.fit.shape import RADII
        from jaxmocap.io.subject import body_dimensions

        # the detections' convention for the torso (root = the middle of the detected hips, thorax = the detected
        # neck: :func:`body_dimensions`), which the silhouettes do not decide; the limbs, widths and radii fitted
        measured = body_dimensions(src.keypoints, src.rig)
        fit = calibrate_from_start(
            stacked,
            fb.rig,
            np.asarray(src.keypoints)[kept],
            keypoint_rig=src.rig,
            preset=self.model.name,
            init=measured if len(measured) >= 6 else None,
            measure=False,
            names=self.CALIBRATED + RADII,
        )
        self.body_dimensions = fit.dims
        self.notes.append(
            f"body dimensions calibrated on frames {kept[0]}–{kept[-1]} ({len(fit.frames)} with a pose from the "
            "detections): " + ", ".join(f"{k} {v:.3f}" for k, v in fit.dims.items() if k in fit.start_dims)
        )
        return build_model(self.o.model, None, None, fit.dims)

    @property
    def velocity(self) -> float:
        """Damping of the constant-velocity prediction (0: none) of the DOFs of ``velocity_dofs``."""
        return float(self.o.velocity)

    # -- likelihood ---------------------------------------------------------------------------------------------

    def _build_likelihood(self) -> lk.Likelihood:
        o = self.o
        names = [n for n, _ in self.cues]
        preset = o.filter if o.filter in ("fbapf", "fbapf2", "fbapf3", "m-apf") else "apf"
        if self.preset is not None and self.preset.schedule is not None:
            preset = self.preset.schedule
        table = lk.schedule_preset(preset, names, self.layers)  # (L, C): λ_c(l)
        gradient = o.filter in GRADIENT_FILTERS
        if (
            gradient
        ):  # every cue in its differentiable configuration (cues.DIFFERENTIABLE); one without is refused
            flat = [n for n in names if DIFFERENTIABLE.get(n) == "no"]
            if flat:
                raise ValueError(
                    f"the {o.filter} filter needs a differentiable likelihood, but cue(s) {', '.join(flat)} "
                    "are piecewise constant in the pose and have no differentiable variant; choose others with "
                    "--cues (differentiable: "
                    + ", ".join(n for n, d in DIFFERENTIABLE.items() if d != "no")
                    + ")"
                )
        cue_objs = []
        for n, w in self.cues:
            params = {}
            if gradient and DIFFERENTIABLE[n] in (
                "bilinear",
                "soft",
            ):  # bilinear reads; "soft": smooth tests too
                params = {"bilinear": True, **({"soft": True} if DIFFERENTIABLE[n] == "soft" else {})}
            if n == "keypoints":
                pairs = tuple((j, k) for j, k in init_mod.KEYPOINT_OF.items() if j in self.model.joint_names)
                params = {**params, "pairs": pairs}
            if self.preset is not None:
                params = {**self.preset.cue_params.get(n, {}), **params}
            cue_objs.append(lk.Cue(n, w, params))
        lik = lk.Likelihood.create(
            self.model, self.features.rig, cue_objs, num_layers=self.layers, schedule=table
        )
        if self.parts is not None and self.preset.partition_cues:
            whole = [n for n in names if not lk.cues.CUES[n].partial]
            if whole:
                self.notes.append(
                    f"cue(s) {', '.join(whole)} weigh the whole body in every partition (only "
                    f"{', '.join(lk.cues.PARTIAL_CUES)} are restricted to a partition's body parts)"
                )
            lik = lik.with_partitions(self.parts)
        return lik

    @property
    def loglik(self):
        """The filter's likelihood ``loglik(X, tobs, layer) -> (N,)`` (:func:`observation_loglik`)."""
        return observation_loglik(
            self.likelihood, self.layers, params_data=self.o.filter not in GRADIENT_FILTERS
        )

    def set_references(self, x0: np.ndarray, first: TrackObservation) -> None:
        """Reference data of the colour cues (histograms, templates) from the first tracked frame at ``x0``
        (:meth:`jaxmocap.likelihood.compose.Likelihood.with_references`); a resumed run recomputes them from the
        same frame and pose, so that it continues with the same likelihood."""
        lik = self.likelihood
        if lik.needs_references:
            dt = self.model.offset.dtype
            self.likelihood = lik.with_references(to_device(x0, dt), first.image)

    @property
    def needs_references(self) -> bool:
        return self.likelihood.needs_references

    def quality(self, loglik_max: np.ndarray) -> float:
        """The frame's ``q_t`` (:mod:`jaxmocap.tracking.loop`) from the step's best log-likelihood per layer
        (``(K, L)`` for a partitioned filter): the last layer's, or with a likelihood restricted to each
        partition's body parts the sum of every partition's last-layer best (each partition alone weighs only
        its own parts)."""
        top = np.asarray(loglik_max, np.float64)
        if self.parts is not None and self.likelihood.partition_weights is not None:
            return float(-np.sum(top.reshape(top.shape[0], -1)[:, -1]))
        return float(-top.reshape(-1)[-1])

    # -- filter -------------------------------------------------------------------------------------------------

    def make_filter(self, x0: np.ndarray):
        """The filter of the options around ``x0`` (the prior of ICONDENSATION / IAPF)."""
        return make_filter(
            self.o.filter,
            self.loglik,
            self.model,
            self.std,
            self.num_particles,
            self.layers,
            prior_mean=x0,
            prior_std=3.0 * self.std,
            survival_target=self.o.survival_target,
            groups=self.groups,
            keep_layers=bool(self.o.count_modes),
            annealing=self.annealing,
            importance={
                k: float(getattr(self.o, k))
                for k in ("dynamics_fraction", "detection_fraction")
                if getattr(self.o, k) is not None
            },
        )

    def compile_arguments(self, key, obs):
        """``(filter, state)`` with the structure and shapes of the first step's, before the initial pose is known
        (:mod:`jaxmocap.tracking.loop`, compiling ahead): the filter around the rest pose (the pose is data of the
        filter) and the state as shapes (``jax.ShapeDtypeStruct``); None when the colour cues' references, taken
        at the initial pose, are still to be set (they are part of the likelihood's structure)."""
        if self.needs_references:
            return None
        x0 = np.asarray(self.model.rest_pose, np.float64)
        filt = self.make_filter(x0)
        return filt, jax.eval_shape(lambda k: self.start(filt, k, x0, 1.0, obs), key)

    def start(self, filt, key, x0: np.ndarray, spread: float, obs):
        """The initial set: ``filter.init(key, x0, spread · Δ)``."""
        dt = self.model.offset.dtype
        del obs
        return filt.init(key, to_device(x0, dt), to_device(spread * self.std, dt))

    # -- frames -------------------------------------------------------------------------------------------------

    def observe(self, t: int):
        """``(tobs, masks, frame data, None)`` of frame ``t``, or ``(None, None, None, why)`` for an unreadable
        frame (skipped with a warning; fatal with ``on_bad_frame="stop"``).

        The frame comes from :meth:`_read`, read ahead in a thread (:class:`jaxmocap.io.read_ahead.ReadAhead`)
        when an earlier call asked for it; this call has the run's next :data:`READ_AHEAD` frames read there, so
        that their decoding and the head-and-hands detector's image work overlap this frame's features and the
        filter's step (the image work of a frame gets a frame's time and more before the frame's proposal waits
        for it)."""
        try:
            k = self._place.get(t)
            ahead = () if k is None else self.frames[k + 1 : k + 1 + READ_AHEAD]
            fd, seen = self._reader(t, ahead=ahead)
        except BadFrame as e:
            if self.o.on_bad_frame == "stop":
                raise MocapInputError(None, f"{e} (--on-bad-frame stop)") from None
            warn(f"skipping frame {t}: {e}")
            return None, None, None, str(e)
        if seen is not None:
            self._hh_look = (fd, seen)
        tobs, masks = self.features(fd, self.model.num_dofs)
        return tobs, masks, fd, None

    def _read(self, t: int):
        """``(frame data, sighting)`` of frame ``t``: the source's images (with the masks and depth maps the
        features need) and, with the head-and-hands proposal, the future of the detector's image work on them
        (:meth:`~jaxmocap.tracking.head_hands.HeadHandsDetector.look`: OpenCV, no pose needed) in a thread of its
        own, else None."""
        fd = self.source.read(t, masks=self.features.needs_masks, depth=self.features.needs_depth)
        seen = None
        if self.o.proposal == "head-hands":
            seen = self._head_hands_worker().submit(self.head_hands.look, fd.images)
        return fd, seen

    def finish_reads(self) -> None:
        """Wait for the frames being read ahead (:meth:`observe`): before anything else reads or closes the
        source."""
        self._reader.wait()

    def _sighting(self, fd):
        """The head-and-hands detector's image work on frame data ``fd`` (:meth:`~jaxmocap.tracking.head_hands.
        HeadHandsDetector.look`): from the thread it was started in when the frame was read, or done now."""
        for held in (self._hh_sight, self._hh_look):
            if held is not None and held[0] is fd:
                seen = held[1].result() if isinstance(held[1], Future) else held[1]
                break
        else:
            seen = self.head_hands.look(fd.images)
        self._hh_sight = (fd, seen)
        return seen

    def _head_hands_worker(self):
        """The thread that runs the head-and-hands detector's image work (:meth:`_read`), started once."""
        if self._hh_worker is None:
            self._hh_worker = ThreadPoolExecutor(1, thread_name_prefix="jaxmocap-head-hands")
        return self._hh_worker

    def check_initial(self, t0: int) -> None:
        """Fail now where ``--init`` cannot work (:func:`jaxmocap.tracking.init.check_initial`)."""
        init_mod.check_initial(self.model, self.source, self.o.init, t0)

    def initial_state(self, t0: int, masks, fd) -> tuple[np.ndarray, float, str]:
        """``(x0, spread factor, how)`` for the first frame (:func:`jaxmocap.tracking.init.initial_state`);
        ``init = "head-hands"``: the head-and-hands pose (:meth:`head_hands_pose`), else — nobody seen — the rest
        pose standing 3 m in front of the first camera (``"default"``, lost until a person is seen)."""
        if self.o.init == "head-hands":
            x = self.head_hands_pose(fd, None)
            if x is not None:
                return x, 1.0, "head-hands"
            return init_mod.default_standing(self.model, self.source.rig), 3.0, "default"
        return init_mod.initial_state(self.model, self.source, self.features.rig, self.o.init, t0, masks, fd)

    def warm_reinit(self, how: str | None) -> None:
        """Compile ahead the re-initialisation from detections (:func:`jaxmocap.tracking.init.warm_keypoint_pose`)
        when the input has detections but the first pose (``how``; None: a resumed run) did not come from them, and
        the head-and-hands fit (:func:`jaxmocap.tracking.head_hands.warm_head_hands_pose`) when the run uses it: in
        a thread of the loop's, before the first frame is tracked (:mod:`jaxmocap.tracking.loop`)."""
        if self.head_hands is not None:
            from jaxmocap.tracking.head_hands import warm_head_hands_pose

            warm_head_hands_pose(self.model, self.source.rig)
        if how != "ik-keypoints" and self.source.has_keypoints and self.o.proposal != "head-hands":
            init_mod.warm_keypoint_pose(
                self.model, self.source.rig, bool(getattr(self.source, "has_depth", False))
            )

    def head_hands_pose(self, fd, reference) -> np.ndarray | None:
        """The pose of the frame's head and hands (:mod:`jaxmocap.tracking.head_hands`; ``reference``: the last
        good estimate), or None when no head is seen. Computed once per frame (the proposal and a
        re-initialisation share it)."""
        if fd is None or self.head_hands is None:
            return None
        ref = None if reference is None else np.asarray(reference, np.float64).tobytes()
        if self._hh_fd is not fd or self._hh_ref != ref:
            from jaxmocap.tracking.head_hands import head_hands_pose

            det = self.head_hands.decide(self._sighting(fd), self.model, reference)
            # the frame is held, so that a later frame cannot take its id
            self._hh_fd, self._hh_ref, self._hh_seen, self._hh_pose = fd, ref, det is not None, None
            if det is not None:
                self._hh_pose = head_hands_pose(self.model, det, reference)
        return self._hh_pose

    def person_absent(self, fd) -> bool:
        """With the head-and-hands proposal: no head is seen in the frame (the track counts as lost)."""
        if self.o.proposal != "head-hands" or fd is None:
            return False
        if self._hh_fd is not fd:
            self.head_hands_pose(fd, None)
        return not self._hh_seen

    def reinit_mean(self, fd, masks, last_good) -> tuple[np.ndarray | None, str | None]:
        """The re-initialisation pose after a track loss (:func:`jaxmocap.tracking.init.reinit_mean`; with the
        head-and-hands proposal, that pose from the frame's skin blobs, or None without a head)."""
        if self.o.proposal == "head-hands":
            x = self.head_hands_pose(fd, last_good)
            return (x, "head-hands") if x is not None else (None, None)
        return init_mod.reinit_mean(self.model, self.source.rig, self.features.rig, fd, masks, last_good)

    def detection(self, fd, masks, last_good) -> np.ndarray | None:
        """A detection-driven pose for the proposal (ICONDENSATION / IAPF only); None without a detection."""
        if self.o.filter not in ("icondensation", "iapf") or fd is None:
            return None
        return self.reinit_mean(fd, masks, last_good)[0]

    # -- outputs ------------------------------------------------------------------------------------------------

    def output_state(self, x: np.ndarray) -> np.ndarray:
        """The state written for the filter's estimate ``x`` (the same state)."""
        return x

    def program_tag(self) -> str | None:
        """What the filter step closes over besides its arguments (:mod:`jaxmocap.stored_programs`): the
        refinement (:meth:`refine_step`) and the body model (:meth:`estimate_joints`), as the SHA-256 of their
        pickle; the filter, the likelihood's geometry among its static data, is an argument and keyed by its
        structure. None (the step is traced every run) when they cannot be pickled."""
        try:
            blob = pickle.dumps((type(self).__qualname__, self.refiner, self.model), protocol=5)
        except Exception:  # noqa: BLE001 (traced as usual)
            return None
        return hashlib.sha256(blob).hexdigest()

    def estimate_joints(self, est: jnp.ndarray) -> jnp.ndarray:
        """``(J, 3)`` joints of the filter's estimate ``est (D,)`` (traceable: computed in the compiled step);
        the same as :meth:`joints` of ``output_state(est)``."""
        return init_mod.joint_positions(self.model, est)

    def joints(self, x: np.ndarray) -> np.ndarray:
        """``(J, 3)`` joints of the written state ``x``."""
        return np.asarray(
            init_mod.joint_positions(self.model, to_device(x, self.model.offset.dtype)), np.float64
        )

    def description(self) -> dict:
        """``run.json``: options, input, model and what the defaults resolved to."""
        import jax

        return {
            "options": self.o.identity(),
            "input": self.source.description,
            "model": self.model.name,
            "dof_names": list(self.model.dof_names),
            "cues": [list(c) for c in self.cues],
            "refine": self.refine,
            "refine_prior": self.refine_prior,
            "refine_depth": self.refine_depth,
            "particles": self.num_particles,
            "layers": self.layers,
            "frames": [self.frames[0], self.frames[-1] + 1],
            "fps": self.source.fps,
            "diffusion_std": self.std.tolist(),
            "body_dimensions": self.body_dimensions,
            "jax": jax.__version__,
        }
