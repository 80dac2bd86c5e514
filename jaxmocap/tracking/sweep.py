"""Experiment sweeps: sequences × filters × seeds, the seeds of each (sequence, filter) in one compiled call.

For each sequence the observations of all frames are built once on the host (the features of the tracker's setup,
:class:`~jaxmocap.tracking.setup.TrackSetup`: foreground, edges, silhouette samples) and stacked to leaves
``(T, ...)``; for each filter (:meth:`TrackSetup.make_filter <jaxmocap.tracking.setup.TrackSetup.make_filter>`: the
tracker's likelihood and per-model defaults) the ``B`` seeds run as one ``jit(vmap(lax.scan))`` (:func:`jaxmocap.filters.sharding.batched_run`) with the batch
axis sharded over the devices, so the runs are spread over every available device (CPU, GPUs, or all devices of
all hosts after ``jax.distributed.initialize``). Run ``b`` starts from ``filter.init(fold_in(key(seed_b), 1), x0,
spread · Δ)`` around the tracker's initial pose ``x0`` (``init``: ground truth, IK or a file) and filters with
``key(seed_b)``.

The runs are **open loop**: the filter step only, without the tracker's host-side additions (damped
constant-velocity prediction of the root, track-loss detection and re-initialisation, detection-driven proposal
centres — ICONDENSATION / IAPF draw from the dynamics and the prior only). They compare filters and seeds on
equal terms; ``jaxmocap track`` remains the way to track one sequence as well as possible.

The error of a run is the mean over its frames and the evaluation joints the model has of the 3D joint error
``1000 ‖p̂_j − p_j‖`` mm (:func:`jaxmocap.eval.metrics.joint_errors`) against the sequence's ground truth.

Spec file (TOML or JSON), every key optional except ``sequences``; command-line options override it::

    sequences = ["seq/walk", "seq/run"]
    filters = ["sir", "apf"]
    seeds = [0, 1, 2, 3]
    model = "upper9"         # the tracker's options: model, particles, layers, cues, frames, init,
    particles = 200          # foreground, downsample
    layers = 3
    devices = 2              # devices to spread the seeds over (default: all)
    chunk = 0                # likelihood chunk in particles (0: whole)
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import pathlib
import time
import tomllib
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.eval import metrics
from jaxmocap.filters import sharding as scale
from jaxmocap.geometry import body as body_mod
from jaxmocap.io import export
from jaxmocap.io.sources import BadFrame, SequenceSource
from jaxmocap.tracking.options import ANNEALED, FILTERS, TrackOptions
from jaxmocap.tracking.setup import TrackSetup

__all__ = ["COLUMNS", "SweepSpec", "load_spec", "parse_seeds", "run_sweep", "write_table"]

COLUMNS = (
    "sequence",
    "filter",
    "seed",
    "model",
    "particles",
    "layers",
    "frames",
    "mean_error_mm",
    "recovered_frames",
    "devices",
    "batch_wall_s",
)


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """What to run: every sequence × filter × seed (see the module docstring for the keys)."""

    sequences: tuple[str, ...]
    filters: tuple[str, ...] = ("apf",)
    seeds: tuple[int, ...] = (0,)
    model: str | None = None
    particles: int | None = None
    layers: int | None = None
    cues: str | None = None
    frames: str | None = None
    init: str = "auto"
    foreground: str = "auto"
    downsample: int = 1
    devices: int | None = None
    chunk: int = 0

    def __post_init__(self):
        if not self.sequences:
            raise ValueError("a sweep needs at least one sequence")
        if not self.filters or not self.seeds:
            raise ValueError("a sweep needs at least one filter and one seed")
        for f in self.filters:
            if f not in FILTERS:
                raise ValueError(f"unknown filter {f!r}; choose from {', '.join(FILTERS)}")
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError("the seeds must be distinct")
        if self.chunk < 0:
            raise ValueError("chunk must be ≥ 0")


def parse_seeds(spec: str | Sequence[int]) -> tuple[int, ...]:
    """``"0,1,5"``, ``"0:4"`` (= 0, 1, 2, 3) or a list of ints."""
    if not isinstance(spec, str):
        return tuple(int(s) for s in spec)
    try:
        if ":" in spec:
            a, b = spec.split(":")
            return tuple(range(int(a), int(b)))
        return tuple(int(s) for s in spec.split(",") if s.strip())
    except ValueError:
        raise ValueError(f"seeds must be 'A:B' or comma-separated integers, got {spec!r}") from None


def load_spec(path: str | pathlib.Path, **overrides) -> SweepSpec:
    """A :class:`SweepSpec` from a TOML or JSON file; ``overrides`` (not None) replace its entries."""
    path = pathlib.Path(path)
    try:
        text = path.read_text()
        data = json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)
    except (OSError, UnicodeDecodeError) as e:
        raise MocapInputError(path, f"cannot read: {e}") from None
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as e:
        raise MocapInputError(path, f"not a valid spec: {e}") from None
    known = {f.name for f in dataclasses.fields(SweepSpec)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise MocapInputError(path, f"unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    data.update({k: v for k, v in overrides.items() if v is not None})
    return make_spec(**data, where=path)


def make_spec(where=None, **kw) -> SweepSpec:
    """A :class:`SweepSpec` from loose values (lists, a seed string); errors name ``where``."""
    try:
        for k in ("sequences", "filters"):
            if k in kw:
                v = kw[k]
                kw[k] = tuple(v.split(",")) if isinstance(v, str) else tuple(str(x) for x in v)
        if "seeds" in kw:
            kw["seeds"] = parse_seeds(kw["seeds"])
        return SweepSpec(**kw)
    except (TypeError, ValueError) as e:
        raise MocapInputError(where, str(e)) from None


class _Prepared:
    """One sequence: its source, stacked observations ``(T, ...)``, initial pose and ground truth."""

    def __init__(self, path: str, spec: SweepSpec):
        self.path = path
        self.source = SequenceSource(path)
        if self.source.groundtruth is None:
            raise MocapInputError(path, "a sweep measures joint errors: the sequence needs groundtruth.npz")
        same = ("model", "particles", "layers", "cues", "frames", "init", "foreground", "downsample")
        self.options = TrackOptions(filter="apf", **{k: getattr(spec, k) for k in same})
        setup = TrackSetup(self.source, self.options)
        self.frames = setup.frames
        D = setup.model.num_dofs
        obs = []
        for t in self.frames:
            try:
                fd = self.source.read(t)
            except BadFrame as e:
                raise MocapInputError(path, f"frame {t}: {e} (a sweep needs every frame)") from None
            tobs, masks = setup.features(fd, D)
            if t == self.frames[0]:
                self.x0, self.spread, _ = setup.initial_state(t, masks, fd)
            obs.append(tobs)
        self.observations = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *obs)
        self.groundtruth = np.asarray(self.source.groundtruth)[self.frames]

    def setup_for(self, filter_name: str, layers: int | None) -> TrackSetup:
        """The setup of ``filter_name`` (its own layers, particles and likelihood schedule)."""
        return TrackSetup(self.source, dataclasses.replace(self.options, filter=filter_name, layers=layers))


def _mean_errors(model: body_mod.BodyModel, estimates: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """``(B,)`` mean joint errors (mm) of estimates ``(B, T, D)`` against ground-truth joints ``(T, 15, 3)``."""
    dt = model.offset.dtype
    joints = jax.jit(jax.vmap(jax.vmap(lambda x: body_mod.joint_positions(model, x))))(
        jnp.asarray(estimates, dt)
    )
    pred = export.eval_joints_of(model, np.asarray(joints, np.float64))  # (B, T, 15, 3), NaN where absent
    err = metrics.joint_errors(pred, gt[None])  # (B, T, 15)
    finite = np.isfinite(err)
    return np.where(finite, err, 0.0).sum(axis=(1, 2)) / np.maximum(finite.sum(axis=(1, 2)), 1)


def run_sweep(spec: SweepSpec, progress: Callable[[str], None] | None = None) -> list[dict]:
    """Run every sequence × filter × seed of ``spec``; one row (:data:`COLUMNS`) per run."""
    mesh = scale.device_mesh(spec.devices, scale.BATCH_AXIS)
    seeds = jnp.asarray(spec.seeds, jnp.uint32)
    keys = jax.vmap(jax.random.key)(seeds)
    init_keys = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
    rows = []
    for path in spec.sequences:
        prep = _Prepared(path, spec)
        for name in spec.filters:
            layers = spec.layers if name in ANNEALED else None
            tr = prep.setup_for(name, layers)
            filt = tr.make_filter(prep.x0)
            if spec.chunk:
                filt = scale.with_chunks(filt, spec.chunk)
            dt = tr.model.offset.dtype
            t0 = time.monotonic()
            states = scale.batched_init(
                filt, init_keys, jnp.asarray(prep.x0, dt), jnp.asarray(prep.spread * tr.std, dt)
            )
            _, info = scale.batched_run(filt, keys, states, prep.observations, mesh)
            est = np.asarray(jax.device_get(info.estimate))
            wall = time.monotonic() - t0
            errors = _mean_errors(tr.model, est, prep.groundtruth)
            recovered = (
                np.asarray(info.recovered).reshape(len(spec.seeds), len(prep.frames), -1).any(-1).sum(-1)
            )
            for b, seed in enumerate(spec.seeds):
                rows.append(
                    dict(
                        sequence=path,
                        filter=name,
                        seed=int(seed),
                        model=tr.model.name,
                        particles=tr.num_particles,
                        layers=tr.layers,
                        frames=f"{prep.frames[0]}:{prep.frames[-1] + 1}",
                        mean_error_mm=float(errors[b]),
                        recovered_frames=int(recovered[b]),
                        devices=mesh.size,
                        batch_wall_s=round(wall, 3),
                    )
                )
            if progress is not None:
                mean = float(np.mean(errors))
                progress(
                    f"{path} {name}: {len(spec.seeds)} seed(s) in {wall:.1f} s, mean error {mean:.1f} mm"
                )
    return rows


def _fmt(v) -> str:
    if isinstance(v, float):
        return "nan" if not math.isfinite(v) else f"{v:.1f}" if abs(v) >= 1 else f"{v:.3g}"
    return str(v)


def write_table(rows: list[dict], out: str | pathlib.Path) -> tuple[pathlib.Path, pathlib.Path]:
    """Write the rows as CSV to ``out`` and as a Markdown table (with a per-filter summary) next to it
    (``.md``). Returns both paths."""
    out = pathlib.Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    csv_path = out if out.suffix.lower() != ".md" else out.with_suffix(".csv")
    md_path = csv_path.with_suffix(".md")
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{r[k]:.6g}" if isinstance(r[k], float) else r[k]) for k in COLUMNS})
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(_fmt(r[k]) for k in COLUMNS) + " |" for r in rows]
    lines += [
        "",
        "| sequence | filter | seeds | mean error (mm) | std over seeds (mm) |",
        "|---|---|---|---|---|",
    ]
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["sequence"], r["filter"]), []).append(r["mean_error_mm"])
    for (s, f), e in groups.items():
        lines.append(f"| {s} | {f} | {len(e)} | {np.mean(e):.1f} | {np.std(e):.1f} |")
    md_path.write_text("\n".join(lines) + "\n")
    return csv_path, md_path
