"""PARSEC bodytrack (unmodified C++, Apache-2.0) built from source and run beside jaxmocap's benchmarks.

``build()`` runs ``make -C $BODYTRACK_SRC OUT=<repo>/build/bodytrack`` (``BODYTRACK_SRC`` default
``/work/shared/parsec/bodytrack``: its README and Makefile; ``build/`` is git-ignored); ``bodytrack_likelihood``
runs its ``ll_bench`` (``TrackingModel::LogLikelihood`` alone), ``bodytrack_frames`` its serial tracker with
per-frame times; ``busy()`` starts a CPU-bound child process for the loaded rounds; ``label`` names a round idle
only when the 1-minute load average is below 1.0.
"""

from __future__ import annotations

import contextlib
import json
import os
import pathlib
import subprocess
import sys
import time

import common
import numpy as np

SRC = pathlib.Path(os.environ.get("BODYTRACK_SRC", "/work/shared/parsec/bodytrack"))
SEQ = pathlib.Path(os.environ.get("JAXMOCAP_DATA", "/work/shared/data")) / "parsec" / "sequenceB_2"
BUILD = common.ROOT / "build" / "bodytrack"
#: the two conditions of every round: nothing added to the machine, and one busy-loop process started by us
CONDITIONS = ("as found", "+1 busy process")


def build(out: pathlib.Path = BUILD) -> pathlib.Path:
    """Build bodytrack's serial tracker and ``ll_bench`` into ``out`` (make skips what exists); returns ``out``."""
    if not (SRC / "Makefile").is_file():
        raise SystemExit(f"error: no bodytrack sources at {SRC} (set BODYTRACK_SRC)")
    targets = [str(out / exe) for exe, _, _ in MODELS.values()] + [str(out / "ll_bench")]
    subprocess.run(["make", "-C", str(SRC), f"OUT={out}", *targets], check=True, stdout=subprocess.DEVNULL)
    return out


@contextlib.contextmanager
def busy(on: bool):
    """While active (if ``on``): one CPU-bound child process, killed on exit."""
    if not on:
        yield
        return
    p = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.5)  # let it reach the run queue
        yield
    finally:
        p.kill()
        p.wait()


def bodytrack_likelihood(particles: int, repeats: int, out: pathlib.Path = BUILD) -> dict:
    """``ll_bench``'s report: ``us_median`` (wall µs per particle), ``cpu_us_median``, ``valid``, ``mean_ll``."""
    r = subprocess.run(
        [str(out / "ll_bench"), str(SEQ), str(particles), str(repeats)],
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(r.stdout.strip().splitlines()[-1])


#: bodytrack's builds: executable and thread-model arguments (4 = serial; 2 = pthreads, 2 threads)
MODELS = {"serial": ("bodytrack-serial", "4", "1"), "pthreads": ("bodytrack-pthreads", "2", "2")}


def bodytrack_frames(
    particles: int, layers: int, frames: int = 2, model: str = "serial", out: pathlib.Path = BUILD
) -> list[float]:
    """Seconds per frame of bodytrack's ``model`` build (:data:`MODELS`): intervals between its "Processing frame"
    lines (the last frame ends when the process exits)."""
    exe, tm, nt = MODELS[model]
    argv = [str(out / exe), str(SEQ), "4", str(frames), str(particles), str(layers), tm, nt, "0"]
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=out)
    stamps = []
    for line in p.stdout:
        if line.startswith("Processing frame"):
            stamps.append(time.perf_counter())
    p.wait()
    end = time.perf_counter()
    if p.returncode != 0 or len(stamps) != frames:
        raise RuntimeError(f"bodytrack-serial failed (exit {p.returncode}, {len(stamps)} frames)")
    return list(np.diff([*stamps, end]))


def cpu() -> str:
    for line in (
        pathlib.Path("/proc/cpuinfo").read_text().splitlines() if os.path.exists("/proc/cpuinfo") else []
    ):
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "CPU"


def label(load: float) -> str:
    return "idle" if load < 1.0 else f"loaded ({load:.1f})"


def side_by_side(jobs: dict, rounds: int, log=print) -> list[dict]:
    """Interleaved A/B: ``jobs`` maps a measurement name to ``(bodytrack_fn, jaxmocap_fn)``, each ``() -> float``
    (or both ``() -> {measurement: float}`` with the same keys, several measurements of one call).
    Every round runs both conditions of :data:`CONDITIONS` (the second with :func:`busy`), in each every
    measurement's two functions, alternating which goes first. Returns dicts ``round, condition, load (1-min load
    average at the start of the condition), what, bodytrack, jaxmocap``."""
    rows = []
    for r in range(rounds):
        for ci, cond in enumerate(CONDITIONS):
            with busy(ci > 0):
                load = os.getloadavg()[0]
                order = (0, 1) if (r + ci) % 2 == 0 else (1, 0)
                for what, fns in jobs.items():
                    v = [{}, {}]
                    for i in order:
                        got = fns[i]()
                        v[i] = got if isinstance(got, dict) else {what: got}
                    for w in v[0]:
                        b, j = v[0][w], v[1][w]
                        rows.append(dict(round=r, condition=cond, load=load, what=w, bodytrack=b, jaxmocap=j))
                        log(
                            f"round {r} {cond:16s} load {load:5.2f} {w:34s} bodytrack {b:8.4f} "
                            f"jaxmocap {j:8.4f} ratio {b / j:5.2f}"
                        )
    return rows


def table(rows: list[dict]) -> str:
    """Markdown: the median ratio (bodytrack / jaxmocap, above 1 = jaxmocap faster) per measurement and
    condition with every round's ratio, then every round with its load and state (idle only below load 1.0)."""
    lines = [
        "Ratio = bodytrack / jaxmocap (above 1: jaxmocap faster), interleaved A/B per round. A round is *idle* "
        "only if the 1-min load average is below 1.0.",
        "",
        "| measurement | condition | rounds | load (min–max) | bodytrack (median) | jaxmocap (median) | "
        "ratio per round | median ratio |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for what in dict.fromkeys(r["what"] for r in rows):
        for cond in CONDITIONS:
            sel = [r for r in rows if r["what"] == what and r["condition"] == cond]
            if not sel:
                continue
            loads = [r["load"] for r in sel]
            ratios = [r["bodytrack"] / r["jaxmocap"] for r in sel]
            lines.append(
                f"| {what} | {cond} | {len(sel)} | {min(loads):.1f}–{max(loads):.1f} | "
                f"{np.median([r['bodytrack'] for r in sel]):.4g} | {np.median([r['jaxmocap'] for r in sel]):.4g} | "
                f"{', '.join(f'{x:.2f}' for x in ratios)} | **{np.median(ratios):.2f}** |"
            )
    lines += [
        "",
        "| round | condition | load (1 min) | state | measurement | bodytrack | jaxmocap | ratio |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['round']} | {r['condition']} | {r['load']:.2f} | {label(r['load'])} | {r['what']} | "
            f"{r['bodytrack']:.4g} | {r['jaxmocap']:.4g} | {r['bodytrack'] / r['jaxmocap']:.2f} |"
        )
    return "\n".join(lines) + "\n"
