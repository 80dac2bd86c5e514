"""Fixtures of the command-line tests (``test_cli_track.py``, ``test_cli_reliability.py``): a small synthetic
sequence and the environment of the ``jaxmocap`` subprocesses. A test module may define its own ``sequence``."""

import os

import pytest

from jaxmocap.synth import generate as synth


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    """60 frames at 60 fps of 96x72 px of the bundled CMU walk, stereo."""
    out = tmp_path_factory.mktemp("seq")
    synth.synthesize(
        "demo", out, rig="stereo", frames="0:120", fps=60.0, size="96x72", seed=0, overwrite=True
    )
    return out


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    """Subprocesses share a persistent compilation cache, so that only the first one compiles: the test session's
    (``tests/conftest.py``; the tests that track in their own process use it too), else a folder of their own."""
    e = dict(os.environ)
    cache = os.environ.get("JAX_COMPILATION_CACHE_DIR") or str(tmp_path_factory.mktemp("jax_cache"))
    e.update(
        JAX_PLATFORMS="cpu", JAX_COMPILATION_CACHE_DIR=cache, JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0"
    )
    return e
