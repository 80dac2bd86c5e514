"""The features of a frame are the same bytes whatever ran before in the process (JAX's compilations and buffers
move where ``malloc`` puts OpenCV's output arrays), with one OpenCV thread or several; the distance transform is
the correctly rounded exact distance (SciPy's ``distance_transform_edt`` is the reference)."""

import pathlib

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage

from jaxmocap.features.edges import distance_transform, masked_canny
from jaxmocap.features.pipeline import FeatureConfig, FeatureExtractor
from jaxmocap.geometry.camera import Rig

DATA = pathlib.Path(__file__).parents[1] / "data" / "features"
FRAME = DATA / "cam04_frame0055_quarter.png"  # a real frame of the Pose2Sim demo, 272x480


def _rig(w, h):
    K = np.array([[[1.2 * w, 0, (w - 1) / 2], [0, 1.2 * w, (h - 1) / 2], [0, 0, 1]]])
    return Rig(
        K=K, dist=np.zeros((1, 5)), R=np.eye(3)[None], t=np.zeros((1, 3)), names=("c",), image_size=((w, h),)
    )


def _maps(extractor, image):
    obs = extractor([image])
    return {k: np.asarray(v).tobytes() for k, v in obs._asdict().items() if v is not None}


@jax.jit
def _work(x, key):
    return jnp.sum(jnp.sin(x[None] * jax.random.uniform(key, (16, 1, 1, 1))))


def _jax_work(image, seed=0):
    """A jitted computation on the frame with large temporary buffers (as a filter step has)."""
    return float(_work(jnp.asarray(image, jnp.float32), jax.random.key(seed)))


@pytest.fixture(scope="module")
def frames():
    img = cv2.imread(str(FRAME))
    assert img is not None
    # the whole frame (130 560 pixels) and a crop of 110 x 140 (under 2^14 pixels: OpenCV hands the precise
    # distance transform to IPP whatever its thread count)
    return [img, np.ascontiguousarray(img[200:340, 80:190])]


@pytest.fixture(params=[1, None], ids=["one-opencv-thread", "opencv-default-threads"])
def opencv_threads(request):
    before = cv2.getNumThreads()
    if request.param is not None:
        cv2.setNumThreads(request.param)
    yield
    cv2.setNumThreads(before)


@pytest.mark.usefixtures("opencv_threads")
def test_features_before_and_after_jax_work_are_the_same_bytes(frames):
    for img in frames:
        h, w = img.shape[:2]
        cfg = FeatureConfig(foreground="none", edges=True, edge_dt=True, skin="rgb", rgb=True)
        extractor = FeatureExtractor(_rig(w, h), cfg)
        ref = _maps(extractor, img)
        assert _jax_work(img) != 0.0
        held = []
        for k in range(8):  # other allocations move the output arrays to other addresses modulo 64
            held.append(np.empty(16 * k + 8, np.uint8))
            held.append(np.empty(4096 * (k + 1) + 16 * k, np.uint8))
            got = _maps(extractor, img)
            for name in ref:
                assert got[name] == ref[name], f"{name} of a {w}x{h} frame changed after other work ({k})"
            _jax_work(img, k)


@pytest.mark.usefixtures("opencv_threads")
def test_distance_transform_is_the_correctly_rounded_exact_distance(frames):
    for img in frames:
        edges = masked_canny(img, None)
        ref = ndimage.distance_transform_edt(edges == 0).astype(np.float32)  # float64 sqrt, rounded once
        np.testing.assert_array_equal(distance_transform(edges), ref)
        np.testing.assert_array_equal(distance_transform(edges, truncate=50.0), np.minimum(ref, 50.0))
