"""The one setup of a tracking run: options + source → model, features, likelihood and filter.

:class:`TrackSetup` is what ``jaxmocap track`` (:class:`jaxmocap.tracking.tracker.Tracker`), the experiment sweep
(:mod:`jaxmocap.tracking.sweep`) and the PARSEC run build on. It validates the options against the input, builds
the body model (:func:`jaxmocap.tracking.options.build_model`), the cues (:func:`~jaxmocap.tracking.options.default_cues`
unless given), the feature pipeline (:class:`jaxmocap.tracking.features.FeatureBuilder`), the likelihood
(:func:`observation_loglik`: a :class:`jaxmocap.likelihood.compose.Likelihood` over the image cues with the λ_c(l)
table of the filter's annealing variant, and the ``coverage`` cue of :mod:`jaxmocap.likelihood.coverage` with its
column of the same table) and, once the initial pose is known, the filter (:func:`jaxmocap.filters.factory.make_filter`).

The frame loop (:mod:`jaxmocap.tracking.loop`) reads these hooks of a setup: ``observe(t)``,
``initial_state(t, masks, fd)``, ``set_references(x0, obs)``, ``make_filter(x0)``, ``start(filter, key, x0,
spread, obs)``, ``detection(fd, masks, last_good)``, ``reinit_mean(fd, masks, last_good)``, ``output_state(x)``,
``joints(x)``, optionally ``estimate_joints(est)`` (traced into the step), ``description()`` and the flags
``track_loss`` / ``resumable`` / ``velocity``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.choices import parse_frames
from jaxmocap.errors import MocapInputError
from jaxmocap.filters.factory import GRADIENT_FILTERS, make_filter, partition_counts
from jaxmocap.io.sources import BadFrame
from jaxmocap.likelihood import compose as lk
from jaxmocap.likelihood.coverage import coverage_energy, d_max_of
from jaxmocap.likelihood.cues import DIFFERENTIABLE
from jaxmocap.tracking import init as init_mod
from jaxmocap.tracking.features import FeatureBuilder, TrackObservation
from jaxmocap.tracking.options import (
    FILTERS,
    SINGLE_LAYER,
    TrackOptions,
    build_model,
    default_cues,
    default_layers,
    default_particles,
    diffusion_std,
    parse_cues,
)
from jaxmocap.tracking.progress import warn

__all__ = ["ObservationLoglik", "TrackSetup", "frame_range", "observation_loglik"]

#: Cues that read the foreground.
FOREGROUND_CUES = ("foreground", "coverage", "silhouette_divergence")


def frame_range(spec: str | None, num_frames: int) -> list[int]:
    """The input frames of ``--frames A:B`` (all without it)."""

    a, b = parse_frames(spec, num_frames)
    return list(range(a, b))


def observation_loglik(
    lik: lk.Likelihood | None,
    coverage_lambda=None,
    d_max=None,
    num_layers: int = 1,
    model=None,
    rig=None,
    params_data: bool = True,
) -> ObservationLoglik:
    """``loglik(X, tobs, layer) -> (N,)`` of a :class:`TrackObservation`: ``lik.batch`` on its image observation,
    minus the ``coverage`` cue ``λ_cov(l) Σ_v E_v`` (:func:`jaxmocap.likelihood.coverage.coverage_energy`) when
    ``coverage_lambda (L,)`` is given (the tracker adds it after the image cues' sum: the order of its float
    operations, on which the tracks depend bit for bit). It carries ``batch_value_and_grad(X, tobs, layer)``
    (per-particle gradients in one ``vmap``), which the gradient filters take
    (:func:`jaxmocap.likelihood.gradients.batch_value_and_grad`). The result is a pytree
    (:class:`ObservationLoglik`): held by a filter, its likelihood's parameters (cue weights, λ, view weights, the
    coverage λ) are data of the filter's step (constants with ``params_data=False``, see :class:`ObservationLoglik`)."""
    return ObservationLoglik(lik, coverage_lambda, d_max, model, rig, num_layers, params_data)


@dataclasses.dataclass(frozen=True, eq=False)
class ObservationLoglik:
    """The tracker's likelihood (:func:`observation_loglik`) as a pytree.

    Data (traced when a filter holding it is an argument of ``jit``): the parameters of the likelihood, its cue
    weights ``k_c (C,)``, λ table ``(L, C, V)`` and view weights ``(V,)``, and ``coverage_lambda (L,)``. Static:
    ``num_layers`` and the geometry — the likelihood's body model, rig, flesh points and references, and the
    coverage cue's ``model``, ``rig`` and ``d_max`` — held by identity (:class:`_Same`), so that they stay constants
    of the compiled program (folded by XLA as before: tracks identical bit for bit) while a likelihood that differs
    only in its parameters (``dataclasses.replace``) reuses it. Hashed by identity.

    ``params_data=False`` keeps the parameters constants too (a new value compiles anew): the tracker's gradient
    filters use it, since XLA compiles the reverse pass of ``λ_c k_c w_v E_c,v`` with traced factors into another
    order of float operations than with constant ones (the forward pass is the same bit for bit either way), and
    their tracks stay those of a program with the parameters folded in."""

    lik: lk.Likelihood | None
    coverage_lambda: jnp.ndarray | None
    d_max: jnp.ndarray | None
    model: object
    rig: object
    num_layers: int = 1
    params_data: bool = True

    def _layer(self, layer):
        return jnp.clip(jnp.asarray(getattr(layer, "index", layer)), 0, self.num_layers - 1)

    def _cover(self, x, tobs):
        im = tobs.image
        return jnp.sum(coverage_energy(self.model, self.rig, x, im.silhouette, im.silhouette_w, self.d_max))

    def __call__(self, X, tobs, layer):
        l = self._layer(layer)
        ll = jnp.zeros(X.shape[0], X.dtype) if self.lik is None else self.lik.batch(X, tobs.image, l)
        if self.coverage_lambda is not None:
            ll = ll - self.coverage_lambda[l] * jax.vmap(lambda x: self._cover(x, tobs))(X)
        return jnp.where(jnp.isfinite(ll), ll, -jnp.inf)

    def _one(self, x, tobs, l):
        ll = 0.0 if self.lik is None else self.lik.log_likelihood(x, tobs.image, l)
        if self.coverage_lambda is not None:
            ll = ll - self.coverage_lambda[l] * self._cover(x, tobs)
        return ll

    def batch_value_and_grad(self, X, tobs, layer):
        l = self._layer(layer)
        return lk.finite_value_and_grad(*jax.vmap(jax.value_and_grad(lambda x: self._one(x, tobs, l)))(X))


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


_LIK_PARAMS = ("cue_weights", "schedule", "view_weights")
_LIK_GEOMETRY = ("model", "rig", "surface", "references")


def _flatten_observation_loglik(f: ObservationLoglik):
    lik = f.lik
    params = None if lik is None else tuple(getattr(lik, n) for n in _LIK_PARAMS)
    geometry = None if lik is None else _Same(*(getattr(lik, n) for n in _LIK_GEOMETRY))
    config = None if lik is None else (lik.cues, lik.contour_points, lik.chunk_size)
    if f.params_data:
        children, constants = (params, f.coverage_lambda), None
    else:
        children, constants = (), _Same(params, f.coverage_lambda)
    aux = (geometry, config, _Same(f.d_max, f.model, f.rig), f.num_layers, constants)
    return children, aux


def _unflatten_observation_loglik(aux, children) -> ObservationLoglik:
    geometry, config, coverage, num_layers, constants = aux
    params, coverage_lambda = children if constants is None else constants.values
    lik = None
    if geometry is not None:
        cues, contour_points, chunk_size = config
        lik = lk.Likelihood(
            **dict(zip(_LIK_GEOMETRY, geometry.values, strict=True)),
            **dict(zip(_LIK_PARAMS, params, strict=True)),
            cues=cues,
            contour_points=contour_points,
            chunk_size=chunk_size,
        )
    d_max, model, rig = coverage.values
    return ObservationLoglik(lik, coverage_lambda, d_max, model, rig, num_layers, constants is None)


jax.tree_util.register_pytree_node(
    ObservationLoglik, _flatten_observation_loglik, _unflatten_observation_loglik
)


class TrackSetup:
    """Options + source → everything a run needs (module docstring).

    Attributes: ``o`` (the options), ``source``, ``frames``, ``model``, ``cues`` (``(name, weight)``),
    ``features``, ``layers``, ``num_particles`` (per layer, or a list of one count per partition), ``std``
    (diffusion per frame), ``likelihood`` (its colour references set by :meth:`set_references`).
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
        if any(n in FOREGROUND_CUES for n, _ in cues) and self.features.foreground == "none":
            raise ValueError("the foreground / coverage cues need a foreground (not --foreground none)")
        self.layers = o.layers if o.layers is not None else default_layers(o.filter)[0]
        if self.layers < 1:
            raise ValueError("--layers must be at least 1")
        if o.filter in SINGLE_LAYER and self.layers != 1:
            raise ValueError(
                f"the {o.filter} filter has no annealing layers (leave --layers out or set it to 1)"
            )
        n = o.particles if o.particles is not None else default_particles(self.model.name, o.filter)
        counts = partition_counts(self.model, o.filter, n)  # raises on a bad count
        self.num_particles = list(counts) if isinstance(n, (list, tuple)) else int(n)
        self.std = diffusion_std(self.model, source.fps) * float(o.diffusion_scale)
        self.likelihood = self._build_likelihood()

    @property
    def velocity(self) -> float:
        """Damping of the constant-velocity prediction of the root translation (0: none)."""
        return float(self.o.velocity)

    # -- likelihood ---------------------------------------------------------------------------------------------

    def _build_likelihood(self) -> lk.Likelihood | None:
        o = self.o
        names = [n for n, _ in self.cues]
        preset = o.filter if o.filter in ("fbapf", "fbapf2", "fbapf3", "m-apf") else "apf"
        table = lk.schedule_preset(preset, names, self.layers)  # (L, C): λ_c(l)
        gradient = o.filter in GRADIENT_FILTERS
        if gradient:
            flat = [n for n in names if DIFFERENTIABLE.get(n) == "no"]
            if flat:
                raise ValueError(
                    f"the {o.filter} filter needs a differentiable likelihood, but cue(s) {', '.join(flat)} "
                    "are piecewise constant in the pose; choose others with --cues (differentiable: "
                    + ", ".join(n for n, d in DIFFERENTIABLE.items() if d != "no")
                    + ")"
                )
        cue_objs, cols = [], []
        for c, (n, w) in enumerate(self.cues):
            if n == "coverage":  # composed by observation_loglik
                continue
            params = {}
            if gradient and DIFFERENTIABLE[n] in ("bilinear", "soft"):
                params = {"bilinear": True, **({"soft": True} if DIFFERENTIABLE[n] == "soft" else {})}
            if n == "keypoints":
                pairs = tuple((j, k) for j, k in init_mod.KEYPOINT_OF.items() if j in self.model.joint_names)
                params = {**params, "pairs": pairs}
            cue_objs.append(lk.Cue(n, w, params))
            cols.append(c)
        cov = [(c, w) for c, (n, w) in enumerate(self.cues) if n == "coverage"]
        self.coverage_lambda = jnp.asarray(table[:, cov[0][0]] * cov[0][1], jnp.float32) if cov else None
        rig = self.features.rig
        self.d_max = d_max_of(rig)
        self._rig = rig.to_jax(jnp.float32)
        if not cue_objs:
            return None
        return lk.Likelihood.create(
            self.model, rig, cue_objs, num_layers=self.layers, schedule=table[:, cols]
        )

    @property
    def loglik(self):
        """The filter's likelihood ``loglik(X, tobs, layer) -> (N,)`` (:func:`observation_loglik`)."""
        return observation_loglik(
            self.likelihood,
            self.coverage_lambda,
            self.d_max,
            self.layers,
            self.model,
            self._rig,
            params_data=self.o.filter not in GRADIENT_FILTERS,
        )

    def set_references(self, x0: np.ndarray, first: TrackObservation) -> None:
        """Reference data of the colour cues (histograms, templates) from the first tracked frame at ``x0``
        (:meth:`jaxmocap.likelihood.compose.Likelihood.with_references`); a resumed run recomputes them from the
        same frame and pose, so that it continues with the same likelihood."""
        lik = self.likelihood
        if lik is not None and lik.needs_references:
            dt = self.model.offset.dtype
            self.likelihood = lik.with_references(jnp.asarray(x0, dt), first.image)

    @property
    def needs_references(self) -> bool:
        return self.likelihood is not None and self.likelihood.needs_references

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
        )

    def start(self, filt, key, x0: np.ndarray, spread: float, obs):
        """The initial set: ``filter.init(key, x0, spread · Δ)``."""
        dt = self.model.offset.dtype
        del obs
        return filt.init(key, jnp.asarray(x0, dt), jnp.asarray(spread * self.std, dt))

    # -- frames -------------------------------------------------------------------------------------------------

    def observe(self, t: int):
        """``(tobs, masks, frame data, None)`` of frame ``t``, or ``(None, None, None, why)`` for an unreadable
        frame (skipped with a warning; fatal with ``on_bad_frame="stop"``)."""
        try:
            fd = self.source.read(t, masks=self.features.needs_masks, depth=self.features.needs_depth)
        except BadFrame as e:
            if self.o.on_bad_frame == "stop":
                raise MocapInputError(None, f"{e} (--on-bad-frame stop)") from None
            warn(f"skipping frame {t}: {e}")
            return None, None, None, str(e)
        tobs, masks = self.features(fd, self.model.num_dofs)
        return tobs, masks, fd, None

    def initial_state(self, t0: int, masks, fd) -> tuple[np.ndarray, float, str]:
        """``(x0, spread factor, how)`` for the first frame (:func:`jaxmocap.tracking.init.initial_state`)."""
        return init_mod.initial_state(self.model, self.source, self.features.rig, self.o.init, t0, masks, fd)

    def reinit_mean(self, fd, masks, last_good) -> tuple[np.ndarray | None, str | None]:
        """The re-initialisation pose after a track loss (:func:`jaxmocap.tracking.init.reinit_mean`)."""
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

    def estimate_joints(self, est: jnp.ndarray) -> jnp.ndarray:
        """``(J, 3)`` joints of the filter's estimate ``est (D,)`` (traceable: computed in the compiled step);
        the same as :meth:`joints` of ``output_state(est)``."""
        return init_mod.joint_positions(self.model, est)

    def joints(self, x: np.ndarray) -> np.ndarray:
        """``(J, 3)`` joints of the written state ``x``."""
        return np.asarray(
            init_mod.joint_positions(self.model, jnp.asarray(x, self.model.offset.dtype)), np.float64
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
            "particles": self.num_particles,
            "layers": self.layers,
            "frames": [self.frames[0], self.frames[-1] + 1],
            "fps": self.source.fps,
            "diffusion_std": self.std.tolist(),
            "jax": jax.__version__,
        }
