"""Rendering: depth on the body surface, GT 2D on reflector pixels, occlusion, blob sizes, scene flow."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.shared import body, kinematics, reflectors
from mocapflow.tasks.deepmocap.film import render
from mocapflow.tasks.studio import cameras, motion
from mocapflow.tasks.deepmocap.film.synth import build_rig, synthesize
from mocapflow.tasks.studio.spec import SequenceSpec

NAMES = reflectors.REFLECTOR_NAMES


@pytest.fixture(scope="module")
def clean_rig():
    return build_rig(SequenceSpec("jumping_jack", frames=12, seed=5, noise=0.0))


@pytest.fixture(scope="module")
def clean_frames(clean_rig):
    return synthesize(clean_rig, 0, 12)


def backproject(view, depth_mm):
    """World points of every pixel with depth (metres), using the view's undistorted rays."""
    ys, xs = np.nonzero(depth_mm)
    z = depth_mm[ys, xs] / 1000.0
    cam_pts = view.rays[ys, xs] * (z / view.rays[ys, xs, 2])[:, None]
    c2w = view.cam.cam_to_world
    return cam_pts @ c2w[:3, :3].T + c2w[:3, 3], ys, xs


def surface_distance(points, prims, rot, pos):
    """Distance of world points to the nearest primitive surface (exact for capsules, bounded for ellipsoids)."""
    best = np.full(len(points), np.inf)
    for prim in prims:
        local = (points - pos[prim.joint]) @ rot[prim.joint]
        if prim.kind == "capsule":
            ab = prim.b - prim.a
            s = np.clip((local - prim.a) @ ab / (ab @ ab), 0, 1)
            d = np.abs(np.linalg.norm(local - (prim.a + np.outer(s, ab)), axis=1) - prim.radii[0])
        else:
            q = (local - prim.a) / prim.radii
            d = np.abs(np.linalg.norm(q, axis=1) - 1) * prim.radii.min()
        best = np.minimum(best, d)
    return best


def test_noise_free_depth_lies_on_the_body_surface(clean_rig, clean_frames):
    for v, view in enumerate(clean_rig.views):
        depth = clean_frames.depth.values[v, 3]
        room_mm = view.bg_t * view.rays[..., 2] * 1000.0
        body_px = np.where(depth < room_mm - 20, depth, 0).astype(np.uint16)  # nearer than the static room
        pts, _, _ = backproject(view, body_px)
        dist = surface_distance(pts, clean_rig.prims, clean_rig.joint_rot[3], clean_rig.joint_pos[3])
        assert len(pts) > 2000
        assert np.median(dist) < 0.001 and np.percentile(dist, 99) < 0.004


def test_gt_2d_positions_fall_on_their_rendered_reflector_pixels(clean_rig, clean_frames):
    """A patch's GT 2D point is on its pixels; a strap's (the limb centre) is too when the limb is seen side-on."""
    rid = clean_frames.gt_reflector_id.values  # (view, frame, y, x)
    uv = clean_frames.gt_reflectors2d.values
    pixels = clean_frames.gt_pixels.values
    checked = {"patch": 0, "strap": 0}
    for v, f, r in zip(*np.nonzero(pixels >= 15)):
        placement = clean_rig.placements[r]
        u, w = np.rint(uv[v, f, r]).astype(int)
        on_pixels = (rid[v, f, max(w - 1, 0):w + 2, max(u - 1, 0):u + 2] == r).any()
        if placement.kind == "patch":
            assert on_pixels, f"{NAMES[r]} view {v} frame {f}"
            checked["patch"] += 1
            continue
        joint = clean_rig.prims[placement.prim].joint
        axis = clean_rig.joint_rot[f, joint] @ placement.normal
        ray = clean_frames.gt_reflectors.values[f, r] - clean_rig.views[v].cam.cam_to_world[:3, 3]
        side_on = abs(axis @ ray) / np.linalg.norm(ray) < np.cos(np.radians(60))
        if side_on:
            assert on_pixels, f"{NAMES[r]} view {v} frame {f}"
            checked["strap"] += 1
        else:  # oblique limb: the centre projects within the limb's image radius of the band
            ys, xs = np.nonzero(rid[v, f] == r)
            radius_px = clean_rig.views[v].cam.fx * clean_rig.prims[placement.prim].radii[0] / np.linalg.norm(ray)
            assert np.hypot(xs - uv[v, f, r, 0], ys - uv[v, f, r, 1]).min() <= radius_px + 1.5
    assert checked["patch"] > 200 and checked["strap"] > 100


def test_reflector_pixels_have_zero_depth_and_saturated_ir(clean_frames):
    rid = clean_frames.gt_reflector_id.values
    on = rid >= 0
    assert on.sum() > 1000
    assert (clean_frames.depth.values[on] == 0).all()
    ir = clean_frames.ir.values
    assert ir[on].min() > 60000
    body_ir = ir[(clean_frames.depth.values > 1500) & (clean_frames.depth.values < 3500) & ~on]
    assert np.median(body_ir) < 8000  # clearly distinguishable from reflectors


def test_blob_areas_are_plausible_at_two_to_three_metres(clean_frames):
    pixels = clean_frames.gt_pixels.values
    visible = pixels[pixels > 0]
    assert 10 <= np.median(visible) <= 400
    assert np.percentile(visible, 95) <= 400
    assert (pixels.max(axis=(0, 1)) >= 10).all(), "every reflector is seen well at least once"


def test_an_arm_across_the_chest_hides_the_chest_patch():
    subject = body.Subject(1.75)
    prims = body.surface(subject)
    placements = reflectors.place(prims)
    view = render.prepare_view(cameras.layout()[0])  # the front sensor

    def pixels(pose):
        rot, pos = kinematics.forward_kinematics(pose.rot, pose.root + body.rest_offsets(subject)[0],
                                                  body.rest_offsets(subject), body.PARENTS)
        still = render.Pose(rot[0], pos[0])
        frame = render.render(view, prims, placements, still, still, still, np.random.default_rng(0), 0.0)
        return dict(zip(NAMES, frame.pixels))

    relaxed = pixels(motion._Pose(1).arms_down())
    across = pixels(motion._Pose(1).arms_down().arm_forward("Right", np.radians(60))
                    .turn("RightShoulder", "z", np.radians(45)))
    assert relaxed["F_R_CHEST"] > 30 and relaxed["F_L_CHEST"] > 30
    assert across["F_R_CHEST"] == 0 and across["F_L_CHEST"] > 30
    assert relaxed["B_BACK"] == 0  # a back patch is hidden by the body from the front


def test_straps_are_seen_from_every_side_and_patches_from_one():
    rig = build_rig(SequenceSpec("elbow_flexion", frames=2, seed=1, noise=0.0))
    ds = synthesize(rig, 0, 1)
    seen = ds.gt_visible.values[:, 0]  # (view, reflector)
    for name in ("R_CALF", "L_CALF"):
        assert seen[:, NAMES.index(name)].all(), f"{name} strap must be visible from all three sensors"
    assert not seen[:, NAMES.index("B_BACK")][0] and seen[:, NAMES.index("F_SPINEMID")][0]


def test_rigid_translation_gives_that_scene_flow_forward_and_backward():
    subject = body.Subject(1.7)
    prims = body.surface(subject)
    placements = reflectors.place(prims)
    view = render.prepare_view(cameras.layout()[1])
    pose = motion._Pose(1).arms_down()
    rot, pos = kinematics.forward_kinematics(pose.rot, pose.root + body.rest_offsets(subject)[0],
                                                  body.rest_offsets(subject), body.PARENTS)
    step = np.array([0.02, -0.01, 0.005])
    now = render.Pose(rot[0], pos[0])
    frame = render.render(view, prims, placements, now, render.Pose(rot[0], pos[0] - 2 * step),
                          render.Pose(rot[0], pos[0] + step), np.random.default_rng(0), 0.0)
    assert frame.body.sum() > 3000
    expected = np.broadcast_to(view.R @ step, (frame.body.sum(), 3))
    np.testing.assert_allclose(frame.scene_flow[frame.body], expected, atol=1e-6)
    np.testing.assert_allclose(frame.scene_flow_prev[frame.body], 2 * expected, atol=1e-6)
    assert not frame.scene_flow[~frame.body].any() and not frame.scene_flow_prev[~frame.body].any()


def test_noisy_depth_has_kinect_artifacts():
    rig = build_rig(SequenceSpec("walking_on_the_spot", frames=2, seed=2, noise=1.0))
    clean = build_rig(SequenceSpec("walking_on_the_spot", frames=2, seed=2, noise=0.0))
    noisy_d, clean_d = synthesize(rig, 0, 1).depth.values, synthesize(clean, 0, 1).depth.values
    both = (noisy_d > 0) & (clean_d > 0)
    diff = noisy_d[both].astype(float) - clean_d[both]
    assert 0.5 < np.std(diff[np.abs(diff) < 50]) < 10  # mm-level range noise
    assert ((clean_d > 0) & (noisy_d == 0)).sum() > 100  # edge dropouts
    assert set(np.unique(noisy_d[noisy_d > 0] % 1)) == {0}  # integer millimetres


def test_any_region_renders_the_same_bytes(clean_rig):
    whole = synthesize(clean_rig, 0, 8)
    part = synthesize(clean_rig, 5, 8)
    for var in ("depth", "ir", "gt_reflector_id", "gt_scene_flow", "gt_reflectors2d"):
        np.testing.assert_array_equal(whole[var].sel(frame=slice(5, 7)).values, part[var].values)


def test_ir_bloom_widens_the_saturated_regions_to_a_real_kinects_and_keeps_the_truth():
    """With ir_bloom_px 3 the regions the sensor saturates (no depth, IR at the reflector level) grow round each
    reflector to the 100-400 px of a real Kinect v2's, while the ground truth (which pixels are which reflector,
    and everything else drawn from the seed) stays as it was."""
    from scipy import ndimage

    plain = synthesize(build_rig(SequenceSpec("elbow_flexion", frames=2, seed=1, noise=0.0)), 0, 1)
    bloomed = synthesize(build_rig(SequenceSpec("elbow_flexion", frames=2, seed=1, noise=0.0, ir_bloom_px=3)), 0, 1)
    np.testing.assert_array_equal(plain.gt_reflector_id.values, bloomed.gt_reflector_id.values)
    np.testing.assert_array_equal(plain.gt_pixels.values, bloomed.gt_pixels.values)

    def areas(ds):
        hot = ds.ir.values[0, 0] >= render.IR_REFLECTOR  # saturated
        labels, n = ndimage.label(hot)
        return np.bincount(labels.ravel())[1:]

    before, after = areas(plain), areas(bloomed)
    assert np.median(before) < 100 <= np.median(after) <= 400
    rid = bloomed.gt_reflector_id.values[0, 0] >= 0
    ring = render.saturated(rid, 3) & ~rid
    assert ring.any() and (bloomed.depth.values[0, 0][ring] == 0).all()  # no depth in the bloom
    assert (plain.depth.values[0, 0][ring] > 0).mean() > 0.5  # where the plain sensor read the body or the room
    with pytest.raises(ValueError, match="ir_bloom_px must be within"):
        SequenceSpec("elbow_flexion", ir_bloom_px=-1)


def test_the_mesh_body_blooms_like_the_capsules():
    """Real-sized reflector regions on the mesh body too: saturated IR and no depth round each reflector, the
    ground truth (the reflectors' own pixels) unchanged."""
    spec = dict(frames=2, seed=1, noise=0.0, body="mesh")
    plain = synthesize(build_rig(SequenceSpec("elbow_flexion", **spec)), 0, 1)
    bloomed = synthesize(build_rig(SequenceSpec("elbow_flexion", ir_bloom_px=3, **spec)), 0, 1)
    np.testing.assert_array_equal(plain.gt_reflector_id.values, bloomed.gt_reflector_id.values)
    rid = bloomed.gt_reflector_id.values[0, 0] >= 0
    ring = render.saturated(rid, 3) & ~rid
    hot = bloomed.ir.values[0, 0] >= render.IR_REFLECTOR
    assert ring.sum() > rid.sum() and hot[ring].all() and (bloomed.depth.values[0, 0][ring] == 0).all()
    assert not (plain.ir.values[0, 0] >= render.IR_REFLECTOR)[ring].all()
