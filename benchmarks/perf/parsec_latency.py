"""First-frame latency of a PARSEC run: a one-frame ``jaxmocap track`` of sequenceB_2 (bodytrack's 4000 × 5) in a
new process, from its start to its exit (every output written), against bodytrack's whole one-frame run, and
against the same command with the package of another git revision (``--against REV``), side by side.

Each checkout gets its own compilation cache directory (``JAXMOCAP_CACHE_DIR``): its first run fills it (cold:
every program compiled and stored), the rounds then time warm runs (what a user gets from the second run of a
configuration on). Every round runs each condition (as found, then beside one busy-loop process,
``bodytrack.busy``) and in it this checkout, ``REV`` (the order alternating) and bodytrack serial's whole run of
one frame, with the 1-minute load average, and this checkout once more with ``--no-plots`` (the run's pictures
left out: bodytrack writes none). ``REV``'s package is ``git archive REV jaxmocap`` in a temporary folder
(the command runs there, so that ``python -m jaxmocap.cli`` imports it).

    JAX_PLATFORMS=cpu .venv/bin/python benchmarks/perf/parsec_latency.py [--rounds 5] [--against REV] [--out FILE]
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
import sys
import tempfile

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import bodytrack
import common


def first_frame(root: pathlib.Path, cache: pathlib.Path, out: pathlib.Path, *options: str) -> float:
    """Wall seconds of ``python -m jaxmocap.cli track sequenceB_2 --frames 0:1 [options]``
    (:func:`common.run_cli`)."""
    return common.run_cli(
        root,
        cache,
        [
            "track",
            str(bodytrack.SEQ),
            "--out",
            str(out),
            "--frames",
            "0:1",
            "--quiet",
            "--overwrite",
            *options,
        ],
    )


#: the column of this checkout's runs with ``--no-plots``
NO_PLOTS = "--no-plots"


def measure(rounds: int, against: str | None, log=print) -> str:
    out_build = bodytrack.build()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        roots = {"this checkout": common.ROOT}
        if against:
            roots[against] = common.checkout_at(against, tmp / "rev")
        names = list(roots)
        cold = {}
        for n in names:
            cold[n] = first_frame(roots[n], tmp / f"cache{names.index(n)}", tmp / f"out{names.index(n)}")
            log(f"cold {n}: {cold[n]:.1f} s")
        rows = bodytrack.revisions_side_by_side(
            rounds,
            names,
            {
                "parsec": lambda n: first_frame(
                    roots[n], tmp / f"cache{names.index(n)}", tmp / f"out{names.index(n)}"
                )
            },
            extra=lambda: {
                NO_PLOTS: first_frame(roots[names[0]], tmp / "cache0", tmp / "out_no_plots", NO_PLOTS),
                "bodytrack": bodytrack.bodytrack_run(4000, 5, frames=1, out=out_build)[1],
            },
            log=log,
        )

    this = names[0]
    lines = [
        f"One-frame `jaxmocap track sequenceB_2 --frames 0:1` (4000 × 5), process start to exit; {common.machine_line()}; "
        f"{common.stamp()}.",
        "",
        "| cache | " + " | ".join(f"{n} s" for n in names) + " |",
        "|---|" + "---|" * len(names),
        "| cold (empty, the first run) | " + " | ".join(f"{cold[n]:.1f}" for n in names) + " |",
        "",
        "Warm (the same cache directories), interleaved rounds:",
        "",
    ]
    head = ["round", "condition", "load (1 min)"] + [f"{n} s" for n in names]
    head += [f"this checkout {NO_PLOTS} s", "bodytrack serial 1 frame s"]
    head += [f"this ÷ {against}"] if against else []
    head += ["bodytrack ÷ this", f"bodytrack ÷ this {NO_PLOTS}"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [str(row["round"]), row["condition"], f"{row['load']:.2f}"]
        cells += [f"{row[n]:.2f}" for n in names] + [f"{row[NO_PLOTS]:.2f}", f"{row['bodytrack']:.2f}"]
        cells += [f"{row[this] / row[against]:.2f}"] if against else []
        cells += [f"{row['bodytrack'] / row[this]:.3f}", f"{row['bodytrack'] / row[NO_PLOTS]:.3f}"]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "Medians per condition:", ""]
    for cond in bodytrack.CONDITIONS:
        sel = [row for row in rows if row["condition"] == cond]
        if not sel:
            continue
        cols = [*names, NO_PLOTS, "bodytrack"]
        med = {n: statistics.median(row[n] for row in sel) for n in cols}
        text = f"- {cond}: " + ", ".join(
            f"{'this checkout ' + n if n == NO_PLOTS else n} {med[n]:.2f} s" for n in cols
        )
        if against:
            text += f"; this ÷ {against} per round median **{statistics.median(row[this] / row[against] for row in sel):.2f}**"
        lines.append(text)
    return "\n".join(lines)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--against", metavar="REV", help="also time the package of git revision REV")
    p.add_argument("--out", type=pathlib.Path, help="write the Markdown result here")
    args = p.parse_args(argv)
    text = "### First-frame latency of the PARSEC run, warm and cold, against bodytrack\n\n"
    text += measure(args.rounds, args.against, log=lambda s: print(s, file=sys.stderr, flush=True))
    argv_text = " ".join(sys.argv[1:] if argv is None else argv)
    command = f"JAX_PLATFORMS=cpu python {common.script(__file__)} {argv_text}".strip()
    common.report(args.out, text, command, write=args.out is not None)


if __name__ == "__main__":
    main()
