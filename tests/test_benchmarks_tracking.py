"""Quick-mode smoke runs of the benchmarks that track whole sequences (end to end, accuracy tables, hybrid vs APF):
tiny sizes, no timing assertion. Apart from ``test_benchmarks.py`` so that the two run on different workers."""

import pytest
from test_benchmarks import TRACKING, check_quick_run


@pytest.mark.slow
@pytest.mark.parametrize("name", TRACKING)
def test_quick_tracking_benchmark_runs(name):
    check_quick_run(name)
