"""The benchmark runner: its RESULTS.md block logic, and a quick-mode smoke run of every benchmark (tiny sizes, no
timing assertion; in one child process, see :func:`quick_run`)."""

import collections
import os
import pathlib
import subprocess
import sys

import pytest

BENCH = pathlib.Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCH))

import run as runner  # noqa: E402


def test_update_block_replaces_only_between_markers():
    text = "# R\n\nhand-written A\n\n<!-- generated:x begin -->\nold\n<!-- generated:x end -->\n\nhand-written B\n"
    out = runner.update_block(text, "x", "new table")
    assert "old" not in out
    assert "hand-written A" in out and "hand-written B" in out
    assert out.index("hand-written A") < out.index("new table") < out.index("hand-written B")
    # a second update replaces again (one block, not two)
    out2 = runner.update_block(out, "x", "newer")
    assert out2.count("generated:x begin") == 1 and "new table" not in out2 and "newer" in out2


def test_update_block_appends_missing_section():
    out = runner.update_block("# R\n\ntext\n", "y", "| a |\n|---|", "Title Y")
    assert out.startswith("# R\n\ntext\n")
    assert "## Title Y\n\n<!-- generated:y begin -->\n| a |\n|---|\n<!-- generated:y end -->\n" in out


def test_unknown_benchmark_is_an_error(capsys):
    with pytest.raises(SystemExit) as e:
        runner.main(["--quick", "--only", "nonexistent"])
    assert e.value.code == 2
    assert "unknown benchmark" in capsys.readouterr().err


def test_machine_block_names_versions():
    block = runner.machine_block((1.0, 2.0, 3.0))
    for word in (
        "cores",
        "load average at start 1.0 / 2.0 / 3.0",
        "Python",
        "JAX",
        "jaxlib",
        "NumPy",
        "OpenCV",
    ):
        assert word in block


@pytest.mark.slow
def test_runner_quick_writes_results(quick_results):
    """The quick run of every benchmark but the tracking ones (the ``quick_results`` fixture) updates a results file
    in place: its blocks written, the text around them kept."""
    proc, text = quick_results
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert "keep me" in text
    assert "<!-- generated:machine begin -->" in text and "<!-- generated:kinematics end -->" in text
    assert "| ratio |" in text


# what each quick benchmark's markdown must contain (its table header or report line)
EXPECT = {
    "kinematics": "particles/s",
    "likelihood": "",
    "parsec": "µs/particle/layer",
    "features": "pairs",
    "render": "frames/s",
    "synth": "view-frames/s",
    "end_to_end": "frames/s",
    "scaling": "| sweep |",
    "iros": "SIR",
    "foreground": "IoU",
    "accuracy": "| configuration |",
    "hybrid": "APF",
}


def test_every_script_is_registered():
    """Every script under perf/ and experiments/ has an entry (its command) in the runner, and every entry a file."""
    scripts = {
        p.relative_to(BENCH).as_posix() for d in ("perf", "experiments") for p in (BENCH / d).glob("*.py")
    }
    assert scripts == {s.path for s in runner.SCRIPTS.values()}
    assert set(runner.BENCHMARKS) <= set(runner.SCRIPTS)


def test_every_result_names_its_command():
    """Every file under results/ is listed in results/README.md with what regenerates it, and every Markdown
    file there starts with that line."""
    index = (BENCH / "results" / "README.md").read_text()
    for p in sorted((BENCH / "results").iterdir()):
        if p.name == "README.md":
            continue
        assert runner.made_by(p.name), p.name
        assert f"| [{p.name}]({p.name}) | {runner.made_by(p.name)} |" in index, p.name
        if p.suffix == ".md":
            assert p.read_text().split("\n", 1)[0] == runner.first_line(p.name), p.name


def test_scripts_import_no_other_script():
    """Scripts share code through common, scenes and reference only."""
    stems = {pathlib.Path(s.path).stem for s in runner.SCRIPTS.values()}
    for s in runner.SCRIPTS.values():
        text = (BENCH / s.path).read_text()
        for stem in stems:
            assert f"import {stem}\n" not in text and f"from {stem} import" not in text, (s.path, stem)


def test_every_benchmark_has_an_expectation():
    assert set(EXPECT) == set(runner.BENCHMARKS)


#: the quick runs that track whole sequences, in tests/test_benchmarks_tracking.py (a file per pytest-xdist worker)
TRACKING = ("accuracy", "end_to_end", "hybrid")


def quick_run(names, results) -> subprocess.CompletedProcess:
    """``benchmarks/run.py --quick --only NAMES --results RESULTS`` in a child process at XLA's lowest backend
    optimisation level: a smoke run (no timing assertion, the numbers are tested elsewhere) whose time is mostly
    compilation, ≈ 30 % faster there."""
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    env.setdefault("JAX_PLATFORMS", "cpu")
    env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0").strip()
    argv = [sys.executable, str(BENCH / "run.py"), "--quick", "--only", *names, "--results", str(results)]
    return subprocess.run(argv, env=env, capture_output=True, text=True, timeout=900)


def quick_block(text, name):
    """The markdown of benchmark ``name`` in a results file's ``text`` (between its markers)."""
    begin, end = runner._markers(name)
    assert text.count(begin) == 1 and text.count(end) == 1, name
    return text.split(begin)[1].split(end)[0]


def check_markdown(name, md):
    """What a quick run's markdown must be: non-empty, no failure reported, the benchmark's expected text."""
    assert isinstance(md, str) and md.strip()
    assert "failed" not in md.lower()
    assert EXPECT[name] in md


def test_every_benchmark_has_a_smoke_test():
    assert set(EXPECT) == set(runner.BENCHMARKS)
    assert set(TRACKING) <= set(runner.BENCHMARKS)


#: the quick runs in this file's child process
OTHERS = sorted(set(runner.BENCHMARKS) - set(TRACKING))


@pytest.fixture(scope="module")
def quick_results(tmp_path_factory):
    """One child process runs every quick benchmark of :data:`OTHERS` into a results file that had text of its own;
    ``(the process, the file's text)``."""
    path = tmp_path_factory.mktemp("quick") / "RESULTS.md"
    path.write_text("# Benchmark results\n\nkeep me\n")
    proc = quick_run(OTHERS, path)
    return proc, path.read_text()


@pytest.mark.slow
@pytest.mark.parametrize("name", OTHERS)
def test_quick_benchmark_runs(name, quick_results):
    check_markdown(name, quick_block(quick_results[1], name))


def test_profile_names_the_kernels_and_their_contents(tmp_path):
    """The profiling tool reads XLA's kernel events from a JAX trace and the operations inside each fusion from
    the compiled program (a tiny program whose one fusion holds a sine)."""
    import jax
    import jax.numpy as jnp

    prof = runner.load("profile_likelihood")

    f = jax.jit(lambda x: jnp.sin(x) * 2.0 + 1.0)
    x = jnp.linspace(0.0, 1.0, 1 << 16)
    f(x).block_until_ready()
    with jax.profiler.trace(str(tmp_path), create_perfetto_trace=True):
        for _ in range(2):
            f(x).block_until_ready()
    times = prof.kernel_times(str(tmp_path), 2)
    contents = prof.fusion_contents(f.lower(x).compile().as_text())
    fused = [name for name, ops in contents.items() if ops["sine"] == 1 and ops["multiply"] >= 1]
    assert fused and fused[0] in times and times[fused[0]] > 0
    # --by-kind: the kernels of one kind (the name without its number) summed
    kinds = prof.by_kind(
        collections.Counter({"add_fusion.1": 1.0, "add_fusion.12": 2.0, "add_fusion": 0.5, "copy.3": 4.0})
    )
    assert kinds == collections.Counter({"add_fusion": 3.5, "copy": 4.0})


def test_plate_source_is_what_a_recording_gives(tmp_path):
    """The tracking experiments' default input (``scenes.PlateSource``): silhouettes subtracted against the plates
    agree with the rendered masks (IoU ≥ 0.9 per view and frame; 0.975–0.995 measured on these frames), the
    keypoints are the simulated detections in the evaluation layout (each confident one within 10 px of the
    ground-truth joint projected by OpenCV), and it reads no rendered mask: with the mask files deleted every
    frame still reads. The oracle input reads the sequence as written."""
    import numpy as np
    import scenes

    from jaxmocap.io.sources import SequenceSource
    from jaxmocap.synth import generate as synth

    sys.path.insert(0, str(pathlib.Path(__file__).parent / "fit"))
    from test_ik import _opencv_pixels  # the joints projected by cv2.projectPoints

    seq = tmp_path / "seq"
    synth.synthesize("demo", seq, rig="stereo", frames="150:162", size=(160, 120), seed=0)
    src = scenes.open_source(seq)
    oracle = scenes.open_source(seq, oracle=True)
    assert isinstance(src, scenes.PlateSource) and type(oracle) is SequenceSource
    assert src.keypoints.shape == (3, 2, 15, 3)
    for t in range(3):
        fd, truth = src.read(t), oracle.read(t)
        for v in range(2):
            m, r = fd.masks[v], truth.masks[v] > 0
            assert np.logical_and(m, r).sum() / np.logical_or(m, r).sum() >= 0.9
            uv = _opencv_pixels(src.rig, src.groundtruth[t])[v]
            kp = fd.keypoints[v]
            seen = kp[:, 2] > 0
            assert seen.sum() >= 10
            assert np.linalg.norm(kp[seen, :2] - uv[seen], axis=-1).max() < 10
    for p in seq.glob("views/*/mask/*.png"):
        p.unlink()
    assert all(len(src.read(t).masks) == 2 for t in range(3))


#: four distorted cameras looking at a person-sized volume (OpenCV's rotation vectors and translations)
_RVECS = ((1.4, 0.0, 0.0), (1.2, 0.6, -0.3), (1.3, -0.7, 0.4), (1.5, 0.2, 0.1))
_TVECS = ((0.0, 1.0, 3.0), (0.3, 0.9, 3.2), (-0.2, 1.1, 3.1), (0.1, 1.0, 2.9))


def _cameras(num_views):
    """``(K, dist, rvecs, tvecs)`` of the first ``num_views`` cameras above (f = 300 px, radial and tangential
    distortion)."""
    import numpy as np

    K = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])
    dist = np.array([-0.1, 0.02, 0.001, -0.001, 0.0])
    return K, dist, np.array(_RVECS[:num_views]), np.array(_TVECS[:num_views])


def _distorted_views(X, num_views):
    """``(rig, kp)``: the first ``num_views`` of the cameras above (K, f = 300 px, radial and tangential
    distortion) and the points ``X (T, J, 3)`` projected into them by ``cv2.projectPoints``, confidence 1:
    ``kp (T, V, J, 3)``."""
    import cv2
    import numpy as np

    from jaxmocap.geometry import camera

    K, dist, rvecs, tvecs = _cameras(num_views)
    rig = camera.from_opencv(
        np.stack([K] * num_views),
        np.stack([dist] * num_views),
        np.stack([cv2.Rodrigues(r)[0] for r in rvecs]),
        tvecs,
    )
    T, J = X.shape[:2]
    kp = np.ones((T, num_views, J, 3))
    for v in range(num_views):
        uv, _ = cv2.projectPoints(X.reshape(-1, 1, 3), rvecs[v], tvecs[v], K, dist)
        kp[:, v, :, :2] = uv.reshape(T, J, 2)
    return rig, kp


def test_accuracy_default_baseline_triangulates_as_opencv():
    """The triangulation baseline of ``experiments/accuracy_default.py``: noise-free detections of three distorted
    cameras give back the 3D joints (closed form: the points projected by OpenCV); with pixel noise and two views
    it agrees with ``cv2.triangulatePoints`` on the undistorted points; a joint seen by one view is NaN and
    counted; the root is the middle of the hips, the head is never estimated."""
    import types

    import cv2
    import numpy as np

    from jaxmocap.geometry.body import EVAL_JOINTS

    acc = runner.load("accuracy_default")
    rng = np.random.default_rng(3)
    V, T, J = 3, 4, len(EVAL_JOINTS)
    X = rng.uniform([-0.5, -0.5, 0.0], [0.5, 0.5, 1.8], (T, J, 3))
    rig, kp = _distorted_views(X, V)
    K, dist, rvecs, tvecs = _cameras(V)
    knee = EVAL_JOINTS.index("left_knee")
    kp[1, 1:, knee, 2] = 0.0  # seen by view 0 only
    got, views = acc.triangulate_detections(types.SimpleNamespace(rig=rig, keypoints=kp))
    hips = [EVAL_JOINTS.index("left_hip"), EVAL_JOINTS.index("right_hip")]
    body = [j for j in range(J) if EVAL_JOINTS[j] not in ("root", "head")]
    ok = np.ones((T, J), bool)
    ok[1, knee] = False
    sel = ok[:, body]
    assert np.abs(got[:, body][sel] - X[:, body][sel]).max() < 2e-3
    assert np.isnan(got[1, knee]).all() and views[1, knee] == 1 and views[0, knee] == 3
    assert np.isnan(got[:, EVAL_JOINTS.index("head")]).all()
    np.testing.assert_allclose(got[:, 0], X[:, hips].mean(axis=1), atol=2e-3)

    noisy = kp.copy()
    noisy[..., :2] += rng.normal(0.0, 1.5, noisy[..., :2].shape)
    noisy[:, 2, :, 2] = 0.0  # two views: the DLT is OpenCV's
    got, _ = acc.triangulate_detections(types.SimpleNamespace(rig=rig, keypoints=noisy))
    P = [np.hstack([cv2.Rodrigues(r)[0], t[:, None]]) for r, t in zip(rvecs, tvecs, strict=True)]
    ab = [cv2.undistortPoints(noisy[:, v, :, :2].reshape(-1, 1, 2), K, dist).reshape(-1, 2).T for v in (0, 1)]
    H = cv2.triangulatePoints(P[0], P[1], ab[0], ab[1])
    ref = (H[:3] / H[3]).T.reshape(T, J, 3)
    assert np.abs(got[:, body][sel] - ref[:, body][sel]).max() < 2e-3


def test_iros2007_recovery_claim_counts_the_runs_that_never_recover():
    """``experiments/iros2007.py``: the IAPF's re-initialisation beats the APF's when it recovers in more runs, or in
    as many and faster; fewer frames over fewer runs (the runs that never recover left out) does not."""
    exp = runner.load("iros2007")
    iapf = [0, 1, 1, 2, 0, 0, 1, 0, 3, 0]  # 10 of 15 runs recovered, 0.8 frames on average
    apf = [1] * 12  # 12 of 15, 1.0 frame
    assert not exp.recovers_better(iapf, apf)
    assert exp.recovers_better(apf, iapf)
    assert exp.recovers_better([0, 1], [1, 1]) and not exp.recovers_better([1, 1], [0, 1])
    assert not exp.recovers_better([], [])


def test_pose2sim_procedure_rejects_the_view_that_disagrees_and_fills_short_gaps():
    """``pose2sim_track.pose2sim_triangulated`` (Pose2Sim's triangulation step with its defaults) on noise-free
    detections of four distorted cameras, projected by OpenCV: every point comes back; a detection moved by 80 px is
    left out (the point is the other three cameras' triangulation, within 1 mm of the truth, where the plain
    weighted DLT is pulled centimetres off); a joint whose four detections all disagree is rejected; a gap of three
    such frames is filled by cubic interpolation (a straight-line motion: exact) and one of twelve is not."""
    import numpy as np

    from jaxmocap.geometry.body import EVAL_JOINTS

    p2s = runner.load("pose2sim_track")
    V, T, J = 4, 30, len(EVAL_JOINTS)
    rng = np.random.default_rng(5)
    drift = np.linspace(0.0, 0.3, T)[:, None, None] * np.array([1.0, 0.0, 0.0])  # along x, 0.3 m in all
    X = rng.uniform([-0.5, -0.5, 0.0], [0.5, 0.5, 1.8], (1, J, 3)) + drift
    rig, kp = _distorted_views(X, V)
    kp[..., 2] = 0.9
    knee, wrist, ankle = (EVAL_JOINTS.index(n) for n in ("left_knee", "left_wrist", "right_ankle"))
    kp[4, 2, knee, :2] += 80.0  # one view off
    apart = 100.0 * np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])  # every view off another way
    kp[10:13, :, wrist, :2] += apart  # rejected, then interpolated
    kp[15:27, :, ankle, :2] += apart  # a gap too long to fill
    got, rejected = p2s.pose2sim_triangulated(rig, kp, range(V))
    assert np.linalg.norm(got[4, knee] - X[4, knee]) < 1e-3
    plain = p2s.triangulated(rig, kp, range(V))
    assert np.linalg.norm(plain[4, knee] - X[4, knee]) > 0.01
    np.testing.assert_allclose(got[10:13, wrist], X[10:13, wrist], atol=1e-3)
    assert np.isnan(got[15:27, ankle]).all()
    fine = np.ones((T, J), bool)
    fine[15:27, ankle] = False
    assert np.abs(got[fine] - X[fine]).max() < 2e-3
    assert rejected == pytest.approx(15 / (T * J))


def test_host_choices_are_the_four_compilations_this_cpus_first():
    """``bench_parsec.py --host-choices`` times the four ways :mod:`jaxmocap.host` compiles PARSEC's likelihood, the
    first row the one this CPU gets (``jaxmocap.host.gathers_apart`` and ``particle_options``)."""
    from jaxmocap import host, parsec

    m = runner.load("parsec")
    seq = m.DATA / "sequenceB_2"
    progs = m.host_choices(parsec.load_body_shape(seq / "BodyShapeParameters.txt"), parsec.load_cameras(seq))
    names = list(progs)
    assert len(names) == 4 and len(set(names)) == 4
    assert [n.endswith("(this CPU's choice)") for n in names] == [True, False, False, False]
    apart = host.gathers_apart()
    loop = host.LOOP_FUSION.items() <= host.particle_options().items()
    assert names[0].startswith(f"{'apart' if apart else 'fused'}, {'loop' if loop else 'fusion'} emitters")


def test_startup_ab_names_the_installed_version_of_a_requirement():
    """``startup_ab.py`` labels this environment's side with the installed version of each requirement it swaps
    (as the package reports it itself), whatever comparison the requirement spells."""
    import numpy

    m = runner.load("startup_ab")
    for req in ("numpy==1.26.4", "numpy>=3", "numpy<2", "numpy~=1.26", "numpy!=2.0.0"):
        assert m.installed(req) == f"numpy=={numpy.__version__}"
