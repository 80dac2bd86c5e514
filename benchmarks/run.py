"""Run the benchmarks and regenerate ``benchmarks/RESULTS.md``; the register of every benchmark script.

    python benchmarks/run.py                     # every benchmark except the slow experiments; updates RESULTS.md
    python benchmarks/run.py --all               # also the slow experiments (accuracy tables, hybrid filters)
    python benchmarks/run.py --only end_to_end scaling
    python benchmarks/run.py --only parsec_track # a script that writes its own results file: runs its command
    python benchmarks/run.py --quick             # tiny sizes, every RESULTS.md benchmark (smoke test); writes nothing
    python benchmarks/run.py --quick --results /tmp/R.md   # … into another file
    python benchmarks/run.py --list              # every script and its command
    python benchmarks/run.py --index             # rewrite results/README.md: each results file and its command

:data:`SCRIPTS` registers every script under ``perf/`` (timed, against a baseline in the same process) and
``experiments/`` (accuracy tables, tracking experiments) with the command that runs it and the files under
``results/`` that command regenerates.

Each benchmark is a function ``(quick) -> markdown`` (a table, or the benchmark's printed report in a code block);
the numbers inside are medians over repeated runs after compilation, with ratios against baselines run in the same
process (see each module's docstring). ``RESULTS.md`` keeps its hand-written text: the runner only replaces what
lies between the markers ``<!-- generated:NAME begin -->`` and ``<!-- generated:NAME end -->`` (and appends a new
section when a benchmark has no markers yet). The ``machine`` block records the CPU model, cores, load average at
the start, versions and date of the last run.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import fnmatch
import importlib.util
import io
import os
import pathlib
import platform
import re
import shlex
import subprocess
import sys
import time
from collections.abc import Callable

os.environ.setdefault("JAX_PLATFORMS", "cpu")

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))  # benchmarks/: the shared modules
import common

HERE = common.BENCH
RESULTS = HERE / "RESULTS.md"
RESULTS_DIR = HERE / "results"


def load(name: str):
    """The module of the registered script ``name`` (see :data:`SCRIPTS`), imported from its file once."""
    stem = pathlib.Path(SCRIPTS[name].path).stem
    if stem not in sys.modules:
        spec = importlib.util.spec_from_file_location(stem, HERE / SCRIPTS[name].path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[stem] = module
        try:
            spec.loader.exec_module(module)
        except BaseException:
            del sys.modules[stem]
            raise
    return sys.modules[stem]


def _captured(fn: Callable, *args) -> str:
    """Run ``fn(*args)`` and return what it printed, in a code block (or its markdown return value)."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        ret = fn(*args)
    text = buf.getvalue().rstrip()
    if isinstance(ret, str) and ret.strip() and ret.strip() in text:
        return text
    return "```\n" + text + "\n```"


# ---------------------------------------------------------------------------------------------------------------
# The benchmarks


def _kinematics(quick: bool) -> str:
    m = load("kinematics")
    r = m.run(200, 2) if quick else m.run(4000, 7)
    return (
        f"`full25`, {r['points']} flesh points, {r['views']} views, {r['particles']} particles.\n\n"
        "| implementation | particles/s |\n|---|---|\n"
        f"| JAX (SoA FK, vmapped, one jit) | {r['jax_particles_per_s']:,.0f} |\n"
        f"| NumPy, same arithmetic vectorised over particles | {r['numpy_particles_per_s']:,.0f} |\n"
        f"| ratio | {r['ratio']:.1f}× |"
    )


def _parsec(quick: bool) -> str:
    m = load("parsec")
    argv = (
        ["--particles", "100", "--repeats", "2", "--numpy-repeats", "1", "--bodytrack-rounds", "0"]
        if quick
        else ["--repeats", "21"]
    )
    return _captured(m.main, m._args(argv))


def _features(quick: bool) -> str:
    m = load("features")
    return _captured(m.main, ["--repeats", "3" if quick else "60"])


def _render(quick: bool) -> str:
    m = load("render")
    return _captured(m.main, ["--quick", "--repeats", "2"] if quick else [])


def _synth(quick: bool) -> str:
    m = load("synth")
    return _captured(m.main, ["--frames", "120:128", "--size", "160x120"] if quick else [])


def _likelihood(quick: bool) -> str:
    return _captured(load("likelihood").main, ["--quick"] if quick else ["--per-cue", "--sweep"])


def _iros(quick: bool) -> str:
    m = load("iros")
    return _captured(m.main, ["--quick"] if quick else [])


def _foreground(quick: bool) -> str:
    m = load("foreground")
    frames, size = ("120:126", "160x120") if quick else ("120:180", "640x480")
    return m.to_markdown(m.evaluate(frames, size), frames, size)


def _hybrid(quick: bool) -> str:
    m = load("hybrid")
    return _captured(m.main, ["--quick"] if quick else [])


def _end_to_end(quick: bool) -> str:
    m = load("end_to_end")
    return m.to_markdown(m.run(quick))


def _scaling(quick: bool) -> str:
    m = load("scaling")
    md = m.main(["--quick"] if quick else [])
    return md if quick else md + "\n\n![likelihood scaling](results/scaling.png)"


def _accuracy(quick: bool) -> str:
    m = load("accuracy")
    log = lambda s: print(s, file=sys.stderr, flush=True)  # noqa: E731
    if quick:
        return m.run(quick=True, out=None, log=log)
    md = m.run(log=log)
    return "Full tables: [results/accuracy.md](results/accuracy.md).\n\n" + md.split("\n", 2)[2]


@dataclasses.dataclass(frozen=True)
class Script:
    """A script under ``benchmarks/``: ``path`` (relative to ``benchmarks/``) and the arguments of the command that
    runs it as measured; ``writes``: the files (glob patterns) under ``results/`` that this command regenerates;
    ``fn``: for the benchmarks reported in ``RESULTS.md``, ``(quick) -> markdown`` (the same measurement, run in
    this process); ``slow``: left out of a plain ``run.py`` (run with ``--all``); ``env``: variables the command
    sets."""

    title: str
    path: str
    args: str = ""
    writes: tuple[str, ...] = ()
    fn: Callable[[bool], str] | None = None
    slow: bool = False
    env: str = ""

    @property
    def command(self) -> str:
        """The command line, from the repository root."""
        words = [self.env, "python", f"benchmarks/{self.path}", self.args]
        return " ".join(w for w in words if w)


#: every script under perf/ and experiments/, by name
SCRIPTS: dict[str, Script] = {
    # perf/: timed, each against a baseline run in the same process
    "kinematics": Script("Forward kinematics + projection", "perf/bench_kinematics.py", fn=_kinematics),
    "likelihood": Script(
        "Likelihood throughput vs NumPy", "perf/bench_likelihood.py", "--per-cue --sweep", fn=_likelihood
    ),
    "parsec": Script("PARSEC bodytrack likelihood", "perf/bench_parsec.py", "--repeats 21", fn=_parsec),
    "features": Script("Image features", "perf/bench_features.py", "--repeats 60", fn=_features),
    "render": Script("Rendering", "perf/bench_render.py", fn=_render),
    "synth": Script("Synthetic sequences", "perf/bench_synth.py", fn=_synth),
    "end_to_end": Script("Frames per second end to end", "perf/end_to_end.py", fn=_end_to_end),
    "scaling": Script(
        "Likelihood scaling", "perf/scaling.py", writes=("scaling.md", "scaling.png"), fn=_scaling
    ),
    "vs_bodytrack": Script(
        "jaxmocap vs PARSEC bodytrack built from source: likelihood and tracker, interleaved, idle and loaded",
        "perf/vs_bodytrack.py",
        "--rounds 5 --auto-rounds --out benchmarks/results/vs_bodytrack.md",
        writes=("vs_bodytrack.md",),
    ),
    "instructions": Script(
        "Instructions per particle of PARSEC's likelihood, ours and bodytrack's (valgrind; load-independent)",
        "perf/instructions.py",
        "--out benchmarks/results/instructions.md",
        writes=("instructions.md",),
        slow=True,
    ),
    "scale": Script(
        "Scaling beyond one device (sharded particles, batched runs, memory)", "perf/bench_scale.py"
    ),
    "startup_ab": Script(
        "Start-up of new processes with a pinned dependency against another version of it",
        "perf/startup_ab.py",
        "--versions ml_dtypes==0.7.0 --rounds 5 --out benchmarks/results/startup_ab.md",
        writes=("startup_ab.md",),
        slow=True,
    ),
    "parsec_latency": Script(
        "First-frame latency of the PARSEC run, warm and cold, against bodytrack and a revision",
        "perf/parsec_latency.py",
        "--rounds 5 --against 9ca9ca5 --out benchmarks/results/parsec_latency.md",
        writes=("parsec_latency.md",),
        env="JAX_PLATFORMS=cpu",
        slow=True,
    ),
    "track_latency": Script(
        "Warm start of jaxmocap track and jaxmocap demo against a revision",
        "perf/track_latency.py",
        "--rounds 5 --against 2e0d2d5 --out benchmarks/results/track_latency.md",
        writes=("track_latency.md",),
        env="JAX_PLATFORMS=cpu",
        slow=True,
    ),
    "compile_partitions": Script(
        "Compile time of the partitioned / hierarchical step",
        "perf/compile_partitions.py",
        writes=("compile_partitions.md",),
    ),
    "compile_time": Script(
        "First-frame latency of jaxmocap track per model and filter family",
        "perf/compile_time.py",
        "--rounds 3 --out benchmarks/results/compile_time.md",
        writes=("compile_time.md",),
        slow=True,
    ),
    "compile_steps": Script(
        "Run time of the filter step per model and filter family",
        "perf/compile_time.py",
        "--steps --out benchmarks/results/compile_steps.md",
        writes=("compile_steps.md",),
        slow=True,
    ),
    "compile_tracks": Script(
        "Whole tracks per model and filter family (the results guard of the compile-time changes)",
        "perf/compile_time.py",
        "--tracks --seeds 0 1 2 --out benchmarks/results/compile_tracks.md",
        writes=("compile_tracks.md",),
        slow=True,
    ),
    "compile_programs": Script(
        "Compile time of the tracker's programs per model",
        "perf/compile_time.py",
        "--programs --isolate --out benchmarks/results/compile_programs.md",
        writes=("compile_programs.md",),
    ),
    "grad_cost": Script(
        "Value and gradient of the tracker's likelihood in forward evaluations (the gradient filters' cost)",
        "perf/grad_cost.py",
        "--models full25 upper14 --cues 'track default' 'keypoints + silhouette' foreground edge_distance "
        "coverage keypoints --rounds 7 --general --against b961c58 --out benchmarks/results/grad_cost.md",
        writes=("grad_cost.md",),
        slow=True,
    ),
    "profile_likelihood": Script(
        "Where the compiled likelihood spends its time", "perf/profile_likelihood.py"
    ),
    "refine_cost": Script(
        "Frames/s of the defaults with and without the refinement's depth term, and of the revision before it",
        "perf/track_rate.py",
        "--rounds 3 --busy --variant 'no depth:refine_depth=0' --against e683eeb "
        "--title 'the depth term of the refinement' --out benchmarks/results/refine_cost.md",
        writes=("refine_cost.md",),
        slow=True,
    ),
    "track_rate": Script(
        "Frames/s of the defaults (50 particles where the estimate is refined on three or more cameras) against the "
        "revision before",
        "perf/track_rate.py",
        "--frames 60 --rounds 5 --busy --against 7216380 "
        "--title '50 particles per layer where the estimate is refined on three or more cameras' "
        "--out benchmarks/results/track_rate.md",
        writes=("track_rate.md",),
        slow=True,
    ),
    "track_rate_iros2007": Script(
        "Frames/s of the IROS 2007 preset at 640x480 in the room, against the revision before the face search "
        "was bounded by each blob's depth",
        "perf/track_rate.py",
        "--preset iros2007 --rigs stereo --size 640x480 --fps 15 --background room --clutter medium "
        "--no-detections --frames 40 --rounds 5 --busy --variant 'features 640x480:downsample=1' "
        "--against 2ec851d "
        "--title 'the IROS 2007 preset, the face search bounded by each blob depth' "
        "--out benchmarks/results/track_rate_iros2007.md",
        writes=("track_rate_iros2007.md",),
        slow=True,
    ),
    "track_rate_full32": Script(
        "Frames/s of the full32 body (spine and shoulder girdles) beside the full25 default",
        "perf/track_rate.py",
        "--frames 60 --rounds 3 --busy --variant full32:model=full32 "
        "--title 'the full32 body beside the full25 default' --out benchmarks/results/track_rate_full32.md",
        writes=("track_rate_full32.md",),
        slow=True,
    ),
    "run_rate": Script(
        "Whole-run frames/s of a 3000-frame track against its step rate (the cost of the outputs)",
        "perf/run_rate.py",
        "--frames 3000 --size 160x120 --particles 100 --layers 3 --repeats 2",
        writes=("run_rate.md",),
        slow=True,
    ),
    # experiments/: accuracy tables over seeds, tracking experiments
    "iros": Script(
        "IROS 2007 synthetic experiment",
        "experiments/iros_synthetic.py",
        writes=("iros_synthetic.md",),
        fn=_iros,
    ),
    "iros2007": Script(
        "IROS 2007 end to end: --preset iros2007, SIR / ICONDENSATION / APF / IAPF on rendered CMU motions",
        "experiments/iros2007.py",
        "--runs 15 --frames 24",
        writes=("iros2007.md",),
        slow=True,
    ),
    "iros2007_ablation": Script(
        "IROS 2007 in clutter: the head found with and without the stereo gate, and the five-cue ablation",
        "experiments/iros2007.py",
        "--ablation --runs 2 --frames 20",
        writes=("iros2007_ablation.md",),
        slow=True,
    ),
    "iros2007_speed": Script(
        "IROS 2007 speed: --preset iros2007 frames/s at 640x480 and 160x120 (default) features, and its stages' times",
        "experiments/iros2007.py",
        "--speed --frames 40",
        writes=("iros2007_speed.md",),
        slow=True,
    ),
    "determinism": Script(
        "One seed tracked twice over 1500 frames in one process: identical poses",
        "experiments/determinism.py",
        "--frames 1500 --size 160x120",
        writes=("determinism.md",),
        slow=True,
    ),
    "foreground": Script(
        "Foreground IoU",
        "experiments/foreground_iou.py",
        "--frames 120:180 --size 640x480",
        writes=("foreground_iou.md",),
        fn=_foreground,
    ),
    "plate_subtraction": Script(
        "Background subtraction against the synthesiser's plates",
        "experiments/plate_subtraction.py",
        "--size 320x240",
        writes=("plate_subtraction.md",),
    ),
    "accuracy": Script(
        "Tracking accuracy", "experiments/accuracy.py", writes=("accuracy.md",), fn=_accuracy, slow=True
    ),
    "accuracy_default": Script(
        "jaxmocap track with its defaults on recording-like input, against triangulating the detections",
        "experiments/accuracy_default.py",
        "--seeds 5",
        writes=("accuracy_default.md",),
        slow=True,
    ),
    "li_kulic": Script(
        "Li & Kulic's tracker (--preset li-kulic): their errors, Table I, counts, ten partitions against six",
        "experiments/li_kulic.py",
        "--seeds 5 --size 320x240",
        writes=("li_kulic.md",),
        slow=True,
    ),
    "li_kulic_overlay": Script(
        "Li & Kulic's tracker on the walk with and without the edge cue: the last frame",
        "experiments/li_kulic.py",
        "--overlay",
        writes=("li_kulic_no_edges.png",),
    ),
    "lopez_mendez": Script(
        "López Méndez Tables 7.1-7.2 with --preset lopez-mendez (frontal-lateral, adaptive background)",
        "experiments/lopez_mendez.py",
        "--runs 5",
        writes=("lopez_mendez.md",),
        slow=True,
    ),
    "hybrid": Script(
        "Hybrid vs APF",
        "experiments/hybrid_vs_apf.py",
        writes=("hybrid_vs_apf.md", "hybrid_vs_apf.png"),
        fn=_hybrid,
        slow=True,
    ),
    "cue_sweeps": Script(
        "Each cue's energy over a grid of two DOFs around the truth",
        "experiments/cue_sweeps.py",
        writes=("cue_sweep_*.png",),
    ),
    "synth_montages": Script(
        "Montages of the synthetic sequences, one per rig preset",
        "experiments/make_synth_montages.py",
        writes=("synth_*.png",),
    ),
    "scene_montages": Script(
        "Montages of the textured subject in the 3D room: detections, plate, subtraction, depth, skin blobs",
        "experiments/make_scene_montages.py",
        writes=("scene_*.png",),
    ),
    "parsec_track": Script(
        "PARSEC sequenceB_2 tracked, against bodytrack",
        "experiments/parsec_track.py",
        "--seeds 3 --rounds 3 --report",
        writes=("parsec_track.md",),
        env="JAX_PLATFORMS=cpu",
    ),
    "parsec_overlay": Script(
        "PARSEC sequenceB_2 frame 1: the tracked model over the four cameras",
        "experiments/parsec_track.py",
        "--overlay benchmarks/results/parsec_overlay.png",
        writes=("parsec_overlay.png",),
        env="JAX_PLATFORMS=cpu",
    ),
    "smoothing": Script(
        "Exported-track error with and without Butterworth smoothing (the default cut-off)",
        "experiments/smoothing.py",
        "--seeds 3",
        writes=("smoothing.md",),
    ),
    "blender_bvh": Script(
        "Blender's BVH importer reads track.bvh: armature joints against the run's (needs Blender)",
        "experiments/blender_bvh.py",
        writes=("blender_bvh.md",),
    ),
    "run_pictures": Script(
        "The pictures of a tracked run: plots/ and the overlay montage",
        "experiments/run_pictures.py",
        writes=("run_*.png",),
    ),
    "pose2sim_track": Script(
        "Pose2Sim demo recording tracked from its project folder, against Pose2Sim's triangulation",
        "experiments/pose2sim_track.py",
        "--out /tmp/p2s --report",
        writes=("pose2sim.md", "pose2sim_overlay.png"),
        env="JAX_PLATFORMS=cpu",
    ),
    "shape_calibration": Script(
        "Body-shape calibration (lengths and radii) from the first frames, poses unknown: synthetic and Pose2Sim",
        "experiments/shape_calibration.py",
        "--rigs ring4 stereo --work /tmp/shape_calibration",
        writes=("shape_calibration.md",),
        env="JAX_PLATFORMS=cpu",
    ),
    "pose2sim_loo": Script(
        "Pose2Sim demo recording, leave one camera out: tracked from three, against their triangulation",
        "experiments/pose2sim_track.py",
        "--out /tmp/p2s_loo --leave-one-out --model full32",
        writes=("pose2sim_loo.md",),
        env="JAX_PLATFORMS=cpu",
    ),
    "pose2sim_loo_detector": Script(
        "Pose2Sim demo recording, leave one camera out, keypoints from the built-in detector",
        "experiments/pose2sim_track.py",
        "--out /tmp/p2s_loo_det --leave-one-out --detector",
        writes=("pose2sim_loo_detector.md",),
        env="JAX_PLATFORMS=cpu",
    ),
    "detector_pose2sim": Script(
        "The built-in 2D pose detector on the Pose2Sim recording: time, distance to OpenPose, tracking with it",
        "experiments/detector_pose2sim.py",
        "--out /tmp/det --track --report",
        writes=("detector_pose2sim.md",),
        env="JAX_PLATFORMS=cpu",
    ),
}

#: the benchmarks reported in RESULTS.md, run in this process by ``run.py``
BENCHMARKS: dict[str, Script] = {k: s for k, s in SCRIPTS.items() if s.fn is not None}

#: the files under results/ that no registered command writes as a whole, and what makes them
OTHER_RESULTS: dict[str, str] = {
    "vs_bodytrack_intel_avx512.md": "`python benchmarks/perf/vs_bodytrack.py --rounds 5 --auto-rounds` on an Intel "
    "Xeon (family 6, model 167) with AVX-512, 2026-12-01 19:19 UTC (kept beside `vs_bodytrack.md`, the latest CPU's)",
    "vs_bodytrack_epyc_avx2.md": "`python benchmarks/perf/vs_bodytrack.py --rounds 5 --auto-rounds --against "
    "9ca9ca5` on an AMD EPYC (family 25, model 17) whose AVX-512 was not exposed, 2026-12-01 08:36 UTC (kept "
    "beside `vs_bodytrack.md`, the latest CPU's)",
    "demo_table.txt": "`jaxmocap demo --out jaxmocap-demo` (copied from `jaxmocap-demo/`)",
    "demo_overlay.png": "`jaxmocap demo --out jaxmocap-demo` (copied from `jaxmocap-demo/`)",
    "likelihood.md": "notes on runs of `python benchmarks/perf/bench_likelihood.py` and "
    "`python benchmarks/perf/profile_likelihood.py` (each table names its command)",
    "scale.md": "notes; the tables are printed by `python benchmarks/perf/bench_scale.py` (its commands are in "
    "the section Measurements)",
    "gradients_shape_notebooks.md": "notes; numbers from `python benchmarks/experiments/hybrid_vs_apf.py`, "
    "`python benchmarks/perf/grad_cost.py` (its section's command), `jaxmocap track --filter hybrid` and the "
    "notebooks in `notebooks/`",
}


def made_by(name: str) -> str:
    """What makes the file ``results/<name>``: the registered commands that write it, or its entry of
    :data:`OTHER_RESULTS` (``""`` for an unknown file)."""
    makers = [f"`{s.command}`" for s in SCRIPTS.values() if any(fnmatch.fnmatch(name, w) for w in s.writes)]
    return "; ".join(makers) or OTHER_RESULTS.get(name, "")


def first_line(name: str) -> str:
    """The first line of the Markdown results file ``name``: an HTML comment naming what regenerates it (the
    scripts write the same line, :func:`common.regenerate_line`)."""
    makers = [s.command for s in SCRIPTS.values() if any(fnmatch.fnmatch(name, w) for w in s.writes)]
    if len(makers) == 1:
        return f"<!-- Regenerate: {makers[0]} -->"
    return f"<!-- Made by: {made_by(name).replace('`', '')} -->"


def results_index() -> str:
    """The text of ``results/README.md``: every file under ``results/`` with the command that regenerates it."""
    rows = []
    for f in sorted(p.name for p in RESULTS_DIR.iterdir() if p.is_file() and p.name != "README.md"):
        rows.append(f"| [{f}]({f}) | {made_by(f) or '**unknown**'} |")
    return (
        "# Results\n\n"
        "Every file here and the command that regenerates it, run from the repository root (this index is written "
        "by `python benchmarks/run.py --index`; `../RESULTS.md` holds the reports of `python benchmarks/run.py`).\n\n"
        "| file | made by |\n|---|---|\n" + "\n".join(rows) + "\n"
    )


def run_script(s: Script) -> int:
    """Run the command of a script that writes its own results (no ``fn``) in a child process; its exit status."""
    env = dict(os.environ, **dict(kv.split("=", 1) for kv in s.env.split()))
    argv = [sys.executable, str(HERE / s.path), *shlex.split(s.args)]
    return subprocess.run(argv, cwd=HERE.parent, env=env, check=False).returncode


# ---------------------------------------------------------------------------------------------------------------
# Machine, versions, RESULTS.md


def machine_block(load: tuple[float, float, float]) -> str:
    import cv2
    import jax
    import jaxlib
    import numpy as np

    from jaxmocap import host

    devices = ", ".join(sorted({f"{d.platform}" for d in jax.devices()}))
    return (
        f"Machine: {host.description()}, {os.cpu_count()} cores, load average at start {load[0]:.1f} / "
        f"{load[1]:.1f} / {load[2]:.1f} (1 / 5 / 15 min); JAX devices: {devices}.  \n"
        f"Versions: Python {platform.python_version()}, JAX {jax.__version__}, jaxlib {jaxlib.__version__}, "
        f"NumPy {np.__version__}, OpenCV {cv2.__version__}.  \n"
        f"Date: {common.stamp()}."
    )


def _markers(name: str) -> tuple[str, str]:
    return f"<!-- generated:{name} begin -->", f"<!-- generated:{name} end -->"


def update_block(text: str, name: str, body: str, title: str | None = None) -> str:
    """``text`` with the block ``name`` replaced by ``body`` (appended as a new ``## title`` section if absent)."""
    begin, end = _markers(name)
    block = f"{begin}\n{body.strip()}\n{end}"
    pat = re.compile(re.escape(begin) + r".*?" + re.escape(end), re.S)
    if pat.search(text):
        return pat.sub(lambda _m: block, text, count=1)
    sep = "" if text.endswith("\n\n") or not text else ("\n" if text.endswith("\n") else "\n\n")
    head = f"## {title}\n\n" if title else ""
    return f"{text}{sep}{head}{block}\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick", action="store_true", help="tiny sizes (smoke test); writes only with --results"
    )
    ap.add_argument("--only", nargs="+", metavar="NAME", help="run only these benchmarks (see --list)")
    ap.add_argument("--all", action="store_true", help="include the slow experiments")
    ap.add_argument(
        "--results", default=None, help=f"file to update (default {RESULTS.name}, not with --quick)"
    )
    ap.add_argument("--list", action="store_true", help="every script, its command, and what it writes")
    ap.add_argument("--index", action="store_true", help="rewrite results/README.md and exit")
    a = ap.parse_args(argv)
    if a.list:
        for k, b in SCRIPTS.items():
            where = ", ".join((["RESULTS.md"] if b.fn else []) + list(b.writes)) or "prints"
            print(f"{k:18s} {b.command}  [{where}]{'  (slow)' if b.slow else ''}")
        return 0
    if a.index:
        (RESULTS_DIR / "README.md").write_text(results_index())
        for p in sorted(RESULTS_DIR.glob("*.md")):  # the first line of each names what regenerates it
            if p.name != "README.md":
                lines = p.read_text().split("\n")
                keep = lines[1:] if lines[0].startswith(("<!-- Regenerate:", "<!-- Made by:")) else lines
                p.write_text("\n".join([first_line(p.name), *keep]))
        return 0
    unknown = [n for n in a.only or [] if n not in SCRIPTS]
    if unknown:
        ap.error(f"unknown benchmark(s) {', '.join(unknown)}; choose from {', '.join(SCRIPTS)}")
    own = [n for n in a.only or [] if n not in BENCHMARKS]  # scripts that write their own results
    if own and a.quick:
        ap.error(f"no quick mode for {', '.join(own)}: they run their full command")
    for n in own:
        print(f"== {n}: {SCRIPTS[n].command}", file=sys.stderr, flush=True)
        if run_script(SCRIPTS[n]) != 0:
            return 1
    if own and len(own) == len(a.only):
        return 0
    names = (
        [n for n in a.only if n in BENCHMARKS]
        if a.only
        else [k for k, b in BENCHMARKS.items() if a.all or a.quick or not b.slow]
    )
    out = pathlib.Path(a.results) if a.results else (None if a.quick else RESULTS)
    load = os.getloadavg()

    def write_block(name: str, body: str, title: str | None = None) -> None:
        # re-read before every write: another run (--only …) may have updated other blocks meanwhile
        if out is not None:
            text = out.read_text() if out.exists() else "# Benchmark results\n"
            out.write_text(update_block(text, name, body, title))

    write_block("machine", machine_block(load))
    failed = []
    for name in names:
        b = BENCHMARKS[name]
        print(f"== {name}: {b.title}", file=sys.stderr, flush=True)
        t0, la = time.monotonic(), os.getloadavg()[0]
        try:
            md = b.fn(a.quick)
        except Exception as e:  # keep going: one broken benchmark must not lose the others' results
            failed.append(name)
            md = f"**failed**: `{type(e).__name__}: {e}`"
            print(f"   {name} failed: {type(e).__name__}: {e}", file=sys.stderr, flush=True)
        dt = time.monotonic() - t0
        stamp = (
            f"_Generated {common.stamp()} by `python benchmarks/run.py --only "
            f"{name}{' --quick' if a.quick else ''}` (same as `{b.command}`), load average {la:.1f} at "
            f"start, {dt:.0f} s._"
        )
        print(md, flush=True)
        write_block(name, stamp + "\n\n" + md, b.title)  # after every benchmark: an interrupted run keeps it
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
