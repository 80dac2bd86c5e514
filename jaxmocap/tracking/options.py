"""The options of a tracking run and their per-model defaults.

:class:`TrackOptions` holds what ``jaxmocap track`` takes (``None`` = the default of the model or input);
:func:`build_model` the body, :func:`default_particles` / :func:`default_layers` / :func:`diffusion_std` /
:func:`default_cues` the defaults, :func:`parse_cues` the ``--cues`` syntax; :func:`load_config` /
:func:`dump_config` a run's configuration file (``jaxmocap track --config run.toml``). The filter names (:data:`FILTERS`)
are those of :mod:`jaxmocap.choices`.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence

import numpy as np

from jaxmocap.choices import (
    ANNEALED,
    FILTERS,
    FOREGROUNDS,
    GRADIENT_FILTERS,
    MODELS,
    PARTITIONED,
    SINGLE_LAYER,
)
from jaxmocap.errors import MocapInputError, load_toml
from jaxmocap.geometry import body as body_mod
from jaxmocap.likelihood import cues as cues_mod

__all__ = [
    "ANNEALED",
    "FILTERS",
    "FOREGROUNDS",
    "GRADIENT_FILTERS",
    "KEYPOINTS_WEIGHT",
    "MODELS",
    "REFINED_VIEWS_PARTICLES",
    "TrackOptions",
    "build_model",
    "default_cues",
    "default_layers",
    "default_refine",
    "default_refine_depth",
    "default_particles",
    "diffusion_std",
    "dump_config",
    "load_config",
    "option_types",
    "parse_cues",
]


def build_model(
    name: str | None,
    body_file: str | os.PathLike | None,
    fallback_body: os.PathLike | None = None,
    dimensions: dict | None = None,
):
    """The body model to track with: preset ``name`` with the dimensions of ``body_file`` (or of the sequence's
    ``fallback_body``, or ``dimensions`` without a body file); without a name, the model the body file names
    (default ``full25``).

    Presets in other units than metres (``parsec31``, registered by :mod:`jaxmocap.parsec`) are built in
    **metres** (:func:`jaxmocap.geometry.body.build` with ``in_metres``) so that they share the calibration and
    cues of the other models.
    """
    path = body_file if body_file is not None else fallback_body
    dims: dict = {}
    file_model = None
    if path is not None:
        file_model, dims = body_mod.load_body_file(path)
    if path is None and dimensions:
        dims = dict(dimensions)
    name = name or file_model or "full25"
    if name not in MODELS:
        raise ValueError(f"unknown model {name!r}; choose one of {', '.join(MODELS)}")
    if name not in body_mod.preset_names():
        raise ValueError(f"body model {name!r} is not registered: import jaxmocap.parsec (its wing) first")
    if file_model is not None and (file_model == "parsec31") != (name == "parsec31"):
        dims = {}  # the dimensions of PARSEC's body and of the other presets have nothing in common
    try:
        return body_mod.build(name, dims or None, in_metres=True)
    except (KeyError, ValueError) as e:
        raise MocapInputError(path, str(e)) from None


def diffusion_std(model: body_mod.BodyModel, fps: float = 30.0) -> np.ndarray:
    """Per-DOF random-walk standard deviation per frame ``(D,)``, chosen for walking-speed motion at 30 fps and
    scaled by ``30 / fps``: root translation 3 cm, root heading 0.06 rad, root tilt 0.04 rad, neck 0.06 rad,
    shoulders and hips 0.10 rad, elbows and knees 0.12 rad, the spine and the shoulder girdles (``full32``'s
    ``spine_*`` and ``*_clavicle_*``, ``parsec31``'s clavicles) 0.03 rad (other angles 0.08 rad)."""
    out = np.empty(model.num_dofs, np.float64)
    root = set(model.topology.segment_dofs[0])
    for d, (name, kind) in enumerate(zip(model.dof_names, model.topology.dof_kinds, strict=True)):
        if kind == "P":
            out[d] = 0.03
        elif d in root:
            out[d] = 0.06 if name.endswith("rz") else 0.04
        elif "neck" in name or "head" in name:
            out[d] = 0.06
        elif "spine" in name or "clavicle" in name:
            out[d] = 0.03
        elif "elbow" in name or "knee" in name:
            out[d] = 0.12
        elif "shoulder" in name or "hip" in name:
            out[d] = 0.10
        else:
            out[d] = 0.08
    return (out * (30.0 / float(fps))).astype(np.float32)


#: Particles per layer of the APF when its estimate is refined on detections seen by three or more cameras
#: (:func:`default_particles`).
REFINED_VIEWS_PARTICLES = 50


def default_particles(model_name: str, filter_name: str, refined_views: bool = False) -> int:
    """Particles per layer (annealed filters) or in all (the others: as many likelihood evaluations per frame).

    ``refined_views``: the run refines each frame's estimate on detections of three or more cameras and moves the
    particles with it (``refine = "track"``, :mod:`jaxmocap.tracking.refine`); the APF then takes
    :data:`REFINED_VIEWS_PARTICLES` per layer for ``full25`` / ``full32``: on the six synthetic four-camera clips of
    ``benchmarks/results/accuracy_default.md`` (realistic input, 3 seeds) 50 particles tracked to 28.7 mm like 300
    (every run within 0.4 mm of its 300-particle twin) at 37.1 against 18.4 frames/s; with a stereo pair, whose
    detections fix depth poorly, 50 lost 4.1 ± 1.0 mm, so a pair keeps 300."""
    base = {"upper9": 150, "upper14": 200, "full25": 300, "full32": 300, "parsec31": 300}[model_name]
    if refined_views and filter_name == "apf" and model_name in ("full25", "full32"):
        return REFINED_VIEWS_PARTICLES
    if filter_name in ("sir", "icondensation"):
        return base * default_layers(filter_name)[1]
    if filter_name in PARTITIONED:
        return max(base // 2, 50)
    return base


def default_layers(filter_name: str) -> tuple[int, int]:
    """``(layers of this filter, layers of the APF)``: 5 for the annealed filters, 2 per level for the
    hierarchical one, 1 for SIR / ICONDENSATION / partitioned sampling."""
    apf = 5
    if filter_name in SINGLE_LAYER:
        return 1, apf
    if filter_name == "hierarchical":
        return 2, apf
    return apf, apf


#: Weight of the default ``keypoints`` cue. Its energy per view is a mean of bounded Geman–McClure terms (at most
#: 1, σ = 20 px), while the silhouette cues cannot tell a body from the same body turned by 180°: at weight 1 the
#: track of a fast turn fell up to 200° behind the body and stayed facing backwards (four cameras, 300° in 2 s).
#: 32 (with the root's angles in the velocity prediction) measured best of 1, 8, 16, 32 and 64 on the synthetic
#: four-camera turn and crouch, and lowered the error of the other four-camera clips and of every stereo clip but
#: the crouch (``benchmarks/results/accuracy_default.md``: its tables and its experiments section).
KEYPOINTS_WEIGHT = 32.0


def default_cues(model_name: str, has_depth: bool, has_keypoints: bool) -> tuple[tuple[str, float], ...]:
    """``(name, weight)`` of the default cues: silhouette (``foreground``), edges (``edge_distance``), the
    silhouette coverage term (weight 4: with a one-pixel ``d_max`` it balances the foreground cue's preference for a
    model that shrinks into the silhouette; chosen on the demo sequence, see ``benchmarks/results/demo_table.txt``),
    ``depth`` when the input has depth maps (the full bodies only: Li & Kulić's cue), and the 2D ``keypoints`` when
    there are detections, weight :data:`KEYPOINTS_WEIGHT`."""
    out = [("foreground", 1.0), ("edge_distance", 1.0), ("coverage", 4.0)]
    if has_depth and model_name in ("full25", "full32"):
        out.append(("depth", 1.0))
    if has_keypoints:
        out.append(("keypoints", KEYPOINTS_WEIGHT))
    return tuple(out)


def default_refine(num_views: int, has_keypoints: bool) -> tuple[str, float]:
    """``(refine, refine_prior)`` of ``refine = "auto"`` / ``refine_prior = None`` (:mod:`jaxmocap.tracking.refine`),
    per input kind, as measured in ``benchmarks/results/accuracy_default.md`` (six synthetic motions, realistic
    input, 3 seeds): ``track`` with detections in two or more views, at λ = :data:`REFINE_PRIOR_VIEWS` with three or
    more views and at λ = :data:`REFINE_PRIOR_PAIR` with a stereo pair, whose detections fix depth poorly; ``none``
    without detections."""
    if not has_keypoints or num_views < 2:
        return "none", REFINE_PRIOR_VIEWS
    return "track", REFINE_PRIOR_VIEWS if num_views >= 3 else REFINE_PRIOR_PAIR


#: Prior weight λ of the refinement with three or more views, and with two (:func:`default_refine`).
REFINE_PRIOR_VIEWS = 1.0
REFINE_PRIOR_PAIR = 30.0

#: σ_d (m) of the refinement's depth term with a stereo pair's depth maps (:func:`default_refine_depth`).
REFINE_DEPTH_SIGMA = 0.05


def default_refine_depth(refine: str, has_depth: bool, num_views: int) -> float:
    """σ_d (m) of ``refine_depth = None``, per input kind, as measured in
    ``benchmarks/results/accuracy_default.md`` (six synthetic motions, realistic input, 3 seeds): the depth term of
    the refinement (:mod:`jaxmocap.tracking.refine`: the camera depths of the trunk's and the limbs' joints read from
    the depth maps) at :data:`REFINE_DEPTH_SIGMA` where the estimate is refined on a stereo pair with depth maps
    (114.4 → 52.7 mm); 0 (none) otherwise: with four cameras the detections place the joints better than maps with
    2 cm noise read at a fixed distance behind the surface (28.7 → 33.0 mm with them)."""
    return REFINE_DEPTH_SIGMA if (refine != "none" and has_depth and num_views == 2) else 0.0


def cues_text(cues) -> str:
    """``[("foreground", 1.0), ("coverage", 4.0)]`` → ``"foreground, coverage:4"`` (the ``--cues`` syntax)."""
    return ", ".join(n if w == 1 else f"{n}:{w:g}" for n, w in cues)


def parse_cues(spec: str | Sequence | None) -> tuple[tuple[str, float], ...] | None:
    """``"foreground,edge_distance:2,coverage"`` → ``(("foreground", 1.0), ("edge_distance", 2.0), …)``."""
    if spec is None:
        return None
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    out = []
    for it in items:
        if isinstance(it, tuple):
            name, w = it
        else:
            name, _, w = str(it).strip().partition(":")
            w = w or 1.0
        try:
            w = float(w)
        except ValueError:
            raise ValueError(f"cue weight of {name!r} must be a number, got {w!r}") from None
        if name not in cues_mod.CUES:
            known = sorted(cues_mod.CUES)
            raise ValueError(f"unknown cue {name!r}; choose from {', '.join(known)}")
        if not (w > 0 and math.isfinite(w)):
            raise ValueError(f"cue weight of {name!r} must be positive, got {w}")
        out.append((name, w))
    if not out:
        raise ValueError("no cue given")
    return tuple(out)


@dataclasses.dataclass
class TrackOptions:
    """Options of a tracking run (``None`` = the per-model / per-input default).

    ``model``/``body``: :func:`build_model` (``body``: a body file, or ``"detections"``: the dimensions measured
    from the input's 2D detections, :func:`jaxmocap.io.subject.body_dimensions`; ``"calibrate"``: limb lengths and radii
    fitted to the run's first 10 frames, :func:`jaxmocap.fit.shape_start.calibrate_from_start`; None: the sequence's body file,
    else the detections' dimensions when the input has detections, else the preset's); ``filter``, ``particles``, ``layers``: :func:`make_filter` (defaults
    :func:`default_particles`, :func:`default_layers`); ``cues``: :func:`parse_cues` (default :func:`default_cues`);
    ``seed``: frame ``t`` uses the key ``fold_in(key(seed), t)``; ``frames``: ``"A:B"``; ``init``: ``groundtruth``,
    ``ik``, a file, or ``auto``; ``foreground``/``downsample``/``samples``: :class:`FeatureBuilder`;
    ``velocity``: damping ``k`` of the constant-velocity prediction ``x_root += k (x̂_{t−1} − x̂_{t−2})`` (0 =
    random walk only), applied to the DOFs of ``velocity_dofs`` (``root``: the root's translation and angles, so
    that a turning body's heading is predicted to go on turning; ``translation``: the translation only, as before
    2026-11; ``all``: every DOF; angle steps of full-turn DOFs wrapped into [−π, π));
    ``refine``: the filter's estimate refined on each frame's detections (:mod:`jaxmocap.tracking.refine`):
    ``estimate`` (the written pose), ``track`` (the particles moved with it), ``none``, or ``auto``
    (:func:`default_refine`); ``refine_prior``: its prior weight λ; ``refine_depth``: σ_d (m) of the refinement's
    depth term on the trunk's and limbs' joints, read from the input's depth maps (0: none; None:
    :func:`default_refine_depth`);
    ``diffusion_scale``: multiplies :func:`diffusion_std`; ``survival_target``: α of
    Deutscher's rule; ``loss_*``/``reinit_widen``: track loss (module docstring); ``on_bad_frame``: ``skip`` or
    ``stop``; ``overlay``: MP4 per view; ``plots``: draw the pictures of ``plots/`` at the end
    (:func:`jaxmocap.eval.plots.plot_run`; ``jaxmocap plot RUN`` draws them later; not part of :meth:`identity`);
    ``resume``/``overwrite``: what to do with a previous run in the output
    folder; ``fsync``: ``fsync`` every rewrite; ``smooth`` (``butterworth[:CUTOFF_HZ]`` or ``none``) and
    ``bvh_units`` (``cm`` or ``m``): the exported track (:mod:`jaxmocap.tracking.outputs`; not part of
    :meth:`identity`: a resumed run may export differently); ``keypoint_layout``: ``auto`` or a layout of
    :data:`jaxmocap.io.keypoints.LAYOUTS`; ``calibration_units``: ``auto``, ``m`` or ``mm``
    (:func:`jaxmocap.io.calibration.check_units`); ``proposal``: the detection-driven pose of ICONDENSATION / IAPF
    and of a re-initialisation, ``auto`` (IK of the keypoints, else the silhouette centroid) or ``head-hands``
    (3D head and hands from skin blobs, :mod:`jaxmocap.tracking.head_hands`; ``init = "head-hands"`` starts from
    it too); ``annealing``: β of the annealed filters, ``auto`` (Deutscher's rule, or the filter's own) or
    ``iros2007`` (the fixed 3-layer (α_l, β_l) of :meth:`jaxmocap.filters.annealing.Schedule.iros2007`);
    ``dynamics_fraction`` / ``detection_fraction``: ICONDENSATION's mixture (None: 0.5 / 0.4, the rest from the
    prior); ``preset``: a named configuration of
    :mod:`jaxmocap.tracking.presets` — its partitions, λ table and cue parameters are read from it by the setup,
    while its option values are applied by :meth:`from_preset` (or :func:`jaxmocap.api.run_options`), under the
    options given explicitly; ``count_modes``: record in each frame's diagnostics the number of modes of the
    particle set after each annealing layer (:func:`jaxmocap.eval.mixtures.count_layer_modes`; APF-based filters;
    about 0.1 s of host time per layer; not part of :meth:`identity`); ``detector``: the 2D pose detector that
    makes the keypoints of videos given without them (:mod:`jaxmocap.io.detect`): ``auto`` (the built-in
    detector when it is installed), ``none``, or a detector's name.
    """

    preset: str | None = None
    model: str | None = None
    body: str | None = None
    filter: str = "apf"
    particles: int | Sequence[int] | None = None
    layers: int | None = None
    cues: str | Sequence | None = None
    seed: int = 0
    frames: str | None = None
    init: str = "auto"
    foreground: str = "auto"
    downsample: int = 1
    velocity: float = 0.5
    velocity_dofs: str = "root"
    refine: str = "auto"
    refine_prior: float | None = None
    refine_depth: float | None = None
    diffusion_scale: float = 1.0
    survival_target: float = 0.5
    samples: int = 64  # jaxmocap.tracking.features.COVERAGE_SAMPLES
    loss_ratio: float = 2.5
    loss_frames: int = 3
    loss_window: int = 5
    reinit_widen: float = 3.0
    on_bad_frame: str = "skip"
    overlay: bool = False
    plots: bool = True
    resume: bool = False
    overwrite: bool = False
    fsync: bool = False
    smooth: str = "butterworth"
    bvh_units: str = "cm"
    keypoint_layout: str = "auto"
    calibration_units: str = "auto"
    count_modes: bool = False
    proposal: str = "auto"
    annealing: str = "auto"
    dynamics_fraction: float | None = None
    detection_fraction: float | None = None
    detector: str = "auto"

    @classmethod
    def from_preset(cls, name: str, **options) -> TrackOptions:
        """The options of preset ``name`` (:mod:`jaxmocap.tracking.presets`) with ``options`` (fields given
        explicitly) over them: ``TrackOptions.from_preset("li-kulic", particles=300)``."""
        from jaxmocap.tracking.presets import apply

        unknown = sorted(set(options) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise TypeError(f"unknown option(s) {', '.join(unknown)}")
        return cls(**apply({**options, "preset": name}))

    def identity(self) -> dict:
        """The options a resumed run must share with the run it continues."""
        keys = (
            "model",
            "body",
            "filter",
            "particles",
            "layers",
            "cues",
            "seed",
            "frames",
            "init",
            "foreground",
        )
        keys += (
            "downsample",
            "velocity",
            "diffusion_scale",
            "samples",
            "loss_ratio",
            "loss_frames",
            "loss_window",
        )
        keys += ("reinit_widen", "keypoint_layout", "calibration_units")
        out = {k: getattr(self, k) for k in keys}
        # (absent at their defaults: older runs resume as they were)
        for k, default in _IDENTITY_DEFAULTS.items():
            if getattr(self, k) != default:
                out[k] = getattr(self, k)
        if self.preset is not None:  # (absent otherwise: runs written before presets resume as they were)
            out["preset"] = self.preset
        if isinstance(self.particles, (list, tuple)):
            out["particles"] = [int(c) for c in self.particles]
        out["cues"] = None if self.cues is None else [list(c) for c in parse_cues(self.cues)]
        return out


#: Options of :meth:`TrackOptions.identity` recorded only away from these defaults.
_IDENTITY_DEFAULTS = {
    "proposal": "auto",
    "annealing": "auto",
    "dynamics_fraction": None,
    "detection_fraction": None,
    "detector": "auto",
    "velocity_dofs": "translation",
    "refine": "none",
    "refine_prior": None,
    "refine_depth": None,
}


# ---------------------------------------------------------------------------------------------------------------
# Configuration files

#: What a run reads besides its options: keys of a configuration file (paths relative to the file's folder).
INPUT_KEYS = {
    "input": "path",
    "videos": "paths",
    "calibration": "path",
    "keypoints": "paths",
    "depth": "paths",
    "plates": "paths",
}
#: Keys of a configuration file about the run itself rather than the tracker.
RUN_KEYS = {"out": "path", "quiet": bool}


def option_types() -> dict[str, object]:
    """Type of each :class:`TrackOptions` field in a configuration file: ``int``, ``float``, ``bool``, ``str`` (the
    first type of the field's annotation: ``float | None`` is a float), ``"particles"`` (an integer or a list of
    integers) or ``"cues"``."""
    scalars = {"bool": bool, "int": int, "float": float}
    out = {}
    for f in dataclasses.fields(TrackOptions):
        if f.name in ("particles", "cues"):
            out[f.name] = f.name
        else:
            out[f.name] = scalars.get(str(f.type).split("|")[0].strip(), str)
    return out


def _checked(path, key: str, kind, value, base: str):
    """``value`` of ``key`` checked against ``kind`` (paths resolved against ``base``); one-line error naming the
    file otherwise."""

    def bad(what):
        return MocapInputError(path, f"{key!r} must be {what}, not {value!r}")

    if kind == "path":
        if not isinstance(value, str):
            raise bad("a path (a string)")
        return os.path.join(base, os.path.expanduser(value))
    if kind == "paths":
        if (
            isinstance(value, str)
            or not isinstance(value, list)
            or not all(isinstance(v, str) for v in value)
        ):
            raise bad("a list of paths")
        return [os.path.join(base, os.path.expanduser(v)) for v in value]
    if kind is bool:
        if not isinstance(value, bool):
            raise bad("true or false")
        return value
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad("an integer")
        return value
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise bad("a number")
        return float(value)
    if kind == "particles":
        ok = isinstance(value, int) and not isinstance(value, bool)
        ok = ok or (
            isinstance(value, list)
            and value
            and all(isinstance(v, int) and not isinstance(v, bool) for v in value)
        )
        if not ok:
            raise bad("an integer or a list of integers")
        return value
    if kind == "cues":
        if isinstance(value, str):
            return value
        if isinstance(value, list) and all(isinstance(v, str) for v in value):
            return ",".join(value)
        raise bad('a string like "foreground,edge_distance:2" or a list of such entries')
    if not isinstance(value, str):
        raise bad("a string")
    return value


def load_config(path: str | os.PathLike) -> dict:
    """A run's configuration file (TOML): any :class:`TrackOptions` field (``filter = "apf"``, ``particles =
    300``, ``cues = "foreground,coverage:4"`` …), the inputs (``input``, ``videos``, ``calibration``,
    ``keypoints``, ``depth``; relative paths are relative to the file's folder) and ``out``, ``quiet``. Returns
    the checked values; an unknown key or a value of the wrong type is a :class:`MocapInputError` naming the
    file (and the key)."""
    path = os.fspath(path)
    data = load_toml(path, "configuration")
    kinds = {**option_types(), **INPUT_KEYS, **RUN_KEYS}
    base = os.path.dirname(os.path.abspath(path))
    out = {}
    for key, value in data.items():
        if key not in kinds:
            raise MocapInputError(path, f"unknown option {key!r}; known: {', '.join(sorted(kinds))}")
        out[key] = _checked(path, key, kinds[key], value, base)
    return out


def dump_config(values: dict) -> str:
    """``values`` (options, inputs, ``out``) as the TOML of :func:`load_config` (None values left out, paths
    absolute), options first."""
    import tomli_w

    doc = {}
    for key, value in values.items():
        if value is None:
            continue
        kind = INPUT_KEYS.get(key) or RUN_KEYS.get(key)
        if kind == "path":
            value = os.path.abspath(os.fspath(value))
        elif kind == "paths":
            value = [os.path.abspath(os.fspath(v)) for v in value]
        elif isinstance(value, tuple):
            value = list(value)
        doc[key] = value
    return tomli_w.dumps(doc)
