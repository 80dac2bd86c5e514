"""Head and hands from skin blobs: the importance function of Fontmarty, Lerasle & Danès (IROS 2007, §IV-A).

Per frame, on the full-size images of a calibrated pair (views ``(0, 1)``):

1. candidate 3D skin blobs ``b_k`` with their first-view centroids ``u_k``: the ``max_blobs`` largest skin regions
   (:meth:`jaxmocap.features.skin.SkinModel.probability_u8`, :func:`jaxmocap.features.blobs.skin_blobs`) of each
   view, matched across the pair under the epipolar constraint and triangulated
   (:func:`jaxmocap.features.blobs.stereo_blobs`). With the stereo gate (``stereo_gate=True``, the default;
   :class:`jaxmocap.features.disparity.StereoGate`: the pair rectified at half size, its SGBM disparity turned
   into world points) a matched blob is kept only where the dense disparity agrees with its own (within
   ``max_disparity_error`` pixels at half size): in a cluttered room a face merged with skin-coloured clutter is
   matched to the wrong blob, metres off. When no kept blob can be a head (none as high as ``min_head_height``),
   the candidates are instead the skin regions of the first view where the dense stereo puts a pixel in the space
   a person can occupy (step 2), each at the median disparity of its pixels moved ``surface_offset`` × its radius
   along the viewing ray (the disparity is that of the visible surface; a head's centre lies about a radius
   behind it). Skin-coloured clutter on the walls fails that gate whatever its colour, and a face that touches
   such clutter in the image is cut from it, with no background model (the cameras may move); on a plain
   backdrop the matched blobs all agree and the result is that of the matching alone;
2. candidates outside the space a person can occupy are dropped: height ``z`` outside ``height_range`` (metres,
   world ``z`` up, floor at 0) or farther than ``max_range`` from the first camera (skin-coloured things on the
   walls);
3. the head (:func:`choose_head`): the blob whose first-view centroid lies in a face found by the Haar detector
   (:class:`jaxmocap.features.face.FaceDetector`; the face box nearest the blob when several), else — no face
   found, or none over a blob — the highest candidate whose height is at least ``min_head_height``. The face is
   searched for around each blob at the sizes a face box has at the blob's depth (``face_box``, 0.12–0.25 m:
   the cascade's boxes on the rendered faces measure 0.16–0.19 m), and not at all around a blob too far for a
   face to fill the cascade's 24-pixel window (beyond 5.3 m at a focal length of 512 px);
4. the hands: the two other candidates within ``reach`` of the head with the best scores (match confidence ×
   mean skin probability of the blob) whose size is a hand's (the disc of the blob's area at its depth has a
   radius of at most ``hand_radius``, 8 cm); of two such candidates closer than ``min_hand_gap`` (0.25 m: a hand
   and its own wrist or forearm) only the better is kept; a missing hand gets weight 0 in the IK;
5. left / right (:func:`assign_hands`): the assignment nearest to the wrists of a reference pose (the last good
   estimate) when there is one, else the person faces the first camera, so that the person's left hand is on the
   camera's right (larger ``x`` in its frame);
6. :func:`jaxmocap.fit.ik.from_head_hands` to the model's configuration nearest the reference pose (or the rest
   pose) that puts the head joint and the wrists on the blobs (:func:`head_hands_pose`).

Everything here runs on the host (OpenCV) except the IK, which is compiled once per model. The image work
(steps 1–2 and the face search, :meth:`HeadHandsDetector.look`) needs no pose, so the tracker runs it for the
next frame in a thread of its own while the current frame is tracked; steps 3–6 need the last estimate.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.features.blobs import skin_blobs, stereo_blobs
from jaxmocap.fit import ik
from jaxmocap.geometry import camera
from jaxmocap.tracking.init import joint_positions, root_translation_dofs

__all__ = [
    "HeadHands",
    "HeadHandsDetector",
    "Sighting",
    "assign_hands",
    "choose_head",
    "head_hands_pose",
    "warm_head_hands_pose",
]


class HeadHands(NamedTuple):
    """One frame's detection: ``head (3,)``, ``left (3,)``, ``right (3,)`` metres, ``weights (3,)`` (head, left,
    right; 0 for a hand not seen) and ``how``: ``"face"`` (the head chosen by the face detector) or ``"highest"``."""

    head: np.ndarray
    left: np.ndarray
    right: np.ndarray
    weights: np.ndarray
    how: str


class Sighting(NamedTuple):
    """What a frame's images show (:meth:`HeadHandsDetector.look`, steps 1–2 and the faces of step 3): the
    plausible blobs ``points (K, 3)``, first-view ``centroids (K, 2)``, ``scores (K,)``, ``radii (K,)``
    (:meth:`HeadHandsDetector.candidates`) and the face boxes ``faces (F, 4)`` found near them."""

    points: np.ndarray
    centroids: np.ndarray
    scores: np.ndarray
    radii: np.ndarray
    faces: np.ndarray


def choose_head(
    points: np.ndarray, centroids: np.ndarray, faces: np.ndarray, min_head_height: float = 1.0
) -> tuple[int | None, str]:
    """Index of the head among candidate blobs and how it was chosen.

    ``points (K, 3)``: the candidates' 3D positions; ``centroids (K, 2)``: their first-view pixel centroids;
    ``faces (F, 4)``: face boxes ``(x, y, w, h)`` in that view. A blob whose centroid lies in a face box is the head
    (``"face"``; among several, the one nearest its box's centre); else the highest blob with ``z ≥
    min_head_height`` (``"highest"``); ``(None, "none")`` when neither exists."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    uv = np.asarray(centroids, np.float64).reshape(-1, 2)
    best, best_d = None, np.inf
    for x, y, w, h in np.asarray(faces, np.float64).reshape(-1, 4):
        inside = (uv[:, 0] >= x) & (uv[:, 0] <= x + w) & (uv[:, 1] >= y) & (uv[:, 1] <= y + h)
        d = np.hypot(uv[:, 0] - (x + w / 2), uv[:, 1] - (y + h / 2))
        for k in np.flatnonzero(inside):
            if d[k] < best_d:
                best, best_d = int(k), float(d[k])
    if best is not None:
        return best, "face"
    tall = np.flatnonzero(pts[:, 2] >= min_head_height)
    if tall.size == 0:
        return None, "none"
    return int(tall[np.argmax(pts[tall, 2])]), "highest"


def assign_hands(
    hands: np.ndarray, rig: camera.Rig, model=None, reference: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``(left, right)`` of two hand positions ``hands (2, 3)``: the assignment nearest the wrists of ``model`` at
    ``reference`` (a pose ``(D,)``) when given, else the one with the person's left hand on the first camera's right
    (larger camera ``x``: a person facing the camera)."""
    h = np.asarray(hands, np.float64)
    if reference is not None and model is not None:
        J = np.asarray(joint_positions(model, jnp.asarray(reference, model.offset.dtype)), np.float64)
        names = model.joint_names
        wl, wr = J[names.index("left_wrist")], J[names.index("right_wrist")]
        straight = np.linalg.norm(h[0] - wl) + np.linalg.norm(h[1] - wr)
        crossed = np.linalg.norm(h[1] - wl) + np.linalg.norm(h[0] - wr)
        return (h[0], h[1]) if straight <= crossed else (h[1], h[0])
    R, t = np.asarray(rig.R[0], np.float64), np.asarray(rig.t[0], np.float64)
    xc = h @ R[0] + t[0]
    return (h[0], h[1]) if xc[0] >= xc[1] else (h[1], h[0])


class HeadHandsDetector:
    """Head and hands of a frame (module docstring, steps 1–5): ``detector(images) -> HeadHands | None``.

    ``rig``: the calibration of the full-size ``images`` (BGR ``uint8``, one per view); ``views``: the stereo
    pair; ``skin_model`` / ``face_detector``: default the package's skin model and OpenCV's frontal-face
    cascade (``face=False``: no face detection, the head is the highest blob); ``min_area``: the smallest blob
    in pixels (default 20 at 640×480, in proportion to the image area, at least 4); ``stereo_gate``: the matched
    blobs checked against dense stereo at ``gate_scale`` of the full size, and the gated blobs when none is left
    that can be a head (step 1; ``max_disparity_error``, ``surface_offset``); ``face_box``: the sizes, metres, of
    the face boxes searched for at a blob's depth (step 3, :meth:`faces_near`); ``min_hand_gap``: step 4."""

    def __init__(
        self,
        rig: camera.Rig,
        views: tuple[int, int] = (0, 1),
        skin_model=None,
        face: bool = True,
        threshold: float = 0.5,
        max_blobs: int = 6,
        min_area: int | None = None,
        max_epipolar: float = 5.0,
        height_range: tuple[float, float] = (0.3, 2.3),
        max_range: float = 6.0,
        min_head_height: float = 1.0,
        reach: float = 1.2,
        hand_radius: float = 0.08,
        stereo_gate: bool = True,
        gate_scale: float = 0.5,
        surface_offset: float = 1.0,
        min_hand_gap: float = 0.25,
        max_disparity_error: float = 2.0,
        face_box: tuple[float, float] = (0.12, 0.25),
    ):
        from jaxmocap.features.skin import default_skin_model

        if rig.num_views < 2:
            raise ValueError("head and hands from skin blobs need a stereo pair (two views or more)")
        self.rig, self.views = rig, tuple(views)
        self.skin_model = skin_model or default_skin_model()
        self.face_detector = None
        if face:
            from jaxmocap.features.face import FaceDetector

            # faces of a person a few metres away are small: a lower size limit than OpenCV's default
            self.face_detector = FaceDetector(min_size=(12, 12), min_neighbors=4)
        if min_area is None:  # 20 pixels at 640x480, in proportion to the image area
            w, h = rig.image_size[0]
            min_area = max(4, round(20 * w * h / (640 * 480)))
        self.threshold, self.max_blobs, self.min_area = float(threshold), int(max_blobs), int(min_area)
        self.max_epipolar = float(max_epipolar)
        self.height_range, self.max_range = tuple(height_range), float(max_range)
        self.min_head_height, self.reach = float(min_head_height), float(reach)
        self.hand_radius = float(hand_radius)
        self.gate, self.surface_offset = None, float(surface_offset)
        self.min_hand_gap, self.max_disparity_error = float(min_hand_gap), float(max_disparity_error)
        if stereo_gate:
            from jaxmocap.features.disparity import StereoGate

            self.gate = StereoGate(rig, self.views, gate_scale, self.max_range, self.height_range)
        self._centre = camera.camera_centres_host(rig)[self.views[0]]
        i = self.views[0]
        self._axis = np.append(np.asarray(rig.R[i], np.float64)[2], np.asarray(rig.t[i], np.float64)[2])
        self._focal = float(np.asarray(rig.K[i], np.float64)[0, 0])
        self.face_box = tuple(float(s) for s in face_box)
        if len(self.face_box) != 2 or not 0 < self.face_box[0] <= self.face_box[1]:
            raise ValueError(
                f"face_box must be (smallest, largest) face box in metres, 0 < smallest ≤ largest: {face_box}"
            )

    def _depth(self, pts: np.ndarray) -> np.ndarray:
        """Depths ``(K,)`` of world points ``pts (K, 3)`` along the first view's optical axis, metres."""
        return pts @ self._axis[:3] + self._axis[3]

    def candidates(self, images) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(points (K, 3), first-view centroids (K, 2), scores (K,), radii (K,))`` of the plausible blobs; a
        score is the blob's mean skin probability in the first view (a hand is skin through and through; a noisy
        patch of clothing is skin in places), times the match's confidence without the stereo gate; a radius,
        metres, is that of the disc of the blob's first-view area at its depth, ``√(A/π) Z / f``.

        Without the stereo gate: the blobs of both views matched under the epipolar constraint and triangulated.
        With it (``stereo_gate=True``, :class:`jaxmocap.features.disparity.StereoGate`): those of the matched
        blobs whose disparity the dense stereo confirms; when none of them can be a head, the blobs of the first
        view's skin probability where the dense disparity puts a pixel in the space a person can occupy, each at
        the median disparity of its gated pixels (module docstring, step 1)."""
        matched = self._plausible(*self._matched_blobs(images))
        if self.gate is None:
            return matched
        frame = self.gate(images, self.views)
        keep = self.gate.agrees(frame, matched[0], self.max_disparity_error)
        matched = tuple(a[keep] for a in matched)
        if np.any(matched[0][:, 2] >= self.min_head_height):
            return matched
        return self._plausible(*self._gated_blobs(frame))

    def _plausible(self, pts, uv, score, radius):
        lo, hi = self.height_range
        ok = (pts[:, 2] >= lo) & (pts[:, 2] <= hi)
        ok &= np.linalg.norm(pts - self._centre, axis=1) <= self.max_range
        return pts[ok], uv[ok], score[ok], radius[ok]

    def _matched_blobs(self, images):
        i, j = self.views
        prob = [self.skin_model.probability_u8(images[v]) for v in (i, j)]
        blobs = [
            skin_blobs(p, self.threshold, self.max_blobs, self.min_area, with_labels=(k == 0))
            for k, p in enumerate(prob)
        ]
        pts, conf, matches = stereo_blobs(
            self.rig, blobs, (i, j), self.max_blobs, max_epipolar=self.max_epipolar
        )
        n = len(matches)
        pts, conf = pts[:n], conf[:n]
        first = [m.i for m in matches]
        uv = blobs[0].centroids[first].reshape(-1, 2)
        skinness = _mean_by_label(blobs[0].labels, prob[0], self.max_blobs)
        score = conf * skinness[first] if n else conf
        radius = np.sqrt(blobs[0].areas[first] / np.pi) * self._depth(pts) / self._focal if n else conf
        return pts, uv, score, radius

    def _gated_blobs(self, frame):
        g = self.gate
        prob = self.skin_model.probability_u8(frame.image)
        prob = np.where(frame.ok, prob, np.uint8(0))
        scale = g.size[0] / self.rig.image_size[self.views[0]][0]
        min_area = max(4, round(self.min_area * scale * scale))
        b = skin_blobs(prob, self.threshold, self.max_blobs, min_area, with_labels=True)
        n = len(b.areas)
        lab = b.labels
        disp = np.array(
            [np.nanmedian(frame.disparity[(lab == k + 1) & frame.ok]) for k in range(n)], np.float64
        )
        pts = g.to_world(np.column_stack([b.centroids, disp])).reshape(-1, 3)
        score = _mean_by_label(lab, prob, self.max_blobs)[:n]
        i = self.views[0]
        R, t, K, d = (
            np.asarray(a[i], np.float64) for a in (self.rig.R, self.rig.t, self.rig.K, self.rig.dist)
        )
        if n:
            uv = cv2.projectPoints(pts, cv2.Rodrigues(R)[0], t, K, d)[0].reshape(-1, 2)
        else:
            uv = np.zeros((0, 2))
        depth = self._depth(pts)
        radius = np.sqrt(b.areas / np.pi) * depth / g.P1[0, 0]
        # the disparity is the visible surface's; a head or a fist is round: its centre lies a radius behind
        ray = pts - self._centre
        pts = pts + self.surface_offset * radius[:, None] * ray / np.linalg.norm(ray, axis=1, keepdims=True)
        return pts, uv, score, radius

    def faces_near(
        self, image: np.ndarray, uv: np.ndarray, depth: np.ndarray | None = None, half: int = 48
    ) -> np.ndarray:
        """Face boxes ``(F, 4)`` found around the centroids ``uv (K, 2)`` (a face is searched for only where a
        candidate blob is: a fraction of the cost of the whole image).

        Without ``depth``: in windows of ``2·half`` pixels, boxes of every size from the detector's ``min_size``.
        With the blobs' depths ``depth (K,)`` (metres along the first camera's axis): only boxes whose size at that
        depth is a face's, ``face_box`` metres, i.e. ``s f / Z`` pixels for ``s`` in ``face_box``, in a window of
        ± the largest such box (a box that holds the centroid lies within it); a blob so far that the largest box
        is smaller than the cascade's window (24 px: no face there can be found) is not searched at all. Both
        bounds cut the cascade's work (its cost grows with the window's area and the number of scales) and the
        first drops boxes of skin-coloured clutter around a blob that are far larger than a face would be there."""
        H, W = image.shape[:2]
        fd = self.face_detector
        window = fd.window  # the cascade's own: no smaller box is found
        smallest, least_crop = max(fd.min_size[0], window[0]), max(2 * fd.min_size[0], window[0])
        out = []
        for k, (u, v) in enumerate(np.asarray(uv, np.float64).reshape(-1, 2)):
            h, bounds = half, (None, None)
            if depth is not None:
                z = float(depth[k])
                if z <= 0 or self._focal * self.face_box[1] / z < max(window):
                    continue
                h = int(np.ceil(self._focal * self.face_box[1] / z))  # the largest box, pixels
                lo = max(smallest, int(np.floor(self._focal * self.face_box[0] / z)))
                bounds = ((lo, lo), (h, h))
            x0, y0 = max(int(u) - h, 0), max(int(v) - h, 0)
            crop = image[y0 : min(int(v) + h, H), x0 : min(int(u) + h, W)]
            if min(crop.shape[:2]) < least_crop:
                continue
            for x, y, w, bh in fd.detect(crop, *bounds):
                out.append((x + x0, y + y0, w, bh))
        return np.asarray(out, np.float64).reshape(-1, 4)

    def __call__(self, images, model=None, reference: np.ndarray | None = None) -> HeadHands | None:
        """The frame's head and hands, or None without a head (``model``/``reference``: :func:`assign_hands`):
        :meth:`decide` on :meth:`look`."""
        return self.decide(self.look(images), model, reference)

    def look(self, images) -> Sighting:
        """The image work of a frame (OpenCV, no pose needed): the candidates and the faces near them. It does not
        depend on the last estimate, so the tracker runs it for the next frame while the current one is tracked
        (:meth:`jaxmocap.tracking.setup.TrackSetup.observe`)."""
        pts, uv, conf, radius = self.candidates(images)
        faces = np.zeros((0, 4))
        if self.face_detector is not None and len(pts):
            faces = self.faces_near(images[self.views[0]], uv, self._depth(pts))
        return Sighting(pts, uv, conf, radius, faces)

    def decide(self, seen: Sighting, model=None, reference: np.ndarray | None = None) -> HeadHands | None:
        """Steps 3–5 on a frame's :class:`Sighting`: the head, the hands and their sides, or None without a head."""
        pts, uv, conf, radius, faces = seen
        k, how = choose_head(pts, uv, faces, self.min_head_height)
        if k is None:
            return None
        head = pts[k]
        rest = [m for m in np.argsort(-conf, kind="stable") if m != k]
        rest = [
            m for m in rest if np.linalg.norm(pts[m] - head) <= self.reach and radius[m] <= self.hand_radius
        ]
        rest = rest[:2]
        if len(rest) == 2 and np.linalg.norm(pts[rest[0]] - pts[rest[1]]) < self.min_hand_gap:
            rest = rest[:1]  # two pieces of one arm (a hand and its wrist or forearm), not two hands
        hands = np.repeat(head[None], 2, axis=0)
        weights = np.array([1.0, 0.0, 0.0])
        if len(rest) == 2:
            left, right = assign_hands(pts[rest], self.rig, model, reference)
            return HeadHands(head, left, right, np.ones(3), how)
        if len(rest) == 1:  # one hand: on the side the reference (or the camera, against the head) puts it
            left, _ = assign_hands(np.stack([pts[rest[0]], head]), self.rig, model, reference)
            side = 0 if np.array_equal(left, pts[rest[0]]) else 1
            hands[side] = pts[rest[0]]
            weights[1 + side] = 1.0
        return HeadHands(head, hands[0], hands[1], weights, how)


def _mean_by_label(labels: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Mean of ``values (H, W)`` (``uint8``, read as ``/255``) over each label ``1 … n`` of ``labels (H, W)``:
    ``(n,)``."""
    on = labels > 0
    lab = labels[on]
    sums = np.bincount(lab, values[on].astype(np.float64), minlength=n + 1)
    counts = np.bincount(lab, minlength=n + 1)
    return sums[1:] / np.maximum(counts[1:], 1) / 255.0


def head_hands_pose(model, det: HeadHands, reference: np.ndarray | None = None) -> np.ndarray | None:
    """The configuration ``(D,)`` of :func:`jaxmocap.fit.ik.from_head_hands` for detection ``det``: started from
    ``reference`` (the last good estimate) moved so that its head is on the detected head when given — turned along
    the hands when both are seen, else keeping the reference's heading —, else from the rest pose turned along the
    hands; the prior pulls the angles towards the reference (or the rest pose). None when the fit is not finite.

    One compiled program per model and form (with or without a reference, :func:`_fit`): a frame's fit is one
    call, and :func:`warm_head_hands_pose` compiles both before a run's first frame."""
    dt = model.offset.dtype
    targets = jnp.asarray(np.stack([det.head, det.left, det.right]), dt)
    weights = jnp.asarray(det.weights, dt)
    if reference is None:
        x = _fit(model, targets, weights, None, jnp.asarray(True))
    else:
        both = bool(np.all(np.asarray(det.weights)[1:] > 0))
        x = _fit(model, targets, weights, jnp.asarray(reference, dt), jnp.asarray(both))
    x = np.asarray(x, np.float64)
    return x if np.all(np.isfinite(x)) else None


@jax.jit
def _fit(model, targets: jnp.ndarray, weights: jnp.ndarray, reference, both: jnp.ndarray) -> jnp.ndarray:
    """The state ``(D,)`` of :func:`head_hands_pose` for ``targets (3, 3)`` (head, left, right), ``weights (3,)``,
    ``reference (D,)`` or None, ``both``: both hands seen (a hand missing: the reference's heading is kept, only
    shifted to the head by :func:`_shift_head`)."""
    head, left, right = targets
    init = None
    if reference is not None:
        turned = ik.head_hands_init(model, head, left, right, reference)
        init = jnp.where(both, turned, _shift_head(model, reference, head))
    fit = ik.from_head_hands(model, head, left, right, weights=weights, init=init, prior_mean=reference)
    return fit.state


def _shift_head(model, x: jnp.ndarray, head: jnp.ndarray) -> jnp.ndarray:
    """``x (D,)`` with its root translated so that its head joint is at ``head (3,)`` (traceable)."""
    J = joint_positions(model, x)
    trans = jnp.asarray(root_translation_dofs(model))
    A = model.dof_axis[trans].T
    return x.at[trans].add(jnp.linalg.pinv(A) @ (head - J[model.joint_names.index("head")]))


def warm_head_hands_pose(model, rig: camera.Rig) -> None:
    """Compile :func:`head_hands_pose`'s programs (with and without a reference) and the joints of a reference pose
    that :func:`assign_hands` computes, on the rest pose standing in front of the first camera
    (:func:`jaxmocap.tracking.init.default_standing`): a run whose first sighting of a person comes after its first
    frame then compiles nothing at that frame."""
    from jaxmocap.tracking.init import default_standing

    x = default_standing(model, rig)
    J = np.asarray(joint_positions(model, jnp.asarray(x, model.offset.dtype)), np.float64)
    head, left, right = (J[model.joint_names.index(n)] for n in ("head", "left_wrist", "right_wrist"))
    det = HeadHands(head, left, right, np.ones(3), "highest")
    head_hands_pose(model, det, None)
    head_hands_pose(model, det, x)
