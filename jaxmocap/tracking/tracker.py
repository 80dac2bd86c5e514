"""The high-level tracker: a calibrated multi-view sequence in, poses out (``jaxmocap track``).

``Tracker(source, out, options).run()`` is the setup of :mod:`jaxmocap.tracking.setup` (options + source → model,
features, likelihood, filter) run by the frame loop of :mod:`jaxmocap.tracking.loop`. The pieces, in the order a
frame goes through them:

* **sources** — :mod:`jaxmocap.io.sources` (a sequence folder, synchronised videos + a calibration);
* **features** — :mod:`jaxmocap.tracking.features` (the image maps and the silhouette samples of the coverage cue);
* **likelihood** — :func:`jaxmocap.tracking.setup.observation_loglik`: a
  :class:`jaxmocap.likelihood.compose.Likelihood` over the image cues and the silhouette ``coverage`` cue
  (:mod:`jaxmocap.likelihood.coverage`), weighted by one λ_c(l) table;
* **filter** — :mod:`jaxmocap.filters.factory` with the per-model defaults of :mod:`jaxmocap.tracking.options`;
* **initialisation** — :mod:`jaxmocap.tracking.init`;
* **loop and outputs** — :mod:`jaxmocap.tracking.loop` (track loss, re-initialisation, resume) and
  :mod:`jaxmocap.tracking.run_folder`.

The names of those modules that the tracker's users reach for are re-exported here.
"""

from __future__ import annotations

import os

from jaxmocap.filters.factory import (
    HYBRID_MOVE,
    make_filter,
    particles_text,
    partition_counts,
    partition_groups,
)
from jaxmocap.io.sources import BadFrame, FrameData, SequenceSource, VideoSource
from jaxmocap.likelihood.coverage import COVERAGE_DMAX, coverage_energy, silhouette_samples
from jaxmocap.tracking.features import FeatureBuilder, TrackObservation
from jaxmocap.tracking.loop import TrackingLoop
from jaxmocap.tracking.options import (
    ANNEALED,
    FILTERS,
    FOREGROUNDS,
    GRADIENT_FILTERS,
    MODELS,
    TrackOptions,
    build_model,
    default_cues,
    default_layers,
    default_particles,
    diffusion_std,
    parse_cues,
)
from jaxmocap.tracking.progress import Progress
from jaxmocap.tracking.setup import TrackSetup

__all__ = [
    "ANNEALED",
    "COVERAGE_DMAX",
    "FILTERS",
    "FOREGROUNDS",
    "GRADIENT_FILTERS",
    "HYBRID_MOVE",
    "MODELS",
    "BadFrame",
    "FeatureBuilder",
    "FrameData",
    "Progress",
    "SequenceSource",
    "TrackObservation",
    "TrackOptions",
    "TrackSetup",
    "Tracker",
    "VideoSource",
    "build_model",
    "coverage_energy",
    "default_cues",
    "default_layers",
    "default_particles",
    "diffusion_std",
    "make_filter",
    "parse_cues",
    "partition_counts",
    "partition_groups",
    "particles_text",
    "silhouette_samples",
]


class Tracker(TrackingLoop):
    """One tracking run: ``Tracker(source, out, options).run()``.

    Attributes after construction (those of its :class:`~jaxmocap.tracking.setup.TrackSetup`, ``setup``):
    ``model``, ``likelihood``, ``cues`` (``(name, weight)``), ``frames`` (the input frame numbers to track),
    ``features``, ``num_particles``, ``layers``, ``std``; ``filter`` once the run has started; ``trace_count``
    (compilations of the filter step).
    """

    def __init__(
        self, source, out: str | os.PathLike, options: TrackOptions | None = None, quiet: bool = False
    ):
        super().__init__(TrackSetup(source, options), out, quiet)
