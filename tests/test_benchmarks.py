"""The benchmark runner: its RESULTS.md block logic, and a quick-mode smoke run of every benchmark (tiny sizes, no
timing assertion)."""

import pathlib
import sys

import pytest

BENCH = pathlib.Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCH))

import run as runner  # noqa: E402


def test_update_block_replaces_only_between_markers():
    text = "# R\n\nhand-written A\n\n<!-- generated:x begin -->\nold\n<!-- generated:x end -->\n\nhand-written B\n"
    out = runner.update_block(text, "x", "new table")
    assert "old" not in out
    assert "hand-written A" in out and "hand-written B" in out
    assert out.index("hand-written A") < out.index("new table") < out.index("hand-written B")
    # a second update replaces again (one block, not two)
    out2 = runner.update_block(out, "x", "newer")
    assert out2.count("generated:x begin") == 1 and "new table" not in out2 and "newer" in out2


def test_update_block_appends_missing_section():
    out = runner.update_block("# R\n\ntext\n", "y", "| a |\n|---|", "Title Y")
    assert out.startswith("# R\n\ntext\n")
    assert "## Title Y\n\n<!-- generated:y begin -->\n| a |\n|---|\n<!-- generated:y end -->\n" in out


def test_unknown_benchmark_is_an_error(capsys):
    with pytest.raises(SystemExit) as e:
        runner.main(["--quick", "--only", "nonexistent"])
    assert e.value.code == 2
    assert "unknown benchmark" in capsys.readouterr().err


def test_machine_block_names_versions():
    block = runner.machine_block((1.0, 2.0, 3.0))
    for word in (
        "cores",
        "load average at start 1.0 / 2.0 / 3.0",
        "Python",
        "JAX",
        "jaxlib",
        "NumPy",
        "OpenCV",
    ):
        assert word in block


@pytest.mark.slow
def test_runner_quick_writes_results(tmp_path):
    path = tmp_path / "RESULTS.md"
    path.write_text("# Benchmark results\n\nkeep me\n")
    assert runner.main(["--quick", "--only", "kinematics", "--results", str(path)]) == 0
    text = path.read_text()
    assert "keep me" in text
    assert "<!-- generated:machine begin -->" in text and "<!-- generated:kinematics end -->" in text
    assert "| ratio |" in text


# what each quick benchmark's markdown must contain (its table header or report line)
EXPECT = {
    "kinematics": "particles/s",
    "likelihood": "",
    "parsec": "µs/particle/layer",
    "features": "pairs",
    "render": "frames/s",
    "synth": "view-frames/s",
    "end_to_end": "frames/s",
    "scaling": "| sweep |",
    "iros": "SIR",
    "foreground": "IoU",
    "accuracy": "| configuration |",
    "hybrid": "APF",
}


def test_every_script_is_registered():
    """Every script under perf/ and experiments/ has an entry (its command) in the runner, and every entry a file."""
    scripts = {
        p.relative_to(BENCH).as_posix() for d in ("perf", "experiments") for p in (BENCH / d).glob("*.py")
    }
    assert scripts == {s.path for s in runner.SCRIPTS.values()}
    assert set(runner.BENCHMARKS) <= set(runner.SCRIPTS)


def test_every_result_names_its_command():
    """Every file under results/ is listed in results/README.md with what regenerates it, and every Markdown
    file there starts with that line."""
    index = (BENCH / "results" / "README.md").read_text()
    for p in sorted((BENCH / "results").iterdir()):
        if p.name == "README.md":
            continue
        assert runner.made_by(p.name), p.name
        assert f"| [{p.name}]({p.name}) | {runner.made_by(p.name)} |" in index, p.name
        if p.suffix == ".md":
            assert p.read_text().split("\n", 1)[0] == runner.first_line(p.name), p.name


def test_scripts_import_no_other_script():
    """Scripts share code through common, scenes and reference only."""
    stems = {pathlib.Path(s.path).stem for s in runner.SCRIPTS.values()}
    for s in runner.SCRIPTS.values():
        text = (BENCH / s.path).read_text()
        for stem in stems:
            assert f"import {stem}\n" not in text and f"from {stem} import" not in text, (s.path, stem)


def test_every_benchmark_has_an_expectation():
    assert set(EXPECT) == set(runner.BENCHMARKS)


#: the quick runs that track whole sequences, in tests/test_benchmarks_tracking.py (a file per pytest-xdist worker)
TRACKING = ("accuracy", "end_to_end", "hybrid")


def check_quick_run(name):
    check_markdown(name, runner.BENCHMARKS[name].fn(True))


def check_markdown(name, md):
    """What a quick run's markdown must be: non-empty, no failure reported, the benchmark's expected text."""
    assert isinstance(md, str) and md.strip()
    assert "failed" not in md.lower()
    assert EXPECT[name] in md


def test_every_benchmark_has_a_smoke_test():
    assert set(EXPECT) == set(runner.BENCHMARKS)
    assert set(TRACKING) <= set(runner.BENCHMARKS)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(set(runner.BENCHMARKS) - set(TRACKING)))
def test_quick_benchmark_runs(name):
    check_quick_run(name)


def test_profile_names_the_kernels_and_their_contents(tmp_path):
    """The profiling tool reads XLA's kernel events from a JAX trace and the operations inside each fusion from
    the compiled program (a tiny program whose one fusion holds a sine)."""
    import jax
    import jax.numpy as jnp

    prof = runner.load("profile_likelihood")

    f = jax.jit(lambda x: jnp.sin(x) * 2.0 + 1.0)
    x = jnp.linspace(0.0, 1.0, 1 << 16)
    f(x).block_until_ready()
    with jax.profiler.trace(str(tmp_path), create_perfetto_trace=True):
        for _ in range(2):
            f(x).block_until_ready()
    times = prof.kernel_times(str(tmp_path), 2)
    contents = prof.fusion_contents(f.lower(x).compile().as_text())
    fused = [name for name, ops in contents.items() if ops["sine"] == 1 and ops["multiply"] >= 1]
    assert fused and fused[0] in times and times[fused[0]] > 0
