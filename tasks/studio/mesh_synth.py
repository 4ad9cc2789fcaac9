"""A studio sequence filmed on the mesh body: the Kinect-like sensors of the capsule studio, Anny as the subject.

The take (tasks/studio/take.py: the Anny body from its own random stream, so the capsule studio's draws, and with
them its placements' jitter and camera layouts, stay the same for the same seed, and the template subject of the
same height performing the motion, skinned onto the mesh) is filmed here; ``build_mesh_rig`` carries the template's
reflectors onto the mesh. ``synthesize_mesh`` ray-casts frames [start, stop) of every
view (one Embree scene per frame, shared by the views) into the raw-sequence schema: depth and IR from the
capsule studio's sensor model, reflector ids from the faces the reflectors cover, scene flow from each hit's
surface point on the neighbouring frames' meshes. Ground truth: the 20 template joints (the mesh bones at them), the
reflectors, and what reproduces every vertex exactly (the phenotype in the attributes, each bone's rotation
and the root's position per frame).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared import body
from mocapflow.tasks.shared.mesh_body import PARTS, MeshBody, part_of_bone
from mocapflow.tasks.studio import mesh_motion, mesh_reflectors, render, take
from mocapflow.tasks.studio.mesh_render import MeshScene, barycentric, cast_view, vertex_normals

MESH_STUDIO_VERSION = "1"
_FINE_PARTS = tuple(p for p in PARTS if PARTS[p] == (p,))


@dataclass(frozen=True)
class MeshRig:
    spec: object  # synth.SequenceSpec
    body: MeshBody
    subject: body.Subject  # the template body of the same height that performs the motion
    placements: tuple  # mesh_reflectors.MeshPlacement, in REFLECTOR_NAMES order
    face_reflector: np.ndarray  # (face,) int8
    face_part: np.ndarray  # (face,) int16 fine body part, for the cloth texture
    views: tuple  # render.View per camera
    motion: object  # motion.Motion of the template, n_frames + 1 frames
    take: mesh_motion.MeshTake  # n_frames + 1 frames

    @property
    def n_frames(self) -> int:
        return self.take.root.shape[0] - 1


def build_mesh_rig(shot: take.Take, prims: tuple, placements: tuple, views: tuple) -> MeshRig:
    """The mesh rig: the take ``shot`` filmed by ``views``, the template's reflector ``placements`` on ``prims``
    (the take's template subject) carried onto the mesh."""
    body_, subject = shot.body, shot.subject
    mesh_placements, face_reflector = mesh_reflectors.place_on_mesh(body_, subject, prims, placements)
    fine = {name: i for i, name in enumerate(_FINE_PARTS)}
    bone_part = np.array([fine[part_of_bone(n)] for n in body_.bone_names], np.int16)
    face_part = bone_part[body_.vertex_bone[body_.faces[:, 0]]]
    return MeshRig(shot.spec, body_, subject, mesh_placements, face_reflector, face_part, views, shot.motion,
                   shot.mesh)


def view_frame(rig: MeshRig, view: render.View, scene: MeshScene, f: int, normals: np.ndarray,
                rng: np.random.Generator) -> render.Frame:
    """One view at frame ``f`` (the posed meshes of f - 1, f and f + 1 are in rig.take)."""
    hits = cast_view(scene, view.cam, view.rays)
    shape = hits.face.shape
    rays = view.rays.reshape(-1, 3)
    hit = np.flatnonzero(hits.face.ravel() >= 0)
    t_hit = hits.depth.ravel()[hit] / np.maximum(rays[hit, 2], 1e-9)  # camera z -> ray length
    keep = t_hit < view.bg_t.ravel()[hit]  # the body is in front of the room
    idx, t_hit = hit[keep], t_hit[keep]  # flat indices of the body's pixels
    body_mask = np.zeros(shape, bool)
    body_mask.ravel()[idx] = True
    t = view.bg_t.copy()
    t.ravel()[idx] = t_hit
    face, bary = hits.face.ravel()[idx], hits.bary.reshape(-1, 2)[idx]
    corners = rig.body.faces[face]  # (n, 3) vertex indices of each hit's face
    verts = rig.take.posed.vertices
    n = barycentric(normals[corners], bary)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    cos = view.bg_cos.copy()
    cos.ravel()[idx] = np.abs(np.einsum("ni,ni->n", n @ view.R.T, rays[idx]))
    rid = np.full(shape, -1, np.int8)
    rid.ravel()[idx] = rig.face_reflector[face]
    reflector = rid >= 0
    here = barycentric(verts[f][corners], bary)
    flow = np.zeros(shape + (3,), np.float32)
    flow_prev = np.zeros_like(flow)
    flow.reshape(-1, 3)[idx] = (barycentric(verts[f + 1][corners], bary) - here) @ view.R.T
    flow_prev.reshape(-1, 3)[idx] = (here - barycentric(verts[max(f - 1, 0)][corners], bary)) @ view.R.T
    hot = render.saturated(reflector, rig.spec.ir_bloom_px)  # a real sensor saturates round each reflector
    depth = render.kinect_depth(t * view.rays[..., 2], cos, hot, rng, rig.spec.noise)
    albedo = view.bg_albedo.copy()
    rest = barycentric(rig.body.vertices[corners], bary)
    albedo.ravel()[idx] = render.ALBEDO["body"] * render.cloth_texture(rig.face_part[face], rest)
    ir = render.kinect_ir(t, cos, albedo, hot, rng, rig.spec.noise)
    pixels = np.bincount(rid[reflector].astype(np.int64), minlength=len(rig.placements)).astype(np.int32)
    return render.Frame(depth, ir, rid, body_mask, flow, flow_prev, pixels)


def synthesize_mesh(rig: MeshRig, start: int, stop: int) -> xr.Dataset:
    """Frames [start, stop) of the sequence in the raw-sequence schema, with ground truth."""
    if not 0 <= start < stop <= rig.n_frames:
        raise ValueError(f"frames [{start}, {stop}) are outside the sequence's 0-{rig.n_frames}")
    n = stop - start
    stack = render.FrameStack(len(rig.views), n, rig.views[0].bg_t.shape, len(rig.placements))
    posed = rig.take.posed
    refl3d = mesh_reflectors.reflector_positions(rig.body, rig.placements, posed.vertices[start:stop])
    for i, f in enumerate(range(start, stop)):
        scene = MeshScene(posed.vertices[f], rig.body.faces)
        normals = vertex_normals(posed.vertices[f], rig.body.faces)
        for v, view in enumerate(rig.views):
            stack.put(v, i, view_frame(rig, view, scene, f, normals, np.random.default_rng([rig.spec.seed, v, f])))
    joint_quats = Rotation.from_matrix(rig.motion.local_rot[start:stop].reshape(-1, 3, 3)).as_quat().reshape(n, -1, 4)
    bone_quats = Rotation.from_matrix(rig.take.rotations[start:stop].reshape(-1, 3, 3)).as_quat().reshape(n, -1, 4)
    extra = {"gt_bone_rotations": (("frame", "bone", "quat"), bone_quats),
             "gt_root": (("frame", "xyz"), rig.take.root[start:stop])}
    ds = stack.dataset(rig.views, rig.spec.fps, start, refl3d, posed.heads[start:stop][:, rig.body.joint_bones()],
                       joint_quats, extra)
    ds = ds.assign_coords(bone=np.array(rig.body.bone_names, dtype=object))
    ds.attrs.update(body="mesh", body_model=f"anny {_anny_version()}", phenotype=asdict(rig.body.phenotype),
                    mesh_studio_version=MESH_STUDIO_VERSION, exercise=rig.motion.label,
                    subject=asdict(rig.subject), seed=rig.spec.seed, noise=rig.spec.noise,
                    reflector_kinds=[p.kind for p in rig.placements],
                    joint_parents=[int(p) for p in body.PARENTS],
                    bone_parents=[int(p) for p in rig.body.bone_parents])
    return ds


def _anny_version() -> str:
    from importlib.metadata import version

    return version("anny")
