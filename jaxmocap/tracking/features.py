"""Frames → what the filter step sees of one frame (:class:`TrackObservation`).

:class:`FeatureBuilder` runs :class:`jaxmocap.features.FeatureExtractor` (foreground from the sequence's masks, a
median background, MOG2 or none; edges; distance transform; depth; the colour map, skin probability and
triangulated skin blobs when a cue reads them), adds the silhouette samples of the ``coverage`` cue
(:func:`jaxmocap.likelihood.coverage.silhouette_samples`) and a placeholder for the detection-driven proposal centre.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.features.observation import Observation
from jaxmocap.features.pipeline import FeatureConfig, FeatureExtractor
from jaxmocap.features.resample import downsample as downsample_image
from jaxmocap.io.sources import BadFrame, FrameData
from jaxmocap.likelihood import cues as cues_mod
from jaxmocap.likelihood.coverage import silhouette_samples
from jaxmocap.tracking.options import FOREGROUNDS

__all__ = ["FeatureBuilder", "TrackObservation"]


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


class FeatureBuilder:
    """Frames → :class:`TrackObservation` (image maps through :class:`jaxmocap.features.FeatureExtractor`).

    ``foreground``: ``mask`` (the source's masks), ``median`` (static background = per-pixel median of up to 15
    frames spread over the input), ``mog2`` (adaptive; stateful, so not reproduced exactly by ``--resume``),
    ``none``; ``auto`` = ``mask`` when the source has masks, else ``median``.
    """

    def __init__(
        self,
        source,
        cue_names: Sequence[str],
        foreground: str = "auto",
        downsample: int = 1,
        num_samples: int = 128,
        frames: Sequence[int] | None = None,
    ):
        if foreground not in FOREGROUNDS:
            raise ValueError(f"unknown foreground {foreground!r}; choose one of {', '.join(FOREGROUNDS)}")
        if foreground == "auto":
            foreground = "mask" if source.has_masks else "median"
        if foreground == "mask" and not source.has_masks:
            raise ValueError(
                "--foreground mask needs an input with foreground masks (a sequence folder's mask/)"
            )
        self.foreground = foreground
        self.source = source
        names = set(cue_names)
        reads = {f for n in names for f in cues_mod.REQUIRES.get(n, ())}
        # IROS 2007's 3D head / hand blobs: skin blobs matched across the first pair
        blobs = "blobs3d" in names
        cfg = FeatureConfig(
            foreground={"mask": "none", "median": "static", "mog2": "mog2", "none": "none"}[foreground],
            edges=bool(names & {"edges", "edge_fraction"}),
            edge_dt="edge_distance" in names,
            skin="rgb" if ("skin" in reads or blobs) else None,
            rgb="rgb" in reads,
            blobs=blobs,
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
        if foreground == "median":
            frames = list(range(source.num_frames)) if frames is None else list(frames)
            pick = sorted(
                {frames[int(i)] for i in np.round(np.linspace(0, len(frames) - 1, min(15, len(frames))))}
            )
            stacks = None
            for t in pick:
                try:
                    fd = source.read(t, masks=False)
                except BadFrame:
                    continue
                stacks = (
                    [[im] for im in fd.images]
                    if stacks is None
                    else [s + [im] for s, im in zip(stacks, fd.images, strict=True)]
                )
            if stacks is None:
                raise MocapInputError(None, "no readable frame to estimate the background from")
            self.extractor.set_background([np.stack(s) for s in stacks])

    def __call__(self, fd: FrameData, dof: int) -> tuple[TrackObservation, np.ndarray]:
        """The observation (with a placeholder centre) and the host foreground masks ``(V, H, W)`` bool."""
        self.extractor.given_masks = fd.masks if self.foreground == "mask" else None
        obs = self.extractor(fd.images, depth=fd.depth)
        if fd.keypoints is not None:
            f = self.extractor.config.downsample
            kp = np.asarray(fd.keypoints, np.float32).copy()
            kp[..., :2] = np.where(kp[..., 2:3] > 0, (kp[..., :2] + 0.5) / f - 0.5, 0.0)
            obs = obs._replace(keypoints2d=jnp.asarray(kp))
        if obs.has("foreground"):
            fg = np.asarray(obs.foreground)
            masks = (fg >= (128 if fg.dtype == np.uint8 else 0.5)) if fg.ndim == 3 else None
        else:
            masks = None
        if self.coverage:
            V, M = len(fd.images), self.num_samples
            uv = np.zeros((V, M, 2), np.float32)
            w = np.zeros((V, M), np.float32)
            if masks is not None:
                for v in range(V):
                    uv[v], w[v] = silhouette_samples(masks[v], M)
            obs = obs._replace(silhouette=jnp.asarray(uv), silhouette_w=jnp.asarray(w))
        return TrackObservation(obs, jnp.zeros(dof, jnp.float32), jnp.asarray(False)), masks
