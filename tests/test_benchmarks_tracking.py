"""Quick-mode smoke runs of the benchmarks that track whole sequences (end to end, accuracy tables, hybrid vs APF):
tiny sizes, no timing assertion, each in a child process (``test_benchmarks.quick_run``). Apart from
``test_benchmarks.py`` so that the two run on different workers."""

import pytest
from test_benchmarks import TRACKING, check_markdown, quick_block, quick_run


@pytest.mark.slow
@pytest.mark.parametrize("name", TRACKING)
def test_quick_tracking_benchmark_runs(name, tmp_path):
    results = tmp_path / "RESULTS.md"
    proc = quick_run([name], results)
    assert proc.returncode == 0, proc.stderr[-4000:]
    check_markdown(name, quick_block(results.read_text(), name))
