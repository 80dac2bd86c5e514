"""Quick-mode smoke runs of the benchmarks that track whole sequences (end to end, accuracy tables, hybrid vs APF):
tiny sizes, no timing assertion. Apart from ``test_benchmarks.py`` so that the two run on different workers.

Each runs as ``benchmarks/run.py --quick --only NAME`` in a child process at XLA's lowest backend optimisation level
(a smoke run: the numbers are tested elsewhere; its programs compile ≈ 30 % faster, and compilation is most of
these runs), and its block of the results file it writes is checked."""

import os
import subprocess
import sys

import pytest
from test_benchmarks import BENCH, TRACKING, check_markdown, runner


@pytest.mark.slow
@pytest.mark.parametrize("name", TRACKING)
def test_quick_tracking_benchmark_runs(name, tmp_path):
    results = tmp_path / "RESULTS.md"
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    env.setdefault("JAX_PLATFORMS", "cpu")
    env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0").strip()
    proc = subprocess.run(
        [sys.executable, str(BENCH / "run.py"), "--quick", "--only", name, "--results", str(results)],
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    begin, end = runner._markers(name)
    text = results.read_text()
    assert text.count(begin) == 1 and text.count(end) == 1
    check_markdown(name, text.split(begin)[1].split(end)[0])
