"""Frames/s of ``jaxmocap track`` side by side: its defaults, variants of its options and an earlier revision.

The bundled CMU walk rendered by :func:`jaxmocap.synth.generate.synthesize` (``--frames`` frames at ``--size``,
seed 0) for each rig of ``--rigs`` (``stereo``: two cameras 0.3 m apart, whose default refinement reads the depth
maps; ``ring4``: four cameras around), read as a recording (:class:`jaxmocap.io.sources.SequenceSource` with
``recording=True``), tracked by :class:`jaxmocap.tracking.tracker.Tracker` in one process with:

* ``default`` — this checkout's defaults;
* ``LABEL`` (``--variant "LABEL:FIELD=VALUE[;FIELD=VALUE…]"``, repeatable) — the defaults with those fields of
  :class:`~jaxmocap.tracking.options.TrackOptions` set otherwise, e.g. ``"no depth:refine_depth=0"``;
* ``REV`` (``--against REV``) — the defaults of the package at git revision ``REV``
  (:func:`common.package_at`), e.g. the revision before a change; ``--against-options "FIELD=VALUE[;…]"`` sets
  fields of its options otherwise (a default that the change moved, to compare like with like).

``--preset NAME`` takes that preset's options instead of the defaults in every configuration (``--variant`` fields
over them); ``--fps``, ``--background``, ``--clutter`` and ``--no-detections`` choose the rendered scene, e.g. the
IROS 2007 scenario: ``--preset iros2007 --rigs stereo --size 640x480 --fps 15 --background room --clutter medium
--no-detections``.

Each configuration is run once to compile (the persistent compilation cache on), then ``--rounds`` interleaved
rounds, the order rotated each round; ``--busy`` adds as many rounds again with a CPU-bound process beside them
(``bodytrack.busy``: a second core's worth of work, as a machine doing other things). Reported per round: each
configuration's frames/s after the first frame (the summary's ``frames_per_s``), its ratio to ``default``, and
the load average.

    python benchmarks/perf/track_rate.py [--rigs stereo ring4] [--frames 40] [--size 320x240] [--rounds 3]
        [--busy] [--variant "no depth:refine_depth=0" …] [--against REV] [--preset NAME] [--fps 30]
        [--background plain] [--clutter none] [--no-detections] [--title T] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import shlex
import subprocess
import sys
import tempfile

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import bodytrack
import common
import numpy as np

import jaxmocap.io.sources
import jaxmocap.tracking.options
import jaxmocap.tracking.tracker
from jaxmocap import compilation_cache
from jaxmocap.synth import generate as synth


def parse_variant(text: str) -> tuple[str, dict]:
    """``"LABEL:FIELD=VALUE[;FIELD=VALUE…]"`` → ``(LABEL, {field: value})`` (:func:`parse_fields`)."""
    label, sep, fields = text.partition(":")
    if not sep or not label.strip() or not fields.strip():
        raise SystemExit(f"--variant {text!r}: expected LABEL:FIELD=VALUE[;FIELD=VALUE…]")
    return label.strip(), parse_fields(fields, f"--variant {text!r}")


def parse_fields(fields: str, what: str) -> dict:
    """``"FIELD=VALUE[;FIELD=VALUE…]"`` → ``{field: value}`` (:func:`common.track_options`); ``what`` names the
    option in the error."""
    try:
        return common.track_options(f.strip() for f in fields.split(";"))
    except ValueError as e:
        raise SystemExit(f"{what}: {e}") from None


def configurations(against: str | None, variants=(), preset: str | None = None, against_options=None):
    """``{name: run(seq, out) -> frames/s}`` of the compared trackers (``variants``: ``(label, options)``; ``preset``:
    the options of that preset instead of the defaults, in every configuration; ``against_options``: fields set
    otherwise for revision ``against``)."""

    def tracker(sources, options_mod, tracker_mod, **options):
        def run(seq, out):
            src = sources.SequenceSource(seq, recording=True)
            try:
                if preset:
                    opts = options_mod.TrackOptions.from_preset(preset, overwrite=True, **options)
                else:
                    opts = options_mod.TrackOptions(overwrite=True, **options)
                return float(tracker_mod.Tracker(src, out, opts, quiet=True).run()["frames_per_s"])
            finally:
                src.close()

        return run

    ours = (jaxmocap.io.sources, jaxmocap.tracking.options, jaxmocap.tracking.tracker)
    out = {"default": tracker(*ours)}
    for label, options in variants:
        out[label] = tracker(*ours, **options)
    if against:
        common.package_at(against, "tracking.tracker")
        theirs = (
            sys.modules[f"jaxmocap_at_rev.{m}"]
            for m in ("io.sources", "tracking.options", "tracking.tracker")
        )
        label = subprocess.run(
            ["git", "-C", str(common.ROOT), "rev-parse", "--short", against], capture_output=True, text=True
        ).stdout.strip()
        label = label or against
        if against_options:
            label += " (" + ", ".join(f"{k}={v}" for k, v in against_options.items()) + ")"
        out[label] = tracker(*theirs, **(against_options or {}))
    return out


def table_row(label: str, load: str, names, fps: dict, ratio: dict, bold: bool = False) -> str:
    """One row of a rig's table: frames/s of every configuration of ``names``, then each ratio to ``default``
    (in the columns' order, whatever order the round ran them in)."""
    b = "**" if bold else ""
    cells = [f"{b}{fps[n]:.1f}{b}" for n in names] + [f"{b}{ratio[n]:.3f}{b}" for n in names[1:]]
    return f"| {label} | {load} | " + " | ".join(cells) + " |"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rigs", nargs="+", default=["stereo", "ring4"], choices=["stereo", "ring4"])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--size", default="320x240")
    ap.add_argument(
        "--fps", type=float, default=30.0, help="the sequence's frame rate (every 120/fps-th frame)"
    )
    ap.add_argument("--background", default="plain", help="the synthetic scene's background (synthesize)")
    ap.add_argument("--clutter", default="none", help="clutter on the room's walls (synthesize)")
    ap.add_argument(
        "--detections", action=argparse.BooleanOptionalAction, default=True, help="simulated 2D detections"
    )
    ap.add_argument("--preset", default=None, help="the options of this preset instead of the defaults")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--busy", action="store_true", help="as many rounds again beside a CPU-bound process")
    ap.add_argument(
        "--variant",
        action="append",
        default=[],
        metavar="LABEL:FIELD=VALUE;…",
        help="also the defaults with these TrackOptions fields set otherwise (repeatable)",
    )
    ap.add_argument("--against", metavar="REV", help="also the defaults of the package at git revision REV")
    ap.add_argument(
        "--against-options",
        metavar="FIELD=VALUE[;FIELD=VALUE…]",
        help="TrackOptions fields set otherwise for the revision of --against",
    )
    ap.add_argument("--title", default="frames/s side by side", help="the result's heading")
    ap.add_argument("--out", default=None, help="write the table here (default: print only)")
    a = ap.parse_args(argv)
    compilation_cache.enable()
    variants = [parse_variant(v) for v in a.variant]
    against_options = None
    if a.against_options:
        against_options = parse_fields(a.against_options, f"--against-options {a.against_options!r}")
    configs = configurations(a.against, variants, a.preset, against_options)
    names = list(configs)
    lines = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        for rig in a.rigs:
            seq = tmp / f"walk_{rig}"
            step = round(120 / a.fps)  # the walk is captured at 120 frames/s
            synth.synthesize(
                "demo", seq, rig=rig, frames=f"0:{step * a.frames}", fps=a.fps, size=a.size, seed=0,
                background=a.background, clutter=a.clutter, detections=a.detections,
            )  # fmt: skip
            for name in names:  # compile (or load from the cache) once each
                configs[name](seq, tmp / "run")
            rows = []
            phases = [("idle", a.rounds)] + ([("busy", a.rounds)] if a.busy else [])
            for phase, rounds in phases:
                with bodytrack.busy(phase == "busy"):
                    for r in range(rounds):
                        order = names[r % len(names) :] + names[: r % len(names)]
                        load = os.getloadavg()[0]
                        fps = {n: configs[n](seq, tmp / "run") for n in order}
                        rows.append((phase, r, load, fps))
                        print(
                            f"{rig} {phase} round {r}: "
                            + ", ".join(f"{n} {fps[n]:.1f}" for n in names)
                            + f" frames/s (load {load:.1f})",
                            flush=True,
                        )
            lines += [
                f"### {rig}\n",
                "| round | load | "
                + " | ".join(f"{n} frames/s" for n in names)
                + " | "
                + " | ".join(f"{n} ÷ default" for n in names[1:])
                + " |",
                "|---" * (2 + 2 * len(names) - 1) + "|",
            ]
            for phase, r, load, fps in rows:
                ratio = {n: fps[n] / fps["default"] for n in names[1:]}
                lines.append(table_row(f"{phase} {r}", f"{load:.1f}", names, fps, ratio))
            for phase, _ in phases:
                sel = [fps for p, _, _, fps in rows if p == phase]
                med = {n: float(np.median([f[n] for f in sel])) for n in names}
                ratio = {n: float(np.median([f[n] / f["default"] for f in sel])) for n in names[1:]}
                lines.append(table_row(f"**{phase}, median**", "", names, med, ratio, bold=True))
            lines.append("")
    cmd = f"python {common.script(__file__)} " + shlex.join(sys.argv[1:] if argv is None else argv)
    text = "\n".join(
        [
            f"# `jaxmocap track`: {a.title}\n",
            f"Reproduce: `{cmd}` ({common.stamp()}, {common.machine_line()})\n",
            f"The bundled walk, {a.frames} frames at {a.size} and {a.fps:g} frames/s (background {a.background}, "
            f"clutter {a.clutter}{'' if a.detections else ', no detections'}), read as a recording; "
            + (f"`jaxmocap track --preset {a.preset}`" if a.preset else "`jaxmocap track`'s defaults")
            + " (`default`)"
            + "".join(
                f", `{label}` (" + ", ".join(f"`{k}={v}`" for k, v in options.items()) + ")"
                for label, options in variants
            )
            + (
                f", and the {'preset' if a.preset else 'defaults'} of revision `{names[-1]}` (`--against {a.against}`"
                + (f" `--against-options {a.against_options}`" if a.against_options else "")
                + ")"
                if a.against
                else ""
            )
            + "; frames/s after the first frame, interleaved rounds in one process (module docstring of "
            "`benchmarks/perf/track_rate.py`).\n",
            *lines,
        ]
    )
    print(text)
    if a.out:
        common.write_result(pathlib.Path(a.out), text, cmd)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
