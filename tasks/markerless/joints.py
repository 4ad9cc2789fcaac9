"""BlazePose's 33 landmarks read as the template's 20 joints (tasks/shared/body.py JOINT_NAMES).

Each joint is a fixed linear combination of landmarks (weights summing to 1), so the map is applied after
triangulation, to the 3D landmarks, exactly as to 2D ones. Per joint (``MAPPING``):

- Hips, SpineBase: the hips' midpoint, (left_hip + right_hip) / 2. The template's root and lower spine are one
  point there (on Anny's default adult at rest both lie 13 mm above and 9 mm before the hip joints' midpoint);
- Neck: on the line from the hips' midpoint through the shoulders' midpoint, NECK_FRACTION = 1.21 of the way
  (hips + 1.21 (shoulders - hips)): the template's neck sits 0.10 m above the upper arms' heads, measured on Anny's
  default adult at rest (mesh_body(Phenotype())): (1.569 - 0.976) / (1.467 - 0.976) = 1.21;
- Head: the ears' midpoint, (left_ear + right_ear) / 2 (the template's head joint is at the ears' height);
- Left/Right Shoulder, Elbow, Wrist, Hip, Knee, Ankle: BlazePose's landmark of the same name, unchanged;
- Left/Right Hand: the index and little fingers' knuckles' midpoint (the middle finger's base, the template's
  hand end), (index + pinky) / 2;
- Left/Right Foot: the toes' base, TOES_FRACTION = 0.7 of the way from the heel to the foot's tip
  (heel + 0.7 (foot_index - heel)).

A joint is given where every landmark it reads is; its confidence is the least of theirs.
"""

from __future__ import annotations

import numpy as np

from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.markerless.blazepose import LANDMARK_NAMES

NECK_FRACTION = 1.21
TOES_FRACTION = 0.7


def _mid(a: str, b: str) -> dict[str, float]:
    return {a: 0.5, b: 0.5}


def _both(side: str) -> dict[str, dict[str, float]]:
    s, S = side.lower(), side
    return {
        f"{S}Shoulder": {f"{s}_shoulder": 1.0}, f"{S}Elbow": {f"{s}_elbow": 1.0}, f"{S}Wrist": {f"{s}_wrist": 1.0},
        f"{S}Hand": _mid(f"{s}_index", f"{s}_pinky"),
        f"{S}Hip": {f"{s}_hip": 1.0}, f"{S}Knee": {f"{s}_knee": 1.0}, f"{S}Ankle": {f"{s}_ankle": 1.0},
        f"{S}Foot": {f"{s}_heel": 1.0 - TOES_FRACTION, f"{s}_foot_index": TOES_FRACTION},
    }


_HIPS = _mid("left_hip", "right_hip")
MAPPING: dict[str, dict[str, float]] = {  # template joint -> {BlazePose landmark: weight}
    "Hips": _HIPS,
    "SpineBase": _HIPS,
    "Neck": {"left_hip": (1 - NECK_FRACTION) / 2, "right_hip": (1 - NECK_FRACTION) / 2,
             "left_shoulder": NECK_FRACTION / 2, "right_shoulder": NECK_FRACTION / 2},
    "Head": _mid("left_ear", "right_ear"),
    **_both("Left"), **_both("Right"),
}
assert set(MAPPING) == set(JOINT_NAMES) and all(abs(sum(w.values()) - 1) < 1e-12 for w in MAPPING.values())


def mapping_matrix() -> np.ndarray:
    """(20, 33): row j the weights of template joint j (JOINT_NAMES order) on BlazePose's landmarks."""
    out = np.zeros((len(JOINT_NAMES), len(LANDMARK_NAMES)))
    for j, name in enumerate(JOINT_NAMES):
        for landmark, weight in MAPPING[name].items():
            out[j, LANDMARK_NAMES.index(landmark)] = weight
    return out


MATRIX = mapping_matrix()
USED = MATRIX != 0  # (20, 33) the landmarks each joint reads
USED_LANDMARKS = np.flatnonzero(USED.any(axis=0))  # the 26 landmarks any joint reads


def template_joints(landmarks: np.ndarray, confidence: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The template's 20 joints from BlazePose's 33 landmarks, 2D or 3D: (..., 33, d) -> (..., 20, d), NaN where a
    landmark the joint reads is missing; and their confidence (..., 20), the least of its landmarks' (1 where no
    ``confidence`` (..., 33) is given, 0 where the joint is missing)."""
    landmarks = np.asarray(landmarks, np.float64)
    if landmarks.shape[-2] != len(LANDMARK_NAMES):
        raise ValueError(f"expected BlazePose's {len(LANDMARK_NAMES)} landmarks along axis -2, got shape "
                         f"{landmarks.shape}")
    filled = np.where(np.isfinite(landmarks), landmarks, 0.0)
    joints = np.einsum("jl,...ld->...jd", MATRIX, filled)
    present = np.isfinite(landmarks).all(axis=-1)  # (..., 33)
    given = (present[..., None, :] | ~USED).all(axis=-1)  # (..., 20)
    joints[~given] = np.nan
    conf = np.ones(landmarks.shape[:-1]) if confidence is None else np.asarray(confidence, np.float64)
    joint_conf = np.where(USED, conf[..., None, :], np.inf).min(axis=-1)
    return joints, np.where(given, joint_conf, 0.0)
