"""The ``jaxmocap`` command.

Subcommands:

* ``jaxmocap calib show FILE`` — print the cameras of any calibration the project reads (OpenCV FileStorage
  YAML/XML, Pose2Sim/OpenCV TOML, caliscope TOML, Qualisys ``.qca.txt``, a PARSEC ``CALIB`` folder).
* ``jaxmocap calib convert IN OUT.toml`` — write it as the canonical Pose2Sim-layout TOML.

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
