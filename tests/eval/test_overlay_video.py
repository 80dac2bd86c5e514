"""Overlay videos: H.264 in MP4 (the codec browsers play), checked by decoding them with PyAV; the montage PNG."""

import av
import cv2
import numpy as np
import pytest

from jaxmocap.eval import viz


def _frames(n, w, h):
    """Smooth colour ramps that move from frame to frame (compressible, so the decoded frames stay close)."""
    y, x = np.mgrid[0:h, 0:w]
    return [
        np.stack(
            [(x * 2 + 8 * k) % 256, (y * 3 + 5 * k) % 256, np.full_like(x, 40 * (k % 5))], axis=-1
        ).astype(np.uint8)
        for k in range(n)
    ]


def test_h264_mp4_per_view_and_montage(tmp_path):
    views = {"left": (64, 48), "right": (63, 47)}  # an odd size is padded to even (yuv420p)
    frames = {v: _frames(20, *size) for v, size in views.items()}
    with viz.OverlayVideo(tmp_path, list(views), list(views.values()), 30000 / 1001, montage=4) as video:
        for k in range(20):
            video.write([frames["left"][k], frames["right"][k]], frame=100 + k)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "overlay_left.mp4",
        "overlay_montage.png",
        "overlay_right.mp4",
    ]  # no temporary file left
    for v, (w, h) in views.items():
        with av.open(str(tmp_path / f"overlay_{v}.mp4")) as c:
            st = c.streams.video[0]
            assert c.format.name.split(",")[0] == "mov"
            assert st.codec_context.name == "h264" and st.codec_context.pix_fmt == "yuv420p"
            assert (st.width, st.height) == (w + w % 2, h + h % 2)
            assert st.average_rate == pytest.approx(30000 / 1001)
            decoded = [f.to_ndarray(format="bgr24") for f in c.decode(video=0)]
        assert len(decoded) == 20
        err = np.abs(decoded[7][:h, :w].astype(float) - frames[v][7].astype(float)).mean()
        assert err < 6.0  # lossy, but the same picture
    montage = cv2.imread(str(tmp_path / "overlay_montage.png"))
    # 2 views x 4 frames, each 240 px high (the whole image, without a rig to crop around the person)
    assert montage.shape[0] == 2 * 240 and montage.shape[1] >= 4 * 300


def test_an_exception_leaves_no_video(tmp_path):
    with pytest.raises(RuntimeError), viz.OverlayVideo(tmp_path, ["a"], [(32, 32)], 25.0) as video:
        video.write(_frames(1, 32, 32))
        raise RuntimeError
    assert list(tmp_path.iterdir()) == []
