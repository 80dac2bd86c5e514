"""Montages of synthetic sequences of the bundled CMU walk (subject 2, trial 1), one per rig preset.

For each rig (``stereo``, ``frontal-lateral``, ``ring4``) this renders the clip's source frames 120–240 at 30 fps
and 640×480 into ``benchmarks/results/synth_<rig>/`` and writes ``benchmarks/results/synth_<rig>.png``: one row per
camera at one frame, with the RGB image, the foreground mask, the virtual depth (colour map over the body's
depth range), the part labels (in the part colours) and the RGB with the ground-truth evaluation joints projected
through the written calibration (dots and the bones between them). Each panel is shown at 1/2.5 scale and the
montage is stored as an adaptive 256-colour PNG to stay small.

    .venv/bin/python benchmarks/experiments/make_synth_montages.py [--frame 12] [--keep]
"""

from __future__ import annotations

import argparse
import pathlib
import shutil
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common
import cv2
import numpy as np
from PIL import Image

from jaxmocap.eval.viz import SKELETON
from jaxmocap.geometry import camera
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io import sequence as seqio
from jaxmocap.synth import generate as synth

PANEL = (256, 192)


def _panel(img: np.ndarray) -> np.ndarray:
    return cv2.resize(img, PANEL, interpolation=cv2.INTER_AREA)


def _depth_panel(depth: np.ndarray) -> np.ndarray:
    m = depth > 0
    out = np.zeros(depth.shape + (3,), np.uint8)
    if m.any():
        lo, hi = np.percentile(depth[m], [1, 99])
        z = np.clip((depth - lo) / max(hi - lo, 1e-3), 0, 1)
        col = cv2.applyColorMap((255 * (1 - z)).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
        out[m] = col[m]
    return out


def _label_panel(labels: np.ndarray, colours: np.ndarray) -> np.ndarray:
    out = np.zeros(labels.shape + (3,), np.uint8)
    m = labels >= 0
    out[m] = (255 * colours[labels[m]]).astype(np.uint8)
    return out


def _overlay(rgb: np.ndarray, uv: np.ndarray) -> np.ndarray:
    out = rgb.copy()
    idx = {n: i for i, n in enumerate(EVAL_JOINTS)}
    s = 16  # sub-pixel drawing
    p = np.round(uv * s).astype(np.int64)
    for a, b in SKELETON:
        cv2.line(out, tuple(p[idx[a]]), tuple(p[idx[b]]), (255, 255, 255), 2, cv2.LINE_AA, shift=4)
    for q in p:
        cv2.circle(out, tuple(q), 5 * s, (255, 230, 0), -1, cv2.LINE_AA, shift=4)
    return out


def _caption(img: np.ndarray, text: str) -> np.ndarray:
    out = img.copy()
    cv2.putText(out, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(out, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def montage(seq: seqio.Sequence, t: int) -> np.ndarray:
    rig = seq.rig.to_jax(np.float32)
    uv = np.asarray(camera.project(rig, np.asarray(seq.groundtruth.joints[t], np.float32)))
    colours = np.asarray(seq.meta["part_colours"], np.float64)
    rows = []
    for v, view in enumerate(seq.views):
        rgb = view.rgb(t)
        panels = [
            _caption(_panel(rgb), f"{view.name} rgb"),
            _caption(_panel(np.repeat(view.mask(t)[..., None], 3, -1).astype(np.uint8) * 255), "mask"),
            _caption(_panel(_depth_panel(view.depth(t))), "depth"),
            _caption(_panel(_label_panel(view.labels(t), colours)), "labels"),
            _caption(_panel(_overlay(rgb, uv[v])), "ground truth"),
        ]
        rows.append(np.concatenate(panels, 1))
    return np.concatenate(rows, 0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frame", type=int, default=12, help="output frame shown (default 12)")
    ap.add_argument("--keep", action="store_true", help="keep the rendered sequence folders")
    args = ap.parse_args()
    common.RESULTS.mkdir(exist_ok=True)
    for rig in synth.PRESETS:
        out = common.RESULTS / f"synth_{rig}"
        t0 = time.perf_counter()
        seq = synth.synthesize("demo", out, rig=rig, frames="120:240", fps=30, seed=1, overwrite=True)
        dt = time.perf_counter() - t0
        img = montage(seq, args.frame)
        path = common.RESULTS / f"synth_{rig}.png"
        Image.fromarray(img).quantize(256, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)
        print(
            f"{rig}: {seq.num_frames} frames x {len(seq.views)} views in {dt:.1f} s (compilation included); "
            f"montage {path} ({path.stat().st_size / 1024:.0f} KB); cameras {', '.join(seq.rig.names)}"
        )
        if not args.keep:
            shutil.rmtree(out)


if __name__ == "__main__":
    main()
