"""Refinement of the filter's estimate on the frame's 2D detections (``TrackOptions.refine``).

The annealed filter's estimate (the weighted mean of a few hundred particles) resolves the limbs only as finely as
its last layer's diffusion: on synthetic four-camera sequences its wrists were 52–58 mm from the truth where
triangulating the same detections gave about 30 mm. Each frame, the estimate ``x̂`` is therefore moved to the state
that reprojects the detections best near it,

    ``x* = argmin_x Σ_v Σ_j w_vj ρ_vj ‖π_v(f_j(x)) − y_vj‖² + λ Σ_d (u_d − û_d)²``

(:func:`jaxmocap.fit.ik.fit_pose_2d`: Levenberg–Marquardt in the solver's bounded coordinates ``u``; ``π_v`` the
view's projection, ``f_j`` the model's joints (:func:`refine_pairs`: the keypoint cue's joints and the head), ``y_vj``
the detection of joint ``j`` in view ``v`` (processed-image pixels) with ``w_vj = c_vj / σ²`` its confidence over
:data:`jaxmocap.tracking.init.KEYPOINT_SIGMA_PX`² (in processed pixels), 0 below confidence
:data:`REFINE_MIN_CONFIDENCE`; ``λ`` = ``TrackOptions.refine_prior``): a Gauss–Newton solution of the posterior
that takes the filter's estimate as the prior's mean. ``ρ_vj`` makes it robust to wrong detections (a left/right
exchange, a bystander's joint): the fit is run once with ``ρ = 1``, then once more from ``x̂`` with the
Geman–McClure weights ``ρ_vj = 1 / (1 + r_vj² / s²)²`` of its residuals ``r_vj`` (one step of iteratively
reweighted least squares, ``s`` = :data:`REFINE_ROBUST_PX`). The model's limb lengths tie the joints together, so
the refined pose is the body that best explains every view's detections at once, which per-joint triangulation
cannot do.

With depth maps (``TrackOptions.refine_depth`` = ``σ_d``, :func:`jaxmocap.tracking.options.default_refine_depth`)
the fit has a depth term as well, ``+ Σ_v Σ_j ω_vj ρ^z_vj (z_v(f_j(x)) − d_vj)²``
(:func:`jaxmocap.fit.ik.fit_pose_2d` with ``depth``; ``z_v`` a joint's camera depth): ``d_vj`` is read from view
``v``'s map around the estimate's projection of joint ``j`` (:meth:`KeypointRefiner.depth_targets`: the median of
a 5×5 window, plus how far the joint lies behind the surface the map sees), for the joints of ``depth_joints``
(:data:`DEPTH_JOINTS_DEFAULT`: the hips, shoulders and thorax 0.10 m behind the surface, the elbows, wrists, knees
and ankles 0.05 m), ``ω_vj = 1/σ_d²`` and ``ρ^z`` the same Geman–McClure reweighting with scale
:data:`REFINE_ROBUST_DEPTH` (a reading of something in front of the joint, an arm before the chest, is
discounted). A joint that the estimate puts more than :data:`DEPTH_OCCLUDED_M` behind its target is taken as
occluded in that view (a leg behind the other one, the map seeing the nearer leg) and left out of the term there:
read at its pixel, the nearer surface would pull it forward onto the occluder, the two legs swapped in depth. A
stereo pair's detections fix a joint's distance along the rays only through a pixel or two of disparity and the
skeleton's projected size (which a wrongly measured body turns into a wrong distance); the depth maps fix it
directly.

``refine = "estimate"`` writes ``x*`` (outputs, velocity prediction, track-loss reference) and leaves the particles;
``"track"`` also moves every particle by ``x* − x̂`` (kept inside the joint limits), so that the next frame's search
starts around the refined pose. The fit is traced into the filter's step: one program, no dispatch of its own
(about 3 ms a frame for ``full25`` on the 2-core CPU; the depth term about 10 ms more with a stereo pair,
``benchmarks/results/refine_cost.md``). The defaults per input kind:
:func:`jaxmocap.tracking.options.default_refine`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.filters.base import apply_limits
from jaxmocap.fit import ik
from jaxmocap.geometry import camera
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io.keypoints import KEYPOINT_INDEX
from jaxmocap.tracking.init import DEPTH_BEHIND_SURFACE, DEPTH_JOINTS

__all__ = [
    "DEPTH_JOINTS_DEFAULT",
    "DEPTH_OCCLUDED_M",
    "DEPTH_LIMBS",
    "DEPTH_TRUNK",
    "REFINE_MIN_CONFIDENCE",
    "REFINE_ROBUST_DEPTH",
    "REFINE_ROBUST_PX",
    "KeypointRefiner",
    "refine_pairs",
]

#: detections of lower confidence are left out of the refinement (as of the first pose's fit)
REFINE_MIN_CONFIDENCE = 0.1
#: scale ``s`` (full-size pixels) of the refinement's Geman–McClure reweighting
REFINE_ROBUST_PX = 10.0
#: scale ``s_d`` (m) of the same reweighting of the depth term
REFINE_ROBUST_DEPTH = 0.15
#: a joint whose estimate lies more than this (m) behind its depth target (the surface read at its projection, plus
#: its distance behind it) is occluded in that view and left out of the depth term there
#: (:meth:`KeypointRefiner.depth_targets`). On the six synthetic stereo clips of
#: ``benchmarks/results/accuracy_default.md`` (realistic input, 10 seeds), 0.25 against none: 48.1 against
#: 51.8 mm (−3.7 ± 1.1 paired; −4.7 ± 1.5 on the 5 seeds not used to choose it among 0.10, 0.15, 0.25 and 0.40),
#: ankles 69.4 → 60.3 mm, ankle errors over 20 cm on 9.4 → 6.5 % of the frames
DEPTH_OCCLUDED_M = 0.25
#: ``(joint, s)`` of the depth term: the joints whose camera depths are read, each ``s`` (m) behind the surface
#: the depth maps see (the trunk's joints :data:`~jaxmocap.tracking.init.DEPTH_BEHIND_SURFACE`)
DEPTH_TRUNK = tuple((j, DEPTH_BEHIND_SURFACE) for j in DEPTH_JOINTS)
#: the limbs' joints, about a limb's radius behind the surface
DEPTH_LIMBS = tuple(
    (f"{side}_{j}", 0.05) for side in ("left", "right") for j in ("elbow", "wrist", "knee", "ankle")
)
#: the joints of the depth term by default: trunk and limbs (measured in ``benchmarks/results/accuracy_default.md``)
DEPTH_JOINTS_DEFAULT = DEPTH_TRUNK + DEPTH_LIMBS


def refine_pairs(model) -> tuple[tuple[str, int], ...]:
    """``(model joint, index)`` of the detections ``(V, 15, 3)`` (:func:`jaxmocap.io.keypoints.eval_keypoints`)
    the refinement fits: the keypoints cue's joints (:data:`jaxmocap.io.keypoints.KEYPOINT_INDEX`) and the head,
    whose detection is the middle of the ears, the model's head centre."""
    names = model.joint_names
    pairs = [(j, k) for j, k in KEYPOINT_INDEX.items() if j in names]
    if "head" in names:
        pairs.append(("head", EVAL_JOINTS.index("head")))
    return tuple(pairs)


class KeypointRefiner:
    """The refinement of one run: ``model``, the processed rig ``rig``, ``pairs`` ((model joint, keypoint index)
    of the detections ``(V, K, 3)``), ``sigma_px`` (the detections' pixel std in processed pixels), ``prior``
    (``λ``), ``mode`` (``"estimate"`` or ``"track"``)."""

    def __init__(
        self,
        model,
        rig,
        pairs,
        sigma_px: float,
        prior: float,
        mode: str,
        robust_px: float | None = None,
        depth_sigma: float | None = None,
        depth_joints=None,
    ):
        if mode not in ("estimate", "track"):
            raise ValueError(f"unknown refinement {mode!r}; choose estimate or track")
        if not pairs:
            raise ValueError("the refinement needs detections of the model's joints")
        if not (np.isfinite(prior) and prior > 0):
            raise ValueError(f"refine_prior must be a positive number, got {prior}")
        self.model, self.rig, self.mode = model, rig, mode
        self.jidx = np.asarray([model.joint_names.index(j) for j, _ in pairs])
        self.kidx = np.asarray([k for _, k in pairs])
        self.sigma_px, self.prior = float(sigma_px), float(prior)
        self.robust_px = None if robust_px is None else float(robust_px)
        self.depth_sigma = None if depth_sigma is None else float(depth_sigma)
        depth_joints = DEPTH_JOINTS_DEFAULT if depth_joints is None else depth_joints
        depth_joints = [(j, s) for j, s in depth_joints if j in model.joint_names]
        self.depth_idx = np.asarray([model.joint_names.index(j) for j, _ in depth_joints], np.int64)
        self.depth_behind = np.asarray([s for _, s in depth_joints], np.float32)

    def targets(self, keypoints2d: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
        """``(V, K, 3)`` detections → ``uv (V, J, 2)`` pixels and weights ``w (V, J)`` in the model's joint order
        (0 for joints without a detection)."""
        V, J = keypoints2d.shape[0], len(self.model.joint_names)
        det = keypoints2d[:, self.kidx]
        c = det[..., 2]
        c = jnp.where(c > REFINE_MIN_CONFIDENCE, c, 0.0) / (self.sigma_px * self.sigma_px)
        uv = jnp.zeros((V, J, 2), keypoints2d.dtype).at[:, self.jidx].set(det[..., :2])
        w = jnp.zeros((V, J), keypoints2d.dtype).at[:, self.jidx].set(c)
        return uv, w

    def depth_targets(self, est: jnp.ndarray, depth: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
        """Camera depths of the joints of ``depth_joints`` read from the depth maps ``(V, H, W)`` (m, 0 = none) at
        the estimate ``est``'s projections: ``d_vj = s_j + median`` of the valid readings in the 5×5 pixels around
        joint ``j``'s projection in view ``v`` (the joint lies ``s_j`` behind the surface the map sees), with weight
        ``1/σ_d²``; 0 for the other joints, outside the image, where nothing was read and where the estimate's
        camera depth ``z_vj`` exceeds ``d_vj`` by more than :data:`DEPTH_OCCLUDED_M` (occluded). ``(V, J)`` each."""
        V, H, W = depth.shape
        X = ik.model_joints(self.model, est)[self.depth_idx]
        px, zc = camera.project_with_depth(self.rig, X)  # (V, n, 2), (V, n)
        off = jnp.arange(-2, 3)
        col = jnp.round(px[..., 0])[..., None, None] + off[None, :]  # (V, n, 1, 5)
        row = jnp.round(px[..., 1])[..., None, None] + off[:, None]  # (V, n, 5, 1)
        inside = (col >= 0) & (col < W) & (row >= 0) & (row < H)
        c = jnp.clip(col, 0, W - 1).astype(jnp.int32)
        r = jnp.clip(row, 0, H - 1).astype(jnp.int32)
        v = jnp.arange(V)[:, None, None, None]
        read = depth.astype(est.dtype)[v, r, c]  # (V, n, 5, 5)
        read = jnp.where(inside & (read > 0), read, jnp.nan).reshape(*read.shape[:2], -1)
        d = jnp.nanmedian(read, axis=-1) + jnp.asarray(self.depth_behind, est.dtype)  # (V, n)
        # a joint the estimate puts well behind the surface its pixel sees is taken as occluded (a leg behind the
        # other, seen along the rays) and left out, instead of pulled onto the occluder
        ok = jnp.isfinite(d) & (zc > 0) & (zc - d <= DEPTH_OCCLUDED_M)
        J = len(self.model.joint_names)
        z = jnp.zeros((V, J), est.dtype).at[:, self.depth_idx].set(jnp.where(ok, d, 0.0))
        wz = (
            jnp.zeros((V, J), est.dtype)
            .at[:, self.depth_idx]
            .set(jnp.where(ok, 1.0 / self.depth_sigma**2, 0.0))
        )
        return z, wz

    def fit(self, est, uv, w, measured=None) -> jnp.ndarray:
        """The fit from the estimate ``est`` (with the depth targets ``measured = (z, wz)`` when given)."""
        z, wz = (None, None) if measured is None else measured
        return ik.fit_pose_2d(
            self.model, self.rig, uv, w, est, prior_weight=self.prior, depth=z, depth_weights=wz
        )

    def __call__(self, state, info, obs):
        """The filter's ``(State, Info)`` after a frame → the same with the estimate refined on the frame's
        :class:`~jaxmocap.features.observation.Observation` ``obs`` (its ``keypoints2d (V, K, 3)``, and its
        ``depth`` maps when the refinement reads depth and the observation has them) and, ``"track"``, the
        particles moved with it. Traceable."""
        uv, w = self.targets(obs.keypoints2d)
        depth = obs.depth if (self.depth_sigma is not None and obs.has("depth")) else None
        est = info.estimate
        measured = None if depth is None else self.depth_targets(est, depth)
        if self.robust_px is None:
            refined = self.fit(est, uv, w, measured)
        else:
            # one reweighting (IRLS) of Geman–McClure with scale s, w ← w / (1 + r²/s²)², fitted again from x̂
            # (the depth term's weights likewise with scale s_d): two passes of one loop, so that the fit is
            # compiled once
            def gm(r2, i):
                return jnp.where(i == 0, 1.0, 1.0 / (1.0 + r2) ** 2)

            def one_pass(i, refined):
                X = ik.model_joints(self.model, refined)
                px, zc = camera.project_with_depth(self.rig, X)
                r = px - uv
                rho = gm(jnp.sum(r * r, axis=-1) / (self.robust_px * self.robust_px), i)
                reweighted = None
                if measured is not None:
                    z, wz = measured
                    reweighted = (z, wz * gm(((zc - z) / REFINE_ROBUST_DEPTH) ** 2, i))
                return self.fit(est, uv, w * rho, reweighted).astype(est.dtype)

            refined = jax.lax.fori_loop(0, 2, one_pass, est)
        # a frame without usable detections (or a failed fit) keeps the filter's own estimate
        ok = (jnp.sum(w > 0) >= 4) & jnp.all(jnp.isfinite(refined))
        refined = jnp.where(ok, refined, est).astype(est.dtype)
        info = info._replace(estimate=refined)
        if self.mode == "track":
            moved = state.particles + (refined - est)[None, :]
            moved = apply_limits(moved, self.model.lower, self.model.upper)
            state = state._replace(particles=moved.astype(state.particles.dtype), estimate=refined)
        else:
            state = state._replace(estimate=refined)
        return state, info
