"""Gaussian mixtures fitted by expectation–maximisation, with the number of components chosen by BIC: the
mode-counting test of López Méndez (2009, §5.2.1), which counts the modes of a likelihood from a particle set
resampled in proportion to it (fewer modes: a less ambiguous cue).

Model (``K`` components, full covariances, ``x ∈ R^d``):

    ``p(x) = Σ_k π_k N(x; μ_k, Σ_k)``

EM (Dempster, Laird & Rubin 1977): E-step responsibilities ``r_ik = π_k N(x_i; μ_k, Σ_k) / p(x_i)`` (in log space);
M-step ``N_k = Σ_i r_ik``, ``π_k = N_k / n``, ``μ_k = Σ_i r_ik x_i / N_k``,
``Σ_k = Σ_i r_ik (x_i − μ_k)(x_i − μ_k)ᵀ / N_k + ε I`` (``ε = reg`` times the mean data variance keeps a component
from collapsing onto one point, which resampled particle sets, full of copies, invite). Iterates until the mean
log-likelihood changes by less than ``tol``; several starts (k-means++ seeding) keep the best.

Model selection: ``BIC = −2 log L + p log n`` with ``p = (K − 1) + K d + K d (d + 1) / 2`` free parameters
(Schwarz 1978); :func:`count_modes` fits ``K = 1 … K_max`` and returns the ``K`` of least BIC.

Host-side NumPy (float64): these are analysis tools for notebooks and studies, not part of a filter's hot path.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["Mixture", "bic", "count_layer_modes", "count_modes", "fit", "log_likelihood", "num_parameters"]


class Mixture(NamedTuple):
    """A fitted mixture: weights ``(K,)``, means ``(K, d)``, covariances ``(K, d, d)``, the total log-likelihood of
    the data it was fitted to, the EM iterations used and whether the tolerance was met."""

    weights: np.ndarray
    means: np.ndarray
    covariances: np.ndarray
    log_likelihood: float
    iterations: int
    converged: bool

    @property
    def num_components(self) -> int:
        return int(self.weights.shape[0])


def _as_data(X) -> np.ndarray:
    X = np.asarray(X, np.float64)
    if X.ndim == 1:
        X = X[:, None]
    if X.ndim != 2 or X.shape[0] < 1:
        raise ValueError(f"data must be (n, d) with n ≥ 1, got shape {X.shape}")
    if not np.all(np.isfinite(X)):
        raise ValueError("data must be finite")
    return X


def _component_logpdf(X: np.ndarray, means: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """``log N(x_i; μ_k, Σ_k)`` as ``(n, K)``, by Cholesky factors."""
    n, d = X.shape
    out = np.empty((n, means.shape[0]))
    for k in range(means.shape[0]):
        Lk = np.linalg.cholesky(covs[k])
        z = np.linalg.solve(Lk, (X - means[k]).T)  # (d, n)
        out[:, k] = -0.5 * np.sum(z * z, axis=0) - np.sum(np.log(np.diag(Lk))) - 0.5 * d * np.log(2 * np.pi)
    return out


def _logsumexp(a: np.ndarray, axis: int) -> np.ndarray:
    m = np.max(a, axis=axis, keepdims=True)
    return np.squeeze(m, axis) + np.log(np.sum(np.exp(a - m), axis=axis))


def log_likelihood(mixture: Mixture, X) -> np.ndarray:
    """``log p(x_i)`` of every row of ``X (n, d)`` under ``mixture``: ``(n,)``."""
    X = _as_data(X)
    lp = _component_logpdf(X, mixture.means, mixture.covariances) + np.log(mixture.weights)
    return _logsumexp(lp, axis=1)


def num_parameters(num_components: int, dim: int) -> int:
    """Free parameters of a full-covariance mixture: ``(K − 1) + K d + K d (d + 1) / 2``."""
    K, d = num_components, dim
    return (K - 1) + K * d + K * d * (d + 1) // 2


def bic(mixture: Mixture, num_samples: int, dim: int) -> float:
    """Bayesian information criterion ``−2 log L + p log n`` (lower is better)."""
    return -2.0 * mixture.log_likelihood + num_parameters(mixture.num_components, dim) * np.log(num_samples)


def _kmeans_pp(rng: np.random.Generator, X: np.ndarray, K: int) -> np.ndarray:
    """k-means++ seeding (Arthur & Vassilvitskii 2007): ``K`` rows of ``X`` as initial means."""
    n = X.shape[0]
    centres = [X[rng.integers(n)]]
    d2 = np.sum((X - centres[0]) ** 2, axis=1)
    for _ in range(1, K):
        total = d2.sum()
        i = rng.integers(n) if total <= 0 else rng.choice(n, p=d2 / total)
        centres.append(X[i])
        d2 = np.minimum(d2, np.sum((X - X[i]) ** 2, axis=1))
    return np.stack(centres)


def _em(X, means, reg_eps, max_iter, tol) -> Mixture:
    n, d = X.shape
    K = means.shape[0]
    # initial covariances: the data covariance for every component; equal weights
    base = np.atleast_2d(np.cov(X.T, bias=True)) + reg_eps * np.eye(d)
    covs = np.repeat(base[None], K, axis=0)
    weights = np.full(K, 1.0 / K)
    prev = -np.inf
    converged = False
    iterations = 0
    for _ in range(max_iter):
        iterations += 1
        lp = _component_logpdf(X, means, covs) + np.log(weights)
        lse = _logsumexp(lp, axis=1)
        ll = float(lse.sum())
        r = np.exp(lp - lse[:, None])  # (n, K)
        Nk = r.sum(axis=0) + 1e-300
        weights = Nk / n
        means = (r.T @ X) / Nk[:, None]
        for k in range(K):
            Z = X - means[k]
            covs[k] = (r[:, k, None] * Z).T @ Z / Nk[k] + reg_eps * np.eye(d)
        if abs(ll - prev) <= tol * n:
            converged = True
            break
        prev = ll
    lp = _component_logpdf(X, means, covs) + np.log(weights)
    ll = float(_logsumexp(lp, axis=1).sum())
    return Mixture(weights, means, covs, ll, iterations, converged)


def fit(
    X,
    num_components: int,
    rng: np.random.Generator,
    *,
    restarts: int = 3,
    max_iter: int = 200,
    tol: float = 1e-6,
    reg: float = 1e-3,
) -> Mixture:
    """Fit a ``K``-component full-covariance mixture to ``X (n, d)`` by EM from ``restarts`` k-means++ starts.

    ``rng``: a NumPy ``Generator`` (the seeding is random); ``tol``: stop when the mean log-likelihood per sample
    changes by at most this; ``reg``: the covariance floor ``ε = reg · mean variance of X`` added to every Σ_k.
    Returns the start with the largest log-likelihood.
    """
    X = _as_data(X)
    n, d = X.shape
    K = int(num_components)
    if not 1 <= K <= n:
        raise ValueError(f"num_components must lie in [1, n = {n}], got {K}")
    scale = float(np.mean(np.var(X, axis=0)))
    reg_eps = reg * (scale if scale > 0 else 1.0)
    best = None
    for _ in range(max(1, restarts) if K > 1 else 1):
        m = _em(X, _kmeans_pp(rng, X, K), reg_eps, max_iter, tol)
        if best is None or m.log_likelihood > best.log_likelihood:
            best = m
    return best


def count_modes(
    X, rng: np.random.Generator, max_components: int = 6, **fit_kw
) -> tuple[int, list[Mixture], np.ndarray]:
    """Number of mixture components by BIC for ``X (n, d)``: ``(K*, fits for K = 1 … K_max, BIC values)``."""
    X = _as_data(X)
    n, d = X.shape
    fits, scores = [], []
    for K in range(1, min(max_components, n) + 1):
        m = fit(X, K, rng, **fit_kw)
        fits.append(m)
        scores.append(bic(m, n, d))
    scores = np.asarray(scores)
    return int(np.argmin(scores)) + 1, fits, scores


def count_layer_modes(
    particles,
    log_weights,
    rng: np.random.Generator,
    dims: int = 2,
    max_components: int = 4,
    *,
    restarts: int = 2,
    max_iter: int = 100,
    tol: float = 1e-4,
    reg: float = 0.05,
) -> list[int]:
    """Modes of each annealing layer's particle set (López Méndez §5.2.1) by :func:`count_modes`.

    ``particles (L, N, D)``, ``log_weights (L, N)`` (normalised or not): per layer, ``N`` particles are drawn in
    proportion to the weights (systematic resampling: the set the next layer starts from), each DOF is
    standardised over that set (metres and radians become comparable; a DOF that does not vary is left out), and
    the modes are counted by BIC on the first ``dims`` principal components (in all ``D`` dimensions a full
    covariance costs ``D (D + 3) / 2`` parameters per component, which a few hundred particles cannot pay for).
    The fit is coarser than :func:`fit`'s defaults (fewer starts and iterations: it runs per frame when a
    tracking run asks for it) and its covariance floor larger (``reg`` 0.05 of the mean variance: a resampled set
    is full of copies, on which a tight component would otherwise buy likelihood). Returns ``L`` counts in
    ``1 … max_components``.
    """
    fit_kw = dict(restarts=restarts, max_iter=max_iter, tol=tol, reg=reg)
    X = np.asarray(particles, np.float64)
    lw = np.asarray(log_weights, np.float64)
    if X.ndim != 3 or lw.shape != X.shape[:2]:
        raise ValueError(f"need particles (L, N, D) and log_weights (L, N), got {X.shape} and {lw.shape}")
    out = []
    for x, w in zip(X, lw, strict=True):
        w = np.where(np.isfinite(w), w, -np.inf)
        p = np.exp(w - np.max(w))
        p /= p.sum()
        n = len(p)
        picks = np.minimum(np.searchsorted(np.cumsum(p), (rng.uniform() + np.arange(n)) / n), n - 1)
        s = x[picks]
        sd = s.std(axis=0)
        z = (s[:, sd > 1e-9] - s[:, sd > 1e-9].mean(axis=0)) / sd[sd > 1e-9]
        if z.shape[1] == 0:
            out.append(1)
            continue
        _, _, vt = np.linalg.svd(z, full_matrices=False)
        k, _, _ = count_modes(z @ vt[: min(dims, z.shape[1])].T, rng, max_components, **fit_kw)
        out.append(int(k))
    return out
