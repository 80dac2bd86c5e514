"""The ``jaxmocap`` command.

Subcommands:

* ``jaxmocap calib show FILE`` — print the cameras of any calibration the project reads (OpenCV FileStorage
  YAML/XML, Pose2Sim/OpenCV TOML, caliscope TOML, Qualisys ``.qca.txt``, a PARSEC ``CALIB`` folder).
* ``jaxmocap calib convert IN OUT.toml`` — write it as the canonical Pose2Sim-layout TOML.
* ``jaxmocap synth --motion CLIP [--mapping FILE.toml] [--scale S] --rig {stereo,frontal-lateral,ring4,FILE} --out
  DIR [...]`` — render a synthetic multi-view sequence of a mocap clip of any skeleton with exact ground truth
  (:func:`jaxmocap.synth.generate.synthesize`).
* ``jaxmocap plot RUN`` — draw a tracking run (trajectories, 3D skeleton, per-frame quality) as PNG files.
* ``jaxmocap sweep SEQ ... --filters F,G --seeds A:B --out results.csv`` — sequences × filters × seeds, the
  seeds in one compiled call spread over the available devices, into one table (:mod:`jaxmocap.tracking.sweep`).

Bad input prints one line naming the file (and line) and exits with status 2, never a traceback. Ctrl-C prints one
line and exits with status 130, SIGTERM with 143 (a tracking run first writes what it has tracked:
:mod:`jaxmocap.tracking.interrupts`).

The command (:func:`run`) exits without the interpreter's teardown once :func:`main` has returned and every file is
closed: freeing JAX's and XLA's objects one by one took 0.42–0.48 s of a 2.4 s one-frame PARSEC run.
"""

from __future__ import annotations

import argparse
import pathlib
import signal
import sys

from jaxmocap import __version__, choices, demo
from jaxmocap.errors import MocapInputError, silence_opencv
from jaxmocap.synth import command as synth_command
from jaxmocap.tracking import presets
from jaxmocap.tracking.smoothing import DEFAULT_CUTOFF_HZ


def _calib_show(args) -> int:
    import numpy as np

    from jaxmocap.geometry import camera
    from jaxmocap.io import calibration

    rig = calibration.load_calibration(args.file)
    rig, note = calibration.check_units(rig, "auto", args.file)
    if note:
        print(f"jaxmocap: note: {note}", file=sys.stderr)
    centres = camera.camera_centres_host(rig)
    print(f"{rig.num_views} cameras in {args.file}")
    for v, name in enumerate(rig.names):
        K = np.asarray(rig.K[v])
        w, h = rig.image_size[v]
        c = centres[v]
        print(
            f"  {name:>10}: {w}x{h} px  f=({K[0, 0]:.1f}, {K[1, 1]:.1f})  c=({K[0, 2]:.1f}, {K[1, 2]:.1f})  "
            f"centre=({c[0]:.3f}, {c[1]:.3f}, {c[2]:.3f}) m"
        )
    return 0


def _calib_convert(args) -> int:
    from jaxmocap.io import calibration

    rig = calibration.load_calibration(args.input)
    calibration.save_calibration(args.output, rig)
    print(f"wrote {rig.num_views} cameras to {args.output}")
    return 0


# ---------------------------------------------------------------------------------------------------------------
# track / eval / demo


def _particle_counts(text: str) -> int | list[int]:
    """``--particles``: ``"300"`` → 300; ``"1000,200,500"`` → ``[1000, 200, 500]`` (one count per partition)."""
    try:
        counts = [int(c) for c in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"particle counts must be integers, got {text!r}") from None
    return counts[0] if len(counts) == 1 else counts


def _print_summary(summary: dict, out) -> None:
    from jaxmocap.filters.factory import particles_text

    s = summary
    fps = s.get("frames_per_s")
    first = s.get("first_frame_s")
    line = f"tracked {s['frames_tracked']} of {s['frames_requested']} frames ({s['frames_skipped']} skipped) in {s['wall_s']:.1f} s"
    if fps and first is not None:
        line += f": {fps:.2f} frames/s after a first frame (with compilation) of {first:.1f} s"
    elif fps:
        line += f" ({fps:.2f} frames/s over the frames tracked before the resume)"
    print(line)
    from jaxmocap.tracking.options import cues_text

    cues = cues_text(s["cues"])
    print(
        f"model {s['model']}, filter {s['filter']}, {particles_text(s['particles'])} particles x {s['layers']} layer(s), cues {cues}"
    )
    print(f"track lost in {s['lost_frames']} frame(s), {s['reinitialisations']} re-initialisation(s)")
    if s.get("mean_error_mm") is not None:
        print(f"mean joint error against the ground truth: {s['mean_error_mm']:.1f} mm")
    if s.get("mean_error_smoothed_mm") is not None:
        print(f"mean joint error of the exported track ({s['smooth']}): {s['mean_error_smoothed_mm']:.1f} mm")
    files = ["poses.npz", "poses.csv", "diagnostics.json"]
    exports = [f"track.bvh ({s['bvh_units']}, y up)" if f == "track.bvh" else f for f in s.get("exports", [])]
    files += exports + [pathlib.Path(p).name for p in s.get("overlays", [])]
    if s.get("plots"):
        files.append(f"plots/ ({', '.join(s['plots'])})")
    print(f"wrote {', '.join(files)} to {out}")
    if exports:
        gaps = s.get("interpolated_frames", 0)
        print(
            f"exported track: smoothing {s['smooth']}, {gaps} frame(s) interpolated (raw estimates in poses.npz)"
        )


#: ``jaxmocap track`` arguments that are inputs rather than options (see :data:`jaxmocap.tracking.options.INPUT_KEYS`)
_INPUTS = ("input", "videos", "calibration", "keypoints", "depth", "plates")


def _stopped(run, out, signum) -> int:
    """One line for a run ended by Ctrl-C (``signum`` SIGINT) or SIGTERM; the exit status."""
    from jaxmocap.tracking import interrupts

    why = "terminated (SIGTERM)" if signum == signal.SIGTERM else "interrupted"
    s = getattr(run, "summary", None)
    if s is None:
        print(f"jaxmocap: {why}", file=sys.stderr)
    else:
        again = (
            " (--resume continues)"
            if run.setup.resumable and s["frames_tracked"] < s["frames_requested"]
            else ""
        )
        print(
            f"jaxmocap: {why}; {s['frames_tracked']} of {s['frames_requested']} frames tracked, written to {out}{again}",
            file=sys.stderr,
        )
    return interrupts.exit_status(
        interrupts.Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()
    )


def _track_values(args) -> dict:
    """The run's settings: the ``--config`` file's, overridden by the options given on the command line (inputs
    given on the command line replace the file's inputs as a whole)."""
    from jaxmocap.tracking.options import RUN_KEYS, load_config, option_types

    values = load_config(args.config) if args.config else {}
    given = {
        k: getattr(args, k)
        for k in (*option_types(), *_INPUTS, *RUN_KEYS)
        if getattr(args, k, None) is not None
    }
    if any(k in given for k in ("input", "videos")):
        for k in _INPUTS:
            values.pop(k, None)
    values.update(given)
    if values.get("out") is None:
        raise ValueError('--out is required (or out = "DIR" in the --config file)')
    return values


def _open_source(values: dict, options):
    from jaxmocap.api import open_source

    folder = values.get("input")
    if folder is not None and values.get("videos") is None and not any(values.get(k) for k in _INPUTS[2:]):
        from jaxmocap.parsec import inputs as parsec_sequence

        if parsec_sequence.is_parsec_folder(folder):  # a PARSEC bodytrack sequence (CALIB/, CAM<k>/, FG<k>/)
            return parsec_sequence.ParsecSource(folder)
    return open_source(
        folder,
        values.get("videos"),
        values.get("calibration"),
        values.get("keypoints"),
        values.get("depth"),
        options.keypoint_layout,
        options.calibration_units,
        plates=values.get("plates"),
        detector=options.detector,
        progress=None if values.get("quiet") else lambda line: print(f"jaxmocap: {line}", file=sys.stderr),
        frames=options.frames,
    )


def _make_run(source, out, options, quiet: bool):
    """The tracking run for ``source``: bodytrack's configuration for a PARSEC sequence, else the Tracker."""
    from jaxmocap.parsec.inputs import ParsecSource
    from jaxmocap.tracking import tracker

    if isinstance(source, ParsecSource):
        from jaxmocap.parsec.track import ParsecTracker

        return ParsecTracker(source, out, options, quiet=quiet)
    return tracker.Tracker(source, out, options, quiet=quiet)


def _track(args) -> int:
    import dataclasses

    from jaxmocap.api import run_options, write_config
    from jaxmocap.tracking import interrupts

    silence_opencv()
    run, out, quiet = None, None, False
    try:
        values = _track_values(args)
        out, quiet = values["out"], bool(values.get("quiet", False))
        options = run_options(values)
        source = _open_source(values, options)
        try:
            project = getattr(source, "project", None)
            if options.frames is None and project and project.get("frames"):
                options = dataclasses.replace(options, frames=project["frames"])
                values["frames"] = options.frames
            run = _make_run(source, out, options, quiet)
            if not quiet:
                for note in getattr(run.setup, "notes", []):
                    print(f"jaxmocap: note: {note}", file=sys.stderr)
            try:
                summary = run.run()
            finally:
                if hasattr(run.setup, "cues") and hasattr(run.setup, "num_particles"):
                    write_config(
                        out, {k: v for k, v in values.items() if k not in ("out", "quiet")}, run.setup
                    )
        finally:
            source.close()
    except (KeyboardInterrupt, interrupts.Terminated) as e:
        interrupts.consume()
        return _stopped(run, out, signal.SIGTERM if isinstance(e, interrupts.Terminated) else signal.SIGINT)
    except MocapInputError:
        raise
    except ValueError as e:  # a bad option value
        print(f"jaxmocap: error: {e}", file=sys.stderr)
        return 2
    if interrupts.received() is not None:  # a signal after the run's last check (its outputs are complete)
        return _stopped(run, out, interrupts.consume())
    if not quiet:
        _print_summary(summary, out)
    return 0


def _smooth_spec(text: str) -> str:
    """``--smooth``: checked here (the cut-off against the frame rate when the input is open)."""
    from jaxmocap.tracking.smoothing import parse_smooth

    try:
        parse_smooth(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def _plot(args) -> int:
    from jaxmocap.eval import plots

    if not pathlib.Path(args.run).is_dir():
        raise MocapInputError(args.run, "no such folder")
    paths = plots.plot_run(args.run, args.out)
    print(f"wrote {', '.join(str(p) for p in paths)}")
    return 0


def _eval(args) -> int:
    from jaxmocap.eval import metrics

    report = metrics.evaluate_folders([args.pred, *(args.runs or [])], args.gt, args.out)
    print(
        metrics.format_table(
            report, f"3D joint error (mm) of {report['num_runs']} run(s) over {report['num_frames']} frames"
        )
    )
    stem = pathlib.Path(args.out).with_suffix("")
    print(f"wrote {args.out}, {stem}_error_over_time.png, {stem}_per_joint.png")
    return 0


# ---------------------------------------------------------------------------------------------------------------
# sweep


def _sweep(args) -> int:
    from jaxmocap.tracking import sweep

    silence_opencv()
    if args.distributed or args.coordinator is not None:
        import jax  # the multi-process runtime: every process runs this command with the same options

        jax.distributed.initialize(args.coordinator, args.num_processes, args.process_id)
    keys = ("filters", "seeds", "model", "particles", "layers", "cues", "frames", "devices", "chunk")
    over = {"sequences": args.sequences or None, **{k: getattr(args, k) for k in keys}}
    try:
        if args.spec is not None:
            spec = sweep.load_spec(args.spec, **over)
        else:
            if not args.sequences:
                raise ValueError("give sequence folders or --spec FILE")
            spec = sweep.make_spec(**{k: v for k, v in over.items() if v is not None})
        say = None if args.quiet else (lambda line: print(line, flush=True))
        rows = sweep.run_sweep(spec, progress=say)
    except MocapInputError:
        raise
    except ValueError as e:  # a bad option value
        print(f"jaxmocap: error: {e}", file=sys.stderr)
        return 2
    if args.distributed or args.coordinator is not None:
        import jax

        if jax.process_index() != 0:  # every process holds the gathered results; the first one writes them
            return 0
    csv_path, md_path = sweep.write_table(rows, args.out)
    if not args.quiet:
        print(f"wrote {len(rows)} run(s) to {csv_path} and {md_path}")
    return 0


def _add_sweep_command(sub) -> None:
    sw = sub.add_parser(
        "sweep",
        help="run sequences x filters x seeds, spread over the devices, into one results table",
        description="Run every sequence x filter x seed (the seeds of a sequence and filter in one compiled "
        "call, spread over the available devices) and write the mean 3D joint error of each run to a CSV "
        "table and a Markdown table next to it.",
    )
    sw.add_argument("sequences", nargs="*", help="sequence folders with ground truth (or use --spec)")
    sw.add_argument(
        "--spec", help="TOML or JSON spec (keys: sequences, filters, seeds, model, particles, ...)"
    )
    sw.add_argument("--filters", help=f"comma-separated filters (default apf): {', '.join(_FILTERS)}")
    sw.add_argument("--seeds", help="seeds: A:B or comma-separated (default 0)")
    sw.add_argument("--model", choices=_MODELS, help="body model (default: the body file's, else full25)")
    sw.add_argument("--particles", type=int, help="particles (per layer for the annealed filters)")
    sw.add_argument("--layers", type=int, help="annealing layers of the annealed filters")
    sw.add_argument("--cues", help="comma-separated cues with optional weights, as for track")
    sw.add_argument("--frames", help="frame range A:B (default: all)")
    sw.add_argument("--devices", type=int, help="devices to spread the runs over (default: all)")
    sw.add_argument("--chunk", type=int, help="evaluate the likelihood in chunks of this many particles")
    sw.add_argument("--out", required=True, help="results CSV (a Markdown table is written next to it)")
    sw.add_argument(
        "--distributed",
        action="store_true",
        help="join JAX's multi-process runtime (jax.distributed.initialize; cluster settings auto-detected)",
    )
    sw.add_argument("--coordinator", metavar="HOST:PORT", help="coordinator of the multi-process runtime")
    sw.add_argument("--num-processes", type=int, help="processes of the multi-process runtime")
    sw.add_argument("--process-id", type=int, help="index of this process (0 writes the table)")
    sw.add_argument("--quiet", action="store_true", help="no progress lines")
    sw.set_defaults(func=_sweep)


# the choices of a tracking run (jaxmocap.choices does not import JAX: building the parser stays fast)
_MODELS, _FILTERS, _FOREGROUNDS = choices.MODELS, choices.FILTERS, choices.FOREGROUNDS
_PRESETS = presets.PRESETS
_LAYOUTS = choices.KEYPOINT_LAYOUTS


def _add_tracking_commands(sub) -> None:
    tr = sub.add_parser(
        "track",
        help="track a person in a sequence folder or synchronised videos",
        description="Track a sequence folder (synthesis format) or synchronised videos with their calibration "
        "into --out: poses.csv, poses.journal and diagnostics.jsonl get every frame as it is tracked; poses.npz and "
        "diagnostics.json are rewritten every few seconds; at the end the exported track (smoothed, gaps filled): "
        "poses_smoothed.npz, track.bvh, poses.trc (OpenSim / Pose2Sim), poses.c3d and plots/ (and the overlays), "
        "written with poses.npz and diagnostics.json on every way out (Ctrl-C, SIGTERM, an error). One run at a "
        "time writes to a folder (run.lock); --resume continues a run that was stopped or killed.",
    )
    tr.add_argument(
        "input",
        nargs="?",
        help="sequence folder, Pose2Sim project folder (Config.toml, calibration/, videos/, pose/) or PARSEC "
        "bodytrack sequence folder (or use --videos)",
    )
    tr.add_argument(
        "--config",
        metavar="FILE",
        help="TOML file of options and inputs (any option below by its long name with _ for -, e.g. "
        'particles = 300, videos = ["a.mp4", "b.mp4"]); options given here override it; the effective '
        "configuration is written to --out as config.toml",
    )
    tr.add_argument("--out", help="output folder")
    tr.add_argument("--videos", nargs="+", metavar="V", help="one synchronised video per camera")
    tr.add_argument(
        "--calibration",
        help="calibration of the videos (any format `jaxmocap calib show` reads, EasyMocap's intri.yml/extri.yml "
        "folder included)",
    )
    tr.add_argument(
        "--keypoints",
        nargs="+",
        metavar="DIR",
        help="2D keypoint JSON folder per camera (with --videos; OpenPose format, files matched to frames by the "
        "number in their names)",
    )
    tr.add_argument(
        "--keypoint-layout",
        choices=("auto", *_LAYOUTS),
        help="layout of the keypoint files (default auto: from the number of keypoints and where they lie)",
    )
    tr.add_argument(
        "--detector",
        choices=choices.DETECTORS,
        help="2D pose detector for videos given without --keypoints (default auto: blazepose when installed, "
        "else none; its detections are cached per video in ~/.cache/jaxmocap/detections)",
    )
    tr.add_argument(
        "--calibration-units",
        choices=("auto", "m", "mm"),
        help="units of the calibration's translations (default auto: millimetres when the cameras are too far "
        "apart for metres)",
    )
    tr.add_argument(
        "--depth", nargs="+", metavar="DIR", help="depth-map folder per camera: .npy metres or 16-bit PNG mm"
    )
    tr.add_argument(
        "--plates",
        nargs="+",
        metavar="IMAGE",
        help="image of the empty scene per camera (with --videos), for --foreground plate; a sequence folder's "
        "are views/<camera>/background.png",
    )
    tr.add_argument(
        "--preset",
        choices=tuple(_PRESETS),
        help=f"a paper's tracker: {', '.join(_PRESETS)}; options given here or in --config override the "
        "preset's (README: Presets)",
    )
    tr.add_argument("--model", choices=_MODELS, help="body model (default: the body file's, else full25)")
    tr.add_argument(
        "--filter",
        choices=(*_FILTERS, *presets.VARIANTS),
        help="particle filter (default apf); a preset's variant with its --preset: "
        + ", ".join(f"{v} ({', '.join(p)})" for v, p in presets.VARIANTS.items()),
    )
    tr.add_argument(
        "--particles",
        type=_particle_counts,
        help="particles (per layer for the annealed filters; default 300 for full25/full32, 50 when the estimate is "
        "refined on detections of three or more cameras); partitioned / hierarchical: one count, or one per "
        "partition separated by commas (full25: torso, head, arms, legs, e.g. 1000,200,350,350,350,350)",
    )
    tr.add_argument("--layers", type=int, help="annealing layers (default 5; 2 per level for hierarchical)")
    tr.add_argument(
        "--cues", help="comma-separated cues with optional weights, e.g. foreground,edge_distance:2,coverage"
    )
    tr.add_argument("--seed", type=int, help="random seed, 0 to 4294967295 (default 0)")
    tr.add_argument("--frames", help="frame range A:B (default: all, or a Pose2Sim project's frame_range)")
    tr.add_argument(
        "--init",
        help="groundtruth, ik, head-hands (skin blobs and face) or a FILE (.npz with 'state', .npy, text); default: "
        "groundtruth if the input has it, else ik",
    )
    tr.add_argument(
        "--body",
        help="body file (TOML) with the subject's dimensions, 'detections' (measured from the 2D keypoints; "
        "the default for an input with keypoints and no body file), or 'calibrate' (lengths and radii fitted to "
        "the first 10 frames' silhouettes and keypoints)",
    )
    tr.add_argument(
        "--foreground",
        choices=_FOREGROUNDS,
        help="foreground source: mask (a sequence's masks), plate (subtraction against each camera's empty-scene "
        "image), median (a median background of the run's frames), mog2, adaptive (López Méndez's adaptive "
        "Gaussian with shadow removal), none; default: masks, else plates, else median",
    )
    tr.add_argument(
        "--downsample", type=int, choices=(1, 2, 4), help="process images at 1/1, 1/2 or 1/4 size"
    )
    tr.add_argument(
        "--on-bad-frame",
        choices=("skip", "stop"),
        help="a frame that does not decode: skip it with a warning (default) or stop",
    )
    tr.add_argument(
        "--count-modes",
        action="store_true",
        default=None,
        help="record the number of modes (EM/BIC) of the particle set after each annealing layer in "
        "diagnostics.json (APF-based filters; slower)",
    )
    tr.add_argument(
        "--overlay",
        action="store_true",
        default=None,
        help="also write an H.264 MP4 per view with the model drawn over the images, and a montage PNG",
    )
    tr.add_argument(
        "--no-plots",
        dest="plots",
        action="store_false",
        default=None,
        help="do not draw the pictures of plots/ at the end (about 1 s; `jaxmocap plot RUN` draws them later)",
    )
    tr.add_argument(
        "--smooth",
        type=_smooth_spec,
        default=None,
        metavar="butterworth[:HZ]|none",
        help="smoothing of the exported track (poses_smoothed.npz, track.bvh, poses.trc, poses.c3d): zero-phase "
        f"Butterworth low-pass, order 4, cut-off HZ (default {DEFAULT_CUTOFF_HZ:g}), or none; lost and "
        "skipped frames are interpolated either way; poses.npz keeps the raw estimates",
    )
    tr.add_argument(
        "--bvh-units", choices=("cm", "m"), default=None, help="length unit of track.bvh (default cm)"
    )
    for flag, kind, what in (
        (
            "--velocity",
            float,
            "damping of the constant-velocity prediction of --velocity-dofs (default 0.5; 0 = none)",
        ),
        ("--diffusion-scale", float, "factor on the per-DOF diffusion (default 1)"),
        ("--survival-target", float, "annealing survival rate alpha (default 0.5)"),
        ("--samples", int, "silhouette samples per view of the coverage cue (default 64)"),
        ("--loss-ratio", float, "lost when the best energy exceeds this times its reference (default 2.5)"),
        ("--loss-frames", int, "... for this many frames in a row (default 3)"),
        ("--loss-window", int, "frames after the initialisation that set the reference energy (default 5)"),
        ("--reinit-widen", float, "spread of a re-initialisation, times the diffusion (default 3)"),
    ):
        tr.add_argument(flag, type=kind, help=what)
    tr.add_argument(
        "--velocity-dofs",
        choices=choices.VELOCITY_DOFS,
        help="DOFs of the constant-velocity prediction: the root's translation and angles (root, default), "
        "its translation only (translation), or every DOF (all)",
    )
    tr.add_argument(
        "--refine",
        choices=choices.REFINEMENTS,
        help="refine the filter's estimate on each frame's 2D detections: the written pose (estimate), the "
        "particles too (track), none, or auto (default: the best measured for the input, see the README)",
    )
    tr.add_argument(
        "--refine-prior",
        type=float,
        help="weight of the filter's estimate in the refinement (default 1; larger stays nearer the filter)",
    )
    tr.add_argument(
        "--refine-depth",
        type=float,
        metavar="SIGMA_M",
        help="standard deviation (m) of a depth term in the refinement: the camera depths of the trunk's and the "
        "limbs' joints read from the input's depth maps (0 = none; default 0.05 with a stereo pair and depth maps, "
        "else none: the best measured, see the README)",
    )
    tr.add_argument(
        "--proposal",
        choices=choices.PROPOSALS,
        help="detection-driven pose of icondensation / iapf and of re-initialisations: auto (keypoint IK, else "
        "the silhouette centroid) or head-hands (3D head and hands from skin blobs and the face detector)",
    )
    tr.add_argument(
        "--annealing",
        choices=choices.ANNEALINGS,
        help="beta of the annealed filters: auto (Deutscher's rule) or iros2007 (fixed 3 layers, "
        "beta = 0.1, 0.4, 1, dynamics exponents 1, 4, 25)",
    )
    for flag, what in (
        (
            "--dynamics-fraction",
            "share of icondensation / iapf particles drawn from the dynamics (default 0.5)",
        ),
        ("--detection-fraction", "share drawn around the detection-driven pose (default 0.4)"),
    ):
        tr.add_argument(flag, type=float, help=what)
    tr.add_argument("--fsync", action="store_true", default=None, help="fsync every output rewrite")
    tr.add_argument(
        "--resume", action="store_true", default=None, help="continue an interrupted run in --out"
    )
    tr.add_argument("--overwrite", action="store_true", default=None, help="replace a previous run in --out")
    tr.add_argument("--quiet", action="store_true", default=None, help="no progress bar, notes or summary")
    tr.set_defaults(func=_track)

    pl = sub.add_parser(
        "plot",
        help="draw a tracking run: joint trajectories, 3D skeleton, per-frame quality (PNG)",
        description="Draw the joint trajectories, a 3D skeleton of selected frames and the per-frame quality "
        "(log-likelihood, survival, lost frames, re-initialisations) of a tracking output folder as PNG "
        "files (also drawn at the end of every run).",
    )
    pl.add_argument("run", help="tracking output folder")
    pl.add_argument("--out", help="folder of the pictures (default RUN/plots)")
    pl.set_defaults(func=_plot)

    ev = sub.add_parser(
        "eval",
        help="3D joint errors of tracking runs against ground truth",
        description="Li & Kulic's average error per frame, joint average error and overall average error, and "
        "Lopez Mendez' eq. 7.1-7.3, in mm, over one or several runs; JSON plus plots.",
    )
    ev.add_argument("--pred", required=True, help="tracking output folder (or its poses.npz)")
    ev.add_argument("--gt", required=True, help="sequence folder with groundtruth.npz (or the file)")
    ev.add_argument(
        "--runs", nargs="+", metavar="DIR", help="further runs of the same sequence (other seeds)"
    )
    ev.add_argument(
        "--out",
        required=True,
        help="JSON report; plots go next to it (<stem>_error_over_time.png, <stem>_per_joint.png)",
    )
    ev.set_defaults(func=_eval)

    de = sub.add_parser(
        "demo",
        help="synthesise, track and evaluate the bundled CMU walk (a few minutes on a laptop CPU)",
        description="Synthesise a stereo sequence of the CMU clip bundled with the package, track it, evaluate "
        "it, print a table and write the overlay video, an overlay frame and plots.",
    )
    de.add_argument("--out", default="jaxmocap-demo", help="output folder (default ./jaxmocap-demo)")
    de.add_argument(
        "--frames",
        default=demo.DEMO_FRAMES,
        help=f"source frame range of the 120 fps clip (default {demo.DEMO_FRAMES})",
    )
    de.add_argument("--size", default=demo.DEMO_SIZE, help=f"image size (default {demo.DEMO_SIZE})")
    de.add_argument("--filter", choices=_FILTERS, default="apf", help="particle filter (default apf)")
    de.add_argument("--particles", type=int, help="particles per layer (default 300)")
    de.add_argument("--layers", type=int, help="annealing layers (default 5)")
    de.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    de.add_argument("--quiet", action="store_true", help="no progress bar")
    de.set_defaults(func=demo.run)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="jaxmocap", description="Markerless motion capture with particle filters in JAX."
    )
    p.add_argument("--version", action="version", version=f"jaxmocap {__version__}")
    p.add_argument(
        "--cpu-threads",
        type=_cpu_threads,
        default="auto",
        metavar="N|auto",
        help="XLA's CPU threads (default auto: one per core that other processes leave free, measured while "
        "the program starts; N: that many)",
    )
    sub = p.add_subparsers(dest="command", required=True)
    calib = sub.add_parser("calib", help="inspect and convert camera calibrations")
    csub = calib.add_subparsers(dest="calib_command", required=True)
    show = csub.add_parser("show", help="print the cameras of a calibration")
    show.add_argument("file")
    show.set_defaults(func=_calib_show)
    conv = csub.add_parser("convert", help="write a calibration as Pose2Sim-layout TOML")
    conv.add_argument("input")
    conv.add_argument("output")
    conv.set_defaults(func=_calib_convert)
    synth_command.add_command(sub)
    _add_tracking_commands(sub)
    _add_sweep_command(sub)
    return p


def main(argv=None) -> int:
    try:
        from jaxmocap.tracking import interrupts
    except KeyboardInterrupt:
        print("jaxmocap: interrupted", file=sys.stderr)
        return 130
    with interrupts.handling():
        try:
            return _main(argv)
        except (KeyboardInterrupt, interrupts.Terminated) as e:  # before or after a run (importing, parsing)
            interrupts.consume()
            why = "terminated (SIGTERM)" if isinstance(e, interrupts.Terminated) else "interrupted"
            print(f"jaxmocap: {why}", file=sys.stderr)
            return interrupts.exit_status(e)


def run() -> None:
    """The ``jaxmocap`` command and ``python -m jaxmocap.cli``: :func:`main`, then the exit handlers a normal exit
    runs (``atexit``: temporary folders, logging), the standard streams flushed, and ``os._exit`` with its status,
    skipping the interpreter's teardown (module dictionaries cleared, every object of JAX and XLA freed one by one,
    the CPU client's threads joined; module docstring). An exception out of :func:`main` (a bug, ``--help``'s
    ``SystemExit``) leaves the way Python's exits do."""
    import atexit
    import os

    code = main()
    if not hasattr(atexit, "_run_exitfuncs"):  # CPython's; another interpreter exits the normal way
        sys.exit(code)
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe or stream: nothing more can reach it
            pass
    os._exit(code)


def _cpu_threads(text: str) -> int | str:
    return "auto" if text == "auto" else _positive_int(text)


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def _main(argv) -> int:
    args = build_parser().parse_args(argv)
    from jaxmocap import host

    host.relax_gc()  # before the imports and the tracing that allocate most
    auto = args.cpu_threads == "auto"
    sample = host.cpu_sample() if auto else None  # the imports below are the measurement's interval
    import jaxmocap.parsec  # noqa: F401  (the PARSEC wing registers the parsec31 body and the .cal camera reader)
    from jaxmocap import compilation_cache, stored_programs

    threads = host.choose_cpu_threads(sample) if auto else args.cpu_threads
    host.limit_cpu_threads(threads)  # before anything starts JAX's backends

    # a second run of a configuration reloads its compiled programs, and its traced steps (no tracing)
    cache = compilation_cache.enable()
    try:
        with stored_programs.use(cache):
            return args.func(args)
    except MocapInputError as e:
        print(f"jaxmocap: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"jaxmocap: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    run()
