"""Gaussian mixtures by EM with BIC selection: the one-component fit against the closed-form maximum-likelihood
estimate, mixture densities against SciPy, recovery of a known mixture, BIC's parameter count."""

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from jaxmocap.eval import mixtures as gmm


def _sample(rng, n_per, means, covs):
    X = np.concatenate([rng.multivariate_normal(m, c, n) for m, c, n in zip(means, covs, n_per, strict=True)])
    return X


def test_one_component_is_the_sample_mle():
    """K = 1: EM converges in one M-step to the sample mean and the biased sample covariance (+ the floor ε I)."""
    rng = np.random.default_rng(0)
    X = rng.normal(size=(300, 3)) @ np.array([[1.0, 0.3, 0.0], [0.0, 0.5, 0.2], [0.0, 0.0, 2.0]])
    m = gmm.fit(X, 1, np.random.default_rng(1), reg=1e-3)
    eps = 1e-3 * np.mean(np.var(X, axis=0))
    np.testing.assert_allclose(m.means[0], X.mean(0), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(m.covariances[0], np.cov(X.T, bias=True) + eps * np.eye(3), rtol=1e-10)
    assert m.weights[0] == pytest.approx(1.0)
    ref = multivariate_normal(X.mean(0), np.cov(X.T, bias=True) + eps * np.eye(3)).logpdf(X).sum()
    assert m.log_likelihood == pytest.approx(ref, rel=1e-10)


def test_mixture_density_matches_scipy():
    rng = np.random.default_rng(2)
    X = rng.normal(size=(50, 2))
    mix = gmm.Mixture(
        weights=np.array([0.2, 0.5, 0.3]),
        means=np.array([[0.0, 0.0], [1.0, -1.0], [-2.0, 0.5]]),
        covariances=np.array([np.eye(2), [[2.0, 0.5], [0.5, 1.0]], [[0.3, -0.1], [-0.1, 0.2]]]),
        log_likelihood=0.0,
        iterations=0,
        converged=True,
    )
    ref = np.log(
        sum(
            w * multivariate_normal(m, c).pdf(X)
            for w, m, c in zip(mix.weights, mix.means, mix.covariances, strict=True)
        )
    )
    np.testing.assert_allclose(gmm.log_likelihood(mix, X), ref, rtol=1e-10)


def test_count_modes_recovers_a_known_mixture():
    """Three well-separated clusters (200, 300, 500 points): BIC picks 3, and each fitted mean lies within
    4 standard errors (4 σ / √n_k per coordinate) of the cluster's true mean; weights within 4 binomial errors."""
    rng = np.random.default_rng(3)
    means = np.array([[0.0, 0.0], [6.0, 0.0], [0.0, 7.0]])
    covs = [np.eye(2) * 0.5, np.array([[1.0, 0.4], [0.4, 0.6]]), np.eye(2) * 0.8]
    n_per = (200, 300, 500)
    X = _sample(rng, n_per, means, covs)
    K, fits, scores = gmm.count_modes(X, np.random.default_rng(4), max_components=5)
    assert K == 3, scores
    m = fits[2]
    order = [int(np.argmin(np.linalg.norm(m.means - mu, axis=1))) for mu in means]
    assert sorted(order) == [0, 1, 2]
    n = sum(n_per)
    for j, k in enumerate(order):
        se = np.sqrt(np.diag(covs[j]) / n_per[j])
        assert np.all(np.abs(m.means[k] - means[j]) < 4 * se), (m.means[k], means[j])
        p = n_per[j] / n
        assert abs(m.weights[k] - p) < 4 * np.sqrt(p * (1 - p) / n)
    # the fitted log-likelihood is that of the returned parameters
    assert m.log_likelihood == pytest.approx(gmm.log_likelihood(m, X).sum(), rel=1e-9)


def test_single_blob_gives_one_mode_and_bic_counts_parameters():
    rng = np.random.default_rng(5)
    X = rng.normal(size=(400, 2))
    K, _, scores = gmm.count_modes(X, np.random.default_rng(6), max_components=4)
    assert K == 1, scores
    # (K − 1) + K d + K d (d + 1) / 2
    assert gmm.num_parameters(1, 2) == 5
    assert gmm.num_parameters(3, 2) == 2 + 6 + 9
    assert gmm.num_parameters(2, 25) == 1 + 50 + 650


def test_bad_input():
    with pytest.raises(ValueError, match="num_components"):
        gmm.fit(np.zeros((3, 2)), 4, np.random.default_rng(0))
    with pytest.raises(ValueError, match="finite"):
        gmm.fit(np.array([[0.0, np.nan]]), 1, np.random.default_rng(0))


def _layer_sets(rng, modes, N=200, D=13):
    """``(L, N, D)`` sets whose layer ``l`` is an equal mixture of ``modes[l]`` spherical Gaussians (σ 1 in
    standardised units) 12 σ apart along random directions, DOFs scaled like a pose (metres 0.05, radians 0.3)."""
    scale = np.where(np.arange(D) < 3, 0.05, 0.3)
    out = []
    for k in modes:
        centres = np.zeros((k, D))
        for j in range(1, k):
            d = rng.normal(size=D)
            centres[j] = centres[j - 1] + 12.0 * d / np.linalg.norm(d)
        out.append((centres[np.arange(N) % k] + rng.normal(size=(N, D))) * scale)
    return np.stack(out)


@pytest.mark.parametrize("seed", range(4))
def test_count_layer_modes_finds_the_known_modes_of_each_layer(seed):
    """Layers with 3, 2 and 1 well-separated modes (López Méndez §5.2.1's count, on the first two principal
    components of the resampled set), and a 2-mode layer whose weights sit on one mode: counted 3, 2, 1, 1."""
    rng = np.random.default_rng(seed)
    X = _layer_sets(rng, [3, 2, 1, 2])
    lw = np.zeros(X.shape[:2])
    lw[3, 0::2] = -np.inf  # layer 3: only the particles of mode 1 (odd indices) carry weight
    assert gmm.count_layer_modes(X, lw, np.random.default_rng(100 + seed)) == [3, 2, 1, 1]


def test_count_layer_modes_checks_shapes():
    with pytest.raises(ValueError, match=r"need particles \(L, N, D\) and log_weights \(L, N\)"):
        gmm.count_layer_modes(np.zeros((2, 5, 3)), np.zeros((2, 4)), np.random.default_rng(0))
