"""What the studio films: a sequence's spec (subject, motion, cameras and the realism switches) and the versions of
the studio's takes that every studio dataset's fingerprint names (systems/studio/specs.py).

The spec is the one all systems film from (DeepMoCap's sensors, UUO's markers, the suit's cameras); the realism
switches and ``ir_bloom_px`` only change DeepMoCap's filming (tasks/deepmocap/film/).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from mocapflow.tasks.studio import take

STUDIO_VERSION = "2"
MESH_STUDIO_VERSION = "1"  # the take on the mesh body (tasks/studio/take.py)
BODIES = ("capsule", "mesh")


REALISM_FIELDS = ("tape", "cloth_cm", "tof_artefacts")
REALISM_VERSION = "1"  # a sequence with a realism switch on is re-rendered when its rendering changes


@dataclass(frozen=True)
class SequenceSpec:
    """What to film: ``motion`` is an exercise name, or ``"bvh"`` with the parsed clip given to build_rig."""

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
    body: str = "capsule"  # the subject: "capsule" (the template's primitives) or "mesh" (Anny, tasks/deepmocap/film/mesh_synth.py)
    motion_map: Mapping[str, str] | None = None  # a BVH clip's joint map {template joint: BVH joint} (retarget.joint_map)
    # DeepMoCap's reflectors and sensors as they really are, on the mesh body only (take.Realism; all off by default)
    tape: bool = False  # reflectors as real 2-inch tape (tasks/deepmocap/film/tape.py)
    cloth_cm: float = 0.0  # cloth up to this thick over the skin, 0-3 cm (tasks/deepmocap/film/cloth.py)
    tof_artefacts: bool = False  # the Kinect v2's time-of-flight artefacts (tasks/deepmocap/film/tof.py)
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
