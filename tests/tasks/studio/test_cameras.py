"""Kinect-v2-like cameras and layouts."""

from __future__ import annotations

import numpy as np
import pytest

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
