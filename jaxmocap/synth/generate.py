"""Synthetic multi-view sequences from real motion capture, with exact ground truth.

The clip may use any skeleton: :func:`load_clip` recognises its evaluation joints, unit and up axis
(:mod:`jaxmocap.io.skeletons`). The subject is the **mocap skeleton itself**, dressed (:mod:`jaxmocap.synth.dressing`):
cones with spherical caps for the bones, a spheroid head, clothing colours per limb and skin-coloured head, neck
and hands. A tracker's body model (the ``body.toml`` written with the sequence, the ``full25`` preset with the
subject's measured lengths and these radii) is an approximation of that scene.

Every view is ray-cast exactly per pixel (:func:`jaxmocap.geometry.render.render_view`), so depth, foreground mask and
part labels agree with the calibration's projection model; then, on the host, Lambert shading under a world
light, compositing over a real photograph or procedural clutter, an optional global illumination change, motion
blur (the mean of renders at consecutive mocap frames), Gaussian sensor noise, and Li & Kulić's virtual depth
sensor (front-surface depth, smoothed inside the silhouette, Gaussian noise of ``depth_noise`` metres, 16-bit
millimetres; :func:`jaxmocap.geometry.render.virtual_depth`).

Rigs and backgrounds: :mod:`jaxmocap.synth.stage`. A face and hair on the head (default), bare forearms
(``sleeves="short"``) and wrist bands: :mod:`jaxmocap.synth.appearance`.

Each view also gets its empty-scene plate (:mod:`jaxmocap.synth.plates`, ``views/<camera>/background.png``) and
simulated OpenPose BODY_25B detections per frame (:mod:`jaxmocap.synth.detections`, ``views/<camera>/openpose/``),
marked as simulated in ``meta.json``.

Determinism: every random number comes from ``numpy.random.default_rng([seed, frame, view])`` (a stream per
output image, independent of the order of work), ``default_rng([seed, frame, view, 2])`` for its simulated
detections, ``default_rng([seed, view])`` for a view's background and ``default_rng([seed, 2²⁰, view, 3])`` for its
plate's noise, and every file is written byte-identically
(:mod:`jaxmocap.io.sequence`).
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib
import shutil
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from importlib import resources

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap import __version__
from jaxmocap.choices import parse_frames
from jaxmocap.errors import MocapInputError
from jaxmocap.geometry import body as body_mod
from jaxmocap.geometry import camera, render
from jaxmocap.io import calibration, skeletons
from jaxmocap.io import sequence as seqio
from jaxmocap.io.mocap import JointSpec, Motion, eval_joints, forward_kinematics
from jaxmocap.synth import appearance, plates, texture
from jaxmocap.synth import detections as dets
from jaxmocap.synth import scene as room_mod
from jaxmocap.synth.dressing import (
    HEAD_LENGTH,
    HEAD_RADIUS,
    ROLE_COLOURS,
    ROLE_RADII,
    Dressing,
    body_dimensions,
    dress,
    dressing_points,
    scene_primitives,
    toe_points,
)

# the rig and background functions stay part of this module's API (__all__)
from jaxmocap.synth.stage import (
    PRESETS,
    background_image,
    look_at,
    place_motion,
    preset_rig,
    subject_frame,
)

__all__ = [
    "PRESETS",
    "ROLE_RADII",
    "ROLE_COLOURS",
    "HEAD_LENGTH",
    "HEAD_RADIUS",
    "Dressing",
    "demo_clip",
    "load_motion",
    "load_clip",
    "dress",
    "dressing_points",
    "scene_primitives",
    "subject_frame",
    "look_at",
    "preset_rig",
    "place_motion",
    "background_image",
    "parse_frames",
    "parse_size",
    "parse_clutter",
    "view_images",
    "body_dimensions",
    "synthesize",
    "CAPS",
    "LIGHT",
    "CMU_LICENCE",
    "BANDAI_LICENCE",
    "default_licence",
]

#: Rendered cones have spherical caps (rounded limbs without gaps at bent joints).
CAPS = "sphere"

#: Light direction in the subject's frame ``(f̂, l̂, ẑ)`` (in front, to its left, above) and ambient term.
LIGHT = (0.4, 0.3, 1.0)
AMBIENT = 0.35

#: Period (seconds) of the global illumination change.
ILLUMINATION_PERIOD = 4.0

_DEMO = ("02_01.amc", "02.asf")


# ---------------------------------------------------------------------------------------------------------------
# Motion input


def demo_clip() -> tuple[pathlib.Path, pathlib.Path]:
    """The bundled CMU clip (subject 2, trial 1: a walk; ASF/AMC, 120 fps): ``(amc path, asf path)``."""
    base = resources.files("jaxmocap") / "data" / "mocap"
    return pathlib.Path(str(base / _DEMO[0])), pathlib.Path(str(base / _DEMO[1]))


def _find_asf(amc: pathlib.Path) -> pathlib.Path:
    """The skeleton of a CMU ``SS_TT.amc``: ``SS.asf`` next to it, else the only ``.asf`` in its folder."""
    guess = amc.with_name(amc.stem.split("_")[0] + ".asf")
    if guess.is_file():
        return guess
    found = sorted(amc.parent.glob("*.asf"))
    if len(found) == 1:
        return found[0]
    raise MocapInputError(amc, "cannot tell which .asf skeleton goes with this .amc motion: pass it (--asf)")


def load_clip(
    path: str | os.PathLike | Motion,
    asf: str | os.PathLike | None = None,
    scale: float | None = None,
    mapping: Mapping[str, JointSpec] | str | os.PathLike | None = None,
    up_axis: str | None = None,
) -> tuple[Motion, skeletons.Recognition]:
    """A clip of any skeleton, recognised and normalised (:func:`jaxmocap.io.skeletons.load_mocap`):
    ``(motion, recognition)``.

    ``path``: a ``.bvh`` file, an ``.amc`` file with its ``asf`` skeleton (found next to it when not given),
    ``"demo"`` (:func:`demo_clip`) or a :class:`~jaxmocap.io.mocap.Motion` (recognised and normalised as it is);
    ``scale`` metres per file unit and ``up_axis`` are detected for a BVH unless given; ``mapping`` (a mapping
    or a TOML file) names evaluation joints the names and the tree's shape would not place."""
    if isinstance(path, Motion):
        given = skeletons.load_mapping(mapping) if isinstance(mapping, str | os.PathLike) else mapping
        try:
            rec = skeletons.recognise(path, given)
            return skeletons.normalise(path, rec.mapping), rec
        except ValueError as e:
            raise MocapInputError(path.source or None, str(e)) from None
    if os.fspath(path) == "demo" and not os.path.isfile("demo"):
        path, default_asf = demo_clip()
        asf = default_asf if asf is None else asf
    p = pathlib.Path(path)
    if not p.is_file():
        raise MocapInputError(p, "no such motion file")
    ext = p.suffix.lower()
    if ext == ".amc" and asf is None:
        asf = _find_asf(p)
    if ext not in (".bvh", ".amc"):
        raise MocapInputError(p, f"unknown motion format {ext!r} (expected .bvh or .amc with an .asf)")
    return skeletons.load_mocap(p, asf=asf, scale=scale, up_axis=up_axis, mapping=mapping)


def load_motion(
    path: str | os.PathLike | Motion, asf: str | os.PathLike | None = None, scale: float | None = None
) -> Motion:
    """The motion of :func:`load_clip` (a :class:`~jaxmocap.io.mocap.Motion` is returned as it is)."""
    if isinstance(path, Motion):
        return path
    return load_clip(path, asf, scale)[0]


# ---------------------------------------------------------------------------------------------------------------
# Options


def parse_size(spec: str | tuple[int, int]) -> tuple[int, int]:
    """``"WxH"`` → ``(w, h)``."""
    if isinstance(spec, str):
        try:
            w, h = (int(s) for s in spec.lower().split("x"))
        except ValueError:
            raise ValueError(f"size must be WxH, got {spec!r}") from None
    else:
        w, h = (int(s) for s in spec)
    if not (8 <= w <= 8192 and 8 <= h <= 8192):
        raise ValueError(f"image size {w}x{h} out of range")
    return w, h


_CLUTTER_LEVELS = {"none": 0.0, "low": 0.3, "medium": 0.6, "high": 1.0}


def parse_clutter(level: str | float) -> float:
    """``none``/``low``/``medium``/``high`` or a number in [0, 1]."""
    if isinstance(level, str) and level.lower() in _CLUTTER_LEVELS:
        return _CLUTTER_LEVELS[level.lower()]
    try:
        x = float(level)
    except ValueError:
        raise ValueError(
            f"clutter must be none, low, medium, high or a number in [0, 1], got {level!r}"
        ) from None
    if not 0.0 <= x <= 1.0:
        raise ValueError(f"clutter must lie in [0, 1], got {x}")
    return x


# ---------------------------------------------------------------------------------------------------------------
# The generator


@jax.jit
def _form_image(normal, label, colours, light, background, illumination, ambient):
    """Lambert shading composited over the background, under a global illumination factor (the formula of
    :func:`jaxmocap.geometry.render.shade` / :func:`jaxmocap.geometry.render.composite`, fused in one XLA loop):
    ``I = clip(a · colour[label] · (ambient + (1 − ambient) max(0, n·l̂)), 0, 1)`` on the body and
    ``clip(a · background, 0, 1)`` elsewhere. ``normal (H, W, 3)`` camera frame, ``label (H, W)``, ``colours
    (L, 3)`` per label or ``(H, W, 3)`` per pixel (a textured albedo), ``light (3,)`` unit in the camera frame,
    ``background (H, W, 3)`` in [0, 1]. Returns float32 ``(H, W, 3)`` in [0, 1]."""
    lam = jnp.maximum(normal[..., 0] * light[0] + normal[..., 1] * light[1] + normal[..., 2] * light[2], 0.0)
    col = colours if colours.ndim == 3 else colours[jnp.maximum(label, 0)]
    fg = illumination * col * (ambient + (1.0 - ambient) * lam)[..., None]
    out = jnp.where((label >= 0)[..., None], fg, illumination * background)
    return jnp.clip(out, 0.0, 1.0).astype(jnp.float32)


def _quantise(image: np.ndarray) -> np.ndarray:
    """Round a float image in 8-bit units to uint8 with saturation."""
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def view_images(
    rng: np.random.Generator,
    renders: Sequence[render.Render],
    colours: jnp.ndarray,
    light: jnp.ndarray,
    background: jnp.ndarray,
    illumination: float = 1.0,
    noise: float = 0.01,
    depth_smooth: float = 1.5,
    depth_noise: float = 0.02,
    albedos: Sequence[jnp.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The images of one view at one frame from its ray-cast renders.

    Args:
      rng: the image's generator (sensor noise, then depth noise).
      renders: one :class:`jaxmocap.geometry.render.Render` per motion-blur sub-frame, the frame's own first.
      colours: ``(L, 3)`` label colours; light: ``(3,)`` unit light direction in the camera frame;
      background: ``(H, W, 3)`` float in [0, 1]; illumination: global illumination factor.
      noise: RGB noise standard deviation (1 = full scale); depth_smooth, depth_noise: the virtual depth sensor
        (:func:`jaxmocap.geometry.render.virtual_depth`).
      albedos: per render a ``(H, W, 3)`` albedo replacing ``colours`` (textured clothing).

    Returns:
      ``rgb (H, W, 3)`` uint8 — the mean of the sub-frames' shaded images plus ``N(0, noise²)``, rounded —,
      ``depth (H, W)`` uint16 millimetres and ``labels (H, W)`` int32 (−1 background) of the first render.
    """
    image = None
    for k, r in enumerate(renders):
        col = colours if albedos is None else albedos[k]
        img = _form_image(r.normal, r.label, col, light, background, illumination, AMBIENT)
        image = img if image is None else image + img
    image = np.asarray(image) * np.float32(255.0 / len(renders))
    rgb8 = _quantise(image + rng.standard_normal(image.shape, dtype=np.float32) * np.float32(255.0 * noise))
    first = renders[0]
    depth_mm = render.virtual_depth(rng, np.asarray(first.depth), depth_smooth, depth_noise)
    return rgb8, depth_mm, np.asarray(first.label)


#: Licence line recorded for a clip of a CMU skeleton: the CMU database's acknowledgement.
CMU_LICENCE = (
    "CMU Graphics Lab Motion Capture Database (mocap.cs.cmu.edu), free for research and commercial use, not for "
    "resale: 'The data used in this project was obtained from mocap.cs.cmu.edu. The database was created with "
    "funding from NSF EIA-0196217.'"
)


#: Licence line recorded for a clip of the Bandai-Namco research set.
BANDAI_LICENCE = "Bandai Namco Research Motion Dataset, CC BY-NC 4.0 (non-commercial use, attribution)"


def default_licence(family: str) -> str:
    """The licence line of a clip whose skeleton was recognised as ``family`` (:mod:`jaxmocap.io.skeletons`):
    the CMU terms, the Bandai-Namco set's, or a request to state it."""
    passes = family.split("+")
    if any(p.startswith("cmu") for p in passes):
        return CMU_LICENCE
    if "bandai_namco" in passes:
        return BANDAI_LICENCE
    return "not stated (pass --licence)"


def detections_path(root: str | os.PathLike, view: str, frame: int) -> pathlib.Path:
    """``root/views/<view>/openpose/<view>_NNNNNNNNNNNN_keypoints.json`` (OpenPose's own naming), folder created."""
    folder = pathlib.Path(root) / seqio.VIEWS / view / "openpose"
    folder.mkdir(parents=True, exist_ok=True)
    return folder / f"{view}_{int(frame):012d}_keypoints.json"


def _clothing(
    m: Motion, dressing: Dressing, colours, seed: int, offset: np.ndarray, cams: camera.Rig, bare=()
):
    """``albedo(render, view, source frame) -> (H, W, 3)`` of :mod:`jaxmocap.synth.texture` for this clip; the
    body parts ``bare`` get the skin's texture."""
    W, X = forward_kinematics(m.parents, m.translations(), m.local_rotations)
    X = X + offset
    J = m.num_joints
    joint_of, axes = [], []
    for c in dressing.bones:  # the joint that carries each cone, and the cone's direction in its frame
        p = dressing.parents[c]
        joint_of.append(p)
        axes.append(m.offsets[c] if c < J else m.end_offsets[c - J])
    hj, he = dressing.head_bone
    joint_of.append(hj)
    axes.append(m.offsets[he] if he < J else m.end_offsets[he - J])
    waves, phases, amps = (
        jnp.asarray(a, jnp.float32)
        for a in texture.texture_waves(dressing.part_roles, np.asarray(axes), seed, bare)
    )
    rays = [
        jnp.asarray(render.pixel_rays(cams.K[v], cams.dist[v], cams.image_size[v]))
        for v in range(cams.num_views)
    ]
    Rv = [jnp.asarray(cams.R[v], jnp.float32) for v in range(cams.num_views)]
    tv = [jnp.asarray(cams.t[v], jnp.float32) for v in range(cams.num_views)]
    idx = np.asarray(joint_of)

    def albedo(r: render.Render, v: int, frame: int) -> jnp.ndarray:
        fr = jnp.asarray(W[frame, idx], jnp.float32)
        fx = jnp.asarray(X[frame, idx], jnp.float32)
        return texture.textured_albedo(
            r.depth, r.label, rays[v], Rv[v], tv[v], fr, fx, colours, waves, phases, amps
        )

    return albedo


def _appearance(
    m: Motion,
    dressing: Dressing,
    points: np.ndarray,
    ej: np.ndarray,
    cams: camera.Rig,
    face: bool,
    bands: bool,
):
    """``decorate(albedo, render, view, source frame) -> (H, W, 3)``: the face and wrist bands of
    :mod:`jaxmocap.synth.appearance` drawn over a clothing albedo. ``points (T, P, 3)`` the dressing's points and
    ``ej (T, 15, 3)`` the evaluation joints, both in the world, at every source frame."""
    W, _ = forward_kinematics(m.parents, m.translations(), m.local_rotations)
    ev = {n: k for k, n in enumerate(body_mod.EVAL_JOINTS)}
    h0, h1 = dressing.head_points
    axes = points[:, h1] - points[:, h0]
    hips = ej[:, ev["left_hip"]] - ej[:, ev["right_hip"]]
    frames = appearance.head_frames(W[:, dressing.head_bone[0]], np.cross(hips, [0.0, 0.0, 1.0]), axes)
    centres = 0.5 * (points[:, h0] + points[:, h1])
    wrists = ej[:, [ev["left_wrist"], ev["right_wrist"]]]
    elbows = ej[:, [ev["left_elbow"], ev["right_elbow"]]]
    banded = jnp.asarray([r in ("forearm", "hand") for r in dressing.part_roles])
    head_label = dressing.num_cones if face else -1
    half = jnp.asarray([dressing.head_radius, 0.5 * dressing.head_length], jnp.float32)
    width = appearance.BAND_WIDTH if bands else 0.0
    f32 = lambda a: jnp.asarray(a, jnp.float32)
    views = [
        (f32(render.pixel_rays(cams.K[v], cams.dist[v], cams.image_size[v])), f32(cams.R[v]), f32(cams.t[v]))
        for v in range(cams.num_views)
    ]

    def decorate(albedo, r: render.Render, v: int, i: int) -> jnp.ndarray:
        rays, R, t = views[v]
        return appearance.decorate(
            albedo, r.depth, r.label, rays, R, t, head_label, f32(centres[i]), f32(frames[i]), half, banded,
            f32(wrists[i]), f32(elbows[i]), width,
        )  # fmt: skip

    return decorate


def _room(cams: camera.Rig, centre, light_world, points, seed: int, clutter: float):
    """The room of :mod:`jaxmocap.synth.scene` seen by every camera, and its shadow caster covering ``points
    (T, P, 3)``."""
    light = light_world / np.linalg.norm(light_world)
    centres = np.asarray(camera.camera_centres(cams.to_jax(jnp.float32)), np.float64)
    room = room_mod.make_room(centre, centres, seed, clutter)
    views = [
        room_mod.room_view(room, cams.K[v], cams.dist[v], cams.R[v], cams.t[v], cams.image_size[v], light)
        for v in range(cams.num_views)
    ]
    aim = np.asarray(centre, np.float64) + [0.0, 0.0, 0.9]
    radius = float(np.linalg.norm(points.reshape(-1, 3) - aim, axis=-1).max()) + 0.3
    return views, room_mod.ShadowCaster(aim, radius, light, views)


def _prepare_output(out: pathlib.Path, overwrite: bool) -> None:
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"{out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise FileExistsError(
                f"{out} is not empty (pass overwrite=True / --overwrite to replace a sequence)"
            )
        if (out / seqio.VIEWS).is_dir():
            shutil.rmtree(out / seqio.VIEWS)
        for name in (seqio.CALIBRATION, seqio.META, seqio.GROUNDTRUTH, seqio.BODY):
            if (out / name).exists():
                (out / name).unlink()
    out.mkdir(parents=True, exist_ok=True)


def _rig_for(rig, size, points: np.ndarray, joints: np.ndarray) -> tuple[camera.Rig, np.ndarray, str]:
    """``(cameras, world offset of the clip, rig name for meta.json)`` for a preset name, a calibration file or
    a :class:`~jaxmocap.geometry.camera.Rig`; ``points (T, P, 3)`` must stay in view of a preset."""
    if isinstance(rig, str) and rig in PRESETS:
        return (
            preset_rig(rig, points, joints, parse_size(size) if size is not None else (640, 480)),
            np.zeros(3),
            rig,
        )
    if isinstance(rig, str) and not os.path.exists(rig):
        raise ValueError(f"unknown rig {rig!r}: a preset ({', '.join(PRESETS)}) or a calibration file")
    source = "Rig" if isinstance(rig, camera.Rig) else os.fspath(rig)
    cams = rig if isinstance(rig, camera.Rig) else calibration.load_calibration(rig)
    if any(s == (0, 0) for s in cams.image_size):
        raise MocapInputError(source, "the calibration does not state its image size")
    if size is not None:
        (w, h), (w0, h0) = parse_size(size), cams.image_size[0]
        if len(set(cams.image_size)) != 1:
            raise ValueError("an image size for the sequence needs cameras that share one image size")
        cams = camera.scale_images(cams, (w / w0, h / h0))
    cams = dataclasses.replace(
        cams, **{k: np.asarray(getattr(cams, k), np.float64) for k in ("K", "dist", "R", "t")}
    )
    return cams, place_motion(cams, joints), source


def synthesize(
    motion: str | os.PathLike | Motion,
    out: str | os.PathLike,
    *,
    rig: str | os.PathLike | camera.Rig = "stereo",
    asf: str | os.PathLike | None = None,
    scale: float | None = None,
    mapping: Mapping[str, JointSpec] | str | os.PathLike | None = None,
    up_axis: str | None = None,
    frames: str | tuple[int | None, int | None] | None = None,
    fps: float = 30.0,
    size: str | tuple[int, int] | None = None,
    seed: int = 0,
    background: str = "photo",
    clutter: str | float = 0.0,
    noise: float = 0.01,
    depth_noise: float = 0.02,
    depth_smooth: float = 1.5,
    illumination: float = 0.0,
    blur: int = 1,
    clothing: str = "plain",
    sleeves: str = "long",
    wrist_bands: bool = False,
    face: bool = True,
    detections: bool = True,
    overwrite: bool = False,
    licence: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> seqio.Sequence:
    """Render a synthetic multi-view sequence of a mocap clip into the folder ``out``
    (layout: :mod:`jaxmocap.io.sequence`) and return it opened.

    Args:
      motion: a ``.bvh``/``.amc`` path, a :class:`~jaxmocap.io.mocap.Motion`, or ``"demo"``
        (:func:`load_clip`); ``asf``, ``scale``, ``mapping``, ``up_axis``: see :func:`load_clip`.
      rig: a preset name (:data:`PRESETS`), a calibration file, or a :class:`~jaxmocap.geometry.camera.Rig`.
      frames: source frame range ``"A:B"`` (default the whole clip); ``fps``: output rate, the source is
        subsampled every ``round(source fps / fps)`` frames.
      size: ``(w, h)`` or ``"WxH"``: image size (presets default 640×480; a calibration is rescaled).
      seed: seeds every random number (noise, clutter, illumination phase).
      background: ``"photo"``, ``"plain"`` or an image path (per-view backdrops), or ``"room"``: a 3D room seen
        consistently by every camera, in which the body casts its shadow (:mod:`jaxmocap.synth.scene`);
        clutter: procedural clutter density (0–1 or none/low/medium/high), on the walls for a room.
      noise: RGB sensor noise standard deviation (image units, 1 = full scale).
      depth_noise: depth noise standard deviation (metres); depth_smooth: its smoothing (pixels).
      illumination: amplitude ``A`` of a global illumination change ``1 + A sin(2π t / 4 s + φ)``.
      blur: number of consecutive source frames averaged per image (motion blur), centred on the frame;
        mask, depth and labels are those of the central frame.
      clothing: ``"plain"`` (one colour per body part) or ``"textured"`` (a solid texture per garment fixed to
        the bones, :mod:`jaxmocap.synth.texture`).
      sleeves: ``"long"`` or ``"short"`` (skin-coloured forearms); wrist_bands: a lime band around each wrist;
        face: a face and hair painted on the head (:mod:`jaxmocap.synth.appearance`).
      detections: write simulated OpenPose BODY_25B detections per view and frame
        (:mod:`jaxmocap.synth.detections`, in ``views/<camera>/openpose/``).
      overwrite: replace an existing sequence in ``out``.
      licence: the clip's licence line for ``meta.json`` (default :func:`default_licence` of its skeleton).
      progress: called as ``progress(done, total)`` after each frame.
    """
    m, rec = load_clip(motion, asf, scale, mapping, up_axis)
    ej_all = eval_joints(m, rec.mapping)
    if not (fps > 0 and math.isfinite(fps)):
        raise ValueError(f"fps must be positive, got {fps}")
    if fps > m.fps * (1 + 1e-9):
        raise ValueError(f"fps {fps} exceeds the clip's {m.fps}")
    if int(blur) < 1:
        raise ValueError("blur must be at least 1 frame")
    if clothing not in ("plain", "textured"):
        raise ValueError(f"clothing must be plain or textured, got {clothing!r}")
    if sleeves not in appearance.SLEEVES:
        raise ValueError(f"sleeves must be long or short, got {sleeves!r}")
    for what, val in (("noise", noise), ("depth_noise", depth_noise), ("depth_smooth", depth_smooth)):
        if not (val >= 0 and math.isfinite(val)):
            raise ValueError(f"{what} must be a non-negative number, got {val}")
    if not (0 <= illumination < 1):
        raise ValueError(f"illumination amplitude must lie in [0, 1), got {illumination}")
    clutter = parse_clutter(clutter)
    a, b = parse_frames(frames, m.num_frames)
    step = max(1, int(round(m.fps / fps)))
    src = np.arange(a, b, step)
    T = len(src)
    dressing = dress(m, rec.mapping)
    points = dressing_points(m, dressing, np.arange(m.num_frames))
    joints = ej_all[src]
    blur_lo = max(0, a - (int(blur) - 1) // 2)
    cams, offset, rig_name = _rig_for(rig, size, points[blur_lo : b + int(blur)], joints)
    points = points + offset
    joints = joints + offset
    out = pathlib.Path(out)
    _prepare_output(out, overwrite)

    palette = dict(texture.TEXTURED_COLOURS) if clothing == "textured" else {}
    bare = tuple(appearance.SHORT_SLEEVES) if sleeves == "short" else ()
    palette.update({k: appearance.SHORT_SLEEVES[k] for k in bare})
    colours = jnp.asarray(dressing.colours(palette), jnp.float32)
    c, f, left = subject_frame(joints)
    light_world = LIGHT[0] * f + LIGHT[1] * left + LIGHT[2] * np.array([0.0, 0.0, 1.0])
    phase = float(np.random.default_rng([int(seed), 1 << 20]).uniform(0, 2 * math.pi))
    V = cams.num_views
    K, dist, Rv, tv = (np.asarray(x, np.float64) for x in (cams.K, cams.dist, cams.R, cams.t))
    room_views = caster = None
    if background == "room":
        room_views, caster = _room(cams, c, light_world, points[blur_lo : b + int(blur)], seed, clutter)
        backgrounds = [jnp.asarray(rv.lit) for rv in room_views]
    else:
        backgrounds = [
            jnp.asarray(background_image(background, cams.image_size[v], v, seed, clutter), jnp.float32)
            / 255.0
            for v in range(V)
        ]
    lights = [jnp.asarray(Rv[v] @ light_world / np.linalg.norm(light_world), jnp.float32) for v in range(V)]
    half = (int(blur) - 1) // 2
    detector = None
    if detections:
        kp, normals = dets.keypoints_3d(
            ej_all + offset,
            points[:, list(dressing.head_points)],
            dressing.head_radius,
            points[:, list(toe_points(m, rec.mapping))],
        )
        detector = dets.Detector(K, dist, Rv, tv, cams.image_size, kp, normals, int(blur))

    albedo_of = None
    if clothing == "textured" or face or wrist_bands:
        textured = (
            _clothing(m, dressing, colours, seed, offset, cams, bare) if clothing == "textured" else None
        )
        decorate = _appearance(m, dressing, points, ej_all + offset, cams, face, wrist_bands)

        def albedo_of(r: render.Render, v: int, s: int) -> jnp.ndarray:
            base = colours[jnp.maximum(r.label, 0)] if textured is None else textured(r, v, s)
            return decorate(base, r, v, s)

    def render_frame(i: int):
        prims = scene_primitives(points[i], dressing)
        views = [
            render.render_view(
                K[v], dist[v], Rv[v], tv[v], cams.image_size[v], prims, caps=CAPS, normals=True
            )
            for v in range(V)
        ]
        return prims, views

    scene = {k: [] for k in ("cone_a", "cone_b", "ell_centre", "ell_axes")}
    pool = ThreadPoolExecutor(max_workers=2)
    writes = []
    try:
        for v in range(V):
            plate = plates.plate_image(
                np.random.default_rng([int(seed), 1 << 20, v, 3]), backgrounds[v], noise
            )
            writes.append(pool.submit(seqio.write_rgb, plates.plate_path(out, cams.names[v]), plate))
        pending = render_frame(int(src[0]))
        for k, i in enumerate(src):
            i = int(i)
            prims, current = pending
            if k + 1 < T:  # dispatched now, computed by XLA while this frame is finished on the host
                pending = render_frame(int(src[k + 1]))
            for key in scene:
                scene[key].append(np.asarray(getattr(prims, key)))
            illum = 1.0 + illumination * math.sin(
                2 * math.pi * (k * step / m.fps) / ILLUMINATION_PERIOD + phase
            )
            subs = [min(max(i + d - half, 0), m.num_frames - 1) for d in range(int(blur))]
            if detector is not None:
                r_a, r_b = np.asarray(dressing.radius_start), np.asarray(dressing.radius_end)
                own = dets.own_labels(
                    kp[i], scene["cone_a"][-1], scene["cone_b"][-1], r_a, r_b, dressing.num_cones
                )
            others = {s: render_frame(s)[1] for s in subs if s != i}
            light_depth = caster.depth(prims, CAPS) if caster is not None else None
            for v in range(V):
                renders = [current[v] if s == i else others[s][v] for s in subs]
                rng = np.random.default_rng([int(seed), k, v])
                bg = backgrounds[v]
                if caster is not None:
                    bg = jnp.asarray(room_views[v].image(caster.shadow(light_depth, v)))
                albedos = (
                    None
                    if albedo_of is None
                    else [albedo_of(r, v, s) for r, s in zip(renders, subs, strict=True)]
                )
                rgb8, depth_mm, labels = view_images(
                    rng, renders, colours, lights[v], bg, illum, noise, depth_smooth, depth_noise, albedos
                )
                name = cams.names[v]
                writes += [
                    pool.submit(seqio.write_rgb, seqio.frame_path(out, name, "rgb", k), rgb8),
                    pool.submit(seqio.write_mask, seqio.frame_path(out, name, "mask", k), labels >= 0),
                    pool.submit(seqio.write_depth, seqio.frame_path(out, name, "depth", k), depth_mm),
                    pool.submit(seqio.write_labels, seqio.frame_path(out, name, "labels", k), labels),
                ]
                if detector is not None:
                    found = detector.frame(np.random.default_rng([int(seed), k, v, 2]), v, i, labels, own)
                    writes.append(pool.submit(dets.write_openpose_json, detections_path(out, name, k), found))
            while len(writes) > 16 * V:
                writes.pop(0).result()
            if progress is not None:
                progress(k + 1, T)
        for w in writes:
            w.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)

    seqio.write_calibration(out, cams)
    dims = body_dimensions(m, dressing, rec.mapping)
    body_mod.save_body(out / seqio.BODY, "full25", dims)
    seqio.write_groundtruth(
        out,
        joints,
        m.positions[src] + offset,
        m.joint_names,
        frame_index=src,
        time=(src - a) / m.fps,
        part_names=np.asarray(dressing.part_names),
        scene_cone_a=np.stack(scene["cone_a"]),
        scene_cone_b=np.stack(scene["cone_b"]),
        scene_cone_r_a=np.asarray(dressing.radius_start),
        scene_cone_r_b=np.asarray(dressing.radius_end),
        scene_ellipsoid_centre=np.stack(scene["ell_centre"]),
        scene_ellipsoid_axes=np.stack(scene["ell_axes"]),
    )
    meta = {
        "frames": T,
        "fps": m.fps / step,
        "generator": f"jaxmocap {__version__} synth",
        "source": {
            "clip": pathlib.Path(m.source).name if m.source else "",
            "licence": default_licence(rec.family) if licence is None else str(licence),
            "skeleton": rec.to_json(),
            "fps": m.fps,
            "frames": [a, b],
            "step": step,
        },
        "rig": rig_name,
        "cameras": list(cams.names),
        "image_size": [list(s) for s in cams.image_size],
        "world_offset": offset,
        "seed": int(seed),
        "background": os.fspath(background)
        if background in ("photo", "plain", "room")
        else pathlib.Path(background).name,
        "clutter": clutter,
        "noise": {"rgb_sigma": noise, "depth_sigma_m": depth_noise, "depth_smooth_px": depth_smooth},
        "illumination_amplitude": illumination,
        "motion_blur_frames": int(blur),
        "clothing": clothing,
        "sleeves": sleeves,
        "wrist_bands": {"colour": appearance.BAND_COLOUR, "width_m": appearance.BAND_WIDTH}
        if wrist_bands
        else None,
        "face": bool(face),
        "light": (light_world / np.linalg.norm(light_world)).round(6),
        "plates": f"views/<camera>/{plates.PLATE}",
        "detections": {
            "simulated": True,
            "format": "OpenPose BODY_25B JSON",
            "path": "views/<camera>/openpose/<camera>_NNNNNNNNNNNN_keypoints.json",
            "model": dataclasses.asdict(detector.model),
        }
        if detector is not None
        else None,
        "caps": CAPS,
        "parts": list(dressing.part_names),
        "part_roles": list(dressing.part_roles),
        "part_colours": np.asarray(colours, np.float64).round(4),
        "body": seqio.BODY,
        "joint_names": list(body_mod.EVAL_JOINTS),
    }
    seqio.write_meta(out, meta)
    return seqio.load_sequence(out)
