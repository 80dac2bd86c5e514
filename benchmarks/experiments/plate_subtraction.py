"""Background subtraction against the synthesiser's empty-scene plates: silhouette IoU per frame of a rendered walk.

The bundled CMU walk (the whole clip, 10 frames/s) is synthesised with the stereo rig (default options: the
photographs behind, sensor noise 0.01); every frame of each view is segmented against that view's written plate
(``views/<camera>/background.png``) by :func:`jaxmocap.synth.plates.subtraction_iou` and scored against the
rendered mask.

    python benchmarks/experiments/plate_subtraction.py [--size 320x240] [--out benchmarks/results/plate_subtraction.md]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
import common
import numpy as np

from jaxmocap.synth import generate as synth
from jaxmocap.synth import plates


def evaluate(
    size: str = "320x240", frames: str = "0:343", seed: int = 5
) -> tuple[np.ndarray, tuple[str, ...]]:
    """``(T, V)`` IoU and the view names."""
    with tempfile.TemporaryDirectory() as tmp:
        seq = synth.synthesize(
            "demo", tmp, rig="stereo", frames=frames, fps=10, size=size, seed=seed, overwrite=True
        )
        return plates.subtraction_iou(seq), seq.view_names


def to_markdown(iou: np.ndarray, views, size: str, frames: str) -> str:
    lines = [
        "# Background subtraction against the written plates (CMU 02_01 walk, stereo rig)",
        "",
        f"Sequence: `jaxmocap synth --motion demo --rig stereo --frames {frames} --fps 10 --size {size} --seed 5`; "
        "segmentation: static background against `views/<camera>/background.png`, per-channel threshold "
        "4·√2·σ (σ the sensor noise, 8-bit units), no morphology; truth: the rendered masks.",
        "",
        "| view | frames | mean IoU | min IoU | 5th percentile |",
        "|---|---|---|---|---|",
    ]
    for v, name in enumerate(views):
        x = iou[:, v]
        lines.append(f"| {name} | {len(x)} | {x.mean():.3f} | {x.min():.3f} | {np.percentile(x, 5):.3f} |")
    lines += [
        "",
        "IoU per frame:",
        "",
        "| frame | " + " | ".join(views) + " |",
        "|---" * (len(views) + 1) + "|",
    ]
    lines += [f"| {t} | " + " | ".join(f"{x:.3f}" for x in row) + " |" for t, row in enumerate(iou)]
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--frames", default="0:343")
    ap.add_argument("--out", default=str(common.RESULTS / "plate_subtraction.md"))
    a = ap.parse_args(argv)
    iou, views = evaluate(a.size, a.frames)
    md = to_markdown(iou, views, a.size, a.frames)
    print(md)
    common.write_result(pathlib.Path(a.out), md, f"python {common.script(__file__)} --size {a.size}")


if __name__ == "__main__":
    main()
