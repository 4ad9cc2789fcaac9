"""UUO's accuracy measures on hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.uuo import metrics


def test_mpjpe_and_mpjve_match_hand_computed_values():
    truth = np.zeros((3, 2, 3))
    joints = truth.copy()
    joints[:, 0, 0] = [0.01, 0.02, 0.04]  # one joint off along x by 1, 2 and 4 cm
    assert metrics.mpjpe(joints, truth) == pytest.approx((0.01 + 0.02 + 0.04) / 6)
    assert metrics.mpjve(joints, truth) == pytest.approx((0.01 + 0.02) / 4)  # velocities 1 and 2 cm/frame, one joint
    assert np.isnan(metrics.mpjve(joints[:1], truth[:1]))
    assert metrics.v2v(joints, truth) == metrics.mpjpe(joints, truth)


def test_surface_distance_is_exact_on_a_square():
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    points = np.array([[0.3, 0.6, 0.01], [0.5, 0.5, -0.2], [2.0, 0.5, 0.0], [0.2, 0.1, 0.0]])
    d = metrics.surface_distance(points, vertices, faces, metrics.incident_faces(faces, 4), neighbours=2)
    np.testing.assert_allclose(d, [0.01, 0.2, 1.0, 0.0], atol=1e-12)
    markers = np.broadcast_to(points[:2], (3, 2, 3)).copy()
    markers[1, 0] = np.nan  # an unseen sample is left out
    assert metrics.m2s(markers, np.broadcast_to(vertices, (3, 4, 3)), faces) == pytest.approx((0.01 * 2 + 0.2 * 3) / 5)


def test_m2s_counts_every_frame_unless_told_fewer():
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    markers = np.zeros((40, 1, 3)) + [0.5, 0.5, 0.0]
    markers[:, 0, 2] = np.arange(40) / 1000.0  # frame f: f mm above the square
    surface = np.broadcast_to(vertices, (40, 4, 3))
    assert metrics.m2s(markers, surface, faces) == pytest.approx(np.arange(40).mean() / 1000.0)
    assert metrics.m2s(markers, surface, faces, frames=2) == pytest.approx(39 / 2000.0)  # frames 0 and 39


def test_a_body_turned_around_faces_180_degrees_off_and_a_small_turn_counts_its_angle():
    from mocapflow.tasks.shared.body import JOINT_NAMES

    names = list(JOINT_NAMES)
    truth = np.zeros((3, len(names), 3))
    truth[:, names.index("LeftHip")] = [0.1, 0.0, 0.9]  # hips across X: facing along -Y or +Y, either way the same
    truth[:, names.index("RightHip")] = [-0.1, 0.0, 0.9]
    turned = truth * [-1, -1, 1]  # half a turn about Z
    assert metrics.facing_error_deg(turned, truth, names) == pytest.approx(180.0)
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    small = truth @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
    small[0] = turned[0]  # one frame of three turned around: the median frame decides
    assert metrics.facing_error_deg(small, truth, names) == pytest.approx(30.0)
    assert metrics.facing_error_deg(truth, truth, names) == 0.0


def test_side_swaps_count_sided_labels_put_on_the_other_side():
    true = np.array(["left_upper_arm", "left_upper_arm", "right_thigh", "torso", "left_shank", "right_hand"])
    got = np.array(["right_upper_arm", "left_upper_arm", "left_thigh", "torso", "", "right_hand"])  # part_of_bone's
    assert metrics.side_swaps(true, got) == (2, 4)  # the unlabelled shank and the torso are not sided labels
