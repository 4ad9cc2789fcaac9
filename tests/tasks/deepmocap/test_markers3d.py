"""2D -> 3D and fusion (DeepMoCap §3.4): back-projection round trip, shared regions split by depth,
the Appendix A construction on a cylinder, patch fusion with a disagreeing view, bad calibration."""

import warnings

import numpy as np
import pytest
import xarray as xr

from mocapflow.tasks.deepmocap import markers3d as m3d
from mocapflow.tasks.shared.cameras import look_at
from mocapflow.tasks.studio.cameras import kinect_v2


def _camera(position, target=(0.0, 0.0, 1.0)):
    return kinect_v2("cam", look_at(np.array(position, float), np.array(target, float)))


def test_backprojection_round_trips_a_known_point():
    cam = _camera([2.5, -1.0, 1.2])
    world = np.array([[0.1, 0.2, 1.3], [-0.3, 0.1, 0.4]])
    uv, z = cam.project(world)  # distorted pixels, camera depth (m)
    points, rays = cam.backproject(uv, z)
    np.testing.assert_allclose(points, world, atol=1e-6)
    to_point = world - cam.cam_to_world[:3, 3]
    np.testing.assert_allclose(rays, to_point / np.linalg.norm(to_point, axis=1, keepdims=True), atol=1e-6)


def test_region_depth_is_the_median_of_its_contour_and_shared_regions_split():
    depth = np.full((40, 60), 3000, np.uint16)  # background wall
    depth[5:35, 5:30] = 2000  # a limb at 2 m ...
    depth[5:35, 30:55] = 2400  # ... beside one at 2.4 m
    blob_id = np.zeros((40, 60), np.uint16)
    blob_id[15:20, 10:15] = 1
    blob_id[15:20, 26:34] = 2  # one region straddling both surfaces: two reflectors touching
    depth[blob_id > 0] = 0  # reflectors return no depth
    xy = np.array([[12.0, 17.0], [27.5, 17.0], [32.5, 17.0]])
    d = m3d.region_depths(xy, np.array([1, 2, 2]), blob_id, depth, contour_px=2, max_depth_spread_mm=150.0)
    np.testing.assert_allclose(d, [2000.0, 2000.0, 2400.0])


def test_a_regions_contour_is_its_ring_in_the_whole_image():
    from scipy import ndimage

    rng = np.random.default_rng(2)
    depth = rng.integers(0, 3000, (30, 40)).astype(np.uint16)  # zeros: invalid depth
    blob_id = np.zeros((30, 40), np.uint16)
    blob_id[0:3, 0:4] = 1  # at the image corner
    blob_id[12:15, 18:21] = 2
    blob_id[13, 21:24] = 2  # not a rectangle
    blob_id[27:30, 35:40] = 3  # at the opposite corner
    boxes = ndimage.find_objects(blob_id)
    for label in (1, 2, 3):
        region = blob_id == label
        ring = ndimage.binary_dilation(region, iterations=2) & ~region & (depth > 0)
        ys, xs = m3d._contour(blob_id, depth, label, boxes[label - 1], 2)
        np.testing.assert_array_equal(np.stack([ys, xs]), np.nonzero(ring))


def test_surface_depth_is_the_median_of_the_depths_near_the_nearest_quartile():
    rng = np.random.default_rng(4)
    for n in [1, 2, 3, 4, 5, 8, 13, 40, 41]:
        for _ in range(20):  # a body at about 1.5 m, some background pixels far behind it, repeated values
            z = np.where(rng.random(n) < 0.3, 4000.0, 1500.0) + rng.integers(0, 60, n).astype(float)
            expected = np.median(z[z <= np.percentile(z, 25) + 150.0])
            assert m3d._surface_depth(z, 150.0) == expected


def test_normal_lines_of_a_cylinder_meet_on_its_axis():
    """Points on a vertical cylinder (radius 4 cm, axis through (0.3, -0.2)) facing two sensors; the
    lines along each sensor's ray through its surface point meet on the axis (Eq. A1)."""
    axis, radius, height = np.array([0.3, -0.2]), 0.04, 1.1
    cams = [np.array([3.0, 0.5, 1.0]), np.array([-1.5, 2.5, 1.2])]
    points, rays = [], []
    for c in cams:
        towards = np.append(axis, height) - c
        ray = towards / np.linalg.norm(towards)
        horizontal = np.append(axis - c[:2], 0.0)
        # the surface point the sensor sees in front of the axis, on the ray through the axis
        t = np.linalg.norm(towards) - radius / np.linalg.norm(horizontal[:2] / np.linalg.norm(towards))
        points.append(c + ray * t)
        rays.append(ray)
    points, rays = np.array(points), np.array(rays)
    np.testing.assert_allclose(np.linalg.norm(points[:, :2] - axis, axis=1), radius, atol=1e-9)  # on the surface
    p, q = m3d.closest_points(points[0], rays[0], points[1], rays[1])
    np.testing.assert_allclose((p + q) / 2, [axis[0], axis[1], height], atol=1e-9)
    centre, used = m3d.fuse_strap(points, rays, np.array([0.9, 0.8]), radius=0.035, tolerance=0.08)
    np.testing.assert_allclose(centre, [axis[0], axis[1], height], atol=1e-6)
    assert used.all()
    single, _ = m3d.fuse_strap(points[:1], rays[:1], np.array([0.9]), radius=0.04, tolerance=0.08)
    # pushed one radius along its ray, which is almost perpendicular to the limb
    np.testing.assert_allclose(single, [axis[0], axis[1], height], atol=1e-3)
    assert m3d.closest_points(points[0], rays[0], points[0] + 1.0, rays[0]) is None  # parallel lines


def test_patch_fusion_is_the_confidence_weighted_mean_without_a_disagreeing_view():
    points = np.array([[1.0, 0.0, 1.0], [1.02, 0.0, 1.0], [1.0, 0.03, 1.0], [1.5, 0.0, 1.0]])
    centre, used = m3d.fuse_patch(points, np.array([1.0, 1.0, 2.0, 1.0]), tolerance=0.05)
    np.testing.assert_array_equal(used, [True, True, True, False])
    np.testing.assert_allclose(centre, [(1.0 + 1.02 + 2.0) / 4, 0.06 / 4, 1.0])


def test_a_view_with_nan_calibration_is_a_clear_error():
    names = ["F_SPINEMID"]
    reflectors = xr.Dataset({k: (("view", "frame", "reflector"), np.ones((1, 1, 1), np.float32))
                             for k in ("x", "y", "confidence")},
                            coords={"view": ["cam"], "frame": [0], "reflector": names})
    masks = xr.Dataset({"blob_id": (("view", "frame", "y", "x"), np.zeros((1, 1, 4, 4), np.uint16))},
                       coords={"view": ["cam"], "frame": [0]})
    frames = xr.Dataset({"depth": (("view", "frame", "y", "x"), np.zeros((1, 1, 4, 4), np.uint16)),
                         **{k: (("view",), [np.nan if k == "fx" else 1.0]) for k in ("fx", "fy", "cx", "cy")},
                         "dist": (("view", "dist_coef"), np.zeros((1, 5))),
                         "cam_to_world": (("view", "row", "col"), np.eye(4)[None])},
                        coords={"view": ["cam"], "frame": [0]}, attrs={"fps": 30.0})
    with pytest.raises(ValueError, match="'cam' has a non-finite calibration"):
        m3d.markers3d(reflectors, masks, frames, m3d.Markers3DConfig())


def _view_frame(cam, world):
    """Depth (a plane at the point's depth) and a 3 x 3 reflector region at the point's pixel."""
    uv, z = cam.project(world[None])
    u, v = np.round(uv[0]).astype(int)
    depth = np.full((cam.height, cam.width), int(round(z[0] * 1000)), np.uint16)
    blob_id = np.zeros_like(depth)
    blob_id[v - 1:v + 2, u - 1:u + 2] = 1
    depth[blob_id > 0] = 0
    return depth, blob_id, (float(u), float(v))


def test_missing_frames_of_a_view_are_skipped_not_fused():
    """View b loses frame 1 entirely and the depth of frame 0: both frames come from view a alone, exactly."""
    world = np.array([0.1, 0.05, 1.2])
    cams = [_camera([2.5, -1.0, 1.2]), _camera([-2.0, -2.0, 1.4])]
    depth, blob, xy = map(list, zip(*[_view_frame(c, world) for c in cams]))
    depth_b0 = np.zeros_like(depth[1])  # frame 0 of view b: no depth arrived
    stack = lambda a0, a1: np.stack([a0, a1])  # noqa: E731  (frame,)
    depths = np.stack([stack(depth[0], depth[0]), stack(depth_b0, np.zeros_like(depth[1]))])
    blobs = np.stack([stack(blob[0], blob[0]), stack(blob[1], np.zeros_like(blob[1]))])
    x = np.array([[[xy[0][0]], [xy[0][0]]], [[xy[1][0]], [np.nan]]], np.float32)  # (view, frame, reflector)
    y = np.array([[[xy[0][1]], [xy[0][1]]], [[xy[1][1]], [np.nan]]], np.float32)
    coords = {"view": ["a", "b"], "frame": [0, 1]}
    reflectors = xr.Dataset({"x": (("view", "frame", "reflector"), x), "y": (("view", "frame", "reflector"), y),
                             "confidence": (("view", "frame", "reflector"), np.where(np.isfinite(x), 0.9, 0.0))},
                            coords={**coords, "reflector": ["F_SPINEMID"]})
    masks = xr.Dataset({"blob_id": (("view", "frame", "y", "x"), blobs)}, coords=coords)
    frames = xr.Dataset({"depth": (("view", "frame", "y", "x"), depths),
                         **{k: (("view",), [float(c.K[i]) for c in cams])
                            for k, i in (("fx", (0, 0)), ("fy", (1, 1)), ("cx", (0, 2)), ("cy", (1, 2)))},
                         "dist": (("view", "dist_coef"), np.stack([np.asarray(c.dist, float) for c in cams])),
                         "cam_to_world": (("view", "row", "col"), np.stack([c.cam_to_world for c in cams]))},
                        coords=coords, attrs={"fps": 30.0})
    out = m3d.markers3d(reflectors, masks, frames, m3d.Markers3DConfig())
    np.testing.assert_allclose(out["position"].values[:, 0], [world, world], atol=0.01)
    np.testing.assert_array_equal(out["views"].values[:, 0], [1, 1])
    assert np.isnan(out["residual"].sel(view="b").values).all()  # view b contributed nothing
    # each view's own estimate is kept beside the fused point: view a's is the point, view b has none
    own = out["view_position"].sel(reflector="F_SPINEMID")
    np.testing.assert_allclose(own.sel(view="a").values, [world, world], atol=0.01)
    assert np.isnan(own.sel(view="b").values).all()
    np.testing.assert_allclose(out["view_confidence"].sel(reflector="F_SPINEMID").values, [[0.9, 0.0], [0.9, 0.0]])


def test_last_resort_lifts_a_recovered_estimate_only_where_no_view_has_a_plain_one():
    found = np.array([[[True, True, False]], [[True, True, True]]])  # (view, frame, reflector)
    recovered = np.array([[[False, True, False]], [[True, True, False]]])
    np.testing.assert_array_equal(m3d.last_resort(found, recovered),
                                  [[[True, True, False]], [[False, True, True]]])


def test_recovered_estimates_are_not_lifted_unless_asked_and_then_only_as_a_last_resort():
    """Both views see the point; view b's estimates are recovered ones, view a loses frame 1."""
    world = np.array([0.1, 0.05, 1.2])
    cams = [_camera([2.5, -1.0, 1.2]), _camera([-2.0, -2.0, 1.4])]
    depth, blob, xy = map(list, zip(*[_view_frame(c, world) for c in cams]))
    coords = {"view": ["a", "b"], "frame": [0, 1]}
    x = np.array([[[xy[0][0]], [np.nan]], [[xy[1][0]], [xy[1][0]]]], np.float32)  # (view, frame, reflector)
    y = np.array([[[xy[0][1]], [np.nan]], [[xy[1][1]], [xy[1][1]]]], np.float32)
    per = ("view", "frame", "reflector")
    reflectors = xr.Dataset({"x": (per, x), "y": (per, y), "confidence": (per, np.where(np.isfinite(x), 0.9, 0.0)),
                             "recovered": (per, np.array([[[False], [False]], [[True], [True]]]))},
                            coords={**coords, "reflector": ["F_SPINEMID"]})
    masks = xr.Dataset({"blob_id": (("view", "frame", "y", "x"), np.stack([np.stack([b, b]) for b in blob]))},
                       coords=coords)
    frames = xr.Dataset({"depth": (("view", "frame", "y", "x"), np.stack([np.stack([d, d]) for d in depth])),
                         **{k: (("view",), [float(c.K[i]) for c in cams])
                            for k, i in (("fx", (0, 0)), ("fy", (1, 1)), ("cx", (0, 2)), ("cy", (1, 2)))},
                         "dist": (("view", "dist_coef"), np.stack([np.asarray(c.dist, float) for c in cams])),
                         "cam_to_world": (("view", "row", "col"), np.stack([c.cam_to_world for c in cams]))},
                        coords=coords, attrs={"fps": 30.0})
    plain = m3d.markers3d(reflectors, masks, frames, m3d.Markers3DConfig())
    np.testing.assert_array_equal(plain["views"].values[:, 0], [1, 0])  # view a alone; frame 1: nothing
    np.testing.assert_allclose(plain["position"].values[0, 0], world, atol=0.01)
    assert np.isnan(plain["position"].values[1, 0]).all()
    assert np.isnan(plain["residual"].sel(view="b").values).all()
    last = m3d.markers3d(reflectors, masks, frames, m3d.Markers3DConfig(lift_recovered=True))
    np.testing.assert_array_equal(last["views"].values[:, 0], [1, 1])  # frame 1 from view b's recovered estimate
    np.testing.assert_allclose(last["position"].values[:, 0], [world, world], atol=0.01)
    assert np.isnan(last["residual"].sel(view="b").values[0]).all()  # frame 0: view a's plain estimate alone


def test_a_view_lifted_below_the_floor_is_dropped_before_fusion():
    """View b reads the reflector on a depth eight times too far: its point lands under the floor and is not fused."""
    world = np.array([0.1, 0.05, 1.2])
    cams = [_camera([2.5, -1.0, 1.2]), _camera([-2.0, -2.0, 1.4])]
    depth, blob, xy = map(list, zip(*[_view_frame(c, world) for c in cams]))
    depth[1] = np.where(depth[1] > 0, depth[1] * 8, 0).astype(np.uint16)  # the background behind, far below the floor
    coords = {"view": ["a", "b"], "frame": [0]}
    per = ("view", "frame", "reflector")
    reflectors = xr.Dataset({"x": (per, np.array([[[xy[0][0]]], [[xy[1][0]]]], np.float32)),
                             "y": (per, np.array([[[xy[0][1]]], [[xy[1][1]]]], np.float32)),
                             "confidence": (per, np.full((2, 1, 1), 0.9, np.float32))},
                            coords={**coords, "reflector": ["F_SPINEMID"]})
    masks = xr.Dataset({"blob_id": (("view", "frame", "y", "x"), np.stack([b[None] for b in blob]))}, coords=coords)
    frames = xr.Dataset({"depth": (("view", "frame", "y", "x"), np.stack([d[None] for d in depth])),
                         **{k: (("view",), [float(c.K[i]) for c in cams])
                            for k, i in (("fx", (0, 0)), ("fy", (1, 1)), ("cx", (0, 2)), ("cy", (1, 2)))},
                         "dist": (("view", "dist_coef"), np.stack([np.asarray(c.dist, float) for c in cams])),
                         "cam_to_world": (("view", "row", "col"), np.stack([c.cam_to_world for c in cams]))},
                        coords=coords, attrs={"fps": 30.0})
    out = m3d.markers3d(reflectors, masks, frames, m3d.Markers3DConfig())
    np.testing.assert_allclose(out["position"].values[0, 0], world, atol=0.01)  # view a's point alone
    assert out["views"].values[0, 0] == 1 and out.attrs["rejected_view_estimates"] == 1
    assert np.isnan(out["view_position"].sel(view="b").values).all()
    kept = m3d.markers3d(reflectors, masks, frames, m3d.Markers3DConfig(floor_m=-100.0, body_reach_m=0.0))
    assert kept.attrs["rejected_view_estimates"] == 0
    assert kept["view_position"].sel(view="b", reflector="F_SPINEMID").values[0, 2] < -0.1  # where it would have gone
    with pytest.raises(ValueError, match="ceiling_m must exceed floor_m"):
        m3d.Markers3DConfig(floor_m=3.0)


def test_a_view_point_beyond_the_bodys_reach_is_dropped_and_an_outstretched_hand_is_not():
    """Frame 0: a trunk of reflectors seen by two views, a hand 0.95 m out to the side (a T-pose) and, in view b, a
    label lifted 2 m away across the floor (a region of the background at the body's height); frame 1: nothing seen."""
    rng = np.random.default_rng(3)
    trunk = np.array([0.0, 0.0, 1.0]) + rng.uniform(-0.25, 0.25, (12, 3))
    hand, stray = np.array([0.95, 0.1, 1.4]), np.array([-1.4, 1.5, 1.2])
    points = np.full((2, 2, 14, 3), np.nan)  # (view, frame, reflector, xyz)
    points[:, 0, :12] = trunk
    points[0, 0, 12] = hand
    points[1, 0, 13] = stray
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an empty frame raises no all-NaN warning
        far = m3d.beyond_reach(points, 1.2)
    assert far.shape == (2, 2, 14) and far.sum() == 1 and far[1, 0, 13]
    assert not m3d.beyond_reach(points, 3.0).any()  # the stray point is 2.05 m out
    with pytest.raises(ValueError, match="body_reach_m must be >= 0"):
        m3d.Markers3DConfig(body_reach_m=-1.0)


def test_region_labels_and_boxes_equal_the_plain_searches():
    from scipy import ndimage

    rng = np.random.default_rng(7)
    blob_id = np.zeros((40, 50), np.uint16)
    for k in range(1, 9):
        y, x = rng.integers(0, 38), rng.integers(0, 48)
        blob_id[y:y + 3, x:x + 3] = k  # later blobs may cover earlier ones: some labels are absent
    assert m3d._boxes(blob_id) == ndimage.find_objects(blob_id)
    assert m3d._boxes(np.zeros((5, 5), np.uint16)) == ndimage.find_objects(np.zeros((5, 5), np.uint16))
    xy = np.vstack([rng.uniform(-2, 52, (200, 2)), [[-9.0, 3.0], [3.0, -20.0], [60.0, 45.0]]])
    expected = [m3d._region_label_at(p, blob_id, 3) for p in np.rint(xy).astype(int)]
    for p, label in zip(np.rint(xy).astype(int), expected):  # the loop it replaced, written out
        x, y = p
        window = blob_id[max(y - 3, 0):y + 4, max(x - 3, 0):x + 4]
        ys, xs = np.nonzero(window)
        k = np.argmin((xs + max(x - 3, 0) - x) ** 2 + (ys + max(y - 3, 0) - y) ** 2) if len(xs) else None
        assert label == (0 if k is None else window[ys[k], xs[k]])
    np.testing.assert_array_equal(m3d._region_labels(xy, blob_id), expected)
