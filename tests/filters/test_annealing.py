"""Survival rate / ESS against their closed forms, the β solvers inside jit against float64 root-finding (scipy),
the thesis correction, schedules (PARSEC's rule and quirks: tests/parsec/test_parsec_annealing.py)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq

from jaxmocap.filters import annealing
from jaxmocap.filters.annealing import Schedule


def _alpha64(beta, ll):
    """Survival rate of exp(β ll) in float64, dead (non-finite) entries counted in N."""
    ll = np.asarray(ll, np.float64)
    live = np.isfinite(ll)
    d = ll[live] - ll[live].max()
    e = np.exp(beta * d)
    return e.sum() ** 2 / (e**2).sum() / ll.size


def _vectors():
    rng = np.random.default_rng(7)
    n = 1000
    return {
        "gaussian": rng.normal(size=n),
        "huge_outlier": np.r_[np.zeros(n - 1), 1e6],
        "outlier_over_noise": np.r_[1e-3 * rng.normal(size=n - 1), 50.0],
        "cauchy_tails": 100.0 * rng.standard_cauchy(n),
        "lognormal_scale": -np.exp(3.0 * rng.normal(size=n)),
        "with_neg_inf": np.r_[rng.normal(size=n - 150), np.full(150, -np.inf)],
        "with_nan_and_inf": np.r_[rng.normal(size=n - 20), np.full(10, np.nan), np.full(10, np.inf)],
        "large_offset": 1e4 + 0.01 * rng.normal(size=n),
        "small_set": rng.normal(size=7),
    }


def test_survival_rate_and_ess_closed_form():
    rng = np.random.default_rng(0)
    w = rng.gamma(0.3, size=500)
    lw = jnp.asarray(np.log(w) - 30.0, jnp.float32)
    expected = w.sum() ** 2 / (w**2).sum()
    np.testing.assert_allclose(float(annealing.ess(lw)), expected, rtol=1e-4)
    np.testing.assert_allclose(float(annealing.survival_rate(lw)), expected / 500, rtol=1e-4)
    assert float(annealing.ess(jnp.zeros(64))) == pytest.approx(64.0, rel=1e-6)
    one_hot = jnp.full((64,), -jnp.inf).at[5].set(3.0)
    assert float(annealing.ess(one_hot)) == pytest.approx(1.0, rel=1e-6)
    assert float(annealing.ess(jnp.full((4,), jnp.nan))) == 0.0
    # dead particles count in N
    half_dead = jnp.asarray([0.0, 0.0, -jnp.inf, jnp.nan])
    assert float(annealing.survival_rate(half_dead)) == pytest.approx(0.5, rel=1e-6)


def test_tempered_survival_rate_matches_float64():
    ll = _vectors()["cauchy_tails"]
    for beta in (0.0, 1e-4, 3e-3, 0.1):
        got = float(jax.jit(annealing.tempered_survival_rate)(beta, jnp.asarray(ll, jnp.float32)))
        assert got == pytest.approx(_alpha64(beta, ll), rel=1e-4, abs=1e-6)


@pytest.mark.parametrize("target", [0.5, 0.2, 0.8])
def test_solve_beta_hits_target_inside_jit(target):
    """|α(β) - α_target| < 1e-3 (evaluated independently in float64) and β equals the float64 root (brentq)."""
    vectors = _vectors()
    solve = jax.jit(annealing.solve_beta, static_argnames=("target",))
    for name, ll in vectors.items():
        ll = np.asarray(ll, np.float32).astype(np.float64)  # the reference sees the same (float32) input
        sol = solve(jnp.asarray(ll, jnp.float32), target=target)
        beta = float(sol.beta)
        assert int(sol.status) == annealing.STATUS_OK, name
        alpha = _alpha64(beta, ll)
        assert abs(alpha - target) < 1e-3, (name, beta, alpha)
        assert float(sol.survival_rate) == pytest.approx(alpha, abs=1e-4)
        root = brentq(lambda b, ll=ll: _alpha64(b, ll) - target, 0.0, 1e3, xtol=1e-14, rtol=1e-12)
        assert beta == pytest.approx(root, rel=1e-2), name


def test_solve_beta_is_vmappable():
    rng = np.random.default_rng(3)
    lls = jnp.asarray(rng.normal(size=(5, 300)) * np.array([[0.1], [1], [10], [100], [1e4]]), jnp.float32)
    sols = jax.jit(jax.vmap(annealing.solve_beta))(lls)
    for ll, beta in zip(np.asarray(lls), np.asarray(sols.beta), strict=True):
        assert abs(_alpha64(beta, ll) - 0.5) < 1e-3


def test_solve_beta_fallbacks():
    solve = jax.jit(annealing.solve_beta)
    # all equal: α ≡ 1, no root → β_max
    sol = solve(jnp.zeros(100))
    assert int(sol.status) == annealing.STATUS_BETA_MAX and float(sol.beta) == 1e3
    # ties at the maximum keep α ≥ 0.6 for every β → β_max
    sol = solve(jnp.asarray(np.r_[np.zeros(60), -np.ones(40)], jnp.float32))
    assert int(sol.status) == annealing.STATUS_BETA_MAX and float(sol.beta) == 1e3
    # 70 % dead: α(0) = 0.3 < 0.5 → β = 0 (uniform over the live ones)
    ll = np.r_[np.random.default_rng(0).normal(size=30), np.full(70, -np.inf)]
    sol = solve(jnp.asarray(ll, jnp.float32))
    assert int(sol.status) == annealing.STATUS_BETA_ZERO and float(sol.beta) == 0.0
    assert float(sol.survival_rate) == pytest.approx(0.3, rel=1e-5)
    # nothing alive: no NaN
    sol = solve(jnp.full((10,), -jnp.inf))
    assert np.isfinite(float(sol.beta)) and float(sol.survival_rate) == 0.0


def test_corrected_beta():
    """López Méndez eq. 6.4: β(l) = β(l-1) - ε(α_target - α(l-1)), ε = 1/(1+l), non-decreasing."""
    f = jax.jit(annealing.corrected_beta, static_argnames=("target", "monotone"))
    # too many survivors (α = 0.9 > 0.5): β grows by ε (0.9 - 0.5) = 0.4 / 3 at l = 2
    assert float(f(2.0, 0.9, 2)) == pytest.approx(2.0 + 0.4 / 3, rel=1e-6)
    # too few survivors: the formula lowers β; the non-decreasing rule keeps it
    assert float(f(2.0, 0.1, 1, monotone=False)) == pytest.approx(2.0 - 0.5 * 0.4, rel=1e-6)
    assert float(f(2.0, 0.1, 1)) == pytest.approx(2.0, rel=1e-6)
    assert float(f(0.05, 0.0, 1, monotone=False)) == 0.0


def test_schedules():
    betas, dyn = annealing.iros2007_exponents()
    assert betas.shape == dyn.shape == (3,)
    s = Schedule.iros2007()
    np.testing.assert_allclose(s.betas, np.asarray(betas), rtol=1e-6)
    np.testing.assert_allclose(s.scales, 1 / np.sqrt(np.asarray(dyn)), rtol=1e-6)
    assert hash(s) == hash(Schedule.iros2007())
    with pytest.raises(ValueError):
        Schedule(kind="fixed", num_layers=2, betas=(1.0,))
    with pytest.raises(ValueError):
        Schedule(kind="nope")
    with pytest.raises(ValueError):  # a rule schedule needs its rule, and only it takes one
        Schedule(kind="rule", num_layers=2)
    with pytest.raises(ValueError):
        Schedule(kind="survival", beta_rule=_deutscher_rule)
    with pytest.raises(ValueError):
        Schedule.deutscher(3, diffusion_scales=(1.0, 0.5))


def _deutscher_rule(ll, schedule):
    """Deutscher's rule as a caller's ``beta_rule`` (the hook a wing's rule plugs into)."""
    return annealing.solve_beta(
        ll, schedule.survival_target, schedule.beta_max, schedule.tol, schedule.maxiter
    )


@pytest.mark.parametrize(
    "schedule",
    [
        Schedule.fixed((0.1, 0.4, 1.0)),
        Schedule.deutscher(3),
        Schedule(kind="corrected", num_layers=3),
        Schedule(kind="rule", num_layers=3, beta_rule=_deutscher_rule),
    ],
)
def test_choose_beta_with_traced_layer(schedule):
    ll = jnp.asarray(np.random.default_rng(1).normal(size=400), jnp.float32)

    @jax.jit
    def run(ll):
        def body(carry, layer):
            beta_prev, surv_prev = carry
            sol = annealing.choose_beta(schedule, ll * (1.0 + layer), layer, beta_prev, surv_prev)
            return (sol.beta, sol.survival_rate), sol

        return jax.lax.scan(body, (jnp.float32(0.0), jnp.float32(1.0)), jnp.arange(3))[1]

    sols = run(ll)
    betas = np.asarray(sols.beta)
    if schedule.kind == "fixed":
        np.testing.assert_allclose(betas, [0.1, 0.4, 1.0], rtol=1e-6)
    elif schedule.kind == "corrected":
        assert abs(float(sols.survival_rate[0]) - 0.5) < 1e-3  # layer 0 by Deutscher's rule
        assert np.all(np.diff(betas) >= 0)
        for l in (1, 2):  # the correction from the previous layer's measured survival rate
            expected = max(betas[l - 1], betas[l - 1] - (0.5 - float(sols.survival_rate[l - 1])) / (1 + l))
            assert betas[l] == pytest.approx(expected, rel=1e-5)
    else:
        for l in range(3):
            assert abs(_alpha64(betas[l], np.asarray(ll) * (1 + l)) - 0.5) < 1e-3
    assert math.isfinite(float(betas.sum()))
