"""Skin models: histogram training against numpy.histogramdd, the lookup-table paths against per-pixel
evaluation of the formulas, the shipped default model on a held-out real frame, and the face detector."""

import pathlib

import cv2
import numpy as np
import pytest
from scipy.stats import mannwhitneyu

from jaxmocap.errors import MocapInputError
from jaxmocap.features.face import FaceDetector
from jaxmocap.features.skin import SkinModel, default_skin_model, train_from_masks, train_skin_model
from jaxmocap.features.skin_training import label_frame, read_openpose_json, roc_auc

DATA = pathlib.Path(__file__).parents[1] / "data" / "features"


def _pixels(rng, mean, std, n):
    return np.clip(np.rint(rng.normal(mean, std, (n, 3))), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def toy_model():
    rng = np.random.default_rng(0)
    skin = _pixels(rng, (110, 140, 200), 20, 5000)  # BGR
    non = rng.integers(0, 256, (20000, 3)).astype(np.uint8)
    return skin, non, train_skin_model(skin, non)


def test_training_counts_match_histogramdd(toy_model):
    skin, non, model = toy_model
    edges = [np.arange(0, 257, 32)] * 3
    for pix, counts in ((skin, model.rgb_skin), (non, model.rgb_nonskin)):
        ref, _ = np.histogramdd(pix[:, ::-1].astype(float), bins=edges)  # [R, G, B]
        np.testing.assert_array_equal(counts, ref)
    hsv = cv2.cvtColor(skin.reshape(-1, 1, 3), cv2.COLOR_BGR2HSV).reshape(-1, 3).astype(float)
    ref, _, _ = np.histogram2d(hsv[:, 0], hsv[:, 1], bins=[np.arange(0, 181, 6), np.arange(0, 257, 8)])
    np.testing.assert_array_equal(model.hs_skin, ref)


def test_probability_map_equals_the_posterior_formula(toy_model):
    _, _, model = toy_model
    rng = np.random.default_rng(1)
    img = rng.integers(0, 256, (37, 53, 3)).astype(np.uint8)
    a, B = model.pseudo_count, 512
    r, g, b = (img[..., 2] // 32, img[..., 1] // 32, img[..., 0] // 32)
    ps = (model.rgb_skin[r, g, b] + a) / (model.rgb_skin.sum() + a * B)
    pn = (model.rgb_nonskin[r, g, b] + a) / (model.rgb_nonskin.sum() + a * B)
    L = ps / pn
    np.testing.assert_allclose(model.likelihood_ratio(img), L, rtol=1e-6)
    for prior in (0.5, 0.1):
        p = prior * L / (prior * L + 1 - prior)
        np.testing.assert_array_equal(model.probability_u8(img, prior), np.rint(255 * p).astype(np.uint8))
    assert model.probability(img).dtype == np.float32


def test_hs_backprojection_equals_the_normalised_histogram(toy_model):
    _, _, model = toy_model
    rng = np.random.default_rng(2)
    img = rng.integers(0, 256, (31, 29, 3)).astype(np.uint8)
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV).astype(int)
    ref = model.hs_skin[hsv[..., 0] // 6, hsv[..., 1] // 8] / model.hs_skin.max()
    np.testing.assert_allclose(model.hs_backprojection(img), ref, atol=0.5 / 255 + 1e-6)


def test_separable_colours_are_classified(toy_model):
    skin, non, model = toy_model
    # skin colours far from the non-skin (uniform) density get p > 0.9; the uniform background's mean p is low
    p_skin = model.probability(skin.reshape(-1, 1, 3)).ravel()
    p_non = model.probability(non.reshape(-1, 1, 3)).ravel()
    assert np.median(p_skin) > 0.9 and np.mean(p_non) < 0.5


def test_train_from_masks_and_save_load_roundtrip(tmp_path, toy_model):
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (20, 30, 3)).astype(np.uint8)
    ms = np.zeros((20, 30), np.uint8)
    ms[5:10, 5:10] = 255
    model = train_from_masks([img], [ms], [255 - ms], description="toy")
    assert model.rgb_skin.sum() == 25 and model.rgb_nonskin.sum() == 575
    path = tmp_path / "m.npz"
    model.save(path)
    back = SkinModel.load(path)
    np.testing.assert_array_equal(back.rgb_skin, model.rgb_skin)
    np.testing.assert_array_equal(back.hs_nonskin, model.hs_nonskin)
    assert back.description == "toy" and back.prior == model.prior
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(MocapInputError, match="bad.npz"):
        SkinModel.load(tmp_path / "bad.npz")
    with pytest.raises(MocapInputError, match="not found"):
        SkinModel.load(tmp_path / "missing.npz")
    with pytest.raises(MocapInputError):
        train_skin_model(np.zeros((0, 3), np.uint8), np.zeros((4, 3), np.uint8))


def test_roc_auc_matches_mann_whitney():
    rng = np.random.default_rng(4)
    pos = rng.integers(0, 20, 300)
    neg = rng.integers(0, 15, 500)  # many ties
    u = mannwhitneyu(pos, neg).statistic
    assert roc_auc(pos, neg) == pytest.approx(u / (300 * 500), rel=1e-12)


def test_default_model_on_a_held_out_camera():
    """cam04 was not used for training; labels come from the OpenPose keypoints with the training rule."""
    model = default_skin_model()
    img = cv2.imread(str(DATA / "cam04_frame0055_quarter.png"))
    people = [p * np.array([0.25, 0.25, 1.0]) for p in read_openpose_json(DATA / "cam04.0055.json")]
    skin, non = label_frame(img.shape[:2], people, margin_px=6)
    assert (skin > 0).sum() > 500 and (non > 0).sum() > 50000
    p = model.probability_u8(img)
    b = model.hs_backprojection(img)
    assert roc_auc(p[skin > 0], p[non > 0]) >= 0.93
    assert roc_auc(b[skin > 0], b[non > 0]) >= 0.95
    assert np.mean(p[skin > 0] > 127) >= 0.75 and np.mean(p[non > 0] > 127) <= 0.15


def test_read_openpose_json_errors(tmp_path):
    (tmp_path / "bad.json").write_text('{"people": [\n  {"pose_keypoints_2d": [1, 2]\n')
    with pytest.raises(MocapInputError, match=r"bad\.json:3"):
        read_openpose_json(tmp_path / "bad.json")
    (tmp_path / "odd.json").write_text('{"people": [{"pose_keypoints_2d": [1, 2]}]}')
    with pytest.raises(MocapInputError, match="multiple of 3"):
        read_openpose_json(tmp_path / "odd.json")


def test_face_detector_finds_the_face():
    img = cv2.imread(str(DATA / "face_caliscope_cam3_frame0020_crop.png"))
    faces = FaceDetector().detect(img)
    assert len(faces) == 1
    x, y, w, h = faces[0]
    assert x <= 205 <= x + w and y <= 195 <= y + h  # face centre read off the image by eye
    assert 80 <= w <= 220
    assert len(FaceDetector().detect(np.full((240, 320, 3), 128, np.uint8))) == 0
    # bounds on the boxes searched for: the same box when they hold it, none when the largest is smaller
    assert np.array_equal(FaceDetector().detect(img, (w // 2, w // 2), (2 * w, 2 * w)), faces)
    assert len(FaceDetector().detect(img, max_size=(w // 2, w // 2))) == 0


def test_face_detector_missing_cascade(tmp_path):
    with pytest.raises(MocapInputError, match="not found"):
        FaceDetector(tmp_path / "missing.xml")
    (tmp_path / "broken.xml").write_text("<opencv_storage></opencv_storage>")
    with pytest.raises(MocapInputError, match="could not load"):
        FaceDetector(tmp_path / "broken.xml")
