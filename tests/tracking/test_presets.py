"""Presets of a tracking run (jaxmocap.tracking.presets): precedence of explicit options, the configuration file
and the command line over a preset's values, and the li-kulic partition layout on the body models."""

import pytest

from jaxmocap import cli
from jaxmocap.api import run_options
from jaxmocap.filters.factory import partition_counts
from jaxmocap.geometry import body
from jaxmocap.tracking import presets
from jaxmocap.tracking.options import TrackOptions

LI_KULIC_COUNTS = [1000, 200, 500, 500, 200, 200, 500, 500, 200, 200]


def test_preset_values_lie_under_explicit_options():
    o = TrackOptions.from_preset("li-kulic")
    assert (o.preset, o.model, o.filter, o.layers) == ("li-kulic", "full25", "partitioned", 1)
    assert o.particles == LI_KULIC_COUNTS
    assert o.cues == "depth,edge_fraction,colour_template,wristband,ground"
    o = TrackOptions.from_preset("li-kulic", particles=300, cues="depth:2,edge_fraction", seed=3)
    assert (o.particles, o.cues, o.seed, o.filter) == (300, "depth:2,edge_fraction", 3, "partitioned")
    # another filter: the preset's per-partition counts and single layer are its filter's, so they go
    o = TrackOptions.from_preset("li-kulic", filter="apf")
    assert (o.filter, o.particles, o.layers, o.model) == ("apf", None, None, "full25")
    # the same through the keyword path of jaxmocap.track and the command line
    assert run_options({"preset": "li-kulic", "particles": 64, "out": "x"}).particles == 64
    assert run_options({"particles": 64}).preset is None


def test_unknown_preset_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown preset .nope.; choose one of .*li-kulic"):
        TrackOptions.from_preset("nope")
    with pytest.raises(TypeError, match="unknown option"):
        TrackOptions.from_preset("li-kulic", partcles=3)
    with pytest.raises(SystemExit) as e:
        cli.build_parser().parse_args(["track", "seq", "--out", "o", "--preset", "nope"])
    assert e.value.code == 2


def test_command_line_beats_config_file_beats_preset(tmp_path):
    cfg = tmp_path / "run.toml"
    cfg.write_text('preset = "li-kulic"\nparticles = 300\nseed = 5\nout = "o"\n', encoding="utf-8")
    parse = cli.build_parser().parse_args
    o = run_options(cli._track_values(parse(["track", "seq", "--config", str(cfg)])))
    assert (o.preset, o.particles, o.seed, o.filter, o.layers) == ("li-kulic", 300, 5, "partitioned", 1)
    o = run_options(cli._track_values(parse(["track", "seq", "--config", str(cfg), "--particles", "80"])))
    assert (o.particles, o.seed) == (80, 5)
    o = run_options(cli._track_values(parse(["track", "seq", "--out", "o", "--preset", "li-kulic"])))
    assert o.particles == LI_KULIC_COUNTS
    o = run_options(
        cli._track_values(parse(["track", "seq", "--out", "o", "--preset", "li-kulic", "--cues", "depth"]))
    )
    assert (o.cues, o.particles) == ("depth", LI_KULIC_COUNTS)


def test_preset_is_part_of_a_runs_identity_only_when_set():
    assert "preset" not in TrackOptions().identity()  # runs written before presets resume unchanged
    assert TrackOptions.from_preset("li-kulic").identity()["preset"] == "li-kulic"


def test_li_kulic_partitions_on_the_body_models():
    m = body.build("full25", None, in_metres=True)
    groups, parts = presets.partition_layout(presets.LI_KULIC, m, "partitioned")
    assert [len(g) for g in groups] == [6, 3, 3, 3, 1, 1, 3, 3, 1, 1]
    assert [p.particles for p in presets.LI_KULIC.partitions] == LI_KULIC_COUNTS
    assert parts[-1] == ("right_shin",)
    assert presets.partition_layout(presets.LI_KULIC, m, "apf") == (None, None)  # unpartitioned filter
    assert partition_counts(m, "partitioned", 50, groups) == (50,) * 10
    with pytest.raises(ValueError, match="has 10 partitions"):
        partition_counts(m, "partitioned", [1000, 200, 350, 350, 350, 350], groups)
    with pytest.raises(ValueError, match="upper14 has no left_thigh"):
        presets.partition_layout(presets.LI_KULIC, body.build("upper14", None, in_metres=True), "partitioned")
