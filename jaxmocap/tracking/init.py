"""Initial and re-initialisation poses of a tracking run, from detections.

* :func:`initial_state` — the first frame's pose: the IK fit of the ground truth, of triangulated 2D keypoints, the
  rest pose facing the first camera over the triangulated silhouette centroid, or a file;
* :func:`reinit_mean` — after a track loss (and the detection-driven proposal centre of ICONDENSATION / IAPF):
  the IK fit of the triangulated keypoints, else the last good estimate with its root moved over the silhouette
  centroid.
"""

from __future__ import annotations

import math
import pathlib

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.fit import ik
from jaxmocap.geometry import body as body_mod
from jaxmocap.geometry import camera
from jaxmocap.io import export
from jaxmocap.io.keypoints import KEYPOINT_INDEX
from jaxmocap.stored_programs import stored_jit
from jaxmocap.transfer import to_device

__all__ = [
    "KEYPOINT_OF",
    "initial_state",
    "keypoint_pose",
    "move_root_over",
    "reinit_mean",
    "default_standing",
    "warm_keypoint_pose",
    "rest_facing",
    "root_translation_dofs",
    "silhouette_centroid",
]

#: Index of each evaluation joint a detector measures in the keypoints of a source (``(V, 15, 3)`` evaluation
#: joints, :func:`jaxmocap.io.keypoints.eval_keypoints`): all but the root and the head.
KEYPOINT_OF = KEYPOINT_INDEX

#: triangulated joints farther than this (m) from the median of the frame's triangulated joints are left out of the
#: first pose (a person's joints lie within about 1.1 m of their median; noisy detections in a close stereo pair
#: move a joint by about 0.2 m per pixel of disparity error along the ray, and a wrong detection in one view puts it
#: metres away: 14 m and 134 m seen on synthetic stereo sequences)
OUTLIER_M = 3.0

#: the pixel standard deviation a detection's weight assumes in the reprojection fit of :func:`keypoint_pose`
KEYPOINT_SIGMA_PX = 3.0


def silhouette_centroid(rig: camera.Rig, masks: np.ndarray | None, min_pixels: int = 20) -> np.ndarray | None:
    """Triangulated centroid ``(3,)`` of the foreground of every view with at least ``min_pixels`` pixels (needs
    two such views), else None."""
    if masks is None:
        return None
    uv, wts = [], []
    for m in masks:
        ys, xs = np.nonzero(m)
        ok = xs.size >= min_pixels
        uv.append([xs.mean(), ys.mean()] if ok else [0.0, 0.0])
        wts.append(1.0 if ok else 0.0)
    if sum(wts) < 2:
        return None
    X = camera.triangulate(rig.to_jax(jnp.float32), to_device(uv, jnp.float32), to_device(wts, jnp.float32))
    X = np.asarray(X, np.float64)
    return X if np.all(np.isfinite(X)) else None


#: ``joint_positions(model, x) -> (J, 3)``, compiled.
joint_positions = stored_jit(body_mod.joint_positions)


def root_translation_dofs(model) -> list[int]:
    return [d for d in model.topology.segment_dofs[0] if model.topology.dof_kinds[d] == "P"]


def move_root_over(model, x: np.ndarray, point: np.ndarray) -> np.ndarray:
    """``x`` with its root translated horizontally so that the model's mean joint lies above ``point``."""
    x = np.asarray(x, np.float64).copy()
    J = np.asarray(joint_positions(model, to_device(x, model.offset.dtype)), np.float64)
    shift = np.zeros(3)
    shift[:2] = point[:2] - J.mean(axis=0)[:2]
    trans = root_translation_dofs(model)
    if trans:
        A = np.asarray(model.dof_axis, np.float64)[trans].T  # (3, k)
        x[trans] += np.linalg.pinv(A) @ shift
    return x


def keypoint_pose(
    model, rig: camera.Rig, keypoints: np.ndarray, init: np.ndarray | None = None, depth=None
) -> np.ndarray | None:
    """IK state from 2D keypoints ``(V, K, 3)`` of every view (full-size pixels): each evaluation joint of
    :data:`KEYPOINT_OF` triangulated from the views that detect it (confidence > 0.1, at least two; those farther
    than :data:`OUTLIER_M` from the median of the others left out), the root as
    the middle of the hips, then :func:`jaxmocap.fit.ik.fit_pose`, refined by :func:`jaxmocap.fit.ik.fit_pose_2d` on
    the detections (weights confidence / :data:`KEYPOINT_SIGMA_PX`²; :func:`reprojection_fit`, which reads the
    frame's ``depth`` maps — one per view, metres, 0 = none — when given). None with fewer than four joints."""
    kp = np.asarray(keypoints, np.float64)
    rj = rig.to_jax(jnp.float32)
    # every joint in one call of one compiled program (NaN where fewer than two views detect it), not one call per
    # joint: dispatches wait for the interpreter lock while the filter step is traced in the thread beside this
    names_k = list(KEYPOINT_OF)
    ks = [KEYPOINT_OF[n] for n in names_k]
    c = np.where(kp[:, ks, 2] > 0.1, kp[:, ks, 2], 0.0).T  # (joints, V)
    uv_k = np.ascontiguousarray(kp[:, ks, :2].transpose(1, 0, 2), np.float32)  # (joints, V, 2)
    Xs = np.asarray(camera.triangulate(rj, uv_k, c.astype(np.float32)))  # float32, as the fit takes them
    targets = {n: Xs[i] for i, n in enumerate(names_k) if np.all(np.isfinite(Xs[i]))}
    if targets:  # a joint triangulated far from the others is a wrong detection or a match at a grazing angle
        centre = np.median(np.stack(list(targets.values())), axis=0)
        targets = {n: X for n, X in targets.items() if np.linalg.norm(X - centre) <= OUTLIER_M}
    if "left_hip" in targets and "right_hip" in targets:
        targets["root"] = 0.5 * (targets["left_hip"] + targets["right_hip"])
    names = model.joint_names
    Y = np.full((len(names), 3), np.nan)
    for i, n in enumerate(names):
        if n in targets:
            Y[i] = targets[n]
    if np.sum(np.all(np.isfinite(Y), axis=1)) < 4:
        return None
    # to_device, not jnp.asarray: a host array's conversion stages a program of its own per shape, and the first
    # re-initialisation from a previous pose (the only call with ``init``) would compile it on a new frame
    dt = np.dtype(model.offset.dtype)
    fit = ik.fit_pose(model, to_device(Y, dt), init=None if init is None else to_device(init, dt))
    x = np.asarray(fit.state, np.float64)
    if not np.all(np.isfinite(x)):
        return None
    # then the same model fitted to the detections themselves (reprojection error): the limb lengths tie the
    # joints' depths together, which triangulating each joint alone cannot do with close views
    uv = np.full((kp.shape[0], len(names), 2), np.nan)
    w = np.zeros((kp.shape[0], len(names)))
    for i, n in enumerate(names):
        if n in KEYPOINT_OF:
            k = KEYPOINT_OF[n]
            uv[:, i] = kp[:, k, :2]
            w[:, i] = np.where(kp[:, k, 2] > 0.1, kp[:, k, 2], 0.0) / KEYPOINT_SIGMA_PX**2
    return reprojection_fit(model, rj, uv, w, x, depth)


#: the distances (factors of the triangulated one, along the first camera's ray through the root) the reprojection
#: fit of :func:`keypoint_pose` starts from
DEPTH_STARTS = (0.7, 0.8, 0.9, 1.0, 1.1, 1.2, 1.3)
#: the joints whose depth-map readings place the body (trunk joints: their pixels lie well inside the silhouette),
#: the distance from the body's surface to those joint centres (m), and the readings' standard deviation (m)
DEPTH_JOINTS = ("thorax", "left_hip", "right_hip", "left_shoulder", "right_shoulder")
DEPTH_BEHIND_SURFACE = 0.1
DEPTH_SIGMA = 0.05


@stored_jit
def _fit_from(model, rig, uv, w, x0):
    """One reprojection fit from ``x0`` (:func:`jaxmocap.fit.ik.fit_pose_2d`), its joints ``(J, 3)`` and its
    weighted reprojection cost, compiled as one program (eager calls would compile every small operation), its
    trace kept on disk by a run of the command line (:func:`jaxmocap.stored_programs.stored_jit`)."""
    xf = ik.fit_pose_2d(model, rig, uv, w, x0)
    X = ik.model_joints(model, xf)
    r = camera.project(rig, X) - jnp.nan_to_num(uv)
    return xf, X, jnp.sum(w * jnp.sum(r**2, axis=-1))


_joints = stored_jit(ik.model_joints)
_project_with_depth = stored_jit(camera.project_with_depth)


def _depth_misfits(model, rig, X: np.ndarray, depth) -> np.ndarray:
    """``z_v − s − d_v`` (m) for the :data:`DEPTH_JOINTS` of joints ``X (J, 3)`` in the views with a depth map:
    ``z_v`` a joint's depth in camera ``v``, ``s`` = :data:`DEPTH_BEHIND_SURFACE`, ``d_v`` the median of the map's
    valid readings in the 5×5 pixels around the joint's projection (joints outside the image or without a
    reading are left out)."""
    idx = [model.joint_names.index(n) for n in DEPTH_JOINTS if n in model.joint_names]
    uv, z = (np.asarray(a, np.float64) for a in _project_with_depth(rig, to_device(X[idx], jnp.float32)))
    out = []
    for v, d in enumerate(depth):
        if d is None:
            continue
        H, W = d.shape
        for (u, vv), zj in zip(uv[v], z[v], strict=True):
            c, r = int(round(u)), int(round(vv))
            if not (0 <= c < W and 0 <= r < H):
                continue
            win = d[max(r - 2, 0) : r + 3, max(c - 2, 0) : c + 3]
            win = win[np.isfinite(win) & (win > 0)]
            if win.size:
                out.append(zj - DEPTH_BEHIND_SURFACE - float(np.median(win)))
    return np.asarray(out)


def reprojection_fit(
    model, rig: camera.Rig, uv: np.ndarray, w: np.ndarray, x: np.ndarray, depth=None
) -> np.ndarray:
    """The fitted state (:func:`jaxmocap.fit.ik.fit_pose_2d`) of least cost over starts from ``x`` and from ``x``
    with its limbs at the rest pose, each with the root moved along the first camera's ray to the distances
    :data:`DEPTH_STARTS`. The cost is the weighted reprojection error, plus, with ``depth`` maps, the squared
    depth misfits over :data:`DEPTH_SIGMA` (:func:`_depth_misfits`); the best start is then moved along the ray
    by the misfits' median and fitted once more. Detections alone leave a flat valley along the ray (with stereo
    views 0.3 m apart at 320×240, fits 0.3–0.5 m nearer than the truth reproject the noisy detections better
    than the truth does); the depth maps decide along it. ``x`` itself when every fit fails."""
    dtype = model.offset.dtype
    rest = np.asarray(model.rest_pose, np.float64)
    limbs = np.ones(len(rest), bool)
    limbs[list(model.topology.segment_dofs[0])] = False
    centre = camera.camera_centres_host(rig)[0]
    trans = root_translation_dofs(model)

    uv_j, w_j = to_device(uv, dtype), to_device(w, dtype)

    def fitted(x0):
        """``(state, cost, depth misfits)`` of a fit from ``x0`` (cost inf when it fails)."""
        xf, X, cost = (
            np.asarray(a, np.float64) for a in _fit_from(model, rig, uv_j, w_j, to_device(x0, dtype))
        )
        if not (np.all(np.isfinite(xf)) and np.isfinite(cost)):
            return xf, np.inf, np.zeros(0)
        dz = _depth_misfits(model, rig, X, depth) if depth is not None else np.zeros(0)
        return xf, float(cost + np.sum((dz / DEPTH_SIGMA) ** 2)), dz

    def along_ray(x0, factor):
        x0 = x0.copy()
        X0 = np.asarray(_joints(model, to_device(x0, dtype)), np.float64)[0]
        x0[trans] += (factor - 1.0) * (X0 - centre)
        return x0

    best, best_cost, best_dz = x, np.inf, np.zeros(0)
    for start in (x, np.where(limbs, rest, x)):
        for f in DEPTH_STARTS if len(trans) == 3 else (1.0,):
            xf, cost, dz = fitted(along_ray(start, f))
            if cost < best_cost:
                best, best_cost, best_dz = xf, cost, dz
    if best_dz.size and len(trans) == 3:
        # the depth readings' median misfit, taken out along the ray, and fitted once more
        root = np.asarray(_joints(model, to_device(best, dtype)), np.float64)[0]
        dist = float(np.linalg.norm(root - centre))
        xf, cost, _ = fitted(along_ray(best, 1.0 - float(np.median(best_dz)) / max(dist, 1e-6)))
        if cost < best_cost:
            best = xf
    return best


def rest_facing(model, rig: camera.Rig, point: np.ndarray) -> np.ndarray:
    """The rest pose standing below ``point`` (horizontally) and facing the first camera."""
    x = np.asarray(model.rest_pose, np.float64).copy()
    centre = camera.camera_centres_host(rig)[0]
    heading = [d for d in model.topology.segment_dofs[0] if model.dof_names[d].endswith("rz")]
    if heading:
        v = centre[:2] - point[:2]
        x[heading[0]] = math.atan2(v[1], v[0])
    return move_root_over(model, x, point)


def default_standing(model, rig: camera.Rig, distance: float = 3.0) -> np.ndarray:
    """The rest pose standing ``distance`` metres in front of the first camera (along its optical axis, on the
    floor), facing it: where a tracker starts when it sees nobody."""
    R = np.asarray(rig.R[0], np.float64)
    centre = camera.camera_centres_host(rig)[0]
    axis = R[2].copy()
    axis[2] = 0.0
    axis /= max(np.linalg.norm(axis), 1e-9)
    return rest_facing(model, rig, centre + distance * axis)


def warm_keypoint_pose(model, rig: camera.Rig, depth: bool = False) -> None:
    """Compile the programs of :func:`keypoint_pose` (its first form, and the re-initialisation's, which starts from
    a previous pose) by fitting the rest pose standing in front of the first camera (:func:`default_standing`),
    projected into every view of ``rig`` (full-size pixels); ``depth``: with the frames' depth maps. A run whose
    first pose came from elsewhere (the silhouettes, a file, the head and hands) but whose input has detections
    calls it before its first frame, so that its first re-initialisation from detections compiles nothing."""
    x = default_standing(model, rig)
    dt = np.dtype(model.offset.dtype)
    X = joint_positions(model, jax.device_put(x.astype(dt)))
    uv = np.asarray(camera.project(rig.to_jax(jnp.float32), X), np.float64)  # (V, J, 2)
    kp = np.zeros((rig.num_views, len(body_mod.EVAL_JOINTS), 3))
    for name, k in KEYPOINT_OF.items():
        if name in model.joint_names:
            kp[:, k, :2], kp[:, k, 2] = uv[:, model.joint_names.index(name)], 1.0
    maps = [np.zeros((1, 1), np.float32)] * rig.num_views if depth else None
    first = keypoint_pose(model, rig, kp, depth=maps)
    keypoint_pose(model, rig, kp, init=x if first is None else first, depth=maps)


def check_initial(model: body_mod.BodyModel, source, init: str, t0: int) -> None:
    """Raise :class:`MocapInputError` where ``init`` cannot give a first pose whatever the frame shows (no ground
    truth for ``groundtruth``, an unreadable or wrong-sized file): checked before the step compiles, so a bad option
    costs no compilation."""
    if init == "groundtruth" and source.groundtruth is None:
        raise MocapInputError(
            getattr(source, "root", None), "--init groundtruth needs a sequence with groundtruth.npz"
        )
    if init not in ("auto", "groundtruth", "ik", "head-hands"):
        pose_from_file(model, pathlib.Path(init), t0)


def initial_state(
    model: body_mod.BodyModel, source, rig: camera.Rig, init: str, t0: int, masks, fd
) -> tuple[np.ndarray, float, str]:
    """``(x0, spread factor, how)`` for the first frame ``t0`` (``init``: ``auto``, ``groundtruth``, ``ik`` or a
    file; ``rig``: the rig of the feature maps ``masks``; ``fd``: the frame's :class:`~jaxmocap.io.sources.FrameData`)."""
    if init == "auto":
        init = "groundtruth" if source.groundtruth is not None else "ik"
    if init == "groundtruth":
        gt = source.groundtruth
        if gt is None:
            raise MocapInputError(
                getattr(source, "root", None),
                "--init groundtruth needs a sequence with groundtruth.npz",
            )
        dt = model.offset.dtype
        targets = to_device(ik.select_joints(model, gt[t0]), dt)
        x = np.asarray(ik.fit_pose(model, targets).state, np.float64)
        if np.all(np.isfinite(x)):
            return x, 0.5, "groundtruth"
        # the pose fit failed (non-finite): the rest pose placed on the ground truth by Procrustes
        x = np.asarray(ik.root_init(model, targets), np.float64)
        if not np.all(np.isfinite(x)):
            x = move_root_over(model, np.asarray(model.rest_pose), np.nanmean(gt[t0], axis=0))
        return x, 2.0, "groundtruth-root"
    if init == "ik":
        if fd.keypoints is not None:
            x = keypoint_pose(model, source.rig, fd.keypoints, depth=fd.depth)
            if x is not None:
                return x, 1.0, "ik-keypoints"
        c = silhouette_centroid(rig, masks)
        if c is None:
            raise MocapInputError(
                None,
                f"cannot initialise at frame {t0}: no detection (no keypoints, and the person is not seen in two views)",
            )
        return rest_facing(model, rig, c), 2.0, "ik-silhouette"
    return pose_from_file(model, pathlib.Path(init), t0), 0.5, "file"


def pose_from_file(model: body_mod.BodyModel, path: pathlib.Path, t0: int) -> np.ndarray:
    """The initial pose ``(D,)`` in a file: ``.npz`` with ``state`` (the row of frame ``t0`` when it has
    ``frame_index``), ``.npy``, or text numbers; clipped to the joint limits."""
    D = model.num_dofs
    if not path.is_file():
        raise MocapInputError(path, "no such initial pose file (--init groundtruth|ik|FILE)")
    if path.suffix.lower() == ".npz":
        data = export._read_npz(path)
        if "state" not in data:
            raise MocapInputError(path, "no 'state' array")
        st = data["state"]
        if st.dtype.kind not in "biuf" or st.ndim not in (1, 2) or st.size == 0 or st.shape[-1] != D:
            raise MocapInputError(
                path,
                f"'state' is {st.dtype} {st.shape}: expected ({D},) or (T, {D}) numbers for the {model.name} model",
            )
        st = np.asarray(st, np.float64).reshape(-1, D)
        row = 0
        if "frame_index" in data:
            fi = data["frame_index"]
            if fi.dtype.kind not in "iu" or fi.shape != (st.shape[0],):
                raise MocapInputError(
                    path, f"'frame_index' is {fi.dtype} {fi.shape}: expected ({st.shape[0]},) integers"
                )
            hits = np.nonzero(fi == t0)[0]
            row = int(hits[0]) if hits.size else 0
        x = st[row]
    elif path.suffix.lower() == ".npy":
        try:
            x = np.asarray(np.load(path, allow_pickle=False), np.float64).reshape(-1)
        except (OSError, ValueError) as e:
            raise MocapInputError(path, f"cannot read: {e}") from None
    else:
        try:
            x = np.asarray(path.read_text().split(), np.float64)
        except (OSError, ValueError) as e:
            raise MocapInputError(path, f"expected {D} numbers: {e}") from None
    if x.shape != (D,):
        raise MocapInputError(path, f"the initial pose has {x.size} values, the {model.name} model {D} DOFs")
    if not np.all(np.isfinite(x)):
        raise MocapInputError(path, "the initial pose has non-finite values")
    return np.clip(x, np.asarray(model.lower), np.asarray(model.upper))


def reinit_mean(
    model: body_mod.BodyModel, source_rig: camera.Rig, rig: camera.Rig, fd, masks, last_good
) -> tuple[np.ndarray | None, str | None]:
    """A detection-driven pose and its source: the IK fit of the frame's keypoints (``source_rig``: full-size
    pixels), else ``last_good`` moved over the silhouette centroid (``rig``: the rig of ``masks``), else
    ``last_good`` itself; ``(None, None)`` without any."""
    if fd is not None and fd.keypoints is not None:
        x = keypoint_pose(model, source_rig, fd.keypoints, init=last_good, depth=fd.depth)
        if x is not None:
            return x, "keypoints"
    c = silhouette_centroid(rig, masks)
    if c is not None and last_good is not None:
        return move_root_over(model, last_good, c), "silhouette"
    if last_good is not None:
        return np.asarray(last_good), "last_estimate"
    return None, None
