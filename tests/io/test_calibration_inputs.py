"""Calibrations as people have them: EasyMocap's intri.yml/extri.yml (written with OpenCV's FileStorage, as
EasyMocap writes them), translations in millimetres, and image sizes that differ from the videos' by codec
padding. Reference: the Pose2Sim demo calibration, and projections by ``cv2.projectPoints``."""

import dataclasses
import pathlib

import cv2
import numpy as np
import pytest

from jaxmocap.errors import MocapInputError
from jaxmocap.io import calibration as C
from jaxmocap.io import sources

P2S = pathlib.Path(__file__).parents[1] / "data" / "calib" / "pose2sim"
CALIB = P2S / "Calib_qualisys_converted_by_pose2sim_a948c20.toml"


@pytest.fixture(scope="module")
def rig():
    return C.load_calibration(CALIB)


def _write_names(fs, names):
    fs.startWriteStruct("names", cv2.FileNode_SEQ)
    for n in names:
        fs.write("", n)
    fs.endWriteStruct()


def _write_easymocap(folder: pathlib.Path, rig, names, rotation_key="both", size=True):
    """intri.yml (names, K_, dist_ 1x5, H_, W_) and extri.yml (names, R_ Rodrigues 3x1, Rot_ 3x3, T_ 3x1 metres),
    with cv2.FileStorage."""
    fs = cv2.FileStorage(str(folder / "intri.yml"), cv2.FILE_STORAGE_WRITE)
    _write_names(fs, names)
    for v, n in enumerate(names):
        fs.write(f"K_{n}", np.asarray(rig.K[v], np.float64))
        fs.write(f"dist_{n}", np.asarray(rig.dist[v], np.float64).reshape(1, 5))
        if size:
            fs.write(f"H_{n}", int(rig.image_size[v][1]))
            fs.write(f"W_{n}", int(rig.image_size[v][0]))
    fs.release()
    fs = cv2.FileStorage(str(folder / "extri.yml"), cv2.FILE_STORAGE_WRITE)
    _write_names(fs, names)
    for v, n in enumerate(names):
        R = np.asarray(rig.R[v], np.float64)
        if rotation_key in ("both", "R"):
            fs.write(f"R_{n}", cv2.Rodrigues(R)[0])
        if rotation_key in ("both", "Rot"):
            fs.write(f"Rot_{n}", R)
        fs.write(f"T_{n}", np.asarray(rig.t[v], np.float64).reshape(3, 1))
    fs.release()


def _opencv_projection(rig, v, X):
    rvec = cv2.Rodrigues(np.asarray(rig.R[v], np.float64))[0]
    uv, _ = cv2.projectPoints(
        X, rvec, np.asarray(rig.t[v], np.float64), np.asarray(rig.K[v]), np.asarray(rig.dist[v])
    )
    return uv.reshape(-1, 2)


@pytest.mark.parametrize("rotation_key", ["both", "R", "Rot"])
def test_easymocap_cameras(rig, tmp_path, rotation_key):
    names = ["01", "02", "03", "04"]
    _write_easymocap(tmp_path, rig, names, rotation_key)
    for given in (tmp_path, tmp_path / "intri.yml", tmp_path / "extri.yml"):
        em = C.load_calibration(given)
        assert em.names == tuple(names) and em.image_size == rig.image_size
        X = np.random.default_rng(0).normal([0.0, 0.0, 1.0], 0.3, (20, 3))
        for v in range(4):
            np.testing.assert_allclose(_opencv_projection(em, v, X), _opencv_projection(rig, v, X), atol=1e-6)


def test_easymocap_without_sizes_or_with_bad_entries(rig, tmp_path):
    _write_easymocap(tmp_path, rig, ["a", "b", "c", "d"], size=False)
    assert C.load_calibration(tmp_path).image_size == ((0, 0),) * 4
    text = (tmp_path / "extri.yml").read_text().replace("T_c:", "Tx_c:")
    (tmp_path / "extri.yml").write_text(text)
    with pytest.raises(MocapInputError, match=r"extri.yml.*missing entry 'T_c'"):
        C.load_calibration(tmp_path)


def test_millimetre_translations_converted(rig):
    """Translations written in millimetres put the demo's cameras kilometres apart: taken as millimetres (a note
    says so), the rig is the metric one; in metres on purpose they stay; in unknown units they are refused."""
    mm = dataclasses.replace(rig, t=np.asarray(rig.t) * 1000.0)
    back, note = C.check_units(mm, "auto", "calib.toml")
    np.testing.assert_allclose(back.t, rig.t, rtol=1e-12)
    assert "millimetres" in note and "divided by 1000" in note
    same, note = C.check_units(rig)
    assert same is rig and note is None
    kept, _ = C.check_units(mm, "m")
    assert kept is mm
    np.testing.assert_allclose(C.check_units(rig, "mm")[0].t, np.asarray(rig.t) / 1000.0)
    with pytest.raises(MocapInputError, match="unknown units"):
        C.check_units(dataclasses.replace(rig, t=np.asarray(rig.t) * 1e6), "auto", "calib.toml")


def test_codec_padding_rule():
    """1080 px wide frames of a camera calibrated at 1088 (H.264 rounds to 16-pixel blocks) are the calibrated
    image cropped; other differences are not."""
    assert sources.codec_cropped((1088, 1920), (1080, 1920))
    assert sources.codec_cropped((1920, 1088), (1920, 1080))
    assert sources.codec_cropped((640, 480), (640, 480))
    assert not sources.codec_cropped((1088, 1920), (1072, 1920))  # 16 px: more than padding
    assert not sources.codec_cropped((1080, 1920), (1088, 1920))  # wider than calibrated
    assert not sources.codec_cropped((1085, 1920), (1080, 1920))  # not a block multiple
    assert not sources.codec_cropped((1280, 720), (640, 360))  # scaled


def _video(path: pathlib.Path, size, frames=3):
    w, h = size
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (w, h))
    for t in range(frames):
        img = np.full((h, w, 3), 40, np.uint8)
        cv2.rectangle(img, (5 + t, 5), (20 + t, 30), (200, 180, 160), -1)
        vw.write(img)
    vw.release()
    return path


def _small_rig(rig, size):
    return dataclasses.replace(rig, image_size=(size,) * rig.num_views)


def test_video_source_accepts_codec_padding_with_a_note(rig, tmp_path):
    calib = tmp_path / "calib.toml"
    C.save_calibration(calib, _small_rig(rig, (64, 48)))
    vids = [_video(tmp_path / f"{k}.avi", (56 if k < 2 else 64, 48)) for k in range(4)]
    src = sources.VideoSource(vids, calib)
    assert src.rig.image_size == ((56, 48), (56, 48), (64, 48), (64, 48))
    assert sum("cropped by the codec's padding" in n for n in src.notes) == 2
    np.testing.assert_array_equal(src.rig.K, C.load_calibration(calib).K)
    assert [im.shape[1] for im in src.read(1).images] == [56, 56, 64, 64]
    src.close()
    C.save_calibration(calib, _small_rig(rig, (80, 48)))
    with pytest.raises(MocapInputError, match="not the calibrated image cropped by codec padding"):
        sources.VideoSource(vids, calib)


def test_video_source_converts_a_millimetre_calibration(rig, tmp_path):
    calib = tmp_path / "calib.toml"
    C.save_calibration(calib, dataclasses.replace(_small_rig(rig, (64, 48)), t=np.asarray(rig.t) * 1000.0))
    vids = [_video(tmp_path / f"{k}.avi", (64, 48)) for k in range(4)]
    src = sources.VideoSource(vids, calib)
    np.testing.assert_allclose(src.rig.t, rig.t, rtol=1e-9)
    assert any("millimetres" in n for n in src.notes)
    src.close()
    src = sources.VideoSource(vids, calib, calibration_units="m")
    assert not src.notes and np.allclose(src.rig.t, np.asarray(rig.t) * 1000.0)
    src.close()


def test_depth_maps_in_other_units_are_refused(rig, tmp_path):
    calib = tmp_path / "calib.toml"
    C.save_calibration(calib, _small_rig(rig, (64, 48)))
    vids = [_video(tmp_path / f"{k}.avi", (64, 48)) for k in range(4)]
    cases = {
        "npy_mm": (".npy", np.full((48, 64), 2500.0, np.float32), "median depth 2500 m.*millimetres"),
        "png_m": (".png", np.full((48, 64), 3, np.uint16), "16-bit depth images are millimetres"),
        "ok": (".png", np.full((48, 64), 2500, np.uint16), None),
    }
    for name, (ext, z, msg) in cases.items():
        dirs = []
        for v in range(4):
            d = tmp_path / name / str(v)
            d.mkdir(parents=True)
            for t in range(3):
                if ext == ".npy":
                    np.save(d / f"{t:04d}.npy", z)
                else:
                    cv2.imwrite(str(d / f"{t:04d}.png"), z)
            dirs.append(d)
        src = sources.VideoSource(vids, calib, depth=dirs)
        if msg is None:
            np.testing.assert_allclose(src.read(0).depth[0], 2.5)
        else:
            with pytest.raises(MocapInputError, match=msg):
                src.read(0)
        src.close()
