"""Generic particle filters (BlackJAX style: ``init(key, ...) -> State``, ``step(key, state, observation) -> (State,
Info)``, pure and jit-able), parametrised by a batched log-likelihood.

* :mod:`~jaxmocap.filters.sir` — SIR / CONDENSATION, ``loglik_batch(X, observation)``;
* :mod:`~jaxmocap.filters.icondensation` — ICONDENSATION, ``loglik_batch(X, observation)``;
* :mod:`~jaxmocap.filters.apf` — APF, IAPF, PARSEC mode, ``loglik_batch(X, observation, layer)``;
* :mod:`~jaxmocap.filters.partitioned` — partitioned sampling, ``loglik_batch(X, observation, k)``, and hierarchical
  sampling, ``loglik_batch(X, observation, layer)``;
* :mod:`~jaxmocap.filters.base` — shared pieces and :func:`~jaxmocap.filters.base.run` (``lax.scan`` over frames).
"""

from jaxmocap.filters.apf import APF, ignore_layer
from jaxmocap.filters.base import Info, Layer, LayerStats, State, run
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
