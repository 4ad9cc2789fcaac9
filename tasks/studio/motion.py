"""Procedural library of DMC3D's 15 exercises (DeepMoCap §4, Table 1) on the template body, and of motions
its exercises lack (``ATHLETIC``: kicks, hops, jumps, turns, crossing legs, dance, a sprint's limb speeds).

Each exercise is a set of joint-angle curves over a phase ``phi`` (one repetition = 2*pi), with
speed (repetitions per second), amplitude (a factor on the nominal angles) and repetitions as
parameters. Angles use the template's rest axes (x right, y forward, z up); the feet are planted
on the floor on every frame (jumps lift them on top of that).

``variation`` (0 = the textbook exercise) overlays smooth random joint-angle curves, a wandering
heading and a drifting root on the exercise, so that no two performances share the same posture:
the domain randomization that lets a network trained on these exercises meet real, untidy motion.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared.body import JOINT_INDEX, JOINTS, PARENTS, Subject, rest_offsets, surface
from mocapflow.tasks.shared.kinematics import forward_kinematics

ARMS_DOWN = np.radians(78.0)  # shoulder adduction from the T-pose to relaxed arms


@dataclass(frozen=True)
class Motion:
    """Local joint rotations and root positions at the studio's frame rate."""

    local_rot: np.ndarray  # (frame, joint, 3, 3)
    root_pos: np.ndarray  # (frame, 3) metres
    fps: float
    label: str

    @property
    def n_frames(self) -> int:
        return self.root_pos.shape[0]


class _Pose:
    """Accumulates per-joint rotations (applied in call order, each in the parent frame) and root offsets."""

    def __init__(self, n: int):
        self.n = n
        self.rot = np.tile(np.eye(3), (n, len(JOINTS), 1, 1))
        self.root = np.zeros((n, 3))
        self.air = np.zeros(n)

    def turn(self, joint: str, axis: str, angle) -> "_Pose":
        angle = np.broadcast_to(np.asarray(angle, float), (self.n,))
        r = Rotation.from_euler(axis, angle[:, None]).as_matrix()
        j = JOINT_INDEX[joint]
        self.rot[:, j] = r @ self.rot[:, j]
        return self

    def arms_down(self, left=0.0, right=0.0) -> "_Pose":
        """Relaxed arms; ``left``/``right`` raise them sideways (abduction, radians)."""
        self.turn("RightShoulder", "y", ARMS_DOWN - np.asarray(right))
        return self.turn("LeftShoulder", "y", -(ARMS_DOWN - np.asarray(left)))

    def arm_forward(self, side: str, angle) -> "_Pose":
        return self.turn(f"{side}Shoulder", "x", angle)  # flexion: raise forward

    def elbow(self, side: str, angle) -> "_Pose":
        return self.turn(f"{side}Elbow", "z", angle if side == "Right" else -np.asarray(angle))

    def hip(self, side: str, flex=0.0, abduct=0.0) -> "_Pose":
        self.turn(f"{side}Hip", "y", -np.asarray(abduct) if side == "Right" else abduct)
        return self.turn(f"{side}Hip", "x", flex)

    def knee(self, side: str, angle) -> "_Pose":
        return self.turn(f"{side}Knee", "x", -np.asarray(angle))

    def ankle(self, side: str, angle) -> "_Pose":
        return self.turn(f"{side}Ankle", "x", angle)

    def spine(self, flex=0.0, side_bend=0.0, twist=0.0) -> "_Pose":
        self.turn("SpineBase", "z", twist)
        self.turn("SpineBase", "y", side_bend)
        return self.turn("SpineBase", "x", -np.asarray(flex))


def _pos(x):
    return np.maximum(x, 0.0)


def _strides(p, phi, a, hip_deg: float, knee_deg: float, arm_deg: float):
    """Alternating knee lifts with opposite arm swings (walking, running in place); -> sin(phi)."""
    s = np.sin(phi)
    for side, sign in (("Right", 1), ("Left", -1)):
        lift = _pos(sign * s)
        p.hip(side, flex=a * np.radians(hip_deg) * lift).knee(side, a * np.radians(knee_deg) * lift)
        p.arm_forward(side, -sign * a * np.radians(arm_deg) * s)
    return s


def _walk(p, phi, a):
    _strides(p, phi, a, 45, 70, 20)
    p.arms_down().elbow("Right", np.radians(15)).elbow("Left", np.radians(15))


def _single_arm_raise(p, phi, a):
    raise_ = a * np.radians(150) * (1 - np.cos(phi)) / 2
    p.arms_down().arm_forward("Right", raise_)


def _elbow_flexion(p, phi, a):
    bend = a * np.radians(130) * (1 - np.cos(phi)) / 2
    p.arms_down(np.radians(8), np.radians(8)).elbow("Right", bend).elbow("Left", bend)


def _knee_flexion(p, phi, a):
    for side, shift in (("Right", 0.0), ("Left", np.pi)):
        bend = _pos(np.sin(phi / 2 + shift / 2)) ** 2 * (np.sin(phi) * (1 if side == "Right" else -1) > 0)
        p.hip(side, flex=a * np.radians(15) * bend).knee(side, a * np.radians(105) * bend)
    p.arms_down(np.radians(10), np.radians(10))


def _closing_arms(p, phi, a):
    up = a * np.radians(165) * (1 - np.cos(phi)) / 2
    p.arms_down(up, up)


def _side_steps(p, phi, a):
    p.root[:, 0] = a * 0.35 * np.sin(phi)
    for side, sign in (("Right", 1), ("Left", -1)):
        lift = _pos(sign * np.cos(phi))
        p.hip(side, abduct=a * np.radians(15) * lift, flex=np.radians(10) * lift).knee(side, np.radians(25) * lift)
    p.arms_down(np.radians(10), np.radians(10))


def _jumping_jack(p, phi, a):
    open_ = (1 - np.cos(phi)) / 2
    p.arms_down(a * np.radians(160) * open_, a * np.radians(160) * open_)
    for side in ("Right", "Left"):
        p.hip(side, abduct=a * np.radians(16) * open_).knee(side, np.radians(12) * np.abs(np.sin(phi)))
    p.air[:] = a * 0.09 * np.abs(np.sin(phi))


def _butt_kicks(p, phi, a):
    s = np.sin(phi)
    for side, sign in (("Right", 1), ("Left", -1)):
        kick = _pos(sign * s)
        p.hip(side, flex=np.radians(8) * kick).knee(side, a * np.radians(125) * kick)
        p.arm_forward(side, -sign * np.radians(30) * s)
    p.arms_down(np.radians(12), np.radians(12)).elbow("Right", np.radians(85)).elbow("Left", np.radians(85))
    p.air[:] = 0.03 * np.abs(s)


def _lunge(p, phi, a):
    for side, sign in (("Right", 1), ("Left", -1)):
        depth = _pos(sign * np.sin(phi)) * a
        other = "Left" if side == "Right" else "Right"
        p.hip(side, flex=np.radians(80) * depth).knee(side, np.radians(90) * depth)
        p.hip(other, flex=-np.radians(25) * depth).knee(other, np.radians(85) * depth)
        p.root[:, 1] += 0.3 * depth
    p.arms_down()
    p.spine(flex=np.radians(5))


def _squat(p, phi, a):
    d = a * (1 - np.cos(phi)) / 2
    p.spine(flex=np.radians(35) * d)
    for side in ("Right", "Left"):
        p.hip(side, flex=np.radians(95) * d, abduct=np.radians(8)).knee(side, np.radians(110) * d)
        p.ankle(side, np.radians(25) * d)
        p.arm_forward(side, np.radians(85) * d)
    p.arms_down()
    p.root[:, 1] = -0.12 * d


def _side_step_knee_elbow(p, phi, a):
    _side_steps(p, phi, 0.6 * a)
    for side, sign in (("Right", 1), ("Left", -1)):
        up = _pos(sign * np.sin(phi)) * a
        other = "Left" if side == "Right" else "Right"
        p.hip(side, flex=np.radians(85) * up).knee(side, np.radians(90) * up)
        p.arm_forward(other, np.radians(70) * up).elbow(other, np.radians(110) * up)
        p.spine(twist=sign * np.radians(25) * up, flex=np.radians(15) * up)


def _side_reach(p, phi, a, sides=("Right",)):
    for side in sides:
        sign = 1 if side == "Right" else -1
        reach = (_pos(sign * np.sin(phi)) if len(sides) > 1 else (1 - np.cos(phi)) / 2) * a
        if side == "Right":
            p.arms_down(0.0, np.radians(170) * reach)
        else:
            p.arms_down(np.radians(170) * reach, 0.0)
        p.spine(side_bend=-sign * np.radians(30) * reach)


def _side_reaches(p, phi, a):
    _side_reach(p, phi, a)


def _alternate_side_reaches(p, phi, a):
    sign = np.sin(phi)
    right, left = _pos(sign) * a, _pos(-sign) * a
    p.arms_down(np.radians(170) * left, np.radians(170) * right)
    p.spine(side_bend=-np.radians(30) * right + np.radians(30) * left)


def _side_jumps(p, phi, a):
    p.root[:, 0] = a * 0.3 * np.sign(np.sin(phi)) * np.minimum(1, 3 * np.abs(np.sin(phi)))
    flight = _pos(np.cos(2 * phi))
    p.air[:] = a * 0.12 * flight
    for side in ("Right", "Left"):
        p.hip(side, flex=np.radians(30) * (1 - flight)).knee(side, np.radians(45) * (1 - flight))
    p.arms_down(np.radians(25), np.radians(25))


def _kick_box(p, phi, a):
    for side, sign in (("Right", 1), ("Left", -1)):
        kick = _pos(sign * np.sin(phi)) ** 1.5 * a
        chamber = np.sin(np.clip(kick * np.pi, 0, np.pi))
        p.hip(side, flex=np.radians(85) * kick).knee(side, np.radians(80) * chamber)
        p.arm_forward(side, np.radians(55)).elbow(side, np.radians(120))
    p.arms_down(np.radians(20), np.radians(20))
    p.spine(flex=-np.radians(8) * np.abs(np.sin(phi)) * a)


# ---- beyond DMC3D: motions of kinds its exercises lack (fast limbs, flight, turns, crossing legs) -------------

def _front_kick(p, phi, a):
    for side, sign in (("Right", 1), ("Left", -1)):
        kick = _pos(sign * np.sin(phi)) ** 2 * a  # a snap up and back, one leg per half repetition
        p.hip(side, flex=np.radians(105) * kick).knee(side, np.radians(70) * np.sin(np.clip(kick * np.pi, 0, np.pi)))
        p.arm_forward(side, -np.radians(35) * kick * sign)
    p.arms_down(np.radians(25), np.radians(25)).elbow("Right", np.radians(70)).elbow("Left", np.radians(70))
    p.spine(flex=-np.radians(12) * np.abs(np.sin(phi)) * a)


def _hop_on_one_leg(p, phi, a):
    flight = _pos(np.sin(phi))
    p.hip("Left", flex=np.radians(35)).knee("Left", np.radians(85))  # the free leg held up behind
    p.hip("Right", flex=np.radians(20) * (1 - flight)).knee("Right", np.radians(35) * (1 - flight))
    p.ankle("Right", -np.radians(20) * flight)
    p.arms_down(np.radians(35) * flight + np.radians(15), np.radians(35) * flight + np.radians(15))
    p.air[:] = a * 0.14 * flight


def _tuck_jump(p, phi, a):
    flight = _pos(np.sin(phi)) ** 1.5 * a
    crouch = _pos(-np.sin(phi)) * a  # the take-off and the landing
    for side in ("Right", "Left"):
        p.hip(side, flex=np.radians(95) * flight + np.radians(45) * crouch)
        p.knee(side, np.radians(120) * flight + np.radians(80) * crouch)
        p.arm_forward(side, np.radians(110) * flight - np.radians(30) * crouch)
    p.arms_down()
    p.spine(flex=np.radians(20) * crouch + np.radians(10) * flight)
    p.air[:] = 0.4 * flight


def _turn_around(p, phi, a):
    p.turn("Hips", "z", a * phi)  # a whole turn per repetition, stepping round
    _walk(p, 4 * phi, 0.6 * a)


def _crossing_legs(p, phi, a):
    p.root[:, 0] = a * 0.45 * np.sin(phi / 2)  # the grapevine travels sideways and back
    for side, sign in (("Right", 1), ("Left", -1)):
        cross = _pos(sign * np.sin(phi)) * a
        p.hip(side, abduct=-np.radians(22) * cross, flex=np.radians(18) * cross).knee(side, np.radians(30) * cross)
    p.spine(twist=np.radians(15) * np.sin(phi) * a)
    p.arms_down(np.radians(30), np.radians(30))


def _dance_swing(p, phi, a):
    swing = np.sin(phi)
    p.root[:, 0] = a * 0.12 * swing
    p.spine(twist=np.radians(30) * swing * a, side_bend=np.radians(12) * swing * a)
    p.arms_down(np.radians(60) + np.radians(60) * _pos(swing) * a, np.radians(60) + np.radians(60) * _pos(-swing) * a)
    p.turn("RightShoulder", "z", np.radians(50) * swing * a).turn("LeftShoulder", "z", np.radians(50) * swing * a)
    for side in ("Right", "Left"):
        p.knee(side, np.radians(25) * np.abs(np.sin(2 * phi)) * a)
    p.elbow("Right", np.radians(40)).elbow("Left", np.radians(40))


def _sprint_in_place(p, phi, a):
    s = _strides(p, phi, a, 90, 115, 60)
    p.arms_down(np.radians(10), np.radians(10)).elbow("Right", np.radians(90)).elbow("Left", np.radians(90))
    p.spine(flex=np.radians(8))
    p.air[:] = 0.05 * np.abs(s) * a


# (joint helper, keyword or axis, amplitude in degrees at variation 1, one-sided): the overlay of ``vary``.
# One-sided curves only bend a hinge further (elbows, knees), never past straight.
VARIATION = (
    ("spine", "flex", 15.0, False), ("spine", "side_bend", 10.0, False), ("spine", "twist", 20.0, False),
    ("Neck", "x", 10.0, False), ("Head", "x", 15.0, False), ("Head", "z", 25.0, False),
    ("LeftShoulder", "x", 30.0, False), ("LeftShoulder", "y", 20.0, False), ("LeftShoulder", "z", 20.0, False),
    ("RightShoulder", "x", 30.0, False), ("RightShoulder", "y", 20.0, False), ("RightShoulder", "z", 20.0, False),
    ("LeftElbow", "elbow", 45.0, True), ("RightElbow", "elbow", 45.0, True),
    ("LeftWrist", "x", 20.0, False), ("RightWrist", "x", 20.0, False),
    ("LeftHip", "x", 35.0, False), ("LeftHip", "y", 25.0, False), ("LeftHip", "z", 30.0, False),
    ("RightHip", "x", 35.0, False), ("RightHip", "y", 25.0, False), ("RightHip", "z", 30.0, False),
    ("LeftKnee", "knee", 60.0, True), ("RightKnee", "knee", 60.0, True),
    ("LeftAnkle", "x", 15.0, False), ("RightAnkle", "x", 15.0, False),
)
HEADING_SWING_DEG = 60.0  # peak heading change over a sequence at variation 1
ROOT_SPEED_M_S = 0.8  # top speed of the root's steady drift at variation 1 (a slow walk)
ROOT_DRIFT_M = 1.0  # the drift's total reach over a sequence, so the subject stays in the cameras' view


def smooth_curve(rng: np.random.Generator, t: np.ndarray, *, f_lo: float = 0.1, f_hi: float = 0.7) -> np.ndarray:
    """A random smooth curve in [-1, 1] over times ``t`` (s): two sinusoids of random frequency and phase."""
    freq = rng.uniform(f_lo, f_hi, 2)  # Hz
    phase = rng.uniform(0, 2 * np.pi, 2)
    weight = rng.dirichlet((1.0, 1.0))
    return (weight[:, None] * np.sin(2 * np.pi * freq[:, None] * t + phase[:, None])).sum(axis=0)  # (frame,)


def vary(pose: _Pose, t: np.ndarray, amount: float, rng: np.random.Generator) -> None:
    """Overlay ``VARIATION``'s smooth random joint curves on ``pose`` (in place), scaled by ``amount``."""
    for joint, how, deg, one_sided in VARIATION:
        curve = smooth_curve(rng, t)
        if one_sided:
            curve = (curve + 1) / 2
        angle = amount * np.radians(deg) * curve
        if joint == "spine":
            pose.spine(**{how: angle})
        elif how == "elbow":
            pose.elbow(joint.removesuffix("Elbow"), angle)
        elif how == "knee":
            pose.knee(joint.removesuffix("Knee"), angle)
        else:
            pose.turn(joint, how, angle)


def wander(t: np.ndarray, amount: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Heading offsets (rad, per frame) and horizontal root drift (m, (frame, 2)) for ``amount`` of variation."""
    heading = amount * np.radians(HEADING_SWING_DEG) * smooth_curve(rng, t, f_lo=0.05, f_hi=0.3)
    direction = rng.uniform(0, 2 * np.pi)
    speed = min(amount * rng.uniform(0, ROOT_SPEED_M_S), ROOT_DRIFT_M / max(t[-1], 1e-6))
    drift = speed * t[:, None] * [np.cos(direction), np.sin(direction)]  # (frame, 2)
    return heading - heading[0], drift


EXERCISES: dict[str, tuple[Callable, float]] = {  # name: (curves, nominal repetitions per second)
    "walking_on_the_spot": (_walk, 0.9),
    "single_arm_raise": (_single_arm_raise, 0.4),
    "elbow_flexion": (_elbow_flexion, 0.5),
    "knee_flexion": (_knee_flexion, 0.45),
    "closing_arms_above_head": (_closing_arms, 0.45),
    "side_steps": (_side_steps, 0.5),
    "jumping_jack": (_jumping_jack, 0.8),
    "butt_kicks_left_right": (_butt_kicks, 1.1),
    "forward_lunge_left_right": (_lunge, 0.3),
    "classic_squat": (_squat, 0.35),
    "side_step_knee_elbow": (_side_step_knee_elbow, 0.45),
    "side_reaches": (_side_reaches, 0.35),
    "side_jumps": (_side_jumps, 0.6),
    "alternate_side_reaches": (_alternate_side_reaches, 0.35),
    "kick_box_kicking": (_kick_box, 0.6),
}
ATHLETIC: dict[str, tuple[Callable, float]] = {  # beyond DMC3D: kicks, hops, jumps, turns, crossing legs, dance
    "front_kick": (_front_kick, 0.8),
    "hop_on_one_leg": (_hop_on_one_leg, 1.6),
    "tuck_jump": (_tuck_jump, 0.7),
    "turn_around": (_turn_around, 0.25),
    "crossing_legs": (_crossing_legs, 0.5),
    "dance_swing": (_dance_swing, 0.7),
    "sprint_in_place": (_sprint_in_place, 2.2),  # a sprint's cadence: limbs at a sprint's speeds
}
EXERCISES.update(ATHLETIC)


def exercise(name: str, subject: Subject, *, n_frames: int, fps: float = 30.0, speed: float = 1.0,
             amplitude: float = 1.0, repetitions: float | None = None, phase: float = 0.0,
             heading_deg: float = 0.0, variation: float = 0.0, seed: int = 0) -> Motion:
    """``name`` performed by ``subject`` for ``n_frames`` frames; feet planted on the floor (z = 0).

    ``variation`` > 0 overlays ``vary`` and ``wander`` (drawn from ``seed``) on the exercise.
    """
    if name not in EXERCISES:
        raise ValueError(f"unknown exercise {name!r}; one of {sorted(EXERCISES)} or a .bvh file")
    curves, rate = EXERCISES[name]
    t = np.arange(n_frames) / fps
    rate = repetitions / max(t[-1], 1e-6) if repetitions else rate * speed
    pose = _Pose(n_frames)
    curves(pose, 2 * np.pi * rate * t + phase, amplitude)
    turn = np.zeros(n_frames)
    if variation > 0:
        rng = np.random.default_rng([seed, 7])
        vary(pose, t, variation, rng)
        turn, drift = wander(t, variation, rng)
        pose.root[:, :2] += drift
    heading = Rotation.from_euler("z", (np.radians(heading_deg) + turn)[:, None]).as_matrix()  # (frame, 3, 3)
    pose.rot[:, JOINT_INDEX["Hips"]] = heading @ pose.rot[:, JOINT_INDEX["Hips"]]
    root = np.einsum("fij,fj->fi", heading, pose.root) + rest_offsets(subject)[JOINT_INDEX["Hips"]]
    root = plant_feet(pose.rot, root, subject) + np.outer(pose.air, [0, 0, 1])
    return Motion(pose.rot, root, fps, name)


def plant_feet(local_rot: np.ndarray, root: np.ndarray, subject: Subject) -> np.ndarray:
    """Shift the root vertically so the lowest point of the feet touches z = 0 on every frame."""
    return root - np.outer(lowest_foot_point(local_rot, root, subject), [0, 0, 1])


def lowest_foot_point(local_rot: np.ndarray, root: np.ndarray, subject: Subject) -> np.ndarray:
    """Height of the lowest foot surface point per frame (ankles, toes minus the foot capsule radius)."""
    _, pos = forward_kinematics(local_rot, root, rest_offsets(subject), PARENTS)
    radius = next(p.radii[0] for p in surface(subject) if p.name == "l_foot")
    feet = [JOINT_INDEX[j] for j in ("LeftAnkle", "LeftFoot", "RightAnkle", "RightFoot")]
    return pos[:, feet, 2].min(axis=1) - radius
