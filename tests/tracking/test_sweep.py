"""``jaxmocap sweep``: sequences × filters × seeds into one table, on a tiny synthetic sequence."""

import csv
import json

import numpy as np
import pytest

from jaxmocap import cli
from jaxmocap.synth import generate as synth
from jaxmocap.tracking import sweep


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    out = tmp_path_factory.mktemp("seq")
    synth.synthesize("demo", out, rig="stereo", frames="0:12", fps=60.0, size="96x72", seed=0, overwrite=True)
    return out


@pytest.mark.slow
def test_sweep_from_spec_file(sequence, tmp_path, capsys):
    spec = tmp_path / "sweep.toml"
    spec.write_text(
        f'sequences = ["{sequence}"]\nfilters = ["sir"]\nseeds = [0, 5]\nmodel = "upper9"\n'
        'cues = "foreground,coverage"\nparticles = 64\n'
    )
    out = tmp_path / "res" / "sweep.csv"
    assert cli.main(["sweep", "--spec", str(spec), "--particles", "24", "--out", str(out)]) == 0
    assert "wrote 2 run(s)" in capsys.readouterr().out
    with out.open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["seed"] for r in rows] == ["0", "5"]
    assert {r["filter"] for r in rows} == {"sir"} and {r["particles"] for r in rows} == {"24"}  # CLI override
    assert {r["frames"] for r in rows} == {"0:6"}
    err = np.array([float(r["mean_error_mm"]) for r in rows])
    # started on the ground-truth pose, a few frames of a walk: far below the ~0.5 m of a lost track, and the
    # seeds give different runs
    assert np.all(np.isfinite(err)) and np.all(err > 0) and np.all(err < 250), err
    assert err[0] != err[1]
    md = (tmp_path / "res" / "sweep.md").read_text()
    assert md.count("| sir |") == 3  # two runs and the per-filter summary


def test_bad_specs(tmp_path, capsys, sequence):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"sequences": [str(sequence)], "seed": 3}))
    assert cli.main(["sweep", "--spec", str(bad), "--out", str(tmp_path / "r.csv")]) == 2
    assert "unknown key(s) seed" in capsys.readouterr().err
    assert cli.main(["sweep", str(sequence), "--filters", "sir,nope", "--out", str(tmp_path / "r.csv")]) == 2
    assert "unknown filter 'nope'" in capsys.readouterr().err
    assert cli.main(["sweep", "--out", str(tmp_path / "r.csv")]) == 2
    assert "give sequence folders" in capsys.readouterr().err
    assert cli.main(["sweep", str(tmp_path), "--out", str(tmp_path / "r.csv")]) == 2
    assert sweep.parse_seeds("2:5") == (2, 3, 4) and sweep.parse_seeds("1,7") == (1, 7)
    with pytest.raises(ValueError, match="seeds"):
        sweep.parse_seeds("a:b")
