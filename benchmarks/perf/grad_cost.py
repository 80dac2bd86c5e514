"""Cost of the log-likelihood's value and gradient for a batch of particles, in forward evaluations.

The gradient filters (``jaxmocap track --filter hybrid``, :mod:`jaxmocap.filters.hybrid`) pay one value-and-gradient
evaluation per moved particle and step; this script measures what one costs against one forward evaluation of the
same particles, in the same process:

* the input: a synthetic stereo sequence of the bundled CMU walk at 320×240 (:func:`jaxmocap.synth.generate.synthesize`,
  rendered once into a temporary folder), read as a recording is (:class:`scenes.PlateSource`: silhouettes by
  subtraction against the empty-scene plates, the simulated 2D detections), its first frame's observation built
  by the tracker's own setup (:class:`jaxmocap.tracking.setup.TrackSetup` with ``--filter hybrid``: the cues read
  bilinearly, as the gradient filters have them);
* the likelihood: the object the filter receives (``TrackSetup.loglik``), per model (``upper14``, ``full25``) and
  cue set (:data:`CUE_SETS`: the default image cues of ``jaxmocap track``, without and with ``depth`` (in the
  defaults of a full-body sequence with depth maps; its smooth variant, as the gradient filters take it), and with
  the default ``keypoints`` as well: the full default set; the silhouette cues with the 2D keypoints; each
  differentiable cue of those alone);
* the particles: ``N`` (200 and 1000) states around the first frame's initial pose (the ground truth's fit), with
  the spread of the tracker's diffusion;
* the programs, each compiled once: ``forward`` = the likelihood ``loglik(X, tobs, layer)``; ``fast`` =
  :func:`jaxmocap.likelihood.gradients.batch_value_and_grad` of it, the path the filter takes (the likelihood's own
  ``batch_value_and_grad``); ``general`` (``--general``, on the default set) = the same through
  :func:`jaxmocap.likelihood.gradients.vjp_value_and_grad`, one reverse pass through the chunked forward program
  (what any other batched likelihood gets);
* the timing: interleaved rounds; in each round every program runs twice in a row and the second run is timed
  (the first runs after the other programs have evicted its data from the caches); the table gives the medians
  over the rounds and the ratios of the medians; the load average is recorded at the start and the end.

    python benchmarks/perf/grad_cost.py [--models upper14 full25] [--cues LABEL ...] [--particles 200 1000]
                                        [--rounds 9]
                                        [--general] [--against REV] [--out benchmarks/results/grad_cost.md] [--quick]

``--against REV`` adds, on every row, the forward pass and the value and gradient of the ``jaxmocap`` package at
git revision ``REV`` (:func:`common.package_at`), timed in the same rounds, with the per-round ratios of this
checkout's to them (a change to the gradient path must not slow the forward one).
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import tempfile
import time

os.environ.setdefault("JAX_PLATFORMS", "cpu")

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

import common  # noqa: E402

#: label -> ``--cues`` of the cue sets measured (keypoints weighted as the pose2sim experiment weighs them)
CUE_SETS = {
    "track default": "foreground,edge_distance,coverage:4",
    "track default + depth": "foreground,edge_distance,coverage:4,depth",
    "full default": "foreground,edge_distance,coverage:4,depth,keypoints:32",
    "depth": "depth",
    "keypoints + silhouette": "foreground,coverage:4,keypoints:4",
    "foreground": "foreground",
    "edge_distance": "edge_distance",
    "coverage": "coverage:4",
    "keypoints": "keypoints:4",
}
COMMAND = (
    "python benchmarks/perf/grad_cost.py --models full25 upper14 --cues 'track default' 'keypoints + silhouette' "
    "foreground edge_distance coverage keypoints --rounds 7 --general --against b961c58 "
    "--out benchmarks/results/grad_cost.md"
)


def make_sequence(folder: pathlib.Path, size: str) -> pathlib.Path:
    """Four frames of the bundled CMU walk, stereo, with simulated detections."""
    from jaxmocap.synth import generate as synth

    out = folder / "seq"
    synth.synthesize("demo", out, rig="stereo", frames="0:4", fps=30.0, size=size, seed=0, overwrite=True)
    return out


def programs(seq: pathlib.Path, model: str, cues: str, n: int, general: bool, package: str = "jaxmocap"):
    """``({name: compiled program}, arguments)`` of one row (module docstring), with the modules of ``package``
    (``jaxmocap_at_rev``: the package at ``--against REV``, :func:`common.package_at`)."""
    import importlib

    import jax
    import jax.numpy as jnp
    import numpy as np
    import scenes

    gradients = importlib.import_module(f"{package}.likelihood.gradients")
    TrackOptions = importlib.import_module(f"{package}.tracking.options").TrackOptions
    TrackSetup = importlib.import_module(f"{package}.tracking.setup").TrackSetup

    source = scenes.PlateSource(seq)
    opts = TrackOptions(model=model, filter="hybrid", cues=cues, foreground="mask", init="groundtruth")
    setup = TrackSetup(source, opts)
    t0 = setup.frames[0]
    tobs, masks, fd, _ = setup.observe(t0)
    x0, _, _ = setup.initial_state(t0, masks, fd)
    noise = np.random.default_rng(0).normal(size=(n, setup.model.num_dofs))
    X = jnp.asarray(np.asarray(x0) + noise * np.asarray(setup.std), jnp.float32)
    loglik = setup.loglik
    layer = setup.layers - 1
    fns = {
        "forward": lambda X, o: loglik(X, o, layer),
        "fast": lambda X, o: gradients.batch_value_and_grad(loglik, X, o, layer),
    }
    if general:
        fns["general"] = lambda X, o: gradients.vjp_value_and_grad(loglik, X, o, layer)
    compiled = {k: jax.jit(f).lower(X, tobs).compile() for k, f in fns.items()}
    return compiled, (X, tobs)


def timed_rounds(compiled: dict, args: tuple, rounds: int, own_args: dict | None = None) -> dict:
    """Seconds per program over ``rounds`` interleaved rounds (each program run twice, the second run timed);
    ``own_args``: the arguments of programs that take others than ``args``."""
    import jax

    def second(f, a):
        jax.block_until_ready(f(*a))
        t = time.perf_counter()
        jax.block_until_ready(f(*a))
        return time.perf_counter() - t

    own_args = own_args or {}
    samples = {k: [] for k in compiled}
    for _ in range(rounds):
        for k, f in compiled.items():
            samples[k].append(second(f, own_args.get(k, args)))
    return samples


def row(seq, model: str, label: str, n: int, rounds: int, general: bool, against: str | None = None) -> dict:
    """One row: medians, ratios, and with ``against`` the forward pass and the value and gradient at that revision
    (``before_forward``, ``before``) timed in the same rounds, with their per-round ratios to this checkout's."""
    import numpy as np

    compiled, args = programs(seq, model, CUE_SETS[label], n, general)
    own = {}
    if against is not None:
        at, own["before"] = programs(seq, model, CUE_SETS[label], n, False, "jaxmocap_at_rev")
        compiled["before"] = at["fast"]
        compiled["before_forward"], own["before_forward"] = at["forward"], own["before"]
    t = timed_rounds(compiled, args, rounds, own)
    med = {k: float(np.median(v)) for k, v in t.items()}
    out = dict(model=model, cues=label, n=n, **{f"{k}_ms": v * 1e3 for k, v in med.items()})
    out["fast_ratio"] = med["fast"] / med["forward"]
    if "general" in med:
        out["general_ratio"] = med["general"] / med["forward"]
    if "before" in med:
        out["before_ratio"] = med["before"] / med["before_forward"]
        for key, now, then in (
            ("now_over_before", "fast", "before"),
            ("forward_now_over_before", "forward", "before_forward"),
        ):
            per_round = np.asarray(t[now]) / np.asarray(t[then])
            out[key] = (float(np.median(per_round)), float(per_round.min()), float(per_round.max()))
    return out


def against_table(rows: list[dict]) -> list[str]:
    """The rows with a ``before`` program: both ratios to the forward pass and the per-round ratios now / before."""
    lines = [
        "| model | cues | N | before ms | ÷ its forward | now ms | ÷ forward | now ÷ before, median of rounds [range] "
        "| forward: now ÷ before [range] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "before_ms" in r:
            m, lo, hi = r["now_over_before"]
            fm, flo, fhi = r["forward_now_over_before"]
            lines.append(
                f"| {r['model']} | {r['cues']} | {r['n']} | {r['before_ms']:.2f} | {r['before_ratio']:.2f} | "
                f"{r['fast_ms']:.2f} | {r['fast_ratio']:.2f} | **{m:.3f}** [{lo:.2f}–{hi:.2f}] | "
                f"{fm:.3f} [{flo:.2f}–{fhi:.2f}] |"
            )
    return lines


def table(rows: list[dict]) -> list[str]:
    lines = [
        "| model | cues | N | forward ms | value + gradient ms | ÷ forward | general path ms | ÷ forward |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        gen = f"{r['general_ms']:.1f} | {r['general_ratio']:.2f}" if "general_ms" in r else "— | —"
        lines.append(
            f"| {r['model']} | {r['cues']} | {r['n']} | {r['forward_ms']:.2f} | {r['fast_ms']:.2f} | "
            f"**{r['fast_ratio']:.2f}** | {gen} |"
        )
    return lines


def main(argv=None) -> str:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", nargs="+", default=["upper14", "full25"])
    ap.add_argument(
        "--cues", nargs="+", default=list(CUE_SETS), choices=list(CUE_SETS), help="cue sets (labels)"
    )
    ap.add_argument("--particles", nargs="+", type=int, default=[200, 1000])
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--general", action="store_true", help="also the general path, on the track default set")
    ap.add_argument("--out", type=pathlib.Path, default=None)
    ap.add_argument("--quick", action="store_true", help="full25, the default set, N = 50, 3 rounds")
    ap.add_argument(
        "--against",
        metavar="REV",
        help="also the forward pass and the value and gradient at git revision REV, timed in the same rounds",
    )
    a = ap.parse_args(argv)
    if a.against:
        common.package_at(a.against, "tracking.setup")
    if a.quick:
        a.models, a.cues, a.particles, a.rounds, a.size = ["full25"], ["track default"], [50], 3, "160x120"
    load0 = os.getloadavg()[0]
    rows = []
    with tempfile.TemporaryDirectory() as d:
        seq = make_sequence(pathlib.Path(d), a.size)
        for model in a.models:
            for label in a.cues:
                for n in a.particles:
                    general = a.general and label == "track default"
                    rows.append(row(seq, model, label, n, a.rounds, general, a.against))
                    print(table(rows[-1:])[-1], flush=True)
    text = "\n".join(
        [
            "### Value and gradient of the tracker's likelihood, in forward evaluations (CPU)",
            "",
            *table(rows),
            "",
            f"{common.machine_line()} at the end ({load0:.1f} at the start); {a.rounds} rounds; {a.size}; "
            f"{common.stamp()}",
        ]
    )
    if a.against:
        text += (
            f"\n\n**This change against {a.against}** (its package imported beside this checkout's, "
            "timed in the same rounds), value + gradient, and the forward pass:\n\n"
            + "\n".join(against_table(rows))
        )
    print(text)
    if a.out is not None and not a.quick:
        common.write_result(a.out, text + "\n", COMMAND)
    return text


if __name__ == "__main__":
    main()
