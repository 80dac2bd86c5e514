"""Training a skin model from video frames with OpenPose BODY_25B keypoints (how the default model was made).

Labelling rule for one frame (the subject is bare-armed and bare-legged, e.g. the Pose2Sim demo trial):

* skin: thin bands along the bare limb segments — shoulder→elbow, elbow→wrist, knee→ankle — shortened by
  ``trim`` of their length at both ends (joints, hands and feet are left out), of width ``width_frac`` × segment
  length, plus the upper chest (the quadrilateral between the shoulders and ``chest_frac`` of the way down to the
  hips, shrunk towards its centre); segments whose keypoints have confidence < ``min_conf`` are skipped;
* non-skin: every pixel farther than a safety margin from the subject (bands of ``body_width_frac`` × segment
  length around every segment, the torso hull, a disc around the head), and outside the bounding boxes (grown by
  half their size) of every other detected person.

The subject is the detected person with the largest keypoint bounding box. Run as a module:

    python -m jaxmocap.features.skin_training --root PATH/pose2sim_demo --cams cam01 cam02 cam03 \\
        --out jaxmocap/data/skin/skin_model.npz
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.features.skin import SkinModel, train_skin_model
from jaxmocap.io.openpose import BODY_25B_INDEX

# BODY_25B indices
NOSE, L_SHOULDER, R_SHOULDER, L_ELBOW, R_ELBOW, L_WRIST, R_WRIST = (
    BODY_25B_INDEX[n] for n in ("Nose", "LShoulder", "RShoulder", "LElbow", "RElbow", "LWrist", "RWrist")
)
L_HIP, R_HIP, L_KNEE, R_KNEE, L_ANKLE, R_ANKLE, NECK, HEAD_TOP = (
    BODY_25B_INDEX[n] for n in ("LHip", "RHip", "LKnee", "RKnee", "LAnkle", "RAnkle", "UpperNeck", "HeadTop")
)
EYES_EARS = tuple(BODY_25B_INDEX[n] for n in ("LEye", "REye", "LEar", "REar"))

SKIN_SEGMENTS = (
    (L_SHOULDER, L_ELBOW),
    (L_ELBOW, L_WRIST),
    (R_SHOULDER, R_ELBOW),
    (R_ELBOW, R_WRIST),
    (L_KNEE, L_ANKLE),
    (R_KNEE, R_ANKLE),
)
BODY_SEGMENTS = SKIN_SEGMENTS + (
    (L_SHOULDER, L_HIP),
    (R_SHOULDER, R_HIP),
    (L_HIP, L_KNEE),
    (R_HIP, R_KNEE),
    (L_SHOULDER, R_SHOULDER),
    (L_HIP, R_HIP),
    (NECK, HEAD_TOP),
)


def read_openpose_json(path: str | os.PathLike) -> list[np.ndarray]:
    """People of an OpenPose JSON file: list of ``(25, 3)`` arrays ``(x, y, confidence)``."""
    try:
        with open(path) as f:
            data = json.load(f)
    except FileNotFoundError:
        raise MocapInputError(path, "OpenPose JSON file not found") from None
    except json.JSONDecodeError as e:
        raise MocapInputError(path, f"invalid JSON: {e.msg}", line=e.lineno) from None
    people = []
    for i, person in enumerate(data.get("people", [])):
        kp = np.asarray(person.get("pose_keypoints_2d", []), np.float64)
        if kp.size % 3:
            raise MocapInputError(
                path, f"people[{i}].pose_keypoints_2d length {kp.size} is not a multiple of 3"
            )
        people.append(kp.reshape(-1, 3))
    return people


def _bbox(kp: np.ndarray, min_conf: float) -> tuple[float, float, float, float] | None:
    ok = kp[:, 2] >= min_conf
    if ok.sum() < 2:
        return None
    x, y = kp[ok, 0], kp[ok, 1]
    return float(x.min()), float(y.min()), float(x.max()), float(y.max())


def _band(mask: np.ndarray, p: np.ndarray, q: np.ndarray, trim: float, width: int) -> None:
    a = p + trim * (q - p)
    b = q - trim * (q - p)
    cv2.line(mask, tuple(int(round(c)) for c in a), tuple(int(round(c)) for c in b), 255, max(1, width))


def label_frame(
    shape: tuple[int, int],
    people: list[np.ndarray],
    min_conf: float = 0.3,
    trim: float = 0.2,
    width_frac: float = 0.12,
    chest_frac: float = 0.4,
    body_width_frac: float = 0.8,
    margin_px: int = 25,
) -> tuple[np.ndarray, np.ndarray]:
    """``(skin_mask, nonskin_mask)`` ``uint8`` 0/255 of shape ``shape = (H, W)`` (see the module docstring)."""
    H, W = shape
    skin = np.zeros((H, W), np.uint8)
    body = np.zeros((H, W), np.uint8)
    boxes = [_bbox(kp, min_conf) for kp in people]
    areas = [0.0 if b is None else (b[2] - b[0]) * (b[3] - b[1]) for b in boxes]
    if not people or max(areas) == 0.0:
        return skin, np.zeros((H, W), np.uint8)
    s = int(np.argmax(areas))
    kp = people[s]
    ok = kp[:, 2] >= min_conf
    xy = kp[:, :2]
    for i, j in SKIN_SEGMENTS:
        if ok[i] and ok[j]:
            length = float(np.linalg.norm(xy[j] - xy[i]))
            _band(skin, xy[i], xy[j], trim, int(round(width_frac * length)))
    if ok[[L_SHOULDER, R_SHOULDER, L_HIP, R_HIP]].all():
        ls, rs = xy[L_SHOULDER], xy[R_SHOULDER]
        lc = ls + chest_frac * (xy[L_HIP] - ls)
        rc = rs + chest_frac * (xy[R_HIP] - rs)
        quad = np.array([ls, rs, rc, lc])
        centre = quad.mean(axis=0)
        quad = centre + 0.6 * (quad - centre)
        cv2.fillPoly(skin, [np.round(quad).astype(np.int32)], 255)
    for i, j in BODY_SEGMENTS:
        if ok[i] and ok[j]:
            length = float(np.linalg.norm(xy[j] - xy[i]))
            _band(body, xy[i], xy[j], 0.0, int(round(body_width_frac * length)) + 2 * margin_px)
    torso = [k for k in (L_SHOULDER, R_SHOULDER, R_HIP, L_HIP) if ok[k]]
    if len(torso) >= 3:
        cv2.fillConvexPoly(body, cv2.convexHull(np.round(xy[torso]).astype(np.int32)), 255)
    head = [k for k in (NOSE, NECK, HEAD_TOP, *EYES_EARS) if ok[k]]
    if head:
        c = xy[head].mean(axis=0)
        scale = (
            float(np.linalg.norm(xy[L_SHOULDER] - xy[R_SHOULDER]))
            if ok[[L_SHOULDER, R_SHOULDER]].all()
            else 100
        )
        cv2.circle(body, tuple(int(round(v)) for v in c), int(round(0.8 * scale)) + margin_px, 255, -1)
    body = cv2.dilate(body, np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8))
    for k, b in enumerate(boxes):
        if k == s or b is None:
            continue
        w, h = b[2] - b[0], b[3] - b[1]
        x0, y0 = int(b[0] - 0.5 * w - margin_px), int(b[1] - 0.5 * h - margin_px)
        x1, y1 = int(b[2] + 0.5 * w + margin_px), int(b[3] + 0.5 * h + margin_px)
        cv2.rectangle(body, (x0, y0), (x1, y1), 255, -1)
    return skin, cv2.bitwise_not(body)


def video_frames(path: str | os.PathLike, indices: list[int]):
    """Yield ``(index, frame)`` for the requested frame indices of a video (decoded sequentially)."""
    cap = cv2.VideoCapture(os.fspath(path))
    if not cap.isOpened():
        raise MocapInputError(path, "cannot open video")
    wanted = set(indices)
    i = 0
    try:
        while wanted:
            ok, frame = cap.read()
            if not ok:
                break
            if i in wanted:
                wanted.discard(i)
                yield i, frame
            i += 1
    finally:
        cap.release()
    if wanted:
        raise MocapInputError(path, f"video ended before frames {sorted(wanted)}")


def pose2sim_samples(
    root: str | os.PathLike,
    cams: list[str],
    frames: list[int],
    max_skin: int = 20000,
    max_nonskin: int = 60000,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Labelled BGR pixels ``(skin (N, 3), non-skin (M, 3))`` from the Pose2Sim demo layout under ``root``:
    ``videos/<cam>.mp4`` and ``derived_by_pose2sim_a948c20/pose/<cam>_json/<cam>.<frame:04d>.json``.
    At most ``max_skin``/``max_nonskin`` pixels per frame, drawn without replacement with a fixed seed."""
    root = pathlib.Path(root)
    rng = np.random.default_rng(seed)
    skin_all, non_all = [], []
    for cam in cams:
        json_dir = root / "derived_by_pose2sim_a948c20" / "pose" / f"{cam}_json"
        for idx, frame in video_frames(root / "videos" / f"{cam}.mp4", frames):
            people = read_openpose_json(json_dir / f"{cam}.{idx:04d}.json")
            skin, non = label_frame(frame.shape[:2], people)
            for mask, out, cap in ((skin, skin_all, max_skin), (non, non_all, max_nonskin)):
                pix = frame[mask > 0]
                if len(pix) > cap:
                    pix = pix[rng.choice(len(pix), cap, replace=False)]
                out.append(pix)
    return np.concatenate(skin_all), np.concatenate(non_all)


def roc_auc(scores_pos: np.ndarray, scores_neg: np.ndarray) -> float:
    """Area under the ROC curve = P(score of a positive > score of a negative) + ½ P(tie) (Mann–Whitney)."""
    pos = np.asarray(scores_pos, np.float64).ravel()
    neg = np.asarray(scores_neg, np.float64).ravel()
    allv = np.concatenate([pos, neg])
    order = np.argsort(allv, kind="mergesort")
    ranks = np.empty(len(allv), np.float64)
    sorted_v = allv[order]
    # average ranks over ties
    _, first, counts = np.unique(sorted_v, return_index=True, return_counts=True)
    avg = first + (counts - 1) / 2.0 + 1.0
    ranks[order] = np.repeat(avg, counts)
    r_pos = ranks[: len(pos)].sum()
    return float((r_pos - len(pos) * (len(pos) + 1) / 2.0) / (len(pos) * len(neg)))


def main(argv=None) -> SkinModel:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--root", required=True, help="Pose2Sim demo folder (videos/, derived_by_pose2sim_a948c20/)"
    )
    ap.add_argument("--cams", nargs="+", default=["cam01", "cam02", "cam03"])
    ap.add_argument("--frames", type=int, nargs="+", default=list(range(0, 100, 10)))
    ap.add_argument("--heldout", nargs="*", default=["cam04"], help="cameras to report the ROC AUC on")
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    s, n = pose2sim_samples(args.root, args.cams, args.frames)
    desc = (
        f"RGB 8-bin likelihood ratio + HS(30x32) histograms; skin = limb bands/upper chest of the BODY_25B "
        f"subject, non-skin = pixels away from any person; Pose2Sim demo {','.join(args.cams)} frames "
        f"{args.frames[0]}..{args.frames[-1]} step {args.frames[1] - args.frames[0] if len(args.frames) > 1 else 1}; "
        f"{len(s)} skin / {len(n)} non-skin pixels"
    )
    model = train_skin_model(s, n, description=desc)
    model.save(args.out)
    print(desc)
    if args.heldout:
        hs, hn = pose2sim_samples(args.root, args.heldout, args.frames, seed=1)
        p_s = model.probability_u8(hs.reshape(-1, 1, 3))
        p_n = model.probability_u8(hn.reshape(-1, 1, 3))
        b_s = model.hs_backprojection(hs.reshape(-1, 1, 3))
        b_n = model.hs_backprojection(hn.reshape(-1, 1, 3))
        print(f"held-out {args.heldout}: {len(hs)} skin / {len(hn)} non-skin pixels")
        print(f"  RGB ratio AUC {roc_auc(p_s, p_n):.4f}; HS back-projection AUC {roc_auc(b_s, b_n):.4f}")
        for t in (0.5, 0.8):
            print(
                f"  RGB p>{t}: true-positive rate {np.mean(p_s > 255 * t):.3f}, "
                f"false-positive rate {np.mean(p_n > 255 * t):.3f}"
            )
    return model


if __name__ == "__main__":
    main()
