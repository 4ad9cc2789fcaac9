"""2D reflectors refined from the solved poses: projection, posed template, label exchange and reprojection,
on a hand-built view whose 3D reflectors, camera and reflector regions are known."""

import numpy as np
import pytest
import xarray as xr
from scipy import ndimage
from scipy.spatial.transform import Rotation

from mocapflow.tasks.deepmocap import refine2d
from mocapflow.tasks.shared.cameras import intrinsics, look_at, project
from mocapflow.tasks.deepmocap.skeleton import patch_normals

K = intrinsics(365.0, 365.0, 256.0, 212.0)
NO_DIST = np.zeros(5)
NAMES = ["L_PELVIS", "R_PELVIS", "L_CALF", "R_CALF", "F_L_HEAD", "F_R_HEAD", "B_HEAD"]
RADIUS = {"L_CALF": 0.052, "R_CALF": 0.052}  # straps: tasks.markers3d.nominal_radius of the shins


def test_projection_matches_the_pinhole_model_and_drops_points_behind():
    pose = look_at(np.array([0.0, -3.0, 1.0]), np.array([0.0, 0.0, 1.0]))  # looking along +y
    points = np.array([[0.0, 0.0, 1.0], [0.5, 1.0, 1.5], [0.0, -4.0, 1.0], [np.nan, 0.0, 0.0]])
    uv, z = project(points, K, NO_DIST, pose)
    assert uv[0] == pytest.approx([256.0, 212.0]) and z[0] == pytest.approx(3.0)
    assert uv[1] == pytest.approx([256.0 + 365.0 * 0.5 / 4.0, 212.0 - 365.0 * 0.5 / 4.0]) and z[1] == pytest.approx(4.0)
    assert np.isnan(uv[2:]).all() and np.isnan(z[2:]).all()  # behind the camera; not finite


def test_posed_reflectors_follow_the_chain_and_unsolved_frames_are_nan():
    parents, bones = np.array([-1, 0]), np.array([0, 1])
    offsets = np.array([[0.1, 0.0, 0.0], [0.0, 0.2, 0.0]])  # reflectors in their bones' frames
    normals = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    rotation = np.zeros((2, 2, 4))
    rotation[:, :, 3] = 1.0  # identity
    rotation[0, 0] = Rotation.from_euler("z", 90, degrees=True).as_quat()  # root turned 90 degrees about z
    rotation[1] = np.nan  # frame 1 unsolved
    position = np.array([[[1.0, 2.0, 3.0], [1.0, 2.5, 3.0]], [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]])
    xyz, normal = refine2d.posed_reflectors(rotation, position, parents, bones, offsets, normals)
    np.testing.assert_allclose(xyz[0], [[1.0, 2.1, 3.0], [0.8, 2.5, 3.0]], atol=1e-12)  # child inherits the turn
    np.testing.assert_allclose(normal[0], [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]], atol=1e-12)
    assert np.isnan(xyz[1]).all() and np.isnan(normal[1]).all()


def test_exchangeable_pairs_leave_out_mirrored_reflectors_close_at_rest():
    pairs = refine2d.exchangeable_pairs(NAMES, 0.10)
    named = {(NAMES[a], NAMES[b]) for a, b in pairs}
    assert named == {("L_PELVIS", "R_PELVIS"), ("L_CALF", "R_CALF")}  # the forehead patches are 6 cm apart
    assert ("F_L_HEAD", "F_R_HEAD") in {(NAMES[a], NAMES[b]) for a, b in refine2d.exchangeable_pairs(NAMES, 0.0)}


def test_labels_are_exchanged_only_when_clearly_nearer_the_other_projection():
    ref = np.array([[100.0, 100.0], [140.0, 100.0]])
    swapped = ref[::-1] + 1.0
    assert list(refine2d.exchange_sides(swapped, ref, [(0, 1)], reach_px=20, margin_px=3)) == [1, 0]
    assert list(refine2d.exchange_sides(ref + 1.0, ref, [(0, 1)], reach_px=20, margin_px=3)) == [0, 1]
    lone = np.array([[139.0, 101.0], [np.nan, np.nan]])  # one estimate, on the other label's projection
    assert list(refine2d.exchange_sides(lone, ref, [(0, 1)], reach_px=20, margin_px=3)) == [1, 0]
    far = np.array([[np.nan, np.nan], [100.0, 130.0]])  # nearer the other label, but 30 px from it
    assert list(refine2d.exchange_sides(far, ref, [(0, 1)], reach_px=20, margin_px=3)) == [0, 1]
    close = np.array([[121.0, 100.0], [119.0, 100.0]])  # an exchange would gain 4 px in sum: 3 px margin
    assert list(refine2d.exchange_sides(close, ref, [(0, 1)], reach_px=20, margin_px=3)) == [1, 0]
    assert list(refine2d.exchange_sides(close, ref, [(0, 1)], reach_px=20, margin_px=5)) == [0, 1]
    assert list(refine2d.exchange_sides(swapped, ref * np.nan, [(0, 1)], reach_px=20, margin_px=3)) == [0, 1]


def test_facing_is_the_cosine_to_the_camera_and_straps_always_face():
    xyz = np.zeros((3, 3))
    normal = np.array([[0.0, -1.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 0.0]])
    cos = refine2d.facing_cosines(xyz, normal, np.array([0.0, -3.0, 0.0]))
    np.testing.assert_allclose(cos, [1.0, -1.0, 1.0])


def scene(world: dict, *, depth_offset_m: dict | None = None, hide: tuple = ()):
    """One view of reflectors at ``world`` (name -> xyz): a 3 px disc at each projection (except ``hide``;
    touching discs make one region, as the mask's connected components), the surface depth on a ring around
    it (a strap's one radius nearer than its centre; plus ``depth_offset_m``), the camera in front of the
    pelvis patches' mean normal.  -> pose, blob_id, area, depth"""
    normals = patch_normals(NAMES)
    facing = normals[[NAMES.index(n) for n in ("L_PELVIS", "R_PELVIS")]].sum(0)
    target = np.mean([world[n] for n in ("L_PELVIS", "R_PELVIS")], axis=0)
    pose = look_at(target + 2.5 * facing / np.linalg.norm(facing), target)
    disc, depth = np.zeros((424, 512), bool), np.zeros((424, 512), np.uint16)
    ys, xs = np.mgrid[0:424, 0:512]
    for name, point in world.items():
        if name in hide:
            continue
        uv, z = project(point[None], K, NO_DIST, pose)
        d2 = (xs - uv[0, 0]) ** 2 + (ys - uv[0, 1]) ** 2
        surface = z[0] - RADIUS.get(name, 0.0) + (depth_offset_m or {}).get(name, 0.0)
        depth[(d2 <= 64) & ~disc] = round(1000 * surface)
        disc |= d2 <= 9
    blob_id, n = ndimage.label(disc)
    return pose, blob_id.astype(np.int32), np.bincount(blob_id.ravel(), minlength=n + 1)[1:].astype(np.int32), depth


def datasets(world: dict, estimates: dict, pose, blob_id, area, depth):
    """The stage's inputs for one view and frame: the template's reflectors on one root joint at ``world``."""
    frame = {"frame": [0]}
    uv, _ = project(np.array([world[n] for n in NAMES]), K, NO_DIST, pose)
    x = np.array([estimates.get(n, (np.nan, np.nan))[0] for n in NAMES], np.float32)
    y = np.array([estimates.get(n, (np.nan, np.nan))[1] for n in NAMES], np.float32)
    found = np.isfinite(x)
    per = ("view", "frame", "reflector")
    reflectors = xr.Dataset(
        {"x": (per, x[None, None]), "y": (per, y[None, None]), "confidence": (per, (0.9 * found)[None, None]),
         "region_size": (per, (9 * found).astype(np.int32)[None, None]), "candidate_x": (per, x[None, None]),
         "candidate_y": (per, y[None, None]), "candidate_confidence": (per, (0.9 * found)[None, None])},
        coords={"view": ["v0"], **frame, "reflector": NAMES}, attrs={"b_min": 5, "c_min": 0.1})
    poses = xr.Dataset({"position": (("frame", "joint", "xyz"), np.zeros((1, 1, 3))),
                        "rotation": (("frame", "joint", "quat"), np.array([[[0.0, 0.0, 0.0, 1.0]]]))}, coords=frame)
    skeleton = xr.Dataset({"parent": ("joint", [-1]), "bone": ("reflector", np.zeros(len(NAMES), int)),
                           "reflector_offset": (("reflector", "xyz"), np.array([world[n] for n in NAMES]))},
                          coords={"reflector": NAMES})
    masks = xr.Dataset({"blob_id": (("view", "frame", "y", "x"), blob_id[None, None]),
                        "blob_area": (("view", "frame", "blob"), area[None, None])}, coords={"view": ["v0"], **frame})
    frames = xr.Dataset({"depth": (("view", "frame", "y", "x"), depth[None, None]),
                         "cam_to_world": (("view", "a", "b"), pose[None]), "dist": (("view", "k"), NO_DIST[None]),
                         **{k: ("view", [v]) for k, v in (("fx", 365.0), ("fy", 365.0), ("cx", 256.0), ("cy", 212.0))}},
                        coords={"view": ["v0"], **frame})
    return reflectors, poses, skeleton, masks, frames, uv


WORLD = {"L_PELVIS": np.array([-0.15, 0.0, 1.0]), "R_PELVIS": np.array([0.15, 0.0, 1.0]),
         "L_CALF": np.array([-0.12, 0.0, 0.45]), "R_CALF": np.array([0.12, 0.0, 0.45]),
         "F_L_HEAD": np.array([-0.03, 0.0, 1.65]), "F_R_HEAD": np.array([0.03, 0.0, 1.65]),
         "B_HEAD": np.array([0.0, 0.15, 1.62])}


def refine(reflectors, poses, skeleton, masks, frames, **params):
    config = refine2d.Refine2DConfig(**params)
    return refine2d.refine_reflectors(reflectors, poses, skeleton, masks, frames, config).isel(view=0, frame=0)


def test_exchanged_calves_come_back_and_a_missing_pelvis_patch_is_added_at_its_region():
    pose, blob_id, area, depth = scene(WORLD, hide=("B_HEAD",))
    _, _, _, _, _, uv = datasets(WORLD, {}, pose, blob_id, area, depth)
    at = {n: tuple(uv[NAMES.index(n)]) for n in NAMES}
    estimates = {"L_CALF": at["R_CALF"], "R_CALF": at["L_CALF"], "L_PELVIS": at["L_PELVIS"],
                 "F_L_HEAD": at["F_R_HEAD"], "F_R_HEAD": at["F_L_HEAD"]}  # calves and foreheads exchanged
    inputs = datasets(WORLD, estimates, pose, blob_id, area, depth)[:5]
    out = refine(*inputs)
    xy = np.column_stack([out["x"].values, out["y"].values])
    for name in ("L_CALF", "R_CALF", "L_PELVIS", "R_PELVIS"):
        assert xy[NAMES.index(name)] == pytest.approx(at[name], abs=0.05), name
    assert list(out["exchanged"].values) == [n in ("L_CALF", "R_CALF") for n in NAMES]
    assert xy[NAMES.index("F_L_HEAD")] == pytest.approx(at["F_R_HEAD"])  # 6 cm apart at rest: left alone
    assert list(out["reprojected"].values) == [n == "R_PELVIS" for n in NAMES]
    r = NAMES.index("R_PELVIS")
    label = blob_id[int(round(at["R_PELVIS"][1])), int(round(at["R_PELVIS"][0]))]
    assert out["confidence"].values[r] == pytest.approx(0.1) and out["region_size"].values[r] == area[label - 1] > 20
    assert out["confidence"].values[NAMES.index("L_CALF")] == pytest.approx(0.9)  # its estimate's own E
    assert np.isnan(xy[NAMES.index("B_HEAD")]).all()  # no region: nothing added
    np.testing.assert_array_equal(out["candidate_x"].values, inputs[0]["candidate_x"].values[0, 0])  # unchanged


def test_no_reflector_is_added_on_a_region_at_the_wrong_depth_or_facing_away():
    world = {**WORLD, "B_HEAD": np.array([0.0, 0.0, 1.62])}  # its region in plain sight, but the patch faces away
    pose, blob_id, area, depth = scene(world, depth_offset_m={"R_PELVIS": -0.3})  # something 30 cm nearer
    inputs = datasets(world, {}, pose, blob_id, area, depth)[:5]
    added = refine(*inputs)["reprojected"].values
    assert not added[NAMES.index("R_PELVIS")] and not added[NAMES.index("B_HEAD")]
    assert added[NAMES.index("L_PELVIS")] and added[NAMES.index("L_CALF")]  # a strap: its surface one radius nearer
    assert refine(*inputs, depth_tolerance_m=0.02)["reprojected"].values[NAMES.index("L_CALF")]  # 5 cm: the radius
    relaxed = refine(*inputs, depth_tolerance_m=0.5, min_facing=-1.0)["reprojected"].values
    assert relaxed[NAMES.index("R_PELVIS")] and relaxed[NAMES.index("B_HEAD")]
    assert not refine(*inputs, reproject_snap_px=0.0)["reprojected"].values.any()


def test_a_missing_reflector_takes_its_part_of_a_region_another_estimate_holds():
    world = {**WORLD, "F_L_HEAD": np.array([-0.02, 0.0, 1.65]), "F_R_HEAD": np.array([0.02, 0.0, 1.65])}
    pose, blob_id, area, depth = scene(world)
    _, _, _, _, _, uv = datasets(world, {}, pose, blob_id, area, depth)
    left, right = uv[NAMES.index("F_L_HEAD")], uv[NAMES.index("F_R_HEAD")]
    assert 4.0 < np.linalg.norm(left - right) < 7.0  # the two forehead discs touch: one region
    label = blob_id[int(round(left[1])), int(round(left[0]))]
    assert label == blob_id[int(round(right[1])), int(round(right[0]))]
    inputs = datasets(world, {"F_R_HEAD": tuple(right)}, pose, blob_id, area, depth)[:5]
    out = refine(*inputs)
    r = NAMES.index("F_L_HEAD")
    assert out["reprojected"].values[r]
    assert np.linalg.norm([out["x"].values[r] - left[0], out["y"].values[r] - left[1]]) < 2.0  # its own half
    assert out["x"].values[NAMES.index("F_R_HEAD")] == pytest.approx(right[0])  # the holder does not move


def test_bad_settings_are_clear_errors():
    with pytest.raises(ValueError, match="depth_tolerance_m must be > 0"):
        refine2d.Refine2DConfig(depth_tolerance_m=0.0)
    with pytest.raises(ValueError, match="min_facing is a cosine"):
        refine2d.Refine2DConfig(min_facing=2.0)
    with pytest.raises(ValueError, match="exchange_reach_px must be >= 0"):
        refine2d.Refine2DConfig(exchange_reach_px=-1.0)
