"""The tracking loop: filter factory, per-model defaults, compile-once, end to end on a synthetic stereo sequence of
a real CMU walk (synthesise → track → evaluate), track-loss detection and re-initialisation."""

import json
import os
import sys
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap import stored_programs
from jaxmocap.eval import metrics
from jaxmocap.filters.factory import make_filter, partition_groups
from jaxmocap.fit import ik
from jaxmocap.geometry import body, camera
from jaxmocap.io import bvh, export
from jaxmocap.io.sources import SequenceSource
from jaxmocap.likelihood.coverage import coverage_energy
from jaxmocap.synth import generate as synth
from jaxmocap.tracking import init as init_mod
from jaxmocap.tracking import smoothing, tracker
from jaxmocap.tracking.options import (
    FILTERS,
    REFINE_DEPTH_SIGMA,
    REFINE_PRIOR_PAIR,
    TrackOptions,
    default_cues,
    default_layers,
    default_particles,
    default_refine_depth,
    diffusion_std,
    parse_cues,
)
from jaxmocap.tracking.setup import TrackSetup

# ---------------------------------------------------------------------------------------------------------------
# The filter factory on a Gaussian likelihood


class _Toy(NamedTuple):
    target: jnp.ndarray
    centre: jnp.ndarray
    valid: jnp.ndarray


SIGMA = 0.05


def _toy_loglik(X, o, layer):
    del layer
    return -0.5 * jnp.sum(((X - o.target) / SIGMA) ** 2, axis=-1)


def _toy(name, model, layers):
    D = model.num_dofs
    target = np.asarray(model.rest_pose, np.float64) + 0.1 * np.sin(np.arange(D))
    x0 = target + 0.15
    std = diffusion_std(model) * 0.5
    f = make_filter(name, _toy_loglik, model, std, 200, layers, prior_mean=x0, prior_std=3 * std)
    return f, target, x0, std


def test_filter_factory_builds_every_filter():
    """The name → filter mapping: classes, annealing schedules, first layers and partitions."""
    from jaxmocap.filters import APF, SIR, ICondensation, Partitioned

    model = body.upper9()
    kinds = {}
    for name in FILTERS:
        f, *_ = _toy(name, model, default_layers(name)[0])
        kinds[name] = type(f)
        if isinstance(f, APF):
            assert f.num_layers == 5
            assert f.schedule.kind == ("corrected" if name == "m-apf" else "survival")
            assert f.first_layer == ("icondensation" if name == "iapf" else "dynamics")
            np.testing.assert_allclose(f.schedule.scales, [0.25 ** (l / 4) for l in range(5)])
        if isinstance(f, Partitioned):
            assert f.groups == partition_groups(model)
            assert (f.schedule is not None) == (name == "hierarchical")
            assert f.scan_partitions and f.runs() == [(0, len(f.groups))]  # a single scanned stage
        # the heading is averaged as an angle
        assert f.circular[model.dof_index("body_rz")] and not f.circular[0]
    assert kinds["sir"] is SIR and kinds["icondensation"] is ICondensation
    assert {kinds[n] for n in ("apf", "iapf", "fbapf", "fbapf2", "fbapf3", "m-apf")} == {APF}
    assert kinds["partitioned"] is Partitioned and kinds["hierarchical"] is Partitioned
    counts = (30, 10, 20, 20)
    f = make_filter("partitioned", _toy_loglik, model, np.ones(model.num_dofs), counts, 1, np.zeros(13), 1)
    assert f.counts == counts and f.runs() == [(0, 4)]  # unequal counts: scanned too, through a padded buffer
    assert f.buffer_size == 128  # the largest count rounded up to whole chunks
    with pytest.raises(ValueError, match="unknown filter"):
        make_filter("kalman", _toy_loglik, model, np.ones(13), 10, 1, np.zeros(13), np.ones(13))


@pytest.mark.parametrize("name", ["icondensation", "apf"])
def test_filters_move_to_a_static_target(name):
    """Started 0.15 away from a static target on every DOF of upper9, the filter ends near it: the RMS error over
    the DOFs falls below 0.05 (a third of the start; the likelihood's own spread is σ = 0.05 per DOF). A filter
    that ignored the weights would keep the start error plus its random walk. ICONDENSATION's detection
    proposal is centred on the target (the proposal-centre wiring of :class:`TrackObservation`)."""
    model = body.upper9()
    f, target, x0, std = _toy(name, model, default_layers(name)[0])
    obs = _Toy(jnp.asarray(target, jnp.float32), jnp.asarray(target, jnp.float32), jnp.asarray(True))
    step = jax.jit(f.step)
    state = f.init(jax.random.key(0), jnp.asarray(x0, jnp.float32), jnp.asarray(std))
    for t in range(12):
        state, info = step(jax.random.fold_in(jax.random.key(1), t), state, obs)
    err = np.sqrt(np.mean((np.asarray(info.estimate) - target) ** 2))
    assert err < 0.05, err


def test_partition_groups_and_defaults():
    m = body.full25()
    groups = partition_groups(m)
    assert [len(g) for g in groups] == [6, 3, 4, 4, 4, 4]
    assert sorted(d for g in groups for d in g) == list(range(m.num_dofs))
    assert [m.dof_names[g[0]] for g in groups] == [
        "root_tx",
        "neck_rx",
        "left_shoulder_rx",
        "right_shoulder_rx",
        "left_hip_rx",
        "right_hip_rx",
    ]
    # full32: the spine joins the root in the trunk's group; each girdle goes with its arm
    m32 = body.full32()
    g32 = partition_groups(m32)
    assert [[m32.dof_names[d] for d in g] for g in g32][:3] == [
        [*(m32.dof_names[:6]), "spine_rx", "spine_ry", "spine_rz"],
        ["neck_rx", "neck_ry", "neck_rz"],
        ["left_clavicle_rx", "left_clavicle_rz", *(f"left_shoulder_r{a}" for a in "xyz"), "left_elbow"],
    ]
    assert [len(g) for g in g32] == [9, 3, 6, 6, 4, 4]
    assert sorted(d for g in g32 for d in g) == list(range(m32.num_dofs))
    s32 = diffusion_std(m32)
    assert s32[m32.dof_index("spine_ry")] == s32[m32.dof_index("left_clavicle_rz")] == pytest.approx(0.03)
    std = diffusion_std(m, fps=30.0)
    np.testing.assert_allclose(diffusion_std(m, fps=60.0), std / 2, rtol=1e-6)
    assert std[m.dof_index("root_tx")] == pytest.approx(0.03)
    assert default_particles("full25", "sir") == 5 * default_particles("full25", "apf")
    assert parse_cues("foreground,edge_distance:2") == (("foreground", 1.0), ("edge_distance", 2.0))
    with pytest.raises(ValueError, match="unknown cue"):
        parse_cues("foreground,nose")
    assert [n for n, _ in default_cues("full25", True, False)] == [
        "foreground",
        "edge_distance",
        "coverage",
        "depth",
    ]


def test_coverage_energy_counts_uncovered_samples():
    """Samples on a projected limb cost 0; samples far from every limb cost 1 each (the energy is the mean)."""
    from jaxmocap.geometry import camera

    m = body.full25()
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    R = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])  # looking along +x, z up
    rig = camera.from_opencv(
        K[None], np.zeros((1, 5)), R[None], (-R @ np.array([-4.0, 0, 1]))[None], ("c",), [(640, 480)]
    )
    rj = rig.to_jax(jnp.float32)
    x = m.rest_pose
    on = np.asarray(jax.jit(lambda x: camera.project(rj, body.joint_positions(m, x)))(x))[
        0
    ]  # inside the flesh
    far = np.array([[5.0, 5.0], [630.0, 5.0], [5.0, 470.0]])
    uv = jnp.asarray(np.concatenate([on, far])[None], jnp.float32)
    w = jnp.ones(uv.shape[:2], jnp.float32)
    energy = jax.jit(coverage_energy)
    e = energy(m, rj, x, uv, w, jnp.asarray([10.0]))
    assert float(e[0]) == pytest.approx(3 / uv.shape[1], abs=1e-6)
    # empty slots (weight 0) do not count
    e0 = energy(m, rj, x, uv, w.at[0, -3:].set(0.0), jnp.asarray([10.0]))
    assert float(e0[0]) == pytest.approx(0.0, abs=1e-6)


# ---------------------------------------------------------------------------------------------------------------
# End to end

FRAMES = "0:48"  # 12 frames at 30 fps of the bundled 120 fps walk
SIZE = "320x240"


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    out = tmp_path_factory.mktemp("seq")
    synth.synthesize("demo", out, rig="stereo", frames=FRAMES, size=SIZE, seed=0, overwrite=True)
    return out


@pytest.fixture(scope="module")
def tracked(sequence, tmp_path_factory):
    out = tmp_path_factory.mktemp("track")
    src = SequenceSource(sequence)
    run = tracker.Tracker(src, out, TrackOptions(particles=200, layers=4, seed=0), quiet=True)
    summary = run.run()
    return run, out, summary


@pytest.mark.slow
def test_end_to_end_error_is_bounded(sequence, tracked):
    """Synthesise → track (full25, APF 200 × 4, default cues, ground-truth start) → evaluate.

    Bound: 120 mm mean joint error over these 12 frames (0.4 s of a walk towards a stereo pair 0.3 m wide, 320×240
    px). Reference points: one pixel is ≈ 14 mm at the subject (3.5 m away, f = 256 px), the tracker's cones
    differ from the rendered body by ≈ 10 mm per joint even at their best fit (IK of the ground truth), and depth
    along the viewing direction, where the legs swing, is seen only through the 2 cm-noise virtual depth map;
    holding the first frame's pose (no tracking) errs by ≈ 200 mm, and the tracker must at least halve that.
    Measured: 72.7 mm (seed 0; 60–80 mm over seeds 0–3)."""
    run, out, summary = tracked
    gt_frames, gt = metrics.load_groundtruth(sequence)
    rep = metrics.evaluate([metrics.load_prediction(out)], gt, gt_frames)
    err = rep["overall_mean_mm"]
    print(f"end-to-end mean joint error: {err:.1f} mm (± {rep['overall_std_mm']:.1f})")
    assert err < 120.0
    assert summary["mean_error_mm"] == pytest.approx(err)
    # no tracking: the first frame's estimate held over the sequence
    poses = export.load_poses(out)
    held = np.repeat(poses["joints"][:1], len(poses["frame_index"]), axis=0)
    static = metrics.evaluate([(poses["frame_index"], held)], gt, gt_frames)["overall_mean_mm"]
    assert static > 2.0 * err, (static, err)


@pytest.mark.slow
def test_compiled_once_and_outputs(sequence, tracked):
    run, out, summary = tracked
    # compiled ahead, while the first frame was initialised, with the structure of the step it then ran
    assert run.compiled_ahead
    assert run.trace_count == 1 and summary["compilations"] == 1
    assert summary["compiled_after_first_frame"] == 0
    assert run._step._cache_size() == 1
    poses = export.load_poses(out)
    T = len(run.frames)
    assert poses["state"].shape == (T, 25) and poses["joints"].shape == (T, 15, 3)
    assert list(poses["dof_names"]) == list(run.model.dof_names)
    assert list(poses["joint_names"]) == list(body.EVAL_JOINTS)
    diag = json.loads((out / "diagnostics.json").read_text())
    assert len(diag["frames"]) == T and diag["summary"]["frames_tracked"] == T
    layer = diag["frames"][3]["layers"][0]
    for key in ("beta", "survival_rate", "loglik_range", "loglik_min", "loglik_max"):
        assert np.isfinite(layer[key])
    assert len(diag["frames"][3]["layers"]) == 4
    assert diag["frames"][0]["init"] == "groundtruth"
    # the exported track (smoothed by default): the BVH reproduces its joints through the project's reader, and
    # it stays within a few centimetres of the raw estimates (2 Hz over 12 frames takes the frame-to-frame jitter of
    # the legs away: 3-5 cm here), and no further from the ground truth than they are
    assert summary["smooth"] == f"butterworth:{smoothing.DEFAULT_CUTOFF_HZ:g}"
    sm = np.load(out / "poses_smoothed.npz")
    np.testing.assert_array_equal(sm["frame_index"], poses["frame_index"])
    assert not sm["interpolated"].any() and summary["interpolated_frames"] == 0
    m = bvh.load_bvh(out / "track.bvh", scale=0.01)
    J = export.bvh_eval_joints(m, run.model)
    np.testing.assert_allclose(export.eval_joints_of(run.model, J), sm["joints"], atol=1e-6)
    assert np.nanmean(np.linalg.norm(sm["joints"] - poses["joints"], axis=-1)) < 0.08
    assert summary["mean_error_smoothed_mm"] <= summary["mean_error_mm"] + 5.0
    for name in (
        "poses.trc",
        "poses.c3d",
        "plots/trajectories.png",
        "plots/skeleton.png",
        "plots/quality.png",
    ):
        assert (out / name).stat().st_size > 0


def _stored_functions():
    """The package's functions kept by ``stored_programs.stored_jit`` (the first pose's fits, the overlays' …)."""
    found = {}
    for name, mod in list(sys.modules.items()):
        if name.startswith("jaxmocap"):
            for v in vars(mod).values():
                if isinstance(v, stored_programs._StoredFunction):
                    found[id(v)] = v
    return list(found.values())


@pytest.mark.slow
def test_a_warm_run_reads_its_traced_programs_back(sequence, tmp_path):
    """As the command line runs (inside ``stored_programs.use``): the first run stores its traced filter step and
    the programs of its first pose (triangulation, IK fits); a second run of the configuration (a new Tracker,
    this process's stored programs forgotten: as in a new process) traces none of them — ``step_traces`` 0, one
    step program all the same — and tracks the same poses bit for bit, which are those of a run outside ``use``
    (plain ``jax.jit``)."""
    opts = TrackOptions(particles=30, layers=2, seed=0, frames="0:3", init="ik", smooth="none")
    cache = tmp_path / "cache"

    def run(name, folder):
        for fn in _stored_functions():
            fn._stored.clear()
        with stored_programs.use(folder):
            r = tracker.Tracker(SequenceSource(sequence), tmp_path / name, opts, quiet=True)
            summary = r.run()
        fits = [s for fn in _stored_functions() for s in fn._stored.values()]
        return r, summary, fits, export.load_poses(tmp_path / name)["state"]

    first, s1, fits1, poses1 = run("first", cache)
    assert (first.trace_count, s1["compilations"], s1["step_traces"]) == (1, 1, 1)
    assert {ik._solve, ik.root_init, init_mod._fit_from, camera.triangulate} <= set(_stored_functions())
    assert len(fits1) >= 4 and all(f.exported >= 1 and f.loaded == 0 for f in fits1)
    stored = sorted((cache / stored_programs.FOLDER).glob("*.jaxexport"))
    assert len(stored) == 1 + sum(f.exported for f in fits1)  # the step and the others
    second, s2, fits2, poses2 = run("second", cache)
    assert (second.trace_count, s2["compilations"], s2["step_traces"]) == (0, 1, 0)
    assert sorted(f.loaded for f in fits2) == sorted(f.exported for f in fits1)
    assert all(f.exported == 0 for f in fits2)
    assert sorted((cache / stored_programs.FOLDER).glob("*.jaxexport")) == stored
    plain, s3, fits3, poses3 = run("plain", None)
    assert (plain.trace_count, s3["compilations"], fits3) == (1, 1, [])
    np.testing.assert_array_equal(poses2, poses1)
    np.testing.assert_array_equal(poses3, poses1)


class _Blanked:
    """A source whose frames ``blank`` show nothing (no foreground, no detection: the background alone)."""

    def __init__(self, source, blank):
        self.s, self.blank = source, set(blank)
        for k in ("rig", "fps", "num_frames", "view_names", "has_masks", "has_depth", "has_keypoints"):
            setattr(self, k, getattr(source, k))
        self.body_path, self.groundtruth, self.description = source.body_path, source.groundtruth, {"test": 1}

    def read(self, t, masks=True, depth=True):
        fd = self.s.read(t, masks, depth)
        if t in self.blank and fd.masks is not None:
            fd = fd._replace(masks=[np.zeros_like(m) for m in fd.masks])
        if t in self.blank and fd.keypoints is not None:
            fd = fd._replace(keypoints=np.zeros_like(fd.keypoints))
        return fd

    def close(self):
        pass


def test_track_loss_is_detected_and_reinitialised(sequence, tmp_path):
    """Frames without a person are reported lost and the filter is re-initialised (from the last good estimate:
    no detection there); tracking goes on afterwards."""
    src = _Blanked(SequenceSource(sequence), blank=(5, 6))
    opts = TrackOptions(model="upper9", cues="coverage", particles=60, layers=2, frames="0:9")
    summary = tracker.Tracker(src, tmp_path, opts, quiet=True).run()
    recs = json.loads((tmp_path / "diagnostics.json").read_text())["frames"]
    lost = [r["frame"] for r in recs if r["lost"]]
    assert lost == [5, 6]
    assert all(r["no_person"] for r in recs if r["frame"] in (5, 6))
    assert [r["reinit_source"] for r in recs if r["reinitialised"]] == ["last_estimate", "last_estimate"]
    assert summary["reinitialisations"] == 2 and summary["lost_frames"] == 2
    assert not recs[7]["lost"] and np.isfinite(recs[8]["quality"])


class _NoFirstDetections(_Blanked):
    """A source whose first frame has no detections (its masks kept)."""

    def read(self, t, masks=True, depth=True):
        fd = self.s.read(t, masks, depth)
        return fd._replace(keypoints=np.zeros_like(fd.keypoints)) if t == 0 else fd


def test_no_frame_compiles_not_even_a_reinitialisation_from_detections(sequence, tmp_path):
    """The first pose comes from the silhouettes (frame 0 has no detections), and every later frame is declared
    lost (``loss_ratio`` 0.1 of a reference learnt over one frame) and re-initialised from its detections: those
    programs are compiled before the first frame (``setup.warm_reinit``), and no frame after the first lowers a
    program on the loop's thread (the in-memory caches are cleared first, so that earlier tests cannot have
    compiled them). The estimate is refined on the detections in the step (``refine="track"``)."""
    jax.clear_caches()
    src = _NoFirstDetections(SequenceSource(sequence), blank=())
    opts = TrackOptions(
        model="upper9", cues="coverage", particles=40, layers=2, frames="0:6", init="ik",
        loss_ratio=0.1, loss_frames=1, loss_window=1, refine="track",
    )  # fmt: skip
    summary = tracker.Tracker(src, tmp_path, opts, quiet=True).run()
    recs = json.loads((tmp_path / "diagnostics.json").read_text())["frames"]
    assert recs[0]["init"] == "ik-silhouette"
    assert [r["reinit_source"] for r in recs if r["reinitialised"]].count("keypoints") >= 2
    assert summary["compiled_after_first_frame"] == 0
    assert not any("compiled_programs" in r for r in recs)


def test_refinement_options_are_checked_against_the_input(sequence):
    """``refine``: a known choice, and detections to refine on; ``auto`` refines a stereo pair's track with the
    stronger prior, and nothing without detections."""
    with pytest.raises(ValueError, match="unknown refine"):
        TrackSetup(SequenceSource(sequence), TrackOptions(refine="smooth", frames="0:2"))
    with pytest.raises(ValueError, match="needs 2D keypoints"):
        TrackSetup(SequenceSource(sequence, detections=False), TrackOptions(refine="track", frames="0:2"))
    assert TrackSetup(SequenceSource(sequence, detections=False), TrackOptions(frames="0:2")).refiner is None
    pair = TrackSetup(SequenceSource(sequence), TrackOptions(frames="0:2"))
    assert (pair.refine, pair.refine_prior) == ("track", REFINE_PRIOR_PAIR)
    given = TrackSetup(SequenceSource(sequence), TrackOptions(refine="track", refine_prior=2.0, frames="0:2"))
    assert (given.refiner.mode, given.refiner.prior) == ("track", 2.0)
    # the depth term: a standard deviation, and depth maps to read (then read even without a depth cue)
    assert pair.refine_depth == REFINE_DEPTH_SIGMA and pair.refiner.depth_sigma == (
        REFINE_DEPTH_SIGMA or None
    )
    with pytest.raises(ValueError, match="refine_depth"):
        TrackSetup(SequenceSource(sequence), TrackOptions(refine_depth=-0.1, frames="0:2"))
    no_depth = SequenceSource(sequence)
    no_depth.has_depth = False
    with pytest.raises(ValueError, match="needs depth maps"):
        TrackSetup(no_depth, TrackOptions(refine_depth=0.05, frames="0:2"))
    assert TrackSetup(no_depth, TrackOptions(frames="0:2")).refine_depth == 0.0
    depth = TrackSetup(
        SequenceSource(sequence), TrackOptions(cues="foreground", refine_depth=0.05, frames="0:2")
    )
    assert depth.refiner.depth_sigma == 0.05 and depth.features.needs_depth
    # by default only a stereo pair's refinement reads the depth maps (four cameras: none; nothing to refine: none)
    assert default_refine_depth("track", True, 2) == REFINE_DEPTH_SIGMA > 0
    assert default_refine_depth("track", True, 4) == default_refine_depth("none", True, 2) == 0.0
    assert default_refine_depth("track", False, 2) == 0.0


class _MasksGone(_NoFirstDetections):
    """No detections in frame 0 and no foreground in frame 4 (its detections kept)."""

    def read(self, t, masks=True, depth=True):
        fd = super().read(t, masks, depth)
        return fd._replace(masks=[np.zeros_like(m) for m in fd.masks]) if t == 4 else fd


class _StopAt3(_MasksGone):
    def read(self, t, masks=True, depth=True):
        if t == 3:
            raise KeyboardInterrupt
        return super().read(t, masks, depth)


def test_a_resumed_run_compiles_its_reinitialisation_before_tracking(sequence, tmp_path):
    """Interrupted at frame 3 and resumed (in-memory caches cleared, as in a new process): frame 4 shows no
    foreground and is re-initialised from its detections, the run's first re-initialisation since the resume;
    neither the keypoint fit nor the filter's re-initialisation compiles there (51 programs before they were
    compiled ahead on resume, 6 with the fit alone)."""
    opts = dict(
        model="upper9", cues="coverage", particles=40, layers=2, frames="0:6", init="ik", loss_frames=1
    )
    with pytest.raises(KeyboardInterrupt):
        tracker.Tracker(
            _StopAt3(SequenceSource(sequence), blank=()), tmp_path, TrackOptions(**opts), quiet=True
        ).run()
    jax.clear_caches()
    src = _MasksGone(SequenceSource(sequence), blank=())
    summary = tracker.Tracker(src, tmp_path, TrackOptions(resume=True, **opts), quiet=True).run()
    recs = json.loads((tmp_path / "diagnostics.json").read_text())["frames"]
    assert summary["resumed_at"] is not None and summary["resumed_at"] < 4
    assert [r["frame"] for r in recs if r["reinitialised"]] == [4]
    assert recs[4]["reinit_source"] == "keypoints"
    assert summary["compiled_after_first_frame"] == 0


class _Interrupting(_Blanked):
    """A source that raises KeyboardInterrupt (Ctrl-C) when frame ``stop`` is read."""

    def __init__(self, source, stop):
        super().__init__(source, blank=())
        self.stop = stop

    def read(self, t, masks=True, depth=True):
        if t == self.stop:
            raise KeyboardInterrupt
        return super().read(t, masks, depth)


@pytest.mark.slow
def test_colour_cues_track_with_first_frame_references_and_resume(sequence, tmp_path):
    """The IROS 2007 cue set (edges, colour histograms, skin, 3D blobs, homogeneous colour) and Li & Kulić's colour
    template run in the tracker: the features include the colour / skin / blob maps, the colour references come
    from the first frame at the initial pose (so the template energy of that pose in that frame is 0), and a run
    interrupted by Ctrl-C and resumed recomputes the same references and ends with the same poses."""
    cues = (
        "foreground,edge_distance,colour_histogram,skin,blobs3d,homogeneous_colour,colour_template,coverage"
    )
    opts = dict(model="upper14", filter="apf", cues=cues, particles=30, layers=2, frames="0:4", seed=3)
    # the runs keep their traced steps as the command line does: the interrupted and the resumed run read the
    # first run's back instead of tracing the same step again
    with stored_programs.use(tmp_path / "programs"):
        full = tracker.Tracker(SequenceSource(sequence), tmp_path / "full", TrackOptions(**opts), quiet=True)
        full.run()
        assert (
            not full.compiled_ahead and full.trace_count == 1
        )  # the references are structure: compiled after them
        lik = full.likelihood
        names = [c.name for c in lik.cues]
        assert all(
            lik.references[names.index(n)] is not None for n in ("colour_histogram", "colour_template")
        )
        first = full._observe(0)[0].image
        for f in ("rgb", "skin", "blobs3d"):
            assert first.has(f), f
        x0 = jnp.asarray(np.load(tmp_path / "full" / "resume.npz")["x0"], jnp.float32)
        e = jax.jit(lik.energies)(x0, first)
        assert float(e[names.index("colour_template")]) == pytest.approx(0.0, abs=1e-5)  # √(… + ε) per sample

        part = tmp_path / "part"
        src = _Interrupting(SequenceSource(sequence), stop=3)
        with pytest.raises(KeyboardInterrupt):
            tracker.Tracker(src, part, TrackOptions(**opts), quiet=True).run()
        done = export.load_poses(part)["frame_index"]
        assert 0 < len(done) < 4
        src = _Interrupting(SequenceSource(sequence), stop=-1)  # the same input description, no Ctrl-C
        tracker.Tracker(src, part, TrackOptions(**opts, resume=True), quiet=True).run()
        a, b = export.load_poses(tmp_path / "full"), export.load_poses(part)
        np.testing.assert_array_equal(a["frame_index"], b["frame_index"])
        np.testing.assert_allclose(a["state"], b["state"], rtol=0, atol=1e-6)


def test_hybrid_filter_of_the_tracker_takes_the_fast_gradient_path(sequence, monkeypatch):
    """``jaxmocap track --filter hybrid``: the filter the tracker builds differentiates its likelihood through
    ``Likelihood.batch_value_and_grad`` (per-particle gradients in one vmap), never the general vjp path."""
    from jaxmocap.filters.hybrid import HybridAPF
    from jaxmocap.likelihood import gradients

    opts = TrackOptions(filter="hybrid", model="upper9", particles=8, layers=2, frames="0:2")
    run = tracker.Tracker(SequenceSource(sequence), os.devnull, opts, quiet=True)
    tobs = run._observe(0)[0]
    run._make_filter(np.asarray(run.model.rest_pose))
    f = run.filter
    assert isinstance(f, HybridAPF) and f.move is not None
    assert gradients.own_value_and_grad(f.loglik_batch) is not None

    def slow(*args, **kwargs):
        raise AssertionError("the general vjp path ran")

    monkeypatch.setattr(gradients, "vjp_value_and_grad", slow)
    state = f.init(jax.random.key(0), jnp.asarray(run.model.rest_pose))
    out = jax.eval_shape(f.step, jax.random.key(1), state, tobs)  # traces every gradient move of the step
    assert out[0].particles.shape == state.particles.shape


def test_every_filter_built_twice_has_one_structure(sequence):
    """The filter the tracker compiles ahead (around the rest pose) and the one it runs (around the initial pose)
    are the same program: for every filter name, two filters built around different poses have one tree
    structure (the pose, the likelihood's arrays are leaves or held by identity; the functions are the same)."""
    for name in FILTERS:
        cues = "foreground,edge_distance,coverage:4" if name in ("hybrid", "apf-refine") else None
        opts = TrackOptions(filter=name, model="upper9", cues=cues)
        run = tracker.Tracker(SequenceSource(sequence), os.devnull, opts, quiet=True)
        x0 = np.asarray(run.model.rest_pose, np.float64)
        a, b = run.setup.make_filter(x0), run.setup.make_filter(x0 + 0.1)
        assert jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(b), name


def test_tracker_gradient_is_that_of_its_batch_likelihood(sequence):
    """The tracker's per-particle value and gradient (flesh points projected as world points, the coverage term on
    the image cues' segment poses) are those of its batch likelihood (flesh points run by run, its own forward
    kinematics), differentiated by ``jax.grad`` on each particle's scalar log-likelihood: the same function up to
    float32 rounding."""
    opts = TrackOptions(filter="hybrid", model="upper9", cues="foreground,edge_distance,coverage:4")
    run = tracker.Tracker(SequenceSource(sequence), os.devnull, opts, quiet=True)
    tobs = run._observe(0)[0]
    ll = run.loglik
    x0 = np.asarray(run.model.rest_pose, np.float32)
    X = jnp.asarray(x0 + 0.03 * np.random.default_rng(0).normal(size=(4, x0.size)), jnp.float32)
    v, g = jax.jit(lambda X: ll.batch_value_and_grad(X, tobs, 1))(X)
    one = jax.jit(jax.vmap(jax.value_and_grad(lambda x: ll(x[None], tobs, 1)[0])))
    v_ref, g_ref = one(X)
    assert np.all(np.isfinite(v_ref)) and np.any(np.asarray(g_ref) != 0)
    np.testing.assert_allclose(v, v_ref, rtol=1e-5)
    np.testing.assert_allclose(g, g_ref, rtol=1e-3, atol=1e-3 * float(np.max(np.abs(g_ref))))


def test_gradient_filters_take_the_default_cues_with_depth(sequence):
    """A full-body sequence with depth maps: its default cues include Li & Kulić's ``depth``, which ``--filter
    hybrid`` takes without a message (its smooth variant: bilinear reads, ``soft=True``), as it takes every cue
    with a differentiable configuration; the value and gradient of the tracker's likelihood around the first frame's
    pose are finite and the gradient is not zero."""
    from jaxmocap.likelihood.cues import DIFFERENTIABLE
    from jaxmocap.tracking.setup import TrackSetup

    src = SequenceSource(sequence)
    opts = TrackOptions(filter="hybrid", model="full25", init="groundtruth", frames="0:2")
    setup = TrackSetup(src, opts)
    names = [n for n, _ in setup.cues]
    assert src.has_depth and names == [n for n, _ in default_cues("full25", True, src.has_keypoints)]
    assert "depth" in names and not any("differentiable" in n for n in setup.notes)
    depth = next(c for c in setup.likelihood.cues if c.name == "depth")
    assert DIFFERENTIABLE["depth"] == "soft" and depth.param_dict == {"bilinear": True, "soft": True}
    tobs, masks, fd, _ = setup.observe(setup.frames[0])
    x0, _, _ = setup.initial_state(setup.frames[0], masks, fd)
    noise = np.random.default_rng(0).normal(size=(4, setup.model.num_dofs)) * np.asarray(setup.std)
    X = jnp.asarray(np.asarray(x0) + noise, jnp.float32)
    v, g = jax.jit(lambda X: setup.loglik.batch_value_and_grad(X, tobs, setup.layers - 1))(X)
    assert np.all(np.isfinite(np.asarray(v))) and np.all(np.isfinite(np.asarray(g)))
    assert np.all(np.abs(np.asarray(g)).max(-1) > 0)


def test_default_particles_per_input_kind():
    """300 APF particles per layer for the full body; 50 where each frame's estimate is refined on detections of
    three or more cameras (``refined_views``: the refinement places the joints, the particles only keep the track),
    not for the other filters or bodies."""
    from jaxmocap.tracking.options import REFINED_VIEWS_PARTICLES

    assert default_particles("full25", "apf") == default_particles("full32", "apf") == 300
    assert default_particles("full25", "apf", refined_views=True) == REFINED_VIEWS_PARTICLES == 50
    assert default_particles("full32", "apf", refined_views=True) == 50
    assert default_particles("full25", "hybrid", refined_views=True) == 300
    assert default_particles("upper14", "apf", refined_views=True) == 200
