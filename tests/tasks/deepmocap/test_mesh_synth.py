"""The studio on the mesh body: Kinect-like frames with reflectors on the skin, ground truth that reproduces the mesh."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapflow.schemas import get_schema
from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body, pose_mesh
from mocapflow.tasks.shared.reflectors import REFLECTOR_NAMES
from mocapflow.tasks.deepmocap.film.synth import build_rig, synthesize
from mocapflow.tasks.studio.spec import SequenceSpec


@pytest.fixture(scope="module")
def take():
    rig = build_rig(SequenceSpec(motion="jumping_jack", frames=6, seed=7, body="mesh", random_layout=True))
    return rig, synthesize(rig, 2, 5)


def test_a_mesh_sequence_is_a_valid_raw_sequence_with_every_reflector_seen(take):
    rig, ds = take
    get_schema("raw_sequence").validate(ds)
    assert ds.attrs["body"] == "mesh" and Phenotype(**ds.attrs["phenotype"]) == rig.body.phenotype
    assert ds.depth.shape[:2] == (3, 3) and list(ds.frame.values) == [2, 3, 4]
    seen = ds.gt_pixels.values.max(axis=(0, 1))
    assert (seen > 0).all(), [n for n, s in zip(REFLECTOR_NAMES, seen) if not s]
    body = ds.gt_body.values
    assert 0.02 < body.mean() < 0.3
    # reflector pixels have no depth and saturate the IR, as on the capsule body
    refl = ds.gt_reflector_id.values >= 0
    assert (ds.depth.values[refl] == 0).all() and np.median(ds.ir.values[refl]) > 60000
    assert np.median(ds.ir.values[body & ~refl]) < 20000


def test_each_visible_patch_projects_onto_its_own_pixels(take):
    rig, ds = take
    rid = ds.gt_reflector_id.values
    uv = ds.gt_reflectors2d.values
    checked = 0
    for r, placement in enumerate(rig.placements):
        if placement.kind != "patch":
            continue
        for v in range(3):
            for i in range(3):
                if ds.gt_pixels.values[v, i, r] < 30:
                    continue
                ys, xs = np.nonzero(rid[v, i] == r)
                centre = uv[v, i, r]
                assert np.hypot(xs - centre[0], ys - centre[1]).min() < 2.0, (placement.name, v, i)
                assert np.hypot(xs.mean() - centre[0], ys.mean() - centre[1]) < 6.0, (placement.name, v, i)
                checked += 1
    assert checked > 20


def test_the_stored_bone_rotations_root_and_phenotype_reproduce_the_mesh(take):
    rig, ds = take
    body = mesh_body(Phenotype(**ds.attrs["phenotype"]))
    n = ds.sizes["frame"]
    rot = Rotation.from_quat(ds.gt_bone_rotations.values.reshape(-1, 4)).as_matrix().reshape(n, -1, 3, 3)
    posed = pose_mesh(body, rot, ds.gt_root.values)
    np.testing.assert_allclose(posed.vertices, rig.take.posed.vertices[2:5], atol=1e-9)
    np.testing.assert_allclose(ds.gt_joints.values, posed.heads[:, body.joint_bones()], atol=1e-6)


def test_the_same_spec_renders_the_same_bytes_and_the_capsule_body_is_unchanged(take):
    rig, ds = take
    again = synthesize(build_rig(rig.spec), 2, 5)
    for name in ("depth", "ir", "gt_reflector_id", "gt_scene_flow", "gt_reflectors"):
        assert np.array_equal(again[name].values, ds[name].values), name
    capsule = build_rig(SequenceSpec(motion="jumping_jack", frames=6, seed=7, random_layout=True))
    mesh_cams = [v.cam.cam_to_world for v in rig.views]
    assert all(np.array_equal(a, v.cam.cam_to_world) for a, v in zip(mesh_cams, capsule.views))  # one layout per seed
    assert "body" not in synthesize(capsule, 0, 1).attrs


@pytest.mark.parametrize("height", [1.50, 2.00])
def test_a_body_asked_for_at_the_end_of_the_height_range_is_filmed(height):
    # the mesh measures its own height a few micrometres off the one asked for; the take must not refuse it
    spec = SequenceSpec("crossing_legs", frames=2, seed=1227, body="mesh", subject_height=height)
    rig = build_rig(spec)
    assert abs(rig.body.height - height) < 1e-4 and abs(rig.subject.height - height) < 1e-4
    assert 1.50 <= rig.subject.height <= 2.00
    raw = synthesize(rig, 0, 2)
    assert raw.sizes["frame"] == 2 and raw.gt_pixels.values.max() > 0
