"""The one forward kinematics: a known chain posed by hand, any joint order, per-frame offsets (BVH),
the solver's parameter form agrees with it, bad trees are refused."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapflow.tasks.deepmocap import poses
from mocapflow.tasks.shared import body, kinematics


def test_a_two_bone_arm_bent_at_the_elbow_lands_where_the_hand_computation_says():
    parents = np.array([-1, 0, 1])  # shoulder -> elbow -> hand
    offsets = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.25, 0.0, 0.0]])
    local = np.tile(np.eye(3), (1, 3, 1, 1))
    local[0, 1] = Rotation.from_euler("z", 90, degrees=True).as_matrix()  # the elbow turns the forearm
    rot, pos = kinematics.forward_kinematics(local, np.array([[1.0, 2.0, 3.0]]), offsets, parents)
    np.testing.assert_allclose(pos[0], [[1.0, 2.0, 3.0], [1.3, 2.0, 3.0], [1.3, 2.25, 3.0]], atol=1e-12)
    np.testing.assert_allclose(rot[0, 2], local[0, 1], atol=1e-12)


def test_joints_listed_before_their_parents_and_per_frame_offsets():
    parents = np.array([2, -1, 1])  # joint 0 hangs from 2, which hangs from the root 1
    offsets = np.array([[[0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]],
                        [[0.0, 0.0, 2.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])  # (frame, joint, 3)
    local = np.tile(np.eye(3), (2, 3, 1, 1))
    _, pos = kinematics.forward_kinematics(local, np.zeros((2, 3)), offsets, parents)
    np.testing.assert_allclose(pos[:, 0], [[1.0, 0.0, 1.0], [1.0, 0.0, 2.0]])
    assert kinematics.world_rotations(local, parents).shape == (2, 3, 3, 3)


def test_the_solvers_parameter_form_is_the_same_kinematics():
    rng = np.random.default_rng(3)
    params = rng.normal(0.0, 0.4, (5, poses.N_DOF))
    offsets = body.rest_offsets(body.Subject())
    rot, pos = poses.forward_kinematics(params, offsets)
    rot2, pos2 = kinematics.forward_kinematics(poses.local_rotations(params), params[:, :3], offsets, body.PARENTS)
    np.testing.assert_array_equal(pos, pos2)
    np.testing.assert_array_equal(rot, rot2)
    np.testing.assert_allclose(np.linalg.norm(pos[:, 1:] - pos[:, body.PARENTS[1:]], axis=-1),
                               np.broadcast_to(np.linalg.norm(offsets[1:], axis=-1), (5, 19)), atol=1e-12)  # bones keep length


@pytest.mark.parametrize("parents, why", [([1, 0], "one root"), ([-1, -1], "one root"), ([-1, 2, 1], "cycle")])
def test_bad_trees_are_refused(parents, why):
    with pytest.raises(kinematics.SkeletonError, match=why):
        kinematics.world_rotations(np.tile(np.eye(3), (1, len(parents), 1, 1)), parents)


def test_rodrigues_and_the_right_jacobian():
    v = np.array([0.3, -0.2, 0.5])
    np.testing.assert_allclose(kinematics.rodrigues(v), Rotation.from_rotvec(v).as_matrix(), atol=1e-12)
    d = 1e-6 * np.array([1.0, 2.0, -1.0])
    step = kinematics.rodrigues(v).T @ kinematics.rodrigues(v + d)  # exp([J_r d]x) to first order
    np.testing.assert_allclose(step - np.eye(3), kinematics.skew(kinematics.right_jacobian(v) @ d), atol=1e-11)
    r, t = kinematics.rigid_fit(np.eye(3), np.eye(3) @ Rotation.from_rotvec(v).as_matrix().T + 1.0)
    np.testing.assert_allclose(r, Rotation.from_rotvec(v).as_matrix(), atol=1e-12)
