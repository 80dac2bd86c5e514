"""Tracking a PARSEC bodytrack sequence the way bodytrack does (``jaxmocap track SEQUENCE_B``).

The configuration of PARSEC's ``bodytrack`` (``../shared/data/parsec/FORMAT.md`` §6): the ``parsec31`` body (10
cylinders, 31-value state), the PARSEC likelihood ``log p(z | x) = −(ErrEdge + ErrInside)`` summed over the cameras
(:mod:`jaxmocap.parsec.likelihood`; poses whose cylinders intersect are dropped), and the annealed particle filter
in PARSEC mode (:meth:`jaxmocap.filters.APF.parsec`: σ_l schedule 0.707σ_0, 0.5σ_0, … then σ_0 in the last layer,
β by bisection for α = 0.5, multinomial resampling, weighted-mean estimate, no motion model), by default with
bodytrack's 4000 particles × 5 layers.

**Initialisation** (§6.5, ``ParticleFilter.h:202-229``): ``x_i = x_0 + σ_0 ⊙ ε_i`` around ``InitialPose.txt``,
weighted against the first tracked frame with that frame's β: ``log w_i = β (ll_i − max ll)`` normalised. The
filter's first layer then resamples from these weights.

**Units.** The filter and the likelihood run in PARSEC's units (radians; the pelvis translation, entries 3–5, in
mm, like ``InitialPose.txt`` and σ_0). The outputs are in metres like every other run: ``state`` is
:func:`jaxmocap.parsec.model.to_metres` of the estimate, for the ``parsec31`` model built in metres
(radii and lengths / 1000, as :func:`jaxmocap.tracking.tracker.build_model` builds it), and the 15 evaluation joints are in metres.
"""

from __future__ import annotations

import json
import os
import pathlib
import sys
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.filters import APF
from jaxmocap.filters.base import State
from jaxmocap.geometry import body as body_mod
from jaxmocap.io import export
from jaxmocap.parsec import annealing
from jaxmocap.parsec import likelihood as pl
from jaxmocap.parsec import model as parsec

__all__ = ["DEFAULT_LAYERS", "DEFAULT_PARTICLES", "ParsecTracker", "make_loglik", "weighted_start"]

#: bodytrack's standard configuration (PARSEC's native input set).
DEFAULT_PARTICLES = 4000
DEFAULT_LAYERS = 5
RUN_JSON = "run.json"


def make_loglik(shape: parsec.BodyShape, cams: parsec.Cameras) -> Callable:
    """``loglik(X (N, 31), observation, layer=None) -> (N,)``: the PARSEC log-likelihood (mm), −∞ for the poses
    bodytrack rejects (intersecting cylinders, returned as −1e10), so that the filter drops them as bodytrack does."""
    raw = pl.make_loglik_batch(shape, cams)

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


class ParsecTracker:
    """One PARSEC tracking run: ``ParsecTracker(source, out, options).run()`` with a
    :class:`jaxmocap.parsec.inputs.ParsecSource` and :class:`jaxmocap.tracking.tracker.TrackOptions`.

    Used options: ``particles`` (default :data:`DEFAULT_PARTICLES`, per layer), ``layers`` (default
    :data:`DEFAULT_LAYERS`), ``seed`` (frame ``t`` uses ``fold_in(key(seed), t)``; the initial set
    ``fold_in(fold_in(key(seed), t0), 1)``), ``frames``, ``init`` (``auto`` = the sequence's ``InitialPose.txt``, or
    a file of 31 numbers in its format), ``on_bad_frame``, ``overwrite``, ``fsync``; the others raise ``ValueError``.
    Attributes: ``model`` (``parsec31`` in metres), ``model_mm``, ``frames``, ``num_particles``, ``layers``,
    ``trace_count`` (compilations of the filter step).
    """

    def __init__(self, source, out: str | os.PathLike, options=None, quiet: bool = False):
        from jaxmocap.synth.generate import parse_frames
        from jaxmocap.tracking.tracker import TrackOptions

        o = TrackOptions() if options is None else options
        bad = _unsupported(o)
        if bad:
            raise ValueError("not supported for a PARSEC bodytrack sequence: " + "; ".join(bad))
        if o.on_bad_frame not in ("skip", "stop"):
            raise ValueError("on_bad_frame must be 'skip' or 'stop'")
        self.o, self.source, self.quiet = o, source, quiet
        self.out = pathlib.Path(out)
        a, b = parse_frames(o.frames, source.num_frames)
        self.frames = list(range(a, b))
        self.num_particles = DEFAULT_PARTICLES if o.particles is None else int(o.particles)
        self.layers = DEFAULT_LAYERS if o.layers is None else int(o.layers)
        if self.num_particles < 2:
            raise ValueError("--particles must be at least 2")
        if self.layers < 1:
            raise ValueError("--layers must be at least 1")
        self.model_mm = parsec.parsec31(source.shape)
        self.model = self._metres_model()
        self.std = np.asarray(source.pose_parameters.std, np.float64)
        self.cues = [["parsec_edge", 1.0], ["parsec_inside", 1.0]]
        self.trace_count = 0
        if o.init == "auto":
            self.x0, self.init_how = np.asarray(source.initial_pose, np.float64), "InitialPose.txt"
        else:
            self.x0, self.init_how = parsec.load_pose(o.init), "file"

    def _metres_model(self) -> body_mod.BodyModel:
        """``parsec31`` of the sequence's body in metres (radii and lengths / 1000), for the outputs."""
        s = self.source.shape
        limbs = np.asarray(s.limbs, np.float64).copy()
        limbs[:, :2] /= parsec.MM_PER_M
        shape_m = parsec.BodyShape(jnp.asarray(limbs), jnp.asarray(np.asarray(s.lengths) / parsec.MM_PER_M))
        return parsec.parsec31(shape_m)

    def _key(self, t: int, purpose: int = 0):
        k = jax.random.fold_in(jax.random.key(int(self.o.seed)), int(t))
        return k if purpose == 0 else jax.random.fold_in(k, purpose)

    def _description(self) -> dict:
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

    def _prepare_out(self) -> None:
        out = self.out
        if out.exists() and not out.is_dir():
            raise MocapInputError(out, "exists and is not a folder")
        if ((out / export.POSES_NPZ).exists() or (out / RUN_JSON).exists()) and not self.o.overwrite:
            raise MocapInputError(out, "already holds a tracking run: pass --overwrite to replace it")
        out.mkdir(parents=True, exist_ok=True)
        for name in (
            RUN_JSON,
            "resume.npz",
            export.POSES_NPZ,
            export.POSES_CSV,
            export.DIAGNOSTICS_JSON,
            export.DIAGNOSTICS_JOURNAL,
            export.TRACK_BVH,
        ):
            if (out / name).exists():
                (out / name).unlink()
        text = json.dumps(self._description(), indent=1, sort_keys=True) + "\n"
        export.atomic_write_text(out / RUN_JSON, text)

    def _observe(self, t: int):
        try:
            return self.source.observation(t), None
        except MocapInputError as e:
            if self.o.on_bad_frame == "stop" or t == self.frames[0]:
                raise
            sys.stderr.write(f"jaxmocap: warning: skipping frame {t}: {e}\n")
            return None, str(e)

    def run(self) -> dict:
        """Track every frame; returns the summary (also in ``diagnostics.json``)."""
        from jaxmocap.tracking.tracker import Progress, _layer_records

        o, src = self.o, self.source
        t_begin = time.monotonic()
        std = jnp.asarray(self.std, jnp.float32)
        loglik = make_loglik(src.shape, src.cameras)
        filt = annealing.parsec_apf(loglik, std, self.num_particles, self.layers)
        t0 = self.frames[0]
        obs0, _ = self._observe(t0)  # a broken first frame fails before any output is written
        self._prepare_out()
        start = jax.jit(lambda k, x, ob: weighted_start(filt, loglik, k, x, std, ob))
        state = start(self._key(t0, 1), jnp.asarray(self.x0, jnp.float32), obs0)

        def step(key, s, ob):
            self.trace_count += 1
            return filt.step(key, s, ob)

        step = jax.jit(step)
        joints_m = jax.jit(lambda x: body_mod.joint_positions(self.model, x))
        writer = export.PoseWriter(self.out, self.model.dof_names, "parsec31", src.fps, fsync=o.fsync)
        diag = export.DiagnosticsWriter(self.out, self._description())
        progress = Progress(len(self.frames), enabled=not self.quiet)
        skipped, first_s = 0, None
        pending = (obs0, None)
        try:
            for i, t in enumerate(self.frames):
                t_frame = time.monotonic()
                obs, why = pending
                if obs is not None:
                    state, info = step(self._key(t), state, obs)
                # prepare the next frame on the host while the step runs
                pending = self._observe(self.frames[i + 1]) if i + 1 < len(self.frames) else None
                if obs is None:
                    skipped += 1
                    diag.append({"frame": t, "skipped": True, "reason": why})
                else:
                    info = jax.device_get(info)
                    est_mm = np.asarray(info.estimate, np.float64)
                    x_m = est_mm.copy()
                    x_m[3:6] /= parsec.MM_PER_M  # parsec.to_metres, in float64
                    J = np.asarray(joints_m(jnp.asarray(x_m, jnp.float32)), np.float64)
                    writer.append(t, x_m, export.eval_joints_of(self.model, J))
                    record = {
                        "frame": t,
                        "time_s": t / src.fps,
                        "quality": float(-np.asarray(info.layers.loglik_max).reshape(-1)[-1]),
                        "recovered": bool(np.asarray(info.recovered)),
                        "lost": False,
                        "reinitialised": False,
                        "reinit_source": None,
                        "seconds": time.monotonic() - t_frame,
                        "layers": _layer_records(info.layers),
                    }
                    if i == 0:
                        record["init"] = self.init_how
                    diag.append(record)
                    if first_s is None:
                        first_s = time.monotonic() - t_frame
                progress.update(i + 1)
        except BaseException:
            progress.end_line()
            writer.close()
            diag.close()
            raise
        writer.close()
        fps = diag.frames_per_s()
        summary = {
            "frames_tracked": writer.num_frames,
            "frames_requested": len(self.frames),
            "frames_skipped": skipped,
            "lost_frames": 0,
            "reinitialisations": 0,
            "wall_s": time.monotonic() - t_begin,
            "first_frame_s": first_s,
            "frames_per_s": fps,
            "interrupted": False,
            "resumed_at": None,
            "compilations": self.trace_count,
            "model": "parsec31",
            "filter": "apf",
            "particles": self.num_particles,
            "layers": self.layers,
            "cues": self.cues,
        }
        if writer.num_frames:
            export.save_model_bvh(self.out / export.TRACK_BVH, self.model, writer.states, src.fps)
        diag.close(summary)
        return summary
