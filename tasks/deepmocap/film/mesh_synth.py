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

A spec's realism switches (take.realism; all off by default, and then every byte is as before): ``tape`` draws the
reflectors as 2-inch tape of their real size, saturating unevenly and flaring (tape.py); ``cloth_cm`` films a cloth
layer over the skin that carries the tape, moves it and folds over parts of it (cloth.py; the ground-truth
reflectors are where the tape is); ``tof_artefacts`` adds the Kinect v2's multipath, flying pixels, motion
artefacts and the sensors' interference (tof.py).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared import body
from mocapflow.tasks.shared.mesh_body import PARTS, MeshBody, part_of_bone
from mocapflow.tasks.deepmocap.film import cloth, mesh_reflectors, render, tape, tof
from mocapflow.tasks.studio import mesh_motion, take
from mocapflow.tasks.studio.mesh_render import MeshScene, barycentric, cast_view, vertex_normals
from mocapflow.tasks.studio.spec import MESH_STUDIO_VERSION

_FINE_PARTS = tuple(p for p in PARTS if PARTS[p] == (p,))


@dataclass(frozen=True)
class MeshRig:
    spec: object  # tasks/studio/spec.py, SequenceSpec
    body: MeshBody
    subject: body.Subject  # the template body of the same height that performs the motion
    placements: tuple  # mesh_reflectors.MeshPlacement, in REFLECTOR_NAMES order
    face_reflector: np.ndarray  # (face,) int8
    face_part: np.ndarray  # (face,) int16 fine body part, for the cloth texture
    views: tuple  # render.View per camera
    motion: object  # motion.Motion of the template, n_frames + 1 frames
    take: mesh_motion.MeshTake  # n_frames + 1 frames
    realism: take.Realism = take.Realism()  # the spec's realism switches
    cloth_layer: cloth.Cloth | None = None  # with cloth_cm > 0
    tapes: tape.TapeLayout | None = None  # with tape
    face_tape: np.ndarray | None = None  # (face,) int8 each face's candidate tape, with tape
    room_seeing: tuple = ()  # per view: (y, x) how many other sensors light the room at each pixel, with tof_artefacts

    @property
    def n_frames(self) -> int:
        return self.take.root.shape[0] - 1

    def surface(self, f: int) -> np.ndarray:
        """The filmed surface's vertices at frame ``f``: the posed skin, or the cloth over it.  (vertex, 3)"""
        skin = self.take.posed.vertices[f]
        if self.cloth_layer is None:
            return skin
        return cloth.cloth_vertices(skin, self.body.faces, self.cloth_layer.thickness)


def build_mesh_rig(shot: take.Take, prims: tuple, placements: tuple, views: tuple) -> MeshRig:
    """The mesh rig: the take ``shot`` filmed by ``views``, the template's reflector ``placements`` on ``prims``
    (the take's template subject) carried onto the mesh."""
    body_, subject = shot.body, shot.subject
    real = take.realism(shot.spec)
    mesh_placements, face_reflector = mesh_reflectors.place_on_mesh(body_, subject, prims, placements)
    layer = tapes = face_tape = None
    if real.cloth_cm > 0:  # its own random stream: the other draws stay as they were
        rng = np.random.default_rng([shot.spec.seed, 6])
        thickness = cloth.cloth_thickness(body_, real.cloth_cm / 100.0, rng)
        slips = cloth.tape_slips(cloth.tape_thickness(body_, mesh_placements, thickness), rng)
        mesh_placements, face_reflector = mesh_reflectors.place_on_mesh(body_, subject, prims, placements, slips)
        layer = cloth.make_cloth(body_, real.cloth_cm / 100.0, cloth.tape_thickness(body_, mesh_placements, thickness),
                                 thickness, rng)
    if real.tape:
        tapes = tape.tape_layout(mesh_placements, np.random.default_rng([shot.spec.seed, 5]))
        face_tape = mesh_reflectors.tape_faces(body_, mesh_placements, tapes.half)
    room_seeing = tuple(_room_seeing(view, views) for view in views) if real.tof else ()
    fine = {name: i for i, name in enumerate(_FINE_PARTS)}
    bone_part = np.array([fine[part_of_bone(n)] for n in body_.bone_names], np.int16)
    face_part = bone_part[body_.vertex_bone[body_.faces[:, 0]]]
    return MeshRig(shot.spec, body_, subject, mesh_placements, face_reflector, face_part, views, shot.motion,
                   shot.mesh, real, layer, tapes, face_tape, room_seeing)


def _room(view: render.View, t: np.ndarray, body_mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The visible surface's world points (y, x, 3), whether each is floor (y, x), and the room's normals (y, x, 3)."""
    world = view.cam.cam_to_world[:3, 3] + (view.rays @ view.R) * t[..., None]
    floor = ~body_mask & (world[..., 2] < 1e-3)
    wall = -np.concatenate([world[..., :2], np.zeros_like(world[..., :1])], axis=-1) / render.ROOM_RADIUS
    return world, floor, np.where(floor[..., None], np.array([0.0, 0.0, 1.0]), wall)


def _room_seeing(view: render.View, views: tuple) -> np.ndarray:
    """How many of the other ``views``' sensors light the empty room at each of ``view``'s pixels.  (y, x) int"""
    world, _, normals = _room(view, view.bg_t, np.zeros(view.bg_t.shape, bool))
    return tof.sensors_seeing(world, normals, [w.cam for w in views if w is not view], np.ones(view.bg_t.shape, bool))


def view_frame(rig: MeshRig, view: render.View, scene: MeshScene, f: int, normals: np.ndarray,
               rng: np.random.Generator, others: tuple = ()) -> render.Frame:
    """One view at frame ``f`` (the posed meshes of f - 1, f and f + 1 are in rig.take); ``others``: the other
    sensors' cameras (their light interferes, with tof_artefacts)."""
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
    n = barycentric(normals[corners], bary)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    cos = view.bg_cos.copy()
    cos.ravel()[idx] = np.abs(np.einsum("ni,ni->n", n @ view.R.T, rays[idx]))
    rest = barycentric(rig.body.vertices[corners], bary)
    labels = rig.face_reflector[face] if rig.tapes is None else tape.label(rig.tapes, rig.face_tape[face], rest)
    if rig.cloth_layer is not None:  # folds lying over parts of the tape
        on = np.flatnonzero(labels >= 0)
        labels[on[cloth.fold_cover(rig.cloth_layer, labels[on].astype(np.int64), rest[on])]] = -1
    rid = np.full(shape, -1, np.int8)
    rid.ravel()[idx] = labels
    reflector = rid >= 0
    here = barycentric(rig.surface(f)[corners], bary)
    flow = np.zeros(shape + (3,), np.float32)
    flow_prev = np.zeros_like(flow)
    flow.reshape(-1, 3)[idx] = (barycentric(rig.surface(f + 1)[corners], bary) - here) @ view.R.T
    flow_prev.reshape(-1, 3)[idx] = (here - barycentric(rig.surface(max(f - 1, 0))[corners], bary)) @ view.R.T
    override = glow = None
    if rig.tapes is None:
        hot = render.saturated(reflector, rig.spec.ir_bloom_px)  # a real sensor saturates round each reflector
    else:  # each tape pixel's own return; the saturated ones flare, the others keep their depth
        on = np.flatnonzero(labels >= 0)
        pix = idx[on]
        override = np.full(shape, np.nan)
        override.ravel()[pix] = tape.tape_ir(rig.tapes, labels[on].astype(np.int64), rest[on], t.ravel()[pix],
                                             cos.ravel()[pix])
        counts = np.nan_to_num(override)
        hot, glow = tape.flare(counts >= render.IR_REFLECTOR, rid, counts, rig.tapes, rig.spec.ir_bloom_px,
                               render.IR_REFLECTOR)
    z = t * view.rays[..., 2]
    dropped = others_seeing = None
    if rig.realism.tof:
        room = rig.room_seeing[[w.cam.name for w in rig.views].index(view.cam.name)]
        z, dropped, others_seeing = _tof(rig, view, z, t, body_mask, idx, n, flow, flow_prev, others, room,
                                         rng.spawn(1)[0])
    depth = render.kinect_depth(z, cos, hot, rng, rig.spec.noise)
    if dropped is not None:
        depth[dropped] = 0
    albedo = view.bg_albedo.copy()
    albedo.ravel()[idx] = render.ALBEDO["body"] * render.cloth_texture(rig.face_part[face], rest)
    ir = render.kinect_ir(t, cos, albedo, hot, rng, rig.spec.noise, override=override, glow=glow)
    if others_seeing is not None:
        ir = tof.interference_ir(ir, others_seeing, hot, rng.spawn(1)[0])
    pixels = np.bincount(rid[reflector].astype(np.int64), minlength=len(rig.placements)).astype(np.int32)
    return render.Frame(depth, ir, rid, body_mask, flow, flow_prev, pixels)


def _tof(rig: MeshRig, view: render.View, z, t, body_mask, idx, n, flow, flow_prev, others, room, rng):
    """The Kinect v2's time-of-flight artefacts on the camera-z map ``z`` (tof.py): multipath near the floor, motion
    smear on fast limbs, flying pixels at silhouettes, the other sensors' interference (``room``: theirs on the empty
    room, rig.room_seeing).
    -> z (y, x), dropped (y, x) bool, other sensors lighting each pixel (y, x) int"""
    world, floor, normals = _room(view, t, body_mask)
    z = tof.multipath(z, view.rays[..., 2], tof.floor_proximity(world, floor, render.ROOM_RADIUS), rng)
    velocity = 0.5 * (flow.astype(np.float64) + flow_prev)  # camera frame, metres per frame
    motion = tof.image_motion(view.rays * t[..., None], velocity, view.cam.fx, view.cam.fy, body_mask, rig.spec.fps)
    z, smeared = tof.motion_smear(z, motion, rng)
    z, _ = tof.flying_pixels(z, rng)
    normals.reshape(-1, 3)[idx] = n
    seeing = np.where(body_mask, tof.sensors_seeing(world, normals, others, body_mask), room)  # the room is static
    z, lost = tof.interference_depth(z, seeing, rig.spec.noise, rng)
    return z, smeared | lost, seeing


def synthesize_mesh(rig: MeshRig, start: int, stop: int) -> xr.Dataset:
    """Frames [start, stop) of the sequence in the raw-sequence schema, with ground truth."""
    if not 0 <= start < stop <= rig.n_frames:
        raise ValueError(f"frames [{start}, {stop}) are outside the sequence's 0-{rig.n_frames}")
    n = stop - start
    stack = render.FrameStack(len(rig.views), n, rig.views[0].bg_t.shape, len(rig.placements))
    posed = rig.take.posed
    surface = posed.vertices[start:stop] if rig.cloth_layer is None else np.stack([rig.surface(f)
                                                                                  for f in range(start, stop)])
    refl3d = mesh_reflectors.reflector_positions(rig.body, rig.placements, surface)  # the tape, on the cloth if any
    for i, f in enumerate(range(start, stop)):
        scene = MeshScene(surface[i], rig.body.faces)
        normals = vertex_normals(surface[i], rig.body.faces)
        for v, view in enumerate(rig.views):
            others = tuple(w.cam for w in rig.views if w is not view)
            stack.put(v, i, view_frame(rig, view, scene, f, normals, np.random.default_rng([rig.spec.seed, v, f]),
                                       others))
    joint_quats = Rotation.from_matrix(rig.motion.local_rot[start:stop].reshape(-1, 3, 3)).as_quat().reshape(n, -1, 4)
    bone_quats = Rotation.from_matrix(rig.take.rotations[start:stop].reshape(-1, 3, 3)).as_quat().reshape(n, -1, 4)
    extra = {"gt_bone_rotations": (("frame", "bone", "quat"), bone_quats),
             "gt_root": (("frame", "xyz"), rig.take.root[start:stop])}
    ds = stack.dataset(rig.views, rig.spec.fps, start, refl3d, posed.heads[start:stop][:, rig.body.joint_bones()],
                       joint_quats, extra)
    ds = ds.assign_coords(bone=np.array(rig.body.bone_names, dtype=object))
    ds.attrs.update(body="mesh", body_model=f"anny {_anny_version()}", phenotype=asdict(rig.body.phenotype),
                    mesh_studio_version=MESH_STUDIO_VERSION, exercise=rig.motion.label,
                    **({"realism": asdict(rig.realism)} if rig.realism.any else {}),
                    subject=asdict(rig.subject), seed=rig.spec.seed, noise=rig.spec.noise,
                    reflector_kinds=[p.kind for p in rig.placements],
                    joint_parents=[int(p) for p in body.PARENTS],
                    bone_parents=[int(p) for p in rig.body.bone_parents])
    return ds


def _anny_version() -> str:
    from importlib.metadata import version

    return version("anny")
