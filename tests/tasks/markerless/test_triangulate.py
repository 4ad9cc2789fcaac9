"""Pose2Sim's outlier rule (tasks/markerless/triangulate.py): a planted wrong view is dropped, the point comes back
from the others; low-confidence views are unused; two views are never cut below; a point whose views still
disagree is not given."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.markerless.triangulate import TriangulateConfig, triangulate_views
from mocapflow.tasks.shared.cameras import Camera


def ring(count=4, radius=3.0, dist=(0.03, 0.0, 0.0, 0.0, 0.0)) -> list[Camera]:
    cams = []
    for k in range(count):
        a = np.radians(90 + 360 * k / count)
        pos = np.array([radius * np.cos(a), radius * np.sin(a), 0.8 + 0.8 * (k % 2)])
        z = np.array([0.0, 0.0, 0.95]) - pos
        z /= np.linalg.norm(z)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        pose = np.eye(4)
        pose[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
        pose[:3, 3] = pos
        cams.append(Camera(f"cam{k}", 900.0, 900.0, 383.5, 511.5, dist, pose, 768, 1024))
    return cams


def observe(points, cams, rng, noise_px=1.0):
    xy = np.stack([c.project(points)[0] for c in cams])
    return xy + rng.normal(0.0, noise_px, xy.shape)


@pytest.fixture
def scene():
    rng = np.random.default_rng(5)
    points = rng.uniform([-0.4, -0.4, 0.1], [0.4, 0.4, 1.8], (200, 3))
    cams = ring()
    return points, cams, observe(points, cams, rng), rng


def test_a_planted_wrong_view_is_dropped_and_the_point_recovered(scene):
    points, cams, xy, rng = scene
    wrong = np.zeros((4, len(points)), bool)
    wrong[rng.integers(0, 4, len(points)), np.arange(len(points))] = True  # one wrong view per point
    planted = xy.copy()
    shift = rng.normal(0.0, 1.0, (len(points), 2))
    shift = 60.0 * shift / np.linalg.norm(shift, axis=1, keepdims=True)  # 60 px off (a left-right swap's size)
    planted[wrong] += shift
    conf = np.full((4, len(points)), 0.9)
    out = triangulate_views(planted, conf, cams, TriangulateConfig(search="subsets"))  # Pose2Sim's search
    assert (out.dropped == wrong).all()  # exactly the planted view, every time
    assert (out.kept == ~wrong).all()
    error_mm = 1000 * np.linalg.norm(out.points - points, axis=1)
    # 1 px of noise is about 3 mm at 3 m (f = 900 px): measured median 3.3, largest 9.5 mm
    assert np.median(error_mm) < 5.0 and error_mm.max() < 15.0, (np.median(error_mm), error_mm.max())
    # the greedy rule (the default: drop the worst view) drops the planted view for most points but a right one for
    # some (measured 15 of 200): a wrong view pulls the point so that a right one shows the largest error
    greedy = triangulate_views(planted, conf, cams)
    misdropped = (greedy.dropped != wrong).any(axis=0)
    assert 0 < misdropped.sum() < 40 and (greedy.dropped.sum(axis=0) >= 1).all()
    assert (greedy.dropped & wrong).any(axis=0).mean() > 0.85
    # without the rule (a threshold nothing passes) the wrong view pulls every point off
    naive = triangulate_views(planted, conf, cams, TriangulateConfig(threshold_px=1e6))
    assert not naive.dropped.any()
    assert np.median(1000 * np.linalg.norm(naive.points - points, axis=1)) > 20.0
    # clean observations (1 px noise) lose no view
    assert not triangulate_views(xy, conf, cams).dropped.any()


def test_views_below_the_confidence_threshold_are_unused_and_weights_favour_the_confident(scene):
    points, cams, xy, rng = scene
    conf = np.full((4, len(points)), 0.9)
    conf[0] = 0.1  # below Pose2Sim's 0.3
    off = xy.copy()
    off[0] += 40.0
    out = triangulate_views(off, conf, cams)
    assert not out.kept[0].any() and not out.dropped[0].any() and out.kept[1:].all()
    assert np.median(1000 * np.linalg.norm(out.points - points, axis=1)) < 5.0
    # a view 8 px off (under the threshold, so kept) moves the point less when it is less confident
    off = xy.copy()
    off[1] += 8.0
    sure = triangulate_views(off, np.full((4, len(points)), 0.9), cams)
    conf = np.full((4, len(points)), 0.9)
    conf[1] = 0.35
    unsure = triangulate_views(off, conf, cams)
    assert sure.kept.all() and unsure.kept.all()
    err = [np.median(np.linalg.norm(t.points - points, axis=1)) for t in (sure, unsure)]
    assert err[1] < 0.8 * err[0], err


def test_two_views_are_kept_and_a_point_they_disagree_on_is_not_given():
    rng = np.random.default_rng(2)
    cams = ring()
    points = rng.uniform([-0.3, -0.3, 0.5], [0.3, 0.3, 1.5], (50, 3))
    xy = observe(points, cams, rng)
    xy[2:] = np.nan  # two views see the points
    conf = np.full((4, len(points)), 0.8)
    out = triangulate_views(xy, conf, cams)
    assert out.kept[:2].all() and not out.dropped.any()
    assert np.nanmax(1000 * np.linalg.norm(out.points - points, axis=1)) < 10.0
    far = xy.copy()
    far[0, :, 1] += 100.0  # vertical: off the epipolar line, no point fits both views
    lost = triangulate_views(far, conf, cams)
    assert np.isnan(lost.points).all() and not lost.dropped.any() and not lost.kept.any()
    kept = triangulate_views(far, conf, cams, TriangulateConfig(discard=False))
    assert np.isfinite(kept.points).all() and kept.kept[:2].all()
    # one view is no point at all
    one = xy.copy()
    one[1] = np.nan
    assert np.isnan(triangulate_views(one, conf, cams).points).all()


def test_a_view_read_left_for_right_is_read_back_and_the_stage_gives_the_joints():
    import xarray as xr

    from mocapflow.tasks.markerless.blazepose import LANDMARK_NAMES, MIRRORED
    from mocapflow.tasks.markerless.joints import template_joints
    from mocapflow.tasks.markerless.triangulate import triangulate_keypoints

    rng = np.random.default_rng(3)
    cams = ring(5)
    n_frame = 4
    # a body's 33 landmarks: the left ones 0.3 m to the subject's left (-x) of the right ones
    base = rng.uniform([0.05, -0.15, 0.1], [0.2, 0.15, 1.7], (33, 3))
    side = np.array([-1.0 if n.startswith("left") else 1.0 if n.startswith("right") else 0.0 for n in LANDMARK_NAMES])
    base[:, 0] *= side
    truth = base[None] + rng.normal(0.0, 0.02, (n_frame, 33, 3))
    xy = np.stack([np.stack([c.project(f)[0] for f in truth]) for c in cams])  # (view, frame, 33, 2)
    xy += rng.normal(0.0, 1.0, xy.shape)
    xy[2, 1] = xy[2, 1, MIRRORED]  # view 2 took the back for the front in frame 1
    conf = np.full(xy.shape[:3], 0.9)
    dims = ("view", "frame", "landmark")
    views = np.array([c.name for c in cams], dtype=object)
    keypoints = xr.Dataset({"x": (dims, xy[..., 0]), "y": (dims, xy[..., 1]), "confidence": (dims, conf)},
                           coords={"view": views, "frame": np.arange(n_frame), "landmark": list(LANDMARK_NAMES)})
    images = xr.Dataset({"fx": ("view", [c.fx for c in cams]), "fy": ("view", [c.fy for c in cams]),
                         "cx": ("view", [c.cx for c in cams]), "cy": ("view", [c.cy for c in cams]),
                         "dist": (("view", "dist_coef"), [list(c.dist) for c in cams]),
                         "cam_to_world": (("view", "row", "col"), [c.cam_to_world for c in cams]),
                         "width": ("view", [c.width for c in cams]), "height": ("view", [c.height for c in cams])},
                        coords={"view": views}, attrs={"fps": 5.0})
    out = triangulate_keypoints(keypoints, images, TriangulateConfig())
    expected = np.zeros((n_frame, 5), bool)
    expected[1, 2] = True
    assert (out["swapped"].values == expected).all()
    assert not out["dropped"].values.any()  # read back, the view agrees with the others
    error_mm = 1000 * np.linalg.norm(out["joints"].values - template_joints(truth)[0], axis=-1)
    assert error_mm.max() < 10.0, error_mm.max()
    # without the check the mirrored view's sided landmarks are dropped as outliers instead (or pull the points)
    unchecked = triangulate_keypoints(keypoints, images, TriangulateConfig(swaps=False))
    assert unchecked["dropped"].values[1, 2].sum() > 10 and not unchecked["swapped"].values.any()
