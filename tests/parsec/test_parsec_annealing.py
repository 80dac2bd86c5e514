"""PARSEC bodytrack's annealing: its β bisection against float64 root-finding (scipy) and its quirks, its
diffusion schedule against the reference report, and its rule inside the core's schedule under jit."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq

from jaxmocap.filters import annealing
from jaxmocap.parsec.annealing import parsec_beta, parsec_diffusion_scales, parsec_rule, parsec_schedule


def _alpha64(beta, ll):
    """Survival rate of exp(β ll) in float64 over the live entries, dead (non-finite) ones counted in N."""
    ll = np.asarray(ll, np.float64)
    e = np.exp(beta * (ll[np.isfinite(ll)] - np.nanmax(np.where(np.isfinite(ll), ll, np.nan))))
    return e.sum() ** 2 / (e**2).sum() / ll.size


# PARSEC's own debug vector for its β search (AnnealingFactor.cpp, set_ets; Apache-2.0, PARSEC 3.0 bodytrack)
_PARSEC_ETS = np.array(
    [0.0431287287, 0.0, 0.1890535963, 0.1314251348, 0.1744840913, 0.1724611824, 0.1665666636, 0.1008506786,
     0.1570010271, 0.1469321041, 0.0941946672, 0.0873843544, 0.1011394290, 0.1401914942, 0.0944126324,
     0.1747114664, 0.0861499931, 0.1744767988, 0.1881925406, 0.0845404237, 0.1416303064, 0.1722650238,
     0.0353243611, 0.1919276523, 0.1255045773]
)  # fmt: skip


def test_parsec_beta():
    fn = jax.jit(parsec_beta)
    sol = fn(jnp.asarray(_PARSEC_ETS, jnp.float32))
    root = brentq(lambda b: _alpha64(b, _PARSEC_ETS) - 0.5, 0.0, 1000.0, xtol=1e-12)
    assert int(sol.status) == annealing.STATUS_OK
    assert abs(_alpha64(float(sol.beta), _PARSEC_ETS) - 0.5) <= 2e-5  # its precision is 1e-5 on α in float32
    assert float(sol.beta) == pytest.approx(root, rel=1e-3)
    # shifting the log-likelihoods changes nothing (w = ll - min ll)
    assert float(fn(jnp.asarray(_PARSEC_ETS - 3.0, jnp.float32)).beta) == pytest.approx(
        float(sol.beta), rel=1e-5
    )
    # invalid particles are dropped from N
    with_dead = jnp.asarray(np.r_[_PARSEC_ETS, -np.inf, np.nan], jnp.float32)
    assert float(fn(with_dead).beta) == pytest.approx(float(sol.beta), rel=1e-5)
    # no sign change over [0, 1000] → 1.0
    flat = fn(jnp.zeros(50))
    assert float(flat.beta) == 1.0 and int(flat.status) == annealing.STATUS_BETA_MAX


def test_parsec_overflow_quirk():
    """With one particle 1000 below the others α stays ≈ 1 up to β·1000 = 40, where the guard declares β too large:
    the bisection ends near β = 40 / 1000 without reaching α = 0.5 (Deutscher's rule returns β_max here)."""
    ll = jnp.asarray(np.r_[np.zeros(999), -1000.0], jnp.float32)
    sol = jax.jit(parsec_beta)(ll)
    assert int(sol.status) == annealing.STATUS_MAXITER
    assert float(sol.beta) == pytest.approx(0.04, rel=1e-4)
    assert int(jax.jit(annealing.solve_beta)(ll).status) == annealing.STATUS_BETA_MAX


def test_parsec_diffusion_scales_match_reference_report():
    """The STDDEV lines of PARSEC's probe report (sequenceB_2, 5 layers; first DOF) divided by σ_0, in run order
    (layers run k = 4 … 0)."""
    stddev_by_k = [0.0113386102, 0.00283465208, 0.00400880352, 0.00566930464, 0.00801760796]  # k = 0 … 4
    expected = [stddev_by_k[k] / stddev_by_k[0] for k in (4, 3, 2, 1, 0)]
    np.testing.assert_allclose(parsec_diffusion_scales(5), expected, rtol=1e-6)
    assert parsec_diffusion_scales(1) == (1.0,)
    s = parsec_schedule(5)
    assert s.kind == "rule" and s.beta_rule is parsec_rule
    assert s.scales == parsec_diffusion_scales(5) and s.beta_max == 1000.0


def test_parsec_rule_with_traced_layer():
    """The core's choose_beta with PARSEC's rule: β by bisection to α = 0.5 at every layer, inside one jit."""
    schedule = parsec_schedule(3)
    ll = jnp.asarray(np.random.default_rng(1).normal(size=400), jnp.float32)

    @jax.jit
    def run(ll):
        def body(carry, layer):
            sol = annealing.choose_beta(schedule, ll * (1.0 + layer), layer, *carry)
            return (sol.beta, sol.survival_rate), sol

        return jax.lax.scan(body, (jnp.float32(0.0), jnp.float32(1.0)), jnp.arange(3))[1]

    betas = np.asarray(run(ll).beta)
    for l in range(3):
        assert abs(_alpha64(betas[l], np.asarray(ll) * (1 + l)) - 0.5) < 1e-3
    # the same β as the rule called directly
    assert float(betas[0]) == pytest.approx(float(jax.jit(parsec_beta)(ll).beta), rel=1e-6)
