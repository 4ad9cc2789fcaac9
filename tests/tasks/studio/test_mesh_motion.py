"""Template motion carried onto the mesh body: bone directions, the floor, determinism (a real CMU clip)."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SHARED
from mocapflow.tasks.shared import mesh_body as mb
from mocapflow.tasks.shared.body import JOINT_INDEX, PARENTS, Subject, rest_offsets
from mocapflow.tasks.shared.kinematics import forward_kinematics
from mocapflow.formats.bvh import parse_bvh
from mocapflow.tasks.studio import mesh_motion, motion, retarget

WALK = SHARED / "motions" / "cmu_12_01_walk.bvh"
pytestmark = pytest.mark.needs_shared  # every test reads the clip


@pytest.fixture(scope="module")
def walk():
    body = mb.mesh_body(mb.random_phenotype(np.random.default_rng(21), 1.80))
    subject = Subject(height=body.height)
    clip = retarget.retarget(parse_bvh(WALK.read_text()), subject, fps=30.0, n_frames=40)
    return body, subject, clip, mesh_motion.retarget(body, subject, clip)


def test_every_mapped_bone_points_where_its_template_segment_points(walk):
    body, subject, clip, take = walk
    _, pos = forward_kinematics(clip.local_rot, clip.root_pos, rest_offsets(subject), PARENTS)
    checked = 0
    for bone, (joint, end_bone, end_joint) in mesh_motion.SEGMENTS.items():
        if end_bone is None:
            continue
        mesh = take.posed.heads[:, body.bone(end_bone)] - take.posed.heads[:, body.bone(bone)]
        tmpl = pos[:, JOINT_INDEX[end_joint]] - pos[:, JOINT_INDEX[joint]]
        cos = np.einsum("fi,fi->f", mesh, tmpl) / np.linalg.norm(mesh, axis=1) / np.linalg.norm(tmpl, axis=1)
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 0.01, bone
        checked += 1
    assert checked == 16


def test_the_hips_follow_the_template_and_the_feet_stand_on_the_floor(walk):
    body, subject, clip, take = walk
    _, pos = forward_kinematics(clip.local_rot, clip.root_pos, rest_offsets(subject), PARENTS)
    hips_tmpl = pos[:, [JOINT_INDEX["LeftHip"], JOINT_INDEX["RightHip"]]].mean(axis=1)
    hips_mesh = take.posed.heads[:, [body.bone("upperleg01.L"), body.bone("upperleg01.R")]].mean(axis=1)
    np.testing.assert_allclose(hips_mesh[:, :2], hips_tmpl[:, :2], atol=1e-9)  # only lifted, never moved across
    soles = body.vertices[:, 2] < mesh_motion.SOLE_HEIGHT_M
    lowest = take.posed.vertices[:, soles, 2].min(axis=1)
    template = motion.lowest_foot_point(clip.local_rot, clip.root_pos, subject)
    stance = template <= template.min() + mesh_motion.CONTACT_M
    assert stance.mean() > 0.2
    np.testing.assert_allclose(lowest[stance], 0.0, atol=1e-9)  # on the floor where the template stands
    assert lowest.min() > -1e-9 and np.median(lowest) < 0.01  # never below it, and a walk keeps a foot down
    lift = hips_mesh[:, 2] - hips_tmpl[:, 2]
    assert np.abs(np.diff(lift)).max() < 0.02  # the lift moves smoothly: under 2 cm a frame at 30 fps
    assert np.linalg.norm(hips_mesh[-1, :2] - hips_mesh[0, :2]) > 0.3  # the subject walks
    joints = take.posed.heads[:, body.joint_bones()]
    assert np.median(np.linalg.norm(joints - pos, axis=2)) < 0.15


def test_the_same_clip_gives_the_same_bytes(walk):
    body, subject, clip, take = walk
    again = mesh_motion.retarget(body, subject, clip)
    assert np.array_equal(again.posed.vertices, take.posed.vertices)
    assert np.array_equal(again.rotations, take.rotations)


def test_the_mesh_bones_point_where_the_source_bvh_bones_point():
    clip = parse_bvh(WALK.read_text())
    body = mb.mesh_body(mb.random_phenotype(np.random.default_rng(22), 1.65))
    subject = Subject(height=body.height)
    take = mesh_motion.retarget(body, subject, retarget.retarget(clip, subject, fps=clip.fps, n_frames=60))
    source = retarget.world_positions(clip)[:60]
    index = {n: i for i, n in enumerate(clip.names)}
    mapping = retarget.joint_map(clip)
    followed = 0
    for bone, (joint, end_bone, _) in mesh_motion.SEGMENTS.items():
        m = mapping.get(joint)
        if end_bone is None or not isinstance(m, tuple):
            continue
        mesh = take.posed.heads[:, body.bone(end_bone)] - take.posed.heads[:, body.bone(bone)]
        src = source[:, index[m[2]]] - source[:, index[m[1]]]
        cos = np.einsum("fi,fi->f", mesh, src) / np.linalg.norm(mesh, axis=1) / np.linalg.norm(src, axis=1)
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 0.05, bone
        followed += 1
    assert followed == 13  # every mapped bone but the neck and the clavicles, which inherit their rotation
