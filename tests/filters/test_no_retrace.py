"""Values that are data never recompile: the annealing schedule's β, survival target and diffusion scales, the
diffusion std, the likelihood's λ schedule and cue weights are pytree leaves of the filter (and of the likelihood it
holds); particle counts, the number of layers and the cues are structure, and a new value of them compiles anew."""

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.features.observation import make_observation
from jaxmocap.filters import APF, Partitioned, hierarchical
from jaxmocap.filters.annealing import Schedule
from jaxmocap.geometry import body, camera
from jaxmocap.likelihood import compose as L
from jaxmocap.synth.generate import look_at
from jaxmocap.tracking.setup import observation_loglik

D = 4
TARGET = jnp.asarray([0.3, -0.2, 0.5, 0.1])


def _quadratic(X, observation, layer):
    """``-|x - z|² / 0.1``: a plain function (static in the filter's structure)."""
    del layer
    return -jnp.sum((X - observation) ** 2, axis=1) / 0.1


class _Counted:
    """``jax.jit`` of ``filt.step`` with the filter as an argument, counting traces.

    A call runs the step (compiled on its first trace); :meth:`trace` only traces it (and lowers it, without XLA's
    compilation), for a filter whose trace is counted but whose results are not read. A trace made by
    :meth:`trace` serves later calls of the same structure as well (jit's trace cache).
    """

    def __init__(self):
        self.traces = 0
        self.fn = jax.jit(self._step)

    def _step(self, filt, key, state, observation):
        self.traces += 1
        return filt.step(key, state, observation)

    def __call__(self, filt, observation):
        state = filt.init(jax.random.key(0), jnp.zeros(D))
        return self.fn(filt, jax.random.key(1), state, observation)

    def trace(self, filt, observation, state=None):
        state = filt.init(jax.random.key(0), jnp.zeros(D)) if state is None else state
        self.fn.lower(filt, jax.random.key(1), state, observation)


def _betas(info):
    return np.asarray(info.layers.beta)


def test_apf_data_changes_do_not_retrace():
    """β (fixed), diffusion scales, diffusion std and the survival target are data: one trace for all of them, and
    each new value changes the result; a new particle count or number of layers retraces."""
    step = _Counted()
    std = jnp.full(D, 0.2)
    f = APF(_quadratic, std, 64, Schedule.fixed((0.2, 0.5, 1.0), (1.0, 0.5, 0.25)))
    s0, i0 = step(f, TARGET)
    f_beta = dataclasses.replace(f, schedule=Schedule.fixed((0.1, 0.3, 0.7), (1.0, 0.5, 0.25)))
    s1, i1 = step(f_beta, TARGET)
    f_scale = dataclasses.replace(f, schedule=Schedule.fixed((0.2, 0.5, 1.0), (1.0, 0.8, 0.6)))
    s2, _ = step(f_scale, TARGET)
    f_std = dataclasses.replace(f, diffusion_std=jnp.full(D, 0.05))
    s3, _ = step(f_std, TARGET)
    assert step.traces == 1
    np.testing.assert_array_equal(_betas(i0), np.float32([0.2, 0.5, 1.0]))
    np.testing.assert_array_equal(_betas(i1), np.float32([0.1, 0.3, 0.7]))
    assert not np.array_equal(np.asarray(s0.log_weights), np.asarray(s1.log_weights))
    assert not np.array_equal(np.asarray(s0.particles), np.asarray(s2.particles))
    assert not np.array_equal(np.asarray(s0.particles), np.asarray(s3.particles))
    # the same values in a fresh filter give the same result (the compiled step is reused exactly)
    s0b, _ = step(APF(_quadratic, std, 64, Schedule.fixed((0.2, 0.5, 1.0), (1.0, 0.5, 0.25))), TARGET)
    np.testing.assert_array_equal(np.asarray(s0.particles), np.asarray(s0b.particles))
    assert step.traces == 1

    # Deutscher's rule: the survival target is data
    d = APF(_quadratic, std, 64, Schedule.deutscher(3, 0.5, (1.0, 0.5, 0.25)))
    _, j0 = step(d, TARGET)
    assert step.traces == 2  # another kind of schedule: another program
    _, j1 = step(dataclasses.replace(d, schedule=Schedule.deutscher(3, 0.2, (1.0, 0.5, 0.25))), TARGET)
    assert step.traces == 2
    assert np.all(_betas(j1) > _betas(j0))  # a lower survival target sharpens the weights
    np.testing.assert_allclose(np.asarray(j0.layers.survival_rate), 0.5, atol=1e-3)
    np.testing.assert_allclose(np.asarray(j1.layers.survival_rate), 0.2, atol=1e-3)

    # structure: particle count and number of layers recompile
    step.trace(dataclasses.replace(f, num_particles=32), TARGET)
    assert step.traces == 3
    step.trace(dataclasses.replace(f, schedule=Schedule.fixed((0.5, 1.0), (1.0, 0.5))), TARGET)
    assert step.traces == 4


def test_partitioned_data_changes_do_not_retrace():
    """Hierarchical sampling: schedule values and diffusion std are data; the counts are structure."""
    step = _Counted()
    groups, counts = ((0, 1), (2, 3)), (48, 48)
    f = hierarchical(_quadratic, jnp.full(D, 0.2), groups, counts, Schedule.fixed((0.3, 1.0), (1.0, 0.5)))
    s0, i0 = step(f, TARGET)
    s1, i1 = step(dataclasses.replace(f, schedule=Schedule.fixed((0.6, 0.9), (1.0, 0.3))), TARGET)
    s2, _ = step(dataclasses.replace(f, diffusion_std=jnp.full(D, 0.1)), TARGET)
    assert step.traces == 1
    np.testing.assert_array_equal(_betas(i0), np.float32([[0.3, 1.0], [0.3, 1.0]]))
    np.testing.assert_array_equal(_betas(i1), np.float32([[0.6, 0.9], [0.6, 0.9]]))
    assert not np.array_equal(np.asarray(s0.particles), np.asarray(s1.particles))
    assert not np.array_equal(np.asarray(s0.particles), np.asarray(s2.particles))
    step.trace(dataclasses.replace(f, counts=(48, 32)), TARGET)
    assert step.traces == 2
    p = Partitioned(_quadratic, jnp.full(D, 0.2), groups, counts)
    step.trace(p, TARGET)
    step.trace(dataclasses.replace(p, diffusion_std=jnp.full(D, 0.3)), TARGET)
    assert step.traces == 3


def _lik_batch(lik, X, observation, layer):
    return lik.batch(X, observation, layer)


@pytest.fixture(scope="module")
def two_cues():
    """upper9 in front of one small camera, a likelihood of two cues and an observation of random maps."""
    model = body.upper9()
    R, t = look_at(np.array([3.0, 0.0, 1.3]), [0.0, 0.0, 1.0])
    K = np.array([[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]])
    rig = camera.from_opencv(K[None], np.zeros((1, 5)), R[None], t[None], image_size=[(64, 48)])
    rng = np.random.default_rng(0)
    fg = (rng.random((1, 48, 64)) > 0.5).astype(np.float32)
    ed = rng.random((1, 48, 64)).astype(np.float32)
    obs = make_observation(rig, foreground=fg, edges=ed)
    lik = L.Likelihood.create(
        model, rig, [L.Cue("foreground", 1.0), L.Cue("edges", 2.0)], num_layers=2, surface_points=60
    )
    return model, lik, obs


def test_likelihood_weights_and_lambda_are_data(two_cues):
    """Cue weights k_c and the λ schedule are leaves: changing them (by ``replace`` or by ``create`` with other
    weights) reuses the compiled likelihood and changes the values; another set of cues compiles anew."""
    model, lik, obs = two_cues
    traces = []

    @jax.jit
    def f(lik, X, obs):
        traces.append(1)
        return lik.batch(X, obs, 1)

    X = model.rest_pose[None] + 0.05 * jax.random.normal(jax.random.key(0), (8, model.num_dofs))
    a = np.asarray(f(lik, X, obs))
    b = np.asarray(f(dataclasses.replace(lik, cue_weights=jnp.asarray([1.0, 5.0])), X, obs))
    c = np.asarray(f(dataclasses.replace(lik, schedule=2.0 * lik.schedule), X, obs))
    lik3 = L.Likelihood.create(
        model, lik.rig, [L.Cue("foreground", 0.5), L.Cue("edges", 2.0)], num_layers=2, surface_points=60
    )
    d = np.asarray(f(lik3, X, obs))
    assert len(traces) == 1
    assert not np.array_equal(a, b) and not np.array_equal(a, d)
    np.testing.assert_allclose(c, 2.0 * a, rtol=1e-6)
    # the weights multiply as before: k_c w_v E_c,v with k_c taken from the cues
    energies = jax.jit(lambda lik, X, obs: jax.vmap(lik.view_energies, in_axes=(0, None))(X, obs))
    e = np.asarray(energies(lik, X, obs))
    e3 = np.asarray(energies(lik3, X, obs))
    np.testing.assert_allclose(e3[:, 0], 0.5 * e[:, 0], rtol=1e-6)
    np.testing.assert_array_equal(e3[:, 1], e[:, 1])
    f.lower(
        L.Likelihood.create(model, lik.rig, [L.Cue("foreground")], num_layers=2, surface_points=60), X, obs
    )
    assert len(traces) == 2


def test_filter_with_pytree_likelihood_does_not_retrace(two_cues):
    """An APF whose likelihood is a ``Partial`` over a Likelihood: new cue weights, λ and β reuse the step."""
    model, lik, obs = two_cues
    counted = _Counted()
    run = counted.fn

    std = jnp.full(model.num_dofs, 0.02)
    f = APF(jax.tree_util.Partial(_lik_batch, lik), std, 16, Schedule.fixed((0.5, 1.0), (1.0, 0.5)))
    state = f.init(jax.random.key(0), model.rest_pose)
    s0, _ = run(f, jax.random.key(1), state, obs)
    lik2 = dataclasses.replace(lik, cue_weights=jnp.asarray([3.0, 0.5]), schedule=0.5 * lik.schedule)
    f2 = dataclasses.replace(
        f,
        loglik_batch=jax.tree_util.Partial(_lik_batch, lik2),
        schedule=Schedule.fixed((0.2, 0.8), (1.0, 0.5)),
    )
    s1, i1 = run(f2, jax.random.key(1), state, obs)
    assert counted.traces == 1
    np.testing.assert_array_equal(_betas(i1), np.float32([0.2, 0.8]))
    assert not np.array_equal(np.asarray(s0.log_weights), np.asarray(s1.log_weights))
    f8 = dataclasses.replace(f, num_particles=8)
    counted.trace(f8, obs, f8.init(jax.random.key(0), model.rest_pose))
    assert counted.traces == 2


class _TrackObs(NamedTuple):
    image: object


def test_tracker_likelihood_parameters_are_data(two_cues):
    """The tracker's likelihood (:func:`observation_loglik`) in a filter: new cue weights or λ reuse the step (its
    geometry stays a constant of the program); a new likelihood geometry is another program."""
    model, lik, obs = two_cues
    counted = _Counted()
    run = counted.fn

    ol = observation_loglik(lik, num_layers=2)
    f = APF(ol, jnp.full(model.num_dofs, 0.02), 16, Schedule.fixed((0.5, 1.0), (1.0, 0.5)))
    state = f.init(jax.random.key(0), model.rest_pose)
    tobs = _TrackObs(obs)
    s0, _ = run(f, jax.random.key(1), state, tobs)
    lik2 = dataclasses.replace(lik, cue_weights=jnp.asarray([3.0, 0.5]), schedule=0.5 * lik.schedule)
    s1, _ = run(
        dataclasses.replace(f, loglik_batch=dataclasses.replace(ol, lik=lik2)), jax.random.key(1), state, tobs
    )
    assert counted.traces == 1
    assert not np.array_equal(np.asarray(s0.log_weights), np.asarray(s1.log_weights))
    # the same parameters give the same result as a likelihood with every leaf traced
    s2, _ = run(
        dataclasses.replace(f, loglik_batch=jax.tree_util.Partial(_lik_batch_image, lik2)),
        jax.random.key(1),
        state,
        tobs,
    )
    np.testing.assert_allclose(np.asarray(s1.log_weights), np.asarray(s2.log_weights), rtol=1e-5, atol=1e-5)
    lik3 = L.Likelihood.create(
        model, lik.rig, [L.Cue("foreground", 1.0), L.Cue("edges", 2.0)], num_layers=2, surface_points=60
    )
    counted.trace(dataclasses.replace(f, loglik_batch=observation_loglik(lik3, num_layers=2)), tobs, state)
    assert counted.traces == 3  # the Partial above, then another geometry (new arrays held as constants)
    # params_data=False (the gradient filters): the parameters are constants, a new value compiles anew
    const = observation_loglik(lik, num_layers=2, params_data=False)
    counted.trace(dataclasses.replace(f, loglik_batch=const), tobs, state)
    counted.trace(dataclasses.replace(f, loglik_batch=const), tobs, state)
    assert counted.traces == 4
    counted.trace(dataclasses.replace(f, loglik_batch=dataclasses.replace(const, lik=lik2)), tobs, state)
    assert counted.traces == 5


def _lik_batch_image(lik, X, tobs, layer):
    ll = lik.batch(X, tobs.image, jnp.clip(layer.index, 0, 1))
    return jnp.where(jnp.isfinite(ll), ll, -jnp.inf)
