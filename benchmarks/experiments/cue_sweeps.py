"""Cue energy landscapes on a synthetic stereo sequence from real motion capture (IROS 2007 Fig. 1, thesis Fig. 4.3).

A short stereo sequence of the bundled CMU walk (subject 2, trial 1) is rendered with :func:`jaxmocap.synth.generate.synthesize`
(the mocap skeleton dressed in cones, photo background, sensor noise, virtual depth). The tracker's ``full25`` body
(the ``body.toml`` written with the sequence) is fitted to the ground-truth joints of each frame used
(:func:`jaxmocap.fit.ik.fit_pose`); that fitted state is the "truth" of the sweeps — the scene is the dressed skeleton,
not the tracker's model, so a cue's minimum is displaced by the model mismatch as well. The observation is made
from the rendered images by :class:`jaxmocap.features.pipeline.FeatureExtractor` (static background, edges, skin,
colour, 3D skin blobs) plus the virtual depth maps; colour references (histograms, templates) come from the first
frame at its fitted pose.

For every cue the energy of a 2-D grid of two arm angles (default: left shoulder abduction ``left_shoulder_rx`` and
left elbow flexion) around the fitted state of a later frame is plotted to
``benchmarks/results/cue_sweep_<cue>.png``; the offset of each minimum from the truth is printed.

    python benchmarks/experiments/cue_sweeps.py [--size 320x240] [--steps 21] [--span 0.8] [--frame 6] [--quick]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common
import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.features.pipeline import FeatureConfig, FeatureExtractor
from jaxmocap.fit import ik
from jaxmocap.geometry import body
from jaxmocap.likelihood import compose as L
from jaxmocap.synth import generate as synth

#: every cue with the parameters used in the sweeps
SWEEP_CUES = (
    L.Cue("foreground"),
    L.Cue("silhouette_divergence"),
    L.Cue("edges"),
    L.Cue("edge_distance"),
    L.Cue("edge_fraction"),
    L.Cue("depth"),
    L.Cue("head_skin"),
    L.Cue("skin"),
    L.Cue("colour_histogram"),
    L.Cue("homogeneous_colour"),
    L.Cue("colour_template"),
    L.Cue("blobs3d"),
    L.Cue("wristband"),
    L.Cue("interpenetration"),
)


def make_frames(
    out: pathlib.Path, size=(640, 480), frames="60:120", fps=30.0, frame: int = 6, rig="frontal-lateral"
):
    """Render the sequence into ``out`` and return ``(model, rig, x_ref, obs_ref, x, obs, fit_rms)``: the fitted
    states and observations of frame 0 (references) and of frame ``frame`` (the sweep)."""
    seq = synth.synthesize("demo", out, rig=rig, size=size, frames=frames, fps=fps, seed=3, overwrite=True)
    model = body.load_body(seq.body_path)
    gt = seq.groundtruth.joints
    cfg = FeatureConfig(foreground="static", rgb=True, blobs=True, skin="rgb", max_blobs=3)
    fx = FeatureExtractor(seq.rig, cfg)
    bg = [
        synth.background_image("photo", seq.rig.image_size[v], v, 3)[..., ::-1]
        for v in range(seq.rig.num_views)
    ]
    fx.set_background(bg)
    out_frames = []
    rms = []
    for t in (0, frame):
        targets = ik.select_joints(model, gt[t])
        fit = ik.fit_pose(model, jnp.asarray(targets), maxiter=60)
        xt = fit.state
        err = np.asarray(body.joint_positions(model, xt)) - targets
        rms.append(float(np.sqrt(np.mean(np.sum(err**2, -1)))))
        bgr = [seq.view(v).rgb(t)[..., ::-1] for v in range(seq.rig.num_views)]
        depth = [seq.view(v).depth(t) for v in range(seq.rig.num_views)]
        obs = fx(bgr, depth=depth)
        # 3D head and hand "blobs": the ground-truth head and wrists with 1 cm noise (the stereo skin-blob matcher
        # needs a narrow baseline; here it only has to give the blob cues something to explain)
        rng = np.random.default_rng(t)
        names = body.EVAL_JOINTS
        blobs = gt[t][[names.index(n) for n in ("head", "left_wrist", "right_wrist")]] + rng.normal(
            0, 0.01, (3, 3)
        )
        obs = obs._replace(blobs3d=jnp.asarray(blobs, jnp.float32), blob_conf=jnp.ones(3, jnp.float32))
        out_frames.append((xt, obs))
    (x0, obs0), (x1, obs1) = out_frames
    return model, fx.rig, x0, obs0, x1, obs1, rms


def sweep(lik: L.Likelihood, x, obs, dofs: tuple[str, str], span: float, steps: int):
    """``(a (steps,), b (steps,), E (C, steps, steps))``: cue energies (``lik.energies``) over the grid of the two
    DOFs ``x[d] + [−span, span]``."""
    i, j = (lik.model.dof_index(d) for d in dofs)
    a = float(x[i]) + np.linspace(-span, span, steps)
    b = float(x[j]) + np.linspace(-span, span, steps)
    A, B = np.meshgrid(a, b, indexing="ij")
    X = jnp.tile(x, (steps * steps, 1)).at[:, i].set(A.ravel()).at[:, j].set(B.ravel())
    aux = lik.prepare(obs)
    E = jax.jit(jax.vmap(lambda x: lik.energies(x, obs, aux)))(X)
    return a, b, np.asarray(E).T.reshape(-1, steps, steps)


def minimum_offset(a, b, E, x_a, x_b) -> float:
    """Distance (radians, in the plane of the two angles) between the grid minimum of ``E`` and the truth."""
    k, m = np.unravel_index(int(np.argmin(E)), E.shape)
    return float(np.hypot(a[k] - x_a, b[m] - x_b))


def plot(path, a, b, E, truth, title, dofs):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(3.4, 2.9), dpi=80)
    im = ax.imshow(E.T, origin="lower", extent=(a[0], a[-1], b[0], b[-1]), aspect="auto", cmap="viridis")
    k, m = np.unravel_index(int(np.argmin(E)), E.shape)
    ax.plot(*truth, "r+", ms=10, mew=2, label="truth")
    ax.plot(a[k], b[m], "wx", ms=7, mew=2, label="minimum")
    ax.set_xlabel(dofs[0] + " (rad)", fontsize=7)
    ax.set_ylabel(dofs[1] + " (rad)", fontsize=7)
    ax.set_title(title, fontsize=8)
    ax.tick_params(labelsize=6)
    fig.colorbar(im, ax=ax).ax.tick_params(labelsize=6)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def run(
    size=(640, 480),
    steps=21,
    span=0.8,
    frame=6,
    dofs=("left_shoulder_ry", "left_elbow"),
    out_dir=common.RESULTS,
    cue_list=SWEEP_CUES,
    surface_points=600,
):
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        model, rig, x0, obs0, x, obs, rms = make_frames(pathlib.Path(tmp) / "seq", size=size, frame=frame)
    print(
        f"sequence + features: {time.perf_counter() - t0:.1f} s; full25 fit to the ground-truth joints: "
        f"RMS {rms[0] * 100:.1f} cm (reference frame), {rms[1] * 100:.1f} cm (sweep frame)"
    )
    lik = L.Likelihood.create(model, rig, cue_list, surface_points=surface_points).with_references(x0, obs0)
    lik.check_observation(obs)
    a, b, E = sweep(lik, x, obs, dofs, span, steps)
    ia, ib = (model.dof_index(d) for d in dofs)
    truth = (float(x[ia]), float(x[ib]))
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for c, cue in enumerate(lik.cues):
        off = minimum_offset(a, b, E[c], *truth)
        rows.append((cue.name, off, float(E[c].min()), float(E[c].max())))
        plot(
            out_dir / f"cue_sweep_{cue.name}.png",
            a,
            b,
            E[c],
            truth,
            f"{cue.name}: min {off:.2f} rad from truth",
            dofs,
        )
    print(f"{'cue':24s} {'min offset (rad)':>16s} {'E min':>10s} {'E max':>10s}")
    for name, off, lo, hi in rows:
        print(f"{name:24s} {off:16.2f} {lo:10.3g} {hi:10.3g}")
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--steps", type=int, default=21)
    ap.add_argument("--span", type=float, default=0.8)
    ap.add_argument("--frame", type=int, default=6)
    ap.add_argument("--out", default=str(common.RESULTS))
    ap.add_argument("--quick", action="store_true", help="small images and grid (smoke test)")
    a = ap.parse_args()
    size = synth.parse_size(a.size)
    if a.quick:
        run(size=(320, 240), steps=7, span=a.span, frame=a.frame, out_dir=a.out, surface_points=300)
    else:
        run(size=size, steps=a.steps, span=a.span, frame=a.frame, out_dir=a.out)


if __name__ == "__main__":
    main()
