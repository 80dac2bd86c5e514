"""Shared test set-up: tests never read ../shared at run time; their data lives in tests/data with its licences.

Compiled programs are shared across the run: the session (the controller, before pytest-xdist starts its
workers, which inherit the environment) points JAX's persistent compilation cache at a fresh temporary folder, so a
program that several tests or both workers build (the same likelihood, filter step or solver with the same shapes)
is compiled by XLA once and loaded from the folder afterwards. The folder is new for every run and removed at its
end: nothing is carried between runs, and a test that counts traces or compilations (``_cache_size``,
``jax.log_compiles``) sees the same counts as without it, since the in-memory jit cache is unchanged.

Programs are compiled for compile time, not run time (:data:`SUITE_XLA_FLAGS` added to ``XLA_FLAGS``, inherited
by the workers and by the ``jaxmocap`` child processes): the suite's programs run for milliseconds, and with
XLA's defaults compiling them was most of its time (with these flags, 5 % of ``test_tracker.py``'s). Two flags: XLA's lowest backend optimisation level
(``--xla_backend_optimization_level=0``: how much LLVM optimises the machine code) and XLA's classic loop emitters
instead of its MLIR fusion emitters (``--xla_cpu_use_fusion_emitters=false``: XLA spends about a third of a compile
in the emitters' per-kernel pipeline). Together they cut the compilation of the tracker's programs 2.6–4.0× and make
them run 4.7–9.7× slower (``benchmarks/perf/compile_time.py --programs --codegen``), which is why the command line
keeps XLA's defaults. Neither changes the operations of
a program: the results agree with the defaults' to float rounding, which the tolerances allow for. Programs compared
bit for bit, and those whose time is run time, are compiled with XLA's defaults by their tests. No test times
anything. To run the suite on the production code generation, name the flags yourself
(``XLA_FLAGS="--xla_backend_optimization_level=2 --xla_cpu_use_fusion_emitters=true" python -m pytest``): a flag
already in ``XLA_FLAGS`` is kept.

Programs are lowered without Python tracebacks in their MLIR locations (:data:`SUITE_JAX_CONFIG`, environment
variables that JAX reads when it is imported: ``JAX_TRACEBACK_IN_LOCATIONS_LIMIT=0``,
``JAX_INCLUDE_FULL_TRACEBACKS_IN_LOCATIONS=false``): the locations serve XLA's dumps and its error messages, and
building them for every operation is part of lowering, which with tracing is most of the suite's time
(``tests/tracking/test_tracker.py`` sampled: tracing 31 %, lowering 21 %, XLA compiling 5 %): that file ran in
105 s instead of 116 s on one worker (one run each; a gain the whole suite's time, ±5 % from run to run, does not
show). The programs are the same.

The cyclic garbage collector runs with the command line's thresholds (:func:`jaxmocap.host.relax_gc`, set in the
controller and in every worker): with CPython's own, ``tests/tracking/test_tracker.py`` spent 9–12 s of its 110–129 s
in about 5 300 young, 490 middle and 30 full collections, each full one walking every object JAX keeps; with them,
3.5 s.
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
    from jaxmocap import host

    host.relax_gc()
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    # the command line's persistent compilation cache stays off in the suite (nothing written to the home
    # directory; tests/test_compilation_cache.py turns it on in its own processes)
    os.environ["JAXMOCAP_CACHE_DIR"] = "off"
    flags = os.environ.get("XLA_FLAGS", "")
    for name, value in SUITE_XLA_FLAGS.items():
        if name not in flags:
            flags = f"{flags} --{name}={value}".strip()
    os.environ["XLA_FLAGS"] = flags
    for name, value in SUITE_JAX_CONFIG.items():
        os.environ.setdefault(name, value)
    if not hasattr(config, "workerinput") and "JAXMOCAP_DETECTIONS_DIR" not in os.environ:
        # the 2D detector's cache (jaxmocap.io.detect) in a folder of the session, removed at its end
        folder = tempfile.mkdtemp(prefix="jaxmocap-tests-detections-")
        config.stash[_DETECTIONS] = folder
        os.environ["JAXMOCAP_DETECTIONS_DIR"] = folder
    if not hasattr(config, "workerinput") and "JAX_COMPILATION_CACHE_DIR" not in os.environ:
        folder = tempfile.mkdtemp(prefix="jaxmocap-tests-xla-")
        config.stash[_CACHE] = folder
        os.environ["JAX_COMPILATION_CACHE_DIR"] = folder
        os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0.5"


def pytest_unconfigure(config):
    for key, name in ((_CACHE, "JAX_COMPILATION_CACHE_DIR"), (_DETECTIONS, "JAXMOCAP_DETECTIONS_DIR")):
        folder = config.stash.get(key, None)
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)
            os.environ.pop(name, None)


#: the code generation of the suite's programs (module docstring): XLA flag -> value, each added to ``XLA_FLAGS``
#: unless that already names it
SUITE_XLA_FLAGS = {"xla_backend_optimization_level": "0", "xla_cpu_use_fusion_emitters": "false"}
#: JAX's configuration for the suite (module docstring): environment variable -> value, unless already set
SUITE_JAX_CONFIG = {
    "JAX_TRACEBACK_IN_LOCATIONS_LIMIT": "0",
    "JAX_INCLUDE_FULL_TRACEBACKS_IN_LOCATIONS": "false",
}

_CACHE = pytest.StashKey[str]()
_DETECTIONS = pytest.StashKey[str]()


def pytest_collection_modifyitems(config, items):
    """The files with end-to-end cases (a test marked ``slow``: child processes, whole tracks) run first, the rest
    after them in their usual order: the two pytest-xdist workers take files from one queue in this order
    (``--dist=loadfile --no-loadscope-reorder``), so the long files are spread over both workers from the start and
    the short ones fill the end, and the workers finish together (the default order puts files with few tests last,
    and a long one of them kept a worker busy after the other had finished)."""
    slow = {item.path for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: item.path not in slow)  # stable: a file's tests stay together and in order
