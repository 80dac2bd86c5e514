"""The host CPU's description against util-linux's ``lscpu`` (its own parser of the same kernel interface) and on
written ``/proc/cpuinfo`` texts; XLA's compiler options per CPU; XLA's CPU thread pool as the kernel lists its
threads; the other processes' load from the kernel's ``/proc/stat`` counters (``--cpu-threads auto``)."""

import os
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from jaxmocap import host

EPYC = """processor\t: 0
vendor_id\t: AuthenticAMD
cpu family\t: 25
model\t\t: 1
model name\t: AMD EPYC
flags\t\t: fpu sse sse2 avx fma avx2 bmi2

processor\t: 1
vendor_id\t: AuthenticAMD
cpu family\t: 25
model\t\t: 1
model name\t: AMD EPYC
flags\t\t: fpu sse sse2 avx fma avx2 bmi2
"""


@pytest.fixture
def cpuinfo(monkeypatch):
    def use(text: str, machine: str = "x86_64"):
        fields = {}
        for line in text.split("\n\n")[0].splitlines():
            k, _, v = line.partition(":")
            fields[k.strip()] = v.strip()
        monkeypatch.setattr(host, "_cpuinfo", lambda: fields)
        monkeypatch.setattr(host.platform, "machine", lambda: machine)

    return use


def test_an_avx2_cpu_is_described_with_its_family_and_model_and_without_avx512(cpuinfo):
    cpuinfo(EPYC)
    assert host.vector_isa() == "AVX2"
    assert host.description() == "AMD EPYC (family 25, model 1; AVX2, no AVX-512)"


def test_avx512_is_named_only_when_the_foundation_flag_is_there(cpuinfo):
    cpuinfo(EPYC.replace("avx2 bmi2", "avx2 bmi2 avx512f avx512bw").replace("model\t\t: 1", "model\t\t: 17"))
    assert host.vector_isa() == "AVX-512"
    assert host.description() == "AMD EPYC (family 25, model 17; AVX-512)"
    cpuinfo(EPYC.replace("avx fma avx2", "avx"))
    assert host.vector_isa() == "AVX"


def test_a_cpu_without_x86_flags_is_named_by_its_architecture(cpuinfo):
    cpuinfo("processor\t: 0\nBogoMIPS\t: 50.00\nFeatures\t: fp asimd", machine="aarch64")
    assert host.vector_isa() == "aarch64"
    assert host.description().endswith("(aarch64)")


@pytest.mark.skipif(shutil.which("lscpu") is None, reason="util-linux's lscpu is not installed")
def test_this_machine_as_lscpu_reads_it():
    out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True, env={"LC_ALL": "C"}).stdout
    fields = {k.strip(): v.strip() for k, _, v in (line.partition(":") for line in out.splitlines())}
    if fields.get("Architecture") != "x86_64":
        pytest.skip("lscpu's flags are x86's")
    flags = set(fields["Flags"].split())
    expected = (
        "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "AVX" if "avx" in flags else "SSE"
    )
    assert host.vector_isa() == expected
    assert f"family {fields['CPU family']}, model {fields['Model']};" in host.description()
    assert host.description().startswith(fields["Model name"])


@pytest.mark.parametrize(
    ("isa", "xla_flags", "expected"),
    [
        ("AVX2", "", host.COPY_REGIONS),
        ("AVX", "--xla_force_host_platform_device_count=2", host.COPY_REGIONS),
        ("AVX-512", "", host.COPY_REGIONS),
        ("aarch64", "", host.COPY_REGIONS),
        ("AVX-512", "--xla_cpu_copy_insertion_use_region_analysis=false", {}),  # the user's XLA_FLAGS decide
    ],
)
def test_particle_options_copy_regions_on_every_cpu_unless_xla_flags_say(
    monkeypatch, isa, xla_flags, expected
):
    """XLA's fusion emitters (its default) on every CPU, the loop emitter no longer on x86 without AVX-512; copy
    insertion with region analysis unless the user's ``XLA_FLAGS`` name it."""
    monkeypatch.setattr(host, "vector_isa", lambda: isa)
    monkeypatch.setenv("XLA_FLAGS", xla_flags)
    assert host.particle_options() == expected
    assert not host.LOOP_FUSION.items() <= host.particle_options().items()


@pytest.mark.parametrize(
    ("isa", "expected"), [("AVX2", True), ("AVX", True), ("AVX-512", False), ("aarch64", False)]
)
def test_gathers_apart_on_x86_without_avx512(monkeypatch, isa, expected):
    """PARSEC's pixel reads run apart from the sampling loop where XLA's fused loop is scalar (x86 without
    AVX-512), fused elsewhere, and fused for an accelerator."""
    import jax

    monkeypatch.setattr(host, "vector_isa", lambda: isa)
    assert host.gathers_apart() is expected
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert host.gathers_apart() is False


def test_no_cpu_option_for_programs_compiled_for_an_accelerator(monkeypatch):
    import jax

    monkeypatch.setattr(host, "vector_isa", lambda: "AVX2")
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert host.particle_options() == {}


def test_particle_options_compile_a_while_loop_to_the_same_values(monkeypatch):
    """This XLA accepts every option and the loop emitter's (an unknown one is an error at compile time), and they
    change no value: a while loop carrying arrays that it updates from one another (the kind of loop copy
    insertion copies)."""
    import jax
    import jax.numpy as jnp

    monkeypatch.delenv("XLA_FLAGS", raising=False)

    def f(x):
        def body(c):
            k, a, b = c
            return k + 1, jnp.where(a > b, a - b, b) * 1.5, a + jnp.sin(b)

        return jax.lax.while_loop(lambda c: c[0] < 7, body, (0, x, x[::-1]))

    x = jnp.linspace(-2.0, 3.0, 64, dtype=jnp.float32)
    ref = jax.jit(f)(x)
    # LOOP_FUSION: bench_parsec.py --host-choices compiles it
    for options in (host.particle_options(), {**host.particle_options(), **host.LOOP_FUSION}):
        out = jax.jit(f, compiler_options=options)(x)
        for a, b in zip(ref, out, strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize("threads", [None, 1])
def test_limit_cpu_threads_sizes_xlas_pool(threads):
    """In a new process (the command line imported first, which must not start JAX's backends): XLA's intra-op
    pool has one thread per CPU of the affinity mask, or the number asked for; the mask is restored."""
    code = (
        "import os, sys; import jaxmocap.cli; from jaxmocap import host; mask = os.sched_getaffinity(0); "
        f"host.limit_cpu_threads({threads}); import jax.numpy as jnp; x = jnp.ones((256, 256)); "
        "(x @ x + jnp.sin(x)).block_until_ready(); "
        "print(host.cpu_threads(), len(mask), os.sched_getaffinity(0) == mask)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=dict(os.environ)
    ).stdout.split()
    pool, cpus, restored = int(out[0]), int(out[1]), out[2]
    assert pool == (threads or cpus) and restored == "True"


def test_cpu_threads_are_chosen_before_the_backends_start():
    import jax.numpy as jnp

    jnp.zeros(1).block_until_ready()  # this process's backends have started
    with pytest.raises(RuntimeError, match="backends have started"):
        host.limit_cpu_threads(1)
    host.limit_cpu_threads(None)  # no choice made: nothing to refuse
    # the command line's default (auto) called in such a process leaves its threads as they are, unmeasured
    assert host.choose_cpu_threads(host.cpu_sample()) is None
    parser = __import__("jaxmocap.cli", fromlist=["build_parser"]).build_parser()
    for bad in ("0", "-2", "two"):  # the command line takes a positive count or auto only
        with pytest.raises(SystemExit):
            parser.parse_args(["--cpu-threads", bad, "demo"])
    assert parser.parse_args(["--cpu-threads", "auto", "demo"]).cpu_threads == "auto"
    assert parser.parse_args(["--cpu-threads", "3", "demo"]).cpu_threads == 3


STAT = """cpu  300 0 100 900 20 0 0 0 0 0
cpu0 100 5 50 400 10 1 2 3 0 0
cpu1 200 0 50 500 10 0 0 0 0 0
intr 12345
ctxt 678
"""


def test_proc_stat_counters_per_cpu():
    """``/proc/stat``'s ``cpuN`` lines (user nice system idle iowait irq softirq steal …): busy = user + nice +
    system + irq + softirq + steal, total = busy + idle + iowait; the aggregate ``cpu`` line is not a CPU."""
    busy, total = host.parse_proc_stat(STAT)
    assert busy == {0: 161, 1: 250} and total == {0: 571, 1: 760}


def test_other_busy_cpus_and_the_threads_they_leave():
    """Each CPU's busy fraction over the interval, summed, less what this process used itself: CPU 0 busy 80 of
    100 jiffies, CPU 1 30 of 100, the process 0.5 CPU-s in 1 s → 0.8 + 0.3 − 0.5 = 0.6 CPUs; CPUs outside the
    set asked about do not count."""
    a = host.CpuSample({0: 0, 1: 0, 2: 0}, {0: 0, 1: 0, 2: 0}, own_s=1.0, wall_s=10.0)
    b = host.CpuSample({0: 80, 1: 30, 2: 100}, {0: 100, 1: 100, 2: 100}, own_s=1.5, wall_s=11.0)
    assert host.other_busy_cpus(a, b, [0, 1]) == pytest.approx(0.6)
    assert host.other_busy_cpus(a, b, [0, 1, 2]) == pytest.approx(1.6)
    assert host.other_busy_cpus(a, b._replace(own_s=5.0), [0, 1]) == 0.0  # never negative
    # one thread per CPU the others leave free, at least one
    table = {(0.0, 2): 2, (0.4, 2): 2, (0.6, 2): 1, (1.0, 2): 1, (3.0, 2): 1, (1.4, 8): 7, (0.0, 1): 1}
    assert {k: host.auto_cpu_threads(*k) for k in table} == table


def test_a_busy_process_is_measured_and_leaves_fewer_threads(monkeypatch):
    """A CPU-bound child process (another program on the machine) shows as at least half a CPU kept busy by
    others over :data:`jaxmocap.host.MIN_INTERVAL_S`, and ``choose_cpu_threads`` records its choice."""
    from jax._src import xla_bridge

    monkeypatch.setattr(host, "_auto_choice", None)  # this test's choice stays in this test
    monkeypatch.setattr(xla_bridge, "backends_are_initialized", lambda: False)  # as in a process starting
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.3)  # the child has started
        a = host.cpu_sample()
        chosen = host.choose_cpu_threads(a)
        b = host.cpu_sample()
    finally:
        busy.kill()
        busy.wait()
    cpus = len(os.sched_getaffinity(0))
    assert host.other_busy_cpus(a, b, sorted(os.sched_getaffinity(0))) >= 0.5
    record = host.thread_summary()["cpu_threads_auto"]
    assert record["other_busy_cpus"] >= 0.5 and record["interval_s"] >= host.MIN_INTERVAL_S
    assert record["threads"] == host.auto_cpu_threads(record["other_busy_cpus"], cpus)
    assert chosen == (None if record["threads"] >= cpus else record["threads"])


def test_commands_set_the_collectors_thresholds_imports_do_not(data_dir):
    """``gc.get_threshold()`` in fresh processes: unchanged by importing the package's modules, then
    :data:`jaxmocap.host.GC_THRESHOLDS` once a command has run (``jaxmocap.cli.main``)."""
    script = (
        "import gc, sys\n"
        "before = gc.get_threshold()\n"
        "import jaxmocap, jaxmocap.cli, jaxmocap.tracking.tracker, jaxmocap.parsec\n"
        "print(before == gc.get_threshold())\n"
        "jaxmocap.cli.main(['calib', 'show', sys.argv[1]])\n"
        "print(list(gc.get_threshold()))\n"
    )
    calib = str(data_dir / "calib" / "parsec" / "CALIB")
    r = subprocess.run([sys.executable, "-c", script, calib], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.strip().splitlines()
    assert lines[0] == "True"
    assert lines[-1] == str(list(host.GC_THRESHOLDS))
    assert host.GC_THRESHOLDS[0] > 700
