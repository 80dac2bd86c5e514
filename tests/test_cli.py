"""The ``jaxmocap`` command: calibration conversion round-trips; bad input is one message and exit status 2."""

import os
import subprocess
import sys

import cv2
import numpy as np

import jaxmocap.parsec  # noqa: F401  (registers the PARSEC .cal camera reader)
from jaxmocap import cli
from jaxmocap.geometry import camera
from jaxmocap.io import calibration


def test_calib_convert_round_trip(tmp_path, data_dir):
    out = tmp_path / "parsec.toml"
    assert cli.main(["calib", "convert", str(data_dir / "calib" / "parsec" / "CALIB"), str(out)]) == 0
    a = calibration.load_calibration(data_dir / "calib" / "parsec" / "CALIB")
    b = calibration.load_calibration(out)
    assert b.names == a.names and b.image_size == a.image_size
    X = np.random.default_rng(0).uniform([-1, -1, 0], [1, 1, 2], size=(50, 3))
    for v in range(a.num_views):
        # the written file is read by OpenCV users with cv2.projectPoints (no skew term in these cameras)
        rvec = cv2.Rodrigues(np.asarray(b.R[v]))[0]
        ref, _ = cv2.projectPoints(X, rvec, np.asarray(b.t[v]), np.asarray(b.K[v]), np.asarray(b.dist[v]))
        uv_a = np.asarray(camera.project(a.to_jax(np.float32), np.asarray(X, np.float32)))[v]
        np.testing.assert_allclose(uv_a, ref[:, 0], atol=1e-2)


def test_bad_input_is_one_line_and_status_2(tmp_path):
    bad = tmp_path / "broken.toml"
    bad.write_text("[cam_1]\nmatrix = [[1, 0], \n")
    r = subprocess.run(
        [sys.executable, "-m", "jaxmocap.cli", "calib", "show", str(bad)], capture_output=True, text=True
    )
    assert r.returncode == 2
    assert "broken.toml" in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_the_command_exits_with_mains_status_its_output_and_its_exit_handlers(tmp_path, data_dir):
    """``jaxmocap.cli.run`` (the console script and ``python -m jaxmocap.cli``) leaves through ``os._exit``: what
    ``main`` printed still reaches a pipe (block-buffered: lost without the flush), the ``atexit`` handlers still
    run, and the status is ``main``'s, 0 or 2."""
    script = (
        "import atexit, sys\n"
        "from jaxmocap import cli\n"
        "atexit.register(lambda: print('exit handler ran', file=sys.stderr))\n"
        "sys.argv = ['jaxmocap', *sys.argv[1:]]\n"
        "cli.run()\n"
        "print('not reached')\n"
    )
    calib = str(data_dir / "calib" / "parsec" / "CALIB")
    # a pipe's buffering as users have it
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    kw = dict(capture_output=True, text=True, env=env)
    ok = subprocess.run([sys.executable, "-c", script, "calib", "show", calib], **kw)
    assert ok.returncode == 0, ok.stderr
    names = calibration.load_calibration(calib).names
    assert all(n in ok.stdout for n in names)
    assert "exit handler ran" in ok.stderr and "not reached" not in ok.stdout
    bad = tmp_path / "broken.toml"
    bad.write_text("[cam_1]\nmatrix = [[1, 0], \n")
    r = subprocess.run([sys.executable, "-c", script, "calib", "show", str(bad)], **kw)
    assert r.returncode == 2 and "broken.toml" in r.stderr and "exit handler ran" in r.stderr
