"""Overlays of a tracked body model on its images (OpenCV) and plots of tracking errors (matplotlib, Agg).

Overlay geometry (:func:`overlay_geometry`, jitted once per model and rig): for each view, the occluding contours
of the model's flesh seen from that camera — the two silhouette generators of every truncated cone
(:func:`jaxmocap.geometry.flesh.cone_contours`) joined into a closed outline, and the contour of each ellipsoid
(:func:`jaxmocap.geometry.flesh.ellipsoid_contours`) — and the evaluation joints, projected with the calibration's lens
model (:func:`jaxmocap.geometry.camera.project`). :func:`draw_overlay` draws them with ``cv2.polylines`` / ``cv2.circle``;
:class:`OverlayVideo` writes one H.264 MP4 per view (PyAV) and a montage PNG.

Plots (:func:`plot_error_over_time`, :func:`plot_per_joint`) take a report of :func:`jaxmocap.eval.metrics.evaluate`
and use matplotlib's object API with the Agg canvas (no display, no global pyplot state).
"""

from __future__ import annotations

import contextlib
import os
import pathlib
from collections.abc import Mapping, Sequence

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.geometry import body as body_mod
from jaxmocap.geometry import camera, flesh
from jaxmocap.stored_programs import stored_jit

__all__ = [
    "SKELETON",
    "OverlayVideo",
    "draw_overlay",
    "overlay_geometry",
    "overlay_image",
    "person_crops",
    "plot_error_over_time",
    "plot_per_joint",
]

#: Bones drawn between evaluation joints (both ends must exist in the model).
SKELETON: tuple[tuple[str, str], ...] = (
    ("root", "thorax"),
    ("thorax", "head"),
    ("thorax", "left_shoulder"),
    ("left_shoulder", "left_elbow"),
    ("left_elbow", "left_wrist"),
    ("thorax", "right_shoulder"),
    ("right_shoulder", "right_elbow"),
    ("right_elbow", "right_wrist"),
    ("root", "left_hip"),
    ("left_hip", "left_knee"),
    ("left_knee", "left_ankle"),
    ("root", "right_hip"),
    ("right_hip", "right_knee"),
    ("right_knee", "right_ankle"),
)

# BGR colours
_FLESH = (80, 220, 80)
_BONE = (0, 220, 255)
_JOINT = (40, 40, 230)
_TRUTH = (255, 255, 255)


#: :func:`jaxmocap.geometry.camera.project` compiled: called per frame of an overlay video, eagerly it would
#: dispatch its ~40 operations one by one
_project = jax.jit(camera.project)


def _own_view(rig: camera.Rig, Q: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Project ``Q (V, M, 3)`` — view ``v``'s points through camera ``v`` — to ``uv (V, M, 2)``, depth ``(V, M)``."""
    uv, z = camera.project_with_depth(rig, Q)  # (V_pts, V_cam, M, ...)
    uv = jnp.moveaxis(jnp.diagonal(uv, axis1=0, axis2=1), -1, 0)
    z = jnp.moveaxis(jnp.diagonal(z, axis1=0, axis2=1), -1, 0)
    return uv, z


@stored_jit(static_argnames=("k",))
def overlay_geometry(model: body_mod.BodyModel, rig: camera.Rig, x: jnp.ndarray, k: int = 10) -> dict:
    """Projected outline of the model in state ``x (D,)`` in every view.

    Returns a dict of arrays: ``cones (V, C, 2k, 2)`` closed outlines (generator 0 then generator 1 reversed),
    ``cones_z (V, C, 2k)`` their camera depths, ``ellipses (V, E, 2k, 2)`` / ``ellipses_z``, ``joints (V, J, 2)``
    / ``joints_z (V, J)`` (``model.joint_names`` order).
    """
    R, t = body_mod.segment_poses(model, x)
    p = flesh.world_primitives(model, R, t)
    centres = camera.camera_centres(rig)
    V = centres.shape[0]
    out = {}
    if p.num_cones:
        gen = jax.vmap(lambda c: flesh.cone_contours(p.cone_a, p.cone_b, p.r_a, p.r_b, c, k))(centres)
        loop = jnp.concatenate([gen[:, :, 0], gen[:, :, 1, ::-1]], axis=2)  # (V, C, 2k, 3)
        C = loop.shape[1]
        uv, z = _own_view(rig, loop.reshape(V, -1, 3))
        out["cones"], out["cones_z"] = uv.reshape(V, C, 2 * k, 2), z.reshape(V, C, 2 * k)
    else:
        out["cones"], out["cones_z"] = jnp.zeros((V, 0, 2 * k, 2)), jnp.zeros((V, 0, 2 * k))
    if p.num_ellipsoids:
        ell = jax.vmap(lambda c: flesh.ellipsoid_contours(p.ell_centre, p.ell_axes, c, 2 * k))(centres)
        E = ell.shape[1]
        uv, z = _own_view(rig, ell.reshape(V, -1, 3))
        out["ellipses"], out["ellipses_z"] = uv.reshape(V, E, 2 * k, 2), z.reshape(V, E, 2 * k)
    else:
        out["ellipses"], out["ellipses_z"] = jnp.zeros((V, 0, 2 * k, 2)), jnp.zeros((V, 0, 2 * k))
    J = body_mod.joint_positions(model, x)
    out["joints"], out["joints_z"] = camera.project_with_depth(rig, J)
    return out


def _pts(uv: np.ndarray, scale: int) -> np.ndarray:
    return np.round(np.asarray(uv, np.float64) * scale).astype(np.int32)


def draw_overlay(
    image: np.ndarray,
    geometry: Mapping[str, np.ndarray],
    view: int,
    joint_names: Sequence[str],
    truth: np.ndarray | None = None,
    thickness: int = 1,
) -> np.ndarray:
    """Draw the outline, bones and joints of :func:`overlay_geometry` (one view) on a BGR ``uint8`` image (a copy).

    ``truth``: optional ground-truth evaluation joints of this view ``(15, 2)`` pixels (NaN = absent), drawn as
    white crosses. Sub-pixel positions are drawn with OpenCV's fixed-point ``shift`` of 4 bits.
    """
    img = np.ascontiguousarray(image).copy()
    shift, s = 4, 16
    g = {key: np.asarray(v) for key, v in geometry.items()}
    for key in ("cones", "ellipses"):
        for outline, z in zip(g[key][view], g[f"{key}_z"][view], strict=True):
            if np.all(z > 0) and np.all(np.isfinite(outline)):
                cv2.polylines(img, [_pts(outline, s)], True, _FLESH, thickness, cv2.LINE_AA, shift)
    uv, z = g["joints"][view], g["joints_z"][view]
    index = {n: i for i, n in enumerate(joint_names)}
    for a, b in SKELETON:
        if a in index and b in index and z[index[a]] > 0 and z[index[b]] > 0:
            pa, pb = _pts(uv[index[a]], s), _pts(uv[index[b]], s)
            cv2.line(
                img,
                tuple(int(v) for v in pa),
                tuple(int(v) for v in pb),
                _BONE,
                thickness,
                cv2.LINE_AA,
                shift,
            )
    r = max(2, round(img.shape[1] / 200))
    for i in range(len(joint_names)):
        if z[i] > 0 and np.all(np.isfinite(uv[i])):
            c = tuple(int(v) for v in _pts(uv[i], s))
            cv2.circle(img, c, r * s, _JOINT, -1, cv2.LINE_AA, shift)
    if truth is not None:
        for p in np.asarray(truth):
            if np.all(np.isfinite(p)):
                c = tuple(int(v) for v in np.round(p).astype(int))
                cv2.drawMarker(img, c, _TRUTH, cv2.MARKER_CROSS, 2 * r + 2, 1)
    return img


def overlay_image(
    images: Sequence[np.ndarray],
    model: body_mod.BodyModel,
    rig: camera.Rig,
    x: np.ndarray,
    truth_joints: np.ndarray | None = None,
) -> list[np.ndarray]:
    """The overlay of state ``x (D,)`` on every view's BGR image; ``truth_joints (15, 3)`` metres (optional)."""
    g = overlay_geometry(model, rig, jnp.asarray(x, model.offset.dtype))
    truth_uv = None
    if truth_joints is not None:
        t = np.asarray(truth_joints, np.float64)
        ok = np.all(np.isfinite(t), axis=-1)
        uv = np.asarray(_project(rig, jnp.asarray(np.where(ok[:, None], t, 0.0), jnp.float32)))
        truth_uv = np.where(ok[None, :, None], uv, np.nan)
    return [
        draw_overlay(im, g, v, model.joint_names, None if truth_uv is None else truth_uv[v])
        for v, im in enumerate(images)
    ]


def person_crops(
    images: Sequence[np.ndarray], rig: camera.Rig, joints: np.ndarray, height: int = 360, margin: float = 0.25
) -> list[np.ndarray]:
    """Crop every view around the projection of ``joints (J, 3)`` (metres; NaN rows ignored) — their bounding box
    grown by ``margin`` of its height on every side, widened to at least 0.6 of its height — and resize the crops
    to ``height`` pixels (bicubic)."""
    J = np.asarray(joints, np.float64)
    J = J[np.all(np.isfinite(J), axis=1)]
    uv = np.asarray(_project(rig, jnp.asarray(J, jnp.float32)), np.float64)  # (V, J, 2)
    out = []
    for v, im in enumerate(images):
        h_img, w_img = im.shape[:2]
        (u0, v0), (u1, v1) = uv[v].min(axis=0), uv[v].max(axis=0)
        bh = max(v1 - v0, 1.0)
        pad = margin * bh
        cu, half_w = 0.5 * (u0 + u1), max(0.5 * (u1 - u0) + pad, 0.3 * (bh + 2 * pad))
        x0, x1 = int(max(0, np.floor(cu - half_w))), int(min(w_img, np.ceil(cu + half_w)))
        y0, y1 = int(max(0, np.floor(v0 - pad))), int(min(h_img, np.ceil(v1 + pad)))
        crop = im[y0:y1, x0:x1]
        scale = height / max(crop.shape[0], 1)
        out.append(
            cv2.resize(crop, (max(1, round(crop.shape[1] * scale)), height), interpolation=cv2.INTER_CUBIC)
        )
    return out


class OverlayVideo:
    """One H.264 MP4 per view (``overlay_<view>.mp4`` in ``out``) that browsers, VS Code and Jupyter play, and a
    montage PNG (``overlay_montage.png``) of evenly spaced frames; :meth:`write` adds a frame of every view.

    Encoding (PyAV, FFmpeg's ``libx264``): ``yuv420p`` (odd image sizes padded by one edge pixel), CRF 20, the
    frame rate as a fraction, ``movflags=+faststart`` (the index at the front, so a browser starts playing before
    the download ends). Each video is written to a temporary file in ``out`` and moved into place on
    :meth:`close` (a killed run leaves no torn MP4).

    Montage: with ``montage`` frames asked for, a thumbnail of every ``stride``-th frame is kept (the stride
    doubles whenever more than ``2 · montage`` are kept) and :meth:`close` writes ``montage`` of them, evenly
    spaced: one row per view, one column per frame, each a :func:`person_crops` crop (around the ``joints`` given
    to :meth:`write`, or the whole image) ``montage_height`` pixels high, labelled with the frame number.
    """

    def __init__(
        self,
        out: str | os.PathLike,
        view_names: Sequence[str],
        sizes: Sequence[tuple[int, int]],
        fps: float,
        rig: camera.Rig | None = None,
        montage: int = 6,
        montage_height: int = 240,
    ):
        import fractions

        import av

        self.out = pathlib.Path(out)
        self.paths = [self.out / f"overlay_{name}.mp4" for name in view_names]
        self.montage_path = self.out / "overlay_montage.png"
        self.rig, self.montage, self.montage_height = rig, int(montage), int(montage_height)
        self._thumbs: list[tuple[int, int, list[np.ndarray]]] = []  # (count, label, crops)
        self._stride, self._count = 1, 0
        rate = fractions.Fraction(float(fps)).limit_denominator(1001)
        self._tmp, self._containers, self._streams = [], [], []
        try:
            for p, (w, h) in zip(self.paths, sizes, strict=True):
                tmp = self.out / f".{p.name}.tmp"
                c = av.open(os.fspath(tmp), mode="w", format="mp4", options={"movflags": "+faststart"})
                self._tmp.append(tmp)
                self._containers.append(c)
                st = c.add_stream("libx264", rate=rate)
                st.width, st.height = int(w) + int(w) % 2, int(h) + int(h) % 2
                st.pix_fmt = "yuv420p"
                st.options = {"crf": "20", "preset": "medium"}
                self._streams.append(st)
        except BaseException:
            self._abort()
            raise

    def write(
        self, images: Sequence[np.ndarray], joints: np.ndarray | None = None, frame: int | None = None
    ) -> None:
        """Add one frame: BGR ``uint8`` images of every view; ``joints (J, 3)`` metres (NaN rows ignored) for the
        montage crops; ``frame`` its number on the montage (default: the count of frames written before)."""
        import av

        for c, st, im in zip(self._containers, self._streams, images, strict=True):
            im = np.ascontiguousarray(im)
            pad_h, pad_w = st.height - im.shape[0], st.width - im.shape[1]
            if pad_h or pad_w:
                im = cv2.copyMakeBorder(im, 0, pad_h, 0, pad_w, cv2.BORDER_REPLICATE)
            for packet in st.encode(av.VideoFrame.from_ndarray(im, format="bgr24")):
                c.mux(packet)
        if self.montage > 0 and self._count % self._stride == 0:
            label = self._count if frame is None else int(frame)
            self._thumbs.append((self._count, label, self._thumbnails(images, joints)))
            if len(self._thumbs) > 2 * self.montage:
                self._stride *= 2
                self._thumbs = [t for t in self._thumbs if t[0] % self._stride == 0]
        self._count += 1

    def _thumbnails(self, images, joints) -> list[np.ndarray]:
        if joints is not None and self.rig is not None and np.any(np.all(np.isfinite(joints), axis=-1)):
            return person_crops(images, self.rig, joints, self.montage_height)
        h = self.montage_height
        return [cv2.resize(im, (max(1, round(im.shape[1] * h / im.shape[0])), h), interpolation=cv2.INTER_AREA)
                for im in images]  # fmt: skip

    def _write_montage(self) -> None:
        from jaxmocap.io.export import atomic_write_bytes

        if not self._thumbs:
            return
        pick = np.unique(np.linspace(0, len(self._thumbs) - 1, min(self.montage, len(self._thumbs))).round())
        chosen = [self._thumbs[int(k)] for k in pick]
        rows = []
        for v in range(len(chosen[0][2])):
            cells = []
            for _, frame, crops in chosen:
                cell = crops[v].copy()
                cv2.putText(cell, f"{frame}", (6, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2,
                            cv2.LINE_AA)  # fmt: skip
                cells.append(cell)
            rows.append(np.concatenate(cells, axis=1))
        width = max(r.shape[1] for r in rows)
        rows = [cv2.copyMakeBorder(r, 0, 0, 0, width - r.shape[1], cv2.BORDER_CONSTANT) for r in rows]
        ok, png = cv2.imencode(".png", np.concatenate(rows, axis=0), [cv2.IMWRITE_PNG_COMPRESSION, 9])
        if ok:
            atomic_write_bytes(self.montage_path, png.tobytes())

    def _abort(self) -> None:
        for c in self._containers:
            with contextlib.suppress(Exception):
                c.close()
        for tmp in self._tmp:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        self._containers = []

    def close(self) -> None:
        """Flush the encoders, move the videos into place and write the montage."""
        if not self._containers:
            return
        try:
            for c, st in zip(self._containers, self._streams, strict=True):
                for packet in st.encode():
                    c.mux(packet)
                c.close()
            for tmp, p in zip(self._tmp, self.paths, strict=True):
                os.replace(tmp, p)
        except BaseException:
            self._abort()
            raise
        self._containers = []
        self._write_montage()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        if exc_type is None:
            self.close()
        else:
            self._abort()


# ---------------------------------------------------------------------------------------------------------------
# Plots


def _figure(size=(7.0, 3.5)):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=100)
    FigureCanvasAgg(fig)
    return fig


def plot_error_over_time(report: Mapping, path: str | os.PathLike, title: str | None = None) -> None:
    """Average error per frame (mm) over the frames of a :func:`jaxmocap.eval.metrics.evaluate` report: each run thin,
    the mean over runs thick with ± one standard deviation over runs shaded, the overall mean dashed."""
    frames = np.asarray(report["frame_index"], np.float64)
    mean = np.asarray([np.nan if v is None else v for v in report["per_frame_mm"]], np.float64)
    std = np.asarray([np.nan if v is None else v for v in report["per_frame_std_mm"]], np.float64)
    fig = _figure()
    ax = fig.add_subplot(1, 1, 1)
    runs = report["thesis"]["eq7_1_per_frame_mm"]
    if len(runs) > 1:
        for row in runs:
            ax.plot(frames, [np.nan if v is None else v for v in row], lw=0.6, alpha=0.5, color="0.5")
        ax.fill_between(frames, mean - std, mean + std, color="tab:blue", alpha=0.2, lw=0)
    ax.plot(frames, mean, color="tab:blue", lw=1.6, label="average error per frame")
    ax.axhline(report["overall_mean_mm"], color="tab:red", ls="--", lw=1.0, label="overall average")
    ax.set_xlabel("frame")
    ax.set_ylabel("error (mm)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(title or f"3D joint error over time ({report['num_runs']} run(s))", fontsize=10)
    fig.tight_layout()
    fig.savefig(os.fspath(path))


def plot_per_joint(report: Mapping, path: str | os.PathLike, title: str | None = None) -> None:
    """Joint average error (mm) as bars with ± one standard deviation (over runs and frames)."""
    names = [n for n in report["joint_names"] if report["per_joint_mm"][n] is not None]
    mean = [report["per_joint_mm"][n] for n in names]
    std = [report["per_joint_std_mm"][n] for n in names]
    fig = _figure((7.0, 3.8))
    ax = fig.add_subplot(1, 1, 1)
    x = np.arange(len(names))
    ax.bar(x, mean, yerr=std, color="tab:blue", alpha=0.8, capsize=2, error_kw={"lw": 0.8})
    ax.set_xticks(x)
    ax.set_xticklabels([n.replace("_", " ") for n in names], rotation=60, ha="right", fontsize=8)
    ax.set_ylabel("error (mm)")
    ax.grid(axis="y", alpha=0.3)
    ax.set_title(title or f"joint average error (overall {report['overall_mean_mm']:.0f} mm)", fontsize=10)
    fig.tight_layout()
    fig.savefig(os.fspath(path))
