"""The studio's core: a take, what every system films.

A take is a subject, a motion and the posed mesh of every frame, with the ground truth that follows from them:
``make_take`` draws the Anny body from the sequence's seed (its own random stream, ``[seed, 2]``), makes the
template subject of the same height perform the motion (an exercise, or a BVH clip retargeted onto it) and
skins the whole motion onto the mesh. Each system's filming module then turns a take into that system's raw
dataset: the DeepMoCap sensors (tasks/deepmocap/film), a UUO marker layout (tasks/uuo/takes.py), the suit's grey
cameras (tasks/suit/takes.py). Nothing here places reflectors or cameras.

A joint take (one performance filmed by several systems at their own rates, pipeline/compare.py) has a clock:
``spec.time_base_fps`` (TIME_BASE_FPS, set by systems/studio/specs.py for every dataset of a catalog's
``joint_take``). Its motion is then resampled, centred and put on the floor once, at that rate over the window
(``start_s``, ``frames / fps``: the same for every system), and the mesh's stance lift worked out once on it
(mesh_motion.stance_lift); each system's frames are sampled from that one motion at their instants (copied where
an instant is on the clock, interpolated between), so every system's truth of a shared instant is one. Without
a clock a take is resampled and centred at its own fps, so the instants it films set its centring, floor height
and stance lift: the same clip filmed at 30 and 5 fps differed by up to 9.6 mm at the same instant.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from mocapflow.tasks.shared import body
from mocapflow.tasks.shared.bvh_clip import BVHClip
from mocapflow.tasks.shared.mesh_body import HEIGHT_RANGE_M, MeshBody, mesh_body, random_phenotype
from mocapflow.tasks.studio import mesh_motion, motion, retarget


TIME_BASE_FPS = 120.0  # a joint take's clock: CMU's rate, which 5, 10, 15, 20, 24, 30, 40 and 60 fps all sample


class RealismError(ValueError):
    """A realism switch with a value the studio cannot film."""


@dataclass(frozen=True)
class Realism:
    """How real the DeepMoCap studio's reflectors and sensors are (every switch off: the studio as it was).

    Filmed by tasks/deepmocap/film: tape: the reflectors drawn as 2-inch tape of their real size, unevenly
    saturating and flaring (tape.py); cloth_cm: a cloth layer 0 to this many cm thick over the skin, carrying,
    moving and partly hiding the tape (cloth.py; 0: bare skin); tof: the Kinect v2's time-of-flight artefacts
    (tof.py).
    """

    tape: bool = False
    cloth_cm: float = 0.0
    tof: bool = False

    def __post_init__(self):
        if not 0 <= self.cloth_cm <= 3:
            raise RealismError(f"cloth_cm = {self.cloth_cm!r}: clothes stand 0-3 cm off the skin; give cloth_cm "
                               "between 0 (bare skin) and 3")

    @property
    def any(self) -> bool:
        return self.tape or self.cloth_cm > 0 or self.tof


def realism(spec) -> Realism:
    """The realism switches of a sequence spec (all off where it has none)."""
    return Realism(bool(getattr(spec, "tape", False)), float(getattr(spec, "cloth_cm", 0.0)),
                   bool(getattr(spec, "tof_artefacts", False)))


@dataclass(frozen=True)
class Take:
    spec: object  # spec.SequenceSpec: the motion, frames, fps and seed of the take
    body: MeshBody  # the subject's mesh body
    subject: body.Subject  # the template body of the same height that performs the motion
    motion: motion.Motion  # the template's motion, n_frames + 1 frames (the extra one gives the last frame's flow)
    mesh: mesh_motion.MeshTake  # the motion skinned onto the mesh, n_frames + 1 frames

    @property
    def n_frames(self) -> int:
        return self.mesh.root.shape[0] - 1


def mesh_subject(spec) -> tuple[MeshBody, body.Subject]:
    """The take's Anny body (from its own random stream ``[seed, 2]``) and the template subject of its height
    (a body asked for at the range's end measures a few micrometres past it: held to the range)."""
    body_ = mesh_body(random_phenotype(np.random.default_rng([spec.seed, 2]), spec.subject_height))
    return body_, body.Subject(height=float(np.clip(body_.height, *HEIGHT_RANGE_M)))


def performed_motion(spec, subject: body.Subject, clip: BVHClip | None) -> motion.Motion:
    """The motion ``subject`` performs, n_frames + 1 frames: the parsed clip (a BVH file's or an AMC take's, read
    by formats/) retargeted (``spec.motion == "bvh"``), else the procedural exercise; with a clock
    (``spec.time_base_fps``) sampled from the motion at that rate."""
    if getattr(spec, "time_base_fps", None) is not None:
        base, times = clocked_motion(spec, subject, clip)
        return sample_motion(base, times, spec.fps)
    return _motion(spec, subject, clip)


def _motion(spec, subject: body.Subject, clip: BVHClip | None) -> motion.Motion:
    if spec.motion == "bvh":
        if clip is None:
            raise ValueError("motion 'bvh' needs the parsed clip (formats/bvh.py parse_bvh, formats/asf_amc.py)")
        frames = None if spec.frames is None else spec.frames + 1
        return retarget.retarget(clip, subject, fps=spec.fps, n_frames=frames, start_s=spec.start_s,
                                 label=spec.label or "bvh", user_map=spec.motion_map)
    return motion.exercise(spec.motion, subject, n_frames=(spec.frames or 90) + 1, fps=spec.fps, speed=spec.speed,
                           amplitude=spec.amplitude, repetitions=spec.repetitions, heading_deg=spec.heading_deg,
                           variation=spec.variation, seed=spec.seed)


def clocked_motion(spec, subject: body.Subject, clip: BVHClip | None) -> tuple[motion.Motion, np.ndarray]:
    """A take with a clock: the motion resampled (and centred, and put on the floor) once at ``spec.time_base_fps``
    over the take's window, whatever its own fps, and the instants of its n_frames + 1 frames (s from the window's
    start: ``frame / fps``)."""
    rate = float(spec.time_base_fps)
    clip = clip if spec.motion == "bvh" else None
    if spec.frames is None and clip is not None:  # the clip from start_s to its end, on the clock as far as it goes
        samples, frames = retarget.available_frames(clip, spec.fps, spec.start_s), None
    else:
        samples = (spec.frames or 90) + 1
        frames = int(np.ceil((samples - 1) / spec.fps * rate - 1e-6))  # the window's length on the clock
        if clip is not None:  # a window that does not end on the clock ends in its last step (< 1 / rate)
            frames = min(frames, retarget.available_frames(clip, rate, spec.start_s) - 1)
    base = _motion(dataclasses.replace(spec, fps=rate, frames=frames, time_base_fps=None), subject, clip)
    return base, np.arange(samples) / spec.fps


def on_clock(times: np.ndarray, fps: float, count: int) -> tuple[np.ndarray, np.ndarray]:
    """For instants ``times`` (s) on a clock of ``count`` ticks at ``fps``: the tick of each and whether it is on
    one (within a microsecond; else it lies between two, or past the last)."""
    ticks = times * fps
    index = np.round(ticks).astype(np.int64)
    on = (np.abs(ticks - index) < 1e-6 * fps) & (index < count)
    return np.minimum(index, count - 1), on


def sample_values(values: np.ndarray, fps: float, times: np.ndarray) -> np.ndarray:
    """``values`` (tick, ...) of a clock at ``fps`` at ``times`` (s): copied on a tick, linear in between (held past
    the last)."""
    index, on = on_clock(times, fps, len(values))
    out = values[index].astype(np.float64)
    if not on.all():
        ticks = np.arange(len(values)) / fps
        flat = values.reshape(len(values), -1)
        out[~on] = np.stack([np.interp(times[~on], ticks, flat[:, k]) for k in range(flat.shape[1])],
                            axis=1).reshape((-1,) + values.shape[1:])
    return out


def sample_motion(base: motion.Motion, times: np.ndarray, fps: float) -> motion.Motion:
    """``base`` (on its clock, ``base.fps``, from the window's start) at ``times`` (s), as a motion at ``fps``: a
    frame on a tick is that tick's; one between ticks has the rotations slerped and the root interpolated."""
    n = len(base.root_pos)
    index, on = on_clock(times, base.fps, n)
    local = base.local_rot[index].copy()
    if not on.all():
        ticks = np.arange(n) / base.fps
        t = np.clip(times[~on], 0.0, ticks[-1])
        for j in range(local.shape[1]):
            local[~on, j] = Slerp(ticks, Rotation.from_matrix(base.local_rot[:, j]))(t).as_matrix()
    return motion.Motion(local, sample_values(base.root_pos, base.fps, times), fps, base.label)


def make_take(spec, clip: BVHClip | None = None) -> Take:
    """The take ``spec`` describes, on the mesh body (with a clock: sampled from the motion on the clock, the mesh
    lifted as the clock's stance frames say)."""
    body_, subject = mesh_subject(spec)
    if getattr(spec, "time_base_fps", None) is None:
        mot = performed_motion(spec, subject, clip)
        return Take(spec, body_, subject, mot, mesh_motion.retarget(body_, subject, mot))
    base, times = clocked_motion(spec, subject, clip)
    mot = sample_motion(base, times, spec.fps)
    lift = sample_values(mesh_motion.stance_lift(body_, subject, base), base.fps, times)
    return Take(spec, body_, subject, mot, mesh_motion.retarget(body_, subject, mot, lift))
