"""DeepMoCap's 26 reflectors on the mesh body: patches of tape on the skin, straps around the limbs.

Each reflector keeps its place on the template body (tasks/shared/reflectors.py, jittered per subject):
its position relative to its segment (how far along it, which way round it) is carried onto the mesh's
matching bone through the rest alignment of tasks/studio/mesh_motion.py. A patch is the 2-inch square of
skin faces around the point where a ray from the segment's axis, in the patch's direction, leaves the
body; its ground truth is that surface point (face, barycentric) on the posed mesh. A strap is the
2-inch band of the limb's skin faces across the segment's axis; its ground truth is the mean of the band's
posed vertices, the limb's centre at the strap.

Each placement also keeps its tape's rest-pose frame (``centre``, ``frame``: rows across, along, out), from which
tasks/deepmocap/film/tape.py draws the tape itself per pixel (``tape: true``), and ``slips`` moves a reflector along its
segment and sideways on the skin, as clothing under the tape does (tasks/deepmocap/film/cloth.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.tasks.shared.body import JOINT_NAMES, PARENTS, Primitive, Subject, rest_offsets
from mocapflow.tasks.shared.kinematics import forward_kinematics
from mocapflow.tasks.shared.mesh_body import MeshBody
from mocapflow.tasks.shared.reflectors import TAPE_WIDTH, Placement
from mocapflow.tasks.studio.mesh_motion import SEGMENTS, rest_alignment
from mocapflow.tasks.studio.mesh_render import MeshScene

# the template primitive a reflector sits on -> the mesh bone that carries it
PRIM_BONES = {"torso": "spine05", "head": "head", "pelvis": "root", "l_clavicle": "clavicle.L", "r_clavicle": "clavicle.R",
              "l_forearm": "lowerarm01.L", "r_forearm": "lowerarm01.R", "l_hand": "wrist.L", "r_hand": "wrist.R",
              "l_shin": "lowerleg01.L", "r_shin": "lowerleg01.R", "l_foot": "foot.L", "r_foot": "foot.R"}
STRAP_REACH_M = 0.10  # a strap takes the limb's skin within this distance of its axis


class MeshPlacementError(ValueError):
    """A reflector that cannot be placed on the mesh."""


@dataclass(frozen=True)
class MeshPlacement:
    name: str
    kind: str  # "patch" | "strap"
    face: int  # patch: the face of its centre (-1 for a strap)
    bary: np.ndarray  # patch: barycentric (u, v) of its centre
    ring: np.ndarray  # strap: vertex indices of the band (empty for a patch)
    bone: str = ""  # the mesh bone that carries it
    centre: np.ndarray | None = None  # rest pose: a patch's surface point, a strap's point on the limb's axis
    frame: np.ndarray | None = None  # (3, 3) rest-pose rows: across the tape, along the segment, out of the skin


def _rest_positions(subject: Subject) -> np.ndarray:
    """Template joints in the rest T-pose (every joint frame aligned with the world).  # (joint, 3)"""
    offsets = rest_offsets(subject)
    rest = np.tile(np.eye(3), (1, len(offsets), 1, 1))
    return forward_kinematics(rest, offsets[None, 0], offsets, PARENTS)[1][0]


def _segment(body: MeshBody, subject: Subject, bone: str, tmpl_rest: np.ndarray):
    """(template origin, template unit axis, template length, mesh origin, mesh unit axis, mesh length)."""
    joint, end_bone, end_joint = SEGMENTS[bone]
    o_t, o_m = tmpl_rest[JOINT_NAMES.index(joint)], body.rest_heads[body.bone(bone)]
    if end_bone is None:
        up = np.array([0.0, 0.0, 1.0])
        return o_t, up, 1.0, o_m, up, 1.0
    a_t = tmpl_rest[JOINT_NAMES.index(end_joint)] - o_t
    a_m = body.rest_heads[body.bone(end_bone)] - o_m
    return o_t, a_t / np.linalg.norm(a_t), np.linalg.norm(a_t), o_m, a_m / np.linalg.norm(a_m), np.linalg.norm(a_m)


def place_on_mesh(body: MeshBody, subject: Subject, prims: tuple[Primitive, ...],
                  placements: tuple[Placement, ...],
                  slips: np.ndarray | None = None) -> tuple[tuple[MeshPlacement, ...], np.ndarray]:
    """The template ``placements`` (on ``prims`` of ``subject``) carried onto ``body``; ``slips`` (reflector, 2):
    metres each one moves along its segment and (a patch) sideways round it, None for none.

    Returns the mesh placements and each face's reflector index (-1 for none).  # (face,) int8
    """
    tmpl_rest = _rest_positions(subject)
    align = rest_alignment(body, subject)
    skin = np.flatnonzero(body.skin)
    scene = MeshScene(body.vertices, body.faces[skin])
    centroids = body.vertices[body.faces].mean(axis=1)  # (face, 3)
    face_reflector = np.full(len(body.faces), -1, np.int8)
    out = []
    for r, p in enumerate(placements):
        prim = prims[p.prim]
        bone = PRIM_BONES.get(prim.name)
        if bone is None:
            raise MeshPlacementError(f"reflector {p.name} sits on template primitive {prim.name!r}, which no mesh bone "
                                     f"carries; add it to PRIM_BONES ({', '.join(PRIM_BONES)})")
        o_t, a_t, l_t, o_m, a_m, l_m = _segment(body, subject, bone, tmpl_rest)
        centre = tmpl_rest[prim.joint] + p.centre  # template rest world position
        along = (centre - o_t) @ a_t / l_t  # fraction of the segment (of a metre where it has no end)
        origin = o_m + along * l_m * a_m
        if slips is not None:
            origin = origin + slips[r, 0] * a_m
        if p.kind == "strap":
            band = _band(body, origin, a_m, bone)
            face_reflector[band] = r
            out.append(MeshPlacement(p.name, "strap", -1, np.zeros(2), np.unique(body.faces[band]), bone, origin,
                                     _frame(a_m, _perpendicular(a_m))))
            continue
        radial = centre - o_t - ((centre - o_t) @ a_t) * a_t
        direction = radial if np.linalg.norm(radial) > 1e-6 else p.normal
        direction = align[body.bone(bone)][1].T @ (direction / np.linalg.norm(direction))  # template -> mesh rest
        face, bary, t = scene.cast(origin[None], direction[None])
        if face[0] < 0:
            raise MeshPlacementError(f"reflector {p.name}: no skin found from {bone} in direction {direction.round(2)}")
        if slips is not None and slips[r, 1]:  # sideways: cast again at the point moved round the segment
            side = np.cross(a_m, direction)
            target = origin + t[0] * direction + slips[r, 1] * side / max(np.linalg.norm(side), 1e-9)
            direction = (target - origin) / np.linalg.norm(target - origin)
            face, bary, t = scene.cast(origin[None], direction[None])
            if face[0] < 0:
                raise MeshPlacementError(f"reflector {p.name}: slipped {slips[r].round(3)} m, no skin found from "
                                         f"{bone}; give a smaller slip")
        face_id = int(skin[face[0]])
        point = origin + t[0] * direction
        normal = np.cross(*(body.vertices[body.faces[face_id, 1:]] - body.vertices[body.faces[face_id, 0]]))
        normal /= np.linalg.norm(normal)
        face_reflector[_square(centroids, point, normal) & body.skin] = r
        out.append(MeshPlacement(p.name, "patch", face_id, bary[0].astype(np.float64), np.zeros(0, np.int64), bone,
                                 point, _frame(a_m, normal)))
    return tuple(out), face_reflector


def _perpendicular(axis: np.ndarray) -> np.ndarray:
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    out = np.cross(axis, helper)
    return out / np.linalg.norm(out)


def _frame(axis: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Rows (across, along, out): ``normal`` out of the skin, ``axis`` (the segment's) made tangent to it.  (3, 3)"""
    along = axis - (axis @ normal) * normal
    if np.linalg.norm(along) < 1e-6:  # the segment points out of the skin (a patch on a segment's end)
        along = _perpendicular(normal)
    along /= np.linalg.norm(along)
    return np.stack([np.cross(along, normal), along, normal])


def tape_faces(body: MeshBody, placements: tuple[MeshPlacement, ...], half_sizes: np.ndarray,
               margin_m: float = 0.02) -> np.ndarray:
    """Each face's candidate tape (-1 for none): faces that may hold part of a tape ``half_sizes`` (reflector, 3:
    across, along, out) big, a face's size (``margin_m``) wider; tasks/deepmocap/film/tape.py tests each pixel exactly.
    A patch's faces face its way (the other side of a hand is not under it).  # (face,) int8"""
    out = np.full(len(body.faces), -1, np.int8)
    corners = body.vertices[body.faces]
    centroids = corners.mean(axis=1)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    for r, p in enumerate(placements):
        if p.centre is None or p.frame is None:
            raise MeshPlacementError(f"reflector {p.name} has no tape frame; place it with place_on_mesh")
        rel = (centroids - p.centre) @ p.frame.T  # (face, 3) across, along, out
        if p.kind == "strap":
            side = p.bone[-2:]
            limb = np.array([n.endswith(side) for n in body.bone_names])[body.vertex_bone[body.faces]].all(axis=1)
            around = np.hypot(rel[:, 0], rel[:, 2])
            near = limb & (np.abs(rel[:, 1]) <= half_sizes[r, 1] + margin_m) & (around <= STRAP_REACH_M)
        else:
            near = ((np.abs(rel[:, 0]) <= half_sizes[r, 0] + margin_m) & (np.abs(rel[:, 1]) <= half_sizes[r, 1] + margin_m)
                    & (np.abs(rel[:, 2]) <= half_sizes[r, 2] + margin_m) & (normals @ p.frame[2] > 0))
        out[near & body.skin] = r
    return out


def _band(body: MeshBody, origin: np.ndarray, axis: np.ndarray, bone: str) -> np.ndarray:
    """Faces of the limb's skin whose centre lies within half a tape width of the plane through ``origin`` across
    ``axis`` (and near the axis: this side's limb only).  # (face,) bool"""
    side = bone[-2:]
    limb = np.array([n.endswith(side) for n in body.bone_names])[body.vertex_bone[body.faces]].all(axis=1)
    rel = body.vertices[body.faces].mean(axis=1) - origin
    along = rel @ axis
    across = np.linalg.norm(rel - np.outer(along, axis), axis=1)
    band = body.skin & limb & (np.abs(along) <= TAPE_WIDTH / 2) & (across <= STRAP_REACH_M)
    if band.sum() < 8:
        raise MeshPlacementError(f"a strap on {bone} found only {band.sum()} skin faces around its limb")
    return band


def _square(centroids: np.ndarray, centre: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Faces whose centroid lies in the 2-inch square of tape around ``centre`` on the plane of ``normal``."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(normal[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(helper, normal)
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    rel = centroids - centre
    half = TAPE_WIDTH / 2
    return (np.abs(rel @ u) <= half) & (np.abs(rel @ v) <= half) & (np.abs(rel @ normal) <= half)


def reflector_positions(body: MeshBody, placements: tuple[MeshPlacement, ...], vertices: np.ndarray) -> np.ndarray:
    """Ground-truth reflector positions on posed meshes: (frame, vertex, 3) -> (frame, reflector, 3)."""
    out = np.empty((vertices.shape[0], len(placements), 3))
    for r, p in enumerate(placements):
        if p.kind == "strap":
            out[:, r] = vertices[:, p.ring].mean(axis=1)
        else:
            corners = vertices[:, body.faces[p.face]]  # (frame, 3, 3)
            u, v = p.bary
            out[:, r] = (1 - u - v) * corners[:, 0] + u * corners[:, 1] + v * corners[:, 2]
    return out
