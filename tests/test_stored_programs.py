"""Programs kept on disk by jax.export (jaxmocap.stored_programs): a second StoredJit with the same tag calls the
program read back without tracing the function, with the same results bit for bit as jax.jit; anything in the key
(tag, argument shapes, package source) that changes traces afresh; a torn file is written again."""

from __future__ import annotations

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
    """A function of a key and a pytree, returning a pytree with a None leaf, that counts its traces."""

    def __init__(self):
        self.traces = 0

    def __call__(self, key, pair, scale):
        self.traces += 1
        noise = jax.random.normal(key, pair.a.shape)
        return {"sum": Pair(jnp.cumsum(pair.a * scale) + noise, jnp.sin(pair.b)), "none": None}


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


def test_without_a_tag_or_a_folder_it_is_plain_jit(tmp_path, monkeypatch):
    fn = Counted()
    s = StoredJit(fn, None, folder=tmp_path)
    _equal(s(*_args()), jax.jit(Counted())(*_args()))
    assert s.lower(*_args()).compile() is not None
    assert (s.exported, s.loaded) == (0, 0) and not any(tmp_path.iterdir())
    # no folder given and no persistent compilation cache in use: nothing stored anywhere
    monkeypatch.setattr(stored_programs, "directory", lambda: None)
    s = StoredJit(Counted(), "tag")
    s(*_args())
    assert (s.exported, s.loaded) == (0, 0)


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
