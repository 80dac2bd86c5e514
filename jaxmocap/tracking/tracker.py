"""The high-level tracker: a calibrated multi-view sequence in, poses out (``jaxmocap track``).

``Tracker(source, out, options).run()`` is the setup of :mod:`jaxmocap.tracking.setup` (options + source → model,
features, likelihood, filter) run by the frame loop of :mod:`jaxmocap.tracking.loop`. The pieces, in the order a
frame goes through them:

* **sources** — :mod:`jaxmocap.io.sources` (a sequence folder, synchronised videos + a calibration);
* **features** — :mod:`jaxmocap.tracking.features` (the image maps and the silhouette samples of the coverage cue);
* **likelihood** — :func:`jaxmocap.tracking.setup.observation_loglik`: one
  :class:`jaxmocap.likelihood.compose.Likelihood` over every cue, the silhouette ``coverage`` cue
  (:mod:`jaxmocap.likelihood.coverage`) included, weighted by one λ_c(l) table;
* **filter** — :mod:`jaxmocap.filters.factory` with the per-model defaults of :mod:`jaxmocap.tracking.options`;
* **initialisation** — :mod:`jaxmocap.tracking.init`;
* **loop and outputs** — :mod:`jaxmocap.tracking.loop` (track loss, re-initialisation, resume) and
  :mod:`jaxmocap.tracking.run_folder`.
"""

from __future__ import annotations

import os

from jaxmocap.tracking.loop import TrackingLoop
from jaxmocap.tracking.options import TrackOptions
from jaxmocap.tracking.setup import TrackSetup

__all__ = ["Tracker"]


class Tracker(TrackingLoop):
    """One tracking run: ``Tracker(source, out, options).run()``.

    Attributes after construction (those of its :class:`~jaxmocap.tracking.setup.TrackSetup`, ``setup``):
    ``model``, ``likelihood``, ``cues`` (``(name, weight)``), ``frames`` (the input frame numbers to track),
    ``features``, ``num_particles``, ``layers``, ``std``; ``filter`` once the run has started; ``trace_count``
    (traces of the filter step: 0 when a warm run read it back from disk) and ``step_programs`` (traced or read
    back: 1).
    """

    def __init__(
        self, source, out: str | os.PathLike, options: TrackOptions | None = None, quiet: bool = False
    ):
        super().__init__(TrackSetup(source, options), out, quiet)
