"""Triangulation on the shared floor: known points through known distorting cameras and back (linear, refined),
each point from its own views, the refinement at the least-squares optimum, points behind a camera, bad inputs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from mocapflow.tasks.shared.cameras import calibrated_camera
from mocapflow.tasks.shared.triangulation import (
    TriangulationError,
    project_points,
    projection_matrices,
    refine_points,
    reprojection_errors,
    triangulate_linear,
    undistort_pixels,
)
from mocapflow.tasks.shared.cameras import look_at, ring_positions

DIST = (-0.25, 0.12, 0.0005, -0.0003, -0.02)


def ring(views=8):
    """Grey cameras (2048x1536, fx about 1800, barrel distortion) on a 2.5 m ring, 1.6 m high, aimed at (0, 0, 1)."""
    return [calibrated_camera(f"cam{i}", fx=1800.0, fy=1795.0, cx=1023.5, cy=767.5, dist=DIST,
                              cam_to_world=look_at(p, (0.0, 0.0, 1.0)), width=2048, height=1536)
            for i, p in enumerate(ring_positions(views, radius=2.5, height=1.6))]


def scene(count=300, noise=0.2, seed=0):
    rng = np.random.default_rng(seed)
    cams = ring()
    points = rng.uniform(-0.5, 0.5, (count, 3)) + [0.0, 0.0, 1.0]  # a 1 m cube around (0, 0, 1)
    xy = project_points(points, cams) + rng.normal(0.0, noise, (len(cams), count, 2))
    return cams, points, xy, rng


def solve(cams, xy, mask=None):
    linear = triangulate_linear(undistort_pixels(xy, cams), projection_matrices(cams), mask)
    return linear, refine_points(linear, xy, cams, mask)


def test_exact_observations_give_the_points_back_exactly():
    cams, points, xy, _ = scene(noise=0.0)
    assert np.isfinite(xy).all() and (xy[..., 0] > 0).all() and (xy[..., 0] < 2048).all()
    linear, refined = solve(cams, xy)
    np.testing.assert_allclose(linear, points, atol=1e-8)
    np.testing.assert_allclose(refined, points, atol=1e-9)
    assert reprojection_errors(refined, xy, cams).max() < 1e-6


def test_noisy_observations_give_sub_millimetre_points_and_the_refinement_lowers_every_error():
    cams, points, xy, _ = scene(noise=0.2)
    linear, refined = solve(cams, xy)
    distance = np.linalg.norm(refined - points, axis=1)
    assert np.median(distance) < 0.4e-3 and distance.max() < 1.5e-3
    before = (reprojection_errors(linear, xy, cams) ** 2).sum(axis=0)
    after = (reprojection_errors(refined, xy, cams) ** 2).sum(axis=0)
    assert (after <= before + 1e-9).all() and after.sum() < before.sum()
    assert 0.15 < np.median(reprojection_errors(refined, xy, cams)) < 0.3  # the 0.2 px noise, less 3 of 16 dof


def test_the_refinement_reaches_the_least_squares_optimum_of_each_point():
    cams, points, xy, _ = scene(count=12, noise=0.5, seed=3)
    _, refined = solve(cams, xy)
    for i in range(len(points)):
        def residual(p, i=i):
            return (project_points(p[None], cams)[:, 0] - xy[:, i]).ravel()
        best = least_squares(residual, points[i], xtol=1e-15, ftol=1e-15, gtol=1e-15).x
        np.testing.assert_allclose(refined[i], best, atol=1e-7)


def test_each_point_uses_only_its_own_views():
    cams, points, xy, rng = scene(noise=0.2, seed=1)
    mask = np.zeros(xy.shape[:2], dtype=bool)  # (view, point)
    for i, n in enumerate(rng.integers(1, 9, xy.shape[1])):
        mask[rng.choice(len(cams), n, replace=False), i] = True
    xy = np.where(mask[..., None], xy, xy + 300.0)  # what the mask leaves out is wrong
    _, refined = solve(cams, xy, mask)
    solved = mask.sum(axis=0) >= 2
    assert np.isnan(refined[~solved]).all() and (~solved).sum() > 10
    distance = np.linalg.norm(refined[solved] - points[solved], axis=1)
    assert np.median(distance) < 0.6e-3 and distance.max() < 5e-3
    hidden = np.where(mask[..., None], xy, np.nan)  # the same, with NaN where not observed
    np.testing.assert_allclose(solve(cams, hidden)[1], refined, atol=1e-9)


def test_projection_matrices_map_points_to_the_undistorted_pixels():
    cams, points, xy, _ = scene(count=50, noise=0.0)
    image = points @ projection_matrices(cams)[:, :, :3].transpose(0, 2, 1) + projection_matrices(cams)[:, None, :, 3]
    np.testing.assert_allclose(image[..., :2] / image[..., 2:], undistort_pixels(xy, cams), atol=1e-6)
    assert np.abs(undistort_pixels(xy, cams) - xy).max() > 8  # the distortion is not negligible


def test_a_point_behind_a_camera_has_no_pixel_there_and_an_infinite_error():
    cams = ring()
    behind = np.array([[0.0, 3.0, 1.6], [0.0, 0.0, 1.0]])  # behind cam0 (at (0, 2.5, 1.6), looking at the centre)
    xy = project_points(behind, cams)
    assert np.isnan(xy[0, 0]).all() and np.isfinite(xy[0, 1]).all()
    claimed = np.full_like(xy, 1000.0)
    claimed[1, 0] = np.nan
    errors = reprojection_errors(behind, claimed, cams)
    assert errors[0, 0] == np.inf and np.isnan(errors[1, 0]) and np.isfinite(errors[2:, 0]).all()


def test_bad_inputs_are_refused_naming_the_fix():
    cams, points, xy, _ = scene(count=5)
    cases = [(lambda: undistort_pixels(xy[:7], cams), "xy has 7 views but 8 cameras were given"),
             (lambda: undistort_pixels(xy, cams[:3] + [None] + cams[4:]), "view 3 has no calibration"),
             (lambda: reprojection_errors(points, xy[..., 0], cams), "xy must be pixels of shape (view, point, 2)"),
             (lambda: reprojection_errors(points[:4], xy, cams), "points must have shape (point, 3) = (5, 3)"),
             (lambda: refine_points(points, xy, cams, mask=np.ones((8, 4), bool)),
              "mask must have shape (view, point)"),
             (lambda: triangulate_linear(xy, projection_matrices(cams)[:7]), "one 3x4 projection matrix per view")]
    for call, message in cases:
        with pytest.raises(TriangulationError) as err:
            call()
        assert message in str(err.value)
