"""Tracking a PARSEC bodytrack sequence the way bodytrack does (``jaxmocap track SEQUENCE_B``).

The configuration of PARSEC's ``bodytrack`` (``jaxmocap/parsec/FORMAT.md`` §6): the ``parsec31`` body (10
cylinders, 31-value state), the PARSEC likelihood ``log p(z | x) = −(ErrEdge + ErrInside)`` summed over the cameras
(:mod:`jaxmocap.parsec.likelihood`; poses whose cylinders intersect are dropped), and the annealed particle filter
in PARSEC mode (:func:`jaxmocap.parsec.annealing.parsec_apf`: σ_l schedule 0.707σ_0, 0.5σ_0, … then σ_0 in the last layer,
β by bisection for α = 0.5, multinomial resampling, weighted-mean estimate, no motion model), by default with
bodytrack's 4000 particles × 5 layers.

**Initialisation** (§6.5, ``ParticleFilter.h:202-229``): ``x_i = x_0 + σ_0 ⊙ ε_i`` around ``InitialPose.txt``,
weighted against the first tracked frame with that frame's β: ``log w_i = β (ll_i − max ll)`` normalised. The
filter's first layer then resamples from these weights.

**Units.** The filter and the likelihood run in PARSEC's units (radians; the pelvis translation, entries 3–5, in
mm, like ``InitialPose.txt`` and σ_0). The outputs are in metres like every other run: ``state`` is
:func:`jaxmocap.parsec.model.to_metres` of the estimate, for the ``parsec31`` model built in metres
(radii and lengths / 1000: :func:`jaxmocap.parsec.model.parsec31_in_metres`), and the 15 evaluation joints are in
metres.

The run is the tracker's frame loop (:class:`jaxmocap.tracking.loop.TrackingLoop`) over :class:`ParsecSetup`: no
motion model beyond the annealing, no track-loss detection, no resume checkpoint.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap import host, parsec
from jaxmocap.errors import MocapInputError
from jaxmocap.filters import APF
from jaxmocap.filters.base import State
from jaxmocap.geometry import body as body_mod
from jaxmocap.parsec import annealing
from jaxmocap.parsec import likelihood as pl
from jaxmocap.stored_programs import StoredJit
from jaxmocap.tracking.loop import TrackingLoop
from jaxmocap.tracking.options import TrackOptions
from jaxmocap.tracking.outputs import check_export_options
from jaxmocap.tracking.progress import warn
from jaxmocap.tracking.setup import frame_range
from jaxmocap.transfer import to_device

__all__ = [
    "DEFAULT_LAYERS",
    "DEFAULT_PARTICLES",
    "ParsecSetup",
    "ParsecTracker",
    "make_loglik",
    "weighted_start",
]

#: bodytrack's standard configuration (PARSEC's native input set).
DEFAULT_PARTICLES = 4000
DEFAULT_LAYERS = 5


def make_loglik(shape: parsec.BodyShape, cams: parsec.Cameras) -> Callable:
    """``loglik(X (N, 31), observation, layer=None) -> (N,)``: the PARSEC log-likelihood (mm), −∞ for the poses
    bodytrack rejects (intersecting cylinders, returned as −1e10), so that the filter drops them as bodytrack does.

    The likelihood is one jitted function: the weighted start and the filter step, which both call it on ``(N, 31)``
    particles, share its trace (a warm one-frame run's preparation 3.9 s instead of 5.0 s, ``parsec_track.md``)."""
    batch = pl.make_loglik_batch(shape, cams)
    raw = jax.jit(lambda X, obs: batch(X, obs))  # called inside the run's programs: their options apply

    def loglik(X, obs, layer=None):
        ll = raw(X, obs)
        return jnp.where(ll <= -1e9, -jnp.inf, ll)

    return loglik


def weighted_start(filt: APF, loglik: Callable, key, x0, std, obs) -> State:
    """bodytrack's initial set: ``x_i = x0 + std ⊙ ε_i`` weighted against ``obs`` with PARSEC's β:
    ``log w_i = β (ll_i − max ll)`` normalised (−∞ for rejected poses)."""
    s = filt.init(key, x0, std)
    ll = loglik(s.particles, obs)
    b = annealing.parsec_beta(ll).beta
    top = jnp.max(jnp.where(jnp.isfinite(ll), ll, -jnp.inf))
    lw = jnp.where(jnp.isfinite(ll), b * (ll - top), -jnp.inf)
    return State(s.particles, lw - jax.scipy.special.logsumexp(lw), s.estimate)


def _f32(x) -> jax.Array:
    """A host array as a float32 device array, copied without a program (:func:`jaxmocap.transfer.to_device`)."""
    return to_device(x, np.float32)


def _unsupported(o) -> list[str]:
    """The track options that have no meaning for a PARSEC sequence (set to something else than the default)."""
    bad = []
    if o.model not in (None, "parsec31"):
        bad.append(f"--model {o.model} (PARSEC input is tracked with parsec31)")
    if o.filter != "apf":
        bad.append(f"--filter {o.filter} (PARSEC input uses the APF in bodytrack's configuration)")
    if o.cues is not None:
        bad.append("--cues (PARSEC input uses bodytrack's edge + inside likelihood)")
    if o.body is not None:
        bad.append("--body (the body is the sequence's BodyShapeParameters.txt)")
    if o.foreground != "auto":
        bad.append("--foreground (the sequence's FG<k> maps are used)")
    if o.downsample != 1:
        bad.append("--downsample")
    if o.overlay:
        bad.append("--overlay")
    if o.resume:
        bad.append("--resume")
    if o.init in ("groundtruth", "ik"):
        bad.append(f"--init {o.init} (use auto: InitialPose.txt, or a file of 31 numbers in its format)")
    return bad


class ParsecSetup:
    """The setup (:mod:`jaxmocap.tracking.setup`) of a PARSEC run: a :class:`jaxmocap.parsec.inputs.ParsecSource`
    and :class:`jaxmocap.tracking.options.TrackOptions`.

    Used options: ``particles`` (default :data:`DEFAULT_PARTICLES`, per layer), ``layers`` (default
    :data:`DEFAULT_LAYERS`), ``seed`` (frame ``t`` uses ``fold_in(key(seed), t)``; the initial set
    ``fold_in(fold_in(key(seed), t0), 1)``), ``frames``, ``init`` (``auto`` = the sequence's ``InitialPose.txt``, or
    a file of 31 numbers in its format), ``on_bad_frame``, ``overwrite``, ``fsync``; the others raise ``ValueError``.
    Attributes: ``model`` (``parsec31`` in metres), ``model_mm``, ``frames``, ``num_particles``, ``layers``,
    ``std`` (PARSEC's σ_0), ``cues``.
    """

    track_loss = False
    resumable = False
    velocity = 0.0
    needs_references = False
    features = None

    def __init__(self, source, options: TrackOptions | None = None):
        o = TrackOptions() if options is None else options
        bad = _unsupported(o)
        if bad:
            raise ValueError("not supported for a PARSEC bodytrack sequence: " + "; ".join(bad))
        if o.on_bad_frame not in ("skip", "stop"):
            raise ValueError("on_bad_frame must be 'skip' or 'stop'")
        self.o, self.source = o, source
        self.frames = frame_range(o.frames, source.num_frames)
        check_export_options(o.smooth, o.bvh_units, source.fps)
        self.num_particles = DEFAULT_PARTICLES if o.particles is None else int(o.particles)
        self.layers = DEFAULT_LAYERS if o.layers is None else int(o.layers)
        if self.num_particles < 2:
            raise ValueError("--particles must be at least 2")
        if self.layers < 1:
            raise ValueError("--layers must be at least 1")
        self.model_mm = parsec.parsec31(source.shape)
        self.model = parsec.parsec31_in_metres(source.shape)
        self.std = np.asarray(source.pose_parameters.std, np.float64)
        self.cues = [("parsec_edge", 1.0), ("parsec_inside", 1.0)]
        if o.init == "auto":
            self.x0, self.init_how = np.asarray(source.initial_pose, np.float64), "InitialPose.txt"
        else:
            self.x0, self.init_how = parsec.load_pose(o.init), "file"
        self._joints = jax.jit(lambda x: body_mod.joint_positions(self.model, x))
        self._filter = None

    def observe(self, t: int):
        """``(observation, None, None, None)``, or ``(None, None, None, why)`` for a frame skipped (the first frame
        and ``on_bad_frame="stop"``: the error)."""
        try:
            return self.source.observation(t), None, None, None
        except MocapInputError as e:
            if self.o.on_bad_frame == "stop" or t == self.frames[0]:
                raise
            warn(f"skipping frame {t}: {e}")
            return None, None, None, str(e)

    def initial_state(self, t0, masks, fd):
        return self.x0, 1.0, self.init_how

    def set_references(self, x0, obs) -> None:
        pass

    def make_filter(self, x0):
        """The APF in PARSEC mode on the PARSEC likelihood: one object per run, whatever ``x0`` (the filter does not
        depend on the first pose), so that the step compiled ahead (:meth:`compile_arguments`) is the step the
        frames call (its program is found by the filter's identity, a closure over the likelihood)."""
        if self._filter is None:
            self._loglik = make_loglik(self.source.shape, self.source.cameras)
            self._filter = annealing.parsec_apf(self._loglik, _f32(self.std), self.num_particles, self.layers)
        return self._filter

    def compile_arguments(self, key, obs):
        """``(filter, state)`` of the first step, the state as shapes (``jax.ShapeDtypeStruct``): the step is
        compiled (or read from the cache) in a thread while :meth:`start` runs (:mod:`jaxmocap.tracking.loop`,
        compiling ahead). The weighted start's state has the shapes and dtypes of ``filter.init``'s."""
        filt = self.make_filter(self.x0)
        pose = jax.ShapeDtypeStruct(self.x0.shape, jnp.float32)  # x0 and σ_0 as the start passes them (_f32)
        return filt, jax.eval_shape(filt.init, key, pose, pose)

    def start(self, filt, key, x0, spread, obs) -> State:
        """bodytrack's weighted initial set (:func:`weighted_start`)."""
        std = _f32(self.std)
        init = StoredJit(
            lambda k, x, ob: weighted_start(filt, self._loglik, k, x, std, ob),
            "weighted start " + self.program_tag(),
            key_structure=not self.tag_names_arguments,
            compiler_options=self.compiler_options(),
        )
        return init(key, _f32(x0), obs)

    #: the tag names the static structure of the step's arguments as well (the filter holds the likelihood, a
    #: closure over the body and the cameras, which the tag hashes): the structure stays out of the key
    tag_names_arguments = True

    def program_tag(self) -> str:
        """What the run's programs close over (:mod:`jaxmocap.stored_programs`): the body's dimensions, the
        cameras, σ_0, the particle and layer counts (the likelihood's configuration is the package's code)."""
        h = hashlib.sha256()
        shape, cams = self.source.shape, self.source.cameras
        for a in (shape.limbs, shape.lengths, *cams, self.std):
            h.update(np.ascontiguousarray(np.asarray(a, np.float64)).tobytes())
        return f"parsec31 apf {self.num_particles}x{self.layers} {h.hexdigest()}"

    def compiler_options(self) -> dict:
        """XLA's options for the run's step: the likelihood's (:func:`jaxmocap.host.particle_options`)."""
        return host.particle_options()

    def detection(self, fd, masks, last_good):
        return None

    def output_state(self, est_mm: np.ndarray) -> np.ndarray:
        """The estimate in metres (:func:`jaxmocap.parsec.model.to_metres`, in float64)."""
        x_m = np.asarray(est_mm, np.float64).copy()
        x_m[3:6] /= parsec.MM_PER_M
        return x_m

    def estimate_joints(self, est_mm: jnp.ndarray) -> jnp.ndarray:
        """The joints (metres) of the estimate, traced into the filter step."""
        return body_mod.joint_positions(self.model, parsec.to_metres(est_mm))

    def joints(self, x_m: np.ndarray) -> np.ndarray:
        return np.asarray(self._joints(_f32(x_m)), np.float64)

    def description(self) -> dict:
        return {
            "input": self.source.description,
            "model": "parsec31",
            "filter": "apf (PARSEC mode)",
            "likelihood": "parsec (edge + inside)",
            "particles": self.num_particles,
            "layers": self.layers,
            "seed": int(self.o.seed),
            "frames": [self.frames[0], self.frames[-1] + 1],
            "fps": self.source.fps,
            "init": self.init_how,
            "pose_std": self.std.tolist(),
            "units": "state: radians and metres (pelvis translation); joints: metres",
            "jax": jax.__version__,
        }


class ParsecTracker(TrackingLoop):
    """One PARSEC tracking run: ``ParsecTracker(source, out, options).run()``, the frame loop of
    :class:`jaxmocap.tracking.loop.TrackingLoop` over a :class:`ParsecSetup` (its attributes are the run's)."""

    def __init__(
        self, source, out: str | os.PathLike, options: TrackOptions | None = None, quiet: bool = False
    ):
        super().__init__(ParsecSetup(source, options), out, quiet)
