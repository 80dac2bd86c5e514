"""The frame loop of every tracking run (``jaxmocap track``, PARSEC's bodytrack configuration).

:class:`TrackingLoop` drives a setup (:class:`jaxmocap.tracking.setup.TrackSetup` or PARSEC's): per frame, the key
is ``fold_in(key(seed), frame)`` (never carried), so that a resumed run reproduces an uninterrupted one; a damped
constant-velocity prediction of the root (its translation, and by default its angles:
``TrackOptions.velocity_dofs``) with full turns of the heading taken out (:mod:`jaxmocap.tracking.prediction`),
the filter step (jitted **once**, with the filter as an argument, so that its data — diffusion std, schedule
values, the likelihood's cue weights and λ — are not constants of the program: ``trace_count`` stays 1, or 0
when the run reads the traced step back from disk, :mod:`jaxmocap.stored_programs`; the summary's
``compilations`` counts both ways of making it: 1), track-loss detection and re-initialisation, and incremental
outputs (:mod:`jaxmocap.io.export`) with a resume checkpoint (``resume.npz``,
:class:`jaxmocap.tracking.run_folder.Checkpoints`: at most once a second, and on every way out; a run killed by
SIGKILL is resumed from its last checkpoint and tracks the frames after it again, to the same bits).

**Before the first frame** (:meth:`TrackingLoop._prepare`) the run takes the output folder's lock
(:class:`jaxmocap.tracking.run_folder.RunLock`), checks the folder (:func:`~jaxmocap.tracking.run_folder.check_out`)
and the input, checks that the particle set fits in memory, and compiles the filter step, refusing a program that
would not fit (:mod:`jaxmocap.tracking.resources`); only then does it write to the folder, so that a run refused
there leaves no half-made folder.

**Every way out** — the end, Ctrl-C, SIGTERM (:mod:`jaxmocap.tracking.interrupts`), an error such as an
undecodable frame with ``--on-bad-frame stop`` — goes through :meth:`TrackingLoop._write_outputs`: ``poses.npz``,
``track.bvh`` and ``diagnostics.json`` with the summary hold every frame tracked. A frame's outputs
(:meth:`TrackingLoop._write_frame`, then the checkpoint) are written in a thread of their own
(:class:`jaxmocap.tracking.run_folder.BackgroundWriter`) while the next frame is tracked; every way out waits for
them, and an error in reading the next frame (prepared while the step runs) is raised only once the current frame
is queued.
``run.json`` records how the run ended (``status``): ``complete`` after the overlays
(:meth:`TrackingLoop.write_overlays`), else ``interrupted`` or ``stopped``.

**Compiling ahead.** A fresh run compiles the filter step in a second thread while the first frame is initialised
(the pose fit of :mod:`jaxmocap.tracking.init` compiles and runs programs of its own): XLA compiles independent
programs side by side on two cores, and the step depends on the initial pose only through data. The setup gives a
filter and state of the right structure (``setup.compile_arguments(key, observation)``; None where the structure
needs the initial pose, e.g. colour references); the first call of the step then finds it compiled. A setup whose
input has detections but whose first pose came from elsewhere compiles the re-initialisation from detections in
a third thread (``setup.warm_reinit(how)``), joined once the step is compiled. A resumed run, which has no first
pose to fit, compiles that fit the same way and runs the filter's re-initialisation once (a fresh run's start
compiles it), so that its first track loss compiles nothing either.

**No frame compiles.** Every frame has the first one's shapes, and whatever runs per frame is compiled once (the
prediction is one program, :func:`jaxmocap.tracking.prediction.predict`; host arrays go to the device by
:func:`jaxmocap.transfer.to_device`, since ``jnp.asarray`` of a host array compiles a conversion per shape). The
loop counts the programs its thread lowers (:class:`jaxmocap.tracking.compile_watch.CompileWatch`): a frame after
the first that compiles has ``compiled_programs`` in its record, the summary has their total
(``compiled_after_first_frame``, 0), and the run warns.

**Track loss.** ``q_t = −max_i log p(z | x_i)`` of the last layer (the energy of the best particle) is compared
with its median ``q_ref`` over the first frames after the initialisation or the last re-initialisation (the
reference is learnt again on every new track: the detections' noise, and with it the keypoint energy, may change
over a sequence, and a reference learnt on the first frames alone had a stereo walk re-initialised from its
detections every third frame once that energy had risen fourfold): the track is lost when
``q_t > loss_ratio · q_ref`` for ``loss_frames`` consecutive frames, when the filter found no finite weight
(``Info.recovered``), or when no view shows any foreground (no person) or the setup's detector sees nobody
(``setup.person_absent(fd)``, the head-and-hands proposal; the quality reference is then learnt again, and the first
frame where it sees a person again re-initialises the filter on them). The filter is then re-initialised around a
detection (``setup.reinit_mean``) with ``reinit_widen`` times the diffusion spread. A setup may define ``q_t`` itself
(``setup.quality(loglik_max)`` of the step's per-layer maxima: a likelihood restricted to each partition's body
parts sums the partitions' best energies). Every frame's record in
``diagnostics.json`` has ``quality``, ``lost``, ``reinitialised`` and ``reinit_source`` (and ``modes``, one count per
layer, with ``count_modes``: :func:`jaxmocap.eval.mixtures.count_layer_modes`). A setup without
``track_loss`` (PARSEC's) never loses the track.
"""

from __future__ import annotations

import copy
import functools
import math
import os
import pathlib
import shutil
import threading
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap import host
from jaxmocap.errors import MocapInputError
from jaxmocap.eval.mixtures import count_layer_modes
from jaxmocap.filters.base import State
from jaxmocap.filters.factory import particles_text
from jaxmocap.io import export
from jaxmocap.io.sources import BadFrame
from jaxmocap.stored_programs import StoredJit
from jaxmocap.tracking import interrupts, outputs, resources, run_folder
from jaxmocap.tracking.compile_watch import CompileWatch
from jaxmocap.tracking.frame_keys import frame_key
from jaxmocap.tracking.prediction import angle_difference, predict, velocity_dofs
from jaxmocap.tracking.progress import CompileNotice, Progress, warn
from jaxmocap.transfer import to_device

__all__ = ["MAX_SEED", "LossTracker", "TrackingLoop", "layer_records"]

#: the largest seed: JAX's keys take 32-bit seeds (without 64-bit mode a larger one would wrap onto a smaller one)
MAX_SEED = 2**32 - 1


class LossTracker:
    """Track-loss bookkeeping (module docstring): the quality reference ``q_ref`` and its window ``q_hist``, the
    run of bad frames ``lost_run``, the last good estimate and the last two ``(frame, estimate)`` (the velocity)."""

    def __init__(self, options, last_good=None):
        self.o = options
        self.q_ref, self.q_hist, self.lost_run, self.last_good = float("nan"), [], 0, last_good
        self.hist: list[tuple[int, np.ndarray]] = []
        #: the setup's detector saw nobody in the last frame (``setup.person_absent``)
        self.unseen = False

    @classmethod
    def from_checkpoint(cls, options, ck) -> LossTracker:
        s = cls(options, np.asarray(ck["last_good"]))
        s.hist = [(int(f), np.asarray(x)) for f, x in zip(ck["hist_frames"], ck["hist_states"], strict=True)]
        s.q_ref, s.lost_run = float(ck["q_ref"]), int(ck["lost_run"])
        s.q_hist = [float(v) for v in np.asarray(ck["q_hist"]).reshape(-1)]
        return s

    def snapshot(self) -> LossTracker:
        """A copy that later frames do not change (for a checkpoint written later)."""
        s = copy.copy(self)
        s.q_hist, s.hist = list(self.q_hist), list(self.hist)
        return s

    def new_track(self) -> None:
        """The filter was re-initialised: no run of bad frames, no velocity, and the quality reference learnt
        again over the next ``loss_window`` frames (module docstring)."""
        self.lost_run, self.hist = 0, []
        self.q_ref, self.q_hist = float("nan"), []

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
    ``filter`` is built once the initial state is known; ``trace_count`` counts the traces of the filter step (0
    when the step was found stored on disk: :mod:`jaxmocap.stored_programs`), ``step_programs`` the step programs
    made, traced or read back (1 for a whole run: a new frame never makes another).
    ``compile_ahead``: compile the step while the first frame is initialised (module docstring);
    ``compiled_ahead``: whether the first step found it compiled that way.
    """

    compile_ahead = True

    def __init__(self, setup, out: str | os.PathLike, quiet: bool = False):
        seed = setup.o.seed
        if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or not 0 <= int(seed) <= MAX_SEED:
            raise ValueError(f"--seed must be an integer from 0 to {MAX_SEED}, got {seed}")
        self.setup = setup
        self.o, self.source = setup.o, setup.source
        self.out = pathlib.Path(out)
        self.quiet = quiet
        self.trace_count = 0
        self.filter = None
        self.summary = None
        self.compile_s = None
        self._compiled = False
        self._ahead = self._warm = None
        self.compiled_ahead = False

        joints_of = getattr(self.setup, "estimate_joints", None)
        refine = getattr(self.setup, "refine_step", None)

        def step(filt, key, state, tobs):
            """The filter step, its estimate refined on the frame's detections when the setup does so
            (``refine_step``), and the joints of the estimate when the setup computes them on the device
            (``estimate_joints``: no second dispatch per frame for the outputs)."""
            self.trace_count += 1
            new, info = filt.step(key, state, tobs)
            if refine is not None:
                new, info = refine(new, info, tobs)
            return new, info, (None if joints_of is None else joints_of(info.estimate))

        # the filter (a pytree: its arrays, schedule values and likelihood leaves are data) is an argument, not a
        # constant of the program: a filter that differs only in data reuses the compiled step. Inside
        # ``stored_programs.use`` (the command line, ``jaxmocap.track``) the traced step is kept on disk under the
        # setup's ``program_tag`` (what the step closes over besides its arguments) and the arguments' structure;
        # a setup without a tag traces every run; ``compiler_options``: XLA's for the step (PARSEC's)
        tag, options = (getattr(self.setup, name, None) for name in ("program_tag", "compiler_options"))
        self._jitted = self._step = StoredJit(
            step,
            None if tag is None else "step " + tag(),
            key_structure=not getattr(self.setup, "tag_names_arguments", False),
            compiler_options=None if options is None else options(),
        )

    @property
    def step_programs(self) -> int:
        """The filter step's programs this run made: traced, or read back from disk."""
        return self.trace_count + self._jitted.loaded

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
        # the state the step gets is committed to the device (see the frame loop): lowered with that placement
        one = jax.sharding.SingleDeviceSharding(_device())
        args = (
            args[0],
            jax.tree.map(
                lambda s: jax.ShapeDtypeStruct(s.shape, s.dtype, weak_type=s.weak_type, sharding=one), args[1]
            ),
        )

        def work():
            try:
                with CompileNotice(self._what(), enabled=not self.quiet):
                    self._jitted.lower(args[0], key, args[1], tobs).compile()
                thread.done = True
            except Exception:  # the step compiles again in :meth:`_compile`, and raises what is wrong
                pass

        thread = threading.Thread(target=work, name="jaxmocap-compile", daemon=True)
        thread.done = False
        thread.start()
        self._ahead = thread

    def _join_ahead(self) -> bool:
        """Wait for the compilation ahead, if one was started; whether it compiled the step."""
        ahead, self._ahead = self._ahead, None
        if ahead is None:
            return False
        ahead.join()
        return ahead.done

    def _start_warm(self, how: str | None) -> None:
        """Compile the re-initialisation's programs in a thread (``setup.warm_reinit(how)``; ``how``: how the
        first pose was found, None for a resumed run), joined by :meth:`_compile`."""
        warm = getattr(self.setup, "warm_reinit", None)
        if warm is None:
            return

        def work():
            try:
                warm(how)
            except Exception:  # a re-initialisation then compiles, and raises what is wrong
                pass

        self._warm = threading.Thread(target=work, name="jaxmocap-warm", daemon=True)
        self._warm.start()

    def _reinit_state(self, t: int, mean: np.ndarray) -> State:
        """The particle set re-initialised at frame ``t`` around ``mean`` ``(D,)``, ``reinit_widen`` times the
        diffusion spread."""
        dt = self.setup.model.offset.dtype
        return self.filter.init(
            self._key(t, 2), to_device(mean, dt), to_device(self.o.reinit_widen * self.setup.std, dt)
        )

    def _key(self, t: int, purpose: int = 0):
        """Frame ``t``'s key for ``purpose`` 0 (the step), 1 (the weighted start) or 2 (a re-initialisation)."""
        return frame_key(int(self.o.seed), int(t), purpose)

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
            check = getattr(self.setup, "check_initial", None)
            if check is not None:
                check(t)
            self._compile_ahead(t, obs[0])
            x0, spread, how = self.setup.initial_state(t, masks, obs[2])
            self._start_warm(how)
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
        state = State(*(to_device(ck[k], dt) for k in ("particles", "log_weights", "estimate")))
        return start, x0, state, LossTracker.from_checkpoint(self.o, ck)

    def _prefetch(self, i: int):
        """The observation tuple of ``frames[i]`` (None past the end), or the exception that reading it raised:
        raised by the loop once the frame before it is written (so ``--on-bad-frame stop`` keeps that frame)."""
        frames = self.setup.frames
        if i >= len(frames):
            return None
        try:
            return self._observe(frames[i])
        except Exception as e:  # noqa: BLE001 (re-raised in order, after the current frame's outputs)
            return _Failed(e)

    def _compile(self, t: int, state, tobs) -> None:
        """Compile the filter step for the shapes of ``state`` and ``tobs`` (saying so), then refuse it when its
        program would not fit in memory (:func:`jaxmocap.tracking.resources.check_program`). The frames then
        reuse the compiled program (``trace_count`` stays 1)."""
        setup = self.setup
        what = self._what()
        t0 = time.monotonic()
        # compiled ahead: the same program, found in JAX's cache (no second notice)
        self.compiled_ahead = self._join_ahead()
        with CompileNotice(what, enabled=not self.quiet and not self.compiled_ahead):
            compiled = self._jitted.lower(self.filter, self._key(t), state, tobs).compile()
        self._compiled = True
        self.compile_s = time.monotonic() - t0
        if self._warm is not None:  # the re-initialisation's programs (:meth:`_start_warm`)
            self._warm.join()
            self._warm = None
        n = setup.num_particles
        resources.check_program(
            compiled, f"--particles {particles_text(n)}: {what}", n if isinstance(n, int) else max(n)
        )

    def _prepare(self) -> dict:
        """Everything before the first frame's outputs: the checks of the folder and the input, the initial state
        (or the checkpoint's) and, for a fresh run, the compiled step; then :func:`run_folder.start_out`. Nothing
        is written to the folder until every check has passed."""
        setup, o = self.setup, self.o
        description = setup.description()
        ck = run_folder.check_out(self.out, description, o.resume, o.overwrite, setup.resumable)
        frames, n = setup.frames, setup.num_particles
        what = f"--particles {particles_text(n)}"
        resources.check_particle_set(n if isinstance(n, int) else max(n), setup.model.num_dofs, what)
        p = {"ck": ck, "description": description}
        if ck is None:
            # a fresh run: everything that can fail on the input fails before any output is written
            start, pending, skipped, x0, spread, how = self._first_frame()
            self._ref_frame = frames[start]
            setup.set_references(x0, pending[0])
            self._make_filter(x0)
            t0 = frames[start]
            state = jax.device_put(
                setup.start(self.filter, self._key(t0, 1), x0, spread, pending[0]), _device()
            )
            self._compile(t0, state, pending[0])
            p.update(start=start, pending=pending, skipped=skipped, x0=x0, how=how, state=state)
            p["loss"] = LossTracker(o, x0)
        else:
            start, x0, state, loss = self._resume(ck)
            if setup.track_loss:
                # the re-initialisation run once (result unused), as a fresh run's start does, so that a first
                # track loss compiles nothing; the fit to detections compiled in a thread (:meth:`_compile` joins)
                self._reinit_state(frames[min(start, len(frames) - 1)], x0)
                self._start_warm(None)
            p.update(start=start, x0=x0, state=state, loss=loss, skipped=[], how=None)
            p["pending"] = self._prefetch(start)
        interrupts.check()  # a signal whose exception was swallowed: stop before writing anything
        run_folder.start_out(self.out, ck is None, description)
        return p

    def run(self) -> dict:
        """Track every frame; returns the summary (also in ``diagnostics.json``).

        Holds the output folder's lock (:class:`run_folder.RunLock`) for the run. Ctrl-C and SIGTERM
        (:mod:`jaxmocap.tracking.interrupts`) and errors end it through :meth:`_write_outputs` (poses, BVH,
        diagnostics with the summary so far) and re-raise; ``self.summary`` holds that summary."""
        self.summary = None
        with interrupts.handling():
            try:
                interrupts.check()
                lock = run_folder.RunLock(self.out)
                if lock.stale and not self.quiet:
                    warn(
                        f"took over the lock of a run that ended without releasing it (pid {lock.stale.get('pid')})"
                    )
                try:
                    prepared = self._prepare()
                except BaseException:
                    lock.release(remove_created_folder=True)
                    raise
                try:
                    return self._run(prepared)
                finally:
                    lock.release()
            except (KeyboardInterrupt, interrupts.Terminated):
                interrupts.consume()  # handed on to the caller
                raise
            finally:
                self._join_ahead()  # a run that failed before its step compiled
                finish = getattr(self.setup, "finish_reads", None)
                if finish is not None:  # the frames read ahead: the caller may close the source next
                    finish()

    def _run(self, p: dict) -> dict:
        setup, o = self.setup, self.o
        model = setup.model
        dt = model.offset.dtype
        moving = velocity_dofs(model, getattr(o, "velocity_dofs", "translation"))
        flags = getattr(self.filter, "circular", None)
        circular = np.zeros(model.num_dofs, bool) if flags is None else np.asarray(flags, bool)
        circular_dev = to_device(circular)
        frames = setup.frames
        stats = {
            "reinitialisations": 0,
            "lost_frames": 0,
            "skipped": 0,
            "first_frame_s": None,
            "compiled_after_first_frame": 0,
        }
        t_begin = time.monotonic()
        old, start, pending = p["ck"], p["start"], p["pending"]
        state, loss, how = p["state"], p["loss"], p["how"]
        if old is not None:
            for k in ("reinitialisations", "lost_frames", "skipped"):
                stats[k] = int(old[k])
        pose_writer = export.PoseWriter(
            self.out,
            model.dof_names,
            model.name,
            self.source.fps,
            keep=None if old is None else int(old["rows"]),
            fsync=o.fsync,
        )
        diag = export.DiagnosticsWriter(
            self.out, p["description"], keep_until=None if old is None else frames[start - 1] + 1
        )
        resumed_at = None if old is None else (frames[start] if start < len(frames) else None)
        for t, why in p["skipped"]:
            stats["skipped"] += 1
            diag.append({"frame": t, "skipped": True, "reason": why})
        progress = Progress(len(frames), enabled=not self.quiet)
        ending = {"wall": t_begin, "resumed_at": resumed_at}
        ck = run_folder.Checkpoints(self.out, o.fsync, model.num_dofs, p["x0"], self._ref_frame)
        writer = run_folder.BackgroundWriter()
        if o.plots:
            threading.Thread(target=outputs.preload, name="jaxmocap-preload", daemon=True).start()

        def write_frame(t, x, joints, record, after):  # in the writer's thread, in frame order
            self._write_frame(pose_writer, diag, t, x, joints, record)
            if after is not None:
                ck.update(*after, pose_writer.num_frames)

        flushed = False
        watch = CompileWatch()  # the programs this thread compiles, frame by frame (none after the first)
        try:
            for i in range(start, len(frames)):
                interrupts.check()
                if isinstance(pending, _Failed):  # the frame before it is written: now stop
                    raise pending.error
                t = frames[i]
                t_frame = time.monotonic()
                tobs, masks, fd, bad = pending
                if tobs is None:  # an unreadable frame, skipped
                    stats["skipped"] += 1
                    writer.submit(
                        functools.partial(diag.append, {"frame": t, "skipped": True, "reason": bad})
                    )
                    pending = self._prefetch(i + 1)
                    progress.update(i + 1)
                    continue
                record = {"frame": t, "time_s": t / self.source.fps}
                if how is not None:
                    record["init"], how = how, None
                # detection-driven proposal centre (ICONDENSATION / IAPF) and the no-person test
                no_person = masks is not None and not np.any(np.sum(masks, axis=(1, 2)) >= 20)
                centre = setup.detection(fd, masks, loss.last_good)
                absent = getattr(setup, "person_absent", None)  # a detector that sees nobody
                unseen = absent is not None and bool(absent(fd))
                no_person = no_person or unseen
                if centre is not None:
                    tobs = tobs._replace(centre=to_device(centre, np.float32), valid=to_device(np.True_))
                # damped constant-velocity prediction of the DOFs of ``velocity_dofs`` (zero without two frames
                # before), then full turns taken out: one program on every frame (``prediction.predict``)
                hist = loss.hist
                v = np.zeros(model.num_dofs)
                if len(hist) == 2 and hist[0][0] == t - 2 and hist[1][0] == t - 1 and setup.velocity > 0:
                    step = angle_difference(hist[1][1], hist[0][1], circular)
                    v = np.where(moving, step, 0.0) * setup.velocity
                # the state committed to the device on every frame (a no-op for arrays already there): the first
                # frame's comes from the start or a re-initialisation, later ones from the step, and a stored step
                # (an exported program) returns committed arrays, which a program lowers differently from
                # uncommitted ones; so predict, and the step compiled ahead from shapes, see one kind of argument
                state = jax.device_put(state, _device())
                state = state._replace(particles=predict(state.particles, to_device(v, dt), circular_dev))
                if not self._compiled:  # a resumed run compiles at its first readable frame
                    self._compile(t, state, tobs)
                state, info, joints = self._step(self.filter, self._key(t), state, tobs)
                # prepare the next frame on the host while the step runs
                pending = self._prefetch(i + 1)
                info, joints = jax.device_get((info, joints))
                est = np.asarray(info.estimate, np.float64)
                quality = getattr(setup, "quality", None)
                top = np.asarray(info.layers.loglik_max)
                q = float(quality(top)) if quality is not None else float(-top.reshape(-1)[-1])
                recovered = bool(np.asarray(info.recovered))
                lost, reinit_source = False, None
                if setup.track_loss:
                    bad_quality = loss.bad_quality(q)
                    # the setup's detector sees a person again after frames without one: re-initialise, relearn q_ref
                    appeared = loss.unseen and not unseen
                    loss.unseen = unseen
                    if unseen:
                        loss.q_ref, loss.q_hist = float("nan"), []
                    lost = recovered or no_person or appeared or loss.lost_run >= o.loss_frames
                    if lost:
                        stats["lost_frames"] += 1
                        mean, reinit_source = setup.reinit_mean(fd, masks, loss.last_good)
                        if mean is not None:
                            state = self._reinit_state(t, mean)
                            stats["reinitialisations"] += 1
                            loss.new_track()
                        else:
                            loss.hist = [*loss.hist, (t, est)][-2:]
                    else:
                        loss.last_good = est if not bad_quality else loss.last_good
                        loss.hist = [*loss.hist, (t, est)][-2:]
                x = setup.output_state(est)
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
                if getattr(info, "layer_sets", None) is not None:  # --count-modes (López Méndez §5.2.1)
                    record["modes"] = count_layer_modes(*info.layer_sets, np.random.default_rng(t))
                # every frame has the first one's shapes: a compilation after the first frame is a defect
                compiled = watch.take()
                if compiled and i > start:
                    record["compiled_programs"] = compiled
                    stats["compiled_after_first_frame"] += compiled
                    if not self.quiet:
                        warn(
                            f"frame {t} compiled {compiled} program(s): please report it, with the command line"
                        )
                after = (t, state, loss.snapshot(), dict(stats)) if setup.resumable else None
                writer.submit(functools.partial(write_frame, t, x, joints, record, after))
                if stats["first_frame_s"] is None:
                    stats["first_frame_s"] = time.monotonic() - t_frame + (self.compile_s or 0.0)
                progress.update(i + 1, "lost" if lost else "")
            watch.close()
            interrupts.check()
            with interrupts.deferred():
                writer.drain()
                ck.flush()
                summary = self._write_outputs(pose_writer, diag, stats, ending)
                flushed = True
            if self.o.overlay and pose_writer.num_frames:
                summary["overlays"] = [os.fspath(q) for q in self.write_overlays(pose_writer)]
            with interrupts.deferred():
                pose_writer.close()
                diag.close(summary)
                run_folder.set_status(self.out, "complete")
        except BaseException as e:
            watch.close()
            progress.end_line()
            stopped = isinstance(e, KeyboardInterrupt | interrupts.Terminated)
            with interrupts.deferred():
                writer.close()  # the frames queued are written (a failed write's exception is ``e`` or after it)
                if not flushed:
                    ck.flush()
                    summary = self._write_outputs(pose_writer, diag, stats, ending, e)
                summary.update(interrupted=stopped, error=None if stopped else str(e))
                pose_writer.close()
                diag.close(summary)
                run_folder.set_status(self.out, "interrupted" if stopped else "stopped")
            self.summary = summary
            raise
        writer.close()
        self.summary = summary
        return summary

    def _write_frame(self, pose_writer, diag, t: int, x: np.ndarray, joints, record: dict) -> None:
        """The outputs of one tracked frame ``t``: the written state ``x`` (``setup.output_state``) and its joints
        ``(J, 3)`` (``model.joint_names`` order, metres; None: ``setup.joints(x)``) appended to the pose files, and
        the diagnostics ``record``. Runs in the output thread (:class:`run_folder.BackgroundWriter`), in frame
        order, while the next frame is tracked."""
        joints = self.setup.joints(x) if joints is None else np.asarray(joints, np.float64)
        pose_writer.append(t, x, export.eval_joints_of(self.setup.model, joints))
        diag.append(record)

    def _write_outputs(self, pose_writer, diag, stats, ending, error: BaseException | None = None) -> dict:
        """The outputs made from every frame tracked so far, written on every way out of a run (the end, Ctrl-C,
        SIGTERM, an error): ``poses.npz``, ``track.bvh``, ``diagnostics.json`` with the summary (returned)."""
        setup = self.setup
        model = setup.model
        n = pose_writer.num_frames
        stopped = isinstance(error, KeyboardInterrupt | interrupts.Terminated)
        summary = {
            "frames_tracked": n,
            "frames_requested": len(setup.frames),
            "frames_skipped": stats["skipped"],
            "lost_frames": stats["lost_frames"],
            "reinitialisations": stats["reinitialisations"],
            "wall_s": time.monotonic() - ending["wall"],
            "first_frame_s": stats["first_frame_s"],
            "frames_per_s": diag.frames_per_s(),
            "interrupted": stopped,
            "error": None if error is None or stopped else str(error),
            "resumed_at": ending["resumed_at"],
            "compilations": self.step_programs,
            "step_traces": self.trace_count,
            "compile_s": self.compile_s,
            "compiled_ahead": self.compiled_ahead,  # the step compiled while the first frame was initialised
            "compiled_after_first_frame": stats["compiled_after_first_frame"],
            "cpu": host.description(),  # what XLA compiled for: speeds compare only on the same CPU
            "xla_options": self._jitted.compiler_options,
            **host.thread_summary(),  # XLA's intra-op pool (jaxmocap --cpu-threads)
            "model": model.name,
            "filter": self.o.filter,
            "particles": setup.num_particles,
            "layers": setup.layers,
            "cues": [list(c) for c in setup.cues],
            "refine": getattr(setup, "refine", "none"),
            "refine_prior": getattr(setup, "refine_prior", None),
            "refine_depth": getattr(setup, "refine_depth", 0.0),
        }
        pose_writer.flush()
        groundtruth = getattr(self.source, "groundtruth", None)
        if n:  # the exported track: poses_smoothed.npz, track.bvh, poses.trc, poses.c3d, plots/
            summary.update(
                outputs.export_track(
                    self.out, model, setup.frames, pose_writer.frames, pose_writer.states, diag.records,
                    self.source.fps, smooth=self.o.smooth, bvh_units=self.o.bvh_units, groundtruth=groundtruth,
                    plots=self.o.plots,
                )
            )  # fmt: skip
        if groundtruth is not None and n:
            from jaxmocap.eval import metrics

            try:
                rep = metrics.evaluate([(np.asarray(pose_writer.frames), pose_writer.joints)], groundtruth)
                summary["mean_error_mm"] = rep["overall_mean_mm"]
            except ValueError:  # nothing to compare (e.g. a diverged, non-finite track)
                summary["mean_error_mm"] = None
        diag.write_json(summary)
        return summary

    def write_overlays(self, pose_writer) -> list[pathlib.Path]:
        """One H.264 MP4 per view of the tracked model drawn over the input (full size), and a montage PNG of six
        frames. Both are written in :data:`run_folder.OVERLAY_TMP` and moved next to the other outputs once
        complete: a run stopped while writing them (each writer is released on the way out) leaves no partial
        video under the final name."""
        from jaxmocap.eval import viz

        rig = self.source.rig
        rj = rig.to_jax(jnp.float32)
        model = self.setup.model
        states = dict(zip(pose_writer.frames, pose_writer.states, strict=True))
        joints = dict(zip(pose_writer.frames, pose_writer.joints, strict=True))
        gt = self.source.groundtruth
        tmp = self.out / run_folder.OVERLAY_TMP
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        try:
            with viz.OverlayVideo(tmp, rig.names, rig.image_size, self.source.fps, rj) as video:
                for t in self.setup.frames:
                    if t not in states:
                        continue
                    try:
                        fd = self.source.read(t, masks=False)
                    except BadFrame:
                        continue
                    truth = None if gt is None else gt[t]
                    video.write(viz.overlay_image(fd.images, model, rj, states[t], truth), joints[t], t)
            with interrupts.deferred():
                paths = []
                for q in (*video.paths, video.montage_path):
                    if q.exists():
                        os.replace(q, self.out / q.name)
                        paths.append(self.out / q.name)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return paths


def _device():
    """The device the loop's state lives on (the default one)."""
    return jax.devices()[0]


class _Failed:
    """A frame whose reading raised ``error`` (kept until the frame before it is written)."""

    def __init__(self, error: BaseException):
        self.error = error


def layer_records(layers) -> list[dict]:
    """Per-layer statistics (``LayerStats`` with a ``(L,)`` or ``(K, L)`` leading shape) as JSON records."""
    arrays = {k: np.asarray(v) for k, v in layers._asdict().items()}
    shape = arrays["beta"].shape
    out = []
    for idx in np.ndindex(*shape):
        rec = {k: (int(v[idx]) if v.dtype.kind in "iu" else float(v[idx])) for k, v in arrays.items()}
        rec.update(zip(("partition", "layer")[-len(shape) :], map(int, idx), strict=True))  # (K, L) or (L,)
        out.append(rec)
    return out
