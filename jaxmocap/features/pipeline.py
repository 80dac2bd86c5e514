"""Frames of all views → ``Observation``: the host-side feature pipeline with its per-view state.

``FeatureExtractor(rig, config)(frames)`` runs, for each view ``v`` (frames BGR ``uint8`` at the calibrated
size ``rig.image_size[v]``): optional down-sampling, foreground segmentation, Canny edges masked by the dilated
foreground → smoothed edge map and distance transform I_DT, skin probability, RGB map; then, across the stereo
pair, skin blobs → matched and triangulated 3D blobs, and SGBM depth in the left view. Fields that the
configuration does not compute follow the empty-field convention of ``jaxmocap.features.observation``, so the shapes of
the returned ``Observation`` depend only on the configuration and the rig.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.features.bands import LIME, band_mask
from jaxmocap.features.blobs import skin_blobs, stereo_blobs
from jaxmocap.features.colour import rgb_float
from jaxmocap.features.edges import edge_map
from jaxmocap.features.foreground import (
    DepthBackground,
    GaussianBackground,
    Mog2Background,
    ShadowParams,
    StaticBackground,
    plate_background,
)
from jaxmocap.features.observation import Observation, make_observation
from jaxmocap.features.resample import downsample, scale_rig
from jaxmocap.features.skin import SkinModel, default_skin_model
from jaxmocap.features.stereo import StereoDepth

FOREGROUND_METHODS = ("static", "gaussian", "mog2", "depth", "none")
SKIN_METHODS = ("rgb", "hs", None)


@dataclass(frozen=True)
class FeatureConfig:
    """Which features to compute and their parameters (hashable; pixel sizes refer to the down-sampled image).

    foreground: ``"static"`` (needs ``set_background``), ``"gaussian"``, ``"mog2"``, ``"depth"`` (needs depth
    maps and ``set_background_depth``) or ``"none"`` (whole image is foreground, the map is left empty).
    skin: ``"rgb"`` (8-bin likelihood ratio), ``"hs"`` (hue–saturation back-projection) or None.
    dt_truncate: I_DT is clipped at this many pixels (default 50, above the edge-distance cue's default cap of
    30 px); truncation lets the transform run on the edges' neighbourhood only (≈ 3× faster at 640×480). None
    gives the untruncated transform.
    """

    foreground: str = "static"
    edges: bool = True
    edge_dt: bool = True
    skin: str | None = "rgb"
    rgb: bool = False
    blobs: bool = False
    stereo_depth: bool = False
    stereo_pair: tuple[int, int] = (0, 1)
    downsample: int = 1
    dtype: str = "float32"
    # foreground
    static_thresholds: float | tuple[float, float, float] = 30.0
    fg_open: int = 3
    fg_dilate: int = 3
    shadow: ShadowParams | None = None
    noise_std: float = 4.0
    gaussian_rho: float = 0.01
    gaussian_k: float = 3.0
    depth_margin: float = 0.1
    # edges
    canny_low: float = 50.0
    canny_high: float = 150.0
    edge_mask_dilate: int = 15
    edge_dilate: int = 3
    edge_sigma: float = 1.0
    dt_truncate: float | None = 50.0
    # skin and blobs
    skin_prior: float | None = None
    max_blobs: int = 3
    blob_threshold: float = 0.5
    blob_min_area: int = 20
    blob_max_epipolar: float = 5.0
    #: what the 3D blobs are made of: ``"skin"`` (head and hands, Fontmarty et al.) or ``"bands"`` (coloured wrist
    #: bands, Li & Kulić: :func:`jaxmocap.features.bands.band_mask` with ``band_hsv``)
    blob_source: str = "skin"
    band_hsv: tuple[tuple[int, int, int], tuple[int, int, int]] = LIME
    # stereo
    sgbm: tuple[tuple[str, int], ...] = field(default=(("num_disparities", 64), ("block_size", 5)))

    def __post_init__(self):
        if self.foreground not in FOREGROUND_METHODS:
            raise ValueError(f"foreground must be one of {FOREGROUND_METHODS}, got {self.foreground!r}")
        if self.skin not in SKIN_METHODS:
            raise ValueError(f"skin must be one of {SKIN_METHODS}, got {self.skin!r}")
        if self.blob_source not in ("skin", "bands"):
            raise ValueError(f"blob_source must be 'skin' or 'bands', got {self.blob_source!r}")
        if self.blobs and self.blob_source == "skin" and self.skin is None:
            raise ValueError("skin blobs need a skin model (skin='rgb' or 'hs')")

    @property
    def mask_cleaning(self) -> dict[str, int]:
        """The clean-up of every foreground model's mask: ``{"open_size": fg_open, "dilate_size": fg_dilate}``."""
        return {"open_size": self.fg_open, "dilate_size": self.fg_dilate}


class FeatureExtractor:
    """Stateful host pipeline: ``extractor(frames, depth=None) -> Observation``.

    ``rig``: the calibration of the full-size frames; ``self.rig`` is the calibration of the maps (scaled when
    ``config.downsample > 1``) — use it with the returned observations.
    """

    def __init__(self, rig, config: FeatureConfig = FeatureConfig(), skin_model: SkinModel | None = None):
        self.config = config
        self.input_rig = rig
        self.rig = scale_rig(rig, config.downsample)
        self.num_views = int(np.shape(rig.K)[0])
        if len(rig.image_size) != self.num_views or any(tuple(s) == (0, 0) for s in rig.image_size):
            raise MocapInputError(
                None, f"the feature pipeline needs the image size of every camera, got {rig.image_size}"
            )
        self.skin_model = (skin_model or default_skin_model()) if config.skin else None
        self.backgrounds: list | None = None
        self.last_masks: list | None = None  # the last frame's foreground masks, on the host (``__call__``)
        if config.foreground == "gaussian":
            self.backgrounds = [
                GaussianBackground(
                    rho=config.gaussian_rho, k=config.gaussian_k, shadow=config.shadow, **config.mask_cleaning
                )
                for _ in range(self.num_views)
            ]
        elif config.foreground == "mog2":
            self.backgrounds = [Mog2Background(**config.mask_cleaning) for _ in range(self.num_views)]
        self.stereo = None
        if config.stereo_depth or config.blobs:
            if self.num_views < 2:
                raise MocapInputError(None, "stereo depth and 3D blobs need at least two views")
        if config.stereo_depth:
            self.stereo = StereoDepth(self.rig, *config.stereo_pair, **dict(config.sgbm))

    # --- backgrounds ----------------------------------------------------------------------------------------
    def set_background(self, backgrounds) -> None:
        """Static background per view: a list of ``V`` BGR images (full size), or of ``(T, H, W, 3)`` stacks
        whose per-pixel median is taken."""
        c = self.config
        frames = self._check_frames(
            [
                np.asarray(b) if np.ndim(b) == 3 else np.median(np.asarray(b), axis=0).astype(np.uint8)
                for b in backgrounds
            ]
        )
        self.backgrounds = [
            StaticBackground(
                f, thresholds=c.static_thresholds, shadow=c.shadow, noise_std=c.noise_std, **c.mask_cleaning
            )
            for f in frames
        ]

    def set_plates(self, plates, sigmas=None) -> None:
        """Static background per view against recorded empty-scene plates (``V`` BGR images, full size):
        :func:`jaxmocap.features.foreground.plate_background`, with the sensor noise ``sigmas`` (one per view,
        8-bit units; None: estimated from each plate), shadow removal, no opening or dilation: at four noise
        standard deviations a plate's false positives are rare (6·10⁻⁵ per pixel and channel), and an opening
        erodes limbs a few pixels wide (on the 96×72 walk it halves the IoU with the exact masks)."""
        frames = self._check_frames(plates)
        sigmas = [None] * len(frames) if sigmas is None else list(sigmas)
        self.backgrounds = [plate_background(f, s) for f, s in zip(frames, sigmas, strict=True)]

    def set_background_depth(self, depths) -> None:
        """Background depth per view (metres, 0 = unknown), full size; for ``foreground="depth"``."""
        c = self.config
        depths = [downsample(np.asarray(d, np.float32), c.downsample) for d in depths]
        self.backgrounds = [DepthBackground(d, margin=c.depth_margin, **c.mask_cleaning) for d in depths]

    # --- per frame ------------------------------------------------------------------------------------------
    def _check_frames(self, frames) -> list[np.ndarray]:
        frames = list(frames)
        if len(frames) != self.num_views:
            raise MocapInputError(None, f"{len(frames)} views given but the calibration has {self.num_views}")
        out = []
        for v, f in enumerate(frames):
            f = np.asarray(f)
            want = tuple(int(x) for x in self.input_rig.image_size[v])
            if f.ndim != 3 or f.shape[2] != 3 or f.dtype != np.uint8:
                raise MocapInputError(
                    None, f"view {v}: expected a BGR uint8 image (H, W, 3), got {f.dtype} {f.shape}"
                )
            if (f.shape[1], f.shape[0]) != want:
                raise MocapInputError(
                    None,
                    f"view {v}: frame is {f.shape[1]}x{f.shape[0]} but the calibration says {want[0]}x{want[1]}",
                )
            out.append(downsample(f, self.config.downsample))
        return out

    def foreground_masks(
        self, frames: list[np.ndarray], depth: list[np.ndarray] | None
    ) -> list[np.ndarray] | None:
        c = self.config
        if c.foreground == "none":
            return None
        if self.backgrounds is None:
            raise MocapInputError(
                None, f"foreground={c.foreground!r} needs set_background/set_background_depth first"
            )
        if c.foreground == "depth":
            if depth is None:
                raise MocapInputError(None, "foreground='depth' needs depth maps for every view")
            return [bg.update(d) for bg, d in zip(self.backgrounds, depth, strict=True)]
        return [bg.update(f) for bg, f in zip(self.backgrounds, frames, strict=True)]

    def __call__(self, frames, depth=None) -> Observation:
        c = self.config
        frames = self._check_frames(frames)
        if depth is not None:
            depth = [downsample(np.asarray(d, np.float32), c.downsample) for d in depth]
            if len(depth) != self.num_views:
                raise MocapInputError(None, f"{len(depth)} depth maps given for {self.num_views} views")
        masks = self.foreground_masks(frames, depth)
        # kept on the host for callers that need the masks there (reading them back from the device would wait
        # for whatever the device is computing, e.g. a tracker's step on the frame before)
        self.last_masks = masks
        maps: dict[str, list] = {}
        if masks is not None:
            maps["foreground"] = masks
        if c.edges or c.edge_dt:
            e01, dts = [], []
            for v, f in enumerate(frames):
                e, dt, _ = edge_map(
                    f,
                    None if masks is None else masks[v],
                    low=c.canny_low,
                    high=c.canny_high,
                    mask_dilate=c.edge_mask_dilate,
                    dilate_size=c.edge_dilate,
                    sigma=c.edge_sigma,
                    truncate=c.dt_truncate,
                )
                e01.append(e)
                dts.append(dt)
            if c.edges:
                maps["edges"] = e01
            if c.edge_dt:
                maps["edge_dt"] = dts
        if c.skin == "rgb":
            maps["skin"] = [self.skin_model.probability_u8(f, c.skin_prior) for f in frames]
        elif c.skin == "hs":
            maps["skin"] = [self.skin_model.hs_backprojection(f) for f in frames]
        if c.rgb:
            maps["rgb"] = [rgb_float(f) for f in frames]
        if self.stereo is not None:
            i, j = c.stereo_pair
            z = self.stereo.depth(frames[i], frames[j])
            maps["depth"] = [z if v == i else np.zeros_like(z) for v in range(self.num_views)]
        elif depth is not None:
            maps["depth"] = depth
        blobs3d = conf = None
        if c.blobs:
            i, j = c.stereo_pair
            # a band is a few pixels wide: kept whole (no opening), small ones too
            if c.blob_source == "bands":
                pair = [
                    skin_blobs(
                        band_mask(frames[v], c.band_hsv), 0.5, c.max_blobs, 4, open_size=1, close_size=3
                    )
                    for v in (i, j)
                ]
            else:
                pair = [
                    skin_blobs(maps["skin"][v], c.blob_threshold, c.max_blobs, c.blob_min_area)
                    for v in (i, j)
                ]
            blobs3d, conf, _ = stereo_blobs(
                self.rig, pair, (i, j), c.max_blobs, max_epipolar=c.blob_max_epipolar
            )
        return make_observation(
            self.rig, **maps, blobs3d=blobs3d, blob_conf=conf, max_blobs=c.max_blobs, dtype=c.dtype
        )
