"""Frames → what the filter step sees of one frame (:class:`TrackObservation`).

:class:`FeatureBuilder` runs :class:`jaxmocap.features.FeatureExtractor` (foreground from the sequence's masks,
the recorded plates, a median background, MOG2, the adaptive Gaussian with shadow removal or none; edges; distance
transform; depth; the colour map, skin probability and triangulated skin blobs or wrist bands when a cue reads
them), adds the silhouette samples of the ``coverage`` cue (:func:`jaxmocap.likelihood.coverage.silhouette_samples`)
and a placeholder for the detection-driven proposal centre.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.features.foreground import ShadowParams
from jaxmocap.features.observation import Observation
from jaxmocap.features.pipeline import FeatureConfig, FeatureExtractor
from jaxmocap.features.resample import downsample as downsample_image
from jaxmocap.io.sources import BadFrame, FrameData
from jaxmocap.io.subject import subject_box
from jaxmocap.likelihood import cues as cues_mod
from jaxmocap.likelihood.coverage import silhouette_samples
from jaxmocap.tracking.options import FOREGROUNDS
from jaxmocap.transfer import to_device

__all__ = [
    "ADAPTIVE_SHADOW",
    "COVERAGE_SAMPLES",
    "FeatureBuilder",
    "TrackObservation",
    "host_masks",
    "median_background",
]

#: The shadow test of ``--foreground adaptive``: darker copies of the background colour (0.4 ≤ α < 1) are shadows,
#: and brighter ones up to α < 1.2 (a global illumination change) background too; chromaticity within 6 σ.
ADAPTIVE_SHADOW = ShadowParams(alpha_min=0.4, alpha_max=1.2, cd_max=6.0)

#: Silhouette samples per view of the ``coverage`` cue (``--samples``). The cue's cost grows with them (each is
#: tested against every projected capsule of every particle: with 128, 40 % of the ``full25`` default likelihood on
#: four cameras); 64 tracked the synthetic clips of ``benchmarks/results/accuracy_default.md`` as well as 128
#: (four cameras 28.7 mm either way over 18 runs) at a higher rate.
COVERAGE_SAMPLES = 64


class TrackObservation(NamedTuple):
    """What the filter step sees of one frame: the image ``Observation`` (with the silhouette samples of the
    coverage cue when it is used) and the proposal centre ``centre (D,)`` with ``valid``."""

    image: Observation
    centre: jnp.ndarray
    valid: jnp.ndarray


class _Extractor(FeatureExtractor):
    """The feature pipeline with foreground masks supplied from outside (a sequence's mask channel)."""

    given_masks: list | None = None

    def foreground_masks(self, frames, depth):
        if self.given_masks is not None:
            f = self.config.downsample
            return [downsample_image(m.astype(np.float32), f) >= 0.5 for m in self.given_masks]
        return super().foreground_masks(frames, depth)


def host_masks(views, shape) -> np.ndarray:
    """The foreground maps ``views`` (``V`` arrays ``(H_v, W_v)``: bool, ``[0, 1]`` or uint8 ``round(255·p)``) as the
    ``(V, H, W)`` bool masks of the observation's ``shape`` (views padded at the bottom/right with background, as
    :func:`jaxmocap.features.observation.make_observation` pads them), computed on the host: ``p ≥ 0.5``."""
    masks = np.zeros(tuple(shape), bool)
    for v, m in enumerate(views):
        m = np.asarray(m)
        masks[v, : m.shape[0], : m.shape[1]] = m >= (128 if m.dtype == np.uint8 else 0.5)
    return masks


def _scene_image(path, shape) -> np.ndarray | None:
    """The scene image at ``path`` cut to ``shape (H, W)`` (a calibrated image larger by codec padding), or None."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None or img.shape[0] < shape[0] or img.shape[1] < shape[1]:
        return None
    return img[: shape[0], : shape[1]].astype(np.float32)


def median_background(source, frames: Sequence[int], num: int = 15) -> list[np.ndarray]:
    """Static background per view (BGR uint8, full size): the per-pixel median of up to ``num`` readable frames
    spread over ``frames``. With detections (a frame's ``keypoints``), each frame's subject box
    (:func:`jaxmocap.io.subject.subject_box`) is left out, and where the subject covers a pixel in every frame the source's scene image of the view
    (``source.scene_images``, e.g. a Pose2Sim project's ``calibration/extrinsics``) fills it when it has one, else
    the plain median."""
    pick = sorted({frames[int(i)] for i in np.round(np.linspace(0, len(frames) - 1, min(num, len(frames))))})
    stacks, keeps = None, None
    for t in pick:
        try:
            fd = source.read(t, masks=False)
        except BadFrame:
            continue
        if stacks is None:
            stacks, keeps = [[] for _ in fd.images], [[] for _ in fd.images]
        for v, im in enumerate(fd.images):
            stacks[v].append(im)
            kp = None if fd.keypoints is None else np.asarray(fd.keypoints[v])
            keeps[v].append(subject_box(kp, im.shape[:2]))
    if stacks is None:
        raise MocapInputError(None, "no readable frame to estimate the background from")
    if not getattr(source, "has_keypoints", False):
        return [np.median(np.stack(s), axis=0).astype(np.uint8) for s in stacks]
    scenes = getattr(source, "scene_images", None)
    out = []
    for v, (s, k) in enumerate(zip(stacks, keeps, strict=True)):
        S, K = np.stack(s), np.stack(k)
        fill = _scene_image(scenes[v], S.shape[1:3]) if scenes else None
        med = np.empty(S.shape[1:], np.float32)
        for r in range(0, S.shape[1], 64):  # in bands of rows: a float copy of the whole stack is large
            band, keep = S[:, r : r + 64].astype(np.float32), K[:, r : r + 64]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN pixels: filled below
                m = np.nanmedian(np.where(keep[..., None], band, np.nan), axis=0)
            hole = ~np.any(keep, axis=0)
            other = np.median(band, axis=0) if fill is None else fill[r : r + 64]
            med[r : r + 64] = np.where(hole[..., None], other, m)
        out.append(np.clip(np.round(med), 0, 255).astype(np.uint8))
    return out


class FeatureBuilder:
    """Frames → :class:`TrackObservation` (image maps through :class:`jaxmocap.features.FeatureExtractor`).

    ``foreground``: ``mask`` (the source's masks), ``median`` (static background: :func:`median_background`),
    ``mog2`` (adaptive; stateful, so not reproduced exactly by ``--resume``), ``adaptive`` (López Méndez's
    adaptive single Gaussian per pixel and channel, eq. 4.1–4.2, with shadow removal:
    :class:`jaxmocap.features.foreground.GaussianBackground` with :class:`~jaxmocap.features.foreground.ShadowParams`,
    its mean started from the input's recorded plates when it has them, else from :func:`median_background`, and
    its σ from the configuration's sensor noise ``noise_std``, 4 grey levels — the shadow test's chromaticity bound is in units of σ; only pixels classified
    as background are learned (``selective``: a subject passing over a pixel would inflate its σ, and with it the
    shadow test's bound, until the subject itself passes for a shadow); the shadow test :data:`ADAPTIVE_SHADOW`
    also takes brighter copies of the background (a global illumination change) for background, so that the
    model learns them; stateful like ``mog2``),
    ``plate`` (static background against each camera's recorded empty-scene plate,
    :func:`jaxmocap.features.foreground.plate_background`: threshold from the plate's own sensor noise, shadow
    removal), ``none``; ``auto`` = ``mask`` when the source has masks, else ``plate`` when it has plates, else
    ``median``.
    """

    def __init__(
        self,
        source,
        cue_names: Sequence[str],
        foreground: str = "auto",
        downsample: int = 1,
        num_samples: int = COVERAGE_SAMPLES,
        frames: Sequence[int] | None = None,
    ):
        if foreground not in FOREGROUNDS:
            raise ValueError(f"unknown foreground {foreground!r}; choose one of {', '.join(FOREGROUNDS)}")
        plate_files = getattr(source, "plate_files", None)
        if foreground == "auto":
            foreground = "mask" if source.has_masks else "plate" if plate_files else "median"
        if foreground == "plate" and not plate_files:
            raise ValueError(
                "--foreground plate needs an empty-scene image per camera (a sequence folder's "
                "views/<camera>/background.png, or --plates with --videos)"
            )
        if foreground == "mask" and not source.has_masks:
            raise ValueError(
                "--foreground mask needs an input with foreground masks (a sequence folder's mask/)"
            )
        self.foreground = foreground
        self.source = source
        names = set(cue_names)
        reads = {f for n in names for f in cues_mod.REQUIRES.get(n, ())}
        # IROS 2007's 3D head / hand blobs: skin blobs matched across the first pair; Li & Kulić's wrist bands
        bands = "wristband" in names
        blobs = "blobs3d" in names or bands
        if bands and "blobs3d" in names:
            raise ValueError("the blobs3d and wristband cues both read the 3D blobs: choose one")
        cfg = FeatureConfig(
            foreground={
                "mask": "none",
                "plate": "static",
                "median": "static",
                "mog2": "mog2",
                "adaptive": "gaussian",
                "none": "none",
            }[foreground],
            shadow=ADAPTIVE_SHADOW if foreground == "adaptive" else None,
            edges=bool(names & {"edges", "edge_fraction"}),
            edge_dt="edge_distance" in names,
            skin="rgb" if ("skin" in reads or (blobs and not bands)) else None,
            rgb="rgb" in reads,
            blobs=blobs,
            blob_source="bands" if bands else "skin",
            downsample=int(downsample),
        )
        self.extractor = _Extractor(source.rig, cfg)
        self.rig = self.extractor.rig
        #: what ``source.read`` must decode for these features: masks for ``--foreground mask``, depth maps for a
        #: depth cue (each is a PNG or file per view to read)
        self.needs_masks = foreground == "mask"
        self.needs_depth = "depth" in reads
        self.num_samples = int(num_samples)
        self.coverage = "coverage" in names
        if foreground == "plate":
            self.extractor.set_plates(source.plates())
        if foreground in ("median", "adaptive"):
            frames = list(range(source.num_frames)) if frames is None else list(frames)
            recorded = foreground == "adaptive" and plate_files
            plates = source.plates() if recorded else median_background(source, frames)
            if foreground == "median":
                self.extractor.set_background(plates)
            else:  # the adaptive model starts from the recorded plates, else the median, never the first frame
                f = cfg.downsample
                for bg, plate in zip(self.extractor.backgrounds, plates, strict=True):
                    bg.init_std, bg.selective = cfg.noise_std, True
                    bg.initialise(downsample_image(plate, f))

    def __call__(self, fd: FrameData, dof: int) -> tuple[TrackObservation, np.ndarray]:
        """The observation (with a placeholder centre) and the host foreground masks ``(V, H, W)`` bool."""
        self.extractor.given_masks = fd.masks if self.foreground == "mask" else None
        obs = self.extractor(fd.images, depth=fd.depth)
        if fd.keypoints is not None:
            f = self.extractor.config.downsample
            kp = np.asarray(fd.keypoints, np.float32).copy()
            kp[..., :2] = np.where(kp[..., 2:3] > 0, (kp[..., :2] + 0.5) / f - 0.5, 0.0)
            obs = obs._replace(keypoints2d=to_device(kp))
        masks = host_masks(self.extractor.last_masks, obs.foreground.shape) if obs.has("foreground") else None
        if self.coverage:
            V, M = len(fd.images), self.num_samples
            uv = np.zeros((V, M, 2), np.float32)
            w = np.zeros((V, M), np.float32)
            if masks is not None:
                for v in range(V):
                    uv[v], w[v] = silhouette_samples(masks[v], M)
            obs = obs._replace(silhouette=to_device(uv), silhouette_w=to_device(w))
        return TrackObservation(obs, to_device(np.zeros(dof, np.float32)), to_device(np.False_)), masks
