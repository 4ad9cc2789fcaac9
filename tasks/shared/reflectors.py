"""The 26 retro-reflective straps and patches, in DeepMoCap's channel order (§3.1, Figure 2).

Patches are flat 2-inch squares of tape on the body surface, seen from one side only (the body
itself hides them from behind). Straps are 2-inch bands around a limb, seen from every side.
Ground truth: a strap's position is the limb centre at the strap, a patch's the centre of the tape.
Sides are anatomical: an ``L_`` reflector sits on the subject's left.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared.body import Primitive

TAPE_WIDTH = 0.0508  # 2 inches, metres

# name, kind, primitive, placement: a direction in the joint frame (patches on ellipsoids),
# (axial fraction, direction) for patches on capsules, or the axial fraction of a strap.
REFLECTOR_TABLE = (
    ("F_SPINEMID", "patch", "torso", (0.0, 1.0, -0.35)),
    ("F_R_CHEST", "patch", "torso", (0.45, 1.0, 0.55)),
    ("F_L_CHEST", "patch", "torso", (-0.45, 1.0, 0.55)),
    ("F_R_HEAD", "patch", "head", (0.35, 1.0, 0.35)),
    ("F_L_HEAD", "patch", "head", (-0.35, 1.0, 0.35)),
    ("B_HEAD", "patch", "head", (0.0, -1.0, 0.2)),
    ("B_BACK", "patch", "torso", (0.0, -1.0, 0.55)),
    ("B_SPINEMID", "patch", "torso", (0.0, -1.0, -0.35)),
    ("B_R_SHOULDER", "patch", "r_clavicle", (0.8, (0.0, -1.0, 0.6))),
    ("F_R_SHOULDER", "patch", "r_clavicle", (0.8, (0.0, 1.0, 0.6))),
    ("R_ELBOW", "strap", "r_forearm", 0.22),
    ("R_WRIST", "strap", "r_forearm", 0.86),
    ("R_HAND", "patch", "r_hand", (0.5, (0.0, 0.0, 1.0))),
    ("B_L_SHOULDER", "patch", "l_clavicle", (0.8, (0.0, -1.0, 0.6))),
    ("F_L_SHOULDER", "patch", "l_clavicle", (0.8, (0.0, 1.0, 0.6))),
    ("L_ELBOW", "strap", "l_forearm", 0.22),
    ("L_WRIST", "strap", "l_forearm", 0.86),
    ("L_HAND", "patch", "l_hand", (0.5, (0.0, 0.0, 1.0))),
    ("R_PELVIS", "patch", "pelvis", (0.75, 0.65, 0.1)),
    ("R_CALF", "strap", "r_shin", 0.35),
    ("R_ANKLE", "strap", "r_shin", 0.88),
    ("R_FOOT", "patch", "r_foot", (0.55, (0.0, 0.25, 1.0))),
    ("L_PELVIS", "patch", "pelvis", (-0.75, 0.65, 0.1)),
    ("L_CALF", "strap", "l_shin", 0.35),
    ("L_ANKLE", "strap", "l_shin", 0.88),
    ("L_FOOT", "patch", "l_foot", (0.55, (0.0, 0.25, 1.0))),
)
REFLECTOR_NAMES = tuple(r[0] for r in REFLECTOR_TABLE)
STRAPS = tuple(r[0] for r in REFLECTOR_TABLE if r[1] == "strap")


@dataclass(frozen=True)
class Placement:
    """One reflector on one primitive, in that primitive's joint frame."""

    name: str
    kind: str  # "patch" | "strap"
    prim: int  # index into the surface primitives
    centre: np.ndarray  # ground-truth point (tape centre, or limb centre for a strap)
    normal: np.ndarray  # patch: outward surface normal; strap: limb axis
    u: np.ndarray  # patch tangent axes (unused for straps)
    v: np.ndarray
    axial: tuple[float, float]  # strap: band [start, end] along the capsule axis, metres


def place(prims: tuple[Primitive, ...], rng: np.random.Generator | None = None, jitter: float = 1.0):
    """Place the 26 reflectors on ``prims``; ``rng`` jitters placement per subject (about +-2 cm, +-8 deg)."""
    index = {p.name: i for i, p in enumerate(prims)}
    out = []
    for name, kind, prim_name, where in REFLECTOR_TABLE:
        k = index[prim_name]
        prim = prims[k]
        if kind == "strap":
            out.append(_strap(name, k, prim, where + _noise(rng, 0.03 * jitter)))
        elif prim.kind == "ellipsoid":
            out.append(_ellipsoid_patch(name, k, prim, _tilt(np.asarray(where, float), rng, jitter)))
        else:
            fraction, direction = where
            out.append(_capsule_patch(name, k, prim, fraction + _noise(rng, 0.05 * jitter),
                                      _tilt(np.asarray(direction, float), rng, jitter)))
    return tuple(out)


def _noise(rng, scale):
    return 0.0 if rng is None else float(rng.uniform(-scale, scale))


def _tilt(direction, rng, jitter):
    if rng is None:
        return direction
    return Rotation.from_rotvec(rng.normal(0.0, np.radians(5.0) * jitter, 3)).apply(direction)


def _strap(name, k, prim, fraction):
    axis = prim.b - prim.a
    length = np.linalg.norm(axis)
    s = fraction * length
    half = TAPE_WIDTH / 2
    return Placement(name, "strap", k, prim.a + axis * fraction, axis / length, np.zeros(3), np.zeros(3),
                     (s - half, s + half))


def _ellipsoid_patch(name, k, prim, direction):
    d = direction / np.linalg.norm(direction)
    t = 1.0 / np.sqrt(np.sum((d / prim.radii) ** 2))
    centre = prim.a + t * d
    normal = (centre - prim.a) / prim.radii**2
    return _patch(name, k, centre, normal)


def _capsule_patch(name, k, prim, fraction, direction):
    axis = (prim.b - prim.a) / np.linalg.norm(prim.b - prim.a)
    radial = direction - axis * (direction @ axis)
    radial /= np.linalg.norm(radial)
    centre = prim.a + (prim.b - prim.a) * fraction + radial * prim.radii[0]
    return _patch(name, k, centre, radial)


def _patch(name, k, centre, normal):
    normal = normal / np.linalg.norm(normal)
    helper = np.array([0.0, 0.0, 1.0]) if abs(normal[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(helper, normal)
    u /= np.linalg.norm(u)
    return Placement(name, "patch", k, centre, normal, u, np.cross(normal, u), (0.0, 0.0))


def world_positions(placements, prims, joint_rot: np.ndarray, joint_pos: np.ndarray) -> np.ndarray:
    """Ground-truth reflector positions.  (frame, joint, 3, 3), (frame, joint, 3) -> (frame, 26, 3)"""
    joints = np.array([prims[p.prim].joint for p in placements])
    centres = np.stack([p.centre for p in placements])  # (26, 3)
    return np.einsum("frij,rj->fri", joint_rot[:, joints], centres) + joint_pos[:, joints]


def label_hits(placements, prim: Primitive, k: int, p_local: np.ndarray) -> np.ndarray:
    """Reflector index (or -1) of surface points ``p_local`` (pixel, 3) on primitive ``k``, in its joint frame."""
    out = np.full(p_local.shape[0], -1, dtype=np.int8)
    half = TAPE_WIDTH / 2
    for r, placement in enumerate(placements):
        if placement.prim != k:
            continue
        rel = p_local - placement.centre
        if placement.kind == "strap":
            s = (p_local - prim.a) @ placement.normal
            hit = (s >= placement.axial[0]) & (s <= placement.axial[1])
        else:
            hit = (np.abs(rel @ placement.u) <= half) & (np.abs(rel @ placement.v) <= half) & \
                  (np.abs(rel @ placement.normal) <= half)
        out[hit] = r
    return out
