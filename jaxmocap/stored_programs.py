"""Traced programs kept on disk, so that a warm start neither traces nor lowers them again.

JAX's persistent compilation cache (:mod:`jaxmocap.compilation_cache`) keeps the *compiled* programs, but it finds
one only after the function has been traced to a jaxpr and lowered to StableHLO, because its key is a hash of
that module. For the PARSEC run those two steps are most of a warm start: tracing and lowering its weighted start
and its filter step take 4–5 s, reloading both executables 1.5 s (``benchmarks/results/parsec_track.md``).

:class:`StoredJit` is ``jax.jit(fn)`` for a function whose trace is fully determined by a **tag** that the caller
builds from everything the function closes over (the body's dimensions, the calibration, the particle count, …)
together with the shapes and dtypes of the arguments' leaves. The first call of a configuration traces ``fn`` as
usual, exports it with :func:`jax.export.export` (StableHLO, serialised) and writes it to ``DIR/<key>.jaxexport``;
a later process with the same key deserialises it and calls it: no Python tracing, no lowering of the function's
body; the compilation of the deserialised module is then found in the persistent cache as usual. The key is a
SHA-256 of the tag, the leaves' abstract values, the backend, the JAX and jaxlib versions and the source of this
package (every ``.py`` file of ``jaxmocap``), so any change of the code or of the versions traces afresh. A file
that cannot be read back (torn, from another JAX) is ignored and written again. Deleting the directory is always
safe. A stored file is loaded as code (the output tree is a pickle, the program StableHLO), like the executables
of JAX's own cache beside it: keep the cache directory private to its user.

Use it only where the tag covers every value the function closes over: a constant missing from the tag would
give a stale program for a new value of it. The argument leaves themselves are data of the program (only their
shapes and dtypes are in the key).
"""

from __future__ import annotations

import functools
import hashlib
import os
import pathlib
import pickle
from collections.abc import Callable

import jax

__all__ = ["StoredJit", "directory", "source_digest"]

#: The sub-folder of the compilation cache that holds the stored programs.
FOLDER = "jaxmocap-exported"
_MAGIC = b"JXMX1\n"


def directory() -> pathlib.Path | None:
    """Where stored programs go: ``FOLDER`` inside the persistent compilation cache directory JAX is using (None
    when it uses none: then :class:`StoredJit` is plain ``jax.jit``)."""
    current = jax.config.jax_compilation_cache_dir
    return pathlib.Path(current) / FOLDER if current else None


@functools.cache
def source_digest() -> str:
    """SHA-256 of every ``.py`` file of the package (relative path and bytes, in sorted order)."""
    root = pathlib.Path(__file__).resolve().parent
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(b"\0")
        h.update(path.read_bytes())
    return h.hexdigest()


def _signature(leaves) -> str:
    """The abstract values of the argument leaves (shape, dtype, weak type), e.g. ``f32[4000,31]``."""
    return ";".join(str(jax.typeof(x)) for x in leaves)


def _versions() -> str:
    import jaxlib

    return f"jax {jax.__version__} jaxlib {jaxlib.__version__} backend {jax.default_backend()}"


class StoredJit:
    """``jax.jit(fn)`` whose exported program is kept on disk under a caller's ``tag`` (module docstring).

    ``tag``: a string that determines ``fn``'s trace for given argument shapes, or None (then this is plain
    ``jax.jit``); ``folder``: where to keep the programs (default :func:`directory`). Calling it and
    :meth:`lower` take the same arguments as ``fn``. ``loaded`` counts the programs read back from disk,
    ``exported`` the programs traced and written this process.
    """

    def __init__(self, fn: Callable, tag: str | None, folder: str | os.PathLike | None = None):
        self.fn = fn
        self.tag = tag
        self.folder = None if folder is None else pathlib.Path(folder)
        self._jit = jax.jit(fn)
        self._programs: dict[str, tuple] = {}
        self.loaded = 0
        self.exported = 0

    def _key(self, leaves) -> str:
        h = hashlib.sha256()
        for part in (self.tag, _signature(leaves), _versions(), source_digest()):
            h.update(part.encode())
            h.update(b"\0")
        return h.hexdigest()

    def _program(self, args: tuple):
        """``(jitted call of the exported program, output tree, flat arguments)``, or None for plain jit."""
        if self.tag is None:
            return None
        folder = self.folder if self.folder is not None else directory()
        if folder is None:
            return None
        leaves, in_tree = jax.tree.flatten(args)
        # the programs of this process by structure and abstract values (hashable, cheap): the text key and its
        # SHA-256 only for a new one, not on every frame's call
        avals = tuple(jax.typeof(x) for x in leaves)
        hit = self._programs.get((in_tree, avals))
        if hit is None:
            path = folder / f"{self._key(leaves)}.jaxexport"
            found = _read(path)
            if found is None:
                found = self._export(in_tree, leaves)
                _write(path, *found)
                self.exported += 1
            else:
                self.loaded += 1
            exp, out_tree = found
            hit = self._programs[in_tree, avals] = (jax.jit(exp.call), out_tree)
        return hit[0], hit[1], leaves

    def _export(self, in_tree, leaves):
        trees = []

        def flat(*xs):
            out_leaves, out_tree = jax.tree.flatten(self.fn(*jax.tree.unflatten(in_tree, xs)))
            trees.append(out_tree)
            return out_leaves

        exp = jax.export.export(jax.jit(flat))(*leaves)  # for the default backend's platform (cpu, cuda, ...)
        return exp, trees[-1]

    def __call__(self, *args):
        prog = self._program(args)
        if prog is None:
            return self._jit(*args)
        call, out_tree, leaves = prog
        return jax.tree.unflatten(out_tree, call(*leaves))

    def _cache_size(self) -> int:
        """The compiled variants in memory (as ``jax.jit``'s): the plain jit's and those of the stored programs."""
        return self._jit._cache_size() + sum(call._cache_size() for call, _ in self._programs.values())

    def lower(self, *args):
        """The lowered program for ``args`` (``.compile()`` it), as ``jax.jit(fn).lower`` (of the flat exported
        function when stored)."""
        prog = self._program(args)
        if prog is None:
            return self._jit.lower(*args)
        call, _, leaves = prog
        return call.lower(*leaves)


def _read(path: pathlib.Path):
    """``(Exported, output tree)`` from ``path``, or None when it is missing or unreadable."""
    try:
        blob = path.read_bytes()
    except OSError:
        return None
    try:
        if not blob.startswith(_MAGIC):
            return None
        body = blob[len(_MAGIC) :]
        n = int.from_bytes(body[:8], "little")
        out_tree = pickle.loads(body[8 : 8 + n])
        exp = jax.export.deserialize(bytearray(body[8 + n :]))
        return exp, out_tree
    except Exception:  # noqa: BLE001 (a torn or foreign file: traced and written again)
        return None


def _write(path: pathlib.Path, exp, out_tree) -> None:
    """Write atomically (a torn file is never left under the final name); a failure only costs the next start."""
    try:
        tree = pickle.dumps(out_tree)
        data = _MAGIC + len(tree).to_bytes(8, "little") + tree + bytes(exp.serialize())
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        try:
            tmp.write_bytes(data)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
    except Exception:  # noqa: BLE001 (unpicklable output tree, read-only or full disk: run as usual)
        pass
