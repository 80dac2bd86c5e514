"""Hybrid (gradient) annealed particle filters against the plain APF on a synthetic sequence from real mocap:
mean joint error against the number of likelihood evaluations per frame.

Scenario (all choices stated here):

* the bundled CMU clip (subject 2, trial 1, a walk), frames ``150:270`` at 30 fps (30 frames, 1 s), rendered by
  :func:`jaxmocap.synth.generate.synthesize` with the ``ring4`` rig (four cameras around the subject, HumanEva-like) at
  320×240, photo backgrounds, sensor noise 0.01 (with the thesis' two-camera ``frontal-lateral`` rig, the APF lost
  the wrists and legs at every particle count tried, 50 to 200 per layer: errors ≈ 95 mm, which says little about
  search efficiency);
* features by the project's pipeline (:class:`jaxmocap.features.pipeline.FeatureExtractor`): static background
  subtraction against each view's empty-scene plate (``views/<camera>/background.png``, the background with one
  exposure's sensor noise, as a recording's; with ``--oracle`` the clean rendered background), Canny edges and
  their distance transform;
* likelihood: ``foreground`` and ``edge_distance`` (σ_e = 6 px), both with bilinear lookups (differentiable), on the
  ``full25`` model with the subject's dimensions (the sequence's ``body.toml``), 400 surface points, particles
  evaluated in one ``vmap`` (``chunk_size=0``);
* motion model (a random walk): Δ = the root-mean-square frame-to-frame change of each state entry, measured on the IK
  fit of the clip's ground truth (:func:`jaxmocap.fit.ik.fit_sequence`), floored at 0.5 cm / 0.01 rad; both filters
  start from the IK state of frame 0 fitted to the simulated BODY_25B detections of the four views
  (:func:`jaxmocap.tracking.init.keypoint_pose`), or with ``--oracle`` to the ground truth;
* APF: Deutscher's survival-rate rule (α = 0.5), ``L`` layers with diffusion scales ``0.6^l``; ``N`` particles per
  layer swept;
* hybrid: the same APF with :class:`jaxmocap.filters.hybrid.GradientMove` in every layer (``S`` = 3 normalised
  gradient steps of one diffusion std each) on the ``k`` = 5 best distinct particles, ``N`` swept; and the "refined"
  variant (plain APF + 10 Adam steps of 0.3 diffusion std from the weighted mean);
* error of a run: mean over frames and the 15 evaluation joints of the Euclidean distance between the model's joints
  at the estimate and the ground truth (mm), averaged over ``runs`` seeds.

Cost: a gradient evaluation (forward + reverse pass, vmapped) is measured against a forward evaluation in the same
process on the same particles (median of repeated timings); the curve's x axis counts a gradient evaluation as that
many forward evaluations ("likelihood-evaluation equivalents"); the table also gives the raw counts.

Usage::

    .venv/bin/python benchmarks/experiments/hybrid_vs_apf.py            # writes benchmarks/results/hybrid_vs_apf.{md,png}
    .venv/bin/python benchmarks/experiments/hybrid_vs_apf.py --quick    # 1 run of 10 frames, APF and hybrid; writes nothing
    .venv/bin/python benchmarks/experiments/hybrid_vs_apf.py --oracle   # clean backgrounds, ground-truth start
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile
import time
from typing import NamedTuple

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common
import jax
import jax.numpy as jnp
import numpy as np

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


class Scenario(NamedTuple):
    """A synthetic tracking problem: likelihood, stacked observations (T frames), ground-truth joints (T, J, 3) in
    the model's joint order, IK states (T, D), diffusion Δ (D,), the filters' initial state (D,)."""

    lik: L.Likelihood
    observations: object
    joints: np.ndarray
    states: np.ndarray
    delta: np.ndarray
    x0: np.ndarray


def observations_of(seq: seqio.Sequence, rig_scale: int = 1, oracle: bool = False):
    """Features of every frame by the project's pipeline (static background = each view's plate, or with
    ``oracle`` the clean rendered background)."""
    fx = FeatureExtractor(seq.rig, FeatureConfig(foreground="static", skin=None, downsample=rig_scale))
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
    frames = []
    for t in range(seq.num_frames):
        frames.append(fx([np.ascontiguousarray(img[..., ::-1]) for img in seq.frame(t)]))
    stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *frames)
    return fx.rig, stacked


def scenario(
    root: pathlib.Path,
    frames: str = "150:270",
    size=(320, 240),
    rig: str = "ring4",
    surface_points: int = 400,
    num_layers: int = 1,
    oracle: bool = False,
) -> Scenario:
    """Render (into ``root``) and prepare the benchmark's tracking problem (see the module docstring)."""
    seq = synth.synthesize("demo", root, rig=rig, frames=frames, fps=30, size=size, seed=1, overwrite=True)
    model = body.load_body(seq.body_path)
    maps_rig, obs = observations_of(seq, oracle=oracle)
    cues = [L.Cue("foreground", params={"bilinear": True}), L.Cue("edge_distance", params={"bilinear": True})]
    # chunk_size=0: one vmap over the particles (measured faster here than the default chunked lax.map, for the
    # forward pass and much more so for the reverse pass; the same likelihood serves every filter)
    lik = L.Likelihood.create(
        model, maps_rig, cues, surface_points=surface_points, num_layers=num_layers, chunk_size=0
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


@jax.jit
def _run(f, key, state, obs):
    return base.run(f.step, key, state, obs)[1].estimate


def joint_error_mm(model, estimates: np.ndarray, joints: np.ndarray) -> float:
    """Mean over frames and joints of ``‖J(x̂_t) − J*_t‖`` in millimetres."""
    J = np.asarray(jax.vmap(lambda x: body.joint_positions(model, x))(jnp.asarray(estimates)))
    return float(1000.0 * np.linalg.norm(J - joints, axis=-1).mean())


def run_filter(f, sc: Scenario, runs: int, seed: int = 0) -> tuple[float, float, float]:
    """``(mean error mm, std over runs, seconds per run after compilation)``."""
    errs, times = [], []
    x0 = jnp.asarray(sc.x0)
    for r in range(runs):
        k0, k1 = jax.random.split(jax.random.key(1000 * seed + r, impl=KEY_IMPL))
        state = f.init(k0, x0, jnp.asarray(sc.delta) * 0.5)
        t0 = time.perf_counter()
        est = np.asarray(_run(f, k1, state, sc.observations))
        times.append(time.perf_counter() - t0)
        errs.append(joint_error_mm(sc.lik.model, est, sc.joints))
    return float(np.mean(errs)), float(np.std(errs)), float(np.median(times[1:] if runs > 1 else times))


def gradient_cost_ratio(sc: Scenario, n: int = 200, repeats: int = 9) -> float:
    """Median time of a vmapped value-and-gradient evaluation over that of a forward evaluation (same particles)."""
    lik = sc.lik
    obs = jax.tree_util.tree_map(lambda a: a[0], sc.observations)
    X = jnp.asarray(sc.states[0]) + jnp.asarray(sc.delta) * jax.random.normal(
        jax.random.key(0, impl=KEY_IMPL), (n, sc.states.shape[1])
    )
    fwd = jax.jit(lambda X, o: lik.batch(X, o, 0))
    vg = jax.jit(lambda X, o: batch_value_and_grad(lik.batch, X, o, 0))
    jax.block_until_ready(fwd(X, obs))
    jax.block_until_ready(vg(X, obs))
    # interleaved, so that a load change on the machine hits both
    t = common.interleaved_rounds(
        {"f": lambda: jax.block_until_ready(fwd(X, obs)), "g": lambda: jax.block_until_ready(vg(X, obs))},
        repeats,
    )
    return float(np.median(t["g"]) / np.median(t["f"]))


class Config(NamedTuple):
    layers: int = 4
    survival: float = 0.5
    apf_particles: tuple = (25, 50, 100, 200, 400)
    hybrid_particles: tuple = (5, 10, 25, 50)
    best_k: int = 5
    steps: int = 3
    learning_rate: float = 1.0
    refine_particles: tuple = (25, 50, 100)
    runs: int = 4
    frames: str = "150:270"


def filters(cfg: Config, sc: Scenario):
    """``{label: (family, filter)}`` for every configuration of the sweep."""
    lik = sc.lik
    model = lik.model
    delta = jnp.asarray(sc.delta)
    sched = Schedule.deutscher(
        cfg.layers, cfg.survival, diffusion_scales=tuple(0.6**l for l in range(cfg.layers))
    )
    common = dict(lower=model.lower, upper=model.upper)
    out = {}
    for n in cfg.apf_particles:
        out[f"APF N={n}"] = ("APF", APF(lik.batch, delta, n, sched, **common))
    for n in cfg.hybrid_particles:
        m = GradientMove(cfg.steps, cfg.learning_rate, "normalised", best_k=min(cfg.best_k, n))
        out[f"hybrid N={n} k={m.best_k} S={m.steps}"] = (
            "hybrid",
            HybridAPF(lik.batch, delta, n, sched, move=m, **common),
        )
    for n in cfg.refine_particles:
        out[f"refined N={n}"] = ("refined", HybridAPF.refined(lik.batch, delta, n, sched, **common))
    return out


def evaluations(f) -> tuple[int, int]:
    if isinstance(f, HybridAPF):
        e = f.evaluations()
        return e["likelihood"], e["gradient"]
    return f.num_particles * f.num_layers, 0


def main(argv=None) -> str:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--quick", action="store_true", help="1 run of 10 frames, APF and hybrid; writes nothing"
    )
    parser.add_argument("--runs", type=int, default=None)
    parser.add_argument(
        "--oracle",
        action="store_true",
        help="clean rendered backgrounds and a ground-truth start (default: plates)",
    )
    args = parser.parse_args(argv)
    cfg = Config()
    if args.quick:
        # the smoke test: one APF and one hybrid size on 10 frames (the refined variant's code path is tested in
        # tests/test_hybrid.py; its compilation would double this run)
        cfg = cfg._replace(
            runs=1, frames="150:160", apf_particles=(25,), hybrid_particles=(10,), refine_particles=()
        )
    if args.runs:
        cfg = cfg._replace(runs=args.runs)
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        sc = scenario(pathlib.Path(tmp) / "seq", frames=cfg.frames, oracle=args.oracle)
    ratio = gradient_cost_ratio(sc)
    print(f"gradient / forward cost ratio: {ratio:.2f}", flush=True)
    rows = []
    for label, (family, f) in filters(cfg, sc).items():
        t0 = time.perf_counter()
        err, sd, sec = run_filter(f, sc, cfg.runs)
        n_lik, n_grad = evaluations(f)
        cost = n_lik + ratio * n_grad
        rows.append((family, label, n_lik, n_grad, cost, err, sd, sec))
        print(
            f"{label:32s} lik {n_lik:5d} grad {n_grad:5d} equiv {cost:7.0f}  error {err:6.1f} ± {sd:4.1f} mm  "
            f"({sec:.2f} s/run, {time.perf_counter() - t0:.0f} s with compile)",
            flush=True,
        )
    md = table(rows, cfg, ratio) + "\n\n" + verdict(rows)
    print(md)
    print(f"\n({time.perf_counter() - t_start:.0f} s)")
    if not args.quick:
        common.RESULTS.mkdir(parents=True, exist_ok=True)
        plot(rows, common.RESULTS / "hybrid_vs_apf.png")
        header = (
            "# Hybrid (gradient) APF against the plain APF\n\n"
            f"Command: `.venv/bin/python {common.script(__file__)}` (scenario and choices: the module docstring). "
            f"Frames {cfg.frames} of the bundled CMU walk at 30 fps, ring4 rig, 320×240; L = {cfg.layers} layers, "
            f"survival rate {cfg.survival}; hybrid: k = {cfg.best_k} best particles, S = {cfg.steps} normalised "
            f"steps of {cfg.learning_rate} diffusion std per layer; {cfg.runs} runs per configuration; input: "
            + (
                "clean rendered backgrounds, started from the ground truth (`--oracle`).\n\n"
                if args.oracle
                else "subtraction against the plates, started from the simulated detections.\n\n"
            )
            + f"Measured cost of one gradient evaluation (forward + reverse, vmapped over 200 particles) = "
            f"{ratio:.2f} forward evaluations (median, same process); 'equivalent' counts use that ratio.\n\n"
            "![error vs evaluations](hybrid_vs_apf.png)\n\n"
        )
        common.write_result(
            common.RESULTS / "hybrid_vs_apf.md",
            header + md + "\n",
            f"python {common.script(__file__)}" + (" --oracle" if args.oracle else ""),
        )
    return md


def table(rows, cfg: Config, ratio: float) -> str:
    lines = [
        "| filter | likelihood evals / frame | gradient evals / frame | equivalent evals / frame | mean joint error (mm, "
        f"± std over {cfg.runs} runs) | s / run |",
        "|---|---|---|---|---|---|",
    ]
    for family, label, n_lik, n_grad, cost, err, sd, sec in rows:
        del family
        lines.append(f"| {label} | {n_lik} | {n_grad} | {cost:.0f} | {err:.1f} ± {sd:.1f} | {sec:.2f} |")
    return "\n".join(lines)


def apf_cost_for(rows, error: float) -> float | None:
    """The APF cost (evaluations per frame) at which the APF curve reaches ``error``: linear interpolation of the
    error in log cost between the sweep's points (None when the APF never gets that low)."""
    pts = sorted((r[4], r[5]) for r in rows if r[0] == "APF")
    if not pts:
        return None
    # the running minimum: more particles are assumed never to hurt (the sweep is noisy)
    costs = np.asarray([c for c, _ in pts])
    errs = np.minimum.accumulate(np.asarray([e for _, e in pts]))
    if error < errs[-1]:
        return None
    if error >= errs[0]:
        return float(costs[0])
    i = int(np.argmax(errs <= error))
    c0, c1, e0, e1 = np.log(costs[i - 1]), np.log(costs[i]), errs[i - 1], errs[i]
    w = 0.0 if e0 == e1 else (e0 - error) / (e0 - e1)
    return float(np.exp(c0 + w * (c1 - c0)))


def verdict(rows) -> str:
    """For each hybrid configuration: the APF cost that reaches the same error, as a ratio to its own cost."""
    best_apf = min(r[5] for r in rows if r[0] == "APF")
    lines = [
        "| filter | its cost (equivalent / raw evals) | error (mm) | APF cost for that error | APF cost ÷ its cost "
        "(equivalent / raw) |",
        "|---|---|---|---|---|",
    ]
    for family, label, n_lik, n_grad, cost, err, _, _ in rows:
        if family == "APF":
            continue
        c = apf_cost_for(rows, err)
        if c is None:
            cell, ratio = f"beyond the sweep (best APF {best_apf:.1f} mm)", "—"
        else:
            cell, ratio = f"{c:.0f}", f"{c / cost:.1f}× / {c / (n_lik + n_grad):.1f}×"
        lines.append(f"| {label} | {cost:.0f} / {n_lik + n_grad} | {err:.1f} | {cell} | {ratio} |")
    return "\n".join(lines)


def plot(rows, path: pathlib.Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for family, marker in (("APF", "o"), ("hybrid", "s"), ("refined", "^")):
        pts = sorted((r[4], r[5], r[6]) for r in rows if r[0] == family)
        if pts:
            c, e, s = map(np.asarray, zip(*pts, strict=True))
            ax.errorbar(c, e, yerr=s, marker=marker, capsize=3, label=family)
    ax.set_xscale("log")
    ax.set_xlabel("likelihood-evaluation equivalents per frame")
    ax.set_ylabel("mean joint error (mm)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main()
