"""The joints carried by the suit's corners (tasks/suit/joints.py)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.tasks.suit import joints


def test_a_moved_and_scaled_neighbourhood_carries_its_joint_exactly():
    rng = np.random.default_rng(0)
    rest = rng.normal(size=(300, 3)) * 0.3
    rest_joints = np.array([[0.0, 0.0, 0.0], [0.2, 0.1, -0.3]])
    near = joints.joint_neighbourhoods(rest, rest_joints, k=30)
    assert near.shape == (2, 30)
    assert np.linalg.norm(rest[near[1]] - rest_joints[1], axis=1).max() <= \
        np.sort(np.linalg.norm(rest - rest_joints[1], axis=1))[29] + 1e-12  # the 30 nearest
    turn = Rotation.from_euler("zyx", [40, -20, 10], degrees=True).as_matrix()
    shift, scale = np.array([1.0, -2.0, 0.5]), 1.1
    moved = (scale * rest @ turn.T + shift)[None].repeat(2, axis=0)
    moved[1, near[0][:25]] = np.nan  # frame 1: joint 0 keeps 5 of its 30 corners, under MIN_POINTS
    out = joints.joints_from_corners(moved, rest, rest_joints, near)
    np.testing.assert_allclose(out[0], scale * rest_joints @ turn.T + shift, atol=1e-9)
    assert np.isnan(out[1, 0]).all() and np.isfinite(out[1, 1]).all()


def test_the_scale_stays_within_its_range_and_corners_sit_on_their_faces():
    rest = np.random.default_rng(1).normal(size=(50, 3))
    rotation, scale, _ = joints.similarity(rest, 3.0 * rest)
    np.testing.assert_allclose(rotation, np.eye(3), atol=1e-9)
    assert scale == joints.SCALE_RANGE[1]
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    on = joints.rest_corners(vertices, np.array([[0, 1, 2]]), np.array([0, 0]), np.array([[0.5, 0.25], [0, 0]]))
    np.testing.assert_allclose(on, [[0.5, 0.25, 0], [0, 0, 0]])
