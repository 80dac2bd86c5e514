"""Particle filters against the Kalman filter on linear-Gaussian random walks, compile-once, recovery from dead
weights, joint limits, circular means, and a smoke run of the IROS 2007 synthetic benchmark.

Agreement with the Kalman filter (exact filters: SIR, ICONDENSATION with mixture weights, the APF in its exact limit,
partitioned and hierarchical sampling on a separable likelihood), from ``REPS`` independent runs on the same data:

* unbiasedness: for every frame and DOF, |mean over runs - Kalman mean| ≤ t·s/sqrt(REPS), s the sample std over runs
  and t the Student quantile (REPS - 1 degrees of freedom) for a two-sided family-wise error of 1e-3 over all T·D
  entries (Bonferroni);
* precision: the mean squared deviation from the Kalman mean is at most twice the Monte Carlo (delta-method)
  prediction V_t. A weighted mean over a set of effective size ESS has variance ≈ Var/ESS; resampling to N particles
  adds ≤ Var/N; an error δ in last frame's mean moves this frame's posterior mean by (1 - K) δ. Hence

      V_t = P_t / ESS_t + P⁻_t · Σ_{earlier stages s of frame t} (1/ESS_s + 1/N_s) + (1 - K_t)² (V_{t-1} + P_{t-1}/N),

  with P⁻ the predicted and P the posterior variance, V_{-1} = P_0 / N (the initial cloud). V_t ignores the errors
  of the cloud's shape (variance, tails) after a low-ESS frame, which feed into the next update when the innovation
  is large; on single frames they were measured to raise the variance up to 2.5-fold, over a whole run by ≤ 1.2-fold,
  hence the factor 2 on the run average.
"""

import dataclasses
import importlib.util
import pathlib
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import t as student_t

from jaxmocap.filters import base
from jaxmocap.filters.annealing import Schedule
from jaxmocap.filters.apf import APF
from jaxmocap.filters.icondensation import ICondensation
from jaxmocap.filters.partitioned import Partitioned, hierarchical
from jaxmocap.filters.sir import SIR

D, T = 3, 25
Q, R, P0 = 0.3, 0.5, 1.0  # dynamics std, observation std, initial variance


def key(seed):
    return jax.random.key(seed, impl="rbg")


class Obs(NamedTuple):
    """z (D,), a detection (D,) and its validity; ``dead``: 0 normal, 1 → every log-likelihood is -inf, 2 → NaN;
    ``dead_layer``: the annealing layer / partition that is dead (-1: all of them when ``dead`` is set)."""

    z: jnp.ndarray
    centre: jnp.ndarray
    valid: jnp.ndarray
    dead: jnp.ndarray
    dead_layer: jnp.ndarray


def _gauss(X, z, dims=None):
    if dims is not None:
        X, z = X[:, np.asarray(dims)], z[np.asarray(dims)]
    return -0.5 * jnp.sum((X - z) ** 2, axis=1) / R**2


def _kill(ll, obs, stage):
    dead_here = (obs.dead > 0) & ((obs.dead_layer < 0) | (obs.dead_layer == stage))
    bad = jnp.where(obs.dead == 2, jnp.nan, -jnp.inf)
    return jnp.where(dead_here, bad, ll)


def loglik(X, obs, layer):
    return _kill(_gauss(X, obs.z), obs, 0)


def loglik_layer(X, obs, layer):
    return _kill(_gauss(X, obs.z), obs, layer.index)


GROUPS = ((0, 1), (2,))


def loglik_partition(X, obs, layer):
    k = layer.partition
    return _kill(_gauss(X, obs.z, GROUPS[k]), obs, k)


def loglik_level(X, obs, layer):
    return _kill(_gauss(X, obs.z, GROUPS[layer.partition]), obs, layer.partition)


#: XLA's default code generation (the suite compiles for compile time, tests/conftest.py), for the steps below: the
#: Kalman comparisons run them hundreds of times on thousands of particles (their time is run time, ≈ 10 × longer
#: at level 0), and the bit-for-bit equality of two differently structured programs is a property of the code
#: generation users run
PRODUCTION = {"xla_backend_optimization_level": 3, "xla_cpu_use_fusion_emitters": True}
STEPS = {
    cls: jax.jit(cls.step, compiler_options=PRODUCTION) for cls in (SIR, ICondensation, APF, Partitioned)
}


def simulate(seed, dead=None):
    rng = np.random.default_rng(seed)
    x = np.sqrt(P0) * rng.normal(size=D) + np.cumsum(rng.normal(0, Q, (T, D)), axis=0)
    z = x + rng.normal(0, R, (T, D))
    det = x + rng.normal(0, 0.3, (T, D))
    code = np.zeros(T, np.int32)
    layer = np.full(T, -1, np.int32)
    for t, (c, l) in (dead or {}).items():
        code[t], layer[t] = c, l
    f32 = lambda a: jnp.asarray(a, jnp.float32)
    obs = Obs(f32(z), f32(det), jnp.ones(T, bool), jnp.asarray(code), jnp.asarray(layer))
    return x, z, obs


def kalman(z):
    m, P = np.zeros(D), P0
    means, post, pred, gain = [], [], [], []
    for zt in z:
        Pm = P + Q**2
        K = Pm / (Pm + R**2)
        m = m + K * (zt - m)
        P = (1 - K) * Pm
        means.append(m.copy()), post.append(P), pred.append(Pm), gain.append(K)
    return np.asarray(means), np.asarray(post), np.asarray(pred), np.asarray(gain)


def filter_sequence(f, seed, obs):
    """Run ``f`` over all frames with the shared jitted step (a Python loop: one compiled step for every frame)."""
    step = STEPS[type(f)]
    state = f.init(key(seed), jnp.zeros(D), jnp.full(D, np.sqrt(P0)))
    infos = []
    for t in range(T):
        frame = jax.tree_util.tree_map(lambda a, t=t: a[t], obs)
        state, info = step(f, jax.random.fold_in(key(seed + 1), t), state, frame)
        infos.append(info)
    return state, jax.tree_util.tree_map(lambda *a: np.stack([np.asarray(x) for x in a]), *infos)


REPS = 10


def check_against_kalman(f, seed, data_seed, stages):
    """Run ``f`` REPS times on one data set and check unbiasedness and precision (module docstring).

    ``stages(info) -> (final_ess (T,), earlier (T,), n_carry)``: the last weighting's ESS, the sums of
    1/ESS + 1/N over the earlier stages of each frame, and the particle count resampled at the start of a frame.
    """
    x, z, obs = simulate(data_seed)
    m, post, pred, gain = kalman(z)
    est, V = [], []
    for r in range(REPS):
        _, info = filter_sequence(f, seed + 1000 * r, obs)
        assert not info.recovered.any()
        final_ess, earlier, n_carry = stages(info)
        v = np.zeros(T)
        prev_v, prev_p = P0 / n_carry, P0
        for t in range(T):
            v[t] = (
                post[t] / final_ess[t]
                + pred[t] * earlier[t]
                + (1 - gain[t]) ** 2 * (prev_v + prev_p / n_carry)
            )
            prev_v, prev_p = v[t], post[t]
        est.append(info.estimate)
        V.append(v)
    est, V = np.asarray(est), np.asarray(V)
    dev = est - m  # (REPS, T, D)
    tq = student_t.isf(1e-3 / (2 * T * D), REPS - 1)
    tstat = np.abs(dev.mean(axis=0)) / (dev.std(axis=0, ddof=1) / np.sqrt(REPS))
    assert np.all(tstat <= tq), (tstat.max(), tq)
    ratio = np.mean(dev**2) / np.mean(V)
    assert ratio <= 2.0, ratio
    return tstat.max(), ratio


N_SIR = 5000


def test_sir_matches_kalman():
    t, ratio = check_against_kalman(
        SIR(loglik, jnp.full(D, Q), N_SIR), 10, 0, lambda i: (i.layers.ess[:, 0], np.zeros(T), N_SIR)
    )
    print(f"SIR: max |t| {t:.2f}, MSE / predicted {ratio:.2f}")


N_IC = 2000


def ic_filter(weighting="mixture"):
    return ICondensation(
        loglik,
        jnp.full(D, Q),
        jnp.zeros(D),
        jnp.full(D, np.sqrt(P0)),
        N_IC,
        detection_std=jnp.full(D, 0.3),
        weighting=weighting,
    )


def test_icondensation_matches_kalman():
    """With the deterministic-mixture weights p(z|x) f(x)/q(x) ICONDENSATION targets the same posterior as SIR."""
    t, ratio = check_against_kalman(ic_filter(), 11, 1, lambda i: (i.layers.ess[:, 0], np.zeros(T), N_IC))
    print(f"ICONDENSATION: max |t| {t:.2f}, MSE / predicted {ratio:.2f}")


N_APF = 4000
EXACT_BETAS = (0.25, 0.25, 0.5)


def test_apf_without_inner_diffusion_is_exact():
    """Absolute exponents β_l applied to sets resampled from the previous layer multiply up: without diffusion after
    layer 0 the APF's final set targets prior × p(z|x)^{Σβ}, the exact posterior when Σβ = 1."""
    f = APF(loglik_layer, jnp.full(D, Q), N_APF, Schedule.fixed(EXACT_BETAS, (1.0, 0.0, 0.0)))

    def stages(info):
        np.testing.assert_allclose(info.layers.beta[0], EXACT_BETAS, rtol=1e-6)
        ess = info.layers.ess
        return ess[:, -1], (1 / ess[:, :-1] + 1 / N_APF).sum(axis=1), N_APF

    t, ratio = check_against_kalman(f, 12, 2, stages)
    print(f"APF (exact limit): max |t| {t:.2f}, MSE / predicted {ratio:.2f}")


def test_annealed_filters_are_close_to_kalman():
    """APF and IAPF with diffusion and Deutscher's rule are searches, not exact Bayesian filters (absolute β_l < 1,
    extra diffusion): their RMS error to the truth must stay within 25 % of the optimal (Kalman) RMS error."""
    x, z, obs = simulate(3)
    kf = kalman(z)[0]
    rms = lambda e: np.sqrt(np.mean((e - x) ** 2))
    schedule = Schedule.deutscher(3, diffusion_scales=(1.0, 0.5, 0.25))
    apf = APF(loglik_layer, jnp.full(D, Q), 2000, schedule)
    iapf = dataclasses.replace(
        apf,
        first_layer="icondensation",
        prior_mean=jnp.zeros(D),
        prior_std=jnp.full(D, np.sqrt(P0)),
        detection_std=jnp.full(D, 0.3),
    )
    for f in (apf, iapf):
        _, info = filter_sequence(f, 13, obs)
        surv = info.layers.survival_rate
        assert np.all(np.abs(surv[:, 1:] - 0.5) < 1e-3)  # Deutscher's rule met in every resampled layer
        assert rms(info.estimate) <= 1.25 * rms(kf), (f.first_layer, rms(info.estimate), rms(kf))


PART_COUNTS = (4000, 2000)


def test_partitioned_sampling_matches_kalman():
    """Separable likelihood p(z|x) = p(z_01|x_01) p(z_2|x_2) and independent dynamics: exact posterior."""
    f = Partitioned(loglik_partition, jnp.full(D, Q), GROUPS, PART_COUNTS)

    def stages(info):
        ess = info.layers.ess[:, :, 0]  # (T, K)
        return ess[:, -1], 1 / ess[:, 0] + 1 / PART_COUNTS[1], min(PART_COUNTS)

    t, ratio = check_against_kalman(f, 14, 4, stages)
    print(f"partitioned: max |t| {t:.2f}, MSE / predicted {ratio:.2f}")


def test_hierarchical_sampling_matches_kalman():
    """Annealing layers per level with β = (1/2, 1/2) and no diffusion in the second layer: exact again."""
    f = hierarchical(
        loglik_level, jnp.full(D, Q), GROUPS, PART_COUNTS, Schedule.fixed((0.5, 0.5), (1.0, 0.0))
    )

    def stages(info):
        ess = info.layers.ess  # (T, K, L)
        assert ess.shape == (T, 2, 2)
        # stages (level, layer) in run order; each but the last is followed by a resampling to ≥ min(counts)
        return (
            ess[:, -1, -1],
            (1 / ess.reshape(T, -1)[:, :-1]).sum(axis=1) + 3 / min(PART_COUNTS),
            min(PART_COUNTS),
        )

    t, ratio = check_against_kalman(f, 15, 5, stages)
    print(f"hierarchical: max |t| {t:.2f}, MSE / predicted {ratio:.2f}")


GROUP_MASKS = np.array([[True, True, False], [False, False, True]])


@pytest.mark.parametrize("hier", [False, True])
@pytest.mark.parametrize("counts", [(1500, 1500), (700, 1500)])
def test_scanned_partitions_equal_the_unrolled_step(hier, counts):
    """``scan_partitions``: the partitions run as one ``lax.scan`` with the partition index traced (unequal counts
    through a padded buffer, the likelihood called on chunks of its rows). The likelihood is traced once instead of
    once per stage, and the particles, estimates, diagnostics and a recovery in the second partition are those of
    the unrolled step bit for bit (same keys, same operations; this likelihood's arithmetic does not depend on the
    batch width)."""
    traces = []

    def ll(X, obs, k):  # reads the partition index as an array, so it works traced and as a Python int
        traces.append(1)
        k = getattr(k, "partition", k)
        m = jnp.asarray(GROUP_MASKS)[k]
        return _kill(-0.5 * jnp.sum(jnp.where(m, (X - obs.z) ** 2, 0.0), axis=1) / R**2, obs, k)

    x, z, obs = simulate(9, dead={6: (1, 1)})
    sched = Schedule.deutscher(2, diffusion_scales=(1.0, 0.5))
    out = {}
    for scan in (False, True):
        kw = dict(scan_partitions=scan, chunk=256)
        f = (
            hierarchical(ll, jnp.full(D, Q), GROUPS, counts, sched, **kw)
            if hier
            else Partitioned(ll, jnp.full(D, Q), GROUPS, counts, **kw)
        )
        assert f.runs() == ([(0, 2)] if scan else [(0, 1), (1, 2)])
        traces.clear()
        step = jax.jit(f.step, compiler_options=PRODUCTION)
        state = f.init(key(2), jnp.zeros(D))
        for t in (5, 6):
            state, info = step(key(3 + t), state, jax.tree.map(lambda a, t=t: a[t], obs))
        out[scan] = (state, info, len(traces))
    (s0, i0, n0), (s1, i1, n1) = out[False], out[True]
    assert (n0, n1) == ((4 if hier else 2), 1)  # hierarchical unrolled: each level's first layer apart
    assert bool(i0.recovered) and bool(i1.recovered)
    assert s1.particles.shape == (counts[-1], D) and i1.layers.ess.shape == (2, 2 if hier else 1)
    np.testing.assert_array_equal(s1.particles, s0.particles)
    np.testing.assert_array_equal(s1.log_weights, s0.log_weights)
    np.testing.assert_array_equal(i1.estimate, i0.estimate)
    for a, b in zip(i1.layers, i0.layers, strict=True):
        np.testing.assert_array_equal(a, b)


def test_chunked_loglik_evaluates_the_rows_of_whole_chunks():
    """:func:`base.chunked_loglik`: the rows of the ``⌈n / chunk⌉`` chunks holding the first ``n`` rows are those of
    the likelihood on the whole buffer, the others ``-inf``; one trace serves every ``n``."""
    traces = []

    def ll(X, obs, layer):
        traces.append(X.shape)
        return -jnp.sum((X - obs) ** 2, axis=1)

    X = jnp.asarray(np.random.default_rng(0).integers(-9, 9, size=(12, 2)), jnp.float32)  # exact arithmetic
    f = jax.jit(lambda X, n: base.chunked_loglik(ll, X, jnp.ones(2), 0, n, 4))
    full = np.asarray(ll(X, jnp.ones(2), 0))
    for n, rows in ((1, 4), (4, 4), (5, 8), (12, 12)):
        out = np.asarray(f(X, n))
        np.testing.assert_array_equal(out[:rows], full[:rows])
        assert np.all(out[rows:] == -np.inf)
    assert traces == [(12, 2), (4, 2)]  # the direct call above and the loop body, traced once
    with pytest.raises(ValueError, match="multiple of the chunk"):
        base.chunked_loglik(ll, X, jnp.ones(2), 0, 3, 5)


def _all_filters():
    sched = Schedule.deutscher(3, diffusion_scales=(1.0, 0.5, 0.25))
    return {
        "sir": SIR(loglik, jnp.full(D, Q), N_SIR),
        "icondensation": ic_filter(),
        "apf": APF(loglik_layer, jnp.full(D, Q), 2000, sched),
        "partitioned": Partitioned(loglik_partition, jnp.full(D, Q), GROUPS, PART_COUNTS),
    }


def test_compiles_once():
    """One compiled step serves every frame, and new array parameters (e.g. another Δ) do not recompile."""
    x, z, obs = simulate(6)
    for name, f in _all_filters().items():
        step = STEPS[type(f)]
        state = f.init(key(0), jnp.zeros(D), jnp.ones(D))
        frame = lambda t: jax.tree_util.tree_map(lambda a: a[t], obs)
        state, _ = step(f, key(0), state, frame(0))
        size = step._cache_size()  # this configuration is now compiled (possibly by an earlier test)
        for t in range(1, 4):
            state, _ = step(f, key(t), state, frame(t))
        g = dataclasses.replace(f, diffusion_std=jnp.full(D, 2 * Q))
        state, _ = step(g, key(9), state, frame(5))
        assert step._cache_size() == size, name


@pytest.mark.parametrize("name", ["sir", "icondensation", "apf", "partitioned"])
@pytest.mark.parametrize("code", [1, 2])
def test_recovery_from_dead_weights(name, code):
    """A frame in which every log-likelihood is -inf (code 1) or NaN (code 2): no NaN anywhere, the frame is flagged,
    the estimate stays at the previous frame's, and tracking goes on (the next frames are finite and unflagged)."""
    bad = 8
    x, z, obs = simulate(7, dead={bad: (code, -1)})
    f = _all_filters()[name]
    state, info = filter_sequence(f, 17, obs)
    for leaf in jax.tree_util.tree_leaves((state, info.estimate, info.best, info.layers.ess)):
        assert np.all(np.isfinite(leaf))
    assert info.recovered[bad] and not info.recovered[:bad].any() and not info.recovered[bad + 1 :].any()
    np.testing.assert_array_equal(info.estimate[bad], info.estimate[bad - 1])
    first_count = f.counts[0] if name == "partitioned" else f.num_particles
    assert info.layers.num_nonfinite.reshape(T, -1)[bad, 0] == first_count
    # tracking resumes: the error a few frames later is back at the order of the posterior std
    kf = kalman(z)[0]
    assert np.all(np.abs(info.estimate[bad + 5 :] - kf[bad + 5 :]) < 3 * np.sqrt(kalman(z)[1][-1]))


def test_recovery_in_one_layer_and_uniform_mode():
    """A dead middle layer of the APF is recovered and the later layers go on; ``recovery="uniform"`` keeps the
    proposed particles with uniform weights."""
    x, z, obs = simulate(8, dead={4: (1, 1)})
    f = _all_filters()["apf"]
    _, info = filter_sequence(f, 18, obs)
    assert info.recovered[4] and info.recovered.sum() == 1
    assert info.layers.num_nonfinite[4, 1] == f.num_particles and info.layers.num_nonfinite[4, 2] == 0
    assert np.all(np.isfinite(info.estimate))
    x, z, obs = simulate(8, dead={4: (1, -1)})
    state, info = filter_sequence(SIR_LIMITED, 18, obs)
    assert info.recovered[4] and np.all(np.isfinite(info.estimate))
    assert np.all(np.isfinite(state.log_weights))
    # "uniform": the proposed particles are kept, so the frame's estimate is their plain mean, not the previous one
    assert not np.array_equal(info.estimate[4], info.estimate[3])


def test_recover_draws_only_when_needed():
    """``recover(..., ok=...)``: the particles unchanged where the weighting succeeded, the fresh cloud
    ``estimate + widen · std ⊙ ε`` (the same draws as without ``ok``) where it failed, only the ``mask``ed
    coordinates re-drawn; the same under ``vmap`` with a batched ``ok``. The compiled program holds the draws in a
    conditional, not in the straight-line code."""
    k = jax.random.key(3)
    X = jnp.arange(12.0).reshape(4, 3)
    prev, std = jnp.asarray([10.0, 20.0, 30.0]), jnp.asarray([1.0, 2.0, 3.0])
    fresh = prev + 2.0 * std * jax.random.normal(k, X.shape)
    same = lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-6)  # float32 rounding of a fused program
    same(base.recover(k, X, prev, std, 2.0), fresh)
    np.testing.assert_array_equal(base.recover(k, X, prev, std, 2.0, ok=jnp.asarray(True)), X)
    same(base.recover(k, X, prev, std, 2.0, ok=jnp.asarray(False)), fresh)
    mask = jnp.asarray([True, False, True])
    got = base.recover(k, X, prev, std, 2.0, ok=jnp.asarray(False), mask=mask)
    same(got, jnp.where(mask, fresh, X))
    ok = jnp.asarray([True, False])
    got = jax.vmap(lambda o: base.recover(k, X, prev, std, 2.0, ok=o))(ok)
    np.testing.assert_array_equal(got[0], X)
    same(got[1], fresh)
    hlo = jax.jit(lambda o: base.recover(k, X, prev, std, 2.0, ok=o)).lower(jnp.asarray(True)).as_text()
    assert "case" in hlo or "conditional" in hlo


def test_limits_clip_and_reflect():
    lo, hi = jnp.asarray([-1.0, 0.0]), jnp.asarray([1.0, jnp.inf])
    X = jnp.asarray([[1.3, -0.5], [-3.5, 2.0], [0.2, 7.0]])
    np.testing.assert_allclose(base.apply_limits(X, lo, hi, "clip"), [[1.0, 0.0], [-1.0, 2.0], [0.2, 7.0]])
    # reflect: 1.3 → 0.7; -3.5 → -1 + |(-3.5 + 1) mod 4 folded| = 0.5; infinite upper bound → clip at 0
    np.testing.assert_allclose(
        base.apply_limits(X, lo, hi, "reflect"), [[0.7, 0.0], [0.5, 2.0], [0.2, 7.0]], atol=1e-6
    )
    # a reflected random walk started at the centre stays symmetric and inside the box
    Y = base.diffuse(key(0), jnp.zeros((20000, 1)), jnp.asarray([3.0]), lo[:1], hi[:1], "reflect")
    assert float(Y.min()) >= -1 and float(Y.max()) <= 1
    assert abs(float(Y.mean())) < 5 * float(Y.std()) / np.sqrt(20000)
    with pytest.raises(ValueError):
        base.apply_limits(X, lo, hi, "wrap")


LOWER, UPPER = jnp.asarray([-0.2, -jnp.pi, -1.0]), jnp.asarray([0.2, jnp.pi, 1.0])
SIR_LIMITED = SIR(
    loglik, jnp.full(D, Q), 2000, lower=LOWER, upper=UPPER, limit_mode="reflect", recovery="uniform"
)


def test_sir_respects_limits_and_circular_mean():
    lower, upper = LOWER, UPPER
    x, z, obs = simulate(9)
    state, info = filter_sequence(SIR_LIMITED, 19, obs)
    assert np.all(state.particles >= np.asarray(lower) - 1e-6) and np.all(
        state.particles <= np.asarray(upper) + 1e-6
    )
    # circular mean: angles on both sides of ±π average to ±π, not to 0
    ang = jnp.asarray([[3.1], [-3.1], [3.0], [-3.0]])
    m = base.weighted_mean(ang, jnp.zeros(4) - jnp.log(4.0), (True,))
    assert abs(abs(float(m[0])) - np.pi) < 1e-5
    assert abs(float(base.weighted_mean(ang, jnp.zeros(4) - jnp.log(4.0))[0])) < 1e-6


def test_isard_blake_correction():
    """Isard & Blake's λ: 1 for particles from the dynamics and the prior, f(x)/g(x) for those from the detector."""
    from jaxmocap.filters import icondensation

    prev = jax.random.normal(key(1), (50, D))
    args = (
        prev,
        jnp.zeros(50) - jnp.log(50.0),
        40,
        (20, 12, 8),
        jnp.full(D, Q),
        jnp.ones(D),
        jnp.bool_(True),
    )
    args += (jnp.full(D, 0.3), jnp.zeros(D), jnp.ones(D))

    @jax.jit
    def run(k):
        X, corr = icondensation.importance_sample(k, *args, scheme="systematic", weighting="isard_blake")
        log_f = base.gaussian_mixture_logpdf(X, prev, jnp.zeros(50) - jnp.log(50.0), jnp.full(D, Q))
        return corr, log_f - base.gaussian_logpdf(X, jnp.ones(D), jnp.full(D, 0.3))

    corr, log_f_over_g = run(key(2))
    np.testing.assert_allclose(corr[20:32], log_f_over_g[20:32], rtol=1e-5, atol=1e-5)
    assert np.all(np.asarray(corr[:20]) == 0) and np.all(np.asarray(corr[32:]) == 0)


def test_configuration_errors():
    with pytest.raises(ValueError):
        Partitioned(loglik_partition, jnp.full(D, Q), ((0, 1), (1,)), (10, 10))
    with pytest.raises(ValueError):
        APF(loglik_layer, jnp.full(D, Q), 10, first_layer="icondensation")
    with pytest.raises(ValueError):
        ICondensation(
            loglik,
            jnp.full(D, Q),
            jnp.zeros(D),
            jnp.ones(D),
            10,
            dynamics_fraction=0.8,
            detection_fraction=0.5,
        )


@pytest.mark.slow
def test_iros_synthetic_benchmark_quick():
    """Smoke run of benchmarks/experiments/iros_synthetic.py --quick: a full Markdown table with finite errors, the Kalman filter
    (the exact posterior mean) at or below every particle filter."""
    path = pathlib.Path(__file__).parents[2] / "benchmarks" / "experiments" / "iros_synthetic.py"
    spec = importlib.util.spec_from_file_location("iros_synthetic", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    cfg = bench.Config(runs=2, frames=15, particles=300)
    errors = bench.run_all(cfg)
    assert set(errors) == set(bench.NAMES)
    for name, e in errors.items():
        assert e.shape == (2,) and np.all(np.isfinite(e)), name
        assert errors["Kalman"].mean() <= e.mean() * 1.05, name
    md = bench.table(errors, cfg)
    assert md.count("\n") == len(bench.NAMES) + 1 and "IAPF" in md


@pytest.mark.parametrize("first_layer", ["dynamics", "icondensation"])
def test_apf_keeps_each_layers_set_when_asked_and_tracks_the_same(first_layer):
    """``keep_layers``: ``Info.layer_sets`` holds the weighted set after each layer (the last one is the new state)
    and the weighted mean of each layer's set agrees with what the layer's stats imply; the step is otherwise the
    same (same key → the same state as without)."""
    _, _, obs = simulate(5)
    f = APF(
        loglik_layer, jnp.full(D, Q), 300, Schedule.deutscher(3, diffusion_scales=(1.0, 0.5, 0.25)),
        first_layer=first_layer, prior_mean=jnp.zeros(D), prior_std=jnp.full(D, np.sqrt(P0)),
        detection_std=jnp.full(D, 0.3),
    )  # fmt: skip
    kept = dataclasses.replace(f, keep_layers=True)
    frame = jax.tree_util.tree_map(lambda a: a[0], obs)
    s0 = f.init(key(1), jnp.zeros(D), jnp.full(D, np.sqrt(P0)))
    s1, i1 = jax.jit(APF.step)(f, key(2), s0, frame)
    s2, i2 = jax.jit(APF.step)(kept, key(2), s0, frame)
    assert i1.layer_sets is None
    X, lw = i2.layer_sets
    assert X.shape == (3, 300, D) and lw.shape == (3, 300)
    np.testing.assert_array_equal(s1.particles, s2.particles)
    np.testing.assert_array_equal(X[-1], s2.particles)
    np.testing.assert_array_equal(lw[-1], s2.log_weights)
    # each layer's ESS from its kept weights is the ESS its stats report
    w = np.exp(np.asarray(lw, np.float64))
    ess = 1.0 / np.sum((w / w.sum(1, keepdims=True)) ** 2, axis=1)
    np.testing.assert_allclose(ess, np.asarray(i2.layers.ess), rtol=1e-3)
