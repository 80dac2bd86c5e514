"""The ``jaxmocap`` command.

Subcommands:

* ``jaxmocap calib show FILE`` — print the cameras of any calibration the project reads (OpenCV FileStorage
  YAML/XML, Pose2Sim/OpenCV TOML, caliscope TOML, Qualisys ``.qca.txt``, a PARSEC ``CALIB`` folder).
* ``jaxmocap calib convert IN OUT.toml`` — write it as the canonical Pose2Sim-layout TOML.
* ``jaxmocap synth --motion CLIP --rig {stereo,frontal-lateral,ring4,FILE} --out DIR [...]`` — render a synthetic
  multi-view sequence of a mocap clip with exact ground truth (:func:`jaxmocap.synth.synthesize`).

Bad input prints one line naming the file (and line) and exits with status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from jaxmocap import __version__
from jaxmocap.errors import MocapInputError


def _calib_show(args) -> int:
    from jaxmocap import camera

    rig = camera.load_calibration(args.file)
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
    from jaxmocap import camera

    rig = camera.load_calibration(args.input)
    camera.save_calibration(args.output, rig)
    print(f"wrote {rig.num_views} cameras to {args.output}")
    return 0


def _synth(args) -> int:
    from jaxmocap import synth

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
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
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
