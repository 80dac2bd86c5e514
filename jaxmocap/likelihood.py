"""Composition of cues into a Gibbs-form log-likelihood with per-layer (feature-based annealing) schedules.

``log p_l(z | x) = −Σ_c λ_c(l) k_c Σ_v w_v E_c,v(x, z)``

with ``E_c,v`` the cue energies of :mod:`jaxmocap.cues` (scalar cues have no view sum), ``k_c`` the cue weight,
``w_v`` per-view weights and ``λ_c(l)`` the schedule of annealing layer ``l`` — López Méndez's feature-based
annealing (eq. 5.2): each layer may weigh the cues differently. The annealing exponent β is applied by the filter
(``p^β``); the schedule supplies the per-layer, per-cue part.

Everything is per particle and pure; :meth:`Likelihood.batch` vmaps over particles. A :class:`Likelihood` is a pytree
(model, rig and flesh points are leaves: gradients reach body dimensions and cameras), and its configuration is
static.

Example::

    lik = Likelihood.create(model, rig, [Cue("foreground"), Cue("edges", 2.0)], num_layers=3)
    ll = jax.jit(lik.batch)(particles, observation, 0)   # (N,)
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap import body, camera, cues, flesh
from jaxmocap.observation import Observation

#: Li & Kulić's base A of ``w = A^(−d)`` (eq. 4): weight ``k`` on a [0, 1] energy is ``λ = k ln A``.
LI_KULIC_BASE = 100.0


@dataclasses.dataclass(frozen=True)
class Cue:
    """One term of the likelihood: cue ``name`` (a key of :data:`jaxmocap.cues.CUES`), weight ``k_c`` and static
    parameters (a tuple of ``(key, value)`` pairs or a dict, kept hashable)."""

    name: str
    weight: float = 1.0
    params: tuple = ()

    def __post_init__(self):
        if self.name not in cues.CUES:
            raise ValueError(f"unknown cue {self.name!r}; choose from {sorted(cues.CUES)}")
        if isinstance(self.params, dict):
            object.__setattr__(self, "params", tuple(sorted(self.params.items())))

    @property
    def param_dict(self) -> dict:
        return dict(self.params)


@dataclasses.dataclass(frozen=True)
class Likelihood:
    """A composed likelihood (see the module docstring). Build it with :meth:`create`.

    Leaves: ``model``, ``rig``, ``surface`` (flesh points), ``view_weights (V,)``, ``schedule (L, C)``.
    Static: ``cues`` (tuple of :class:`Cue`), ``contour_points`` (per silhouette line).
    """

    model: body.BodyModel
    rig: camera.Rig
    surface: flesh.FleshPoints
    view_weights: jnp.ndarray
    schedule: jnp.ndarray
    cues: tuple = dataclasses.field(metadata=dict(static=True), default=())
    contour_points: int = dataclasses.field(metadata=dict(static=True), default=8)

    @staticmethod
    def create(
        model: body.BodyModel,
        rig: camera.Rig,
        cue_list: Sequence[Cue],
        *,
        num_layers: int = 1,
        schedule: str | np.ndarray = "apf",
        surface_points: int = 600,
        contour_points: int = 8,
        view_weights: Sequence[float] | None = None,
    ) -> Likelihood:
        """Build a likelihood.

        Args:
          model, rig: body model and calibrated cameras.
          cue_list: the cues and their weights.
          num_layers: annealing layers the schedule covers (a layer index beyond it uses the last row).
          schedule: a preset name of :func:`schedule_preset` or an explicit ``(L, C)`` array of λ.
          surface_points: total flesh samples, spread over segments in proportion to area (Li & Kulić: 15–75 per
            cone).
          contour_points: samples on each silhouette line of each cone (and on the head's outline).
          view_weights: ``w_v`` (default all 1).
        """
        cue_list = tuple(cue_list)
        if not cue_list:
            raise ValueError("a likelihood needs at least one cue")
        lam = (
            schedule_preset(schedule, [c.name for c in cue_list], num_layers)
            if isinstance(schedule, str)
            else np.asarray(schedule, dtype=np.float32)
        )
        if lam.shape != (num_layers, len(cue_list)):
            raise ValueError(
                f"schedule must have shape (num_layers, num_cues) = {(num_layers, len(cue_list))}"
            )
        V = rig.num_views
        w = np.ones(V, np.float32) if view_weights is None else np.asarray(view_weights, np.float32)
        if w.shape != (V,):
            raise ValueError(f"view_weights needs one weight per view ({V})")
        dtype = model.offset.dtype
        return Likelihood(
            model=model,
            rig=rig.to_jax(dtype),
            surface=flesh.surface_points(model, flesh.surface_layout(model, total=surface_points)),
            view_weights=jnp.asarray(w, dtype),
            schedule=jnp.asarray(lam, dtype),
            cues=cue_list,
            contour_points=contour_points,
        )

    # -----------------------------------------------------------------------------------------------------------

    def _needs(self) -> frozenset:
        out: set = set()
        for c in self.cues:
            out |= cues.CUES[c.name][2]
        return frozenset(out)

    def check_observation(self, obs: Observation) -> None:
        """Raise a clear error if the observation lacks a field a cue needs, or disagrees with the rig."""
        for c in self.cues:
            for field in cues.REQUIRES[c.name]:
                if not obs.has(field):
                    raise ValueError(f"cue {c.name!r} needs observation field {field!r}, which is empty")
        if obs.num_views != self.rig.num_views:
            raise ValueError(f"observation has {obs.num_views} views, the calibration {self.rig.num_views}")

    def geometry(self, x: jnp.ndarray) -> cues.Geometry:
        """Projected geometry of one particle ``x (D,)`` — only the parts the cues need."""
        needs = self._needs()
        R, t = body.segment_poses(self.model, x)
        g = {}
        if needs & {"joints", "joints_uv"}:
            J = body.joint_positions(self.model, x)
            g["joints"] = J
            if "joints_uv" in needs:
                g["joints_uv"] = camera.project(self.rig, J)
        if "surface" in needs:
            X, N = self.surface.world(R, t)
            uv, z = camera.project_with_depth(self.rig, X)
            C = camera.camera_centres(self.rig)  # (V, 3)
            facing = jnp.sum(N[None] * (C[:, None, :] - X[None]), axis=-1) > 0
            g.update(surface=X, surface_uv=uv, surface_depth=z, surface_facing=facing & (z > 0))
        if "contour" in needs or "primitives" in needs:
            prims = flesh.world_primitives(self.model, R, t)
            g["primitives"] = prims
        if "contour" in needs:
            k = self.contour_points
            C = camera.camera_centres(self.rig)
            pts = []
            if prims.num_cones:
                pc = jax.vmap(
                    lambda c: flesh.cone_contours(prims.cone_a, prims.cone_b, prims.r_a, prims.r_b, c, k)
                )(C)
                pts.append(pc.reshape(C.shape[0], -1, 3))
            if prims.num_ellipsoids:
                pe = jax.vmap(lambda c: flesh.ellipsoid_contours(prims.ell_centre, prims.ell_axes, c, 2 * k))(
                    C
                )
                pts.append(pe.reshape(C.shape[0], -1, 3))
            Q = jnp.concatenate(pts, axis=1)  # (V, Q, 3): each view's own contour points
            g["contour_uv"] = _project_own_view(self.rig, Q)
        return cues.Geometry(**g)

    def energies(self, x: jnp.ndarray, obs: Observation) -> jnp.ndarray:
        """``(C,)`` view-weighted cue energies ``k_c Σ_v w_v E_c,v`` of one particle (before the schedule)."""
        g = self.geometry(x)
        out = []
        for c in self.cues:
            fn, per_view, _ = cues.CUES[c.name]
            ctx = cues.CueContext(self.model.joint_names, c.param_dict, self.rig)
            e = fn(g, obs, ctx)
            if per_view:
                e = jnp.sum(self.view_weights * e)
            out.append(c.weight * e)
        return jnp.stack(out)

    def log_likelihood(self, x: jnp.ndarray, obs: Observation, layer=0) -> jnp.ndarray:
        """Scalar ``log p_l(z | x)`` of one particle at annealing layer ``layer``: an int (traced or static) or the
        :class:`jaxmocap.filters.base.Layer` the annealed filters pass (its ``index`` is used)."""
        layer = getattr(layer, "index", layer)
        lam = self.schedule[jnp.clip(layer, 0, self.schedule.shape[0] - 1)]
        return -jnp.sum(lam * self.energies(x, obs))

    def batch(self, X: jnp.ndarray, obs: Observation, layer=0) -> jnp.ndarray:
        """``(N,)`` log-likelihoods of particles ``X (N, D)``; non-finite values become −inf."""
        ll = jax.vmap(lambda x: self.log_likelihood(x, obs, layer))(X)
        return jnp.where(jnp.isfinite(ll), ll, -jnp.inf)


jax.tree_util.register_dataclass(
    Likelihood,
    data_fields=["model", "rig", "surface", "view_weights", "schedule"],
    meta_fields=["cues", "contour_points"],
)


def _project_own_view(rig: camera.Rig, Q: jnp.ndarray) -> jnp.ndarray:
    """Project ``Q (V, M, 3)`` — view ``v``'s points through camera ``v`` only — to ``(V, M, 2)``."""
    uv = camera.project(rig, Q)  # (V_points, V_cams, M, 2)
    return jnp.moveaxis(jnp.diagonal(uv, axis1=0, axis2=1), -1, 0)


# ---------------------------------------------------------------------------------------------------------------
# Schedules (feature-based annealing)

#: cues that describe the silhouette coarsely and are smooth over large pose changes (used in early layers)
COARSE_CUES = frozenset({"foreground", "silhouette_divergence", "depth", "blobs3d", "keypoints", "ground"})
#: cues that localise precisely but have narrow basins (weighted up in later layers)
FINE_CUES = frozenset({"edges", "edge_distance", "edge_fraction"})


def schedule_preset(name: str, cue_names: Sequence[str], num_layers: int) -> np.ndarray:
    """λ_c(l) tables, ``(L, C)``, for the annealing variants compared in López Méndez ch. 6–7.

    * ``apf`` — every cue with λ = 1 in every layer (the standard APF: the layers differ only by β).
    * ``m-apf`` — the same cue weights; the filter varies the survival-rate target per layer (see
      :mod:`jaxmocap.filters.apf`); listed so every variant has a schedule.
    * ``fbapf`` — feature-based annealing: coarse cues (silhouette, depth, detections) at full weight from the first
      layer; fine cues (edges) enter linearly, ``λ = l / (L − 1)``, reaching 1 in the last layer.
    * ``fbapf2`` — coarse cues fade out as the fine cues fade in (``1 − l/(L−1)`` vs ``l/(L−1)``), never below 0.25.
    * ``fbapf3`` — two stages: coarse cues only in the first half of the layers, all cues in the second half.
    * ``li-kulic`` — λ = ln 100 for every cue (their ``w = A^(−d)``, A = 100).

    Priors (``interpenetration``) keep λ = 1 in every variant. These tables are this project's reading of the
    thesis' schedules (eq. 6.5–6.7): coarse-to-fine cue weighting across layers.
    """
    L, C = num_layers, len(cue_names)
    ramp = np.linspace(0.0, 1.0, L) if L > 1 else np.ones(1)
    lam = np.ones((L, C), np.float64)
    for c, n in enumerate(cue_names):
        fine = n in FINE_CUES
        coarse = n in COARSE_CUES
        if name in ("apf", "m-apf"):
            continue
        if name == "li-kulic":
            lam[:, c] = math.log(LI_KULIC_BASE)
        elif name == "fbapf":
            if fine:
                lam[:, c] = ramp
        elif name == "fbapf2":
            if fine:
                lam[:, c] = ramp
            elif coarse:
                lam[:, c] = np.maximum(1.0 - ramp, 0.25)
        elif name == "fbapf3":
            if fine:
                lam[:, c] = (np.arange(L) >= L // 2).astype(float) if L > 1 else 1.0
        else:
            raise ValueError(
                f"unknown schedule {name!r}; choose apf, m-apf, fbapf, fbapf2, fbapf3 or li-kulic"
            )
    return lam.astype(np.float32)
