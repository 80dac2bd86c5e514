"""``jaxmocap.track(...)`` against ``jaxmocap track``: the same joints for one seed, with the options given as
arguments, on the command line or in a ``--config`` file; the effective configuration written back into the run
folder; nothing written without ``out``; one-line errors for a bad configuration file."""

import tomllib

import numpy as np
import pytest

import jaxmocap
from jaxmocap import cli
from jaxmocap.io import export
from jaxmocap.synth import generate as synth

OPTS = {
    "model": "upper9",
    "cues": "foreground,coverage",
    "particles": 40,
    "layers": 2,
    "frames": "2:7",
    "seed": 3,
}
FLAGS = ["--model", "upper9", "--cues", "foreground,coverage", "--particles", "40", "--layers", "2"]
FLAGS += ["--frames", "2:7", "--seed", "3"]


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    out = tmp_path_factory.mktemp("seq")
    synth.synthesize("demo", out, rig="stereo", frames="0:16", fps=60.0, size="96x72", seed=0, overwrite=True)
    return out


@pytest.fixture(scope="module")
def api_result(sequence):
    return jaxmocap.track(input=sequence, **OPTS)


def test_api_returns_the_command_lines_joints(sequence, api_result, tmp_path, capsys):
    res = api_result
    assert res.out is None and res.frames.tolist() == [2, 3, 4, 5, 6]
    assert (
        res.joints.shape == (5, 15, 3)
        and res.states.shape == (5, len(res.dof_names))
        and res.model == "upper9"
    )
    assert set(res.diagnostics) >= {"quality", "lost", "reinitialised"}
    assert all(a.shape == (5,) for a in res.diagnostics.values())
    assert np.all(np.isfinite(res.diagnostics["quality"]))
    assert cli.main(["track", str(sequence), "--out", str(tmp_path / "cli"), "--quiet", *FLAGS]) == 0
    poses = export.load_poses(tmp_path / "cli")
    np.testing.assert_array_equal(poses["joints"], res.joints)
    np.testing.assert_array_equal(poses["state"], res.states)
    np.testing.assert_array_equal(poses["frame_index"], res.frames)


def test_config_file_and_its_write_back(sequence, api_result, tmp_path):
    """The options in a --config file give the same run; the run folder gets config.toml, the effective
    configuration (defaults resolved), which runs the same again; options on the command line override the file."""
    cfg = tmp_path / "run.toml"
    cfg.write_text(
        f'input = "{sequence}"\nout = "first"\nmodel = "upper9"\ncues = "foreground,coverage"\nparticles = 40\n'
        'layers = 2\nframes = "2:7"\nseed = 99\n'
    )
    assert cli.main(["track", "--config", str(cfg), "--seed", "3", "--quiet"]) == 0
    first = tmp_path / "first"  # relative to the file's folder
    np.testing.assert_array_equal(export.load_poses(first)["joints"], api_result.joints)
    written = tomllib.loads((first / "config.toml").read_text())
    assert written["seed"] == 3 and written["particles"] == 40 and written["model"] == "upper9"
    assert written["input"] == str(sequence) and written["out"] == str(first)
    assert written["filter"] == "apf" and written["foreground"] == "auto"
    again = jaxmocap.track(config=first / "config.toml", out=tmp_path / "again")
    np.testing.assert_array_equal(again.joints, api_result.joints)
    assert again.config["cues"] == "foreground, coverage" and (tmp_path / "again" / "config.toml").is_file()


@pytest.mark.parametrize(
    "text, needles",
    [
        ("partcles = 40\n", ["run.toml", "unknown option 'partcles'"]),
        ("particles = 'many'\n", ["run.toml", "'particles' must be an integer or a list of integers"]),
        ("seed = 1.5\n", ["run.toml", "'seed' must be an integer"]),
        ("videos = 'a.mp4'\n", ["run.toml", "'videos' must be a list of paths"]),
        ("particles = [\n", ["run.toml", "not valid TOML"]),
    ],
)
def test_bad_configuration_is_one_line(text, needles, tmp_path, capsys):
    cfg = tmp_path / "run.toml"
    cfg.write_text(text)
    code = cli.main(["track", "--config", str(cfg), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith("jaxmocap: error: "), err
    for n in needles:
        assert n in err, err
    assert not (tmp_path / "o").exists()


def test_unknown_keyword_and_missing_out(sequence, tmp_path, capsys):
    with pytest.raises(TypeError, match="partcles"):
        jaxmocap.track(input=sequence, partcles=3)
    code = cli.main(["track", str(sequence)])
    err = capsys.readouterr().err
    assert code == 2 and "--out is required" in err and err.count("\n") == 1
