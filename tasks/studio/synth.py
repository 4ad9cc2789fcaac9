"""One studio sequence: a subject, its reflectors, a motion and a camera layout, rendered by frame region.

``build_rig`` fixes everything a sequence's seed and spec determine (subject, placement jitter,
cameras, the whole motion); ``synthesize`` renders frames [start, stop) of it as a raw-sequence
Dataset with every ground-truth group. Each frame's sensor noise is seeded by (seed, view, frame),
so any region renders the same bytes whether it is computed alone or as part of a longer run.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Mapping

import numpy as np
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared import body, reflectors
from mocapflow.tasks.shared.kinematics import forward_kinematics
from mocapflow.tasks.studio import cameras, mesh_synth, motion, render, take

STUDIO_VERSION = "2"
BODIES = ("capsule", "mesh")


REALISM_FIELDS = ("tape", "cloth_cm", "tof_artefacts")
REALISM_VERSION = "1"  # a sequence with a realism switch on is re-rendered when its rendering changes


@dataclass(frozen=True)
class SequenceSpec:
    """What to film: ``motion`` is an exercise name, or ``"bvh"`` with the clip's text given to build_rig."""

    motion: str
    frames: int | None = 90
    fps: float = 30.0
    views: int = 3
    seed: int = 0
    subject_height: float | None = None
    noise: float = 1.0
    speed: float = 1.0
    amplitude: float = 1.0
    repetitions: float | None = None
    start_s: float = 0.0
    jitter: float = 1.0
    heading_deg: float = 0.0
    variation: float = 0.0  # random posture, heading and drift on an exercise (motion.vary, motion.wander)
    random_layout: bool = False
    camera_roll_deg: float = 0.0  # with random_layout: each sensor rolled by up to this many degrees either way
    ir_bloom_px: int = 0  # the sensor's saturation spreads this many whole pixels round each reflector (render.saturated)
    layout: Mapping[str, Any] | None = None
    label: str = ""  # the motion's name in the ground truth (defaults to ``motion``)
    body: str = "capsule"  # the subject: "capsule" (the template's primitives) or "mesh" (Anny, tasks/studio/mesh_synth.py)
    motion_map: Mapping[str, str] | None = None  # a BVH clip's joint map {template joint: BVH joint} (bvh.joint_map)
    # DeepMoCap's reflectors and sensors as they really are, on the mesh body only (take.Realism; all off by default)
    tape: bool = False  # reflectors as real 2-inch tape (tasks/studio/tape.py)
    cloth_cm: float = 0.0  # cloth up to this thick over the skin, 0-3 cm (tasks/studio/cloth.py)
    tof_artefacts: bool = False  # the Kinect v2's time-of-flight artefacts (tasks/studio/tof.py)
    # a joint take's clock: the motion resampled and centred once at this rate over the window, and every frame sampled
    # from that (take.clocked_motion), so takes of one performance at any fps hold one truth per instant (None: the
    # motion resampled and centred at the sequence's own fps, as a single-system catalog films it)
    time_base_fps: float | None = None

    def __post_init__(self):
        if self.frames is not None and self.frames <= 0:
            raise ValueError(f"frames must be positive, got {self.frames}")
        if self.fps <= 0 or self.views <= 0 or self.noise < 0:
            raise ValueError(f"fps ({self.fps}) and views ({self.views}) must be positive, noise ({self.noise}) >= 0")
        if not 0 <= self.camera_roll_deg <= 45:
            raise ValueError(f"camera_roll_deg must be within 0-45 degrees (a real rig's sensors sit 1-3 off level), "
                             f"got {self.camera_roll_deg}")
        if self.camera_roll_deg and (not self.random_layout or self.layout is not None):
            raise ValueError(f"camera_roll_deg ({self.camera_roll_deg}) rolls a random ring's sensors: set "
                             "random_layout: true without a layout, or give the layout's sensors (or ring) a roll_deg")
        if not 0 <= self.ir_bloom_px <= 20:
            raise ValueError(f"ir_bloom_px must be within 0-20 pixels (a real Kinect v2's reflector regions need about 3), "
                             f"got {self.ir_bloom_px}")
        if self.time_base_fps is not None and not self.time_base_fps > 0:
            raise ValueError(f"time_base_fps must be positive (the rate a joint take's motion is sampled at once, e.g. "
                             f"120), got {self.time_base_fps}")
        if self.variation < 0:
            raise ValueError(f"variation must be >= 0 (0 = the textbook exercise), got {self.variation}")
        if self.body not in BODIES:
            raise ValueError(f"body must be one of {', '.join(BODIES)}, got {self.body!r}")
        if self.motion_map is not None and self.motion != "bvh":
            raise ValueError(f"motion_map maps a BVH clip's joints; the exercise {self.motion!r} has none, so leave "
                             "motion_map out")
        if self.variation and self.motion == "bvh":
            raise ValueError(f"variation ({self.variation}) applies to the procedural exercises; a BVH clip is "
                             "played as recorded, so leave variation out")
        if take.realism(self).any and self.body != "mesh":  # realism() checks the values
            on = ", ".join(f"{k}: {getattr(self, k)}" for k in REALISM_FIELDS if getattr(self, k))
            raise take.RealismError(f"{on} is filmed on the mesh body only, not body {self.body!r}; set body: mesh, "
                                    "or leave those fields out")


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


def build_rig(spec: SequenceSpec, bvh_text: str | None = None) -> Rig | mesh_synth.MeshRig:
    """Everything fixed by ``spec``: the subject, placements, cameras and the whole motion (on the mesh body: the
    take of tasks/studio/take.py, filmed by the same sensors)."""
    rng = np.random.default_rng([spec.seed, 1])
    subject = body.random_subject(rng, spec.subject_height)
    shot = None
    if spec.body == "mesh":  # the template of the mesh's height performs the motion; the draws above stay
        shot = take.make_take(spec, bvh_text)
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
    mot = take.performed_motion(spec, subject, bvh_text)
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
