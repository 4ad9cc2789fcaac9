"""A real monocular 3D pose estimate as UUO's prior: BlazePose GHUM (full) on a take's video, Anny fitted to it.

The paper runs HMR 2.0 on the take's video and starts UUO from its body (Milef et al. 2024, §3.1). Here the
estimator is BlazePose GHUM 3D (Bazarevsky et al. 2020; Grishchenko et al. 2022), the two TensorFlow Lite
networks that ship in the mediapipe wheel (``pose_detection.tflite``, ``pose_landmark_full.tflite``), run by the
LiteRT interpreter (``ai-edge-litert``, the ``monocular`` extra) instead of mediapipe's graph, whose own
dependencies clash with OpenCV's headless build. The graph's steps are rebuilt as functions of arrays:

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

from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.uuo.prior import FilePriorConfig, PriorError, joints_prior

DETECTOR_SIZE = 224
LANDMARK_SIZE = 256
N_LANDMARKS = 39  # 33 of the body, then 33 (hips' centre) and 34 (the body circle's point) for tracking
_STRIDES = (8, 16, 32, 32, 32)  # the detector's SSD layers; each gives two anchors per cell

# BlazePose's landmarks (the person's own left and right).
NOSE, LEFT_EAR, RIGHT_EAR = 0, 7, 8
LEFT_SHOULDER, RIGHT_SHOULDER, LEFT_ELBOW, RIGHT_ELBOW, LEFT_WRIST, RIGHT_WRIST = 11, 12, 13, 14, 15, 16
LEFT_PINKY, RIGHT_PINKY, LEFT_INDEX, RIGHT_INDEX = 17, 18, 19, 20
LEFT_HIP, RIGHT_HIP, LEFT_KNEE, RIGHT_KNEE, LEFT_ANKLE, RIGHT_ANKLE = 23, 24, 25, 26, 27, 28
LEFT_HEEL, RIGHT_HEEL, LEFT_FOOT_INDEX, RIGHT_FOOT_INDEX = 29, 30, 31, 32

# Where the template's neck joint lies on the line from the hips' centre through the shoulders' (the upper arms'
# heads): 1.21 of the way, measured on Anny's default adult at rest (mesh_body(Phenotype())), whose SpineBase
# is its Hips and whose Head is at the ears' height.
NECK_FRACTION = 1.21
TOES_FRACTION = 0.7  # the toes' base between the heel and the foot's tip


class EstimatorError(RuntimeError):
    """The monocular estimator cannot run (its runtime or model missing or broken)."""


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


# ---- the networks' geometry (kernels) ------------------------------------------------------------------------

def ssd_anchors() -> np.ndarray:
    """Centres (x, y) in [0, 1] of the detector's 2,254 anchors, in its output order (fixed size 1).  -> (2254, 2)"""
    out, layer = [], 0
    while layer < len(_STRIDES):
        stride, per_cell = _STRIDES[layer], 0
        while layer < len(_STRIDES) and _STRIDES[layer] == stride:  # layers of one stride share the grid
            per_cell, layer = per_cell + 2, layer + 1
        cells = int(np.ceil(DETECTOR_SIZE / stride))
        yy, xx = np.mgrid[0:cells, 0:cells]
        centres = np.stack([(xx + 0.5) / cells, (yy + 0.5) / cells], axis=-1).reshape(-1, 1, 2)
        out.append(np.repeat(centres, per_cell, axis=1).reshape(-1, 2))
    return np.concatenate(out)


_ANCHORS = ssd_anchors()


def letterbox(image: np.ndarray, size: int) -> tuple[np.ndarray, float, np.ndarray]:
    """``image`` (y, x, 3) uint8 padded to a square and resized to ``size``: (float32 in [-1, 1], the square's side
    in pixels, its offset (x, y) in the image)."""
    import cv2

    h, w = image.shape[:2]
    side = max(h, w)
    square = np.zeros((side, side, 3), np.uint8)
    oy, ox = (side - h) // 2, (side - w) // 2
    square[oy:oy + h, ox:ox + w] = image
    small = cv2.resize(square, (size, size), interpolation=cv2.INTER_AREA)
    return small.astype(np.float32) / 127.5 - 1.0, float(side), np.array([ox, oy], float)


def decode_detection(boxes: np.ndarray, logits: np.ndarray, side: float, offset: np.ndarray,
                     min_score: float) -> np.ndarray | None:
    """The best-scored body's four key points in image pixels, or None below ``min_score``.

    boxes (2254, 12): per anchor the box (x, y, w, h) then four key points (x, y), in detector pixels relative to
    the anchor's centre; logits (2254,).  -> (4, 2)"""
    scores = 1.0 / (1.0 + np.exp(-np.clip(logits, -80.0, 80.0)))
    best = int(np.argmax(scores))
    if scores[best] < min_score:
        return None
    points = boxes[best, 4:12].reshape(4, 2) / DETECTOR_SIZE + _ANCHORS[best]  # in [0, 1] of the square
    return points * side - offset


@dataclass(frozen=True)
class Region:
    """A square region of the image: centre (x, y) pixels, side in pixels, rotation (radians, image plane)."""

    centre: np.ndarray
    side: float
    rotation: float

    @property
    def turn(self) -> np.ndarray:
        c, s = np.cos(self.rotation), np.sin(self.rotation)
        return np.array([[c, -s], [s, c]])

    def to_image(self, crop_xy: np.ndarray, crop_size: int) -> np.ndarray:
        """Crop pixels (n, 2) -> image pixels (n, 2)."""
        return (crop_xy / crop_size - 0.5) * self.side @ self.turn.T + self.centre

    def crop_transform(self, crop_size: int) -> np.ndarray:
        """The 2 x 3 affine map from crop pixels to image pixels (cv2.warpAffine with WARP_INVERSE_MAP)."""
        out = np.zeros((2, 3))
        out[:, :2] = self.turn * self.side / crop_size
        out[:, 2] = self.centre - self.turn @ np.array([0.5, 0.5]) * self.side
        return out


def body_region(centre: np.ndarray, circle: np.ndarray, scale: float = 1.25) -> Region:
    """The region around a body from its hips' centre and a point on its circle (mediapipe's alignment points,
    target angle 90 degrees, then enlarged by ``scale``)."""
    d = np.asarray(circle, float) - np.asarray(centre, float)
    rotation = np.pi / 2 - np.arctan2(-d[1], d[0])
    return Region(np.asarray(centre, float), 2.0 * float(np.hypot(*d)) * scale, float(rotation))


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


# BlazePose's 33 body landmarks with the sides swapped (the nose stays): a mirrored image's landmarks read back.
MIRRORED_LANDMARKS = np.array([0, 4, 5, 6, 1, 2, 3, 8, 7, 10, 9, 12, 11, 14, 13, 16, 15, 18, 17, 20, 19, 22, 21, 24, 23,
                               26, 25, 28, 27, 30, 29, 32, 31])


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

def _interpreter(model: bytes, what: str):
    try:
        from ai_edge_litert.interpreter import Interpreter
    except ImportError as exc:
        raise EstimatorError("the monocular prior runs BlazePose's .tflite networks with LiteRT, which is not "
                             "installed; pip install 'mocapflow[monocular]' (the ai-edge-litert package)") from exc
    if not isinstance(model, (bytes, bytearray)) or not model:
        raise EstimatorError(f"the {what} network is missing: give the stage's {what} parameter the path of its "
                             ".tflite file (python -m mocapflow.systems.uuo.blazepose DIR fetches both)")
    try:
        interp = Interpreter(model_content=bytes(model), num_threads=1)
        interp.allocate_tensors()
    except (ValueError, RuntimeError) as exc:
        raise EstimatorError(f"the {what} network's file is not a TensorFlow Lite model LiteRT can run: {exc}") from exc
    return interp


class BlazePose:
    """BlazePose GHUM 3D (full): detection, region tracking and landmarks, one frame after another."""

    def __init__(self, detector: bytes, landmarker: bytes, min_detection: float = 0.5, min_presence: float = 0.5):
        self._det = _interpreter(detector, "detector")
        self._lmk = _interpreter(landmarker, "landmarker")
        self.min_detection, self.min_presence = min_detection, min_presence
        det_in, det_out = self._det.get_input_details(), self._det.get_output_details()
        lmk_in = self._lmk.get_input_details()
        lmk_out = {d["name"]: d for d in self._lmk.get_output_details()}
        if (tuple(det_in[0]["shape"]) != (1, DETECTOR_SIZE, DETECTOR_SIZE, 3)
                or tuple(lmk_in[0]["shape"]) != (1, LANDMARK_SIZE, LANDMARK_SIZE, 3)
                or not {"Identity", "Identity_1", "Identity_4"} <= set(lmk_out)):
            raise EstimatorError("the networks are not BlazePose's pose_detection and pose_landmark_full (inputs "
                                 f"{det_in[0]['shape'].tolist()} and {lmk_in[0]['shape'].tolist()}); fetch them with "
                                 "python -m mocapflow.systems.uuo.blazepose DIR")
        self._det_io = (det_in[0]["index"], det_out[0]["index"], det_out[1]["index"])
        self._lmk_io = (lmk_in[0]["index"], lmk_out["Identity"]["index"], lmk_out["Identity_1"]["index"],
                        lmk_out["Identity_4"]["index"])

    def detect(self, image: np.ndarray) -> Region | None:
        """The region of the best body the detector finds, or None."""
        square, side, offset = letterbox(image, DETECTOR_SIZE)
        inp, boxes, logits = self._det_io
        self._det.set_tensor(inp, square[None])
        self._det.invoke()
        points = decode_detection(self._det.get_tensor(boxes)[0], self._det.get_tensor(logits)[0, :, 0], side, offset,
                                  self.min_detection)
        return None if points is None else body_region(points[0], points[1])

    def landmarks(self, image: np.ndarray, region: Region) -> tuple[np.ndarray, np.ndarray, float]:
        """(image landmarks (39, 2) pixels, world landmarks (39, 3) metres in image axes, presence flag)."""
        import cv2

        crop = cv2.warpAffine(image, region.crop_transform(LANDMARK_SIZE), (LANDMARK_SIZE, LANDMARK_SIZE),
                              flags=cv2.WARP_INVERSE_MAP | cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        inp, screen, flag, world = self._lmk_io
        self._lmk.set_tensor(inp, (crop.astype(np.float32) / 255.0)[None])
        self._lmk.invoke()
        xy = region.to_image(self._lmk.get_tensor(screen)[0].reshape(N_LANDMARKS, 5)[:, :2], LANDMARK_SIZE)
        w = self._lmk.get_tensor(world)[0].reshape(N_LANDMARKS, 3)
        w = np.column_stack([w[:, :2] @ region.turn.T, w[:, 2]])  # the crop's axes back to the image's
        return xy, w, float(self._lmk.get_tensor(flag)[0, 0])

    def track(self, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World landmarks per frame, Z up (frame, 33, 3), NaN where no body was found; and the presence (frame,)."""
        out = np.full((len(frames), 33, 3), np.nan)
        presence = np.zeros(len(frames))
        region = None
        for k, image in enumerate(frames):
            region = region or self.detect(image)
            if region is None:
                continue
            xy, world, presence[k] = self.landmarks(image, region)
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
