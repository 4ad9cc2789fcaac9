"""BlazePose GHUM (full) as functions of arrays: the detector, the body's region and the landmark network, shared by
the systems that read a body off images (UUO's monocular prior reads its 3D world landmarks, the markerless peer its
image landmarks).

Bazarevsky et al. 2020; Grishchenko et al. 2022: the two TensorFlow Lite networks that ship in mediapipe 0.10.14's
wheel (``pose_detection.tflite``, ``pose_landmark_full.tflite``; ``python -m mocapflow.systems.uuo.blazepose DIR``
fetches them), run by LiteRT (``ai-edge-litert``, the ``monocular`` extra) instead of mediapipe's graph, whose own
dependencies clash with OpenCV's headless build. The graph's steps:

1. the detector on the frame letterboxed to 224 x 224 (SSD anchors, one box and four key points per anchor);
2. the region of interest from two key points (the hips' centre and a point on the body's circle): a square twice
   their distance wide, enlarged by 1.25, turned so the body stands upright;
3. the landmark network on that region cut out at 256 x 256: 39 landmarks in the crop (x, y, z, visibility and
   presence logits each; 33 of the body, then two that give the next region), a presence flag, and the 39 world
   landmarks (metres, hips-centred, the crop's axes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DETECTOR_SIZE = 224
LANDMARK_SIZE = 256
N_LANDMARKS = 39  # 33 of the body, then 33 (hips' centre) and 34 (the body circle's point) for the region
N_BODY = 33
_STRIDES = (8, 16, 32, 32, 32)  # the detector's SSD layers; each gives two anchors per cell

# BlazePose's 33 body landmarks (the person's own left and right).
LANDMARK_NAMES = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye", "right_eye_outer",
    "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder", "right_shoulder", "left_elbow",
    "right_elbow", "left_wrist", "right_wrist", "left_pinky", "right_pinky", "left_index", "right_index",
    "left_thumb", "right_thumb", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
    "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)
NOSE, LEFT_EAR, RIGHT_EAR = 0, 7, 8
LEFT_SHOULDER, RIGHT_SHOULDER, LEFT_ELBOW, RIGHT_ELBOW, LEFT_WRIST, RIGHT_WRIST = 11, 12, 13, 14, 15, 16
LEFT_PINKY, RIGHT_PINKY, LEFT_INDEX, RIGHT_INDEX = 17, 18, 19, 20
LEFT_HIP, RIGHT_HIP, LEFT_KNEE, RIGHT_KNEE, LEFT_ANKLE, RIGHT_ANKLE = 23, 24, 25, 26, 27, 28
LEFT_HEEL, RIGHT_HEEL, LEFT_FOOT_INDEX, RIGHT_FOOT_INDEX = 29, 30, 31, 32
# Each landmark's mirror image (left and right swapped, the nose its own): a mirrored image's landmarks read back.
MIRRORED = np.array([LANDMARK_NAMES.index(n.replace("left", "@").replace("right", "left").replace("@", "right"))
                     for n in LANDMARK_NAMES])


class EstimatorError(RuntimeError):
    """BlazePose cannot run (its runtime or a network missing or broken)."""


# ---- the networks' geometry ----------------------------------------------------------------------------------

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


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.clip(x, -80.0, 80.0)))


# ---- the networks (run by LiteRT) ----------------------------------------------------------------------------

def interpreter(model: bytes | None, what: str):
    """A LiteRT interpreter of one network's .tflite bytes, one thread."""
    try:
        from ai_edge_litert.interpreter import Interpreter
    except ImportError as exc:
        raise EstimatorError("BlazePose's .tflite networks run with LiteRT, which is not installed; pip install "
                             "'mocapflow[monocular]' (the ai-edge-litert package)") from exc
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
    """BlazePose GHUM 3D (full) on single images: the body's region, then its landmarks there."""

    def __init__(self, detector: bytes | None, landmarker: bytes | None, min_detection: float = 0.5,
                 min_presence: float = 0.5):
        self._det = interpreter(detector, "detector")
        self._lmk = interpreter(landmarker, "landmarker")
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
        """The region of the best body the detector finds in an RGB image, or None."""
        square, side, offset = letterbox(image, DETECTOR_SIZE)
        inp, boxes, logits = self._det_io
        self._det.set_tensor(inp, square[None])
        self._det.invoke()
        points = decode_detection(self._det.get_tensor(boxes)[0], self._det.get_tensor(logits)[0, :, 0], side, offset,
                                  self.min_detection)
        return None if points is None else body_region(points[0], points[1])

    def landmarks(self, image: np.ndarray, region: Region) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """(image landmarks (39, 2) pixels, their visibility (39,) in [0, 1], world landmarks (39, 3) metres in the
        image's axes, the presence flag)."""
        import cv2

        crop = cv2.warpAffine(image, region.crop_transform(LANDMARK_SIZE), (LANDMARK_SIZE, LANDMARK_SIZE),
                              flags=cv2.WARP_INVERSE_MAP | cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        inp, screen, flag, world = self._lmk_io
        self._lmk.set_tensor(inp, (crop.astype(np.float32) / 255.0)[None])
        self._lmk.invoke()
        raw = self._lmk.get_tensor(screen)[0].reshape(N_LANDMARKS, 5)
        xy = region.to_image(raw[:, :2], LANDMARK_SIZE)
        w = self._lmk.get_tensor(world)[0].reshape(N_LANDMARKS, 3)
        w = np.column_stack([w[:, :2] @ region.turn.T, w[:, 2]])  # the crop's axes back to the image's
        return xy, sigmoid(raw[:, 3]), w, float(self._lmk.get_tensor(flag)[0, 0])
