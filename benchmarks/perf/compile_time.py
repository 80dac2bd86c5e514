"""XLA compile time of the hot programs, per body model: forward kinematics, the tracker's likelihood, one APF step.

For each model (``upper9``, ``upper14``, ``full25``) and piece:

* ``fk``: ``body.segment_poses`` vmapped over the particles;
* ``likelihood``: the log-likelihood the tracker builds with its default cues
  (:func:`jaxmocap.tracking.tracker.default_cues`: ``foreground``, ``edge_distance`` and the ``coverage`` term,
  plus ``depth`` on ``full25`` with ``--depth``) over all particles of a layer;
* ``apf``: one frame of the annealed particle filter (:func:`jaxmocap.tracking.tracker.make_filter`, default
  particles and layers), the program ``jaxmocap track`` compiles before its first frame;

the time to trace and lower (``jit(...).lower``), to compile the lowered module (``.compile()``, XLA), and the
size of the lowered module in lines of StableHLO text (the CPU compiler's time grows with it). The persistent
compilation cache is off, each program is new to the process (``--isolate``: each row in a fresh interpreter, as
``jaxmocap track`` sees it). Scene: two 640×480 views 30 cm apart, 3.5 m from the subject; synthetic maps (the
compile time does not depend on their content). Prints a markdown table.

    python benchmarks/perf/compile_time.py [--models upper9 upper14 full25] [--pieces fk likelihood apf]
                                           [--particles 8192] [--depth] [--isolate] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import jax

jax.config.update("jax_enable_compilation_cache", False)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxmocap.features.observation import make_observation  # noqa: E402
from jaxmocap.geometry import body, camera  # noqa: E402
from jaxmocap.likelihood import compose as lk  # noqa: E402
from jaxmocap.synth.generate import look_at  # noqa: E402
from jaxmocap.tracking import tracker as tr  # noqa: E402

MODELS = ("upper9", "upper14", "full25")
PIECES = ("fk", "likelihood", "apf")
W, H = 640, 480


def stereo_rig() -> camera.Rig:
    """Two cameras 30 cm apart, 1.3 m high, 3.5 m from the subject, 640×480."""
    Rs, ts = zip(*[look_at(np.array([3.5, y, 1.3]), [0.0, 0.0, 1.0]) for y in (-0.15, 0.15)], strict=True)
    K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
    return camera.from_opencv(
        np.stack([K, K]), np.zeros((2, 5)), np.stack(Rs), np.stack(ts), image_size=[(W, H)] * 2
    )


def observation(rig: camera.Rig, depth: bool, samples: int = 128) -> tr.TrackObservation:
    """Blocky random maps (foreground, edge distances, depth) and silhouette samples, as the tracker's frame."""
    rng = np.random.default_rng(0)
    small = rng.uniform(0.0, 1.0, (2, H // 16 + 1, W // 16 + 1)).astype(np.float32)
    field = np.repeat(np.repeat(small, 16, 1), 16, 2)[:, :H, :W]
    fg = (field > 0.3).astype(np.float32)
    obs = make_observation(
        rig,
        foreground=fg,
        edges=field,
        edge_dt=40.0 * field,
        depth=np.where(fg > 0, 2.5 + field, 0.0).astype(np.float32) if depth else None,
    )
    uv = np.stack([rng.uniform((0, 0), (W - 1, H - 1), (samples, 2)) for _ in range(2)]).astype(np.float32)
    w = np.ones((2, samples), np.float32)
    return tr.TrackObservation(obs, jnp.asarray(uv), jnp.asarray(w), jnp.zeros(0), jnp.asarray(False))


def tracker_loglik(model: body.BodyModel, rig: camera.Rig, depth: bool, layers: int):
    """``loglik(X, tobs, layer) -> (N,)`` of the tracker with its default cues (image cues through
    :class:`jaxmocap.likelihood.compose.Likelihood`, the coverage term through
    :func:`jaxmocap.tracking.tracker.coverage_energy`, the APF schedule)."""
    cues = tr.default_cues(model.name, depth, False)
    names = [n for n, _ in cues]
    table = lk.schedule_preset(
        "apf", ["silhouette_divergence" if n == "coverage" else n for n in names], layers
    )
    image = [(i, n, w) for i, (n, w) in enumerate(cues) if n not in tr.TRACKER_CUES]
    lik = lk.Likelihood.create(
        model,
        rig,
        [lk.Cue(n, w) for _, n, w in image],
        num_layers=layers,
        schedule=table[:, [i for i, _, _ in image]],
    )
    cov = [(i, w) for i, (n, w) in enumerate(cues) if n == "coverage"]
    cov_lam = jnp.asarray(table[:, cov[0][0]] * cov[0][1], jnp.float32)
    rj = rig.to_jax(jnp.float32)
    d_max = jnp.asarray([max(1.0, tr.COVERAGE_DMAX * w) for w, _ in rig.image_size], jnp.float32)

    def loglik(X, tobs, layer):
        l = jnp.clip(jnp.asarray(getattr(layer, "index", layer)), 0, layers - 1)
        ll = lik.batch(X, tobs.image, l)
        e = jax.vmap(lambda x: jnp.sum(tr.coverage_energy(model, rj, x, tobs.cover_uv, tobs.cover_w, d_max)))(
            X
        )
        ll = ll - cov_lam[l] * e
        return jnp.where(jnp.isfinite(ll), ll, -jnp.inf)

    return loglik


def program(model_name: str, piece: str, particles: int, depth: bool):
    """``(jitted function, arguments, particles)`` of one piece."""
    model = body.build(model_name)
    rig = stereo_rig()
    layers = tr.default_layers("apf")[0]
    n = particles if piece != "apf" else tr.default_particles(model_name, "apf")
    x0 = np.asarray(model.rest_pose, np.float32)
    X = jnp.asarray(x0 + 0.05 * np.random.default_rng(1).normal(size=(n, model.num_dofs)), jnp.float32)
    if piece == "fk":
        return jax.jit(jax.vmap(lambda x: body.segment_poses(model, x))), (X,), n
    tobs = observation(rig, depth)._replace(center=jnp.zeros(model.num_dofs, jnp.float32))
    loglik = tracker_loglik(model, rig, depth and model_name == "full25", layers)
    if piece == "likelihood":
        return jax.jit(loglik), (X, tobs, 0), n
    std = tr.diffusion_std(model)
    filt = tr.make_filter("apf", loglik, model, std, n, layers, prior_mean=x0, prior_std=3.0 * std)
    state = filt.init(jax.random.key(0), jnp.asarray(x0))
    return jax.jit(filt.step), (jax.random.key(1), state, tobs), n


def measure(model_name: str, piece: str, particles: int, depth: bool) -> dict:
    f, args, n = program(model_name, piece, particles, depth)
    t0 = time.perf_counter()
    lowered = f.lower(*args)
    t1 = time.perf_counter()
    lowered.compile()
    t2 = time.perf_counter()
    return dict(
        model=model_name,
        piece=piece,
        particles=n,
        lower_s=t1 - t0,
        compile_s=t2 - t1,
        hlo_lines=len(lowered.as_text().splitlines()),
    )


def _isolated(model_name: str, piece: str, particles: int, depth: bool) -> dict:
    """:func:`measure` in a fresh interpreter (no compiled program or trace shared with earlier rows)."""
    cmd = [sys.executable, __file__, "--row", model_name, piece, str(particles)] + (
        ["--depth"] if depth else []
    )
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env={**os.environ})
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", nargs="*", default=list(MODELS), choices=MODELS)
    ap.add_argument("--pieces", nargs="*", default=list(PIECES), choices=PIECES)
    ap.add_argument(
        "--particles", type=int, default=8192, help="particles of fk and likelihood (default 8192)"
    )
    ap.add_argument(
        "--depth", action="store_true", help="the input has depth maps (full25 adds the depth cue)"
    )
    ap.add_argument("--isolate", action="store_true", help="each row in a fresh interpreter")
    ap.add_argument("--quick", action="store_true", help="upper9 only, 256 particles (smoke test)")
    ap.add_argument("--row", nargs=3, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.row:
        print(json.dumps(measure(a.row[0], a.row[1], int(a.row[2]), a.depth)))
        return
    if a.quick:
        a.models, a.particles = ["upper9"], 256
    print(f"jax {jax.__version__}, {jax.devices()[0].platform}, load average {os.getloadavg()[0]:.2f}")
    print("| model | piece | particles | lower s | compile s | HLO lines |\n|---|---|---|---|---|---|")
    for m in a.models:
        for p in a.pieces:
            r = (_isolated if a.isolate else measure)(m, p, a.particles, a.depth)
            print(
                f"| {r['model']} | {r['piece']} | {r['particles']} | {r['lower_s']:.2f} | {r['compile_s']:.2f} | "
                f"{r['hlo_lines']} |",
                flush=True,
            )
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
