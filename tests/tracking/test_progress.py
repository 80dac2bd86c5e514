"""The lines ``jaxmocap track`` prints around the compilation of its step."""

import io

import jax
import jax.numpy as jnp

from jaxmocap.tracking.progress import CompileNotice


def test_compile_notice_names_the_stage_and_its_time():
    f = jax.jit(lambda x: jnp.cumsum(jnp.sin(x)))
    out = io.StringIO()
    with CompileNotice("the test step", stream=out) as notice:
        f(jnp.arange(7.0))
    lines = out.getvalue().splitlines()
    assert lines[0] == "jaxmocap: compiling the test step ..."
    assert lines[1].startswith(f"jaxmocap: compiled in {notice.seconds:.1f} s, ")
    cache = jax.config.jax_compilation_cache_dir
    assert lines[1].endswith(f"cached for next time in {cache}" if cache else "compilation cache off")
    assert f._cache_size() == 1 and notice.seconds > 0
    quiet = io.StringIO()
    with CompileNotice("x", enabled=False, stream=quiet):
        f(jnp.arange(7.0))
    assert quiet.getvalue() == ""


def test_compile_notice_stays_silent_after_an_error():
    out = io.StringIO()
    try:
        with CompileNotice("a failing step", stream=out):
            raise ValueError("bad input")
    except ValueError:
        pass
    assert out.getvalue().splitlines() == ["jaxmocap: compiling a failing step ..."]
