"""Montages of the synthetic subject in the 3D room, one per rig preset: what the cues see on one frame.

For each rig (``stereo``, ``frontal-lateral``, ``ring4``) this renders source frames 120–240 of the bundled CMU walk at
10 frames/s and 640×480 with ``--background room --clothing textured`` and writes
``benchmarks/results/scene_<rig>.png``: one row per camera at one frame, with the RGB image and the simulated
OpenPose detections (dots: left red, right blue, centre green; larger where confident), the empty-scene plate,
background subtraction against it with shadows removed (white: agreed foreground, red: false foreground, blue:
missed), depth (SGBM on the stereo pair for the left view, the virtual depth sensor otherwise; a colour map over the
body's range) and the skin probability inside the subtracted silhouette with the skin blobs (circles). Each panel is
a 4:3 window around the body shown at 256×192; the montage is an adaptive 256-colour PNG.

    .venv/bin/python benchmarks/experiments/make_scene_montages.py [--frame 5]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common
import cv2
import numpy as np
from PIL import Image

from jaxmocap.features import blobs, skin, stereo
from jaxmocap.features import foreground as fg
from jaxmocap.io import openpose
from jaxmocap.synth import generate as synth
from jaxmocap.synth import plates

PANEL = (256, 192)


def _panel(img: np.ndarray) -> np.ndarray:
    return cv2.resize(img, PANEL, interpolation=cv2.INTER_AREA)


def _crop(mask: np.ndarray) -> tuple[slice, slice]:
    """A 4:3 window around the body's silhouette with a margin, inside the image."""
    h, w = mask.shape
    ys, xs = np.nonzero(mask)
    if not len(ys):
        return slice(0, h), slice(0, w)
    ch = min(h, int(1.3 * (ys.max() - ys.min() + 1)) + 16)
    cw = min(w, int(ch * 4 / 3))
    ch = min(h, int(cw * 3 / 4))
    cy, cx = (ys.min() + ys.max()) // 2, (xs.min() + xs.max()) // 2
    y0, x0 = min(max(0, cy - ch // 2), h - ch), min(max(0, cx - cw // 2), w - cw)
    return slice(y0, y0 + ch), slice(x0, x0 + cw)


def _depth_panel(depth: np.ndarray, body: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Depth inside the silhouette, coloured over the 1st–99th percentile of the rendered ``reference``."""
    out = np.zeros(depth.shape + (3,), np.uint8)
    m = (depth > 0) & body
    if m.any():
        lo, hi = np.percentile(reference[body & (reference > 0)], [1, 99])
        z = np.clip((depth - lo) / max(hi - lo, 1e-3), 0, 1)
        col = cv2.applyColorMap((255 * (1 - z)).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
        out[m] = col[m]
    return out


def _detections(rgb: np.ndarray, det: np.ndarray) -> np.ndarray:
    out = rgb.copy()
    for name, (x, y, c) in zip(openpose.BODY_25B_KEYPOINTS, det, strict=True):
        if c > 0:
            colour = (230, 40, 40) if name[0] == "L" else (40, 80, 230) if name[0] == "R" else (40, 200, 40)
            cv2.circle(out, (int(round(x)), int(round(y))), 2 + int(3 * c), colour, -1, cv2.LINE_AA)
    return out


def montage(seq, frame: int) -> np.ndarray:
    model = skin.default_skin_model()
    sigma = np.sqrt(2) * 255 * seq.meta["noise"]["rgb_sigma"]
    sgbm = None
    if seq.meta["rig"] == "stereo":
        K = np.asarray(seq.rig.K[0])
        c = [-np.asarray(seq.rig.R[v]).T @ np.asarray(seq.rig.t[v]) for v in (0, 1)]
        left, right = (seq.views[v].rgb(frame)[..., ::-1] for v in (0, 1))
        disp = stereo.sgbm_disparity(left, right, num_disparities=96)
        sgbm = stereo.disparity_to_depth(disp, K[0, 0], float(np.linalg.norm(c[0] - c[1])))
    rows, found = [], []
    for v, view in enumerate(seq.views):
        rgb = view.rgb(frame)
        bgr = np.ascontiguousarray(rgb[..., ::-1])
        plate = plates.read_plate(seq.root, view.name)
        sub = fg.StaticBackground(
            np.ascontiguousarray(plate[..., ::-1]), 15, 1, 3, plates.ROOM_SHADOW, noise_std=sigma
        )
        pred, truth = sub.update(bgr) > 0, view.mask(frame) > 0
        diff = np.zeros(rgb.shape, np.uint8)
        diff[pred & truth] = 255
        diff[pred & ~truth] = (230, 40, 40)
        diff[~pred & truth] = (40, 80, 230)
        depth = sgbm if (sgbm is not None and v == 0) else view.depth(frame)
        depth_img = _depth_panel(depth, truth, view.depth(frame))
        p = model.probability(bgr) * pred
        b = blobs.skin_blobs(p, max_blobs=3, min_area=10, open_size=1, close_size=3)
        found.append(b)
        sk = cv2.cvtColor((255 * p).astype(np.uint8), cv2.COLOR_GRAY2RGB)
        for (x, y), a in zip(b.centroids, b.areas, strict=True):
            cv2.circle(sk, (int(x), int(y)), int(max(6, np.sqrt(a))), (250, 200, 0), 2, cv2.LINE_AA)
        det = openpose.load_openpose_json(synth.detections_path(seq.root, view.name, frame))
        panels = [_detections(rgb, det), plate, diff, depth_img, sk]
        ys, xs = _crop(truth)
        rows.append(np.concatenate([_panel(x[ys, xs]) for x in panels], 1))
    return np.concatenate(rows, 0)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frame", type=int, default=5)
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        for rig in synth.PRESETS:
            seq = synth.synthesize(
                "demo",
                pathlib.Path(tmp) / rig,
                rig=rig,
                frames="120:240",
                fps=10,
                size=(640, 480),
                seed=1,
                background="room",
                clothing="textured",
            )
            img = Image.fromarray(montage(seq, a.frame)).quantize(256, method=Image.Quantize.MEDIANCUT)
            out = common.RESULTS / f"scene_{rig}.png"
            img.save(out, optimize=True)
            print(f"wrote {out}")


if __name__ == "__main__":
    main()
