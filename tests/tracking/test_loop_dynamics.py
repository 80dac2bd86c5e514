"""The tracking loop's motion model between frames: the DOFs of the constant-velocity prediction, angle steps
across ±π, and full turns taken out of full-turn angles (a body that keeps turning one way)."""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.filters.factory import make_filter
from jaxmocap.geometry import body
from jaxmocap.tracking.loop import LossTracker
from jaxmocap.tracking.options import TrackOptions, diffusion_std
from jaxmocap.tracking.prediction import angle_difference, unwind, velocity_dofs


@pytest.fixture(scope="module")
def model():
    return body.upper9()


def test_velocity_dofs_select_the_root_translation_its_angles_or_all(model):
    """``translation``: the root's prismatic DOFs (three); ``root``: the root segment's DOFs (upper9: the
    translation and the heading); ``all``: every DOF; anything else is refused."""
    root = list(model.topology.segment_dofs[0])
    kinds = np.asarray(model.topology.dof_kinds)
    t = velocity_dofs(model, "translation")
    assert np.flatnonzero(t).tolist() == [d for d in root if kinds[d] == "P"] and t.sum() == 3
    assert np.flatnonzero(velocity_dofs(model, "root")).tolist() == root
    assert [model.dof_names[d] for d in root][3:] == ["body_rz"]
    assert velocity_dofs(model, "all").all()
    with pytest.raises(ValueError, match="velocity_dofs"):
        velocity_dofs(model, "heading")


def test_angle_difference_wraps_full_turn_angles_only():
    """179° → −179° is a step of +2° on a full-turn angle, and −358° on any other DOF; steps inside (−π, π) are
    the plain difference."""
    a = np.radians([-179.0, -179.0, 30.0])
    b = np.radians([179.0, 179.0, 10.0])
    d = np.degrees(angle_difference(a, b, np.array([True, False, True])))
    np.testing.assert_allclose(d, [2.0, -358.0, 20.0], atol=1e-9)


def test_unwind_moves_the_set_by_whole_turns():
    """A set whose mean heading is 5.5 rad moves by −2π as one piece (every particle by the same amount, so a set
    straddling 2π stays contiguous); one at −4 rad by +2π; a set inside [−π, π] and the DOFs not flagged keep their
    values bit for bit."""
    rng = np.random.default_rng(0)
    X = np.zeros((64, 3), np.float32)
    X[:, 0] = 5.5 + 0.8 * rng.standard_normal(64)  # some particles above 2π, some below
    X[:, 1] = 2.0 + 0.3 * rng.standard_normal(64)
    X[:, 2] = 5.5 + 0.1 * rng.standard_normal(64)  # not flagged
    out = np.asarray(unwind(jnp.asarray(X), jnp.asarray([True, True, False])))
    np.testing.assert_allclose(out[:, 0] - X[:, 0], -2 * np.pi, atol=1e-5)
    np.testing.assert_array_equal(out[:, 1:], X[:, 1:])
    X[:, 0] -= 9.5  # mean −4 rad
    out = np.asarray(unwind(jnp.asarray(X), jnp.asarray([True, True, False])))
    np.testing.assert_allclose(out[:, 0] - X[:, 0], 2 * np.pi, atol=1e-5)


class _Heading(NamedTuple):
    heading: jnp.ndarray


def test_a_body_turning_past_its_heading_limits_is_followed(model):
    """A target whose heading turns by 0.1 rad per frame (its limits are ±2π) for 80 frames: 8 rad, past the limit
    from a start at 0. The APF (200 particles, 3 layers) on a likelihood of the heading alone (σ = 0.05 rad,
    periodic), with the root's heading in the velocity prediction and :func:`unwind` between frames as the loop
    does, ends within 0.1 rad of the target's heading (mod 2π). Without :func:`unwind` the particles are clipped at
    2π and the estimate stays about 1.7 rad behind (8 − 2π)."""
    h = [d for d in model.topology.segment_dofs[0] if model.dof_names[d].endswith("rz")][0]
    lo, hi = float(model.lower[h]), float(model.upper[h])
    assert (lo, hi) == pytest.approx((-2 * np.pi, 2 * np.pi))

    def loglik(X, o, layer):
        del layer
        d = jnp.mod(X[:, h] - o.heading + jnp.pi, 2 * jnp.pi) - jnp.pi
        return -0.5 * (d / 0.05) ** 2

    std = diffusion_std(model)
    x0 = np.asarray(model.rest_pose, np.float64)
    f = make_filter("apf", loglik, model, std, 200, 3, prior_mean=x0, prior_std=3 * std)
    circular = np.asarray(f.circular, bool)
    assert circular[h] and circular.sum() == 1
    moving = velocity_dofs(model, "root")
    step = jax.jit(f.step)

    def run(with_unwind):
        state = f.init(jax.random.key(0), jnp.asarray(x0, jnp.float32), jnp.asarray(0.5 * std))
        hist = []
        for t in range(80):
            if len(hist) == 2:
                v = np.where(moving, angle_difference(hist[1], hist[0], circular), 0.0) * 0.5
                state = state._replace(particles=state.particles + jnp.asarray(v, jnp.float32))
            if with_unwind:
                state = state._replace(particles=unwind(state.particles, jnp.asarray(circular)))
            target = 0.1 * (t + 1)
            state, info = step(jax.random.fold_in(jax.random.key(1), t), state, _Heading(jnp.float32(target)))
            hist = [*hist, np.asarray(info.estimate, np.float64)][-2:]
        return float(angle_difference(hist[-1][h : h + 1], np.array([target]), np.array([True]))[0])

    assert abs(run(True)) < 0.1
    assert run(False) == pytest.approx(2 * np.pi - 8.0, abs=0.15)


def test_a_new_track_learns_its_quality_reference_again():
    """Track-loss bookkeeping: the reference is the median of the first ``loss_window`` energies; an energy above
    ``loss_ratio`` times it is bad, and ``loss_frames`` bad frames in a row make a loss. After a re-initialisation
    (``new_track``) the reference is learnt again: energies four times the old reference are then the new normal,
    not a loss every third frame."""
    o = TrackOptions(loss_ratio=2.5, loss_frames=3, loss_window=5)
    loss = LossTracker(o)
    for q in (1.0, 1.2, 0.9, 1.1, 1.0):  # the reference: their median, 1.0
        assert not loss.bad_quality(q)
    assert loss.q_ref == 1.0
    assert [loss.bad_quality(q) for q in (4.0, 4.2, 3.9)] == [True, True, True] and loss.lost_run == 3
    loss.new_track()
    assert loss.lost_run == 0 and loss.hist == [] and np.isnan(loss.q_ref)
    assert not any(loss.bad_quality(q) for q in (4.0, 4.4, 3.8, 4.1, 4.2, 4.5, 3.9))
    assert loss.q_ref == 4.1  # the median of the five energies after the new start
    assert loss.bad_quality(10.5)  # 2.5 × 4.1 = 10.25
