"""Inputs the benchmark scripts share: the likelihood benchmarks' stereo scene, and the synthetic CMU sequences the
tracking benchmarks run the tracker on.

Likelihood scene (``perf/bench_likelihood.py``, ``perf/profile_likelihood.py``, and the NumPy baseline of
:mod:`reference.numpy_baselines`): two 640×480 cameras 30 cm apart (the IROS 2007 robot head), smooth random
observation maps of the right shapes and ranges, particles drawn around the rest pose; :data:`CONFIGS` names each
body model + cue set, :func:`build` makes its likelihood.

Tracked sequences (``experiments/accuracy.py``, ``perf/compile_partitions.py``): the bundled CMU walk (and the CMU
Charleston dance when ``../shared/data/mocap/cmu`` is there) synthesised for the stereo preset
(:func:`make_sequences`), tracked by :class:`CachedTracker` (the tracker exactly as ``jaxmocap track`` runs it,
keeping its compiled step and observations across seeds) with the options of a :class:`Config`
(:func:`track_options`), on the input of :func:`open_source`: by default what a real setup records
(:class:`PlateSource`: silhouettes by background subtraction against each view's empty-scene plate, the
simulated 2D detections, initialisation by inverse kinematics on them); the *oracle* input (the rendered masks,
initialisation from the ground truth) only where asked for. Both track the body of the sequence's body file.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import shutil
import time

import numpy as np
from common import ROOT

from jaxmocap.features.observation import make_observation
from jaxmocap.geometry import body, camera
from jaxmocap.io import calibration
from jaxmocap.io.sources import FrameData, SequenceSource
from jaxmocap.likelihood import compose as L
from jaxmocap.synth import generate as synth
from jaxmocap.synth import plates
from jaxmocap.synth.generate import look_at
from jaxmocap.tracking import tracker
from jaxmocap.tracking.options import TrackOptions

W, H = 640, 480
F = np.float32

IROS_CUES = ("edge_distance", "colour_histogram", "blobs3d", "skin", "homogeneous_colour")
#: name -> (body model, cues, target particles/s, flesh surface samples)
CONFIGS = {
    "upper14-iros": ("upper14", IROS_CUES, 100_000, 600),
    "full25-lk": ("full25", ("edges", "foreground", "depth"), 50_000, 600),
}
#: the IROS 2007 set with fewer surface samples (the cost is linear in them): how far the default is from the target
SAMPLE_SWEEP = {
    "upper14-iros-P300": ("upper14", IROS_CUES, 100_000, 300),
    "upper14-iros-P150": ("upper14", IROS_CUES, 100_000, 150),
}


# ---------------------------------------------------------------------------------------------------------------
# Likelihood scene


def stereo_rig() -> camera.Rig:
    """Two cameras 30 cm apart, 1.3 m high, 3.5 m from the subject (the IROS 2007 robot head), 640×480."""
    Rs, ts = zip(*[look_at(np.array([3.5, y, 1.3]), [0.0, 0.0, 1.0]) for y in (-0.15, 0.15)], strict=True)
    K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
    return camera.from_opencv(
        np.stack([K, K]), np.zeros((2, 5)), np.stack(Rs), np.stack(ts), image_size=[(W, H)] * 2
    )


def observation(rig, rng):
    """Synthetic maps of the right shapes and ranges (smooth random fields: the timing does not depend on content)."""

    def field(scale=1.0):
        small = rng.uniform(0, 1, (2, H // 16 + 1, W // 16 + 1)).astype(F)
        return np.repeat(np.repeat(small, 16, 1), 16, 2)[:, :H, :W] * scale

    fg = (field() > 0.3).astype(F)
    return make_observation(
        rig,
        foreground=fg,
        edges=field(),
        edge_dt=field(40.0),
        skin=field(),
        depth=np.where(fg > 0, 2.5 + field(1.0), 0.0).astype(F),
        rgb=np.stack([field(), field(), field()], -1),
        blobs3d=np.array([[0.0, 0.0, 1.6], [0.3, 0.25, 1.2], [0.3, -0.25, 1.2]]),
    )


def particles(model, n, rng):
    """``(n, D)`` float32 states: the rest pose + N(0, 0.05²) on every DOF, clipped to the joint limits."""
    x = np.asarray(model.rest_pose, F).copy()
    noise = rng.normal(0.0, 0.05, (n, model.num_dofs)).astype(F)
    return np.clip(x + noise, np.asarray(model.lower), np.asarray(model.upper)).astype(F)


def build(config: str, rng):
    """``(model, rig, observation, likelihood, target particles/s)`` of the configuration ``config`` (a key of
    :data:`CONFIGS` or :data:`SAMPLE_SWEEP`); colour references taken at the rest pose when a cue needs them."""
    preset, names, target, points = {**CONFIGS, **SAMPLE_SWEEP}[config]
    model = getattr(body, preset)()
    rig = stereo_rig()
    obs = observation(rig, rng)
    lik = L.Likelihood.create(model, rig, [L.Cue(n) for n in names], surface_points=points)
    if lik.needs_references:
        lik = lik.with_references(model.rest_pose, obs)
    return model, rig, obs, lik, target


# ---------------------------------------------------------------------------------------------------------------
# Tracked synthetic sequences

SHARED_CMU = ROOT.parent / "shared" / "data" / "mocap" / "cmu"
#: the shared motion capture (``shared/data/mocap`` beside the checkout or beside one of its parent folders)
MOCAP = next(
    (d for d in (SHARED_CMU.parent, *(p / "shared" / "data" / "mocap" for p in ROOT.parents)) if d.is_dir()),
    SHARED_CMU.parent,
)
BASE_CUES = ("foreground", "edge_distance", "coverage:4")


def clips() -> list[tuple[str, str | pathlib.Path, pathlib.Path | None]]:
    """``(name, motion, asf)`` of the clips used: the bundled walk, plus the Charleston dance when the shared data
    is there."""
    out: list[tuple[str, str | pathlib.Path, pathlib.Path | None]] = [("walk 02_01", "demo", None)]
    dance = SHARED_CMU / "charleston1.amc"
    if dance.is_file() and (SHARED_CMU / "charleston.asf").is_file():
        out.append(("charleston", dance, SHARED_CMU / "charleston.asf"))
    return out


class CachedTracker(tracker.Tracker):
    """A :class:`~jaxmocap.tracking.tracker.Tracker` that keeps its compiled step and its per-frame observations across runs
    (the initial state comes from the ground truth or the detections of the first frame, so every seed starts from
    the same ``x0``)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._obs_cache: dict = {}
        self.step_seconds: list[float] = []

    def _make_filter(self, x0):
        if self.filter is None:
            super()._make_filter(x0)
            inner = self._step

            def timed(filt, key, state, tobs):
                t = time.perf_counter()
                out = inner(filt, key, state, tobs)
                out[0].particles.block_until_ready()
                self.step_seconds.append(time.perf_counter() - t)
                return out

            self._step = timed

    def _observe(self, t):
        if t not in self._obs_cache:
            self._obs_cache[t] = super()._observe(t)
        return self._obs_cache[t]

    def run_seeds(self, seeds: int, seq_dir) -> tuple[list[float], list[dict], list[tuple]]:
        """Runs with seeds ``0 … seeds − 1``: each run's error against the sequence's ground truth (thesis eq. 7.1
        averaged over frames, mm), its summary and its prediction (:func:`jaxmocap.eval.metrics.load_prediction`)."""
        from jaxmocap.eval import metrics

        gt_frames, gt = metrics.load_groundtruth(seq_dir)
        errors, summaries, runs = [], [], []
        for s in range(seeds):
            self.o.seed = s
            summaries.append(self.run())
            runs.append(metrics.load_prediction(self.out))
            errors.append(float(metrics.evaluate(runs[-1:], gt, gt_frames)["overall_mean_mm"]))
        return errors, summaries, runs

    @property
    def median_step_s(self) -> float:
        """The median compiled-step time, the first step (which may compile) left out."""
        steady = self.step_seconds[1:] if len(self.step_seconds) > 1 else self.step_seconds
        return float(np.median(steady))


@dataclasses.dataclass
class Config:
    label: str
    model: str
    filter: str
    particles: int | tuple[int, ...]
    layers: int
    cues: tuple[str, ...] = BASE_CUES


def track_options(cfg: Config, oracle: bool = False) -> TrackOptions:
    """The tracker options of ``cfg``. The source's masks are the foreground (:func:`open_source`: subtracted against
    the plates, or rendered with ``oracle``); the first pose comes from inverse kinematics on the 2D detections, or
    with ``oracle`` from the ground truth of the first frame."""
    return TrackOptions(
        model=cfg.model,
        filter=cfg.filter,
        particles=cfg.particles,
        layers=cfg.layers,
        cues=",".join(cfg.cues),
        init="groundtruth" if oracle else "ik",
        foreground="mask",
        overwrite=True,
    )


class PlateSource(SequenceSource):
    """A synthetic sequence read as a real recording would be: the silhouettes of each frame by static background
    subtraction against the view's empty-scene plate (:func:`jaxmocap.synth.plates.subtractors`: thresholds at four
    noise standard deviations, shadow removal in the room), and the simulated OpenPose BODY_25B detections
    (``views/<camera>/openpose/``, read by :func:`jaxmocap.io.subject.load_subject` as a video's keypoint folders
    are) as the 2D keypoints. The rendered masks are never read; the ground truth stays for scoring. The body's
    dimensions stay the sequence's body file (a subject measured beforehand): measured from the stereo pair's
    detections they come out far off (triangulation over a 0.30 m baseline with pixels of detection noise; on the
    walk at 320×240 the hip width 0.74 m for 0.18 m, the thigh 0.61 m for 0.43 m)."""

    def __init__(self, root):
        super().__init__(root)
        self.subtract = plates.subtractors(self.seq)
        if not self.has_keypoints:
            raise ValueError(f"{self.root}: no simulated detections (synthesize with detections=True)")
        self.description = {**self.description, "foreground": "plates", "keypoints": "simulated BODY_25B"}

    def read(self, t: int, masks: bool = True, depth: bool = True) -> FrameData:
        fd = super().read(t, masks=False, depth=depth)
        m = [s.update(im) > 0 for s, im in zip(self.subtract, fd.images, strict=True)] if masks else None
        return FrameData(fd.images, m, fd.depth, self.keypoints[t])


class RecordingSource(PlateSource):
    """A synthetic sequence as a recording gives it: the images, the empty-scene plates, the depth maps and the
    simulated detections (:class:`PlateSource`'s), no masks: the tracker's own ``--foreground`` (``plate``,
    ``adaptive`` …) segments the images. The ground truth stays for scoring."""

    def __init__(self, root):
        super().__init__(root)
        self.has_masks = False
        self.description = {**self.description, "foreground": "the tracker's"}

    def read(self, t: int, masks: bool = True, depth: bool = True) -> FrameData:
        return super().read(t, masks=False, depth=depth)


def open_source(seq_dir, oracle: bool = False) -> SequenceSource:
    """The tracker's input for a synthetic sequence: :class:`PlateSource`, or with ``oracle`` the sequence as
    written (rendered masks, ground truth for initialisation; the detections left out, as before they were read)."""
    return SequenceSource(seq_dir, detections=False) if oracle else PlateSource(seq_dir)


def make_sequences(work: pathlib.Path, frames: str, size: str, log=print, max_clips: int | None = None):
    seqs = []
    for name, motion, asf in clips()[:max_clips]:
        d = work / name.replace(" ", "_")
        t0 = time.monotonic()
        synth.synthesize(motion, d, rig="stereo", asf=asf, frames=frames, size=size, seed=0, overwrite=True)
        log(f"synthesised {name}: {time.monotonic() - t0:.0f} s")
        seqs.append((name, d))
    return seqs


class PingPong:
    """A frame source of ``num_frames`` frames that plays a sequence folder's frames forwards, then backwards, and so
    on (``0 … T−1, T−2 … 1, 0 …``): a long input with continuous motion, from a short synthetic sequence. Frame ``t``
    is frame ``bounce(t)`` of ``source``, ground truth included."""

    def __init__(self, source, num_frames: int):
        self.s = source
        for k in ("rig", "fps", "view_names", "has_masks", "has_depth", "has_keypoints", "body_path"):
            setattr(self, k, getattr(source, k))
        self.num_frames = int(num_frames)
        self.index = np.asarray([self.bounce(t) for t in range(self.num_frames)])
        gt = source.groundtruth
        self.groundtruth = None if gt is None else np.asarray(gt)[self.index]
        self.description = {**source.description, "ping_pong_frames": self.num_frames}

    def bounce(self, t: int) -> int:
        T = self.s.num_frames
        period = 2 * (T - 1)
        k = t % period
        return k if k < T else period - k

    def read(self, t: int, masks: bool = True, depth: bool = True):
        return self.s.read(int(self.index[t]), masks, depth)

    def close(self) -> None:
        self.s.close()


# ---------------------------------------------------------------------------------------------------------------
# The Pose2Sim demo recording (``experiments/pose2sim_track.py``, ``experiments/shape_calibration.py``)

P2S_DATA = pathlib.Path(os.environ.get("JAXMOCAP_DATA", "/work/shared/data")) / "video" / "pose2sim_demo"
P2S_DERIVED = "derived_by_pose2sim_a948c20"
P2S_TRC = f"{P2S_DERIVED}/pose-3d/S00_P00_T01_BalancingTrial_0-100.trc"
P2S_CALIB = "calibration/Calib_qualisys_converted_by_pose2sim_a948c20.toml"
P2S_CAMS = [f"cam0{c}" for c in range(1, 5)]


def pose2sim_project(dest: pathlib.Path, cams, pose: bool = True) -> pathlib.Path:
    """A Pose2Sim project folder at ``dest`` of links to the recording, with the cameras ``cams`` (indices); without
    ``pose`` no ``pose/`` folder (the tracker's built-in detector makes the keypoints)."""
    if dest.exists():
        shutil.rmtree(dest)
    for sub in ("videos", "pose", "calibration/extrinsics"):
        (dest / sub).mkdir(parents=True)
    (dest / "Config.toml").symlink_to(P2S_DATA / "Config.toml")
    rig = calibration.load_calibration(P2S_DATA / P2S_CALIB)
    if list(cams) == list(range(rig.num_views)):
        (dest / "calibration" / "Calib.toml").symlink_to(P2S_DATA / P2S_CALIB)
    else:
        calibration.save_calibration(dest / "calibration" / "Calib.toml", camera.select(rig, list(cams)))
    for c in cams:
        name = P2S_CAMS[c]
        (dest / "videos" / f"{name}.mp4").symlink_to(P2S_DATA / "videos" / f"{name}.mp4")
        if pose:
            (dest / "pose" / f"{name}_json").symlink_to(P2S_DATA / P2S_DERIVED / "pose" / f"{name}_json")
        ext = P2S_DATA / "calibration" / "extrinsics" / f"{name}_ext.png"
        (dest / "calibration" / "extrinsics" / ext.name).symlink_to(ext)
    return dest
