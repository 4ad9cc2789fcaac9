"""One studio sequence: a subject, its reflectors, a motion and a camera layout, rendered by frame region.

``build_rig`` fixes everything a sequence's seed and spec determine (subject, placement jitter,
cameras, the whole motion); ``synthesize`` renders frames [start, stop) of it as a raw-sequence
Dataset with every ground-truth group. Each frame's sensor noise is seeded by (seed, view, frame),
so any region renders the same bytes whether it is computed alone or as part of a longer run.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared import body, reflectors
from mocapflow.tasks.shared.bvh_clip import BVHClip
from mocapflow.tasks.shared.kinematics import forward_kinematics
from mocapflow.tasks.deepmocap.film import mesh_synth, render
from mocapflow.tasks.studio import cameras, motion, take
from mocapflow.tasks.studio.spec import STUDIO_VERSION, SequenceSpec


@dataclass(frozen=True)
class Rig:
    spec: SequenceSpec
    subject: body.Subject
    prims: tuple
    placements: tuple
    views: tuple  # render.View per camera
    motion: motion.Motion  # n_frames + 1 frames (the extra one gives the last frame's scene flow)
    joint_rot: np.ndarray  # (frame + 1, joint, 3, 3)
    joint_pos: np.ndarray  # (frame + 1, joint, 3)

    @property
    def n_frames(self) -> int:
        return self.joint_pos.shape[0] - 1

    def pose(self, f: int) -> render.Pose:
        return render.Pose(self.joint_rot[f], self.joint_pos[f])


def build_rig(spec: SequenceSpec, clip: BVHClip | None = None) -> Rig | mesh_synth.MeshRig:
    """Everything fixed by ``spec``: the subject, placements, cameras and the whole motion (on the mesh body: the
    take of tasks/studio/take.py, filmed by the same sensors)."""
    rng = np.random.default_rng([spec.seed, 1])
    subject = body.random_subject(rng, spec.subject_height)
    shot = None
    if spec.body == "mesh":  # the template of the mesh's height performs the motion; the draws above stay
        shot = take.make_take(spec, clip)
        subject = shot.subject
    prims = body.surface(subject)
    placements = reflectors.place(prims, rng, spec.jitter)
    layout_spec = spec.layout or (cameras.random_ring(rng, spec.views) if spec.random_layout else None)
    if spec.camera_roll_deg:  # a random ring (checked by SequenceSpec); its own stream: the draws above stay
        layout_spec["ring"]["roll_deg"] = cameras.random_rolls(np.random.default_rng([spec.seed, 2]), spec.views,
                                                               spec.camera_roll_deg)
    cams = cameras.layout(layout_spec, views=spec.views, rng=rng if spec.random_layout else None)
    views = tuple(render.prepare_view(c) for c in cams)
    if shot is not None:
        return mesh_synth.build_mesh_rig(shot, prims, placements, views)
    mot = take.performed_motion(spec, subject, clip)
    rot, pos = forward_kinematics(mot.local_rot, mot.root_pos, body.rest_offsets(subject), body.PARENTS)
    return Rig(spec, subject, prims, placements, views, mot, rot, pos)


def synthesize(rig: Rig | mesh_synth.MeshRig, start: int, stop: int) -> xr.Dataset:
    """Frames [start, stop) of the sequence in the raw-sequence schema, with ground truth."""
    if isinstance(rig, mesh_synth.MeshRig):
        return mesh_synth.synthesize_mesh(rig, start, stop)
    if not 0 <= start < stop <= rig.n_frames:
        raise ValueError(f"frames [{start}, {stop}) are outside the sequence's 0-{rig.n_frames}")
    n = stop - start
    stack = render.FrameStack(len(rig.views), n, rig.views[0].bg_t.shape, len(rig.placements))
    refl3d = reflectors.world_positions(rig.placements, rig.prims, rig.joint_rot[start:stop], rig.joint_pos[start:stop])
    for v, view in enumerate(rig.views):
        for i, f in enumerate(range(start, stop)):
            stack.put(v, i, render.render(view, rig.prims, rig.placements, rig.pose(f), rig.pose(max(f - 1, 0)),
                                          rig.pose(f + 1), np.random.default_rng([rig.spec.seed, v, f]), rig.spec.noise,
                                          bloom_px=rig.spec.ir_bloom_px))
    quats = Rotation.from_matrix(rig.motion.local_rot[start:stop].reshape(-1, 3, 3)).as_quat().reshape(n, -1, 4)
    ds = stack.dataset(rig.views, rig.spec.fps, start, refl3d, rig.joint_pos[start:stop], quats)
    ds.attrs.update(exercise=rig.motion.label, subject=asdict(rig.subject), studio_version=STUDIO_VERSION,
                    seed=rig.spec.seed, noise=rig.spec.noise,
                    reflector_kinds=[p.kind for p in rig.placements],
                    joint_parents=[int(p) for p in body.PARENTS])
    return ds
