"""``jaxmocap synth``: its options and the command, which renders a synthetic multi-view sequence of a mocap clip
(:func:`jaxmocap.synth.generate.synthesize`, imported when the command runs)."""

from __future__ import annotations

import sys

from jaxmocap.errors import MocapInputError

__all__ = ["OPTIONS", "add_command", "keywords", "run"]

#: The options of ``jaxmocap synth`` that :func:`jaxmocap.synth.generate.synthesize` takes by the same name (the
#: flag's dashes as underscores): flag and ``add_argument`` settings.
OPTIONS: tuple[tuple[str, dict], ...] = (
    (
        "--motion",
        dict(required=True, help="a .bvh or .amc clip of any skeleton, or 'demo' (the bundled CMU walk)"),
    ),
    ("--asf", dict(help="ASF skeleton of an .amc clip (default: SS.asf next to SS_TT.amc)")),
    (
        "--mapping",
        dict(help="TOML file naming file joints for evaluation joints (default: by names, then shape)"),
    ),
    ("--scale", dict(type=float, help="metres per file unit (BVH default: detected from the legs)")),
    ("--up-axis", dict(choices=("y", "z"), help="the file's up axis (BVH default: detected)")),
    ("--rig", dict(default="stereo", help="stereo, frontal-lateral, ring4 or a calibration file")),
    ("--frames", dict(help="source frame range A:B (default: the whole clip)")),
    ("--fps", dict(type=float, default=30.0, help="output frame rate (default 30; subsamples)")),
    ("--size", dict(help="image size WxH (default 640x480, or the calibration's)")),
    ("--seed", dict(type=int, default=0, help="seed of every random number (default 0)")),
    (
        "--background",
        dict(default="photo", help="photo, plain, an image file, or room (a 3D room with shadows)"),
    ),
    ("--clutter", dict(default="none", help="procedural clutter: none, low, medium, high or 0-1")),
    ("--noise", dict(type=float, default=0.01, help="RGB noise sigma, 1 = full scale (default 0.01)")),
    ("--depth-noise", dict(type=float, default=0.02, help="depth noise sigma in m (default 0.02)")),
    ("--depth-smooth", dict(type=float, default=1.5, help="depth smoothing in px (default 1.5)")),
    ("--illumination", dict(type=float, default=0.0, help="illumination change amplitude 0-1")),
    ("--blur", dict(type=int, default=1, help="motion blur: source frames averaged (default 1)")),
    (
        "--clothing",
        dict(default="plain", choices=("plain", "textured"), help="clothing texture (default plain)"),
    ),
    ("--sleeves", dict(default="long", choices=("long", "short"), help="short: bare forearms")),
    ("--wrist-bands", dict(action="store_true", help="a lime band around each wrist (Li & Kulic's markers)")),
    ("--licence", dict(help="licence line of the clip for meta.json (default: the CMU terms)")),
    ("--overwrite", dict(action="store_true", help="replace an existing sequence in --out")),
)


def keywords() -> list[str]:
    """The keywords of :func:`jaxmocap.synth.generate.synthesize` that :data:`OPTIONS` set."""
    return [flag[2:].replace("-", "_") for flag, _ in OPTIONS]


def add_command(sub) -> None:
    """Add the ``synth`` command to the sub-parsers ``sub`` of ``jaxmocap``'s parser."""
    syn = sub.add_parser(
        "synth",
        help="render a synthetic multi-view sequence of a mocap clip",
        description="Render a synthetic multi-view sequence (RGB, mask, part labels, virtual depth, calibration, "
        "ground truth, body file) of a motion-capture clip; see README 'Sequence folder format'.",
    )
    for flag, settings in OPTIONS:
        syn.add_argument(flag, **settings)
    syn.add_argument("--quiet", action="store_true", help="no progress output")
    syn.add_argument("--out", required=True, help="output sequence folder")
    syn.set_defaults(func=run)


def run(args) -> int:
    """The command: :func:`jaxmocap.synth.generate.synthesize` with :data:`OPTIONS` (status 2 for a bad value)."""
    from jaxmocap.synth import generate as synth

    def progress(done, total):
        if not args.quiet and (done == total or done % 10 == 0):
            print(f"\rframe {done}/{total}", end="\n" if done == total else "", flush=True)

    options = {name: getattr(args, name) for name in keywords()}
    try:
        seq = synth.synthesize(out=args.out, progress=progress, **options)
    except MocapInputError:
        raise
    except ValueError as e:  # a bad option value
        print(f"jaxmocap: error: {e}", file=sys.stderr)
        return 2
    print(
        f"wrote {seq.num_frames} frames x {len(seq.views)} views ({', '.join(seq.view_names)}) to {args.out}"
    )
    return 0
