"""BlazePose's 2D keypoints in one view: the detector, then the landmark network on the body's region, every frame.

BlazePose GHUM (full) (Bazarevsky et al. 2020; Grishchenko et al. 2022): the two TensorFlow Lite networks that ship
in mediapipe 0.10.14's wheel (``pose_detection.tflite``, ``pose_landmark_full.tflite``; ``python -m
mocapflow.systems.uuo.blazepose DIR`` fetches them), run by LiteRT (``ai-edge-litert``, the ``monocular`` extra)
instead of mediapipe's graph. The graph's steps as functions of arrays:

1. the detector on the frame letterboxed to 224 x 224 (SSD anchors, one box and four key points per anchor);
2. the region of interest from two key points (the hips' centre and a point on the body's circle): a square twice
   their distance wide, enlarged by 1.25, turned so the body stands upright;
3. the landmark network on that region cut out at 256 x 256: 39 landmarks in the crop (x, y, z, visibility and
   presence logits each; 33 of the body, then two that give a tighter region), and a presence flag;
4. with ``refine`` the region is made again from the landmarks' own two alignment points (33, 34) and the landmark
   network run once more on it (mediapipe's tracking step, on the same frame).

Every frame is detected afresh (mediapipe's static-image mode): a view's keypoints do not depend on the frames
before it, so the engine's regions of frames give the same result however they are cut. A keypoint's confidence
is its visibility (the sigmoid of the network's logit) times the frame's presence flag; Pose2Sim weights and
thresholds its triangulation by the 2D detector's likelihood the same way.

The networks and their geometry are the house's (tasks/shared/blazepose.py, which UUO's monocular prior reads the
3D world landmarks of); this system reads the image landmarks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

from mocapflow.tasks.shared.blazepose import (LANDMARK_NAMES, MIRRORED, N_BODY, BlazePose, EstimatorError,
                                              body_region)

__all__ = ["LANDMARK_NAMES", "MIRRORED", "KeypointsConfig", "KeypointDetector", "blazepose_keypoints"]


def as_rgb(image: np.ndarray) -> np.ndarray:
    """A grey (y, x) or colour (y, x, 3) uint8 image as the networks' RGB input: grey repeated in three channels."""
    image = np.asarray(image)
    if image.ndim == 2:
        return np.repeat(image[..., None], 3, axis=-1)
    if image.ndim == 3 and image.shape[-1] == 3:
        return image
    raise EstimatorError(f"an image must be grey (y, x) or RGB (y, x, 3), got shape {image.shape}")


@dataclass(frozen=True)
class KeypointsConfig:
    """BlazePose's two networks (engine-loaded weight files, handed over as bytes) and its thresholds."""

    detector: str = ""  # path of pose_detection.tflite (python -m mocapflow.systems.uuo.blazepose DIR fetches it)
    landmarker: str = ""  # path of pose_landmark_full.tflite
    min_detection: float = 0.5  # the detector's score for a body (mediapipe's default)
    min_presence: float = 0.5  # the landmark network's presence flag below which the view's frame gives nothing
    refine: bool = True  # run the landmark network again on the region its own landmarks give (step 4)

    def __post_init__(self):
        if not (0 < self.min_detection < 1 and 0 < self.min_presence < 1):
            raise ValueError(f"BlazePose thresholds must lie in (0, 1), got min_detection={self.min_detection}, "
                             f"min_presence={self.min_presence}")


class KeypointDetector:
    """BlazePose's detector and landmark network on single images: 33 image landmarks and their confidence."""

    def __init__(self, detector: bytes | None, landmarker: bytes | None, config: KeypointsConfig = KeypointsConfig()):
        self.estimator = BlazePose(detector, landmarker, config.min_detection, config.min_presence)
        self.config = config

    def keypoints(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """One image's 33 body landmarks (33, 2) pixels (NaN where no body), their confidence (33,) (visibility
        times presence; 0 where no body) and the presence flag (0 without a detection)."""
        image = as_rgb(image)
        none = np.full((N_BODY, 2), np.nan), np.zeros(N_BODY), 0.0
        region = self.estimator.detect(image)
        if region is None:
            return none
        xy, visibility, _, presence = self.estimator.landmarks(image, region)
        if self.config.refine and presence >= self.config.min_presence:
            xy, visibility, _, presence = self.estimator.landmarks(image, body_region(xy[33], xy[34]))
        if presence < self.config.min_presence:
            return none[0], none[1], presence
        return xy[:N_BODY], visibility[:N_BODY] * presence, presence


# ---- the stage ----------------------------------------------------------------------------------------------

def blazepose_keypoints(images: xr.Dataset, config: KeypointsConfig, detector: bytes | None = None,
                        landmarker: bytes | None = None) -> xr.Dataset:
    """Stage ``keypoints``: BlazePose's 33 image landmarks in every view and frame of multi-view images (``image``
    (view, frame, y, x) grey or (view, frame, y, x, rgb) colour), in the images' own (distorted) pixels."""
    estimator = KeypointDetector(detector, landmarker, config)
    image = images["image"]
    order = ("view", "frame", "y", "x") + (("rgb",) if "rgb" in image.dims else ())
    pixels = image.transpose(*order).values
    views, frames = images["view"].values, images["frame"].values
    xy = np.full((len(views), len(frames), N_BODY, 2), np.nan, np.float32)
    confidence = np.zeros((len(views), len(frames), N_BODY), np.float32)
    presence = np.zeros((len(views), len(frames)), np.float32)
    for v in range(len(views)):
        for f in range(len(frames)):
            xy[v, f], confidence[v, f], presence[v, f] = estimator.keypoints(pixels[v, f])
    dims = ("view", "frame", "landmark")
    return xr.Dataset({"x": (dims, xy[..., 0]), "y": (dims, xy[..., 1]), "confidence": (dims, confidence),
                       "presence": (("view", "frame"), presence)},
                      coords={"view": views, "frame": frames, "landmark": np.array(LANDMARK_NAMES, dtype=object)},
                      attrs={"estimator": "BlazePose GHUM full (mediapipe 0.10.14 models, LiteRT), static images"})
