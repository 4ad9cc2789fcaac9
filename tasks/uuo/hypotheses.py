"""Stage 1 of UUO's mocap solver, widened: which way the body faces and which side is which (Milef et al. 2024,
§3.5.1).

The paper tries four root yaws (B = {0, 90, 180, 270} degrees) and keeps the one of least chamfer (Eq. 3). A
body can also be solved mirrored (its left limbs on the right side's markers: a monocular estimate that swapped
the sides, or markers that fit either way), and part matching's closest points fall into the basin of the yaw
they start from. Here every root yaw in steps of ``step_deg`` (30) and, where the prior is not left-right
symmetric, the mirrored prior are placed on the markers by part matching (§3.4.2) on a few frames; the
placements are ranked by their chamfer (Eq. 1), those that end facing within ``distinct_deg`` of a better one of
the same handedness dropped, and the best ``keep`` are solved in full.

A solved hypothesis is then judged beyond its chamfer by anatomical plausibility (``plausibility``): the knees
and elbows bent against their hinge (a body turned around on a bent leg's markers bends its knee backward), and
a body that walks backward across the volume. The kernels here are pure functions of arrays; the stages are in
solve.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocapflow.tasks.shared.mesh_body import MeshBody
from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody, posed_heads
from mocapflow.tasks.uuo import metrics
from mocapflow.tasks.uuo.matching import MatchConfig

MIRROR = np.diag([-1.0, 1.0, 1.0])  # the rest body's left-right reflection (its sagittal plane is x = 0)
# The hinges (the head bones of the upper limb, the lower limb and its far end; which way it bends: -1 the knee
# backward, +1 the elbow forward).
HINGES = (("upperleg01.L", "lowerleg01.L", "foot.L", -1.0), ("upperleg01.R", "lowerleg01.R", "foot.R", -1.0),
          ("upperarm01.L", "lowerarm01.L", "wrist.L", 1.0), ("upperarm01.R", "lowerarm01.R", "wrist.R", 1.0))


class HypothesisError(ValueError):
    """Hypothesis settings the solver cannot use."""


@dataclass(frozen=True)
class ScreenConfig:
    step_deg: float = 30.0  # root yaws tried: 0, step, 2 step, ... (at most 30 apart)
    search_yaws_deg: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0)  # the chain search's starts (the paper's B)
    mirror: bool = True  # also the prior mirrored left-right (skipped when the prior is symmetric)
    keep: int = 4  # placements solved in full (the solve stages' ``rank`` 0 .. keep-1)
    distinct_deg: float = 45.0  # a placement facing within this of a better one (same handedness) is the same
    symmetric_m: float = 0.01  # a prior whose mirror image lies within this of it is symmetric (the rest pose)
    matching: MatchConfig = field(default_factory=lambda: MatchConfig(frames=16, vertices=600, iterations=12))

    def __post_init__(self):
        if not 0 < self.step_deg <= 30 or self.keep < 1 or not 0 <= self.distinct_deg < 180 \
                or not self.search_yaws_deg:
            raise HypothesisError(f"screen needs 0 < step_deg <= 30, keep >= 1, 0 <= distinct_deg < 180 and a "
                                  f"search yaw, got {self.step_deg}, {self.keep}, {self.distinct_deg} and "
                                  f"{self.search_yaws_deg}")


def yaws(step_deg: float) -> np.ndarray:
    """The root yaws tried, degrees: 0, step, ... below 360."""
    return np.arange(0.0, 360.0 - 1e-9, step_deg)


def mirror_bones(names) -> np.ndarray:
    """Each bone's mirror bone (``.L`` <-> ``.R``; a bone on the midline is its own).  -> (bone,) indices"""
    names = list(names)
    swap = {".L": ".R", ".R": ".L"}
    return np.array([names.index(n[:-2] + swap[n[-2:]]) if n[-2:] in swap else i for i, n in enumerate(names)])


def mirrored(fit: BodyFit, bones: np.ndarray) -> BodyFit:
    """The body mirrored through its own sagittal plane, in place: every bone takes its mirror bone's rotation
    reflected (S L S), the root keeps its rotation and head, so the body faces the same way with its sides swapped.
    (World rotations W'_b' = M W_b S with M = W_root S W_root^T, the reflection through the posed body's plane.)"""
    local = MIRROR @ fit.local[:, bones] @ MIRROR
    local[:, 0] = fit.local[:, 0]
    return BodyFit(local, fit.root.copy(), fit.phenotype)


def is_symmetric(body: SolverBody, fit: BodyFit, bones: np.ndarray, tolerance_m: float) -> bool:
    """Whether the body's mirror image is itself (the neutral rest pose of markers only): its bone heads within
    ``tolerance_m`` of the mirrored body's, on a few frames."""
    frames = np.unique(np.linspace(0, len(fit.root) - 1, min(8, len(fit.root))).astype(int))
    sub = BodyFit(fit.local[frames], fit.root[frames], fit.phenotype)
    return bool(np.abs(posed_heads(body, sub) - posed_heads(body, mirrored(sub, bones))).max() < tolerance_m)


def distinct(candidates: list[dict], keep: int, distinct_deg: float) -> list[dict]:
    """The best ``keep`` placements by chamfer, each facing more than ``distinct_deg`` from every better one of
    the same handedness.  candidates: dicts with ``chamfer``, ``matched_yaw_deg``, ``mirror``"""
    out: list[dict] = []
    for c in sorted(candidates, key=lambda c: c["chamfer"]):
        if all(c["mirror"] != o["mirror"] or angle_deg(c["matched_yaw_deg"], o["matched_yaw_deg"]) > distinct_deg
               for o in out):
            out.append(c)
        if len(out) == keep:
            break
    return out


def angle_deg(a: float, b: float) -> float:
    """The angle between two headings, degrees in [0, 180]."""
    return float(abs((a - b + 180.0) % 360.0 - 180.0))


def rest_forward(body: MeshBody) -> np.ndarray:
    """The rest body's forward direction, horizontal: the hips' left-right axis crossed with up.  -> (3,)"""
    names = list(body.bone_names)
    across = body.rest_heads[names.index("upperleg01.L")] - body.rest_heads[names.index("upperleg01.R")]
    return np.array([across[1], -across[0], 0.0]) / np.linalg.norm(across[:2])


def hinge_flexion_deg(body: MeshBody, world: np.ndarray, heads: np.ndarray) -> np.ndarray:
    """Each hinge's signed flexion, degrees: the lower limb's angle from the upper limb's line, positive toward the
    side the joint bends to (the knee toward the thigh's back, the elbow toward the upper arm's front; that side is
    the rest body's forward carried by the upper limb's own rotation, so it follows the limb's twist).
    world (frame, bone, 3, 3) world rotations, heads (frame, bone, 3) -> (frame, hinge)"""
    names = list(body.bone_names)
    forward = rest_forward(body)
    out = np.empty((len(heads), len(HINGES)))
    for k, (upper, joint, end, bend) in enumerate(HINGES):
        u = heads[:, names.index(joint)] - heads[:, names.index(upper)]
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        lower = heads[:, names.index(end)] - heads[:, names.index(joint)]
        lower /= np.linalg.norm(lower, axis=-1, keepdims=True)
        side = world[:, body.bone_parents[names.index(joint)]] @ (bend * forward)  # (frame, 3)
        side -= (side * u).sum(-1, keepdims=True) * u
        side /= np.linalg.norm(side, axis=-1, keepdims=True)
        out[:, k] = np.degrees(np.arctan2((lower * side).sum(-1), (lower * u).sum(-1)))
    return out


def hyperextension_deg(flexion: np.ndarray, tolerance_deg: float) -> float:
    """How far the knees and elbows bend against their hinge: per frame the sum over the hinges of the flexion
    below -``tolerance_deg`` (degrees), averaged over frames. A healthy knee or elbow reaches a few degrees of
    hyperextension; a body solved turned around on a bent leg's markers bends its knee backward.
    flexion (frame, hinge) from hinge_flexion_deg"""
    return float(np.maximum(0.0, -flexion - tolerance_deg).sum(-1).mean())


def backward_travel(joints: np.ndarray, names, travel_m: float = 1.0) -> float:
    """How clearly the body travels backward over the take: the hips' net horizontal displacement against its
    median facing, -cos of the angle (0 when forward or sideways), scaled by the distance up to ``travel_m``. People
    walk and run forward; a gait take solved turned around walks backward.  joints (frame, joint, 3) -> [0, 1]"""
    names = list(names)
    hips = joints[:, names.index("Hips"), :2]
    n = max(1, len(hips) // 10)
    move = np.median(hips[-n:], axis=0) - np.median(hips[:n], axis=0)
    distance = float(np.linalg.norm(move))
    if distance < 1e-6:
        return 0.0
    heading = metrics.facing(joints, names)
    ahead = np.array([np.cos(np.median(np.unwrap(heading))), np.sin(np.median(np.unwrap(heading)))])
    return float(max(0.0, -(move @ ahead) / distance) * min(1.0, distance / travel_m))
