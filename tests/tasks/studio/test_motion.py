"""The procedural exercise library and the template it moves (tasks/studio/motion.py)."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.shared import body, kinematics
from mocapflow.tasks.studio import motion


def joints(m, subject):
    return kinematics.forward_kinematics(m.local_rot, m.root_pos, body.rest_offsets(subject), body.PARENTS)[1]


def test_template_has_20_joints_levels_0_to_6_and_40_dof():
    assert len(body.JOINT_NAMES) == 20 and body.DOF.sum() == 40
    assert body.LEVELS[body.JOINT_INDEX["Hips"]] == 0 and body.LEVELS[body.JOINT_INDEX["LeftHand"]] == 6


@pytest.mark.parametrize("name", sorted(motion.EXERCISES))
def test_every_exercise_is_planted_and_moves(name):
    subject = body.Subject(1.8)
    m = motion.exercise(name, subject, n_frames=60)
    pos = joints(m, subject)
    assert np.isfinite(pos).all()
    assert motion.lowest_foot_point(m.local_rot, m.root_pos, subject).min() > -1e-9
    assert np.ptp(pos, axis=0).max() > 0.1, "the exercise must move some joint by 10 cm"


# largest rotation of each joint from its rest orientation (degrees): a person's range, generously
JOINT_LIMITS_DEG = {"SpineBase": 60, "Neck": 45, "Head": 60, "LeftShoulder": 180, "RightShoulder": 180,
                    "LeftElbow": 150, "RightElbow": 150, "LeftWrist": 80, "RightWrist": 80, "LeftHip": 130,
                    "RightHip": 130, "LeftKnee": 150, "RightKnee": 150, "LeftAnkle": 50, "RightAnkle": 50}


@pytest.mark.parametrize("name", sorted(motion.ATHLETIC))
def test_athletic_motions_stay_within_joint_limits_and_knees_and_elbows_never_overextend(name):
    from scipy.spatial.transform import Rotation

    m = motion.exercise(name, body.Subject(1.75), n_frames=120)
    for joint, limit in JOINT_LIMITS_DEG.items():
        rot = Rotation.from_matrix(m.local_rot[:, body.JOINT_INDEX[joint]])
        assert np.degrees(rot.magnitude()).max() <= limit, joint
    rotvec = lambda j: Rotation.from_matrix(m.local_rot[:, body.JOINT_INDEX[j]]).as_rotvec()  # noqa: E731
    assert (rotvec("LeftKnee")[:, 0] <= 1e-9).all() and (rotvec("RightKnee")[:, 0] <= 1e-9).all()  # flexion only
    assert (rotvec("RightElbow")[:, 2] >= -1e-9).all() and (rotvec("LeftElbow")[:, 2] <= 1e-9).all()


def test_athletic_motions_reach_a_sprints_limb_speeds_flight_and_a_whole_turn():
    subject = body.Subject(1.75)

    def run(name):
        m = motion.exercise(name, subject, n_frames=120)
        return m, joints(m, subject)

    def peak_speed(pos, joint):
        return (np.linalg.norm(np.diff(pos[:, body.JOINT_INDEX[joint]], axis=0), axis=-1) * 30.0).max()

    _, sprint = run("sprint_in_place")
    assert peak_speed(sprint, "RightKnee") > 8.0 and peak_speed(sprint, "RightHand") > 5.0  # m/s
    _, kick = run("front_kick")
    assert 8.0 < peak_speed(kick, "RightFoot") < 25.0
    jump, _ = run("tuck_jump")
    assert motion.lowest_foot_point(jump.local_rot, jump.root_pos, subject).max() > 0.3  # both feet 30 cm up
    turn, pos = run("turn_around")  # 0.25 turns a second: half a turn in 60 frames, a whole one in 120
    hips, left, right = (body.JOINT_INDEX[j] for j in ("Hips", "LeftHip", "RightHip"))
    across = pos[:, left, :2] - pos[:, right, :2]
    heading = np.unwrap(np.arctan2(across[:, 1], across[:, 0]))
    assert np.degrees(np.ptp(heading)) > 300
    assert np.isfinite(pos[:, hips]).all()


def test_exercise_parameters_and_errors():
    subject = body.Subject()
    slow = motion.exercise("elbow_flexion", subject, n_frames=90, repetitions=1)
    fast = motion.exercise("elbow_flexion", subject, n_frames=90, repetitions=3)
    wrist = body.JOINT_INDEX["RightWrist"]
    peaks = lambda m: int(np.sum(np.diff(np.sign(np.diff(joints(m, subject)[:, wrist, 2]))) < 0))  # noqa: E731
    assert peaks(slow) < peaks(fast)
    small = motion.exercise("elbow_flexion", subject, n_frames=90, amplitude=0.3)
    assert np.ptp(joints(small, subject)[:, wrist, 2]) < np.ptp(joints(slow, subject)[:, wrist, 2])
    with pytest.raises(ValueError, match="unknown exercise 'moonwalk'"):
        motion.exercise("moonwalk", subject, n_frames=10)
    with pytest.raises(ValueError, match="outside the studio's 1.50-2.00 m"):
        body.Subject(2.3)


def test_variation_overlays_seeded_posture_heading_and_drift():
    subject = body.Subject(1.75)
    plain = motion.exercise("classic_squat", subject, n_frames=61)
    np.testing.assert_array_equal(motion.exercise("classic_squat", subject, n_frames=61, variation=0.0,
                                                  seed=3).local_rot, plain.local_rot)
    varied = motion.exercise("classic_squat", subject, n_frames=61, variation=1.0, seed=3)
    again = motion.exercise("classic_squat", subject, n_frames=61, variation=1.0, seed=3)
    other = motion.exercise("classic_squat", subject, n_frames=61, variation=1.0, seed=4)
    np.testing.assert_array_equal(varied.local_rot, again.local_rot)
    p0, p1, p2 = joints(plain, subject), joints(varied, subject), joints(other, subject)
    assert np.median(np.linalg.norm(p1 - p0, axis=-1)) > 0.05  # a different posture, not a copy
    assert np.median(np.linalg.norm(p2 - p1, axis=-1)) > 0.05  # and another one for another seed
    drift = np.linalg.norm(varied.root_pos[:, :2] - varied.root_pos[0, :2], axis=-1)
    assert drift.max() <= motion.ROOT_DRIFT_M + 0.3  # drift (plus the squat's own hip travel) stays in view
    assert abs(motion.lowest_foot_point(varied.local_rot, varied.root_pos, subject).min()) < 1e-9  # planted
    bones = np.linalg.norm(p1[:, 1:] - p1[:, body.PARENTS[1:]], axis=-1)
    np.testing.assert_allclose(bones, np.broadcast_to(bones[0], bones.shape), atol=1e-9)


def test_varied_knees_bend_only_forward():
    from scipy.spatial.transform import Rotation

    subject = body.Subject(1.75)
    for seed in range(5):
        m = motion.exercise("walking_on_the_spot", subject, n_frames=40, variation=1.0, seed=seed)
        for knee in ("LeftKnee", "RightKnee"):
            flexion = Rotation.from_matrix(m.local_rot[:, body.JOINT_INDEX[knee]]).as_rotvec()
            assert np.abs(flexion[:, 1:]).max() < 1e-9  # a hinge about x
            assert flexion[:, 0].max() <= 1e-9  # knee(angle) turns by -angle: never hyperextended
