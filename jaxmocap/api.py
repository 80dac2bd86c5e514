"""The Python entry point of a tracking run: ``result = jaxmocap.track(videos=[…], calibration=…, **options)``.

:func:`track` opens the input (:func:`open_source`: synchronised videos with their calibration and optional
keypoint / depth folders, a Pose2Sim project folder, or a sequence folder), runs the tracker of ``jaxmocap track``
(:class:`jaxmocap.tracking.tracker.Tracker`, the same code: one seed gives the same joints as the command line) and
returns the poses, states and per-frame diagnostics as arrays (:class:`TrackResult`). Files are written only when
``out`` is given (the outputs of ``jaxmocap track`` and ``config.toml``, the effective configuration); without it the
run goes to a temporary folder that is removed.

Compilation cache: on by default, as on the command line (:mod:`jaxmocap.compilation_cache`: a second run of a
configuration reloads its compiled programs); ``cache=False``, or ``JAXMOCAP_CACHE_DIR=off`` in the environment,
leaves JAX's configuration as it is.

Example::

    import jaxmocap
    res = jaxmocap.track(videos=["cam1.mp4", "cam2.mp4"], calibration="calib.toml",
                         keypoints=["cam1_json", "cam2_json"], particles=300, seed=0)
    # without keypoints, the built-in detector makes them (detector="auto"; "none" tracks from the images alone)
    res = jaxmocap.track(videos=["cam1.mp4", "cam2.mp4"], calibration="calib.toml", detector="blazepose")
    res.joints        # (T, 15, 3) metres, jaxmocap.geometry.body.EVAL_JOINTS
    res.states        # (T, D), res.dof_names
    res.diagnostics["quality"], res.diagnostics["lost"]   # (T,)
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import shutil
import tempfile
from collections.abc import Mapping, Sequence

import numpy as np

from jaxmocap.errors import MocapInputError

__all__ = ["CONFIG_TOML", "TrackResult", "open_source", "run_options", "track", "write_config"]

#: the effective configuration of a run, written into its output folder
CONFIG_TOML = "config.toml"

#: per-frame diagnostics returned as arrays (the records of ``diagnostics.json``)
DIAGNOSTICS = ("quality", "lost", "reinitialised", "recovered", "no_person", "seconds")


@dataclasses.dataclass
class TrackResult:
    """What :func:`track` returns. ``frames (T,)`` input frame numbers of the tracked frames; ``joints (T, 15, 3)``
    metres (``joint_names``, NaN for joints the model lacks); ``states (T, D)`` (``dof_names``); ``diagnostics``:
    ``{name: (T,)}`` for ``quality`` (energy of the best particle), ``lost``, ``reinitialised``, ``recovered``,
    ``no_person``, ``seconds``; ``summary`` (that of ``diagnostics.json``); ``notes`` (what was assumed about
    the input); ``config`` (the effective configuration); ``out`` (the output folder, None when nothing was
    kept)."""

    frames: np.ndarray
    joints: np.ndarray
    states: np.ndarray
    joint_names: tuple[str, ...]
    dof_names: tuple[str, ...]
    model: str
    fps: float
    diagnostics: dict[str, np.ndarray]
    summary: dict
    notes: list[str]
    config: dict
    out: pathlib.Path | None


def run_options(values: Mapping):
    """The :class:`~jaxmocap.tracking.options.TrackOptions` of ``values`` (option names; other keys ignored), with
    the options of the preset ``values["preset"]`` (:mod:`jaxmocap.tracking.presets`) under those given."""
    from jaxmocap.tracking.options import TrackOptions
    from jaxmocap.tracking.presets import apply

    names = {f.name for f in dataclasses.fields(TrackOptions)}
    given = apply({k: v for k, v in values.items() if k in names and v is not None})
    return TrackOptions(**given)


def open_source(
    input=None,
    videos: Sequence | None = None,
    calibration=None,
    keypoints: Sequence | None = None,
    depth: Sequence | None = None,
    keypoint_layout: str = "auto",
    calibration_units: str = "auto",
    plates: Sequence | None = None,
    detector: str | None = "none",
    progress=None,
    frames: str | None = None,
):
    """The frame source of a run: ``videos`` + ``calibration`` (+ ``keypoints``, ``depth``, ``plates``:
    :class:`jaxmocap.io.sources.VideoSource`), or ``input``: a Pose2Sim project folder
    (:func:`jaxmocap.io.pose2sim.open_project`) or a sequence folder (:class:`jaxmocap.io.sources.SequenceSource`).
    ``detector`` (``auto``, ``none`` or a name of :data:`jaxmocap.io.detect.DETECTORS`) makes the keypoints of
    videos given without them, in the frames ``"A:B"`` (default all); ``progress``: its progress lines."""
    from jaxmocap.io import pose2sim, sources

    if (input is None) == (videos is None):
        raise ValueError(
            "give either a sequence folder or a Pose2Sim project folder (INPUT), or --videos V1 V2 ... with --calibration"
        )
    if videos is not None:
        if calibration is None:
            raise ValueError("--videos needs --calibration FILE")
        return sources.VideoSource(
            list(videos),
            calibration,
            keypoints,
            depth,
            keypoint_layout=keypoint_layout,
            calibration_units=calibration_units,
            plates=plates,
            detector=detector,
            progress=progress,
            frames=frames,
        )
    if keypoints or depth or calibration or plates:
        raise ValueError(
            "--calibration, --keypoints, --depth and --plates go with --videos (a folder input has its own)"
        )
    if pose2sim.is_project(input):
        return pose2sim.open_project(input, keypoint_layout, calibration_units, detector, progress, frames)
    return sources.SequenceSource(input)


def _resolved(values: Mapping, setup) -> dict:
    """The effective configuration: the inputs of ``values``, every option of the run (``setup.o``; not
    ``resume`` / ``overwrite``, which say what to do with an earlier run in the folder) and what the defaults
    resolved to (model, cues, particles, layers, frames)."""
    from jaxmocap.tracking.options import INPUT_KEYS

    out = {k: v for k, v in values.items() if k in INPUT_KEYS}
    out.update({k: v for k, v in dataclasses.asdict(setup.o).items() if k not in ("resume", "overwrite")})
    a, b = setup.frames[0], setup.frames[-1] + 1
    out.update(
        model=setup.model.name,
        cues=", ".join(n if w == 1 else f"{n}:{w:g}" for n, w in setup.cues),
        particles=setup.num_particles,
        layers=setup.layers,
        frames=f"{a}:{b}",
    )
    return out


def write_config(out: str | os.PathLike, values: Mapping, setup=None) -> pathlib.Path | None:
    """Write the effective configuration (:func:`jaxmocap.tracking.options.dump_config`) as ``config.toml`` into a
    run folder that holds the run of ``setup`` (its ``run.json`` has the same options and input); returns its
    path, or None when the folder holds no run, or another one."""
    from jaxmocap.io.export import atomic_write_text
    from jaxmocap.tracking.options import dump_config
    from jaxmocap.tracking.run_folder import RUN_JSON

    out = pathlib.Path(out)
    try:
        run = json.loads((out / RUN_JSON).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return None
    if setup is not None:
        mine = json.loads(json.dumps(setup.description()))
        if (
            "options" not in mine
        ):  # a run configured otherwise (PARSEC's bodytrack setup): no TrackOptions to write
            return None
        if run.get("options") != mine["options"] or run.get("input") != mine["input"]:
            return None  # the folder holds another run (this one was refused)
    values = _resolved(values, setup) if setup is not None else dict(values)
    path = out / CONFIG_TOML
    atomic_write_text(path, dump_config({**values, "out": os.fspath(out)}))
    return path


def _diagnostics(out: pathlib.Path, frames: np.ndarray) -> tuple[dict[str, np.ndarray], dict]:
    from jaxmocap.io.export import DIAGNOSTICS_JSON

    try:
        doc = json.loads((out / DIAGNOSTICS_JSON).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as e:
        raise MocapInputError(out / DIAGNOSTICS_JSON, f"cannot read: {e}") from None
    by_frame = {r["frame"]: r for r in doc.get("frames", []) if not r.get("skipped") and "frame" in r}
    diag = {}
    for name in DIAGNOSTICS:
        vals = [by_frame.get(int(f), {}).get(name) for f in frames]
        kind = float if name in ("quality", "seconds") else bool
        diag[name] = np.asarray([np.nan if v is None and kind is float else (v or False) for v in vals], kind)
    return diag, doc.get("summary") or {}


def track(
    videos: Sequence[str | os.PathLike] | None = None,
    calibration: str | os.PathLike | None = None,
    *,
    input: str | os.PathLike | None = None,
    keypoints: Sequence[str | os.PathLike] | None = None,
    depth: Sequence[str | os.PathLike] | None = None,
    plates: Sequence[str | os.PathLike] | None = None,
    out: str | os.PathLike | None = None,
    config: str | os.PathLike | None = None,
    quiet: bool = True,
    cache: bool = True,
    **options,
) -> TrackResult:
    """Track a person; returns :class:`TrackResult` (module docstring).

    Input: ``videos`` (one per camera, synchronised) with ``calibration`` and optional ``keypoints`` / ``depth``
    folders and ``plates`` (empty-scene images; one of each per camera), or ``input``: a Pose2Sim project folder or a sequence folder. ``options``: the fields
    of :class:`jaxmocap.tracking.options.TrackOptions` (``filter``, ``particles``, ``seed``, ``cues``, ``frames``,
    ``keypoint_layout``, ``calibration_units``, ``preset``, ``detector`` …; a preset's values lie under the others;
    ``detector``: the 2D pose detector of videos given without ``keypoints``, ``"auto"``, ``"none"`` or
    ``"blazepose"``, :mod:`jaxmocap.io.detect`). ``config``: a configuration file
    (:func:`jaxmocap.tracking.options.load_config`) whose values the arguments given here override. ``out``: keep
    the outputs there (else a temporary folder, removed); ``quiet``: no progress line; ``cache``: the persistent
    compilation cache. Bad input raises :class:`jaxmocap.errors.MocapInputError` (or ``ValueError`` for a bad
    option value), with one line naming the problem.
    """
    from jaxmocap import compilation_cache, stored_programs
    from jaxmocap.io.export import load_poses
    from jaxmocap.tracking.options import option_types
    from jaxmocap.tracking.tracker import Tracker

    cache_dir = compilation_cache.enable() if cache else None
    unknown = sorted(set(options) - set(option_types()))
    if unknown:
        raise TypeError(f"track() got unknown option(s) {', '.join(unknown)}")
    given = {
        "input": input,
        "videos": None if videos is None else [os.fspath(v) for v in videos],
        "calibration": calibration,
        "keypoints": None if keypoints is None else [os.fspath(k) for k in keypoints],
        "depth": None if depth is None else [os.fspath(d) for d in depth],
        "plates": None if plates is None else [os.fspath(p) for p in plates],
        **options,
    }
    values = {}
    if config is not None:
        from jaxmocap.tracking.options import load_config

        values = load_config(config)
        values.pop("quiet", None)
        if out is None:
            out = values.get("out")
    if (
        input is not None or videos is not None
    ) and config is not None:  # inputs given here replace the file's
        for k in ("input", "videos", "calibration", "keypoints", "depth", "plates"):
            values.pop(k, None)
    values.update({k: v for k, v in given.items() if v is not None})
    values.pop("out", None)
    opts = run_options(values)
    source = open_source(
        values.get("input"),
        values.get("videos"),
        values.get("calibration"),
        values.get("keypoints"),
        values.get("depth"),
        opts.keypoint_layout,
        opts.calibration_units,
        plates=values.get("plates"),
        detector=opts.detector,
        frames=opts.frames,
    )
    temporary = out is None
    folder = (
        pathlib.Path(tempfile.mkdtemp(prefix="jaxmocap-track-")) / "run" if temporary else pathlib.Path(out)
    )
    try:
        project = getattr(source, "project", None)
        if opts.frames is None and project and project.get("frames"):
            opts = dataclasses.replace(opts, frames=project["frames"])
            values["frames"] = opts.frames
        tracker = Tracker(source, folder, opts, quiet=quiet)
        try:
            with stored_programs.use(cache_dir):  # the traced step kept beside the compiled programs
                summary = tracker.run()
        finally:
            if not temporary:
                write_config(folder, values, tracker.setup)
        poses = load_poses(folder)
        frames = np.asarray(poses["frame_index"], np.int64)
        diag, saved = _diagnostics(folder, frames)
        return TrackResult(
            frames=frames,
            joints=np.asarray(poses["joints"], np.float64),
            states=np.asarray(poses["state"], np.float64),
            joint_names=tuple(str(n) for n in poses.get("joint_names", ())),
            dof_names=tuple(tracker.model.dof_names),
            model=tracker.model.name,
            fps=float(source.fps),
            diagnostics=diag,
            summary={**saved, **summary},
            notes=list(tracker.setup.notes),
            config=_resolved(values, tracker.setup),
            out=None if temporary else folder,
        )
    finally:
        source.close()
        if temporary:
            shutil.rmtree(folder.parent, ignore_errors=True)
