"""The one Camera: known points through a known camera and back, behind-the-camera points, a raw sequence's
calibration read once and checked."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import plane_sequence
from mocapflow.tasks.shared.cameras import Camera, CalibrationError, calibrated_camera, camera_of


def camera(dist=(0.05, -0.1, 0.001, -0.002, 0.02)) -> Camera:
    pose = np.eye(4)
    pose[:3, :3] = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]  # looking along world +Y, Z up
    pose[:3, 3] = [0.2, -3.0, 1.0]
    return Camera("cam", 400.0, 410.0, 320.0, 240.0, tuple(dist), pose, 640, 480)


def test_known_points_project_by_the_pinhole_model_and_come_back():
    cam = camera(dist=(0.0,) * 5)
    world = np.array([[0.2, 1.0, 1.0], [0.6, 1.0, 0.5]])  # 4 m in front of the camera
    uv, z = cam.project(world)
    np.testing.assert_allclose(uv, [[320.0, 240.0], [320.0 + 400.0 * 0.4 / 4, 240.0 + 410.0 * 0.5 / 4]])
    np.testing.assert_allclose(z, [4.0, 4.0])
    points, rays = camera().backproject(*camera().project(world))
    np.testing.assert_allclose(points, world, atol=1e-9)
    to_point = world - cam.cam_to_world[:3, 3]
    np.testing.assert_allclose(rays, to_point / np.linalg.norm(to_point, axis=1, keepdims=True), atol=1e-9)


def test_points_behind_or_not_finite_do_not_project():
    uv, z = camera().project(np.array([[0.2, -5.0, 1.0], [np.nan, 0.0, 0.0], [0.2, 1.0, 1.0]]))
    assert np.isnan(uv[:2]).all() and np.isnan(z[:2]).all() and np.isfinite(uv[2]).all()


def test_pixel_rays_point_through_their_pixels():
    cam = camera()
    rays = cam.pixel_rays()  # (y, x, 3) in the camera frame
    world = rays[[10, 400], [30, 600]] @ cam.cam_to_world[:3, :3].T * 2.0 + cam.cam_to_world[:3, 3]
    np.testing.assert_allclose(cam.project(world)[0], [[30.0, 10.0], [600.0, 400.0]], atol=1e-6)
    assert cam.pixel_rays() is rays  # computed once per calibration


def test_a_raw_sequence_gives_its_camera_and_a_bad_calibration_is_refused():
    frames = plane_sequence([np.zeros(3)])
    cam = camera_of(frames, "cam")
    assert (cam.width, cam.height, cam.fx) == (512, 424, 365.0)
    np.testing.assert_array_equal(cam.as_dict()["cam_to_world"], np.eye(4))
    broken = frames.copy()
    broken["fx"] = broken["fx"] * np.nan
    with pytest.raises(CalibrationError, match="view 'cam' has a non-finite calibration"):
        camera_of(broken, "cam")


def test_calibrated_camera_checks_every_value_naming_it():
    good = dict(fx=365.0, fy=365.0, cx=256.0, cy=212.0, dist=[0.0] * 5, cam_to_world=np.eye(4), width=512, height=424)
    assert calibrated_camera("k0", **good).width == 512
    for change, message in [({"fx": "abc"}, "view 'k0': fx must be a number, got 'abc'"),
                            ({"fy": -1.0}, "focal lengths fx, fy must be positive"),
                            ({"dist": [0.0] * 4}, "dist must be five distortion coefficients"),
                            ({"cam_to_world": np.eye(3)}, "cam_to_world must be a 4x4 camera-to-world transform"),
                            ({"cx": float("nan")}, "view 'k0' has a non-finite calibration: cx = nan"),
                            ({"width": 511.5}, "width must be a whole number of pixels")]:
        with pytest.raises(CalibrationError) as err:
            calibrated_camera("k0", **{**good, **change})
        assert message in str(err.value)
