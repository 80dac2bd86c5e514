"""Speed of the composed cue likelihood (``Likelihood.batch``, jitted) against a NumPy implementation of the same
computation in the same process (issue 5).

Configurations (2 views, 640×480, synthetic observation maps; :data:`scenes.CONFIGS`):

* ``upper14-iros``: ``upper14`` with the IROS 2007 cue set (edge_distance, colour_histogram, blobs3d, skin,
  homogeneous_colour); target ≥ 100 k particles/s on 2 cores;
* ``full25-lk``: ``full25`` with edges + foreground + depth; target ≥ 50 k particles/s.

Particles are drawn around a standing pose in view of both cameras. JAX: median (and minimum) wall time of
``--repeats`` calls after compilation. NumPy: the same FK (twists), flesh points, occluding contours,
projection, facing test, nearest-pixel lookups and cue energies, vectorised over particles (float32,
:class:`reference.numpy_baselines.NumpyLikelihood`), median of ``--numpy-repeats``; both are checked to agree on the first 64 particles before timing.

``upper14-iros-P300`` / ``-P150``: the IROS 2007 set with 300 / 150 flesh surface samples instead of 600 (the
cost is linear in them). ``--per-cue`` times each IROS 2007 cue alone, with the geometry it needs. ``--sweep``
times the first two configurations at 10², 10³, 10⁴ and 10⁵ particles, each against NumPy.

``--divergence`` times the foreground divergence (López Méndez eq. 4.6) side by side, before and after its
undistorted sample grid became a host-side table (:func:`jaxmocap.likelihood.cues._grid_rays`): the
``lopez-mendez`` preset's likelihood (``upper9``, all five cues) at 200 particles, with the samples undistorted in
the compiled program as before (the path a traced rig takes) and read from the table, and without the divergence;
interleaved rounds (each the median of ``--repeats`` calls), the median before/after ratio, the load average, and
the largest difference of the two log-likelihoods.

``--chunks`` times the particle chunks of ``Likelihood.batch`` side by side: equal chunks of at most
``chunk_size`` (``n = ⌈N / 128⌉`` chunks of ``⌈N / n⌉``, 200 particles as 2 × 100) against the former padding of
every batch to a multiple of ``chunk_size`` (200 as 2 × 128, 56 copies evaluated and dropped), emulated by padding
the batch before the call; ``upper14-iros`` and ``full25-lk`` at 200, 300 and 1000 particles; interleaved rounds
(each the mean of 5 calls), the per-round ratio padded / equal and its median, the load average; the two give
the same values bit for bit (checked).

    .venv/bin/python benchmarks/perf/bench_likelihood.py [--particles 8192] [--repeats 7] [--per-cue] [--sweep] [--quick]
    .venv/bin/python benchmarks/perf/bench_likelihood.py --configs --divergence [--rounds 15]
    .venv/bin/python benchmarks/perf/bench_likelihood.py --configs --chunks [--rounds 15]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common
from reference.numpy_baselines import NumpyLikelihood
from scenes import CONFIGS, SAMPLE_SWEEP, build, particles

from jaxmocap.likelihood import compose as L


def run(config, n, repeats, np_repeats, rng):
    model, rig, obs, lik, target = build(config, rng)
    X = jnp.asarray(particles(model, n, rng))
    fj = jax.jit(lik.batch)
    t0 = time.perf_counter()
    ll = np.asarray(fj(X, obs, 0))
    compile_s = time.perf_counter() - t0
    nl = NumpyLikelihood(lik, obs)
    Xn = np.asarray(X)
    ref = nl(Xn[:64])
    # nearest-pixel rounding of a sample exactly on a pixel edge may differ between the two: compare robustly
    rel = np.abs(ll[:64] - ref) / np.maximum(np.abs(ref), 1e-3)
    agree = float(np.median(rel)), float(np.quantile(rel, 0.9))
    tj = common.timed_calls(lambda: fj(X, obs, 0).block_until_ready(), repeats).wall
    tn = common.timed_calls(lambda: nl(Xn), np_repeats).wall
    return dict(
        config=config,
        particles=n,
        compile_s=compile_s,
        jax_s=float(np.median(tj)),
        jax_min_s=float(np.min(tj)),
        numpy_s=float(np.median(tn)),
        jax_pps=n / float(np.median(tj)),
        numpy_pps=n / float(np.median(tn)),
        target=target,
        agree=agree,
        P=lik.surface.local.shape[0],
    )


def per_cue(config: str, n: int, repeats: int, rng) -> list[tuple[str, float]]:
    """``(cue, median seconds)`` of the jitted likelihood of each cue of ``config`` alone (same particles and
    surface samples; each includes the FK / projection that cue needs, which the full set shares), then of the
    full set."""
    model, rig, obs, lik, _ = build(config, rng)
    X = jnp.asarray(particles(model, n, rng))
    points = lik.surface.local.shape[0]
    out = []
    for cue in lik.cues:
        one = L.Likelihood.create(model, rig, [cue], surface_points=points)
        if one.needs_references:
            one = one.with_references(model.rest_pose, obs)
        f = jax.jit(one.batch)
        f(X, obs, 0).block_until_ready()
        out.append((cue.name, common.median_seconds(lambda f=f: f(X, obs, 0).block_until_ready(), repeats)))
    f = jax.jit(lik.batch)
    f(X, obs, 0).block_until_ready()
    out.append(("all together", common.median_seconds(lambda: f(X, obs, 0).block_until_ready(), repeats)))
    return out


def divergence_side_by_side(n: int, rounds: int, repeats: int, rng) -> dict:
    """Median seconds per ``Likelihood.batch`` call of the ``lopez-mendez`` preset's cues at ``n`` particles:
    ``before`` (the divergence's samples undistorted in the compiled program), ``after`` (read from the host
    table), ``without`` (the preset's cues without the divergence), and the same for the divergence alone;
    interleaved rounds. Returns name → ``(rounds,)`` medians, ``diff`` (largest |Δ log-likelihood|, before
    against after) and the load averages."""
    from unittest import mock

    from scenes import observation, stereo_rig

    from jaxmocap.geometry import body
    from jaxmocap.likelihood import cues
    from jaxmocap.tracking.presets.lopez_mendez import ALL_CUES, CLASSIC_CUES

    model, rig = body.upper9(), stereo_rig()
    obs = observation(rig, rng)
    X = jnp.asarray(particles(model, n, rng))

    def compiled(names: str, traced_grid: bool):
        lik = L.Likelihood.create(model, rig, [L.Cue(c) for c in names.split(",")], num_layers=3)
        f = jax.jit(lambda X, o: lik.batch(X, o, 0))
        traced = mock.patch.object(cues, "_grid_rays", lambda rig, grid: None)
        with traced if traced_grid else contextlib.nullcontext():
            f(X, obs).block_until_ready()  # compiled here, with or without the host table
        return f

    fns = {
        "before": compiled(ALL_CUES, True),
        "after": compiled(ALL_CUES, False),
        "without": compiled(CLASSIC_CUES, False),
        "alone before": compiled("silhouette_divergence", True),
        "alone after": compiled("silhouette_divergence", False),
    }
    diff = float(jnp.max(jnp.abs(fns["before"](X, obs) - fns["after"](X, obs))))
    load0 = os.getloadavg()[0]
    times = {k: [] for k in fns}
    for _ in range(rounds):
        for k, f in fns.items():
            times[k].append(common.median_seconds(lambda f=f: f(X, obs).block_until_ready(), repeats))
    return {
        **{k: np.asarray(v) for k, v in times.items()},
        "diff": diff,
        "load": (load0, os.getloadavg()[0]),
    }


def print_divergence(n: int, rounds: int, repeats: int, rng) -> None:
    r = divergence_side_by_side(n, rounds, repeats, rng)
    print(
        f"\nForeground divergence before/after the host-side sample grid: lopez-mendez cues, upper9, {n} particles, "
        f"{rounds} interleaved rounds of {repeats} calls, load average {r['load'][0]:.1f} -> {r['load'][1]:.1f}"
    )
    print(
        "| likelihood | before ms | after ms | before / after (median of the rounds' ratios) |\n|---|---|---|---|"
    )
    for label, b, a in (
        ("all five cues", "before", "after"),
        ("divergence alone", "alone before", "alone after"),
    ):
        ratio = np.median(r[b] / r[a])
        print(f"| {label} | {np.median(r[b]) * 1e3:.2f} | {np.median(r[a]) * 1e3:.2f} | {ratio:.2f}× |")
    w = np.median(r["without"])
    print(
        f"| without the divergence | | {w * 1e3:.2f} | divergence's share after: "
        f"{np.median(r['after'] / r['without']):.2f}× the four cues |"
    )
    print(f"largest |log-likelihood before − after|: {r['diff']:.2e}")


def chunks_side_by_side(rounds: int) -> None:
    """``--chunks`` (module docstring): one table row per configuration and particle count."""
    print("\nParticle chunks of Likelihood.batch: equal chunks against padding to a multiple of chunk_size")
    print("| config | particles | padded to | ratio per round (padded / equal time) | median | load |")
    print("|---|---|---|---|---|---|")
    for cfg in CONFIGS:
        model, _, obs, lik, _ = build(cfg, np.random.default_rng(0))
        for n in (200, 300, 1000):
            padded = -(-n // lik.chunk_size) * lik.chunk_size
            X = jnp.asarray(particles(model, n, np.random.default_rng(n)))
            equal = jax.jit(lambda X, o, lik=lik: lik.batch(X, o, 0))

            def pad(X, o, lik=lik, n=n, padded=padded):
                copies = jnp.broadcast_to(X[:1], (padded - n, X.shape[1]))
                return lik.batch(jnp.concatenate([X, copies]), o, 0)[:n]

            pad = jax.jit(pad)
            if not np.array_equal(np.asarray(equal(X, obs)), np.asarray(pad(X, obs))):
                raise AssertionError(f"{cfg}, {n} particles: the two chunkings differ")
            ratios = []
            for r in range(rounds):
                t = {}
                for name, f in (("pad", pad), ("equal", equal))[:: 1 if r % 2 else -1]:
                    calls = common.timed_calls(
                        lambda f=f, X=X, o=obs: f(X, o).block_until_ready(), 5, warmup=1
                    )
                    t[name] = float(calls.wall.sum())
                ratios.append(t["pad"] / t["equal"])
            text = ", ".join(f"{q:.2f}" for q in ratios)
            print(
                f"| {cfg} | {n} | {padded} | {text} | **{np.median(ratios):.2f}** | {os.getloadavg()[0]:.2f} |",
                flush=True,
            )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--particles", type=int, default=8192)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--numpy-repeats", type=int, default=3)
    ap.add_argument(
        "--configs",
        nargs="*",
        default=None,
        help=f"default: all of {[*CONFIGS, *SAMPLE_SWEEP]} (quick: the first two)",
    )
    ap.add_argument("--quick", action="store_true", help="1024 particles, 3 repeats, 1 NumPy repeat")
    ap.add_argument(
        "--sweep",
        action="store_true",
        help="also time upper14-iros and full25-lk at 10^2 ... 10^5 particles against NumPy (1 NumPy repeat)",
    )
    ap.add_argument(
        "--per-cue",
        action="store_true",
        help="also time each cue of upper14-iros alone (where its time goes)",
    )
    ap.add_argument(
        "--divergence",
        action="store_true",
        help="also time the divergence cue before/after its host-side sample grid (lopez-mendez cues, 200 particles)",
    )
    ap.add_argument(
        "--chunks",
        action="store_true",
        help="also time equal particle chunks against padding to a multiple of chunk_size (200, 300, 1000 particles)",
    )
    ap.add_argument("--rounds", type=int, default=15, help="interleaved rounds of --divergence and --chunks")
    a = ap.parse_args(argv)
    if a.quick:
        a.particles, a.repeats, a.numpy_repeats = 1024, 3, 1
    if a.configs is None:
        a.configs = list(CONFIGS) if a.quick else [*CONFIGS, *SAMPLE_SWEEP]
    rng = np.random.default_rng(0)
    print(f"jax {jax.__version__}, {jax.devices()[0].platform}, load average {os.getloadavg()[0]:.2f}")
    print(
        "| config | P | particles | JAX median (min) s | JAX particles/s | NumPy s | NumPy particles/s | "
        "speed-up | target | rel. diff median / p90 |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for cfg in a.configs:
        r = run(cfg, a.particles, a.repeats, a.numpy_repeats, rng)
        print(
            f"| {cfg} | {r['P']} | {r['particles']} | {r['jax_s']:.4f} ({r['jax_min_s']:.4f}) | "
            f"{r['jax_pps']:,.0f} | {r['numpy_s']:.3f} | {r['numpy_pps']:,.0f} | "
            f"{r['numpy_s'] / r['jax_s']:.1f}× | {r['target']:,} | {r['agree'][0]:.1e} / {r['agree'][1]:.1e} |",
            flush=True,
        )
    if a.sweep:
        print("\nThroughput against the particle count (JAX: median of the repeats; NumPy: one run):")
        print(
            "| config | particles | JAX particles/s | NumPy particles/s | speed-up |\n|---|---|---|---|---|"
        )
        for cfg in CONFIGS:
            for n in (100, 1_000, 10_000, 100_000):
                r = run(cfg, n, a.repeats, 1, rng)
                print(
                    f"| {cfg} | {n:,} | {r['jax_pps']:,.0f} | {r['numpy_pps']:,.0f} | "
                    f"{r['numpy_s'] / r['jax_s']:.1f}× |",
                    flush=True,
                )
    if a.per_cue:
        print(f"\nupper14-iros, each cue alone ({a.particles} particles, with the geometry that cue needs):")
        print("| cue | median ms | particles/s |\n|---|---|---|")
        for name, sec in per_cue("upper14-iros", a.particles, a.repeats, rng):
            print(f"| {name} | {sec * 1e3:.1f} | {a.particles / sec:,.0f} |", flush=True)
    if a.divergence:
        print_divergence(200, a.rounds, a.repeats, rng)
    if a.chunks:
        chunks_side_by_side(a.rounds)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
