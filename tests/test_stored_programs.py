"""Programs kept on disk by jax.export (jaxmocap.stored_programs): a second StoredJit with the same tag calls the
program read back without tracing the function, with the same results bit for bit as jax.jit; anything in the key
(tag, argument shapes, package source) that changes traces afresh; a torn file is written again."""

from __future__ import annotations

import contextlib
import dataclasses
import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmocap import stored_programs
from jaxmocap.stored_programs import StoredJit
from jaxmocap.tracking import resources


class Pair(NamedTuple):
    a: jax.Array
    b: jax.Array


class Counted:
    """A function of a key and a pytree, returning a pytree with a None leaf, that counts its traces; ``shift``: a
    constant of its program (:func:`_fresh`: a program no compilation cache has seen)."""

    def __init__(self, shift: float = 0.0):
        self.traces = 0
        self.shift = shift

    def __call__(self, key, pair, scale):
        self.traces += 1
        noise = jax.random.normal(key, pair.a.shape)
        return {"sum": Pair(jnp.cumsum(pair.a * scale) + noise + self.shift, jnp.sin(pair.b)), "none": None}


@contextlib.contextmanager
def _config(name: str, value):
    """JAX's configuration ``name`` set to ``value`` inside the block, restored after it."""
    before = getattr(jax.config, name)
    jax.config.update(name, value)
    try:
        yield
    finally:
        jax.config.update(name, before)


@pytest.fixture
def uncached():
    """No program compiled during the test enters JAX's persistent compilation cache (the suite's, whatever its
    threshold): every compilation of a new program is XLA's, so its executable is kept."""
    with _config("jax_persistent_cache_min_compile_time_secs", 1e9):
        yield


@pytest.fixture
def all_cached():
    """Every program compiled during the test enters JAX's persistent compilation cache (the suite's,
    tests/conftest.py)."""
    assert jax.config.jax_compilation_cache_dir
    with _config("jax_persistent_cache_min_compile_time_secs", 0.0):
        yield


@pytest.fixture
def source_locations():
    """Programs lowered with their source lines in their locations (the suite lowers without them,
    tests/conftest.py)."""
    with _config("jax_traceback_in_locations_limit", 10):
        yield


def _fresh() -> float:
    """A constant that makes a program new to JAX's persistent compilation cache, whatever earlier tests or runs
    put there (an executable is kept only when XLA compiles it)."""
    import uuid

    return 1.0 + uuid.uuid4().int % 100_000 / 1e6


def _args(n=5):
    key = jax.random.fold_in(jax.random.key(3), 7)
    return key, Pair(jnp.arange(n, dtype=jnp.float32), jnp.linspace(0.0, 1.0, 3)), jnp.float32(1.5)


def _equal(x, y):
    xs, tx = jax.tree.flatten(x)
    ys, ty = jax.tree.flatten(y)
    assert tx == ty
    for a, b in zip(xs, ys, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_second_instance_reads_the_program_back_without_tracing(tmp_path):
    args = _args()
    want = jax.jit(Counted())(*args)
    f1 = Counted()
    first = StoredJit(f1, "tag", folder=tmp_path)
    _equal(first(*args), want)
    assert (first.exported, first.loaded, f1.traces) == (1, 0, 1)
    assert len(list(tmp_path.glob("*.jaxexport"))) == 1
    _equal(first(*args), want)  # the same process: no second trace or file
    assert (first.exported, f1.traces) == (1, 1)

    f2 = Counted()
    second = StoredJit(f2, "tag", folder=tmp_path)
    _equal(second(*args), want)
    assert (second.exported, second.loaded, f2.traces) == (0, 1, 0)
    # lower / compile give the program that is called, with XLA's memory estimate (the run's memory check)
    stored = resources.program_bytes(second.lower(*args).compile())
    plain = resources.program_bytes(jax.jit(Counted()).lower(*args).compile())
    assert f2.traces == 0 and stored is not None and plain is not None and stored >= plain > 0


def test_what_is_in_the_key_traces_afresh(tmp_path, monkeypatch):
    StoredJit(Counted(), "tag", folder=tmp_path)(*_args())
    for fn, tag, args in ((Counted(), "other tag", _args()), (Counted(), "tag", _args(n=6))):
        s = StoredJit(fn, tag, folder=tmp_path)
        out = s(*args)
        assert (s.exported, s.loaded, fn.traces) == (1, 0, 1)
        _equal(out, jax.jit(Counted())(*args))
    # a change of the package's source
    monkeypatch.setattr(stored_programs, "source_digest", lambda: "edited")
    fn = Counted()
    s = StoredJit(fn, "tag", folder=tmp_path)
    s(*_args())
    assert (s.exported, fn.traces) == (1, 1)
    assert len(list(tmp_path.glob("*.jaxexport"))) == 4


@pytest.mark.parametrize("damage", ["torn", "foreign"])
def test_an_unreadable_file_is_traced_and_written_again(tmp_path, damage):
    StoredJit(Counted(), "tag", folder=tmp_path)(*_args())
    (path,) = tmp_path.glob("*.jaxexport")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2] if damage == "torn" else b"not a program" + data[20:])
    fn = Counted()
    s = StoredJit(fn, "tag", folder=tmp_path)
    _equal(s(*_args()), jax.jit(Counted())(*_args()))
    assert (s.exported, s.loaded, fn.traces) == (1, 0, 1)
    again = Counted()  # written again whole: read back by the next one
    s = StoredJit(again, "tag", folder=tmp_path)
    _equal(s(*_args()), jax.jit(Counted())(*_args()))
    assert (s.exported, s.loaded, again.traces) == (0, 1, 0)


def test_without_a_tag_or_a_folder_it_is_plain_jit(tmp_path):
    fn = Counted()
    s = StoredJit(fn, None, folder=tmp_path)
    _equal(s(*_args()), jax.jit(Counted())(*_args()))
    assert s.lower(*_args()).compile() is not None
    assert (s.exported, s.loaded) == (0, 0) and not any(tmp_path.iterdir())
    # no folder given and outside stored_programs.use (a JAX compilation cache alone does not store): plain jit
    assert stored_programs.directory() is None
    s = StoredJit(Counted(), "tag")
    s(*_args())
    assert (s.exported, s.loaded) == (0, 0)
    with stored_programs.use(tmp_path) as folder:  # inside: the folder of the block
        assert folder == tmp_path / stored_programs.FOLDER == stored_programs.directory()
        s(*_args())
        with stored_programs.use(None):
            assert stored_programs.directory() is None
    assert (s.exported, s.loaded) == (1, 0) and len(list(folder.glob("*.jaxexport"))) == 1
    assert stored_programs.directory() is None


@jax.tree_util.register_dataclass
@dataclasses.dataclass
class Scaled:
    """A pytree with data ``a`` and static data ``power`` and ``how`` (part of its tree structure)."""

    a: jax.Array
    power: int = dataclasses.field(metadata={"static": True})
    how: object = dataclasses.field(default="sin", metadata={"static": True})


def _powered(x: Scaled):
    y = x.a**x.power
    return jnp.sin(y) if x.how == "sin" else x.how(y)


def test_the_structure_of_the_arguments_is_in_the_key(tmp_path):
    """Static data of the arguments' tree (a filter's settings, the likelihood's geometry) changes the program
    under one tag: each value gets its own stored program, never another's; static data that cannot be pickled
    (a lambda) is not stored at all, unless the caller's tag names it (``key_structure=False``)."""
    a = jnp.linspace(0.5, 1.5, 4, dtype=jnp.float32)
    for power in (2, 3, 2):
        s = StoredJit(_powered, "tag", folder=tmp_path)
        _equal(s(Scaled(a, power)), jax.jit(_powered)(Scaled(a, power)))
    assert len(list(tmp_path.glob("*.jaxexport"))) == 2
    s = StoredJit(_powered, "tag", folder=tmp_path)
    s(Scaled(a, 3))
    assert (s.exported, s.loaded) == (0, 1)
    s = StoredJit(_powered, "tag", folder=tmp_path)
    _equal(s(Scaled(a, 2, lambda y: -y)), -(a**2))
    assert (s.exported, s.loaded) == (0, 0) and len(list(tmp_path.glob("*.jaxexport"))) == 2
    # a caller whose tag names the structure (key_structure=False) stores it all the same
    s = StoredJit(_powered, "tag naming the lambda", folder=tmp_path, key_structure=False)
    _equal(s(Scaled(a, 2, lambda y: -y)), -(a**2))
    assert (s.exported, s.loaded) == (1, 0) and len(list(tmp_path.glob("*.jaxexport"))) == 3


def test_under_a_transformation_it_is_the_plain_jit(tmp_path):
    """Called with tracers (inside the caller's vmap, jit or grad) it is jax.jit, inlined: nothing stored."""
    s = StoredJit(lambda x: jnp.sin(x) * x, "tag", folder=tmp_path)
    x = jnp.linspace(0.0, 1.0, 6, dtype=jnp.float32).reshape(2, 3)
    np.testing.assert_array_equal(
        np.asarray(jax.vmap(s)(x)), np.asarray(jax.vmap(jax.jit(lambda x: jnp.sin(x) * x))(x))
    )
    g = jax.grad(lambda v: jnp.sum(s(v)))(x[0])
    np.testing.assert_allclose(np.asarray(g), np.asarray(jnp.sin(x[0]) + x[0] * jnp.cos(x[0])), rtol=1e-6)
    assert (s.exported, s.loaded) == (0, 0) and not any(tmp_path.iterdir())


_TRACES = []


def _scaled_sum(x, y=None, n: int = 2):
    _TRACES.append(n)
    return jnp.cumsum(x * n) + (0.0 if y is None else y)


def test_stored_jit_stores_a_module_function_inside_use_only(tmp_path):
    """stored_jit: a module-level function with static arguments. Outside use it is jax.jit (with its static
    arguments); inside, one stored program per static value, read back by a new wrapper (as by a new process)
    without tracing, with the results of jax.jit bit for bit."""
    x = jnp.arange(5, dtype=jnp.float32)
    plain = jax.jit(_scaled_sum, static_argnames=("n",))
    f = stored_programs.stored_jit(_scaled_sum, static_argnames=("n",))
    assert f.__name__ == "_scaled_sum" and f.__doc__ == _scaled_sum.__doc__
    _equal(f(x, n=3), plain(x, n=3))
    assert not any(tmp_path.iterdir())
    with stored_programs.use(tmp_path) as folder:
        _equal(f(x, None, 3), plain(x, n=3))  # the static argument given by position
        _equal(f(x, y=x), plain(x, y=x))
        assert len(list(folder.glob("*.jaxexport"))) == 2
        del _TRACES[:]
        again = stored_programs.stored_jit(_scaled_sum, static_argnames=("n",))
        _equal(again(x, n=3), plain(x, n=3))
        _equal(again(x, y=x), plain(x, y=x))
        assert (
            _TRACES == [] and again._cache_size() - again._jit._cache_size() == 2
        )  # its two stored programs
        _equal(jax.jit(lambda v: again(v, n=4))(x), plain(x, n=4))  # traced inside a caller: inlined
        assert _TRACES == [4] and len(list(folder.glob("*.jaxexport"))) == 2


def test_cache_size_counts_the_compiled_variants(tmp_path):
    s = StoredJit(Counted(), "tag", folder=tmp_path)
    assert s._cache_size() == 0
    s(*_args())
    s(*_args())
    assert s._cache_size() == 1
    s(*_args(n=6))  # another shape: another program
    assert s._cache_size() == 2
    plain = StoredJit(Counted(), None)
    plain(*_args())
    assert plain._cache_size() == 1


@pytest.mark.parametrize("tag", [None, "tag"])
def test_compiler_options_reach_xla_stored_or_not(tmp_path, tag):
    """XLA parses the options when it compiles: a value it rejects fails the call and ``lower().compile()`` (so the
    options are not dropped on either path), and a valid one leaves the results as ``jax.jit``'s."""
    args = _args()
    bad = StoredJit(
        Counted(), tag, folder=tmp_path / "bad", compiler_options={"xla_cpu_use_fusion_emitters": "no"}
    )
    with pytest.raises(Exception, match="xla_cpu_use_fusion_emitters"):
        bad(*args)
    with pytest.raises(Exception, match="xla_cpu_use_fusion_emitters"):
        bad.lower(*args).compile()
    loops = StoredJit(
        Counted(), tag, folder=tmp_path / "ok", compiler_options={"xla_cpu_use_fusion_emitters": False}
    )
    got, want = loops(*args), jax.jit(Counted())(*args)
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6)


class _Lowerings:
    """Counts the programs JAX lowers to MLIR and those XLA compiles while it is active (JAX's monitoring
    events)."""

    def __enter__(self):
        self.lowered = self.compiled = 0

        def listen(event, duration, **kwargs):
            self.lowered += event == "/jax/core/compile/jaxpr_to_mlir_module_duration"
            self.compiled += event == "/jax/core/compile/backend_compile_duration"

        self._listen = listen
        jax.monitoring.register_event_duration_secs_listener(listen)
        return self

    def __exit__(self, *exc):
        jax.monitoring.unregister_event_duration_listener(self._listen)


def test_a_new_instance_runs_the_kept_executable_without_lowering(tmp_path, uncached):
    """Beside each stored program its compiled executable is kept (``.xlaexec``); a new instance (as a new process)
    runs it without lowering or compiling anything, with the results of jax.jit bit for bit, and ``lower`` /
    ``compile`` give that executable (with XLA's memory estimate)."""
    args, shift = _args(), _fresh()
    want = jax.jit(Counted(shift))(*args)
    first = StoredJit(Counted(shift), "tag", folder=tmp_path)
    _equal(first(*args), want)
    assert len(list(tmp_path.glob("*.xlaexec"))) == 1
    second = StoredJit(Counted(shift), "tag", folder=tmp_path)
    with _Lowerings() as seen:
        _equal(second(*args), want)
        compiled = second.lower(*args).compile()
    assert (seen.lowered, seen.compiled, second.loaded) == (0, 0, 1)
    assert resources.program_bytes(compiled) is not None
    _equal(compiled(*jax.tree.leaves(args)), jax.tree.leaves(want))
    # the same arguments lowered ahead from their shapes (the tracker's compilation ahead) find it as well
    third = StoredJit(Counted(shift), "tag", folder=tmp_path)
    shapes = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), args)
    with _Lowerings() as seen:
        third.lower(*shapes).compile()
        _equal(third(*args), want)
    assert (seen.lowered, seen.compiled) == (0, 0)


def test_an_executable_read_from_the_compilation_cache_is_not_kept(tmp_path, all_cached):
    """An executable that JAX's persistent cache supplied is not written (jaxlib 0.10 serialises it without its
    kernels): after a cache hit the run uses it and keeps none; a real compilation then keeps one again."""
    args, shift = _args(n=7), _fresh()
    want = jax.jit(Counted(shift))(*args)
    StoredJit(Counted(shift), "cache hit", folder=tmp_path)(*args)  # compiled by XLA: kept, and cached
    (kept,) = tmp_path.glob("*.xlaexec")
    kept.unlink()
    again = StoredJit(Counted(shift), "cache hit", folder=tmp_path)
    hits = stored_programs._cache_hits()
    _equal(again(*args), want)
    assert stored_programs._cache_hits() == hits + 1 and not list(tmp_path.glob("*.xlaexec"))


def test_a_torn_executable_is_compiled_and_written_again(tmp_path, uncached):
    args, shift = _args(n=4), _fresh()
    want = jax.jit(Counted(shift))(*args)
    StoredJit(Counted(shift), "tag", folder=tmp_path)(*args)
    (kept,) = tmp_path.glob("*.xlaexec")
    whole = kept.read_bytes()
    kept.write_bytes(whole[: len(whole) // 2])
    with _Lowerings() as seen:
        _equal(StoredJit(Counted(shift), "tag", folder=tmp_path)(*args), want)
    assert seen.lowered == 1  # compiled again, and written: read back below
    with _Lowerings() as seen:
        _equal(StoredJit(Counted(shift), "tag", folder=tmp_path)(*args), want)
    assert seen.lowered == 0


def test_the_machine_digest_names_the_flags_options_cpu_and_threads(monkeypatch):
    base = stored_programs.machine_digest({"xla_cpu_use_fusion_emitters": False})
    assert base == stored_programs.machine_digest({"xla_cpu_use_fusion_emitters": False})
    assert base != stored_programs.machine_digest({"xla_cpu_use_fusion_emitters": True})
    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_optimization_level=1 --xla_cpu_enable_fast_math=false")
    assert base != stored_programs.machine_digest({"xla_cpu_use_fusion_emitters": False})
    monkeypatch.setattr(stored_programs, "_cpu_identity", lambda: "another CPU")
    other_cpu = stored_programs.machine_digest({"xla_cpu_use_fusion_emitters": False})
    assert base != other_cpu
    from jaxmocap import host

    threads = host.cpu_threads()
    assert threads is None or threads >= 1  # XLA's pool has started (jax.devices() in the digest)
    monkeypatch.setattr(host, "cpu_threads", lambda: (threads or 1) + 1)
    assert stored_programs.machine_digest({"xla_cpu_use_fusion_emitters": False}) != other_cpu


_SOLVE = """
import sys, pathlib, jax, jax.numpy as jnp, numpy as np
from jaxmocap.stored_programs import StoredJit
s = StoredJit(lambda a, b: jnp.linalg.solve(a, b), "solve", folder=pathlib.Path(sys.argv[1]))
a = np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 1.0], [0.0, 1.0, 2.0]], np.float32)
x = s(jnp.asarray(a), jnp.asarray([1.0, 2.0, 3.0], jnp.float32))
print(s.loaded, s.exported, " ".join(repr(float(v)) for v in np.asarray(x)))
"""


def test_an_executable_that_calls_lapack_runs_in_a_new_process(tmp_path):
    """A program with LAPACK calls (a linear solve), read back as an executable in a process that lowered
    nothing: JAX's LAPACK kernels are initialised first (without that the call crashes the process), and the
    solution is NumPy's."""
    import os
    import subprocess
    import sys

    # without the suite's compilation cache: the solve is compiled by XLA in the first process (so kept) whatever
    # the cache holds
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    runs = [
        subprocess.run(
            [sys.executable, "-c", _SOLVE, str(tmp_path)],
            capture_output=True,
            text=True,
            timeout=300,
            env=env,
        )
        for _ in range(2)
    ]
    for r in runs:
        assert r.returncode == 0, r.stderr[-2000:]
    (first,), (second,) = (r.stdout.split("\n")[:1] for r in runs)
    assert first.split()[:2] == ["0", "1"] and second.split()[:2] == ["1", "0"]
    assert len(list(tmp_path.glob("*.xlaexec"))) == 1
    a = np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 1.0], [0.0, 1.0, 2.0]])
    want = np.linalg.solve(a, [1.0, 2.0, 3.0])
    for line in (first, second):
        np.testing.assert_allclose([float(v) for v in line.split()[2:]], want, rtol=1e-5)


def _scaled_sine(c: float):
    def scaled_sine(x):
        return c * jnp.sin(x)

    return scaled_sine


def test_an_edited_package_finds_the_executable_of_an_unchanged_program(
    tmp_path, monkeypatch, uncached, source_locations
):
    """The executable is named by the program without its source locations (:func:`program_digest`): after an edit
    of the package (another source digest: the program is traced and exported again) and for the same operations
    traced from other source lines, the executable kept is run, not compiled again."""
    x, c = jnp.linspace(0.0, 1.0, 5, dtype=jnp.float32), _fresh()
    want = StoredJit(_scaled_sine(c), "tag", folder=tmp_path)(x)
    monkeypatch.setattr(stored_programs, "source_digest", lambda: "edited")
    elsewhere = lambda x: c * jnp.sin(x)  # noqa: E731 (the same program from another line)
    for fn in (_scaled_sine(c), elsewhere):
        s = StoredJit(fn, f"tag {fn.__name__}", folder=tmp_path)
        with _Lowerings() as seen:
            got = s(x)
        assert (s.exported, seen.compiled) == (1, 0)
        _equal(got, want)
    assert len(list(tmp_path.glob("*.jaxexport"))) == 3 and len(list(tmp_path.glob("*.xlaexec"))) == 1

    def exported(fn):  # as StoredJit exports a function (one wrapper, one module name)
        def flat(v):
            return fn(v)

        return jax.export.export(jax.jit(flat))(x)

    a, b = exported(_scaled_sine(c)), exported(elsewhere)
    assert a.mlir_module() != b.mlir_module()  # their source locations differ
    assert stored_programs.program_digest(a) == stored_programs.program_digest(b)


def test_each_thread_count_keeps_its_own_executable(tmp_path, monkeypatch, all_cached):
    """XLA's CPU code differs with the threads of its pool, which JAX's cache key does not hold: a process with
    another thread count (``--cpu-threads``) neither runs the executable kept by the first nor gets the first's
    compilation from JAX's cache, but compiles and keeps its own."""
    from jaxmocap import host

    args, shift = _args(n=6), _fresh()
    want = jax.jit(Counted(shift))(*args)
    StoredJit(Counted(shift), "threads", folder=tmp_path)(*args)
    assert len(list(tmp_path.glob("*.xlaexec"))) == 1
    n = host.cpu_threads() or 1
    monkeypatch.setattr(host, "cpu_threads", lambda: n + 1)
    other = StoredJit(Counted(shift), "threads", folder=tmp_path)
    hits = stored_programs._cache_hits()
    with _Lowerings() as seen:
        _equal(other(*args), want)
    assert seen.compiled == 1 and stored_programs._cache_hits() == hits
    assert len(list(tmp_path.glob("*.xlaexec"))) == 2


def test_a_narrower_pool_runs_a_wider_pools_executable(tmp_path, monkeypatch, all_cached):
    """A process whose XLA CPU pool has fewer threads than the one an executable was compiled for (``--cpu-threads
    auto`` beside a busy process) runs that executable when its own is missing: no lowering, no compilation, the
    same values; its own, once there, is preferred. (The other way round a process compiles its own:
    :func:`test_each_thread_count_keeps_its_own_executable`.)"""
    from jaxmocap import host

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2}, raising=False)
    args, shift = _args(n=7), _fresh()
    want = jax.jit(Counted(shift))(*args)
    monkeypatch.setattr(host, "cpu_threads", lambda: 3)
    StoredJit(Counted(shift), "narrower", folder=tmp_path)(*args)
    assert len(list(tmp_path.glob("*.xlaexec"))) == 1
    monkeypatch.setattr(host, "cpu_threads", lambda: 1)
    narrow = StoredJit(Counted(shift), "narrower", folder=tmp_path)
    with _Lowerings() as seen:
        _equal(narrow(*args), want)
    assert (seen.lowered, seen.compiled) == (0, 0)
    (wide,) = tmp_path.glob("*.xlaexec")
    # without it the narrow pool compiles and keeps its own, which is then read first (the wide one torn)
    kept = wide.read_bytes()
    wide.unlink()
    _equal(StoredJit(Counted(shift), "narrower", folder=tmp_path)(*args), want)
    (own,) = tmp_path.glob("*.xlaexec")
    wide.write_bytes(kept[: len(kept) // 2])
    with _Lowerings() as seen:
        _equal(StoredJit(Counted(shift), "narrower", folder=tmp_path)(*args), want)
    assert (seen.lowered, seen.compiled) == (0, 0) and own.is_file()
