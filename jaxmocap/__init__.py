"""jaxmocap: differentiable markerless human motion capture with particle filters, in JAX.

The packages follow a frame's way through the tracker: :mod:`~jaxmocap.geometry` (kinematics, bodies, flesh,
cameras) → :mod:`~jaxmocap.features` (images to an :class:`~jaxmocap.features.observation.Observation`) →
:mod:`~jaxmocap.likelihood` (cues and their Gibbs-form sum) → :mod:`~jaxmocap.filters` (particle filters) →
:mod:`~jaxmocap.tracking` (setup and the frame loop), with :mod:`~jaxmocap.fit` (IK, shape), :mod:`~jaxmocap.io`
(frame sources, calibration, mocap, exports) and :mod:`~jaxmocap.eval` (metrics, plots) beside them, and two wings
that depend on the core and never the other way: :mod:`~jaxmocap.synth` (synthetic sequences) and
:mod:`~jaxmocap.parsec` (PARSEC bodytrack's tracker).

The names below are the public API, imported on first use (``import jaxmocap`` itself stays light)::

    import jaxmocap
    rig = jaxmocap.load_calibration("calib.toml")
    result = jaxmocap.track(videos=["a.mp4", "b.mp4"], calibration="calib.toml", particles=300)
    result.joints  # (T, 15, 3)
    tracker = jaxmocap.Tracker(source, "run1", jaxmocap.TrackOptions(filter="apf", particles=300))
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: public name -> module that defines it
_API = {
    # tracking
    "track": "jaxmocap.api",
    "TrackResult": "jaxmocap.api",
    "Tracker": "jaxmocap.tracking.tracker",
    "TrackOptions": "jaxmocap.tracking.options",
    "TrackSetup": "jaxmocap.tracking.setup",
    "SequenceSource": "jaxmocap.io.sources",
    "VideoSource": "jaxmocap.io.sources",
    # likelihood
    "Likelihood": "jaxmocap.likelihood.compose",
    "CueSpec": "jaxmocap.likelihood.cues",
    "Observation": "jaxmocap.features.observation",
    # filters
    "APF": "jaxmocap.filters.apf",
    "SIR": "jaxmocap.filters.sir",
    "ICondensation": "jaxmocap.filters.icondensation",
    "Partitioned": "jaxmocap.filters.partitioned",
    "hierarchical": "jaxmocap.filters.partitioned",
    "HybridAPF": "jaxmocap.filters.hybrid",
    "Schedule": "jaxmocap.filters.annealing",
    "make_filter": "jaxmocap.filters.factory",
    # geometry
    "BodyModel": "jaxmocap.geometry.body",
    "build_body": ("jaxmocap.geometry.body", "build"),
    "Rig": "jaxmocap.geometry.camera",
    # io
    "load_calibration": "jaxmocap.io.calibration",
    "save_calibration": "jaxmocap.io.calibration",
    "MocapInputError": "jaxmocap.errors",
}

__all__ = ["__version__", *sorted(_API)]


def __getattr__(name: str):
    where = _API.get(name)
    if where is None:
        raise AttributeError(f"module 'jaxmocap' has no attribute {name!r}")
    module, attr = where if isinstance(where, tuple) else (where, name)
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_API))
