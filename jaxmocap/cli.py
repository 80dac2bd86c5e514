"""The ``jaxmocap`` command.

Subcommands:

* ``jaxmocap calib show FILE`` — print the cameras of any calibration the project reads (OpenCV FileStorage
  YAML/XML, Pose2Sim/OpenCV TOML, caliscope TOML, Qualisys ``.qca.txt``, a PARSEC ``CALIB`` folder).
* ``jaxmocap calib convert IN OUT.toml`` — write it as the canonical Pose2Sim-layout TOML.
* ``jaxmocap synth --motion CLIP --rig {stereo,frontal-lateral,ring4,FILE} --out DIR [...]`` — render a synthetic
  multi-view sequence of a mocap clip with exact ground truth (:func:`jaxmocap.synth.generate.synthesize`).
* ``jaxmocap sweep SEQ ... --filters F,G --seeds A:B --out results.csv`` — sequences × filters × seeds, the
  seeds in one compiled call spread over the available devices, into one table (:mod:`jaxmocap.tracking.sweep`).

Bad input prints one line naming the file (and line) and exits with status 2, never a traceback. Ctrl-C prints one
line and exits with status 130, SIGTERM with 143 (a tracking run first writes what it has tracked:
:mod:`jaxmocap.tracking.interrupts`).
"""

from __future__ import annotations

import argparse
import pathlib
import signal
import sys

from jaxmocap import __version__, choices
from jaxmocap.errors import MocapInputError


def _calib_show(args) -> int:
    import numpy as np

    from jaxmocap.geometry import camera
    from jaxmocap.io import calibration

    rig = calibration.load_calibration(args.file)
    centres = np.asarray(camera.camera_centres(rig.to_jax()))
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


def _synth(args) -> int:
    from jaxmocap.synth import generate as synth

    def progress(done, total):
        if not args.quiet and (done == total or done % 10 == 0):
            print(f"\rframe {done}/{total}", end="\n" if done == total else "", flush=True)

    try:
        seq = synth.synthesize(
            args.motion,
            args.out,
            rig=args.rig,
            asf=args.asf,
            scale=args.scale,
            frames=args.frames,
            fps=args.fps,
            size=args.size,
            seed=args.seed,
            background=args.background,
            clutter=args.clutter,
            noise=args.noise,
            depth_noise=args.depth_noise,
            depth_smooth=args.depth_smooth,
            illumination=args.illumination,
            blur=args.blur,
            overwrite=args.overwrite,
            licence=args.licence,
            progress=progress,
        )
    except MocapInputError:
        raise
    except ValueError as e:  # a bad option value
        print(f"jaxmocap: error: {e}", file=sys.stderr)
        return 2
    print(
        f"wrote {seq.num_frames} frames x {len(seq.views)} views ({', '.join(seq.view_names)}) to {args.out}"
    )
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


def _cues_text(cues) -> str:
    """``[("foreground", 1.0), ("coverage", 4.0)]`` → ``"foreground, coverage:4"`` (the ``--cues`` syntax)."""
    return ", ".join(n if w == 1 else f"{n}:{w:g}" for n, w in cues)


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
    cues = _cues_text(s["cues"])
    print(
        f"model {s['model']}, filter {s['filter']}, {particles_text(s['particles'])} particles x {s['layers']} layer(s), cues {cues}"
    )
    print(f"track lost in {s['lost_frames']} frame(s), {s['reinitialisations']} re-initialisation(s)")
    if s.get("mean_error_mm") is not None:
        print(f"mean joint error against the ground truth: {s['mean_error_mm']:.1f} mm")
    files = ["poses.npz", "poses.csv", "diagnostics.json", "track.bvh"]
    files += [pathlib.Path(p).name for p in s.get("overlays", [])]
    print(f"wrote {', '.join(files)} to {out}")


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


def _track_options(args):
    from jaxmocap.tracking.options import TrackOptions

    return TrackOptions(
        model=args.model,
        body=args.body,
        filter=args.filter,
        particles=args.particles,
        layers=args.layers,
        cues=args.cues,
        seed=args.seed,
        frames=args.frames,
        init=args.init,
        foreground=args.foreground,
        downsample=args.downsample,
        on_bad_frame=args.on_bad_frame,
        overlay=args.overlay,
        resume=args.resume,
        overwrite=args.overwrite,
    )


def _open_source(args):
    from jaxmocap.io import sources

    if (args.input is None) == (args.videos is None):
        raise ValueError("give either a sequence folder (INPUT) or --videos V1 V2 ... with --calibration")
    if args.videos is not None:
        if args.calibration is None:
            raise ValueError("--videos needs --calibration FILE")
        return sources.VideoSource(args.videos, args.calibration, args.keypoints, args.depth)
    if args.keypoints or args.depth or args.calibration:
        raise ValueError(
            "--calibration, --keypoints and --depth go with --videos (a sequence folder has its own)"
        )
    from jaxmocap.parsec import inputs as parsec_sequence

    if parsec_sequence.is_parsec_folder(args.input):  # a PARSEC bodytrack sequence (CALIB/, CAM<k>/, FG<k>/)
        return parsec_sequence.ParsecSource(args.input)
    return sources.SequenceSource(args.input)


def _make_run(source, args, options):
    """The tracking run for ``source``: bodytrack's configuration for a PARSEC sequence, else the Tracker."""
    from jaxmocap.parsec.inputs import ParsecSource
    from jaxmocap.tracking import tracker

    if isinstance(source, ParsecSource):
        from jaxmocap.parsec.track import ParsecTracker

        return ParsecTracker(source, args.out, options, quiet=args.quiet)
    return tracker.Tracker(source, args.out, options, quiet=args.quiet)


def _silence_opencv() -> None:
    """OpenCV's own log lines (e.g. about a corrupt PNG chunk) would clutter the one-line error messages."""
    import cv2

    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)


def _track(args) -> int:
    from jaxmocap.tracking import interrupts

    _silence_opencv()
    run = None
    try:
        options = _track_options(args)
        source = _open_source(args)
        try:
            run = _make_run(source, args, options)
            summary = run.run()
        finally:
            source.close()
    except (KeyboardInterrupt, interrupts.Terminated) as e:
        interrupts.consume()
        return _stopped(
            run, args.out, signal.SIGTERM if isinstance(e, interrupts.Terminated) else signal.SIGINT
        )
    except MocapInputError:
        raise
    except ValueError as e:  # a bad option value
        print(f"jaxmocap: error: {e}", file=sys.stderr)
        return 2
    if interrupts.received() is not None:  # a signal after the run's last check (its outputs are complete)
        return _stopped(run, args.out, interrupts.consume())
    if not args.quiet:
        _print_summary(summary, args.out)
    return 0


def evaluate_runs(pred: list, gt: str, out: str | None = None, quiet: bool = False):
    """Evaluate tracking output folders against a sequence's ground truth; write JSON and plots when ``out``."""
    from jaxmocap.eval import metrics, viz

    gt_frames, gt_joints = metrics.load_groundtruth(gt)
    runs = [metrics.load_prediction(p) for p in pred]
    try:
        report = metrics.evaluate(runs, gt_joints, gt_frames, run_names=[str(p) for p in pred])
    except ValueError as e:
        raise MocapInputError(pred[0], str(e)) from None
    if out is not None:
        out = pathlib.Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        report.save(out)
        stem = out.with_suffix("")
        viz.plot_error_over_time(report, f"{stem}_error_over_time.png")
        viz.plot_per_joint(report, f"{stem}_per_joint.png")
    return report


def _eval(args) -> int:
    from jaxmocap.eval import metrics

    report = evaluate_runs([args.pred, *(args.runs or [])], args.gt, args.out)
    print(
        metrics.format_table(
            report, f"3D joint error (mm) of {report['num_runs']} run(s) over {report['num_frames']} frames"
        )
    )
    stem = pathlib.Path(args.out).with_suffix("")
    print(f"wrote {args.out}, {stem}_error_over_time.png, {stem}_per_joint.png")
    return 0


DEMO_FRAMES = "0:240"
DEMO_SIZE = "320x240"


def _demo(args) -> int:
    import shutil
    import time

    import cv2
    import numpy as np

    from jaxmocap.eval import metrics, viz
    from jaxmocap.filters.factory import particles_text
    from jaxmocap.io.sources import SequenceSource
    from jaxmocap.synth import generate as synth
    from jaxmocap.tracking import tracker
    from jaxmocap.tracking.options import TrackOptions

    _silence_opencv()
    t0 = time.monotonic()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    seq_dir, track_dir = out / "sequence", out / "track"
    print(f"motion: {synth.demo_clip()[0].name} (CMU subject 2, trial 1: a walk). {synth.CMU_LICENCE}")
    print(f"1/4 synthesising a stereo sequence ({args.size}) of source frames {args.frames} ...", flush=True)
    seq = synth.synthesize(
        "demo", seq_dir, rig="stereo", frames=args.frames, size=args.size, seed=args.seed, overwrite=True
    )
    t1 = time.monotonic()
    print(f"    {seq.num_frames} frames x {len(seq.views)} views in {t1 - t0:.1f} s", flush=True)
    print(f"2/4 tracking with {args.filter} ...", flush=True)
    options = TrackOptions(
        filter=args.filter,
        particles=args.particles,
        layers=args.layers,
        seed=args.seed,
        init="groundtruth",
        overlay=True,
        overwrite=True,
    )
    source = SequenceSource(seq_dir)
    if track_dir.exists():
        shutil.rmtree(track_dir)
    run = tracker.Tracker(source, track_dir, options, quiet=args.quiet)
    summary = run.run()
    t2 = time.monotonic()
    print("3/4 evaluating ...", flush=True)
    report = evaluate_runs([track_dir], seq_dir, out / "eval.json")
    print("4/4 overlay frame ...", flush=True)
    mid = len(run.frames) // 2
    poses = metrics.load_prediction(track_dir)
    state = dict(zip(poses[0].tolist(), np.load(track_dir / "poses.npz")["state"], strict=True))[
        run.frames[mid]
    ]
    fd = source.read(run.frames[mid], masks=False)
    truth = seq.groundtruth.joints[run.frames[mid]]
    views = viz.overlay_image(fd.images, run.model, source.rig.to_jax(), state, truth)
    crops = viz.person_crops(views, source.rig.to_jax(), truth)  # the subject, enlarged, in both views
    cv2.imwrite(
        str(out / "demo_overlay.png"), np.concatenate(crops, axis=1), [cv2.IMWRITE_PNG_COMPRESSION, 9]
    )
    total = time.monotonic() - t0
    cues = _cues_text(summary["cues"])
    head = [
        "jaxmocap demo: CMU 02_01 (walk), synthetic stereo, " + f"{seq.num_frames} frames at {args.size}",
        f"model {summary['model']}, filter {summary['filter']}, {particles_text(summary['particles'])} particles x "
        f"{summary['layers']} layers, cues {cues}, init from ground truth",
        f"tracking {t2 - t1:.1f} s ({summary['frames_per_s']:.2f} frames/s after the first frame), total {total:.1f} s",
        "",
    ]
    table = "\n".join(head) + metrics.format_table(report)
    (out / "demo_table.txt").write_text(table + "\n")
    print()
    print(table)
    print()
    print(
        f"wrote {out / 'demo_table.txt'}, {out / 'demo_overlay.png'}, {out / 'eval.json'} (+ plots), {track_dir}/ (poses, BVH, overlay videos)"
    )
    return 0


# ---------------------------------------------------------------------------------------------------------------
# sweep


def _sweep(args) -> int:
    from jaxmocap.tracking import sweep

    _silence_opencv()
    if args.distributed or args.coordinator is not None:
        import jax  # the multi-process runtime: every process runs this command with the same options

        jax.distributed.initialize(args.coordinator, args.num_processes, args.process_id)
    over = dict(
        sequences=args.sequences or None,
        filters=args.filters,
        seeds=args.seeds,
        model=args.model,
        particles=args.particles,
        layers=args.layers,
        cues=args.cues,
        frames=args.frames,
        devices=args.devices,
        chunk=args.chunk,
    )
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


def _add_tracking_commands(sub) -> None:
    tr = sub.add_parser(
        "track",
        help="track a person in a sequence folder or synchronised videos",
        description="Track a sequence folder (synthesis format) or synchronised videos with their calibration "
        "into --out: poses.csv, poses.journal and diagnostics.jsonl get every frame as it is tracked; poses.npz and "
        "diagnostics.json are rewritten every few seconds; track.bvh (and the overlays) are written at the end, "
        "and poses.npz, diagnostics.json and track.bvh on every way out (Ctrl-C, SIGTERM, an error). One run at a "
        "time writes to a folder (run.lock); --resume continues a run that was stopped or killed.",
    )
    tr.add_argument(
        "input", nargs="?", help="sequence folder or PARSEC bodytrack sequence folder (or use --videos)"
    )
    tr.add_argument("--out", required=True, help="output folder")
    tr.add_argument("--videos", nargs="+", metavar="V", help="one synchronised video per camera")
    tr.add_argument(
        "--calibration", help="calibration of the videos (any format `jaxmocap calib show` reads)"
    )
    tr.add_argument(
        "--keypoints", nargs="+", metavar="DIR", help="OpenPose JSON folder per camera (with --videos)"
    )
    tr.add_argument(
        "--depth", nargs="+", metavar="DIR", help="depth-map folder per camera: .npy metres or 16-bit PNG mm"
    )
    tr.add_argument("--model", choices=_MODELS, help="body model (default: the body file's, else full25)")
    tr.add_argument("--filter", choices=_FILTERS, default="apf", help="particle filter (default apf)")
    tr.add_argument(
        "--particles",
        type=_particle_counts,
        help="particles (per layer for the annealed filters); partitioned / hierarchical: one count, or one per "
        "partition separated by commas (full25: torso, head, arms, legs, e.g. 1000,200,350,350,350,350)",
    )
    tr.add_argument("--layers", type=int, help="annealing layers (default 5; 2 per level for hierarchical)")
    tr.add_argument(
        "--cues", help="comma-separated cues with optional weights, e.g. foreground,edge_distance:2,coverage"
    )
    tr.add_argument("--seed", type=int, default=0, help="random seed, 0 to 4294967295 (default 0)")
    tr.add_argument("--frames", help="frame range A:B (default: all)")
    tr.add_argument(
        "--init",
        default="auto",
        help="groundtruth, ik or a FILE (.npz with 'state', .npy, text); default: groundtruth if the input has it, else ik",
    )
    tr.add_argument("--body", help="body file (TOML) with the subject's dimensions")
    tr.add_argument(
        "--foreground",
        choices=_FOREGROUNDS,
        default="auto",
        help="foreground source (default: masks of a sequence, else a median background)",
    )
    tr.add_argument(
        "--downsample", type=int, choices=(1, 2, 4), default=1, help="process images at 1/1, 1/2 or 1/4 size"
    )
    tr.add_argument(
        "--on-bad-frame",
        choices=("skip", "stop"),
        default="skip",
        help="a frame that does not decode: skip it with a warning (default) or stop",
    )
    tr.add_argument(
        "--overlay",
        action="store_true",
        help="also write an MP4 per view with the model drawn over the images",
    )
    tr.add_argument("--resume", action="store_true", help="continue an interrupted run in --out")
    tr.add_argument("--overwrite", action="store_true", help="replace a previous run in --out")
    tr.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    tr.set_defaults(func=_track)

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
        default=DEMO_FRAMES,
        help=f"source frame range of the 120 fps clip (default {DEMO_FRAMES})",
    )
    de.add_argument("--size", default=DEMO_SIZE, help=f"image size (default {DEMO_SIZE})")
    de.add_argument("--filter", choices=_FILTERS, default="apf", help="particle filter (default apf)")
    de.add_argument("--particles", type=int, help="particles per layer (default 300)")
    de.add_argument("--layers", type=int, help="annealing layers (default 5)")
    de.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    de.add_argument("--quiet", action="store_true", help="no progress bar")
    de.set_defaults(func=_demo)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="jaxmocap", description="Markerless motion capture with particle filters in JAX."
    )
    p.add_argument("--version", action="version", version=f"jaxmocap {__version__}")
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
    syn = sub.add_parser(
        "synth",
        help="render a synthetic multi-view sequence of a mocap clip",
        description="Render a synthetic multi-view sequence (RGB, mask, part labels, virtual depth, calibration, "
        "ground truth, body file) of a motion-capture clip; see README 'Sequence folder format'.",
    )
    syn.add_argument("--motion", required=True, help="a .bvh or .amc clip, or 'demo' (the bundled CMU walk)")
    syn.add_argument("--asf", help="ASF skeleton of an .amc clip (default: SS.asf next to SS_TT.amc)")
    syn.add_argument("--scale", type=float, help="metres per file unit (BVH default: the CMU conversion's)")
    syn.add_argument("--rig", default="stereo", help="stereo, frontal-lateral, ring4 or a calibration file")
    syn.add_argument("--frames", help="source frame range A:B (default: the whole clip)")
    syn.add_argument("--fps", type=float, default=30.0, help="output frame rate (default 30; subsamples)")
    syn.add_argument("--size", help="image size WxH (default 640x480, or the calibration's)")
    syn.add_argument("--seed", type=int, default=0, help="seed of every random number (default 0)")
    syn.add_argument("--background", default="photo", help="photo, plain or an image file (default photo)")
    syn.add_argument("--clutter", default="none", help="procedural clutter: none, low, medium, high or 0-1")
    syn.add_argument(
        "--noise", type=float, default=0.01, help="RGB noise sigma, 1 = full scale (default 0.01)"
    )
    syn.add_argument("--depth-noise", type=float, default=0.02, help="depth noise sigma in m (default 0.02)")
    syn.add_argument("--depth-smooth", type=float, default=1.5, help="depth smoothing in px (default 1.5)")
    syn.add_argument("--illumination", type=float, default=0.0, help="illumination change amplitude 0-1")
    syn.add_argument("--blur", type=int, default=1, help="motion blur: source frames averaged (default 1)")
    syn.add_argument("--licence", help="licence line of the clip for meta.json (default: the CMU terms)")
    syn.add_argument("--overwrite", action="store_true", help="replace an existing sequence in --out")
    syn.add_argument("--quiet", action="store_true", help="no progress output")
    syn.add_argument("--out", required=True, help="output sequence folder")
    syn.set_defaults(func=_synth)
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


def _main(argv) -> int:
    args = build_parser().parse_args(argv)
    import jaxmocap.parsec  # noqa: F401  (the PARSEC wing registers the parsec31 body and the .cal camera reader)
    from jaxmocap import compilation_cache

    compilation_cache.enable()  # a second run of a configuration reloads its compiled programs
    try:
        return args.func(args)
    except MocapInputError as e:
        print(f"jaxmocap: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"jaxmocap: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
