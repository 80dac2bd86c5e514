"""Shared test set-up: tests never read ../shared at run time; their data lives in tests/data with its licences.

Compiled programs are shared across the run: the session (the controller, before pytest-xdist starts its
workers, which inherit the environment) points JAX's persistent compilation cache at a fresh temporary folder, so a
program that several tests or both workers build (the same likelihood, filter step or solver with the same shapes)
is compiled by XLA once and loaded from the folder afterwards. The folder is new for every run and removed at its
end: nothing is carried between runs, and a test that counts traces or compilations (``_cache_size``,
``jax.log_compiles``) sees the same counts as without it, since the in-memory jit cache is unchanged.
"""

import os
import pathlib
import shutil
import tempfile

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
    if not hasattr(config, "workerinput") and "JAX_COMPILATION_CACHE_DIR" not in os.environ:
        folder = tempfile.mkdtemp(prefix="jaxmocap-tests-xla-")
        config.stash[_CACHE] = folder
        os.environ["JAX_COMPILATION_CACHE_DIR"] = folder
        os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0.5"


def pytest_unconfigure(config):
    folder = config.stash.get(_CACHE, None)
    if folder is not None:
        shutil.rmtree(folder, ignore_errors=True)
        os.environ.pop("JAX_COMPILATION_CACHE_DIR", None)


_CACHE = pytest.StashKey[str]()
