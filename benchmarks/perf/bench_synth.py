"""Speed of synthetic sequence generation per 640×480 view (``jaxmocap synth``).

Scene: the bundled CMU walk (subject 2, trial 1, source frames 120–240 at 30 fps), dressed in 29 sphere-capped
cones and a head spheroid, seen by the ``stereo`` preset at 640×480. Reports medians over every view of every
frame (after compilation) of:

1. ray casting: :func:`jaxmocap.geometry.render.render_view` (depth, labels, normals) until the result is ready;
2. the in-memory images of a view: ray casting + shading/compositing + sensor noise + virtual depth
   (:func:`jaxmocap.synth.generate.view_images`), i.e. the rendering of RGB, mask, labels and depth;
3. the whole command: :func:`jaxmocap.synth.generate.synthesize` (rig fitting, ray casting, image formation and the PNG
   writes), as view-frames per second of wall time, compiled (second run in the process);

and the same-process baselines: ray casting every tile, without screen-space culling (``cull=False``), and the
unfused host image formation of :mod:`jaxmocap.geometry.render` (``shade`` + ``composite`` + ``add_sensor_noise`` +
``virtual_depth`` in NumPy) in place of stage 2's fused shading. Wall and process CPU time are both given, with
the load average (the CI-like machine is shared).

    .venv/bin/python benchmarks/perf/bench_synth.py [--frames 120:240] [--size 640x480]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxmocap.geometry import render
from jaxmocap.io.mocap import eval_joints  # noqa: E402
from jaxmocap.synth import generate as synth  # noqa: E402


def _median_ms(samples):
    return 1e3 * float(np.median(samples))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", default="120:240")
    ap.add_argument("--size", default="640x480")
    args = ap.parse_args(argv)
    size = synth.parse_size(args.size)
    motion = synth.load_motion("demo")
    a, b = synth.parse_frames(args.frames, motion.num_frames)
    src = np.arange(a, b, 4)
    dressing = synth.dress(motion)
    points = synth.dressing_points(motion, dressing, np.arange(motion.num_frames))
    joints = eval_joints(motion)[src]
    rig = synth.preset_rig("stereo", points[a:b], joints, size)
    K, dist, R, t = (np.asarray(x, np.float64) for x in (rig.K, rig.dist, rig.R, rig.t))
    V = rig.num_views
    colours = jnp.asarray(dressing.colours(), jnp.float32)
    bgs = [jnp.asarray(synth.background_image("photo", size, v, 0), jnp.float32) / 255.0 for v in range(V)]
    _, f, left = synth.subject_frame(joints)
    lw = synth.LIGHT[0] * f + synth.LIGHT[1] * left + synth.LIGHT[2] * np.array([0.0, 0.0, 1.0])
    lights = [jnp.asarray(R[v] @ lw / np.linalg.norm(lw), jnp.float32) for v in range(V)]
    print(f"jax {jax.__version__}, {os.cpu_count()} CPUs, load average {os.getloadavg()}")
    print(f"{len(src)} frames x {V} views at {size[0]}x{size[1]}, {dressing.num_cones} cones + head")

    rays = [jnp.asarray(render.pixel_rays(K[v], dist[v], size)) for v in range(V)]

    def cast(i, v, cull=None):
        prims = synth.scene_primitives(points[i], dressing)
        if cull is None:
            return render.render_view(K[v], dist[v], R[v], t[v], size, prims, caps=synth.CAPS)
        return render.render(
            rays[v],
            jnp.asarray(R[v], jnp.float32),
            jnp.asarray(t[v], jnp.float32),
            prims,
            caps=synth.CAPS,
            cull=cull,
        )

    def timed(fn):
        wall, cpu = [], []
        fn(int(src[0]), 0)  # compile
        for i in src:
            for v in range(V):
                w0, c0 = time.perf_counter(), time.process_time()
                fn(int(i), v)
                wall.append(time.perf_counter() - w0)
                cpu.append(time.process_time() - c0)
        return _median_ms(wall), _median_ms(cpu)

    def ray_cast(i, v):
        jax.block_until_ready(cast(i, v))

    def ray_cast_all(i, v):
        jax.block_until_ready(cast(i, v, cull=False))

    def images(i, v):
        rng = np.random.default_rng([0, i, v])
        synth.view_images(rng, [cast(i, v)], colours, lights[v], bgs[v], 1.0, 0.01, 1.5, 0.02)

    bg_np = [np.asarray(bg, np.float64) for bg in bgs]

    def images_numpy(i, v):
        r = cast(i, v)
        rng = np.random.default_rng([0, i, v])
        rgb, mask = render.shade(r, dressing.colours(), light=np.asarray(lights[v]))
        img = render.add_sensor_noise(rng, render.composite(rgb, mask, bg_np[v]), 0.01)
        depth = render.virtual_depth(rng, np.asarray(r.depth), 1.5, 0.02)
        return img, depth, np.asarray(r.label)

    rows = [
        ("ray casting (culled tiles)", timed(ray_cast)),
        ("ray casting, no tile culling (cull=False) [baseline]", timed(ray_cast_all)),
        ("view images: ray casting + fused shading + noise + virtual depth", timed(images)),
        ("view images with render.shade/composite/add_sensor_noise [baseline]", timed(images_numpy)),
    ]
    for name, (wall, cpu) in rows:
        print(f"{name:70s} median {wall:7.1f} ms wall ({1e3 / wall:5.1f} /s), {cpu:7.1f} ms CPU")
    print(f"ratio ray casting without / with culling: {rows[1][1][0] / rows[0][1][0]:.2f}")
    print(f"ratio NumPy image formation / fused: {rows[3][1][0] / rows[2][1][0]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        kw = dict(rig="stereo", frames=args.frames, size=size, seed=0)
        synth.synthesize("demo", os.path.join(tmp, "warm"), **{**kw, "frames": f"{a}:{a + 8}"})
        w0, c0 = time.perf_counter(), time.process_time()
        seq = synth.synthesize("demo", os.path.join(tmp, "run"), **kw)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    n = seq.num_frames * len(seq.views)
    print(
        f"synthesize (PNG writes included): {n} view-frames in {wall:.2f} s wall = {n / wall:.1f} view-frames/s, "
        f"{1e3 * cpu / n:.1f} ms CPU per view-frame; load average {os.getloadavg()}"
    )


if __name__ == "__main__":
    main()
