"""``jaxmocap track`` / ``eval``: crash safety and resume (a run killed with SIGKILL, then ``--resume``, equals an
uninterrupted run of the same seed), and one clear message with exit status 2 for each kind of bad input."""

import json
import shutil
import signal
import subprocess
import sys
import time

import av
import cv2
import numpy as np
import pytest

from jaxmocap import cli
from jaxmocap.geometry import camera
from jaxmocap.io import bvh, calibration, export
from jaxmocap.synth import generate as synth

# a small, fast configuration: 60 frames at 60 fps of 96x72 px, upper body, two cues
TRACK_OPTS = ["--model", "upper9", "--cues", "foreground,coverage", "--particles", "40", "--layers", "2"]


def _cmd(*args):
    return [sys.executable, "-m", "jaxmocap.cli", *map(str, args)]


def _csv_rows(path):
    try:
        return max(0, len(path.read_text().splitlines()) - 1)
    except FileNotFoundError:
        return 0


@pytest.mark.slow
def test_killed_run_is_valid_and_resume_completes_it(sequence, env, tmp_path):
    full, part = tmp_path / "full", tmp_path / "part"
    done = subprocess.run(
        _cmd("track", sequence, "--out", full, "--quiet", *TRACK_OPTS), env=env, capture_output=True
    )
    assert done.returncode == 0, done.stderr.decode()
    ref = export.load_poses(full)
    T = len(ref["frame_index"])
    assert T == 60

    proc = subprocess.Popen(_cmd("track", sequence, "--out", part, "--quiet", *TRACK_OPTS), env=env)
    deadline = time.monotonic() + 300
    while _csv_rows(part / "poses.csv") < 5 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL, "the run ended before it could be killed"

    # the partial outputs load, agree with each other and with the uninterrupted run
    p = export.load_poses(part)
    n = len(p["frame_index"])
    assert 5 <= n < T
    np.testing.assert_array_equal(p["frame_index"], ref["frame_index"][:n])
    np.testing.assert_array_equal(p["state"], ref["state"][:n])
    np.testing.assert_array_equal(p["joints"], ref["joints"][:n])
    rows = np.loadtxt(part / "poses.csv", delimiter=",", skiprows=1, ndmin=2)
    assert n - 1 <= rows.shape[0] <= n  # the CSV line follows the npz rewrite
    np.testing.assert_allclose(rows[:, 2 : 2 + p["state"].shape[1]], p["state"][: rows.shape[0]], rtol=1e-7)

    res = subprocess.run(
        _cmd("track", sequence, "--out", part, "--quiet", "--resume", *TRACK_OPTS),
        env=env,
        capture_output=True,
    )
    assert res.returncode == 0, res.stderr.decode()
    q = export.load_poses(part)
    np.testing.assert_array_equal(q["frame_index"], ref["frame_index"])
    np.testing.assert_array_equal(q["state"], ref["state"])
    np.testing.assert_array_equal(q["joints"], ref["joints"])
    rows = np.loadtxt(part / "poses.csv", delimiter=",", skiprows=1, ndmin=2)
    np.testing.assert_array_equal(rows[:, 0], ref["frame_index"])
    diag = json.loads((part / "diagnostics.json").read_text())
    assert [r["frame"] for r in diag["frames"]] == list(range(T))
    # the resume continues from the last checkpoint (at most a second old, written after its frame's outputs):
    # the frames after it are tracked again, to the same bits (above)
    assert diag["summary"]["frames_tracked"] == T and 0 < diag["summary"]["resumed_at"] <= n
    assert (part / "track.bvh").read_text() == (full / "track.bvh").read_text()

    # resuming with other options is refused
    code = subprocess.run(
        _cmd("track", sequence, "--out", part, "--resume", "--seed", "3", *TRACK_OPTS),
        env=env,
        capture_output=True,
    )
    assert code.returncode == 2 and b"cannot resume" in code.stderr


def test_undecodable_frame_is_skipped_or_stops(sequence, env, tmp_path):
    bad = tmp_path / "seq"
    shutil.copytree(sequence, bad)
    broken = bad / "views" / "right" / "rgb" / "000003.png"
    broken.write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    args = ("track", bad, *TRACK_OPTS, "--frames", "0:8")
    stop = subprocess.run(
        _cmd(*args, "--out", tmp_path / "a", "--on-bad-frame", "stop", "--quiet"),
        env=env,
        capture_output=True,
    )
    assert stop.returncode == 2
    err = stop.stderr.decode()
    assert "000003.png" in err and "Traceback" not in err and err.count("\n") == 1
    # the frames tracked before the bad one are written (frame 2 was tracked before frame 3 was read), with the
    # BVH and the diagnostics of a stopped run
    stopped = tmp_path / "a"
    assert list(export.load_poses(stopped / "poses.npz")["frame_index"]) == [0, 1, 2]
    assert bvh.load_bvh(stopped / "track.bvh", scale=0.01).num_frames == 3
    diag = json.loads((stopped / "diagnostics.json").read_text())
    assert diag["summary"]["frames_tracked"] == 3 and "000003.png" in diag["summary"]["error"]
    assert json.loads((stopped / "run.json").read_text())["status"] == "stopped"
    skip = subprocess.run(_cmd(*args, "--out", tmp_path / "b", "--quiet"), env=env, capture_output=True)
    assert skip.returncode == 0, skip.stderr.decode()
    assert "warning: skipping frame 3" in skip.stderr.decode()
    p = export.load_poses(tmp_path / "b")
    assert list(p["frame_index"]) == [0, 1, 2, 4, 5, 6, 7]
    diag = json.loads((tmp_path / "b" / "diagnostics.json").read_text())
    assert [r["frame"] for r in diag["frames"] if r.get("skipped")] == [3]


# ---------------------------------------------------------------------------------------------------------------
# Bad input: one line on stderr, exit status 2, no traceback


def _main(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.err


def _videos_track(capsys, vids, calib, out, *options):
    """``jaxmocap track --videos … --calibration … --out …`` without the 2D detector (these videos hold no
    person)."""
    return _main(
        capsys,
        "track",
        "--videos",
        *vids,
        "--calibration",
        calib,
        "--out",
        out,
        "--detector",
        "none",
        *options,
    )


def _one_error(code, err, *needles):
    assert code == 2, err
    assert err.startswith("jaxmocap: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err


def _rig(size=(64, 48), views=2):
    K = np.array([[0.8 * size[0], 0, size[0] / 2], [0, 0.8 * size[0], size[1] / 2], [0, 0, 1.0]])
    Rs, ts = [], []
    for v in range(views):
        R, t = synth.look_at([3.0, 0.3 * v - 0.15, 1.3], [0.0, 0.0, 1.0])
        Rs.append(R)
        ts.append(t)
    names = tuple(f"cam{v}" for v in range(views))
    return camera.from_opencv(
        np.stack([K] * views), np.zeros((views, 5)), np.stack(Rs), np.stack(ts), names, [size] * views
    )


def _video(path, frames, size=(64, 48), moving=True):
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, size)
    assert w.isOpened()
    rng = np.random.default_rng(0)
    background = rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8)
    for t in range(frames):
        img = background.copy()
        if moving:  # a bright block walking across the image
            x = 5 + 3 * t
            img[10:40, x : x + 8] = 250
        w.write(img)
    w.release()
    return path


@pytest.fixture
def videos(tmp_path):
    calib = tmp_path / "calib.toml"
    calibration.save_calibration(calib, _rig())
    return tmp_path, calib, [_video(tmp_path / "a.avi", 6), _video(tmp_path / "b.avi", 6)]


def test_parser_choices_match_the_tracker():
    from jaxmocap.tracking.options import FILTERS, FOREGROUNDS, MODELS

    assert cli._MODELS == MODELS and cli._FILTERS == FILTERS
    assert cli._FOREGROUNDS == FOREGROUNDS


def test_missing_input(capsys, tmp_path):
    code, err = _main(capsys, "track", tmp_path / "nothing", "--out", tmp_path / "o")
    _one_error(code, err, "nothing", "not a sequence folder")
    code, err = _main(
        capsys,
        "track",
        "--videos",
        tmp_path / "x.mp4",
        "--calibration",
        tmp_path / "c.toml",
        "--out",
        tmp_path / "o",
    )
    _one_error(code, err, "x.mp4", "no such video")
    code, err = _main(capsys, "track", "--out", tmp_path / "o")
    _one_error(code, err, "either a sequence folder")


def test_unreadable_files(capsys, videos):
    tmp, calib, vids = videos
    bad_calib = tmp / "bad.toml"
    bad_calib.write_text("[cam0\nmatrix = ")
    code, err = _main(capsys, "track", "--videos", *vids, "--calibration", bad_calib, "--out", tmp / "o")
    _one_error(code, err, "bad.toml")
    bad_video = tmp / "bad.avi"
    bad_video.write_bytes(b"RIFF0000AVI garbage")
    code, err = _main(
        capsys, "track", "--videos", vids[0], bad_video, "--calibration", calib, "--out", tmp / "o"
    )
    _one_error(code, err, "bad.avi", "cannot open the video")


def test_videos_of_different_lengths(capsys, videos):
    tmp, calib, vids = videos
    longer = _video(tmp / "c.avi", 7)
    code, err = _main(
        capsys, "track", "--videos", vids[0], longer, "--calibration", calib, "--out", tmp / "o"
    )
    _one_error(code, err, "c.avi", "has 7 frames but", "synchronised")


def test_calibration_disagrees_with_videos(capsys, videos):
    tmp, calib, vids = videos
    code, err = _main(capsys, "track", "--videos", vids[0], "--calibration", calib, "--out", tmp / "o")
    _one_error(code, err, "calib.toml", "2 cameras but 1 videos")
    other = tmp / "other.toml"
    calibration.save_calibration(other, _rig(size=(80, 60)))
    code, err = _main(capsys, "track", "--videos", *vids, "--calibration", other, "--out", tmp / "o")
    _one_error(code, err, "other.toml", "80x60", "64x48")


def test_non_finite_depth(capsys, videos):
    tmp, calib, vids = videos
    dirs = []
    for v in range(2):
        d = tmp / f"depth{v}"
        d.mkdir()
        for t in range(6):
            z = np.full((48, 64), 3.0, np.float32)
            if v == 1 and t == 0:
                z[5, 7] = np.nan
            np.save(d / f"{t:04d}.npy", z)
        dirs.append(d)
    code, err = _videos_track(capsys, vids, calib, tmp / "o", "--depth", *dirs)
    _one_error(code, err, "0000.npy", "NaN/inf")


def test_empty_scene(capsys, tmp_path):
    calib = tmp_path / "calib.toml"
    calibration.save_calibration(calib, _rig())
    vids = [_video(tmp_path / f"{k}.avi", 6, moving=False) for k in "ab"]
    code, err = _videos_track(capsys, vids, calib, tmp_path / "o")
    _one_error(code, err, "no person")


def test_bad_options(capsys, videos, sequence, tmp_path):
    tmp, calib, vids = videos
    code, err = _videos_track(capsys, vids, calib, tmp / "o", "--init", "groundtruth")
    _one_error(code, err, "groundtruth")
    code, err = _main(capsys, "track", sequence, "--cues", "foreground,smell", "--out", tmp / "o")
    _one_error(code, err, "unknown cue 'smell'")
    code, err = _main(capsys, "track", sequence, "--frames", "50:10", "--out", tmp / "o")
    _one_error(code, err, "empty")
    code, err = _main(capsys, "track", sequence, "--init", tmp / "pose.npy", "--out", tmp / "o")
    _one_error(code, err, "pose.npy", "no such initial pose file")
    code, err = _main(capsys, "track", sequence, "--particles", "10,20", "--out", tmp / "o")
    _one_error(code, err, "one particle count per partition", "'apf'")
    code, err = _main(
        capsys, "track", sequence, "--model", "upper9", "--filter", "partitioned", "--particles", "10,20",
        "--out", tmp / "o",
    )  # fmt: skip
    _one_error(code, err, "partitions (", "got 2")
    # the cut-off against the frame rate (60 fps: below 30 Hz); a bad --smooth is argparse's error (status 2)
    code, err = _main(capsys, "track", sequence, "--smooth", "butterworth:45", "--out", tmp / "o")
    _one_error(code, err, "below half the frame rate (30 Hz)")
    for bad in (["--smooth", "gauss"], ["--bvh-units", "mm"]):
        with pytest.raises(SystemExit) as e:
            cli.main(["track", str(sequence), *bad, "--out", str(tmp / "o")])
        assert e.value.code == 2
        assert bad[1] in capsys.readouterr().err
    (tmp / "busy").mkdir()
    export.atomic_write_npz(tmp / "busy" / "poses.npz", {"x": np.zeros(1)})
    code, err = _main(capsys, "track", sequence, "--out", tmp / "busy")
    _one_error(code, err, "already holds a tracking run", "--resume")


def test_eval_bad_input(capsys, sequence, tmp_path):
    code, err = _main(
        capsys, "eval", "--pred", tmp_path / "none", "--gt", sequence, "--out", tmp_path / "e.json"
    )
    _one_error(code, err, "none")
    code, err = _main(
        capsys, "eval", "--pred", tmp_path, "--gt", tmp_path / "noseq", "--out", tmp_path / "e.json"
    )
    _one_error(code, err, "noseq", "no ground truth")


def test_eval_command(capsys, sequence, tmp_path):
    """``jaxmocap eval`` over two runs: the JSON fields, the plots and the printed table."""
    from jaxmocap.eval import metrics

    _, gt = metrics.load_groundtruth(sequence)
    runs = []
    for r, shift in enumerate((0.01, 0.03)):
        w = export.PoseWriter(tmp_path / f"run{r}", ("x",), "test", fps=60.0)
        for t in range(gt.shape[0]):
            w.append(t, [0.0], gt[t] + np.array([shift, 0.0, 0.0]))
        w.close()
        runs.append(tmp_path / f"run{r}")
    code = cli.main(
        [
            "eval",
            "--pred",
            str(runs[0]),
            "--runs",
            str(runs[1]),
            "--gt",
            str(sequence),
            "--out",
            str(tmp_path / "e.json"),
        ]
    )
    out = capsys.readouterr().out
    assert code == 0
    rep = json.loads((tmp_path / "e.json").read_text())
    assert rep["num_runs"] == 2 and rep["overall_mean_mm"] == pytest.approx(20.0)
    assert rep["overall_std_mm"] == pytest.approx(10.0) and rep["per_joint_mm"]["head"] == pytest.approx(20.0)
    assert len(rep["per_frame_mm"]) == gt.shape[0]
    assert (tmp_path / "e_error_over_time.png").stat().st_size > 0 and (tmp_path / "e_per_joint.png").exists()
    assert "overall" in out and "20.0" in out


@pytest.mark.slow
def test_demo_command(capsys, tmp_path):
    """The demo end to end, at a tiny size: table, overlay frame, plots, overlay videos."""
    code = cli.main(
        [
            "demo",
            "--out",
            str(tmp_path),
            "--frames",
            "0:32",
            "--size",
            "128x96",
            "--particles",
            "30",
            "--layers",
            "2",
            "--quiet",
        ]
    )
    out = capsys.readouterr().out
    assert code == 0
    assert "mocap.cs.cmu.edu" in out and "overall" in out
    assert (tmp_path / "demo_table.txt").read_text().strip() in out
    png = tmp_path / "demo_overlay.png"
    assert cv2.imread(str(png)) is not None and png.stat().st_size <= 300_000
    for name in (
        "eval.json",
        "eval_error_over_time.png",
        "eval_per_joint.png",
        "track/overlay_left.mp4",
        "track/overlay_montage.png",
        "track/track.bvh",
        "track/poses.trc",
        "track/poses.c3d",
        "track/plots/skeleton.png",
    ):
        assert (tmp_path / name).stat().st_size > 0
    with av.open(str(tmp_path / "track" / "overlay_right.mp4")) as c:  # H.264, as browsers play it
        assert c.streams.video[0].codec_context.name == "h264"
        assert sum(1 for _ in c.decode(video=0)) == 8


def test_particle_count_per_partition(capsys, sequence, tmp_path):
    """``--particles`` with one count per partition (Li & Kulić's unequal counts) reaches the partitioned filter:
    the carried set has the last partition's count and the summary lists every count. With ``--no-plots`` the run
    draws no pictures (the other exports are written)."""
    from jaxmocap.filters.factory import partition_groups
    from jaxmocap.geometry import body

    groups = partition_groups(body.upper9())
    counts = [12 + 4 * k for k in range(len(groups))]
    text = ",".join(map(str, counts))
    out = tmp_path / "o"
    code = cli.main(
        ["track", str(sequence), "--model", "upper9", "--filter", "partitioned", "--particles", text,
         "--cues", "coverage", "--frames", "0:2", "--out", str(out), "--no-plots"]
    )  # fmt: skip
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "/".join(map(str, counts)) + " particles" in captured.out
    summary = json.loads((out / "diagnostics.json").read_text())["summary"]
    assert summary["particles"] == counts
    assert "plots" not in summary and not (out / "plots").exists() and (out / "track.bvh").is_file()
    with np.load(out / "resume.npz") as ck:
        assert ck["particles"].shape[0] == counts[-1]
