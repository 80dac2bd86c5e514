"""López Méndez (2009) Tables 7.1–7.2 with ``--preset lopez-mendez``: APF, M-APF, FBAPF, FBAPF2, FBAPF3 and
APFdivergence on synthetic frontal-lateral sequences from real motion capture, read as a recording.

Scenario (every choice stated here):

* motions with arm work: the CMU Charleston dance (arms swinging), Bandai-Namco's "raise up left hand" and the
  CMU walk 02_01 (arm swing) — the thesis' reaching / picking up / drinking clips are not in the project's data;
  30 frames at 30 fps of each (the dance and the walk: source frames 150:270 at 120 fps; the hand: 12:42 of its 55
  frames at 30 fps, the raise and the lowering), rendered by
  :func:`jaxmocap.synth.generate.synthesize` with the ``frontal-lateral`` rig at ``--size`` (default 160×120: the
  machine is 2 shared cores) in the 3D room (the body casts its shadow), low clutter, a ±10 % illumination change,
  motion blur over 2 source frames, sensor noise 0.01;
* the input a recording gives (:class:`scenes.RecordingSource`): the images, the empty-scene plates and the
  simulated BODY_25B detections; the silhouettes come from the tracker's ``--foreground adaptive`` (eq. 4.1–4.2
  with shadow removal, started from the plates), the first pose from inverse kinematics on the detections; no rendered mask or ground
  truth enters a run;
* the tracker exactly as ``jaxmocap track --preset lopez-mendez --filter SCHEME`` runs it (``upper9``, 200
  particles × 3 layers, the scheme's cues and λ table: :mod:`jaxmocap.tracking.presets.lopez_mendez`), each
  scheme compiled once per sequence and run with ``--runs`` seeds (thesis: 5);
* error of a run: thesis eq. 7.1 (mean 3D joint error over the evaluation joints of ``upper9``) averaged over the
  frames, eq. 7.2; per sequence μ and σ over the runs (eq. 7.3: σ of the per-run means);
* mode counts: one extra run (seed 0) of APF and FBAPF per sequence with ``count_modes`` (EM/BIC on the first two
  principal components of each layer's resampled set, :func:`jaxmocap.eval.mixtures.count_layer_modes`): the mean
  count per layer over the frames;
* speed: frames/s of the compiled step (median step time) and of the whole run (reading, features, step, outputs).

The thesis' numbers of Tables 7.1–7.2 are not recorded in this project, so the table has no column of them; the
claims are checked on the numbers measured here.

    .venv/bin/python benchmarks/experiments/lopez_mendez.py [--runs 5] [--quick]

Writes ``benchmarks/results/lopez_mendez.md`` (not with ``--quick``: 1 sequence, 8 frames, 2 runs, 3 schemes).
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
from scenes import MOCAP, CachedTracker, RecordingSource

from jaxmocap.io.sources import SequenceSource
from jaxmocap.synth import generate as synth
from jaxmocap.tracking.options import TrackOptions

RESULTS = common.RESULTS / "lopez_mendez.md"
SCHEMES = ("apf", "m-apf", "fbapf", "fbapf2", "fbapf3", "apf-divergence")
LABELS = dict(zip(SCHEMES, ("APF", "M-APF", "FBAPF", "FBAPF2", "FBAPF3", "APFdivergence"), strict=True))
RENDER = dict(background="room", clutter="low", illumination=0.1, blur=2, noise=0.01)


def clips() -> list[tuple[str, object, dict]]:
    """``(name, motion, synthesize keywords)`` of the motions used (those whose files are present)."""
    out = []
    dance = MOCAP / "cmu" / "charleston1.amc"
    if dance.is_file():
        out.append(("charleston", dance, dict(asf=MOCAP / "cmu" / "charleston.asf", frames="150:270")))
    hand = MOCAP / "bandai" / "dataset-2_raise-up-left-hand_normal_001.bvh"
    if hand.is_file():
        out.append(("raise left hand", hand, dict(frames="12:42")))
    out.append(("walk 02_01", "demo", dict(frames="150:270")))
    return out


def run_scheme(seq: pathlib.Path, scheme: str, runs: int, work: pathlib.Path, particles: int) -> dict:
    """Per-run errors (mm), median and 10th-percentile step times, whole-run frames/s of ``scheme`` on ``seq``."""
    source = RecordingSource(seq)
    try:
        o = TrackOptions.from_preset(
            "lopez-mendez", filter=scheme, init="ik", particles=particles, overwrite=True, smooth="none"
        )
        tr = CachedTracker(source, work / "track", o, quiet=True)
        errors, summaries, _ = tr.run_seeds(runs, seq)
        fps = [r.get("frames_per_s") or float("nan") for r in summaries]
        steady = tr.step_seconds[1:] or tr.step_seconds
        return {
            "errors": errors,
            "step_s": tr.median_step_s,
            "step_p10_s": float(np.percentile(steady, 10)),
            "run_fps": float(np.median(fps)),
        }
    finally:
        source.close()


def mode_counts(seq: pathlib.Path, scheme: str, work: pathlib.Path, particles: int) -> np.ndarray:
    """Mean mode count per layer over the frames of one run (seed 0) with ``count_modes``."""
    import json

    source = RecordingSource(seq)
    try:
        o = TrackOptions.from_preset(
            "lopez-mendez", filter=scheme, init="ik", particles=particles, overwrite=True, smooth="none",
            count_modes=True,
        )  # fmt: skip
        out = work / "modes"
        CachedTracker(source, out, o, quiet=True).run()
        recs = json.loads((out / "diagnostics.json").read_text(encoding="utf-8"))["frames"]
        return np.mean([r["modes"] for r in recs if "modes" in r], axis=0)
    finally:
        source.close()


#: what the table shows about the divergence on these sequences (written for the measured table)
READING = (
    "Reading: these sequences render the whole body, and the divergence (eq. 4.6) counts the legs' pixels too, "
    "which `upper9` has no part to cover, so it can pull the upper body down into them (the slide `accuracy.md` "
    "reports for `upper9` on full-body input); the thesis' cameras framed the upper body. With the adaptive "
    "background started from the recorded plates no scheme loses the track here; started from the median of the "
    "frames (the plates unused) the divergence schemes lost it on the walk (350–520 mm)."
)


def _claim(ok: bool) -> str:
    return "**holds**" if ok else "**does not hold**"


def report(res: dict, modes: dict, args, elapsed: float) -> str:
    names = list(res)
    lines = [
        f"<!-- Regenerate: python benchmarks/experiments/lopez_mendez.py --runs {args.runs} -->",
        "# López Méndez (2009) Tables 7.1–7.2 with `--preset lopez-mendez`",
        "",
        f"Command: `python benchmarks/experiments/lopez_mendez.py --runs {args.runs}` (every choice is in its module "
        f"docstring), on the 2-core CPU shared with other jobs (load average {args.load[0]:.1f} at the start, "
        f"{args.load[1]:.1f} at the end), {time.strftime('%Y-%m-%d')}, {elapsed / 60:.0f} min. "
        f"Sequences: {len(names)} motion(s), frontal-lateral rig, {args.size} px (small: the machine is 2 shared "
        f"cores), {args.frames_out} frames at 30 fps each, room with the body's shadow, low clutter, ±10 % "
        "illumination, motion blur; input as recorded (adaptive background subtraction with shadow removal, IK "
        f"start from simulated detections; no rendered masks, no ground truth). {args.particles} particles × 3 "
        f"layers, **{args.runs} runs per scheme** (thesis: 5). Error: eq. 7.1 averaged over frames (eq. 7.2), "
        "μ ± σ over runs (eq. 7.3), mm.",
        "",
        "The thesis' Table 7.1 / 7.2 values are not recorded in this project: the claims below are checked on the "
        "numbers measured here only.",
        "",
        "## Table 7.1 (APF, M-APF, FBAPF, FBAPF2, FBAPF3) and Table 7.2 (APFdivergence)",
        "",
        "| scheme | " + " | ".join(names) + " | all | step frames/s | run frames/s |",
        "|---|" + "---|" * (len(names) + 3),
    ]
    schemes = [s for s in SCHEMES if s in res[names[0]]]
    allm = {}
    for s in schemes:
        cells = []
        every = []
        for n in names:
            e = np.asarray(res[n][s]["errors"])
            every.extend(e.tolist())
            cells.append(f"{e.mean():.1f} ± {e.std():.1f}")
        allm[s] = (float(np.mean(every)), float(np.mean([np.std(res[n][s]["errors"]) for n in names])))
        step = np.median([1.0 / res[n][s]["step_s"] for n in names])
        fast = np.median([1.0 / res[n][s]["step_p10_s"] for n in names])
        run = np.median([res[n][s]["run_fps"] for n in names])
        lines.append(
            f"| {LABELS[s]} | "
            + " | ".join(cells)
            + f" | **{allm[s][0]:.1f}** | {step:.0f} ({fast:.0f}) | {run:.0f} |"
        )
    lines += [
        "",
        '"all": the mean over sequences and runs. σ in the claims: the mean over sequences of the per-sequence σ.',
        "",
    ]
    if "walk 02_01" in names:
        lines += [READING, ""]
    if {"apf", "fbapf", "fbapf2", "fbapf3"} <= set(allm):
        fb = {s: allm[s] for s in ("fbapf", "fbapf2", "fbapf3")}
        best = min(fb, key=lambda s: fb[s][0])
        lines.append("## Claims")
        lines.append("")
        mean_ok = all(v[0] < allm["apf"][0] for v in fb.values())
        sd_ok = all(v[1] < allm["apf"][1] for v in fb.values())
        lines.append(
            f"* Feature-based annealing beats classical annealing in mean: {_claim(mean_ok)} (APF "
            f"{allm['apf'][0]:.1f}; " + ", ".join(f"{LABELS[s]} {v[0]:.1f}" for s, v in fb.items()) + " mm)."
        )
        lines.append(
            f"* … and in σ: {_claim(sd_ok)} (APF {allm['apf'][1]:.1f}; "
            + ", ".join(f"{LABELS[s]} {v[1]:.1f}" for s, v in fb.items())
            + " mm)."
        )
        if "apf-divergence" in allm:
            a, d, f = allm["apf"][0], allm["apf-divergence"][0], allm["fbapf"][0]
            part = d < a and f < a
            lines.append(
                f"* Part of the gain comes from the divergence (APF > APFdivergence > FBAPF): "
                f"{_claim(part and f <= d)} (APF {a:.1f}, APFdivergence {d:.1f}, FBAPF {f:.1f} mm)."
            )
        if "m-apf" in allm:
            lines.append(
                f"* M-APF below APF: {_claim(allm['m-apf'][0] < allm['apf'][0])} "
                f"(M-APF {allm['m-apf'][0]:.1f}, APF {allm['apf'][0]:.1f} mm)."
            )
        worst = max(fb, key=lambda s: fb[s][0])
        lines.append(
            f"* FBAPF3 is the worst of the three feature-based schemes: {_claim(worst == 'fbapf3')} (worst: "
            f"{LABELS[worst]}; best: {LABELS[best]})."
        )
        lines.append("")
    if modes:
        lines += [
            "## Modes per layer (EM/BIC, mean over the frames of one run, seed 0)",
            "",
            "| sequence | scheme | layer 0 | layer 1 | layer 2 |",
            "|---|---|---|---|---|",
        ]
        for (n, s), m in modes.items():
            lines.append(f"| {n} | {LABELS[s]} | " + " | ".join(f"{v:.2f}" for v in m) + " |")
        a = np.mean([m for (n, s), m in modes.items() if s == "apf"], axis=0)
        f = np.mean([m for (n, s), m in modes.items() if s == "fbapf"], axis=0)
        lines += [
            "",
            f"* Feature-based annealing reduces multimodality (fewer modes in the last layer, FBAPF against APF): "
            f"{_claim(f[-1] < a[-1])} (last layer {f[-1]:.2f} against {a[-1]:.2f}; first layer {f[0]:.2f} against "
            f"{a[0]:.2f}).",
            "",
        ]
    lines += [
        "Speed: the thesis tracks at 9.5 frames/s with capture; this project's goal is ≥ 60 frames/s on the 2-core "
        "CPU. Step frames/s: the compiled filter step alone (median; in brackets at the 10th percentile of the step "
        "times, what the step runs at when the shared machine lets it); run frames/s: the whole run (reading, "
        "adaptive background, edges, skin, step, outputs), median over runs, at this image size; each the median "
        "over the sequences.",
        "",
    ]
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--particles", type=int, default=200)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-modes", action="store_true", help="skip the mode-count runs")
    args = ap.parse_args(argv)
    cl = clips()
    schemes = SCHEMES
    if args.quick:
        args.runs, args.size, args.particles = 2, "96x72", 60
        cl, schemes = cl[-1:], ("apf", "fbapf", "apf-divergence")
    t0, load0 = time.monotonic(), os.getloadavg()[0]
    res, modes = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        work = pathlib.Path(tmp)
        for name, motion, kw in cl:
            seq = work / name.replace(" ", "_")
            kw = dict(kw)
            if args.quick:
                a = int(kw["frames"].split(":")[0])
                kw["frames"] = f"{a}:{a + (32 if motion == 'demo' else 8)}"
            synth.synthesize(
                motion, seq, rig="frontal-lateral", fps=30.0, size=args.size, seed=0, overwrite=True,
                detections=True, **RENDER, **kw,
            )  # fmt: skip
            args.frames_out = SequenceSource(seq).num_frames
            res[name] = {}
            for s in schemes:
                t = time.monotonic()
                res[name][s] = r = run_scheme(seq, s, args.runs, work, args.particles)
                e = np.asarray(r["errors"])
                print(
                    f"{name:16s} {LABELS[s]:14s} {e.mean():7.1f} ± {e.std():5.1f} mm  step {1 / r['step_s']:6.0f} "
                    f"f/s  run {r['run_fps']:5.0f} f/s  ({time.monotonic() - t:.0f} s)",
                    flush=True,
                )
            if not args.no_modes:
                for s in ("apf", "fbapf"):
                    modes[(name, s)] = mode_counts(seq, s, work, args.particles)
                    print(
                        f"{name:16s} {LABELS[s]:14s} modes per layer {np.round(modes[(name, s)], 2)}",
                        flush=True,
                    )
    args.load = (load0, os.getloadavg()[0])
    md = report(res, modes, args, time.monotonic() - t0)
    print(md)
    if not args.quick:
        RESULTS.write_text(md, encoding="utf-8")
        print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
