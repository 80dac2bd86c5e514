"""Start-to-exit time of a warm ``jaxmocap track`` and ``jaxmocap demo``, against the package of another git revision.

A warm run is what a user gets from the second run of a configuration on: its compiled programs (and, since the
traced filter step and first-pose fits are kept as well, :mod:`jaxmocap.stored_programs`, its traced programs) are
read back from the cache instead of being made again. Two commands, each in a new process, from its start to its
exit (every output written):

* ``track``: ``jaxmocap track SEQ --init ik --frames 0:2`` on a stereo sequence of the bundled CMU walk (320×240,
  rendered once by :func:`jaxmocap.synth.generate.synthesize` with simulated 2D detections), started from its
  detections (the ground truth in the folder is read only to evaluate the track);
* ``demo``: ``jaxmocap demo`` with its defaults (renders and tracks 60 frames of the walk: the README's main job).

Each checkout gets its own compilation cache directory (``JAXMOCAP_CACHE_DIR``); its first run of each command
fills it (cold). The rounds then time warm runs: every round runs each condition (as found, then beside one
busy-loop process, ``bodytrack.busy``) and in it each command with this checkout and ``REV`` (the order
alternating), with the 1-minute load average; the table gives the ratio per round and its median per condition.
``REV``'s package is ``git archive REV jaxmocap`` in a temporary folder (the commands run there, so that ``python -m
jaxmocap.cli`` imports it).

    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/perf/track_latency.py [--rounds 5] [--against REV]
                                                                         [--commands track demo] [--out FILE]
"""

from __future__ import annotations

import argparse
import functools
import pathlib
import statistics
import sys
import tempfile

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import bodytrack
import common


def make_sequence(folder: pathlib.Path) -> pathlib.Path:
    """Eight frames (30 fps) of the bundled CMU walk, stereo, 320×240, with simulated detections."""
    from jaxmocap.synth import generate as synth

    out = folder / "walk_stereo"
    synth.synthesize(
        "demo", out, rig="stereo", frames="0:32", fps=30.0, size="320x240", seed=0, overwrite=True
    )
    return out


def command(name: str, seq: pathlib.Path, out: pathlib.Path) -> list[str]:
    if name == "track":
        return [
            "track",
            str(seq),
            "--init",
            "ik",
            "--frames",
            "0:2",
            "--out",
            str(out),
            "--overwrite",
            "--quiet",
        ]
    return ["demo", "--out", str(out), "--quiet"]


def measure(rounds: int, against: str | None, commands: list[str], log=print) -> str:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        seq = make_sequence(tmp)
        roots = {"this checkout": common.ROOT}
        if against:
            roots[against] = common.checkout_at(against, tmp / "rev")
        names = list(roots)

        def once(n, c):
            i = names.index(n)
            return common.run_cli(roots[n], tmp / f"cache{i}", command(c, seq, tmp / f"out{i}_{c}"))

        cold = {(n, c): once(n, c) for c in commands for n in names}
        for (n, c), s in cold.items():
            log(f"cold {c} {n}: {s:.1f} s")
        rows = bodytrack.revisions_side_by_side(
            rounds, names, {c: functools.partial(once, c=c) for c in commands}, log=log
        )

    this = names[0]
    lines = [
        f"{common.machine_line()}; {common.stamp()}. `track`: `jaxmocap track SEQ --init ik --frames 0:2` (a stereo "
        "sequence of the bundled walk, 320×240, simulated detections); `demo`: `jaxmocap demo` (its defaults). "
        "Process start to exit.",
        "",
        "| command | cache | " + " | ".join(f"{n} s" for n in names) + " |",
        "|---|---|" + "---|" * len(names),
    ]
    for c in commands:
        lines.append(
            f"| {c} | cold (empty, the first run) | " + " | ".join(f"{cold[n, c]:.1f}" for n in names) + " |"
        )
    lines += ["", "Warm (the same cache directories), interleaved rounds:", ""]
    head = ["round", "condition", "command", "load (1 min)"] + [f"{n} s" for n in names]
    head += [f"this ÷ {against}"] if against else []
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [str(row["round"]), row["condition"], row["command"], f"{row['load']:.2f}"]
        cells += [f"{row[n]:.2f}" for n in names]
        cells += [f"{row[this] / row[against]:.2f}"] if against else []
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "Medians per command and condition:", ""]
    for c in commands:
        for cond in bodytrack.CONDITIONS:
            sel = [row for row in rows if row["condition"] == cond and row["command"] == c]
            if not sel:
                continue
            med = {n: statistics.median(row[n] for row in sel) for n in names}
            text = f"- {c}, {cond}: " + ", ".join(f"{n} {med[n]:.2f} s" for n in names)
            if against:
                ratios = [row[this] / row[against] for row in sel]
                text += (
                    f"; this ÷ {against} per round median **{statistics.median(ratios):.2f}** "
                    f"[{min(ratios):.2f}–{max(ratios):.2f}]"
                )
            lines.append(text)
    return "\n".join(lines)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--against", metavar="REV", help="also time the package of git revision REV")
    p.add_argument("--commands", nargs="+", choices=("track", "demo"), default=["track", "demo"])
    p.add_argument("--out", type=pathlib.Path, help="write the Markdown result here")
    args = p.parse_args(argv)
    text = "### Warm start of `jaxmocap track` and `jaxmocap demo`\n\n"
    text += measure(
        args.rounds, args.against, args.commands, log=lambda s: print(s, file=sys.stderr, flush=True)
    )
    argv_text = " ".join(sys.argv[1:] if argv is None else argv)
    command_line = f"JAX_PLATFORMS=cpu python {common.script(__file__)} {argv_text}".strip()
    common.report(args.out, text, command_line, write=args.out is not None)


if __name__ == "__main__":
    main()
