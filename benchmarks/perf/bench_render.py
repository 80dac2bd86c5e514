"""Frames per second of the ray-casting renderer for one 640×480 view of a 16-primitive body.

Scene: a standing skeleton dressed in 15 cones and an ellipsoid head (:func:`jaxmocap.geometry.render.primitives_from_skeleton`)
seen from 3.5 m (the body covers a few percent of the image, as in a multi-view capture) and from 1.2 m (a
close-up: the body covers most of the frame — the worst case for screen-space culling). For each configuration
(caps, normals, tile size, culling on/off) the median time of a render after compilation, until the result is
ready, is printed as frames/s, with the ratio against the same configuration without culling (the baseline: every
pixel against every primitive), measured in the same process, interleaved.

    .venv/bin/python benchmarks/perf/bench_render.py [--repeats 30]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxmocap.geometry import render  # noqa: E402

W, H = 640, 480
K = np.array([[520.0, 0.0, 319.5], [0.0, 520.0, 239.5], [0.0, 0.0, 1.0]])

# joints (z up): pelvis, spine, neck, head top, arms (shoulder, elbow, wrist, hand) ×2, legs (hip, knee, ankle) ×2
JOINTS = np.array(
    [
        [0.0, 0.0, 1.0],
        [0.0, 0.0, 1.25],
        [0.0, 0.0, 1.45],
        [0.0, 0.0, 1.70],
        [0.0, 0.18, 1.42],
        [0.05, 0.22, 1.15],
        [0.25, 0.22, 1.05],
        [0.30, 0.22, 1.0],
        [0.0, -0.18, 1.42],
        [-0.05, -0.24, 1.15],
        [-0.05, -0.25, 0.9],
        [-0.05, -0.25, 0.82],
        [0.0, 0.09, 0.95],
        [0.1, 0.1, 0.55],
        [0.05, 0.1, 0.1],
        [0.0, -0.09, 0.95],
        [-0.05, -0.1, 0.55],
        [-0.02, -0.1, 0.1],
    ]
)
PARENTS = (-1, 0, 1, 2, 2, 4, 5, 6, 2, 8, 9, 10, 0, 12, 13, 0, 15, 16)
BONES = (1, 2, 4, 5, 6, 7, 8, 9, 10, 11, 13, 14, 16, 17, 12)
RADII = np.array(
    [0.13, 0.06, 0.05, 0.045, 0.035, 0.03, 0.05, 0.045, 0.035, 0.03, 0.07, 0.05, 0.07, 0.05, 0.06]
)


def look_at(centre, target):
    c = np.asarray(centre, float)
    f = np.asarray(target, float) - c
    f /= np.linalg.norm(f)
    x = np.cross(f, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(f, x), f])
    return jnp.asarray(R, jnp.float32), jnp.asarray(-R @ c, jnp.float32)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--quick", action="store_true", help="one view, culled vs not culled only (smoke test)")
    args = ap.parse_args(argv)

    prims = render.primitives_from_skeleton(
        jnp.asarray(JOINTS, jnp.float32),
        PARENTS,
        jnp.asarray(RADII, jnp.float32),
        bones=BONES,
        head=(2, 3),
        head_radius=0.09,
    )
    rays = jnp.asarray(render.pixel_rays(K, None, (W, H)))
    views = {
        "3.5 m": look_at([3.5, 0.3, 1.1], [0.0, 0.0, 1.0]),
        "1.2 m": look_at([1.2, 0.1, 1.0], [0.0, 0.0, 1.0]),
    }
    print(f"jax {jax.__version__}, {os.cpu_count()} CPUs, load average {os.getloadavg()}")
    print(
        f"{W}x{H}, {prims.num_cones} cones + {prims.num_ellipsoids} ellipsoid, median of {args.repeats} after compile"
    )

    configs = []
    for view in views:
        for caps in ("flat", "sphere"):
            for normals in (True, False):
                for tile in (16, 32):
                    for cull in (True, False):
                        configs.append((view, caps, normals, tile, cull))
    if args.quick:
        configs = [c for c in configs if c[:4] == ("3.5 m", "sphere", True, 32)]

    def call(cfg):
        view, caps, normals, tile, cull = cfg
        R, t = views[view]
        return render.render(rays, R, t, prims, caps=caps, normals=normals, tile=tile, cull=cull)

    coverage = {}
    for cfg in configs:
        out = jax.block_until_ready(call(cfg))
        coverage[cfg[0]] = float(np.mean(np.asarray(out.mask)))
    times = common.interleaved_rounds(
        {cfg: lambda cfg=cfg: jax.block_until_ready(call(cfg)) for cfg in configs}, args.repeats
    )

    print(
        f"{'view':>6} {'caps':>6} {'normals':>7} {'tile':>4} {'cull':>5} {'ms':>8} {'frames/s':>9} {'vs no cull':>10}"
    )
    for cfg in configs:
        med = float(np.median(times[cfg]))
        base = float(np.median(times[cfg[:-1] + (False,)]))
        view, caps, normals, tile, cull = cfg
        print(
            f"{view:>6} {caps:>6} {normals!s:>7} {tile:>4} {cull!s:>5} {1e3 * med:8.1f} {1.0 / med:9.1f} "
            f"{base / med:9.2f}x"
        )
    for view, cov in coverage.items():
        print(f"body covers {100 * cov:.1f} % of the image at {view}")


if __name__ == "__main__":
    main()
