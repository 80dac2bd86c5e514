"""The command line's persistent compilation cache: where it lives, how it is turned off, and that a second process
reloads a compiled program instead of compiling it (JAX's own log says which)."""

import os
import pathlib
import subprocess
import sys

from jaxmocap import compilation_cache

SCRIPT = """
import logging, sys
import jax, jax.numpy as jnp
from jaxmocap import compilation_cache
logging.basicConfig(level=logging.DEBUG, stream=sys.stdout, format="%(message)s")
print("cache dir:", compilation_cache.enable())  # the default keeps every program, this small one too
@jax.jit
def sine_sum(x):
    return jnp.cumsum(jnp.sin(x) * 3.0)
print("value:", float(sine_sum(jnp.arange(5.0))[-1]))
"""


def test_cache_directory_from_the_environment(tmp_path):
    assert compilation_cache.cache_dir({"JAXMOCAP_CACHE_DIR": str(tmp_path)}) == tmp_path
    for off in ("off", "OFF", "0", ""):
        assert compilation_cache.cache_dir({"JAXMOCAP_CACHE_DIR": off}) is None
    assert compilation_cache.cache_dir({"XDG_CACHE_HOME": "/x"}) == pathlib.Path("/x/jaxmocap/xla")


def _run(env):
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_second_process_reloads_the_compiled_program(tmp_path):
    cache = tmp_path / "xla"
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env.update(JAXMOCAP_CACHE_DIR=str(cache), JAX_PLATFORMS="cpu")
    first = _run(env)
    assert f"cache dir: {cache}" in first
    assert "Writing jit_sine_sum to persistent compilation cache" in first
    assert any(cache.iterdir())
    second = _run(env)
    assert "Persistent compilation cache hit for 'jit_sine_sum'" in second
    value = [line for line in first.splitlines() if line.startswith("value:")]
    assert value and value == [line for line in second.splitlines() if line.startswith("value:")]
    # turned off: nothing is configured and nothing written
    off = _run(dict(env, JAXMOCAP_CACHE_DIR="off", XDG_CACHE_HOME=str(tmp_path / "home")))
    assert "cache dir: None" in off and not (tmp_path / "home").exists()
