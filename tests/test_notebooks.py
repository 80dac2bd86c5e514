"""The notebooks in ``notebooks/`` (jupytext percent format, plain Python) run top to bottom as scripts in their
small-size mode and write their figures to the output folder they are given."""

import os
import pathlib
import subprocess
import sys

import cv2
import pytest

NOTEBOOKS = pathlib.Path(__file__).parent.parent / "notebooks"
FIGURES = {
    "01_annealing_schedules": ("lambda_schedules", "beta_per_layer", "correction_rule", "clouds_per_layer"),
    "02_cue_study": ("sweeps", "modes"),
    "03_gradients": ("gradient_field", "hybrid_vs_apf"),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(FIGURES))
def test_notebook_runs_and_writes_its_figures(name, tmp_path):
    env = dict(
        os.environ,
        JAXMOCAP_NB_SMALL="1",
        JAXMOCAP_NB_OUT=str(tmp_path),
        MPLBACKEND="Agg",
        PYTHONDONTWRITEBYTECODE="1",
    )
    env.setdefault("JAX_PLATFORMS", "cpu")
    # a smoke run (the numbers are tested elsewhere): XLA's lowest backend optimisation level compiles ≈ 30 % faster
    env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0").strip()
    # run as a script under the suite's garbage-collector thresholds (jaxmocap.host.relax_gc; 8-10 % of a process
    # that traces JAX programs goes to collections with CPython's own)
    launch = (
        "import runpy, sys; from jaxmocap import host; host.relax_gc(); "
        "sys.argv = sys.argv[1:]; runpy.run_path(sys.argv[0], run_name='__main__')"
    )
    proc = subprocess.run(
        [sys.executable, "-c", launch, f"{name}.py"],
        cwd=NOTEBOOKS,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert "figures in" in proc.stdout
    for fig in FIGURES[name]:
        path = tmp_path / name / f"{fig}.png"
        assert path.is_file(), f"{name} did not write {fig}.png"
        img = cv2.imread(str(path))
        assert img is not None and img.shape[0] > 100 and img.shape[1] > 100 and img.std() > 1.0
    # nothing written into the repository
    assert not list(NOTEBOOKS.glob("*.png"))
