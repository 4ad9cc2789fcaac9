"""The suit's corner reconstruction (§3.3, Chen et al. 2021): known corners seen by known distorting cameras, claims
planted wrong in 0-3 of 8 views, two-view corners, a camera that claims corners behind it, frames, bad inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mocapflow.tasks.shared.cameras import calibrated_camera
from mocapflow.tasks.shared.triangulation import project_points
from mocapflow.tasks.shared.cameras import look_at, ring_positions
from mocapflow.tasks.suit.reconstruct import (
    ReconstructConfig,
    ReconstructError,
    drop_unread,
    reconstruct_frame,
    reconstruct_read_first,
    reconstruct_frames,
)

DIST = (-0.25, 0.12, 0.0005, -0.0003, -0.02)
CENTRE = (0.0, 0.0, 1.0)


def camera(name, position, target=CENTRE):
    return calibrated_camera(name, fx=1800.0, fy=1795.0, cx=1023.5, cy=767.5, dist=DIST,
                             cam_to_world=look_at(position, target), width=2048, height=1536)


def ring(views=8):
    """Grey cameras (2048x1536, fx about 1800, barrel distortion) on a 2.5 m ring, 1.6 m high, aimed at (0, 0, 1)."""
    return [camera(f"cam{i}", p) for i, p in enumerate(ring_positions(views, radius=2.5, height=1.6))]


def scene(count=300, seed=0, cams=None):
    """Known corners in a 1 m cube around (0, 0, 1) and their pixels in every camera, with 0.2 px noise."""
    rng = np.random.default_rng(seed)
    cams = ring() if cams is None else cams
    points = rng.uniform(-0.5, 0.5, (count, 3)) + CENTRE
    xy = project_points(points, cams) + rng.normal(0.0, 0.2, (len(cams), count, 2))
    return cams, points, xy, rng


def plant(xy, wrong, rng):
    """Claims of ``wrong`` (view, corner) moved 20-200 px in a random direction."""
    angle, radius = rng.uniform(0, 2 * np.pi, wrong.shape), rng.uniform(20, 200, wrong.shape)
    offset = radius[..., None] * np.stack([np.cos(angle), np.sin(angle)], axis=-1)
    return xy + wrong[..., None] * offset


def wrong_views(rng, views, corners, count):
    wrong = np.zeros((views, corners), dtype=bool)
    for c in range(corners):
        wrong[rng.choice(views, count, replace=False), c] = True
    return wrong


def distance_mm(result, points):
    return 1000 * np.linalg.norm(result.position - points, axis=1)


@pytest.mark.parametrize("planted", [0, 1, 2, 3])
def test_planted_wrong_views_are_dropped_and_every_corner_recovered(planted):
    cams, points, xy, rng = scene(seed=planted)
    wrong = wrong_views(rng, len(cams), len(points), planted)
    result = reconstruct_frame(plant(xy, wrong, rng), cams)
    distance = distance_mm(result, points)
    assert np.isfinite(distance).all()
    assert np.median(distance) < 0.5 and distance.max() < 2.0
    assert not (result.kept & wrong).any()
    assert (result.kept | wrong).mean() > 0.95  # the right claims are kept, bar a few the IQR rule takes
    assert (result.error_px[wrong] > 15).all() and np.median(result.error_px[result.kept]) < 0.3


def test_the_iqr_rule_alone_loses_the_corners_with_three_wrong_views_of_eight():
    cams, points, xy, rng = scene(seed=3)
    xy = plant(xy, wrong_views(rng, len(cams), len(points), 3), rng)
    iqr_only = reconstruct_frame(xy, cams, ReconstructConfig(max_view_error_px=math.inf))
    assert np.isnan(iqr_only.position).all(axis=1).mean() > 0.9  # Q3 lies among the wrong views: kept, then > 1.5 px
    assert np.isfinite(reconstruct_frame(xy, cams).position).all()  # hence max_view_error_px


def test_one_wrong_view_of_three_is_dropped_by_the_absolute_bound():
    cams, points, xy, rng = scene(count=100, seed=4)
    claims = wrong_views(rng, len(cams), len(points), 3)  # three views claim each corner
    wrong = np.zeros_like(claims)
    wrong[np.argmax(claims, axis=0), np.arange(len(points))] = True  # the first of them wrongly
    xy = np.where(claims[..., None], plant(xy, wrong, rng), np.nan)
    result = reconstruct_frame(xy, cams)
    assert np.isfinite(result.position).all() and np.median(distance_mm(result, points)) < 1.0
    np.testing.assert_array_equal(result.kept, claims & ~wrong)
    assert np.isnan(result.error_px[~claims]).all()
    plain_mean = reconstruct_frame(xy, cams, ReconstructConfig(selection_cap_px=math.inf))
    assert np.isnan(plain_mean.position).all(axis=1).mean() > 0.3  # a pair with the wrong view often wins: the cap


def test_a_corner_seen_by_two_views_is_kept_when_they_agree_and_discarded_when_one_is_wrong():
    cams, points, xy, rng = scene(count=100, seed=5)
    pairs = np.array([rng.choice(len(cams), 2, replace=False) for _ in points])  # (corner, 2) the claiming views
    claims = np.zeros(xy.shape[:2], dtype=bool)
    claims[pairs[:, 0], np.arange(len(points))] = claims[pairs[:, 1], np.arange(len(points))] = True
    odd = np.arange(len(points)) % 2 == 1
    for c in np.flatnonzero(odd):  # the second view of an odd corner claims a pixel 20-200 px off its epipolar line
        xy[pairs[c, 1], c] += rng.uniform(20, 200) * across_epipolar_line(cams, points[c], *pairs[c])
    result = reconstruct_frame(np.where(claims[..., None], xy, np.nan), cams)
    assert np.isnan(result.position[odd]).all() and not result.kept[:, odd].any()
    mean_error = np.nanmean(result.error_px[:, odd], axis=0)
    assert (mean_error > ReconstructConfig().max_mean_error_px).all()  # the paper's 1.5 px rule discards them
    assert np.median(distance_mm(result, points)[~odd]) < 1.0
    np.testing.assert_array_equal(result.kept[:, ~odd], claims[:, ~odd])


def across_epipolar_line(cams, point, seeing, other):
    """Unit pixel direction in view ``other`` across the epipolar line of ``point`` seen by view ``seeing``."""
    centre = cams[seeing].cam_to_world[:3, 3]
    along = project_points(np.stack([point, point + 0.05 * (point - centre)]), [cams[other]])[0]  # (2, 2)
    direction = along[1] - along[0]
    return np.array([-direction[1], direction[0]]) / np.linalg.norm(direction)


def test_a_camera_claiming_corners_behind_it_is_never_kept():
    away = camera("away", (0.0, 1.2, 1.0), target=(0.0, 5.0, 1.0))  # between the ring and the cube, facing out
    cams, points, xy, rng = scene(cams=ring() + [away], seed=6)
    assert np.isnan(xy[-1]).all()  # no corner is in front of it
    xy[-1] = rng.uniform([200, 200], [1800, 1300], (len(points), 2))  # yet it claims them all
    result = reconstruct_frame(xy, cams)
    assert not result.kept[-1].any() and (result.error_px[-1] == np.inf).all()
    distance = distance_mm(result, points)
    assert np.isfinite(distance).all() and np.median(distance) < 0.5


def test_corners_with_fewer_than_two_claims_are_not_reconstructed():
    cams, points, xy, _ = scene(count=10, seed=7)
    xy[:, :3] = np.nan
    xy[1:, 3:6] = np.nan
    xy[2, 6, 0] = np.nan  # one coordinate missing: no claim
    result = reconstruct_frame(xy, cams)
    assert np.isnan(result.position[:6]).all() and not result.kept[:, :6].any()
    assert np.isnan(result.error_px[:, :6]).all()
    assert np.isfinite(result.position[6:]).all() and not result.kept[2, 6] and result.kept[:, 7:].all()


def test_frames_are_reconstructed_one_by_one():
    cams, points, xy, rng = scene(count=40, seed=8)
    frames = np.stack([xy, plant(xy, wrong_views(rng, len(cams), len(points), 2), rng), np.full_like(xy, np.nan)])
    result = reconstruct_frames(frames, cams)
    assert result.position.shape == (3, 40, 3) and result.kept.shape == result.error_px.shape == (3, 8, 40)
    for f in range(2):
        one = reconstruct_frame(frames[f], cams)
        np.testing.assert_array_equal(result.kept[f], one.kept)
        np.testing.assert_allclose(result.position[f], one.position)
        assert np.median(distance_mm(one, points)) < 0.5
    assert np.isnan(result.position[2]).all() and not result.kept[2].any()
    empty = reconstruct_frames(frames[:0], cams)
    assert empty.position.shape == (0, 40, 3) and empty.kept.shape == (0, 8, 40)


def test_bad_inputs_are_refused_naming_the_thing_the_value_and_the_fix():
    cams, points, xy, _ = scene(count=5)
    cases = [(lambda: reconstruct_frame(xy[:7], cams), "xy has 7 views but 8 cameras were given; pass one camera"),
             (lambda: reconstruct_frame(xy, cams[:2] + [None] + cams[3:]),
              "view 2 has no calibration (its camera is None); calibrate the view or drop it"),
             (lambda: reconstruct_frame(xy[None], cams),
              "shape (view, corner, 2) with NaN where a view claims nothing, got shape (1, 8, 5, 2)"),
             (lambda: reconstruct_frames(xy, cams), "shape (frame, view, corner, 2)"),
             (lambda: reconstruct_frame(xy[..., :1], cams), "got shape (8, 5, 1)"),
             (lambda: ReconstructConfig(min_views=1), "min_views must be at least 2")]
    for call, message in cases:
        with pytest.raises(ReconstructError) as err:
            call()
        assert message in str(err.value)


def test_grown_labels_add_views_to_corners_but_make_none_without_two_read_ones():
    cams, points, xy, _ = scene(count=6, seed=3)
    result = reconstruct_frames(xy[None], cams)
    before = result.kept.copy()
    assert before[0].sum(axis=0).min() >= 3
    read = np.zeros((1, len(cams), 6), bool)
    read[0, :2, 0] = True  # corner 0: two views read, six grown
    read[0, :1, 1] = True  # corner 1: one read; corners 2-5 grown in every view
    read[0, :, 2] = True
    drop_unread(result, read, 2)
    assert np.isfinite(result.position[0, [0, 2]]).all() and np.isnan(result.position[0, [1, 3, 4, 5]]).all()
    np.testing.assert_array_equal(result.kept[0, :, 0], before[0, :, 0])  # grown views stay with a corner read ones make
    assert not result.kept[0, :, [1, 3, 4, 5]].any()
    assert np.median(distance_mm(reconstruct_frame(xy, cams), points)) < 0.5


def test_grown_claims_join_a_corner_only_near_where_the_read_ones_put_it():
    cams, points, xy, rng = scene(count=30, seed=5)
    read = np.zeros((len(cams), 30), bool)
    read[:3, :20] = True  # corners 0-19 read in three views; 20-29 only grown
    claims = xy.copy()
    off = rng.uniform(0, 2 * np.pi, 10)
    claims[5, :10] += 2.5 * np.column_stack([np.cos(off), np.sin(off)])  # grown 2.5 px off: inside the 3 px bound
    result = reconstruct_read_first(claims[None], read[None], cams)
    kept = result.kept[0]
    assert not kept[5, :10].any() and kept[5, 10:20].all()  # the near ones join, the 2.5 px ones do not
    assert kept[3:, 10:20].all() and np.isnan(result.position[0, 20:]).all()  # grown alone make no corner
    assert np.median(distance_mm(type(result)(result.position[0], kept, result.error_px[0]), points)[:20]) < 0.5
    alike = reconstruct_frames(claims[None], cams, ReconstructConfig(read_views=0))
    assert np.isfinite(alike.position[0, 20:]).all()  # every claim alike: the grown ones make corners too

