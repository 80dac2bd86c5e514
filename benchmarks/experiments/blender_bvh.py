"""Blender's own BVH importer reads a tracked ``track.bvh``: its armature's joints against the run's joints.

Scenario (all choices stated here):

* a run of ``jaxmocap track`` as a user makes it: the bundled CMU walk (subject 2, trial 1, source frames 0:240 →
  60 frames at 30 fps) synthesised for the ``stereo`` preset at 320×240, tracked with the defaults (full25, APF,
  default cues, ``--smooth butterworth``) but 100 particles × 3 layers, in centimetres (``--bvh-units cm``); the
  same exported states written again in metres (:func:`jaxmocap.io.body_bvh.save_model_bvh` with scale 1);
* Blender (Debian's ``blender`` package, run as ``blender -b --factory-startup --python-expr …``) imports each file
  with its stock importer ``bpy.ops.import_anim.bvh`` (defaults: forward −Z, up Y, rotation mode NATIVE, start
  frame 1) and ``global_scale`` 0.01 (cm) or 1 (m). Debian's Blender 3.4 runs Python 3.11, where the importer's
  ``open(path, 'rU')`` fails for every file: the driving script wraps ``builtins.open`` to drop the ``U``;
* at every frame the world position of every pose bone's head (``armature.matrix_world @ bone.head``) is read
  and mapped from Blender's axes to the project's world (the importer turns the file's y up into z up and its
  −Z forward into +Y: ``(x, y, z)_world = (−y, x, z)_Blender``);
* error: the distance between the bone of every evaluation joint (:func:`jaxmocap.io.body_bvh.bvh_joint_names`)
  and that joint in the run's ``poses_smoothed.npz``, over all frames; plus the importer's rest pose (bone heads
  and tails of the armature as built: height, floor, facing) and its complaints (zero-length bones).

    .venv/bin/python benchmarks/experiments/blender_bvh.py [--blender blender] [--quick]

Writes ``benchmarks/results/blender_bvh.md`` (not with ``--quick``). Needs Blender (``apt-get install blender``),
which is too heavy for CI: the tests check the same files with bvhio and pybvh instead.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # benchmarks/: the shared modules
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import common

from jaxmocap.io import body_bvh
from jaxmocap.io.sources import SequenceSource
from jaxmocap.synth import generate as synth
from jaxmocap.tracking import tracker
from jaxmocap.tracking.options import TrackOptions

RESULTS = common.RESULTS / "blender_bvh.md"

#: Run inside Blender: import the BVH, read every pose bone's world head at every frame and the rest armature.
BLENDER_SCRIPT = r"""
import builtins, json, sys
_open = builtins.open
def _open_without_u(file, mode="r", *args, **kwargs):
    return _open(file, mode.replace("U", ""), *args, **kwargs)
builtins.open = _open_without_u  # Blender 3.4's importer opens with 'rU', which Python 3.11 refuses
import bpy
path, scale, out = sys.argv[sys.argv.index("--") + 1:]
result = bpy.ops.import_anim.bvh(filepath=path, global_scale=float(scale))
arm = bpy.context.object
scene = bpy.context.scene
names = [b.name for b in arm.pose.bones]
action = arm.animation_data.action
first, last = (int(round(v)) for v in action.frame_range)
heads = []
for f in range(first, last + 1):
    scene.frame_set(f)
    heads.append([list(arm.matrix_world @ b.head) for b in arm.pose.bones])
rest = {b.name: [list(arm.matrix_world @ b.head_local), list(arm.matrix_world @ b.tail_local)] for b in arm.data.bones}
json.dump({"result": list(result), "names": names, "frames": [first, last], "heads": heads, "rest": rest,
           "version": bpy.app.version_string}, _open(out, "w"))
"""


def blender_import(
    blender: str, bvh_path: pathlib.Path, scale: float, work: pathlib.Path
) -> tuple[dict, str]:
    """Run Blender's importer on ``bvh_path``; returns what the script read and Blender's printed output."""
    out = work / f"{bvh_path.stem}_blender.json"
    cmd = [blender, "-b", "--factory-startup", "--python-expr", BLENDER_SCRIPT, "--", str(bvh_path), str(scale),
           str(out)]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    if proc.returncode != 0 or not out.is_file():
        raise RuntimeError(
            f"Blender failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        )
    return json.loads(out.read_text()), proc.stdout + proc.stderr


def to_world(p: np.ndarray) -> np.ndarray:
    """Blender's axes (z up, the file's −Z forward as +Y) → the project's world: ``(x, y, z) = (−y, x, z)``."""
    p = np.asarray(p, np.float64)
    return np.stack([-p[..., 1], p[..., 0], p[..., 2]], axis=-1)


def compare(data: dict, model, joints: np.ndarray) -> dict:
    """Errors (mm) of the Blender bones of the evaluation joints against ``joints (T, J_model, 3)``."""
    heads = to_world(np.asarray(data["heads"]))  # (T, bones, 3)
    cols = [data["names"].index(n) for n in body_bvh.bvh_joint_names(model)]
    err = np.linalg.norm(heads[:, cols] - joints, axis=-1) * 1000.0
    rest = {n: to_world(np.asarray(v)) for n, v in data["rest"].items()}
    points = np.concatenate(list(rest.values()))
    names = dict(zip(model.joint_names, body_bvh.bvh_joint_names(model), strict=True))
    return {
        "frames": heads.shape[0],
        "bones": heads.shape[1],
        "max_mm": float(err.max()),
        "mean_mm": float(err.mean()),
        "rest_height_m": float(points[:, 2].max() - points[:, 2].min()),
        "rest_floor_m": float(points[:, 2].min()),
        "rest_head_z": float(rest[names["head"]][0, 2]),
        "rest_ankle_z": float(rest[names["left_ankle"]][0, 2]),
        "rest_left_y": float(rest[names["left_shoulder"]][0, 1] - rest[names["right_shoulder"]][0, 1]),
        "rest_min_bone_m": float(min(np.linalg.norm(v[1] - v[0]) for v in rest.values())),
    }


def main(argv=None) -> str:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--blender", default="blender", help="the Blender executable (default: blender on PATH)")
    ap.add_argument("--quick", action="store_true", help="8 frames at 160x120, 30 particles; writes nothing")
    args = ap.parse_args(argv)
    blender = shutil.which(args.blender)
    if blender is None:
        sys.exit(f"{args.blender} not found: install Blender (e.g. apt-get install -y blender)")
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        work = pathlib.Path(tmp)
        seq, run_dir = work / "seq", work / "run"
        frames, size = ("0:32", "160x120") if args.quick else ("0:240", "320x240")
        synth.synthesize("demo", seq, rig="stereo", frames=frames, size=size, seed=0, overwrite=True)
        particles, layers = (30, 2) if args.quick else (100, 3)
        source = SequenceSource(seq)
        try:
            run = tracker.Tracker(
                source, run_dir, TrackOptions(particles=particles, layers=layers), quiet=True
            )
            summary = run.run()
        finally:
            source.close()
        model = run.model
        sm = np.load(run_dir / "poses_smoothed.npz")
        joints = sm["joints"][:, [list(sm["joint_names"]).index(n) for n in model.joint_names]]
        metres = work / "track_m.bvh"
        body_bvh.save_model_bvh(metres, model, sm["state"], float(sm["fps"]), scale=body_bvh.UNITS["m"])
        rows, version = [], ""
        for label, path, scale in (("cm (0.01)", run_dir / "track.bvh", 0.01), ("m (1)", metres, 1.0)):
            data, printed = blender_import(blender, path, scale, work)
            version = data["version"]
            r = compare(data, model, joints)
            r.update(label=label, zero_length=printed.count("zero length"), result=",".join(data["result"]))
            rows.append(r)
    lines = [
        f"Blender {version} (Debian), stock importer `bpy.ops.import_anim.bvh`, background mode; run: "
        f"{summary['frames_tracked']} frames of the CMU walk, full25, `--smooth {summary['smooth']}`, "
        f"{time.monotonic() - t0:.0f} s in all.",
        "",
        "| file units (import scale) | import | frames | bones | evaluation-joint error max / mean (mm) | "
        "zero-length bones | rest pose: height, lowest point, head z, ankle z, left − right shoulder y, "
        "shortest bone (m) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['label']} | {r['result']} | {r['frames']} | {r['bones']} | {r['max_mm']:.4f} / "
            f"{r['mean_mm']:.4f} | {r['zero_length']} | {r['rest_height_m']:.3f}, {r['rest_floor_m']:.3f}, "
            f"{r['rest_head_z']:.3f}, {r['rest_ankle_z']:.3f}, {r['rest_left_y']:.3f}, {r['rest_min_bone_m']:.3f} |"
        )
    lines += [
        "",
        "The error is float rounding of the file's 6 decimals and of Blender's float32 matrices. Rest pose: the "
        "importer's armature stands upright on the floor (the ankles at z ≈ 0: the BVH root's OFFSET is its rest "
        "height; the lowest points are the 5 cm end sites below the ankles), its left shoulder towards +y of "
        "the world (Blender's +X), i.e. facing Blender's −Y (the front view); no bone has zero length.",
    ]
    return common.report(RESULTS, "\n".join(lines), f"python {common.script(__file__)}", write=not args.quick)


if __name__ == "__main__":
    main()
