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

``refine = "estimate"`` writes ``x*`` (outputs, velocity prediction, track-loss reference) and leaves the particles;
``"track"`` also moves every particle by ``x* − x̂`` (kept inside the joint limits), so that the next frame's search
starts around the refined pose. The fit is traced into the filter's step: one program, no dispatch of its own
(about 3 ms a frame for ``full25`` on the 2-core CPU). The defaults per input kind:
:func:`jaxmocap.tracking.options.default_refine`.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxmocap.filters.base import apply_limits
from jaxmocap.fit import ik
from jaxmocap.geometry import camera
from jaxmocap.geometry.body import EVAL_JOINTS
from jaxmocap.io.keypoints import KEYPOINT_INDEX

__all__ = ["REFINE_MIN_CONFIDENCE", "REFINE_ROBUST_PX", "KeypointRefiner", "refine_pairs"]

#: detections of lower confidence are left out of the refinement (as of the first pose's fit)
REFINE_MIN_CONFIDENCE = 0.1
#: scale ``s`` (full-size pixels) of the refinement's Geman–McClure reweighting
REFINE_ROBUST_PX = 10.0


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
        self, model, rig, pairs, sigma_px: float, prior: float, mode: str, robust_px: float | None = None
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

    def __call__(self, state, info, keypoints2d: jnp.ndarray):
        """The filter's ``(State, Info)`` after a frame → the same with the estimate refined (and, ``"track"``,
        the particles moved with it). Traceable."""
        uv, w = self.targets(keypoints2d)
        est = info.estimate
        refined = ik.fit_pose_2d(self.model, self.rig, uv, w, est, prior_weight=self.prior)
        if self.robust_px is not None:
            # one reweighting (IRLS) of Geman–McClure with scale s, w ← w / (1 + r²/s²)², fitted again from x̂
            r = camera.project(self.rig, ik.model_joints(self.model, refined)) - uv
            r2 = jnp.sum(r * r, axis=-1) / (self.robust_px * self.robust_px)
            w = w / (1.0 + r2) ** 2
            refined = ik.fit_pose_2d(self.model, self.rig, uv, w, est, prior_weight=self.prior)
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
