"""Traced programs kept on disk, so that a warm start neither traces nor lowers them again.

JAX's persistent compilation cache (:mod:`jaxmocap.compilation_cache`) keeps the *compiled* programs, but it finds
one only after the function has been traced to a jaxpr and lowered to StableHLO, because its key is a hash of
that module. For a warm run those two steps are most of the start: PARSEC's weighted start and filter step take
4–5 s to trace and lower, reloading both executables 1.5 s (``benchmarks/results/parsec_track.md``); the filter step
of ``jaxmocap track`` (likelihood, annealing layers, refinement) 5–8 s.

:class:`StoredJit` is ``jax.jit(fn)`` for a function whose trace is fully determined by a **tag** that the caller
builds from everything the function closes over (the body's dimensions, the calibration, the particle count, …)
together with the shapes and dtypes of the arguments' leaves. The first call of a configuration traces ``fn`` as
usual, exports it with :func:`jax.export.export` (StableHLO, serialised) and writes it to ``DIR/<key>.jaxexport``;
a later process with the same key deserialises it and calls it: no Python tracing, no lowering of the function's
body. Beside it the program's **executable** is kept once XLA has compiled it (``DIR/<program>.<machine>.xlaexec``,
:class:`_Program`; ``<program>``: :func:`program_digest`, the exported StableHLO without its source locations, so
that an edit of the package re-exports a program but finds its executable when the program is the same;
``<machine>``: :func:`machine_digest`, the versions, XLA's flags and options and the host CPU): a process that
finds it runs it without lowering the exported module, hashing it for the compilation cache or importing SciPy
(which JAX's export does for its LAPACK kernels). A warm one-frame PARSEC run took 1.94 s with the executables
against 2.18 s without (per-round ratio 0.94, beside a busy process 0.87;
``benchmarks/perf/parsec_latency.py --against 7bb1c6a``). Without an executable the deserialised module is
lowered and compiled, the compilation found in the persistent cache as usual. The key is a SHA-256 of the tag, the
leaves' abstract values, the backend, the JAX and jaxlib versions and the source of this package (every ``.py``
file of ``jaxmocap``), so any change of the code or of the versions traces afresh. A file that cannot be read back
(torn, from another JAX) is ignored and written again. Deleting the directory is always safe. A stored file is
loaded as code (the trees are pickles, the program StableHLO, the executable machine code), like the executables
of JAX's own cache beside it: keep the cache directory private to its user.

Use it only where the tag covers every value the function closes over: a constant missing from the tag would
give a stale program for a new value of it. The argument leaves themselves are data of the program (only their
shapes and dtypes are in the key); the **structure** of the arguments — the tree and its static data, e.g. a
filter's settings and the body model, rig and flesh points that the tracker's likelihood holds as constants of
its program — is in the key as the SHA-256 of its pickle, so it needs no tag of its own. Arguments whose structure
cannot be pickled (a lambda, a closure in the static data) are never stored: plain ``jax.jit`` for them. So is
everything outside :func:`use`: the command line and :func:`jaxmocap.track` store programs while the compilation
cache is on (:mod:`jaxmocap.compilation_cache`); a script that wants the same wraps its run in
``with stored_programs.use(compilation_cache.enable()):``. Outside such a block (tests, notebooks that
monkeypatch the package's functions) every call traces as ``jax.jit`` does.

Besides the tag, structure and shapes, the key holds the versions of JAX, jaxlib, NumPy, optax and jaxopt, the
backend, the configuration flags that change a trace (``jax_enable_x64``, the default matmul precision, the
dtype and rank promotion rules, the PRNG implementation) and the package's source.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.metadata
import inspect
import os
import pathlib
import pickle
import platform
import threading
from collections.abc import Callable, Iterator

import jax

__all__ = ["StoredJit", "directory", "machine_digest", "program_digest", "source_digest", "stored_jit", "use"]

#: The sub-folder of the compilation cache that holds the stored programs.
FOLDER = "jaxmocap-exported"
_MAGIC = b"JXMX3\n"


#: the folders of the enclosing :func:`use` blocks, innermost last (None: storing off in that block)
_ACTIVE: list[pathlib.Path | None] = []


@contextlib.contextmanager
def use(cache: str | os.PathLike | None) -> Iterator[pathlib.Path | None]:
    """Store and read programs in ``cache / FOLDER`` inside the block (``cache``: the compilation cache directory,
    :func:`jaxmocap.compilation_cache.enable`'s result; None: not at all). Module-wide, not per thread: a thread
    started in the block (the tracker compiles its step ahead in one) sees it too. Yields the folder."""
    folder = None if cache is None else pathlib.Path(cache) / FOLDER
    _ACTIVE.append(folder)
    try:
        yield folder
    finally:
        _ACTIVE.pop()


def directory() -> pathlib.Path | None:
    """Where stored programs go: the folder of the innermost :func:`use` block, None outside one (then
    :class:`StoredJit` without a ``folder`` is plain ``jax.jit``)."""
    return _ACTIVE[-1] if _ACTIVE else None


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


#: the distributions whose code runs while the package's functions are traced
_TRACED_WITH = ("jax", "jaxlib", "numpy", "optax", "jaxopt")
#: the configuration flags that change what a function traces to
_TRACE_FLAGS = (
    "jax_enable_x64",
    "jax_default_matmul_precision",
    "jax_numpy_dtype_promotion",
    "jax_numpy_rank_promotion",
    "jax_default_prng_impl",
)


@functools.cache
def _distributions() -> str:
    found = []
    for name in _TRACED_WITH:
        try:
            found.append(f"{name} {importlib.metadata.version(name)}")
        except importlib.metadata.PackageNotFoundError:
            found.append(f"{name} -")
    return " ".join(found)


def _versions() -> str:
    """The versions, backend and trace flags of the key (module docstring)."""
    flags = " ".join(f"{f}={getattr(jax.config, f, None)}" for f in _TRACE_FLAGS)
    return f"{_distributions()} jax {jax.__version__} backend {jax.default_backend()} {flags}"


def _traced(leaves) -> bool:
    """Whether any leaf is a tracer (the call is inside a caller's ``jit``, ``vmap`` or ``grad``)."""
    return any(isinstance(x, jax.core.Tracer) for x in leaves)


def _structure(in_tree) -> str | None:
    """SHA-256 of the pickled argument structure (its static data included), None when it cannot be pickled."""
    try:
        return hashlib.sha256(pickle.dumps(in_tree, protocol=5)).hexdigest()
    except Exception:  # noqa: BLE001 (a lambda or a closure in the static data: this call is not stored)
        return None


class StoredJit:
    """``jax.jit(fn)`` whose exported program is kept on disk under a caller's ``tag`` (module docstring).

    ``tag``: a string that determines ``fn``'s trace for a given argument structure and shapes (it names what
    ``fn`` closes over), or None (then this is plain ``jax.jit``); ``folder``: where to keep the programs (default
    :func:`directory`: only inside :func:`use`); ``key_structure=False``: the tag names the arguments' static
    structure too (a caller whose arguments hold a closure, such as PARSEC's filter and its likelihood), which is
    then left out of the key; ``compiler_options``: XLA's options for its compilation (``jax.jit``'s; not part of
    the stored program, which is compiled after it is read). Calling it and
    :meth:`lower` take the same arguments as ``fn``. ``loaded`` counts the programs read back from disk,
    ``exported`` the programs traced and written this process.
    """

    def __init__(
        self,
        fn: Callable,
        tag: str | None,
        folder: str | os.PathLike | None = None,
        key_structure: bool = True,
        compiler_options: dict | None = None,
    ):
        self.fn = fn
        self.tag = tag
        self.key_structure = key_structure
        self.folder = None if folder is None else pathlib.Path(folder)
        self.compiler_options = dict(compiler_options or {})
        self._jit = jax.jit(fn, compiler_options=self.compiler_options or None)
        # (folder, argument tree, abstract values) -> (jitted call, output tree), None for plain jit
        self._programs: dict[tuple, tuple | None] = {}
        self.loaded = 0
        self.exported = 0

    def _key(self, structure: str, leaves) -> str:
        h = hashlib.sha256()
        for part in (self.tag, structure, _signature(leaves), _versions(), source_digest()):
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
        if _traced(leaves):  # inside a caller's jit, vmap or grad
            return None
        # the programs of this process by structure and abstract values (hashable, cheap): the text key and its
        # SHA-256 only for a new one, not on every frame's call
        avals = tuple(jax.typeof(x) for x in leaves)
        try:
            hit = self._programs[folder, in_tree, avals]
        except KeyError:
            hit = self._programs[folder, in_tree, avals] = self._find(folder, in_tree, leaves)
        if hit is None:  # a structure that cannot be keyed: plain jit
            return None
        return hit[0], hit[1], leaves

    def _find(self, folder: pathlib.Path, in_tree, leaves):
        """``(jitted call, output tree)`` of the program read from ``folder`` or traced and written there; None
        when the structure cannot be keyed."""
        structure = _structure(in_tree) if self.key_structure else "named by the tag"
        if structure is None:
            return None
        path = folder / f"{self._key(structure, leaves)}.jaxexport"
        found = _read(path)
        if found is None:
            exp, out_tree = self._export(in_tree, leaves)
            found = exp, (out_tree, *_program_facts(exp))
            _write_file(path, _MAGIC, found[1], exp.serialize())
            self.exported += 1
        else:
            self.loaded += 1
        exp, (out_tree, digest, lapack) = found
        # the exported program runs on one device: its arguments placed there explicitly, so that the program
        # lowered ahead from shapes (``lower`` with ``jax.ShapeDtypeStruct``) is the one a call with committed
        # arrays (outputs of other programs) lowers to; left unspecified, such arguments add their sharding to
        # the module, another program to compile (the tracker's step compiled twice in a cold run: 2 × 17–20 s)
        one = jax.sharding.SingleDeviceSharding(jax.devices()[0])

        # named for the executables it keeps and the threads of XLA's CPU pool (the module's name is part of JAX's
        # cache key, the thread count is not, though XLA's code differs with it (:func:`machine_digest`): an
        # executable from the cache cannot be kept, :class:`_Program`, and a cache filled before executables were
        # kept, or by a process with another thread count, holds this program under another name)
        def stored_executable(*xs):
            return exp.call(*xs)

        stored_executable.__name__ = stored_executable.__qualname__ = f"stored_executable_{_threads()}"
        jitted = jax.jit(stored_executable, in_shardings=one, compiler_options=self.compiler_options or None)
        return _Program(jitted, folder / f"{digest}.xlaexec", self.compiler_options, lapack), out_tree

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
        stored = (hit for hit in self._programs.values() if hit is not None)
        return self._jit._cache_size() + sum(program.compiled is not None for program, _ in stored)

    def lower(self, *args):
        """The lowered program for ``args`` (``.compile()`` it), as ``jax.jit(fn).lower`` (of the flat exported
        function when stored)."""
        prog = self._program(args)
        if prog is None:
            return self._jit.lower(*args)
        call, _, leaves = prog
        return call.lower(*leaves)


class _Program:
    """A stored program's compiled executable, kept on disk beside it (``<program>.<machine>.xlaexec``:
    :func:`program_digest`, :func:`machine_digest`).

    The first call (or ``lower(...).compile()``) of a process reads the executable back when this machine and
    configuration wrote it (:func:`machine_digest`): no lowering of the exported program, no look-up in the
    compilation cache (which needs the lowered module's hash). Otherwise it lowers ``jitted`` (the exported
    program's call, whose compilation the persistent cache may still hold), compiles it and writes the
    executable — only when XLA really compiled it: an executable that JAX's persistent cache supplied serialises
    without its kernels in jaxlib 0.10 (read back, its first call fails with "Function … not found"), so after a
    cache hit nothing is written and the run keeps the cache's executable (:func:`_cache_hits`). A program that
    calls LAPACK gets JAX's LAPACK kernels initialised before its executable is read back (lowering does that);
    where that is not possible the executable is not used. A process whose XLA CPU pool has fewer threads than
    the one the executable was compiled for (``--cpu-threads auto`` choosing one thread beside a busy process)
    runs that executable when its own is missing, instead of compiling for 10–30 s: its parallel loops run on the
    threads there are, the same values (the PARSEC likelihood compiled for two threads ran at 13.35 µs per
    particle on one, 12.94 µs compiled for one; the other way round it loses its second thread, 12.81 against
    8.17 µs, so a wider pool compiles its own). An executable that cannot be read back is compiled
    and written again — unless JAX's cache holds the program (its last real compilation put it there): then the
    run uses the cache's executable, as without this class, until that entry goes."""

    def __init__(self, jitted, path: pathlib.Path, compiler_options: dict, lapack: bool):
        self.jitted = jitted
        self.path = path.with_name(f"{path.stem}.{machine_digest(compiler_options)}.xlaexec")
        self._program_path, self._options = path, compiler_options
        self.lapack = lapack  # the program calls LAPACK (:func:`_program_facts`)
        self.compiled = None
        self._lock = threading.Lock()

    def compile(self, leaves):
        """The compiled executable for arguments shaped like ``leaves`` (arrays or ``jax.ShapeDtypeStruct``)."""
        with self._lock:
            if self.compiled is None:
                compiled = _read_executable(self.path, self.lapack)
                for wider in self._wider_paths() if compiled is None else ():
                    compiled = _read_executable(wider, self.lapack)
                    if compiled is not None:
                        break
                if compiled is None:
                    hits = _cache_hits()
                    compiled = self.jitted.lower(*leaves).compile()
                    if _cache_hits() == hits:  # compiled by XLA in this thread, not read from JAX's cache
                        _write_executable(self.path, compiled)
                self.compiled = compiled
            return self.compiled

    def _wider_paths(self) -> list[pathlib.Path]:
        """The executables of the same program compiled for a wider XLA CPU pool, the narrowest first (named only
        when this pool's own is missing)."""
        p = self._program_path
        return [p.with_name(f"{p.stem}.{machine_digest(self._options, k)}.xlaexec") for k in _wider_pools()]

    def __call__(self, *leaves):
        return self.compile(leaves)(*leaves)

    def lower(self, *leaves):
        return _Lowered(self, leaves)


class _Lowered:
    """What :meth:`StoredJit.lower` gives for a stored program: ``.compile()`` returns its executable."""

    def __init__(self, program: _Program, leaves):
        self.program, self.leaves = program, leaves

    def compile(self):
        return self.program.compile(self.leaves)


class _StoredFunction:
    """:func:`stored_jit`'s wrapper: ``jax.jit(fn, static_argnames=static)`` outside :func:`use` or under a
    transformation, a :class:`StoredJit` per combination of static values inside."""

    def __init__(self, fn: Callable, static: tuple[str, ...]):
        self.fn, self.static = fn, static
        self._signature = inspect.signature(fn)
        self._jit = jax.jit(fn, static_argnames=static) if static else jax.jit(fn)
        self._stored: dict[tuple, StoredJit] = {}
        functools.update_wrapper(self, fn)

    def _split(self, args, kwargs):
        bound = self._signature.bind(*args, **kwargs)
        bound.apply_defaults()
        static = tuple((n, bound.arguments[n]) for n in self.static)
        names = tuple(n for n in bound.arguments if n not in self.static)
        return static, names, tuple(bound.arguments[n] for n in names)

    def _stored_for(self, static, names) -> StoredJit:
        s = self._stored.get((static, names))
        if s is None:
            fn, fixed = self.fn, dict(static)

            def call(*dynamic):
                return fn(**dict(zip(names, dynamic, strict=True)), **fixed)

            tag = f"{fn.__module__}.{fn.__qualname__} {names!r} {static!r}"
            s = self._stored[static, names] = StoredJit(call, tag)
        return s

    def _plain(self, args, kwargs) -> bool:
        return directory() is None or _traced(jax.tree.leaves((args, kwargs)))

    def __call__(self, *args, **kwargs):
        if self._plain(args, kwargs):
            return self._jit(*args, **kwargs)
        static, names, dynamic = self._split(args, kwargs)
        return self._stored_for(static, names)(*dynamic)

    def lower(self, *args, **kwargs):
        if self._plain(args, kwargs):
            return self._jit.lower(*args, **kwargs)
        static, names, dynamic = self._split(args, kwargs)
        return self._stored_for(static, names).lower(*dynamic)

    def _cache_size(self) -> int:
        """The compiled variants in memory: the plain jit's and those of the stored programs."""
        return self._jit._cache_size() + sum(s._cache_size() for s in self._stored.values())


def stored_jit(fn: Callable | None = None, *, static_argnames: tuple[str, ...] = ()):
    """``jax.jit`` for a module-level function whose trace depends only on its arguments and the package's code
    (no closure, no module-level value that changes at run time): inside :func:`use` its traced programs are kept
    on disk like :class:`StoredJit`'s, tagged with the function's qualified name and the values of its
    ``static_argnames`` (which must be hashable and have a faithful ``repr``). Called under ``jit``, ``vmap`` or
    ``grad`` it is the plain ``jax.jit``, inlined into the caller's program as usual."""
    if fn is None:
        return functools.partial(stored_jit, static_argnames=tuple(static_argnames))
    return _StoredFunction(fn, tuple(static_argnames))


def program_digest(exp) -> str:
    """32 hex digits of SHA-256 of the exported program's StableHLO without its locations (the source lines
    it was traced from), as JAX's compilation cache keys a program: an edit that only moves lines re-exports the
    program (the key holds the package's source) but finds its executable."""
    return _program_facts(exp)[0]


def _program_facts(exp) -> tuple[str, bool]:
    """``(program_digest(exp), whether the program calls LAPACK)``, from one print of its StableHLO (kept in the
    ``.jaxexport`` file: a program read back never prints it)."""
    text = exp.mlir_module()
    lapack = "lapack_" in text
    try:
        from jax._src.interpreters import mlir
        from jax._src.lib.mlir import ir

        with mlir.make_ir_context():
            text = ir.Module.parse(text).operation.get_asm(enable_debug_info=False)
    except Exception:  # noqa: BLE001 (another JAX: the text with its locations, a narrower key)
        pass
    return hashlib.sha256(text.encode()).hexdigest()[:32], lapack


def _read_file(path: pathlib.Path, magic: bytes):
    """``(header, payload)`` of a file :func:`_write_file` wrote with ``magic``; None when it is missing or is
    not such a file."""
    try:
        blob = path.read_bytes()
    except OSError:
        return None
    if not blob.startswith(magic):
        return None
    body = blob[len(magic) :]
    n = int.from_bytes(body[:8], "little")
    return pickle.loads(body[8 : 8 + n]), body[8 + n :]


def _read(path: pathlib.Path):
    """``(Exported, (output tree, program digest, calls LAPACK))`` from ``path``, or None when it is missing or
    unreadable."""
    try:
        found = _read_file(path, _MAGIC)
        if found is None:
            return None
        header, payload = found
        return jax.export.deserialize(bytearray(payload)), header
    except Exception:  # noqa: BLE001 (a torn or foreign file: traced and written again)
        return None


_EXEC_MAGIC = b"JXMC2\n"
_HITS = threading.local()
_LISTENING = []


def _count_hit(event: str, **kwargs) -> None:
    if event == "/jax/compilation_cache/cache_hits":
        _HITS.n = getattr(_HITS, "n", 0) + 1


def _cache_hits() -> int:
    """How many programs this thread has read from JAX's persistent compilation cache so far (counted from the
    first call: a listener of JAX's monitoring events, which JAX calls in the compiling thread)."""
    if not _LISTENING:
        _LISTENING.append(_count_hit)
        jax.monitoring.register_event_listener(_count_hit)
    return getattr(_HITS, "n", 0)


@functools.cache
def _cpu_identity() -> str:
    """The host CPU's model and instruction-set flags (an XLA CPU executable is machine code for them)."""
    try:
        text = pathlib.Path("/proc/cpuinfo").read_text()
    except OSError:
        return f"{platform.machine()} {platform.processor()}"
    lines = [
        ln for ln in text.splitlines() if ln.split(":")[0].strip() in ("model name", "flags", "Features")
    ]
    return "\n".join(sorted(set(lines)))


def _threads(count: int | None = None) -> str:
    """``"<n>threads"``: the threads of XLA's CPU pool (:func:`jaxmocap.host.cpu_threads`, or ``count``) when the
    default backend is the CPU, else ``"accelerator"``."""
    from jaxmocap import host

    if jax.default_backend() != "cpu":
        return "accelerator"
    return f"{host.cpu_threads() if count is None else count}threads"


def _wider_pools() -> list[int]:
    """Thread counts above this process's XLA CPU pool, up to the CPUs of its affinity mask (none for an
    accelerator): the pools whose executables this process may run (:class:`_Program`)."""
    from jaxmocap import host

    if jax.default_backend() != "cpu":
        return []
    n = host.cpu_threads() or 1
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return list(range(n + 1, max(cpus, n) + 1))


def machine_digest(compiler_options: dict | None = None, threads: int | None = None) -> str:
    """16 hex digits naming what a compiled executable depends on beyond its program: the JAX and jaxlib
    versions, the backend's platform and version, the device kind, ``XLA_FLAGS``, the compiler options, the host
    CPU's model and flags and the threads of XLA's CPU pool (:func:`jaxmocap.host.cpu_threads`: XLA's CPU code
    differs with them — the PARSEC step's executable is 3 390 423 bytes compiled with one, 3 403 623 with two —
    and the command line chooses one or two by load, ``--cpu-threads auto``; JAX's own cache key does not hold
    them); ``threads``: the digest for a pool of that many threads instead of this process's."""
    dev = jax.devices()[0]
    parts = (
        f"jax {jax.__version__} jaxlib {importlib.metadata.version('jaxlib')}",
        f"{dev.platform} {dev.client.platform_version} {dev.device_kind}",
        os.environ.get("XLA_FLAGS", ""),
        repr(sorted((compiler_options or {}).items())),
        _cpu_identity(),
        _threads(threads),
    )
    return hashlib.sha256("\0".join(parts).encode()).hexdigest()[:16]


def _lapack_ready() -> bool:
    """Initialise JAX's CPU LAPACK kernels (lowering a LAPACK operation does; a program read back as an
    executable is not lowered); False where this JAX has no such hook."""
    try:
        from jax._src.lax import linalg

        linalg.initialize_lapack()
        return True
    except Exception:  # noqa: BLE001 (another JAX: the program is compiled from its export instead)
        return False


def _read_executable(path: pathlib.Path, lapack: bool):
    """The ``jax.stages.Compiled`` stored at ``path``, or None when it is missing, unreadable or unusable
    (``lapack``: the program calls LAPACK, whose kernels must be set up first)."""
    if lapack and path.is_file() and not _lapack_ready():
        return None
    try:
        found = _read_file(path, _EXEC_MAGIC)
        if found is None:
            return None
        (in_tree, out_tree), payload = found
        from jax.experimental import serialize_executable

        return serialize_executable.deserialize_and_load(payload, in_tree, out_tree)
    except Exception:  # noqa: BLE001 (torn, foreign or stale: compiled and written again)
        return None


def _write_executable(path: pathlib.Path, compiled) -> None:
    """Write ``compiled`` (:func:`_write_file`); an executable that cannot be serialised is not kept."""
    from jax.experimental import serialize_executable

    try:
        data, in_tree, out_tree = serialize_executable.serialize(compiled)
    except Exception:  # noqa: BLE001 (not serialisable: compiled again next time)
        return
    _write_file(path, _EXEC_MAGIC, (in_tree, out_tree), data)


def _write_file(path: pathlib.Path, magic: bytes, header, payload) -> None:
    """``magic``, the pickled ``header`` (its length first) and ``payload``, written atomically (a torn file is
    never left under the final name); a failure (an unpicklable header, a read-only or full disk) only costs the
    next start."""
    try:
        head = pickle.dumps(header)
        _write_atomic(path, magic + len(head).to_bytes(8, "little") + head + bytes(payload))
    except Exception:  # noqa: BLE001 (run as usual)
        pass


def _write_atomic(path: pathlib.Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    # one temporary name per process and thread: two threads of a run (the step compiled ahead, the
    # re-initialisation warmed) may store the same program at once
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
