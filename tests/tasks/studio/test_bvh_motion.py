"""BVH parsing and retargeting of the real CMU clips; the procedural exercise library; the template."""

from __future__ import annotations

import re

import numpy as np
import pytest

from conftest import SHARED
from shared_data import cmu_clips
from mocapflow.tasks.shared import body, kinematics
from mocapflow.tasks.studio import bvh, cameras, motion

CLIPS = cmu_clips()


def joints(m, subject):
    return kinematics.forward_kinematics(m.local_rot, m.root_pos, body.rest_offsets(subject), body.PARENTS)[1]


def test_template_has_20_joints_levels_0_to_6_and_40_dof():
    assert len(body.JOINT_NAMES) == 20 and body.DOF.sum() == 40
    assert body.LEVELS[body.JOINT_INDEX["Hips"]] == 0 and body.LEVELS[body.JOINT_INDEX["LeftHand"]] == 6


@pytest.mark.needs_shared
@pytest.mark.parametrize("clip", CLIPS, ids=lambda p: p.stem)
def test_retargeted_cmu_clip_keeps_bone_lengths_and_feet_on_the_floor(clip):
    subject = body.Subject(1.68)
    m = bvh.retarget(bvh.parse_bvh(clip.read_text()), subject, fps=30)
    pos = joints(m, subject)
    bones = np.linalg.norm(pos[:, 1:] - pos[:, body.PARENTS[1:]], axis=-1)
    np.testing.assert_allclose(bones, np.broadcast_to(bones[0], bones.shape), atol=1e-9)
    feet = motion.lowest_foot_point(m.local_rot, m.root_pos, subject)
    assert abs(feet.min()) < 1e-6  # the lowest contact touches the floor
    assert np.percentile(feet, 10) < 0.03  # and the feet are near the floor most of the time
    left, right = pos[:, body.JOINT_INDEX["LeftHip"]], pos[:, body.JOINT_INDEX["RightHip"]]
    assert np.mean(left[:, 0] < right[:, 0]) > 0.95  # subject's left is -X: faces +Y like the template
    head = pos[:, body.JOINT_INDEX["Head"], 2]
    assert 1.3 < np.median(head) < 1.68


@pytest.mark.needs_shared
def test_walk_moves_forward_and_jumping_jacks_leave_the_ground():
    subject = body.Subject(1.75)
    walk = bvh.retarget(bvh.parse_bvh((SHARED / "motions" / "cmu_12_01_walk.bvh").read_text()), subject)
    assert walk.root_pos[-1, 1] - walk.root_pos[0, 1] > 2.0
    jj = bvh.retarget(bvh.parse_bvh((SHARED / "motions" / "cmu_14_14_jumping_jacks.bvh").read_text()), subject)
    assert motion.lowest_foot_point(jj.local_rot, jj.root_pos, subject).max() > 0.05


@pytest.mark.needs_shared
def test_a_window_of_a_travelling_clip_is_centred_where_it_is_filmed():
    subject = body.Subject(1.7)
    walk = bvh.parse_bvh((SHARED / "motions" / "cmu_12_01_walk.bvh").read_text())
    window = bvh.retarget(walk, subject, fps=30, n_frames=61, start_s=0.0)
    np.testing.assert_allclose(window.root_pos[:, :2].mean(axis=0), [0, 0], atol=1e-9)
    whole = bvh.retarget(walk, subject, fps=30)  # the same frames, centred on the whole walk (the old way)
    np.testing.assert_allclose(whole.local_rot[:61], window.local_rot, atol=1e-12)  # only the placement differs
    assert whole.root_pos[:61, 1].mean() < -1.0  # the walk's first two seconds: over a metre behind the centre
    seen = cameras.outside_share(cameras.layout(), joints(window, subject))
    assert seen.max() < 0.01  # the default ring sees the subject (a toe may graze an image's edge)
    assert cameras.outside_share(cameras.layout(), joints(whole, subject)[:61]).max() > 0.25  # as it did not


@pytest.mark.parametrize("text,message", [
    ("", r"unexpected end of file \(expected HIERARCHY\)"),
    ("MOTION\n", "expected 'HIERARCHY', found 'MOTION'"),
    ("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0\n", r"unexpected end of file \(expected an OFFSET number\)"),
    ("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 x\n", "line 4: expected a number, found 'x'"),
    ("HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 1 Wrotation\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\n0\n",
     "unknown channel"),
    ("HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 1 Xrotation\n}\nMOTION\nFrames: 2\nFrame Time: 0.1\n0\n",
     "MOTION holds 1 numbers, expected Frames 2 x 1 channels"),
])
def test_malformed_bvh_is_a_clear_error(text, message):
    with pytest.raises(bvh.BVHError, match=message):
        bvh.parse_bvh(text)


TWO_JOINTS = ("HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation "
              "Yrotation\nJOINT Knee\n{\nOFFSET 0 -40 0\nCHANNELS 3 Zrotation Xrotation Yrotation\nEnd Site\n{\n"
              "OFFSET 0 -40 0\n}\n}\n}\nMOTION\nFrames: 3\nFrame Time: 0.1\n")  # 80 units tall: positions within 8e4


def two_joint_clip(bad_column: int, value: str) -> tuple[str, int]:
    """The clip's text with frame 2's ``bad_column`` set to ``value``, and the line it is on."""
    rows = ["0 90 0 0 0 0 0 0 0"] * 3
    row = rows[2].split()
    row[bad_column] = value
    rows[2] = " ".join(row)
    text = TWO_JOINTS + "\n".join(rows) + "\n"
    return text, len(TWO_JOINTS.splitlines()) + 3


@pytest.mark.parametrize("column,value,where", [
    (7, "nan", "joint Knee, channel Xrotation is nan"),
    (0, "1e308", "joint Hips, channel Xposition is 1e+308"),
    (5, "-inf", "joint Hips, channel Yrotation is -inf"),
    (1, "90000", "joint Hips, channel Yposition is 90000.0"),  # beyond 1000 skeleton sizes (8e4)
    (6, "2e5", "joint Knee, channel Zrotation is 200000.0"),  # beyond 1e5 degrees
])
def test_a_non_finite_or_absurd_motion_value_is_refused_naming_its_line_frame_joint_and_channel(column, value, where):
    text, line = two_joint_clip(column, value)
    with pytest.raises(bvh.BVHError, match=rf"^line {line}: frame 2 \(0 = the first\), {re.escape(where)}, and 1 value"):
        bvh.parse_bvh(text)
    ok, _ = two_joint_clip(column, "70000" if column < 3 else "9e4")  # within the bounds: read as written
    assert bvh.parse_bvh(ok).data[2, column] == float("70000" if column < 3 else "9e4")


def test_a_non_finite_offset_is_refused_naming_its_joint():
    with pytest.raises(bvh.BVHError, match=r"the OFFSET of Knee is \[0.0, nan, 0.0\]: offsets must be finite"):
        bvh.parse_bvh(two_joint_clip(0, "0")[0].replace("OFFSET 0 -40 0\nCHANNELS", "OFFSET 0 nan 0\nCHANNELS"))


def test_non_cmu_skeleton_is_rejected():
    text = "HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 3 Xrotation Yrotation Zrotation\n}\nMOTION\nFrames: 1\n" \
           "Frame Time: 0.1\n0 0 0\n"
    with pytest.raises(bvh.BVHError, match="lacks joints"):
        bvh.retarget(bvh.parse_bvh(text), body.Subject())


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
