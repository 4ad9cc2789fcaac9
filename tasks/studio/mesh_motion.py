"""Motion on the mesh body: the template's motion (an exercise or a retargeted BVH clip) carried onto Anny's rig.

Each template segment drives one Anny bone (``SEGMENTS``): the bone takes the segment's world rotation
from the template's rest T-pose, after the smallest rotation that turns the bone's rest direction (Anny's
A-pose) onto the segment's rest direction, so every mapped bone points where its segment points, frame by
frame. Bones no segment drives (the spine's upper vertebrae, the neck's, the clavicle's shoulder bone, the
pelvis bones, fingers and toes) turn with their parent. The root is placed so that the mesh's hip joints'
midpoint follows the template's, and each frame is lifted so that the mesh's lowest sole point is on the
floor in the frames where the template stands, the lift interpolated in between, so a jump keeps its
height. Copying the template's lowest foot point instead made the mesh float where the template does (its
proportions differ from the source's: 1.5-4.6 cm in stance on the CMU clips), and one lift for the whole
take left the stance soles 2-3 cm up where the mesh's legs bend differently (benchmarks/mesh_studio.py).
A joint take lifts each frame by the stance lift of its time base (``stance_lift`` on the motion sampled once,
interpolated to the frame's instant: tasks/studio/take.py), so every system's mesh stands alike at an instant.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.tasks.shared.body import JOINT_INDEX, PARENTS, Subject, rest_offsets
from mocapflow.tasks.shared.kinematics import forward_kinematics, world_rotations
from mocapflow.tasks.shared.mesh_body import MeshBody, PosedMesh, pose_mesh
from mocapflow.tasks.studio.motion import Motion, lowest_foot_point

# Anny bone: (template joint whose world rotation it takes, Anny bone whose head ends it, template joint ending
# the segment). None: the bone takes the joint's rotation as it is (its rest orientation is the template's).
SEGMENTS = {
    "root": ("Hips", None, None),
    "spine05": ("SpineBase", "neck01", "Neck"),
    "neck01": ("Neck", "head", "Head"),
    "head": ("Head", None, None),
    "clavicle.L": ("Neck", "upperarm01.L", "LeftShoulder"),
    "upperarm01.L": ("LeftShoulder", "lowerarm01.L", "LeftElbow"),
    "lowerarm01.L": ("LeftElbow", "wrist.L", "LeftWrist"),
    "wrist.L": ("LeftWrist", "finger3-1.L", "LeftHand"),
    "upperleg01.L": ("LeftHip", "lowerleg01.L", "LeftKnee"),
    "lowerleg01.L": ("LeftKnee", "foot.L", "LeftAnkle"),
    "foot.L": ("LeftAnkle", "toe3-1.L", "LeftFoot"),
}
SEGMENTS.update({b.replace(".L", ".R"): (j.replace("Left", "Right"), e and e.replace(".L", ".R"),
                                            c and c.replace("Left", "Right"))
                 for b, (j, e, c) in list(SEGMENTS.items()) if b.endswith(".L")})
SOLE_HEIGHT_M = 0.08  # rest vertices below this height are the feet, whose lowest point meets the floor
CONTACT_M = 0.03  # the template stands on a frame whose lowest foot point is within this of the take's lowest


@dataclass(frozen=True)
class MeshTake:
    rotations: np.ndarray  # (frame, bone, 3, 3) each bone's world rotation from its rest orientation
    root: np.ndarray  # (frame, 3) the root bone's head
    posed: PosedMesh


def _turn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a onto unit vector b.  # (3, 3)"""
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        raise ValueError("a bone's rest direction is opposite its segment's; no unique smallest turn")
    k = axis / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * K @ K  # Rodrigues' formula with sin = s, cos = c


def rest_alignment(body: MeshBody, subject: Subject) -> dict[int, tuple[int, np.ndarray]]:
    """Anny bone index -> (template joint index, rotation from the bone's rest to the segment's rest)."""
    offsets = rest_offsets(subject)
    out = {}
    for bone, (joint, end_bone, end_joint) in SEGMENTS.items():
        b = body.bone(bone)
        if end_bone is None:
            out[b] = (JOINT_INDEX[joint], np.eye(3))
            continue
        mesh_dir = body.rest_heads[body.bone(end_bone)] - body.rest_heads[b]
        tmpl_dir = offsets[JOINT_INDEX[end_joint]]
        out[b] = (JOINT_INDEX[joint], _turn(mesh_dir / np.linalg.norm(mesh_dir), tmpl_dir / np.linalg.norm(tmpl_dir)))
    return out


def bone_rotations(body: MeshBody, subject: Subject, local_rot: np.ndarray) -> np.ndarray:
    """Every Anny bone's world rotation from its rest orientation, for the template's ``local_rot``.

    local_rot: (frame, joint, 3, 3) -> (frame, bone, 3, 3)
    """
    world = world_rotations(local_rot, PARENTS)  # (frame, joint, 3, 3) from the T-pose
    align = rest_alignment(body, subject)
    out = np.empty((local_rot.shape[0], len(body.bone_names), 3, 3))
    for b, parent in enumerate(body.bone_parents):  # parents come first
        if b in align:
            joint, turn = align[b]
            out[:, b] = world[:, joint] @ turn
        else:
            out[:, b] = out[:, parent]
    return out


def retarget(body: MeshBody, subject: Subject, motion: Motion, lift: np.ndarray | None = None) -> MeshTake:
    """``motion`` (performed by the template ``subject``) performed by the mesh ``body``. ``lift``: the height the
    stance frames give each frame (stance_lift, sampled from a joint take's time base: take.make_take), by default
    the one these frames give themselves; a frame is never lifted less than its lowest sole needs."""
    rotations, root, posed = _posed(body, subject, motion)
    lowest = _lowest_sole(body, posed)
    if lift is None:
        lift = _stance_lift(lowest, lowest_foot_point(motion.local_rot, motion.root_pos, subject))
    up = np.outer(np.maximum(lift, -lowest), [0.0, 0.0, 1.0])
    posed = PosedMesh(posed.vertices + up[:, None], posed.heads + up[:, None], posed.frames)
    return MeshTake(rotations, root + up, posed)


def stance_lift(body: MeshBody, subject: Subject, motion: Motion) -> np.ndarray:
    """Per frame of ``motion`` the height its stance frames give the mesh (before the floor check of retarget):
    what a joint take samples at each system's instants.  # (frame,)"""
    _, _, posed = _posed(body, subject, motion)
    return _stance_lift(_lowest_sole(body, posed), lowest_foot_point(motion.local_rot, motion.root_pos, subject))


def _posed(body: MeshBody, subject: Subject, motion: Motion) -> tuple[np.ndarray, np.ndarray, PosedMesh]:
    """The bones' world rotations, the root and the mesh posed by ``motion``, before the lift."""
    rotations = bone_rotations(body, subject, motion.local_rot)
    _, pos = forward_kinematics(motion.local_rot, motion.root_pos, rest_offsets(subject), PARENTS)
    hips = [JOINT_INDEX["LeftHip"], JOINT_INDEX["RightHip"]]
    mesh_hips = body.rest_heads[[body.bone("upperleg01.L"), body.bone("upperleg01.R")]].mean(axis=0)
    root_rest = body.rest_heads[0]
    root = pos[:, hips].mean(axis=1) - rotations[:, 0] @ (mesh_hips - root_rest)  # hip midpoints coincide
    return rotations, root, pose_mesh(body, rotations, root)


def _lowest_sole(body: MeshBody, posed: PosedMesh) -> np.ndarray:
    """Per frame the height of the mesh's lowest sole point.  # (frame,)"""
    return posed.vertices[:, body.vertices[:, 2] < SOLE_HEIGHT_M, 2].min(axis=1)


def _stance_lift(lowest: np.ndarray, template_lowest: np.ndarray) -> np.ndarray:
    """Per-frame height that puts the lowest sole on the floor in the template's stance frames (its lowest foot
    point within CONTACT_M of the take's lowest), interpolated between them (a jump keeps its height over
    them).  # (frame,)"""
    stance = template_lowest <= template_lowest.min() + CONTACT_M
    frames = np.arange(len(lowest))
    return np.interp(frames, frames[stance], -lowest[stance])
