"""Articulated template body (DeepMoCap §3.5, Figure 9a): 20 joints, hierarchy levels L0-L6, 40 DoF.

World frame: Z up, metres; in the rest pose (a T-pose) the subject faces +Y, its right side is +X
and its left side -X. Every joint's rest frame is aligned with the world, so a pose is a set of
local rotations (relative to the parent) plus the root translation. The surface is a set of
capsules (limbs) and ellipsoids (pelvis, torso, head), each rigidly attached to one joint frame,
good enough for limbs to occlude each other correctly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# (name, parent, hierarchy level, degrees of freedom)
JOINTS: tuple[tuple[str, str | None, int, int], ...] = (
    ("Hips", None, 0, 6),
    ("SpineBase", "Hips", 1, 3),
    ("Neck", "SpineBase", 2, 3),
    ("Head", "Neck", 3, 2),
    ("LeftShoulder", "Neck", 3, 3),
    ("LeftElbow", "LeftShoulder", 4, 2),
    ("LeftWrist", "LeftElbow", 5, 2),
    ("LeftHand", "LeftWrist", 6, 0),
    ("RightShoulder", "Neck", 3, 3),
    ("RightElbow", "RightShoulder", 4, 2),
    ("RightWrist", "RightElbow", 5, 2),
    ("RightHand", "RightWrist", 6, 0),
    ("LeftHip", "Hips", 1, 3),
    ("LeftKnee", "LeftHip", 2, 1),
    ("LeftAnkle", "LeftKnee", 3, 2),
    ("LeftFoot", "LeftAnkle", 4, 0),
    ("RightHip", "Hips", 1, 3),
    ("RightKnee", "RightHip", 2, 1),
    ("RightAnkle", "RightKnee", 3, 2),
    ("RightFoot", "RightAnkle", 4, 0),
)
JOINT_NAMES = tuple(j[0] for j in JOINTS)
JOINT_INDEX = {name: i for i, name in enumerate(JOINT_NAMES)}
PARENTS = np.array([JOINT_INDEX[p] if p else -1 for _, p, _, _ in JOINTS])
LEVELS = np.array([lvl for _, _, lvl, _ in JOINTS])
DOF = np.array([d for _, _, _, d in JOINTS])
assert DOF.sum() == 40 and LEVELS.max() == 6
BODY_PARTS = {  # the 20 joints in six parts, for figures per part (`mocapflow compare`)
    "torso": ("Hips", "SpineBase", "Neck"),
    "head": ("Head",),
    "upper arms": ("LeftShoulder", "RightShoulder", "LeftElbow", "RightElbow"),
    "wrists, hands": ("LeftWrist", "RightWrist", "LeftHand", "RightHand"),
    "upper legs": ("LeftHip", "RightHip", "LeftKnee", "RightKnee"),
    "ankles, feet": ("LeftAnkle", "RightAnkle", "LeftFoot", "RightFoot"),
}

# Rest offsets from the parent, as fractions of body height (x right, y forward, z up).
# Segment proportions after Drillis & Contini's anthropometric table.
_OFFSETS = {
    "Hips": (0.0, 0.0, 0.53),
    "SpineBase": (0.0, 0.0, 0.045),
    "Neck": (0.0, -0.01, 0.27),
    "Head": (0.0, 0.01, 0.07),
    "LeftShoulder": (-0.11, 0.0, -0.025),
    "LeftElbow": (-0.186, 0.0, 0.0),
    "LeftWrist": (-0.146, 0.0, 0.0),
    "LeftHand": (-0.08, 0.0, 0.0),
    "LeftHip": (-0.088, 0.0, -0.05),
    "LeftKnee": (0.0, 0.0, -0.245),
    "LeftAnkle": (0.0, 0.0, -0.246),
    "LeftFoot": (0.0, 0.115, -0.03),
}
for _name in list(_OFFSETS):
    if _name.startswith("Left"):
        x, y, z = _OFFSETS[_name]
        _OFFSETS["Right" + _name[4:]] = (-x, y, z)


@dataclass(frozen=True)
class Subject:
    """Subject parameters: height (1.50-2.00 m), segment proportion factors and limb girth."""

    height: float = 1.75
    arm_scale: float = 1.0
    leg_scale: float = 1.0
    torso_scale: float = 1.0
    shoulder_scale: float = 1.0
    girth: float = 1.0

    def __post_init__(self):
        if not 1.50 <= self.height <= 2.00:
            raise ValueError(f"subject height {self.height} m is outside the studio's 1.50-2.00 m range")


def random_subject(rng: np.random.Generator, height: float | None = None) -> Subject:
    """A sex-neutral random subject; proportions within a few percent of the template."""
    return Subject(
        height=float(height if height is not None else rng.uniform(1.55, 1.95)),
        arm_scale=float(rng.uniform(0.95, 1.05)),
        leg_scale=float(rng.uniform(0.95, 1.05)),
        torso_scale=float(rng.uniform(0.95, 1.05)),
        shoulder_scale=float(rng.uniform(0.92, 1.08)),
        girth=float(rng.uniform(0.85, 1.2)),
    )


def rest_offsets(subject: Subject) -> np.ndarray:
    """Rest offset of every joint from its parent, metres.  # (joint, 3)"""
    out = np.zeros((len(JOINTS), 3))
    for i, name in enumerate(JOINT_NAMES):
        scale = subject.height * np.ones(3)
        if any(k in name for k in ("Elbow", "Wrist", "Hand")):
            scale *= subject.arm_scale
        elif any(k in name for k in ("Knee", "Ankle", "Foot")):
            scale *= subject.leg_scale
        elif name in ("Neck", "Head"):
            scale *= subject.torso_scale
        elif "Shoulder" in name:
            scale[0] *= subject.shoulder_scale
        out[i] = np.asarray(_OFFSETS[name]) * scale
    return out


# ---- surface ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Primitive:
    """A capsule (segment a->b in the joint frame, radius) or an ellipsoid (centre, radii) on one joint."""

    name: str
    joint: int
    kind: str  # "capsule" | "ellipsoid"
    a: np.ndarray  # capsule start or ellipsoid centre, in the joint's frame
    b: np.ndarray  # capsule end (unused for ellipsoids)
    radii: np.ndarray  # (r,) for a capsule, (rx, ry, rz) for an ellipsoid


_CAPSULES = {  # segment name: (joint, child or None, radius as fraction of height)
    "neck": ("Neck", "Head", 0.028),
    "l_clavicle": ("Neck", "LeftShoulder", 0.03),
    "r_clavicle": ("Neck", "RightShoulder", 0.03),
    "l_upperarm": ("LeftShoulder", "LeftElbow", 0.027),
    "r_upperarm": ("RightShoulder", "RightElbow", 0.027),
    "l_forearm": ("LeftElbow", "LeftWrist", 0.022),
    "r_forearm": ("RightElbow", "RightWrist", 0.022),
    "l_hand": ("LeftWrist", "LeftHand", 0.018),
    "r_hand": ("RightWrist", "RightHand", 0.018),
    "l_thigh": ("LeftHip", "LeftKnee", 0.04),
    "r_thigh": ("RightHip", "RightKnee", 0.04),
    "l_shin": ("LeftKnee", "LeftAnkle", 0.029),
    "r_shin": ("RightKnee", "RightAnkle", 0.029),
    "l_foot": ("LeftAnkle", "LeftFoot", 0.022),
    "r_foot": ("RightAnkle", "RightFoot", 0.022),
}
_ELLIPSOIDS = {  # name: (joint, centre (fraction of height), radii (fraction of height))
    "pelvis": ("Hips", (0.0, 0.0, -0.01), (0.105, 0.065, 0.07)),
    "torso": ("SpineBase", (0.0, -0.005, 0.145), (0.095, 0.06, 0.16)),
    "head": ("Head", (0.0, 0.012, 0.05), (0.048, 0.058, 0.068)),
}


def surface(subject: Subject) -> tuple[Primitive, ...]:
    """The body's closed surface for ``subject``, primitives in their joint frames."""
    offsets = rest_offsets(subject)
    h, g = subject.height, subject.girth
    prims = []
    for name, (joint, child, radius) in _CAPSULES.items():
        j = JOINT_INDEX[joint]
        end = offsets[JOINT_INDEX[child]]
        radius = radius * h * (g if name not in ("neck",) else 1.0)
        start = np.zeros(3)
        if name.endswith("clavicle"):
            start = 0.35 * end  # the shoulder capsule starts off the neck line
        prims.append(Primitive(name, j, "capsule", start, end, np.array([radius])))
    for name, (joint, centre, radii) in _ELLIPSOIDS.items():
        girth = np.array([g, g, 1.0]) if name != "head" else np.ones(3)
        prims.append(Primitive(name, JOINT_INDEX[joint], "ellipsoid", np.asarray(centre) * h, np.zeros(3),
                               np.asarray(radii) * h * girth))
    return tuple(prims)
