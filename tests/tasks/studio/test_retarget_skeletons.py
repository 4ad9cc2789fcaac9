"""Retargeting skeletons other than CMU's cgspeed BVH (tasks/studio/retarget.py): a Mixamo-style T-pose skeleton (Y
up, centimetres), a user's joint map, a clip shaped like Bandai Namco's research set and a CMU-named ASF/AMC take."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.formats.asf_amc import read_asf_amc
from mocapflow.formats.bvh import parse_bvh
from mocapflow.tasks.shared import body, kinematics
from mocapflow.tasks.shared.bvh_clip import BVHClip, BVHError
from mocapflow.tasks.studio import retarget
from mocapflow.tasks.studio.motion import Motion
from motion_files import LYING_MAP, USER_MAP, cmu_amc_text, cmu_asf_text, lying_text, mixamo_text


def template_joints(motion, subject):
    return kinematics.forward_kinematics(motion.local_rot, motion.root_pos, body.rest_offsets(subject), body.PARENTS)


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.mark.parametrize("prefix", ["mixamorig:", ""])
def test_a_mixamo_skeleton_is_found_and_followed_along_its_chains(prefix):
    clip = parse_bvh(mixamo_text(prefix))
    m = retarget.joint_map(clip)
    assert m["SpineBase"] == (f"{prefix}Spine1", f"{prefix}Spine", f"{prefix}Neck")  # the whole spine chain
    assert m["LeftWrist"] == (f"{prefix}LeftHand", f"{prefix}LeftHand", f"{prefix}LeftHandMiddle1")  # not the thumb
    assert m["Head"] == (f"{prefix}Head", f"{prefix}Head", f"{prefix}Head_End")  # an end site ends the head
    assert m["Hips"][0] == f"{prefix}Hips" and m["Neck"] == "inherit"


@pytest.mark.parametrize("prefix", ["mixamorig:", ""])
def test_a_mixamo_clip_lands_on_the_template_bone_by_bone(prefix):
    subject = body.Subject(1.75)
    clip = parse_bvh(mixamo_text(prefix))
    motion = retarget.retarget(clip, subject, fps=30.0)
    assert motion.n_frames == 4  # the leading T-pose dropped, the others kept at the file's own rate
    rot, pos = template_joints(motion, subject)
    # The T-pose is the template's rest pose: every local rotation the identity.
    np.testing.assert_allclose(motion.local_rot[0], np.broadcast_to(np.eye(3), motion.local_rot[0].shape), atol=1e-9)
    # Each mapped bone points where the file's bone points, in the studio's axes.
    source = retarget.world_positions(clip)
    index = {n: i for i, n in enumerate(clip.names)}
    for joint, (_, start, end) in ((k, v) for k, v in retarget.joint_map(clip).items() if v != "inherit"):
        want = unit(source[:, index[end]] - source[:, index[start]])
        j = body.JOINT_INDEX[joint]
        child = retarget.BONE_END[joint]
        got = unit(pos[:, body.JOINT_INDEX[child]] - pos[:, j]) if child in body.JOINT_INDEX else rot[:, j, :, 2]
        np.testing.assert_allclose(got, want, atol=1e-9, err_msg=joint)
    j = body.JOINT_INDEX
    np.testing.assert_allclose(unit(pos[1, j["LeftElbow"]] - pos[1, j["LeftShoulder"]]), [0, 0, 1], atol=1e-9)
    np.testing.assert_allclose(unit(pos[2, j["RightAnkle"]] - pos[2, j["RightKnee"]]), [0, -1, 0], atol=1e-9)
    np.testing.assert_allclose(unit(pos[0, j["LeftHip"]] - pos[0, j["RightHip"]]), [-1, 0, 0], atol=1e-9)
    # Turned 90 degrees to its left (about +Z): its left now points backward (-Y), its forearm to its front (-X).
    np.testing.assert_allclose(unit(pos[3, j["LeftHip"]] - pos[3, j["RightHip"]]), [0, -1, 0], atol=1e-9)
    np.testing.assert_allclose(unit(pos[3, j["LeftWrist"]] - pos[3, j["LeftElbow"]]), [-1, 0, 0], atol=1e-9)
    # 44 cm forward on a leg of 88 cm: half the template's leg, along the studio's facing (+Y).
    leg = np.linalg.norm(body.rest_offsets(subject)[[j["LeftKnee"], j["LeftAnkle"]]], axis=1).sum()
    np.testing.assert_allclose(motion.root_pos[3] - motion.root_pos[0], [0, leg / 2, 0], atol=1e-9)
    bones = np.linalg.norm(pos[:, 1:] - pos[:, body.PARENTS[1:]], axis=-1)
    np.testing.assert_allclose(bones, np.broadcast_to(bones[0], bones.shape), atol=1e-9)


def test_a_user_map_retargets_a_skeleton_no_known_naming_fits():
    subject = body.Subject(1.7)
    clip = parse_bvh(mixamo_text("rig_"))
    with pytest.raises(BVHError, match=r"matches no known naming .*; none names a joint of this file"):
        retarget.retarget(clip, subject)
    renamed = parse_bvh(mixamo_text().replace("LeftUpLeg", "LeftThigh"))
    with pytest.raises(BVHError, match=r"the closest, Mixamo, lacks joints \['LeftUpLeg'\]; give a joint map"):
        retarget.joint_map(renamed)
    user_map = {k: f"rig_{v}" for k, v in USER_MAP.items()}
    mine = retarget.retarget(clip, subject, user_map=user_map)
    known = retarget.retarget(parse_bvh(mixamo_text()), subject)
    np.testing.assert_allclose(mine.local_rot, known.local_rot, atol=1e-12)
    np.testing.assert_allclose(mine.root_pos, known.root_pos, atol=1e-12)


@pytest.mark.parametrize("change,message", [
    ({"Pelvis": "rig_Hips"}, r"unknown template joints \['Pelvis'\]"),
    ({"Neck": None}, r"lacks template joints \['Neck'\]"),
    ({"Head": "rig_Skull"}, r"names joints the file lacks: \{'Head': 'rig_Skull'\}"),
    ({"LeftHand": None}, r"rig_LeftHand has 2 children .* name the joint its bone points to as 'LeftHand'"),
    ({"LeftElbow": "rig_RightForeArm"}, r"LeftElbow \(rig_RightForeArm\) is not below LeftShoulder \(rig_LeftArm\)"),
    ({"SpineBase": "rig_Hips"}, r"the bone of Hips \(rig_Hips -> rig_Hips\)|is not below Hips"),
])
def test_a_bad_user_map_is_a_clear_error(change, message):
    clip = parse_bvh(mixamo_text("rig_"))
    user_map = {k: f"rig_{v}" for k, v in USER_MAP.items()}
    user_map.update({k: v for k, v in change.items() if v})
    for k in (k for k, v in change.items() if v is None):
        del user_map[k]
    with pytest.raises(BVHError, match=message):
        retarget.joint_map(clip, user_map)


def test_a_skeleton_that_is_not_y_up_is_refused():
    lying = mixamo_text().replace("OFFSET 0 -45 0", "OFFSET 0 0 45").replace("OFFSET 0 -43 0", "OFFSET 0 0 43")
    with pytest.raises(BVHError, match=r"not upright along \+Y .* export the clip Y up"):
        retarget.joint_map(parse_bvh(lying))


def travelling(clip: BVHClip, frames: int, metres: float) -> BVHClip:
    """``clip``'s T-pose walked ``metres`` forward (+Z, the file's facing) over ``frames`` frames, after a leading
    T-pose frame (dropped by retarget)."""
    data = np.tile(clip.data[1], (frames + 1, 1))
    data[1:, 2] = np.linspace(0, metres * 100, frames)  # the root's Zposition, centimetres
    return BVHClip(clip.names, clip.parents, clip.offsets, clip.channels, clip.frame_time, data)


def test_a_window_is_centred_on_its_own_frames_and_a_whole_clip_on_all_of_them():
    subject = body.Subject(1.75)
    clip = travelling(parse_bvh(mixamo_text()), 121, 8.0)  # 4 s at 30 fps, 8 m forward
    leg = np.linalg.norm(body.rest_offsets(subject)[[body.JOINT_INDEX["LeftKnee"], body.JOINT_INDEX["LeftAnkle"]]],
                         axis=1).sum()
    scale = leg / 88.0  # the template's leg over the file's (45 + 43 cm)
    whole = retarget.retarget(clip, subject, fps=30.0)
    np.testing.assert_allclose(whole.root_pos[[0, -1], 1], [-400 * scale, 400 * scale], atol=1e-9)
    for start_s, n in ((0.0, 31), (2.5, 31), (1.0, 90)):
        window = retarget.retarget(clip, subject, fps=30.0, n_frames=n, start_s=start_s)
        np.testing.assert_allclose(window.root_pos[:, :2].mean(axis=0), [0, 0], atol=1e-9)
        k = int(round(start_s * 30))  # the same frames, moved by where their middle was in the whole clip
        np.testing.assert_allclose(window.root_pos[:, :2] - whole.root_pos[k:k + n, :2],
                                   [[0, -whole.root_pos[k:k + n, 1].mean()]] * n, atol=1e-9)
        np.testing.assert_allclose(window.root_pos[:, 2], whole.root_pos[k:k + n, 2], atol=1e-12)


def test_a_clip_lying_at_zero_rotation_takes_its_first_frame_as_rest_and_bones_from_its_joints():
    clip = parse_bvh(lying_text())  # shaped like Bandai Namco's set: six channels, empty End Sites, lying along X
    m = retarget.joint_map(clip, LYING_MAP)
    assert m["Head"] == ("Head", "Neck", "Head")  # its End Site has no length: the head continues the neck
    assert m["LeftWrist"] == ("Hand_L", "LowerArm_L", "Hand_L") and m["LeftAnkle"] == ("Foot_L", "Foot_L", "Toes_L")
    subject = body.Subject(1.75)
    motion = retarget.retarget(clip, subject, user_map=LYING_MAP)  # rest_frame "auto": the zero pose lies, so frame 0
    _, pos = template_joints(motion, subject)
    j = body.JOINT_INDEX
    feet = pos[:, [j["LeftAnkle"], j["RightAnkle"]], 2].max(axis=1)
    assert (pos[:, j["Head"], 2] - feet > 1.1).all()  # upright in every frame, the bent knee's foot 43 cm up included
    offsets = body.rest_offsets(subject)
    rest = template_joints(Motion(np.tile(np.eye(3), (1, 20, 1, 1)), offsets[:1], 30.0, "rest"), subject)[1][0]
    assert abs(pos[0, j["Head"], 2] - motion.root_pos[0, 2] - (rest[j["Head"], 2] - offsets[0, 2])) < 0.02
    bones = np.linalg.norm(pos[:, 1:] - pos[:, body.PARENTS[1:]], axis=-1)
    np.testing.assert_allclose(bones, np.broadcast_to(np.linalg.norm(offsets[1:], axis=1), bones.shape), atol=1e-9)
    np.testing.assert_allclose(unit(pos[0, j["LeftHip"]] - pos[0, j["RightHip"]]), [-1, 0, 0], atol=1e-9)
    np.testing.assert_allclose(unit(pos[2, j["LeftHip"]] - pos[2, j["RightHip"]]), [0, -1, 0], atol=1e-9)  # turned
    leg = np.linalg.norm(offsets[[j["LeftKnee"], j["LeftAnkle"]]], axis=1).sum()
    np.testing.assert_allclose(motion.root_pos[2, :2] - motion.root_pos[0, :2], [0, 40 * leg / 83], atol=1e-9)
    # The same motion of the same skeleton standing at zero rotation, measured from its frame 0: the same take.
    standing = retarget.retarget(parse_bvh(lying_text(lying=False)), subject, user_map=LYING_MAP, rest_frame=0)
    np.testing.assert_allclose(motion.local_rot, standing.local_rot, atol=1e-9)
    np.testing.assert_allclose(motion.root_pos, standing.root_pos, atol=1e-9)


def test_a_rest_frame_is_checked_and_a_lying_zero_pose_names_the_frame_to_take():
    clip = parse_bvh(lying_text())
    with pytest.raises(BVHError, match=r"the zero pose .* is not upright along \+Y \(head minus ankles: "
                                           r"\[149.0, 0.0, -0.5\]\), but the clip stands upright along \+Y in 4 of "
                                           r"its 4 frames: take the rest pose from one of them, rest_frame: 0") as err:
        retarget.joint_map(clip, LYING_MAP, rest_frame=None)
    assert "export" not in str(err.value)  # the clip is Y up already
    for bad in (4, -1, "first"):
        with pytest.raises(BVHError, match=rf"rest_frame {bad!r} is none of None .* a frame of the clip \(0-3\)"):
            retarget.joint_map(clip, LYING_MAP, rest_frame=bad)
    subject = body.Subject(1.7)
    standing = parse_bvh(mixamo_text())  # stands at zero rotation: "auto" takes the zero pose, as None does
    for a, b in zip(retarget.retarget(standing, subject).local_rot,
                    retarget.retarget(standing, subject, rest_frame=None).local_rot):
        assert np.array_equal(a, b)


def test_a_non_root_joints_position_channels_are_its_offset():
    clip = parse_bvh(lying_text())
    column = sum(len(c) for c in clip.channels[:clip.names.index("Foot_L")])  # Foot_L's Xposition: its shin, lying
    data = clip.data.copy()
    data[:, column] *= 2  # a shin of 82 cm in every frame (its OFFSET still says 41)
    longer = BVHClip(clip.names, clip.parents, clip.offsets, clip.channels, clip.frame_time, data)
    subject = body.Subject(1.75)
    motion = retarget.retarget(longer, subject, user_map=LYING_MAP)
    j = body.JOINT_INDEX
    leg = np.linalg.norm(body.rest_offsets(subject)[[j["LeftKnee"], j["LeftAnkle"]]], axis=1).sum()
    np.testing.assert_allclose(motion.root_pos[2, :2] - motion.root_pos[0, :2], [0, 40 * leg / (42 + 82)], atol=1e-9)


def test_a_cmu_named_take_lands_on_the_template_bone_by_bone():
    subject = body.Subject(1.75)
    clip = read_asf_amc(cmu_asf_text(), cmu_amc_text(), fps=30.0)
    mapping = retarget.joint_map(clip)
    assert mapping["SpineBase"] == ("thorax", "upperback", "lowerneck") and mapping["Head"][2] == "head_End"
    motion = retarget.retarget(clip, subject, fps=30.0)
    rot, pos = kinematics.forward_kinematics(motion.local_rot, motion.root_pos, body.rest_offsets(subject),
                                             body.PARENTS)
    source = retarget.world_positions(clip)
    for joint, (_, start, end) in ((k, v) for k, v in mapping.items() if v != "inherit"):
        want = source[:, clip.names.index(end)] - source[:, clip.names.index(start)]
        child = retarget.BONE_END[joint]
        j = body.JOINT_INDEX[joint]
        got = pos[:, body.JOINT_INDEX[child]] - pos[:, j] if child in body.JOINT_INDEX else rot[:, j, :, 2]
        cos = np.einsum("fi,fi->f", got, want) / np.linalg.norm(got, axis=1) / np.linalg.norm(want, axis=1)
        np.testing.assert_allclose(cos, 1.0, atol=1e-12, err_msg=joint)
    j = body.JOINT_INDEX
    np.testing.assert_allclose(motion.local_rot[0], np.broadcast_to(np.eye(3), motion.local_rot[0].shape), atol=1e-9)
    shin = pos[1, j["LeftAnkle"]] - pos[1, j["LeftKnee"]]  # the left knee bent 90 degrees: the shin backward
    upper_arm = pos[2, j["RightElbow"]] - pos[2, j["RightShoulder"]]  # the right arm raised sideways: up
    np.testing.assert_allclose(shin / np.linalg.norm(shin), [0, -1, 0], atol=1e-9)
    np.testing.assert_allclose(upper_arm / np.linalg.norm(upper_arm), [0, 0, 1], atol=1e-9)
