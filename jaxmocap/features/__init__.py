"""Host-side image features with OpenCV → ``jaxmocap.features.observation.Observation``.

Modules: ``foreground`` (static background, adaptive Gaussian, MOG2, depth; shadow removal), ``edges`` (Canny,
smoothed edge map, distance transform I_DT), ``skin`` (RGB likelihood ratio, HS back-projection; default model),
``face`` (Haar cascade), ``blobs`` (skin blobs, epipolar matching, triangulation), ``stereo`` (rectification, SGBM,
depth), ``colour`` (RGB maps, ROI histograms, Bhattacharyya distance), ``resample`` (down-sampling and the
scaled rig), ``pipeline`` (``FeatureExtractor``: all views of a frame → ``Observation``).
"""

from jaxmocap.features.blobs import (
    Blobs,
    epipolar_distance,
    fundamental_from_rig,
    fundamental_matrix,
    match_blobs,
    skin_blobs,
    stereo_blobs,
    triangulate_pair,
)
from jaxmocap.features.colour import bhattacharyya_distance, rgb_float, roi_histograms
from jaxmocap.features.edges import (
    canny_edges,
    distance_transform,
    edge_map,
    mask_edges,
    masked_canny,
    smooth_edges,
)
from jaxmocap.features.face import FaceDetector
from jaxmocap.features.foreground import (
    DepthBackground,
    GaussianBackground,
    Mog2Background,
    ShadowParams,
    StaticBackground,
    brightness_chromaticity_distortion,
    depth_foreground,
    shadow_mask,
)
from jaxmocap.features.pipeline import FeatureConfig, FeatureExtractor
from jaxmocap.features.resample import downsample, scale_rig
from jaxmocap.features.skin import SkinModel, default_skin_model, train_from_masks, train_skin_model
from jaxmocap.features.stereo import StereoDepth, bad_pixel_rate, disparity_to_depth, sgbm_disparity

__all__ = [
    "Blobs",
    "DepthBackground",
    "FaceDetector",
    "FeatureConfig",
    "FeatureExtractor",
    "GaussianBackground",
    "Mog2Background",
    "ShadowParams",
    "SkinModel",
    "StaticBackground",
    "StereoDepth",
    "bad_pixel_rate",
    "bhattacharyya_distance",
    "brightness_chromaticity_distortion",
    "canny_edges",
    "default_skin_model",
    "depth_foreground",
    "disparity_to_depth",
    "distance_transform",
    "downsample",
    "edge_map",
    "epipolar_distance",
    "fundamental_from_rig",
    "fundamental_matrix",
    "mask_edges",
    "masked_canny",
    "match_blobs",
    "rgb_float",
    "roi_histograms",
    "scale_rig",
    "sgbm_disparity",
    "shadow_mask",
    "skin_blobs",
    "smooth_edges",
    "stereo_blobs",
    "train_from_masks",
    "train_skin_model",
    "triangulate_pair",
]
