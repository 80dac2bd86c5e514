"""The frame loop of every tracking run (``jaxmocap track``, PARSEC's bodytrack configuration).

:class:`TrackingLoop` drives a setup (:class:`jaxmocap.tracking.setup.TrackSetup` or PARSEC's): per frame, the key
is ``fold_in(key(seed), frame)`` (never carried), so that a resumed run reproduces an uninterrupted one; a damped
constant-velocity prediction of the root translation, the filter step (jitted **once**, with the filter as an
argument, so that its data — diffusion std, schedule values, the likelihood's cue weights and λ — are not constants
of the program: ``trace_count`` stays 1),
track-loss detection and re-initialisation, and incremental outputs (:mod:`jaxmocap.io.export`) with a resume
checkpoint (``resume.npz``) after each frame.

**Compiling ahead.** A fresh run compiles the filter step in a second thread while the first frame is initialised
(the pose fit of :mod:`jaxmocap.tracking.init` compiles and runs programs of its own): XLA compiles independent
programs side by side on two cores, and the step depends on the initial pose only through data. The setup gives a
filter and state of the right structure (``setup.compile_arguments(key, observation)``; None where the structure
needs the initial pose, e.g. colour references); the first call of the step then finds it compiled.

**Track loss.** ``q_t = −max_i log p(z | x_i)`` of the last layer (the energy of the best particle) is compared
with its median ``q_ref`` over the first frames after the initialisation: the track is lost when
``q_t > loss_ratio · q_ref`` for ``loss_frames`` consecutive frames, when the filter found no finite weight
(``Info.recovered``), or when no view shows any foreground (no person). The filter is then re-initialised around a
detection (``setup.reinit_mean``) with ``reinit_widen`` times the diffusion spread. Every frame's record in
``diagnostics.json`` has ``quality``, ``lost``, ``reinitialised`` and ``reinit_source``. A setup without
``track_loss`` (PARSEC's) never loses the track.
"""

from __future__ import annotations

import math
import os
import pathlib
import threading
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.filters.base import State
from jaxmocap.filters.factory import particles_text
from jaxmocap.io import export
from jaxmocap.io.sources import BadFrame
from jaxmocap.tracking import outputs, run_folder
from jaxmocap.tracking.init import root_translation_dofs
from jaxmocap.tracking.progress import CompileNotice, Progress

__all__ = ["LossTracker", "TrackingLoop", "layer_records"]


class LossTracker:
    """Track-loss bookkeeping (module docstring): the quality reference ``q_ref`` and its window ``q_hist``, the
    run of bad frames ``lost_run``, the last good estimate and the last two ``(frame, estimate)`` (the velocity)."""

    def __init__(self, options, last_good=None):
        self.o = options
        self.q_ref, self.q_hist, self.lost_run = float("nan"), [], 0
        self.last_good = last_good
        self.hist: list[tuple[int, np.ndarray]] = []

    @classmethod
    def from_checkpoint(cls, options, ck) -> LossTracker:
        s = cls(options, np.asarray(ck["last_good"]))
        s.hist = [(int(f), np.asarray(x)) for f, x in zip(ck["hist_frames"], ck["hist_states"], strict=True)]
        s.q_ref = float(ck["q_ref"])
        s.q_hist = [float(v) for v in np.asarray(ck["q_hist"]).reshape(-1)]
        s.lost_run = int(ck["lost_run"])
        return s

    def bad_quality(self, q: float) -> bool:
        """Update the reference with ``q`` and tell whether ``q`` is bad; counts the run of bad frames."""
        o = self.o
        if not math.isfinite(self.q_ref):
            if math.isfinite(q):
                self.q_hist.append(q)
            if len(self.q_hist) >= o.loss_window:
                self.q_ref = float(np.median(self.q_hist))
        bad = math.isfinite(self.q_ref) and (not math.isfinite(q) or q > o.loss_ratio * self.q_ref)
        self.lost_run = self.lost_run + 1 if bad else 0
        return bad


class TrackingLoop:
    """One tracking run over a setup: ``run()`` tracks every frame of ``setup.frames`` into ``out``.

    Subclasses build ``self.setup`` in their constructor; the setup's attributes (``model``, ``frames``,
    ``likelihood``, ``features``, ``cues``, ``num_particles``, ``layers``, ``std`` …) are read through the run.
    ``filter`` is built once the initial state is known; ``trace_count`` counts compilations of the filter step.
    ``compile_ahead``: compile the step while the first frame is initialised (module docstring);
    ``compiled_ahead``: whether the first step found it compiled that way.
    """

    compile_ahead = True

    def __init__(self, setup, out: str | os.PathLike, quiet: bool = False):
        self.setup = setup
        self.o, self.source = setup.o, setup.source
        self.out = pathlib.Path(out)
        self.quiet = quiet
        self.trace_count = 0
        self.filter = None
        self._ahead = None
        self.compiled_ahead = False

        def step(filt, key, state, tobs):
            self.trace_count += 1
            return filt.step(key, state, tobs)

        # the filter (a pytree: its arrays, schedule values and likelihood leaves are data) is an argument, not a
        # constant of the program: a filter that differs only in data reuses the compiled step
        self._step = jax.jit(step)

    def __getattr__(self, name):
        if name == "setup":
            raise AttributeError(name)
        return getattr(self.setup, name)

    # -- hooks --------------------------------------------------------------------------------------------------

    def _observe(self, t: int):
        return self.setup.observe(t)

    def _make_filter(self, x0: np.ndarray):
        self.filter = self.setup.make_filter(x0)

    def _what(self) -> str:
        o, setup = self.o, self.setup
        return f"the {o.filter} step ({setup.model.name}, {particles_text(setup.num_particles)} particles)"

    def _compile_ahead(self, t: int, tobs) -> None:
        """Start compiling the step in a thread (module docstring), with the notice lines of
        :class:`CompileNotice`; ``self._ahead`` is the thread, or None when the setup gives no arguments."""
        make = getattr(self.setup, "compile_arguments", None)
        if not self.compile_ahead or make is None or self.trace_count:
            return
        key = self._key(t)
        args = make(key, tobs)
        if args is None:
            return

        def work():
            try:
                with CompileNotice(self._what(), enabled=not self.quiet):
                    self._step.lower(args[0], key, args[1], tobs).compile()
                thread.done = True
            except Exception:  # the first call compiles again, and raises what is wrong
                pass

        thread = threading.Thread(target=work, name="jaxmocap-compile", daemon=True)
        thread.done = False
        thread.start()
        self._ahead = thread

    def _join_ahead(self) -> None:
        """Wait for a compilation ahead that no step has waited for (a run that failed before its first step)."""
        ahead, self._ahead = self._ahead, None
        if ahead is not None:
            ahead.join()

    def _first_call(self, filt, key, state, tobs):
        """The first call of the step: after the compilation ahead, else in a :class:`CompileNotice`."""
        ahead, self._ahead = self._ahead, None
        if ahead is not None:
            ahead.join()
            if ahead.done:
                self.compiled_ahead = True
                return self._step(filt, key, state, tobs)
        with CompileNotice(self._what(), enabled=not self.quiet):
            return self._step(filt, key, state, tobs)

    def _key(self, t: int, purpose: int = 0):
        k = jax.random.fold_in(jax.random.key(int(self.o.seed)), int(t))
        return k if purpose == 0 else jax.random.fold_in(k, purpose)

    # -- the loop -----------------------------------------------------------------------------------------------

    def _first_frame(self):
        """Find the first readable frame, check that a person is visible there and initialise the filter.

        Returns ``(index into frames, its observation tuple, the skipped frames, x0, spread, how)``."""
        skipped = []
        for i, t in enumerate(self.setup.frames):
            obs = self._observe(t)
            if obs[0] is None:
                skipped.append((t, obs[3]))
                continue
            masks = obs[1]
            if masks is not None and int(np.sum(masks)) < 20:
                raise MocapInputError(
                    None,
                    f"no person in frame {t}: the foreground ({self.setup.features.foreground}) is empty in every view (an "
                    "empty scene? a median background of frames where the person hardly moves?); use --frames to "
                    "start where the person is visible, or another --foreground",
                )
            self._compile_ahead(t, obs[0])
            x0, spread, how = self.setup.initial_state(t, masks, obs[2])
            return i, obs, skipped, np.asarray(x0, np.float64), spread, how
        raise MocapInputError(None, "no frame of the input could be read")

    def _resume(self, ck):
        """The state of a run continued from checkpoint ``ck``."""
        setup, frames = self.setup, self.setup.frames
        done = int(ck["frame"])
        if done not in frames:
            raise MocapInputError(
                self.out / run_folder.RESUME_NPZ,
                f"checkpoint of frame {done}, outside the frames of this run",
            )
        start = frames.index(done) + 1
        x0 = np.asarray(ck["x0"], np.float64)
        self._ref_frame = int(ck["ref_frame"]) if "ref_frame" in ck else frames[0]
        if setup.needs_references:
            first = self._observe(self._ref_frame)[0]
            if first is None:
                raise MocapInputError(None, f"frame {self._ref_frame} of the colour references is unreadable")
            setup.set_references(x0, first)
        self._make_filter(x0)
        dt = setup.model.offset.dtype
        state = State(*(jnp.asarray(ck[k], dt) for k in ("particles", "log_weights", "estimate")))
        return start, x0, state, LossTracker.from_checkpoint(self.o, ck)

    def run(self) -> dict:
        """Track every frame; returns the summary (also in ``diagnostics.json``)."""
        try:
            return self._run()
        finally:
            self._join_ahead()

    def _run(self) -> dict:
        setup, o = self.setup, self.o
        model = setup.model
        dt = model.offset.dtype
        trans = np.zeros(model.num_dofs, bool)
        trans[root_translation_dofs(model)] = True
        frames = setup.frames
        stats = {"reinitialisations": 0, "lost_frames": 0, "skipped": 0, "first_frame_s": None}
        t_begin = time.monotonic()
        description = setup.description()
        ck = run_folder.check_out(self.out, description, o.resume, o.overwrite, setup.resumable)
        if (
            ck is None
        ):  # a fresh run: everything that can fail on the input fails before any output is written
            start, pending, skipped, x0, spread, how = self._first_frame()
            self._ref_frame = frames[start]
            setup.set_references(x0, pending[0])
            self._make_filter(x0)
            t0 = frames[start]
            state = setup.start(self.filter, self._key(t0, 1), x0, spread, pending[0])
            loss = LossTracker(o, x0)
        else:
            start, x0, state, loss = self._resume(ck)
            skipped, how = [], None
            for k in ("reinitialisations", "lost_frames", "skipped"):
                stats[k] = int(ck[k])
            pending = self._observe(frames[start]) if start < len(frames) else None
        run_folder.start_out(self.out, ck is None, description)
        pose_writer = export.PoseWriter(
            self.out,
            model.dof_names,
            model.name,
            self.source.fps,
            keep=None if ck is None else int(ck["rows"]),
            fsync=o.fsync,
        )
        diag = export.DiagnosticsWriter(
            self.out, description, keep_until=None if ck is None else frames[start - 1] + 1
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
                centre = setup.detection(fd, masks, loss.last_good)
                if centre is not None:
                    tobs = tobs._replace(centre=jnp.asarray(centre, jnp.float32), valid=jnp.asarray(True))
                # damped constant-velocity prediction of the root translation
                hist = loss.hist
                if len(hist) == 2 and hist[0][0] == t - 2 and hist[1][0] == t - 1 and setup.velocity > 0:
                    v = np.where(trans, hist[1][1] - hist[0][1], 0.0) * setup.velocity
                    state = state._replace(particles=state.particles + jnp.asarray(v, dt))
                if i == start:  # compiles the step, or waits for it: say so, and how long it took
                    state, info = self._first_call(self.filter, self._key(t), state, tobs)
                else:
                    state, info = self._step(self.filter, self._key(t), state, tobs)
                # prepare the next frame on the host while the step runs
                pending = self._observe(frames[i + 1]) if i + 1 < len(frames) else None
                info = jax.device_get(info)
                est = np.asarray(info.estimate, np.float64)
                q = float(-np.asarray(info.layers.loglik_max).reshape(-1)[-1])
                recovered = bool(np.asarray(info.recovered))
                lost, reinit_source = False, None
                if setup.track_loss:
                    bad_quality = loss.bad_quality(q)
                    lost = recovered or no_person or loss.lost_run >= o.loss_frames
                    if lost:
                        stats["lost_frames"] += 1
                        mean, reinit_source = setup.reinit_mean(fd, masks, loss.last_good)
                        if mean is not None:
                            state = self.filter.init(
                                self._key(t, 2),
                                jnp.asarray(mean, dt),
                                jnp.asarray(o.reinit_widen * setup.std, dt),
                            )
                            stats["reinitialisations"] += 1
                            loss.lost_run = 0
                            loss.hist = []
                        else:
                            loss.hist = [*loss.hist, (t, est)][-2:]
                    else:
                        loss.last_good = est if not bad_quality else loss.last_good
                        loss.hist = [*loss.hist, (t, est)][-2:]
                x = setup.output_state(est)
                pose_writer.append(t, x, export.eval_joints_of(model, setup.joints(x)))
                record.update(
                    quality=q,
                    recovered=recovered,
                    no_person=bool(no_person),
                    lost=bool(lost),
                    reinitialised=reinit_source is not None,
                    reinit_source=reinit_source,
                    seconds=time.monotonic() - t_frame,
                    layers=layer_records(info.layers),
                )
                diag.append(record)
                if setup.resumable:
                    run_folder.write_checkpoint(
                        self.out, o.fsync, model.num_dofs, t, state, loss, stats, pose_writer.num_frames, x0,
                        self._ref_frame,
                    )  # fmt: skip
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

    def _finish(self, pose_writer, diag, stats, wall, interrupted, resumed_at) -> dict:
        setup = self.setup
        model = setup.model
        n = pose_writer.num_frames
        summary = {
            "frames_tracked": n,
            "frames_requested": len(setup.frames),
            "frames_skipped": stats["skipped"],
            "lost_frames": stats["lost_frames"],
            "reinitialisations": stats["reinitialisations"],
            "wall_s": wall,
            "first_frame_s": stats["first_frame_s"],
            "frames_per_s": diag.frames_per_s(),
            "interrupted": interrupted,
            "resumed_at": resumed_at,
            "compilations": self.trace_count,
            "model": model.name,
            "filter": self.o.filter,
            "particles": setup.num_particles,
            "layers": setup.layers,
            "cues": [list(c) for c in setup.cues],
        }
        groundtruth = getattr(self.source, "groundtruth", None)
        if n:  # the exported track: poses_smoothed.npz, track.bvh, poses.trc, poses.c3d, plots/
            summary.update(
                outputs.export_track(
                    self.out, model, setup.frames, pose_writer.frames, pose_writer.states, diag.records,
                    self.source.fps, smooth=self.o.smooth, bvh_units=self.o.bvh_units, groundtruth=groundtruth,
                )
            )  # fmt: skip
        if groundtruth is not None and n:
            from jaxmocap.eval import metrics

            try:
                rep = metrics.evaluate([(np.asarray(pose_writer.frames), pose_writer.joints)], groundtruth)
                summary["mean_error_mm"] = rep["overall_mean_mm"]
            except ValueError:  # nothing to compare (e.g. a diverged, non-finite track)
                summary["mean_error_mm"] = None
        diag.close(summary)
        if self.o.overlay and n and not interrupted:
            summary["overlays"] = [os.fspath(p) for p in self.write_overlays(pose_writer)]
        return summary

    def write_overlays(self, pose_writer) -> list[pathlib.Path]:
        """One H.264 MP4 per view of the tracked model drawn over the input (full size), and a montage PNG."""
        from jaxmocap.eval import viz

        rig = self.source.rig
        rj = rig.to_jax(jnp.float32)
        model = self.setup.model
        states = dict(zip(pose_writer.frames, pose_writer.states, strict=True))
        joints = dict(zip(pose_writer.frames, pose_writer.joints, strict=True))
        gt = self.source.groundtruth
        with viz.OverlayVideo(self.out, rig.names, rig.image_size, self.source.fps, rj) as video:
            for t in self.setup.frames:
                if t not in states:
                    continue
                try:
                    fd = self.source.read(t, masks=False)
                except BadFrame:
                    continue
                truth = None if gt is None else gt[t]
                video.write(viz.overlay_image(fd.images, model, rj, states[t], truth), joints[t], t)
        return [p for p in (*video.paths, video.montage_path) if p.exists()]


def layer_records(layers) -> list[dict]:
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
