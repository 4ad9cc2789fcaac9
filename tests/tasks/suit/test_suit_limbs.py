"""Limbs no labelled corner holds, posed on the unclaimed corner detections (tasks/suit/limbs.py): the search over
rotations, the matching and triangulation, and ``fill.fill_suit_detections`` on Anny with a bent forearm no corner
of which is observed."""

import numpy as np
import pytest
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared import mesh_body as mb
from mocapflow.tasks.shared.cameras import calibrated_camera
from mocapflow.tasks.shared.kinematics import world_rotations
from mocapflow.tasks.shared.place_fit import reference_body
from mocapflow.tasks.shared.cameras import look_at
from mocapflow.tasks.suit.body_fit import corner_weights, face_normals
from mocapflow.tasks.suit.fill import FillDetectionsConfig, FillSuitConfig, fill_suit, fill_suit_detections
from mocapflow.tasks.suit.limbs import (LimbConfig, LimbError, limb_pixels, limb_points, limbs_of, matched_pixels,
                                        rotation_grid, search, unclaimed, views_of)

WIDTH, HEIGHT = 768, 1024


def ring(count: int, radius: float = 3.0, height: float = 1.2, target=(0.0, 0.0, 1.0)) -> list:
    """Cameras on a ring looking at ``target`` (OpenCV axes: x right, y down, z forward)."""
    out = []
    for k in range(count):
        a = 2 * np.pi * k / count
        centre = np.array([radius * np.cos(a), radius * np.sin(a), height + 0.3 * (k % 2)])
        out.append(calibrated_camera(f"cam{k:02d}", fx=900.0, fy=900.0, cx=WIDTH / 2, cy=HEIGHT / 2,
                                     dist=[0.02, -0.01, 0.0, 0.0, 0.0], cam_to_world=look_at(centre, target),
                                     width=WIDTH, height=HEIGHT))
    return out


def sleeve(count: int = 40, radius: float = 0.04, length: float = 0.25, seed: int = 3):
    """Points scattered on a cylinder along +x from the origin (no symmetry), with outward normals.  -> (c, 3) x 2"""
    rng = np.random.default_rng(seed)
    a, s = rng.uniform(0, 2 * np.pi, count), rng.uniform(0.03, length, count)
    normals = np.column_stack([np.zeros(count), np.cos(a), np.sin(a)])
    return np.column_stack([s, np.zeros(count), np.zeros(count)]) + radius * normals, normals


def facing_pixels(cameras, points, normals, clutter: int = 0, seed: int = 0) -> list[np.ndarray]:
    """Each view's pixels of the points facing it, plus ``clutter`` random pixels.  -> [(n, 2)]"""
    rng = np.random.default_rng(seed)
    out = []
    for cam in cameras:
        facing = ((cam.cam_to_world[:3, 3] - points) * normals).sum(1) > 0
        uv, _ = cam.project(points[facing])
        out.append(np.concatenate([uv, rng.uniform([0, 0], [WIDTH, HEIGHT], (clutter, 2))]))
    return out


def test_rotation_grid_spans_the_reach():
    grid = rotation_grid(30.0, 90.0)
    angles = np.degrees(Rotation.from_matrix(grid).magnitude())
    assert angles.max() <= 90.0 + 1e-6 and np.isclose(angles.min(), 0.0)
    assert len(grid) == 123  # the points of a cubic lattice within three steps of the origin
    np.testing.assert_allclose(grid @ grid.transpose(0, 2, 1), np.broadcast_to(np.eye(3), grid.shape), atol=1e-12)


def test_labels_claim_their_detections():
    detections = np.array([[[10.0, 10.0], [50.0, 50.0], [np.nan, np.nan], [90.0, 90.5]]])
    labels = np.array([[[10.4, 10.0], [np.nan, np.nan], [90.0, 91.6]]])
    free = unclaimed(detections, labels, claimed_px=1.0)
    np.testing.assert_array_equal(free[0], [[50.0, 50.0], [90.0, 90.5]])


def test_search_turns_a_sleeve_onto_its_detections_and_matches_them():
    cameras = ring(6)
    points, normals = sleeve()
    pivot = np.array([0.1, 0.0, 1.2])
    rest = pivot + points
    truth = Rotation.from_rotvec([0.3, -1.1, 0.6]).as_matrix()  # 73 degrees away
    posed, turned = pivot + points @ truth.T, normals @ truth.T
    detected = facing_pixels(cameras, posed, turned)
    views = views_of(cameras, facing_pixels(cameras, posed, turned, clutter=200))
    found, share = search(pivot, rest, normals, views, LimbConfig())
    assert np.degrees(Rotation.from_matrix(found @ truth.T).magnitude()) < 1.5
    assert share > 0.95  # nearly every facing point on a detection
    moved = pivot + points @ found.T
    xy = matched_pixels(moved, normals @ found.T, views, match_px=3.0)
    exact = np.stack([cam.project(posed)[0] for cam in cameras])
    hit = np.isfinite(xy).all(-1)
    assert hit.sum() >= 0.9 * sum(len(d) for d in detected)  # (point, view) pairs facing the camera
    np.testing.assert_allclose(xy[hit], exact[hit], atol=1e-9)  # the detections themselves
    np.testing.assert_allclose(limb_points(xy[None], cameras)[0][hit.sum(0) >= 2], posed[hit.sum(0) >= 2],
                               atol=1e-6)
    empty = views_of(cameras, [np.zeros((0, 2))] * len(cameras))
    assert np.isnan(matched_pixels(moved, normals, empty, 3.0)).all()


def test_a_bone_with_enough_observed_corners_or_too_little_support_is_left_alone():
    cameras = ring(4)
    points, normals = sleeve(16)
    limb = limbs_of(("root", "arm"), np.array([-1, 0]), np.ones(len(points), int), lambda n: n, ("arm",))
    heads = np.array([[[0.0, 0.0, 1.0], [0.1, 0.0, 1.2]]])
    posed = (heads[0, 1] + points)[None]
    views = [views_of(cameras, facing_pixels(cameras, posed[0], normals))]
    observed = np.zeros((1, len(points)), bool)
    args = (posed, normals[None], heads, observed, limb, views)
    assert np.isfinite(limb_pixels(*args, LimbConfig(min_corners=3))).any()
    observed[0, :3] = True
    assert np.isnan(limb_pixels(posed, normals[None], heads, observed, limb, views, LimbConfig(min_corners=3))).all()
    clutter = [views_of(cameras, facing_pixels(cameras, posed[0] + [0.0, 0.5, 0.0], normals, clutter=5))]
    assert np.isnan(limb_pixels(*args[:-1], clutter, LimbConfig(min_share=0.5))).all()


def test_limbs_carry_their_subtree_and_score_their_part():
    names = ("root", "upper", "lower", "hand", "other")
    parents = np.array([-1, 0, 1, 2, 0])
    part = {"root": "trunk", "upper": "arm", "lower": "forearm", "hand": "forearm", "other": "leg"}.get
    corner_bone = np.array([0, 1, 2, 3, 4, 2])
    upper, lower = limbs_of(names, parents, corner_bone, part, ("upper", "lower"))
    np.testing.assert_array_equal(upper.carried, [False, True, True, True, False, True])
    np.testing.assert_array_equal(upper.scored, [False, True, False, False, False, False])
    np.testing.assert_array_equal(lower.scored, [False, False, True, True, False, True])
    np.testing.assert_array_equal(upper.subtree, [False, True, True, True, False])
    with pytest.raises(LimbError, match="no bone 'elbow'"):
        limbs_of(names, parents, corner_bone, part, ("elbow",))
    with pytest.raises(LimbError, match="out of range"):
        LimbConfig(min_share=1.5)


# --- the task on Anny -------------------------------------------------------------------------------------------------

FRAMES = 2


@pytest.fixture(scope="module")
def anny_take():
    """Anny at the default phenotype, the left elbow bent 70-80 degrees (the fit's pose prior keeps it straight);
    corners on the skin, every corner the left forearm moves unobserved, 20 % of the others hidden; six cameras
    detect every corner facing them, plus clutter, and label the observed ones."""
    body = mb.mesh_body(mb.Phenotype())
    rng = np.random.default_rng(5)
    local = np.tile(np.eye(3), (FRAMES, len(body.bone_names), 1, 1))
    elbow = body.bone("lowerarm01.L")
    local[:, elbow] = Rotation.from_rotvec([[0.0, 0.0, 1.2], [0.0, 0.2, 1.35]]).as_matrix()
    root = body.rest_heads[0] + np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0]])
    posed = mb.pose_mesh(body, world_rotations(local, body.bone_parents), root)
    face, bary = mb.random_surface_points(body, rng, 600)
    elsewhere = ~(body.part_faces("left_forearm") | body.part_faces("left_hand"))[face]
    arm_face, arm_bary = mb.random_surface_points(body, rng, 40, "left_forearm")
    face, bary = np.concatenate([face[elsewhere], arm_face]), np.concatenate([bary[elsewhere], arm_bary])
    w = np.column_stack([1 - bary.sum(1), bary])
    truth = (posed.vertices[:, body.faces[face]] * w[None, ..., None]).sum(2)  # (frame, corner, 3)
    normals = np.stack([face_normals(v, body.faces[face]) for v in posed.vertices])
    observed = rng.random(truth.shape[:2]) > 0.2
    below_elbow = [body.bone(n) for n in ("lowerarm01.L", "lowerarm02.L", "wrist.L")]
    moved_by_forearm = corner_weights(reference_body(), face, bary)[:, below_elbow].sum(1) > 0
    observed[:, moved_by_forearm] = False  # nothing observed holds the elbow
    observed[:, -40:] = False
    cameras = ring(6, target=body.rest_heads[0] + [0.0, 0.0, 0.2])
    views = [c.name for c in cameras]
    det = np.full((len(views), FRAMES, 700, 2), np.nan)
    lab = np.full((len(views), FRAMES, len(face), 2), np.nan)
    for f in range(FRAMES):
        for v, cam in enumerate(cameras):
            facing = ((cam.cam_to_world[:3, 3] - truth[f]) * normals[f]).sum(1) > 0
            uv = cam.project(truth[f])[0]
            found = np.concatenate([uv[facing], rng.uniform([0, 0], [WIDTH, HEIGHT], (60, 2))])
            det[v, f, :len(found)] = found
            lab[v, f][facing & observed[f]] = uv[facing & observed[f]]
    moved_by_forearm[-40:] = True
    return face, bary, truth, observed, cameras, views, det, lab, moved_by_forearm


def datasets(face, bary, truth, observed, cameras, views, det, lab):
    frame, corner = np.arange(FRAMES), np.arange(len(face))
    points = xr.Dataset({"position": (("frame", "corner", "xyz"), np.where(observed[..., None], truth, np.nan))},
                        coords={"frame": frame, "corner": corner}, attrs={"fps": 30.0})
    cal = {k: (("view",), [getattr(c, k) for c in cameras]) for k in ("fx", "fy", "cx", "cy", "width", "height")}
    images = xr.Dataset({"corner_face": (("corner",), face), "corner_bary": (("corner", "uv"), bary),
                         "cells": (("cell", "k"), np.zeros((0, 4), np.int64)),
                         "dist": (("view", "dist_coef"), [list(c.dist) for c in cameras]),
                         "cam_to_world": (("view", "row", "col"), [c.cam_to_world for c in cameras]), **cal},
                        coords={"view": views}, attrs={"fps": 30.0})
    corners = xr.Dataset({"x": (("view", "frame", "detection"), det[..., 0]),
                          "y": (("view", "frame", "detection"), det[..., 1])}, coords={"view": views, "frame": frame})
    labels = xr.Dataset({"x": (("view", "frame", "corner"), lab[..., 0]), "y": (("view", "frame", "corner"), lab[..., 1])},
                        coords={"view": views, "frame": frame, "corner": corner})
    return points, images, corners, labels


def test_fill_suit_detections_puts_an_unobserved_forearm_back(anny_take):
    face, bary, truth, observed, cameras, views, det, lab, moved = anny_take
    points, images, corners, labels = datasets(face, bary, truth, observed, cameras, views, det, lab)
    plain = fill_suit(points, images, FillSuitConfig())
    held = fill_suit_detections(points, images, corners, labels, FillDetectionsConfig())
    forearm = np.broadcast_to(moved, observed.shape)
    err_plain = np.linalg.norm(plain["position"].values - truth, axis=-1)[forearm] * 1000.0
    err_held = np.linalg.norm(held["position"].values - truth, axis=-1)[forearm] * 1000.0
    assert np.median(err_plain) > 40.0  # the straight arm of the pose prior
    assert np.median(err_held) < 2.0 and np.percentile(err_held, 95) < 5.0
    np.testing.assert_array_equal(held["observed"].values, observed)  # placed corners are not observations
    rest = ~observed & ~forearm
    assert np.median(np.linalg.norm(held["position"].values - truth, axis=-1)[rest]) * 1000.0 < 1.0
