"""The studio's core: a take, what every system films.

A take is a subject, a motion and the posed mesh of every frame, with the ground truth that follows from them:
``make_take`` draws the Anny body from the sequence's seed (its own random stream, ``[seed, 2]``), makes the
template subject of the same height perform the motion (an exercise, or a BVH clip retargeted onto it) and
skins the whole motion onto the mesh. Each system's filming module then turns a take into that system's raw
dataset: the DeepMoCap sensors (synth.py, mesh_synth.py), a UUO marker layout (uuo_takes.py), the suit's grey
cameras (suit_takes.py). Nothing here places reflectors or cameras.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.tasks.shared import body
from mocapflow.tasks.shared.mesh_body import HEIGHT_RANGE_M, MeshBody, mesh_body, random_phenotype
from mocapflow.tasks.studio import bvh, mesh_motion, motion


class RealismError(ValueError):
    """A realism switch with a value the studio cannot film."""


@dataclass(frozen=True)
class Realism:
    """How real the DeepMoCap studio's reflectors and sensors are (every switch off: the studio as it was).

    tape: the reflectors drawn as 2-inch tape of their real size, unevenly saturating and flaring (tape.py);
    cloth_cm: a cloth layer 0 to this many cm thick over the skin, carrying, moving and partly hiding the tape
    (cloth.py; 0: bare skin); tof: the Kinect v2's time-of-flight artefacts (tof.py).
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
    spec: object  # synth.SequenceSpec: the motion, frames, fps and seed of the take
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


def performed_motion(spec, subject: body.Subject, bvh_text: str | None) -> motion.Motion:
    """The motion ``subject`` performs, n_frames + 1 frames: the BVH clip retargeted (``spec.motion == "bvh"``),
    else the procedural exercise."""
    if spec.motion == "bvh":
        if bvh_text is None:
            raise ValueError("motion 'bvh' needs the clip's text")
        frames = None if spec.frames is None else spec.frames + 1
        return bvh.retarget(bvh.parse_bvh(bvh_text), subject, fps=spec.fps, n_frames=frames, start_s=spec.start_s,
                            label=spec.label or "bvh", user_map=spec.motion_map)
    return motion.exercise(spec.motion, subject, n_frames=(spec.frames or 90) + 1, fps=spec.fps, speed=spec.speed,
                           amplitude=spec.amplitude, repetitions=spec.repetitions, heading_deg=spec.heading_deg,
                           variation=spec.variation, seed=spec.seed)


def make_take(spec, bvh_text: str | None = None) -> Take:
    """The take ``spec`` describes, on the mesh body."""
    body_, subject = mesh_subject(spec)
    mot = performed_motion(spec, subject, bvh_text)
    return Take(spec, body_, subject, mot, mesh_motion.retarget(body_, subject, mot))
