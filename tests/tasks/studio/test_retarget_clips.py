"""The real CMU clips retargeted onto the template (tasks/studio/retarget.py; parsed by formats/bvh.py)."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SHARED
from shared_data import cmu_clips
from mocapflow.formats.bvh import parse_bvh
from mocapflow.tasks.shared import body, kinematics
from mocapflow.tasks.shared.bvh_clip import BVHError
from mocapflow.tasks.studio import cameras, motion, retarget

CLIPS = cmu_clips()


def joints(m, subject):
    return kinematics.forward_kinematics(m.local_rot, m.root_pos, body.rest_offsets(subject), body.PARENTS)[1]


@pytest.mark.needs_shared
@pytest.mark.parametrize("clip", CLIPS, ids=lambda p: p.stem)
def test_retargeted_cmu_clip_keeps_bone_lengths_and_feet_on_the_floor(clip):
    subject = body.Subject(1.68)
    m = retarget.retarget(parse_bvh(clip.read_text()), subject, fps=30)
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
    walk = retarget.retarget(parse_bvh((SHARED / "motions" / "cmu_12_01_walk.bvh").read_text()), subject)
    assert walk.root_pos[-1, 1] - walk.root_pos[0, 1] > 2.0
    jj = retarget.retarget(parse_bvh((SHARED / "motions" / "cmu_14_14_jumping_jacks.bvh").read_text()), subject)
    assert motion.lowest_foot_point(jj.local_rot, jj.root_pos, subject).max() > 0.05


@pytest.mark.needs_shared
def test_a_window_of_a_travelling_clip_is_centred_where_it_is_filmed():
    subject = body.Subject(1.7)
    walk = parse_bvh((SHARED / "motions" / "cmu_12_01_walk.bvh").read_text())
    window = retarget.retarget(walk, subject, fps=30, n_frames=61, start_s=0.0)
    np.testing.assert_allclose(window.root_pos[:, :2].mean(axis=0), [0, 0], atol=1e-9)
    whole = retarget.retarget(walk, subject, fps=30)  # the same frames, centred on the whole walk (the old way)
    np.testing.assert_allclose(whole.local_rot[:61], window.local_rot, atol=1e-12)  # only the placement differs
    assert whole.root_pos[:61, 1].mean() < -1.0  # the walk's first two seconds: over a metre behind the centre
    seen = cameras.outside_share(cameras.layout(), joints(window, subject))
    assert seen.max() < 0.01  # the default ring sees the subject (a toe may graze an image's edge)
    assert cameras.outside_share(cameras.layout(), joints(whole, subject)[:61]).max() > 0.25  # as it did not


def test_non_cmu_skeleton_is_rejected():
    text = "HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 3 Xrotation Yrotation Zrotation\n}\nMOTION\nFrames: 1\n" \
           "Frame Time: 0.1\n0 0 0\n"
    with pytest.raises(BVHError, match="lacks joints"):
        retarget.retarget(parse_bvh(text), body.Subject())
