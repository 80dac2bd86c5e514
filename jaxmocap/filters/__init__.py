"""Generic particle filters (BlackJAX style: ``init(key, ...) -> State``, ``step(key, state, observation) -> (State,
Info)``, pure and jit-able), parametrised by a batched log-likelihood.

Every filter calls its likelihood as ``loglik_batch(X (N, D), observation, layer) -> (N,)`` with ``layer`` a
:class:`~jaxmocap.filters.base.Layer` (``index``, ``beta``, ``partition``; :func:`~jaxmocap.filters.base.ignore_layer`
adapts a likelihood without it).

* :mod:`~jaxmocap.filters.sir` — SIR / CONDENSATION;
* :mod:`~jaxmocap.filters.icondensation` — ICONDENSATION;
* :mod:`~jaxmocap.filters.apf` — APF, IAPF, PARSEC mode;
* :mod:`~jaxmocap.filters.partitioned` — partitioned and hierarchical sampling;
* :mod:`~jaxmocap.filters.hybrid` — the APF with gradient moves;
* :mod:`~jaxmocap.filters.factory` — every filter by name around a body model;
* :mod:`~jaxmocap.filters.base` — shared pieces and :func:`~jaxmocap.filters.base.run` (``lax.scan`` over frames).
"""

from jaxmocap.filters.apf import APF
from jaxmocap.filters.base import Info, Layer, LayerStats, State, ignore_layer, run
from jaxmocap.filters.icondensation import ICondensation
from jaxmocap.filters.partitioned import Partitioned, hierarchical
from jaxmocap.filters.sir import SIR

__all__ = [
    "APF",
    "SIR",
    "ICondensation",
    "Info",
    "Layer",
    "LayerStats",
    "Partitioned",
    "State",
    "hierarchical",
    "ignore_layer",
    "run",
]
