"""Composition of cues into a Gibbs-form log-likelihood with per-layer, per-view schedules.

``log p_l(z | x) = −Σ_c Σ_v λ_c,v(l) k_c w_v E_c,v(x, z)``

with ``E_c,v`` the cue energies of :mod:`jaxmocap.likelihood.cues` (view-free cues have one term), ``k_c`` the cue weight,
``w_v`` per-view weights and ``λ_c,v(l)`` the schedule of annealing layer ``l`` — López Méndez's feature-based
annealing (eq. 5.2): each layer may weigh the cues differently, and here each view as well (e.g. a view whose
segmentation is unreliable enters late). The annealing exponent β is applied by the filter (``p^β``); the schedule
supplies the per-layer, per-cue, per-view part. Cues that need no image (3D blobs, ground, priors) compose the same
way.

Evaluation (:meth:`Likelihood.batch`, what the filters call):

1. ``prepare``: what depends on the observation only (masked depth, packed colours, foreground samples), once;
2. geometry per particle (:meth:`Likelihood.geometry`): FK, flesh points (run by run of points on one segment,
   straight into camera coordinates), projection, facing test, one shared nearest-pixel index per sample set and
   the visible index through which one gather reads a colour and whether the sample is seen, computed once for all
   cues of the table;
3. the λ table: particles are processed in chunks of at most ``chunk_size`` (``lax.map`` over ``n = ⌈N / chunk_size⌉``
   vmapped chunks of ``⌈N / n⌉``, the last padded with copies of the first particle), so that the
   ``(chunk, V, P)`` intermediates stay in cache — on CPU this is 2–3× faster than one vmap over all particles —
   and each particle's ``−Σ_c Σ_v λ_c,v k_c w_v E_c,v`` is one sum over its ``(C, V)`` table;
4. a cue registered as ``separate`` (:class:`jaxmocap.likelihood.cues.CueSpec`: the silhouette ``coverage``) is
   then subtracted as a term of its own, ``(λ_c k_c) · Σ_v w_v E_c,v``, its energy evaluated over all particles in
   one vmap from the geometry it needs alone (its λ is the same in every view). The value is the same sum; this
   order of float operations is the one the tracker's results were computed with, and tracks depend on it bit for
   bit: inside the table the coverage energies compile together with the other cues' geometry (a few float32 ulps
   apart in about half the entries), and the table's one sum rounds differently from the table followed by the
   term; either sends the particles on another trajectory (the demo's overall error: 111.6 mm instead of 118.2).

A :class:`Likelihood` is a pytree (model, rig, flesh points, weights, schedule and reference data are leaves:
gradients reach body dimensions and cameras), and its configuration is static.

Example::

    lik = Likelihood.create(model, rig, [Cue("foreground"), Cue("edges", 2.0)], num_layers=3, schedule="fbapf")
    ll = jax.jit(lik.batch)(particles, observation, 0)   # (N,)
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.features.observation import Observation
from jaxmocap.geometry import body, camera, flesh, kinematics
from jaxmocap.likelihood import cues, maps
from jaxmocap.likelihood import partition as part_mod
from jaxmocap.transfer import to_device

#: Li & Kulić's base A of ``w = A^(−d)`` (eq. 4): weight ``k`` on a [0, 1] energy is ``λ = k ln A``.
LI_KULIC_BASE = 100.0


@dataclasses.dataclass(frozen=True)
class Cue:
    """One term of the likelihood: cue ``name`` (a key of :data:`jaxmocap.likelihood.cues.CUES`), weight ``k_c`` and static
    parameters (a tuple of ``(key, value)`` pairs or a dict, kept hashable). The weight is data: it is left out of
    the comparison and the hash (cues that differ only in weight are equal), and :meth:`Likelihood.create` copies it
    into the likelihood's ``cue_weights`` leaf, so that a new weight reuses the compiled likelihood."""

    name: str
    weight: float = dataclasses.field(default=1.0, compare=False)
    params: tuple = ()

    def __post_init__(self):
        if self.name not in cues.CUES:
            raise ValueError(f"unknown cue {self.name!r}; choose from {sorted(cues.CUES)}")
        if isinstance(self.params, dict):
            object.__setattr__(self, "params", tuple(sorted(self.params.items())))

    @property
    def param_dict(self) -> dict:
        return dict(self.params)

    @property
    def spec(self) -> cues.CueSpec:
        return cues.CUES[self.name]


def finite_value_and_grad(value: jnp.ndarray, grad):
    """``(value, grad)`` with ``value → −inf`` and ``grad → 0`` wherever the value or the gradient is not finite
    (``grad`` a pytree whose leaves have ``value``'s shape as their leading shape)."""
    ok = jnp.isfinite(value)
    mask = lambda g: jnp.where(
        jnp.reshape(ok, ok.shape + (1,) * (g.ndim - ok.ndim)) & jnp.isfinite(g), g, 0.0
    ).astype(g.dtype)
    return jnp.where(ok, value, -jnp.inf), jax.tree_util.tree_map(mask, grad)


@dataclasses.dataclass(frozen=True)
class Likelihood:
    """A composed likelihood (see the module docstring). Build it with :meth:`create`.

    Leaves: ``model``, ``rig``, ``surface`` (flesh points), ``view_weights (V,)``, ``schedule (L, C, V)``,
    ``cue_weights (C,)`` (``k_c``; :meth:`create` copies the weights of ``cues``), ``references`` (per cue: None or the reference
    arrays of :meth:`with_references`), ``partition_weights`` (None, or the per-sample tables of
    :meth:`with_partitions`: at partition ``k`` the cues that honour them weigh only its body parts).
    Static: ``cues`` (tuple of :class:`Cue`: names and parameters), ``contour_points`` (per silhouette line),
    ``chunk_size``. A likelihood that differs from another only in its leaves (weights, λ, references) is the same
    program under ``jit``: ``dataclasses.replace(lik, cue_weights=..., schedule=...)`` does not recompile.
    """

    model: body.BodyModel
    rig: camera.Rig
    surface: flesh.FleshPoints
    view_weights: jnp.ndarray
    schedule: jnp.ndarray
    references: tuple = ()
    cue_weights: jnp.ndarray | None = None
    partition_weights: part_mod.PartWeights | None = None
    cues: tuple = dataclasses.field(metadata=dict(static=True), default=())
    contour_points: int = dataclasses.field(metadata=dict(static=True), default=8)
    chunk_size: int = dataclasses.field(metadata=dict(static=True), default=128)

    @staticmethod
    def create(
        model: body.BodyModel,
        rig: camera.Rig,
        cue_list: Sequence[Cue],
        *,
        num_layers: int = 1,
        schedule: str | np.ndarray = "apf",
        surface_points: int | flesh.SurfaceLayout = 600,
        contour_points: int = 8,
        view_weights: Sequence[float] | None = None,
        chunk_size: int = 128,
    ) -> Likelihood:
        """Build a likelihood.

        Args:
          model, rig: body model and calibrated cameras (the rig of the observation's maps).
          cue_list: the cues and their weights.
          num_layers: annealing layers the schedule covers (a layer index beyond it uses the last row).
          schedule: a preset name of :func:`schedule_preset`, or an explicit array of λ: ``(L, C)`` (the same for
            every view) or ``(L, C, V)`` (per view; a view-free cue uses its view-0 entry, and its entries must
            agree across views).
          surface_points: total flesh samples, spread over segments in proportion to area (Li & Kulić: 15–75 per
            cone), or a :class:`jaxmocap.geometry.flesh.SurfaceLayout`.
          contour_points: samples on each silhouette line of each cone (and ``2×`` on the head's outline).
          view_weights: ``w_v`` (default all 1).
          chunk_size: particles per chunk in :meth:`batch` (0: one vmap over all particles).
        """
        cue_list = tuple(cue_list)
        if not cue_list:
            raise ValueError("a likelihood needs at least one cue")
        V, C = rig.num_views, len(cue_list)
        lam = (
            schedule_preset(schedule, [c.name for c in cue_list], num_layers)
            if isinstance(schedule, str)
            else np.asarray(schedule, dtype=np.float32)
        )
        if lam.shape == (num_layers, C):
            lam = np.repeat(lam[:, :, None], V, axis=2)
        if lam.shape != (num_layers, C, V):
            raise ValueError(
                f"schedule must have shape (num_layers, num_cues) = {(num_layers, C)} "
                f"or (num_layers, num_cues, num_views) = {(num_layers, C, V)}, got {lam.shape}"
            )
        for c, cue in enumerate(cue_list):
            if (not cue.spec.per_view or cue.spec.separate) and not np.all(lam[:, c, :] == lam[:, c, :1]):
                why = "is composed as a term of its own" if cue.spec.per_view else "has no views"
                raise ValueError(f"cue {cue.name!r} {why}: its schedule must be the same for every view")
        w = np.ones(V, np.float32) if view_weights is None else np.asarray(view_weights, np.float32)
        if w.shape != (V,):
            raise ValueError(f"view_weights needs one weight per view ({V})")
        dtype = model.offset.dtype
        layout = (
            surface_points
            if isinstance(surface_points, flesh.SurfaceLayout)
            else flesh.surface_layout(model, total=int(surface_points))
        )
        return Likelihood(
            model=model,
            rig=rig.to_jax(dtype),
            surface=flesh.surface_points_compiled(model, layout),
            view_weights=to_device(w, dtype),
            schedule=to_device(lam, dtype),
            references=(None,) * C,
            cue_weights=to_device([c.weight for c in cue_list], dtype),
            cues=cue_list,
            contour_points=contour_points,
            chunk_size=int(chunk_size),
        )

    # -----------------------------------------------------------------------------------------------------------
    # Configuration helpers

    def _needs(self, which: Sequence[int] | None = None) -> frozenset:
        """The geometry the cues ``which`` (indices; default all) read."""
        out: set = set()
        for c in range(len(self.cues)) if which is None else which:
            out |= self.cues[c].spec.needs(self.cues[c].param_dict)
        return frozenset(out)

    def _table_cues(self) -> tuple[int, ...]:
        """Indices of the cues composed in the λ table (every cue not registered as ``separate``)."""
        return tuple(c for c, cue in enumerate(self.cues) if not cue.spec.separate)

    def _separate_cues(self) -> tuple[int, ...]:
        """Indices of the cues composed as terms of their own after the table (module docstring, step 4)."""
        return tuple(c for c, cue in enumerate(self.cues) if cue.spec.separate)

    def _context(self, c: int, aux=None, part=None) -> cues.CueContext:
        cue = self.cues[c]
        ref = self.references[c] if self.references else None
        part = part if cue.spec.partial else None
        return cues.CueContext(
            self.model.joint_names, cue.param_dict, self.rig, self.model, self.surface.segment, aux, ref, part
        )

    def with_partitions(self, parts) -> Likelihood:
        """The same likelihood weighing, at partition ``k`` (``batch(..., partition=k)``, or the ``partition`` of
        the filter's :class:`~jaxmocap.filters.base.Layer`), only the body parts ``parts[k]`` (segment names or
        indices) in the cues that honour it (:mod:`jaxmocap.likelihood.partition`); ``parts=None`` removes it.
        The table is data: a likelihood of other partitions is the same compiled program."""
        if parts is None:
            return dataclasses.replace(self, partition_weights=None)
        table = part_mod.segment_table(self.model, parts)
        tables = part_mod.sample_tables(self.model, table, self.surface.segment, self.contour_points)
        dt = self.model.offset.dtype
        return dataclasses.replace(
            self, partition_weights=part_mod.PartWeights(*(jnp.asarray(t, dt) for t in tables))
        )

    def _part(self, partition):
        """The :class:`~jaxmocap.likelihood.cue_context.PartWeights` of ``partition`` (default 0), or None
        without a partition table."""
        if self.partition_weights is None:
            return None
        return part_mod.part_weights(self.partition_weights, 0 if partition is None else partition)

    @property
    def needs_references(self) -> bool:
        """Whether a cue reads first-frame reference data (set by :meth:`with_references`)."""
        return any(c.spec.reference for c in self.cues)

    def check_observation(self, obs: Observation) -> None:
        """Raise a clear error if the observation lacks a field a cue needs, disagrees with the rig, or a cue
        needs reference data that :meth:`with_references` has not set."""
        for c, cue in enumerate(self.cues):
            for field in cue.spec.requires:
                if not obs.has(field):
                    raise ValueError(f"cue {cue.name!r} needs observation field {field!r}, which is empty")
            if cue.spec.reference and (not self.references or self.references[c] is None):
                raise ValueError(
                    f"cue {cue.name!r} needs reference data: call with_references(x0, obs0) first"
                )
        if obs.num_views != self.rig.num_views:
            raise ValueError(f"observation has {obs.num_views} views, the calibration {self.rig.num_views}")

    # -----------------------------------------------------------------------------------------------------------
    # Geometry

    def pose_stage(self, x: jnp.ndarray, needs: frozenset | None = None) -> dict:
        """The small per-particle part of the geometry of ``x (D,)``: segment poses ``R, t``, and as the cues need
        them (``needs``: default what every cue reads) the joints ``(J, 3)``, the world primitives and each view's
        occluding contours (cone generators as lines, ellipsoid outlines as ellipses; sampled by
        :meth:`_contour_points`).

        :meth:`batch` runs this over all particles at once (many small operations: better amortised over a large
        batch) and :meth:`geometry_from_pose` in chunks (long per-point arrays: better kept in cache).
        """
        needs = self._needs() if needs is None else needs
        R, t = body.segment_poses(self.model, x)
        out = {"R": R, "t": t}
        if "facing" in needs:
            Cc = camera.camera_centres(self.rig).astype(R.dtype)  # (V, 3)
            d = Cc[:, None, :] - t[None]  # (V, S, 3)
            out["camera_local"] = jnp.stack(
                [
                    R[None, :, 0, i] * d[..., 0] + R[None, :, 1, i] * d[..., 1] + R[None, :, 2, i] * d[..., 2]
                    for i in range(3)
                ],
                -1,
            )
        if needs & {"joints", "joints_uv"}:
            out["joints"] = kinematics.transform_points(
                R, t, self.model.joint_point, self.model.joint_segment
            )
        if needs & {"contour", "contour_index", "primitives"}:
            out["primitives"] = prims = flesh.world_primitives(self.model, R, t)
        if needs & {"contour", "contour_index"}:
            # the contours as lines and ellipses per view (a few vectors per primitive); their points are sampled
            # in geometry_from_pose, next to the projection that reads them
            Cc = camera.camera_centres(self.rig).astype(R.dtype)
            if prims.num_cones:
                out["contour_lines"] = jax.vmap(
                    lambda c: flesh.cone_contour_lines(prims.cone_a, prims.cone_b, prims.r_a, prims.r_b, c)
                )(Cc)  # (V, C, 2, 3) twice
            if prims.num_ellipsoids:
                out["contour_ellipses"] = jax.vmap(
                    lambda c: flesh.ellipsoid_contour_frames(prims.ell_centre, prims.ell_axes, c)
                )(Cc)  # (V, E, 3) three times
        return out

    def _contour_points(self, pose: dict) -> jnp.ndarray:
        """``(V, Q, 3)`` occluding-contour points of each view: ``contour_points`` on each cone generator, then
        twice as many on each ellipsoid's outline (:func:`jaxmocap.geometry.flesh.cone_contours`,
        :func:`jaxmocap.geometry.flesh.ellipsoid_contours`), from the lines and ellipses of :meth:`pose_stage`."""
        V, k = self.rig.num_views, self.contour_points
        pts = []
        if "contour_lines" in pose:
            pts.append(flesh.contour_line_points(*pose["contour_lines"], k).reshape(V, -1, 3))
        if "contour_ellipses" in pose:
            pts.append(flesh.ellipse_points(*pose["contour_ellipses"], 2 * k).reshape(V, -1, 3))
        return jnp.concatenate(pts, axis=1) if len(pts) > 1 else pts[0]

    def geometry_from_pose(
        self,
        pose: dict,
        image_shape: tuple[int, int] | None = None,
        needs: frozenset | None = None,
        *,
        adjoint: bool = False,
    ) -> cues.Geometry:
        """Projected geometry of one particle from its :meth:`pose_stage` (see :meth:`geometry`; ``needs`` as
        there; ``adjoint``: :meth:`_surface_geometry`)."""
        needs = self._needs() if needs is None else needs
        V = self.rig.num_views
        g = {}
        if "joints" in pose:
            g["joints"] = pose["joints"]
            if "joints_uv" in needs:
                g["joints_uv"] = camera.project(self.rig, pose["joints"])
        if needs & {"surface", "surface_index", "facing"}:
            g.update(self._surface_geometry(pose, image_shape, needs, adjoint))
        if "primitives" in pose:
            g["primitives"] = pose["primitives"]
        if needs & {"contour", "contour_index"}:
            quv = camera.project_per_view(self.rig, self._contour_points(pose))
            g["contour_uv"] = quv
            if "contour_index" in needs and image_shape is not None:
                g["contour_index"], g["contour_inside"] = maps.nearest_index(quv, (V,) + tuple(image_shape))
        return cues.Geometry(**g)

    def _surface_geometry(self, pose: dict, image_shape, needs, adjoint: bool = False) -> dict:
        """The flesh-point fields of :class:`jaxmocap.likelihood.cues.Geometry` (world points, pixels, depth, facing, indices).

        Points stored segment by segment (at most :data:`jaxmocap.geometry.kinematics.MAX_RUNS` runs) go run by run: the
        camera-from-segment transform ``A_vs = R_v R_s``, ``b_vs = R_v t_s + t_v`` maps the run's local points to
        camera coordinates (no world points in between, no per-point gather of transforms), every field of the run
        is computed from them, and each field is concatenated over the runs at the end, so that XLA materialises
        the final fields only (on its CPU backend a concatenation of intermediate coordinates was copied, and the
        projection recomputed in every consumer). Other layouts project the world points (the same values up to
        rounding). ``adjoint=True`` (reverse mode only, :meth:`batch_value_and_grad`) differentiates the runs by
        their written-out reverse pass (:func:`jaxmocap.geometry.kinematics.affine_by_runs`).

        Facing: ``n·(c_v − X) > 0`` in the segment frame, ``n_p·c_v,s(p) > n_p·p_p`` with ``c_v,s = R_sᵀ(c_v − t_s)``
        the camera centre in segment ``s``'s frame (``camera_local`` of :meth:`pose_stage`), and in front of it.
        """
        R, t = pose["R"], pose["t"]
        V = self.rig.num_views
        n, p = self.surface.normal, self.surface.local

        def dot3(a, b):  # a · b over the last axis, written out (broadcasting the leading axes)
            return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]

        npp = dot3(n, p)
        facing = "facing" in needs
        shape = (V,) + tuple(image_shape) if "surface_index" in needs and image_shape is not None else None

        def fields(uv, z, nc, npp):
            out = {"surface_uv": uv, "surface_depth": z}
            if facing:
                out["surface_facing"] = (nc > npp) & (z > 0)
            if shape is not None:
                out["surface_index"], out["surface_inside"] = maps.nearest_index(uv, shape)
                if facing:
                    out["surface_visible_index"] = maps.visible_index(
                        out["surface_index"], out["surface_facing"] & out["surface_inside"], shape
                    )
            return out

        cl = pose.get("camera_local")  # (V, S, 3)
        X = kinematics.transform_points(
            R, t, p, self.surface.segment, adjoint=adjoint
        )  # world points (dropped when unused)
        runs = kinematics.segment_runs(self.surface.segment)
        if len(runs) <= kinematics.MAX_RUNS:
            Rc = jnp.asarray(self.rig.R, R.dtype)
            tc = jnp.asarray(self.rig.t, R.dtype)
            # (sums of three products written out: XLA's CPU backend hands a reduction over 3 to a library)
            A = sum(Rc[:, None, :, j, None] * R[None, :, None, j, :] for j in range(3))  # (V, S, 3, 3)
            b = sum(Rc[:, None, :, j] * t[None, :, None, j] for j in range(3)) + tc[:, None]  # (V, S, 3)
            parts = []
            pieces = kinematics.affine_by_runs(A, b, p, runs, adjoint)
            for (start, stop, s), cam in zip(runs, pieces, strict=True):
                uv, z = camera.pixels_from_camera(self.rig, *cam)
                nc = dot3(cl[:, s, None, :], n[start:stop]) if facing else None
                parts.append(fields(uv, z, nc, npp[start:stop]))
            out = {k: jnp.concatenate([q[k] for q in parts], axis=1) for k in parts[0]}
        else:
            uv, z = camera.project_with_depth(self.rig, X)
            nc = dot3(cl[:, np.asarray(self.surface.segment, np.int32)], n) if facing else None
            out = fields(uv, z, nc, npp)
        out["surface"] = X
        return out

    def geometry(self, x: jnp.ndarray, image_shape: tuple[int, int] | None = None) -> cues.Geometry:
        """Projected geometry of one particle ``x (D,)`` — only the parts the cues need.

        ``image_shape``: ``(H, W)`` of the observation's maps, for the shared nearest-pixel indices (left out when
        None). How the flesh-point fields are laid out for XLA's CPU backend: :meth:`_surface_geometry` and
        :mod:`jaxmocap.likelihood.maps`.
        """
        return self.geometry_from_pose(self.pose_stage(x), image_shape)

    # -----------------------------------------------------------------------------------------------------------
    # Evaluation

    def prepare(self, obs: Observation) -> tuple:
        """Per-call work of each cue that depends on the observation only (``None`` for cues without it)."""
        cache: dict = {}
        out = []
        for c, cue in enumerate(self.cues):
            p = cue.spec.prepare
            out.append(None if p is None else p(obs, self._context(c), cache))
        return tuple(out)

    def view_energies(
        self, x: jnp.ndarray, obs: Observation, aux: tuple | None = None, partition=None
    ) -> jnp.ndarray:
        """``(C, V)`` weighted cue energies ``k_c w_v E_c,v`` of one particle (before the schedule); a view-free
        cue has ``k_c E_c`` in column 0 and zeros elsewhere. ``aux``: :meth:`prepare` (computed here if None);
        ``partition``: that partition's body parts (:meth:`with_partitions`)."""
        aux = self.prepare(obs) if aux is None else aux
        return self._energies_from_pose(self.pose_stage(x), obs, aux, part=self._part(partition))

    def _energies_from_pose(
        self,
        pose: dict,
        obs: Observation,
        aux: tuple,
        which: Sequence[int] | None = None,
        adjoint: bool = False,
        part=None,
    ) -> jnp.ndarray:
        """``(len(which), V)`` rows of :meth:`view_energies` for the cues ``which`` (default all), from a
        :meth:`pose_stage` that has what they need (``adjoint``: :meth:`_surface_geometry`; ``part``: a
        partition's :class:`~jaxmocap.likelihood.cue_context.PartWeights`)."""
        if (
            self.cue_weights is None
        ):  # the cues' own weights are not part of the structure (Cue: compare=False)
            raise ValueError("a Likelihood needs cue_weights (C,): build it with Likelihood.create")
        which = range(len(self.cues)) if which is None else which
        g = self.geometry_from_pose(pose, obs.image_shape, self._needs(which), adjoint=adjoint)
        V = self.rig.num_views
        rows = []
        for c in which:
            cue = self.cues[c]
            e = cue.spec.energy(g, obs, self._context(c, aux[c], part))
            k = self.cue_weights[c]
            if cue.spec.per_view:
                rows.append(k * self.view_weights * e)
            else:
                rows.append(jnp.zeros((V,), e.dtype).at[0].set(k * e))
        return jnp.stack(rows)

    def energies(
        self, x: jnp.ndarray, obs: Observation, aux: tuple | None = None, partition=None
    ) -> jnp.ndarray:
        """``(C,)`` view-weighted cue energies ``k_c Σ_v w_v E_c,v`` of one particle (before the schedule)."""
        return jnp.sum(self.view_energies(x, obs, aux, partition), axis=-1)

    def layer_lambda(self, layer=0) -> jnp.ndarray:
        """``(C, V)`` λ of annealing layer ``layer``: an int (traced or static) or the
        :class:`jaxmocap.filters.base.Layer` the annealed filters pass (its ``index`` is used)."""
        return self.schedule[self._layer_index(layer)]

    def _layer_index(self, layer):
        return jnp.clip(getattr(layer, "index", layer), 0, self.schedule.shape[0] - 1)

    def _table_lambda(self, layer) -> jnp.ndarray:
        """``(C_table, V)`` λ of the table's cues at ``layer``: the table's columns of the schedule, taken as static
        slices of its runs of consecutive cues (with constant parameters XLA then compiles the table as it compiles
        a likelihood of those cues alone; a gather of the same columns gives another program and other float
        rounding), then the layer's row."""
        table = self._table_cues()
        schedule = self.schedule
        if len(table) < len(self.cues):
            starts = [c for c in table if c - 1 not in table]
            stops = [c + 1 for c in table if c + 1 not in table]
            schedule = jnp.concatenate([schedule[:, a:b] for a, b in zip(starts, stops, strict=True)], axis=1)
        return schedule[self._layer_index(layer)]

    def _table_loglik(
        self,
        pose: dict,
        obs: Observation,
        aux: tuple,
        lam_table: jnp.ndarray,
        adjoint: bool = False,
        part=None,
    ) -> jnp.ndarray:
        """``−Σ_c Σ_v λ_c,v k_c w_v E_c,v`` over the cues of the table, of one particle's :meth:`pose_stage` (with
        what those cues need) and their λ (:meth:`_table_lambda`)."""
        e = self._energies_from_pose(pose, obs, aux, self._table_cues(), adjoint, part)
        return -jnp.sum(lam_table * e)

    def _separate_energy(
        self, c: int, x: jnp.ndarray, obs: Observation, aux: tuple, pose: dict | None = None, part=None
    ) -> jnp.ndarray:
        """``Σ_v w_v E_c,v`` of the separate cue ``c`` at one particle ``x (D,)``, from the geometry it reads
        alone (``pose``: a :meth:`pose_stage` of ``x`` with what the cue needs, computed here if None)."""
        cue = self.cues[c]
        needs = self._needs((c,))
        pose = self.pose_stage(x, needs) if pose is None else pose
        g = self.geometry_from_pose(pose, obs.image_shape, needs)
        e = cue.spec.energy(g, obs, self._context(c, aux[c], part))
        return jnp.sum(self.view_weights * e) if cue.spec.per_view else e

    def _separate_weight(self, c: int, layer) -> jnp.ndarray:
        """``λ_c(l) k_c`` of the separate cue ``c`` at ``layer`` (its λ is the same in every view): the ``(L,)``
        column ``λ_c k_c``, then the layer's entry."""
        return (self.schedule[:, c, 0] * self.cue_weights[c])[self._layer_index(layer)]

    def log_likelihood(
        self,
        x: jnp.ndarray,
        obs: Observation,
        layer=0,
        aux: tuple | None = None,
        *,
        adjoint: bool = False,
        partition=None,
    ) -> jnp.ndarray:
        """Scalar ``log p_l(z | x)`` of one particle at annealing layer ``layer`` (see :meth:`layer_lambda`), composed
        as :meth:`batch` composes it, from one :meth:`pose_stage` with what every cue needs (one forward kinematics,
        and one reverse pass through it when differentiated); ``adjoint``: :meth:`_surface_geometry`;
        ``partition``: as in :meth:`batch`."""
        aux = self.prepare(obs) if aux is None else aux
        part = self._part(layer_partition(layer, partition))
        table = self._table_cues()
        pose = self.pose_stage(x)
        ll = self._table_loglik(pose, obs, aux, self._table_lambda(layer), adjoint, part) if table else 0.0
        for c in self._separate_cues():
            ll = ll - self._separate_weight(c, layer) * self._separate_energy(c, x, obs, aux, pose, part)
        return ll

    def batch(self, X: jnp.ndarray, obs: Observation, layer=0, partition=None) -> jnp.ndarray:
        """``(N,)`` log-likelihoods of particles ``X (N, D)``; non-finite values become −inf.

        The observation-only work is done once; particles go through the λ table in equal chunks of at most
        ``chunk_size`` (module docstring, step 3; padding copies' results dropped), then the separate cues are
        subtracted (module docstring). ``partition`` (default: ``layer.partition`` of a filter's
        :class:`~jaxmocap.filters.base.Layer`, else 0; an int or traced int32): with a partition table
        (:meth:`with_partitions`) the cues weigh that partition's body parts; ignored without one.
        """
        aux = self.prepare(obs)
        part = self._part(layer_partition(layer, partition))
        table, separate = self._table_cues(), self._separate_cues()
        N, D = X.shape
        if table:
            lam_table = self._table_lambda(layer)
            ll = self._chunked(
                lambda p: self._table_loglik(p, obs, aux, lam_table, part=part), X, self._needs(table)
            )
            ll = jnp.where(jnp.isfinite(ll), ll, -jnp.inf)
        else:
            ll = jnp.zeros((N,), X.dtype)
        if not separate:
            return ll
        for c in separate:
            e = jax.vmap(lambda x, c=c: self._separate_energy(c, x, obs, aux, part=part))(X)
            ll = ll - self._separate_weight(c, layer) * e
        return jnp.where(jnp.isfinite(ll), ll, -jnp.inf)

    def _chunked(self, f, X: jnp.ndarray, needs: frozenset) -> jnp.ndarray:
        """``(N,)`` values of ``f(pose)`` for the :meth:`pose_stage` of each particle of ``X (N, D)``: the pose stage
        over all particles, then ``f`` in chunks of ``chunk_size`` (module docstring, steps 2–3)."""
        N, D = X.shape
        c = self.chunk_size
        n = 1 if c <= 0 or N <= c else -(-N // c)
        c = -(-N // n)  # n chunks as equal as can be: 200 particles go as 2 × 100, not 2 × 128 with 56 copies
        if n > 1 and n * c > N:
            X = jnp.concatenate([X, jnp.broadcast_to(X[:1], (n * c - N, D))])
        pose = jax.vmap(lambda x: self.pose_stage(x, needs))(X)
        f = jax.vmap(f)
        if n == 1:
            return f(pose)
        chunks = jax.tree_util.tree_map(lambda a: a.reshape((n, c) + a.shape[1:]), pose)
        return jax.lax.map(f, chunks).reshape(-1)[:N]

    def batch_value_and_grad(
        self, X: jnp.ndarray, obs: Observation, layer=0, partition=None
    ) -> tuple[jnp.ndarray, jnp.ndarray]:
        """Values ``(N,)`` and gradients ``∂ℓ/∂x (N, D)`` of particles ``X (N, D)``: the per-particle
        :meth:`log_likelihood` differentiated in one ``vmap`` (reverse mode through the chunked ``lax.map`` of
        :meth:`batch` was measured 4–9× slower on a CPU), its flesh points moved with their runs' written-out
        reverse pass (``adjoint=True``: :meth:`_surface_geometry`). Non-finite values give ``−inf``, zero gradient.

        More than ``2 · chunk_size`` particles go through it in ``n = ⌈N / (2 chunk_size)⌉`` chunks of ``⌈N / n⌉``
        (``lax.map`` over the vmapped value-and-gradient of a chunk, padded with copies of the first particle): the
        reverse pass keeps every intermediate of the forward one, which for a thousand particles no longer stays in
        the caches, while each chunk repeats the per-call work inside the loop (measured on a CPU, default cues:
        ``upper14`` at 1000 particles 25 % faster in chunks of 128 or 250 than in one; ``full25`` at 200 particles
        10 % slower in two chunks, 60 % slower in four).
        """
        aux = self.prepare(obs)
        ll = lambda x: self.log_likelihood(x, obs, layer, aux, adjoint=True, partition=partition)  # noqa: E731
        f, (N, D) = jax.vmap(jax.value_and_grad(ll)), X.shape
        most = 2 * self.chunk_size
        if most <= 0 or N <= most:
            return finite_value_and_grad(*f(X))
        n = -(-N // most)
        c = -(-N // n)  # n chunks of at most 2 chunk_size, as equal as can be: fewer than n copies padded
        Xp = jnp.concatenate([X, jnp.broadcast_to(X[:1], (n * c - N, D))]) if n * c > N else X
        values, grads = jax.lax.map(f, Xp.reshape(n, c, D))
        return finite_value_and_grad(values.reshape(-1)[:N], grads.reshape(-1, D)[:N])

    # -----------------------------------------------------------------------------------------------------------
    # Reference data (first frame)

    def with_references(self, x0: jnp.ndarray, obs0: Observation) -> Likelihood:
        """The same likelihood with the reference data of its colour cues taken from a first frame (host side).

        ``x0 (D,)``: the pose in that frame (ground truth or initialisation); ``obs0``: its observation (with
        ``rgb``). ``colour_histogram``: per view and ROI segment, the ROI mask is the model rendered at ``x0``
        (:func:`jaxmocap.geometry.render.render_view`, visible pixels of the segment's primitive) and the reference is
        :func:`jaxmocap.features.colour.roi_histograms` of the frame's colours over it (``(V, R, B)``; with
        ``soft=True`` the same pixels binned with the cue's triangular kernel).
        ``colour_template``: the colour at each surface sample that faces camera ``v`` at ``x0`` and lies inside
        the image (and on the foreground when the observation has one): ``(T (3, V, P), valid (V, P))``.
        """
        from jaxmocap.features.colour import roi_histograms
        from jaxmocap.geometry import render

        refs = list(self.references) if self.references else [None] * len(self.cues)
        x0 = jnp.asarray(x0, self.model.offset.dtype)
        V = self.rig.num_views
        H, W = obs0.image_shape
        for c, cue in enumerate(self.cues):
            kind = cue.spec.reference
            if kind is None:
                continue
            if not obs0.has("rgb"):
                raise ValueError(f"cue {cue.name!r} needs the first frame's rgb map for its reference")
            rgb8 = np.asarray(
                jnp.round(jnp.clip(obs0.rgb.astype(jnp.float32) * cues._unit_scale(obs0.rgb), 0, 1) * 255)
            )
            rgb8 = rgb8.astype(np.uint8)
            ctx = self._context(c)
            if kind == "histogram":
                p = cue.param_dict
                segs = cues._segment_ids(ctx, p.get("rois"), "fleshed")
                # the ROI masks are rendered in float32 whatever the model's dtype (a reference, not differentiated)
                prims = jax.tree_util.tree_map(
                    lambda a: jnp.asarray(a, jnp.float32), render.primitives_from_model(self.model, x0)
                )
                cam = [np.asarray(a, np.float32) for a in (self.rig.K, self.rig.dist, self.rig.R, self.rig.t)]
                label_of = {
                    s: i
                    for i, s in enumerate(
                        flesh.cone_segments(self.model) + flesh.ellipsoid_segments(self.model)
                    )
                }
                hists = []
                for v in range(V):
                    lab = np.asarray(
                        render.render_view(
                            cam[0][v], cam[1][v], cam[2][v], cam[3][v], (W, H), prims, normals=False
                        ).label
                    )
                    masks = [lab == label_of[s] for s in segs]
                    bins = int(p.get("bins", 4))
                    if p.get("soft", False):  # the same triangular-kernel binning as the cue
                        rows = []
                        for m in masks:
                            h = np.asarray(_soft_histogram(jnp.asarray(rgb8[v][m]), bins))
                            rows.append(h / max(float(jnp.sum(h)), 1e-12))
                        hists.append(np.stack(rows))
                    else:
                        bgr = np.ascontiguousarray(rgb8[v, ..., ::-1])
                        hists.append(roi_histograms(bgr, masks, bins=bins, space=p.get("space", "rgb")))
                refs[c] = jnp.asarray(np.stack(hists), self.model.offset.dtype)
            elif kind == "template":
                # the colours are read exactly as the cue reads them (nearest 8-bit colour, or bilinear), so that
                # the energy at (x0, obs0) is 0
                refs[c] = _template_reference(self, c, x0, obs0)
        return dataclasses.replace(self, references=tuple(refs))


@functools.partial(jax.jit, static_argnums=1)
def _template_reference(lik: Likelihood, c: int, x0: jnp.ndarray, obs0: Observation) -> tuple:
    """``colour_template``'s reference of cue ``c`` of ``lik`` (see :meth:`Likelihood.with_references`):
    ``T (3, V, P)`` and ``valid (V, P)``. One compiled program (the geometry's hundreds of operations run one by one
    would each be compiled for their shapes), reused by every likelihood of the same structure and shapes."""
    g0 = lik.geometry(x0, obs0.image_shape)
    ctx = lik._context(c, cues._prepare_colour(obs0, lik._context(c), {}))
    rgb, inside = cues._surface_rgb(obs0, g0, ctx)
    T = jnp.stack(rgb)  # (3, V, P)
    valid = g0.surface_facing & inside
    if obs0.has("foreground"):
        fg = maps.gather(obs0.foreground, g0.surface_index, cues._unit_scale(obs0.foreground))
        valid = valid & (fg >= 0.5)
    return T.astype(lik.model.offset.dtype), valid


@functools.partial(jax.jit, static_argnums=1)
def _soft_histogram(rgb8: jnp.ndarray, bins: int) -> jnp.ndarray:
    """``(bins³,)`` sums of the triangular-kernel bin weights (:func:`jaxmocap.likelihood.cues._soft_bin_weights`)
    of the 8-bit colours ``rgb8 (N, 3)`` (RGB), unnormalised."""
    px = rgb8.astype(jnp.float32) / 255.0
    return jnp.sum(cues._soft_bin_weights(tuple(px[:, i] for i in range(3)), bins), axis=0)


jax.tree_util.register_dataclass(
    Likelihood,
    data_fields=[
        "model",
        "rig",
        "surface",
        "view_weights",
        "schedule",
        "references",
        "cue_weights",
        "partition_weights",
    ],
    meta_fields=["cues", "contour_points", "chunk_size"],
)


def layer_partition(layer, partition=None):
    """The partition to weigh: ``partition`` when given, else the ``partition`` of a filter's
    :class:`~jaxmocap.filters.base.Layer`, else 0 (a bare layer index)."""
    return getattr(layer, "partition", 0) if partition is None else partition


# ---------------------------------------------------------------------------------------------------------------
# Schedules (feature-based annealing)

#: cues that describe the silhouette coarsely and are smooth over large pose changes (used in early layers)
COARSE_CUES = frozenset(
    {
        "foreground",
        "silhouette_divergence",
        "coverage",
        "depth",
        "blobs3d",
        "keypoints",
        "ground",
        "wristband",
        "skin",
        "head_skin",
        "colour_histogram",
        "homogeneous_colour",
    }
)
#: cues that localise precisely but have narrow basins (weighted up in later layers)
FINE_CUES = frozenset({"edges", "edge_distance", "edge_fraction", "colour_template"})


def schedule_preset(name: str, cue_names: Sequence[str], num_layers: int) -> np.ndarray:
    """λ_c(l) tables, ``(L, C)``, for the annealing variants compared in López Méndez ch. 6–7.

    * ``apf`` — every cue with λ = 1 in every layer (the standard APF: the layers differ only by β).
    * ``m-apf`` — the same cue weights; the filter varies the survival-rate target per layer (see
      :mod:`jaxmocap.filters.apf`); listed so every variant has a schedule.
    * ``fbapf`` — feature-based annealing: coarse cues (:data:`COARSE_CUES`: silhouette, depth, detections,
      skin, colour distributions) at full weight from the first layer; fine cues (:data:`FINE_CUES`: edges,
      per-point colour) enter linearly, ``λ = l / (L − 1)``, reaching 1 in the last layer.
    * ``fbapf2`` — coarse cues fade out as the fine cues fade in (``1 − l/(L−1)`` vs ``l/(L−1)``), never below 0.25.
    * ``fbapf3`` — two stages: coarse cues only in the first half of the layers, all cues in the second half.
    * ``li-kulic`` — λ = ln 100 for every cue (their ``w = A^(−d)``, A = 100, eq. 4: the product of the cue weights
      is ``exp(−ln A Σ_c d_c)``).

    Priors (``interpenetration``) keep λ = 1 in every variant. These tables are this project's reading of the
    thesis' schedules (eq. 6.5–6.7): coarse-to-fine cue weighting across layers. Per-view tables are these
    broadcast over views, or any ``(L, C, V)`` array given to :meth:`Likelihood.create`.
    """
    L, C = num_layers, len(cue_names)
    ramp = np.linspace(0.0, 1.0, L) if L > 1 else np.ones(1)
    lam = np.ones((L, C), np.float64)
    known = ("apf", "m-apf", "fbapf", "fbapf2", "fbapf3", "li-kulic")
    if name not in known:
        raise ValueError(f"unknown schedule {name!r}; choose {', '.join(known)}")
    for c, n in enumerate(cue_names):
        fine = n in FINE_CUES
        coarse = n in COARSE_CUES
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
    return lam.astype(np.float32)
