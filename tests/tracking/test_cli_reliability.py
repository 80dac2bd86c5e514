"""``jaxmocap track`` never loses a result behind exit status 0 and never ends with a traceback: a second writer is
refused while the first goes on; SIGTERM and Ctrl-C end with one line and the outputs written (poses, BVH,
diagnostics with the summary); a run killed while writing its overlays is completed by ``--resume`` (readable BVH
and MP4s); impossible options end with one line and exit status 2 and leave no output folder behind."""

import json
import os
import signal
import subprocess
import time

import cv2
import numpy as np
import pytest
from test_cli_track import TRACK_OPTS, _cmd, _csv_rows, _main, _one_error

from jaxmocap import cli
from jaxmocap.io import bvh, export
from jaxmocap.tracking import resources


def _wait(cond, proc, timeout=300.0):
    deadline = time.monotonic() + timeout
    while not cond() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.002)
    assert proc.poll() is None, "the run ended before the test could act on it"


def _start(sequence, env, out, *more):
    return subprocess.Popen(
        _cmd("track", sequence, "--out", out, "--quiet", *TRACK_OPTS, *more),
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )


def _finish(proc):
    out, err = proc.communicate(timeout=600)
    return proc.returncode, err.decode()


def _outputs_agree(out, status):
    """Poses (snapshot, journal, CSV), BVH and the diagnostics summary hold the same frames."""
    p = export.load_poses(out / "poses.npz")
    n = len(p["frame_index"])
    assert (
        n
        == len(export.read_pose_journal(out / "poses.journal")["frame_index"])
        == _csv_rows(out / "poses.csv")
    )
    diag = json.loads((out / "diagnostics.json").read_text())
    assert diag["summary"]["frames_tracked"] == n and len(diag["frames"]) == n
    assert bvh.load_bvh(out / "track.bvh", scale=0.01).num_frames == n
    assert json.loads((out / "run.json").read_text())["status"] == status
    return n, diag["summary"]


@pytest.mark.slow
def test_a_second_writer_is_refused_while_the_first_runs(capsys, sequence, env, tmp_path):
    out = tmp_path / "run"
    first = _start(sequence, env, out)
    try:
        _wait(lambda: _csv_rows(out / "poses.csv") >= 2, first)
        first.send_signal(signal.SIGSTOP)  # paused, holding its lock, while another run tries
        for how in ("--overwrite", "--resume"):
            code, err = _main(capsys, "track", sequence, "--out", out, "--quiet", *TRACK_OPTS, how)
            _one_error(code, err, "is being written by another run", f"pid {first.pid} on")
    finally:
        first.send_signal(signal.SIGCONT)
        code, err = _finish(first)
    assert code == 0, err
    n, summary = _outputs_agree(out, "complete")
    assert n == 60 and summary["resumed_at"] is None
    code, err = _main(capsys, "track", sequence, "--out", out, "--quiet", "--resume", *TRACK_OPTS)
    _one_error(code, err, "holds a complete run", "nothing to resume")


@pytest.mark.slow
def test_a_run_killed_while_writing_its_overlays_is_completed_by_resume(capsys, sequence, env, tmp_path):
    """A run killed (SIGKILL) while it writes the overlay videos leaves none under its final name; the resume
    writes them and exits 0, with a BVH and MP4s that their readers open."""
    out = tmp_path / "run"
    proc = _start(sequence, env, out, "--overlay")
    try:
        _wait(lambda: (out / ".overlays.tmp").exists(), proc)
        proc.send_signal(signal.SIGKILL)
    finally:
        _finish(proc)
    assert not list(out.glob("overlay_*.mp4"))  # none under its final name until it is complete
    assert json.loads((out / "run.json").read_text())["status"] == "running"
    code, err = _main(
        capsys, "track", sequence, "--out", out, "--quiet", "--resume", "--overlay", *TRACK_OPTS
    )
    assert code == 0, err
    n, summary = _outputs_agree(out, "complete")
    assert n == 60 and summary["resumed_at"] is None and not summary["interrupted"]
    for view in ("left", "right"):
        cap = cv2.VideoCapture(str(out / f"overlay_{view}.mp4"))
        ok, img = cap.read()
        assert ok and img.shape == (72, 96, 3) and int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 60
        cap.release()
    assert not (out / ".overlays.tmp").exists()


def test_ctrl_c_while_starting_is_one_line(sequence, env, tmp_path):
    proc = _start(sequence, env, tmp_path / "run")
    time.sleep(1.5)  # importing JAX, or building the setup
    proc.send_signal(signal.SIGINT)
    code, err = _finish(proc)
    assert code == 130 and err.count("\n") == 1 and err.startswith("jaxmocap: interrupted"), err


class _SignalsAt:
    """A frame source that sends ``sig`` to its own process when frame ``t`` is read."""

    def __init__(self, source, t, sig):
        self.s, self.t, self.sig = source, t, sig

    def __getattr__(self, name):
        return getattr(self.s, name)

    def read(self, t, *args, **kwargs):
        if t == self.t:
            os.kill(os.getpid(), self.sig)
        return self.s.read(t, *args, **kwargs)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_a_signal_during_a_run_is_one_line_and_flushes_the_outputs(
    capsys, sequence, tmp_path, monkeypatch, sig
):
    """Ctrl-C (exit status 130) and SIGTERM (143) while frames are tracked: one line naming what was written,
    and every output — poses, BVH, diagnostics with the summary — holds the frames tracked. Frames are read
    ``READ_AHEAD`` ahead (:meth:`jaxmocap.tracking.setup.TrackSetup.observe`): frame 7 is read, and the signal
    sent, while frame ``7 − READ_AHEAD − 1`` is tracked."""
    from jaxmocap.tracking.setup import READ_AHEAD

    opened = cli._open_source
    monkeypatch.setattr(cli, "_open_source", lambda *a: _SignalsAt(opened(*a), 7, sig))
    out = tmp_path / "run"
    code, err = _main(capsys, "track", sequence, "--out", out, "--quiet", *TRACK_OPTS, "--frames", "0:20")
    why = "terminated (SIGTERM)" if sig == signal.SIGTERM else "interrupted"
    assert code == 128 + sig and err.count("\n") == 1 and err.startswith(f"jaxmocap: {why}; "), err
    n, summary = _outputs_agree(out, "interrupted")
    assert (
        7 - READ_AHEAD - 2 <= n <= 7
        and summary["interrupted"]
        and f"{n} of 20 frames" in err
        and "--resume continues" in err
    )


def test_impossible_options_are_one_line_and_leave_no_folder(capsys, sequence, tmp_path, monkeypatch):
    out = tmp_path / "o"
    args = ("track", sequence, "--out", out, *TRACK_OPTS, "--frames", "0:3")
    code, err = _main(capsys, *args, "--seed", "99999999999999999999")
    _one_error(code, err, "--seed must be an integer from 0 to 4294967295")
    code, err = _main(
        capsys, "track", sequence, "--out", out, "--particles", "100000000000", "--model", "upper9"
    )
    _one_error(code, err, "at most 2,147,483,647 particles")
    assert not out.exists()
    for state in (np.float64(1.0), np.zeros(0), np.zeros((2, 3, 25)), np.array(["x"] * 13)):
        np.savez(tmp_path / "init.npz", state=state)
        code, err = _main(capsys, *args, "--init", tmp_path / "init.npz")
        _one_error(code, err, "init.npz", "'state' is", "expected (13,) or (T, 13)")
        assert not out.exists()
    # a compiled step that would not fit (XLA's estimate, made here to exceed the memory): refused before it runs
    monkeypatch.setattr(resources, "program_bytes", lambda compiled: 10**15)
    code, err = _main(capsys, *args, "--quiet")
    _one_error(
        code, err, "--particles 40: the apf step (upper9, 40 particles) needs 1000000.0 GB", "use fewer"
    )
    assert not out.exists()


def test_memory_figures_are_xla_s_and_the_particle_set_s():
    """``program_bytes`` is the compiled program's temporaries plus outputs (a matrix product's output is its
    size); the particle set of 10⁸ particles of 25 DOFs is 10.4 GB of float32."""
    import jax
    import jax.numpy as jnp

    compiled = jax.jit(lambda a: a @ a).lower(jnp.ones((256, 256), jnp.float32)).compile()
    need = resources.program_bytes(compiled)
    assert need >= 256 * 256 * 4
    with pytest.raises(ValueError, match="needs 10.4 GB, more than the 1.0 GB"):
        resources.check_particle_set(10**8, 25, "--particles 100000000", available=10**9)
    resources.check_particle_set(10**6, 25, "--particles 1000000", available=10**9)
    with pytest.raises(ValueError, match=f"about {int(1000 * (need // 2) / need)} would fit"):
        resources.check_program(compiled, "the step", 1000, available=need // 2)
    resources.check_program(compiled, "the step", 1000, available=need)
