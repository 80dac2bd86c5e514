"""One frame of image evidence on the device side: per-view maps stacked by view and 3D/2D detections.

``Observation`` is a NamedTuple, hence a JAX pytree whose leaves are device arrays. Everything the cues read from
images for one frame lives here; the host side (``jaxmocap.features``) fills it with OpenCV.

Shapes (``V`` views, ``H×W`` the image size after any down-sampling, ``K`` blob slots, ``J`` 2D keypoints):

=============== ================== ==========================================================================
field           shape              content
=============== ================== ==========================================================================
``foreground``  ``(V, H, W)``      foreground probability / mask in [0, 1]
``edges``       ``(V, H, W)``      smoothed edge map in [0, 1] (Canny, dilated, Gaussian-blurred)
``edge_dt``     ``(V, H, W)``      distance from each pixel to the nearest edge pixel, in pixels (I_DT)
``skin``        ``(V, H, W)``      skin probability in [0, 1]
``depth``       ``(V, H, W)``      depth along the camera z axis in metres, 0 = no measurement
``rgb``         ``(V, H, W, 3)``   RGB colour in [0, 1] (colour templates / histograms)
``blobs3d``     ``(K, 3)``         3D positions of skin blobs (head, hands), metres, world frame
``blob_conf``   ``(K,)``           confidence in [0, 1] of each blob slot; 0 = empty slot
``keypoints2d`` ``(V, J, 3)``      2D detections ``(u, v, confidence)``; confidence 0 = missing
``silhouette``  ``(V, M, 2)``      silhouette samples (pixels) of the coverage cue, with ``silhouette_w``
                                   ``(V, M)`` their weights (0 = empty slot); both None when not computed
=============== ================== ==========================================================================

Fixed-shape convention (so that one ``jit`` compilation serves every frame of a configuration):

* a map field that the configuration does not compute is a zero array of shape ``(V, 1, 1)`` (``(V, 1, 1, 3)``
  for ``rgb``); ``Observation.has(name)`` tells it apart from a real map, from static shapes only, so it can be
  used inside traced code;
* ``blobs3d``/``blob_conf`` always have ``K`` slots (``max_blobs``); unused slots have confidence 0;
* ``keypoints2d`` without detections is ``(V, 1, 3)`` zeros (confidence 0).

Map dtypes: ``float32`` (default), ``float16`` or ``uint8``. In ``uint8`` the maps with values in [0, 1]
(foreground, edges, skin, rgb) store ``round(255·p)``, ``edge_dt`` stores pixels clipped to 255, and ``depth``
stays ``float32`` (metres do not fit in a byte). ``as_float`` undoes the byte scaling.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import cv2
import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.stored_programs import stored_jit
from jaxmocap.transfer import to_device

MAP_FIELDS = ("foreground", "edges", "edge_dt", "skin", "depth")
"""Per-view scalar maps ``(V, H, W)``."""

UNIT_FIELDS = ("foreground", "edges", "skin", "rgb")
"""Fields whose values lie in [0, 1] (stored as ``round(255·p)`` in ``uint8``)."""

MAP_DTYPES = ("float32", "float16", "uint8")


class Observation(NamedTuple):
    """Image evidence of one frame; see the module docstring for shapes and the empty-field convention."""

    foreground: jnp.ndarray
    edges: jnp.ndarray
    edge_dt: jnp.ndarray
    skin: jnp.ndarray
    depth: jnp.ndarray
    rgb: jnp.ndarray
    blobs3d: jnp.ndarray
    blob_conf: jnp.ndarray
    keypoints2d: jnp.ndarray
    silhouette: jnp.ndarray | None = None
    silhouette_w: jnp.ndarray | None = None

    @property
    def num_views(self) -> int:
        return int(self.foreground.shape[0])

    @property
    def image_shape(self) -> tuple[int, int]:
        """``(H, W)`` of the maps that are present; ``(1, 1)`` when no map is present."""
        for name in MAP_FIELDS:
            if self.has(name):
                return tuple(getattr(self, name).shape[1:3])
        return (1, 1)

    def has(self, name: str) -> bool:
        """Whether field ``name`` holds real data (decided from static shapes: usable under ``jit``).

        Maps are absent when their spatial shape is ``(1, 1)``; ``keypoints2d`` is absent when it has one
        all-zero row per view (shape ``(V, 1, 3)``) — at trace time only the shape is known, so ``(V, 1, 3)``
        counts as absent; ``blobs3d`` is always present (empty slots have zero confidence).
        """
        a = getattr(self, name)
        if name in MAP_FIELDS or name == "rgb":
            return tuple(a.shape[1:3]) != (1, 1)
        if name == "keypoints2d":
            return a.shape[1] != 1
        if name in ("blobs3d", "blob_conf"):
            return a.shape[0] > 0
        if name in ("silhouette", "silhouette_w"):
            return a is not None
        raise KeyError(name)


def as_float(x: jnp.ndarray, unit: bool = True) -> jnp.ndarray:
    """Map stored in any of the map dtypes → float32; ``uint8`` maps with ``unit=True`` are divided by 255."""
    if x.dtype == jnp.uint8 and unit:
        return x.astype(jnp.float32) * (1.0 / 255.0)
    return x.astype(jnp.float32)


def encode_map(x: np.ndarray, dtype: str, *, unit: bool) -> np.ndarray:
    """Host-side encoding of a float map into a map dtype (see the module docstring).

    ``unit``: values are in [0, 1] and become ``round(255·x)`` in ``uint8``; otherwise ``uint8`` stores
    ``round(x)`` clipped to ``[0, 255]``. ``uint8`` input of a unit map is already ``round(255·p)``.
    """
    if dtype not in MAP_DTYPES:
        raise ValueError(f"map dtype must be one of {MAP_DTYPES}, got {dtype!r}")
    x = np.asarray(x)
    if dtype == "uint8":
        if x.dtype == np.uint8:
            return x
        flat = np.ascontiguousarray(x, np.float32).reshape(-1, x.shape[-1])
        # saturate(|255 x|), rounded to nearest: OpenCV's fast path for [0, 1] → byte (clips negatives to their
        # absolute value, which is why maps must be non-negative).
        return cv2.convertScaleAbs(flat, alpha=255.0 if unit else 1.0).reshape(x.shape)
    if x.dtype == np.uint8 and unit:
        return (x.astype(np.float32) * np.float32(1.0 / 255.0)).astype(dtype, copy=False)
    return x.astype(dtype, copy=False)


@stored_jit(static_argnames=("dtype", "unit"))
def _to_float_on_device(x: jnp.ndarray, dtype: str, unit: bool) -> jnp.ndarray:
    """``uint8`` unit maps → ``x / 255``; any map → ``dtype`` (a program kept on disk by a run of the command
    line, :func:`jaxmocap.stored_programs.stored_jit`)."""
    if x.dtype == jnp.uint8 and unit:
        return (x.astype(jnp.float32) * (1.0 / 255.0)).astype(dtype)
    return x.astype(dtype)


def _expected_sizes(rig) -> list[tuple[int, int]] | None:
    """Calibrated ``(w, h)`` per view; ``(0, 0)`` (size unknown to the calibration) is not checked."""
    if rig is None:
        return None
    V = int(np.shape(rig.K)[0])
    sizes = [(int(w), int(h)) for (w, h) in rig.image_size]
    if len(sizes) != V:
        raise MocapInputError(None, f"the calibration has {V} cameras but {len(sizes)} image sizes")
    return sizes


def _stack_views(
    name: str,
    value,
    num_views: int,
    sizes: list[tuple[int, int]] | None,
    fill,
    channels: int | None,
) -> np.ndarray:
    """List of ``V`` per-view arrays (or a stacked array) → ``(V, H, W[, C])``, padded to the largest view with
    ``fill`` (a number, or a function of the list of arrays, called only when padding is needed)."""
    if isinstance(value, np.ndarray):
        views = [value[i] for i in range(value.shape[0])]
    else:
        views = [np.asarray(a) for a in value]
    if len(views) != num_views:
        raise MocapInputError(None, f"{name}: {len(views)} views given but the calibration has {num_views}")
    want_ndim = 2 if channels is None else 3
    for v, a in enumerate(views):
        if a.ndim != want_ndim or (channels is not None and a.shape[2] != channels):
            shape = "(H, W)" if channels is None else f"(H, W, {channels})"
            raise MocapInputError(None, f"{name}[view {v}]: expected shape {shape}, got {a.shape}")
        if sizes is not None and sizes[v] != (0, 0) and (a.shape[1], a.shape[0]) != sizes[v]:
            raise MocapInputError(
                None,
                f"{name}[view {v}]: image is {a.shape[1]}x{a.shape[0]} (w x h) but the calibration says "
                f"{sizes[v][0]}x{sizes[v][1]}; fix the calibration's image size or resize the frames",
            )
    if isinstance(value, np.ndarray):
        return value
    if len({a.shape for a in views}) == 1 and len({a.dtype for a in views}) == 1:
        return np.stack(views)
    H = max(a.shape[0] for a in views)
    W = max(a.shape[1] for a in views)
    dtype = np.result_type(*[a.dtype for a in views])
    fill_value = fill(views) if callable(fill) else fill
    out = np.full((num_views, H, W) + (() if channels is None else (channels,)), fill_value, dtype=dtype)
    for v, a in enumerate(views):
        out[v, : a.shape[0], : a.shape[1]] = a
    return out


def empty_map(num_views: int, dtype: str = "float32", channels: int | None = None) -> np.ndarray:
    """The placeholder of an unused map field: zeros ``(V, 1, 1)`` (``(V, 1, 1, C)`` with channels)."""
    shape = (num_views, 1, 1) + (() if channels is None else (channels,))
    return np.zeros(shape, dtype=dtype)


def make_observation(
    rig=None,
    *,
    num_views: int | None = None,
    foreground: Sequence[np.ndarray] | np.ndarray | None = None,
    edges: Sequence[np.ndarray] | np.ndarray | None = None,
    edge_dt: Sequence[np.ndarray] | np.ndarray | None = None,
    skin: Sequence[np.ndarray] | np.ndarray | None = None,
    depth: Sequence[np.ndarray] | np.ndarray | None = None,
    rgb: Sequence[np.ndarray] | np.ndarray | None = None,
    blobs3d: np.ndarray | None = None,
    blob_conf: np.ndarray | None = None,
    keypoints2d: np.ndarray | None = None,
    max_blobs: int = 3,
    dtype: str = "float32",
) -> Observation:
    """Validate host arrays, stack them by view, encode them in ``dtype`` and move them to the device.

    Each map argument is a list of ``V`` arrays ``(H_v, W_v)`` (``(H_v, W_v, 3)`` for ``rgb``) or a stacked
    array. With a ``rig`` (``jaxmocap.geometry.camera.Rig``), the number of views must equal its number of cameras and
    each view's ``(W_v, H_v)`` must equal ``rig.image_size[v]`` (unless that is ``(0, 0)``, unknown); otherwise
    ``MocapInputError``. Views of
    different calibrated sizes are padded at the bottom/right to the largest ``(H, W)``: with 0 for every map
    except ``edge_dt``, which is padded with its largest value (no edge there). All present maps must have the
    same size. Missing fields follow the fixed-shape convention of the module docstring.

    Values: foreground/edges/skin in [0, 1] (``uint8`` inputs are read as ``round(255·p)``), ``edge_dt`` in
    pixels, ``depth`` in metres (0 = none), ``rgb`` in [0, 1] RGB order. ``blobs3d (k, 3)`` with ``k ≤ K`` rows
    is padded to ``K = max_blobs`` slots of confidence 0 (``blob_conf`` defaults to ones for given rows).
    """
    if dtype not in MAP_DTYPES:
        raise ValueError(f"map dtype must be one of {MAP_DTYPES}, got {dtype!r}")
    sizes = _expected_sizes(rig)
    if sizes is not None:
        if num_views is not None and num_views != len(sizes):
            raise MocapInputError(None, f"num_views={num_views} but the calibration has {len(sizes)} views")
        num_views = len(sizes)
    if num_views is None:
        given = [x for x in (foreground, edges, edge_dt, skin, depth, rgb) if x is not None]
        if not given:
            raise ValueError("make_observation needs a rig, num_views or at least one map")
        num_views = len(given[0])
    V = num_views

    maps: dict[str, np.ndarray] = {}
    for name, value in (
        ("foreground", foreground),
        ("edges", edges),
        ("edge_dt", edge_dt),
        ("skin", skin),
        ("depth", depth),
    ):
        if value is None:
            continue
        fill = (lambda views: float(max(np.max(a) for a in views))) if name == "edge_dt" else 0.0
        maps[name] = _stack_views(name, value, V, sizes, fill, None)
    if rgb is not None:
        maps["rgb"] = _stack_views("rgb", rgb, V, sizes, 0.0, 3)
    hw = {name: a.shape[1:3] for name, a in maps.items()}
    if len(set(hw.values())) > 1:
        raise MocapInputError(None, f"maps disagree in size: {hw}")

    out = {}
    for name in (*MAP_FIELDS, "rgb"):
        channels = 3 if name == "rgb" else None
        map_dtype = "float32" if (name == "depth" and dtype == "uint8") else dtype
        if name not in maps:
            out[name] = to_device(empty_map(V, map_dtype, channels))
        elif map_dtype == "uint8":
            out[name] = to_device(encode_map(maps[name], "uint8", unit=name in UNIT_FIELDS))
        else:
            # float targets: copy the host array as it is (bytes stay bytes) and convert on the device
            out[name] = _to_float_on_device(to_device(maps[name]), map_dtype, name in UNIT_FIELDS)

    K = int(max_blobs)
    b3 = np.zeros((K, 3), np.float32)
    bc = np.zeros((K,), np.float32)
    if blobs3d is not None:
        blobs3d = np.asarray(blobs3d, np.float32).reshape(-1, 3)
        if blobs3d.shape[0] > K:
            raise MocapInputError(None, f"blobs3d has {blobs3d.shape[0]} rows but max_blobs={K}")
        n = blobs3d.shape[0]
        b3[:n] = blobs3d
        if blob_conf is None:
            bc[:n] = 1.0
        else:
            blob_conf = np.asarray(blob_conf, np.float32).reshape(-1)
            if blob_conf.shape[0] != n:
                raise MocapInputError(None, f"blob_conf has {blob_conf.shape[0]} rows, blobs3d has {n}")
            bc[:n] = blob_conf
    elif blob_conf is not None:
        raise MocapInputError(None, "blob_conf given without blobs3d")

    if keypoints2d is None:
        kp = np.zeros((V, 1, 3), np.float32)
    else:
        kp = np.asarray(keypoints2d, np.float32)
        if kp.ndim != 3 or kp.shape[0] != V or kp.shape[2] != 3:
            raise MocapInputError(None, f"keypoints2d must be (V={V}, J, 3), got {kp.shape}")

    return Observation(
        foreground=out["foreground"],
        edges=out["edges"],
        edge_dt=out["edge_dt"],
        skin=out["skin"],
        depth=out["depth"],
        rgb=out["rgb"],
        blobs3d=to_device(b3),
        blob_conf=to_device(bc),
        keypoints2d=to_device(kp),
    )
