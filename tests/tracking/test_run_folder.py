"""The run folder: one writer at a time (a second one is refused with the holder's pid and host, the lock of a
killed process is taken over), no half-made folder after a failed start, and a resume that checks every output it
continues from — a missing or foreign file is refused with one message and left as it was."""

import json
import os
import shlex
import signal
import socket
import subprocess
import sys

import numpy as np
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.io import export
from jaxmocap.tracking import run_folder

DOFS = ("a", "b")
DESC = {"options": {"seed": 0}, "input": {"frames": 9}, "model": "m", "dof_names": list(DOFS)}


def _tracked(out, rows=5, desc=DESC):
    """A folder as a run that tracked ``rows`` frames leaves it (checkpoint after the last)."""
    run_folder.start_out(out, True, desc)
    poses = export.PoseWriter(out, DOFS, "m", fps=30.0)
    diag = export.DiagnosticsWriter(out, desc)
    for t in range(rows):
        poses.append(t, [t, -0.5 * t], np.full((15, 3), 0.1 * t))
        diag.append({"frame": t, "seconds": 0.01})
    poses.close()
    diag.close()
    export.atomic_write_npz(
        out / run_folder.RESUME_NPZ, {"frame": np.asarray(rows - 1), "rows": np.asarray(rows)}
    )
    return out


def _files(out):
    return {p.name: p.read_bytes() for p in sorted(out.iterdir()) if p.is_file()}


def _refused(out, *needles, desc=DESC):
    before = _files(out)
    with pytest.raises(MocapInputError) as e:
        run_folder.check_out(out, desc, resume=True, overwrite=False)
    for n in needles:
        assert n in str(e.value), str(e.value)
    assert _files(out) == before  # nothing written, nothing erased
    return str(e.value)


def test_a_complete_folder_resumes_from_its_checkpoint(tmp_path):
    out = _tracked(tmp_path / "run")
    ck = run_folder.check_out(out, DESC, resume=True, overwrite=False)
    assert int(ck["rows"]) == 5 and int(ck["frame"]) == 4
    other = {**DESC, "options": {"seed": 1}}
    with pytest.raises(MocapInputError, match="other options or input"):
        run_folder.check_out(out, other, resume=True, overwrite=False)


def _options(*argv) -> dict:
    """The options' identity of ``jaxmocap track --resume ARGV`` as the command line parses them."""
    from jaxmocap import cli
    from jaxmocap.api import run_options

    args = cli.build_parser().parse_args(["track", "in", "--out", "out", "--resume", *argv])
    return run_options(cli._track_values(args)).identity()


def _suggested(message: str) -> list[str]:
    return shlex.split(message.split("resume with ", 1)[1])


@pytest.mark.parametrize(
    "then, now",
    [
        ({"particles": 300}, {"particles": 50}),  # the four-camera default that changed (300 -> 50)
        ({"layers": 5, "refine": "track"}, {"layers": 3, "refine": "estimate"}),
        ({"cues": [["foreground", 1.0], ["coverage", 4.0]], "refine_prior": 1.0},
         {"cues": [["foreground", 1.0]], "refine_prior": 2.0}),
    ],
)  # fmt: skip
def test_a_default_that_resolves_otherwise_is_named_and_its_option_continues_the_run(tmp_path, then, now):
    """The same options, but defaults that resolve otherwise (a version whose default for the input moved): refused,
    naming each with the option that gives the old value back; those options, parsed by the command line, resume
    the run (the options differ from the old run's only by the values its defaults resolved to)."""
    desc = {**DESC, "options": _options(), "particles": 300, "layers": 5, **then}
    out = _tracked(tmp_path / "run", desc=desc)
    with pytest.raises(
        MocapInputError, match="where this run's defaults resolve otherwise: resume with --"
    ) as e:
        run_folder.check_out(out, {**desc, **now}, resume=True, overwrite=False)
    for k in then:
        assert k.replace("_", " ") in str(e.value)
    argv = _suggested(str(e.value))
    assert len(argv) == 2 * len(then)
    ck = run_folder.check_out(out, {**desc, "options": _options(*argv)}, resume=True, overwrite=False)
    assert int(ck["rows"]) == 5
    # an option given with another value than the old run's default resolved to is named the same way
    _refused(
        out,
        "resume with --particles 300",
        desc={**desc, "options": _options("--particles", "299"), "particles": 299},
    )
    # a run that did not record what its defaults resolved to: an option given now is another option
    legacy = _tracked(tmp_path / "legacy", desc={**DESC, "options": _options()})
    _refused(
        legacy, "other options", desc={**DESC, "options": _options("--particles", "300"), "particles": 300}
    )


def test_a_body_measured_otherwise_cannot_be_continued(tmp_path):
    """A resolved value no option sets (the body measured from the detections) refuses the resume with
    --overwrite; floats that differ by rounding (another CPU) do not."""
    dims = {"femur": 0.43, "tibia": 0.41}
    desc = {**DESC, "body_dimensions": dims, "diffusion_std": [0.01, 0.02]}
    out = _tracked(tmp_path / "run", desc=desc)
    rounded = {**desc, "body_dimensions": {"femur": 0.43 * (1 + 1e-9), "tibia": 0.41}}
    assert run_folder.check_out(out, rounded, resume=True, overwrite=False) is not None
    with pytest.raises(MocapInputError, match="other body dimensions, .*cannot continue it: --overwrite"):
        run_folder.check_out(
            out, {**desc, "body_dimensions": {**dims, "femur": 0.45}}, resume=True, overwrite=False
        )


def test_pose_files_that_do_not_cover_the_checkpoint_are_refused(tmp_path):
    out = _tracked(tmp_path / "run")
    (out / export.POSES_JOURNAL).unlink()
    (out / export.POSES_NPZ).unlink()
    _refused(out, "checkpoint covers 5 tracked frames", "cannot resume")
    out = _tracked(tmp_path / "short")
    data = (out / export.POSES_JOURNAL).read_bytes()
    (out / export.POSES_JOURNAL).write_bytes(data[: -8 * (1 + 2 + 45) - 3])  # two records short, one torn
    export.atomic_write_npz(out / export.POSES_NPZ, export.read_pose_journal(out / export.POSES_JOURNAL))
    _refused(out, "poses.journal 3", "poses.npz 3")


def test_foreign_files_are_refused_and_left_alone(tmp_path):
    out = _tracked(tmp_path / "csv")
    (out / export.POSES_CSV).write_text("time,x,y\n0,1,2\n")
    _refused(out, "poses.csv", "not written by this run")
    out = _tracked(tmp_path / "csv_frames")
    text = (out / export.POSES_CSV).read_text().replace("\n2,", "\n7,")
    (out / export.POSES_CSV).write_text(text)
    _refused(out, "poses.csv", "frame numbers disagree")
    out = _tracked(tmp_path / "npz")
    other = export.PoseWriter(tmp_path / "elsewhere", ("x", "y", "z"), "m", fps=30.0)
    other.append(0, [0, 0, 0], np.zeros((15, 3)))
    other.close()
    (out / export.POSES_NPZ).write_bytes((tmp_path / "elsewhere" / export.POSES_NPZ).read_bytes())
    _refused(out, "poses.npz", "another model")
    out = _tracked(tmp_path / "npz_rows")
    a = export.load_poses(out / export.POSES_NPZ)
    a["state"] = a["state"] + 1.0
    export.atomic_write_npz(out / export.POSES_NPZ, a)
    _refused(out, "poses.npz", "disagrees with poses.journal")


def test_missing_checkpoint_diagnostics_or_run_json_are_refused(tmp_path):
    out = _tracked(tmp_path / "ck")
    (out / run_folder.RESUME_NPZ).unlink()
    _refused(out, "resume.npz", "the 5 frames tracked here cannot be continued")
    out = _tracked(tmp_path / "diag")
    (out / export.DIAGNOSTICS_JOURNAL).unlink()
    _refused(out, "diagnostics.jsonl", "missing")
    out = _tracked(tmp_path / "runjson")
    (out / run_folder.RUN_JSON).unlink()
    _refused(out, "run.json", "missing")


def test_a_complete_run_is_not_resumed(tmp_path):
    out = _tracked(tmp_path / "run")
    run_folder.set_status(out, "complete")
    assert json.loads((out / run_folder.RUN_JSON).read_text())["status"] == "complete"
    _refused(out, "holds a complete run", "nothing to resume")


def test_lost_snapshot_and_csv_are_rebuilt_from_the_journal(tmp_path):
    """``poses.npz`` and ``poses.csv`` are made from the journal: when they are missing, a resume writes them
    again, byte for byte."""
    out = _tracked(tmp_path / "run")
    before = _files(out)
    (out / export.POSES_NPZ).unlink()
    (out / export.POSES_CSV).unlink()
    run_folder.check_out(out, DESC, resume=True, overwrite=False)
    export.PoseWriter(out, DOFS, "m", fps=30.0, keep=5).close()
    after = _files(out)
    for name in (export.POSES_NPZ, export.POSES_CSV, export.POSES_JOURNAL):
        assert after[name] == before[name], name


def test_a_fresh_run_never_replaces_a_run_without_overwrite(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / export.POSES_CSV).write_text("someone else's table\n")
    with pytest.raises(MocapInputError, match=r"already holds a tracking run \(poses.csv\)"):
        run_folder.check_out(out, DESC, resume=False, overwrite=False)
    assert run_folder.check_out(out, DESC, resume=False, overwrite=True) is None


def test_a_second_writer_is_refused_with_the_holder(tmp_path):
    out = tmp_path / "run"
    lock = run_folder.RunLock(out)
    holder = json.loads((out / run_folder.LOCK).read_text())
    assert holder["pid"] == os.getpid() and holder["host"] == socket.gethostname()
    with pytest.raises(MocapInputError) as e:
        run_folder.RunLock(out)
    assert f"pid {os.getpid()} on {socket.gethostname()}" in str(e.value)
    lock.release()
    assert not (out / run_folder.LOCK).exists()
    run_folder.RunLock(out).release()  # free again


def test_the_lock_of_a_killed_process_is_taken_over(tmp_path):
    out = tmp_path / "run"
    code = (
        "import sys, time; from jaxmocap.tracking.run_folder import RunLock; "
        f"RunLock({str(out)!r}); print('locked', flush=True); time.sleep(60)"
    )
    with subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True) as proc:
        try:
            assert proc.stdout.readline().strip() == "locked"
            with pytest.raises(MocapInputError, match=f"pid {proc.pid} on"):
                run_folder.RunLock(out)
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
    lock = run_folder.RunLock(out)  # the kernel dropped the dead holder's lock; its file names it
    assert lock.stale["pid"] == proc.pid
    lock.release()


def test_a_failed_start_leaves_no_folder_behind(tmp_path):
    out = tmp_path / "new" / "run"
    run_folder.RunLock(out).release(remove_created_folder=True)
    assert not out.exists()
    old = tmp_path / "old"
    old.mkdir()
    run_folder.RunLock(old).release(remove_created_folder=True)
    assert old.is_dir() and not any(old.iterdir())
    (tmp_path / "file").write_text("x")
    with pytest.raises(MocapInputError, match="not a folder"):
        run_folder.RunLock(tmp_path / "file")
