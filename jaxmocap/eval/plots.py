"""Pictures of a tracking run without ground truth (``jaxmocap plot RUN``, also drawn at the end of every run):
matplotlib figures on the Agg canvas, saved as PNG in ``RUN/plots/``.

* ``trajectories.png`` — x, y and z (metres, z up) over time of the root, head, wrists and ankles the model has:
  the raw estimates of ``poses.npz`` thin, the exported track of ``poses_smoothed.npz`` (smoothed, gaps filled)
  thick, interpolated frames shaded.
* ``skeleton.png`` — the exported track's evaluation joints in 3D at six evenly spaced frames, bones of
  :data:`jaxmocap.eval.viz.SKELETON`, on equal axes (one box for all panels; the floor ``z = 0`` drawn when in view).
* ``quality.png`` — per frame, from ``diagnostics.jsonl``: the best particle's log-likelihood ``max_i log p(z | x_i)``
  of the last layer (``-quality``), the survival rate and the effective sample size of the last layer, and the
  frames where the track was lost (shaded), re-initialised (vertical lines) or skipped (crosses).
"""

from __future__ import annotations

import io
import json
import math
import os
import pathlib

import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.geometry.body import EVAL_JOINTS

__all__ = ["PLOTS", "plot_quality", "plot_run", "plot_skeleton", "plot_trajectories", "read_records"]

#: The folder of the pictures in a run folder.
PLOTS = "plots"
_TRAJECTORY_JOINTS = ("root", "head", "left_wrist", "right_wrist", "left_ankle", "right_ankle")
# fixed margins of the two 8 x 6 inch figures of three stacked panels, room for their labels and title
# (tight_layout measures every text first: about 0.3 s a figure)
_MARGINS = {"left": 0.11, "right": 0.98, "bottom": 0.08, "top": 0.94, "hspace": 0.3}


def _figure(size):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=100)
    FigureCanvasAgg(fig)
    return fig


def _stacked(fig, n: int = 3) -> list:
    """``n`` panels stacked on one time axis: its tick labels on the bottom panel only, at most five ticks on each
    value axis (every tick is a line and a text object to build and draw: most of a picture's time)."""
    from matplotlib.ticker import MaxNLocator

    axes = [fig.add_subplot(n, 1, 1)]
    axes += [fig.add_subplot(n, 1, k + 1, sharex=axes[0]) for k in range(1, n)]
    for ax in axes:
        ax.yaxis.set_major_locator(MaxNLocator(5))
    for ax in axes[:-1]:
        ax.tick_params(labelbottom=False)
    return axes


def _save(fig, path) -> None:
    """Save ``fig`` as PNG atomically (a torn picture is never left behind)."""
    from jaxmocap.io.export import atomic_write_bytes

    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write_bytes(path, buf.getvalue())


def _load(path: pathlib.Path) -> dict | None:
    if not path.is_file():
        return None
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError) as e:
        raise MocapInputError(path, f"cannot read: {e}") from None


def read_records(run: pathlib.Path) -> list[dict]:
    """The per-frame diagnostics records of a run: ``diagnostics.jsonl`` (a torn last line dropped), else the
    ``frames`` of ``diagnostics.json``, else none."""
    journal, doc = run / "diagnostics.jsonl", run / "diagnostics.json"
    if journal.is_file():
        out = []
        for line in journal.read_text(encoding="utf-8").splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                break
        return out
    if doc.is_file():
        try:
            return list(json.loads(doc.read_text(encoding="utf-8")).get("frames", []))
        except json.JSONDecodeError as e:
            raise MocapInputError(doc, f"cannot read: {e}") from None
    return []


def _gap_spans(ax, t: np.ndarray, mask: np.ndarray, colour: str, label: str | None) -> None:
    """Shade the runs of ``mask`` over the times ``t`` (half a frame either side)."""
    if not np.any(mask):
        return
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        ax.axvspan(t[a] - dt / 2, t[b - 1] + dt / 2, color=colour, alpha=0.25, lw=0, label=label)
        label = None


def plot_trajectories(raw: dict, smoothed: dict | None, path: str | os.PathLike) -> None:
    """``trajectories.png`` (module docstring) of ``poses.npz`` arrays ``raw`` and ``poses_smoothed.npz``."""
    fig = _figure((8.0, 6.0))
    axes = _stacked(fig)
    names = [n for n in _TRAJECTORY_JOINTS if np.any(np.isfinite(raw["joints"][:, EVAL_JOINTS.index(n)]))]
    colours = {n: f"C{k}" for k, n in enumerate(names)}
    for k, ax in enumerate(axes):
        for n in names:
            j = EVAL_JOINTS.index(n)
            style = {"lw": 0.8, "alpha": 0.6} if smoothed is not None else {"lw": 1.4}
            ax.plot(raw["time"], raw["joints"][:, j, k], color=colours[n], ls="-", **style)
            if smoothed is not None:
                ax.plot(smoothed["time"], smoothed["joints"][:, j, k], color=colours[n], lw=1.6,
                        label=n.replace("_", " "))  # fmt: skip
        if smoothed is not None:
            _gap_spans(
                ax, smoothed["time"], smoothed["interpolated"], "0.5", "interpolated" if k == 0 else None
            )
        ax.set_ylabel(f"{'xyz'[k]} (m)")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    how = f"smoothed ({smoothed['smooth']}) thick, raw thin" if smoothed is not None else "raw estimates"
    axes[0].set_title(f"joint trajectories: {how}", fontsize=10)
    handles, labels = axes[0].get_legend_handles_labels()
    if not handles:
        handles = [axes[0].lines[k] for k in range(len(names))]
        labels = [n.replace("_", " ") for n in names]
    axes[0].legend(handles, labels, loc="upper left", fontsize=7, ncol=4)
    fig.subplots_adjust(**_MARGINS)
    _save(fig, path)


def plot_skeleton(joints: np.ndarray, frames: np.ndarray, path: str | os.PathLike, count: int = 6) -> None:
    """``skeleton.png``: ``joints (T, 15, 3)`` at ``count`` evenly spaced rows, labelled by ``frames (T,)``."""
    from matplotlib.ticker import MaxNLocator

    from jaxmocap.eval.viz import SKELETON

    rows = np.unique(np.linspace(0, len(frames) - 1, min(count, len(frames))).round().astype(int))
    cols = min(3, len(rows))
    nrows = -(-len(rows) // cols)
    fig = _figure((3.2 * cols, 3.3 * nrows))
    P = joints[rows]
    ok = np.isfinite(P)
    lo = np.array([np.min(P[..., a][ok[..., a]], initial=np.inf) for a in range(3)])
    hi = np.array([np.max(P[..., a][ok[..., a]], initial=-np.inf) for a in range(3)])
    if not np.all(np.isfinite(lo)):  # nothing finite to show (a diverged track)
        lo, hi = np.full(3, -1.0), np.full(3, 1.0)
    centre, half = (lo + hi) / 2, max(float(np.max(hi - lo)) / 2, 0.5)
    for i, r in enumerate(rows):
        ax = fig.add_subplot(nrows, cols, i + 1, projection="3d")
        J = joints[r]
        for a, b in SKELETON:
            pa, pb = J[EVAL_JOINTS.index(a)], J[EVAL_JOINTS.index(b)]
            if np.all(np.isfinite(pa)) and np.all(np.isfinite(pb)):
                ax.plot(*np.stack([pa, pb]).T, color="tab:blue", lw=2)
        good = np.all(np.isfinite(J), axis=1)
        ax.scatter(*J[good].T, color="tab:red", s=8, depthshade=False)
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(centre[2] - half, centre[2] + half)
        if centre[2] - half <= 0.0:
            g = np.array([-half, half])
            X, Y = np.meshgrid(centre[0] + g, centre[1] + g)
            ax.plot_surface(X, Y, np.zeros_like(X), color="0.8", alpha=0.3, lw=0)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=15, azim=-60)
        ax.set_title(f"frame {int(frames[r])}", fontsize=9)
        ax.tick_params(labelsize=6, pad=0)
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.set_major_locator(MaxNLocator(4))
        for name in ("x", "y", "z"):
            getattr(ax, f"set_{name}label")(f"{name} (m)", fontsize=7, labelpad=-2)
    # fixed margins: the 3D axes fill their cells as tight_layout placed them, without its 0.4 s of measuring
    fig.subplots_adjust(left=0.02, right=0.98, bottom=0.03, top=0.93, wspace=0.15, hspace=0.2)
    _save(fig, path)


def plot_quality(records: list[dict], path: str | os.PathLike) -> None:
    """``quality.png`` (module docstring) of the diagnostics ``records``."""
    tracked = [r for r in records if not r.get("skipped") and "quality" in r]
    f = np.asarray([r["frame"] for r in tracked], np.float64)
    nan = lambda v: math.nan if v is None else float(v)
    loglik = np.asarray([-nan(r["quality"]) for r in tracked])
    last = [r["layers"][-1] if r.get("layers") else {} for r in tracked]
    survival = np.asarray([nan(s.get("survival_rate")) for s in last])
    ess = np.asarray([nan(s.get("ess")) for s in last])
    fig = _figure((8.0, 6.0))
    ax1, ax2, ax3 = _stacked(fig)
    ax1.plot(f, loglik, color="tab:blue", lw=1.2)
    ax1.set_ylabel("best log-likelihood", fontsize=8)
    ax2.plot(f, survival, color="tab:green", lw=1.2)
    ax2.set_ylim(0, 1.05)
    ax2.set_ylabel("survival rate", fontsize=8)
    ax3.plot(f, ess, color="tab:purple", lw=1.2)
    top = float(np.nanmax(ess)) if np.any(np.isfinite(ess)) else 1.0
    ax3.set_ylim(0, 1.1 * max(top, 1.0))  # a constant ESS (the APF's α·N) stays in view
    ax3.set_ylabel("effective sample size", fontsize=8)
    ax3.set_xlabel("frame")
    lost = np.asarray([bool(r.get("lost")) for r in tracked])
    reinit = [r["frame"] for r in tracked if r.get("reinitialised")]
    skipped = [r["frame"] for r in records if r.get("skipped")]
    for k, ax in enumerate((ax1, ax2, ax3)):
        _gap_spans(ax, f, lost, "tab:red", "track lost" if k == 0 else None)
        for j, t in enumerate(reinit):
            ax.axvline(t, color="tab:orange", lw=1.0, label="re-initialised" if k == 0 and j == 0 else None)
        if skipped:
            y = ax.get_ylim()[0]
            ax.plot(skipped, [y] * len(skipped), "kx", ms=5, label="skipped" if k == 0 else None)
        ax.grid(alpha=0.3)
    if ax1.get_legend_handles_labels()[0]:
        ax1.legend(loc="lower left", fontsize=7, ncol=3)
    summary = f"{int(lost.sum())} lost, {len(reinit)} re-initialisation(s), {len(skipped)} skipped"
    ax1.set_title(f"per-frame quality over {len(tracked)} tracked frames: {summary}", fontsize=10)
    fig.subplots_adjust(**_MARGINS)
    _save(fig, path)


def plot_run(run: str | os.PathLike, out: str | os.PathLike | None = None) -> list[pathlib.Path]:
    """Draw the three pictures of the run folder ``run`` into ``out`` (default ``run/plots``); returns their
    paths (the quality plot only when the run has diagnostics records of tracked frames). Raises
    :class:`MocapInputError` when ``run`` holds no ``poses.npz`` with a tracked frame."""
    run = pathlib.Path(run)
    raw = _load(run / "poses.npz")
    if raw is None or "joints" not in raw or len(raw["joints"]) == 0:
        raise MocapInputError(
            run, "holds no tracked frame (no poses.npz, or an empty one): not a tracking run"
        )
    raw.setdefault("time", raw["frame_index"] / float(raw.get("fps", 1.0)))
    smoothed = _load(run / "poses_smoothed.npz")
    if smoothed is not None:
        smoothed = {k: (str(v) if k == "smooth" else v) for k, v in smoothed.items()}
    folder = pathlib.Path(out) if out is not None else run / PLOTS
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / "trajectories.png", folder / "skeleton.png"]
    plot_trajectories(raw, smoothed, paths[0])
    best = smoothed if smoothed is not None else raw
    plot_skeleton(best["joints"], best["frame_index"], paths[1])
    records = read_records(run)
    if any("quality" in r for r in records):
        paths.append(folder / "quality.png")
        plot_quality(records, paths[-1])
    return paths
