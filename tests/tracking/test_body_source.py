"""Which body dimensions a run tracks with: ``--body detections`` measures the subject from the input's 2D
detections even where the input carries a body file of its own; without it, the body file is kept;
``--body calibrate`` fits the lengths and radii to the run's first frames."""

import numpy as np
import pytest

from jaxmocap.io.sources import SequenceSource
from jaxmocap.io.subject import load_subject
from jaxmocap.synth import generate as synth
from jaxmocap.tracking.options import TrackOptions, build_model
from jaxmocap.tracking.setup import TrackSetup


class _WithDetections(SequenceSource):
    """A synthetic sequence with its simulated BODY_25B detections as the input's keypoints (and its body file)."""

    def __init__(self, root):
        super().__init__(root)
        folders = [str(self.root / "views" / n / "openpose") for n in self.view_names]
        sub = load_subject(folders, self.rig, range(self.num_frames), self.fps, total=self.num_frames)
        self.keypoints, self.has_keypoints = sub.keypoints, True


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    out = tmp_path_factory.mktemp("seq")
    synth.synthesize(
        "demo", out, rig="ring4", frames="0:48", fps=10.0, size="160x120", seed=0, overwrite=True
    )
    return _WithDetections(out)


def _lengths(model) -> np.ndarray:
    return np.linalg.norm(np.asarray(model.offset), axis=-1)


def test_detections_replace_the_body_file_and_the_file_is_kept_otherwise(source):
    assert source.body_path is not None
    opts = dict(model="upper9", frames="0:2")
    kept = TrackSetup(source, TrackOptions(**opts))
    measured = TrackSetup(source, TrackOptions(body="detections", **opts))
    from_file = build_model("upper9", source.body_path)
    assert kept.body_dimensions is None
    np.testing.assert_array_equal(_lengths(kept.model), _lengths(from_file))
    assert measured.body_dimensions and any("measured from the triangulated" in n for n in measured.notes)
    np.testing.assert_array_equal(
        _lengths(measured.model), _lengths(build_model("upper9", None, None, measured.body_dimensions))
    )
    assert not np.allclose(_lengths(measured.model), _lengths(from_file))


@pytest.mark.parametrize(("model", "whole"), [("full25", False), ("full32", True)])
def test_track_runs_with_a_calibrated_body(source, tmp_path, model, whole):
    """``body="calibrate"``: a run (``jaxmocap track``'s :class:`~jaxmocap.tracking.tracker.Tracker`) with the
    preset's lengths and radii fitted to the run's first frames
    (:func:`jaxmocap.fit.shape_start.calibrate_from_start`): the model is the preset built with those dimensions,
    with radii moved from the preset's; for the default body and for ``full32`` (spine and shoulder girdles), whose
    run is then tracked whole (every frame, the dimensions recorded in ``run.json``; the default body's tracking
    is that of every other tracker test)."""
    import json

    from jaxmocap.geometry import body
    from jaxmocap.tracking.tracker import Tracker

    opts = TrackOptions(body="calibrate", model=model, frames="0:4", particles=40, layers=2, smooth="none")
    run = Tracker(source, tmp_path, opts, quiet=True)
    setup = run.setup
    dims = setup.body_dimensions
    assert dims and any("calibrated on frames 0–3" in n for n in setup.notes)
    assert setup.model.name == model
    np.testing.assert_allclose(
        _lengths(setup.model), _lengths(build_model(model, None, None, dims)), rtol=1e-6
    )
    moved = [
        k
        for k in ("thigh_radius_top", "torso_radius_top")
        if abs(dims[k] - body.DEFAULT_DIMENSIONS[k]) > 1e-4
    ]
    assert moved, dims
    if not whole:
        return
    run.run()
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["status"] == "complete" and record["frames"] == [0, 4]
    assert record["body_dimensions"]["thigh_radius_top"] == pytest.approx(dims["thigh_radius_top"])
    states = np.load(tmp_path / "poses.npz")["state"]
    assert states.shape[0] == 4 and np.all(np.isfinite(states))
    with pytest.raises(ValueError, match="needs 2D keypoints"):
        TrackSetup(
            SequenceSource(source.root, detections=False), TrackOptions(body="calibrate", frames="0:4")
        )
