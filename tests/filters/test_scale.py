"""Sharded particles, batched runs and chunked likelihoods (:mod:`jaxmocap.filters.sharding`).

The multi-device cases run in a subprocess with ``XLA_FLAGS=--xla_force_host_platform_device_count=2`` (the flag
only takes effect before ``jax`` is imported). References are the plain, single-device runs with the same keys:

* sharding: resampling is global and the random numbers do not depend on the placement, so the ancestors (hence
  the particles) are the same; the estimates are weighted means whose sums run in another order (per device,
  then across), so they agree to float32 rounding: ``|Δ| ≤ 1e-5`` on values of order 1 (a few hundred ulps of
  slack over the ~``log2 N`` extra roundings of a sum of ``N = 256`` terms);
* batching: ``vmap`` evaluates the same per-run arithmetic, to the same float32 tolerance;
* chunking: the likelihood is per-particle, so chunked and whole evaluations are equal bit for bit.
"""

import json
import os
import pathlib
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.filters import APF, SIR, ignore_layer
from jaxmocap.filters import sharding as scale
from jaxmocap.filters.annealing import Schedule
from jaxmocap.filters.base import run

D, T, N = 3, 4, 256
TOL = 1e-5


def _ll(X, z):
    return -0.5 * jnp.sum(((X - z) / 0.2) ** 2, axis=1)


_LL_LAYER = ignore_layer(_ll)
# one compilation per filter configuration, shared by the tests (the filter is an argument, its config static)
_RUN = jax.jit(lambda f, k, s, o: run(f.step, k, s, o))


def _problem():
    """A random-walk target observed with Gaussian noise: ``ll(x, z) = −|x − z|² / (2 σ²)``, σ = 0.2."""
    truth = jnp.cumsum(jnp.full((T, D), 0.1), axis=0)
    return truth + 0.05 * jax.random.normal(jax.random.key(9), (T, D)), _ll


_SUBPROCESS = textwrap.dedent(
    """
    import json
    from jaxmocap import host; host.relax_gc()  # the suite's garbage-collector thresholds (tests/conftest.py)
    import jax, jax.numpy as jnp, numpy as np
    from tests.filters.test_scale import D, N, _RUN, _problem, _filters
    from jaxmocap.filters import sharding as scale

    assert jax.device_count() == 2, jax.devices()
    obs, ll = _problem()
    mesh = scale.device_mesh()
    out = {}
    filters = _filters(ll)
    for name, f in filters.items():
        s0 = f.init(jax.random.key(0), jnp.zeros(D))
        ref_s, ref_i = _RUN(f, jax.random.key(1), s0, obs)
        sh_s, sh_i = scale.sharded_run(f, jax.random.key(1), scale.shard_state(s0, mesh), obs, mesh)
        out[name] = dict(
            devices=len(sh_s.particles.sharding.device_set),
            spec=str(sh_s.particles.sharding.spec),
            estimate=float(np.abs(np.asarray(sh_i.estimate) - np.asarray(ref_i.estimate)).max()),
            particles=float(np.abs(np.asarray(sh_s.particles) - np.asarray(ref_s.particles)).max()),
        )
    # frame by frame with the jitted sharded step (the tracker's way of running a filter)
    f = filters["sir"]
    s0 = f.init(jax.random.key(0), jnp.zeros(D))
    ref = _RUN(f, jax.random.key(1), s0, obs)[1].estimate
    step = scale.sharded_step(f, mesh)
    s, est = scale.shard_state(s0, mesh), []
    for t, k in enumerate(jax.random.split(jax.random.key(1), obs.shape[0])):
        s, info = step(k, s, obs[t])
        est.append(info.estimate)
    out["step"] = dict(
        spec=str(s.particles.sharding.spec), estimate=float(np.abs(np.stack(est) - np.asarray(ref)).max())
    )
    # three seeds spread over two devices (padded to four), against one run per seed
    f = _filters(ll)["sir"]
    keys = jax.vmap(jax.random.key)(jnp.arange(3))
    states = scale.batched_init(f, keys, jnp.zeros(D))
    _, info = scale.batched_run(f, keys, states, obs, mesh)
    errs = []
    for b in range(3):
        s0 = f.init(keys[b], jnp.zeros(D))
        errs.append(float(np.abs(np.asarray(_RUN(f, keys[b], s0, obs)[1].estimate) - info.estimate[b]).max()))
    out["batched"] = dict(shape=list(info.estimate.shape), err=max(errs))
    print("RESULT" + json.dumps(out))
    """
)


def _filters(ll):
    assert ll is _ll
    std = jnp.full(D, 0.1)
    return {"sir": SIR(_LL_LAYER, std, N), "apf": APF(_LL_LAYER, std, N, Schedule.deutscher(2, 0.5))}


def test_sharded_equals_unsharded_on_two_devices():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    root = str(pathlib.Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run(
        [sys.executable, "-c", _SUBPROCESS], env=env, cwd=root, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT")][-1]
    out = json.loads(line[len("RESULT") :])
    for name in ("sir", "apf"):
        r = out[name]
        assert r["devices"] == 2 and "particles" in r["spec"], r
        assert r["particles"] <= 1e-6, (name, r)  # the same ancestors: global resampling
        assert r["estimate"] <= TOL, (name, r)
    assert "particles" in out["step"]["spec"] and out["step"]["estimate"] <= TOL, out["step"]
    assert out["batched"]["shape"] == [3, T, D]
    assert out["batched"]["err"] <= TOL, out["batched"]


def test_batched_runs_equal_per_seed_runs():
    obs, ll = _problem()
    for name in ("apf",):  # the SIR case runs spread over two devices in the subprocess above
        f = _filters(ll)[name]
        keys = jax.vmap(jax.random.key)(jnp.array([0, 7, 42]))
        states = scale.batched_init(f, keys, jnp.zeros(D))
        final, info = scale.batched_run(f, keys, states, obs)
        assert info.estimate.shape == (3, T, D)
        for b in range(3):
            s_b, i_b = _RUN(f, keys[b], f.init(keys[b], jnp.zeros(D)), obs)
            np.testing.assert_allclose(info.estimate[b], i_b.estimate, atol=TOL, err_msg=name)
            np.testing.assert_allclose(final.particles[b], s_b.particles, atol=TOL, err_msg=name)
        # different seeds really give different runs
        assert np.abs(np.asarray(info.estimate[0] - info.estimate[1])).max() > 1e-4


def test_batched_sequences_of_equal_shape():
    obs, ll = _problem()
    f = _filters(ll)["sir"]
    seqs = jnp.stack([obs, obs[::-1]])  # (B=2, T, D)
    keys = jax.vmap(jax.random.key)(jnp.array([3, 3]))
    states = scale.batched_init(f, keys, jnp.zeros(D))
    _, info = scale.batched_run(f, keys, states, seqs, batched_observations=True)
    for b in range(2):
        ref = _RUN(f, keys[b], f.init(keys[b], jnp.zeros(D)), seqs[b])[1].estimate
        np.testing.assert_allclose(info.estimate[b], ref, atol=TOL)


@pytest.mark.parametrize("n, c", [(1000, 128), (1024, 256), (50, 128), (7, 3)])
def test_chunked_equals_whole(n, c):
    X = jax.random.normal(jax.random.key(0), (n, D))
    z = jnp.array([0.1, -0.2, 0.3])

    def ll(X, z, layer):
        return -0.5 * jnp.sum(((X - z) / (0.2 + 0.1 * layer)) ** 2, axis=1) + jnp.log(1.0 + X[:, 0] ** 2)

    whole = jax.jit(ll)(X, z, 1)
    parts = jax.jit(scale.chunked(ll, c))(X, z, 1)
    assert parts.shape == (n,)
    np.testing.assert_array_equal(np.asarray(parts), np.asarray(whole))


def test_chunked_filter_equals_plain_filter():
    obs, ll = _problem()
    f = _filters(ll)["apf"]
    s0 = f.init(jax.random.key(0), jnp.zeros(D))
    ref = _RUN(f, jax.random.key(1), s0, obs)
    g = scale.with_chunks(f, 64)
    got = _RUN(g, jax.random.key(1), s0, obs)
    np.testing.assert_array_equal(np.asarray(got[1].estimate), np.asarray(ref[1].estimate))


def test_bad_input():
    obs, ll = _problem()
    f = _filters(ll)["sir"]
    mesh = scale.device_mesh(1)
    with pytest.raises(ValueError, match="num_devices"):
        scale.device_mesh(jax.device_count() + 1)
    with pytest.raises(TypeError, match="loglik_batch"):
        scale.with_chunks(object(), 8)
    # one device: everything divides, and the sharded run is the plain run
    s0 = f.init(jax.random.key(0), jnp.zeros(D))
    _, info = scale.sharded_run(f, jax.random.key(1), scale.shard_state(s0, mesh), obs, mesh)
    ref = _RUN(f, jax.random.key(1), s0, obs)[1].estimate
    np.testing.assert_allclose(info.estimate, ref, atol=TOL)


_MULTIPROCESS = textwrap.dedent(
    """
    import json, sys
    from jaxmocap import host; host.relax_gc()  # the suite's garbage-collector thresholds (tests/conftest.py)
    import jax
    jax.distributed.initialize(sys.argv[1], num_processes=2, process_id=int(sys.argv[2]))
    import jax.numpy as jnp, numpy as np
    from tests.filters.test_scale import D, _RUN, _problem, _filters
    from jaxmocap.filters import sharding as scale

    assert jax.process_count() == 2 and jax.device_count() == 2 and jax.local_device_count() == 1
    obs, ll = _problem()
    f = _filters(ll)["sir"]
    keys = jax.vmap(jax.random.key)(jnp.arange(3))
    states = scale.batched_init(f, keys, jnp.zeros(D))
    _, info = scale.batched_run(f, keys, states, obs, scale.device_mesh(None, scale.BATCH_AXIS))
    errs = [
        np.abs(np.asarray(_RUN(f, keys[b], f.init(keys[b], jnp.zeros(D)), obs)[1].estimate) - info.estimate[b]).max()
        for b in range(3)
    ]
    print("RESULT" + json.dumps([type(info.estimate).__name__, list(info.estimate.shape), float(max(errs))]))
    """
)


@pytest.mark.slow
def test_batched_runs_over_two_processes():
    """JAX's multi-process runtime on one machine: two processes with one CPU device each form a global mesh;
    three seeds are spread over them and the gathered results equal the per-seed runs on every process."""
    import socket

    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = s.getsockname()[1]
    root = str(pathlib.Path(__file__).resolve().parents[2])
    env = dict(
        os.environ, JAX_PLATFORMS="cpu", PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", "")
    )
    env.pop("XLA_FLAGS", None)
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _MULTIPROCESS, f"localhost:{port}", str(i)],
            env=env,
            cwd=root,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]
    outs = [p.communicate(timeout=300) for p in procs]
    for p, (out, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err[-3000:]
        line = [x for x in out.splitlines() if x.startswith("RESULT")][-1]
        kind, shape, e = json.loads(line[len("RESULT") :])
        assert kind == "ndarray" and shape == [3, T, D], (kind, shape)  # gathered to every process
        assert e <= TOL
