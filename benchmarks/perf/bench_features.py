"""Host feature pipeline speed on a 640×480 stereo pair: foreground + edges + I_DT + skin → Observation.

Frames: the Middlebury Aloe pair (tests/data/features) resized to 640×480 as a static background, with a textured
ellipse moving over it and sensor noise. Reports the median over repeated frame pairs of each stage and of the
whole ``FeatureExtractor`` call (including the copy of the maps to the device), as frame pairs per second, for a
few configurations, and the share of each stage.

    .venv/bin/python benchmarks/perf/bench_features.py [--repeats 60] [--threads N]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys

import cv2
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

from jaxmocap.features.edges import distance_transform, masked_canny, smooth_edges  # noqa: E402
from jaxmocap.features.foreground import GaussianBackground, StaticBackground  # noqa: E402
from jaxmocap.features.pipeline import FeatureConfig, FeatureExtractor  # noqa: E402
from jaxmocap.features.skin import default_skin_model  # noqa: E402
from jaxmocap.geometry.camera import Rig  # noqa: E402

DATA = common.ROOT / "tests" / "data" / "features"
W, H = 640, 480


def make_frames(n: int, seed: int = 0):
    bgs = [
        cv2.resize(cv2.imread(str(DATA / f"aloe{s}.jpg")), (W, H), interpolation=cv2.INTER_AREA) for s in "LR"
    ]
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W]
    tex = np.stack(
        [90 + 30 * np.sin(xx / 3.0), 120 + 30 * np.cos(yy / 4.0), 190 + 30 * np.sin((xx + yy) / 5.0)], -1
    )
    pairs = []
    for k in range(n):
        pair = []
        for v, bg in enumerate(bgs):
            cx, cy = 200 + 5 * k - 20 * v, 240 + 2 * k
            m = ((xx - cx) / 60.0) ** 2 + ((yy - cy) / 150.0) ** 2 <= 1
            f = bg.astype(np.float32)
            f[m] = tex[m]
            f += rng.normal(0, 3.0, f.shape).astype(np.float32)
            pair.append(np.clip(f, 0, 255).astype(np.uint8))
        pairs.append(pair)
    return bgs, pairs


def rig():
    K = np.tile(np.array([[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]]), (2, 1, 1))
    t = np.array([[0.0, 0, 0], [-0.12, 0, 0]])
    return Rig(
        K=K,
        dist=np.zeros((2, 5)),
        R=np.tile(np.eye(3), (2, 1, 1)),
        t=t,
        names=("L", "R"),
        image_size=((W, H),) * 2,
    )


def interleaved_times(fns: dict, pairs, repeats: int) -> dict:
    """Seconds per pair of every function, timed round-robin (each repeat runs every function once on the same
    pair), so that a load that varies over time affects all of them alike. Returns name → array of times."""
    for fn in fns.values():
        for p in pairs[:3]:
            fn(p)  # warm-up (first-call allocations, JAX dispatch caches)
    return common.interleaved_rounds(fns, repeats, lambda r: (pairs[r % len(pairs)],))


def report(title: str, times: dict) -> dict:
    print(f"\n{title:<50s} median ms   pairs/s   (best ms)")
    out = {}
    for k, ts in times.items():
        med = float(np.median(ts))
        out[k] = med
        print(f"  {k:<48s} {med * 1e3:8.2f}  {1.0 / med:8.1f}   ({ts.min() * 1e3:.2f})")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=60)
    ap.add_argument("--threads", type=int, default=None, help="cv2.setNumThreads (default: OpenCV's choice)")
    args = ap.parse_args(argv)
    if args.threads is not None:
        cv2.setNumThreads(args.threads)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"OpenCV {cv2.__version__}, threads {cv2.getNumThreads()}, CPUs {os.cpu_count()}, load {load:.1f}; 640x480 pair"
    )
    bgs, pairs = make_frames(30)
    skin = default_skin_model()

    # --- stages (per pair, both views) ------------------------------------------------------------------------
    static = [StaticBackground(b) for b in bgs]
    masks = [static[v].update(pairs[0][v]) for v in range(2)]
    gauss = [GaussianBackground() for _ in range(2)]
    for v in range(2):
        gauss[v].update(bgs[v])
    stages = {
        "foreground: static + open + dilate": lambda p: [static[v].update(p[v]) for v in range(2)],
        "foreground: adaptive Gaussian": lambda p: [gauss[v].update(p[v]) for v in range(2)],
        "edges: masked Canny + dilate + blur": lambda p: [
            smooth_edges(masked_canny(p[v], masks[v])) for v in range(2)
        ],
        "I_DT, full image": lambda p: [distance_transform(masked_canny(p[v], masks[v])) for v in range(2)],
        "I_DT, truncated at 50 px": lambda p: [
            distance_transform(masked_canny(p[v], masks[v]), 50.0) for v in range(2)
        ],
        "skin: RGB ratio LUT (uint8)": lambda p: [skin.probability_u8(p[v]) for v in range(2)],
        "skin: HS back-projection": lambda p: [skin.hs_backprojection(p[v]) for v in range(2)],
    }
    stage_med = report("stage (both views)", interleaved_times(stages, pairs, args.repeats))

    # --- whole pipeline → Observation -------------------------------------------------------------------------
    configs = {
        "static fg + edges + I_DT(50) + skin, float32": FeatureConfig(),
        "same, uint8 maps": FeatureConfig(dtype="uint8"),
        "same, float16 maps": FeatureConfig(dtype="float16"),
        "same, down-sampled by 2": FeatureConfig(downsample=2),
        "same, I_DT not truncated": FeatureConfig(dt_truncate=None),
        "adaptive Gaussian fg instead of static": FeatureConfig(foreground="gaussian"),
        "default + 3D skin blobs": FeatureConfig(blobs=True),
        "default + SGBM depth (64 disparities)": FeatureConfig(stereo_depth=True),
    }
    fns = {}
    for name, cfg in configs.items():
        fx = FeatureExtractor(rig(), cfg, skin_model=skin)
        if cfg.foreground == "static":
            fx.set_background(bgs)
        fns[name] = lambda p, fx=fx: jax.block_until_ready(fx(p))
    med = report("pipeline: host features + copy to device", interleaved_times(fns, pairs, args.repeats))
    base = next(iter(med.values()))
    print(
        "\nspeed relative to the first pipeline row: "
        + ", ".join(f"{k}: {base / v:.2f}" for k, v in med.items())
    )
    core = [
        "foreground: static + open + dilate",
        "edges: masked Canny + dilate + blur",
        "I_DT, truncated at 50 px",
        "skin: RGB ratio LUT (uint8)",
    ]
    total = sum(stage_med[k] for k in core)
    print(
        "share of the default stages: "
        + ", ".join(f"{k.split(',')[0]} {stage_med[k] / total:.0%}" for k in core)
    )


if __name__ == "__main__":
    main()
