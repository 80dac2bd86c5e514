"""Tracking accuracy of every filter on short synthetic sequences rendered from real CMU motion capture.

Scenario (all choices stated here):

* clips: the bundled CMU walk (subject 2, trial 1) and, when ``../shared/data/mocap/cmu`` is present, the CMU
  Charleston dance; source frames ``--frames`` (default ``150:270`` at 120 fps → 30 frames at 30 fps), rendered by
  :func:`jaxmocap.synth.generate.synthesize` with the ``stereo`` preset at ``--size`` (default 320×240), photo background,
  sensor noise 0.01, virtual depth (noise 2 cm);
* the tracker exactly as ``jaxmocap track`` runs it (:class:`jaxmocap.tracking.tracker.Tracker`: damped
  constant-velocity prediction, track-loss handling) on the input a real setup records (``benchmarks/scenes.py``,
  :class:`PlateSource`): silhouettes by background subtraction against each view's empty-scene plate, the first
  pose by inverse kinematics on the simulated BODY_25B detections; with ``--oracle``, the rendered masks and the
  first pose fitted to the ground truth instead (both with the sequence's body file). Each configuration compiled once and run with ``--seeds`` seeds (frame ``t`` of seed ``s`` uses the
  key ``fold_in(key(s), t)``);
* error of a run: thesis eq. 7.1, the mean over frames and evaluation joints of the Euclidean distance between the
  model's joints at the estimate and the ground truth (mm) (:func:`jaxmocap.eval.metrics.evaluate`); tables give the mean
  ± std of that per-run error over seeds and clips, and the tracking time per frame (after compilation).

Tables:

(a) every filter of :data:`jaxmocap.tracking.FILTERS` on ``full25`` at an equal compute budget of ``--budget``
    likelihood evaluations per frame (default 600: 600 particles for SIR / ICONDENSATION; 200 × 3 layers for the
    annealed filters; ``600 / G`` per partition for partitioned sampling with ``G`` DOF groups; ``600 / (2 G)`` per
    level for the two-layer hierarchical filter);
(b) thesis Table 7.1: APF, M-APF, FBAPF, FBAPF2, FBAPF3 with 200 particles × 3 layers, on ``full25`` with the
    cues of (a) (when (a) runs too, its rows for these filters are reused: they are the same runs). Not on the
    thesis' ``upper9``: on these full-body sequences an upper-body model slides down inside the silhouette (nothing
    in the foreground / edge cues pins it to the top of it) and every variant ends 375–510 mm off;
(c) Li & Kulić Table I on ``full25`` with partitioned sampling: all cues (foreground + coverage, ``edge_fraction`` —
    their edge cue, eq. 2 — and ``depth``, eq. 1) against each cue left out, and their per-partition particle
    counts scaled to full, half and quarter. Theirs are torso 1000, head 200, upper arms 500, forearms 200,
    thighs 500, calves 200 (2600 evaluations per frame); this project's partitions of ``full25`` are torso, head,
    each whole arm and each whole leg, so each limb gets half of its two partitions' counts — torso 1000, head
    200, each arm (500 + 200) / 2 = 350, each leg 350: the same 2600 evaluations per frame.

    .venv/bin/python benchmarks/experiments/accuracy.py [--seeds 5] [--quick] [--only a b c] [--oracle]

Writes ``benchmarks/results/accuracy.md`` (not with ``--quick``).
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import common
from scenes import CachedTracker, Config, make_sequences, open_source, track_options

from jaxmocap.filters.factory import particles_text, partition_groups  # noqa: E402
from jaxmocap.tracking.options import FILTERS, build_model  # noqa: E402

RESULTS = common.RESULTS / "accuracy.md"

#: Li & Kulić's per-partition counts mapped onto the partitions of ``full25`` (see table (c) above)
LI_KULIC_COUNTS = (1000, 200, 350, 350, 350, 350)
THESIS_FILTERS = ("apf", "m-apf", "fbapf", "fbapf2", "fbapf3")


def run_config(
    cfg: Config, seq_dir: pathlib.Path, seeds: int, work: pathlib.Path, oracle: bool = False
) -> dict:
    """Errors (mm, one per seed) and the median step time of ``cfg`` on one sequence (``oracle``: the rendered
    masks and ground-truth initialisation, :func:`scenes.open_source`)."""
    source = open_source(seq_dir, oracle)
    try:
        run = CachedTracker(source, work / "track", track_options(cfg, oracle), quiet=True)
        errors, summaries, _ = run.run_seeds(seeds, seq_dir)
        lost = [int(s.get("lost_frames", 0) or 0) for s in summaries]
        return {"errors": errors, "step_s": run.median_step_s, "lost": lost}
    finally:
        source.close()


def configs_a(budget: int) -> list[Config]:
    groups = len(partition_groups(build_model("full25", None)))
    out = []
    for f in FILTERS:
        if f in ("sir", "icondensation"):
            n, L = budget, 1
        elif f == "partitioned":
            n, L = max(budget // groups, 2), 1
        elif f == "hierarchical":
            n, L = max(budget // (2 * groups), 2), 2
        else:
            n, L = budget // 3, 3
        out.append(Config(f, "full25", f, n, L))
    return out


def configs_b(particles: int = 200) -> list[Config]:
    return [Config(f.upper(), "full25", f, particles, 3) for f in THESIS_FILTERS]


def configs_c(scale: float = 1.0) -> list[Config]:
    """Li & Kulić's ablation with their per-partition particle counts (:data:`LI_KULIC_COUNTS`) times ``scale``."""

    def n(frac=1.0):
        return tuple(max(int(c * scale * frac), 2) for c in LI_KULIC_COUNTS)

    full = ("foreground", "coverage:4", "edge_fraction", "depth")
    out = [Config("all cues", "full25", "partitioned", n(), 1, full)]
    for drop, name in (("edge_fraction", "without edge"), ("depth", "without depth")):
        out.append(Config(name, "full25", "partitioned", n(), 1, tuple(c for c in full if c != drop)))
    out.append(
        Config(
            "without silhouette (foreground + coverage)",
            "full25",
            "partitioned",
            n(),
            1,
            ("edge_fraction", "depth"),
        )
    )
    for frac, name in ((0.5, "half particles"), (0.25, "quarter particles")):
        out.append(Config(name, "full25", "partitioned", n(frac), 1, full))
    return out


def fmt(errors: list[float]) -> str:
    e = np.asarray(errors, np.float64)
    return f"{e.mean():.1f} ± {e.std(ddof=1) if e.size > 1 else 0.0:.1f}"


def run_table(
    name: str,
    configs: list[Config],
    sequences,
    seeds: int,
    work: pathlib.Path,
    log=print,
    on_row=None,
    oracle: bool = False,
) -> list[dict]:
    rows = []
    for cfg in configs:
        errs, steps, lost, per_clip = [], [], [], {}
        for clip, seq_dir in sequences:
            t0 = time.monotonic()
            r = run_config(cfg, seq_dir, seeds, work, oracle)
            errs += r["errors"]
            steps.append(r["step_s"])
            lost += r["lost"]
            per_clip[clip] = r["errors"]
            log(
                f"[{name}] {cfg.label} on {clip}: {fmt(r['errors'])} mm, {r['step_s'] * 1e3:.0f} ms/frame "
                f"({time.monotonic() - t0:.0f} s)"
            )
        rows.append(
            {
                "label": cfg.label,
                "config": cfg,
                "errors": errs,
                "per_clip": per_clip,
                "step_s": float(np.median(steps)),
                "lost": float(np.mean(lost)),
            }
        )
        if on_row is not None:
            on_row(rows)
    return rows


def table_md(rows: list[dict], clip_names: list[str], particles_col: bool = True) -> str:
    head = "| configuration | particles × layers | cues | " + " | ".join(f"{c} (mm)" for c in clip_names)
    head += " | all (mm) | ms/frame | lost frames/run |"
    lines = [head, "|" + "---|" * (6 + len(clip_names))]
    for r in rows:
        c = r["config"]
        cells = [fmt(r["per_clip"][n]) for n in clip_names]
        lines.append(
            f"| {r['label']} | {particles_text(c.particles)} × {c.layers} | {', '.join(c.cues)} | "
            + " | ".join(cells)
            + f" | **{fmt(r['errors'])}** | {r['step_s'] * 1e3:.0f} | {r['lost']:.1f} |"
        )
    return "\n".join(lines)


def _mean(rows, label):
    return float(np.mean(next(r for r in rows if r["label"] == label)["errors"]))


def verdict_b(rows) -> str:
    m = {r["label"]: float(np.mean(r["errors"])) for r in rows}
    order = sorted(m, key=m.get)
    fb_best = min(m[k] for k in ("FBAPF", "FBAPF2", "FBAPF3"))
    holds = fb_best < m["APF"]
    return (
        f"Ranking here (lowest error first): {' < '.join(order)}. The thesis reports the feature-based variants "
        f"below the standard APF; best feature-based {fb_best:.1f} mm vs APF {m['APF']:.1f} mm: "
        f"**{'holds' if holds else 'does not hold'}** on these sequences (differences smaller than the std over "
        "seeds are not significant)."
    )


def verdict_c(rows) -> str:
    allc = _mean(rows, "all cues")
    parts = []
    for r in rows[1:]:
        d = float(np.mean(r["errors"])) - allc
        parts.append(f"{r['label']}: {'+' if d >= 0 else ''}{d:.1f} mm")
    worse = all(float(np.mean(r["errors"])) >= allc for r in rows[1:4])
    fewer = _mean(rows, "half particles") >= allc and _mean(rows, "quarter particles") >= _mean(
        rows, "half particles"
    )
    return (
        f"Against all cues ({allc:.1f} mm): "
        + "; ".join(parts)
        + ". Li & Kulić report that every cue left out "
        f"raises the error and that fewer particles raise it (while cutting time): cue ordering "
        f"**{'holds' if worse else 'does not hold'}**, particle ordering **{'holds' if fewer else 'does not hold'}** "
        "here."
    )


def verdict_a(rows) -> str:
    m = {r["label"]: float(np.mean(r["errors"])) for r in rows}
    order = sorted(m, key=m.get)
    iros = m["iapf"] <= m["icondensation"] and m["apf"] <= m["sir"] and m["icondensation"] <= m["sir"]
    return (
        f"Ranking (lowest error first): {' < '.join(f'{k} {m[k]:.1f}' for k in order)}. IROS 2007's ordering "
        f"IAPF ≈ APF < ICONDENSATION < SIR at equal compute: **{'holds' if iros else 'does not hold'}** here "
        "(pairs closer than the std over seeds are ties)."
    )


def run(
    quick: bool = False,
    seeds: int = 5,
    only=("a", "b", "c"),
    frames: str = "150:270",
    size: str = "320x240",
    budget: int = 600,
    out: pathlib.Path | None = RESULTS,
    log=print,
    max_clips: int | None = None,
    filters: tuple[str, ...] | None = None,
    oracle: bool = False,
) -> str:
    """Run the tables; returns the markdown (and writes it to ``out`` unless ``None``). ``oracle``: track the
    rendered masks from the ground truth's first pose (module docstring)."""
    if quick:
        seeds, frames, size, budget = 1, "150:162", "160x120", 60
    t_start = time.monotonic()
    sections = []
    with tempfile.TemporaryDirectory() as tmp:
        work = pathlib.Path(tmp)
        seqs = make_sequences(work, frames, size, log, 1 if quick else max_clips)
        names = [n for n, _ in seqs]
        partial = pathlib.Path(str(out) + ".partial") if out is not None else None

        def emit(title, text):
            sections.append(f"## {title}\n\n{text}\n")
            if partial is not None:
                partial.write_text("\n".join(sections))

        def progress(rows):  # the rows so far, for a run cut short
            if partial is not None:
                partial.write_text(
                    "\n".join([*sections, "## (in progress)\n\n" + table_md(rows, names) + "\n"])
                )

        if "a" in only:
            cfgs = configs_a(budget)
            if quick:
                cfgs = [c for c in cfgs if c.filter == "sir"]
            elif filters:
                cfgs = [c for c in cfgs if c.filter in filters]
            rows = rows_a = run_table("a", cfgs, seqs, seeds, work, log, progress, oracle)
            text = table_md(rows, names)
            if not quick and {"sir", "icondensation", "apf", "iapf"} <= {r["config"].filter for r in rows}:
                text += "\n\n" + verdict_a(rows)
            emit(
                f"(a) Every filter at {budget} likelihood evaluations per frame (full25, {seeds} seeds × "
                f"{len(seqs)} clips)",
                text,
            )
        if "b" in only:
            cfgs = configs_b(20 if quick else 200)
            if quick:
                cfgs = cfgs[:1]
            if "a" in only and not quick and budget == 600 and not filters:
                rows = [
                    dict(r, label=r["label"].upper()) for r in rows_a if r["config"].filter in THESIS_FILTERS
                ]
            else:
                rows = run_table("b", cfgs, seqs, seeds, work, log, progress, oracle)
            text = table_md(rows, names)
            if not quick:
                text += "\n\n" + verdict_b(rows)
            emit(f"(b) Thesis Table 7.1 (full25, 2 views, {seeds} seeds × {len(seqs)} clips)", text)
        if "c" in only:
            cfgs = configs_c(0.05 if quick else 1.0)
            if quick:
                cfgs = cfgs[:1]
            rows = run_table("c", cfgs, seqs, seeds, work, log, progress, oracle)
            text = table_md(rows, names)
            if not quick:
                text += "\n\n" + verdict_c(rows)
            emit(
                f"(c) Li & Kulić Table I (full25, partitioned sampling, {seeds} seeds × {len(seqs)} clips)",
                text,
            )
    command = f"python {common.script(__file__)}" + (" --oracle" if oracle else "")
    inputs = (
        "rendered masks, initialised from the ground truth (oracle input)"
        if oracle
        else "silhouettes subtracted against the plates, initialised from the simulated detections"
    )
    head = (
        "# Tracking accuracy on synthetic sequences from real CMU motion capture\n\n"
        f"Generated by `{command}` ({common.stamp()}, "
        f"{time.monotonic() - t_start:.0f} s): source frames {frames} at 30 fps, {size}, stereo preset, "
        f"{inputs}. Error: thesis eq. 7.1 (mean 3D joint error, mm), "
        "mean ± std over runs (seeds × clips; per-clip columns over seeds). ms/frame: the compiled filter step "
        "(likelihood + resampling), median; feature extraction not included. See the module docstring for every "
        "choice.\n"
    )
    md = head + "\n" + "\n".join(sections)
    if out is not None:
        common.write_result(out, md, command)
        p = pathlib.Path(str(out) + ".partial")
        if p.exists():
            p.unlink()
    return md


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick", action="store_true", help="one seed, tiny images, few configurations; writes nothing"
    )
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--only", nargs="+", default=["a", "b", "c"], choices=["a", "b", "c"])
    ap.add_argument("--frames", default="150:270")
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--budget", type=int, default=600)
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--clips", type=int, default=None, help="use only the first N clips")
    ap.add_argument("--filters", nargs="+", default=None, help="table (a): only these filters")
    ap.add_argument(
        "--oracle",
        action="store_true",
        help="rendered masks and ground-truth initialisation (default: plates)",
    )
    a = ap.parse_args(argv)
    log = lambda s: print(s, file=sys.stderr, flush=True)  # noqa: E731
    md = run(
        a.quick,
        a.seeds,
        tuple(a.only),
        a.frames,
        a.size,
        a.budget,
        None if a.quick else pathlib.Path(a.out),
        log,
        a.clips,
        tuple(a.filters) if a.filters else None,
        a.oracle,
    )
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
