"""Detections of every person in every view → the tracked subject's keypoints, and what they say about the
calibration.

Input: per frame and view, the detected persons as evaluation-joint keypoints ``(P, 15, 3)``
(:func:`jaxmocap.io.keypoints.eval_keypoints`) in the pixels of a calibrated :class:`~jaxmocap.geometry.camera.Rig`.

**Multi-view persons** (:func:`multiview_persons`). Per frame: every pair of detections in two views is
triangulated (DLT on undistorted points, joints of confidence > ``c_min`` in both) and kept as a seed when both
reproject within ``τ_v`` of their detections (the median over joints; ``τ_v = 3 %`` of the view's larger image
side, 58 px for 1920 px, 9.6 px for 320 px); the seed is extended by the detection of each other view that lies within ``τ_v`` of the
seed's projection, re-triangulated from all of them (a joint whose rays meet behind a camera has no triangulation
and is left out), and the seed with the most views (then the smallest mean
``residual / τ``) is a person; its detections are taken out and the search repeats.

**Subject** (:func:`select_subject`). The persons of consecutive frames are linked into tracks (nearest centre, the
median of the triangulated joints, within ``0.5 m + 3 m/s · Δt`` across the cameras' lines of sight,
:meth:`ViewGeometry.lateral_distance`: a pair of close cameras triangulates depth poorly — the centre of the
demo's walk, 0.3 m baseline at 320×240, moved by up to 2 m along the rays from one frame to the next — so a 3D gate
split the subject into short tracks and left the first 12–23 frames of two of three demo seeds without
detections); the subject is the track seen in the most views
over the recording (Σ views over its frames): the person whose detections triangulate consistently across cameras
and who stays in view, not the first person of each file. Joints the subject's detection in a view misses are
taken from another detection of that view lying on the subject's triangulated joints (a detector that split the
person in two). In a frame where the subject forms no multi-view person
(seen by one camera), each view takes the detection nearest (within ``τ_v``) to the projection of the subject's
joints at the nearest frame of its track (at most ``max_gap`` frames away). With one camera the subject is the
largest detection (bounding-box diagonal of its confident joints) of each frame. With ``mirrored`` (detections of
the built-in detector, :mod:`jaxmocap.io.detect`, which may read a person seen from behind as facing the camera),
a view the subject leaves out takes a detection whose left-right mirror lies within ``τ_v`` of the subject's
projection, mirrored.

**Calibration checks** (:func:`check_rig`). Over frames where two or more views detect someone: the median over
frames of the best 2-view residual ``/ τ`` of every pair of cameras. When some pair disagrees (> 1), every
assignment of the detection folders to the cameras (up to 6 cameras) is tried: if another order makes every pair
agree, the input is refused naming that order; a camera that agrees with no other camera is refused; and the
triangulated subject's limbs must be of human size up to a unit's factor: thigh and upper arm are 0.15–0.8 m, and
the median triangulated length is refused outside 0.05–3 m (a 1000× larger subject means translations in
millimetres, a 100× larger one centimetres; the margin lets a stereo pair with a short baseline, whose
triangulation of noisy detections stretches the limbs, pass: 0.92 m measured on a synthetic walk at 320×240 over a
0.3 m baseline).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import NamedTuple

import cv2
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry.body import EVAL_JOINTS

__all__ = [
    "NOISY_VIEW",
    "OUTLIER_FACTOR",
    "Person",
    "SubjectKeypoints",
    "ViewGeometry",
    "body_dimensions",
    "check_order",
    "check_rig",
    "check_rig_silhouettes",
    "limb_lengths",
    "load_subject",
    "multiview_persons",
    "select_subject",
    "subject_box",
    "view_noise",
    "view_noise_notes",
]

C_MIN = 0.3
TAU_FRACTION = 0.03
PAIR_FRACTION = 0.015
MIN_JOINTS = 4


class ViewGeometry:
    """The rig's cameras for host-side triangulation: ``P (V, 3, 4)`` = ``[R | t]`` in normalised coordinates,
    focal lengths ``f (V,)`` (pixels per normalised unit, the mean of ``f_x, f_y``) and thresholds ``tau (V,)``."""

    def __init__(self, rig):
        self.K = np.asarray(rig.K, np.float64)
        self.dist = np.asarray(rig.dist, np.float64)
        R, t = np.asarray(rig.R, np.float64), np.asarray(rig.t, np.float64)
        self.P = np.concatenate([R, t[:, :, None]], axis=2)
        self.f = 0.5 * (self.K[:, 0, 0] + self.K[:, 1, 1])
        self.tau = np.asarray([max(TAU_FRACTION * max(w, h), 2.0) for w, h in rig.image_size], np.float64)
        self.names = list(rig.names)
        self.num_views = len(self.names)

    def normalise(self, v: int, kp: np.ndarray) -> np.ndarray:
        """``(…, J, 3)`` pixel keypoints of view ``v`` → ``(…, J, 3)`` undistorted normalised coordinates (a, b, c)."""
        kp = np.asarray(kp, np.float64)
        flat = kp[..., :2].reshape(-1, 1, 2)
        ab = cv2.undistortPoints(flat, self.K[v], self.dist[v]).reshape(*kp.shape[:-1], 2)
        return np.concatenate([ab, kp[..., 2:3]], axis=-1)

    def triangulate(self, views: list[int], ab: np.ndarray, scale: np.ndarray | None = None) -> np.ndarray:
        """Joints ``(J, 3)`` from ``ab (n, J, 3)`` of ``views`` (weights: confidence > ``C_MIN``, times ``scale``
        ``(n,)`` per view or ``(n, J)`` per view and joint when given); NaN for a joint with fewer than two such
        views."""
        w = np.where(ab[..., 2] > C_MIN, 1.0, 0.0)  # (n, J)
        seen = np.sum(w, axis=0)
        if scale is not None:
            scale = np.asarray(scale, np.float64)
            w = w * (scale[:, None] if scale.ndim == 1 else scale)
        P = self.P[views]  # (n, 3, 4)
        rows_a = w[..., None] * (ab[..., 0:1] * P[:, None, 2] - P[:, None, 0])  # (n, J, 4)
        rows_b = w[..., None] * (ab[..., 1:2] * P[:, None, 2] - P[:, None, 1])
        A = np.concatenate([rows_a, rows_b], axis=0).transpose(1, 0, 2)  # (J, 2n, 4)
        _, _, vh = np.linalg.svd(A)
        h = vh[:, -1]
        with np.errstate(all="ignore"):
            X = h[:, :3] / h[:, 3:4]
        X[seen < 2] = np.nan
        return X

    def in_front(self, views: list[int], X: np.ndarray) -> np.ndarray:
        """``(J,)``: whether each joint of ``X (J, 3)`` lies in front of every camera of ``views`` (False where
        ``X`` is not finite)."""
        ok = np.all(np.isfinite(X), axis=1)
        Xf = np.where(ok[:, None], X, 0.0)
        for v in views:
            ok &= Xf @ self.P[v, 2, :3] + self.P[v, 2, 3] > 1e-6
        return ok

    def lateral_distance(self, a: np.ndarray, b: np.ndarray) -> float:
        """The distance (m) between points ``a`` and ``b`` ``(3,)`` across the cameras' lines of sight: per camera,
        the offset of ``b`` from ``a`` perpendicular to the camera's ray through their midpoint; the largest over
        the cameras. Several cameras around a person bound every direction (the depth of one is across the ray of
        another); a close pair leaves out the depth, which it triangulates poorly."""
        R, t = self.P[:, :, :3], self.P[:, :, 3]
        ray = (0.5 * (a + b)) @ R.transpose(0, 2, 1) + t  # (V, 3) midpoint in each camera's frame
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        d = (b - a) @ R.transpose(0, 2, 1)  # (V, 3) the offset in each camera's frame
        across = d - np.sum(d * ray, axis=1, keepdims=True) * ray
        return float(np.max(np.linalg.norm(across, axis=1)))

    def joint_residuals(self, v: int, X: np.ndarray, ab: np.ndarray) -> np.ndarray:
        """``(J,)`` pixel distances between the projections of ``X (J, 3)`` into view ``v`` and ``ab (J, 3)``; inf
        where ``X`` is not finite, a detection has confidence ≤ ``C_MIN`` or a point is behind the camera."""
        out = np.full(len(X), np.inf)
        ok = np.all(np.isfinite(X), axis=1) & (ab[:, 2] > C_MIN)
        xc = X[ok] @ self.P[v, :, :3].T + self.P[v, :, 3]
        front = xc[:, 2] > 1e-6
        d = np.linalg.norm(xc[front, :2] / xc[front, 2:3] - ab[ok][front, :2], axis=1) * self.f[v]
        idx = np.flatnonzero(ok)[front]
        out[idx] = d
        return out

    def residual(self, v: int, X: np.ndarray, ab: np.ndarray) -> float:
        """Median over joints (finite in ``X``, confidence > ``C_MIN`` in ``ab (J, 3)``) of the pixel distance
        between the projection of ``X`` into view ``v`` and the detections; inf with fewer than ``MIN_JOINTS`` or
        a point behind the camera."""
        ok = np.all(np.isfinite(X), axis=1) & (ab[:, 2] > C_MIN)
        if ok.sum() < MIN_JOINTS:
            return np.inf
        r = self.joint_residuals(v, X, ab)[ok]
        return float(np.median(r)) if np.all(np.isfinite(r)) else np.inf


class Person(NamedTuple):
    """A person seen in several views of one frame: ``views {view: detection index}``, the triangulated joints
    ``X (15, 3)`` (NaN where unknown), the residual ``/ τ`` per view, its centre ``(3,)`` and ``behind (15,)``:
    the joints whose rays met behind a camera (detections that contradict each other, e.g. left and right
    exchanged in one view)."""

    views: dict[int, int]
    X: np.ndarray
    score: dict[int, float]
    centre: np.ndarray
    behind: np.ndarray


def _person(geo: ViewGeometry, ab: list[np.ndarray], chosen: dict[int, int]) -> Person | None:
    views = sorted(chosen)
    X = geo.triangulate(views, np.stack([ab[v][chosen[v]] for v in views]))
    behind = np.all(np.isfinite(X), axis=1) & ~geo.in_front(views, X)
    X[behind] = np.nan  # no triangulation: rays that meet behind a camera
    if np.sum(np.all(np.isfinite(X), axis=1)) < MIN_JOINTS:
        return None
    score = {v: geo.residual(v, X, ab[v][chosen[v]]) / geo.tau[v] for v in views}
    return Person(dict(chosen), X, score, np.nanmedian(X, axis=0), behind)


def multiview_persons(geo: ViewGeometry, dets: list[np.ndarray], max_seeds: int = 20) -> list[Person]:
    """The persons of one frame seen consistently by two or more views (module docstring); ``dets``: per view the
    detections ``(P_v, 15, 3)`` in pixels."""
    ab = [geo.normalise(v, d) if len(d) else d for v, d in enumerate(dets)]
    free = {
        (v, p) for v, d in enumerate(dets) for p in range(len(d)) if np.sum(d[p, :, 2] > C_MIN) >= MIN_JOINTS
    }
    out = []
    while True:
        seeds = []
        for a, b in itertools.combinations(range(geo.num_views), 2):
            for i, j in itertools.product(range(len(dets[a])), range(len(dets[b]))):
                if (a, i) in free and (b, j) in free:
                    s = _person(geo, ab, {a: i, b: j})
                    if s is not None and max(s.score.values()) <= 1.0:
                        seeds.append((max(s.score.values()), s))
        if not seeds:
            return out
        seeds.sort(key=lambda x: x[0])
        best, best_key = None, None
        for _, seed in seeds[:max_seeds]:
            chosen = dict(seed.views)
            for v in range(geo.num_views):
                if v in chosen:
                    continue
                fits = [
                    (geo.residual(v, seed.X, ab[v][p]) / geo.tau[v], p)
                    for p in range(len(dets[v]))
                    if (v, p) in free
                ]
                if fits and min(fits)[0] <= 1.0:
                    chosen[v] = min(fits)[1]
            person = _person(geo, ab, chosen) if len(chosen) > 2 else seed
            if person is None or max(person.score.values()) > 1.0:
                person = seed
            key = (-len(person.views), float(np.mean(list(person.score.values()))))
            if best_key is None or key < best_key:
                best, best_key = person, key
        out.append(best)
        free -= {(v, p) for v, p in best.views.items()}


def _largest(dets: np.ndarray) -> int | None:
    best, size = None, -1.0
    for p, kp in enumerate(dets):
        ok = kp[:, 2] > 0.1
        if ok.sum() >= 2:
            d = float(np.linalg.norm(kp[ok, :2].max(axis=0) - kp[ok, :2].min(axis=0)))
            if d > size:
                best, size = p, d
    return best


def _completed(geo: ViewGeometry, v: int, X: np.ndarray, dets: np.ndarray, p: int, taken: set) -> np.ndarray:
    """Detection ``p`` of view ``v`` with the joints it misses taken from the view's other detections (not part
    of a multi-view person, ``taken``) where they lie within ``τ_v`` of the projection of the person's ``X``: a
    detector that splits one person in two (upper and lower body) gives back one person."""
    out = dets[p].copy()
    missing = out[:, 2] <= C_MIN
    if not missing.any():
        return out
    for q in range(len(dets)):
        if q == p or (v, q) in taken:
            continue
        r = geo.joint_residuals(v, X, geo.normalise(v, dets[q]))
        fill = missing & (r <= geo.tau[v])
        out[fill] = dets[q][fill]
        missing &= ~fill
    return out


def _link(geo: ViewGeometry, persons: list[list[Person]], fps: float) -> list[dict[int, Person]]:
    """Tracks ``{frame index: person}``: each frame's persons joined to the track whose last centre is nearest
    across the cameras' lines of sight (:meth:`ViewGeometry.lateral_distance`), within ``0.5 m + 3 m/s · Δt``."""
    tracks: list[dict[int, Person]] = []
    for t, frame in enumerate(persons):
        pairs = []
        for k, tr in enumerate(tracks):
            last = max(tr)
            gate = 0.5 + 3.0 * (t - last) / fps
            for i, p in enumerate(frame):
                d = geo.lateral_distance(tr[last].centre, p.centre)
                if d <= gate:
                    pairs.append((d, k, i))
        used_t, used_p = set(), set()
        for _, k, i in sorted(pairs):
            if k not in used_t and i not in used_p:
                tracks[k][t] = frame[i]
                used_t.add(k)
                used_p.add(i)
        tracks += [{t: p} for i, p in enumerate(frame) if i not in used_p]
    return tracks


#: Index of each evaluation joint's left-right mirror (``left_*`` ↔ ``right_*``; root, thorax and head stay).
MIRROR = [
    EVAL_JOINTS.index(j.replace("left_", "right_") if j.startswith("left_") else j.replace("right_", "left_"))
    for j in EVAL_JOINTS
]


def _best_fit(geo: ViewGeometry, v: int, X: np.ndarray, dets: np.ndarray, skip, mirrored: bool):
    """The detection of view ``v`` (``(P, 15, 3)``, indices in ``skip`` left out), or with ``mirrored`` its
    left-right mirror (:data:`MIRROR`), whose residual to the projection of ``X`` is smallest and ``≤ τ_v``; None
    when none is."""
    best = None
    for p in range(len(dets)):
        if p in skip:
            continue
        for kp in (dets[p], dets[p][MIRROR]) if mirrored else (dets[p],):
            r = geo.residual(v, X, geo.normalise(v, kp)) / geo.tau[v]
            if r <= 1.0 and (best is None or r < best[0]):
                best = (r, kp)
    return None if best is None else best[1]


def select_subject(
    rig, dets: list[list[np.ndarray]], fps: float = 30.0, max_gap: int = 10, mirrored: bool = False
) -> tuple[np.ndarray, dict]:
    """The subject's keypoints ``(T, V, 15, 3)`` (zeros where a view has none) from ``dets[t][v]`` ``(P, 15, 3)``
    (module docstring), and a report: ``persons`` (multi-view persons per frame), ``subject_frames`` (frames
    where the subject is a multi-view person) and ``views_per_frame``. ``mirrored``: a view that the multi-view
    subject of a frame leaves out takes a detection whose left-right mirror lies on the subject's projection (a
    detector that read a person seen from behind as facing it), mirrored; and the mirrors count in frames where the
    subject is seen by one view."""
    T, V = len(dets), rig.num_views
    out = np.zeros((T, V, len(EVAL_JOINTS), 3))
    if V == 1:
        for t in range(T):
            p = _largest(dets[t][0])
            if p is not None:
                out[t, 0] = dets[t][0][p]
        return out, {"persons": [], "subject_frames": 0, "views_per_frame": []}
    geo = ViewGeometry(rig)
    persons = [multiview_persons(geo, dets[t]) for t in range(T)]
    tracks = _link(geo, persons, fps)
    report = {"persons": [len(p) for p in persons], "subject_frames": 0, "views_per_frame": [0] * T}
    if not tracks:
        return out, report
    subject = max(tracks, key=lambda tr: (sum(len(p.views) for p in tr.values()), len(tr)))
    report["subject_frames"] = len(subject)
    known = sorted(subject)
    for t in range(T):
        if t in subject:
            taken = {(v, p) for person in persons[t] for v, p in person.views.items()}
            for v, p in subject[t].views.items():
                out[t, v] = _completed(geo, v, subject[t].X, dets[t][v], p, taken)
                out[t, v, subject[t].behind, 2] = 0.0  # contradicting detections: none of them is kept
            for v in range(V) if mirrored else ():
                if v not in subject[t].views:
                    kp = _best_fit(geo, v, subject[t].X, dets[t][v], {p for w, p in taken if w == v}, True)
                    if kp is not None:
                        out[t, v] = kp
            continue
        near = min(known, key=lambda k: abs(k - t))
        if abs(near - t) > max_gap:
            continue
        for v in range(V):
            kp = _best_fit(geo, v, subject[near].X, dets[t][v], (), mirrored)
            if kp is not None:
                out[t, v] = kp
    report["views_per_frame"] = [int(np.sum(np.any(out[t, :, :, 2] > 0, axis=1))) for t in range(T)]
    return out, report


def subject_box(kp: np.ndarray | None, shape) -> np.ndarray:
    """``(H, W)`` bool: False inside the bounding box of the confident (> 0.1) keypoints ``kp (K, 3)`` widened by
    25 % of its height on every side, True elsewhere (everywhere without two such keypoints)."""
    keep = np.ones(shape, bool)
    if kp is None:
        return keep
    ok = kp[:, 2] > 0.1
    if ok.sum() >= 2:
        lo, hi = kp[ok, :2].min(axis=0), kp[ok, :2].max(axis=0)
        pad = 0.25 * (hi[1] - lo[1])
        x0, y0 = np.floor(lo - pad).astype(int)
        x1, y1 = np.ceil(hi + pad).astype(int)
        keep[max(y0, 0) : max(y1 + 1, 0), max(x0, 0) : max(x1 + 1, 0)] = False
    return keep


# ---------------------------------------------------------------------------------------------------------------
# What the detections say about the calibration


def _pair_score(
    geo: ViewGeometry,
    cams: tuple[int, int],
    dets: tuple[np.ndarray, np.ndarray],
    min_joints: int = MIN_JOINTS,
) -> float:
    """The best 2-view residual (px, the larger of the two views) over the detection pairs of two cameras
    (``min_joints`` joints triangulated at least): inf when every pair triangulates behind a camera, NaN when no
    pair has enough joints."""
    a, b = cams
    if not len(dets[0]) or not len(dets[1]):
        return np.nan
    ab_a, ab_b = geo.normalise(a, dets[0]), geo.normalise(b, dets[1])
    best = np.nan
    for i, j in itertools.product(range(len(dets[0])), range(len(dets[1]))):
        X = geo.triangulate([a, b], np.stack([ab_a[i], ab_b[j]]))
        ok = np.all(np.isfinite(X), axis=1)
        if ok.sum() >= min_joints:
            r = np.concatenate(
                [geo.joint_residuals(a, X, ab_a[i])[ok], geo.joint_residuals(b, X, ab_b[j])[ok]]
            )
            score = float(np.median(r)) if np.all(np.isfinite(r)) else np.inf
            best = score if np.isnan(best) else min(best, score)
    return best


def _pair_table(geo: ViewGeometry, dets: list[list[np.ndarray]], min_joints: int, orders: bool) -> dict:
    """``{(a, b, x, y): median over frames of the best 2-view residual (px) of cameras a < b seeing the
    detections of folders x and y}`` (``orders``: every x ≠ y, else x = a, y = b)."""
    V = geo.num_views
    out = {}
    for a, b in itertools.combinations(range(V), 2):
        for x, y in itertools.permutations(range(V), 2) if orders else [(a, b)]:
            s = [_pair_score(geo, (a, b), (d[x], d[y]), min_joints) for d in dets]
            s = [v for v in s if not np.isnan(v)]
            out[a, b, x, y] = float(np.median(s)) if s else np.nan
    return out


def _agreement(table: dict, order: tuple[int, ...]) -> np.ndarray:
    """``M (V, V)``: the 2-view residual (px) of cameras ``a, b`` when camera ``c`` sees folder ``order[c]``."""
    V = len(order)
    M = np.full((V, V), np.nan)
    for a, b in itertools.combinations(range(V), 2):
        M[a, b] = M[b, a] = table[a, b, order[a], order[b]]
    return M


def limb_lengths(X: np.ndarray) -> np.ndarray:
    """Thigh and upper-arm lengths ``(4,)`` (left, right) of evaluation joints ``X (15, 3)``; NaN where unknown."""
    j = {n: i for i, n in enumerate(EVAL_JOINTS)}
    pairs = [
        ("left_hip", "left_knee"),
        ("right_hip", "right_knee"),
        ("left_shoulder", "left_elbow"),
        ("right_shoulder", "right_elbow"),
    ]
    return np.asarray([np.linalg.norm(X[j[a]] - X[j[b]]) for a, b in pairs])


def _sample(dets: list[list[np.ndarray]], max_frames: int) -> list[list[np.ndarray]]:
    """Up to ``max_frames`` frames spread over those where two or more views detect someone."""
    useful = [t for t, d in enumerate(dets) if sum(len(x) > 0 for x in d) >= 2]
    if not useful:
        return []
    pick = [useful[int(i)] for i in np.round(np.linspace(0, len(useful) - 1, min(max_frames, len(useful))))]
    return [dets[t] for t in sorted(set(pick))]


def check_order(
    geo: ViewGeometry,
    sample: list[list[np.ndarray]],
    source,
    min_joints: int = MIN_JOINTS,
    what: str = "detections",
):
    """``M (V, V)`` 2-view residuals (px) of the given order; refuses (``MocapInputError``) when another assignment
    of the inputs to the cameras (up to 6 cameras) has less than half the summed residual (a pair triangulating
    behind a camera counts as infinite)."""
    V = geo.num_views
    table = _pair_table(geo, sample, min_joints, orders=V <= 6)
    ident = tuple(range(V))
    M = _agreement(table, ident)
    if V <= 6 and not np.all(np.nan_to_num(M, nan=0.0) <= PAIR_FRACTION / TAU_FRACTION * np.min(geo.tau)):
        total = lambda o: float(np.nansum(_agreement(table, o)))  # noqa: E731
        best = min(itertools.permutations(range(V)), key=total)
        if best != ident and total(best) < 0.5 * total(ident):
            order = ", ".join(f"input {best[c] + 1} → camera {geo.names[c]!r}" for c in range(V))
            given = (
                "behind the cameras in the given order"
                if not np.isfinite(total(ident))
                else f"{total(ident):.0f} px in the given order"
            )
            raise MocapInputError(
                source,
                f"the {what} triangulate far better with the inputs in another order than the calibration's "
                f"cameras ({order}: 2-view residuals {total(best):.0f} px in all, {given}): give the videos in "
                "the calibration's camera order",
            )
    return M


#: the median triangulated thigh / upper-arm length (m) outside which the calibration's units are refused: a
#: person's 0.15–0.8 m with room for triangulation noise, still a factor ≥ 10 from a unit error's lengths
LIMB_UNIT_RANGE = (0.05, 3.0)


def check_rig(rig, dets: list[list[np.ndarray]], source=None, max_frames: int = 12) -> list[str]:
    """Refuse (``MocapInputError`` naming ``source``) a calibration the detections ``dets[t][v]`` contradict
    (module docstring); returns notes. Uses up to ``max_frames`` frames spread over those where two or more views
    detect someone; says nothing with fewer than three such frames."""
    V = rig.num_views
    sample = _sample(dets, max_frames)
    if V < 2 or len(sample) < 3:
        return []
    geo = ViewGeometry(rig)
    names = geo.names
    limit = PAIR_FRACTION / TAU_FRACTION * geo.tau  # (V,) px
    M = check_order(geo, sample, source)
    notes = []
    worst = np.nan_to_num(M / np.minimum(limit[:, None], limit[None, :]), nan=0.0)
    if worst.max() > 1.0:
        for c in range(V):
            others = [M[c, b] for b in range(V) if b != c and not np.isnan(M[c, b])]
            if others and min(others) > limit[c]:
                raise MocapInputError(
                    source,
                    f"camera {names[c]!r}: its detections agree with no other camera's (2-view residual "
                    f"{min(others):.0f} px at best, {limit[c]:.0f} px expected at most): its calibration does "
                    "not match its video (camera order? another recording?)",
                )
        a, b = np.unravel_index(np.argmax(worst), worst.shape)
        notes.append(f"cameras {names[a]!r} and {names[b]!r} agree poorly (2-view residual {M[a, b]:.0f} px)")
    lengths = []
    for frame in sample:
        for p in multiview_persons(geo, frame):
            lengths += [x for x in limb_lengths(p.X) if np.isfinite(x)]
    if len(lengths) >= 4:
        med = float(np.median(lengths))
        if not LIMB_UNIT_RANGE[0] <= med <= LIMB_UNIT_RANGE[1]:
            hint = " (translations in millimetres? --calibration-units mm)" if 150 <= med <= 800 else ""
            raise MocapInputError(
                source,
                f"the detections triangulate to limbs {med:.3g} m long (thigh and upper arm; 0.15-0.8 m for a "
                f"person, {LIMB_UNIT_RANGE[0]:g}-{LIMB_UNIT_RANGE[1]:g} m accepted): the calibration's units disagree with metres{hint}",
            )
    return notes


def check_rig_silhouettes(rig, centroids: np.ndarray, source=None) -> None:
    """The camera-order check of :func:`check_order` on silhouette centroids ``(T, V, 2)`` (pixels of ``rig``;
    NaN where a view sees no one): the centroids of one person's silhouettes are nearly the projections of one
    point, so the inputs in the calibration's order triangulate them consistently, in front of the cameras."""
    T, V = centroids.shape[:2]
    dets = []
    for t in range(T):
        row = []
        for v in range(V):
            if np.all(np.isfinite(centroids[t, v])):
                d = np.zeros((1, len(EVAL_JOINTS), 3))
                d[0, 0] = [*centroids[t, v], 1.0]
                row.append(d)
            else:
                row.append(np.zeros((0, len(EVAL_JOINTS), 3)))
        dets.append(row)
    sample = _sample(dets, T)
    if V >= 2 and len(sample) >= 3:
        check_order(ViewGeometry(rig), sample, source, min_joints=1, what="silhouettes")


# ---------------------------------------------------------------------------------------------------------------
# Keypoint folders → the subject


class SubjectKeypoints(NamedTuple):
    """The subject's detections ``keypoints (T, V, 15, 3)`` float32 (evaluation joints, :func:`select_subject`),
    the ``layout`` read, and ``notes`` for the user."""

    keypoints: np.ndarray
    layout: str
    notes: list[str]


def load_subject(
    folders,
    rig,
    frames: Sequence[int],
    fps: float = 30.0,
    layout: str = "auto",
    hint: str | None = None,
    check: bool = True,
    total: int | None = None,
    mirrored: bool = False,
) -> SubjectKeypoints:
    """Read one keypoint folder per camera (OpenPose-format JSON, :mod:`jaxmocap.io.openpose`) for the frame
    numbers ``frames``, matched by the frame number in the file names (a frame without a file has no detections;
    with ``total``, the videos' frame count, a file numbered ``≥ total`` is refused); the layout (``"auto"``: :func:`jaxmocap.io.keypoints.detect_layout`, then ``hint`` — e.g. a
    Pose2Sim ``Config.toml``'s — when the files leave it open); the calibration checks of :func:`check_rig`
    (``check``) and the subject of :func:`select_subject` (``mirrored``: left-right mirrors allowed)."""
    from jaxmocap.io import keypoints as kp_mod
    from jaxmocap.io.openpose import frame_files, read_people

    notes: list[str] = []
    raw = []  # raw[v][t]: list of (K, 3)
    count, count_file, pooled = None, None, []
    frames = [int(f) for f in frames]
    for folder in folders:
        files = frame_files(folder)
        late = [f for f in files if total is not None and f >= total]
        if late:
            raise MocapInputError(
                files[min(late)],
                f"keypoints of frame {min(late)}, but the videos have {total} frames (0-{total - 1}): file "
                "names must carry the videos' 0-based frame numbers",
            )
        missing = [t for t in frames if t not in files]
        if missing:
            shown = ", ".join(map(str, missing[:5])) + (", …" if len(missing) > 5 else "")
            notes.append(
                f"{folder}: no keypoint file for {len(missing)} of {len(frames)} frames ({shown}): no detections there"
            )
        per = []
        for t in frames:
            people = read_people(files[t]) if t in files else []
            if people:
                if count is None:
                    count, count_file = people[0].shape[0], files[t]
                elif people[0].shape[0] != count:
                    raise MocapInputError(
                        files[t], f"{people[0].shape[0]} keypoints per person, but {count_file} has {count}"
                    )
                if len(pooled) < 2000:
                    pooled += people
            per.append(people)
        raw.append(per)
    if count is None:
        notes.append("the keypoint files hold no detected person")
        empty = np.zeros((len(frames), rig.num_views, len(EVAL_JOINTS), 3), np.float32)
        return SubjectKeypoints(empty, "none", notes)
    where = folders[0]
    if layout == "auto":
        try:
            found = kp_mod.detect_layout(count, pooled)
        except ValueError as e:
            raise MocapInputError(count_file, str(e)) from None
        if found is None:
            if hint is None or kp_mod.COUNTS[hint] != count:
                raise MocapInputError(
                    where,
                    f"{count} keypoints per person: BODY_25 or BODY_25B? Say which with --keypoint-layout",
                )
            found = hint
        elif hint is not None and hint != found:
            notes.append(f"the keypoint files hold {count} keypoints per person: read as {found}, not {hint}")
        layout = found
    elif layout not in kp_mod.LAYOUTS:
        raise ValueError(
            f"unknown keypoint layout {layout!r}; choose one of auto, {', '.join(kp_mod.LAYOUTS)}"
        )
    elif kp_mod.COUNTS[layout] != count:
        raise MocapInputError(
            count_file, f"{count} keypoints per person, but the {layout} layout has {kp_mod.COUNTS[layout]}"
        )
    empty = np.zeros((0, len(EVAL_JOINTS), 3))
    dets = [
        [
            kp_mod.eval_keypoints(np.stack(raw[v][t]), layout) if raw[v][t] else empty
            for v in range(len(folders))
        ]
        for t in range(len(frames))
    ]
    if check:
        notes += check_rig(rig, dets, where)
    keypoints, report = select_subject(rig, dets, fps, mirrored=mirrored)
    if rig.num_views > 1 and report["subject_frames"] == 0:
        notes.append("no person is seen consistently by two cameras in any frame: no detections used")
    return SubjectKeypoints(keypoints.astype(np.float32), layout, notes)


def body_dimensions(keypoints: np.ndarray, rig) -> dict[str, float]:
    """Subject dimensions (metres) for :func:`jaxmocap.geometry.body.build` from its detections ``(T, V, 15, 3)``
    (evaluation joints, pixels of ``rig``): every joint triangulated per frame (confidence > ``C_MIN`` in at least
    two views), then the median over frames of each limb length (both sides pooled), shoulder and hip widths, the
    torso length ``|thorax − mid-hip|`` and the shoulder drop ``|thorax − mid-shoulder|``, with ``hip_drop = 0``:
    the detector's hips define the pelvis centre (their middle), so the model's root and thorax coincide with the
    middle of the detected hips and the detected neck. Dimensions no frame measures are left out."""
    kp = np.asarray(keypoints, np.float64)
    geo = ViewGeometry(rig)
    views = list(range(rig.num_views))
    X = np.stack(
        [
            geo.triangulate(views, np.stack([geo.normalise(v, kp[t, v]) for v in views]))
            for t in range(len(kp))
        ]
    )  # (T, 15, 3)
    j = {n: i for i, n in enumerate(EVAL_JOINTS)}

    def dist(a, b):
        return np.linalg.norm(X[:, j[a]] - X[:, j[b]], axis=-1)

    def med(*ds):
        v = np.concatenate(ds)
        v = v[np.isfinite(v)]
        return float(np.median(v)) if v.size else float("nan")

    def sides(a, b):
        return med(dist(f"left_{a}", f"left_{b}"), dist(f"right_{a}", f"right_{b}"))

    mid_hip = 0.5 * (X[:, j["left_hip"]] + X[:, j["right_hip"]])
    mid_shoulder = 0.5 * (X[:, j["left_shoulder"]] + X[:, j["right_shoulder"]])
    dims = {
        "upper_arm_length": sides("shoulder", "elbow"),
        "forearm_length": sides("elbow", "wrist"),
        "thigh_length": sides("hip", "knee"),
        "shin_length": sides("knee", "ankle"),
        "shoulder_width": med(dist("left_shoulder", "right_shoulder")),
        "hip_width": med(dist("left_hip", "right_hip")),
        "torso_length": med(np.linalg.norm(X[:, j["thorax"]] - mid_hip, axis=-1)),
        "shoulder_drop": med(np.linalg.norm(X[:, j["thorax"]] - mid_shoulder, axis=-1)),
        "hip_drop": 0.0,
    }
    return {n: v for n, v in dims.items() if np.isfinite(v) and (v > 0 or n == "hip_drop")}


#: A residual whose ``r² / (2 − h)`` exceeds this many times the view's median is a wrong detection, not noise
#: (:func:`view_noise`; for Gaussian noise one residual in a thousand).
OUTLIER_FACTOR = 10.0


def view_noise(
    keypoints: np.ndarray, rig, min_views: int = 3, rounds: int = 8, max_frames: int = 200
) -> np.ndarray:
    """``(V,)``: each view's keypoint noise (px per coordinate), measured from how its detections agree with the
    other views' (a variance-component estimate).

    Every joint of every frame seen by at least ``min_views`` views (confidence > ``C_MIN``) is triangulated from
    all of them, each view's rows weighed by ``f_v / σ_v`` (one standard deviation of its noise in normalised
    coordinates), and reprojected. A view's squared residual ``r²`` (px) has the expectation ``σ_v² (2 − h)``, with
    ``h`` its share of the fit (the trace of its 2×2 block of the hat matrix ``A N⁻¹ Aᵀ`` of the weighted
    projection Jacobians ``A``, ``N = Σ_v A_vᵀ A_v``): the triangulated point moves towards every detection, most
    towards a view that decides it alone. So ``σ_v² = Σ r² / Σ (2 − h)`` over the view's residuals (Förstner's
    estimate), leaving out a residual whose ``r² / (2 − h)`` is more than :data:`OUTLIER_FACTOR` times the view's
    median (a wrong detection, not noise). Starting from equal noise, the weights and the estimate
    are computed ``rounds`` times (iteratively reweighted least squares, as in a variance-component
    estimation): with equal weights a noisy view's error spreads into the views that constrain the same direction.
    With two views the two residuals are one disagreement split between them, hence ``min_views = 3``. NaN for a
    view with fewer than 20 residuals. ``keypoints (T, V, J, 3)`` in the pixels of ``rig``; at most ``max_frames``
    frames, spread evenly over the ``T``."""
    kp = np.asarray(keypoints, np.float64)
    geo = ViewGeometry(rig)
    V = geo.num_views
    views = list(range(V))
    R, t = geo.P[:, :, :3], geo.P[:, :, 3]
    picked = np.unique(np.linspace(0, kp.shape[0] - 1, min(max_frames, kp.shape[0])).round().astype(int))
    # every (frame, joint) seen by min_views views, as one batch of points: ab (V, M, 3)
    ab = np.stack([geo.normalise(v, kp[picked, v]) for v in views]).reshape(V, -1, 3)
    obs = ab[..., 2] > C_MIN
    seen = np.sum(obs, axis=0) >= min_views
    ab, obs = ab[:, seen], obs[:, seen]
    out = np.full(V, np.nan)
    if not seen.any():
        return out
    sigma = np.ones(V)
    for _ in range(rounds):
        scale = geo.f / sigma  # (V,)
        # the linear triangulation's rows measure the error times the point's depth in each view: weighed again
        # by 1/depth, its solution is the weighted reprojection fit to first order
        X = geo.triangulate(views, ab, scale)  # (M, 3)
        z = np.einsum("vj,nj->vn", R[:, 2], X) + t[:, 2:3]  # (V, M)
        with np.errstate(all="ignore"):
            X = geo.triangulate(views, ab, scale[:, None] / np.where(z > 1e-6, z, np.inf))
        xc = np.einsum("vij,nj->vni", R, X) + t[:, None]  # (V, M, 3)
        z = xc[..., 2]
        with np.errstate(all="ignore"):
            a, b = xc[..., 0] / z, xc[..., 1] / z
            zero = np.zeros_like(a)
            D = np.stack([np.stack([1 / z, zero, -a / z], -1), np.stack([zero, 1 / z, -b / z], -1)], -2)
            A = np.einsum("vnij,vjk->vnik", D, R) * (scale[:, None] * obs)[..., None, None]  # (V, M, 2, 3)
            A = np.where(np.isfinite(A), A, 0.0)
            Ni = np.linalg.pinv(np.einsum("vnij,vnik->njk", A, A))  # (M, 3, 3)
        h = np.einsum("vnij,njk,vnik->vn", A, Ni, A)  # (V, M): each view's share of the fit
        out = np.full(V, np.nan)
        for v in views:
            r = geo.joint_residuals(v, X, ab[v])
            ok = obs[v] & np.isfinite(r) & (z[v] > 0) & (2.0 - h[v] > 0.05)
            r2, dof = r[ok] ** 2, 2.0 - h[v][ok]
            if r2.size >= 20:
                kept = r2 / dof < OUTLIER_FACTOR * np.median(r2 / dof)
                out[v] = float(np.sqrt(np.sum(r2[kept]) / np.sum(dof[kept])))
        if not np.all(np.isfinite(out)):
            break
        sigma = out
    return out


#: A camera whose keypoint noise is this many times the median camera's is named in a run's notes
#: (:func:`view_noise_notes`).
NOISY_VIEW = 2.0


def view_noise_notes(names: Sequence[str], sigma: np.ndarray) -> list[str]:
    """What a run tells of its cameras' keypoint noise ``sigma (V,)`` (:func:`view_noise`): the noise of each
    measured camera, and the cameras :data:`NOISY_VIEW` times as noisy as the median camera or more, whose
    calibration or synchronisation is worth checking. Nothing when no camera was measured."""
    sigma = np.asarray(sigma, np.float64)
    if not np.any(np.isfinite(sigma)):
        return []
    shown = ", ".join(f"{n} {s:.1f}" for n, s in zip(names, sigma, strict=True) if np.isfinite(s))
    out = [f"keypoint noise per camera (px, from how its detections agree with the others'): {shown}"]
    middle = float(np.nanmedian(sigma))
    noisy = [n for n, s in zip(names, sigma, strict=True) if s >= NOISY_VIEW * middle]
    if noisy:
        out.append(
            f"{', '.join(noisy)}: detections {NOISY_VIEW:g}× or more as far from the other cameras' as the median "
            "camera's; check the calibration and synchronisation of "
            + ("that camera" if len(noisy) == 1 else "those cameras")
        )
    return out
