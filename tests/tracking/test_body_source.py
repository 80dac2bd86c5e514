"""Which body dimensions a run tracks with: ``--body detections`` measures the subject from the input's 2D
detections even where the input carries a body file of its own; without it, the body file is kept."""

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
        "demo", out, rig="ring4", frames="0:24", fps=10.0, size="160x120", seed=0, overwrite=True
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
