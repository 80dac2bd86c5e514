"""Videos given in another order than the calibration's cameras are refused before tracking, also without 2D
detections: the centroids of the person's silhouettes (static background) triangulate consistently, in front of the
cameras, only in the calibration's order. Synthetic sequences (a CMU walk rendered by the synthesis wing) written
as videos with their calibration."""

import cv2
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.io import calibration, sources
from jaxmocap.synth import generate as synth
from jaxmocap.tracking.options import TrackOptions
from jaxmocap.tracking.setup import TrackSetup


def _as_videos(seq_dir, out):
    seq = sources.SequenceSource(seq_dir)
    calib = out / "calib.toml"
    calibration.save_calibration(calib, seq.rig)
    paths = []
    for v, name in enumerate(seq.view_names):
        w, h = seq.rig.image_size[v]
        path = out / f"{name}.avi"
        vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), seq.fps, (w, h))
        for t in range(seq.num_frames):
            vw.write(seq.read(t, masks=False, depth=False).images[v])
        vw.release()
        paths.append(path)
    return calib, paths


@pytest.mark.parametrize("rig", ["stereo", "ring4"])
def test_videos_in_another_order_are_refused(rig, tmp_path):
    synth.synthesize(
        "demo", tmp_path / "seq", rig=rig, frames="0:480", fps=5.0, size="96x72", seed=0, overwrite=True
    )
    calib, vids = _as_videos(tmp_path / "seq", tmp_path)
    opts = TrackOptions(model="upper9", cues="foreground,coverage")
    TrackSetup(sources.VideoSource(vids, calib), opts)  # the calibration's order: accepted
    swapped = [vids[1], vids[0], *vids[2:]]
    with pytest.raises(
        MocapInputError, match=r"calib.toml: the silhouettes .*another order .*input 2 → camera"
    ):
        TrackSetup(sources.VideoSource(swapped, calib), opts)
