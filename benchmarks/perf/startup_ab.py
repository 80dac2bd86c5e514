"""Start-up cost of a dependency's version: new processes with this environment's packages against the same with
another version of some packages put ahead of them, side by side.

For every ``--versions`` requirement (``ml_dtypes==0.7.0``) the script installs that version alone into a
temporary folder (``pip install --no-deps --target``) and runs each command below once with ``PYTHONPATH`` naming
that folder and once without (the order alternating), ``--rounds`` times, as found and beside one busy-loop
process (``bodytrack.busy``), with the 1-minute load average:

* ``python -c "import jax"``: the interpreter's start and JAX's import;
* where sequenceB_2's folder is there (``benchmarks/bodytrack.py``), a warm one-frame PARSEC run, ``jaxmocap track
  sequenceB_2 --frames 0:1 --no-plots`` (4000 × 5; its programs read from a compilation cache filled by an
  untimed first run of each side), process start to exit, as ``benchmarks/perf/parsec_latency.py`` times it.

It reports the seconds per round, the medians and the ratio other / installed per round.

    python benchmarks/perf/startup_ab.py --versions ml_dtypes==0.7.0 [--rounds 5] [--out FILE]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import bodytrack
import common


def installed(requirement: str) -> str:
    """The installed version of the distribution ``requirement`` names (``ml_dtypes==0.7.0`` → ``0.6.0``)."""
    from importlib import metadata

    from packaging.requirements import Requirement

    name = Requirement(requirement).name
    return f"{name}=={metadata.version(name)}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--versions", nargs="+", required=True, metavar="NAME==VERSION")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--out", type=pathlib.Path, help="write the Markdown report here")
    a = ap.parse_args(argv)
    work = pathlib.Path(tempfile.mkdtemp(prefix="startup_ab_"))
    other = work / "packages"
    pip = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(other), *a.versions]
    subprocess.run(pip, check=True)
    mine = ", ".join(installed(v) for v in a.versions)
    theirs = ", ".join(a.versions)
    # label → (PYTHONPATH, compilation cache) of each side
    sides = {mine: (None, work / "cache0"), theirs: (str(other), work / "cache1")}
    # command name → label → python's arguments
    commands = {"python -c 'import jax'": {label: ["-c", "import jax"] for label in sides}}
    if bodytrack.SEQ.is_dir():
        track = commands["warm one-frame PARSEC track --no-plots"] = {
            label: ["-m", "jaxmocap.cli", "track", str(bodytrack.SEQ), "--frames", "0:1", "--no-plots"]
            + ["--overwrite", "--out", str(work / f"run{k}")]
            for k, label in enumerate(sides)
        }
        for label, (path, cache) in sides.items():  # fills each side's cache (untimed)
            common.run_python(common.ROOT, track[label], cache, path)
    rows = []
    for r in range(a.rounds):
        for condition in ("as found", "+1 busy process"):
            with bodytrack.busy(condition != "as found"):
                for name, args in commands.items():
                    times = {}
                    for label in list(sides)[:: 1 if r % 2 == 0 else -1]:
                        path, cache = sides[label]
                        times[label] = common.run_python(common.ROOT, args[label], cache, path)
                    rows.append((r, condition, name, os.getloadavg()[0], times[mine], times[theirs]))
    lines = [
        f"### Start-up with {theirs} against {mine}, side by side\n",
        f"{common.machine_line()}; {common.stamp()}; Python {sys.version.split()[0]}. Each command in a new "
        "process, the two sides in alternating order per round; ratio = other / installed (above 1: the installed "
        "version starts faster).\n",
        f"| round | condition | command | load (1 min) | {mine} s | {theirs} s | ratio |",
        "|---|---|---|---|---|---|---|",
    ]
    lines += [
        f"| {r} | {c} | {n} | {ld:.2f} | {x:.3f} | {y:.3f} | {y / x:.2f} |" for r, c, n, ld, x, y in rows
    ]
    lines.append("\nMedians:\n")
    for condition in ("as found", "+1 busy process"):
        for name in commands:
            got = [(x, y) for _, c, n, _, x, y in rows if (c, n) == (condition, name)]
            mx, my = (statistics.median(v) for v in zip(*got, strict=True))
            ratio = statistics.median(y / x for x, y in got)
            lines.append(
                f"- {condition}, {name}: {mine} {mx:.3f} s, {theirs} {my:.3f} s; ratio per round median "
                f"**{ratio:.2f}**"
            )
    text = "\n".join(lines)
    command = "python " + common.script(__file__) + " " + " ".join(sys.argv[1:] if argv is None else argv)
    common.report(a.out, text, command, write=a.out is not None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
