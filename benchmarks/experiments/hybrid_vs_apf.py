"""At equal wall time, does the hybrid (gradient) annealed particle filter beat the plain APF? Mean joint error
against wall time per frame, on synthetic sequences of real motions, with realistic input.

Scenario (all choices stated here):

* clips (:data:`CLIPS`): 30 frames at 30 fps (120 source frames at 120 fps, every 4th) of four real CMU motions:
  the bundled walk 02_01, the Charleston dance and two stretches of 131_03 (a turn of about 300° while stepping,
  two-footed hops) from ``../shared/data/mocap/cmu``; each rendered once by
  :func:`jaxmocap.synth.generate.synthesize` with the ``ring4`` rig (four cameras around the subject) at 320×240,
  photo backgrounds, sensor noise 0.01, rendering seed 0;
* input (the default; realistic): features by the project's pipeline
  (:class:`jaxmocap.features.pipeline.FeatureExtractor`): static background subtraction against each view's
  empty-scene plate (``views/<camera>/background.png``, the background with one exposure's sensor noise, as a
  recording's), Canny edges and their distance transform; both filters start from the IK state of frame 0 fitted
  to the simulated BODY_25B detections of the four views (:func:`jaxmocap.tracking.init.keypoint_pose`). No
  ground-truth pose, rendered mask or part label reaches a filter. ``--oracle`` (clean rendered backgrounds, a
  ground-truth start) prints its tables and writes nothing;
* likelihood: ``foreground`` and ``edge_distance`` (σ_e = 6 px), both with bilinear lookups (differentiable), on the
  ``full25`` model with the subject's dimensions (the sequence's ``body.toml``), 400 surface points, particles
  evaluated in one ``vmap`` (``chunk_size=0``), gradients by ``Likelihood.batch_value_and_grad``;
* motion model (a random walk): Δ = the root-mean-square frame-to-frame change of each state entry, measured on the
  IK fit of the clip's ground truth (:func:`jaxmocap.fit.ik.fit_sequence`), floored at 0.5 cm / 0.01 rad;
  the initial particle spread Δ / 2;
* filters (:data:`SPECS`; Deutscher's survival-rate rule α = 0.5, diffusion scales ``0.6^l``):
  APF with L = 4 layers, N = 25 … 800 particles per layer; hybrid (:class:`jaxmocap.filters.hybrid.HybridAPF`
  with :class:`~jaxmocap.filters.hybrid.GradientMove`: S = 3 normalised gradient steps of one diffusion std on the
  k = 5 best distinct particles) in every layer of 4, N = 10 … 50; the "refined" variant (the plain APF + 10 Adam
  steps of 0.3 diffusion std from the weighted mean, :meth:`HybridAPF.refined`), N = 25 … 100; variants that
  spend fewer gradient evaluations: the moves in the last layer only (of 4), N = 25 … 100; 2 layers with moves in
  both, N = 50 … 200; S = 1 step in every layer of 4, N = 25, 50, and S = 2, N = 25;
* seeds: every configuration runs with filter seeds ``0 … --seeds − 1`` (default 5) on every clip;
* error of a run: mean over frames and the 15 evaluation joints of the Euclidean distance between the model's joints
  at the estimate and the ground truth (mm);
* wall time: one compiled program per configuration tracks the whole clip (``lax.scan`` over frames, features
  computed beforehand, the same for every filter); its wall time (after an untimed call that compiles it) ÷ the
  number of frames is the run's time per frame. The runs are interleaved: for every clip and seed, every
  configuration runs once, in an order rotated by the seed, so that a load change on the shared machine affects
  all alike; the load average is recorded at every run. Each clip's runs run in a process of their own (a child
  of the script: one process that had compiled the programs of two clips ran out of memory maps in LLVM). A
  configuration's time is the median over all its runs (every clip and seed: the work per frame does not depend
  on the clip);
* the cost of a value-and-gradient evaluation over a forward evaluation (vmapped, the same particles) is measured
  in each clip's process (:func:`gradient_cost_ratio`, at 200 and at 5 particles).

The two questions, for every APF configuration (time ``t``, error ``e``): does a hybrid configuration with a time
≤ t / 2 reach an error ≤ e? Which hybrid configuration with a time ≤ t has the lowest error, and is it lower than
e? ("hybrid" here: every gradient configuration, variants included; choosing the lowest of several noisy means
favours the hybrid.)

Every run is saved under ``--work`` as soon as it ends (one JSON file per clip, configuration and seed), and the
results file is rewritten after every clip: a rerun with the same ``--work`` resumes where the last one stopped;
``--report`` rewrites the results file from the saved runs alone.

Usage::

    python benchmarks/experiments/hybrid_vs_apf.py [--seeds 5] [--work DIR]   # writes results/hybrid_vs_apf.{md,png}
    python benchmarks/experiments/hybrid_vs_apf.py --quick    # 1 clip, 10 frames, 1 seed, APF and hybrid; writes nothing
    python benchmarks/experiments/hybrid_vs_apf.py --report   # the results file from the runs saved under --work
    python benchmarks/experiments/hybrid_vs_apf.py --oracle   # clean backgrounds, ground-truth start; prints only
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time
from typing import NamedTuple

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import common
import jax
import jax.numpy as jnp
import numpy as np
from scenes import MOCAP

from jaxmocap import compilation_cache
from jaxmocap.features.pipeline import FeatureConfig, FeatureExtractor
from jaxmocap.filters import base
from jaxmocap.filters.annealing import Schedule
from jaxmocap.filters.apf import APF
from jaxmocap.filters.hybrid import GradientMove, HybridAPF
from jaxmocap.fit import ik
from jaxmocap.geometry import body
from jaxmocap.io import sequence as seqio
from jaxmocap.io.subject import load_subject
from jaxmocap.likelihood import compose as L
from jaxmocap.likelihood.gradients import batch_value_and_grad
from jaxmocap.synth import generate as synth
from jaxmocap.synth import plates
from jaxmocap.tracking.init import keypoint_pose

KEY_IMPL = "rbg"
RESULTS = common.RESULTS / "hybrid_vs_apf.md"
CMU = MOCAP / "cmu"
#: (name, motion, asf, first source frame): 4 · frames source frames from there (120 fps → 30 fps)
CLIPS = (
    ("walk 02_01", "demo", None, 150),
    ("charleston", CMU / "charleston1.amc", CMU / "charleston.asf", 150),
    ("turn 131_03", CMU / "131_03.bvh", None, 780),
    ("hops 131_03", CMU / "131_03.bvh", None, 420),
)
SURVIVAL = 0.5


class Spec(NamedTuple):
    """One filter configuration (hashable: the compiled program's static argument). ``family``: ``"APF"``,
    ``"hybrid"`` (moves in ``move_layers``, None: every layer) or ``"refined"``."""

    family: str
    particles: int
    layers: int = 4
    move_layers: tuple | None = None
    best_k: int = 5
    steps: int = 3

    @property
    def group(self) -> str:
        """The curve a configuration belongs to (the tables' and the figure's series)."""
        if self.family != "hybrid":
            return self.family if self.layers == 4 else f"{self.family} L={self.layers}"
        steps = "" if self.steps == 3 else f" S={self.steps}"
        if self.move_layers == (self.layers - 1,):
            return f"hybrid{steps}, last layer of {self.layers}"
        return f"hybrid{steps}" if self.layers == 4 else f"hybrid{steps} L={self.layers}"

    @property
    def label(self) -> str:
        return f"{self.group} N={self.particles}"

    def evaluations(self) -> tuple[int, int]:
        """``(likelihood, gradient)`` evaluations per frame."""
        if self.family == "APF":
            return self.particles * self.layers, 0
        e = build(self, lambda X, o, l: X[:, 0], jnp.ones(1), None, None).evaluations()
        return e["likelihood"], e["gradient"]


#: the sweep (see the module docstring)
SPECS = (
    *(Spec("APF", n) for n in (25, 50, 100, 200, 400, 800)),
    *(Spec("hybrid", n) for n in (10, 25, 50)),
    *(Spec("refined", n) for n in (25, 50, 100)),
    *(Spec("hybrid", n, move_layers=(3,)) for n in (25, 50, 100)),
    *(Spec("hybrid", n, layers=2) for n in (50, 100, 200)),
    *(Spec("hybrid", n, steps=1) for n in (25, 50)),
    Spec("hybrid", 25, steps=2),
)
QUICK_SPECS = (Spec("APF", 25), Spec("hybrid", 10))
#: what the tables show (written for the run of 2026-11-29 15:56 UTC, 5 seeds; a rerun keeps it: rewrite it then)
READING = (
    "Reading (written for the run of 2026-11-29 15:56 UTC, after the faster gradient path of 6fc9aa2; every time "
    "is 1.5–1.8× that of the run of 2026-11-25, APF N = 200 31.7 against 20 ms per frame: the machine was "
    "slower that day and shared). At 17 ms per frame and more, yes: the hybrid with S = 3 steps on the 5 best "
    "particles in every layer has 85.5 / 83.0 / 81.3 mm pooled at 27.6 / 30.9 / 35.1 ms (N = 10 / 25 / 50) "
    "against the APF's 97.5 mm at 31.7 ms (N = 200; the best hybrid at that time −14.4 ± 4.6 mm, more than "
    "2 s.e.), 91.4 mm at 60 ms (N = 400; −10.1 ± 4.6 mm) and 87.1 mm at 118 ms (N = 800): all three hybrid "
    "sizes reach the largest APF's error in 0.23–0.30× its time (each within the noise of it, −1.6 to −5.8 mm). "
    "At 17 ms the 2-layer hybrid (N = 50) beats the APF with 100 particles (95.8 against 104.8 mm at 18 ms, "
    "−9.0 ± 3.8 mm). At the two cheapest APF budgets (6 and 10 ms) no gradient configuration is that fast (the "
    "cheapest, the refined APF with 25 particles, takes 11.3 ms). Per motion the hybrid is "
    "clearly better on the turn and the hops, level on the walk (53.9 against 55.4 mm for APF N = 800) and not "
    "better on the Charleston (72.7 against 66.9 mm). Against the run of 2026-11-25 the gradient got cheaper "
    "relative to the forward pass (value and gradient 2.6–2.9 forward evaluations at 200 particles in the clips' "
    "processes, 4.9–6.3 before): S = 3 at N = 25 took 0.97× the time of APF N = 200 (1.24× before), so the "
    "hybrid meets the APF's error at half its time for 2 of 6 budgets (1 before) and beats it at equal time "
    "by more than 2 s.e. for 3 (1 before). The hybrid's time is still not proportional to its gradient "
    "evaluations (20 / 40 / 60 per frame: 8.0 / 20.9 / 25.2 ms above APF N = 25 for S = 1 / 2 / 3): each "
    "value-and-gradient call on the 5 moved particles costs about 2 ms, mostly the fixed costs of its kernels. "
    "The refined APF (10 Adam steps from the mean) does not pay (101.2 mm at 23 ms against the APF's 104.8 mm "
    "at 18 ms). The lowest pooled error of 15 gradient configurations is an optimistic pick; the three hybrid "
    "sizes together are the fairer reading. Runtime: 2690 s for the whole run, compilation included."
)


def build(spec: Spec, loglik_batch, delta, lower, upper):
    """The filter of ``spec`` on ``loglik_batch`` with diffusion ``delta (D,)`` and joint limits."""
    sched = Schedule.deutscher(
        spec.layers, SURVIVAL, diffusion_scales=tuple(0.6**l for l in range(spec.layers))
    )
    kw = dict(lower=lower, upper=upper)
    n = spec.particles
    if spec.family == "APF":
        return APF(loglik_batch, delta, n, sched, **kw)
    if spec.family == "refined":
        return HybridAPF.refined(loglik_batch, delta, n, sched, **kw)
    move = GradientMove(spec.steps, 1.0, "normalised", best_k=min(spec.best_k, n), layers=spec.move_layers)
    return HybridAPF(loglik_batch, delta, n, sched, move=move, **kw)


@functools.partial(jax.jit, static_argnums=0)
def _track(spec: Spec, lik: L.Likelihood, delta, key, state, obs):
    """The estimates ``(T, D)`` of the filter of ``spec`` over the stacked observations (one program per spec and
    shapes: the likelihood is traced, so clips of the same sizes share it)."""
    f = build(spec, lik.batch, delta, lik.model.lower, lik.model.upper)
    return base.run(f.step, key, state, obs)[1].estimate


# ---------------------------------------------------------------------------------------------------------------
# Scenario


class Scenario(NamedTuple):
    """A synthetic tracking problem: likelihood, stacked observations (T frames), ground-truth joints (T, J, 3) in
    the model's joint order, IK states (T, D), diffusion Δ (D,), the filters' initial state (D,)."""

    lik: L.Likelihood
    observations: object
    joints: np.ndarray
    states: np.ndarray
    delta: np.ndarray
    x0: np.ndarray


def key_of(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name).strip("_")


def render(work: pathlib.Path, clip, frames: int, size: str) -> seqio.Sequence:
    """The synthetic sequence of ``clip`` under ``work`` (rendered once: a marker file says it is complete)."""
    name, motion, asf, start = clip
    d = work / "sequences" / f"{key_of(name)}_{frames}_{size}"
    done = d / ".complete"
    if not done.exists():
        synth.synthesize(motion, d, rig="ring4", asf=asf, frames=f"{start}:{start + 4 * frames}", fps=30,
                         size=size, seed=0, overwrite=True)  # fmt: skip
        done.write_text("")
    return seqio.load_sequence(d)


def observations_of(seq: seqio.Sequence, oracle: bool = False):
    """Features of every frame by the project's pipeline (static background = each view's plate, or with
    ``oracle`` the clean rendered background)."""
    fx = FeatureExtractor(seq.rig, FeatureConfig(foreground="static", skin=None))
    seed, clutter = int(seq.meta["seed"]), float(seq.meta["clutter"])
    if oracle:
        bgs = [
            np.ascontiguousarray(
                synth.background_image("photo", seq.rig.image_size[v], v, seed, clutter)[..., ::-1]
            )
            for v in range(seq.rig.num_views)
        ]
    else:
        bgs = [np.ascontiguousarray(plates.read_plate(seq.root, name)[..., ::-1]) for name in seq.view_names]
    fx.set_background(bgs)
    frames = [
        fx([np.ascontiguousarray(img[..., ::-1]) for img in seq.frame(t)]) for t in range(seq.num_frames)
    ]
    return fx.rig, jax.tree_util.tree_map(lambda *a: jnp.stack(a), *frames)


def scenario(seq: seqio.Sequence, surface_points: int = 400, oracle: bool = False) -> Scenario:
    """The tracking problem of a rendered sequence (see the module docstring)."""
    model = body.load_body(seq.body_path)
    maps_rig, obs = observations_of(seq, oracle=oracle)
    cues = [L.Cue("foreground", params={"bilinear": True}), L.Cue("edge_distance", params={"bilinear": True})]
    # chunk_size=0: one vmap over the particles (measured faster here than the default chunked lax.map, for the
    # forward pass and much more so for the reverse pass; the same likelihood serves every filter)
    lik = L.Likelihood.create(
        model, maps_rig, cues, surface_points=surface_points, num_layers=4, chunk_size=0
    )
    joints = ik.select_joints(model, seq.groundtruth.joints)
    states = np.asarray(ik.fit_sequence(model, jnp.asarray(joints, jnp.float32)).state)
    floor = np.where(np.asarray(model.angular), 0.01, 0.005)
    delta = np.maximum(np.sqrt(np.mean(np.diff(states, axis=0) ** 2, axis=0)), floor)
    x0 = states[0] if oracle else detected_pose(seq, model)
    return Scenario(lik, obs, joints, states, delta.astype(np.float32), np.asarray(x0, np.float32))


def detected_pose(seq: seqio.Sequence, model) -> np.ndarray:
    """The IK state of frame 0 from the simulated detections of every view (:func:`keypoint_pose`)."""
    folders = [str(seq.root / seqio.VIEWS / name / "openpose") for name in seq.view_names]
    kp = load_subject(folders, seq.rig, [0], seq.fps, total=seq.num_frames).keypoints[0]
    x = keypoint_pose(model, seq.rig, kp)
    if x is None:
        raise ValueError("too few joints detected in frame 0 to initialise from the detections")
    return x


def joint_error_mm(model, estimates: np.ndarray, joints: np.ndarray) -> float:
    """Mean over frames and joints of ``‖J(x̂_t) − J*_t‖`` in millimetres."""
    J = np.asarray(jax.vmap(lambda x: body.joint_positions(model, x))(jnp.asarray(estimates)))
    return float(1000.0 * np.linalg.norm(J - joints, axis=-1).mean())


def run_once(spec: Spec, sc: Scenario, seed: int) -> tuple[float, float]:
    """``(error mm, wall seconds of the tracking call)`` of one run of ``spec`` with filter seed ``seed``."""
    k0, k1 = jax.random.split(jax.random.key(seed, impl=KEY_IMPL))
    delta = jnp.asarray(sc.delta)
    f = build(spec, sc.lik.batch, delta, sc.lik.model.lower, sc.lik.model.upper)
    state = f.init(k0, jnp.asarray(sc.x0), delta * 0.5)
    jax.block_until_ready(state)
    t0 = time.perf_counter()
    est = np.asarray(_track(spec, sc.lik, delta, k1, state, sc.observations))
    wall = time.perf_counter() - t0
    return joint_error_mm(sc.lik.model, est, sc.joints), wall


def gradient_cost_ratio(sc: Scenario, n: int = 200, repeats: int = 9) -> float:
    """Median time of a vmapped value-and-gradient evaluation over that of a forward evaluation (same ``n``
    particles, interleaved rounds)."""
    lik = sc.lik
    obs = jax.tree_util.tree_map(lambda a: a[0], sc.observations)
    X = jnp.asarray(sc.states[0]) + jnp.asarray(sc.delta) * jax.random.normal(
        jax.random.key(0, impl=KEY_IMPL), (n, sc.states.shape[1])
    )
    fwd = jax.jit(lambda X, o: lik.batch(X, o, 0))
    vg = jax.jit(lambda X, o: batch_value_and_grad(lik.batch, X, o, 0))
    jax.block_until_ready(fwd(X, obs))
    jax.block_until_ready(vg(X, obs))
    t = common.interleaved_rounds(
        {"f": lambda: jax.block_until_ready(fwd(X, obs)), "g": lambda: jax.block_until_ready(vg(X, obs))},
        repeats,
    )
    return float(np.median(t["g"]) / np.median(t["f"]))


# ---------------------------------------------------------------------------------------------------------------
# Runs


def unit_path(work: pathlib.Path, clip_name: str, spec: Spec, seed: int) -> pathlib.Path:
    return work / "units" / key_of(clip_name) / key_of(spec.label) / f"seed{seed}.json"


def save_json(path: pathlib.Path, data: dict) -> None:
    """Write ``data`` through a temporary file and a rename (a crash leaves the old file or none)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data))
    os.replace(tmp, path)


def run_clip(
    work, clip, specs, seeds: int, frames: int, size: str, oracle: bool, process: str, on_ratio
) -> bool:
    """Every missing run of ``clip`` (interleaved: per seed every spec once, in an order rotated by the seed);
    returns whether any ran."""
    todo = [(s, sp) for s in range(seeds) for sp in specs if not unit_path(work, clip[0], sp, s).exists()]
    if not todo:
        return False
    t0 = time.perf_counter()
    sc = scenario(render(work, clip, frames, size), oracle=oracle)
    print(f"{clip[0]}: scenario ready ({time.perf_counter() - t0:.0f} s)", flush=True)
    on_ratio(sc)
    for sp in {sp for _, sp in todo}:  # compile (or fetch) every program before the timed runs
        t1 = time.perf_counter()
        run_once(sp, sc, 10_000)
        print(f"  {sp.label}: first call {time.perf_counter() - t1:.1f} s", flush=True)
    for s in range(seeds):
        r = s % len(specs)
        for sp in specs[r:] + specs[:r]:
            path = unit_path(work, clip[0], sp, s)
            if path.exists():
                continue
            load = os.getloadavg()[0]
            err, wall = run_once(sp, sc, s)
            n = len(sc.joints)
            save_json(path, dict(error_mm=err, wall_s=wall, frames=n, s_per_frame=wall / n, load=load,
                                 process=process, time=common.stamp()))  # fmt: skip
            print(f"  seed {s} {sp.label:32s} {err:6.1f} mm  {1000 * wall / n:7.1f} ms/frame  load {load:.1f}",
                  flush=True)  # fmt: skip
    return True


def load_units(work: pathlib.Path, clips, specs, seeds: int) -> dict:
    """``{(clip name, spec): [unit dict, …]}`` of the saved runs."""
    out = {}
    for c in clips:
        for sp in specs:
            units = [unit_path(work, c[0], sp, s) for s in range(seeds)]
            out[c[0], sp] = [json.loads(p.read_text()) for p in units if p.exists()]
    return out


# ---------------------------------------------------------------------------------------------------------------
# Report


class Row(NamedTuple):
    spec: Spec
    ms: float  # median wall ms per frame over every run of the spec
    err: float  # mean error (mm) over the runs considered
    se: float  # its standard error
    runs: int
    later: bool = False  # its runs are in other processes than the APF's (not interleaved with them)

    @property
    def name(self) -> str:
        return self.spec.label + (" †" if self.later else "")


def rows_of(units: dict, clips, specs) -> list[Row]:
    """One row per spec over the runs of ``clips`` (time: the median over every clip's runs)."""
    rows = []
    for sp in specs:
        all_runs = [u for c in CLIPS for u in units.get((c[0], sp), [])]
        errs = np.asarray([u["error_mm"] for c in clips for u in units.get((c[0], sp), [])])
        if not all_runs or not errs.size:
            continue
        ms = 1000.0 * float(np.median([u["s_per_frame"] for u in all_runs]))
        # the pooled mean is the mean of the clips' means (equal seeds); its standard error from the spread
        # within each clip (the clips are the same for every configuration)
        per = [np.asarray([u["error_mm"] for u in units.get((c[0], sp), [])]) for c in clips]
        se = float(np.sqrt(sum(e.var(ddof=1) / e.size if e.size > 1 else np.nan for e in per)) / len(per))
        apf = {u["process"] for c in CLIPS for u in units.get((c[0], SPECS[0]), [])}
        later = not apf & {u["process"] for u in all_runs}
        rows.append(Row(sp, ms, float(errs.mean()), se, int(errs.size), later))
    return rows


def answers(rows: list[Row]) -> list[tuple]:
    """For every APF budget (an APF row's time ``t``): ``(apf row, best APF row at ≤ t, best gradient row at
    ≤ t / 2 or None, best gradient row at ≤ t or None)``; "best": the lowest mean error, for both families alike."""
    grad = [r for r in rows if r.spec.family != "APF"]
    apf = [r for r in rows if r.spec.family == "APF"]

    def best(rs, t):
        return min((r for r in rs if r.ms <= t), key=lambda r: r.err, default=None)

    return [(a, best(apf, a.ms), best(grad, a.ms / 2), best(grad, a.ms)) for a in apf]


def _cell(r: Row | None, a: Row) -> str:
    if r is None:
        return "none that fast | —"
    d = r.err - a.err
    s = np.hypot(r.se, a.se)
    sig = " (> 2 s.e.)" if abs(d) > 2 * s else ""
    return f"{r.name}: {r.ms:.0f} ms, {r.err:.1f} mm | {d:+.1f} ± {s:.1f}{sig}"


def answer_table(rows: list[Row]) -> str:
    lines = [
        "| budget: APF | its ms / frame | best APF at ≤ that time: error (mm) | best gradient filter at ≤ ½ the "
        "time | its error − the APF's (mm, ± s.e.) | best gradient filter at ≤ the time | its error − the APF's "
        "(mm, ± s.e.) |",
        "|---|---|---|---|---|---|---|",
    ]
    for a, b, h, e in answers(rows):
        which = "" if b.spec == a.spec else f" (N={b.spec.particles})"
        lines.append(
            f"| N={a.spec.particles} | {a.ms:.0f} | {b.err:.1f} ± {b.se:.1f}{which} | {_cell(h, b)} | {_cell(e, b)} |"
        )
    return "\n".join(lines)


def verdict(rows: list[Row]) -> tuple[str, str]:
    """The two answers in words: for how many APF budgets the best gradient filter at ≤ ½ the time has an error
    ≤ the best APF's, and at ≤ the time a lower one (and for how many by more than 2 standard errors)."""
    res = answers(rows)

    def count(triples, strict):
        hits = [
            (a, b, g)
            for a, b, g in triples
            if g is not None and (g.err < b.err if strict else g.err <= b.err)
        ]
        clear = [a for a, b, g in hits if b.err - g.err > 2 * np.hypot(b.se, g.se)]
        names = ", ".join(f"N={a.spec.particles}" for a, _, _ in hits) or "none"
        return f"{len(hits)} of {len(triples)} ({names}; by more than 2 s.e.: {len(clear)})"

    q1 = count([(a, b, h) for a, b, h, _ in res], False)
    q2 = count([(a, b, e) for a, b, _, e in res], True)
    return (
        f"reaches the best APF's error with ≤ ½ of the APF's time for {q1} APF budgets",
        f"has a lower error than the best APF at ≤ the APF's time for {q2}",
    )


def sweep_table(units: dict, clips, specs) -> str:
    per_clip = {c[0]: {r.spec: r for r in rows_of(units, [c], specs)} for c in clips}
    pooled = {r.spec: r for r in rows_of(units, clips, specs)}
    head = " | ".join(c[0] for c in clips)
    lines = [
        f"| filter | likelihood / gradient evals per frame | ms / frame (median; quartiles) | {head} "
        "| pooled (± s.e.) |",
        "|---|---|---|" + "---|" * len(clips) + "---|",
    ]
    for sp in specs:
        if sp not in pooled:
            continue
        p = pooled[sp]
        n_lik, n_grad = sp.evaluations()
        cells = " | ".join(
            f"{per_clip[c[0]][sp].err:.1f} ± {per_clip[c[0]][sp].se:.1f}" if sp in per_clip[c[0]] else "—"
            for c in clips
        )
        q = 1000 * np.percentile(
            [u["s_per_frame"] for c in CLIPS for u in units.get((c[0], sp), [])], [25, 75]
        )
        lines.append(
            f"| {p.name} | {n_lik} / {n_grad} | {p.ms:.1f}; {q[0]:.1f} – {q[1]:.1f} | {cells} "
            f"| {p.err:.1f} ± {p.se:.1f} |"
        )
    return "\n".join(lines)


def report(
    work: pathlib.Path, clips, specs, seeds: int, frames: int, size: str, oracle: bool, reading: str = ""
) -> str:
    """The results file's text from the runs saved under ``work`` (``reading``: a paragraph written for the
    measured tables, shown when every run is there)."""
    units = load_units(work, clips, specs, seeds)
    runs = [u for v in units.values() for u in v]
    if not runs:
        return "no runs saved"
    loads = np.asarray([u["load"] for u in runs])
    processes = {u["process"] for u in runs}
    ratios = {p.stem: json.loads(p.read_text()) for p in sorted((work / "ratio").glob("*.json"))}
    pooled = rows_of(units, clips, specs)
    q1, q2 = verdict(pooled)
    complete = len(runs) == len(clips) * len(specs) * seeds
    parts = [
        "# Hybrid (gradient) APF against the plain APF at equal wall time\n",
        *([] if complete else [f"> **Partial**: {len(runs)} of {len(clips) * len(specs) * seeds} runs.\n"]),
        f"Command: `python {common.script(__file__)}`; scenario and every choice: the script's docstring. "
        f"{len(clips)} clips ({', '.join(c[0] for c in clips)}), {frames} frames each at 30 fps, ring4 rig "
        f"(4 views), {size}; input: "
        + (
            "**oracle** (clean rendered backgrounds, ground-truth start).\n"
            if oracle
            else "background subtraction against the plates, start from the simulated detections (no ground "
            "truth, rendered mask or part label).\n"
        ),
        "Filters: APF with L = 4 layers, Deutscher's survival rate α = 0.5, diffusion Δ · 0.6^l, N particles per "
        "layer; hybrid: the same with S = 3 normalised gradient steps of one diffusion std on the k = 5 best "
        "distinct particles in every layer, unless the label says otherwise (S=1, S=2; moves in the last layer "
        "of 4 only; L=2 layers); refined: the APF + 10 Adam steps of 0.3 diffusion std from the weighted mean. "
        "Likelihood: foreground + edge distance (bilinear), `full25` with the subject's dimensions, 400 surface "
        "points.\n",
        f"{seeds} filter seeds per clip and configuration; {len(runs)} runs, interleaved (every configuration once "
        f"per clip and seed, in an order rotated by the seed) in {len(processes)} processes (one per clip{'' if len(processes) == len(clips) else ' and sweep'}), "
        f"{min(u['time'] for u in runs)} – {max(u['time'] for u in runs)}; {common.machine_line().rsplit(',', 1)[0]}; load average (1 min) at "
        f"the runs' starts {loads.min():.1f} – {loads.max():.1f}, median {np.median(loads):.1f} (the machine was "
        "shared with other timing runs). Time = the wall time of the compiled tracking of a clip (filter only; the "
        "features are computed beforehand and are the same for every filter) ÷ its frames, median over every "
        "run of the configuration.\n",
    ]
    if ratios:
        names = {key_of(c[0]): c[0] for c in clips}
        cells = "; ".join(
            f"{names.get(k, k)}: {r['ratio200']:.2f} / {r['ratio5']:.2f} (load {r['load']:.1f})"
            for k, r in ratios.items()
        )
        parts.append(
            "Value-and-gradient ÷ forward cost (vmapped, the same particles, in each clip's process, 200 / 5 "
            f"particles; the hybrid moves the 5 best): {cells}.\n"
        )
    parts += [
        "## The answers (pooled over the clips)\n",
        f"The best gradient filter (any hybrid or refined configuration) {q1}; it {q2}.\n",
        answer_table(pooled) + "\n",
        "Best gradient filter: the hybrid or refined configuration with the lowest mean error among those at most "
        "that fast (selecting the lowest of several noisy means favours the gradient filters); ± s.e.: the "
        "standard errors of the two means combined.\n",
        "## Per motion\n",
    ]
    for c in clips:
        rows = rows_of(units, [c], specs)
        a1, a2 = verdict(rows)
        parts += [f"### {c[0]}\n", f"The best gradient filter {a1}; it {a2}.\n", answer_table(rows) + "\n"]
    parts += [
        "## Every configuration\n",
        "Mean joint error (mm, ± standard error over the seeds; pooled: the mean of the clips' means, its "
        "standard error from the spread within each clip) and the wall time per frame (median and quartiles over "
        "every run).\n",
        sweep_table(units, clips, specs) + "\n",
    ]
    later = [r for r in pooled if r.later]
    if later:
        lo = [u["load"] for r in later for c in CLIPS for u in units.get((c[0], r.spec), [])]
        parts.append(
            "† Run after the sweep, in processes of their own (one per clip), interleaved with each other but not "
            f"with the APF's runs (load average {min(lo):.1f} – {max(lo):.1f} at their starts): their times "
            "compare less well.\n"
        )
    if complete and reading:
        parts.append(reading + "\n")
    parts.append("![error against wall time per frame](hybrid_vs_apf.png)\n")
    return "\n".join(parts)


def plot(work, clips, specs, seeds: int, path: pathlib.Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    units = load_units(work, clips, specs, seeds)
    panels = [("pooled over the clips", clips), *((c[0], [c]) for c in clips)]
    cols = 3
    rows_n = -(-(len(panels) + 1) // cols)  # one more cell for the legend
    fig, axes = plt.subplots(rows_n, cols, figsize=(4.2 * cols, 3.4 * rows_n), sharex=True)
    axes = np.ravel(axes)
    groups = list(dict.fromkeys(sp.group for sp in specs))
    markers = "osv^Dp*<>"
    for ax, (title, cs) in zip(axes, panels, strict=False):
        rows = rows_of(units, cs, specs)
        for g, m in zip(groups, markers, strict=False):
            pts = sorted((r.ms, r.err, r.se) for r in rows if r.spec.group == g)
            if pts:
                t, e, s = map(np.asarray, zip(*pts, strict=True))
                ax.errorbar(t, e, yerr=s, marker=m, ms=4, capsize=2, label=g, lw=1.6 if g == "APF" else 0.9)
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xticks([3, 5, 10, 20, 50, 100])
        ax.tick_params(labelbottom=True)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("wall ms / frame (median)")
        ax.set_ylabel("mean joint error (mm)")
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    for ax in axes[len(panels) :]:
        ax.axis("off")
    axes[len(panels)].legend(handles, labels, loc="center", fontsize=8, title="± s.e. over seeds")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> str:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--quick", action="store_true", help="1 clip, 10 frames, 1 seed, APF and hybrid; writes nothing"
    )
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--frames", type=int, default=30, help="frames per clip at 30 fps (default 30)")
    parser.add_argument("--size", default="320x240")
    parser.add_argument(
        "--work", default=None, help="folder of the saved runs (default: <tmp>/jaxmocap_hybrid_vs_apf)"
    )
    parser.add_argument(
        "--report", action="store_true", help="only rewrite the results file from the saved runs"
    )
    parser.add_argument(
        "--oracle", action="store_true", help="clean backgrounds, ground-truth start; prints only"
    )
    parser.add_argument("--clip", default=None, help=argparse.SUPPRESS)  # one clip's runs in this process
    a = parser.parse_args(argv)
    clips, specs, seeds, frames = CLIPS, SPECS, a.seeds, a.frames
    if a.quick:
        clips, specs, seeds, frames = CLIPS[:1], QUICK_SPECS, 1, 10
    if a.work:
        root = pathlib.Path(a.work)
    elif a.quick:
        root = pathlib.Path(tempfile.mkdtemp(prefix="jaxmocap_hybrid_vs_apf_quick_"))
    else:
        root = pathlib.Path(tempfile.gettempdir()) / "jaxmocap_hybrid_vs_apf"
    work = root / (f"oracle_{frames}_{a.size}" if a.oracle else f"plates_{frames}_{a.size}")
    write = not (a.quick or a.oracle)
    t_start = time.perf_counter()
    if a.clip is not None or a.quick:
        # the runs of one clip, in this process
        compilation_cache.enable()
        clip = CLIPS[0] if a.quick else next(c for c in CLIPS if key_of(c[0]) == a.clip)
        process = f"{os.getpid()}@{common.stamp()}"

        def on_ratio(sc: Scenario) -> None:
            if (work / "ratio" / f"{key_of(clip[0])}.json").exists():
                return  # measured in the clip's first process
            load = os.getloadavg()[0]
            # a quick run (a smoke run) measures the 5-particle ratio only: each size traces and compiles both
            # programs again (7–8 s)
            r200 = float("nan") if a.quick else gradient_cost_ratio(sc, 200)
            r5 = gradient_cost_ratio(sc, 5)
            print(f"value-and-gradient / forward cost: {r200:.2f} (200 particles), {r5:.2f} (5)", flush=True)
            save_json(work / "ratio" / f"{key_of(clip[0])}.json", dict(ratio200=r200, ratio5=r5, load=load))

        run_clip(work, clip, specs, seeds, frames, a.size, a.oracle, process, on_ratio)
        if not a.quick:
            return ""
    elif not a.report:
        # one child process per clip: a clip's runs share a process (their times compare), and the compiled
        # programs of earlier clips do not pile up in it (a process that had compiled ~40 of them ran out of
        # memory maps in LLVM)
        for clip in clips:
            if all(unit_path(work, clip[0], sp, s).exists() for sp in specs for s in range(seeds)):
                continue
            argv = [sys.executable, __file__, "--clip", key_of(clip[0]), "--seeds", str(seeds), "--frames",
                    str(frames), "--size", a.size, "--work", str(root)] + (["--oracle"] if a.oracle else [])  # fmt: skip
            proc = subprocess.run(argv, check=False)
            if proc.returncode != 0:
                print(
                    f"{clip[0]}: the runs' process failed (exit {proc.returncode}); saved runs kept",
                    flush=True,
                )
            if write:
                common.write_result(RESULTS, report(work, clips, specs, seeds, frames, a.size, a.oracle) + "\n",
                                    f"python {common.script(__file__)}")  # fmt: skip
    md = report(work, clips, specs, seeds, frames, a.size, a.oracle, READING if write else "")
    print(md)
    print(f"\n({time.perf_counter() - t_start:.0f} s)")
    if write:
        plot(work, clips, specs, seeds, common.RESULTS / "hybrid_vs_apf.png")
        common.write_result(RESULTS, md + "\n", f"python {common.script(__file__)}")
    if a.quick and not a.work:
        shutil.rmtree(root, ignore_errors=True)
    return md


if __name__ == "__main__":
    main()
