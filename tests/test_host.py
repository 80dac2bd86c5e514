"""The host CPU's description against util-linux's ``lscpu`` (its own parser of the same kernel interface) and on
written ``/proc/cpuinfo`` texts."""

import shutil
import subprocess

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
        ("AVX2", "", host.LOOP_FUSION),
        ("AVX", "--xla_force_host_platform_device_count=2", host.LOOP_FUSION),
        ("AVX-512", "", {}),
        ("aarch64", "", {}),
        ("AVX2", "--xla_cpu_use_fusion_emitters=true", {}),  # the user's XLA_FLAGS decide
    ],
)
def test_loop_fusion_is_chosen_on_x86_without_avx512_unless_xla_flags_say(
    monkeypatch, isa, xla_flags, expected
):
    monkeypatch.setattr(host, "vector_isa", lambda: isa)
    monkeypatch.setenv("XLA_FLAGS", xla_flags)
    assert host.loop_fusion_options() == expected


def test_no_cpu_option_for_programs_compiled_for_an_accelerator(monkeypatch):
    import jax

    monkeypatch.setattr(host, "vector_isa", lambda: "AVX2")
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert host.loop_fusion_options() == {}
