"""How the likelihood's cost grows: time against particles, annealing layers, views and image size.

Setup (a cheap, self-contained version of the tracker's hot path): the ``full25`` model with default dimensions
standing at the origin; ``V`` cameras on a 3.5 m circle around it looking at its centre (focal 0.8 × width);
an observation of random smooth foreground and edge-distance maps (``jaxmocap.features.observation.make_observation``);
the tracker's default image cues ``foreground`` + ``edge_distance`` (600 surface points, 8 contour points per cone);
particles = the rest pose + N(0, 0.05²) noise. Every point is the median of ``repeats`` calls after compilation:

* particles N (2 views, 320×240): :meth:`jaxmocap.likelihood.compose.Likelihood.batch` of N particles;
* layers L (N = 200, 2 views, 320×240): one compiled APF step (:func:`jaxmocap.tracking.make_filter`, Deutscher's
  survival-rate rule) with L layers: L likelihood batches + resampling + diffusion;
* views V ∈ {1, 2, 4} (N = 1000, 320×240) and image size (N = 1000, 2 views).

Peak memory of each point: what XLA's compiled program allocates (``Compiled.memory_analysis()``: arguments +
outputs + temporaries − aliased), the device memory the call needs beyond the Python process itself.

    .venv/bin/python benchmarks/perf/scaling.py [--quick] [--repeats 7]

Writes ``benchmarks/results/scaling.png`` and ``benchmarks/results/scaling.md`` (not with ``--quick``).
"""

from __future__ import annotations

import argparse
import math
import os
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
os.environ.setdefault("JAX_PLATFORMS", "cpu")
import common
import cv2  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from jaxmocap.features.observation import make_observation  # noqa: E402
from jaxmocap.filters.factory import make_filter  # noqa: E402
from jaxmocap.geometry import body, camera
from jaxmocap.likelihood import compose as lk  # noqa: E402
from jaxmocap.tracking.options import diffusion_std  # noqa: E402


def ring_rig(views: int, size: tuple[int, int]) -> camera.Rig:
    """``views`` cameras on a 3.5 m circle at 1.1 m height looking at (0, 0, 1), image ``size = (w, h)``."""
    w, h = size
    f = 0.8 * w
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    Ks, Rs, ts = [], [], []
    for v in range(views):
        a = 2 * math.pi * v / views
        c = np.array([3.5 * math.cos(a), 3.5 * math.sin(a), 1.1])
        z = np.array([0.0, 0.0, 1.0]) - c
        z /= np.linalg.norm(z)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        Ks.append(K)
        Rs.append(R)
        ts.append(-R @ c)
    return camera.from_opencv(
        np.stack(Ks), np.zeros((views, 5)), np.stack(Rs), np.stack(ts), image_size=[size] * views
    )


def observation(rig: camera.Rig, seed: int = 0):
    rng = np.random.default_rng(seed)
    w, h = rig.image_size[0]
    V = rig.num_views
    fg, dt = [], []
    for _ in range(V):
        noise = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), max(w / 40, 1))
        mask = (noise > np.median(noise)).astype(np.uint8)
        edges = cv2.Canny(mask * 255, 50, 150)
        fg.append(mask.astype(np.float32))
        dt.append(cv2.distanceTransform((edges == 0).astype(np.uint8), cv2.DIST_L2, 3).astype(np.float32))
    return make_observation(rig, foreground=fg, edge_dt=dt)


def _peak_mb(jitted, *args) -> float:
    """Megabytes of arguments + outputs + temporaries (− aliased) of ``jitted`` compiled for ``args``."""
    m = jitted.lower(*args).compile().memory_analysis()
    total = m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes - m.alias_size_in_bytes
    return total / 2**20


def _median(fn, repeats: int) -> float:
    """Median seconds of ``fn()`` until its result is ready, after one call that compiles."""
    return common.median_seconds(lambda: jax.block_until_ready(fn()), repeats, warmup=1)


def _particles(model, n: int, seed: int = 0) -> jnp.ndarray:
    x = np.asarray(model.rest_pose, np.float32)
    X = x + np.random.default_rng(seed).normal(0, 0.05, (n, x.size)).astype(np.float32)
    return jnp.asarray(X)


def _likelihood(model, rig, layers: int = 1, points: int = 600):
    cues = [lk.Cue("foreground", 1.0), lk.Cue("edge_distance", 1.0)]
    return lk.Likelihood.create(model, rig, cues, num_layers=layers, surface_points=points)


def run(quick: bool = False, repeats: int = 7) -> dict:
    """Rows ``{"axis", "value", "seconds", "per_particle_us"}`` for the four sweeps."""
    model = body.build("full25")
    if quick:
        ns, layers, views, sizes, repeats, n_fixed = (50,), (2,), (1,), ((160, 120),), 1, 50
    else:
        ns = (100, 1000, 10000)
        layers, views, sizes, n_fixed = (1, 3, 5), (1, 2, 4), ((160, 120), (320, 240), (640, 480)), 1000
    pts = 100 if quick else 600
    rows = []
    base = {}  # (2 views, 320×240, N) → seconds: the particle sweep's points, reused by the other sweeps
    rig2 = ring_rig(2, (320, 240))
    obs2 = observation(rig2)
    lik = _likelihood(model, rig2, 1, pts)
    f = jax.jit(lambda X, o: lik.batch(X, o, 0))
    for n in ns:
        X = _particles(model, n)
        s = base[n] = _median(lambda X=X: f(X, obs2), repeats)
        mem = base[("mb", n)] = _peak_mb(f, X, obs2)
        rows.append(
            {"axis": "particles", "value": n, "seconds": s, "per_particle_us": s / n * 1e6, "mb": mem}
        )
    n_l = 20 if quick else 200
    for L in layers:
        likL = _likelihood(model, rig2, L, pts)
        flt = make_filter(
            "apf",
            lambda X, o, layer, likL=likL: likL.batch(X, o, layer),
            model,
            diffusion_std(model),
            n_l,
            L,
            prior_mean=np.asarray(model.rest_pose),
            prior_std=3 * diffusion_std(model),
        )
        state = flt.init(jax.random.key(0), model.rest_pose, jnp.asarray(diffusion_std(model)))
        step = jax.jit(flt.step)
        s = _median(lambda step=step, state=state: step(jax.random.key(1), state, obs2)[0].particles, repeats)
        mem = _peak_mb(step, jax.random.key(1), state, obs2)
        rows.append(
            {"axis": "layers", "value": L, "seconds": s, "per_particle_us": s / (n_l * L) * 1e6, "mb": mem}
        )
    X = _particles(model, n_fixed)
    for V in views:
        if V == 2 and n_fixed in base:
            rows.append(
                {
                    "axis": "views",
                    "value": V,
                    "seconds": base[n_fixed],
                    "per_particle_us": base[n_fixed] / n_fixed * 1e6,
                    "mb": base[("mb", n_fixed)],
                }
            )
            continue
        rig = ring_rig(V, (320, 240))
        o = observation(rig)
        likV = _likelihood(model, rig, 1, pts)
        fV = jax.jit(lambda X, o, likV=likV: likV.batch(X, o, 0))
        s = _median(lambda fV=fV, o=o: fV(X, o), repeats)
        mem = _peak_mb(fV, X, o)
        rows.append(
            {"axis": "views", "value": V, "seconds": s, "per_particle_us": s / n_fixed * 1e6, "mb": mem}
        )
    for size in sizes:
        if size == (320, 240) and n_fixed in base:
            s = base[n_fixed]
            rows.append(
                {
                    "axis": "image size",
                    "value": "320x240",
                    "seconds": s,
                    "per_particle_us": s / n_fixed * 1e6,
                    "mb": base[("mb", n_fixed)],
                }
            )
            continue
        rig = ring_rig(2, size)
        o = observation(rig)
        likS = _likelihood(model, rig, 1, pts)
        fS = jax.jit(lambda X, o, likS=likS: likS.batch(X, o, 0))
        s = _median(lambda fS=fS, o=o: fS(X, o), repeats)
        rows.append(
            {
                "axis": "image size",
                "value": f"{size[0]}x{size[1]}",
                "seconds": s,
                "per_particle_us": s / n_fixed * 1e6,
                "mb": _peak_mb(fS, X, o),
            }
        )
    return {"rows": rows, "n_layers": n_l, "n_fixed": n_fixed, "repeats": repeats}


def _growth(rows, axis, key="seconds") -> str:
    r = [x for x in rows if x["axis"] == axis]
    if len(r) < 2 or axis == "image size":
        return ""
    v = np.log([float(x["value"]) for x in r])
    t = np.log([x[key] for x in r])
    k = np.polyfit(v, t, 1)[0]
    return f"{'time' if key == 'seconds' else 'memory'} ∝ {axis}^{k:.2f}"


def to_markdown(res: dict) -> str:
    rows = res["rows"]
    lines = [
        "| sweep | value | median time (ms) | µs per particle-evaluation | peak memory (MB) |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['axis']} | {r['value']} | {r['seconds'] * 1e3:.2f} | {r['per_particle_us']:.2f} | "
            f"{r['mb']:.1f} |"
        )
    axes = ("particles", "layers", "views")
    fits = [g for g in [_growth(rows, a) for a in axes] + [_growth(rows, a, "mb") for a in axes] if g]
    note = (
        f"\nFixed: 2 views, 320×240, N = {res['n_fixed']} (views / size sweeps), N = {res['n_layers']} per layer "
        f"(layers sweep: one APF step), full25, cues foreground + edge_distance; median of {res['repeats']} after "
        "compilation. Log-log slopes: " + "; ".join(fits) + "."
    )
    return "\n".join(lines) + "\n" + note


def plot(res: dict, path: pathlib.Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = res["rows"]
    fig, axs = plt.subplots(2, 4, figsize=(16, 6.4))
    for ax, mem_ax, axis, xlabel in zip(
        axs[0],
        axs[1],
        ("particles", "layers", "views", "image size"),
        ("particles N", f"annealing layers L (APF step, N = {res['n_layers']})", "views", "image size"),
        strict=True,
    ):
        r = [x for x in rows if x["axis"] == axis]
        xs = list(range(len(r))) if axis == "image size" else [x["value"] for x in r]
        ax.plot(xs, [x["seconds"] * 1e3 for x in r], "o-")
        mem_ax.plot(xs, [x["mb"] for x in r], "s-", color="C1")
        for a, unit in ((ax, "ms"), (mem_ax, "peak MB")):
            if axis == "particles":
                a.set_xscale("log")
                a.set_yscale("log")
            if axis == "image size":
                a.set_xticks(xs, [x["value"] for x in r])
            a.set_xlabel(xlabel)
            a.set_ylabel(unit)
            a.grid(alpha=0.3)
    fig.suptitle("Likelihood cost: time (top) and peak memory of the compiled call (bottom); full25, CPU")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv=None) -> str:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny sweeps (smoke test); writes nothing")
    ap.add_argument("--repeats", type=int, default=7)
    a = ap.parse_args(argv)
    res = run(a.quick, a.repeats)
    md = to_markdown(res)
    print(md)
    if not a.quick:
        plot(res, common.RESULTS / "scaling.png")
        cmd = f"python {common.script(__file__)}"
        common.write_result(
            common.RESULTS / "scaling.md",
            f"# Likelihood scaling\n\nCommand: `.venv/bin/{cmd}`; plot: `scaling.png`.\n\n" + md + "\n",
            cmd,
        )
    return md


if __name__ == "__main__":
    main()
