"""Kinect-v2-like cameras and layouts."""

from __future__ import annotations

import numpy as np
import pytest

from scipy.spatial.transform import Rotation

from mocapflow.tasks.studio import cameras


def test_default_layout_is_the_dmc_ring():
    cams = cameras.layout()
    assert len(cams) == 3
    pos = np.array([c.cam_to_world[:3, 3] for c in cams])
    assert np.allclose(np.linalg.norm(pos[:, :2], axis=1), 2.5) and np.allclose(pos[:, 2], 0.8)
    angles = np.sort(np.degrees(np.arctan2(pos[:, 1], pos[:, 0])) % 360)
    np.testing.assert_allclose(np.diff(angles), [120, 120])
    for cam in cams:
        assert (cam.width, cam.height) == (512, 424)
        fov = 2 * np.degrees(np.arctan([cam.width / 2 / cam.fx, cam.height / 2 / cam.fy]))
        np.testing.assert_allclose(fov, [70.6, 60.0], atol=0.05)
        uv, z = cam.project(np.array([cameras.CAPTURE_CENTRE]))
        assert np.allclose(uv[0], [cam.cx, cam.cy], atol=1.0) and 2.4 < z[0] < 2.6


def test_rays_and_projection_round_trip_through_distortion():
    cam = cameras.layout()[2]
    rays = cam.pixel_rays()
    ys, xs = np.array([0, 100, 211, 423]), np.array([0, 400, 255, 511])
    world = (rays[ys, xs] * 2.0) @ cam.cam_to_world[:3, :3].T + cam.cam_to_world[:3, 3]
    uv, _ = cam.project(world)
    np.testing.assert_allclose(uv, np.stack([xs, ys], axis=1), atol=1e-3)


def test_random_layouts_stay_within_the_dmc_envelope():
    rng = np.random.default_rng(0)
    for _ in range(20):
        for cam in cameras.layout(cameras.random_ring(rng), rng=rng):
            x, y, z = cam.cam_to_world[:3, 3]
            assert 2.0 <= np.hypot(x, y) <= 3.0 and 0.5 <= z <= 1.0


def test_camera_looking_away_is_rejected():
    with pytest.raises(ValueError, match="does not see the capture centre"):
        cameras.layout({"sensors": [{"name": "away", "position": [0, 2.5, 0.8], "target": [0, 6, 0.8]}]})
    with pytest.raises(ValueError, match="has no 'position"):
        cameras.layout({"sensors": [{"name": "nowhere"}]})


# A sensor 2.5 m in front of the capture centre (at -Y, looking +Y), a pinhole without distortion.
FRONT = {"name": "front", "position": [0.0, -2.5, 0.9], "fx": 300.0, "fy": 300.0, "cx": 255.5, "cy": 211.5,
         "dist": [0.0] * 5}


def test_a_rolled_sensor_sees_a_known_point_turned_in_its_image():
    above = np.array([[0.0, 0.0, 1.4]])  # 0.5 m above the centre, 2.5 m ahead: 60 px above it unrolled
    level = cameras.layout({"sensors": [FRONT]})[0]
    np.testing.assert_allclose(level.project(above)[0][0], [255.5, 211.5 - 60.0], atol=1e-9)
    rolled = cameras.layout({"sensors": [{**FRONT, "roll_deg": 30.0}]})[0]
    # Rolled 30 degrees (x toward y): the point turns counter-clockwise about the image centre, by 30 degrees.
    np.testing.assert_allclose(rolled.project(above)[0][0], [255.5 - 60 * np.sin(np.radians(30)),
                                                             211.5 - 60 * np.cos(np.radians(30))], atol=1e-9)
    np.testing.assert_allclose(rolled.project(np.array([cameras.CAPTURE_CENTRE]))[0][0], [255.5, 211.5], atol=1e-9)
    np.testing.assert_allclose(rolled.cam_to_world[:3, 3], FRONT["position"])


def test_a_sensor_given_its_whole_rotation_or_quaternion_is_the_rolled_one():
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    # Looking +Y with image right +X and image down -Z, rolled 30 degrees: columns x, y, z of the camera.
    rotation = [[c, -s, 0.0], [0.0, 0.0, 1.0], [-s, -c, 0.0]]
    rolled = cameras.layout({"sensors": [{**FRONT, "roll_deg": 30.0}]})[0]
    by_matrix = cameras.layout({"sensors": [{**FRONT, "rotation": rotation}]})[0]
    np.testing.assert_allclose(by_matrix.cam_to_world, rolled.cam_to_world, atol=1e-12)
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    typed = np.round([w, x, y, z], 6).tolist()  # a quaternion typed to six places still passes, made exact
    by_quaternion = cameras.layout({"sensors": [{**FRONT, "quaternion": typed}]})[0]
    np.testing.assert_allclose(by_quaternion.cam_to_world, rolled.cam_to_world, atol=1e-6)


@pytest.mark.parametrize("change,message", [
    ({"rotation": [[1.1, 0, 0], [0, 0, 1], [0, -1, 0]]}, "rotation is not orthonormal .* by 0.21"),
    ({"rotation": [[-1, 0, 0], [0, 0, 1], [0, -1, 0]]}, "rotation has determinant -1.000, a reflection"),
    ({"rotation": [[1, 0, 0], [0, 0, 1]]}, "rotation must be 3 rows of 3 finite numbers"),
    ({"quaternion": [1, 0, 0, 0.2]}, r"quaternion \[1.0, 0.0, 0.0, 0.2\] has norm 1.0198"),
    ({"quaternion": [1, 0, 0]}, r"quaternion must be 4 finite numbers \[w, x, y, z\]"),
    ({"rotation": [[1, 0, 0], [0, 0, 1], [0, -1, 0]], "roll_deg": 2},
     r"its orientation is given more than one way \(roll_deg, rotation\)"),
    ({"quaternion": [1, 0, 0, 0], "target": [0, 0, 1]}, r"its orientation is given more than one way \(quaternion, target\)"),
])
def test_a_sensor_orientation_that_is_not_a_rotation_is_a_clear_error(change, message):
    with pytest.raises(cameras.LayoutError, match=f"sensor 'front': {message}"):
        cameras.layout({"sensors": [{**FRONT, **change}]})


def test_a_ring_rolls_each_sensor_about_its_own_viewing_axis():
    ring = {"ring": {"count": 3, "radius": 2.5, "height": 0.8}}
    level = cameras.layout(ring)
    rolled = cameras.layout({"ring": {**ring["ring"], "roll_deg": [0.0, 2.0, -3.0]}})
    for cam, ref, deg in zip(rolled, level, [0.0, 2.0, -3.0]):
        np.testing.assert_allclose(cam.cam_to_world[:3, 3], ref.cam_to_world[:3, 3])
        np.testing.assert_allclose(cam.cam_to_world[:3, 2], ref.cam_to_world[:3, 2], atol=1e-12)  # same viewing axis
        turn = np.degrees(np.arctan2(ref.cam_to_world[:3, 1] @ cam.cam_to_world[:3, 0],
                                     ref.cam_to_world[:3, 0] @ cam.cam_to_world[:3, 0]))
        assert turn == pytest.approx(deg, abs=1e-9)  # image x turned toward image y by the roll
    with pytest.raises(ValueError, match=r"roll_deg \[1.0, 2.0\] must be one number or one per sensor \(3\)"):
        cameras.layout({"ring": {**ring["ring"], "roll_deg": [1.0, 2.0]}})
    one = cameras.layout({"ring": {**ring["ring"], "roll_deg": 2.0}})  # one roll for every sensor
    assert all(np.allclose(a.cam_to_world, b.cam_to_world) for a, b in zip(one, cameras.layout(
        {"ring": {**ring["ring"], "roll_deg": [2.0] * 3}})))


def test_a_studio_sequence_rolls_its_random_ring_and_keeps_every_other_draw():
    from mocapflow.tasks.deepmocap.film.synth import build_rig
    from mocapflow.tasks.studio.spec import SequenceSpec

    plain = build_rig(SequenceSpec("elbow_flexion", frames=2, seed=7, random_layout=True))
    rolled = build_rig(SequenceSpec("elbow_flexion", frames=2, seed=7, random_layout=True, camera_roll_deg=3.0))
    np.testing.assert_array_equal(plain.joint_pos, rolled.joint_pos)
    turns = []
    for a, b in zip(plain.views, rolled.views):
        np.testing.assert_allclose(a.cam.cam_to_world[:3, 3], b.cam.cam_to_world[:3, 3])
        assert (a.cam.fx, a.cam.cx) == (b.cam.fx, b.cam.cx)
        turns.append(np.degrees(np.arccos(np.clip(a.cam.cam_to_world[:3, 0] @ b.cam.cam_to_world[:3, 0], -1, 1))))
    assert 0 < max(turns) <= 3.0 + 1e-9 and len(set(np.round(turns, 6))) == len(turns)  # each its own roll
    with pytest.raises(ValueError, match="camera_roll_deg"):
        SequenceSpec("elbow_flexion", camera_roll_deg=-1.0)
    with pytest.raises(ValueError, match="rolls a random ring's sensors"):
        SequenceSpec("elbow_flexion", camera_roll_deg=2.0)  # no random ring to roll


def forward_camera(dist=(0.0, 0.0, 0.0, 0.0, 0.0)) -> cameras.Camera:
    """A 100 x 80 pinhole at the origin looking along +Y (x right = world +X, y down = world -Z)."""
    pose = np.eye(4)
    pose[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # columns: the camera x, y, z axes in the world
    return cameras.Camera("front", 50.0, 50.0, 49.5, 39.5, tuple(dist), pose, 100, 80)


def test_the_share_of_points_a_camera_cannot_see_counts_those_outside_its_image_and_behind_it():
    cam = forward_camera()  # sees |x| < 1 and |z| < 0.8 at 1 m
    points = np.array([[[0, 1, 0], [0.9, 1, 0.7], [1.2, 1, 0], [0, -1, 0]],  # in, in, right of the image, behind
                       [[0, 2, 0], [0, 2, 1.7], [np.nan, 2, 0], [0, 3, -2.6]]])  # in, above, unseen, below
    np.testing.assert_allclose(cameras.outside_share([cam], points), [4 / 7])
    np.testing.assert_allclose(cameras.outside_share([cam, cam], points[:, :2]), [0.25, 0.25])
    assert np.isnan(cameras.outside_share([cam], np.full((1, 2, 3), np.nan))).all()
    ring = cameras.layout()  # the default ring sees the capture centre; 5 m off to the side, two of them do not
    centre = np.array([[cameras.CAPTURE_CENTRE]])
    np.testing.assert_allclose(cameras.outside_share(ring, centre), [0, 0, 0])
    assert cameras.outside_share(ring, centre + [5.0, 0, 0]).sum() >= 2


def test_a_point_the_distortion_folds_back_into_the_image_is_outside():
    cam = forward_camera(dist=(-0.5, 0.0, 0.0, 0.0, 0.0))  # r_d = r (1 - 0.5 r^2): folds back past r = 0.82
    far = np.array([[[-1.6, 1, 0]]])  # 58 degrees off axis: r_d = -1.6 (1 - 1.28) = 0.45, inside the image
    uv, _ = cam.project(far[0])
    assert 0 <= uv[0, 0] < cam.width and 0 <= uv[0, 1] < cam.height
    np.testing.assert_allclose(cameras.outside_share([cam], far), [1.0])
