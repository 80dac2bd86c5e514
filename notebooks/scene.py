"""A small synthetic scene shared by the notebooks: a ``full25`` subject rendered by :mod:`jaxmocap.geometry.render` from its
own body model into two views, with the maps the image cues read (blurred silhouette, edges, their distance
transform) and the projected evaluation joints as 2D keypoints.

Environment: ``JAXMOCAP_NB_SMALL=1`` shrinks the notebooks' problem sizes (what the test suite uses);
``JAXMOCAP_NB_OUT`` is the folder the figures go to (default: ``<temp dir>/jaxmocap-notebooks``).
"""

from __future__ import annotations

import os
import pathlib
import tempfile
from typing import NamedTuple

import cv2
import jax.numpy as jnp
import numpy as np

from jaxmocap.features.observation import Observation, make_observation
from jaxmocap.geometry import body, camera, render
from jaxmocap.synth.stage import look_at

SMALL = os.environ.get("JAXMOCAP_NB_SMALL", "0") not in ("", "0")
SIZE = (96, 72) if SMALL else (160, 120)
#: (keypoint name, index) pairs of the keypoints cue: the evaluation joints in order.
PAIRS = tuple((n, i) for i, n in enumerate(body.EVAL_JOINTS))
#: The two joint angles the notebooks sweep (IROS 2007 Fig. 1 / thesis Fig. 4.3 sweep an arm's angles).
SWEEP = ("left_shoulder_rx", "left_elbow")


def output_dir(name: str) -> pathlib.Path:
    """``$JAXMOCAP_NB_OUT/name`` (default under the temporary directory), created."""
    root = os.environ.get("JAXMOCAP_NB_OUT") or os.path.join(tempfile.gettempdir(), "jaxmocap-notebooks")
    out = pathlib.Path(root) / name
    out.mkdir(parents=True, exist_ok=True)
    return out


def rig(size=SIZE) -> camera.Rig:
    """Two cameras 3.2 m away, in front of and beside the subject, at 1.3 m height (focal 0.8 · width)."""
    W, H = size
    Rs, ts = zip(
        *[look_at(np.asarray(c), [0.0, 0.0, 1.0]) for c in ([3.2, 0.4, 1.3], [0.5, 3.2, 1.3])], strict=True
    )
    K = np.array([[0.8 * W, 0.0, (W - 1) / 2], [0.0, 0.8 * W, (H - 1) / 2], [0.0, 0.0, 1.0]])
    return camera.from_opencv(
        np.stack([K, K]), np.zeros((2, 5)), np.stack(Rs), np.stack(ts), image_size=[size] * 2
    )


def pose(model: body.BodyModel, t: float = 0.0) -> jnp.ndarray:
    """A pose with the left arm raised and bent; ``t`` (frames) swings the arm and turns the body slowly."""
    x = model.rest_pose
    for name, v in (
        ("left_shoulder_rx", 0.8 + 0.12 * t),
        ("left_elbow", 0.9 - 0.08 * t),
        ("right_shoulder_ry", -0.4),
        ("root_rz", 0.3 + 0.03 * t),
        ("right_knee", 0.3),
    ):
        x = x.at[model.dof_index(name)].set(v)
    return x


class Frame(NamedTuple):
    observation: Observation
    state: np.ndarray  # (D,) the true pose
    mask: np.ndarray  # (V, H, W) bool


def render_frame(model: body.BodyModel, r: camera.Rig, x) -> Frame:
    """Render ``model`` at ``x`` in every view of ``r`` and build the observation (foreground, edges, edge
    distance transform, keypoints of the projected evaluation joints)."""
    prims = render.primitives_from_model(model, jnp.asarray(x))
    fgs, edges, dts, masks = [], [], [], []
    for v in range(r.num_views):
        depth = np.asarray(
            render.render_view(r.K[v], r.dist[v], r.R[v], r.t[v], r.image_size[v], prims).depth
        )
        mask = (depth > 0).astype(np.uint8)
        e = cv2.Canny(mask * 255, 50, 150)
        masks.append(mask > 0)
        fgs.append(cv2.GaussianBlur(mask.astype(np.float32), (5, 5), 1.0))
        edges.append((e > 0).astype(np.float32))
        dts.append(cv2.distanceTransform((e == 0).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE))
    J = np.asarray(body.joint_positions(model, jnp.asarray(x)))
    idx = [model.joint_names.index(n) for n in body.EVAL_JOINTS]
    uv = np.asarray(camera.project(r, J[idx]))
    kp = np.concatenate([uv, np.ones(uv.shape[:2] + (1,))], -1)
    obs = make_observation(r, foreground=fgs, edges=edges, edge_dt=dts, keypoints2d=kp)
    return Frame(obs, np.asarray(x), np.stack(masks))
