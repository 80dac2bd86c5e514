"""The li-kulic preset's likelihood: each partition weighed by the cues of its own body parts (Li & Kulić eq. 1–3
sum over the sample points of the partition's body parts), checked against the cue definitions computed here in
NumPy from the projected samples, and by what moving another partition's DOFs does (nothing)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap.geometry import flesh
from jaxmocap.io.sources import SequenceSource
from jaxmocap.likelihood.cues import DEPTH_PENALTY_M
from jaxmocap.synth import generate as synth
from jaxmocap.tracking.options import TrackOptions
from jaxmocap.tracking.setup import TrackSetup

LN_A = np.log(100.0)


@pytest.fixture(scope="module")
def setup_obs(tmp_path_factory):
    """The preset's setup on 2 frames of 96x72 px stereo (depth, masks), its first observation and the
    ground-truth pose ``x0`` (colour templates taken there)."""
    out = tmp_path_factory.mktemp("seq")
    synth.synthesize("demo", out, rig="stereo", frames="0:8", fps=30.0, size="96x72", seed=0, overwrite=True)
    setup = TrackSetup(SequenceSource(out), TrackOptions.from_preset("li-kulic", init="groundtruth"))
    tobs, masks, fd, _ = setup.observe(0)
    x0, _, _ = setup.initial_state(0, masks, fd)
    setup.set_references(x0, tobs)
    return setup, tobs.image, np.asarray(x0, np.float32)


@pytest.fixture(scope="module")
def energies(setup_obs):
    """``f(x, k) -> (C, V)`` view energies at partition ``k``, one compiled program for every ``k``."""
    setup, obs, _ = setup_obs
    lik = setup.likelihood
    return jax.jit(lambda x, k: lik.view_energies(x, obs, None, k))


def _unit(a):
    """A stored map in [0, 1] (uint8 maps hold round(255 p))."""
    a = np.asarray(a)
    return a.astype(np.float32) / 255.0 if a.dtype == np.uint8 else a.astype(np.float32)


def _partition_segments(setup, k):
    names = setup.model.segment_names
    return {names.index(s) for s in setup.parts[k]}


def test_ten_partitions_in_the_papers_order_with_their_dofs(setup_obs):
    setup, _, _ = setup_obs
    m = setup.model
    dofs = [[m.dof_names[d] for d in g] for g in setup.groups]
    assert dofs == [
        ["root_tx", "root_ty", "root_tz", "root_rz", "root_ry", "root_rx"],
        ["neck_rx", "neck_ry", "neck_rz"],
        ["left_shoulder_rx", "left_shoulder_ry", "left_shoulder_rz"],
        ["right_shoulder_rx", "right_shoulder_ry", "right_shoulder_rz"],
        ["left_elbow"],
        ["right_elbow"],
        ["left_hip_rx", "left_hip_ry", "left_hip_rz"],
        ["right_hip_rx", "right_hip_ry", "right_hip_rz"],
        ["left_knee"],
        ["right_knee"],
    ]
    assert sorted(d for g in setup.groups for d in g) == list(range(m.num_dofs))  # every DOF once
    assert setup.num_particles == [1000, 200, 500, 500, 200, 200, 500, 500, 200, 200]
    filt = setup.make_filter(np.asarray(m.rest_pose))
    assert filt.groups == setup.groups and filt.counts == tuple(setup.num_particles)
    assert filt.schedule is None and filt.resampling == "systematic"
    # the cues of eq. 1-3 and the ground distance, each weighed as 100^(-d) (lambda = ln 100)
    assert [n for n, _ in setup.cues] == ["depth", "edge_fraction", "colour_template", "wristband", "ground"]
    np.testing.assert_allclose(np.asarray(setup.likelihood.schedule), LN_A, rtol=1e-6)
    # track loss watches the whole body: the partitions' best energies summed (each weighs its own parts)
    top = -np.arange(1.0, 11.0)[:, None]  # (K, L) best log-likelihoods of a step
    assert setup.quality(top) == pytest.approx(55.0)


def test_depth_and_edge_energies_of_a_partition_are_means_over_its_own_samples(setup_obs, energies):
    """Eq. 1 and 2 restricted to a partition's body part, computed here from the projected samples."""
    setup, obs, x0 = setup_obs
    lik = setup.likelihood
    names = [c.name for c in lik.cues]
    g = jax.jit(lambda x: lik.geometry(x, obs.image_shape))(jnp.asarray(x0))
    V = obs.num_views
    # eq. 1: |z_p - D(u_p)| on camera-facing samples, D the depth where the pixel is foreground, else 2.8 m
    D = np.where(_unit(obs.foreground) >= 0.5, np.asarray(obs.depth, np.float32), 0.0)
    Dm = D.reshape(-1)[np.asarray(g.surface_index)]
    ok = np.asarray(g.surface_inside) & (Dm > 0)
    d = np.where(ok, np.abs(np.asarray(g.surface_depth) - Dm), DEPTH_PENALTY_M)
    facing = np.asarray(g.surface_facing)
    seg_p = np.asarray(lik.surface.segment)
    # eq. 2: contour samples off the Canny edges; 2 generators x k points per cone, then 2k per ellipsoid
    m = setup.model
    k_c = lik.contour_points
    seg_q = np.repeat(list(flesh.cone_segments(m)) + list(flesh.ellipsoid_segments(m)), 2 * k_c)
    edges = _unit(obs.edges)
    on = np.asarray(g.contour_inside) & (edges.reshape(-1)[np.asarray(g.contour_index)] >= 0.5)
    checked = 0
    for k in range(len(setup.parts)):
        segs = _partition_segments(setup, k)
        w = facing & np.isin(seg_p, list(segs))[None]
        depth = np.minimum((d * w).sum(-1) / np.maximum(w.sum(-1), 1), DEPTH_PENALTY_M) / DEPTH_PENALTY_M
        mine = np.isin(seg_q, list(segs))
        edge = 1.0 - on[:, mine].mean(-1)
        E = np.asarray(energies(jnp.asarray(x0), k))
        np.testing.assert_allclose(E[names.index("depth")], depth, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(E[names.index("edge_fraction")], edge, rtol=1e-5, atol=1e-6)
        checked += int(w.sum() > 0)
    assert checked >= 8 and V == 2  # most parts face a camera: the test compares non-empty sums


def test_ground_term_counts_only_the_partitions_own_ankle(setup_obs, energies):
    setup, obs, x0 = setup_obs
    names = [c.name for c in setup.likelihood.cues]
    m = setup.model
    x = x0.copy()
    x[m.dof_names.index("root_tz")] -= 0.1  # both ankles about 10 cm below the floor
    j = jax.jit(lambda x: setup.likelihood.geometry(x).joints)(jnp.asarray(x))
    z = np.asarray(j)[[m.joint_names.index("left_ankle"), m.joint_names.index("right_ankle")], 2]
    below = np.maximum(-z, 0.0) / 0.05  # E = sum over ankles of max(0, floor - z) / 5 cm
    assert np.all(below > 0.5)
    by_part = {
        p[0]: float(np.asarray(energies(jnp.asarray(x), k))[names.index("ground"), 0])
        for k, p in enumerate(setup.parts)
    }
    assert by_part["left_shin"] == pytest.approx(below[0], rel=1e-4)
    assert by_part["right_shin"] == pytest.approx(below[1], rel=1e-4)
    assert all(v == 0.0 for s, v in by_part.items() if not s.endswith("_shin"))


def test_moving_one_partition_leaves_the_others_energies_unchanged(setup_obs, energies):
    """Partitioned sampling's premise: partition k's weight depends on the DOFs that move its body parts only.
    Bending the right elbow changes the right forearm's energies and none of the legs' or the head's."""
    setup, obs, x0 = setup_obs
    m = setup.model
    x = x0.copy()
    x[m.dof_names.index("right_elbow")] += 0.8
    parts = [p[0] for p in setup.parts]
    before = {p: np.asarray(energies(jnp.asarray(x0), k)) for k, p in enumerate(parts)}
    after = {p: np.asarray(energies(jnp.asarray(x), k)) for k, p in enumerate(parts)}
    assert not np.allclose(before["right_forearm"], after["right_forearm"])
    for p in (
        "head",
        "left_upper_arm",
        "left_forearm",
        "left_thigh",
        "right_thigh",
        "left_shin",
        "right_shin",
    ):
        np.testing.assert_array_equal(before[p], after[p], err_msg=p)


def test_one_partition_of_every_part_is_the_whole_body_likelihood(setup_obs, energies):
    """A table whose one partition holds every body part gives the energies without a table; the filter's batch
    is −ln 100 times the sum of the partition's cue energies, one compiled program for every partition."""
    setup, obs, x0 = setup_obs
    lik = setup.likelihood
    X = jnp.asarray(x0)[None] + 0.05 * jax.random.normal(jax.random.key(0), (4, x0.size))
    view = jax.jit(lambda lik, x: lik.view_energies(x, obs))
    whole = np.asarray(view(lik.with_partitions([setup.model.segment_names]), X[1]))
    plain = np.asarray(view(lik.with_partitions(None), X[1]))
    np.testing.assert_allclose(whole, plain, rtol=1e-5, atol=1e-7)
    f = jax.jit(lambda X, k: lik.batch(X, obs, 0, k))
    for k in (0, 4, 9):
        e = np.stack([np.asarray(energies(X[i], k)).sum() for i in range(len(X))])
        np.testing.assert_allclose(np.asarray(f(X, k)), -LN_A * e, rtol=1e-5)
    assert f._cache_size() == 1  # the partition is data of the compiled likelihood
