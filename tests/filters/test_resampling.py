"""Resampling schemes: unbiased offspring counts, the structural guarantees of each scheme, variance ordering,
non-finite weights. Statistical checks use fixed keys and bounds derived from the number of repeats."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import norm

from jaxmocap.filters import resampling

N = 40
R = 2000  # repeats
SCHEMES = sorted(resampling.SCHEMES)


def _weights(seed=0):
    """Skewed weights with a few exact zeros (log-weight -inf) and one NaN entry."""
    rng = np.random.default_rng(seed)
    w = rng.gamma(0.5, size=N)
    w[[3, 17]] = 0.0
    w /= w.sum()
    lw = np.log(np.where(w > 0, w, 1.0)) + 7.3  # unnormalised on purpose
    lw[[3, 17]] = -np.inf
    lw[25] = np.nan
    w[25] = 0.0
    w /= w.sum()
    return jnp.asarray(lw, jnp.float32), w


def _counts(scheme, log_w, num_samples, key):
    fn = resampling.get(scheme)

    @jax.jit
    def one(k):
        anc = fn(k, log_w, num_samples)
        return jnp.bincount(anc, length=log_w.shape[0]), anc

    counts, anc = jax.vmap(one)(jax.random.split(key, R))
    return np.asarray(counts), np.asarray(anc)


@pytest.fixture(scope="module")
def draws():
    log_w, w = _weights()
    out = {}
    for i, scheme in enumerate(SCHEMES):
        for m in (N, 3 * N + 7):
            out[scheme, m] = _counts(scheme, log_w, m, jax.random.key(100 + 10 * i + m, impl="rbg"))
    return w, out


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("factor", [1, 3])
def test_unbiased_offspring_counts(draws, scheme, factor):
    """Mean offspring count over R repeats equals M w_i within a Bonferroni z-bound (family-wise 1e-3).

    Every scheme has Var n_i ≤ M w_i (multinomial: M w(1-w); residual/stratified: a sum of Bernoullis with total mean
    at most M w_i; systematic: f(1-f) with f = frac(M w_i) ≤ M w_i), so the standard error of the mean is at most
    sqrt(M w_i / R)."""
    w, out = draws
    m = N if factor == 1 else 3 * N + 7
    counts, anc = out[scheme, m]
    assert anc.dtype == np.int32 and anc.shape == (R, m)
    assert np.all(counts.sum(axis=1) == m)
    var = m * w * (1 - w) if scheme == "multinomial" else m * w
    z = norm.isf(1e-3 / (2 * N))
    mean = counts.mean(axis=0)
    se = np.sqrt(var / R)
    assert np.all(np.abs(mean - m * w) <= z * se + 1e-12), np.max(
        np.abs(mean - m * w) / np.maximum(se, 1e-12)
    )
    # dead particles (-inf, NaN) are never selected
    assert np.all(counts[:, [3, 17, 25]] == 0)


def test_structural_guarantees(draws):
    """Systematic: every count is ⌊M w⌋ or ⌈M w⌉. Stratified: within one of those. Residual: at least ⌊M w⌋."""
    w, out = draws
    for m in (N, 3 * N + 7):
        mw = m * w
        eps = 1e-4 * m  # float32 cumulative sums may move a point across a boundary that M w_i touches
        lo, hi = np.floor(mw - eps), np.ceil(mw + eps)
        sys_c = out["systematic", m][0]
        assert np.all((sys_c >= lo) & (sys_c <= hi))
        strat_c = out["stratified", m][0]
        assert np.all((strat_c >= lo - 1) & (strat_c <= hi + 1))
        res_c = out["residual", m][0]
        assert np.all(res_c >= lo)


def test_variance_ordering(draws):
    """Multinomial total variance matches M(1 - Σw²); stratified, systematic and residual are lower.

    The relative standard error of a sample variance over R repeats is about sqrt((2 + κ)/R) with κ ≤ 1 the excess
    kurtosis of a count with mean ≥ 1, i.e. ≤ 3.9 % here; 5 of those bound the check on the multinomial."""
    w, out = draws
    m = N
    totals = {s: out[s, m][0].var(axis=0, ddof=1).sum() for s in SCHEMES}
    expected = m * (1 - np.sum(w**2))
    assert abs(totals["multinomial"] / expected - 1) < 5 * math.sqrt(3 / R)
    for s in ("stratified", "systematic", "residual"):
        assert totals[s] < 0.8 * expected, (s, totals[s], expected)
    assert totals["systematic"] <= totals["stratified"] * 1.1


@pytest.mark.parametrize("scheme", SCHEMES)
def test_all_dead_is_uniform_and_jittable(scheme):
    """No finite log-weight: the scheme treats the weights as uniform instead of failing or returning garbage."""
    fn = jax.jit(resampling.get(scheme), static_argnums=2)
    lw = jnp.full((8,), -jnp.inf).at[2].set(jnp.nan)
    anc = np.asarray(fn(jax.random.key(0, impl="rbg"), lw, 8000))
    counts = np.bincount(anc, minlength=8)
    # uniform: each count ~ Binomial(8000, 1/8), sd ≈ 29.6; 6 sd
    assert np.all(np.abs(counts - 1000) < 6 * math.sqrt(8000 * (1 / 8) * (7 / 8)))


def test_point_mass_and_shapes():
    lw = jnp.full((5,), -jnp.inf).at[3].set(0.0)
    for scheme in SCHEMES:
        anc = resampling.get(scheme)(jax.random.key(1, impl="rbg"), lw, 11)
        assert anc.shape == (11,) and np.all(np.asarray(anc) == 3)


def test_normalised_weights_and_unknown_scheme():
    lw = jnp.log(jnp.asarray([1.0, 2.0, 3.0, 4.0])) - 50.0
    np.testing.assert_allclose(np.asarray(resampling.normalised_weights(lw)), [0.1, 0.2, 0.3, 0.4], rtol=1e-5)
    with pytest.raises(ValueError, match="unknown resampling scheme"):
        resampling.get("bogus")
