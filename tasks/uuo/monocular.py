"""A real monocular 3D pose estimate as UUO's prior: BlazePose GHUM (full) on a take's video, Anny fitted to it.

The paper runs HMR 2.0 on the take's video and starts UUO from its body (Milef et al. 2024, §3.1). Here the
estimator is BlazePose GHUM 3D (Bazarevsky et al. 2020; Grishchenko et al. 2022), the two TensorFlow Lite
networks that ship in the mediapipe wheel (``pose_detection.tflite``, ``pose_landmark_full.tflite``), run by the
LiteRT interpreter (``ai-edge-litert``, the ``monocular`` extra) instead of mediapipe's graph, whose own
dependencies clash with OpenCV's headless build. The graph's steps are rebuilt as functions of arrays (tasks/shared/blazepose.py):

1. the detector on the frame letterboxed to 224 x 224 (SSD anchors, one box and four key points per anchor);
2. the region of interest from two key points (the hips' centre and a point on the body's circle): a square
   twice their distance wide, enlarged by 1.25, turned so the body stands upright;
3. the landmark network on that region cut out at 256 x 256: 39 landmarks in the crop (33 of the body, two
   that give the next frame's region), their visibility, a presence flag, and the 39 world landmarks (metres,
   hips-centred, the crop's axes);
4. the next frame's region from its landmarks 33 and 34 (tracking), the detector again when the flag drops.

The world landmarks are turned back by the region's rotation (image axes: x right, y down, z away from the
camera), then onto Z up, and the template's 20 joints are read off them (``template_joints``). ``monocular_prior``
fits Anny to those joints as a prior file is fitted (tasks/uuo/prior.py). The estimate knows nothing of the
studio's truth: it sees the video's pixels only.

A second and third estimate of one take, for combining three (tasks/uuo/combine.py), come from the estimator's
input perturbed (``shift_px``, ``scale``, ``flip`` of MonocularPriorConfig; ``perturb_frames``): the networks
are deterministic, so a rerun on the same pixels repeats itself exactly, while a moved, zoomed or mirrored video
changes the detector's box and the landmark network's crop, and so the estimate (test-time augmentation). Such
estimates share the networks' biases: their errors are correlated, unlike independent simulated draws.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import xarray as xr

from mocapflow.tasks.shared import blazepose
from mocapflow.tasks.shared.blazepose import (LEFT_ANKLE, LEFT_EAR, LEFT_ELBOW, LEFT_FOOT_INDEX, LEFT_HEEL, LEFT_HIP,
                                              LEFT_INDEX, LEFT_KNEE, LEFT_PINKY, LEFT_SHOULDER, LEFT_WRIST, MIRRORED,
                                              RIGHT_ANKLE, RIGHT_EAR, RIGHT_ELBOW, RIGHT_FOOT_INDEX, RIGHT_HEEL,
                                              RIGHT_HIP, RIGHT_INDEX, RIGHT_KNEE, RIGHT_PINKY, RIGHT_SHOULDER,
                                              RIGHT_WRIST, body_region)
from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.uuo.prior import FilePriorConfig, PriorError, joints_prior

# Where the template's neck joint lies on the line from the hips' centre through the shoulders' (the upper arms'
# heads): 1.21 of the way, measured on Anny's default adult at rest (mesh_body(Phenotype())), whose SpineBase
# is its Hips and whose Head is at the ears' height.
NECK_FRACTION = 1.21
TOES_FRACTION = 0.7  # the toes' base between the heel and the foot's tip


@dataclass(frozen=True)
class MonocularPriorConfig:
    """The estimator's networks (BlazePose's two .tflite files, engine-loaded weight files) and the Anny fit."""

    detector: str = ""  # path of pose_detection.tflite (python -m mocapflow.systems.uuo.blazepose fetches it)
    landmarker: str = ""  # path of pose_landmark_full.tflite
    min_detection: float = 0.5  # the detector's score for a body (mediapipe's default)
    min_presence: float = 0.5  # the landmark network's presence flag below which the frame is lost
    fit: FilePriorConfig = field(default_factory=FilePriorConfig)
    # The estimator's input perturbed, for a second and third estimate of one take (tasks/uuo/combine.py): every
    # frame moved by shift_px (x right, y down, pixels) and zoomed by scale about its centre (the edge pixels
    # repeated), and with flip mirrored left-right, the landmarks mirrored back and their sides swapped. The
    # default perturbs nothing.
    shift_px: tuple[float, float] = (0.0, 0.0)
    scale: float = 1.0
    flip: bool = False

    def __post_init__(self):
        if not (0 < self.min_detection < 1 and 0 < self.min_presence < 1):
            raise PriorError(f"monocular prior thresholds must lie in (0, 1), got min_detection={self.min_detection}, "
                             f"min_presence={self.min_presence}")
        if len(self.shift_px) != 2 or not np.isfinite(self.shift_px).all() or not 0.5 <= self.scale <= 2.0:
            raise PriorError(f"monocular prior perturbation out of range: shift_px two finite pixel offsets (x, y) "
                             f"(got {self.shift_px}), scale in [0.5, 2] (got {self.scale}); (0, 0) and 1 perturb "
                             "nothing")


def to_z_up(world: np.ndarray) -> np.ndarray:
    """BlazePose world landmarks (x right, y down, z away from the camera) onto a right-handed Z-up frame:
    (x, y, z) -> (x, z, -y).  (..., 3) -> (..., 3)"""
    return np.stack([world[..., 0], world[..., 2], -world[..., 1]], axis=-1)


def template_joints(landmarks: np.ndarray) -> np.ndarray:
    """The template's 20 joints (JOINT_NAMES) read off BlazePose's 33 body landmarks.  (..., 33+, 3) -> (..., 20, 3)

    Shoulders, elbows, wrists, hips, knees and ankles are BlazePose's own; a hand is its index and little
    finger's knuckles' middle (the middle finger's base); a foot the toes' base between heel and tip; the trunk's
    joints lie on the line through the hips' and the shoulders' centres (NECK_FRACTION), the head's at the ears'."""
    lm = landmarks
    hips = (lm[..., LEFT_HIP, :] + lm[..., RIGHT_HIP, :]) / 2
    shoulders = (lm[..., LEFT_SHOULDER, :] + lm[..., RIGHT_SHOULDER, :]) / 2
    ears = (lm[..., LEFT_EAR, :] + lm[..., RIGHT_EAR, :]) / 2

    def foot(heel: int, tip: int) -> np.ndarray:
        return lm[..., heel, :] + TOES_FRACTION * (lm[..., tip, :] - lm[..., heel, :])

    named = {
        "Hips": hips, "SpineBase": hips, "Neck": hips + NECK_FRACTION * (shoulders - hips), "Head": ears,
        "LeftShoulder": lm[..., LEFT_SHOULDER, :], "LeftElbow": lm[..., LEFT_ELBOW, :],
        "LeftWrist": lm[..., LEFT_WRIST, :], "LeftHand": (lm[..., LEFT_INDEX, :] + lm[..., LEFT_PINKY, :]) / 2,
        "RightShoulder": lm[..., RIGHT_SHOULDER, :], "RightElbow": lm[..., RIGHT_ELBOW, :],
        "RightWrist": lm[..., RIGHT_WRIST, :], "RightHand": (lm[..., RIGHT_INDEX, :] + lm[..., RIGHT_PINKY, :]) / 2,
        "LeftHip": lm[..., LEFT_HIP, :], "LeftKnee": lm[..., LEFT_KNEE, :], "LeftAnkle": lm[..., LEFT_ANKLE, :],
        "LeftFoot": foot(LEFT_HEEL, LEFT_FOOT_INDEX),
        "RightHip": lm[..., RIGHT_HIP, :], "RightKnee": lm[..., RIGHT_KNEE, :], "RightAnkle": lm[..., RIGHT_ANKLE, :],
        "RightFoot": foot(RIGHT_HEEL, RIGHT_FOOT_INDEX),
    }
    return np.stack([named[name] for name in JOINT_NAMES], axis=-2)


MIRRORED_LANDMARKS = MIRRORED  # BlazePose's 33 landmarks with the sides swapped (the nose stays)


def perturb_frames(frames: np.ndarray, shift_px: tuple[float, float] = (0.0, 0.0), scale: float = 1.0,
                   flip: bool = False) -> np.ndarray:
    """Video frames (frame, y, x, 3) uint8 zoomed by ``scale`` about each frame's centre, moved by ``shift_px``
    (x, y) pixels (the edge pixels repeated into what comes into view) and, with ``flip``, mirrored left-right.
    Nothing asked, the frames themselves."""
    import cv2

    if tuple(shift_px) == (0.0, 0.0) and scale == 1.0 and not flip:
        return frames
    h, w = frames.shape[1:3]
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    warp = np.zeros((2, 3))
    warp[:, :2] = np.eye(2) * scale
    warp[:, 2] = centre - scale * centre + np.asarray(shift_px, float)
    if flip:  # x -> (w - 1) - x after the zoom and shift
        warp = np.array([[-1.0, 0.0, w - 1.0], [0.0, 1.0, 0.0]]) @ np.vstack([warp, [0.0, 0.0, 1.0]])
    moved = [cv2.warpAffine(image, warp, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
             for image in frames]
    return np.stack(moved) if moved else frames


def unmirror_landmarks(landmarks: np.ndarray) -> np.ndarray:
    """World landmarks (..., 33, 3) Z up estimated on a left-right mirrored image, back to the real body: x negated
    (image right is world x, to_z_up) and the sides swapped.  -> (..., 33, 3)"""
    out = landmarks[..., MIRRORED_LANDMARKS, :].copy()
    out[..., 0] *= -1.0
    return out


# ---- the estimator (the two networks run by LiteRT) ----------------------------------------------------------

class BlazePose(blazepose.BlazePose):
    """BlazePose GHUM 3D (full), one frame after another: the region tracked from each frame's landmarks."""

    def track(self, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World landmarks per frame, Z up (frame, 33, 3), NaN where no body was found; and the presence (frame,)."""
        out = np.full((len(frames), 33, 3), np.nan)
        presence = np.zeros(len(frames))
        region = None
        for k, image in enumerate(frames):
            region = region or self.detect(image)
            if region is None:
                continue
            xy, _, world, presence[k] = self.landmarks(image, region)
            if presence[k] < self.min_presence:
                region = None  # lost: the detector looks again on the next frame
                continue
            out[k] = to_z_up(world[:33])
            region = body_region(xy[33], xy[34])
        return out, presence


# ---- the stage ----------------------------------------------------------------------------------------------

def monocular_prior(markers: xr.Dataset, config: MonocularPriorConfig, detector: bytes | None = None,
                    landmarker: bytes | None = None) -> xr.Dataset:
    """Stage ``prior`` (monocular): BlazePose on the take's video (``video`` of the markers: (frame, y, x, rgb)),
    its world landmarks read as the template's joints, Anny fitted to them; frames without a body are lost."""
    if "video" not in markers:
        raise PriorError("a monocular prior needs the take's video and these markers have none; film it (the "
                         "studio_markers dataset's 'video' option) or bring an estimate as a prior file (file_prior)")
    estimator = BlazePose(detector, landmarker, config.min_detection, config.min_presence)
    frames = perturb_frames(markers["video"].transpose("frame", "y", "x", "rgb").values, config.shift_px,
                            config.scale, config.flip)
    landmarks, presence = estimator.track(frames)
    if config.flip:
        landmarks = unmirror_landmarks(landmarks)
    joints = template_joints(landmarks)
    found = np.isfinite(joints).all(axis=(1, 2))
    if not found.any():
        raise PriorError(f"BlazePose found no body in any of the video's {len(frames)} frames; check the video "
                         "(a person in view, lit) or use prior: simulated or none")
    out = joints_prior(markers["frame"].values, joints, float(markers.attrs.get("fps", 0.0)), config.fit, "monocular")
    return out.assign_attrs(estimator="BlazePose GHUM 3D full (mediapipe 0.10.14 models, LiteRT)",
                            found_frames=int(found.sum()), presence_median=float(np.median(presence[found])),
                            input_perturbed={"shift_px": [float(v) for v in config.shift_px],
                                             "scale": float(config.scale), "flip": bool(config.flip)})
