"""Shared test set-up: tests never read ../shared at run time; their data lives in tests/data with its licences."""

import os
import pathlib

import pytest

DATA = pathlib.Path(__file__).parent / "data"


@pytest.fixture
def data_dir() -> pathlib.Path:
    return DATA


def pytest_configure(config):
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    # the command line's persistent compilation cache stays off in the suite (nothing written to the home
    # directory; tests/test_compilation_cache.py turns it on in its own processes)
    os.environ["JAXMOCAP_CACHE_DIR"] = "off"
